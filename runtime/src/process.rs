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

/// Makes the allocator give every buffer of 1 MiB or more a mapping of its
/// own, returned to the OS when it is freed.
///
/// glibc's default threshold adapts: once a large mapped buffer is freed,
/// buffers up to its size come from the heap, whose freed memory stays
/// resident. A run's frames are such buffers (the LBM's slice of a flume
/// 4× as long is 15 MB a frame), so they had kept ~24 MB of heap resident
/// there (docs/BENCHMARKS.md, session 42). A fixed threshold costs a fresh
/// mapping per frame, some page faults every few seconds. Other C
/// libraries: nothing.
pub fn return_large_buffers_on_free() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: mallopt only changes the allocator's thresholds, under the
    // allocator's own lock; it touches no memory of ours.
    unsafe {
        libc::mallopt(libc::M_MMAP_THRESHOLD, 1 << 20);
    }
}

/// One `--progress-json` line: `{"event":"progress","phase":…,"t":…,"t_end":…,"steps":…,"wall":…}`.
pub fn progress_line(phase: &str, t: f64, t_end: f64, steps: u64, wall: f64) -> String {
    format!(
        "{{\"event\":\"progress\",\"phase\":\"{phase}\",\"t\":{t},\"t_end\":{t_end},\"steps\":{steps},\"wall\":{wall}}}"
    )
}

/// How a run reports progress to whoever launched it.
pub trait Progress {
    /// Phase `phase` (`deposition`, `gravity_phase`, `collapse`, `flow`) is
    /// at simulated time `t` of `t_end` s after `steps` steps.
    fn phase(&mut self, phase: &str, t: f64, t_end: f64, steps: u64);
    /// A note for the user (set-up figures, warnings).
    fn log(&mut self, message: &str);
}

/// A solver process's progress: `--progress-json` lines on stdout for
/// `coupler` ([`progress_line`]), or readable lines on stderr.
#[derive(Debug)]
pub struct Reporter {
    solver: &'static str,
    json: bool,
    started: std::time::Instant,
}

impl Reporter {
    pub fn new(solver: &'static str, json: bool) -> Self {
        Self { solver, json, started: std::time::Instant::now() }
    }
}

impl Progress for Reporter {
    fn phase(&mut self, phase: &str, t: f64, t_end: f64, steps: u64) {
        let wall = self.started.elapsed().as_secs_f64();
        if self.json {
            say!("{}", progress_line(phase, t, t_end, steps, wall));
        } else {
            let name = phase.replace('_', " ");
            tell!("{name}: t = {t:.4} / {t_end} s, {steps} steps, {wall:.1} s wall");
        }
    }
    fn log(&mut self, message: &str) {
        tell!("{}: {message}", self.solver);
    }
}

/// Progress that says nothing (tests, in-process drivers).
#[derive(Debug, Clone, Copy, Default)]
pub struct Quiet;

impl Progress for Quiet {
    fn phase(&mut self, _phase: &str, _t: f64, _t_end: f64, _steps: u64) {}
    fn log(&mut self, _message: &str) {}
}

/// The line a solver process ends a run with: status, time, steps, wall
/// time, throughput in the solver's unit, and the runout (the liquid
/// front for the liquid alone).
pub fn summary_line(solver: &str, s: &schemas::summary::RunSummary) -> String {
    let tp = &s.throughput;
    let rate = match (tp.particle_steps_per_s, tp.cell_updates_per_s, tp.point_updates_per_s) {
        (Some(r), _, _) => format!("{r:.3e} particle-steps/s"),
        (_, Some(r), _) => format!("{:.1} MLUPS", r / 1e6),
        (_, _, Some(r)) => format!("{r:.3e} point-updates/s"),
        _ => String::from("no throughput"),
    };
    let reach = if s.runout.is_finite() {
        format!("runout {:.4}", s.runout)
    } else {
        format!("liquid front {:.4}", s.liquid_front.last().map_or(f64::NAN, |f| f.x_norm))
    };
    format!(
        "{solver}: {} at t = {:.4} s after {} steps in {:.1} s ({rate}); {reach}",
        s.status, s.sim_time, s.steps, s.wall_seconds
    )
}

