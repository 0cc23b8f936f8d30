//! Starting, watching and stopping solver processes (tokio: child processes,
//! signals, timers), then assembling `run.mcap` and `summary.json`.
//!
//! Children run with `--supervised` (they get SIGTERM if the coupler dies) and
//! `--progress-json` (one JSON object per stdout line). Ctrl-C or SIGTERM is
//! forwarded as SIGINT: the child stops at a step boundary and finalises its
//! recording; a second Ctrl-C kills it.

use std::path::{Path, PathBuf};
use std::process::{ExitCode, Stdio};
use std::time::{Duration, Instant};

use indicatif::{ProgressBar, ProgressStyle};
use tokio::io::{AsyncBufReadExt, BufReader};
use tokio::process::Command;
use tokio::signal::unix::{signal, SignalKind};

use schemas::scene::Schedule;
use schemas::summary::{ExchangeSummary, RunExchange, RunStatus, RunSummary};
use schemas::{Method, Scene, EXIT_BAD_SCENE, EXIT_INTERRUPTED};

/// The directory holding this executable; solver binaries are its siblings.
fn sibling_binary(name: &str) -> Result<PathBuf, String> {
    let exe = std::env::current_exe().map_err(|e| format!("cannot locate the coupler executable: {e}"))?;
    let path = exe.with_file_name(name);
    if path.exists() {
        Ok(path)
    } else {
        Err(format!(
            "{} not found next to {}; build it with `cargo build --release -p {name}`",
            path.display(),
            exe.display()
        ))
    }
}

/// What the terminal shows while the processes run: a progress bar on a
/// terminal; plain lines otherwise (`--quiet`, or stderr going to a file or
/// a pipe, where a bar would draw nothing and, worse, swallow the
/// processes' own messages with it).
struct Bar {
    bar: Option<ProgressBar>,
    phase: String,
    /// (simulated time, wall time) of the previous progress event.
    last: (f64, f64),
    /// Plain lines: wall time of the last progress line printed.
    last_line: Option<f64>,
}

/// Plain progress lines on a terminal under `--quiet`, at most this often (s).
const PLAIN_PROGRESS_EVERY: f64 = 0.5;
/// Plain progress lines into a file or pipe (a log), at most this often (s).
const LOGGED_PROGRESS_EVERY: f64 = 10.0;

impl Bar {
    fn new(quiet: bool) -> Self {
        use std::io::IsTerminal as _;
        let bar = (!quiet && std::io::stderr().is_terminal()).then(|| {
            let b = ProgressBar::new(1000);
            b.set_style(
                ProgressStyle::with_template("{prefix:>11} [{bar:30}] {msg} | elapsed {elapsed_precise}, ETA {eta}")
                    .expect("valid template")
                    .progress_chars("=> "),
            );
            b.enable_steady_tick(Duration::from_millis(500));
            b
        });
        Self { bar, phase: String::new(), last: (0.0, 0.0), last_line: None }
    }

    /// A process's line, or one of the coupler's own: always printed.
    fn println(&self, line: &str) {
        match &self.bar {
            Some(b) if !b.is_hidden() => b.println(line),
            _ => eprintln!("{line}"),
        }
    }

    fn progress(&mut self, ev: &serde_json::Value) {
        let phase = ev["phase"].as_str().unwrap_or("").to_string();
        let t = ev["t"].as_f64().unwrap_or(0.0);
        let t_end = ev["t_end"].as_f64().unwrap_or(1.0).max(1e-12);
        let wall = ev["wall"].as_f64().unwrap_or(0.0);
        let new_phase = phase != self.phase;
        let (t0, w0) = if new_phase { (t, wall) } else { self.last };
        self.last = (t, wall);
        let rate = if wall > w0 { (t - t0) / (wall - w0) } else { 0.0 };
        let msg = format!("t = {t:.4} / {t_end:.3} s, {:.1} ms simulated per wall second", rate * 1e3);
        match &self.bar {
            Some(b) => {
                if new_phase {
                    b.reset();
                    b.set_prefix(phase.clone());
                }
                b.set_position(((t / t_end) * 1000.0).clamp(0.0, 1000.0) as u64);
                b.set_message(msg);
            }
            None => {
                use std::io::IsTerminal as _;
                let every = if std::io::stderr().is_terminal() { PLAIN_PROGRESS_EVERY } else { LOGGED_PROGRESS_EVERY };
                let due = new_phase || t >= t_end || self.last_line.is_none_or(|w| wall - w >= every);
                if due {
                    eprintln!("{phase}: {msg}, {wall:.1} s wall");
                    self.last_line = Some(wall);
                }
            }
        }
        self.phase = phase;
    }

