//! What every solver process does the same way: output that never panics,
//! stopping at a step boundary on SIGINT/SIGTERM, dying with its supervisor,
//! and the progress lines `coupler` reads.

use std::path::PathBuf;
use std::sync::atomic::AtomicBool;
use std::sync::Arc;

/// `println!` that ignores a closed stdout: when the coupler is gone its
/// pipes are closed, and a panic on a write would skip finishing the recording.
#[macro_export]
macro_rules! say {
    ($($t:tt)*) => {{
        use std::io::Write as _;
        let _ = writeln!(std::io::stdout().lock(), $($t)*);
    }};
}

/// `eprintln!` that ignores a closed stderr (see [`say!`]).
#[macro_export]
macro_rules! tell {
    ($($t:tt)*) => {{
        use std::io::Write as _;
        let _ = writeln!(std::io::stderr().lock(), $($t)*);
    }};
}

/// A flag raised by SIGINT or SIGTERM. Install it first thing in `main`, so
/// a signal during start-up is not lost; the run loop polls it at step boundaries.
pub fn stop_flag() -> std::io::Result<Arc<AtomicBool>> {
    let stop = Arc::new(AtomicBool::new(false));
    for sig in [signal_hook::consts::SIGINT, signal_hook::consts::SIGTERM] {
        signal_hook::flag::register(sig, Arc::clone(&stop))?;
    }
    Ok(stop)
}

/// Asks the kernel to send SIGTERM when the parent dies, so a killed coupler
/// leaves no orphan solver (the SIGTERM handler then stops at a step boundary).
pub fn die_with_parent() {
    #[cfg(target_os = "linux")]
    // SAFETY: prctl with PR_SET_PDEATHSIG only sets a flag on this process.
    unsafe {
        libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGTERM);
        if libc::getppid() == 1 {
            libc::raise(libc::SIGTERM);
        }
    }
}

/// One `--progress-json` line: `{"event":"progress","phase":…,"t":…,"t_end":…,"steps":…,"wall":…}`.
pub fn progress_line(phase: &str, t: f64, t_end: f64, steps: u64, wall: f64) -> String {
    format!(
        "{{\"event\":\"progress\",\"phase\":\"{phase}\",\"t\":{t},\"t_end\":{t_end},\"steps\":{steps},\"wall\":{wall}}}"
    )
}

/// The arguments of every solver's `run` subcommand (what `coupler` passes).
#[derive(Debug, Clone, clap::Args)]
pub struct RunArgs {
    /// Scene file (TOML).
    pub scene: PathBuf,
    /// Output directory (default: runs/<solver>, e.g. runs/dem).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Override a scene value, e.g. --set output.end_time=0.2 (repeatable).
    #[arg(long = "set", value_name = "KEY.PATH=VALUE")]
    pub set: Vec<String>,
    /// Worker threads (default: all cores). Results do not depend on it.
    #[arg(long)]
    pub threads: Option<usize>,
    /// Skip the MCAP recording (to measure what recording costs).
    #[arg(long)]
    pub no_record: bool,
    /// Machine-readable progress on stdout, one JSON object per line (used by `coupler`).
    #[arg(long)]
    pub progress_json: bool,
    /// Stop when the parent process dies (set by `coupler`).
    #[arg(long)]
    pub supervised: bool,
}

/// Options of a run that are not part of the physics.
#[derive(Debug, Clone)]
pub struct RunOptions {
    pub out_dir: PathBuf,
    /// Record to MCAP (off only for benchmarks measuring the recording cost).
    pub record: bool,
}
