//! 3D DEM of spheres for granular column collapses (Ceccato et al. 2020 §3.1).
//!
//! * [`contact`]: closed forms of the spring–dashpot contact (ζ from e, duration);
//! * [`law`]: the contact law (Eqs. 1–3), one kernel for grain–grain and grain–wall;
//! * [`neighbours`]: linked cells and the Verlet pair list with contact history;
//! * [`world`]: the state and its `step` (named stages, parallel, deterministic);
//! * [`setup`]: laws, walls and time step from a scene;
//! * [`packing`]: gravity deposition with a disk cache;
//! * [`run`]: a whole run with recording and summary.

pub mod biaxial;
pub mod contact;
pub mod hydro;
pub mod lammps;
pub mod lanes;
pub mod law;
pub mod neighbours;
pub mod packing;
pub mod plan;
pub mod rng;
pub mod run;
pub mod setup;
pub mod vec3;
pub mod world;