    fn finish(&self) {
        if let Some(b) = &self.bar {
            b.finish_and_clear();
        }
    }
}

/// Lines of a child's pipe, decoded lossily: a stray non-UTF-8 byte must not
/// stop the draining (a child blocked on a full pipe would hang the run).
struct LossyLines<R> {
    reader: BufReader<R>,
    buf: Vec<u8>,
}

impl<R: tokio::io::AsyncRead + Unpin> LossyLines<R> {
    fn new(pipe: R) -> Self {
        Self { reader: BufReader::new(pipe), buf: Vec::new() }
    }

    /// The next line without its newline; None at end of file or on a read
    /// error. Cancel-safe: a partly read line stays in the buffer.
    async fn next_line(&mut self) -> Option<String> {
        match self.reader.read_until(b'\n', &mut self.buf).await {
            Ok(0) | Err(_) if self.buf.is_empty() => None,
            _ => {
                let line = String::from_utf8_lossy(self.buf.strip_suffix(b"\n").unwrap_or(&self.buf)).into_owned();
                self.buf.clear();
                Some(line)
            }
        }
    }
}

/// The solver processes a method runs: binary name and the short name of
/// its outputs (`<short>.mcap`, `<short>_summary.json`). The first one's
/// progress drives the bar; in a coupled run the DEM leads time.
fn solvers_for(method: Method) -> &'static [(&'static str, &'static str)] {
    match method {
        Method::DemDry => &[("dem_proc", "dem")],
        Method::LbmFluid => &[("lbm_proc", "lbm")],
        Method::DemLbm => &[("dem_proc", "dem"), ("lbm_proc", "lbm")],
        Method::Mpm => &[("mpm_proc", "mpm")],
    }
}

/// What a child's watcher task reports.
enum Event {
    /// A progress event of process `k`.
    Progress(usize, serde_json::Value),
    /// A line process `k` wrote to stderr.
    Line(usize, String),
    Exited(usize, std::io::Result<std::process::ExitStatus>),
}

/// How long the other process of a coupled run may take to finish after the
/// first one ended normally (it records its last frame and state).
const PEER_FINISH_GRACE: Duration = Duration::from_secs(300);
/// How long the other process may take to stop after the first one failed,
/// once it steps (it records its last frame and state).
const PEER_STOP_GRACE: Duration = Duration::from_secs(10);
/// The same for a process still setting up (it has reported no progress:
/// building its lattice): it has recorded nothing yet and may not look at
/// its stop flag until its set-up ends, seconds later, so it gets a moment
/// and is then killed.
const SETUP_STOP_GRACE: Duration = Duration::from_millis(500);

/// A run id for iceoryx2 service names: unique on this machine, short, [A-Za-z0-9_-].
fn new_run_id(scene: &Scene) -> String {
    let nanos = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map(|d| d.as_nanos()).unwrap_or(0);
    let name: String = scene.spec.scene.name.chars().take(16).collect();
    format!("{name}-{}-{:x}", std::process::id(), (nanos % (1 << 32)) as u64)
}

fn describe(status: &std::process::ExitStatus) -> String {
    use std::os::unix::process::ExitStatusExt;
    match (status.code(), status.signal()) {
        (Some(c), _) => format!("exit status {c}"),
        (None, Some(9)) => "killed by signal 9 (SIGKILL)".into(),
        (None, Some(s)) => format!("killed by signal {s}"),
        _ => "unknown status".into(),
    }
}

