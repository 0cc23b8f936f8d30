//! `coupler campaign`: the paper's Table 1 matrix in its quick form (20
//! runs, both methods, dry and saturated), the report read back against
//! the runs' own summaries, resuming a campaign, interrupting one, and
//! the refusals.

use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::sync::OnceLock;
use std::time::{Duration, Instant};

use integration_tests::{binary, process_running, repo_root, scratch_dir, summary};
use schemas::summary::RunSummary;

fn campaign(args: &[&str], out: &Path, cache: &Path) -> Output {
    Command::new(binary("coupler"))
        .current_dir(repo_root())
        .env("SGF_CACHE_DIR", cache)
        .arg("campaign")
        .args(args)
        .arg("--out")
        .arg(out)
        .output()
        .expect("coupler starts")
}

/// The quick campaign, once for all tests of this file (~3 min on 2 cores).
fn quick() -> &'static (PathBuf, Output) {
    static RUN: OnceLock<(PathBuf, Output)> = OnceLock::new();
    RUN.get_or_init(|| {
        let dir = scratch_dir("campaign_quick");
        let out = dir.join("out");
        let o = campaign(&["scenes/ceccato2020", "--quick"], &out, &dir.join("cache"));
        assert!(o.status.success(), "quick campaign failed:\n{}", String::from_utf8_lossy(&o.stderr));
        (out, o)
    })
}

const CASES: [&str; 20] = [
    "dry_h030",
    "dry_h040",
    "dry_h050",
    "dry_h060",
    "dry_h070",
    "sat_h030",
    "sat_h040",
    "sat_h050",
    "sat_h060",
    "sat_h070",
    "mpm_dry_h030",
    "mpm_dry_h040",
    "mpm_dry_h050",
    "mpm_dry_h060",
    "mpm_dry_h070",
    "mpm_sat_h030",
    "mpm_sat_h040",
    "mpm_sat_h050",
    "mpm_sat_h060",
    "mpm_sat_h070",
];

/// The report's table rows that start with `| first |`, split into cells.
fn rows<'a>(report: &'a str, section: &str) -> Vec<Vec<&'a str>> {
    let start = report.find(section).unwrap_or_else(|| panic!("report lacks {section:?}"));
    let body = &report[start..];
    let end = body[section.len()..].find("\n## ").map_or(body.len(), |e| e + section.len());
    let lines: Vec<&str> = body[..end].lines().collect();
    // A header is the row above a |---| separator.
    (0..lines.len())
        .filter(|&i| lines[i].starts_with("| ") && !lines.get(i + 1).is_some_and(|n| n.starts_with("|---")))
        .map(|i| lines[i].trim_matches('|').split('|').map(str::trim).collect())
        .collect()
}

/// The front at `t` as the report reads it: linear between samples; a
/// run that stopped at rest keeps its last front after its end.
fn front_at(s: &RunSummary, t: f64) -> f64 {
    let f = &s.front;
    let i = f.partition_point(|p| p.t_norm < t);
    if i >= f.len() && s.status.as_str() == "at_rest" {
        return f.last().map_or(f64::NAN, |p| p.x_norm);
    }
    if i == 0 || i >= f.len() {
        return f64::NAN;
    }
    let (a, b) = (&f[i - 1], &f[i]);
    a.x_norm + (b.x_norm - a.x_norm) * (t - a.t_norm) / (b.t_norm - a.t_norm)
}

