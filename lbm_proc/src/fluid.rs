//! The lattice state and its time step.
//!
//! [`Fluid::step`] is one stage, `stream_collide`, fused per cell: pull the 19
//! incoming populations (half-way bounce-back where the source is a wall),
//! take the moments, relax (BGK or TRT, each with the Smagorinsky eddy
//! viscosity), add Guo's forcing, and write the post-collision populations to
//! the second lattice. The lattices are then swapped (A/B pattern). Work is
//! split over z-planes with rayon; the step allocates nothing.
//!
//! Storage, chosen for a bandwidth-bound kernel (lbm-free-surface.md §5):
//! * populations struct-of-arrays, population i of cell c at `i * ncells + c`,
//!   cells x-fastest, so one x-row of one direction is contiguous and the
//!   kernel works on rows of [`LANES`] cells with plain vector loops;
//! * shifted: the stored value is f_i − w_i (ρ0 = 1), as FluidX3D does
//!   (Lehmann et al. 2022, PRE 106, 015308). Near rest f_i − w_i is ~1e-3 of
//!   f_i, so f32 keeps ~3 more significant digits of the non-equilibrium
//!   part and of the density deviation than unshifted f32 would;
//! * the stored populations are post-collision: ρ and u at the current time
//!   are read from them directly (Guo's scheme puts ρu + F/2 into the
//!   post-collision momentum), so no macroscopic field is written in the hot
//!   loop;
//! * one flag byte per cell ([`flags`]), and one class byte per x-row that
//!   says whether the row holds liquid at all, whether it holds interface
//!   cells, and whether its pulls can touch a non-fluid cell. Rows with no
//!   liquid (gas above the free surface) cost nothing; rows far from walls
//!   and the surface skip the per-cell flag checks.
//!
//! The free surface (mass tracking, `free_surface`) adds interface and gas
//! cells: the kernel rebuilds the populations an interface cell pulls from
//! gas and accumulates its mass exchange in the same pass; conversions run
//! after it. Direct forcing of particle-covered cells (Eq. 5, [`ForcedCell`],
//! driven by [`crate::coupling`]) is computed in the same pass, between the
//! pull and the collision, for the listed cells only.

use rayon::prelude::*;
use runtime::isa::Isa;

use crate::memory::{huge_copy, huge_vec};
use schemas::scene::ForcingGain;
use serde::{Deserialize, Serialize};
use std::time::Instant;

use crate::lattice::{E, OPP, Q, W};
use crate::real::Real;
use crate::watchdog::{Instability, Quantity, WatchdogLimits};

mod forcing;
mod free_surface;
pub use forcing::{forcing_gain, uses_effective_tau, AppliedForce, ForcedCell};
pub use free_surface::{InterfaceCell, Sample};

/// Cell flags. Liquid cells (fluid, interface) have bit 0 clear, so the
/// kernel tells "pull from here" from "bounce back" with one bit test.
pub mod flags {
    /// A liquid cell: collides and streams.
    pub const FLUID: u8 = 0;
    /// A no-slip obstacle: links into it bounce back half-way.
    pub const WALL: u8 = 1;
    /// A partly filled cell of the free surface: collides and streams, and
    /// tracks its liquid mass m; populations pulled from gas are rebuilt.
    pub const INTERFACE: u8 = 2;
    /// An empty cell: stores nothing meaningful and is never computed.
    pub const GAS: u8 = 3;

    /// Fluid or interface: the cells that collide, stream and hold liquid.
    #[inline(always)]
    pub fn is_liquid(flag: u8) -> bool {
        flag & 1 == 0
    }
}

/// Cells per vector chunk of a row: long enough that each of the 38 streams
/// moves 512 B (f32) per visit, which the hardware prefetchers need (32 lanes
/// ran ~30 % slower), short enough that the 19-row buffer stays in L1.
pub const LANES: usize = 128;

/// What lies beyond the two faces of the box normal to one axis.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum Faces {
    /// The box wraps around.
    Periodic,
    /// No-slip walls half a cell beyond the first and last nodes.
    Walls,
}

/// The collision operator.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub enum Collision {
    /// Single relaxation time 1/τ.
    Bgk,
    /// Two relaxation times (Ginzburg): τ+ sets the viscosity, τ− = ½ + Λ/(τ+ − ½).
    /// Λ = 3/16 puts the half-way bounce-back wall exactly mid-link for
    /// Poiseuille flow; Λ = 1/4 is the most stable choice.
    Trt {
        /// The magic parameter Λ.
        magic: f64,
    },
}

impl Collision {
    /// TRT with Λ = 3/16 (as FluidX3D).
    pub const TRT_3_16: Collision = Collision::Trt { magic: 3.0 / 16.0 };
}

/// Physical parameters, lattice units.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct FluidParams {
    /// Molecular relaxation time τ0 = 3ν_L + ½ (see [`crate::units::Units::tau_from_viscosity`]); > ½.
    pub tau: f64,
    pub collision: Collision,
    /// Smagorinsky constant C of Eq. 4 (paper: 0.16); 0 switches the eddy viscosity off.
    pub smagorinsky: f64,
    /// Body acceleration (gravity), lattice units; the force density is ρ a,
    /// in interface cells too (docs/lbm.md, "Free surface").
    pub acceleration: [f64; 3],
    /// Free-surface conversion margin κ: an interface cell fills when
    /// m > (1 + κ)ρ and empties when m < −κρ (Thürey 2007: 1e-3). The margin
    /// stops cells from toggling between states on round-off-sized flux.
    #[serde(default = "default_kappa")]
    pub kappa: f64,
}

fn default_kappa() -> f64 {
    1e-3
}

impl FluidParams {
    /// τ0 with the defaults: BGK, C = 0.16, no body force. BGK is the
    /// default because at the paper's τ0 = 0.500667 it survived even without
    /// Smagorinsky where TRT 3/16 (τ− ≈ 280) blew up, and its eddy viscosity
    /// matches Eq. 4 (tests/stability.rs, tests/flows.rs); TRT 3/16 is the
    /// choice when the wall position matters (exact Poiseuille).
    pub fn new(tau: f64) -> Self {
        FluidParams {
            tau,
            collision: Collision::Bgk,
            smagorinsky: 0.16,
            acceleration: [0.0; 3],
            kappa: default_kappa(),
        }
    }

    fn validate(&self) -> Result<(), ConfigError> {
        if !(self.tau.is_finite() && self.tau > 0.5) {
            return Err(ConfigError::Tau(self.tau));
        }
        if !(self.smagorinsky.is_finite() && self.smagorinsky >= 0.0) {
            return Err(ConfigError::Smagorinsky(self.smagorinsky));
        }
        if let Collision::Trt { magic } = self.collision {
            if !(magic.is_finite() && magic > 0.0) {
                return Err(ConfigError::Magic(magic));
            }
        }
        if !self.acceleration.iter().all(|a| a.is_finite()) {
            return Err(ConfigError::Acceleration(self.acceleration));
        }
        if !(0.0..0.5).contains(&self.kappa) {
            return Err(ConfigError::Kappa(self.kappa));
        }
        Ok(())
    }
}

/// Why a fluid cannot be built or changed as asked.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ConfigError {
    #[error("relaxation time tau must be finite and > 0.5, got {0} (tau = 0.5 is zero viscosity)")]
    Tau(f64),
    #[error("Smagorinsky constant must be finite and >= 0, got {0}")]
    Smagorinsky(f64),
    #[error("TRT magic parameter must be finite and > 0, got {0}")]
    Magic(f64),
    #[error("body acceleration must be finite, got {0:?}")]
    Acceleration([f64; 3]),
    #[error("free-surface conversion margin kappa must lie in [0, 0.5), got {0}")]
    Kappa(f64),
    #[error("set_flag takes FLUID or WALL (interface and gas come from init_liquid / remove_walls), got {0}")]
    Flag(u8),
    #[error("cell {0:?} is not a wall, so it cannot be removed")]
    NotWall([usize; 3]),
    #[error("box dimensions must be >= 1 cell each, got {0:?}")]
    Dims([usize; 3]),
    #[error("cell {cell:?} lies outside the box {dims:?}")]
    OutOfBox { cell: [usize; 3], dims: [usize; 3] },
    #[error("state is inconsistent: {0}")]
    State(String),
    #[error("cell {0:?} would be a fluid cell next to gas: an interface cell must separate them (set geometry before init_liquid)")]
    FluidNextToGas([usize; 3]),
    #[error("forced cell {cell}: {why}")]
    Forcing { cell: usize, why: &'static str },
}

/// Everything needed to continue a run exactly (with [`FluidParams`]).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FluidState<T> {
    /// Cells along x, y, z.
    pub dims: [usize; 3],
    pub faces: [Faces; 3],
    /// One of [`flags`] per cell, x fastest.
    pub flags: Vec<u8>,
    /// Post-collision f_i − w_i, population i of cell c at `i * ncells + c`.
    pub populations: Vec<T>,
    /// Liquid mass m of each interface cell (f64 whatever `T` is, so that
    /// mass is conserved to f64 round-off); 0 in all other cells (a fluid
    /// cell's mass is its density ρ).
    pub mass: Vec<f64>,
    /// Excess mass of conversions that found no interface neighbour to take
    /// it; counted in [`Fluid::liquid_mass`], never dropped.
    pub pending_excess: f64,
    /// Liquid mass when the liquid was set up, for [`Fluid::mass_drift`].
    pub reference_mass: Option<f64>,
    /// Steps taken.
    pub step: u64,
}

/// Row classes (bits of `Scratch::rows`).
/// The row holds a fluid or interface cell; rows without are skipped.
const ROW_ANY_LIQUID: u8 = 1;
const ROW_ALL_FLUID: u8 = 2;
/// Every source row of every pull is all fluid: no per-cell wall checks needed.
const ROW_SOURCES_FLUID: u8 = 4;
/// The row holds an interface cell (reconstruction and mass exchange).
const ROW_ANY_INTERFACE: u8 = 8;
/// The row holds a wall cell (an obstacle inside the box).
const ROW_ANY_WALL: u8 = 16;
/// No source row of any pull holds a wall cell: sources are liquid or gas.
const ROW_SOURCES_NO_WALL: u8 = 32;

/// Buffers the step needs besides the state.
#[derive(Debug, Clone)]
struct Scratch<T> {
    /// The lattice written by the step.
    next: Vec<T>,
    /// Class of each x-row, index `z * ny + y`.
    rows: Vec<u8>,
    /// Liquid span of each x-row: its first liquid cell and one past its
    /// last (0..0 without liquid), kept with the classes.
    spans: Vec<(u32, u32)>,
    rows_stale: bool,
    /// Fill ε = m/ρ of every cell (1 fluid, 0 gas and wall) as of the end of
    /// the last step: the old-level ε both sides of an interface–interface
    /// link use, which makes the exchange antisymmetric.
    fill: Vec<f64>,
    /// Density ρ of every interface cell (stale elsewhere), summed by the
    /// kernel from the populations it writes, as [`Fluid::density_at`] sums
    /// them, and kept by the conversions for the cells they make interface:
    /// the conversions read one value instead of 19 scattered ones.
    interface_density: Vec<f64>,
    /// Interface cells, ascending index.
    interface: Vec<usize>,
    /// Number of fluid cells.
    fluid_count: usize,
    /// Times the pending excess was given back to the liquid, and the mass
    /// given back (lattice units): diagnostics, not part of the state.
    pending_returned: u64,
    returned_mass: f64,
    /// Conversion work lists, reused every step.
    lists: free_surface::Lists,
    /// Direct forcing for the next steps and what it did in the last one.
    forcing: forcing::Forcing,
}

