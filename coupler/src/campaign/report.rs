//! `OUT/report.md`: every run of a campaign in one table, the paper's
//! figures drawn from the runs' summaries, and the two methods side by
//! side. Written from the `summary.json` files alone, so it can be
//! rewritten at any time from what has finished.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use schemas::measures::FrontSample;
use schemas::scene::Condition;
use schemas::summary::{RunStatus, RunSummary};

use super::figures::{Chart, Series, Stroke, PALETTE};
use super::snapshots::{self, ComparisonRow, Recording};
use super::{Campaign, Case, Comparison, Schedule};

/// How the campaign was run, for the report's header.
#[derive(Debug, Clone)]
pub struct Context {
    pub command_line: String,
    pub schedule: Schedule,
    /// Wall time of this invocation, s.
    pub wall_seconds: f64,
    pub interrupted: bool,
    /// Cases this invocation started; none when it only rewrote the report.
    pub cases_started: usize,
}

/// Normalised times at which the report reads the fronts.
pub const FRONT_TIMES: [f64; 3] = [1.0, 2.0, 4.0];

/// One finished run and the measures the report takes from it.
#[derive(Debug, Clone)]
pub struct Row<'a> {
    pub case: &'a Case,
    pub summary: &'a RunSummary,
}

impl Row<'_> {
    /// The mass front at `t_norm`, linearly between samples; NaN outside the run.
    pub fn front_at(&self, t_norm: f64) -> f64 {
        let x = interpolate(&self.summary.front, t_norm);
        match self.summary.front.last() {
            // A run stopped at rest keeps its last front.
            Some(last) if x.is_nan() && t_norm > last.t_norm && self.summary.status == RunStatus::AtRest => last.x_norm,
            _ => x,
        }
    }

    /// Where the deposit falls below one grain diameter: the summary's
    /// `runout_pile` (the DEM's width-averaged height; the MPM's since
    /// session 32, by the same rule), or, for MPM summaries written before
    /// it, on the profile (the highest point top per bin) the first
    /// crossing of one diameter, linear between bin centres.
    pub fn pile_edge(&self) -> f64 {
        if let Some(p) = self.summary.runout_pile {
            return p;
        }
        let (dep, d) = (&self.summary.deposit, self.case.grain_diameter);
        if dep.is_empty() || d <= 0.0 {
            return f64::NAN;
        }
        let edge = match dep.iter().position(|p| p[1] < d) {
            None => dep[dep.len() - 1][0],
            Some(0) => dep[0][0],
            Some(i) => {
                let (a, b) = (dep[i - 1], dep[i]);
                a[0] + (b[0] - a[0]) * (a[1] - d) / (a[1] - b[1])
            }
        };
        let l0 = self.case.column_length;
        (edge - self.case.origin_x - l0) / l0
    }

    pub fn liquid_front_end(&self) -> f64 {
        self.summary.liquid_front.last().map_or(f64::NAN, |f| f.x_norm)
    }

    /// The run's wall time: every attempt's since its last fresh start
    /// when the campaign ran it (a resumed run costs all its attempts),
    /// else the summary's.
    pub fn wall(&self) -> f64 {
        super::attempts_wall(self.case)
            .map(|w| w.0)
            .unwrap_or(self.summary.wall_seconds_total.unwrap_or(self.summary.wall_seconds))
    }

    /// Relative change of the liquid's mass over the run (the solids'
    /// are conserved by construction in both methods).
    pub fn liquid_mass_drift(&self) -> f64 {
        match (&self.summary.lbm, &self.summary.mpm) {
            (Some(l), _) => l.mass_relative_change,
            (None, Some(m)) if m.liquid_points > 0 => m.liquid_mass_relative_change,
            _ => f64::NAN,
        }
    }

    pub fn throughput(&self) -> String {
        let t = &self.summary.throughput;
        let mut parts = Vec::new();
        if let Some(p) = t.particle_steps_per_s {
            parts.push(format!("{p:.2e} particle-steps/s"));
        }
        if let Some(c) = t.cell_updates_per_s {
            parts.push(format!("{:.1} MLUPS", c / 1e6));
        }
        if let Some(p) = t.point_updates_per_s {
            parts.push(format!("{p:.2e} point-updates/s"));
        }
        parts.join(", ")
    }
}

/// Linear interpolation of a front in normalised time; NaN outside it.
pub fn interpolate(front: &[FrontSample], t_norm: f64) -> f64 {
    let i = front.partition_point(|f| f.t_norm < t_norm);
    match (i.checked_sub(1).and_then(|j| front.get(j)), front.get(i)) {
        (_, Some(b)) if b.t_norm == t_norm => b.x_norm,
        (Some(a), Some(b)) => a.x_norm + (b.x_norm - a.x_norm) * (t_norm - a.t_norm) / (b.t_norm - a.t_norm),
        _ => f64::NAN,
    }
}

fn condition_word(c: Condition) -> &'static str {
    match c {
        Condition::Dry => "dry",
        Condition::Saturated => "saturated",
        Condition::Liquid => "liquid",
    }
}

/// A column's H0 and L0 in µm: runs of one column are repeats (seeds).
type Column = (u64, u64);

/// Runs of one series, condition and column (several: seeds).
type GroupKey = (Condition, String, Column);

fn key(row: &Row) -> GroupKey {
    let um = |m: f64| (m * 1e6).round() as u64;
    (row.case.condition, row.case.series.clone(), (um(row.case.column_height), um(row.case.column_length)))
}

