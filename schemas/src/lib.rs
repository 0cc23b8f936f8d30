//! Types every process shares: scene files and their validation, the contact
//! law's closed forms, the MPM's grid, wave speeds and time step, measures
//! of a collapse, run summaries, and the MCAP recorder with its topic names.

pub mod contact;
pub mod error;
pub mod exchange;
pub mod isa;
pub mod link;
pub mod measures;
pub mod metrics;
pub mod mpm;
pub mod overrides;
pub mod process;
pub mod record;
pub mod scene;
pub mod summary;

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