/// Runs the scene's solver processes under supervision: output prepared,
/// the processes started, their progress and messages shown, signals
/// forwarded, a failure stopping the others, then the summary merged, the
/// recording collected and the outcome reported as an exit status.
pub async fn run(scene: Scene, out: PathBuf, threads: Option<usize>, quiet: bool, resume: bool) -> ExitCode {
    let started = Instant::now();
    let method = scene.method();
    let solvers = solvers_for(method);
    let names: Vec<&str> = solvers.iter().map(|(s, _)| *s).collect();
    let coupled = solvers.len() > 1;
    let prepared = (|| {
        let bins = solvers.iter().map(|(solver, _)| sibling_binary(solver)).collect::<Result<Vec<_>, _>>()?;
        let resume = if resume { Some(find_checkpoints(&out, &names, &scene)?) } else { None };
        let (scene_toml, scene_file, carried) = prepare_output(&out, solvers, &scene, resume.is_some())?;
        Ok::<_, String>((bins, scene_toml, scene_file, resume.map(|r| Resume { carried, ..r })))
    })();
    let (bins, scene_toml, scene_file, resume) = match prepared {
        Ok(p) => p,
        Err(e) => {
            eprintln!("coupler: {e}");
            return ExitCode::FAILURE;
        }
    };
    let run_id = new_run_id(&scene);
    // Concurrent: both work at once, one core each; sequential: they take turns with all cores.
    let threads = threads.or((coupled && scene.spec.coupling.schedule == Schedule::Concurrent).then_some(1));
    let (tx, rx) = tokio::sync::mpsc::unbounded_channel();
    let launch = Launch {
        scene_file: &scene_file,
        out: &out,
        threads,
        run_id: coupled.then_some(run_id.as_str()),
        checkpoints: resume.as_ref().map(|r| r.checkpoints.as_slice()),
    };
    let pids = match spawn_solvers(&bins, &launch, tx) {
        Ok(pids) => pids,
        Err(e) => {
            eprintln!("coupler: {e}");
            return ExitCode::FAILURE;
        }
    };
    eprintln!(
        "coupler: {} {} ({}) with {}{}, output in {}",
        if resume.is_some() { "resuming" } else { "running" },
        scene.spec.scene.name,
        method.name(),
        names.join(" + "),
        if coupled {
            format!(" (run id {run_id}, {} schedule)", scene.spec.coupling.schedule.name())
        } else {
            String::new()
        },
        out.display()
    );
    let Some(ended) = supervise(rx, &pids, &names, quiet).await else {
        return ExitCode::FAILURE;
    };
    if coupled {
        let cleaned = runtime::link::cleanup_stale(Some(&run_id));
        if cleaned > 0 {
            eprintln!("coupler: removed the shared memory of {cleaned} dead process(es) of run {run_id}");
        }
    }
    let interrupted = ended.interrupts > 0;
    let failed = ended.first_failure.is_some();
    let summary = finish_summary(&out, solvers, started.elapsed().as_secs_f64(), interrupted, failed);
    let recording = collect_recording(&out, solvers, &scene_toml, summary.as_ref(), resume.as_ref());
    if !interrupted && !failed && summary.is_some() {
        // A finished run has nothing to resume: its checkpoints only take space.
        let _ = std::fs::remove_dir_all(runtime::checkpoint::folder(&out));
    }
    conclude(&ended, &names, coupled, summary.as_ref(), &recording, &out)
}

/// Where a resumed run continues from.
struct Resume {
    /// Each process's checkpoint, in the order of its solvers.
    checkpoints: Vec<PathBuf>,
    /// Simulated time of the checkpoint, ns: the earlier recording is kept up to it.
    cut_ns: u64,
    /// The earlier recordings carried into the new `run.mcap`.
    carried: Vec<PathBuf>,
}

/// The newest checkpoint every process of the run in `out` wrote at the
/// same moment, or why there is none.
fn find_checkpoints(out: &Path, names: &[&str], scene: &Scene) -> Result<Resume, String> {
    let dir = runtime::checkpoint::folder(out);
    let (found, skipped) = runtime::checkpoint::latest_common(&dir, names, scene);
    for why in &skipped {
        eprintln!("coupler: passed over {why}");
    }
    let Some(found) = found else {
        return Err(format!(
            "no checkpoint in {} that {} wrote at the same moment: the scene must set output.checkpoint_interval and the run must have reached its first one. Start it afresh with `coupler run {} --out {}`",
            dir.display(),
            names.join(" and "),
            out.join("scene.toml").display(),
            out.display()
        ));
    };
    let time = found.iter().map(|(_, f)| f.driver.time).fold(0.0, f64::max);
    eprintln!(
        "coupler: continuing from t = {time:.5} s ({})",
        found.iter().map(|(p, _)| p.display().to_string()).collect::<Vec<_>>().join(", ")
    );
    Ok(Resume {
        checkpoints: found.into_iter().map(|(p, _)| p).collect(),
        cut_ns: (time * 1e9).round() as u64,
        carried: Vec::new(),
    })
}

