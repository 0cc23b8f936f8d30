//! Faults of a coupled run (issue: dead peer, Ctrl-C, wrong run id): the
//! coupler notices, stops the other process, says which one died and how,
//! leaves a readable run.mcap and no process or shared memory behind.

use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use integration_tests::{binary, find_process, process_running, repo_root, scratch_dir};

const SCENE: &str = "scenes/validation/settling_sphere.toml";

/// The settling sphere with no end, under `coupler`, once both processes
/// exchange (the DEM's recording exists); stderr captured to a file.
fn start_long_coupled_run(name: &str) -> (Child, PathBuf) {
    let out = scratch_dir(name);
    let log = std::fs::File::create(out.with_extension("log")).unwrap();
    let child = Command::new(binary("coupler"))
        .current_dir(repo_root())
        .args(["run", SCENE, "--quiet", "--set", "output.end_time=100", "--out"])
        .arg(&out)
        .stderr(Stdio::from(log))
        .spawn()
        .unwrap();
    let started = Instant::now();
    while !out.join("dem.mcap").exists() || !out.join("lbm.mcap").exists() {
        assert!(started.elapsed() < Duration::from_secs(60), "coupled run never started");
        std::thread::sleep(Duration::from_millis(100));
    }
    // Past the first chunk flush (runtime::record::FLUSH_EVERY = 2 s): a
    // process killed later loses at most its last 2 s of recording.
    std::thread::sleep(Duration::from_millis(3500));
    (child, out)
}

fn wait_with_timeout(child: &mut Child, limit: Duration) -> std::process::ExitStatus {
    let started = Instant::now();
    loop {
        if let Some(st) = child.try_wait().unwrap() {
            return st;
        }
        assert!(started.elapsed() < limit, "coupler still running {limit:?} after the fault");
        std::thread::sleep(Duration::from_millis(50));
    }
}

/// Messages in a recording, read as a stream (works on unfinished files too).
fn topics_in(path: &std::path::Path) -> std::collections::BTreeSet<String> {
    let bytes = std::fs::read(path).unwrap();
    mcap::MessageStream::new(&bytes).unwrap().map(|m| m.unwrap().channel.topic.clone()).collect()
}

fn kill_one_and_check(victim: &str, survivor: &str, name: &str) {
    let (mut coupler, out) = start_long_coupled_run(name);
    let pid = find_process(victim, &out).expect("victim process running");
    // SAFETY: signalling a process this test started (through the coupler).
    unsafe { libc::kill(pid, libc::SIGKILL) };
    let status = wait_with_timeout(&mut coupler, Duration::from_secs(30));
    assert_eq!(status.code(), Some(1), "coupler exit status after {victim} died");
    let log = std::fs::read_to_string(out.with_extension("log")).unwrap();
    assert!(
        log.contains(&format!("coupler: {victim} failed (killed by signal 9 (SIGKILL))")),
        "the coupler must name the dead process and how it died:\n{log}"
    );
    assert!(!process_running(survivor, &out), "{survivor} left running");
    assert!(!process_running(victim, &out), "{victim} left running");
    // One readable recording with both processes' topics up to the fault.
    let topics = topics_in(&out.join("run.mcap"));
    for t in ["/dem/particles", "/dem/metrics", "/lbm/metrics", "/log"] {
        assert!(topics.contains(t), "run.mcap lacks {t}: {topics:?}");
    }
    let s: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap();
    assert_eq!(s["status"], "failed");
}

#[test]
fn killed_lbm_stops_the_dem_and_is_named() {
    kill_one_and_check("lbm_proc", "dem_proc", "coupled_lbm_killed");
}

#[test]
fn killed_dem_stops_the_lbm_and_is_named() {
    kill_one_and_check("dem_proc", "lbm_proc", "coupled_dem_killed");
    // No stale shared memory blocks the next coupled run.
    let out = scratch_dir("coupled_after_kill");
    let status = Command::new(binary("coupler"))
        .current_dir(repo_root())
        .args(["run", SCENE, "--quiet", "--set", "output.end_time=0.02", "--out"])
        .arg(&out)
        .status()
        .unwrap();
    assert!(status.success(), "a coupled run after a killed one must start");
}