/// Every case ran to its end and the runs table holds, row by row, the
/// numbers of its `summary.json`: status, runout, the fronts read at
/// t/t_ref = 1, 2, 4 (linear between samples), the liquid front.
#[test]
fn quick_campaign_reports_every_run_with_its_summary() {
    let (out, _) = quick();
    let report = std::fs::read_to_string(out.join("report.md")).expect("report.md written");
    assert!(report.contains("20 of 20 cases finished"), "{report}");
    let table = rows(&report, "## Runs");
    assert_eq!(table.len(), CASES.len(), "one row per case");
    for (row, name) in table.iter().zip(CASES) {
        assert_eq!(row[0], name, "rows in the campaign file's order");
        let s = summary(&out.join("cases").join(name));
        assert!(matches!(row[4], "completed" | "at_rest"), "{name}: {row:?}");
        assert_eq!(row[4], s.status.as_str());
        assert_eq!(row[8], format!("{:.3}", s.runout), "{name}: runout");
        let fronts: Vec<String> = [1.0, 2.0, 4.0]
            .iter()
            .map(|&t| {
                let x = front_at(&s, t);
                if x.is_finite() {
                    format!("{x:.2}")
                } else {
                    "–".into()
                }
            })
            .collect();
        assert_eq!(row[10], fronts.join(" / "), "{name}: fronts");
        if name.contains("sat") {
            let liquid = s.liquid_front.last().expect("a saturated run measures its liquid front").x_norm;
            assert_eq!(row[11], format!("{liquid:.3}"), "{name}: liquid front");
        } else {
            assert_eq!(row[11], "–", "{name}: a dry run has no liquid front");
        }
        // The method and the aspect ratio come from the scene.
        let method = if name.starts_with("mpm") {
            "mpm"
        } else if name.starts_with("sat") {
            "dem_lbm"
        } else {
            "dem"
        };
        assert_eq!(row[1], method);
        let h: f64 = name[name.len() - 3..].parse::<f64>().unwrap() / 1000.0;
        assert_eq!(row[3], format!("{:.2}", h / 0.04));
    }
}

/// The runout table is the mean of each case's runs, one row per method,
/// condition and aspect ratio; the methods table pairs DEM and MPM for
/// each of the ten cases. Across a, the runout grows from the lowest to
/// the tallest column for each method and condition (the paper's Fig. 12;
/// a = 0.75 against 1.75 more than doubles the released height, a trend a
/// coarse run keeps).
#[test]
fn quick_campaign_runout_and_methods_tables_follow_the_runs() {
    let (out, _) = quick();
    let report = std::fs::read_to_string(out.join("report.md")).unwrap();
    let runout = rows(&report, "## Runout against aspect ratio");
    assert_eq!(runout.len(), 20, "{runout:?}");
    for r in &runout {
        let prefix = match (r[0], r[1]) {
            ("DEM", "dry") => "dry",
            ("DEM", "saturated") => "sat",
            ("MPM", "dry") => "mpm_dry",
            ("MPM", "saturated") => "mpm_sat",
            other => panic!("unexpected group {other:?}"),
        };
        let a: f64 = r[2].parse().unwrap();
        let name = format!("{prefix}_h{:03}", (a * 40.0).round() as u32);
        let s = summary(&out.join("cases").join(&name));
        assert_eq!(r[3], "1", "{name}: one run per case");
        assert_eq!(r[4], format!("{:.3}", s.runout), "{name}");
    }
    for group in runout.chunks(5) {
        let first: f64 = group[0][4].parse().unwrap();
        let last: f64 = group[4][4].parse().unwrap();
        assert!(last > first, "runout does not grow with a for {} {}: {first} -> {last}", group[0][0], group[0][1]);
    }
    let methods = rows(&report, "## The two methods side by side");
    assert_eq!(methods.len(), 10, "{methods:?}");
    for m in &methods {
        let ratio: f64 = m[6].trim_end_matches(" *").parse().unwrap();
        let (dem, mpm): (f64, f64) = (m[4].parse().unwrap(), m[5].parse().unwrap());
        assert!((ratio - mpm / dem).abs() < 0.006, "{m:?}");
        // The flag is set on the unrounded ratio: check it away from the threshold.
        if ((mpm / dem - 1.0).abs() - 0.2).abs() > 0.01 {
            assert_eq!(m[6].ends_with('*'), (mpm / dem - 1.0).abs() > 0.2, "{m:?}");
        }
    }
}