/// Ends a solver process after its run: the summary line and
/// [`finish_run`], or the error (exit status 1).
pub fn exit_after_run<E: std::fmt::Display>(
    solver: &str,
    progress_json: bool,
    result: Result<schemas::summary::RunSummary, E>,
) -> std::process::ExitCode {
    match result {
        Ok(summary) => {
            tell!("{}", summary_line(solver, &summary));
            finish_run(progress_json, summary.status)
        }
        Err(e) => {
            tell!("{solver}: error: {e}");
            std::process::ExitCode::FAILURE
        }
    }
}

/// The arguments of every solver's `run` subcommand (what `coupler` passes).
#[derive(Debug, Clone, clap::Args)]
pub struct RunArgs {
    /// Scene file (TOML).
    pub scene: PathBuf,
    /// Output directory (default: `runs/<solver>`, e.g. `runs/dem`).
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
    /// Continue from this checkpoint (`OUT/checkpoints/<process>-<step>.ckpt`,
    /// written every `output.checkpoint_interval`) instead of starting the
    /// scene afresh; the run ends as the uninterrupted one would, bit for
    /// bit. `coupler run --resume DIR` picks it for every process.
    #[arg(long, value_name = "CHECKPOINT")]
    pub resume: Option<PathBuf>,
    /// Machine-readable progress on stdout, one JSON object per line (used by `coupler`).
    #[arg(long)]
    pub progress_json: bool,
    /// Stop when the parent process dies (set by `coupler`).
    #[arg(long)]
    pub supervised: bool,
    /// Coupled scenes: the run id shared with the peer process (`coupler`
    /// sets it; by hand, start dem_proc and lbm_proc with the same id).
    #[arg(long)]
    pub run_id: Option<String>,
    /// Coupled scenes: seconds to wait for the peer process at start-up.
    /// The LBM waits while the DEM deposits its packing.
    #[arg(long, default_value_t = 120.0)]
    pub connect_timeout: f64,
    /// Coupled scenes: run alone, with the peer played back from the
    /// messages this process received in a recorded run (recorded with
    /// `--set output.record_exchange=true`): reproduces that run's part of
    /// this process bit for bit. Same scene and overrides as the recording.
    #[arg(long, value_name = "RUN.mcap", conflicts_with = "run_id")]
    pub replay_peer: Option<PathBuf>,
}

/// The link settings of a coupled scene: `Ok(None)` for an uncoupled one.
/// `particles`: the grains per message (0 for the LBM, which takes the
/// DEM's count at the handshake). Exit status 2 when a coupled scene has no
/// `--run-id` or an uncoupled one has one.
pub fn link_config(
    solver: &str,
    args: &RunArgs,
    scene: &schemas::Scene,
    stop: &Arc<AtomicBool>,
    particles: usize,
) -> Result<Option<crate::link::LinkConfig>, std::process::ExitCode> {
    let bad = || std::process::ExitCode::from(schemas::EXIT_BAD_SCENE as u8);
    let coupled = scene.method() == schemas::Method::DemLbm;
    if args.replay_peer.is_some() {
        if !coupled {
            tell!(
                "{solver}: --replay-peer is for coupled scenes (grains and fluids); this scene is {}",
                scene.method().name()
            );
            return Err(bad());
        }
        return Ok(None);
    }
    match (&args.run_id, coupled) {
        (None, false) => Ok(None),
        (Some(_), false) => {
            tell!(
                "{solver}: --run-id is for scenes with grains and fluids (coupled); this scene is {}",
                scene.method().name()
            );
            Err(bad())
        }
        (None, true) => {
            tell!("{solver}: the scene couples grains and fluids: run it with `coupler run`, start dem_proc and lbm_proc with the same --run-id ID, or replay a recorded peer with --replay-peer RUN.mcap");
            Err(bad())
        }
        (Some(id), true) => {
            if let Err(e) = crate::link::validate_run_id(id) {
                tell!("{solver}: {e}");
                return Err(bad());
            }
            if !(args.connect_timeout.is_finite() && args.connect_timeout > 0.0) {
                tell!("{solver}: --connect-timeout must be a positive number of seconds, got {}", args.connect_timeout);
                return Err(bad());
            }
            let mut cfg = crate::link::LinkConfig::new(id.clone(), scene_hash(scene), particles);
            cfg.connect_timeout = std::time::Duration::from_secs_f64(args.connect_timeout);
            cfg.stop = Some(Arc::clone(stop));
            Ok(Some(cfg))
        }
    }
}

/// Hash of the scene as run (after overrides): both coupled processes must agree on it.
pub fn scene_hash(scene: &schemas::Scene) -> u64 {
    schemas::stable_hash(scene.to_toml().as_bytes())
}