/// Creates `out`, removes a previous run's results from it (a reused
/// directory must not show them as this run's) and writes the scene as
/// resolved. Returns the scene's TOML and its file. When `resuming`, the
/// earlier recordings are kept aside instead (`previous.mcap`, and
/// `previous-<process>.mcap` for files a killed coupler did not merge) and
/// returned, to be carried into the new one.
fn prepare_output(
    out: &Path,
    solvers: &[(&str, &str)],
    scene: &Scene,
    resuming: bool,
) -> Result<(String, PathBuf, Vec<PathBuf>), String> {
    std::fs::create_dir_all(out).map_err(|e| format!("cannot create output directory {}: {e}", out.display()))?;
    let mut carried = Vec::new();
    if resuming {
        let mut aside = vec![("run.mcap".to_string(), "previous.mcap".to_string())];
        for (_, short) in solvers {
            aside.push((format!("{short}.mcap"), format!("previous-{short}.mcap")));
        }
        for (from, to) in aside {
            let (from, to) = (out.join(from), out.join(to));
            if from.exists() {
                std::fs::rename(&from, &to)
                    .map_err(|e| format!("cannot move {} aside to {}: {e}", from.display(), to.display()))?;
            }
            if to.exists() {
                carried.push(to);
            }
        }
    }
    if !resuming {
        // Another run's checkpoints must not be resumed as this one's.
        let checkpoints = runtime::checkpoint::folder(out);
        if checkpoints.exists() {
            std::fs::remove_dir_all(&checkpoints)
                .map_err(|e| format!("cannot remove the previous run's {}: {e}", checkpoints.display()))?;
        }
    }
    let mut stale = vec!["run.mcap".to_string(), "summary.json".into()];
    for (_, short) in solvers {
        stale.push(format!("{short}.mcap"));
        stale.push(format!("{short}_summary.json"));
    }
    for name in stale {
        let path = out.join(name);
        if path.exists() {
            std::fs::remove_file(&path)
                .map_err(|e| format!("cannot remove the previous run's {}: {e}", path.display()))?;
        }
    }
    let scene_toml = scene.to_toml();
    let scene_file = out.join("scene.toml");
    std::fs::write(&scene_file, &scene_toml)
        .map_err(|e| format!("cannot write {}: {e} (is the disk full?)", scene_file.display()))?;
    Ok((scene_toml, scene_file, carried))
}

/// How each solver process is started.
struct Launch<'a> {
    /// The resolved scene (relative explicit-sphere files resolve against
    /// the original scene's directory; the resolved scene embeds them).
    scene_file: &'a Path,
    out: &'a Path,
    threads: Option<usize>,
    /// Coupled runs: the link's run id.
    run_id: Option<&'a str>,
    /// A resumed run: each process's checkpoint.
    checkpoints: Option<&'a [PathBuf]>,
}

/// Starts one process per binary, each watched by a task that forwards its
/// progress, its stderr lines and its exit.
/// Returns their pids; if one cannot start, those started are killed.
fn spawn_solvers(
    bins: &[PathBuf],
    launch: &Launch<'_>,
    tx: tokio::sync::mpsc::UnboundedSender<Event>,
) -> Result<Vec<Option<u32>>, String> {
    let mut pids = Vec::new();
    for (k, bin) in bins.iter().enumerate() {
        let mut cmd = Command::new(bin);
        cmd.arg("run").arg(launch.scene_file).arg("--out").arg(launch.out);
        cmd.arg("--progress-json").arg("--supervised");
        if let Some(n) = launch.threads {
            cmd.arg("--threads").arg(n.to_string());
        }
        if let Some(id) = launch.run_id {
            cmd.arg("--run-id").arg(id);
        }
        if let Some(c) = launch.checkpoints {
            cmd.arg("--resume").arg(&c[k]);
        }
        cmd.stdout(Stdio::piped()).stderr(Stdio::piped()).stdin(Stdio::null()).kill_on_drop(true);
        let child = match cmd.spawn() {
            Ok(c) => c,
            Err(e) => {
                for &pid in &pids {
                    kill_pid(pid, libc::SIGKILL);
                }
                return Err(format!("cannot start {}: {e}", bin.display()));
            }
        };
        pids.push(child.id());
        tokio::spawn(watch_child(child, k, tx.clone()));
    }
    Ok(pids)
}

/// Forwards process `k`'s progress events and stderr lines to the
/// supervisor, then its exit.
async fn watch_child(mut child: tokio::process::Child, k: usize, tx: tokio::sync::mpsc::UnboundedSender<Event>) {
    let mut stdout = LossyLines::new(child.stdout.take().expect("piped"));
    let mut stderr = LossyLines::new(child.stderr.take().expect("piped"));
    let (mut out_open, mut err_open) = (true, true);
    let status = loop {
        tokio::select! {
            line = stdout.next_line(), if out_open => match line {
                Some(l) => {
                    if let Ok(ev) = serde_json::from_str::<serde_json::Value>(&l) {
                        if ev["event"] == "progress" { let _ = tx.send(Event::Progress(k, ev)); }
                    }
                }
                None => out_open = false,
            },
            line = stderr.next_line(), if err_open => match line {
                Some(l) => { let _ = tx.send(Event::Line(k, l)); }
                None => err_open = false,
            },
            st = child.wait() => break st,
        }
    };
    // Drain what the child wrote just before exiting.
    while err_open {
        match tokio::time::timeout(Duration::from_millis(200), stderr.next_line()).await {
            Ok(Some(l)) => {
                let _ = tx.send(Event::Line(k, l));
            }
            _ => err_open = false,
        }
    }
    let _ = tx.send(Event::Exited(k, status));
}

