//! End to end through the real binaries: `coupler run` on a small dry column,
//! the summary, the recording read back by the `mcap` crate and by the
//! official Python reader, `coupler inspect`, and Ctrl-C.

use std::path::PathBuf;
use std::process::{Command, Stdio};
use std::sync::OnceLock;
use std::time::{Duration, Instant};

use foxglove::Decode;
use integration_tests::{binary, coupler_run, repo_root, scratch_dir};

/// Runs the small dry column once for all tests of this file.
fn small_run() -> &'static PathBuf {
    static RUN: OnceLock<PathBuf> = OnceLock::new();
    RUN.get_or_init(|| coupler_run("dry_small", "scenes/validation/dry_small.toml", &[]))
}

fn summary() -> serde_json::Value {
    let text = std::fs::read_to_string(small_run().join("summary.json")).expect("summary.json written");
    serde_json::from_str(&text).expect("summary is JSON")
}

#[test]
fn summary_holds_the_measures() {
    let s = summary();
    for key in [
        "scene",
        "method",
        "sim_time",
        "wall_seconds",
        "steps",
        "throughput",
        "front",
        "runout",
        "deposit",
        "porosity_initial",
    ] {
        assert!(s.get(key).is_some(), "summary lacks {key}");
    }
    assert_eq!(s["method"], "dem");
    assert_eq!(s["scene"], "dry_small");
    let t_ref = s["t_ref"].as_f64().unwrap();
    assert!((t_ref - (0.03f64 / 9.81).sqrt()).abs() < 1e-12);
    // Porosity of a deposited monodisperse packing with its wall layers: 0.36–0.48.
    let n = s["porosity_initial"].as_f64().unwrap();
    assert!((0.36..0.48).contains(&n), "porosity {n}");

    let front = s["front"].as_array().unwrap();
    assert!(front.len() >= 20, "{} front samples", front.len());
    let f0 = &front[0];
    // At t = 0 the front is the gate: X_f = L0 within a grain (0.5 % of the mass
    // rule measures the leading edge of the grains).
    assert_eq!(f0["t"].as_f64().unwrap(), 0.0);
    assert!(f0["x_norm"].as_f64().unwrap().abs() < 2.5e-3 / 0.02, "{f0}");
    for f in front {
        let (t, tn, x, xn) = (
            f["t"].as_f64().unwrap(),
            f["t_norm"].as_f64().unwrap(),
            f["x"].as_f64().unwrap(),
            f["x_norm"].as_f64().unwrap(),
        );
        assert!((tn - t / t_ref).abs() < 1e-9 && (xn - (x - 0.02) / 0.02).abs() < 1e-9);
    }
    // The column collapses: the front advances well beyond the gate, and the
    // runout is the last front sample.
    let runout = s["runout"].as_f64().unwrap();
    assert!(runout > 0.5, "runout {runout}");
    assert_eq!(runout, front.last().unwrap()["x_norm"].as_f64().unwrap());
    // The front of the connected mass: same sampling, starts at the gate, and
    // ends no further than the front of all grains plus one grain.
    let connected = s["front_connected"].as_array().unwrap();
    assert_eq!(connected.len(), front.len());
    assert!((connected[0]["x"].as_f64().unwrap() - f0["x"].as_f64().unwrap()).abs() < 2.5e-3);
    let runout_connected = s["runout_connected"].as_f64().unwrap();
    assert!(runout_connected > 0.5 && runout_connected <= runout + 2.5e-3 / 0.02, "{runout_connected} vs {runout}");
    // The pile's edge starts at the gate (the column's averaged height drops
    // from H0 to 0 within one bin of L0) and ends behind the mass front.
    let pile = s["front_pile"].as_array().unwrap();
    assert_eq!(pile.len(), front.len());
    let edge0 = pile[0]["x"].as_f64().unwrap();
    assert!((edge0 - 0.02).abs() < 2.5e-3, "pile edge at t = 0: {edge0}");
    let runout_pile = s["runout_pile"].as_f64().unwrap();
    assert!(runout_pile > 0.3 && runout_pile <= runout + 2.5e-3 / 0.02, "{runout_pile} vs {runout}");
    // Deposit: grains spread out, the pile is lower than the initial column.
    let deposit = s["deposit"].as_array().unwrap();
    let h_max = deposit.iter().map(|p| p[1].as_f64().unwrap()).fold(0.0, f64::max);
    assert!(h_max < 0.0315 && h_max > 0.005, "deposit height {h_max}");
    let pst = s["throughput"]["particle_steps_per_s"].as_f64().unwrap();
    let grains = s["dem"]["particles"].as_f64().unwrap();
    let expected = s["steps"].as_f64().unwrap() * grains / s["wall_seconds"].as_f64().unwrap();
    assert!((pst - expected).abs() < 1e-6 * expected);
    // The stage timers under the names docs/recording.md gives, within the run's wall time.
    let stages = s["dem"]["stage_seconds"].as_object().unwrap();
    let names: Vec<&str> = stages.keys().map(String::as_str).collect();
    assert_eq!(names, ["compute_contact_forces", "kick_and_drift", "sum_and_kick", "update_neighbours"]);
    let sum: f64 = stages.values().map(|v| v.as_f64().unwrap()).sum();
    assert!(sum > 0.0 && sum <= s["wall_seconds"].as_f64().unwrap(), "stage seconds {sum}");
}

