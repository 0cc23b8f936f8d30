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

/// Held while target/pyenv is created or pip installs into it.
static PYTHON_SETUP: std::sync::Mutex<()> = std::sync::Mutex::new(());

/// A Python interpreter with `mcap` and `mcap-protobuf-support`, installed
/// once into target/pyenv from PyPI. None if python3 or pip is unavailable.
/// One test at a time sets it up: two tests of one binary creating the
/// venv at once rebuilt it under each other's pip (a CI run's script
/// died without a word).
pub fn python_with_mcap() -> Option<PathBuf> {
    let _one_at_a_time = PYTHON_SETUP.lock().unwrap_or_else(|poisoned| poisoned.into_inner());
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

/// The Python of [`python_with_mcap`] with `module` importable, pip
/// installing `package` into it on first use. None where pip cannot.
pub fn python_with(module: &str, package: &str) -> Option<PathBuf> {
    let python = python_with_mcap()?;
    let ready =
        || Command::new(&python).args(["-c", &format!("import {module}")]).output().is_ok_and(|o| o.status.success());
    if ready() {
        return Some(python);
    }
    let _one_at_a_time = PYTHON_SETUP.lock().unwrap_or_else(|poisoned| poisoned.into_inner());
    if ready() {
        return Some(python);
    }
    let installed = Command::new(&python)
        .args(["-m", "pip", "install", "--quiet", "--disable-pip-version-check", package])
        .status()
        .is_ok_and(|s| s.success());
    (installed && ready()).then_some(python)
}

/// The pid of a process named `name` whose command line mentions `arg`.
pub fn find_process(name: &str, arg: &Path) -> Option<i32> {
    let entries = std::fs::read_dir("/proc").ok()?;
    let needle = arg.to_string_lossy().to_string();
    entries.flatten().find_map(|e| {
        let pid: i32 = e.file_name().to_str()?.parse().ok()?;
        let cmdline = std::fs::read(e.path().join("cmdline")).ok()?;
        let cmd = String::from_utf8_lossy(&cmdline).replace('\0', " ");
        (cmd.contains(name) && cmd.contains(&needle)).then_some(pid)
    })
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

/// The test-only in-process driver: `dem_proc::run::run` and
/// `lbm_proc::run::run`, the same functions the two binaries call, on two
/// threads of this process exchanging over in-memory channels
/// ([`runtime::exchange::memory_pair`]). Writes dem.mcap, lbm.mcap and both
/// summaries into `out`; returns the DEM's and the LBM's summaries.
pub fn run_coupled_in_process(
    scene_path: &str,
    set: &[String],
    out: &Path,
) -> (schemas::summary::RunSummary, schemas::summary::RunSummary) {
    let scene = schemas::Scene::load(&repo_root().join(scene_path), set).expect("scene loads");
    let opts = runtime::process::RunOptions { out_dir: out.to_path_buf(), record: true, resume: None };
    let stop = std::sync::atomic::AtomicBool::new(false);
    let (dem_end, lbm_end) = runtime::exchange::memory_pair();
    std::thread::scope(|s| {
        let lbm = s.spawn(|| {
            let mut end = lbm_end;
            let r = lbm_proc::run::run(&scene, &opts, &stop, &mut runtime::process::Quiet, Some(&mut end));
            drop(end);
            r
        });
        let connect: dem_proc::hydro::Connect =
            Box::new(move |_| Ok(Box::new(dem_end) as Box<dyn runtime::exchange::LoadPeer>));
        let dem = dem_proc::run::run(&scene, &opts, &stop, &mut runtime::process::Quiet, Some(connect));
        let lbm = lbm.join().expect("LBM thread");
        (dem.expect("DEM run"), lbm.expect("LBM run"))
    })
}

/// Every `/dem/state` frame of a DEM recording, decoded.
pub fn dem_states(mcap_path: &Path) -> Vec<dem_proc::run::DemState> {
    let bytes = std::fs::read(mcap_path).expect("recording exists");
    let mut out = Vec::new();
    for msg in mcap::MessageStream::new(&bytes).expect("mcap") {
        let msg = msg.expect("message");
        if msg.channel.topic == schemas::topics::DEM_STATE {
            out.push(dem_proc::run::DemState::decode(&msg.data).expect("state decodes"));
        }
    }
    out
}

/// The raw messages of `topic` in a recording, in log order.
pub fn topic_messages(mcap_path: &Path, topic: &str) -> Vec<Vec<u8>> {
    let bytes = std::fs::read(mcap_path).expect("recording exists");
    mcap::MessageStream::new(&bytes)
        .expect("mcap")
        .map(|m| m.expect("message"))
        .filter(|m| m.channel.topic == topic)
        .map(|m| m.data.into_owned())
        .collect()
}

/// The fields of a protobuf message whose fields are all `double` (wire type
/// 1), by field number; fields at their default 0 are absent on the wire.
pub fn proto_doubles(bytes: &[u8]) -> std::collections::BTreeMap<u64, f64> {
    let mut out = std::collections::BTreeMap::new();
    let mut at = 0;
    while at < bytes.len() {
        let (mut key, mut shift) = (0u64, 0);
        loop {
            let b = bytes[at];
            at += 1;
            key |= u64::from(b & 0x7f) << shift;
            shift += 7;
            if b & 0x80 == 0 {
                break;
            }
        }
        assert_eq!(key & 7, 1, "field {} is not a double", key >> 3);
        out.insert(key >> 3, f64::from_le_bytes(bytes[at..at + 8].try_into().unwrap()));
        at += 8;
    }
    out
}

/// Topics whose messages hold wall-clock figures (rates, wait times) or
/// the processes' own log lines: all others of two runs of one scene must
/// match byte for byte.
pub const WALL_CLOCK_TOPICS: [&str; 6] =
    ["/log", "/dem/metrics", "/lbm/metrics", "/mpm/metrics", "/dem/coupling", "/lbm/coupling"];

/// Every message of a recording by topic: (log time, bytes).
pub fn messages(path: &Path) -> std::collections::BTreeMap<String, Vec<(u64, Vec<u8>)>> {
    let bytes = std::fs::read(path).expect("recording exists");
    let mut out = std::collections::BTreeMap::<String, Vec<(u64, Vec<u8>)>>::new();
    for m in mcap::MessageStream::new(&bytes).expect("an MCAP file") {
        let m = m.expect("a complete recording");
        out.entry(m.channel.topic.clone()).or_default().push((m.log_time, m.data.into_owned()));
    }
    out
}

/// The run's `summary.json`.
pub fn summary(out: &Path) -> schemas::summary::RunSummary {
    let text = std::fs::read_to_string(out.join("summary.json")).expect("summary.json");
    serde_json::from_str(&text).expect("a run summary")
}

/// Two runs of one scene in `straight` and `resumed` ended alike: every
/// message of their `run.mcap` but the wall-clock topics byte for byte at
/// the same times, as many frames of those, the same summary measures.
pub fn assert_same_run(straight: &Path, resumed: &Path) {
    let (a, b) = (messages(&straight.join("run.mcap")), messages(&resumed.join("run.mcap")));
    let topics: Vec<&String> = a.keys().filter(|t| !WALL_CLOCK_TOPICS.contains(&t.as_str())).collect();
    assert!(topics.iter().any(|t| t.ends_with("/state")), "the recording holds states: {topics:?}");
    for t in topics {
        let (x, y) = (&a[t], b.get(t).unwrap_or_else(|| panic!("the resumed recording lacks {t}")));
        assert_eq!(x.len(), y.len(), "{t}: {} messages straight, {} resumed", x.len(), y.len());
        for (k, (m, n)) in x.iter().zip(y).enumerate() {
            assert!(m.0 == n.0 && m.1 == n.1, "{t}: message {k} (t = {} ns) differs after the resume", m.0);
        }
    }
    for t in WALL_CLOCK_TOPICS.iter().filter(|t| **t != "/log") {
        let (n, m) = (a.get(*t).map_or(0, Vec::len), b.get(*t).map_or(0, Vec::len));
        assert_eq!(n, m, "{t}: as many frames resumed as straight");
    }
    let (s, r) = (summary(straight), summary(resumed));
    assert_eq!((s.steps, s.sim_time.to_bits()), (r.steps, r.sim_time.to_bits()), "the same end");
    assert_eq!(s.runout.to_bits(), r.runout.to_bits(), "the same runout");
    assert_eq!(s.front, r.front, "the same front history");
    assert_eq!(s.liquid_front, r.liquid_front, "the same liquid front history");
}
