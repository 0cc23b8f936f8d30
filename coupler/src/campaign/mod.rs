//! `coupler campaign`: a matrix of runs from one campaign file, each a
//! normal `coupler run` in its own directory, then a report with figures.
//!
//! A campaign file (`scenes/ceccato2020/campaign.toml`) names its cases
//! (scene files, each with optional `--set` values) and the overrides of
//! `--quick`, a coarse version of the same matrix. The campaign is
//! resumable: a case whose `summary.json` says it finished is not rerun,
//! one that was stopped continues from its last checkpoint (or afresh
//! when it wrote none), and the report is rewritten from every summary at
//! the end of each invocation.

mod figures;
mod report;
mod snapshots;

use std::collections::BTreeSet;
use std::io::{Read, Seek, SeekFrom};
use std::os::unix::process::CommandExt;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitCode, Stdio};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use serde::Deserialize;
use signal_hook::iterator::Signals;

use schemas::scene::{Condition, Scene};
use schemas::summary::{RunStatus, RunSummary};
use schemas::{Method, EXIT_BAD_SCENE};

/// What `coupler campaign` was asked.
#[derive(Debug, Clone)]
pub struct Args {
    /// A campaign file, or a folder holding `campaign.toml`.
    pub source: PathBuf,
    pub quick: bool,
    pub out: Option<PathBuf>,
    pub jobs: Option<usize>,
}

/// The campaign file.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct CampaignFile {
    campaign: Header,
    /// Cases beyond `campaign.scenes`: a scene with `--set` values.
    #[serde(default)]
    case: Vec<CaseSpec>,
    #[serde(default)]
    quick: QuickOverrides,
    /// Figures that set chosen cases' snapshots side by side.
    #[serde(default)]
    compare: Vec<Comparison>,
}

/// A figure of snapshots side by side (e.g. the paper's Fig. 13): a row per
/// case, a column per time.
#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Comparison {
    /// Names the figure's file, `figures/compare_<name>.png`.
    pub name: String,
    /// The figure's heading in the report.
    #[serde(default)]
    pub title: String,
    /// Case names, one row each, top to bottom.
    pub cases: Vec<String>,
    /// Normalised times t/t_ref, one column each, left to right.
    pub times: Vec<f64>,
}

/// Most rows and columns a comparison draws (the PNG grows with both).
const COMPARISON_MAX_PANELS: usize = 8;

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct Header {
    name: String,
    #[serde(default)]
    description: String,
    /// Scene files (relative to the campaign file), each a case named by
    /// its `scene.name`.
    #[serde(default)]
    scenes: Vec<String>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct CaseSpec {
    name: String,
    scene: String,
    #[serde(default)]
    set: Vec<String>,
    /// The report's name for the runs this case belongs to (default: the
    /// method, `DEM` or `MPM`); runs of one series, condition and H0 are
    /// repeats (seeds) of one case.
    #[serde(default)]
    series: Option<String>,
    /// The speed-against-error sets this case is part of (`study`), and
    /// its place in each (`level`: grows as the run gets finer, e.g.
    /// elements per L0 or points per element); the finest level is a
    /// set's reference. One name and one number, or two lists of the same
    /// length when one run belongs to several sets (the paper's lattice
    /// is both the lattice set's middle level and the sub-step set's
    /// finest), so that it is run once.
    #[serde(default)]
    study: Option<OneOrMany<String>>,
    #[serde(default)]
    level: Option<OneOrMany<f64>>,
    /// The outcome the case must have (hard cases); without it the case
    /// must complete or come to rest.
    #[serde(default)]
    expect: Option<Expect>,
    /// Wall seconds after which a case still running is stopped and
    /// counted as a hang.
    #[serde(default)]
    max_wall: Option<f64>,
}

/// A value or a list of them.
#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(untagged)]
enum OneOrMany<T> {
    One(T),
    Many(Vec<T>),
}

impl<T> OneOrMany<T> {
    fn into_vec(self) -> Vec<T> {
        match self {
            OneOrMany::One(v) => vec![v],
            OneOrMany::Many(v) => v,
        }
    }
}

/// What a case must end as.
#[derive(Debug, Clone, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Expect {
    pub outcome: ExpectedOutcome,
    /// Words its log must hold (the cause a stop names).
    #[serde(default)]
    pub message: Option<String>,
}

#[derive(Debug, Clone, Copy, Deserialize, PartialEq, Eq)]
#[serde(rename_all = "snake_case")]
pub enum ExpectedOutcome {
    /// Completed or came to rest.
    Runs,
    /// Stopped by its watchdog (`unstable`), naming the cause.
    Stops,
    /// Either; never a panic, a hang or a NaN.
    RunsOrStops,
}

impl ExpectedOutcome {
    pub fn word(self) -> &'static str {
        match self {
            ExpectedOutcome::Runs => "runs",
            ExpectedOutcome::Stops => "stops",
            ExpectedOutcome::RunsOrStops => "runs or stops",
        }
    }
}

/// `--set` values of `--quick`: `all` for every case, then those of each
/// solver the case runs (`dem`: dem_proc, `lbm`: lbm_proc, `mpm`: mpm_proc).
#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct QuickOverrides {
    #[serde(default)]
    all: Vec<String>,
    #[serde(default)]
    dem: Vec<String>,
    #[serde(default)]
    lbm: Vec<String>,
    #[serde(default)]
    mpm: Vec<String>,
}

impl QuickOverrides {
    fn is_empty(&self) -> bool {
        self.all.is_empty() && self.dem.is_empty() && self.lbm.is_empty() && self.mpm.is_empty()
    }

    fn for_method(&self, method: Method) -> Vec<String> {
        let mut set = self.all.clone();
        if matches!(method, Method::DemDry | Method::DemLbm) {
            set.extend(self.dem.iter().cloned());
        }
        if matches!(method, Method::LbmFluid | Method::DemLbm) {
            set.extend(self.lbm.iter().cloned());
        }
        if method == Method::Mpm {
            set.extend(self.mpm.iter().cloned());
        }
        set
    }
}