/// How the processes ended.
struct Ended {
    statuses: Vec<Option<std::process::ExitStatus>>,
    /// Whether each process has reported progress: it is in a phase that
    /// polls its stop flag (deposition, gravity phase, the run loop, which
    /// reports as it begins). One that has not is still setting up.
    reporting: Vec<bool>,
    /// When each running process is killed if it has not exited by then.
    deadlines: Vec<Option<tokio::time::Instant>>,
    /// Killed by the coupler during its set-up after a Ctrl-C: its end is
    /// the interruption asked for, not a failure.
    stopped_in_setup: Vec<bool>,
    /// Each process's last error line (`<name>: error: …`, or any line of
    /// its naming an error), repeated when the coupler reports the failure.
    last_error: Vec<Option<String>>,
    /// The first process that ended abnormally, and how.
    first_failure: Option<(usize, std::process::ExitStatus)>,
    /// SIGINT/SIGTERM received.
    interrupts: u32,
}

impl Ended {
    /// Process `j` must be gone by `deadline` (an earlier one holds).
    fn kill_by(&mut self, j: usize, deadline: tokio::time::Instant) {
        let d = &mut self.deadlines[j];
        *d = Some(d.map_or(deadline, |t| t.min(deadline)));
    }

    /// The first deadline of a process still running.
    fn next_deadline(&self) -> Option<tokio::time::Instant> {
        (0..self.statuses.len()).filter(|&j| self.statuses[j].is_none()).filter_map(|j| self.deadlines[j]).min()
    }

    /// Keeps `line` of process `k` (`name`) when it reports an error.
    fn note_line(&mut self, k: usize, name: &str, line: String) {
        let own = line.strip_prefix(name).and_then(|rest| rest.strip_prefix(": "));
        if let Some(text) = own.filter(|t| t.contains("error") || t.contains("unstable") || t.contains("fix:")) {
            self.last_error[k] = Some(text.strip_prefix("error: ").unwrap_or(text).to_string());
        }
    }
}

/// Until every process has exited: shows progress (the first process's
/// drives the bar) and lines, forwards signals, and when one process ends
/// lets the others finish (normal end) or stops them (failure: 10 s to
/// record their last state once they report progress, 0.5 s in set-up),
/// killing any that outlive their grace. None when
/// the signal handlers cannot be installed.
async fn supervise(
    mut rx: tokio::sync::mpsc::UnboundedReceiver<Event>,
    pids: &[Option<u32>],
    names: &[&str],
    quiet: bool,
) -> Option<Ended> {
    let (mut sigint, mut sigterm) = match (signal(SignalKind::interrupt()), signal(SignalKind::terminate())) {
        (Ok(a), Ok(b)) => (a, b),
        _ => {
            eprintln!("coupler: cannot install signal handlers");
            return None;
        }
    };
    let mut bar = Bar::new(quiet);
    let mut ended = Ended {
        statuses: vec![None; names.len()],
        reporting: vec![false; names.len()],
        deadlines: vec![None; names.len()],
        stopped_in_setup: vec![false; names.len()],
        last_error: vec![None; names.len()],
        first_failure: None,
        interrupts: 0,
    };
    let far = tokio::time::Instant::now() + Duration::from_secs(86400 * 365);
    loop {
        tokio::select! {
            ev = rx.recv() => match ev {
                Some(Event::Progress(k, ev)) => {
                    ended.reporting[k] = true;
                    if k == 0 {
                        bar.progress(&ev);
                    }
                }
                Some(Event::Line(k, l)) => {
                    bar.println(&l);
                    ended.note_line(k, names[k], l);
                }
                Some(Event::Exited(k, st)) => {
                    let st = match st {
                        Ok(s) => s,
                        Err(e) => {
                            bar.println(&format!("coupler: lost track of {}: {e}", names[k]));
                            std::os::unix::process::ExitStatusExt::from_raw(1 << 8)
                        }
                    };
                    process_exited(&mut ended, k, st, pids, names, &bar);
                }
                None => break,
            },
            _ = sigint.recv() => interrupted(&mut ended, pids, names, &bar),
            _ = sigterm.recv() => interrupted(&mut ended, pids, names, &bar),
            _ = tokio::time::sleep_until(ended.next_deadline().unwrap_or(far)), if ended.next_deadline().is_some() => {
                let now = tokio::time::Instant::now();
                for j in 0..names.len() {
                    if ended.statuses[j].is_none() && ended.deadlines[j].is_some_and(|d| d <= now) {
                        if !ended.stopped_in_setup[j] {
                            bar.println(&format!("coupler: {} did not stop in time; killing it", names[j]));
                        }
                        kill_pid(pids[j], libc::SIGKILL);
                        ended.deadlines[j] = None;
                    }
                }
            }
        }
    }
    bar.finish();
    Some(ended)
}