/// Each series' colour, in the order the campaign file names them.
fn series_colors(rows: &[Row]) -> BTreeMap<String, plotters::style::RGBColor> {
    let mut colors = BTreeMap::new();
    for r in rows {
        let n = colors.len();
        colors.entry(r.case.series.clone()).or_insert(PALETTE[n % PALETTE.len()]);
    }
    colors
}

/// A series name as part of a file name.
fn slug(name: &str) -> String {
    name.chars().map(|c| if c.is_ascii_alphanumeric() { c.to_ascii_lowercase() } else { '_' }).collect()
}

fn scientific(x: f64) -> String {
    if x.is_finite() {
        format!("{x:.2e}")
    } else {
        "–".into()
    }
}

fn number(x: f64, digits: usize) -> String {
    if x.is_finite() {
        format!("{x:.digits$}")
    } else {
        "–".into()
    }
}

/// Mean, least and largest of the finite values.
fn spread(values: impl Iterator<Item = f64>) -> Option<(f64, f64, f64, usize)> {
    let v: Vec<f64> = values.filter(|x| x.is_finite()).collect();
    if v.is_empty() {
        return None;
    }
    let mean = v.iter().sum::<f64>() / v.len() as f64;
    Some((
        mean,
        v.iter().copied().fold(f64::INFINITY, f64::min),
        v.iter().copied().fold(f64::NEG_INFINITY, f64::max),
        v.len(),
    ))
}

fn machine() -> String {
    let cores = std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1);
    let model = std::fs::read_to_string("/proc/cpuinfo")
        .ok()
        .and_then(|c| {
            c.lines()
                .find_map(|l| l.strip_prefix("model name").map(|m| m.trim_start_matches([' ', '\t', ':']).to_string()))
        })
        .unwrap_or_else(|| "unknown CPU".into());
    format!("{cores} cores ({model})")
}

/// Writes `OUT/report.md` and `OUT/figures/*.{svg,png}`; returns the report's path.
pub fn write(campaign: &Campaign, summaries: &[Option<RunSummary>], ctx: &Context) -> Result<PathBuf, String> {
    let rows: Vec<Row> = campaign
        .cases
        .iter()
        .zip(summaries)
        .filter_map(|(case, s)| s.as_ref().map(|summary| Row { case, summary }))
        .collect();
    let figures = campaign.out.join("figures");
    std::fs::create_dir_all(&figures).map_err(|e| format!("cannot create {}: {e}", figures.display()))?;
    let mut md = String::new();
    header(&mut md, campaign, &rows, ctx);
    runs_table(&mut md, campaign, summaries);
    fronts_section(&mut md, &rows, &figures)?;
    runout_section(&mut md, &rows, &figures)?;
    deposits_section(&mut md, &rows, &figures)?;
    methods_table(&mut md, &rows);
    outcomes_section(&mut md, campaign, summaries);
    speed_against_error(&mut md, &rows, &campaign.cases, &figures)?;
    recorded_sections(&mut md, &rows, &campaign.comparisons, &figures)?;
    let path = campaign.out.join("report.md");
    std::fs::write(&path, &md).map_err(|e| format!("cannot write {}: {e}", path.display()))?;
    remove_unlinked_figures(&figures, &md)?;
    Ok(path)
}

/// Removes the images in `figures` that `md` does not link: those of an
/// earlier report whose cases or comparisons have changed, which a reader
/// of the folder would take for this report's.
fn remove_unlinked_figures(figures: &Path, md: &str) -> Result<(), String> {
    let linked: std::collections::HashSet<&str> =
        md.split("figures/").skip(1).filter_map(|rest| rest.split([')', ' ', '\n']).next()).collect();
    let entries = std::fs::read_dir(figures).map_err(|e| format!("cannot list {}: {e}", figures.display()))?;
    for entry in entries.flatten() {
        let path = entry.path();
        let is_image = path.extension().is_some_and(|e| e == "svg" || e == "png");
        let name = entry.file_name();
        if is_image && !name.to_str().is_some_and(|n| linked.contains(n)) {
            std::fs::remove_file(&path).map_err(|e| format!("cannot remove the stale {}: {e}", path.display()))?;
        }
    }
    Ok(())
}

fn header(md: &mut String, campaign: &Campaign, rows: &[Row], ctx: &Context) {
    let _ = writeln!(md, "# Campaign {}{}\n", campaign.name, if campaign.quick { " (quick)" } else { "" });
    if !campaign.description.is_empty() {
        let _ = writeln!(md, "{}\n", campaign.description);
    }
    if campaign.quick {
        md.push_str(
            "> **Quick form**: a coarse version of the matrix (`[quick]` of the campaign file) that checks the \
             whole chain in minutes. Its numbers are not the study's.\n\n",
        );
    }
    let cases_wall: f64 = rows.iter().map(Row::wall).sum();
    let _ = writeln!(
        md,
        "Made by `{}` from `{}` on {}, {} case(s) at a time with {} thread(s) each. \
         {} of {} cases finished{}. {}; the finished runs' own wall times sum to {:.0} s.\n",
        ctx.command_line,
        campaign.file.display(),
        machine(),
        ctx.schedule.jobs,
        ctx.schedule.threads,
        rows.len(),
        campaign.cases.len(),
        if ctx.interrupted { " (the campaign was interrupted: run the same command again to continue)" } else { "" },
        if ctx.cases_started == 0 {
            "This invocation ran no case (it wrote the report from the finished runs)".to_string()
        } else {
            format!("This invocation ran {} case(s) in {:.0} s", ctx.cases_started, ctx.wall_seconds)
        },
        cases_wall
    );
    md.push_str(
        "Fronts are normalised as in the paper: (X_f − L0)/L0 against t/t_ref, t_ref = √(H0/g) dry and \
         √(H0/g′) saturated; X_f leaves 0.5 % of the solid mass beyond it. The *pile edge* is where the \
         deposit's height falls below one grain diameter. DEM means DEM (dry) or DEM–LBM (saturated).\n\n",
    );
}