/// Every figure the report names exists as SVG and PNG; each front
/// figure of a saturated case draws four curves (both methods' solid and
/// liquid fronts), each dry one two, and the runout figure one line per
/// method and condition.
#[test]
fn quick_campaign_draws_every_figure() {
    let (out, _) = quick();
    let report = std::fs::read_to_string(out.join("report.md")).unwrap();
    let figures: Vec<&str> = report.match_indices("](figures/").map(|(i, _)| &report[i + 10..]).collect();
    let mut svgs = 0;
    for f in figures {
        let name = &f[..f.find(')').unwrap()];
        let path = out.join("figures").join(name);
        let bytes = std::fs::read(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        if name.ends_with(".svg") {
            svgs += 1;
            let svg = String::from_utf8(bytes).unwrap();
            assert!(svg.starts_with("<svg") && svg.trim_end().ends_with("</svg>"), "{name}");
            let lines = svg.matches("<polyline").count();
            if name.starts_with("front_saturated") {
                // Four curves, four legend keys.
                assert!(lines >= 8, "{name}: {lines} lines");
            } else if name.starts_with("front_dry") {
                assert!(lines >= 4, "{name}: {lines} lines");
            }
        } else {
            assert!(name.ends_with(".png"), "{name}");
            assert_eq!(&bytes[..8], b"\x89PNG\r\n\x1a\n", "{name}");
        }
    }
    // 10 cases, 4 overviews, runout, 2 deposits, 10 DEM coordination
    // charts, the MPM's fluidised share; a snapshot (PNG) per run.
    assert_eq!(svgs, 28);
    for name in CASES {
        assert!(report.contains(&format!("](figures/snapshots_{name}.png)")), "no snapshots of {name}");
    }
    let runout = std::fs::read_to_string(out.join("figures/runout.svg")).unwrap();
    for label in ["DEM dry", "DEM saturated", "MPM dry", "MPM saturated"] {
        assert!(runout.contains(label), "runout figure lacks {label}");
    }
    // The campaign's two [[compare]] figures: both methods in two rows,
    // three times in three columns of 600 px.
    for name in ["methods_h030", "methods_h060"] {
        assert!(report.contains(&format!("](figures/compare_{name}.png)")), "no comparison {name}");
        let png = std::fs::read(out.join(format!("figures/compare_{name}.png"))).unwrap();
        let size = |at: usize| u32::from_be_bytes(png[at..at + 4].try_into().unwrap());
        let (width, height) = (size(16), size(20));
        assert_eq!(width, 1800, "{name}: three columns of 600 px");
        assert!((34 + 2 * 110..=34 + 2 * 420).contains(&height), "{name}: two rows, {height} px");
    }
    assert!(report.contains("Rows top to bottom: `sat_h060`, `mpm_sat_h060`; columns at t/t_ref = 1, 2, 4."));
}

/// The same command again runs nothing that finished; a case whose
/// summary is gone is run again, alone, and gives the same result.
#[test]
fn a_campaign_continues_where_it_stopped() {
    let (out, _) = quick();
    let again = scratch_dir("campaign_again");
    let copy = again.join("out");
    let status = Command::new("cp").arg("-r").arg(out).arg(&copy).status().unwrap();
    assert!(status.success());
    let before = summary(&copy.join("cases/mpm_dry_h030"));
    std::fs::remove_file(copy.join("cases/mpm_dry_h030/summary.json")).unwrap();
    let o = campaign(&["scenes/ceccato2020", "--quick"], &copy, &again.join("cache"));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    assert!(err.contains("19 already finished, 1 to run"), "{err}");
    assert!(err.contains("mpm_dry_h030 started"), "{err}");
    let after = summary(&copy.join("cases/mpm_dry_h030"));
    assert_eq!(after.runout, before.runout, "same scene, same result");
    assert_eq!(after.front.len(), before.front.len());
    let report = std::fs::read_to_string(copy.join("report.md")).unwrap();
    assert!(report.contains("20 of 20 cases finished. This invocation ran 1 case(s) in "), "{report}");
    // Again with everything finished: the report is rewritten, nothing run.
    let o = campaign(&["scenes/ceccato2020", "--quick"], &copy, &again.join("cache"));
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let report = std::fs::read_to_string(copy.join("report.md")).unwrap();
    assert!(report.contains("This invocation ran no case (it wrote the report from the finished runs)"), "{report}");
    // A full campaign is not continued in a quick one's folder.
    let o = campaign(&["scenes/ceccato2020"], &copy, &again.join("cache"));
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(err.contains("holds the campaign ceccato2020 --quick, not ceccato2020") && err.contains("--out"), "{err}");
}

/// A campaign file of its own: two small dry columns with checkpoints.
fn small_campaign(dir: &Path) -> PathBuf {
    let root = repo_root();
    let file = dir.join("campaign.toml");
    let scene = root.join("scenes/validation/dry_small.toml");
    let text = format!(
        "[campaign]\nname = \"small\"\n\n[[case]]\nname = \"a\"\nscene = {scene:?}\nset = [\"output.end_time=1.5\", \"output.stop_at_rest=false\", \"output.checkpoint_interval=0.05\"]\n\n\
         [[case]]\nname = \"b\"\nscene = {scene:?}\nset = [\"output.end_time=1.5\", \"output.stop_at_rest=false\", \"output.checkpoint_interval=0.05\", \"particles[0].packing.seed=2\"]\n"
    );
    std::fs::write(&file, text).unwrap();
    file
}

/// A second campaign on the folder of a running one is refused. Ctrl-C:
/// the campaign stops its running cases (each keeps its recording and
/// checkpoints), writes the report, exits 130, leaves no process; the
/// same command then finishes the cases, continuing from checkpoints.
#[test]
fn an_interrupted_campaign_stops_cleanly_and_continues() {
    let dir = scratch_dir("campaign_interrupted");
    let file = small_campaign(&dir);
    let out = dir.join("out");
    let mut child = Command::new(binary("coupler"))
        .current_dir(repo_root())
        .env("SGF_CACHE_DIR", dir.join("cache"))
        .arg("campaign")
        .arg(&file)
        .args(["--jobs", "2"])
        .arg("--out")
        .arg(&out)
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    // Wait until both cases have written a checkpoint.
    let start = Instant::now();
    let has_checkpoint = |case: &str| {
        std::fs::read_dir(out.join("cases").join(case).join("checkpoints"))
            .map(|d| d.flatten().any(|e| e.path().extension().is_some_and(|x| x == "ckpt")))
            .unwrap_or(false)
    };
    while !(has_checkpoint("a") && has_checkpoint("b")) {
        assert!(start.elapsed() < Duration::from_secs(120), "no checkpoints after 120 s");
        assert!(child.try_wait().unwrap().is_none(), "campaign ended before its checkpoints");
        std::thread::sleep(Duration::from_millis(50));
    }
    // A second campaign on the same folder is refused while the first runs.
    let second = campaign(&[file.to_str().unwrap()], &out, &dir.join("cache"));
    let err = String::from_utf8_lossy(&second.stderr);
    assert_eq!(second.status.code(), Some(1), "{err}");
    assert!(err.contains(&format!("another campaign is running in {} (pid {})", out.display(), child.id())), "{err}");
    // SAFETY: signalling our own child.
    unsafe { libc::kill(child.id() as i32, libc::SIGINT) };
    let o = child.wait_with_output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(130), "{err}");
    assert!(err.contains("campaign interrupted") && err.contains("run the same command again"), "{err}");
    assert!(!process_running("coupler", &out.join("cases")), "a case's coupler outlived the campaign");
    for proc in ["dem_proc", "coupler"] {
        assert!(!process_running(proc, &out), "{proc} left running");
    }
    let report = std::fs::read_to_string(out.join("report.md")).unwrap();
    assert!(report.contains("0 of 2 cases finished") && report.contains("interrupted"), "{report}");
    for case in ["a", "b"] {
        let s = summary(&out.join("cases").join(case));
        assert_eq!(s.status.as_str(), "interrupted", "{case}");
    }
    let o = campaign(&[file.to_str().unwrap(), "--jobs", "2"], &out, &dir.join("cache"));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    assert!(err.contains("a resumed from its checkpoint") && err.contains("b resumed from its checkpoint"), "{err}");
    // Each case's log keeps both attempts, and its wall time in the
    // report is their sum.
    for case in ["a", "b"] {
        let log = std::fs::read_to_string(out.join("cases").join(format!("{case}.log"))).unwrap();
        assert!(
            log.contains("=== coupler campaign: started afresh") && log.contains("=== coupler campaign: resumed"),
            "{log}"
        );
        let attempts = std::fs::read_to_string(out.join("cases").join(format!("{case}.attempts"))).unwrap();
        assert_eq!(attempts.lines().map(|l| l.split(' ').next().unwrap()).collect::<Vec<_>>(), ["fresh", "resume"]);
    }
    for case in ["a", "b"] {
        let s = summary(&out.join("cases").join(case));
        assert!(matches!(s.status.as_str(), "completed" | "at_rest"), "{case}: {}", s.status);
    }
    let report = std::fs::read_to_string(out.join("report.md")).unwrap();
    assert!(report.contains("2 of 2 cases finished"), "{report}");
}