/// A D3Q19 fluid in a box of cells.
#[derive(Debug, Clone)]
pub struct Fluid<T: Real = f32> {
    state: FluidState<T>,
    params: FluidParams,
    scratch: Scratch<T>,
    /// The instruction set the stream-collide kernel runs with (results do
    /// not depend on it); `Isa::current()` unless set.
    isa: Isa,
    /// Wall seconds spent in each stage of [`Fluid::step`] since creation.
    pub stage_seconds: FluidStageSeconds,
    /// A step begun by [`Fluid::begin_step`] still needs its free-surface
    /// conversions ([`Fluid::finish_step`]).
    surface_pending: bool,
}

/// Wall time per stage of [`Fluid::step`], s.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct FluidStageSeconds {
    /// Row classification after flag changes, and sizing the applied-force list.
    pub prepare: f64,
    pub stream_collide: f64,
    /// Fill conversions, excess distribution, interface list (the mass
    /// exchange Δm is part of `stream_collide`).
    pub update_surface: f64,
}

/// Per-step constants of the collision, in the kernel's float type.
#[derive(Clone, Copy)]
struct Coefficients<T> {
    tau0: T,
    tau0_sq: T,
    /// 18√2 C² of the closed-form τ_eff.
    smag: T,
    magic: T,
    accel: [T; 3],
}

impl<T: Real> Fluid<T> {
    /// A box of fluid cells at rest (u = 0 under the body force), ρ = 1.
    pub fn new(dims: [usize; 3], faces: [Faces; 3], params: FluidParams) -> Result<Self, ConfigError> {
        params.validate()?;
        let ncells = dims[0]
            .checked_mul(dims[1])
            .and_then(|n| n.checked_mul(dims[2]))
            .filter(|&n| n > 0 && n.checked_mul(Q).is_some())
            .ok_or(ConfigError::Dims(dims))?;
        let rest = crate::lattice::equilibrium(1.0, params.acceleration.map(|a| 0.5 * a));
        let state = FluidState {
            dims,
            faces,
            flags: huge_vec(ncells, |_| flags::FLUID),
            populations: huge_vec(Q * ncells, |k| T::from_f64(rest[k / ncells] - W[k / ncells])),
            mass: huge_vec(ncells, |_| 0.0),
            pending_excess: 0.0,
            reference_mass: None,
            step: 0,
        };
        Self::from_placed_state(state, params)
    }

    /// Continues from a saved state.
    pub fn from_state(mut state: FluidState<T>, params: FluidParams) -> Result<Self, ConfigError> {
        // A decoded state's arrays were touched on normal pages: copied once
        // onto huge pages (memory.rs), 1.7 GB for the lab column.
        state.flags = huge_copy(&state.flags);
        state.populations = huge_copy(&state.populations);
        state.mass = huge_copy(&state.mass);
        Self::from_placed_state(state, params)
    }

    /// [`Fluid::from_state`] for a state whose arrays are already placed.
    fn from_placed_state(state: FluidState<T>, params: FluidParams) -> Result<Self, ConfigError> {
        params.validate()?;
        let [nx, ny, nz] = state.dims;
        let ncells = nx * ny * nz;
        if ncells == 0
            || state.flags.len() != ncells
            || state.populations.len() != Q * ncells
            || state.mass.len() != ncells
        {
            return Err(ConfigError::State(format!(
                "dims {:?} need {} flags, {} populations and {} masses, got {}, {} and {}",
                state.dims,
                ncells,
                Q * ncells,
                ncells,
                state.flags.len(),
                state.populations.len(),
                state.mass.len()
            )));
        }
        if let Some(c) = state.flags.iter().position(|&f| f > flags::GAS) {
            return Err(ConfigError::State(format!("cell index {c} has unknown flag {}", state.flags[c])));
        }
        if !state.pending_excess.is_finite() || state.mass.iter().any(|m| !m.is_finite()) {
            return Err(ConfigError::State("liquid masses must be finite".into()));
        }
        let scratch = Scratch {
            next: huge_copy(&state.populations),
            rows: vec![0; ny * nz],
            spans: vec![(0, 0); ny * nz],
            rows_stale: true,
            fill: huge_vec(ncells, |_| 0.0),
            interface_density: huge_vec(ncells, |_| 0.0),
            interface: Vec::new(),
            fluid_count: 0,
            pending_returned: 0,
            returned_mass: 0.0,
            lists: Default::default(),
            forcing: Default::default(),
        };
        let mut fluid = Fluid {
            state,
            params,
            scratch,
            isa: Isa::current(),
            stage_seconds: FluidStageSeconds::default(),
            surface_pending: false,
        };
        // The kernel relies on it: only interface cells pull from gas.
        let [nx, ny, _] = fluid.state.dims;
        let flags = &fluid.state.flags;
        if let Some(c) = (0..ncells).into_par_iter().find_first(|&c| flags[c] == flags::FLUID && fluid.borders_gas(c)) {
            return Err(ConfigError::FluidNextToGas([c % nx, (c / nx) % ny, c / (nx * ny)]));
        }
        fluid.rebuild_lists();
        fluid.classify_rows();
        Ok(fluid)
    }

    pub fn state(&self) -> &FluidState<T> {
        debug_assert!(!self.surface_pending, "a step begun by begin_step needs finish_step before its state is read");
        &self.state
    }
    /// Runs the kernel with `isa`, lowered to what the CPU supports.
    pub fn set_isa(&mut self, isa: Isa) {
        self.isa = isa.min(Isa::best_supported());
    }
    pub fn isa(&self) -> Isa {
        self.isa
    }
    pub fn params(&self) -> &FluidParams {
        &self.params
    }
    pub fn set_params(&mut self, params: FluidParams) -> Result<(), ConfigError> {
        params.validate()?;
        self.params = params;
        Ok(())
    }
    pub fn dims(&self) -> [usize; 3] {
        self.state.dims
    }
    pub fn ncells(&self) -> usize {
        self.state.flags.len()
    }
    pub fn steps(&self) -> u64 {
        self.state.step
    }

    fn index(&self, cell: [usize; 3]) -> Result<usize, ConfigError> {
        let [nx, ny, nz] = self.state.dims;
        if cell[0] < nx && cell[1] < ny && cell[2] < nz {
            Ok((cell[2] * ny + cell[1]) * nx + cell[0])
        } else {
            Err(ConfigError::OutOfBox { cell, dims: self.state.dims })
        }
    }

    pub fn flag(&self, cell: [usize; 3]) -> Result<u8, ConfigError> {
        Ok(self.state.flags[self.index(cell)?])
    }

    /// Makes `cell` a wall (`flags::WALL`) or a fluid cell (`flags::FLUID`):
    /// geometry set-up. An interface cell overwritten here loses its tracked
    /// mass; set walls before [`Fluid::init_liquid`], and open a gate during a
    /// run with [`Fluid::remove_walls`].
    pub fn set_flag(&mut self, cell: [usize; 3], flag: u8) -> Result<(), ConfigError> {
        // A begun step's conversions read the kernel's interface densities: finish it first.
        self.finish_step();
        let c = self.index(cell)?;
        if flag != flags::FLUID && flag != flags::WALL {
            return Err(ConfigError::Flag(flag));
        }
        if flag == flags::FLUID && self.borders_gas(c) {
            return Err(ConfigError::FluidNextToGas(cell));
        }
        let old = self.state.flags[c];
        if old == flags::INTERFACE {
            if let Ok(k) = self.scratch.interface.binary_search(&c) {
                self.scratch.interface.remove(k);
            }
        }
        if old == flags::FLUID {
            self.scratch.fluid_count -= 1;
        }
        self.state.flags[c] = flag;
        self.state.mass[c] = 0.0;
        self.scratch.rows_stale = true;
        if flag == flags::FLUID {
            self.scratch.fluid_count += 1;
            self.scratch.fill[c] = 1.0;
        } else {
            self.scratch.fill[c] = 0.0;
            // The step never writes non-liquid cells; keeping them equal in
            // both lattices makes the state independent of the step parity.
            self.write_cell(c, &[0.0; Q]);
        }
        Ok(())
    }

    /// Sets `cell` to equilibrium with density `rho` and velocity `u` (lattice units).
    ///
    /// The stored populations are post-collision, whose momentum is ρ(u + a/2)
    /// under Guo forcing, so the equilibrium is taken at u + a/2; the cell
    /// then reports exactly (ρ, u).
    pub fn set_equilibrium(&mut self, cell: [usize; 3], rho: f64, u: [f64; 3]) -> Result<(), ConfigError> {
        // A begun step's conversions read the kernel's interface densities: finish it first.
        self.finish_step();
        let c = self.index(cell)?;
        let a = self.params.acceleration;
        let feq = crate::lattice::equilibrium(rho, [u[0] + 0.5 * a[0], u[1] + 0.5 * a[1], u[2] + 0.5 * a[2]]);
        self.write_cell(c, &std::array::from_fn(|i| feq[i] - W[i]));
        if self.state.flags[c] == flags::INTERFACE {
            self.scratch.fill[c] = self.state.mass[c] / self.density_at(c);
        }
        Ok(())
    }

    /// Sets the stored f_i − w_i of cell index `c` in both lattices.
    fn write_cell(&mut self, c: usize, g: &[f64; Q]) {
        let n = self.ncells();
        for i in 0..Q {
            self.state.populations[i * n + c] = T::from_f64(g[i]);
            self.scratch.next[i * n + c] = T::from_f64(g[i]);
        }
    }

    /// Whether a D3Q19 neighbour of cell index `c` is gas.
    fn borders_gas(&self, c: usize) -> bool {
        self.neighbours(c)[1..].iter().flatten().any(|&nb| self.state.flags[nb] == flags::GAS)
    }

    /// Density and velocity of cell index `c` (lattice units), from the
    /// post-collision populations: ρ = Σf, u = (Σ f e − F/2)/ρ.
    fn moments_at(&self, c: usize) -> (f64, [f64; 3]) {
        self.moments_with(c, self.scratch.forcing.last_force(c, self.state.dims[0]))
    }

    /// [`Fluid::moments_at`] with the cell's last direct force `ib` given.
    fn moments_with(&self, c: usize, ib: [f64; 3]) -> (f64, [f64; 3]) {
        let n = self.ncells();
        let p = &self.state.populations;
        let mut drho = 0.0;
        let mut j = [0.0; 3];
        for i in 0..Q {
            let g = p[i * n + c].to_f64();
            drho += g;
            for a in 0..3 {
                j[a] += E[i][a] as f64 * g;
            }
        }
        let rho = 1.0 + drho;
        let acc = self.params.acceleration;
        // A forced cell's stored momentum also holds half its last direct force.
        (rho, std::array::from_fn(|a| (j[a] - 0.5 * ib[a]) / rho - 0.5 * acc[a]))
    }

    /// Density ρ = Σ f_i of cell index `c`, summed as [`Fluid::moments_at`] does.
    fn density_at(&self, c: usize) -> f64 {
        let n = self.ncells();
        density_of(|i| self.state.populations[i * n + c].to_f64())
    }

    /// Density and velocity of `cell`, lattice units.
    pub fn moments(&self, cell: [usize; 3]) -> Result<(f64, [f64; 3]), ConfigError> {
        Ok(self.moments_at(self.index(cell)?))
    }

    /// Liquid mass Σ_F ρ + Σ_I m + pending excess (lattice units: ρ0Δx³),
    /// summed in f64 in a fixed order (ascending cell, whatever the thread
    /// count: the terms are found plane by plane in parallel, then added in
    /// order). Without a free surface this is Σρ.
    pub fn liquid_mass(&self) -> f64 {
        let fl = &self.state.flags;
        let terms: Vec<f64> = self
            .liquid_planes()
            .flat_map_iter(|cells| {
                cells.filter_map(move |c| match fl[c] {
                    flags::FLUID => Some(self.density_at(c)),
                    flags::INTERFACE => Some(self.state.mass[c]),
                    _ => None,
                })
            })
            .collect();
        terms.iter().sum::<f64>() + self.state.pending_excess
    }