fn runs_table(md: &mut String, campaign: &Campaign, summaries: &[Option<RunSummary>]) {
    md.push_str("## Runs\n\n");
    md.push_str(
        "| case | method | condition | a | status | t_end / t_ref | wall s | throughput | runout | pile edge | \
         front at 1 / 2 / 4 t_ref | liquid front | liquid mass drift | peak Mach |\n",
    );
    md.push_str("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n");
    for (case, summary) in campaign.cases.iter().zip(summaries) {
        let Some(summary) = summary else {
            let _ = writeln!(
                md,
                "| {} | {} | {} | {:.2} | not finished | | | | | | | | | |",
                case.name,
                case.method.name(),
                condition_word(case.condition),
                case.aspect()
            );
            continue;
        };
        let row = Row { case, summary };
        let fronts: Vec<String> = FRONT_TIMES.iter().map(|&t| number(row.front_at(t), 2)).collect();
        let mach = summary.lbm.as_ref().map_or(f64::NAN, |l| l.max_mach);
        let _ = writeln!(
            md,
            "| {} | {} | {} | {:.2} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} |",
            case.name,
            case.method.name(),
            condition_word(case.condition),
            case.aspect(),
            summary.status,
            number(summary.sim_time / summary.t_ref, 2),
            number(row.wall(), 1),
            row.throughput(),
            number(summary.runout, 3),
            number(row.pile_edge(), 3),
            fronts.join(" / "),
            number(row.liquid_front_end(), 3),
            if row.liquid_mass_drift().is_finite() { format!("{:.1e}", row.liquid_mass_drift()) } else { "–".into() },
            number(mach, 3),
        );
    }
    md.push('\n');
}

/// Figure file names are the stem; the report links the SVG and the PNG.
fn figure(md: &mut String, stem: &str, alt: &str) {
    let _ = writeln!(md, "![{alt}](figures/{stem}.svg)\n\n[PNG](figures/{stem}.png)\n");
}

fn groups<'a>(rows: &'a [Row<'a>]) -> BTreeMap<GroupKey, Vec<&'a Row<'a>>> {
    let mut g: BTreeMap<GroupKey, Vec<&Row>> = BTreeMap::new();
    for r in rows {
        g.entry(key(r)).or_default().push(r);
    }
    g
}

fn front_points(front: &[FrontSample]) -> Vec<(f64, f64)> {
    front.iter().map(|f| (f.t_norm, f.x_norm)).collect()
}

fn fronts_section(md: &mut String, rows: &[Row], dir: &Path) -> Result<(), String> {
    md.push_str(
        "## Fronts (the paper's Figs. 3 and 10)\n\nEach case with both methods: the solid front (solid line) \
         and the liquid front (dashed).\n\n",
    );
    // Cases: one condition and column height, every method and seed.
    let mut cases: BTreeMap<(Condition, Column), Vec<&Row>> = BTreeMap::new();
    for r in rows {
        let (c, _, column) = key(r);
        cases.entry((c, column)).or_default().push(r);
    }
    let colors = series_colors(rows);
    // Columns of one H0 with different L0 get the aspect ratio in their file name.
    let mut heights: BTreeMap<(Condition, u64), usize> = BTreeMap::new();
    for (condition, (h_um, _)) in cases.keys() {
        *heights.entry((*condition, *h_um)).or_default() += 1;
    }
    for ((condition, (h_um, _)), runs) in &cases {
        let h0 = *h_um as f64 * 1e-6;
        let a = runs[0].case.aspect();
        let mut series = Vec::new();
        let mut labelled = std::collections::BTreeSet::new();
        for r in runs {
            let name = &r.case.series;
            let color = colors[name];
            let first = labelled.insert(name);
            let label = |what: &str| if first { format!("{name} {what}") } else { String::new() };
            series.push(Series::new(label("solid front"), front_points(&r.summary.front), color, Stroke::Solid));
            if !r.summary.liquid_front.is_empty() {
                series.push(Series::new(
                    label("liquid front"),
                    front_points(&r.summary.liquid_front),
                    color,
                    Stroke::Dashed,
                ));
            }
        }
        let mut stem = format!("front_{}_h{:03}", condition_word(*condition), (h0 * 1000.0).round() as u64);
        if heights[&(*condition, *h_um)] > 1 {
            stem.push_str(&format!("_a{:.0}", a * 100.0));
        }
        Chart {
            title: format!("{}, H0 = {:.2} m, a = {a:.2}", capitalised(condition_word(*condition)), h0),
            x_label: "t / t_ref".into(),
            y_label: "(X_f − L0) / L0".into(),
            series,
            log_axes: false,
        }
        .write(&dir.join(&stem))?;
        figure(md, &stem, &format!("fronts, {} a = {a:.2}", condition_word(*condition)));
    }
    // The paper's layout: every aspect ratio on one figure, per condition and method.
    for ((condition, family), runs) in by_condition_and_series(rows) {
        let series = aspect_series(&runs, |r| front_points(&r.summary.front), Stroke::Solid);
        let stem = format!("fronts_{}_{}", condition_word(condition), slug(&family));
        Chart {
            title: format!("{} fronts, {}", family, condition_word(condition)),
            x_label: "t / t_ref".into(),
            y_label: "(X_f − L0) / L0".into(),
            series,
            log_axes: false,
        }
        .write(&dir.join(&stem))?;
        figure(md, &stem, &format!("{family} fronts, {}, every aspect ratio", condition_word(condition)));
    }
    Ok(())
}

