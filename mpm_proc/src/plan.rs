//! The MPM's plan of a scene, the closed forms that `mpm_proc` and
//! `coupler check` share: the background grid, the wave speeds and the
//! CFL time step, the soil's elastic and Mohr–Coulomb constants, and the
//! Ergun drag at the initial porosity (paper Eqs. 7–9, 12;
//! `/work/shared/reference/mpm-2pdp.md` §3, §7).
//!
//! All SI. The soil is the first particle block (density ρ_s, diameter D,
//! `packing.porosity` n0, `packing.region`), the liquid the first fluid
//! block (density ρ_L, viscosity μ, region); numerics and the soil model come
//! from [`Scene::mpm`]. Meant for scenes validated as `mpm`; on others the
//! missing pieces come out as `None` or NaN. [`SceneMpm`] adds them to a
//! [`Scene`] as methods.

use schemas::scene::{MpmPressureScheme, PackingSpec, Scene};

mod report;
pub use report::{plan, MEASURED_MPM_RATE};

/// The wave that limits the MPM time step.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Wave {
    /// Undrained P-wave of the saturated soil, √((E_oed + K_L/n0)/ρ_sat).
    Undrained,
    /// Compression wave of free liquid, √(K_L/ρ_L).
    Liquid,
    /// P-wave of the dry skeleton, √(E_oed/((1 − n0)ρ_s)).
    Dry,
}

impl Wave {
    pub fn name(self) -> &'static str {
        match self {
            Wave::Undrained => "undrained P-wave",
            Wave::Liquid => "liquid compression wave",
            Wave::Dry => "dry P-wave",
        }
    }
}

/// Wave speeds and the CFL step the MPM takes (constant over the run: the
/// grid does not change and the waves are those of the initial state).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MpmTimeStep {
    /// Oedometric modulus E_oed = E(1 − ν)/((1 + ν)(1 − 2ν)), Pa.
    pub oedometric_modulus: f64,
    /// Initial porosity n0 of the soil (`particles[0].packing.porosity`); None without soil.
    pub porosity: Option<f64>,
    /// Grain density ρ_s, kg/m³; None without soil.
    pub grain_density: Option<f64>,
    /// Liquid density ρ_L, kg/m³; None without liquid.
    pub liquid_density: Option<f64>,
    /// Saturated density ρ_sat = (1 − n0)ρ_s + n0 ρ_L, kg/m³; None unless soil and liquid.
    pub saturated_density: Option<f64>,
    /// Undrained P-wave speed c_u, m/s (soil and liquid present).
    pub undrained: Option<f64>,
    /// Free-liquid compression wave speed c_L, m/s (liquid present).
    pub liquid: Option<f64>,
    /// Dry P-wave speed c_d, m/s (soil present).
    pub dry: Option<f64>,
    /// The fastest of the waves that limit the step, m/s, and which one it
    /// is: every wave present under the explicit pore pressure; under
    /// `mpm.pressure_scheme = "implicit"` with soil present only the dry
    /// skeleton's, since the pressure (the undrained and the liquid waves)
    /// is integrated by backward Euler, stable at any step (design note
    /// docs/design/mpm-implicit-pressure.md §5: ~1.9× the explicit step).
    pub max_speed: f64,
    pub limiting: Wave,
    /// Δt = `mpm.courant` · `mpm.element_size` / c_max, s.
    pub dt: f64,
    /// Steps to `output.end_time`: ceil(end_time/Δt) (the gravity phase not counted).
    pub steps: u64,
}

impl MpmTimeStep {
    /// The fastest wave the scene has, m/s, whether or not it limits the
    /// step (under the implicit pore pressure the liquid's waves do not).
    pub fn fastest_present(&self) -> f64 {
        [self.undrained, self.liquid, self.dry].into_iter().flatten().fold(self.max_speed, f64::max)
    }
}

/// The MPM background grid: square elements of side `h` from `origin`
/// (domain.min in x and z), `nx` × `nz` of them.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MpmGrid {
    pub element_size: f64,
    /// `domain.min[0]` and `domain.min[2]`, m.
    pub origin: [f64; 2],
    pub nx: usize,
    pub nz: usize,
}

impl MpmGrid {
    pub fn elements(&self) -> usize {
        self.nx * self.nz
    }

    pub fn nodes(&self) -> usize {
        (self.nx + 1) * (self.nz + 1)
    }

    /// Element index range [lo, hi) along x (axis 0) or z (axis 2) covered
    /// by the interval [min, max] (bounds on grid lines, as validated along
    /// x; along z see [`MpmGrid::rows`]).
    pub fn span(&self, axis: usize, min: f64, max: f64) -> (usize, usize) {
        let (o, n) = if axis == 0 { (self.origin[0], self.nx) } else { (self.origin[1], self.nz) };
        let idx = |x: f64| (((x - o) / self.element_size).round().max(0.0) as usize).min(n);
        (idx(min), idx(max))
    }