    /// Each cell holding liquid (fill ε > 0) with its liquid mass ρε
    /// (lattice units), in ascending cell order; planes in parallel.
    pub fn liquid_cell_masses(&self) -> Vec<(usize, f64)> {
        let fill = &self.scratch.fill;
        self.liquid_planes()
            .flat_map_iter(|cells| cells.filter(|&c| fill[c] > 0.0).map(|c| (c, self.density_at(c) * fill[c])))
            .collect()
    }

    /// Per z-plane, in order, the cells of its liquid spans (the rows'
    /// first to last liquid cell; rows without liquid are skipped).
    fn liquid_planes(&self) -> impl IndexedParallelIterator<Item = impl Iterator<Item = usize> + '_> + '_ {
        let [nx, ny, nz] = self.state.dims;
        let stale = self.scratch.rows_stale;
        (0..nz).into_par_iter().map(move |z| {
            (0..ny).flat_map(move |y| {
                let r = z * ny + y;
                // Row spans are valid unless flags changed since the last step.
                let (lo, hi) =
                    if stale { (0, nx) } else { (self.scratch.spans[r].0 as usize, self.scratch.spans[r].1 as usize) };
                (r * nx + lo)..(r * nx + hi)
            })
        })
    }

    /// (liquid mass − reference)/reference, the reference being the liquid
    /// mass when [`Fluid::init_liquid`] (or [`Fluid::mark_reference_mass`])
    /// ran; `None` before either.
    pub fn mass_drift(&self) -> Option<f64> {
        self.state.reference_mass.map(|m0| (self.liquid_mass() - m0) / m0)
    }

    /// Takes the current liquid mass as the reference of [`Fluid::mass_drift`].
    pub fn mark_reference_mass(&mut self) {
        self.state.reference_mass = Some(self.liquid_mass());
    }

    /// Visits the liquid cells of plane z in ascending order with their
    /// density and velocity ([`Fluid::moments_at`]), walking the forced
    /// cells along: a binary search of them per cell cost more than the
    /// moments in a packed bed (every liquid cell forced).
    fn plane_liquid_moments(&self, z: usize, mut visit: impl FnMut(usize, f64, [f64; 3])) {
        let [nx, ny, _] = self.state.dims;
        let (start, end) = (z * nx * ny, (z + 1) * nx * ny);
        let mut forced = self.scratch.forcing.cursor_from(start);
        for c in start..end {
            if flags::is_liquid(self.state.flags[c]) {
                let (rho, u) = self.moments_with(c, forced.force_at(c));
                visit(c, rho, u);
            }
        }
    }

    /// ½ Σ m u² over fluid (m = ρ) and interface cells, lattice units.
    /// Planes in parallel, summed in plane order (the same for any thread count).
    pub fn kinetic_energy(&self) -> f64 {
        let planes: Vec<f64> = (0..self.state.dims[2])
            .into_par_iter()
            .map(|z| {
                let mut e = 0.0;
                self.plane_liquid_moments(z, |c, rho, u| {
                    let m = if self.state.flags[c] == flags::INTERFACE { self.state.mass[c] } else { rho };
                    e += 0.5 * m * (u[0] * u[0] + u[1] * u[1] + u[2] * u[2]);
                });
                e
            })
            .collect();
        planes.iter().sum()
    }

    /// Largest |u| over fluid and interface cells, lattice units.
    pub fn max_speed(&self) -> f64 {
        (0..self.state.dims[2])
            .into_par_iter()
            .map(|z| {
                let mut max = 0.0_f64;
                self.plane_liquid_moments(z, |_, _, u| max = max.max((u[0] * u[0] + u[1] * u[1] + u[2] * u[2]).sqrt()));
                max
            })
            .reduce(|| 0.0, f64::max)
    }

    /// The first fluid or interface cell (lowest index) whose populations are
    /// not finite, whose density leaves the limits, whose speed exceeds the
    /// Mach limit, or (interface) whose fill ε = m/ρ leaves
    /// [−κ − margin, 1 + κ + margin]. Never panics; meant to run every few
    /// steps. Mass drift is reported by [`Fluid::mass_drift`].
    pub fn check(&self, limits: &WatchdogLimits) -> Result<(), Instability> {
        let [nx, ny, nz] = self.state.dims;
        let n = self.ncells();
        let cs = crate::lattice::CS2.sqrt();
        let found = (0..nz).into_par_iter().find_map_first(|z| {
            // The forced cells walked along, as in `plane_liquid_moments`.
            let mut forced = self.scratch.forcing.cursor_from(z * nx * ny);
            for c in z * nx * ny..(z + 1) * nx * ny {
                let flag = self.state.flags[c];
                if !flags::is_liquid(flag) {
                    continue;
                }
                let bad = if let Some(i) = (0..Q).find(|&i| !self.state.populations[i * n + c].is_finite()) {
                    Some((Quantity::Population(i), self.state.populations[i * n + c].to_f64()))
                } else {
                    let (rho, u) = self.moments_with(c, forced.force_at(c));
                    let mach = (u[0] * u[0] + u[1] * u[1] + u[2] * u[2]).sqrt() / cs;
                    // Written so that NaN moments count as out of bounds.
                    if !(limits.min_density..=limits.max_density).contains(&rho) || rho.is_nan() {
                        Some((Quantity::Density, rho))
                    } else if mach.is_nan() || mach > limits.max_mach {
                        Some((Quantity::Mach, mach))
                    } else if flag == flags::INTERFACE {
                        let fill = self.state.mass[c] / rho;
                        let margin = self.params.kappa + limits.fill_margin;
                        (!(-margin..=1.0 + margin).contains(&fill)).then_some((Quantity::Fill, fill))
                    } else {
                        None
                    }
                };
                if let Some((quantity, value)) = bad {
                    let cell = [c % nx, (c / nx) % ny, c / (nx * ny)];
                    return Some(Instability { step: self.state.step, cell, quantity, value, limits: *limits });
                }
            }
            None
        });
        found.map_or(Ok(()), Err)
    }

    /// Advances one time step: [`Fluid::begin_step`], then
    /// [`Fluid::finish_step`].
    pub fn step(&mut self) {
        self.begin_step();
        self.finish_step();
    }

    /// The first part of a step: stream and collide (direct forcing and the
    /// interface cells' mass exchange included), the lattices swapped, the
    /// step counted. What the forcing applied ([`Fluid::applied_forcing`])
    /// is final here, so a coupled run can answer the DEM and let it step
    /// while [`Fluid::finish_step`] does the free-surface conversions, which
    /// do not change the loads. A step still pending is finished first.
    ///
    /// Post: until `finish_step`, only the forcing read-outs are meaningful;
    /// the state's flags and masses are those before the conversions.
    pub fn begin_step(&mut self) {
        self.finish_step();
        let t0 = Instant::now();
        if self.scratch.rows_stale {
            self.classify_rows();
        }
        self.scratch.forcing.start_step();
        let t1 = Instant::now();
        match self.params.collision {
            Collision::Bgk => self.stream_collide::<false>(),
            Collision::Trt { .. } => self.stream_collide::<true>(),
        }
        std::mem::swap(&mut self.state.populations, &mut self.scratch.next);
        self.state.step += 1;
        self.surface_pending = true;
        let t2 = Instant::now();
        let st = &mut self.stage_seconds;
        st.prepare += (t1 - t0).as_secs_f64();
        st.stream_collide += (t2 - t1).as_secs_f64();
    }

    /// The rest of the step begun by [`Fluid::begin_step`]: the free-surface
    /// conversions (steps 3–9 of `free_surface`). Does nothing when no step
    /// is pending.
    pub fn finish_step(&mut self) {
        if !std::mem::take(&mut self.surface_pending) {
            return;
        }
        let t0 = Instant::now();
        if !self.scratch.interface.is_empty() {
            self.update_surface();
        }
        self.stage_seconds.update_surface += t0.elapsed().as_secs_f64();
    }

    /// Recomputes the row classes after flags changed.
    fn classify_rows(&mut self) {
        let [_, ny, nz] = self.state.dims;
        for r in 0..ny * nz {
            self.classify_row(r);
        }
        for r in 0..ny * nz {
            self.classify_row_sources(r);
        }
        self.scratch.rows_stale = false;
    }

    /// The bits of row `r` that depend on its own cells.
    fn classify_row(&mut self, r: usize) {
        let nx = self.state.dims[0];
        let row = &self.state.flags[r * nx..(r + 1) * nx];
        // One pass for the four kinds (compares and ORs, vectorised), then
        // the span's ends only where there is liquid.
        let (mut fluid, mut interface, mut wall, mut gas) = (false, false, false, false);
        for &f in row {
            fluid |= f == flags::FLUID;
            interface |= f == flags::INTERFACE;
            wall |= f == flags::WALL;
            gas |= f == flags::GAS;
        }
        let any = fluid || interface;
        let all = !(interface || wall || gas);
        self.scratch.spans[r] = if any {
            let first = row.iter().position(|&f| flags::is_liquid(f)).unwrap_or(0);
            let last = row.iter().rposition(|&f| flags::is_liquid(f)).unwrap_or(0);
            (first as u32, last as u32 + 1)
        } else {
            (0, 0)
        };
        self.scratch.rows[r] = if any { ROW_ANY_LIQUID } else { 0 }
            | if all { ROW_ALL_FLUID } else { 0 }
            | if interface { ROW_ANY_INTERFACE } else { 0 }
            | if wall { ROW_ANY_WALL } else { 0 };
    }

    /// The `ROW_SOURCES_FLUID` bit of row `r`, from its neighbour rows' own bits.
    fn classify_row_sources(&mut self, r: usize) {
        let [_, ny, nz] = self.state.dims;
        let faces = self.state.faces;
        let (y, z) = (r % ny, r / ny);
        let rows = &mut self.scratch.rows;
        let (mut sources_fluid, mut no_wall) = (true, true);
        for dz in -1..=1 {
            for dy in -1..=1 {
                // Rows beyond a wall face are not read: the pull bounces back there.
                if let (Some(ys), Some(zs)) = (wrap(y, dy, ny, faces[1]), wrap(z, dz, nz, faces[2])) {
                    sources_fluid &= rows[zs * ny + ys] & ROW_ALL_FLUID != 0;
                    no_wall &= rows[zs * ny + ys] & ROW_ANY_WALL == 0;
                }
            }
        }
        rows[r] = (rows[r] & !(ROW_SOURCES_FLUID | ROW_SOURCES_NO_WALL))
            | if sources_fluid { ROW_SOURCES_FLUID } else { 0 }
            | if no_wall { ROW_SOURCES_NO_WALL } else { 0 };
    }

    /// Reclassifies the rows in `rows` (sorted, deduplicated by the caller
    /// or not: the work is idempotent) and the source bits of their neighbours.
    fn reclassify_rows(&mut self, rows: &[usize]) {
        if self.scratch.rows_stale {
            return; // the next step reclassifies everything anyway
        }
        let [_, ny, nz] = self.state.dims;
        let faces = self.state.faces;
        for &r in rows {
            self.classify_row(r);
        }
        for &r in rows {
            let (y, z) = (r % ny, r / ny);
            for dz in -1..=1 {
                for dy in -1..=1 {
                    if let (Some(ys), Some(zs)) = (wrap(y, dy, ny, faces[1]), wrap(z, dz, nz, faces[2])) {
                        self.classify_row_sources(zs * ny + ys);
                    }
                }
            }
        }
    }

    fn coefficients(&self) -> Coefficients<T> {
        let p = &self.params;
        let magic = match p.collision {
            Collision::Bgk => 0.0,
            Collision::Trt { magic } => magic,
        };
        Coefficients {
            tau0: T::from_f64(p.tau),
            tau0_sq: T::from_f64(p.tau * p.tau),
            smag: T::from_f64(18.0 * std::f64::consts::SQRT_2 * p.smagorinsky * p.smagorinsky),
            magic: T::from_f64(magic),
            accel: p.acceleration.map(T::from_f64),
        }
    }