fn capitalised(word: &str) -> String {
    let mut c = word.chars();
    c.next().map(|f| f.to_uppercase().chain(c).collect()).unwrap_or_default()
}

fn by_condition_and_series<'a>(rows: &'a [Row<'a>]) -> BTreeMap<(Condition, String), Vec<&'a Row<'a>>> {
    let mut m: BTreeMap<(Condition, String), Vec<&Row>> = BTreeMap::new();
    for r in rows {
        m.entry((r.case.condition, r.case.series.clone())).or_default().push(r);
    }
    m
}

/// One curve per run, coloured by aspect ratio, labelled once per ratio.
fn aspect_series(runs: &[&Row], points: impl Fn(&Row) -> Vec<(f64, f64)>, stroke: Stroke) -> Vec<Series> {
    let mut aspects: Vec<u64> = runs.iter().map(|r| (r.case.aspect() * 1000.0).round() as u64).collect();
    aspects.sort_unstable();
    aspects.dedup();
    let mut labelled = std::collections::BTreeSet::new();
    runs.iter()
        .map(|r| {
            let a = (r.case.aspect() * 1000.0).round() as u64;
            let color = PALETTE[aspects.iter().position(|&x| x == a).unwrap_or(0) % PALETTE.len()];
            let label = if labelled.insert(a) { format!("a = {:.2}", r.case.aspect()) } else { String::new() };
            Series::new(label, points(r), color, stroke)
        })
        .collect()
}

fn runout_section(md: &mut String, rows: &[Row], dir: &Path) -> Result<(), String> {
    md.push_str(
        "## Runout against aspect ratio (the paper's Fig. 12)\n\nMean over the runs of each case (markers) and \
         their range (bars) where a case was run with several deposition seeds.\n\n",
    );
    let groups = groups(rows);
    let mut series = Vec::new();
    let mut table = String::from(
        "| method | condition | a | runs | runout (0.5 % front) | range | pile edge |\n|---|---|---|---|---|---|---|\n",
    );
    for (n, ((condition, family), _)) in by_condition_and_series(rows).into_iter().enumerate() {
        let mut points = Vec::new();
        let mut bars = Vec::new();
        for ((c, f, _), runs) in &groups {
            if *c != condition || f != &family {
                continue;
            }
            let a = runs[0].case.aspect();
            let Some((mean, lo, hi, count)) = spread(runs.iter().map(|r| r.summary.runout)) else { continue };
            let pile = spread(runs.iter().map(|r| r.pile_edge())).map_or(f64::NAN, |p| p.0);
            points.push((a, mean));
            if count > 1 {
                bars.push((a, lo, hi));
            }
            let _ = writeln!(
                table,
                "| {family} | {} | {a:.2} | {count} | {mean:.3} | {} | {} |",
                condition_word(condition),
                if count > 1 { format!("{lo:.3}–{hi:.3}") } else { "–".into() },
                number(pile, 3)
            );
        }
        let color = PALETTE[n % PALETTE.len()];
        let stroke = if condition == Condition::Dry { Stroke::Dashed } else { Stroke::Solid };
        series.push(Series::new(format!("{family} {}", condition_word(condition)), points.clone(), color, stroke));
        series.push(Series { bars, ..Series::new("", points, color, Stroke::Markers) });
    }
    Chart {
        title: "Runout against aspect ratio".into(),
        x_label: "a = H0 / L0".into(),
        y_label: "(L_f − L0) / L0".into(),
        series,
        log_axes: false,
    }
    .write(&dir.join("runout"))?;
    figure(md, "runout", "runout against aspect ratio");
    md.push_str(&table);
    md.push('\n');
    Ok(())
}

/// The method of a series' runs (`DEM` or `MPM`).
fn r_family(runs: &[&Row]) -> &'static str {
    runs.first().map_or("DEM", |r| r.case.family())
}

fn deposits_section(md: &mut String, rows: &[Row], dir: &Path) -> Result<(), String> {
    md.push_str(
        "## Final deposits (the paper's Fig. 11)\n\nHeight of the deposit averaged over the flume's width \
         against the distance from the gate, both normalised; DEM solid, MPM dashed.\n\n",
    );
    let mut by_condition: BTreeMap<Condition, Vec<&Row>> = BTreeMap::new();
    for r in rows {
        by_condition.entry(r.case.condition).or_default().push(r);
    }
    let names: Vec<String> = series_colors(rows).into_keys().collect();
    for (condition, runs) in by_condition {
        let mut series = Vec::new();
        for family in &names {
            let of: Vec<&Row> = runs.iter().copied().filter(|r| &r.case.series == family).collect();
            if of.is_empty() {
                continue;
            }
            let stroke = if r_family(&of) == "MPM" { Stroke::Dashed } else { Stroke::Solid };
            let mut s = aspect_series(
                &of,
                |r| {
                    let (l0, h0) = (r.case.column_length, r.case.column_height);
                    r.summary.deposit.iter().map(|p| ((p[0] - l0) / l0, p[1] / h0)).collect()
                },
                stroke,
            );
            for x in &mut s {
                if !x.label.is_empty() {
                    x.label = format!("{family} {}", x.label);
                }
            }
            series.extend(s);
        }
        let stem = format!("deposit_{}", condition_word(condition));
        Chart {
            title: format!("Final deposits, {}", condition_word(condition)),
            x_label: "(x − L0) / L0".into(),
            y_label: "h / H0".into(),
            series,
            log_axes: false,
        }
        .write(&dir.join(&stem))?;
        figure(md, &stem, &format!("final deposits, {}", condition_word(condition)));
    }
    Ok(())
}

