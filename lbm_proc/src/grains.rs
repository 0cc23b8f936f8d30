//! The LBM's half of the DEM–LBM coupling: one lattice step with the grains
//! of an exchange forced in (Eq. 5, [`crate::coupling`]), answered with
//! each grain's load (docs/coupling.md).

use runtime::exchange::{ExchangeHeader, HydroLoad, ParticleState};

use crate::coupling::{Coupling, CouplingError, Sphere};
use crate::fluid::Fluid;
use crate::real::Real;

/// The coupling kernel with the buffers of one exchange (reused: no
/// allocation once the grain count is reached).
#[derive(Debug, Clone)]
pub struct GrainForcing {
    coupling: Coupling,
    /// Added to each grain's load per unit grain volume, N/m³ (the
    /// buoyancy −ρ_L g when the lattice leaves the liquid's weight out).
    added_buoyancy: [f64; 3],
    spheres: Vec<Sphere>,
    /// Wall seconds in covering, forcing bookkeeping and force sums.
    pub coupling_seconds: f64,
}

impl GrainForcing {
    /// The coupling's memory of the last step (a checkpoint keeps it).
    pub fn held_liquid(&self) -> crate::coupling::HeldLiquid {
        self.coupling.held_liquid()
    }

    /// Continues from a checkpoint's [`GrainForcing::held_liquid`].
    pub fn restore_held_liquid(&mut self, held: crate::coupling::HeldLiquid) {
        self.coupling.restore_held_liquid(held);
    }

    pub fn new(coupling: Coupling) -> Self {
        GrainForcing { coupling, added_buoyancy: [0.0; 3], spheres: Vec::new(), coupling_seconds: 0.0 }
    }

    /// Adds `per_volume` × πD³/6 (N/m³ × m³) to every grain's load: the
    /// buoyancy of `lbm.hydrostatics = "buoyancy"` ([`crate::setup::LbmSetup::grain_buoyancy`]).
    pub fn with_added_buoyancy(mut self, per_volume: [f64; 3]) -> Self {
        self.added_buoyancy = per_volume;
        self
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
        let added = self.added_buoyancy;
        loads.extend(states.iter().zip(forces).map(|(s, f)| HydroLoad {
            id: s.id,
            _pad: 0,
            force: {
                let volume = 4.0 / 3.0 * std::f64::consts::PI * s.radius.powi(3);
                std::array::from_fn(|a| f.surface_force[a] + added[a] * volume)
            },
            torque: f.surface_torque,
            liquid_mass: f.liquid_mass,
        }));
        self.coupling_seconds += covered + collected.elapsed().as_secs_f64();
        Ok(())
    }
}