/// A campaign file with a mistake stops before any run, naming it.
#[test]
fn bad_campaign_files_are_refused_with_the_reason() {
    let dir = scratch_dir("campaign_bad");
    let out = dir.join("out");
    let cache = dir.join("cache");
    let write = |text: &str| {
        let f = dir.join("campaign.toml");
        std::fs::write(&f, text).unwrap();
        f
    };
    let check = |file: &Path, expect: &[&str]| {
        let o = campaign(&[file.to_str().unwrap()], &out, &cache);
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{err}");
        for e in expect {
            assert!(err.contains(e), "expected {e:?} in: {err}");
        }
        assert!(!out.join("cases").exists(), "nothing run");
    };
    let scene = repo_root().join("scenes/validation/dry_small.toml");
    check(&write("[campaign]\nname = \"x\"\nsceens = []\n"), &["sceens"]);
    check(&write("[campaign]\nname = \"x\"\n"), &["no cases"]);
    check(
        &write(&format!(
            "[campaign]\nname = \"x\"\n[[case]]\nname = \"a\"\nscene = {scene:?}\nset = [\"dem.friction=-1\"]\n"
        )),
        &["case", "dem.friction"],
    );
    check(
        &write(&format!(
            "[campaign]\nname = \"x\"\n[[case]]\nname = \"a\"\nscene = {scene:?}\n[[case]]\nname = \"a\"\nscene = {scene:?}\n"
        )),
        &["two cases are named \"a\""],
    );
    check(&dir.join("missing.toml"), &["cannot read campaign file"]);
    check(
        &write(&format!("[campaign]\nname = \"x\"\n[[case]]\nname = \"../a\"\nscene = {scene:?}\n")),
        &["case name \"../a\""],
    );
    check(
        &write(&format!("[campaign]\nname = \"x\"\n[[case]]\nname = \"a\"\nscene = {scene:?}\nstudy = \"s\"\n")),
        &["study and level go together"],
    );
    let one_case = format!("[campaign]\nname = \"x\"\n[[case]]\nname = \"a\"\nscene = {scene:?}\n");
    for (compare, reason) in [
        ("name = \"f\"\ncases = [\"b\"]\ntimes = [1.0]", "no case is named \"b\""),
        ("name = \"f\"\ncases = [\"a\"]\ntimes = []", "0 times; give 1 to 8"),
        ("name = \"f\"\ncases = [\"a\"]\ntimes = [-1.0]", "time -1 is not a t/t_ref >= 0"),
        ("name = \"f/g\"\ncases = [\"a\"]\ntimes = [1.0]", "compare \"f/g\": use letters"),
        ("name = \"f\"\ncases = [\"a\"]\ntimes = [1.0]\nwhen = 2", "when"),
    ] {
        check(&write(&format!("{one_case}[[compare]]\n{compare}\n")), &[reason]);
    }
}