/// Every case with an expected outcome (hard cases): what it must do,
/// what it did, and the evidence (the cause its log names when stopped;
/// mass drift and time reached when it ran).
fn outcomes_section(md: &mut String, campaign: &Campaign, summaries: &[Option<RunSummary>]) {
    let expecting: Vec<(&Case, Option<&RunSummary>)> = campaign
        .cases
        .iter()
        .zip(summaries)
        .filter(|(c, _)| c.expect.is_some() || c.max_wall.is_some())
        .map(|(c, s)| (c, s.as_ref()))
        .collect();
    if expecting.is_empty() {
        return;
    }
    md.push_str(
        "## Expected outcomes\n\nEach case must run (completed or at rest), stop with a message naming the \
         cause, or either; never panic, hang or give NaN.\n\n| case | expected | got | t_end / t_ref | liquid mass drift | \
         verdict | what its log says |\n|---|---|---|---|---|---|---|\n",
    );
    for (case, summary) in expecting {
        let expected = case.expect.as_ref().map_or("runs", |e| e.outcome.word());
        let log = std::fs::read_to_string(case.dir.with_file_name(format!("{}.log", case.name))).unwrap_or_default();
        let words = case.expect.as_ref().and_then(|e| e.message.clone());
        // The line naming the cause, or the solver's last word.
        let said = words
            .as_deref()
            .and_then(|w| log.lines().find(|l| l.contains(w)))
            .or_else(|| {
                log.lines().rev().find(|l| l.contains("unstable") || l.contains("at_rest") || l.contains("completed"))
            })
            .unwrap_or("")
            .replace('|', "/");
        let said: String = said.chars().take(320).collect();
        let (got, t, drift) = match summary {
            Some(s) => {
                let row = Row { case, summary: s };
                (s.status.to_string(), number(s.sim_time / s.t_ref, 2), scientific(row.liquid_mass_drift()))
            }
            None => ("not finished".into(), "–".into(), "–".into()),
        };
        let verdict = match case.verdict(summary) {
            Ok(()) => "as expected".to_string(),
            Err(why) => format!("**not as expected**: {why}"),
        };
        let _ = writeln!(md, "| {} | {expected} | {got} | {t} | {drift} | {verdict} | {said} |", case.name);
    }
    md.push('\n');
}

/// The relative L2 distance between a front and a reference front over
/// normalised time: √(∫ (x − x_ref)² dt / ∫ x_ref² dt) on [0, the
/// shorter run's end], both read every 0.05 t_ref (linear between
/// samples). NaN when the two share no time.
pub fn front_l2(front: &[FrontSample], reference: &[FrontSample]) -> f64 {
    let end = match (front.last(), reference.last()) {
        (Some(a), Some(b)) => a.t_norm.min(b.t_norm),
        _ => return f64::NAN,
    };
    if !(end.is_finite() && end >= 0.0) {
        return f64::NAN;
    }
    let (mut diff, mut norm) = (0.0, 0.0);
    let steps = (end / 0.05).floor() as usize;
    for k in 0..=steps {
        let t = k as f64 * 0.05;
        let (x, r) = (interpolate(front, t), interpolate(reference, t));
        if x.is_finite() && r.is_finite() {
            diff += (x - r) * (x - r);
            norm += r * r;
        }
    }
    if norm > 0.0 {
        (diff / norm).sqrt()
    } else {
        f64::NAN
    }
}

/// The observed order of convergence from two errors at two levels
/// (levels grow as runs get finer, as 1/h): ln(e_coarse/e_fine) /
/// ln(level_fine/level_coarse).
pub fn observed_order(coarse: (f64, f64), fine: (f64, f64)) -> f64 {
    (coarse.1 / fine.1).ln() / (fine.0 / coarse.0).ln()
}