/// Ctrl-C: both processes stop at a step boundary, the merged recording is
/// finished, the summary says `interrupted`, exit status 130.
#[test]
fn ctrl_c_stops_both_processes_cleanly() {
    let (mut coupler, out) = start_long_coupled_run("coupled_interrupted");
    // SAFETY: signalling the child we spawned.
    unsafe { libc::kill(coupler.id() as i32, libc::SIGINT) };
    let status = wait_with_timeout(&mut coupler, Duration::from_secs(30));
    assert_eq!(status.code(), Some(130));
    let s: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap();
    assert_eq!(s["status"], "interrupted");
    let t = s["sim_time"].as_f64().unwrap();
    assert!(t > 0.0 && t < 100.0, "{t}");
    let bytes = std::fs::read(out.join("run.mcap")).unwrap();
    assert!(mcap::Summary::read(&bytes).unwrap().is_some(), "merged recording finished");
    assert!(!process_running("dem_proc", &out) && !process_running("lbm_proc", &out));
}

/// A process started by hand on a run id nobody else uses is refused with a
/// message naming the run id and the fix, not left hanging.
#[test]
fn wrong_run_id_is_refused_with_a_message() {
    let out = scratch_dir("coupled_wrong_run_id");
    let output = Command::new(binary("lbm_proc"))
        .current_dir(repo_root())
        .args(["run", SCENE, "--run-id", "nobody-here", "--connect-timeout", "1", "--out"])
        .arg(&out)
        .output()
        .unwrap();
    assert_eq!(output.status.code(), Some(1));
    let err = String::from_utf8_lossy(&output.stderr);
    assert!(err.contains("no DEM process answered on run id \"nobody-here\""), "{err}");
    assert!(err.contains("--run-id nobody-here"), "the message must say how to fix it: {err}");
    // And a coupled scene started by hand without any run id: status 2 and the two ways to run it.
    let output = Command::new(binary("dem_proc")).current_dir(repo_root()).args(["run", SCENE]).output().unwrap();
    assert_eq!(output.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&output.stderr).contains("coupler run"));
}

/// A process that stops on its own (the LBM's watchdog) under `coupler`
/// with stderr going to a pipe, as in a batch job's log: its own message
/// passes through (no progress bar to swallow it), and the coupler's last
/// line repeats the cause and its fix. Exit status 1, the DEM stopped.
#[test]
fn a_blow_up_under_the_coupler_is_reported_with_its_fix_in_a_log() {
    let out = scratch_dir("coupled_lbm_blow_up");
    let output = Command::new(binary("coupler"))
        .current_dir(repo_root())
        // Mach 1e-4: the first frame's flow around the falling sphere trips the watchdog.
        .args(["run", SCENE, "--set", "lbm.mach_limit=0.0001", "--out"])
        .arg(&out)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert_eq!(output.status.code(), Some(1), "{stderr}");
    assert!(stderr.contains("lbm_proc: error: the flow became unstable"), "the process's own line: {stderr}");
    let last = stderr.lines().last().unwrap_or_default();
    assert!(
        last.starts_with("coupler: lbm_proc failed (exit status 1): the flow became unstable")
            && last.contains("lower the time step")
            && last.contains("the other process was stopped"),
        "the coupler's last line: {last}"
    );
    assert!(!process_running("dem_proc", &out) && !process_running("lbm_proc", &out));
    // The summary says what ended it: the watchdog, not a crash.
    let s: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap();
    assert_eq!(s["status"], "unstable");
}

/// The settling sphere on a 16x finer lattice (~18 M cells: seconds of
/// LBM set-up that do not look at the stop flag), under `coupler`, once
/// the LBM has begun building it; stderr to a log.
fn start_run_in_lbm_set_up(name: &str) -> (Child, PathBuf) {
    let out = scratch_dir(name);
    let log = std::fs::File::create(out.with_extension("log")).unwrap();
    let coupler = Command::new(binary("coupler"))
        .current_dir(repo_root())
        .args(["run", SCENE, "--quiet", "--set", "lbm.spacing=0.000125", "--set", "output.end_time=100", "--out"])
        .arg(&out)
        .stderr(Stdio::from(log))
        .spawn()
        .unwrap();
    // The LBM names its lattice just before it builds it.
    let started = Instant::now();
    while !std::fs::read_to_string(out.with_extension("log")).unwrap_or_default().contains("lbm_proc: lattice") {
        assert!(started.elapsed() < Duration::from_secs(60), "the LBM never began its set-up");
        std::thread::sleep(Duration::from_millis(20));
    }
    std::thread::sleep(Duration::from_millis(300));
    assert!(process_running("lbm_proc", &out), "the LBM must still be setting up");
    (coupler, out)
}