/// The method's family in the report: `DEM` (dry DEM and DEM–LBM), `MPM`, `LBM`.
fn family_of(method: Method) -> &'static str {
    match method {
        Method::Mpm => "MPM",
        Method::DemDry | Method::DemLbm => "DEM",
        Method::LbmFluid => "LBM",
    }
}

/// One run of the campaign, resolved and validated.
#[derive(Debug, Clone)]
pub struct Case {
    pub name: String,
    pub scene_path: PathBuf,
    /// Every `--set` value the run gets (the case's, then `--quick`'s).
    pub set: Vec<String>,
    pub method: Method,
    pub condition: Condition,
    /// L0 and H0, m.
    pub column_length: f64,
    pub column_height: f64,
    /// The largest grain diameter, m (the pile edge's height threshold).
    pub grain_diameter: f64,
    /// The solvers' own estimate of the run's wall time at full speed, s.
    pub estimate_s: f64,
    /// `OUT/cases/<name>`.
    pub dir: PathBuf,
    /// The domain's x origin, m (the back wall).
    pub origin_x: f64,
    /// The report's series (default: [`Case::family`]).
    pub series: String,
    /// The speed-against-error sets of the case and its level in each.
    pub studies: Vec<(String, f64)>,
    pub expect: Option<Expect>,
    pub max_wall: Option<f64>,
}

impl Case {
    /// `dem`/`dem_lbm` runs are DEM(-LBM), `mpm` runs MPM: the two methods
    /// the report sets side by side.
    pub fn family(&self) -> &'static str {
        family_of(self.method)
    }

    /// Aspect ratio H0 / L0.
    pub fn aspect(&self) -> f64 {
        self.column_height / self.column_length
    }

    /// The case's summary when it finished: completed, at rest, or
    /// stopped by its watchdog (an outcome, not an accident).
    pub fn finished_summary(&self) -> Option<RunSummary> {
        let text = std::fs::read_to_string(self.dir.join("summary.json")).ok()?;
        let summary: RunSummary = serde_json::from_str(&text).ok()?;
        matches!(summary.status, RunStatus::Completed | RunStatus::AtRest | RunStatus::Unstable).then_some(summary)
    }

    /// Whether the case ended as it must: its expectation, or completed
    /// or at rest without one; never a panic in its log or a hang. The
    /// reason when not.
    pub fn verdict(&self, summary: Option<&RunSummary>) -> Result<(), String> {
        let log = std::fs::read_to_string(self.dir.with_file_name(format!("{}.log", self.name))).unwrap_or_default();
        if log.contains("panicked at") {
            return Err("a process panicked (see its log)".into());
        }
        if self.timeout_path().exists() {
            return Err(format!("still running after max_wall = {} s: a hang", self.max_wall.unwrap_or(f64::NAN)));
        }
        let Some(s) = summary else { return Err("did not finish".into()) };
        let ran = matches!(s.status, RunStatus::Completed | RunStatus::AtRest);
        let outcome = self.expect.as_ref().map_or(ExpectedOutcome::Runs, |e| e.outcome);
        let fits = match outcome {
            ExpectedOutcome::Runs => ran,
            ExpectedOutcome::Stops => s.status == RunStatus::Unstable,
            ExpectedOutcome::RunsOrStops => ran || s.status == RunStatus::Unstable,
        };
        if !fits {
            return Err(format!("{} where it must be: {}", s.status, outcome.word()));
        }
        if let Some(words) = self.expect.as_ref().and_then(|e| e.message.as_deref()) {
            if s.status == RunStatus::Unstable && !log.contains(words) {
                return Err(format!("stopped without naming {words:?} in its log"));
            }
        }
        if let Some(field) = nan_field(s).filter(|_| ran) {
            return Err(format!("its summary holds NaN ({field})"));
        }
        Ok(())
    }

    /// Marks a case stopped for running past `max_wall`.
    fn timeout_path(&self) -> PathBuf {
        self.dir.with_file_name(format!("{}.timeout", self.name))
    }

    /// Whether the case's processes left a checkpoint to continue from.
    fn has_checkpoint(&self) -> bool {
        std::fs::read_dir(self.dir.join("checkpoints"))
            .map(|d| d.flatten().any(|e| e.path().extension().is_some_and(|x| x == "ckpt")))
            .unwrap_or(false)
            && self.dir.join("scene.toml").exists()
    }
}

/// A loaded campaign.
#[derive(Debug)]
pub struct Campaign {
    pub name: String,
    pub description: String,
    pub file: PathBuf,
    pub quick: bool,
    pub out: PathBuf,
    pub cases: Vec<Case>,
    pub comparisons: Vec<Comparison>,
}