/// Speed against error for each `study` of the campaign: each level's
/// wall time against its runout's and its front's error from the finest
/// level's run, on log-log axes, and the observed orders.
fn speed_against_error(md: &mut String, rows: &[Row], cases: &[Case], dir: &Path) -> Result<(), String> {
    let mut studies: BTreeMap<&str, Vec<(f64, &Row)>> = BTreeMap::new();
    for r in rows {
        for (study, level) in &r.case.studies {
            studies.entry(study).or_default().push((*level, r));
        }
    }
    if studies.is_empty() {
        return Ok(());
    }
    md.push_str(
        "## Speed against error\n\nEach study's runs against its finest: the runout's relative error and the \
         front's relative L2 error over normalised time (to the shorter run's end), against each run's wall \
         time. The observed order p between two levels is ln(e_coarse / e_fine) / ln(level_fine / \
         level_coarse) (levels grow as 1/h).\n\n",
    );
    let mut table = String::from(
        "| study | level | case | wall s | runout | runout error | front L2 error | order (runout) | order (front) |\n\
         |---|---|---|---|---|---|---|---|---|\n",
    );
    let mut series = Vec::new();
    for (n, (study, mut runs)) in studies.into_iter().enumerate() {
        runs.sort_by(|a, b| a.0.total_cmp(&b.0));
        let (finest_level, reference) = *runs.last().expect("a study has a run");
        // The reference is the finest level of the campaign file, finished or not.
        let finest = cases
            .iter()
            .flat_map(|c| c.studies.iter().filter(|(s, _)| s == study).map(move |(_, l)| (*l, &c.name)))
            .max_by(|a, b| a.0.total_cmp(&b.0));
        if let Some((level, name)) = finest.filter(|(level, _)| *level > finest_level) {
            let _ = writeln!(
                table,
                "| {study} | {level} | {name} | not finished: no errors until the finest run has | | | | | |"
            );
            continue;
        }
        let mut points = (Vec::new(), Vec::new());
        let mut previous: Option<(f64, f64, f64)> = None;
        for &(level, r) in &runs {
            let is_reference = std::ptr::eq(r, reference);
            let runout_error = (r.summary.runout - reference.summary.runout).abs() / reference.summary.runout.abs();
            let front_error = front_l2(&r.summary.front, &reference.summary.front);
            let (order_runout, order_front) = match previous {
                Some((l, er, ef)) if !is_reference => {
                    (observed_order((l, er), (level, runout_error)), observed_order((l, ef), (level, front_error)))
                }
                _ => (f64::NAN, f64::NAN),
            };
            let _ = writeln!(
                table,
                "| {study} | {level} | {} | {} | {} | {} | {} | {} | {} |",
                r.case.name,
                number(r.wall(), 1),
                number(r.summary.runout, 3),
                if is_reference { "(reference)".into() } else { scientific(runout_error) },
                if is_reference { "(reference)".into() } else { scientific(front_error) },
                number(order_runout, 2),
                number(order_front, 2),
            );
            if !is_reference {
                points.0.push((r.wall(), runout_error));
                points.1.push((r.wall(), front_error));
                previous = Some((level, runout_error, front_error));
            }
        }
        let color = PALETTE[n % PALETTE.len()];
        series.push(Series::new(format!("{study}: runout"), points.0.clone(), color, Stroke::Solid));
        series.push(Series::new("", points.0, color, Stroke::Markers));
        series.push(Series::new(format!("{study}: front L2"), points.1.clone(), color, Stroke::Dashed));
        series.push(Series::new("", points.1, color, Stroke::Markers));
    }
    Chart {
        title: "Speed against error".into(),
        x_label: "wall time, s".into(),
        y_label: "relative error against the finest run".into(),
        series,
        log_axes: true,
    }
    .write(&dir.join("speed_error"))?;
    figure(md, "speed_error", "speed against error");
    md.push_str(&table);
    md.push('\n');
    Ok(())
}

/// The figures drawn from each run's recording: snapshots of every case,
/// the campaign's side-by-side comparisons, coordination numbers of the
/// DEM's, the fluidised share of the MPM's. Each recording is read once.
fn recorded_sections(md: &mut String, rows: &[Row], comparisons: &[Comparison], dir: &Path) -> Result<(), String> {
    // For each comparison, its rows as they are read (by case name).
    let mut compared: Vec<BTreeMap<&str, Result<Option<ComparisonRow>, String>>> =
        comparisons.iter().map(|_| BTreeMap::new()).collect();
    let mut snaps = String::from(
        "## Snapshots (the paper's Figs. 2, 4, 5 and 9)\n\nSide views (x–z) at t/t_ref = 0, 1, 2, 4 and at the \
         end of each run; all the flume's width projected. Raster images (PNG).\n\n",
    );
    let mut coordination = String::from(
        "## Coordination numbers (the paper's Figs. 6–7)\n\nThe fraction of grains with each number of \
         contacts at t/t_ref = 0, 1, 2, 4 and at the end (`coordination` of `/dem/particles`).\n\n",
    );
    let mut fluidised: Vec<Series> = Vec::new();
    let mut fluidised_table =
        String::from("| case | largest share | summary's `fluidised_fraction_max` |\n|---|---|---|\n");
    let mpm_rows: Vec<&Row> = rows.iter().filter(|r| r.case.family() == "MPM").collect();
    for r in rows {
        let path = r.case.dir.join("run.mcap");
        if !path.exists() {
            let _ = writeln!(snaps, "{}: no recording ({} is missing)\n", r.case.name, path.display());
            continue;
        }
        // One unreadable recording costs its own figures, not the report.
        let rec = match Recording::read(&path) {
            Ok(rec) => rec,
            Err(e) => {
                let _ = writeln!(snaps, "{}: {e}\n", r.case.name);
                continue;
            }
        };
        for (c, rows) in comparisons.iter().zip(compared.iter_mut()) {
            if c.cases.contains(&r.case.name) {
                rows.insert(&r.case.name, snapshots::comparison_row(r.case, r.summary, &rec, &c.times));
            }
        }
        let stem = format!("snapshots_{}", r.case.name);
        match snapshots::snapshots(r.case, r.summary, &rec, &dir.join(format!("{stem}.png"))) {
            Ok(true) => {
                let _ = writeln!(snaps, "![snapshots of {}](figures/{stem}.png)\n", r.case.name);
            }
            Ok(false) => {}
            Err(e) => {
                let _ = writeln!(snaps, "{}: no snapshots: {e}\n", r.case.name);
            }
        }
        if r.case.family() == "DEM" {
            match snapshots::coordination(r.case, r.summary, &rec).and_then(|chart| {
                let stem = format!("coordination_{}", r.case.name);
                chart.map(|c| c.write(&dir.join(&stem)).map(|_| stem)).transpose()
            }) {
                Ok(Some(stem)) => figure(&mut coordination, &stem, &format!("coordination numbers of {}", r.case.name)),
                Ok(None) => {}
                Err(e) => {
                    let _ = writeln!(coordination, "{}: {e}\n", r.case.name);
                }
            }
        } else if r.case.family() == "MPM" {
            let share = match snapshots::fluidised_share(r.summary, &rec) {
                Ok(share) => share,
                Err(e) => {
                    let _ = writeln!(fluidised_table, "| {} | {e} | |", r.case.name);
                    continue;
                }
            };
            let largest = share.iter().map(|p| p.1).fold(f64::NAN, f64::max);
            let _ = writeln!(
                fluidised_table,
                "| {} | {} | {} |",
                r.case.name,
                number(largest, 4),
                r.summary.mpm.as_ref().map_or("–".into(), |m| number(m.fluidised_fraction_max, 4))
            );
            // Coloured by aspect ratio, as the other figures.
            let mut aspects: Vec<u64> = mpm_rows.iter().map(|m| (m.case.aspect() * 1000.0).round() as u64).collect();
            aspects.sort_unstable();
            aspects.dedup();
            let k = aspects.iter().position(|&a| a == (r.case.aspect() * 1000.0).round() as u64).unwrap_or(0);
            let stroke = if r.case.condition == Condition::Dry { Stroke::Dashed } else { Stroke::Solid };
            let label = format!("{} a = {:.2}", condition_word(r.case.condition), r.case.aspect());
            fluidised.push(Series::new(label, share, PALETTE[k % PALETTE.len()], stroke));
        }
    }
    comparison_section(md, comparisons, compared, dir);
    md.push_str(&snaps);
    md.push_str(&coordination);
    if !fluidised.is_empty() {
        md.push_str(
            "## The MPM's fluidised share (the paper's Fig. 8)\n\nThe share of the soil's points whose porosity \
             exceeds n_max (they carry no effective stress), on every recorded frame.\n\n",
        );
        Chart {
            title: "MPM: fluidised share of the soil".into(),
            x_label: "t / t_ref".into(),
            y_label: "fluidised share of the solid points".into(),
            series: fluidised,
            log_axes: false,
        }
        .write(&dir.join("fluidised"))?;
        figure(md, "fluidised", "fluidised share of the MPM soil");
        md.push_str(&fluidised_table);
        md.push('\n');
    }
    Ok(())
}

