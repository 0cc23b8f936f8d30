//! D3Q19 lattice Boltzmann fluid for the DEM–LBM method of Ceccato et al. 2020 (§3.1).
//!
//! * [`units`]: the one SI ↔ lattice converter, τ from viscosity;
//! * [`coupling`]: particle coupling (Eq. 5), direct forcing of the cells
//!   covered by spheres, force, torque and buoyancy on each sphere;
//! * [`lattice`]: D3Q19 velocities, weights, opposites, equilibrium;
//! * [`fluid`]: the state and its fused stream–collide step (BGK or TRT,
//!   Smagorinsky Eq. 4, Guo forcing, half-way bounce-back, periodic faces),
//!   and the free surface by mass tracking (interface and gas cells);
//! * [`watchdog`]: the stability check with a typed diagnosis;
//! * [`run`]: a whole fluid-only run: gates, frames, MCAP, summary;
//! * [`setup`]: a checked scene (SI) on the lattice: box, units, gates, liquid;
//! * [`memory`]: lattice arrays backed by memory only where written (the liquid's);
//! * [`real`]: the population float type (f32 default, f64 for comparison);
//! * [`bench`](mod@bench): bulk throughput and memory bandwidth measurement;
//! * [`validation`]: the coupling's validation cases (sphere arrays, packed
//!   beds) against published drag and permeability.
//!
//! Everything inside is in lattice units (Δx = Δt = ρ0 = 1). See `docs/lbm.md`.

pub mod bench;
pub mod coupling;
pub mod fluid;
pub mod grains;
pub mod lattice;
pub mod memory;
pub mod plan;
pub mod real;
pub mod run;
pub mod setup;
pub mod units;
pub mod validation;
pub mod watchdog;

pub use coupling::{Coupling, CouplingError, Sphere, SphereForce};
pub use fluid::{Collision, Faces, Fluid, FluidParams, FluidState, InterfaceCell, Sample};
pub use units::Units;
pub use watchdog::{Instability, WatchdogLimits};
