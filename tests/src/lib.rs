//! Helpers for the cross-process tests: where the binaries are, scratch
//! directories, and a Python with the official `mcap` reader.

use std::path::{Path, PathBuf};
use std::process::Command;

/// The workspace root.
pub fn repo_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).parent().expect("tests/ has a parent").to_path_buf()
}

/// The directory cargo puts this profile's binaries in (target/<profile>).
fn profile_dir() -> PathBuf {
    let exe = std::env::current_exe().expect("test executable path");
    // target/<profile>/deps/<test>-<hash>
    exe.parent().and_then(Path::parent).expect("target/<profile>").to_path_buf()
}

/// A workspace binary built by this `cargo test` run.
pub fn binary(name: &str) -> PathBuf {
    let p = profile_dir().join(name);
    assert!(
        p.exists(),
        "{} is missing: run the tests with `cargo test --workspace --release`, which builds every binary",
        p.display()
    );
    p
}

/// An empty directory under target/ for one test.
pub fn scratch_dir(name: &str) -> PathBuf {
    let d = profile_dir().join("test-runs").join(name);
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).expect("create scratch dir");
    d
}

/// A Python interpreter with `mcap` and `mcap-protobuf-support`, installed
/// once into target/pyenv from PyPI. None if python3 or pip is unavailable.
pub fn python_with_mcap() -> Option<PathBuf> {
    let venv = profile_dir().parent()?.join("pyenv");
    let python = venv.join("bin/python");
    let ready = |py: &Path| {
        Command::new(py)
            .args(["-c", "import mcap, mcap_protobuf"])
            .output()
            .map(|o| o.status.success())
            .unwrap_or(false)
    };
    if python.exists() && ready(&python) {
        return Some(python);
    }
    let created =
        Command::new("python3").args(["-m", "venv"]).arg(&venv).status().map(|s| s.success()).unwrap_or(false);
    if !created {
        return None;
    }
    let installed = Command::new(&python)
        .args([
            "-m",
            "pip",
            "install",
            "--quiet",
            "--disable-pip-version-check",
            "mcap",
            "mcap-protobuf-support",
            "protobuf",
        ])
        .status()
        .map(|s| s.success())
        .unwrap_or(false);
    (installed && ready(&python)).then_some(python)
}

/// Whether a process named `name` whose command line mentions `arg` is alive.
pub fn process_running(name: &str, arg: &Path) -> bool {
    let Ok(entries) = std::fs::read_dir("/proc") else { return false };
    let needle = arg.to_string_lossy().to_string();
    entries.flatten().any(|e| {
        let cmdline = std::fs::read(e.path().join("cmdline")).unwrap_or_default();
        let cmd = String::from_utf8_lossy(&cmdline).replace('\0', " ");
        cmd.contains(name) && cmd.contains(&needle)
    })
}

/// Runs `coupler run SCENE --quiet --out <scratch>/<name> EXTRA…` from the
/// workspace root (packing cache inside the scratch directory) and returns
/// the output directory; panics if the run fails.
pub fn coupler_run(name: &str, scene: &str, extra: &[&str]) -> PathBuf {
    let out = scratch_dir(name);
    let status = Command::new(binary("coupler"))
        .current_dir(repo_root())
        .env("SGF_CACHE_DIR", out.join("cache"))
        .args(["run", scene, "--quiet"])
        .args(extra)
        .arg("--out")
        .arg(&out)
        .status()
        .expect("coupler starts");
    assert!(status.success(), "coupler run {scene} failed: {status}");
    out
}