/// The campaign's `[[compare]]` figures: the listed cases' snapshots side
/// by side, a row per case and a column per time; a case without a
/// recording is named in place of its row.
fn comparison_section(
    md: &mut String,
    comparisons: &[Comparison],
    mut compared: Vec<BTreeMap<&str, Result<Option<ComparisonRow>, String>>>,
    dir: &Path,
) {
    for (c, found) in comparisons.iter().zip(compared.iter_mut()) {
        let title = if c.title.is_empty() { format!("Side by side: {}", c.name) } else { c.title.clone() };
        let _ = writeln!(
            md,
            "## {title}\n\nRows top to bottom: {}; columns at t/t_ref = {}. Soil points brown (fluidised \
             orange), pore water blue; grains by speed, water surface blue.\n",
            c.cases.iter().map(|n| format!("`{n}`")).collect::<Vec<_>>().join(", "),
            c.times.iter().map(|t| format!("{t}")).collect::<Vec<_>>().join(", ")
        );
        let mut rows = Vec::new();
        let mut missing = Vec::new();
        for name in &c.cases {
            match found.remove(name.as_str()) {
                Some(Ok(Some(row))) => rows.push(row),
                Some(Ok(None)) => missing.push(format!("{name}: its recording holds no points")),
                Some(Err(e)) => missing.push(format!("{name}: {e}")),
                None => missing.push(format!("{name}: not finished or no recording")),
            }
        }
        for m in &missing {
            let _ = writeln!(md, "- {m}");
        }
        if rows.is_empty() {
            md.push('\n');
            continue;
        }
        let stem = format!("compare_{}", c.name);
        match snapshots::comparison(&title, rows, &dir.join(format!("{stem}.png"))) {
            Ok(()) => {
                let _ = writeln!(md, "\n![{title}](figures/{stem}.png)\n");
            }
            Err(e) => {
                let _ = writeln!(md, "\n{e}\n");
            }
        }
    }
}