/// Process `k` exited with `st`: notes it, and gives the others still
/// running their deadline: after a normal end time to finish; after a
/// failure a SIGINT and 10 s to record their last state if they report
/// progress, 0.5 s if they are still setting up.
fn process_exited(
    ended: &mut Ended,
    k: usize,
    st: std::process::ExitStatus,
    pids: &[Option<u32>],
    names: &[&str],
    bar: &Bar,
) {
    ended.statuses[k] = Some(st);
    let running: Vec<usize> = (0..names.len()).filter(|&j| ended.statuses[j].is_none()).collect();
    let asked = ended.interrupts > 0 && (st.code() == Some(EXIT_INTERRUPTED) || ended.stopped_in_setup[k]);
    let normal = st.success() || asked;
    if !normal && ended.first_failure.is_none() {
        ended.first_failure = Some((k, st));
    }
    let now = tokio::time::Instant::now();
    if normal {
        for &j in &running {
            ended.kill_by(j, now + PEER_FINISH_GRACE);
        }
        return;
    }
    if running.is_empty() {
        return;
    }
    let others: Vec<&str> = running.iter().map(|&j| names[j]).collect();
    bar.println(&format!("coupler: {} ended ({}); stopping {}", names[k], describe(&st), others.join(", ")));
    for &j in &running {
        kill_pid(pids[j], libc::SIGINT);
        ended.kill_by(j, now + if ended.reporting[j] { PEER_STOP_GRACE } else { SETUP_STOP_GRACE });
    }
}

/// Ctrl-C or SIGTERM: the first is forwarded as SIGINT, and a process still
/// setting up (no progress yet: it does not poll its stop flag there, and
/// has recorded nothing) is killed after 0.5 s; a second kills every process.
fn interrupted(ended: &mut Ended, pids: &[Option<u32>], names: &[&str], bar: &Bar) {
    ended.interrupts += 1;
    forward(pids, &ended.statuses, names, ended.interrupts, bar);
    if ended.interrupts == 1 {
        let now = tokio::time::Instant::now();
        let setting_up: Vec<usize> =
            (0..names.len()).filter(|&j| ended.statuses[j].is_none() && !ended.reporting[j]).collect();
        for j in setting_up {
            ended.stopped_in_setup[j] = true;
            ended.kill_by(j, now + SETUP_STOP_GRACE);
        }
    }
}

/// The exit status and the last words of a run.
fn conclude(
    ended: &Ended,
    names: &[&str],
    coupled: bool,
    summary: Option<&RunSummary>,
    recording: &Path,
    out: &Path,
) -> ExitCode {
    if let Some((k, st)) = ended.first_failure {
        if st.code() == Some(EXIT_BAD_SCENE) {
            eprintln!("coupler: {} rejected the scene (exit status 2); see the message above", names[k]);
            return ExitCode::from(EXIT_BAD_SCENE as u8);
        }
        if ended.interrupts > 1 {
            eprintln!("coupler: killed after a second interrupt; {} may lack its summary section (streaming MCAP readers still read it)", recording.display());
            return ExitCode::from(EXIT_INTERRUPTED as u8);
        }
        let others = if coupled { "; the other process was stopped" } else { "" };
        let why = match &ended.last_error[k] {
            Some(e) => format!(": {e}"),
            None if st.code().is_some() => "; see its message above".to_string(),
            None => String::new(),
        };
        eprintln!(
            "coupler: {} failed ({}){why}{others}. What was recorded so far is in {} (readable by streaming MCAP readers)",
            names[k],
            describe(&st),
            recording.display()
        );
        return ExitCode::FAILURE;
    }
    if ended.interrupts > 0 {
        if recording.exists() {
            eprintln!("coupler: run interrupted; the recording up to the interruption is in {}", recording.display());
        } else {
            eprintln!("coupler: run interrupted before the collapse started; nothing was recorded");
        }
        return ExitCode::from(EXIT_INTERRUPTED as u8);
    }
    match summary {
        Some(s) => {
            report(s, out);
            ExitCode::SUCCESS
        }
        None => {
            eprintln!("coupler: {} finished but left no readable summary in {}", names.join(" + "), out.display());
            ExitCode::FAILURE
        }
    }
}