#[test]
fn recording_reads_back_with_the_mcap_crate() {
    let bytes = std::fs::read(small_run().join("run.mcap")).expect("run.mcap written");
    let summary = mcap::Summary::read(&bytes).unwrap().expect("finished file has a summary section");
    let topics: Vec<String> = summary.channels.values().map(|c| c.topic.clone()).collect();
    for t in ["/dem/particles", "/dem/metrics", "/dem/state", "/log"] {
        assert!(topics.iter().any(|x| x == t), "missing {t} in {topics:?}");
    }
    let s = summary_json_from(&bytes, &summary);
    let grains = s["dem"]["particles"].as_u64().unwrap() as usize;
    let mut clouds = 0;
    let mut last_state = None;
    for msg in mcap::MessageStream::new(&bytes).unwrap() {
        let msg = msg.unwrap();
        match msg.channel.topic.as_str() {
            "/dem/particles" => {
                let cloud = foxglove::schemas::PointCloud::decode(&msg.data[..]).unwrap();
                assert_eq!(cloud.point_stride, 24);
                assert_eq!(cloud.data.len(), grains * 24, "one point per grain");
                // Every grain inside the flume (z above the floor minus a small overlap).
                for p in cloud.data.chunks(24) {
                    let z = f32::from_le_bytes(p[8..12].try_into().unwrap());
                    let r = f32::from_le_bytes(p[12..16].try_into().unwrap());
                    assert!(z > r * 0.9 && (r - 1.25e-3).abs() < 1e-6, "z {z} r {r}");
                }
                clouds += 1;
            }
            "/dem/state" => last_state = Some(msg.data.to_vec()),
            _ => {}
        }
    }
    assert_eq!(clouds, s["front"].as_array().unwrap().len(), "one cloud per front sample");
    // The full-precision state decodes and matches the final summary exactly.
    let state = dem_proc::run::DemState::decode(&last_state.expect("state frames")).unwrap();
    assert_eq!(state.grains.len(), grains);
    assert_eq!(state.time, s["sim_time"].as_f64().unwrap());
}

fn summary_json_from(bytes: &[u8], summary: &mcap::Summary) -> serde_json::Value {
    let idx = summary.metadata_indexes.iter().find(|m| m.name == "summary").expect("summary metadata");
    let meta = mcap::read::metadata(bytes, idx).unwrap();
    serde_json::from_str(&meta.metadata["json"]).unwrap()
}