/// Both methods case by case (the runs' means); `*` where their pile
/// edges differ by more than 20 %.
fn methods_table(md: &mut String, rows: &[Row]) {
    md.push_str(
        "## The two methods side by side\n\n| condition | a | DEM runout | MPM runout | DEM pile edge | MPM pile edge | \
         MPM / DEM pile edge | DEM front 1 / 2 / 4 t_ref | MPM front 1 / 2 / 4 t_ref | DEM liquid front | MPM liquid front |\n\
         |---|---|---|---|---|---|---|---|---|---|---|\n",
    );
    let groups = groups(rows);
    let heights: std::collections::BTreeSet<(Condition, Column)> = groups.keys().map(|(c, _, h)| (*c, *h)).collect();
    for (condition, h) in heights {
        let (Some(dem), Some(mpm)) =
            (groups.get(&(condition, "DEM".to_string(), h)), groups.get(&(condition, "MPM".to_string(), h)))
        else {
            continue;
        };
        let mean = |runs: &[&Row], f: &dyn Fn(&Row) -> f64| spread(runs.iter().map(|r| f(r))).map_or(f64::NAN, |s| s.0);
        let fronts = |runs: &[&Row]| {
            FRONT_TIMES.iter().map(|&t| number(mean(runs, &|r| r.front_at(t)), 2)).collect::<Vec<_>>().join(" / ")
        };
        let (pd, pm) = (mean(dem, &|r| r.pile_edge()), mean(mpm, &|r| r.pile_edge()));
        let ratio = pm / pd;
        let _ = writeln!(
            md,
            "| {} | {:.2} | {} | {} | {} | {} | {}{} | {} | {} | {} | {} |",
            condition_word(condition),
            dem[0].case.aspect(),
            number(mean(dem, &|r| r.summary.runout), 3),
            number(mean(mpm, &|r| r.summary.runout), 3),
            number(pd, 3),
            number(pm, 3),
            number(ratio, 2),
            if (ratio - 1.0).abs() > 0.2 { " *" } else { "" },
            fronts(dem),
            fronts(mpm),
            number(mean(dem, &|r| r.liquid_front_end()), 3),
            number(mean(mpm, &|r| r.liquid_front_end()), 3),
        );
    }
    md.push('\n');
}

#[cfg(test)]
mod tests {
    #[test]
    fn figures_the_report_does_not_link_are_removed() {
        let dir = std::env::temp_dir().join(format!("sgf-figures-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        for name in ["front.svg", "front.png", "old_case.png", "old.svg", "notes.txt"] {
            std::fs::write(dir.join(name), b"x").unwrap();
        }
        let md = "![fronts](figures/front.svg)\n\n[PNG](figures/front.png)\n";
        super::remove_unlinked_figures(&dir, md).unwrap();
        let mut left: Vec<String> =
            std::fs::read_dir(&dir).unwrap().flatten().map(|e| e.file_name().into_string().unwrap()).collect();
        left.sort();
        assert_eq!(left, ["front.png", "front.svg", "notes.txt"]);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    use super::*;

    fn sample(t_norm: f64, x_norm: f64) -> FrontSample {
        FrontSample { t: t_norm * 0.1, t_norm, x: 0.04 * (1.0 + x_norm), x_norm }
    }

    /// A front read between samples is the straight line between them;
    /// at a sample, the sample; outside the run, NaN.
    #[test]
    fn fronts_interpolate_between_samples() {
        let front = [sample(0.0, 0.0), sample(1.0, 1.0), sample(3.0, 2.0)];
        assert_eq!(interpolate(&front, 1.0), 1.0);
        assert!((interpolate(&front, 2.0) - 1.5).abs() < 1e-12);
        assert!((interpolate(&front, 0.25) - 0.25).abs() < 1e-12);
        assert!(interpolate(&front, 3.5).is_nan());
        assert!(interpolate(&front, -0.1).is_nan());
        assert!(interpolate(&[], 1.0).is_nan());
    }

    /// A front against itself is 0 away; a front 10 % longer everywhere
    /// is 0.1 away; the order of errors halving as the level doubles is 1.
    #[test]
    fn front_distance_and_observed_order() {
        let reference = [sample(0.0, 0.0), sample(1.0, 1.0), sample(2.0, 2.0)];
        assert_eq!(front_l2(&reference, &reference), 0.0);
        let longer = [sample(0.0, 0.0), sample(1.0, 1.1), sample(2.0, 2.2)];
        assert!((front_l2(&longer, &reference) - 0.1).abs() < 1e-12);
        assert!(front_l2(&[], &reference).is_nan());
        assert!((observed_order((10.0, 0.2), (20.0, 0.1)) - 1.0).abs() < 1e-12);
        assert!((observed_order((10.0, 0.4), (20.0, 0.1)) - 2.0).abs() < 1e-12);
    }

    #[test]
    fn spread_skips_nan() {
        let (mean, lo, hi, n) = spread([1.0, f64::NAN, 3.0].into_iter()).unwrap();
        assert_eq!((mean, lo, hi, n), (2.0, 1.0, 3.0, 2));
        assert!(spread([f64::NAN].into_iter()).is_none());
    }

    fn case(name: &str, h0: f64, l0: f64) -> Case {
        Case {
            name: name.into(),
            scene_path: PathBuf::new(),
            set: Vec::new(),
            method: schemas::Method::DemLbm,
            condition: Condition::Saturated,
            column_length: l0,
            column_height: h0,
            grain_diameter: 2.5e-3,
            estimate_s: 0.0,
            dir: PathBuf::new(),
            origin_x: 0.0,
            series: "DEM".into(),
            studies: Vec::new(),
            expect: None,
            max_wall: None,
        }
    }

    /// Runs of one column (H0 and L0) and series are repeats; the same H0
    /// on another L0 is another case, not a seed.
    #[test]
    fn repeats_share_the_column_not_only_its_height() {
        let summary: RunSummary = serde_json::from_str(include_str!("testdata/summary_dem_lbm.json")).unwrap();
        let cases = [case("a", 0.06, 0.04), case("a_seed2", 0.06, 0.04), case("wide", 0.06, 0.08)];
        let rows: Vec<Row> = cases.iter().map(|c| Row { case: c, summary: &summary }).collect();
        let g = groups(&rows);
        assert_eq!(g.len(), 2, "{:?}", g.keys().collect::<Vec<_>>());
        let sizes: Vec<usize> = g.values().map(Vec::len).collect();
        assert_eq!(sizes, [2, 1]);
    }
}