/// Reads and checks the campaign file and every case's scene before any
/// run starts: a bad case stops the campaign with its name and reason.
pub fn load(args: &Args) -> Result<Campaign, String> {
    let file = if args.source.is_dir() { args.source.join("campaign.toml") } else { args.source.clone() };
    let text = std::fs::read_to_string(&file).map_err(|e| {
        format!(
            "cannot read campaign file {}: {e} (give a campaign file, or a folder holding campaign.toml)",
            file.display()
        )
    })?;
    let spec: CampaignFile = toml::from_str(&text).map_err(|e| format!("{}: {e}", file.display()))?;
    if args.quick && spec.quick.is_empty() {
        return Err(format!(
            "{}: --quick needs a [quick] table with values (e.g. `all = [\"output.end_time=0.2\"]`); without them it would run the full matrix: add them, or run without --quick",
            file.display()
        ));
    }
    let base = file.parent().map(Path::to_path_buf).unwrap_or_default();
    let out = args.out.clone().unwrap_or_else(|| {
        PathBuf::from("runs").join(format!("campaign-{}{}", spec.campaign.name, if args.quick { "-quick" } else { "" }))
    });
    let listed = spec.campaign.scenes.iter().map(|s| (None, s.clone(), Vec::new(), None, Vec::new(), None, None));
    let mut extra = Vec::new();
    for c in &spec.case {
        let study = case_studies(c).map_err(|e| format!("{}: case {:?}: {e}", file.display(), c.name))?;
        if c.max_wall.is_some_and(|w| !(w > 0.0 && w.is_finite())) {
            return Err(format!("{}: case {:?}: max_wall must be > 0 s", file.display(), c.name));
        }
        extra.push((
            Some(c.name.clone()),
            c.scene.clone(),
            c.set.clone(),
            c.series.clone(),
            study,
            c.expect.clone(),
            c.max_wall,
        ));
    }
    let mut cases = Vec::new();
    let mut names = BTreeSet::new();
    for (name, scene_file, mut set, series, study, expect, max_wall) in listed.chain(extra) {
        let scene_path = base.join(&scene_file);
        let scene = Scene::load(&scene_path, &set).map_err(|e| format!("case {scene_file}: invalid scene:\n{e}"))?;
        if args.quick {
            set.extend(spec.quick.for_method(scene.method()));
        }
        let scene = Scene::load(&scene_path, &set)
            .map_err(|e| format!("case {scene_file}: invalid scene under --quick's values:\n{e}"))?;
        if matches!(scene.method(), Method::DemDry | Method::DemLbm) {
            dem_proc::setup::check_scene(&scene).map_err(|e| format!("case {scene_file}: invalid scene:\n{e}"))?;
        }
        let name = name.unwrap_or_else(|| scene.spec.scene.name.clone());
        if !valid_name(&name) {
            return Err(format!(
                "{}: case name {name:?}: use letters, digits, '_', '-' and '.', not starting with '.' (it names files and folders)",
                file.display()
            ));
        }
        if !names.insert(name.clone()) {
            return Err(format!("{}: two cases are named {name:?}: give the [[case]] another name", file.display()));
        }
        let a = &scene.spec.analysis;
        cases.push(Case {
            origin_x: scene.spec.domain.min[0],
            series: series.unwrap_or_else(|| family_of(scene.method()).to_string()),
            studies: study,
            expect,
            max_wall,
            dir: out.join("cases").join(&name),
            name,
            method: scene.method(),
            condition: a.condition,
            column_length: a.column_length,
            column_height: a.column_height,
            grain_diameter: scene.spec.particles.iter().map(|p| p.diameter).fold(0.0, f64::max),
            estimate_s: crate::check::plans(&scene).iter().map(|p| p.wall_estimate).filter(|w| w.is_finite()).sum(),
            scene_path,
            set,
        });
    }
    if cases.is_empty() {
        return Err(format!(
            "{}: no cases: list scene files in campaign.scenes or add [[case]] tables",
            file.display()
        ));
    }
    check_comparisons(&spec.compare, &cases).map_err(|e| format!("{}: {e}", file.display()))?;
    Ok(Campaign {
        name: spec.campaign.name,
        description: spec.campaign.description,
        file,
        quick: args.quick,
        out,
        cases,
        comparisons: spec.compare,
    })
}

/// Each `[[compare]]` names a file, rows of existing cases and times at or
/// after the start.
fn check_comparisons(comparisons: &[Comparison], cases: &[Case]) -> Result<(), String> {
    let mut names = BTreeSet::new();
    for c in comparisons {
        if !valid_name(&c.name) {
            return Err(format!(
                "compare {:?}: use letters, digits, '_', '-' and '.' in its name (it names the figure's file)",
                c.name
            ));
        }
        if !names.insert(&c.name) {
            return Err(format!("two [[compare]] figures are named {:?}", c.name));
        }
        let sizes = [("cases", c.cases.len()), ("times", c.times.len())];
        if let Some((what, n)) = sizes.iter().find(|(_, n)| *n == 0 || *n > COMPARISON_MAX_PANELS) {
            return Err(format!("compare {:?}: {n} {what}; give 1 to {COMPARISON_MAX_PANELS}", c.name));
        }
        let mut rows = BTreeSet::new();
        if let Some(twice) = c.cases.iter().find(|n| !rows.insert(n.as_str())) {
            return Err(format!("compare {:?}: case {twice:?} is listed twice: give each row once", c.name));
        }
        if let Some(unknown) = c.cases.iter().find(|n| !cases.iter().any(|k| &k.name == *n)) {
            return Err(format!("compare {:?}: no case is named {unknown:?}", c.name));
        }
        if let Some(t) = c.times.iter().find(|t| !(t.is_finite() && **t >= 0.0)) {
            return Err(format!("compare {:?}: time {t} is not a t/t_ref >= 0", c.name));
        }
    }
    Ok(())
}

/// A case's `study` and `level` as (set, level) pairs: both absent, or
/// both given with as many levels as sets, each level a finite number and
/// no set named twice.
fn case_studies(c: &CaseSpec) -> Result<Vec<(String, f64)>, String> {
    let (studies, levels) = match (c.study.clone(), c.level.clone()) {
        (None, None) => return Ok(Vec::new()),
        (Some(s), Some(l)) => (s.into_vec(), l.into_vec()),
        _ => return Err("study and level go together (level a finite number that grows as the run gets finer)".into()),
    };
    if studies.len() != levels.len() || studies.is_empty() {
        return Err(format!(
            "{} stud(ies) but {} level(s): give one level per study, in the same order",
            studies.len(),
            levels.len()
        ));
    }
    if let Some(l) = levels.iter().find(|l| !l.is_finite()) {
        return Err(format!("level {l} is not a finite number (it grows as the run gets finer)"));
    }
    let mut seen = BTreeSet::new();
    if let Some(s) = studies.iter().find(|s| !seen.insert(s.as_str())) {
        return Err(format!("study {s:?} is listed twice: a case has one level in a study"));
    }
    Ok(studies.into_iter().zip(levels).collect())
}

