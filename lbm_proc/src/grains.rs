//! The LBM's half of the DEM–LBM coupling: one lattice step with the grains
//! of an exchange forced in (Eq. 5, [`crate::coupling`]), answered with
//! each grain's load (docs/coupling.md).

use schemas::exchange::{ExchangeHeader, HydroLoad, ParticleState};

use crate::coupling::{Coupling, CouplingError, Sphere};
use crate::fluid::Fluid;
use crate::real::Real;

/// The coupling kernel with the buffers of one exchange (reused: no
/// allocation once the grain count is reached).
#[derive(Debug, Clone)]
pub struct GrainForcing {
    coupling: Coupling,
    spheres: Vec<Sphere>,
    /// Wall seconds in covering, forcing bookkeeping and force sums.
    pub coupling_seconds: f64,
}

impl GrainForcing {
    pub fn new(coupling: Coupling) -> Self {
        GrainForcing { coupling, spheres: Vec::new(), coupling_seconds: 0.0 }
    }

    /// One fluid step with `states` forced in; `loads` gets one entry per
    /// state, same order and ids. The step's free-surface conversions are
    /// left to the caller's [`Fluid::finish_step`] (after answering the
    /// DEM, so that they overlap its sub-steps; the next step finishes them
    /// anyway).
    ///
    /// Pre: `header.count == states.len()`. Post: `fluid` advanced one step
    /// but for its conversions; the fluid's momentum change from the forcing
    /// equals minus the sum of the returned forces without buoyancy
    /// (tests/coupling.rs).
    pub fn step<T: Real>(
        &mut self,
        fluid: &mut Fluid<T>,
        header: &ExchangeHeader,
        states: &[ParticleState],
        loads: &mut Vec<HydroLoad>,
    ) -> Result<(), CouplingError> {
        debug_assert_eq!(header.count as usize, states.len());
        let started = std::time::Instant::now();
        self.spheres.clear();
        self.spheres.extend(states.iter().map(|s| Sphere {
            position: s.position,
            velocity: s.velocity,
            angular_velocity: s.angular_velocity,
            radius: s.radius,
        }));
        self.coupling.apply(fluid, &self.spheres)?;
        let covered = started.elapsed().as_secs_f64();
        fluid.begin_step();
        let collected = std::time::Instant::now();
        let forces = self.coupling.collect(fluid)?;
        loads.clear();
        loads.extend(states.iter().zip(forces).map(|(s, f)| HydroLoad {
            id: s.id,
            _pad: 0,
            force: f.surface_force,
            torque: f.surface_torque,
            liquid_mass: f.liquid_mass,
        }));
        self.coupling_seconds += covered + collected.elapsed().as_secs_f64();
        Ok(())
    }
}
