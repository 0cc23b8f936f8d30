//! Topic and metadata names of the recordings, in one place for every
//! process, the readers and the docs (docs/recording.md).

pub const DEM_PARTICLES: &str = "/dem/particles";
pub const DEM_SPHERES: &str = "/dem/spheres";
pub const DEM_METRICS: &str = "/dem/metrics";
pub const DEM_STATE: &str = "/dem/state";
/// The loads the DEM received, one message per exchange (`output.record_exchange`).
pub const DEM_RECEIVED_LOADS: &str = "/dem/received_loads";
/// The grain states the LBM received, one message per exchange.
pub const LBM_RECEIVED_STATES: &str = "/lbm/received_states";
/// Coupled runs: each process's wall time per frame (`CouplingTimings`).
pub const DEM_COUPLING: &str = "/dem/coupling";
pub const LBM_COUPLING: &str = "/lbm/coupling";
pub const LBM_SURFACE: &str = "/lbm/surface";
pub const LBM_SLICE: &str = "/lbm/slice";
pub const LBM_METRICS: &str = "/lbm/metrics";
pub const LBM_STATE: &str = "/lbm/state";
pub const MPM_SOLID: &str = "/mpm/solid";
pub const MPM_LIQUID: &str = "/mpm/liquid";
pub const MPM_METRICS: &str = "/mpm/metrics";
pub const MPM_STATE: &str = "/mpm/state";
pub const LOG: &str = "/log";

/// Metadata record names.
pub mod metadata {
    /// The scene as run (TOML after overrides), key `toml`.
    pub const SCENE: &str = "scene";
    /// The run summary, key `json`.
    pub const SUMMARY: &str = "summary";
}