/// A case name is a file name: `[A-Za-z0-9_.-]+`, not starting with a dot.
fn valid_name(name: &str) -> bool {
    !name.is_empty()
        && !name.starts_with('.')
        && name.chars().all(|c| c.is_ascii_alphanumeric() || matches!(c, '_' | '-' | '.'))
}

/// What `OUT/campaign.json` records, so that a campaign continued in the
/// same folder is the same campaign.
#[derive(Debug, serde::Serialize, Deserialize, PartialEq)]
struct Marker {
    name: String,
    quick: bool,
}

/// Takes `OUT/campaign.lock` for this process (an advisory `flock`,
/// released by the kernel however the process ends), so that two
/// campaigns never run the same cases at once. The file holds the
/// holder's pid, for the message.
fn lock_output(out: &Path) -> Result<std::fs::File, String> {
    use std::io::{Read, Seek, Write};
    use std::os::fd::AsRawFd;
    std::fs::create_dir_all(out).map_err(|e| format!("cannot create {}: {e}", out.display()))?;
    let path = out.join("campaign.lock");
    let mut file = std::fs::OpenOptions::new()
        .read(true)
        .write(true)
        .create(true)
        .truncate(false)
        .open(&path)
        .map_err(|e| format!("cannot open {}: {e}", path.display()))?;
    // SAFETY: flock on a descriptor this function owns; no memory is passed.
    if unsafe { libc::flock(file.as_raw_fd(), libc::LOCK_EX | libc::LOCK_NB) } != 0 {
        let mut holder = String::new();
        let _ = file.read_to_string(&mut holder);
        return Err(format!(
            "another campaign is running in {} (pid {}): wait for it to end, stop it (Ctrl-C), or give another --out",
            out.display(),
            holder.trim()
        ));
    }
    let written = file.set_len(0).and_then(|_| file.rewind()).and_then(|_| write!(file, "{}", std::process::id()));
    written.map_err(|e| format!("cannot write {}: {e}", path.display()))?;
    Ok(file)
}

fn claim_output(campaign: &Campaign) -> Result<(), String> {
    let path = campaign.out.join("campaign.json");
    let marker = Marker { name: campaign.name.clone(), quick: campaign.quick };
    if let Ok(text) = std::fs::read_to_string(&path) {
        let old: Marker = serde_json::from_str(&text)
            .map_err(|e| format!("{} is not a campaign's marker ({e}): give another --out", path.display()))?;
        if old != marker {
            let kind = |m: &Marker| format!("{}{}", m.name, if m.quick { " --quick" } else { "" });
            return Err(format!(
                "{} holds the campaign {}, not {}: give another --out",
                campaign.out.display(),
                kind(&old),
                kind(&marker)
            ));
        }
    }
    std::fs::create_dir_all(campaign.out.join("cases"))
        .map_err(|e| format!("cannot create {}: {e}", campaign.out.display()))?;
    std::fs::write(&path, serde_json::to_string_pretty(&marker).expect("marker serialises"))
        .map_err(|e| format!("cannot write {}: {e}", path.display()))
}

/// A case being run.
struct Running {
    index: usize,
    child: Child,
    started: Instant,
    resumed: bool,
    /// When `summary.json` was last written before this attempt.
    summary_before: Option<std::time::SystemTime>,
    /// Stopped for running past the case's `max_wall`.
    timed_out: bool,
}

/// How the cases share the machine: `jobs` at once, `threads` each.
#[derive(Debug, Clone, Copy)]
pub struct Schedule {
    pub jobs: usize,
    pub threads: usize,
}

impl Schedule {
    /// Two one-thread cases at once on a 2-core machine ran the quick
    /// matrix in 163 s, one two-thread case at a time in 186 s (a case's
    /// second thread gives it 1.77×, a second case 2×; docs/campaign.md):
    /// one case per core by default. The results do not depend on it.
    fn new(jobs: Option<usize>) -> Self {
        let cores = std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1);
        let jobs = jobs.unwrap_or(cores).max(1);
        Schedule { jobs, threads: (cores / jobs).max(1) }
    }
}

/// `coupler campaign --check`: the campaign's cases as they would run,
/// and which have finished; nothing is run or written.
pub fn check(args: &Args) -> ExitCode {
    let campaign = match load(args) {
        Ok(c) => c,
        Err(e) => {
            eprintln!("coupler: {e}");
            return ExitCode::from(EXIT_BAD_SCENE as u8);
        }
    };
    println!(
        "campaign     {}{} — {}\nfile         {}\noutput       {}",
        campaign.name,
        if campaign.quick { " (quick)" } else { "" },
        campaign.description,
        campaign.file.display(),
        campaign.out.display()
    );
    let mut total = 0.0;
    for c in &campaign.cases {
        let study: String = c.studies.iter().map(|(s, l)| format!(", study {s:?} level {l}")).collect();
        let expect = c.expect.as_ref().map(|e| format!(", must {}", e.outcome.word())).unwrap_or_default();
        let done = c.finished_summary().map(|s| format!(", finished ({})", s.status)).unwrap_or_default();
        println!(
            "case         {:<28} {:<8} {:<10} a = {:.2}, series {:?}, ~{:.0} s at full speed{study}{expect}{done}",
            c.name,
            c.method.name(),
            format!("{:?}", c.condition).to_lowercase(),
            c.aspect(),
            c.series,
            c.estimate_s
        );
        total += c.estimate_s;
    }
    println!(
        "estimate     {} cases, ~{} of the solvers' own estimates (coupler check's)",
        campaign.cases.len(),
        human_seconds(total)
    );
    ExitCode::SUCCESS
}