/// `dem_proc` killed while `lbm_proc` still builds its lattice: the
/// coupler does not wait for the set-up to end. It stops the LBM at once (a
/// process that has reported no progress has recorded nothing) and exits
/// within a second, naming the dead process; nothing is left running.
#[test]
fn a_peer_killed_during_the_lbm_set_up_brings_the_coupler_down_at_once() {
    let (mut coupler, out) = start_run_in_lbm_set_up("coupled_killed_in_setup");
    let pid = find_process("dem_proc", &out).expect("dem_proc running");
    // SAFETY: signalling a process this test started (through the coupler).
    unsafe { libc::kill(pid, libc::SIGKILL) };
    let killed = Instant::now();
    let status = wait_with_timeout(&mut coupler, Duration::from_secs(30));
    let took = killed.elapsed();
    let log = std::fs::read_to_string(out.with_extension("log")).unwrap();
    assert_eq!(status.code(), Some(1), "{log}");
    assert!(log.contains("coupler: dem_proc failed (killed by signal 9 (SIGKILL))"), "{log}");
    assert!(!process_running("lbm_proc", &out) && !process_running("dem_proc", &out), "left running");
    println!("coupler exited {:.2} s after dem_proc was killed", took.as_secs_f64());
    // Issue 23 asks for 1 s (0.56 s measured on a quiet machine: 0.5 s of
    // grace for a process in set-up, then SIGKILL); 3 s leaves room for a
    // loaded CI machine, against the 10.4 s it took before.
    assert!(took < Duration::from_secs(3), "coupler took {took:?} to exit:\n{log}");
}

/// Ctrl-C while `lbm_proc` still builds its lattice: an interruption, not
/// a failure. The DEM stops at its step boundary, the LBM (which would not
/// look at its stop flag for seconds) is killed after 0.5 s, and the
/// coupler exits 130 at once; nothing is left running.
#[test]
fn ctrl_c_during_the_lbm_set_up_stops_the_run_at_once() {
    let (mut coupler, out) = start_run_in_lbm_set_up("coupled_interrupted_in_setup");
    // SAFETY: signalling a process this test started.
    unsafe { libc::kill(coupler.id() as i32, libc::SIGINT) };
    let asked = Instant::now();
    let status = wait_with_timeout(&mut coupler, Duration::from_secs(30));
    let took = asked.elapsed();
    let log = std::fs::read_to_string(out.with_extension("log")).unwrap();
    assert_eq!(status.code(), Some(130), "{log}");
    assert!(log.contains("coupler: run interrupted"), "{log}");
    assert!(!log.contains("failed"), "an interruption is no failure:\n{log}");
    assert!(!process_running("lbm_proc", &out) && !process_running("dem_proc", &out), "left running");
    println!("coupler exited {:.2} s after Ctrl-C", took.as_secs_f64());
    assert!(took < Duration::from_secs(3), "coupler took {took:?} to exit:\n{log}");
}

/// Two coupled runs of the same scene at once, in two output directories
/// (issue 23, part 6): each gets its own run id, so their shared-memory
/// links do not cross, and both record the same states, byte for byte, as
/// each would alone.
#[test]
fn two_coupled_runs_at_once_do_not_interfere() {
    let outs = [scratch_dir("coupled_twin_a"), scratch_dir("coupled_twin_b")];
    let mut runs: Vec<Child> = outs
        .iter()
        .map(|out| {
            Command::new(binary("coupler"))
                .current_dir(repo_root())
                .args(["run", SCENE, "--quiet", "--set", "output.end_time=0.02", "--out"])
                .arg(out)
                .stderr(Stdio::null())
                .spawn()
                .unwrap()
        })
        .collect();
    for run in &mut runs {
        let status = wait_with_timeout(run, Duration::from_secs(120));
        assert!(status.success(), "a run of the pair failed: {status}");
    }
    for topic in ["/dem/state", "/lbm/state"] {
        let [a, b] = outs.clone().map(|out| integration_tests::topic_messages(&out.join("run.mcap"), topic));
        assert!(!a.is_empty(), "{topic} recorded");
        assert!(a == b, "{topic} differs between the two runs ({} and {} messages)", a.len(), b.len());
    }
}
