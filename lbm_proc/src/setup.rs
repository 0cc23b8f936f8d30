//! From a checked scene (SI) to the lattice: units, box, walls, gates, the
//! initial liquid, and the solver parameters.
//!
//! Cell (i, j, k) has its centre at `domain.min + (i + ½, j + ½, k + ½) Δx`.
//! Every face of the box is a no-slip wall for the liquid (half-way
//! bounce-back, so the wall lies half a cell beyond the first and last
//! nodes: exactly on the domain face when the box is a whole number of
//! cells). A gate is a slab of wall cells one cell thick on the closed side
//! of its plane, removed at its release time.

use schemas::scene::{Collision as SceneCollision, Hydrostatics, Scene};

use crate::fluid::{Collision, Faces, FluidParams};
use crate::units::Units;
use crate::watchdog::WatchdogLimits;

/// Why a scene cannot be put on a lattice.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SetupError {
    #[error("lbm_proc simulates one liquid: fluids[{index}] has density {density} kg/m³ and viscosity {viscosity} Pa s, fluids[0] has {density0} and {viscosity0}; give every fluid block the same liquid")]
    MixedLiquids { index: usize, density: f64, viscosity: f64, density0: f64, viscosity0: f64 },
    #[error("the scene has no [[fluids]] block: nothing for the LBM to do (grain-only scenes run in dem_proc)")]
    NoLiquid,
    #[error("lattice units: {0}")]
    Units(String),
}

/// A gate on the lattice.
#[derive(Debug, Clone, PartialEq)]
pub struct LatticeGate {
    pub name: String,
    /// Simulated time at which its cells stop being walls, s.
    pub release_time: f64,
    /// The wall cells.
    pub cells: Vec<[usize; 3]>,
}

/// Everything `lbm_proc` needs from a scene, in lattice units where it says so.
#[derive(Debug, Clone)]
pub struct LbmSetup {
    pub units: Units,
    /// Cells along x, y, z.
    pub dims: [usize; 3],
    /// Lower corner of the lattice (the domain's), m.
    pub origin: [f64; 3],
    pub faces: [Faces; 3],
    pub params: FluidParams,
    pub limits: WatchdogLimits,
    pub gates: Vec<LatticeGate>,
    /// Liquid density, kg/m³, and kinematic viscosity, m²/s.
    pub density: f64,
    pub kinematic_viscosity: f64,
    /// −ρ_L g, N/m³: the buoyancy per unit grain volume added to every
    /// grain's load when the lattice leaves the liquid's weight out
    /// (`lbm.hydrostatics = "buoyancy"`); zero otherwise.
    pub grain_buoyancy: [f64; 3],
    /// Lines for the log: rounding of the box, τ.
    pub notes: Vec<String>,
}