/// Options of a run that are not part of the physics.
#[derive(Debug, Clone)]
pub struct RunOptions {
    pub out_dir: PathBuf,
    /// Record to MCAP (off only for benchmarks measuring the recording cost).
    pub record: bool,
    /// The checkpoint to continue from (`--resume`).
    pub resume: Option<PathBuf>,
}

/// Loads and checks the scene a solver was given; `unfit` names why this
/// solver has nothing to do with it. Exit status 2 with the reason otherwise.
pub fn load_scene(
    solver: &str,
    path: &std::path::Path,
    set: &[String],
    unfit: impl Fn(&schemas::Scene) -> Option<String>,
) -> Result<schemas::Scene, std::process::ExitCode> {
    let bad = || std::process::ExitCode::from(schemas::EXIT_BAD_SCENE as u8);
    let scene = schemas::Scene::load(path, set).map_err(|e| {
        tell!("{solver}: invalid scene {}:\n{e}", path.display());
        bad()
    })?;
    if let Some(why) = unfit(&scene) {
        tell!("{solver}: {why}");
        return Err(bad());
    }
    Ok(scene)
}

/// The start of every solver's `run`: the stop flag first (so no signal is
/// lost), parent death when supervised, the scene, the worker threads.
pub fn start_run(
    solver: &str,
    args: &RunArgs,
    unfit: impl Fn(&schemas::Scene) -> Option<String>,
) -> Result<(Arc<AtomicBool>, schemas::Scene), std::process::ExitCode> {
    let stop = stop_flag().map_err(|e| {
        tell!("{solver}: cannot install signal handler: {e}");
        std::process::ExitCode::FAILURE
    })?;
    if args.supervised {
        die_with_parent();
    }
    return_large_buffers_on_free();
    let scene = load_scene(solver, &args.scene, &args.set, unfit)?;
    set_global_threads(solver, args.threads)?;
    Ok((stop, scene))
}

/// Sizes rayon's global pool (default: all cores) with the calling thread as
/// one of its workers. Call it from the thread that steps the solver: its
/// parallel loops then start in place, where from a thread outside the pool
/// every loop hands its work over and blocks until a worker wakes (a futex
/// wake-up per stage, 13 % of a one-thread DEM step: docs/BENCHMARKS.md).
///
/// Also checks `SGF_ISA` (the kernels' instruction set, [`crate::isa`]) so
/// that a bad value stops every binary before it starts work.
pub fn set_global_threads(solver: &str, threads: Option<usize>) -> Result<(), std::process::ExitCode> {
    if let Err(e) = crate::isa::Isa::detected() {
        tell!("{solver}: {e}");
        return Err(std::process::ExitCode::from(schemas::EXIT_BAD_SCENE as u8));
    }
    let mut builder = rayon::ThreadPoolBuilder::new().use_current_thread();
    if let Some(n) = threads {
        builder = builder.num_threads(n.max(1));
    }
    builder.build_global().map_err(|e| {
        tell!(
            "{solver}: cannot set {} threads: {e}",
            threads.map_or("the default number of".to_string(), |n| n.to_string())
        );
        std::process::ExitCode::FAILURE
    })
}

/// The end of a run that wrote its summary: the `done` progress event and
/// the exit status (130 after an interruption).
pub fn finish_run(progress_json: bool, status: schemas::summary::RunStatus) -> std::process::ExitCode {
    if progress_json {
        say!("{{\"event\":\"done\",\"status\":\"{status}\"}}");
    }
    if status == schemas::summary::RunStatus::Interrupted {
        std::process::ExitCode::from(schemas::EXIT_INTERRUPTED as u8)
    } else {
        std::process::ExitCode::SUCCESS
    }
}

/// How long a kept-awake worker goes on looking for work after its last
/// job before it gives its core back: longer than the serial stretches
/// inside a step (the MPM's pressure solve, ~0.1 ms), shorter than a
/// coupled process's wait for its peer (an exchange's 57 DEM steps take
/// ~50 ms, an LBM step ~30 ms: docs/BENCHMARKS.md). Even so, coupled
/// processes that kept their workers awake lost 5-6 %, so the run driver
/// keeps them awake only in a run alone.
pub const AWAKE_IDLE_LIMIT: std::time::Duration = std::time::Duration::from_micros(500);

