//! Resume (issue 23): a run killed with SIGKILL after its first checkpoints
//! and continued with `coupler run --resume DIR` ends as the run never
//! interrupted, bit for bit: every recorded state, frame and exchanged
//! message the same bytes at the same times, and the same summary. One run
//! per method: the dry DEM (grain contacts and wall springs), the fluid
//! alone (free surface), the two-phase MPM, and the coupled DEM–LBM under
//! both schedules (the concurrent one has an answer in flight at every
//! checkpoint, which the LBM sends again).

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use integration_tests::{assert_same_run, binary, find_process, repo_root, scratch_dir};

fn coupler(out: &Path, args: &[&str]) -> Command {
    let mut cmd = Command::new(binary("coupler"));
    cmd.current_dir(repo_root()).env("SGF_CACHE_DIR", out.join("cache")).args(args).arg("--quiet");
    cmd
}

fn run_straight(name: &str, scene: &str, set: &[String]) -> PathBuf {
    let out = scratch_dir(name);
    let mut cmd = coupler(&out, &["run", scene]);
    for s in set {
        cmd.arg("--set").arg(s);
    }
    let log = std::fs::File::create(out.with_extension("log")).expect("log file");
    let status = cmd.arg("--out").arg(&out).stderr(Stdio::from(log)).status().expect("coupler starts");
    assert!(status.success(), "{name}: the uninterrupted run failed: {status}");
    out
}

/// Starts the run, waits until every process has written a checkpoint,
/// kills `victim` with SIGKILL and waits for the coupler to end.
fn run_killed(name: &str, scene: &str, set: &[String], processes: &[&str], victim: &str) -> PathBuf {
    let out = scratch_dir(name);
    let mut cmd = coupler(&out, &["run", scene]);
    for s in set {
        cmd.arg("--set").arg(s);
    }
    let log = std::fs::File::create(out.with_extension("log")).expect("log file");
    let mut child: Child = cmd.arg("--out").arg(&out).stderr(Stdio::from(log)).spawn().expect("coupler starts");
    let folder = out.join("checkpoints");
    let started = Instant::now();
    let ready = || {
        processes.iter().all(|p| {
            std::fs::read_dir(&folder).into_iter().flatten().flatten().any(|e| {
                let n = e.file_name().to_string_lossy().to_string();
                n.starts_with(&format!("{p}-")) && n.ends_with(".ckpt")
            })
        })
    };
    while !ready() {
        assert!(child.try_wait().expect("wait").is_none(), "{name}: the run ended before its first checkpoint");
        assert!(started.elapsed() < Duration::from_secs(120), "{name}: no checkpoint after 120 s");
        std::thread::sleep(Duration::from_millis(5));
    }
    let pid = find_process(victim, &out).expect("the victim runs");
    // SAFETY: signalling a process this test started (through the coupler).
    unsafe { libc::kill(pid, libc::SIGKILL) };
    let status = child.wait().expect("coupler ends");
    assert!(!status.success(), "{name}: the run must have been killed, not completed ({status})");
    out
}

fn resume(out: &Path) {
    let log = std::fs::File::create(out.with_extension("resume.log")).expect("log file");
    let dir = out.to_str().expect("a UTF-8 path");
    let status = coupler(out, &["run", "--resume", dir]).stderr(Stdio::from(log)).status().expect("coupler");
    let text = std::fs::read_to_string(out.with_extension("resume.log")).unwrap_or_default();
    assert!(status.success(), "coupler run --resume {} failed: {status}\n{text}", out.display());
    assert!(text.contains("continuing from t ="), "the resume names its checkpoint:\n{text}");
}

fn killed_and_resumed_equals_straight(name: &str, scene: &str, set: &[&str], processes: &[&str], victim: &str) {
    let set: Vec<String> = set.iter().map(|s| s.to_string()).collect();
    let straight = run_straight(&format!("{name}_straight"), scene, &set);
    let resumed = run_killed(&format!("{name}_resumed"), scene, &set, processes, victim);
    resume(&resumed);
    assert_same_run(&straight, &resumed);
}