impl LbmSetup {
    pub fn from_scene(scene: &Scene) -> Result<Self, SetupError> {
        let spec = &scene.spec;
        let first = spec.fluids.first().ok_or(SetupError::NoLiquid)?;
        for (index, f) in spec.fluids.iter().enumerate().skip(1) {
            if f.density != first.density || f.viscosity != first.viscosity {
                return Err(SetupError::MixedLiquids {
                    index,
                    density: f.density,
                    viscosity: f.viscosity,
                    density0: first.density,
                    viscosity0: first.viscosity,
                });
            }
        }
        let lbm = scene.lbm();
        let units =
            Units::new(lbm.spacing, lbm.time_step, first.density).map_err(|e| SetupError::Units(e.to_string()))?;
        let nu = first.viscosity / first.density;
        let tau = units.tau_from_viscosity(nu).map_err(|e| SetupError::Units(e.to_string()))?;
        let d = &spec.domain;
        let dx = lbm.spacing;
        let mut notes = Vec::new();
        let dims = [0, 1, 2].map(|a| {
            let exact = (d.max[a] - d.min[a]) / dx;
            let n = (exact.round() as usize).max(3);
            if (n as f64 - exact).abs() > 1e-6 {
                notes.push(format!(
                    "the domain is {:.6} m along {}, not a whole number of cells of {dx} m: the lattice has {n} cells ({:.6} m), so the far wall sits {:+.2e} m from the domain face",
                    d.max[a] - d.min[a],
                    ["x", "y", "z"][a],
                    n as f64 * dx,
                    n as f64 * dx - (d.max[a] - d.min[a])
                ));
            }
            n
        });
        let collision = match lbm.collision {
            SceneCollision::Bgk => Collision::Bgk,
            SceneCollision::Trt => Collision::Trt { magic: lbm.trt_magic },
        };
        let params = FluidParams {
            collision,
            smagorinsky: lbm.smagorinsky,
            acceleration: match lbm.hydrostatics {
                Hydrostatics::Lattice => d.gravity.map(|g| units.acceleration_to_lattice(g)),
                Hydrostatics::Buoyancy => [0.0; 3],
            },
            ..FluidParams::new(tau)
        };
        let grain_buoyancy = match lbm.hydrostatics {
            Hydrostatics::Lattice => [0.0; 3],
            Hydrostatics::Buoyancy => {
                notes.push(format!(
                    "hydrostatics = buoyancy: the liquid feels no gravity; each grain's load gets -rho_L V g = {:.4e} N per cm^3 of grain",
                    first.density * scene.gravity_magnitude() * 1e-6
                ));
                d.gravity.map(|g| -first.density * g)
            }
        };
        notes.push(format!(
            "lattice {} x {} x {} cells of {dx} m, dt {} s; tau0 = {tau:.6}, {:?}, Smagorinsky C = {}",
            dims[0], dims[1], dims[2], lbm.time_step, collision, lbm.smagorinsky
        ));
        let mut setup = LbmSetup {
            units,
            dims,
            origin: d.min,
            faces: [Faces::Walls; 3],
            params,
            limits: WatchdogLimits { max_mach: lbm.mach_limit, ..WatchdogLimits::default() },
            gates: Vec::new(),
            density: first.density,
            kinematic_viscosity: nu,
            grain_buoyancy,
            notes,
        };
        for (g, gate) in spec.gates.iter().enumerate() {
            let n = scene.gate_normals[g];
            let cells = setup.cells_where(|c| {
                // Signed distance of the centre from the plane, positive on the open side.
                let s: f64 = (0..3).map(|a| (c[a] - gate.point[a]) * n[a]).sum();
                s <= 0.0 && s > -dx
            });
            setup.gates.push(LatticeGate { name: gate.name.clone(), release_time: gate.release_time, cells });
        }
        Ok(setup)
    }

    /// Centre of cell `c`, m.
    pub fn centre(&self, c: [usize; 3]) -> [f64; 3] {
        let dx = self.units.dx();
        [0, 1, 2].map(|a| self.origin[a] + (c[a] as f64 + 0.5) * dx)
    }

    /// The cells whose centre satisfies `keep`, x fastest.
    pub fn cells_where(&self, keep: impl Fn([f64; 3]) -> bool) -> Vec<[usize; 3]> {
        let [nx, ny, nz] = self.dims;
        let mut out = Vec::new();
        for k in 0..nz {
            for j in 0..ny {
                for i in 0..nx {
                    if keep(self.centre([i, j, k])) {
                        out.push([i, j, k]);
                    }
                }
            }
        }
        out
    }

    /// Whether the centre of `c` lies in a fluid block's region (and in no gate).
    pub fn starts_liquid(&self, scene: &Scene, c: [usize; 3]) -> bool {
        let x = self.centre(c);
        let inside = |min: [f64; 3], max: [f64; 3]| (0..3).all(|a| x[a] >= min[a] && x[a] < max[a]);
        scene.spec.fluids.iter().any(|f| inside(f.region.min, f.region.max))
            && !self.gates.iter().any(|g| g.cells.binary_search_by(|p| order(p).cmp(&order(&c))).is_ok())
    }
}

/// Sort key matching `cells_where`'s order (x fastest).
fn order(c: &[usize; 3]) -> [usize; 3] {
    [c[2], c[1], c[0]]
}
