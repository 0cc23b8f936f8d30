//! One sphere settling from rest in a closed tank of liquid, the free-grain
//! case of the coupling study (docs/coupling.md, "Settling sphere"): the
//! grain moves, so the forcing acts on a moving boundary, cells are
//! covered and uncovered every step, and the force the grain is given is
//! the coupling's surface force (the one `lbm_proc` answers the DEM with),
//! not the force a fixed array feels.
//!
//! Set-up, lattice units: a tank of square cross-section `width` D and
//! height `height` D, no-slip walls on all six faces (half-way bounce-back),
//! the liquid at rest. The lattice carries no gravity (the buoyancy form,
//! `lbm.hydrostatics = "buoyancy"`: no hydrostatic compression), so the
//! sphere, of density ratio s = ρ_s/ρ_L, feels its net weight
//! −(s − 1)ρ_L V g plus the surface force. It starts at rest on the tank's
//! axis `release` D below the lid; Newton's equations are integrated once
//! per lattice step (symplectic Euler, the force held over the step, as
//! the DEM's 57 sub-steps hold it).
//!
//! Reference: the terminal velocity in an unbounded liquid by
//! Schiller–Naumann, C_d = 24/Re (1 + 0.15 Re^0.687)
//! (`shared/reference/coupling-references.md` §3), times the wall factor
//! of [`wall_factor`]. g is chosen so that the unbounded terminal Reynolds
//! number is the case's `reynolds`; the measured velocity is the mean over
//! the fall from `window.0` to `window.1` D above the floor.

use std::f64::consts::PI;

use super::{lattice_units, FluidCondition};
use crate::coupling::{Coupling, ForcingGain, Sphere};
use crate::fluid::{Faces, Fluid};

/// Schiller & Naumann's (1933) drag factor C_d Re/24 = 1 + 0.15 Re^0.687.
pub fn schiller_naumann(re: f64) -> f64 {
    1.0 + 0.15 * re.powf(0.687)
}

/// Ratio of the settling velocity on the axis of a square duct of side L to
/// the unbounded one, for a sphere of diameter D at terminal Reynolds
/// number `re`: Di Felice's (1996, Int. J. Multiphase Flow 22, 527)
/// correlation for a cylinder, ((1 − λ)/(1 − 0.33λ))^α with
/// (3.3 − α)/(α − 0.85) = 0.1 Re, fitted to experiments at 0.1 < Re < 10³,
/// applied with the cylinder-equivalent λ = 0.904 D/L: a sphere on the
/// axis of a square duct has the Stokes wall coefficient 1.903 D/L (Happel
/// & Brenner 1965, Table 7-4.1) where a cylinder has 2.104 λ (Faxén), so
/// the two agree to first order in Stokes flow. At Re → 0 the factor is
/// within 0.5 % of Faxén's series for λ ≤ 0.1 (tested). The correlation is
/// not in `coupling-references.md` (quoted from the paper, unchecked
/// there); the study's tank-width check finds it 3–7 points too strong at
/// L = 10 D (docs/coupling.md, "Settling sphere").
pub fn wall_factor(d_over_l: f64, re: f64) -> f64 {
    let lambda = 1.903 / 2.10444 * d_over_l;
    let alpha = (3.3 + 0.085 * re) / (1.0 + 0.1 * re);
    ((1.0 - lambda) / (1.0 - 0.33 * lambda)).powf(alpha)
}

/// The liquid of a settling case and the unbounded terminal velocity it
/// sets.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum SettlingLiquid {
    /// No eddy viscosity; ν chosen so that the unbounded terminal velocity
    /// is `velocity` (lattice units, Mach number √3 × velocity) at the
    /// case's Reynolds number: τ0 = ½ + 3 velocity D/Re.
    Viscous { velocity: f64 },
    /// The paper's water at this resolution ([`FluidCondition::paper_water`]:
    /// τ0 = 0.50067 at D/Δx = 4.17, Smagorinsky 0.16); the terminal velocity
    /// follows from Re, Re ν/D (slow: 1.6e-3 at Re = 30).
    PaperWater,
}