/// Runs `coupler campaign`.
pub fn run(args: Args, command_line: String) -> ExitCode {
    let campaign = match load(&args) {
        Ok(c) => c,
        Err(e) => {
            eprintln!("coupler: {e}");
            return ExitCode::from(EXIT_BAD_SCENE as u8);
        }
    };
    let _lock = match lock_output(&campaign.out) {
        Ok(lock) => lock,
        Err(e) => {
            eprintln!("coupler: {e}");
            return ExitCode::FAILURE;
        }
    };
    if let Err(e) = claim_output(&campaign) {
        eprintln!("coupler: {e}");
        return ExitCode::FAILURE;
    }
    // SIGINT and SIGTERM are counted: the first stops the campaign
    // gently, later ones escalate (`interrupt`).
    let stops = Arc::new(AtomicUsize::new(0));
    let mut signals = match Signals::new([signal_hook::consts::SIGINT, signal_hook::consts::SIGTERM]) {
        Ok(s) => s,
        Err(e) => {
            eprintln!("coupler: cannot install the signal handler: {e}");
            return ExitCode::FAILURE;
        }
    };
    let counter = Arc::clone(&stops);
    std::thread::spawn(move || {
        for _ in signals.forever() {
            counter.fetch_add(1, Ordering::SeqCst);
        }
    });
    let schedule = Schedule::new(args.jobs);
    let started = Instant::now();
    let outcome = execute(&campaign, schedule, &stops);
    let wall = started.elapsed().as_secs_f64();
    let finished: Vec<Option<RunSummary>> = campaign.cases.iter().map(Case::finished_summary).collect();
    let context = report::Context {
        command_line,
        schedule,
        wall_seconds: wall,
        interrupted: outcome.interrupted,
        cases_started: outcome.started,
    };
    match report::write(&campaign, &finished, &context) {
        Ok(path) => eprintln!("coupler: report {}", path.display()),
        Err(e) => {
            eprintln!("coupler: cannot write the report: {e}");
            if !outcome.interrupted {
                return ExitCode::FAILURE;
            }
        }
    }
    let done = finished.iter().flatten().count();
    if outcome.interrupted {
        eprintln!(
            "coupler: campaign interrupted after {wall:.0} s with {done} of {} cases finished; run the same command again to continue",
            campaign.cases.len()
        );
        return ExitCode::from(130);
    }
    let bad: Vec<&str> = campaign
        .cases
        .iter()
        .zip(&finished)
        .filter(|(c, s)| c.verdict(s.as_ref()).is_err())
        .map(|(c, _)| c.name.as_str())
        .collect();
    if bad.is_empty() {
        eprintln!(
            "coupler: campaign {} finished: {done} cases; this invocation ran {} of them in {wall:.0} s",
            campaign.name, outcome.started
        );
        ExitCode::SUCCESS
    } else {
        eprintln!(
            "coupler: campaign {}: {} of {} cases did not end as they must ({}); see the report and OUT/cases/<name>.log",
            campaign.name,
            bad.len(),
            campaign.cases.len(),
            bad.join(", ")
        );
        ExitCode::FAILURE
    }
}

struct Outcome {
    interrupted: bool,
    /// Cases this invocation started (fresh or resumed).
    started: usize,
}

/// Runs every case not yet finished, `schedule.jobs` at a time, longest
/// estimate first (the last to start are the short ones, so the cores
/// finish together).
fn execute(campaign: &Campaign, schedule: Schedule, stops: &AtomicUsize) -> Outcome {
    let total = campaign.cases.len();
    let mut pending: Vec<usize> = (0..total).filter(|&i| campaign.cases[i].finished_summary().is_none()).collect();
    pending.sort_by(|&a, &b| campaign.cases[b].estimate_s.total_cmp(&campaign.cases[a].estimate_s));
    let skipped = total - pending.len();
    eprintln!(
        "coupler: campaign {}{}: {total} cases, {skipped} already finished, {} to run, {} at a time with {} thread{} each; output {}",
        campaign.name,
        if campaign.quick { " (quick)" } else { "" },
        pending.len(),
        schedule.jobs,
        schedule.threads,
        if schedule.threads == 1 { "" } else { "s" },
        campaign.out.display()
    );
    let mut progress = Progress::new(campaign, &pending);
    let mut running: Vec<Running> = Vec::new();
    // A case whose resume was refused (its checkpoints unusable) is run
    // afresh, once; one that resumed and then failed is not.
    let mut fresh_after_refused_resume = BTreeSet::new();
    let mut queue: std::collections::VecDeque<usize> = pending.into();
    let mut started = 0;
    let mut last_report = Instant::now();
    let stopping = || stops.load(Ordering::SeqCst) > 0;
    loop {
        if stopping() {
            interrupt(&mut running, campaign, stops);
            return Outcome { interrupted: true, started };
        }
        while running.len() < schedule.jobs && !stopping() {
            let Some(index) = queue.pop_front() else { break };
            let case = &campaign.cases[index];
            let resume = case.has_checkpoint() && !fresh_after_refused_resume.contains(&index);
            let summary_before = summary_stamp(case);
            match spawn(case, schedule.threads, resume) {
                Ok(child) => {
                    started += 1;
                    eprintln!(
                        "coupler: [{}/{total}] {} {}",
                        skipped + started,
                        case.name,
                        if resume { "resumed from its checkpoint" } else { "started" }
                    );
                    let _ = std::fs::remove_file(case.timeout_path());
                    running.push(Running {
                        index,
                        child,
                        started: Instant::now(),
                        resumed: resume,
                        summary_before,
                        timed_out: false,
                    });
                }
                Err(e) => {
                    eprintln!("coupler: {}: cannot start: {e}", case.name);
                    progress.finish(index, 0.0, false);
                }
            }
        }
        if running.is_empty() {
            return Outcome { interrupted: stopping(), started };
        }
        std::thread::sleep(Duration::from_millis(100));
        for r in running.iter_mut() {
            let case = &campaign.cases[r.index];
            let limit = case.max_wall.unwrap_or(f64::INFINITY);
            if !r.timed_out && r.started.elapsed().as_secs_f64() > limit {
                eprintln!("coupler: {} still runs after max_wall = {limit} s: stopping it (a hang)", case.name);
                let _ = std::fs::write(case.timeout_path(), format!("{limit}\n"));
                // SAFETY: signalling our own child.
                unsafe { libc::kill(r.child.id() as i32, libc::SIGINT) };
                r.timed_out = true;
            }
        }
        let mut i = 0;
        while i < running.len() {
            match running[i].child.try_wait() {
                Ok(None) => i += 1,
                Err(e) => {
                    // Not known to have ended: keep watching it.
                    eprintln!("coupler: cannot poll {}: {e}", campaign.cases[running[i].index].name);
                    i += 1;
                }
                Ok(Some(_)) => {
                    let r = running.swap_remove(i);
                    let case = &campaign.cases[r.index];
                    let elapsed = r.started.elapsed().as_secs_f64();
                    record_attempt(case, r.resumed, elapsed);
                    let summary = case.finished_summary();
                    let never_started = summary_stamp(case) == r.summary_before;
                    if summary.is_none() && r.resumed && never_started && !stopping() {
                        eprintln!(
                            "coupler: {}: its checkpoints were refused (see its log); running it afresh",
                            case.name
                        );
                        fresh_after_refused_resume.insert(r.index);
                        queue.push_front(r.index);
                        started -= 1;
                        continue;
                    }
                    progress.finish(r.index, elapsed, summary.is_some());
                    eprintln!("coupler: {} {}", case.name, outcome_line(case, summary.as_ref(), elapsed));
                    eprintln!("coupler: {}", progress.line(&running, schedule));
                    last_report = Instant::now();
                }
            }
        }
        if last_report.elapsed() > Duration::from_secs(60) {
            eprintln!("coupler: {}", progress.line(&running, schedule));
            last_report = Instant::now();
        }
    }
}

