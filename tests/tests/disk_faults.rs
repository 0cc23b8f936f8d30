//! Disk and file faults (issue 23, part 4): an output directory that
//! cannot be made, a disk that fills under the recording and under a
//! checkpoint. Each ends with a message naming the file and the cause, a
//! non-zero exit and no panic; what was recorded before stays readable.
//!
//! A full disk is the kernel's own: the file is a symbolic link to
//! `/dev/full`, whose every write fails with ENOSPC ("No space left on
//! device"), as a full file system's do, with no mount (the suite runs
//! unprivileged in containers). The damaged and cut recordings are in
//! `dry_column.rs` (`inspect_*`), damaged checkpoints in `fuzz_inputs.rs`
//! and `runtime::checkpoint`'s unit tests.

use std::path::Path;
use std::process::Command;

use integration_tests::{binary, repo_root, scratch_dir};

const SCENE: &str = "scenes/validation/dry_small.toml";

fn dem_run(out: &Path, set: &[&str]) -> std::process::Output {
    let mut cmd = Command::new(binary("dem_proc"));
    cmd.current_dir(repo_root()).env("SGF_CACHE_DIR", out.join("cache")).args(["run", SCENE, "--out"]).arg(out);
    for s in set {
        cmd.arg("--set").arg(s);
    }
    cmd.output().expect("dem_proc starts")
}

fn full_disk_here(path: &Path) -> bool {
    if !Path::new("/dev/full").exists() {
        assert!(std::env::var_os("CI").is_none(), "CI must have /dev/full");
        eprintln!("SKIPPED: this system has no /dev/full");
        return false;
    }
    std::os::unix::fs::symlink("/dev/full", path).expect("symlink to /dev/full");
    true
}

#[test]
fn an_output_directory_that_cannot_be_made_is_named() {
    // Under /proc nothing can be created, whoever runs the test (root too).
    let out = Command::new(binary("coupler"))
        .current_dir(repo_root())
        .args(["run", SCENE, "--quiet", "--out", "/proc/sgf-cannot-be-made"])
        .output()
        .expect("coupler starts");
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(err.contains("cannot create output directory /proc/sgf-cannot-be-made"), "{err}");
    assert!(!err.contains("panicked"), "{err}");
}

#[test]
fn a_disk_that_fills_under_the_recording_stops_the_run_with_the_cause() {
    let out = scratch_dir("disk_full_recording");
    if !full_disk_here(&out.join("dem.mcap")) {
        return;
    }
    let o = dem_run(&out, &[]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success(), "the run must fail:\n{err}");
    assert!(err.contains("No space left on device") && err.contains("is the disk full?"), "{err}");
    assert!(err.contains("dem.mcap"), "names the file:\n{err}");
    assert!(!err.contains("panicked"), "{err}");
}

/// The recording is closed into complete chunks before every checkpoint:
/// a checkpoint that cannot be written leaves the recording readable up to it.
#[test]
fn a_disk_that_fills_under_a_checkpoint_stops_the_run_and_keeps_the_recording() {
    let out = scratch_dir("disk_full_checkpoint");
    let interval = 0.05;
    let scene = schemas::Scene::load(&repo_root().join(SCENE), &[]).expect("scene");
    let dt = dem_proc::setup::DemSetup::from_scene(&scene).numerics.dt;
    let first = runtime::driver::Cadence::steps_in(interval, dt);
    std::fs::create_dir_all(out.join("checkpoints")).unwrap();
    if !full_disk_here(&out.join(format!("checkpoints/dem_proc-{first:014}.ckpt.partial"))) {
        return;
    }
    let o = dem_run(&out, &[&format!("output.checkpoint_interval={interval}")]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success(), "the run must fail:\n{err}");
    assert!(err.contains("cannot write checkpoint") && err.contains("No space left on device"), "{err}");
    assert!(!err.contains("panicked"), "{err}");
    let inspect = Command::new(binary("coupler")).arg("inspect").arg(out.join("dem.mcap")).output().unwrap();
    let text = String::from_utf8_lossy(&inspect.stdout);
    assert!(inspect.status.success(), "{text}");
    let span = text.lines().find(|l| l.starts_with("time span")).unwrap_or_else(|| panic!("nothing readable:\n{text}"));
    let last: f64 = span.split(".. ").nth(1).and_then(|r| r.split(' ').next()).and_then(|x| x.parse().ok()).unwrap();
    assert!(last >= interval - 1e-9, "the recording reaches the checkpoint's time {interval} s: {span}");
}