/// The figures read from the recordings agree with the solvers' own
/// measures: the coordination curves' means at the start and the end are
/// the DEM summary's, and the largest fluidised share over the recorded
/// frames is the MPM summary's `fluidised_fraction_max` (its soil points
/// carry equal masses, so the point share is the mass share).
#[test]
fn quick_campaign_recorded_figures_agree_with_the_summaries() {
    let (out, _) = quick();
    for name in CASES.iter().filter(|n| !n.starts_with("mpm")) {
        let s = summary(&out.join("cases").join(name));
        let dem = s.dem.as_ref().unwrap();
        let svg = std::fs::read_to_string(out.join(format!("figures/coordination_{name}.svg"))).unwrap();
        let means: Vec<f64> = svg
            .match_indices("(mean ")
            .map(|(i, _)| svg[i + 6..].split(')').next().unwrap().parse().unwrap())
            .collect();
        assert!(means.len() >= 3, "{name}: {means:?}");
        assert!(
            (means[0] - dem.coordination_initial).abs() <= 0.005,
            "{name}: {means:?} against {}",
            dem.coordination_initial
        );
        let last = *means.last().unwrap();
        assert!((last - dem.coordination_final).abs() <= 0.005, "{name}: {means:?} against {}", dem.coordination_final);
    }
    let report = std::fs::read_to_string(out.join("report.md")).unwrap();
    let table = rows(&report, "## The MPM's fluidised share");
    assert_eq!(table.len(), 10, "{table:?}");
    for r in &table {
        let s = summary(&out.join("cases").join(r[0]));
        let largest: f64 = r[1].parse().unwrap();
        assert!((largest - s.mpm.as_ref().unwrap().fluidised_fraction_max).abs() <= 1e-4, "{r:?}");
    }
}