/// Keeps the other workers of the calling thread's pool awake while a
/// stepping loop runs: each spins, taking the parallel loops' chunks the
/// moment they are pushed, instead of falling asleep between loops and
/// being woken by a futex (and, on a virtual machine, by the hypervisor)
/// at the next one. Call [`AwakeWorkers::keep_awake`] at each step.
///
/// Why: rayon parks an idle worker after ~32 rounds of looking for work,
/// a few tens of µs. A step of many short parallel loops with serial work
/// between them then pays a wake-up per loop: the MPM made 4.7 context
/// switches a step on two threads (docs/BENCHMARKS.md, sessions 40–41).
///
/// A waiter burns its core while it spins, so it stops once it has found
/// no work for [`AWAKE_IDLE_LIMIT`] (a run writing its recording) and the
/// next `keep_awake` starts it again. The run driver does not use it in a
/// coupled process: there the peer steps on the core a waiter would spin
/// on, and it cost 5-6 % (docs/BENCHMARKS.md, session 41). Nothing is kept awake with one thread, from outside a pool,
/// or where the pool has more threads than the machine has cores (a
/// spinning waiter would take the core the stepping thread needs).
///
/// A waiter never holds up a step. `keep_awake` runs between steps, when
/// the pool has no work pending, so the waiters are the oldest jobs in the
/// stepping thread's queue and thieves take them before any of the step's
/// own jobs. A waiter that runs on the stepping thread itself (taken back
/// from its queue while it waits in a join), or inside another waiter (one
/// spinning worker taking the next waiter as pending work, with three or
/// more threads), returns at once. Dropping the keeper stops the waiters.
/// It stays on the thread that made it (`!Send`): its waiters are spawned
/// into that thread's pool.
pub struct AwakeWorkers {
    shared: std::sync::Arc<AwakeShared>,
    caller: usize,
    waiters: usize,
    on_its_thread: std::marker::PhantomData<*const ()>,
}

#[derive(Default)]
struct AwakeShared {
    live: std::sync::atomic::AtomicUsize,
    stop: std::sync::atomic::AtomicBool,
    /// Waiters that started spinning, over the keeper's life.
    started: std::sync::atomic::AtomicUsize,
}

thread_local! {
    /// Whether this thread is running a waiter (a waiter inside it returns at once).
    static IN_WAITER: std::cell::Cell<bool> = const { std::cell::Cell::new(false) };
}

impl AwakeWorkers {
    /// A keeper for the pool of the calling thread (none kept awake where
    /// the rules above say so).
    pub fn new() -> Self {
        let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
        let threads = rayon::current_num_threads();
        let (caller, waiters) = match rayon::current_thread_index() {
            Some(caller) if threads <= cores => (caller, threads - 1),
            _ => (0, 0),
        };
        Self { shared: Default::default(), caller, waiters, on_its_thread: std::marker::PhantomData }
    }

    /// How many workers this keeper keeps awake (0: none).
    pub fn waiters(&self) -> usize {
        self.waiters
    }

    /// How many times a waiter has started spinning so far.
    pub fn waiters_started(&self) -> usize {
        self.shared.started.load(std::sync::atomic::Ordering::Acquire)
    }

    /// Starts again any waiter that has stopped. One atomic load when all
    /// are awake.
    pub fn keep_awake(&self) {
        use std::sync::atomic::Ordering;
        while self.shared.live.load(Ordering::Acquire) < self.waiters {
            self.shared.live.fetch_add(1, Ordering::AcqRel);
            let (shared, caller) = (self.shared.clone(), self.caller);
            rayon::spawn(move || {
                if rayon::current_thread_index() != Some(caller) && !IN_WAITER.get() {
                    IN_WAITER.set(true);
                    shared.started.fetch_add(1, Ordering::AcqRel);
                    shared.wait_for_work();
                    IN_WAITER.set(false);
                }
                shared.live.fetch_sub(1, Ordering::AcqRel);
            });
        }
    }
}

impl Default for AwakeWorkers {
    fn default() -> Self {
        Self::new()
    }
}

impl Drop for AwakeWorkers {
    fn drop(&mut self) {
        self.shared.stop.store(true, std::sync::atomic::Ordering::Release);
    }
}