#[test]
fn inspect_lists_topics_and_summary() {
    let out = Command::new(binary("coupler")).arg("inspect").arg(small_run().join("run.mcap")).output().unwrap();
    assert!(out.status.success());
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(text.contains("/dem/particles") && text.contains("foxglove.PointCloud"), "{text}");
    assert!(text.contains("runout"), "{text}");
    let s = summary();
    let n = s["front"].as_array().unwrap().len();
    assert!(text.lines().any(|l| l.starts_with("/dem/metrics") && l.contains(&format!(" {n} "))), "{text}");
}

/// A recording cut short (a writer killed mid-chunk, a disk that filled):
/// `inspect` reads what it can, says which record the file ends inside and
/// how much of it is missing, and does not fail.
#[test]
fn inspect_says_what_a_cut_recording_lost() {
    let bytes = std::fs::read(small_run().join("run.mcap")).unwrap();
    let cut = scratch_dir("inspect_cut").join("cut.mcap");
    let keep = bytes.len() * 6 / 10;
    std::fs::write(&cut, &bytes[..keep]).unwrap();
    let out = Command::new(binary("coupler")).arg("inspect").arg(&cut).output().unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{text}{}", String::from_utf8_lossy(&out.stderr));
    assert!(text.contains("no summary section") && text.contains("/dem/particles"), "{text}");
    let cut_line = text.lines().find(|l| l.starts_with("cut")).unwrap_or_else(|| panic!("no 'cut' line:\n{text}"));
    // The record the file ends in claims bytes the copy lacks: at most what was cut off.
    let missing: usize = cut_line.split("its last ").nth(1).and_then(|r| r.split(' ').next()).unwrap().parse().unwrap();
    assert!(missing > 0 && missing <= bytes.len() - keep, "{cut_line}");
}

/// A finished recording damaged since (bytes overwritten in its middle, as
/// a bad disk or a bad copy would): `inspect` reads every chunk, not only
/// the summary section, says how many messages are still readable and up
/// to when, and exits 1.
#[test]
fn inspect_tells_a_damaged_finished_recording() {
    let mut bytes = std::fs::read(small_run().join("run.mcap")).unwrap();
    let at = bytes.len() / 2;
    for b in &mut bytes[at..at + 64] {
        *b ^= 0x5a;
    }
    let damaged = scratch_dir("inspect_damaged").join("damaged.mcap");
    std::fs::write(&damaged, &bytes).unwrap();
    let out = Command::new(binary("coupler")).arg("inspect").arg(&damaged).output().unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert_eq!(out.status.code(), Some(1), "{text}{}", String::from_utf8_lossy(&out.stderr));
    let line = text.lines().find(|l| l.starts_with("damaged")).unwrap_or_else(|| panic!("no 'damaged' line:\n{text}"));
    let (before, after) = line.split_once(" of its ").unwrap_or_else(|| panic!("no counts: {line}"));
    let read: u64 = before.rsplit(' ').next().and_then(|w| w.parse().ok()).unwrap_or_else(|| panic!("{line}"));
    let recorded: u64 = after.split(' ').next().and_then(|w| w.parse().ok()).unwrap_or_else(|| panic!("{line}"));
    assert!(read < recorded, "fewer readable than recorded: {line}");
    assert!(String::from_utf8_lossy(&out.stderr).contains("is damaged"), "the last word names it");
}