    /// Stage `stream_collide`: reads `state.populations`, writes `scratch.next`
    /// for every fluid and interface cell (non-liquid cells of `next` are left
    /// untouched), adds each interface cell's mass exchange to its mass, and
    /// writes the direct force of each forced liquid cell.
    fn stream_collide<const TRT: bool>(&mut self) {
        let [nx, ny, nz] = self.state.dims;
        let coef = self.coefficients();
        let forcing = &mut self.scratch.forcing;
        let applied = SharedOut(forcing.applied.as_mut_ptr(), forcing.applied.len());
        let kernel = Kernel {
            src: &self.state.populations,
            flags: &self.state.flags,
            rows: &self.scratch.rows,
            spans: &self.scratch.spans,
            fill: &self.scratch.fill,
            nx,
            ny,
            nz,
            ncells: nx * ny * nz,
            faces: self.state.faces,
            coef,
            accel: self.params.acceleration,
            forced: &forcing.cells,
            forced_rows: &forcing.rows,
            gain: forcing.gain,
            tau0: self.params.tau,
            smag: 18.0 * std::f64::consts::SQRT_2 * self.params.smagorinsky * self.params.smagorinsky,
        };
        let out = SharedOut(self.scratch.next.as_mut_ptr(), self.scratch.next.len());
        let mass = SharedOut(self.state.mass.as_mut_ptr(), self.state.mass.len());
        let density = SharedOut::new(&mut self.scratch.interface_density);
        let isa = self.isa;
        // One task per plane: the liquid's planes cost very different
        // amounts (late in the lab column a sheet a few cells deep holds most
        // of the work), and rayon's default split hands each thread a run of
        // planes it cannot share: 2 threads ran only 1.13× faster than one.
        (0..nz).into_par_iter().with_max_len(1).for_each(|z| {
            let mut buffer = [[T::ZERO; LANES]; Q];
            let mut accel = [[T::ZERO; LANES]; 4];
            kernel.plane::<TRT>(isa, z, &out, &mass, &density, &applied, &mut buffer, &mut accel);
        });
    }
}

/// The neighbour coordinate `x + d` along an axis of `n` cells, or `None`
/// beyond a wall face.
#[inline(always)]
fn wrap(x: usize, d: i32, n: usize, faces: Faces) -> Option<usize> {
    let s = x as isize + d as isize;
    if s >= 0 && (s as usize) < n {
        Some(s as usize)
    } else if faces == Faces::Periodic {
        Some(s.rem_euclid(n as isize) as usize)
    } else {
        None
    }
}

/// ρ = 1 + Σ g_i of one cell from its stored deviations g_i = f_i − w_i,
/// summed in f64 in direction order. Every density the conversions use is
/// summed here (the kernel's kept ones and [`Fluid::density_at`]), so kept
/// and recomputed densities agree bit for bit.
#[inline(always)]
fn density_of(g: impl Fn(usize) -> f64) -> f64 {
    1.0 + (0..Q).map(g).sum::<f64>()
}

/// The index step from a cell to its neighbour along `e` in a box `nx` × `ny`
/// cells wide, for cells off the box's faces (no wrap, no wall face).
#[inline(always)]
fn link_offset(e: [i32; 3], nx: usize, ny: usize) -> isize {
    e[0] as isize + e[1] as isize * nx as isize + e[2] as isize * (nx * ny) as isize
}

/// `dst.copy_from_slice(src)`, inlined as vector moves for the common full
/// chunk (a variable-length copy would call `memmove` 38 times per chunk).
#[inline(always)]
fn copy_lanes<T: Copy>(dst: &mut [T], src: &[T]) {
    if let (Ok(d), Ok(s)) = (<&mut [T; LANES]>::try_from(&mut *dst), <&[T; LANES]>::try_from(src)) {
        *d = *s;
    } else {
        dst.copy_from_slice(src);
    }
}

/// A buffer written from several threads at disjoint indices: the output
/// lattice, the mass array, the applied forces (here) and the coupling's
/// forced-cell lists (`coupling.rs`).
///
/// Sound where each index is written by one task only and nothing reads the
/// buffer while the writers run. In the kernel each thread handles whole
/// z-planes and writes only indices `i * ncells + c` with c in its own plane.
pub(crate) struct SharedOut<T>(*mut T, usize);
// SAFETY: see the type's comment; T itself is sent between threads.
unsafe impl<T: Send> Sync for SharedOut<T> {}

impl<T> SharedOut<T> {
    /// Shares `buffer` for disjoint writes (see the type's comment).
    pub(crate) fn new(buffer: &mut [T]) -> Self {
        SharedOut(buffer.as_mut_ptr(), buffer.len())
    }

    /// SAFETY: no other live slice may overlap `start..start + len`, and the
    /// range must lie inside the buffer.
    #[inline(always)]
    #[allow(clippy::mut_from_ref)] // the writer hands out disjoint ranges by contract, as `split_at_mut` would
    pub(crate) unsafe fn slice(&self, start: usize, len: usize) -> &mut [T] {
        assert!(start + len <= self.1);
        // SAFETY: in bounds (checked above) and unaliased (caller's contract).
        unsafe { std::slice::from_raw_parts_mut(self.0.add(start), len) }
    }
}

struct Kernel<'a, T> {
    src: &'a [T],
    flags: &'a [u8],
    rows: &'a [u8],
    spans: &'a [(u32, u32)],
    fill: &'a [f64],
    nx: usize,
    ny: usize,
    nz: usize,
    ncells: usize,
    faces: [Faces; 3],
    coef: Coefficients<T>,
    accel: [f64; 3],
    /// Forced cells, ascending index, and where each row's run of them
    /// starts (`forced_rows[r]..forced_rows[r + 1]`; empty without forcing).
    forced: &'a [ForcedCell],
    forced_rows: &'a [usize],
    gain: ForcingGain,
    /// The molecular τ0 in f64, for the forcing gain (the f32 `coef.tau0`
    /// would round τ0 − ½ = 6.7e-4 to 4 digits).
    tau0: f64,
    /// 18√2 C² of the closed-form τ_eff in f64, for the gain rules that
    /// take a cell's effective τ.
    smag: f64,
}