/// When the case's `summary.json` was last written (None: there is none).
fn summary_stamp(case: &Case) -> Option<std::time::SystemTime> {
    std::fs::metadata(case.dir.join("summary.json")).and_then(|m| m.modified()).ok()
}

/// `OUT/cases/<name>.attempts`: one line per attempt (`fresh` or `resume`
/// and its wall seconds), so that a resumed run's cost is the sum of its
/// attempts since the last fresh start.
fn attempts_path(case: &Case) -> PathBuf {
    case.dir.with_file_name(format!("{}.attempts", case.name))
}

fn record_attempt(case: &Case, resumed: bool, elapsed: f64) {
    use std::io::Write as _;
    let path = attempts_path(case);
    let append = resumed && path.exists();
    let file = std::fs::OpenOptions::new().create(true).append(append).write(true).truncate(!append).open(&path);
    if let Ok(mut f) = file {
        // Best effort: without it the report shows the last attempt's wall time.
        let _ = writeln!(f, "{} {elapsed:.3}", if resumed { "resume" } else { "fresh" });
    }
}

/// The wall seconds of every attempt of a case since its last fresh
/// start, if the campaign ran it.
pub fn attempts_wall(case: &Case) -> Option<(f64, usize)> {
    let text = std::fs::read_to_string(attempts_path(case)).ok()?;
    let seconds: Vec<f64> = text.lines().filter_map(|l| l.split_whitespace().nth(1)?.parse().ok()).collect();
    (!seconds.is_empty()).then(|| (seconds.iter().sum(), seconds.len()))
}

fn outcome_line(case: &Case, summary: Option<&RunSummary>, elapsed: f64) -> String {
    match summary {
        Some(s) => {
            format!("{} in {elapsed:.0} s at t = {:.2} t_ref: runout {:.3}", s.status, s.sim_time / s.t_ref, s.runout)
        }
        None => format!(
            "did not finish ({elapsed:.0} s): see {}",
            case.dir.with_file_name(format!("{}.log", case.name)).display()
        ),
    }
}

/// Starts `coupler run` for one case: its own process group (a Ctrl-C at
/// the terminal reaches the campaign, which passes it on once), and a
/// SIGTERM if the campaign dies, so no run outlives it.
fn spawn(case: &Case, threads: usize, resume: bool) -> std::io::Result<Child> {
    let exe = std::env::current_exe()?;
    std::fs::create_dir_all(case.dir.parent().expect("a case dir has a parent"))?;
    let log_path = case.dir.with_file_name(format!("{}.log", case.name));
    // Every attempt's output is kept, each under a header.
    let mut log = std::fs::OpenOptions::new().create(true).append(true).open(&log_path)?;
    {
        use std::io::Write as _;
        let since_epoch = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).unwrap_or_default();
        writeln!(
            log,
            "=== coupler campaign: {} at unix time {} ===",
            if resume { "resumed from its checkpoint" } else { "started afresh" },
            since_epoch.as_secs()
        )?;
    }
    let mut cmd = Command::new(exe);
    cmd.arg("run");
    if resume {
        cmd.arg("--resume").arg(&case.dir);
    } else {
        // A case run afresh starts from nothing its earlier attempt left.
        let _ = std::fs::remove_file(case.dir.join("summary.json"));
        cmd.arg(&case.scene_path).arg("--out").arg(&case.dir);
        for s in &case.set {
            cmd.arg("--set").arg(s);
        }
    }
    cmd.arg("--quiet").arg("--threads").arg(threads.to_string());
    cmd.stdin(Stdio::null()).stdout(log.try_clone()?).stderr(log).process_group(0);
    // SAFETY: prctl is async-signal-safe; the closure touches no memory of
    // the parent's.
    unsafe {
        cmd.pre_exec(|| {
            if libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGTERM) != 0 {
                return Err(std::io::Error::last_os_error());
            }
            Ok(())
        });
    }
    cmd.spawn()
}