    /// Range [lo, hi) of the points' lattice rows, `per` to an element,
    /// covered by the z interval [min, max] (bounds on those rows, as
    /// validated: a block may end inside an element).
    pub fn rows(&self, min: f64, max: f64, per: usize) -> (usize, usize) {
        let pitch = self.element_size / per as f64;
        let idx = |z: f64| (((z - self.origin[1]) / pitch).round().max(0.0) as usize).min(self.nz * per);
        (idx(min), idx(max))
    }
}

/// The drag of Eqs. 7–9 at the initial porosity, and Re_p of Eq. 12.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MpmDrag {
    /// Intrinsic permeability κ = D² n0³/(A (1 − n0)²) (Eq. 9), m².
    pub permeability: f64,
    /// Hydraulic conductivity k = κ ρ_L g/μ, m/s.
    pub conductivity: f64,
    /// Linear drag coefficient per unit volume μ n0²/κ (f1 of Eq. 7 over
    /// the relative velocity), kg/(m³ s).
    pub linear_coefficient: f64,
    /// β = B/√(κ A n0³) of Eq. 8, 1/m.
    pub beta: f64,
    /// Reference velocity √(g H0), m/s (H0 = `analysis.column_height`).
    pub reference_velocity: f64,
    /// Re_p = D ρ_L √(g H0)/μ (Eq. 12 with v_L,ref = √(g H0)).
    pub reynolds: f64,
    /// Δt · (μ n0²/κ) · (1/((1 − n0)ρ_s) + 1/(n0 ρ_L)): the linear drag's
    /// relaxation of the relative velocity per step. An explicit (forward
    /// Euler) drag overshoots above 1 and diverges above 2; the solver
    /// integrates the drag implicitly per node, which is stable for any value.
    pub stiffness: f64,
}

/// E_oed = E(1 − ν)/((1 + ν)(1 − 2ν)), Pa.
pub fn oedometric_modulus(young: f64, poisson: f64) -> f64 {
    young * (1.0 - poisson) / ((1.0 + poisson) * (1.0 - 2.0 * poisson))
}

/// K0 = ν/(1 − ν): horizontal over vertical effective stress at rest (elastic).
pub fn at_rest_coefficient(poisson: f64) -> f64 {
    poisson / (1.0 - poisson)
}

/// Rankine active coefficient K_a = (1 − sin φ)/(1 + sin φ), φ in degrees.
pub fn active_coefficient(friction_angle_deg: f64) -> f64 {
    let s = friction_angle_deg.to_radians().sin();
    (1.0 - s) / (1.0 + s)
}

/// Intrinsic permeability of Eq. 9 (Kozeny–Carman with Ergun's A), m².
pub fn permeability(diameter: f64, porosity: f64, ergun_a: f64) -> f64 {
    let solid = 1.0 - porosity;
    diameter * diameter * porosity * porosity * porosity / (ergun_a * solid * solid)
}

/// The MPM's reading of a scene: grid, porosity, time step, drag.
pub trait SceneMpm {
    /// n0 of the MPM soil: `particles[0].packing.porosity` (None without a
    /// soil block or with a `count` packing).
    fn mpm_porosity(&self) -> Option<f64>;
    /// The MPM background grid over the x–z section of the domain.
    fn mpm_grid(&self) -> MpmGrid;
    /// The wave speeds of the MPM scene and the CFL step from them.
    fn mpm_time_step(&self) -> MpmTimeStep;
    /// The Ergun drag at n0 and Re_p of Eq. 12; None unless the scene has
    /// both a soil and a liquid.
    fn mpm_drag(&self) -> Option<MpmDrag>;
}

impl SceneMpm for Scene {
    /// n0 of the MPM soil: `particles[0].packing.porosity` (None without a
    /// soil block or with a `count` packing).
    fn mpm_porosity(&self) -> Option<f64> {
        match &self.spec.particles.first()?.packing {
            PackingSpec::Deposit { porosity, .. } => *porosity,
            PackingSpec::Explicit { .. } => None,
        }
    }

    /// The MPM background grid over the x–z section of the domain.
    fn mpm_grid(&self) -> MpmGrid {
        let h = self.mpm().element_size;
        let d = &self.spec.domain;
        let n = |a: usize| ((d.max[a] - d.min[a]) / h).round().max(0.0) as usize;
        MpmGrid { element_size: h, origin: [d.min[0], d.min[2]], nx: n(0), nz: n(2) }
    }