impl<T: Real> Kernel<'_, T> {
    /// Streams and collides plane z, compiled for instruction set `isa`.
    #[inline(always)]
    fn plane<const TRT: bool>(
        &self,
        isa: Isa,
        z: usize,
        out: &SharedOut<T>,
        mass: &SharedOut<f64>,
        density: &SharedOut<f64>,
        applied: &SharedOut<AppliedForce>,
        f: &mut [[T; LANES]; Q],
        accel: &mut [[T; LANES]; 4],
    ) {
        match isa {
            #[cfg(target_arch = "x86_64")]
            // SAFETY: `Isa::detected` returns Avx2 only where the CPU has AVX2 and FMA.
            Isa::Avx2 => unsafe { self.plane_avx2::<TRT>(z, out, mass, density, applied, f, accel) },
            _ => self.plane_rows::<TRT, false>(z, out, mass, density, applied, f, accel),
        }
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    unsafe fn plane_avx2<const TRT: bool>(
        &self,
        z: usize,
        out: &SharedOut<T>,
        mass: &SharedOut<f64>,
        density: &SharedOut<f64>,
        applied: &SharedOut<AppliedForce>,
        f: &mut [[T; LANES]; Q],
        accel: &mut [[T; LANES]; 4],
    ) {
        self.plane_rows::<TRT, true>(z, out, mass, density, applied, f, accel)
    }

    #[inline(always)]
    fn plane_rows<const TRT: bool, const AVX2: bool>(
        &self,
        z: usize,
        out: &SharedOut<T>,
        mass: &SharedOut<f64>,
        density: &SharedOut<f64>,
        applied: &SharedOut<AppliedForce>,
        f: &mut [[T; LANES]; Q],
        accel: &mut [[T; LANES]; 4],
    ) {
        for y in 0..self.ny {
            self.row::<TRT, AVX2>(y, z, out, mass, density, applied, f, accel);
        }
    }

    /// Streams and collides the fluid and interface cells of row (y, z).
    /// `AVX2`: the caller runs the AVX2 build (the CPU has AVX2 and FMA), so
    /// the out-of-line paths are called in their AVX2 builds too.
    #[inline(always)]
    fn row<const TRT: bool, const AVX2: bool>(
        &self,
        y: usize,
        z: usize,
        out: &SharedOut<T>,
        mass: &SharedOut<f64>,
        density: &SharedOut<f64>,
        applied: &SharedOut<AppliedForce>,
        f: &mut [[T; LANES]; Q],
        accel: &mut [[T; LANES]; 4],
    ) {
        let class = self.rows[z * self.ny + y];
        // This row's forced cells; `k` walks them along with the chunks.
        // Every entry is written here (those of cells not computed with
        // zeros), so the list needs no reset before the step.
        let (mut k, k_end) = match self.forced_rows.get(z * self.ny + y..z * self.ny + y + 2) {
            Some(&[a, b]) => (a, b),
            _ => (0, 0),
        };
        if class & ROW_ANY_LIQUID == 0 {
            self.unforced(k, k_end, applied);
            return;
        }
        let all_fluid = class & ROW_ALL_FLUID != 0;
        // A pull from gas needs no test here: only interface cells border
        // gas, and `interface_cell` rebuilds those pulls whatever they
        // brought. So only wall cells among the sources need the per-cell
        // test. In a flume no row is fluid end to end, and with the test on
        // every pull of every row the paper's column ran at 9 MLUPS against
        // the bulk box's 125.
        let check_walls = class & (ROW_SOURCES_FLUID | ROW_SOURCES_NO_WALL) == 0;
        let row_start = (z * self.ny + y) * self.nx;
        // A mixed row is worked only over its liquid span: with a short
        // column in a long flume most of a row is gas.
        let (mut x0, end) = if all_fluid {
            (0, self.nx)
        } else {
            let (first, end) = self.spans[z * self.ny + y];
            (first as usize, end as usize)
        };
        if y + PREFETCH_AHEAD < self.ny && end - x0 < PREFETCH_ROWS_UNDER {
            self.prefetch_row(y + PREFETCH_AHEAD, z, x0, end, out);
        }
        while x0 < end {
            let n = LANES.min(end - x0);
            let own = row_start + x0;
            // Forced cells before this chunk lie outside the liquid span or in skipped chunks.
            let skipped = k + self.forced[k..k_end].iter().take_while(|c| c.cell < own).count();
            self.unforced(k, skipped, applied);
            k = skipped;
            // One pass over a mixed row's chunk flags (liquid flags have bit
            // 0 clear): a chunk of gas and wall only (the liquid front in a
            // long flume) is skipped, an all-liquid one is copied out whole.
            let (some_liquid, own_liquid) = if all_fluid {
                (true, true)
            } else {
                let (and, or) = self.flags[own..own + n].iter().fold((1, 0), |(and, or), &fl| (and & fl, or | fl));
                (and & 1 == 0, or & 1 == 0)
            };
            if !some_liquid {
                x0 += n;
                continue;
            }
            for i in 0..Q {
                self.gather(i, y, z, x0, n, check_walls, &mut f[i]);
            }
            if class & ROW_ANY_INTERFACE != 0 {
                for l in 0..n {
                    if self.flags[own + l] == flags::INTERFACE {
                        #[cfg(target_arch = "x86_64")]
                        if AVX2 {
                            // SAFETY: AVX2 is set only under `plane_avx2`, run only where the CPU has AVX2 and FMA.
                            unsafe { self.interface_cell_avx2(x0 + l, y, z, l, f, mass) };
                            continue;
                        }
                        self.interface_cell(x0 + l, y, z, l, f, mass);
                    }
                }
            }
            // Whole vectors of lanes; the lanes past n, and gas or wall
            // lanes, hold finite leftovers and are not written.
            let lanes = n.next_multiple_of(8).min(LANES);
            if k < k_end && self.forced[k].cell < own + n {
                k = match AVX2 {
                    #[cfg(target_arch = "x86_64")]
                    // SAFETY: AVX2 is set only under `plane_avx2`, run only where the CPU has AVX2 and FMA.
                    true => unsafe { self.forced_chunk_avx2::<TRT>(k, k_end, own, n, lanes, applied, f, accel) },
                    _ => self.forced_chunk::<TRT>(k, k_end, own, n, lanes, applied, f, accel),
                };
            } else {
                collide::<T, TRT, false>(f, lanes, &self.coef, accel);
            }
            if class & ROW_ANY_INTERFACE != 0 {
                for l in 0..n {
                    if self.flags[own + l] == flags::INTERFACE {
                        // The values written below, summed as `Fluid::density_at` sums them.
                        // SAFETY: cell own + l lies in plane z, which only this task writes.
                        unsafe { density.slice(own + l, 1)[0] = density_of(|i| f[i][l].to_f64()) };
                    }
                }
            }
            for i in 0..Q {
                // SAFETY: cell indices own..own+n lie in plane z, which only this task writes.
                let dst = unsafe { out.slice(i * self.ncells + own, n) };
                if own_liquid {
                    copy_lanes(dst, &f[i][..n]);
                } else {
                    for l in 0..n {
                        if flags::is_liquid(self.flags[own + l]) {
                            dst[l] = f[i][l];
                        }
                    }
                }
            }
            x0 += n;
        }
        self.unforced(k, k_end, applied);
    }

    /// Writes "no force" for forced entries `k..k_end`, whose cells are not
    /// liquid or lie outside the row's liquid span.
    #[inline(always)]
    fn unforced(&self, k: usize, k_end: usize, applied: &SharedOut<AppliedForce>) {
        if k < k_end {
            // SAFETY: the entries of a row lie in its plane, which only this task writes.
            let out = unsafe { applied.slice(k, k_end - k) };
            for (a, c) in out.iter_mut().zip(&self.forced[k..k_end]) {
                *a = AppliedForce { cell: c.cell, ..Default::default() };
            }
        }
    }

    /// Collides a chunk holding forced cells (entries `k..` up to the
    /// chunk's end) with per-lane accelerations; returns the next entry.
    /// Out of line so that the unforced chunk loop keeps its code.
    #[inline(never)]
    fn forced_chunk<const TRT: bool>(
        &self,
        k: usize,
        k_end: usize,
        own: usize,
        n: usize,
        lanes: usize,
        applied: &SharedOut<AppliedForce>,
        f: &mut [[T; LANES]; Q],
        accel: &mut [[T; LANES]; 4],
    ) -> usize {
        self.forced_chunk_body::<TRT>(k, k_end, own, n, lanes, applied, f, accel)
    }

    /// [`Kernel::forced_chunk`] in the AVX2 build.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    #[inline(never)]
    unsafe fn forced_chunk_avx2<const TRT: bool>(
        &self,
        k: usize,
        k_end: usize,
        own: usize,
        n: usize,
        lanes: usize,
        applied: &SharedOut<AppliedForce>,
        f: &mut [[T; LANES]; Q],
        accel: &mut [[T; LANES]; 4],
    ) -> usize {
        self.forced_chunk_body::<TRT>(k, k_end, own, n, lanes, applied, f, accel)
    }

    #[inline(always)]
    fn forced_chunk_body<const TRT: bool>(
        &self,
        mut k: usize,
        k_end: usize,
        own: usize,
        n: usize,
        lanes: usize,
        applied: &SharedOut<AppliedForce>,
        f: &mut [[T; LANES]; Q],
        accel: &mut [[T; LANES]; 4],
    ) -> usize {
        for a in 0..3 {
            accel[a] = [self.coef.accel[a]; LANES];
        }
        accel[3] = [T::ZERO; LANES];
        // A linear scan, not a binary search: the entries are read in order
        // right after, and the search's dependent loads each missed the cache.
        let chunk_end = k + self.forced[k..k_end].iter().take_while(|c| c.cell < own + n).count();
        // A chunk inside a packing is mostly forced cells: their moments are
        // then summed for all lanes at once, vectorised (same operations in the
        // same order per lane, so the same bits as one lane at a time).
        let mut moments = None;
        if chunk_end - k >= VECTOR_MOMENTS_FROM {
            let mut m = LaneMoments { drho: [0.0; LANES], j: [[0.0; LANES]; 3] };
            lane_moments(f, n, &mut m);
            moments = Some(m);
        }
        while k < chunk_end {
            let cell = self.forced[k];
            if flags::is_liquid(self.flags[cell.cell]) {
                let l = cell.cell - own;
                let m = match &moments {
                    Some(m) => CellMoments::of_lane(m, l),
                    None => CellMoments::of_cell(f, l),
                };
                let force = self.direct_force(&cell, l, &m, f, accel);
                // SAFETY: entry k's cell lies in plane z, which only this task writes.
                unsafe { applied.slice(k, 1)[0] = force };
            } else {
                self.unforced(k, k + 1, applied);
            }
            k += 1;
        }
        collide::<T, TRT, true>(f, lanes, &self.coef, accel);
        k
    }

    /// The direct force density on forced liquid cell `cell` (lane `l` of
    /// `f`, which holds its pulled pre-collision populations, gas pulls
    /// already rebuilt), folded into the lane's acceleration for the
    /// collision:
    ///
    /// F_IB = b [2(ρU − Σ f e) − ρa] with w = weight × fill (fill 1 in a
    /// fluid cell, the old-level ε clamped to [0, 1] in an interface cell)
    /// the covered fraction and b its [`ForcingGain`].
    ///
    /// Guo's shifted velocity is u = (Σ f e + (ρa + F_IB)/2)/ρ, so b = 1 gives
    /// u = U exactly in this step; b < 1 moves u that fraction of the way.
    /// The clamp keeps the gain at most 1 (beyond it u would overshoot U).
    /// The covered volume w (not b) sets the liquid the grain holds and the
    /// split of the momentum balance below, so buoyancy does not depend on
    /// the gain.
    #[inline(always)]
    fn direct_force(
        &self,
        cell: &ForcedCell,
        l: usize,
        m: &CellMoments,
        f: &[[T; LANES]; Q],
        accel: &mut [[T; LANES]; 4],
    ) -> AppliedForce {
        let fill = if self.flags[cell.cell] == flags::INTERFACE { self.fill[cell.cell].clamp(0.0, 1.0) } else { 1.0 };
        let w = cell.weight * fill;
        let tau = if forcing::uses_effective_tau(self.gain) && w < 1.0 { self.effective_tau(f, l) } else { self.tau0 };
        let b = forcing::forcing_gain(self.gain, w, tau);
        let j = m.j;
        let rho = 1.0 + m.drho;
        let force: [f64; 3] = std::array::from_fn(|a| b * (2.0 * (rho * cell.target[a] - j[a]) - rho * self.accel[a]));
        for a in 0..3 {
            accel[a][l] = T::from_f64(self.accel[a] + force[a] / rho);
        }
        // A fully covered cell holds the liquid inside a grain, which only
        // follows the grain: it relaxes at τ = 1 (row 3 of `accel`), so no
        // non-equilibrium survives there. At the paper's τ0 = 0.50067 that
        // non-equilibrium fed a growing pore-scale mode that fluidised a
        // saturated packing at rest within 10 ms (docs/coupling.md). Mass and
        // momentum are conserved at any τ, so F_IB and the surface force are
        // unchanged; partly covered cells (the grain's surface) keep τ.
        accel[3][l] = T::from_f64(if w >= 1.0 { 1.0 } else { 0.0 });
        // Guo's forcing adds ρa + F_IB to the momentum over the step; the
        // covered part's share is what the grain holds (coupling.rs, step 6).
        let held = std::array::from_fn(|a| w * (j[a] + rho * self.accel[a] + force[a]));
        AppliedForce { cell: cell.cell, force, liquid: w * rho, held }
    }

    /// τ_eff of lane `l` of `f` (pulled populations, stored as f − w) under
    /// the uniform body force alone: [`smagorinsky_tau`] evaluated before the
    /// direct force is added (the gain that sets the force cannot wait for
    /// the strain the force produces).
    #[inline(always)]
    fn effective_tau(&self, f: &[[T; LANES]; Q], l: usize) -> f64 {
        smagorinsky_tau(&std::array::from_fn(|i| f[i][l].to_f64()), self.accel, self.tau0, self.smag)
    }

    /// The free-surface part of the pull for interface cell (x, y, z), lane
    /// `l` of `f` (which holds the pulled, pre-collision populations):
    ///
    /// * a population pulled from a gas cell is rebuilt (Körner et al. 2005)
    ///   as f_i = f_i^eq(ρ_A, u) + f_ī^eq(ρ_A, u) − f_ī*(x) with ρ_A = 1 and u
    ///   the cell's velocity before this step; in the stored shift g = f − w
    ///   that is g_i = w_i[9(e_i·u)² − 3u²] − g_ī*(x);
    /// * the mass exchange Δm = Σ_i s_i [f_i*(x − e_i) − f_ī*(x)] (what
    ///   arrives from the neighbour minus what leaves toward it) with s = 1
    ///   for a fluid neighbour, ½(ε(x) + ε(x − e_i)) for an interface
    ///   neighbour, 0 for gas and wall, is added to the cell's mass. Both
    ///   cells of a link see the same s and opposite differences, bit for
    ///   bit, so Σm changes only by f64 round-off.
    #[inline(never)]
    fn interface_cell(&self, x: usize, y: usize, z: usize, l: usize, f: &mut [[T; LANES]; Q], mass: &SharedOut<f64>) {
        self.interface_cell_body(x, y, z, l, f, mass)
    }

    /// [`Kernel::interface_cell`] in the AVX2 build.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    #[inline(never)]
    unsafe fn interface_cell_avx2(
        &self,
        x: usize,
        y: usize,
        z: usize,
        l: usize,
        f: &mut [[T; LANES]; Q],
        mass: &SharedOut<f64>,
    ) {
        self.interface_cell_body(x, y, z, l, f, mass)
    }

    #[inline(always)]
    fn interface_cell_body(
        &self,
        x: usize,
        y: usize,
        z: usize,
        l: usize,
        f: &mut [[T; LANES]; Q],
        mass: &SharedOut<f64>,
    ) {
        let (nx, ny, n) = (self.nx, self.ny, self.ncells);
        let c = (z * ny + y) * nx + x;
        let own: [f64; Q] = std::array::from_fn(|j| self.src[j * n + c].to_f64());
        let rho = 1.0 + own.iter().sum::<f64>();
        let u: [f64; 3] = std::array::from_fn(|a| {
            let j: f64 = (0..Q).map(|i| E[i][a] as f64 * own[i]).sum();
            j / rho - 0.5 * self.accel[a]
        });
        let usq = u[0] * u[0] + u[1] * u[1] + u[2] * u[2];
        let eps = self.fill[c];
        let mut dm = 0.0;
        // Off the box's faces every source lies at a fixed offset.
        let inside = x > 0 && x + 1 < nx && y > 0 && y + 1 < ny && z > 0 && z + 1 < self.nz;
        for i in 1..Q {
            let e = E[i];
            let s = if inside {
                (c as isize - link_offset(e, nx, ny)) as usize
            } else {
                let (Some(xs), Some(ys), Some(zs)) = (
                    wrap(x, -e[0], nx, self.faces[0]),
                    wrap(y, -e[1], ny, self.faces[1]),
                    wrap(z, -e[2], self.nz, self.faces[2]),
                ) else {
                    continue; // beyond a wall face: bounced back, no exchange
                };
                (zs * ny + ys) * nx + xs
            };
            let outgoing = own[OPP[i]];
            match self.flags[s] {
                flags::FLUID => dm += f[i][l].to_f64() - outgoing,
                flags::INTERFACE => dm += 0.5 * (eps + self.fill[s]) * (f[i][l].to_f64() - outgoing),
                flags::GAS => {
                    let eu = e[0] as f64 * u[0] + e[1] as f64 * u[1] + e[2] as f64 * u[2];
                    f[i][l] = T::from_f64(W[i] * (9.0 * eu * eu - 3.0 * usq) - outgoing);
                }
                _ => {} // wall: bounced back in `gather`
            }
        }
        // SAFETY: cell c lies in plane z, which only this task writes.
        unsafe { mass.slice(c, 1)[0] += dm };
    }

    /// Asks for the cache lines that row (y, z) will pull from and write
    /// over x0..end (the span of the row before it, a guess). A short
    /// liquid span in a long row (a column in a flume: 67 of 1167 cells)
    /// is 38 streams of a few cache lines each, 4.7 kB apart: too short
    /// for the hardware prefetchers, so every line waited on memory.
    #[inline(always)]
    fn prefetch_row(&self, y: usize, z: usize, x0: usize, end: usize, out: &SharedOut<T>) {
        #[cfg(target_arch = "x86_64")]
        {
            use std::arch::x86_64::{_mm_prefetch, _MM_HINT_T0};
            let per_line = 64 / std::mem::size_of::<T>();
            let (lo, hi) = (x0.saturating_sub(1), (end + 1).min(self.nx));
            let own = (z * self.ny + y) * self.nx;
            let r = z * self.ny + y;
            // Interface cells read their own populations (their velocity and
            // the outgoing half of the mass exchange), off the pulls' rows.
            let own_read = self.rows[r] & ROW_ANY_INTERFACE != 0;
            for i in 0..Q {
                let e = E[i];
                if let (Some(ys), Some(zs)) =
                    (wrap(y, -e[1], self.ny, self.faces[1]), wrap(z, -e[2], self.nz, self.faces[2]))
                {
                    let row = i * self.ncells + (zs * self.ny + ys) * self.nx;
                    for x in (lo..hi).step_by(per_line) {
                        // SAFETY: a prefetch reads nothing architecturally; the index is in bounds anyway.
                        unsafe { _mm_prefetch::<_MM_HINT_T0>(self.src.as_ptr().add(row + x) as *const i8) };
                    }
                }
                let dst = i * self.ncells + own;
                for x in (x0..end).step_by(per_line) {
                    // SAFETY: as above, `out` spans every population of every cell.
                    unsafe { _mm_prefetch::<_MM_HINT_T0>(out.0.add(dst + x) as *const i8) };
                    if own_read {
                        // SAFETY: as above.
                        unsafe { _mm_prefetch::<_MM_HINT_T0>(self.src.as_ptr().add(dst + x) as *const i8) };
                    }
                }
            }
        }
    }

    /// Pulls population `i` for cells x0..x0+n of row (y, z) into `dst`:
    /// f_i(x) = f_i*(x − e_i), or f_ī*(x) (half-way bounce-back) when x − e_i
    /// is not liquid or lies beyond a wall face. Gas sources are then rebuilt
    /// by [`Kernel::interface_cell`] (a fluid cell never borders gas).
    #[inline(always)]
    fn gather(&self, i: usize, y: usize, z: usize, x0: usize, n: usize, check_walls: bool, dst: &mut [T; LANES]) {
        let (nx, ncells, src) = (self.nx, self.ncells, self.src);
        let own = (z * self.ny + y) * nx + x0;
        let bounce = OPP[i] * ncells + own;
        let e = E[i];
        let (Some(ys), Some(zs)) = (wrap(y, -e[1], self.ny, self.faces[1]), wrap(z, -e[2], self.nz, self.faces[2]))
        else {
            copy_lanes(&mut dst[..n], &src[bounce..bounce + n]);
            return;
        };
        let src_row = (zs * self.ny + ys) * nx;
        let base = i * ncells + src_row;
        // Lanes whose source x falls off the row: lane 0 for e_x = +1, lane n−1 for e_x = −1.
        let lo = usize::from(e[0] == 1 && x0 == 0);
        let hi = if e[0] == -1 && x0 + n == nx { n - 1 } else { n };
        let start = (x0 + lo) as isize - e[0] as isize;
        let start = base + start as usize;
        copy_lanes(&mut dst[lo..hi], &src[start..start + (hi - lo)]);
        let periodic_x = self.faces[0] == Faces::Periodic;
        if lo == 1 {
            dst[0] = if periodic_x { src[base + nx - 1] } else { src[bounce] };
        }
        if hi == n - 1 {
            dst[n - 1] = if periodic_x { src[base] } else { src[bounce + n - 1] };
        }
        if check_walls {
            for l in 0..n {
                if let Some(xs) = wrap(x0 + l, -e[0], nx, self.faces[0]) {
                    if !flags::is_liquid(self.flags[src_row + xs]) {
                        dst[l] = src[bounce + l];
                    }
                }
            }
        }
    }
}