fn kill_pid(pid: Option<u32>, sig: i32) {
    if let Some(pid) = pid {
        // SAFETY: kill(2) on a pid we spawned; a process already reaped may
        // in theory be reused, but our children are waited by their tasks
        // only after they exit, and we signal only those still running.
        unsafe {
            libc::kill(pid as i32, sig);
        }
    }
}

fn forward(pids: &[Option<u32>], statuses: &[Option<std::process::ExitStatus>], names: &[&str], count: u32, bar: &Bar) {
    let running = (0..pids.len()).filter(|&j| statuses[j].is_none());
    if count == 1 {
        bar.println("coupler: stopping at the next step boundary (press Ctrl-C again to kill)");
        for j in running {
            kill_pid(pids[j], libc::SIGINT);
        }
    } else {
        for j in running {
            bar.println(&format!("coupler: killing {}", names[j]));
            kill_pid(pids[j], libc::SIGKILL);
        }
    }
}

/// The run's recording: with one solver process its file renamed; with two,
/// both merged into one timeline (the inputs removed once merged). A
/// resumed run's recording is merged with what the earlier ones recorded up
/// to the checkpoint; if it recorded nothing, the earlier one stays as it was.
fn collect_recording(
    out: &Path,
    solvers: &[(&str, &str)],
    scene_toml: &str,
    summary: Option<&RunSummary>,
    resume: Option<&Resume>,
) -> PathBuf {
    let run = out.join("run.mcap");
    let inputs: Vec<PathBuf> = solvers.iter().map(|(_, short)| out.join(format!("{short}.mcap"))).collect();
    let carried = resume.map_or(&[][..], |r| r.carried.as_slice());
    if !inputs.iter().any(|p| p.exists()) {
        if let Some(first) = carried.first() {
            // Nothing new: the earlier recording is put back, uncut.
            if carried.len() == 1 && std::fs::rename(first, &run).is_ok() {
                return run;
            }
            return first.clone();
        }
        return run;
    }
    if inputs.len() == 1 && carried.is_empty() {
        if let Err(e) = std::fs::rename(&inputs[0], &run) {
            eprintln!("coupler: cannot move {} to {}: {e}", inputs[0].display(), run.display());
            return inputs[0].clone();
        }
        return run;
    }
    let json = summary.map(|s| serde_json::to_string_pretty(s).expect("serialises"));
    let cut = resume.map(|r| r.cut_ns);
    let sources: Vec<crate::merge::Source> = carried
        .iter()
        .map(|p| crate::merge::Source { path: p, until: cut })
        .chain(inputs.iter().map(|p| crate::merge::Source { path: p, until: None }))
        .collect();
    match crate::merge::merge_recordings(&sources, &run, scene_toml, json.as_deref()) {
        Ok(merged) => {
            for t in &merged.truncated {
                eprintln!("coupler: {t} ended early (its process stopped before finishing it); its complete chunks are in run.mcap");
            }
            for p in inputs.iter().chain(carried) {
                let _ = std::fs::remove_file(p);
            }
            run
        }
        Err(e) => {
            eprintln!(
                "coupler: could not merge the recordings into {}: {e}; the per-process files are kept",
                run.display()
            );
            let _ = std::fs::remove_file(&run);
            inputs[0].clone()
        }
    }
}