    /// The wave speeds of the MPM scene and the CFL step from them:
    /// c_u = √((E_oed + K_L/n0)/ρ_sat) with soil and liquid, c_L = √(K_L/ρ_L)
    /// with liquid, c_d = √(E_oed/((1 − n0)ρ_s)) with soil;
    /// Δt = courant · element_size / max(c) over the waves that limit
    /// (`MpmTimeStep::max_speed`).
    fn mpm_time_step(&self) -> MpmTimeStep {
        let m = self.mpm();
        let e_oed = oedometric_modulus(m.young_modulus, m.poisson_ratio);
        let k_l = m.liquid_bulk_modulus;
        let soil = self.spec.particles.first();
        let n0 = soil.map(|_| self.mpm_porosity().unwrap_or(f64::NAN));
        let rho_s = soil.map(|p| p.density);
        let rho_l = self.spec.fluids.first().map(|f| f.density);
        let rho_sat = match (n0, rho_s, rho_l) {
            (Some(n), Some(s), Some(l)) => Some((1.0 - n) * s + n * l),
            _ => None,
        };
        let undrained = match (n0, rho_sat) {
            (Some(n), Some(r)) => Some(((e_oed + k_l / n) / r).sqrt()),
            _ => None,
        };
        let liquid = rho_l.map(|l| (k_l / l).sqrt());
        let dry = match (n0, rho_s) {
            (Some(n), Some(s)) => Some((e_oed / ((1.0 - n) * s)).sqrt()),
            _ => None,
        };
        let mut max_speed = f64::NAN;
        let mut limiting = Wave::Undrained;
        let pressure_implicit = m.pressure_scheme == MpmPressureScheme::Implicit && dry.is_some();
        for (c, w) in [(undrained, Wave::Undrained), (liquid, Wave::Liquid), (dry, Wave::Dry)] {
            if pressure_implicit && w != Wave::Dry {
                continue;
            }
            if let Some(c) = c {
                if max_speed.is_nan() || c > max_speed {
                    max_speed = c;
                    limiting = w;
                }
            }
        }
        let dt = m.courant * m.element_size / max_speed;
        let steps = (self.spec.output.end_time / dt).ceil();
        MpmTimeStep {
            oedometric_modulus: e_oed,
            porosity: n0,
            grain_density: rho_s,
            liquid_density: rho_l,
            saturated_density: rho_sat,
            undrained,
            liquid,
            dry,
            max_speed,
            limiting,
            dt,
            steps: if steps.is_finite() && steps >= 0.0 { steps as u64 } else { 0 },
        }
    }