#[test]
fn a_killed_dry_dem_run_resumes_bit_for_bit() {
    killed_and_resumed_equals_straight(
        "resume_dem",
        "scenes/validation/dry_small.toml",
        &["output.checkpoint_interval=0.05", "output.stop_at_rest=false"],
        &["dem_proc"],
        "dem_proc",
    );
}

#[test]
fn a_killed_fluid_run_resumes_bit_for_bit() {
    killed_and_resumed_equals_straight(
        "resume_lbm",
        "scenes/validation/water_block.toml",
        &["output.checkpoint_interval=0.03", "output.state_interval=0.05"],
        &["lbm_proc"],
        "lbm_proc",
    );
}

/// The f64 lattice (`lbm.precision`) checkpoints and resumes through the
/// same path, its populations kept in f64.
#[test]
fn a_killed_f64_fluid_run_resumes_bit_for_bit() {
    killed_and_resumed_equals_straight(
        "resume_lbm_f64",
        "scenes/validation/water_block.toml",
        &["output.checkpoint_interval=0.03", "output.state_interval=0.05", "lbm.precision=\"f64\""],
        &["lbm_proc"],
        "lbm_proc",
    );
}

/// Also what `--resume` refuses: other physics than the run's (its
/// checkpoints passed over, named, the run directory left as it was) and a
/// finished run (its checkpoints removed when it completed).
#[test]
fn a_killed_mpm_run_resumes_bit_for_bit() {
    let name = "resume_mpm";
    let scene = "scenes/ceccato2020/mpm_sat_h030.toml";
    // Checkpoints between frames (every 0.015 s against frames every
    // 0.01 s): what a frame gathers over its steps (the pore-pressure
    // peak, the liquid's impulse) must carry over the kill.
    let set = ["output.end_time=0.1".to_string(), "output.checkpoint_interval=0.015".to_string()];
    let straight = run_straight(&format!("{name}_straight"), scene, &set);
    assert!(!straight.join("checkpoints").exists(), "a completed run keeps no checkpoints");
    let refused = refused_resume(&straight, &[]);
    assert!(refused.contains("no checkpoint in"), "{refused}");
    let resumed = run_killed(&format!("{name}_resumed"), scene, &set, &["mpm_proc"], "mpm_proc");
    let recording = std::fs::read(resumed.join("run.mcap")).expect("the killed run's recording");
    let refused = refused_resume(&resumed, &["mpm.courant=0.4"]);
    assert!(refused.contains("is of a different scene"), "{refused}");
    assert!(std::fs::read(resumed.join("run.mcap")).expect("kept") == recording, "a refused resume changes nothing");
    resume(&resumed);
    assert_same_run(&straight, &resumed);
}

/// `coupler run --resume DIR --set …` that must fail: its message.
fn refused_resume(out: &Path, set: &[&str]) -> String {
    let dir = out.to_str().expect("a UTF-8 path");
    let mut cmd = coupler(out, &["run", "--resume", dir]);
    for s in set {
        cmd.arg("--set").arg(s);
    }
    let o = cmd.output().expect("coupler");
    assert_eq!(o.status.code(), Some(1), "refused with exit status 1");
    String::from_utf8_lossy(&o.stderr).to_string()
}

fn coupled(schedule: &str, victim: &str) {
    killed_and_resumed_equals_straight(
        &format!("resume_coupled_{schedule}"),
        "scenes/validation/settling_sphere.toml",
        &[
            "output.end_time=0.1",
            "output.checkpoint_interval=0.01",
            "output.state_interval=0.02",
            "output.record_exchange=true",
            &format!("coupling.schedule=\"{schedule}\""),
        ],
        &["dem_proc", "lbm_proc"],
        victim,
    );
}

#[test]
fn a_killed_sequential_coupled_run_resumes_bit_for_bit() {
    coupled("sequential", "dem_proc");
}

#[test]
fn a_killed_concurrent_coupled_run_resumes_bit_for_bit() {
    coupled("concurrent", "lbm_proc");
}
