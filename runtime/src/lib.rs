//! The ground every solver process stands on, apart from what it computes:
//! the DEM ⇄ LBM shared-memory [`link`] and the peers a solver exchanges
//! with ([`exchange`]: the link, an in-process pair, a replayed recording);
//! the run loop every solver uses ([`driver`]) and the exchange with a
//! coupled peer it owns ([`coupled`]);
//! the MCAP [`record`]er and the plottable [`metrics`] it writes; signals,
//! parent death, the command line and the thread pool ([`process`]); the
//! kernels' instruction set ([`isa`]).
//!
//! The vocabulary these speak (scenes, messages, topics, summaries) is the
//! `schemas` crate, which depends on none of this.

pub mod checkpoint;
pub mod coupled;
pub mod driver;
pub mod exchange;
pub mod isa;
pub mod link;
pub mod metrics;
pub mod process;
pub mod record;