/// The recording read by a reader this project did not write: PyPI `mcap`
/// with `mcap-protobuf-support`, through the script printed in docs/recording.md.
#[test]
fn python_reader_prints_the_front() {
    let Some(python) = integration_tests::python_with_mcap() else {
        assert!(std::env::var_os("CI").is_none(), "CI must be able to install the Python mcap reader");
        eprintln!("SKIPPED: python3 with pip is not available on this machine");
        return;
    };
    let script = repo_root().join("docs/read_front.py");
    let out = Command::new(python).arg(&script).arg(small_run().join("run.mcap")).output().unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let text = String::from_utf8_lossy(&out.stdout);
    let s = summary();
    let front = s["front"].as_array().unwrap();
    let rows: Vec<Vec<f64>> = text
        .lines()
        .filter(|l| !l.starts_with("runout"))
        .map(|l| l.split_whitespace().map(|x| x.parse().unwrap()).collect())
        .collect();
    assert_eq!(rows.len(), front.len());
    for (row, f) in rows.iter().zip(front) {
        for (v, key) in row.iter().zip(["t", "t_norm", "x", "x_norm"]) {
            let want = f[key].as_f64().unwrap();
            assert!((v - want).abs() <= 1e-5 * want.abs().max(1e-3), "{key}: python {v} vs {want}");
        }
    }
    let runout: f64 = text.lines().find_map(|l| l.strip_prefix("runout ")).unwrap().trim().parse().unwrap();
    assert!((runout - s["runout"].as_f64().unwrap()).abs() < 1e-5 * runout.abs());
}

/// Starts the small column with no end and waits until its collapse (and
/// recording) has begun. Output is discarded so no pipe can fill up.
fn start_endless_run(name: &str) -> (std::process::Child, PathBuf) {
    let out = scratch_dir(name);
    let child = Command::new(binary("coupler"))
        .current_dir(repo_root())
        .env("SGF_CACHE_DIR", out.join("cache"))
        .args(["run", "scenes/validation/dry_small.toml", "--quiet"])
        .args(["--set", "output.end_time=100", "--set", "output.stop_at_rest=false", "--out"])
        .arg(&out)
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let started = Instant::now();
    while !out.join("dem.mcap").exists() {
        assert!(started.elapsed() < Duration::from_secs(120), "run never started");
        std::thread::sleep(Duration::from_millis(100));
    }
    (child, out)
}

/// Ctrl-C: the solver stops at a step boundary, the recording is finalised,
/// the summary says `interrupted`, the exit status is 130, no process is left.
#[test]
fn ctrl_c_stops_cleanly() {
    let (mut child, out) = start_endless_run("interrupted");
    std::thread::sleep(Duration::from_millis(1500));
    // SAFETY: signalling the child we spawned.
    unsafe { libc::kill(child.id() as i32, libc::SIGINT) };
    let status = child.wait().unwrap();
    assert_eq!(status.code(), Some(130));
    let s: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap();
    assert_eq!(s["status"], "interrupted");
    assert!(s["sim_time"].as_f64().unwrap() > 0.0 && s["sim_time"].as_f64().unwrap() < 100.0);
    let bytes = std::fs::read(out.join("run.mcap")).unwrap();
    assert!(mcap::Summary::read(&bytes).unwrap().is_some(), "recording finalised");
    assert!(!integration_tests::process_running("dem_proc", &out), "dem_proc left running");
}

/// An explicit packing (no deposition, porosity undefined: null in the
/// summary): a sphere dropped from 10 mm. A bouncing ball with restitution e
/// dropped from h comes to rest after t = √(2h/g)·(1 + e)/(1 − e) = 0.705 s;
/// the run stops at rest shortly after, never before.
#[test]
fn bouncing_sphere_comes_to_rest_on_time() {
    let out = scratch_dir("bouncing_sphere");
    let status = Command::new(binary("coupler"))
        .current_dir(repo_root())
        .args(["run", "scenes/validation/bouncing_sphere.toml", "--quiet", "--out"])
        .arg(&out)
        .status()
        .unwrap();
    assert!(status.success());
    let s: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap();
    assert!(s["porosity_initial"].is_null(), "{}", s["porosity_initial"]);
    assert_eq!(s["status"], "at_rest");
    let (h, g, e) = (0.01f64, 9.81f64, 0.88f64);
    let t_rest = (2.0 * h / g).sqrt() * (1.0 + e) / (1.0 - e);
    let t = s["sim_time"].as_f64().unwrap();
    assert!(t > 0.95 * t_rest && t < t_rest + 0.1, "at rest at {t} s, bounce sequence ends at {t_rest} s");
    // Resting on the floor: the deposit is one grain high.
    let top = s["deposit"].as_array().unwrap().iter().map(|p| p[1].as_f64().unwrap()).fold(0.0, f64::max);
    assert!((top - 2.5e-3).abs() < 1e-5, "{top}");
}