/// A speed-against-error study: three element sizes of one MPM column.
/// The report's table holds each run's errors against the finest as the
/// summaries give them, and the observed order from those errors; the
/// figure has log axes.
#[test]
fn a_study_is_reported_as_speed_against_error() {
    let dir = scratch_dir("campaign_study");
    let scene = repo_root().join("scenes/ceccato2020/mpm_dry_h030.toml");
    let mut text = String::from("[campaign]\nname = \"study\"\n");
    for (tag, h, level) in [("e5", "0.005", 8), ("e3p3", "0.0033333333333333335", 12), ("e2p5", "0.0025", 16)] {
        text += &format!(
            "\n[[case]]\nname = \"{tag}\"\nscene = {scene:?}\nseries = \"MPM {tag}\"\nstudy = \"element size\"\nlevel = {level}\n\
             set = [\"mpm.element_size={h}\", \"mpm.points_per_element=4\", \"output.end_time=0.2\", \"output.stop_at_rest=false\"]\n"
        );
    }
    let file = dir.join("campaign.toml");
    std::fs::write(&file, text).unwrap();
    let out = dir.join("out");
    let o = campaign(&[file.to_str().unwrap()], &out, &dir.join("cache"));
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let report = std::fs::read_to_string(out.join("report.md")).unwrap();
    let table = rows(&report, "## Speed against error");
    assert_eq!(table.len(), 3, "{table:?}");
    let s: Vec<RunSummary> = ["e5", "e3p3", "e2p5"].iter().map(|n| summary(&out.join("cases").join(n))).collect();
    let reference = s[2].runout;
    assert_eq!(table[2][2], "e2p5");
    assert_eq!(table[2][5], "(reference)");
    let errors: Vec<f64> = (0..2).map(|i| (s[i].runout - reference).abs() / reference).collect();
    for i in 0..2 {
        assert_eq!(table[i][1], ["8", "12"][i]);
        assert_eq!(table[i][5], format!("{:.2e}", errors[i]), "{:?}", table[i]);
    }
    // The order between the two coarse levels, from their errors:
    // ln(e_8 / e_12) / ln(12 / 8).
    let order = (errors[0] / errors[1]).ln() / 1.5f64.ln();
    assert_eq!(table[1][7], format!("{order:.2}"), "{:?}", table[1]);
    let svg = std::fs::read_to_string(out.join("figures/speed_error.svg")).unwrap();
    assert!(svg.contains("element size: runout") && svg.contains("element size: front L2"));
}