/// Adds the coupler's fields to the solvers' summaries and writes
/// `summary.json`, typed (`RunSummary`: NaN measures are written as null
/// and read back as NaN). A coupled run's summary is the DEM's (fronts, runout, deposit) with
/// the LBM's liquid front, lattice details and throughput, and the exchange
/// as each process saw it.
fn finish_summary(
    out: &Path,
    solvers: &[(&str, &str)],
    wall_total: f64,
    interrupted: bool,
    failed: bool,
) -> Option<RunSummary> {
    let mut parts = Vec::new();
    for (_, short) in solvers {
        let path = out.join(format!("{short}_summary.json"));
        let Ok(text) = std::fs::read_to_string(&path) else { continue };
        match serde_json::from_str::<RunSummary>(&text) {
            Ok(s) => parts.push((*short, path, s)),
            Err(e) => {
                eprintln!("coupler: {} is not a run summary of this build ({e}); it is left in place", path.display())
            }
        }
    }
    // A failed run keeps whatever summaries were written; a normal one needs all.
    let complete = parts.len() == solvers.len();
    if parts.is_empty() || (!complete && !failed) {
        return None;
    }
    let mut summary = if solvers.len() > 1 { merge_coupled(&parts) } else { parts[0].2.clone() };
    summary.wall_seconds_total = Some(wall_total);
    if interrupted {
        summary.status = RunStatus::Interrupted;
    } else if failed {
        // A watchdog's stop is the run's outcome (`unstable`, its cause
        // in /log); any other failure of a process is `failed`.
        let watchdog = parts.iter().any(|(_, _, s)| s.status == RunStatus::Unstable);
        summary.status = if watchdog { RunStatus::Unstable } else { RunStatus::Failed };
    }
    let path = out.join("summary.json");
    if let Err(e) = std::fs::write(&path, serde_json::to_string_pretty(&summary).expect("serialises")) {
        eprintln!("coupler: cannot write {}: {e} (is the disk full?)", path.display());
        return None;
    }
    for (_, p, _) in &parts {
        let _ = std::fs::remove_file(p);
    }
    Some(summary)
}

/// A coupled run's summary from the processes' (all, or what a failed run
/// left): the first (the DEM's), with the LBM's liquid front, details, cell
/// rate and wall time, and both views of the exchange.
fn merge_coupled(parts: &[(&str, PathBuf, RunSummary)]) -> RunSummary {
    let mut summary = parts[0].2.clone();
    let mut exchange = RunExchange::default();
    for (short, _, part) in parts {
        let view = match &part.exchange {
            Some(ExchangeSummary::Process(d)) => Some(d.clone()),
            _ => None,
        };
        if exchange.schedule.is_empty() {
            exchange.schedule = view.as_ref().map(|d| d.schedule.clone()).unwrap_or_default();
        }
        match *short {
            "dem" => exchange.dem = view,
            "lbm" => {
                exchange.lbm = view;
                summary.liquid_front = part.liquid_front.clone();
                summary.lbm = part.lbm.clone();
                summary.throughput.cell_updates_per_s = part.throughput.cell_updates_per_s;
                summary.wall_seconds_lbm = Some(part.wall_seconds);
            }
            _ => {}
        }
    }
    summary.exchange = Some(ExchangeSummary::Run(exchange));
    summary.method = "dem_lbm".into();
    summary
}

fn report(s: &RunSummary, out: &Path) {
    let t = &s.throughput;
    let mut rates = Vec::new();
    if let Some(p) = t.particle_steps_per_s {
        rates.push(format!("{p:.3e} particle-steps/s"));
    } else if let Some(c) = t.cell_updates_per_s {
        rates.push(format!("{:.1} MLUPS", c / 1e6));
    }
    if let Some(p) = t.point_updates_per_s {
        rates.push(format!("{p:.3e} point-updates/s"));
    }
    let rate = if rates.is_empty() { "no throughput".to_string() } else { rates.join(", ") };
    eprintln!(
        "coupler: {} ({}) after t = {:.4} s = {:.2} t_ref, {} steps in {:.1} s, {rate}",
        s.scene,
        s.status,
        s.sim_time,
        s.sim_time / s.t_ref,
        s.steps,
        s.wall_seconds,
    );
    if s.runout.is_finite() {
        eprintln!("coupler: runout (L_f - L0)/L0 = {:.4}; initial porosity {:.4}", s.runout, s.porosity_initial);
    }
    if let Some(front) = s.liquid_front.last() {
        eprintln!("coupler: liquid front (X_f - L0)/L0 = {:.4} at the end", front.x_norm);
    }
    eprintln!("coupler: wrote {} and {}", out.join("run.mcap").display(), out.join("summary.json").display());
}

#[cfg(test)]
mod tests {
    use super::LossyLines;

    #[test]
    fn non_utf8_output_does_not_stop_the_reader() {
        let rt = tokio::runtime::Builder::new_current_thread().build().unwrap();
        rt.block_on(async {
            let bytes: &[u8] = b"first\n\xff\xfe stray bytes\nlast without newline";
            let mut lines = LossyLines::new(bytes);
            assert_eq!(lines.next_line().await.as_deref(), Some("first"));
            assert_eq!(lines.next_line().await.as_deref(), Some("\u{fffd}\u{fffd} stray bytes"));
            assert_eq!(lines.next_line().await.as_deref(), Some("last without newline"));
            assert_eq!(lines.next_line().await, None);
        });
    }
}