/// Liquid spans shorter than this are prefetched a row ahead (longer ones
/// are long enough streams for the hardware prefetchers).
const PREFETCH_ROWS_UNDER: usize = 512;
const PREFETCH_AHEAD: usize = 1;

/// Forced cells in a chunk from which their moments are summed for all
/// lanes at once ([`lane_moments`]) instead of one cell at a time.
const VECTOR_MOMENTS_FROM: usize = 16;

/// Per lane of a chunk: Σg (= ρ − 1) and Σ g e of the pulled populations
/// (f64 sums).
#[derive(Clone, Copy)]
struct LaneMoments {
    drho: [f64; LANES],
    j: [[f64; LANES]; 3],
}

/// The moments of one forced cell, as [`Kernel::direct_force`] needs them.
struct CellMoments {
    drho: f64,
    j: [f64; 3],
}

impl CellMoments {
    fn of_lane(m: &LaneMoments, l: usize) -> CellMoments {
        CellMoments { drho: m.drho[l], j: [m.j[0][l], m.j[1][l], m.j[2][l]] }
    }

    /// Lane `l` of `f` (pulled populations), summed over i in ascending
    /// order as [`lane_moments`] does.
    #[inline(always)]
    fn of_cell<T: Real>(f: &[[T; LANES]; Q], l: usize) -> CellMoments {
        let (mut drho, mut j) = (0.0, [0.0; 3]);
        for i in 0..Q {
            let g = f[i][l].to_f64();
            drho += g;
            for a in 0..3 {
                j[a] += E[i][a] as f64 * g;
            }
        }
        CellMoments { drho, j }
    }
}

/// [`CellMoments::of_cell`] for lanes 0..n of a chunk, vectorised over the
/// lanes; lanes from n on are left as they are.
/// Lanes go in blocks of [`MOMENT_BLOCK`] whose four sums stay in registers
/// over the 19 directions (summing all lanes direction by direction loaded
/// and stored every sum 19 times); each lane's sums take the same operations
/// in the same order either way. A block's sums are then added to `m`, so
/// the result is a lane's plain sum only for a zeroed `m` (as the caller
/// passes it; a sum from +0.0 is never −0.0, so adding it to +0.0 is exact).
#[inline(always)]
fn lane_moments<T: Real>(f: &[[T; LANES]; Q], n: usize, m: &mut LaneMoments) {
    const B: usize = MOMENT_BLOCK;
    let mut l0 = 0;
    while l0 + B <= n {
        let (mut drho, mut j) = ([0.0; B], [[0.0; B]; 3]);
        for i in 0..Q {
            let e = E[i].map(|x| x as f64);
            let pulled: &[T; B] = f[i][l0..l0 + B].try_into().expect("a block of lanes");
            for b in 0..B {
                let g = pulled[b].to_f64();
                drho[b] += g;
                for a in 0..3 {
                    j[a][b] += e[a] * g;
                }
            }
        }
        for b in 0..B {
            m.drho[l0 + b] += drho[b];
            for a in 0..3 {
                m.j[a][l0 + b] += j[a][b];
            }
        }
        l0 += B;
    }
    for i in 0..Q {
        let e = E[i].map(|x| x as f64);
        for l in l0..n {
            let g = f[i][l].to_f64();
            m.drho[l] += g;
            for a in 0..3 {
                m.j[a][l] += e[a] * g;
            }
        }
    }
}

/// Lanes per register block of [`lane_moments`]: 4 f64 fill one AVX2 register.
const MOMENT_BLOCK: usize = 4;

/// The Smagorinsky relaxation time of [`collide`] in f64 for one cell's
/// populations `g` (stored as f − w) under body acceleration `a`:
/// τ = ½(τ0 + √(τ0² + 18√2 C² |Π^neq|/ρ)), `smag` = 18√2 C², with the
/// force-corrected Π^neq = Σ g e e − δρ/3 − ρuu + ½ρ(au + ua) and Guo's
/// u = Σ g e/ρ + a/2. Used by the gain rules that take a cell's τ_eff.
pub(crate) fn smagorinsky_tau(g: &[f64; Q], a: [f64; 3], tau0: f64, smag: f64) -> f64 {
    let (mut drho, mut j, mut p) = (0.0, [0.0; 3], [[0.0; 3]; 3]);
    for i in 0..Q {
        drho += g[i];
        for x in 0..3 {
            j[x] += E[i][x] as f64 * g[i];
            for y in 0..3 {
                p[x][y] += (E[i][x] * E[i][y]) as f64 * g[i];
            }
        }
    }
    let rho = 1.0 + drho;
    let u: [f64; 3] = std::array::from_fn(|k| j[k] / rho + 0.5 * a[k]);
    let mut q = 0.0;
    for x in 0..3 {
        for y in 0..3 {
            let diagonal = if x == y { drho / 3.0 } else { 0.0 };
            let neq = p[x][y] - diagonal - rho * u[x] * u[y] + 0.5 * rho * (a[x] * u[y] + u[x] * a[y]);
            q += neq * neq;
        }
    }
    0.5 * (tau0 + (tau0 * tau0 + smag * q.sqrt() / rho).sqrt())
}