impl AwakeShared {
    /// Runs the pool's pending jobs as they come until stopped or idle for
    /// [`AWAKE_IDLE_LIMIT`].
    fn wait_for_work(&self) {
        use std::sync::atomic::Ordering;
        let mut idle_since: Option<std::time::Instant> = None;
        let mut rounds = 0u32;
        while !self.stop.load(Ordering::Acquire) {
            if rayon::yield_now() == Some(rayon::Yield::Executed) {
                idle_since = None;
                continue;
            }
            std::hint::spin_loop();
            rounds = rounds.wrapping_add(1);
            // The clock only every 64 idle rounds: it costs more than a round.
            if rounds.is_multiple_of(64)
                && idle_since.get_or_insert_with(std::time::Instant::now).elapsed() > AWAKE_IDLE_LIMIT
            {
                return;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::{AwakeWorkers, AWAKE_IDLE_LIMIT};
    use rayon::prelude::*;

    fn pool(threads: usize) -> rayon::ThreadPool {
        rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("a pool")
    }

    /// Σ i² for i < n, exactly: n(n−1)(2n−1)/6.
    fn squares(n: u64) -> u64 {
        n * (n - 1) * (2 * n - 1) / 6
    }

    /// Many short parallel loops with serial work between them, the
    /// pattern the waiters are kept awake for: each loop's exact sum.
    fn loops(awake: &AwakeWorkers) -> Vec<u64> {
        (1..200u64)
            .map(|n| {
                awake.keep_awake();
                (0..(n * 50) as u32).into_par_iter().with_min_len(16).map(|i| u64::from(i).pow(2)).sum::<u64>()
            })
            .collect()
    }

    #[test]
    fn parallel_loops_kept_awake_give_the_exact_sums() {
        let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
        for threads in [1, 2, 3] {
            let (sums, waiters) = pool(threads).install(|| {
                let awake = AwakeWorkers::new();
                (loops(&awake), awake.waiters())
            });
            assert_eq!(waiters, if threads <= cores { threads - 1 } else { 0 }, "{threads} threads");
            for (k, s) in sums.iter().enumerate() {
                assert_eq!(*s, squares((k as u64 + 1) * 50), "{threads} threads, loop {k}");
            }
        }
    }

    /// Polls (for a machine busy with other tests) until no waiter is live.
    fn until_none_live(awake: &AwakeWorkers) {
        let given_back = (0..4000).any(|_| {
            std::thread::sleep(AWAKE_IDLE_LIMIT / 5);
            awake.shared.live.load(std::sync::atomic::Ordering::Acquire) == 0
        });
        assert!(given_back, "the waiters stopped");
    }

    #[test]
    fn idle_waiters_give_their_cores_back_after_the_limit_and_start_again() {
        pool(2).install(|| {
            let awake = AwakeWorkers::new();
            if awake.waiters() == 0 {
                return; // a one-core machine keeps nothing awake
            }
            let since = std::time::Instant::now();
            awake.keep_awake();
            while awake.waiters_started() == 0 {
                std::hint::spin_loop();
            }
            // A pause past the limit, as a coupled process waiting for its
            // peer: the waiter, started after `since`, spins at least the
            // limit, then stops.
            until_none_live(&awake);
            assert!(since.elapsed() >= AWAKE_IDLE_LIMIT, "a waiter spins for the limit before it stops");
            let sums = loops(&awake);
            assert_eq!(sums[198], squares(199 * 50));
            let restarted = std::time::Instant::now();
            while awake.waiters_started() < 2 && restarted.elapsed() < std::time::Duration::from_secs(5) {
                awake.keep_awake();
                std::thread::sleep(AWAKE_IDLE_LIMIT / 5);
            }
            assert!(awake.waiters_started() >= 2, "the next step started it again");
        });
    }

    #[test]
    fn dropping_the_keeper_stops_its_waiters() {
        pool(2).install(|| {
            let awake = AwakeWorkers::new();
            if awake.waiters() == 0 {
                return;
            }
            let shared = awake.shared.clone();
            awake.keep_awake();
            while awake.waiters_started() == 0 {
                std::hint::spin_loop();
            }
            drop(awake);
            let stopped = (0..4000).any(|_| {
                std::thread::sleep(AWAKE_IDLE_LIMIT / 5);
                shared.live.load(std::sync::atomic::Ordering::Acquire) == 0
            });
            assert!(stopped && shared.stop.load(std::sync::atomic::Ordering::Acquire));
        });
    }

    #[test]
    fn outside_a_pool_nothing_is_kept_awake() {
        let waiters = std::thread::spawn(|| AwakeWorkers::new().waiters()).join().expect("runs");
        assert_eq!(waiters, 0);
    }
}