/// Passes the stop on to every running case and waits for them: the
/// first signal a SIGINT each (each ends its run, keeping its recording
/// and checkpoints), a second one another SIGINT (a case's coupler then
/// kills its solvers), a third SIGKILL to each case's process group.
fn interrupt(running: &mut Vec<Running>, campaign: &Campaign, stops: &AtomicUsize) {
    eprintln!(
        "coupler: stopping {} running case(s); each keeps its recording and checkpoints (Ctrl-C again to hurry them)",
        running.len()
    );
    let mut forwarded = 0;
    while !running.is_empty() {
        let seen = stops.load(Ordering::SeqCst);
        while forwarded < seen {
            forwarded += 1;
            for r in running.iter() {
                let pid = r.child.id() as i32;
                // SAFETY: signalling our own children (their groups: they
                // lead them, process_group(0)).
                unsafe {
                    if forwarded <= 2 {
                        libc::kill(pid, libc::SIGINT);
                    } else {
                        libc::kill(-pid, libc::SIGKILL);
                    }
                }
            }
        }
        running.retain_mut(|r| match r.child.try_wait() {
            Ok(None) => true,
            _ => {
                record_attempt(&campaign.cases[r.index], r.resumed, r.started.elapsed().as_secs_f64());
                eprintln!("coupler: {} stopped", campaign.cases[r.index].name);
                false
            }
        });
        std::thread::sleep(Duration::from_millis(50));
    }
}

/// Progress over the whole campaign and its ETA: the cases' own estimates
/// (`coupler check`'s), scaled by how long the finished cases took against
/// theirs, and the running cases' progress lines (`t = … / … s`).
struct Progress<'a> {
    campaign: &'a Campaign,
    done: usize,
    to_run: usize,
    remaining_estimate: f64,
    spent: f64,
    spent_estimate: f64,
}

impl<'a> Progress<'a> {
    fn new(campaign: &'a Campaign, pending: &[usize]) -> Self {
        Progress {
            campaign,
            done: 0,
            to_run: pending.len(),
            remaining_estimate: pending.iter().map(|&i| campaign.cases[i].estimate_s).sum(),
            spent: 0.0,
            spent_estimate: 0.0,
        }
    }

    /// A case ended; `finished`: it ran to its end (only those calibrate the estimates).
    fn finish(&mut self, index: usize, elapsed: f64, finished: bool) {
        let estimate = self.campaign.cases[index].estimate_s;
        self.done += 1;
        self.remaining_estimate -= estimate;
        if finished && elapsed > 0.0 && estimate > 0.0 {
            self.spent += elapsed;
            self.spent_estimate += estimate;
        }
    }

    fn line(&self, running: &[Running], schedule: Schedule) -> String {
        // Wall seconds per estimated second: 1 until a case has finished.
        let scale = if self.spent_estimate > 0.0 { self.spent / self.spent_estimate } else { 1.0 };
        let mut left = self.remaining_estimate * scale;
        let mut longest: f64 = 0.0;
        let mut now = Vec::new();
        for r in running {
            let case = &self.campaign.cases[r.index];
            let elapsed = r.started.elapsed().as_secs_f64();
            let fraction = run_fraction(&case.dir.with_file_name(format!("{}.log", case.name)));
            let remaining = match fraction {
                Some(f) if f > 0.02 => elapsed * (1.0 - f) / f,
                _ => (case.estimate_s * scale - elapsed).max(0.0),
            };
            // The running case's estimate is in `remaining_estimate`:
            // replace it by what its own progress says.
            left += remaining - case.estimate_s * scale;
            longest = longest.max(remaining);
            now.push(match fraction {
                Some(f) => format!("{} {:.0} %", case.name, 100.0 * f),
                None => format!("{} {elapsed:.0} s", case.name),
            });
        }
        // The cores share what is left, but no sooner than the longest running case ends.
        let eta = (left.max(0.0) / schedule.jobs as f64).max(longest);
        format!(
            "{} of {} done, running: {}; ETA {}",
            self.done,
            self.to_run,
            if now.is_empty() { "none".to_string() } else { now.join(", ") },
            human_seconds(eta)
        )
    }
}

/// The share of its simulated time a running case has reached, from the
/// last `PHASE: t = A / B s` of its log (the quiet progress lines of
/// `coupler run`).
fn run_fraction(log: &Path) -> Option<f64> {
    let mut file = std::fs::File::open(log).ok()?;
    let len = file.metadata().ok()?.len();
    file.seek(SeekFrom::Start(len.saturating_sub(4096))).ok()?;
    let mut bytes = Vec::new();
    file.read_to_end(&mut bytes).ok()?;
    // The cut may fall inside a character.
    let tail = String::from_utf8_lossy(&bytes);
    tail.lines().rev().find_map(|line| {
        let (phase, progress) = line.split_once(": t = ")?;
        let (now, rest) = progress.split_once(" / ")?;
        let end = rest.split_whitespace().next()?;
        let (now, end): (f64, f64) = (now.trim().parse().ok()?, end.parse().ok()?);
        // Before t = 0 (deposition, the MPM's gravity phase) the run has
        // not started its simulated time.
        let preparing = matches!(phase, "deposition" | "gravity_phase");
        (end > 0.0).then(|| if preparing { 0.0 } else { (now / end).clamp(0.0, 1.0) })
    })
}

fn human_seconds(s: f64) -> String {
    if s < 90.0 {
        format!("{s:.0} s")
    } else if s < 5400.0 {
        format!("{:.0} min", s / 60.0)
    } else {
        format!("{:.1} h", s / 3600.0)
    }
}

