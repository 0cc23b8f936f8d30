//! Stability watchdog: a typed diagnosis instead of a silent blow-up.
//!
//! Thresholds follow lbm-free-surface.md §8: |u| should stay below ~0.1
//! (Mach 0.17) and is fatal above Mach 0.3, where the second-order
//! equilibrium's O(Ma³) error dominates; the density of a weakly compressible
//! liquid stays within a few percent of 1, so [0.5, 2] only catches runs that
//! have already failed.

use serde::{Deserialize, Serialize};

/// Bounds checked by [`crate::fluid::Fluid::check`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct WatchdogLimits {
    /// Lowest lattice density, default 0.5.
    pub min_density: f64,
    /// Highest lattice density, default 2.
    pub max_density: f64,
    /// Highest |u|/c_s, default 0.3 (|u| ≤ 0.3·√(1/3) ≈ 0.173 lattice units).
    pub max_mach: f64,
    /// How far an interface cell's fill ε may stray beyond [−κ, 1 + κ]. The
    /// conversions leave every interface cell inside that band except for
    /// the excess mass a converted neighbour hands over in the same step (the
    /// cell converts in the next one): up to 0.39 at the paper's Δt on a fast
    /// front. Default 1.0: only a fill off by a whole cell means trouble;
    /// measured extremes are in docs/lbm.md (Watchdog).
    pub fill_margin: f64,
}

impl Default for WatchdogLimits {
    fn default() -> Self {
        WatchdogLimits { min_density: 0.5, max_density: 2.0, max_mach: 0.3, fill_margin: 1.0 }
    }
}

/// The quantity that left its bounds.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum Quantity {
    /// Population f_i (index into [`crate::lattice::E`]) is NaN or infinite.
    Population(usize),
    /// Lattice density.
    Density,
    /// |u|/c_s.
    Mach,
    /// Fill ε = m/ρ of an interface cell.
    Fill,
}

/// The first cell found out of bounds, with what to change.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, thiserror::Error)]
#[error("{}", describe(self))]
pub struct Instability {
    /// Steps completed when the check ran.
    pub step: u64,
    /// Cell (i, j, k).
    pub cell: [usize; 3],
    pub quantity: Quantity,
    pub value: f64,
    pub limits: WatchdogLimits,
}

impl Instability {
    /// The most likely remedy for this failure.
    pub fn fix(&self) -> &'static str {
        match self.quantity {
            Quantity::Population(_) => {
                "the collision lost stability (tau too close to 1/2 for the local shear): \
                 raise the Smagorinsky constant, switch to TRT, or lower the time step"
            }
            Quantity::Density => {
                "density far outside [min, max] means the collision lost stability (raise the Smagorinsky \
                 constant, or use BGK rather than TRT near tau = 1/2); slightly outside means the \
                 compressibility error is too large (Mach or gravity head too high in lattice units): \
                 lower the time step"
            }
            Quantity::Mach => {
                "flow too fast for the lattice: lower the time step (u_L = u dt/dx), \
                 or raise the Smagorinsky constant / use TRT if the speed comes from an instability"
            }
            Quantity::Fill => {
                "an interface cell's fill left [-kappa, 1 + kappa] by more than the margin: the mass \
                 exchange per step is too large (lower the time step), or the surface is breaking up \
                 into spray (raise the Smagorinsky constant)"
            }
        }
    }
}

fn describe(e: &Instability) -> String {
    let (i, j, k) = (e.cell[0], e.cell[1], e.cell[2]);
    let what = match e.quantity {
        Quantity::Population(q) => format!("population f_{q} is {}", e.value),
        Quantity::Density => {
            format!("lattice density is {:.6} (allowed [{}, {}])", e.value, e.limits.min_density, e.limits.max_density)
        }
        Quantity::Mach => format!("Mach number |u|/c_s is {:.4} (allowed {})", e.value, e.limits.max_mach),
        Quantity::Fill => format!(
            "interface fill is {:.4} (allowed margin {} beyond [-kappa, 1 + kappa])",
            e.value, e.limits.fill_margin
        ),
    };
    format!("LBM unstable after step {}: at cell ({i}, {j}, {k}) {what}; fix: {}", e.step, e.fix())
}
