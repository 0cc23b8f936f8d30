//! What every solver process does the same way: output that never panics,
//! stopping at a step boundary on SIGINT/SIGTERM, dying with its supervisor,
//! and the progress lines `coupler` reads.

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