/// The first of a summary's figures that a run's blow-up turns to NaN (or
/// infinity), if any: its time, the solid's runout, the liquid's mass and
/// Mach number, the MPM's kinetic energies and masses, the grains'
/// coordination. Figures NaN by design (an LBM-only run's runout, an
/// explicit packing's porosity) are not looked at.
fn nan_field(s: &RunSummary) -> Option<&'static str> {
    let mut figures = vec![("sim_time", s.sim_time)];
    if s.dem.is_some() || s.mpm.is_some() {
        figures.push(("runout", s.runout));
    }
    if let Some(d) = &s.dem {
        figures.push(("dem.coordination_final", d.coordination_final));
    }
    if let Some(l) = &s.lbm {
        figures.extend([("lbm.mass_relative_change", l.mass_relative_change), ("lbm.max_mach", l.max_mach)]);
    }
    if let Some(m) = &s.mpm {
        figures.extend([
            ("mpm.max_kinetic_energy", m.max_kinetic_energy),
            ("mpm.final_kinetic_energy", m.final_kinetic_energy),
            ("mpm.solid_mass_relative_change", m.solid_mass_relative_change),
        ]);
        if m.liquid_points > 0 {
            figures.push(("mpm.liquid_mass_relative_change", m.liquid_mass_relative_change));
        }
    }
    figures.into_iter().find(|(_, x)| !x.is_finite()).map(|(name, _)| name)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The ETA reads how far a running case has got from its last
    /// progress line; before t = 0 (deposition, gravity phase) it has
    /// done none of its run.
    #[test]
    fn a_running_case_is_as_far_as_its_last_progress_line() {
        let log = std::env::temp_dir().join(format!("sgf-campaign-log-{}", std::process::id()));
        let fraction = |text: &str| {
            std::fs::write(&log, text).unwrap();
            run_fraction(&log)
        };
        assert_eq!(
            fraction("deposition: t = 0.2464 / 3.000 s, 3.7 ms simulated per wall second, 40.8 s wall\n"),
            Some(0.0)
        );
        let f = fraction(
            "deposition: t = 3.000 / 3.000 s, 1 ms simulated per wall second, 80 s wall\n\
             collapse: t = 0.2125 / 0.850 s, 42.9 ms simulated per wall second, 15.4 s wall\n\
             dem_proc: a line with t = 1 s and a / in it\n",
        )
        .unwrap();
        assert!((f - 0.25).abs() < 1e-12, "{f}");
        assert_eq!(fraction("gravity_phase: t = 0.1 / 0.200 s, 1 ms simulated per wall second, 1 s wall\n"), Some(0.0));
        assert_eq!(fraction("coupler: nothing yet\n"), None);
        std::fs::remove_file(&log).ok();
    }

    /// A blow-up's NaN is caught in the figures it reaches, not only in the
    /// time; the figures NaN by design are left alone. The summary is a
    /// real one (`scenes/hard/neutral_grain.toml` to 0.1 s, fronts cut).
    #[test]
    fn nan_in_a_summary_is_named_by_its_field() {
        let real: RunSummary = serde_json::from_str(include_str!("testdata/summary_dem_lbm.json")).unwrap();
        assert_eq!(nan_field(&real), None);
        let mut s = real.clone();
        s.lbm.as_mut().unwrap().mass_relative_change = f64::NAN;
        assert_eq!(nan_field(&s), Some("lbm.mass_relative_change"));
        let mut s = real.clone();
        s.dem.as_mut().unwrap().coordination_final = f64::INFINITY;
        assert_eq!(nan_field(&s), Some("dem.coordination_final"));
        let mut s = real.clone();
        s.runout = f64::NAN;
        assert_eq!(nan_field(&s), Some("runout"));
        // An LBM-only run has no runout; an explicit packing no porosity.
        s.dem = None;
        s.porosity_initial = f64::NAN;
        assert_eq!(nan_field(&s), None);
    }

    /// `--quick`'s lists apply by the solvers a case runs.
    #[test]
    fn quick_overrides_follow_the_solvers_of_the_method() {
        let q = QuickOverrides {
            all: vec!["a".into()],
            dem: vec!["d".into()],
            lbm: vec!["l".into()],
            mpm: vec!["m".into()],
        };
        assert_eq!(q.for_method(Method::DemDry), ["a", "d"]);
        assert_eq!(q.for_method(Method::DemLbm), ["a", "d", "l"]);
        assert_eq!(q.for_method(Method::LbmFluid), ["a", "l"]);
        assert_eq!(q.for_method(Method::Mpm), ["a", "m"]);
    }

    /// One run in several speed-against-error sets: a list of sets and a
    /// level in each, the same length; a single name and number as before.
    #[test]
    fn a_case_joins_several_studies_with_a_level_in_each() {
        let spec = |extra: &str| -> CaseSpec {
            toml::from_str(&format!("name = \"c\"\nscene = \"s.toml\"\n{extra}")).unwrap()
        };
        assert_eq!(case_studies(&spec("")).unwrap(), []);
        assert_eq!(case_studies(&spec("study = \"lattice\"\nlevel = 4.5")).unwrap(), [("lattice".to_string(), 4.5)]);
        let both = case_studies(&spec("study = [\"lattice\", \"sub-steps\"]\nlevel = [4.17, 57]")).unwrap();
        assert_eq!(both, [("lattice".to_string(), 4.17), ("sub-steps".to_string(), 57.0)]);
        let err = case_studies(&spec("study = [\"lattice\", \"sub-steps\"]\nlevel = [4.17]")).unwrap_err();
        assert!(err.contains("2 stud(ies) but 1 level(s)"), "{err}");
        let err = case_studies(&spec("study = [\"a\", \"a\"]\nlevel = [1, 2]")).unwrap_err();
        assert!(err.contains("\"a\" is listed twice"), "{err}");
        let err = case_studies(&spec("study = \"a\"")).unwrap_err();
        assert!(err.contains("study and level go together"), "{err}");
    }

    /// A compare names each case once: a second row of the same case would
    /// draw nothing new.
    #[test]
    fn a_comparison_lists_each_case_once() {
        let compare = |cases: &[&str]| Comparison {
            name: "c".into(),
            title: String::new(),
            cases: cases.iter().map(|c| c.to_string()).collect(),
            times: vec![1.0],
        };
        let err = check_comparisons(&[compare(&["x", "x"])], &[]).unwrap_err();
        assert!(err.contains("case \"x\" is listed twice"), "{err}");
        let err = check_comparisons(&[compare(&["x"])], &[]).unwrap_err();
        assert!(err.contains("no case is named \"x\""), "{err}");
    }
}