/// The hard cases (`scenes/hard`) in their quick form: every case ends as
/// its campaign file says it must (runs, or stops naming the cause), none
/// panics, hangs or gives NaN; the lattice driven past Mach 0.5 stops
/// with `unstable` and the fix in the report.
#[test]
fn hard_cases_end_as_expected() {
    let dir = scratch_dir("campaign_hard");
    let out = dir.join("out");
    let o = campaign(&["scenes/hard", "--quick"], &out, &dir.join("cache"));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    let report = std::fs::read_to_string(out.join("report.md")).unwrap();
    let table = rows(&report, "## Expected outcomes");
    assert_eq!(table.len(), 14, "{table:?}");
    for r in &table {
        assert_eq!(r[5], "as expected", "{r:?}");
        // A case that runs with liquid keeps its mass: the free surface's
        // bookkeeping is exact to round-off in f32 populations (measured
        // 3e-14 to 5e-7 here, 1.4e-6 at most over the full study's runs;
        // the MPM's liquid points carry constant mass).
        if r[1] == "runs" && r[4] != "–" {
            let drift: f64 = r[4].parse().unwrap_or_else(|_| panic!("mass drift {:?} in {r:?}", r[4]));
            assert!(drift.abs() < 1e-5, "{}: liquid mass drift {drift:e}", r[0]);
        }
    }
    let blow_up = table.iter().find(|r| r[0] == "lbm_blow_up").expect("the blow-up case");
    assert_eq!(blow_up[2], "unstable", "{blow_up:?}");
    assert!(blow_up[6].contains("Mach") && blow_up[6].contains("lower the time step"), "{blow_up:?}");
    let s = summary(&out.join("cases/lbm_blow_up"));
    assert_eq!(s.status.as_str(), "unstable");
}

/// Every campaign file shipped (`campaign.toml`, `*.campaign.toml` under
/// `scenes/`) is valid: `coupler campaign FILE --check` loads it and every
/// case's scene (and under `--quick`), and lists each case.
#[test]
fn every_shipped_campaign_file_checks() {
    fn campaign_files(dir: &Path, out: &mut Vec<PathBuf>) {
        for entry in std::fs::read_dir(dir).unwrap().flatten() {
            let path = entry.path();
            if path.is_dir() {
                campaign_files(&path, out);
            } else if path.to_string_lossy().ends_with("campaign.toml") {
                out.push(path);
            }
        }
    }
    let mut files = Vec::new();
    campaign_files(&repo_root().join("scenes"), &mut files);
    assert!(files.len() >= 5, "{files:?}");
    let dir = scratch_dir("campaign_check");
    for file in &files {
        for quick in [false, true] {
            let mut args = vec![file.to_str().unwrap()];
            if quick {
                args.push("--quick");
            }
            args.push("--check");
            let o = campaign(&args, &dir.join("out"), &dir.join("cache"));
            let text = String::from_utf8_lossy(&o.stdout);
            assert!(o.status.success(), "{}: {}", file.display(), String::from_utf8_lossy(&o.stderr));
            let cases = text.lines().filter(|l| l.starts_with("case ")).count();
            assert!(cases >= 8, "{}: {cases} cases\n{text}", file.display());
        }
    }
    assert!(!dir.join("out").exists(), "--check writes nothing");
}

/// `--quick` on a campaign without a `[quick]` table is refused: it would
/// silently run the full matrix.
#[test]
fn quick_without_a_quick_table_is_refused() {
    let dir = scratch_dir("campaign_no_quick");
    std::fs::create_dir_all(&dir).unwrap();
    let text = std::fs::read_to_string(repo_root().join("scenes/ceccato2020/push_dry.campaign.toml")).unwrap();
    let without = &text[..text.find("[quick]").expect("the shipped file has a [quick] table")];
    // Its scenes by absolute path, so the file can live outside `scenes/`
    // (where the shipped-files test would find it).
    let scenes = repo_root().join("scenes/ceccato2020");
    let without = without.replace("scene = \"", &format!("scene = \"{}/", scenes.display()));
    let file = dir.join("no_quick.campaign.toml");
    std::fs::write(&file, without).unwrap();
    let quick = campaign(&[file.to_str().unwrap(), "--quick", "--check"], &dir.join("out"), &dir.join("cache"));
    let full = campaign(&[file.to_str().unwrap(), "--check"], &dir.join("out"), &dir.join("cache"));
    let err = String::from_utf8_lossy(&quick.stderr);
    assert!(!quick.status.success() && err.contains("[quick]"), "{err}");
    assert!(full.status.success(), "{}", String::from_utf8_lossy(&full.stderr));
}
