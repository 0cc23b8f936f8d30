//! The vocabulary every process shares: scene files and their validation,
//! the messages the DEM and the LBM exchange, the recordings' topic names,
//! run summaries and the measures of a collapse. Plain data and pure
//! functions (serde, toml, thiserror only); the transport, the recorder and
//! the process handling that use it are the `runtime` crate.

pub mod error;
pub mod measures;
pub mod messages;
pub mod overrides;
pub mod plan;
pub mod scene;
pub mod summary;
pub mod topics;

pub use error::SceneError;
pub use scene::{Method, Scene};

/// Exit status of every binary for a scene or usage error.
pub const EXIT_BAD_SCENE: i32 = 2;
/// Exit status after Ctrl-C (128 + SIGINT).
pub const EXIT_INTERRUPTED: i32 = 130;

/// FNV-1a 64-bit: a stable hash for cache keys (std's hasher may change between releases).
pub fn stable_hash(bytes: &[u8]) -> u64 {
    let mut h = 0xcbf2_9ce4_8422_2325_u64;
    for &b in bytes {
        h ^= b as u64;
        h = h.wrapping_mul(0x0000_0100_0000_01b3);
    }
    h
}