/// One settling run's parameters.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SettlingCase {
    /// Unbounded terminal Reynolds number U_∞ D/ν by Schiller–Naumann.
    pub reynolds: f64,
    /// Sphere diameter, cells.
    pub d_cells: f64,
    pub liquid: SettlingLiquid,
    pub gain: ForcingGain,
    /// ρ_s/ρ_L. Default 2.6, the paper's grains in water.
    pub density_ratio: f64,
    /// Tank side and height, D. Defaults 10 and 32 (Re ≤ 16), 24 + Re/2
    /// above (a longer run-up).
    pub width: f64,
    pub height: f64,
    /// Start depth of the centre below the lid, D. Default 4.
    pub release: f64,
    /// Heights of the centre above the floor between which the velocity is
    /// averaged, D. Default (20, 12), 8 D of fall, after a run-up of
    /// max(8, Re/2) D from the release: the approach to the terminal
    /// velocity is slower than the quasi-steady drag's exponential (the
    /// history force; at Re = 30 the velocity still grew 3.6 % across the
    /// window after 8 D). The floor's Stokes correction 9R/(16h) is ≤ 2.3 %
    /// at 12 D, smaller at Re ≥ 1, where the disturbance decays beyond the
    /// Oseen length D/Re; it is not corrected for.
    pub window: (f64, f64),
    /// Start of the centre across the tank, cells from the cell edge
    /// nearest the axis (⌊side/2⌋). Default (0.27, 0.13): off the lattice's
    /// symmetry lines, the same sub-cell position in every tank. At
    /// D/Δx = 4.17 the drag depends on it by up to ~10 % (docs/coupling.md).
    pub offset: [f64; 2],
}

impl SettlingCase {
    /// The study's tank and grains at terminal Reynolds number `reynolds`,
    /// `d_cells` cells per diameter.
    pub fn new(reynolds: f64, d_cells: f64, liquid: SettlingLiquid, gain: ForcingGain) -> Self {
        let (release, run_up, window) = (4.0, (0.5 * reynolds).max(8.0), (20.0, 12.0));
        SettlingCase {
            reynolds,
            d_cells,
            liquid,
            gain,
            density_ratio: 2.6,
            width: 10.0,
            height: window.0 + run_up + release,
            release,
            window,
            offset: [0.27, 0.13],
        }
    }

    /// The lattice fluid and the unbounded terminal velocity, lattice units.
    pub fn fluid(&self) -> (FluidCondition, f64) {
        match self.liquid {
            SettlingLiquid::Viscous { velocity } => {
                (FluidCondition::viscous(0.5 + 3.0 * velocity * self.d_cells / self.reynolds), velocity)
            }
            SettlingLiquid::PaperWater => {
                let fluid = FluidCondition::paper_water(self.d_cells);
                (fluid, self.reynolds * fluid.nu() / self.d_cells)
            }
        }
    }
}

/// What a settling run measured.
#[derive(Debug, Clone, PartialEq)]
pub struct SettlingRun {
    pub case: SettlingCase,
    /// Molecular τ0.
    pub tau: f64,
    /// Tank cells: side, height.
    pub cells: [usize; 2],
    /// Unbounded Schiller–Naumann terminal velocity, and times the wall
    /// factor: the expected velocity in this tank.
    pub unbounded: f64,
    pub expected: f64,
    /// Mean settling velocity over the window.
    pub measured: f64,
    /// measured / expected − 1.
    pub error: f64,
    /// (velocity leaving the window − entering it) / measured: near 0 when
    /// the sphere was at its terminal velocity throughout.
    pub trend: f64,
    /// Over the window, the mean vertical surface force (what the grain is
    /// given) over the mean vertical −Σ share·F_IB (the forcing's reaction):
    /// 1 when the interior liquid's momentum is steady.
    pub surface_over_forcing: f64,
    pub steps: usize,
}

/// Why a settling run gave no velocity.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SettlingError {
    #[error("the lattice became unstable at step {0} (τ0 {1:.5}): lower the velocity or raise the resolution")]
    Unstable(usize, f64),
    #[error("the sphere did not cross the window within {0} steps")]
    TooSlow(usize),
}