/// The coupler killed outright (SIGKILL, no chance to clean up): the solver
/// notices through PR_SET_PDEATHSIG, stops at a step boundary, and leaves a
/// finished recording whose summary says `interrupted`; no process is left.
#[test]
fn killed_coupler_leaves_no_orphan_and_a_finished_recording() {
    let (mut child, out) = start_endless_run("coupler_killed");
    std::thread::sleep(Duration::from_millis(1000));
    child.kill().unwrap(); // SIGKILL
    child.wait().unwrap();
    let killed = Instant::now();
    while integration_tests::process_running("dem_proc", &out) {
        assert!(killed.elapsed() < Duration::from_secs(2), "dem_proc still running 2 s after the coupler died");
        std::thread::sleep(Duration::from_millis(50));
    }
    let bytes = std::fs::read(out.join("dem.mcap")).unwrap();
    let summary = mcap::Summary::read(&bytes).unwrap().expect("recording finished by dem_proc itself");
    let s = summary_json_from(&bytes, &summary);
    assert_eq!(s["status"], "interrupted");
    assert!(s["sim_time"].as_f64().unwrap() > 0.0);
}

/// The Python decoder of `/dem/state` printed in docs/recording.md reads a
/// fresh recording the way the solver does (the doc cannot drift from the
/// layout unnoticed).
#[test]
fn python_state_decoder_in_the_docs_matches_the_layout() {
    let Some(python) = integration_tests::python_with_mcap() else {
        assert!(std::env::var_os("CI").is_none(), "CI must be able to install the Python mcap reader");
        eprintln!("SKIPPED: python3 with pip is not available on this machine");
        return;
    };
    let doc = std::fs::read_to_string(repo_root().join("docs/recording.md")).unwrap();
    let start = doc.find("A decoder in Python").expect("decoder section");
    let code_start = doc[start..].find("```python\n").unwrap() + start + "```python\n".len();
    let code_end = doc[code_start..].find("```").unwrap() + code_start;
    let script = format!(
        "{}\nimport sys\nfrom mcap.reader import make_reader\nlast = None\nwith open(sys.argv[1], 'rb') as f:\n    for _, _, m in make_reader(f).iter_messages(topics=['/dem/state']):\n        last = m.data\ns = decode_state(last)\nprint(s['version'], s['step'], len(s['pos']), len(s['ids']), len(s['block_starts']), len(s['pairs']), len(s['walls']), len(s['walls_active']), repr(s['time']), repr(s['pos'][-1][2]), s['ids'][-1])\n",
        &doc[code_start..code_end]
    );
    let mcap = small_run().join("run.mcap");
    let out = Command::new(python).arg("-c").arg(&script).arg(&mcap).output().unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let state = integration_tests::dem_states(&mcap).pop().expect("a state");
    let want = format!(
        "{} {} {} {} {} {} {} {} {:?} {:?} {}",
        state.version,
        state.step,
        state.grains.len(),
        state.ids.len(),
        state.block_starts.len(),
        state.histories.pairs.len(),
        state.histories.walls.len(),
        state.walls_active.len(),
        state.time,
        state.grains.pos.last().unwrap()[2],
        state.ids.last().unwrap()
    );
    assert_eq!(String::from_utf8_lossy(&out.stdout).trim(), want);
}