    /// The Ergun drag at n0 and Re_p of Eq. 12; None unless the scene has
    /// both a soil and a liquid.
    fn mpm_drag(&self) -> Option<MpmDrag> {
        let m = self.mpm();
        let soil = self.spec.particles.first()?;
        let liquid = self.spec.fluids.first()?;
        let n0 = self.mpm_porosity().unwrap_or(f64::NAN);
        let (mu, rho_l, rho_s, d) = (liquid.viscosity, liquid.density, soil.density, soil.diameter);
        let g = self.gravity_magnitude();
        let kappa = permeability(d, n0, m.ergun_a);
        let linear = mu * n0 * n0 / kappa;
        let v_ref = (g * self.spec.analysis.column_height).sqrt();
        let dt = self.mpm_time_step().dt;
        Some(MpmDrag {
            permeability: kappa,
            conductivity: kappa * rho_l * g / mu,
            linear_coefficient: linear,
            beta: m.ergun_b / (kappa * m.ergun_a * n0.powi(3)).sqrt(),
            reference_velocity: v_ref,
            reynolds: d * rho_l * v_ref / mu,
            stiffness: dt * linear * (1.0 / ((1.0 - n0) * rho_s) + 1.0 / (n0 * rho_l)),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::Path;

    fn close(a: f64, b: f64, rel: f64) -> bool {
        (a - b).abs() <= rel * b.abs()
    }

    /// mpm-2pdp.md §7: E_oed = 1.346e7 Pa, ρ_sat = 1960, c₁ = 180 m/s,
    /// free water 141 m/s, dry 93 m/s for n = 0.4, ρ_s = 2600.
    #[test]
    fn wave_speeds_of_the_lab_column() {
        let s = load(&["mpm.pressure_scheme=\"explicit\""]);
        let t = s.mpm_time_step();
        assert!(close(t.oedometric_modulus, 1.346e7, 1e-3), "{t:?}");
        assert!(close(t.saturated_density.unwrap(), 1960.0, 1e-12), "{t:?}");
        assert!(close(t.undrained.unwrap(), 180.0, 2e-3), "{t:?}");
        assert!(close(t.liquid.unwrap(), 141.4, 1e-3), "{t:?}");
        assert!(close(t.dry.unwrap(), 93.0, 2e-3), "{t:?}");
        assert_eq!(t.limiting, Wave::Undrained);
        // Δt = 0.5 · 0.004 / 179.94 = 1.111e-5 s; 0.85 s takes 76 494 steps.
        assert!(close(t.dt, 0.5 * 0.004 / t.undrained.unwrap(), 1e-14) && close(t.dt, 1.1115e-5, 1e-3), "{t:?}");
        assert_eq!(t.steps, (0.85 / t.dt).ceil() as u64);
    }

    /// The lab column of Ceccato et al. 2020 for the MPM (Table 2:
    /// n0 = 0.40), every MPM setting at its default
    /// (`scenes/validation/mpm_lab_column_defaults.toml`).
    fn load(set: &[&str]) -> Scene {
        let set: Vec<String> = set.iter().map(|s| s.to_string()).collect();
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenes/validation/mpm_lab_column_defaults.toml");
        Scene::load(&path, &set).unwrap()
    }

    /// Under the implicit pore pressure (the default) the skeleton's wave
    /// limits the step: Δt = 0.5 · 0.004 / 92.9 = 2.15e-5 s, 1.94× the
    /// explicit one (c_u/c_d); water alone keeps its own wave (nothing else
    /// would bound the step).
    #[test]
    fn the_implicit_pore_pressure_steps_at_the_skeletons_wave() {
        let explicit = load(&["mpm.pressure_scheme=\"explicit\""]).mpm_time_step();
        let t = load(&[]).mpm_time_step();
        assert_eq!(t.limiting, Wave::Dry);
        assert!(close(t.dt, 0.5 * 0.004 / t.dry.unwrap(), 1e-14) && close(t.dt, 2.153e-5, 1e-3), "{t:?}");
        assert!(close(t.dt / explicit.dt, explicit.undrained.unwrap() / t.dry.unwrap(), 1e-12));
        let water = load(&["particles=[]", "analysis.condition=\"liquid\"", "mpm.pressure_scheme=\"implicit\""]);
        assert_eq!(water.mpm_time_step().limiting, Wave::Liquid);
    }

    #[test]
    fn one_phase_scenes_take_their_own_wave() {
        // Dry soil: the dry P-wave limits.
        let dry = load(&["fluids=[]", "analysis.condition=\"dry\""]);
        let t = dry.mpm_time_step();
        assert_eq!((t.undrained, t.liquid, t.limiting), (None, None, Wave::Dry));
        assert!(close(t.max_speed, 92.9, 2e-3), "{t:?}");
        assert!(dry.mpm_drag().is_none());
        // Water alone: the liquid wave.
        let water = load(&["particles=[]", "analysis.condition=\"liquid\""]);
        let t = water.mpm_time_step();
        assert_eq!((t.undrained, t.dry, t.limiting), (None, None, Wave::Liquid));
        assert!(close(t.dt, 0.5 * 0.004 / 2e4_f64.sqrt(), 1e-12), "{t:?}");
    }

    /// analytic-checks.md "Porous flow": κ = 7.41e-9 m², K = 0.0727 m/s;
    /// Re_p = 2.5e-3 · 1000 · √(9.81 · 0.06) / 1e-3 = 1918.
    #[test]
    fn drag_of_the_lab_bed() {
        let s = load(&[]);
        let d = s.mpm_drag().unwrap();
        assert!(close(d.permeability, 7.41e-9, 1e-3), "{d:?}");
        assert!(close(d.conductivity, 0.0727, 1e-3), "{d:?}");
        assert!(close(d.reynolds, 1918.4, 1e-3), "{d:?}");
        // μ n0²/κ = 1e-3 · 0.16 / 7.407e-9 = 2.16e4; × (1/1560 + 1/400) × Δt
        // = 1.46e-3 at the implicit scheme's Δt = 2.153e-5 s.
        assert!(close(d.linear_coefficient, 2.16e4, 1e-3), "{d:?}");
        assert!(close(d.stiffness, 1.461e-3, 1e-2), "{d:?}");
    }

    #[test]
    fn grid_and_spans() {
        let s = load(&[]);
        let g = s.mpm_grid();
        assert_eq!((g.nx, g.nz, g.elements(), g.nodes()), (175, 30, 5250, 176 * 31));
        assert_eq!(g.span(0, 0.0, 0.04), (0, 10));
        assert_eq!(g.span(2, 0.0, 0.06), (0, 15));
    }

    #[test]
    fn soil_constants() {
        assert!(close(at_rest_coefficient(0.3), 0.4286, 1e-4));
        assert!(close(active_coefficient(35.0), 0.2710, 1e-3));
    }
}