/// BGK (`TRT = false`) or TRT collision with Smagorinsky and Guo forcing on
/// the first `lanes` lanes of `f`, in place; `f` holds f_i − w_i before and after.
///
/// Pre: `f` finite where results are used. Post: mass is conserved exactly
/// up to round-off and the momentum changes by F = ρa per cell.
///
/// * Moments: ρ = 1 + Σg, u = Σ g e/ρ + a/2 (Guo's half-force shift).
/// * Π̃ = Σ e e g − δ(ρ−1)/3 − ρ u u + ½ρ (a u + u a): the non-equilibrium
///   momentum flux with Guo's force correction (Krüger et al. 2017 §6.3;
///   Chapman–Enskog gives Π̃ = −2ρ c_s² τ S), Q = Π̃:Π̃.
/// * τ = ½[τ0 + √(τ0² + 18√2 C² √Q/ρ)]: the local closed form of
///   ν0 + (CΔ)²|S| = c_s²(τ − ½) with |S| = √(2 S:S) (Hou et al. 1996;
///   lbm-free-surface.md §2), i.e. Eq. 4 of the paper with C = 0.16.
/// * TRT: each pair (i, ī) splits into g± = ½(g_i ± g_ī); g+ relaxes with
///   ω+ = 1/τ, g− with ω− = 1/(½ + Λ/(τ − ½)); BGK is ω− = ω+. Guo's source
///   w_i[3(e−u) + 9(e·u)e]·F splits into S+ = w_i ρ[9(e·u)(e·a) − 3u·a] and
///   S− = 3w_i ρ e·a, weighted (1 − ω±/2).
///
/// `FORCED`: the acceleration of lane l is `accel[·][l]` (uniform a plus a
/// direct force over ρ) instead of the uniform `c.accel`; the unforced
/// instance compiles to the same code as before forcing existed.
#[inline(always)]
fn collide<T: Real, const TRT: bool, const FORCED: bool>(
    f: &mut [[T; LANES]; Q],
    lanes: usize,
    c: &Coefficients<T>,
    accel: &[[T; LANES]; 4],
) {
    let k = |x: f64| T::from_f64(x);
    let (half, one, third) = (k(0.5), k(1.0), k(1.0 / 3.0));
    let (w0, w1, w2) = (k(W[0]), k(W[1]), k(W[7]));
    let (c3, c45, c15, c9) = (k(3.0), k(4.5), k(1.5), k(9.0));
    for l in 0..lanes {
        let [ax, ay, az] = if FORCED { [accel[0][l], accel[1][l], accel[2][l]] } else { c.accel };
        // Pair sums and differences, one per pair (2p+1, 2p+2).
        let s: [T; 9] = std::array::from_fn(|p| f[2 * p + 1][l] + f[2 * p + 2][l]);
        let d: [T; 9] = std::array::from_fn(|p| f[2 * p + 1][l] - f[2 * p + 2][l]);
        let g0 = f[0][l];
        // Pair p's first direction: 0:+x 1:+y 2:+z 3:(1,1,0) 4:(−1,1,0) 5:(0,1,1) 6:(0,−1,1) 7:(1,0,1) 8:(1,0,−1).
        let drho = g0 + s[0] + s[1] + s[2] + s[3] + s[4] + s[5] + s[6] + s[7] + s[8];
        let rho = one + drho;
        let inv_rho = one / rho;
        let ux = (d[0] + d[3] - d[4] + d[7] + d[8]) * inv_rho + half * ax;
        let uy = (d[1] + d[3] + d[4] + d[5] - d[6]) * inv_rho + half * ay;
        let uz = (d[2] + d[5] + d[6] + d[7] - d[8]) * inv_rho + half * az;

        let hr = half * rho;
        let pxx = s[0] + s[3] + s[4] + s[7] + s[8] - drho * third - rho * ux * ux + hr * (ax * ux + ax * ux);
        let pyy = s[1] + s[3] + s[4] + s[5] + s[6] - drho * third - rho * uy * uy + hr * (ay * uy + ay * uy);
        let pzz = s[2] + s[5] + s[6] + s[7] + s[8] - drho * third - rho * uz * uz + hr * (az * uz + az * uz);
        let pxy = s[3] - s[4] - rho * ux * uy + hr * (ax * uy + ux * ay);
        let pyz = s[5] - s[6] - rho * uy * uz + hr * (ay * uz + uy * az);
        let pxz = s[7] - s[8] - rho * ux * uz + hr * (ax * uz + ux * az);
        let q = pxx * pxx + pyy * pyy + pzz * pzz + k(2.0) * (pxy * pxy + pyz * pyz + pxz * pxz);
        // The same closure as `smagorinsky_tau` (the gain rules' f64 copy, tested there).
        let tau = half * (c.tau0 + (c.tau0_sq + c.smag * q.sqrt() * inv_rho).sqrt());
        let wp = one / tau;
        let wm = if TRT { (tau - half) / (half * (tau - half) + c.magic) } else { wp };
        // Row 3 of a forced chunk's `accel`: 1 where the cell relaxes at τ = 1 instead.
        let (wp, wm) = if FORCED {
            let b = accel[3][l];
            (wp + b * (one - wp), wm + b * (one - wm))
        } else {
            (wp, wm)
        };
        let (kp, km) = (one - half * wp, one - half * wm);

        let usq = ux * ux + uy * uy + uz * uz;
        let ua = ux * ax + uy * ay + uz * az;
        let base = drho - c15 * rho * usq;
        f[0][l] = g0 - wp * (g0 - w0 * base) - kp * w0 * c3 * rho * ua;
        let pair = |w: T, eu: T, ea: T, s: T, d: T| -> (T, T) {
            let eq_p = w * (base + c45 * rho * eu * eu);
            let eq_m = w * c3 * rho * eu;
            let src_p = w * rho * (c9 * eu * ea - c3 * ua);
            let src_m = w * c3 * rho * ea;
            let (gp, gm) = (half * s, half * d);
            let np = gp - wp * (gp - eq_p) + kp * src_p;
            let nm = gm - wm * (gm - eq_m) + km * src_m;
            (np + nm, np - nm)
        };
        let dirs: [(T, T, T); 9] = [
            (w1, ux, ax),
            (w1, uy, ay),
            (w1, uz, az),
            (w2, ux + uy, ax + ay),
            (w2, uy - ux, ay - ax),
            (w2, uy + uz, ay + az),
            (w2, uz - uy, az - ay),
            (w2, ux + uz, ax + az),
            (w2, ux - uz, ax - az),
        ];
        for p in 0..9 {
            let (w, eu, ea) = dirs[p];
            let (a, b) = pair(w, eu, ea, s[p], d[p]);
            f[2 * p + 1][l] = a;
            f[2 * p + 2][l] = b;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::lattice::{equilibrium, CS2};

    fn periodic<T: Real>(dims: [usize; 3], params: FluidParams) -> Fluid<T> {
        Fluid::new(dims, [Faces::Periodic; 3], params).expect("valid parameters")
    }

    #[test]
    fn smagorinsky_tau_reads_the_non_equilibrium_stress() {
        // f = f_eq(ρ, u) + w_i 9/2 (e_i e_i − I/3) : Π with a traceless Π:
        // its second moment beyond equilibrium is exactly Π, so |Π^neq| = |Π|
        // and τ follows the closed form; the shift g = f − w of the storage.
        let (rho, u) = (1.02, [0.03, -0.01, 0.02]);
        let pi = [[2e-4, 1e-3, 0.0], [1e-3, -3e-4, -5e-4], [0.0, -5e-4, 1e-4]];
        let feq = equilibrium(rho, u);
        let g: [f64; Q] = std::array::from_fn(|i| {
            let contraction: f64 = (0..3)
                .flat_map(|x| (0..3).map(move |y| (x, y)))
                .map(|(x, y)| {
                    let q = (E[i][x] * E[i][y]) as f64 - if x == y { CS2 } else { 0.0 };
                    q * pi[x][y]
                })
                .sum();
            feq[i] + W[i] * contraction / (2.0 * CS2 * CS2) - W[i]
        });
        let norm = pi.iter().flatten().map(|p| p * p).sum::<f64>().sqrt();
        let (tau0, smag) = (0.500667, 18.0 * std::f64::consts::SQRT_2 * 0.16 * 0.16);
        let expected = 0.5 * (tau0 + (tau0 * tau0 + smag * norm / rho).sqrt());
        let tau = smagorinsky_tau(&g, [0.0; 3], tau0, smag);
        assert!((tau - expected).abs() < 1e-12, "{tau} vs {expected}");
        assert!(tau > tau0 + 4e-4, "the strain must raise tau: {tau}");
        // At equilibrium τ_eff is τ0.
        let g0: [f64; Q] = std::array::from_fn(|i| feq[i] - W[i]);
        assert!((smagorinsky_tau(&g0, [0.0; 3], tau0, smag) - tau0).abs() < 1e-9);
    }

    #[test]
    fn uniform_flow_is_a_fixed_point_of_the_kernel() {
        // A uniform equilibrium has no gradients: streaming moves identical
        // cells and Π^neq = 0, so collision must return f^eq exactly. This
        // pins the kernel's hand-written moments, weights and equilibrium to
        // lattice::equilibrium.
        let u = [0.05, -0.03, 0.02];
        for collision in [Collision::Bgk, Collision::TRT_3_16] {
            let params = FluidParams { collision, ..FluidParams::new(0.53) };
            let mut fluid = periodic::<f64>([3, 2, 2], params);
            for c in 0..12 {
                fluid.set_equilibrium([c % 3, (c / 3) % 2, c / 6], 1.02, u).expect("in box");
            }
            for _ in 0..5 {
                fluid.step();
            }
            let feq = equilibrium(1.02, u);
            let n = fluid.ncells();
            for i in 0..Q {
                for c in 0..n {
                    let f = fluid.state().populations[i * n + c] + W[i];
                    assert!((f - feq[i]).abs() < 1e-15, "{collision:?} f_{i} = {f}, f_eq = {}", feq[i]);
                }
            }
        }
    }

    #[test]
    fn body_force_adds_exactly_a_per_step() {
        // Periodic and uniform: Guo forcing must give du/dt = a and keep ρ.
        let a = [1e-5, -2e-5, 3e-5];
        for collision in [Collision::Bgk, Collision::TRT_3_16] {
            let params = FluidParams { collision, acceleration: a, ..FluidParams::new(0.7) };
            let mut fluid = periodic::<f64>([2, 2, 2], params);
            for step in 1..=10 {
                fluid.step();
                let (rho, u) = fluid.moments([1, 0, 1]).expect("in box");
                assert!((rho - 1.0).abs() < 1e-14);
                for d in 0..3 {
                    assert!((u[d] - step as f64 * a[d]).abs() < 1e-15, "{collision:?} step {step}: u = {u:?}");
                }
            }
        }
    }

    #[test]
    fn bad_parameters_are_errors_not_panics() {
        let faces = [Faces::Periodic; 3];
        assert_eq!(Fluid::<f32>::new([4, 4, 4], faces, FluidParams::new(0.5)).err(), Some(ConfigError::Tau(0.5)));
        let p = FluidParams { smagorinsky: -0.1, ..FluidParams::new(0.6) };
        assert!(matches!(Fluid::<f32>::new([4, 4, 4], faces, p), Err(ConfigError::Smagorinsky(_))));
        let p = FluidParams { collision: Collision::Trt { magic: f64::NAN }, ..FluidParams::new(0.6) };
        assert!(matches!(Fluid::<f32>::new([4, 4, 4], faces, p), Err(ConfigError::Magic(_))));
        assert!(matches!(Fluid::<f32>::new([0, 4, 4], faces, FluidParams::new(0.6)), Err(ConfigError::Dims(_))));
        let mut fluid = periodic::<f32>([4, 4, 4], FluidParams::new(0.6));
        assert!(matches!(fluid.set_flag([4, 0, 0], flags::WALL), Err(ConfigError::OutOfBox { .. })));
        let mut state = fluid.state().clone();
        state.populations.pop();
        assert!(matches!(Fluid::from_state(state, FluidParams::new(0.6)), Err(ConfigError::State(_))));
    }

    #[test]
    fn watchdog_names_the_cell_the_quantity_and_the_fix() {
        let mut fluid = periodic::<f32>([6, 5, 4], FluidParams::new(0.6));
        assert_eq!(fluid.check(&WatchdogLimits::default()), Ok(()));
        fluid.set_equilibrium([4, 3, 2], 1.0, [0.2, 0.0, 0.0]).expect("in box");
        let e = fluid.check(&WatchdogLimits::default()).expect_err("Mach 0.35");
        assert_eq!((e.cell, e.quantity), ([4, 3, 2], Quantity::Mach));
        assert!((e.value - 0.2 / CS2.sqrt()).abs() < 1e-6);
        fluid.set_equilibrium([1, 1, 1], 2.5, [0.0; 3]).expect("in box");
        let e = fluid.check(&WatchdogLimits::default()).expect_err("density");
        assert_eq!((e.cell, e.quantity), ([1, 1, 1], Quantity::Density), "lowest cell index first");
        let n = fluid.ncells();
        fluid.state.populations[7 * n] = f32::NAN;
        let e = fluid.check(&WatchdogLimits::default()).expect_err("NaN");
        assert_eq!((e.cell, e.quantity), ([0, 0, 0], Quantity::Population(7)));
        let msg = e.to_string();
        assert!(msg.contains("cell (0, 0, 0)") && msg.contains("f_7") && msg.contains("Smagorinsky"), "{msg}");
    }

    #[test]
    fn watchdog_checks_the_interface_fill_and_set_up_errors_are_typed() {
        let params = FluidParams { acceleration: [0.0, 0.0, -1e-4], ..FluidParams::new(0.6) };
        let mut fluid = Fluid::<f32>::new([6, 5, 8], [Faces::Walls; 3], params).expect("valid parameters");
        fluid.init_liquid(|c| c[2] < 4).expect("in box");
        assert_eq!(fluid.interface_cells(), 30, "one layer of 6 x 5 interface cells at z = 3");
        assert_eq!(fluid.active_cells(), 120);
        assert!((fluid.fill([2, 2, 3]).expect("in box") - 0.5).abs() < 1e-12);
        assert_eq!(fluid.check(&WatchdogLimits::default()), Ok(()));
        let c = (3 * 5 + 2) * 6 + 4;
        fluid.state.mass[c] = 2.2;
        let e = fluid.check(&WatchdogLimits::default()).expect_err("fill 2.2");
        assert_eq!((e.cell, e.quantity), ([4, 2, 3], Quantity::Fill));
        assert!(e.to_string().contains("interface fill"), "{e}");
        assert_eq!(fluid.set_flag([0, 0, 0], flags::GAS), Err(ConfigError::Flag(flags::GAS)));
        assert!(matches!(fluid.remove_walls(&[[1, 1, 1]]), Err(ConfigError::NotWall([1, 1, 1]))));
        // The kernel lets only interface cells pull from gas: a fluid cell
        // next to gas is refused, from set-up and from a saved state.
        assert_eq!(fluid.set_flag([2, 2, 3], flags::FLUID), Err(ConfigError::FluidNextToGas([2, 2, 3])));
        assert_eq!(fluid.flag([2, 2, 3]), Ok(flags::INTERFACE), "a refused change leaves the cell as it was");
        let mut state = fluid.state().clone();
        state.flags[(4 * 5 + 2) * 6 + 2] = flags::FLUID;
        assert!(matches!(Fluid::from_state(state, params), Err(ConfigError::FluidNextToGas([2, 2, 4]))));
        let p = FluidParams { kappa: 0.7, ..params };
        assert_eq!(fluid.set_params(p), Err(ConfigError::Kappa(0.7)));
    }

    #[test]
    fn results_do_not_depend_on_thread_count_and_restart_is_exact() {
        let params = FluidParams { acceleration: [1e-5, 0.0, -2e-5], ..FluidParams::new(0.52) };
        let mut fluid = Fluid::<f32>::new([20, 6, 9], [Faces::Periodic, Faces::Walls, Faces::Walls], params)
            .expect("valid parameters");
        fluid.set_flag([5, 2, 4], flags::WALL).expect("in box");
        for c in 0..fluid.ncells() {
            let (x, y, z) = (c % 20, (c / 20) % 6, c / 120);
            let u = [0.03 * (y as f64 * 0.7).sin(), 0.02 * (x as f64 * 0.3).cos(), 0.01 * (z as f64).sin()];
            fluid.set_equilibrium([x, y, z], 1.0, u).expect("in box");
        }
        let run = |threads: usize, mut f: Fluid<f32>, steps: usize| {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("pool");
            pool.install(|| (0..steps).for_each(|_| f.step()));
            f
        };
        let one = run(1, fluid.clone(), 40);
        let two = run(2, fluid.clone(), 40);
        assert!(one.state() == two.state(), "1 and 2 threads differ");
        let half = run(2, fluid, 17);
        let restarted = Fluid::from_state(half.state().clone(), *half.params()).expect("valid state");
        let resumed = run(2, restarted, 23);
        assert!(resumed.state() == one.state(), "restart from a snapshot is not exact");
    }
}

#[cfg(test)]
mod isa_tests {
    use super::*;

    /// A collapsing block with walls, gas, an interface, Smagorinsky and a
    /// body force: every branch of the row kernel.
    fn collapsing_block(collision: Collision) -> Fluid<f32> {
        let params =
            FluidParams { acceleration: [0.0, 0.0, -1e-4], collision, smagorinsky: 0.16, ..FluidParams::new(0.5007) };
        let mut fluid = Fluid::<f32>::new([70, 5, 30], [Faces::Walls, Faces::Periodic, Faces::Walls], params)
            .expect("valid parameters");
        fluid.init_liquid(|[x, _, z]| x < 20 && z < 22).expect("valid block");
        // A grain's worth of forced cells, partly covered ones included, in the liquid and at its surface.
        let forced = (0..fluid.ncells()).filter_map(|c| {
            let (x, y, z) = ((c % 70) as f64, ((c / 70) % 5) as f64, (c / 350) as f64);
            let r = ((x - 10.0).powi(2) + (y - 2.0).powi(2) + (z - 20.0).powi(2)).sqrt();
            (r < 3.5).then(|| ForcedCell { cell: c, weight: (3.5 - r).min(1.0), target: [0.01, 0.0, -0.02] })
        });
        fluid.set_direct_forcing(forced).expect("valid forcing");
        fluid
    }

    /// A coupled run answers the DEM between the two halves of a step: the
    /// forcing read-out must be final after `begin_step`, and the halves
    /// together must be `step` bit for bit.
    #[test]
    fn a_step_in_two_halves_is_the_whole_step() {
        let mut whole = collapsing_block(Collision::Bgk);
        let mut halves = whole.clone();
        for _ in 0..40 {
            whole.step();
            halves.begin_step();
            assert_eq!(halves.applied_forcing(), whole.applied_forcing());
            halves.finish_step();
            halves.finish_step(); // nothing pending: no effect
        }
        assert!(whole.interface_cells() > 0 && whole.applied_forcing().iter().any(|a| a.force[0] != 0.0));
        assert!(halves.state() == whole.state());
        // A step begun twice finishes the first before the second.
        halves.begin_step();
        halves.begin_step();
        halves.finish_step();
        (0..2).for_each(|_| whole.step());
        assert!(halves.state() == whole.state());
    }

    /// A set-up change between `begin_step` and `finish_step` finishes the
    /// begun step first (its conversions read the kernel's densities), so it
    /// acts as it would after a whole step.
    #[test]
    fn a_change_between_the_halves_of_a_step_finishes_the_step_first() {
        let mut whole = collapsing_block(Collision::Bgk);
        (0..20).for_each(|_| whole.step());
        // An interface cell: its conversion reads its density.
        let c = whole.scratch.interface[whole.scratch.interface.len() / 2];
        let cell = [c % 70, (c / 70) % 5, c / 350];
        let mut halves = whole.clone();
        halves.begin_step();
        halves.set_equilibrium(cell, 1.05, [0.01, 0.0, 0.0]).expect("in the box");
        halves.step();
        whole.step();
        whole.set_equilibrium(cell, 1.05, [0.01, 0.0, 0.0]).expect("in the box");
        whole.step();
        assert!(halves.state() == whole.state());
    }

    /// The velocity of a forced cell includes half the force the last step
    /// applied to it (Guo), looked up by row: installing the next step's list
    /// (other cells, other rows) must not change what the last step applied.
    #[test]
    fn moments_report_the_last_applied_force_until_the_next_step() {
        let mut fluid = collapsing_block(Collision::Bgk);
        (0..5).for_each(|_| fluid.step());
        let forced = fluid.applied_forcing().iter().find(|a| a.force[0] != 0.0).expect("a forced cell").cell;
        let cell = [forced % 70, (forced / 70) % 5, forced / 350];
        let before = fluid.moments(cell).expect("in the box");
        // Reference without the force: the plain moments of the populations.
        let (_, unforced) = fluid.moments_with(forced, [0.0; 3]);
        assert!((before.1[0] - unforced[0]).abs() > 1e-9, "the applied force shows in the velocity");
        let shifted = (0..fluid.ncells()).filter(|&c| c % 70 > 40 && c / 350 < 5).map(|c| ForcedCell {
            cell: c,
            weight: 1.0,
            target: [0.0; 3],
        });
        fluid.set_direct_forcing(shifted).expect("valid forcing");
        assert_eq!(fluid.moments(cell).expect("in the box"), before);
        fluid.step();
        assert_eq!(fluid.moments_with(forced, [0.0; 3]), fluid.moments(cell).expect("in the box"), "no force now");
    }

    /// The conversions read each interface cell's density from the kernel's
    /// sum (and their own, for cells they make interface): it must be the
    /// density of the stored populations, bit for bit, after every step.
    #[test]
    fn kept_interface_densities_are_the_populations_densities() {
        let mut fluid = collapsing_block(Collision::Bgk);
        let mut converted = 0;
        for _ in 0..200 {
            let before = fluid.scratch.interface.clone();
            fluid.step();
            converted += fluid.scratch.interface.iter().filter(|c| before.binary_search(c).is_err()).count();
            for &c in &fluid.scratch.interface {
                assert_eq!(fluid.scratch.interface_density[c].to_bits(), fluid.density_at(c).to_bits(), "cell {c}");
            }
        }
        assert!(converted > 100, "the block's surface must move for the test to mean anything: {converted} new cells");
    }

    /// The recorded mass and front read the liquid plane by plane in
    /// parallel, over the rows' liquid spans: the same cells, summed in the
    /// same order, as a serial walk over every cell.
    #[test]
    fn parallel_liquid_sums_match_a_serial_walk_bit_for_bit() {
        let mut fluid = collapsing_block(Collision::Bgk);
        for step in 0..120 {
            fluid.step();
            if step % 40 != 39 {
                continue;
            }
            let serial: f64 = (0..fluid.ncells())
                .map(|c| match fluid.state.flags[c] {
                    flags::FLUID => fluid.density_at(c),
                    flags::INTERFACE => fluid.state.mass[c],
                    _ => 0.0,
                })
                .sum::<f64>()
                + fluid.state.pending_excess;
            assert_eq!(fluid.liquid_mass().to_bits(), serial.to_bits());
            let scanned: Vec<(usize, f64)> = (0..fluid.ncells())
                .filter(|&c| fluid.fill_field()[c] > 0.0)
                .map(|c| (c, fluid.moments_at(c).0 * fluid.fill_field()[c]))
                .collect();
            assert!(scanned.len() > 1000);
            assert_eq!(fluid.liquid_cell_masses(), scanned);
        }
    }

    #[test]
    fn lane_moments_match_one_cell_at_a_time_bit_for_bit() {
        let mut x = 0x9E37_79B9_u64;
        let mut noise = || {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            (x % 2001) as f32 * 1e-4 - 0.1
        };
        let mut f = [[0.0f32; LANES]; Q];
        f.iter_mut().flatten().for_each(|g| *g = noise());
        // Whole register blocks, a ragged last block, a full chunk, fewer lanes than a block.
        for n in [100, 103, LANES, 3] {
            let mut m = LaneMoments { drho: [0.0; LANES], j: [[0.0; LANES]; 3] };
            lane_moments(&f, n, &mut m);
            for l in 0..n {
                let (a, b) = (CellMoments::of_lane(&m, l), CellMoments::of_cell(&f, l));
                assert_eq!(a.drho.to_bits(), b.drho.to_bits(), "n {n} lane {l}");
                for d in 0..3 {
                    assert_eq!(a.j[d].to_bits(), b.j[d].to_bits(), "n {n} lane {l}");
                }
            }
            assert!(m.drho[n..].iter().all(|&x| x == 0.0), "lanes from n on are left as they are");
        }
    }

    #[test]
    fn every_instruction_set_gives_bit_identical_steps() {
        for collision in [Collision::Bgk, Collision::Trt { magic: 0.25 }] {
            let start = collapsing_block(collision);
            let mut runs = Isa::all_supported().into_iter().map(|isa| {
                let mut f = start.clone();
                f.set_isa(isa);
                assert_eq!(f.isa(), isa);
                (0..300).for_each(|_| f.step());
                (isa, f)
            });
            let (_, reference) = runs.next().expect("the baseline is always supported");
            // The block must actually have moved, and the forcing acted, for the comparison to mean anything.
            assert!(reference.interface_cells() > 0 && reference.max_speed() > 1e-3);
            assert!(reference.applied_forcing().iter().any(|a| a.force.iter().any(|&x| x != 0.0)));
            for (isa, f) in runs {
                assert!(f.state() == reference.state(), "{collision:?}: {isa:?} differs from the baseline");
            }
        }
    }
}