/// Runs one [`SettlingCase`] in single precision (the scenes' lattice)
/// until the centre leaves the window, at most 3× the steps the unbounded
/// terminal velocity would need from the release.
pub fn settle(case: SettlingCase) -> Result<SettlingRun, SettlingError> {
    let (fluid, unbounded) = case.fluid();
    let d = case.d_cells;
    let side = (case.width * d).round() as usize;
    let height = (case.height * d).round() as usize;
    let mut lattice =
        Fluid::<f32>::new([side, side, height], [Faces::Walls; 3], fluid.params([0.0; 3])).expect("a valid tank");
    let mut coupling = Coupling::new(lattice_units(), [0.0; 3]).expect("finite origin").with_gain(case.gain);
    let nu = fluid.nu();
    let s = case.density_ratio;
    let volume = PI * d.powi(3) / 6.0;
    let g = 18.0 * nu * unbounded * schiller_naumann(case.reynolds) / ((s - 1.0) * d * d);
    let start = [(side / 2) as f64 + case.offset[0], (side / 2) as f64 + case.offset[1]];
    let mut sphere = Sphere {
        position: [start[0], start[1], height as f64 - case.release * d],
        velocity: [0.0; 3],
        angular_velocity: [0.0; 3],
        radius: 0.5 * d,
    };
    let (mass, inertia) = (s * volume, s * volume * d * d / 10.0);
    let (top, bottom) = (case.window.0 * d, case.window.1 * d);
    let max_steps = (3.0 * (sphere.position[2] - bottom) / unbounded) as usize;
    let mut entered: Option<(f64, f64)> = None;
    let (mut surface_sum, mut forcing_sum) = (0.0, 0.0);
    for step in 1..=max_steps {
        let z_before = sphere.position[2];
        let w_before = -sphere.velocity[2];
        let force = coupling.step(&mut lattice, std::slice::from_ref(&sphere)).expect("a sphere inside the tank")[0];
        let net = [force.surface_force[0], force.surface_force[1], force.surface_force[2] - (s - 1.0) * volume * g];
        for a in 0..3 {
            sphere.velocity[a] += net[a] / mass;
            sphere.angular_velocity[a] += force.surface_torque[a] / inertia;
            sphere.position[a] += sphere.velocity[a];
        }
        if !sphere.velocity[2].is_finite() || step % 100 == 0 && !lattice.max_speed().is_finite() {
            return Err(SettlingError::Unstable(step, fluid.tau));
        }
        let (z, w) = (sphere.position[2], -sphere.velocity[2]);
        // Crossing times and velocities interpolated within the step.
        let cross = |level: f64| {
            let f = (z_before - level) / (z_before - z);
            (step as f64 - 1.0 + f, w_before + f * (w - w_before))
        };
        if entered.is_none() && z <= top {
            entered = Some(cross(top));
        }
        if entered.is_some() {
            surface_sum += force.surface_force[2];
            forcing_sum += force.force[2];
        }
        if z <= bottom {
            let (t_in, w_in) = entered.expect("the window's top is above its bottom");
            let (t_out, w_out) = cross(bottom);
            let measured = (top - bottom) / (t_out - t_in);
            let re = case.reynolds;
            let expected = unbounded * wall_factor(1.0 / case.width, re);
            return Ok(SettlingRun {
                case,
                tau: fluid.tau,
                cells: [side, height],
                unbounded,
                expected,
                measured,
                error: measured / expected - 1.0,
                trend: (w_out - w_in) / measured,
                surface_over_forcing: surface_sum / forcing_sum,
                steps: step,
            });
        }
    }
    Err(SettlingError::TooSlow(max_steps))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// At Re → 0 the wall factor is Faxén's series 1 − 2.10444λ + 2.08877λ³
    /// − 0.94813λ⁵ (coupling-references.md §3) in the equivalent λ.
    #[test]
    fn wall_factor_is_faxens_in_stokes_flow() {
        for l_over_d in [10.0_f64, 16.0, 40.0] {
            let lambda = 1.903 / 2.10444 / l_over_d;
            let faxen = 1.0 - 2.10444 * lambda + 2.08877 * lambda.powi(3) - 0.94813 * lambda.powi(5);
            let factor = wall_factor(1.0 / l_over_d, 0.0);
            assert!((factor / faxen - 1.0).abs() < 5e-3, "L/D {l_over_d}: {factor} against Faxén {faxen}");
        }
        // Inertia weakens the walls' hold: at Re = 30 the factor is closer to 1.
        assert!(wall_factor(0.1, 30.0) > wall_factor(0.1, 1.0) + 0.05);
    }

    /// Schiller–Naumann's C_d = 24/Re × factor at the reference values.
    #[test]
    fn schiller_naumann_matches_the_tabulated_drag() {
        for (re, cd) in [(0.1, 247.4), (1.0, 27.60), (10.0, 4.151), (100.0, 1.092)] {
            let ours = 24.0 / re * schiller_naumann(re);
            assert!((ours / cd - 1.0).abs() < 1e-3, "Re {re}: C_d {ours} against {cd}");
        }
    }
}
