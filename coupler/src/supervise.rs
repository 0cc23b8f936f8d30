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
use tokio::process::{Child, Command};
use tokio::signal::unix::{signal, SignalKind};

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

struct Bar {
    bar: Option<ProgressBar>,
    phase: String,
    /// (simulated time, wall time) of the previous progress event.
    last: (f64, f64),
}

impl Bar {
    fn new(quiet: bool) -> Self {
        let bar = (!quiet).then(|| {
            let b = ProgressBar::new(1000);
            b.set_style(
                ProgressStyle::with_template("{prefix:>11} [{bar:30}] {msg} | elapsed {elapsed_precise}, ETA {eta}")
                    .expect("valid template")
                    .progress_chars("=> "),
            );
            b.enable_steady_tick(Duration::from_millis(500));
            b
        });
        Self { bar, phase: String::new(), last: (0.0, 0.0) }
    }

    fn println(&self, line: &str) {
        match &self.bar {
            Some(b) => b.println(line),
            None => eprintln!("{line}"),
        }
    }

    fn progress(&mut self, ev: &serde_json::Value) {
        let phase = ev["phase"].as_str().unwrap_or("").to_string();
        let t = ev["t"].as_f64().unwrap_or(0.0);
        let t_end = ev["t_end"].as_f64().unwrap_or(1.0).max(1e-12);
        let wall = ev["wall"].as_f64().unwrap_or(0.0);
        let (t0, w0) = if phase == self.phase { self.last } else { (t, wall) };
        self.last = (t, wall);
        let rate = if wall > w0 { (t - t0) / (wall - w0) } else { 0.0 };
        let msg = format!("t = {t:.4} / {t_end:.3} s, {:.1} ms simulated per wall second", rate * 1e3);
        match &self.bar {
            Some(b) => {
                if phase != self.phase {
                    b.reset();
                    b.set_prefix(phase.clone());
                }
                b.set_position(((t / t_end) * 1000.0).clamp(0.0, 1000.0) as u64);
                b.set_message(msg);
            }
            None => eprintln!("{phase}: {msg}, {wall:.1} s wall"),
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

/// Sends `sig` to a running child.
fn send_signal(child: &Child, sig: i32) {
    if let Some(pid) = child.id() {
        // SAFETY: kill(2) with a pid we spawned and still own (not yet reaped).
        unsafe {
            libc::kill(pid as i32, sig);
        }
    }
}

/// The one solver process a method runs: binary name and the short name of its outputs.
fn solver_for(method: Method) -> Option<(&'static str, &'static str)> {
    match method {
        Method::DemDry => Some(("dem_proc", "dem")),
        Method::LbmFluid => Some(("lbm_proc", "lbm")),
        Method::DemLbm => None,
    }
}

pub async fn run(scene: Scene, out: PathBuf, threads: Option<usize>, quiet: bool) -> ExitCode {
    let started = Instant::now();
    let method = scene.method();
    let Some((solver, short)) = solver_for(method) else {
        eprintln!(
            "coupler: scene {} needs the {} method (dem_proc + lbm_proc coupled), which this build does not have yet: dry DEM scenes and fluid-only LBM scenes run so far",
            scene.spec.scene.name,
            method.name(),
        );
        return ExitCode::from(EXIT_BAD_SCENE as u8);
    };
    let solver_bin = match sibling_binary(solver) {
        Ok(p) => p,
        Err(e) => {
            eprintln!("coupler: {e}");
            return ExitCode::FAILURE;
        }
    };
    if let Err(e) = std::fs::create_dir_all(&out) {
        eprintln!("coupler: cannot create output directory {}: {e}", out.display());
        return ExitCode::FAILURE;
    }
    // A reused output directory must not show a previous run's results as this one's.
    for stale in
        ["run.mcap".to_string(), format!("{short}.mcap"), "summary.json".into(), format!("{short}_summary.json")]
    {
        let path = out.join(stale);
        if path.exists() {
            if let Err(e) = std::fs::remove_file(&path) {
                eprintln!("coupler: cannot remove the previous run's {}: {e}", path.display());
                return ExitCode::FAILURE;
            }
        }
    }
    let scene_file = out.join("scene.toml");
    if let Err(e) = std::fs::write(&scene_file, scene.to_toml()) {
        eprintln!("coupler: cannot write {}: {e} (is the disk full?)", scene_file.display());
        return ExitCode::FAILURE;
    }
    // Relative explicit-sphere files resolve against the original scene directory;
    // the resolved scene embeds them instead.
    let mut cmd = Command::new(&solver_bin);
    cmd.arg("run").arg(&scene_file).arg("--out").arg(&out).arg("--progress-json").arg("--supervised");
    if let Some(n) = threads {
        cmd.arg("--threads").arg(n.to_string());
    }
    cmd.stdout(Stdio::piped()).stderr(Stdio::piped()).stdin(Stdio::null()).kill_on_drop(true);
    let mut child = match cmd.spawn() {
        Ok(c) => c,
        Err(e) => {
            eprintln!("coupler: cannot start {}: {e}", solver_bin.display());
            return ExitCode::FAILURE;
        }
    };
    eprintln!(
        "coupler: running {} ({}) with {solver}, output in {}",
        scene.spec.scene.name,
        method.name(),
        out.display()
    );

    let mut stdout = LossyLines::new(child.stdout.take().expect("piped"));
    let mut stderr = LossyLines::new(child.stderr.take().expect("piped"));
    let (mut sigint, mut sigterm) = match (signal(SignalKind::interrupt()), signal(SignalKind::terminate())) {
        (Ok(a), Ok(b)) => (a, b),
        _ => {
            eprintln!("coupler: cannot install signal handlers");
            return ExitCode::FAILURE;
        }
    };
    let mut bar = Bar::new(quiet);
    let mut interrupts = 0;
    let mut stdout_open = true;
    let mut stderr_open = true;
    let status = loop {
        tokio::select! {
            line = stdout.next_line(), if stdout_open => match line {
                Some(l) => {
                    if let Ok(ev) = serde_json::from_str::<serde_json::Value>(&l) {
                        if ev["event"] == "progress" { bar.progress(&ev); }
                    }
                }
                _ => stdout_open = false,
            },
            line = stderr.next_line(), if stderr_open => match line {
                Some(l) => bar.println(&l),
                None => stderr_open = false,
            },
            _ = sigint.recv() => { interrupts += 1; forward(&child, solver, interrupts, &bar); }
            _ = sigterm.recv() => { interrupts += 1; forward(&child, solver, interrupts, &bar); }
            st = child.wait() => break st,
        }
    };
    // Drain what the child wrote just before exiting.
    while stderr_open {
        match tokio::time::timeout(Duration::from_millis(200), stderr.next_line()).await {
            Ok(Some(l)) => bar.println(&l),
            _ => stderr_open = false,
        }
    }
    bar.finish();
    let status = match status {
        Ok(s) => s,
        Err(e) => {
            eprintln!("coupler: lost track of {solver}: {e}");
            return ExitCode::FAILURE;
        }
    };

    let recording = collect_recording(&out, short);
    let summary = finish_summary(&out, short, started.elapsed().as_secs_f64(), interrupts > 0 && !status.success());
    let recorded = recording.exists();
    match status.code() {
        Some(0) => match &summary {
            Some(s) => {
                report(s, &out);
                ExitCode::SUCCESS
            }
            None => {
                eprintln!("coupler: {solver} finished but left no readable summary in {}", out.display());
                ExitCode::FAILURE
            }
        },
        Some(c) if c == EXIT_INTERRUPTED => {
            if recorded {
                eprintln!(
                    "coupler: run interrupted; the recording up to the interruption is in {}",
                    recording.display()
                );
            } else {
                eprintln!("coupler: run interrupted before the collapse started; nothing was recorded");
            }
            ExitCode::from(EXIT_INTERRUPTED as u8)
        }
        Some(c) if c == EXIT_BAD_SCENE => {
            eprintln!("coupler: {solver} rejected the scene (exit status 2); see the message above");
            ExitCode::from(EXIT_BAD_SCENE as u8)
        }
        _ if interrupts > 1 => {
            eprintln!("coupler: {solver} killed after a second interrupt; {} may lack its summary section (streaming MCAP readers still read it)", recording.display());
            ExitCode::from(EXIT_INTERRUPTED as u8)
        }
        code => {
            let how = match code {
                Some(c) => format!("exit status {c}"),
                None => {
                    use std::os::unix::process::ExitStatusExt;
                    format!("signal {}", status.signal().unwrap_or(0))
                }
            };
            eprintln!(
                "coupler: {solver} failed ({how}); see its message above. What was recorded so far is in {} (readable by streaming MCAP readers)",
                recording.display()
            );
            ExitCode::FAILURE
        }
    }
}

fn forward(child: &Child, solver: &str, count: u32, bar: &Bar) {
    if count == 1 {
        bar.println("coupler: stopping at the next step boundary (press Ctrl-C again to kill)");
        send_signal(child, libc::SIGINT);
    } else {
        bar.println(&format!("coupler: killing {solver}"));
        send_signal(child, libc::SIGKILL);
    }
}

/// With one solver process its recording is the run's recording.
fn collect_recording(out: &Path, short: &str) -> PathBuf {
    let run = out.join("run.mcap");
    let solver = out.join(format!("{short}.mcap"));
    if solver.exists() {
        if let Err(e) = std::fs::rename(&solver, &run) {
            eprintln!("coupler: cannot move {} to {}: {e}", solver.display(), run.display());
            return solver;
        }
    }
    run
}

/// Adds the coupler's fields to the solver's summary and writes `summary.json`.
/// Kept as JSON values: NaN measures arrive as null and stay null.
fn finish_summary(out: &Path, short: &str, wall_total: f64, interrupted: bool) -> Option<serde_json::Value> {
    let solver_summary = out.join(format!("{short}_summary.json"));
    let text = std::fs::read_to_string(&solver_summary).ok()?;
    let mut summary: serde_json::Value = match serde_json::from_str(&text) {
        Ok(v) => v,
        Err(e) => {
            eprintln!("coupler: {} is not valid JSON: {e}", solver_summary.display());
            return None;
        }
    };
    summary["wall_seconds_total"] = wall_total.into();
    if interrupted {
        summary["status"] = "interrupted".into();
    }
    let path = out.join("summary.json");
    if let Err(e) = std::fs::write(&path, serde_json::to_string_pretty(&summary).expect("serialises")) {
        eprintln!("coupler: cannot write {}: {e} (is the disk full?)", path.display());
        return None;
    }
    let _ = std::fs::remove_file(solver_summary);
    Some(summary)
}

fn report(s: &serde_json::Value, out: &Path) {
    let num = |v: &serde_json::Value| v.as_f64().unwrap_or(f64::NAN);
    let rate = match (s["throughput"]["particle_steps_per_s"].as_f64(), s["throughput"]["cell_updates_per_s"].as_f64())
    {
        (Some(p), _) => format!("{p:.3e} particle-steps/s"),
        (None, Some(c)) => format!("{:.1} MLUPS", c / 1e6),
        (None, None) => "no throughput".into(),
    };
    eprintln!(
        "coupler: {} ({}) after t = {:.4} s = {:.2} t_ref, {} steps in {:.1} s, {rate}",
        s["scene"].as_str().unwrap_or("?"),
        s["status"].as_str().unwrap_or("?"),
        num(&s["sim_time"]),
        num(&s["sim_time"]) / num(&s["t_ref"]),
        s["steps"],
        num(&s["wall_seconds"]),
    );
    if let Some(runout) = s["runout"].as_f64() {
        eprintln!("coupler: runout (L_f - L0)/L0 = {runout:.4}; initial porosity {:.4}", num(&s["porosity_initial"]));
    }
    if let Some(front) = s["liquid_front"].as_array().and_then(|f| f.last()) {
        eprintln!("coupler: liquid front (X_f - L0)/L0 = {:.4} at the end", num(&front["x_norm"]));
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
