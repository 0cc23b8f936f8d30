//! Figures drawn from a run's recording (`run.mcap`) rather than its
//! summary: snapshots of the column (the paper's Figs. 2, 4, 5, 9), the
//! DEM's coordination numbers (Figs. 6–7) and the MPM's fluidised share
//! (Fig. 8).
//!
//! Snapshots are raster images (PNG only): thousands of grains drawn as
//! vectors would make each SVG megabytes for no gain.

use std::collections::BTreeMap;
use std::path::Path;

use foxglove::schemas::PointCloud;
use foxglove::Decode;
use plotters::prelude::*;
use schemas::summary::RunSummary;
use schemas::topics;

use super::figures::{Chart, Series, Stroke, FONT, PALETTE};
use super::Case;
use crate::export::{cloud_frame, Frame};

/// Normalised times of the snapshots and coordination curves; the run's
/// last frame is added.
pub const SNAPSHOT_TIMES: [f64; 4] = [0.0, 1.0, 2.0, 4.0];

/// The point clouds of a recording, by topic: (simulated time, encoded cloud).
pub struct Recording {
    clouds: BTreeMap<&'static str, Vec<(f64, Vec<u8>)>>,
}

const CLOUDS: [&str; 4] = [topics::DEM_PARTICLES, topics::LBM_SURFACE, topics::MPM_SOLID, topics::MPM_LIQUID];

impl Recording {
    /// Reads the clouds the figures use; a recording cut short gives what
    /// was read.
    pub fn read(path: &Path) -> Result<Self, String> {
        let bytes = std::fs::read(path).map_err(|e| format!("cannot read {}: {e}", path.display()))?;
        let stream = mcap::MessageStream::new_with_options(&bytes, mcap::read::Options::IgnoreEndMagic.into())
            .map_err(|e| format!("{} is not an MCAP file: {e}", path.display()))?;
        let mut clouds: BTreeMap<&'static str, Vec<(f64, Vec<u8>)>> = BTreeMap::new();
        for msg in stream {
            let Ok(msg) = msg else { break };
            if let Some(topic) = CLOUDS.iter().find(|t| **t == msg.channel.topic) {
                clouds.entry(topic).or_default().push((msg.log_time as f64 * 1e-9, msg.data.into_owned()));
            }
        }
        Ok(Recording { clouds })
    }

    fn decode(topic: &str, time: f64, data: &[u8]) -> Result<Frame, String> {
        let cloud = PointCloud::decode(data).map_err(|e| format!("a {topic} message does not decode: {e}"))?;
        cloud_frame(&cloud, time)
    }

    /// The frame of `topic` nearest to `t` (s), if any lies within `tolerance`.
    pub fn frame_near(&self, topic: &str, t: f64, tolerance: f64) -> Result<Option<Frame>, String> {
        let Some(frames) = self.clouds.get(topic) else { return Ok(None) };
        let best = frames.iter().min_by(|a, b| (a.0 - t).abs().total_cmp(&(b.0 - t).abs()));
        match best {
            Some((time, data)) if (time - t).abs() <= tolerance => Self::decode(topic, *time, data).map(Some),
            _ => Ok(None),
        }
    }

    /// Every frame of `topic`, decoded one at a time.
    pub fn each_frame(&self, topic: &str, mut f: impl FnMut(&Frame)) -> Result<(), String> {
        for (time, data) in self.clouds.get(topic).map(Vec::as_slice).unwrap_or_default() {
            f(&Self::decode(topic, *time, data)?);
        }
        Ok(())
    }

    /// The simulated time of the last frame of `topic`.
    pub fn last_time(&self, topic: &str) -> Option<f64> {
        self.clouds.get(topic).and_then(|f| f.last()).map(|f| f.0)
    }
}

/// The times (s) of the snapshots of a run: [`SNAPSHOT_TIMES`] within
/// the run and its last frame.
fn snapshot_times(summary: &RunSummary, last: f64) -> Vec<f64> {
    let mut times: Vec<f64> =
        SNAPSHOT_TIMES.iter().map(|tn| tn * summary.t_ref).filter(|&t| t < last - 0.5 * summary.t_ref).collect();
    times.push(last);
    times
}

/// What a snapshot panel draws: points in x-z with a colour and a
/// radius in metres, back to front.
struct Layer {
    points: Vec<(f64, f64, f64, RGBColor)>,
}

/// Writes a PNG of the column at t/t_ref = 0, 1, 2, 4 and at the end:
/// grains coloured by speed over √(g H0) with the water's surface, or
/// MPM points coloured by phase status with the pore water. Returns false
/// when the recording holds no points to draw.
pub fn snapshots(case: &Case, summary: &RunSummary, rec: &Recording, path: &Path) -> Result<bool, String> {
    let Some(last) = rec.last_time(main_topic(case)) else { return Ok(false) };
    let mut rows = Vec::new();
    for t in snapshot_times(summary, last) {
        let layers = layers_at(case, summary, rec, t)?;
        rows.push(vec![(format!("t / t_ref = {:.1}", t / summary.t_ref), layers)]);
    }
    let heading = format!("{}: {} (a = {:.2}); {}", case.name, case.method.name(), case.aspect(), legend(case));
    draw_grid(&heading, &rows, extent(case, summary), path)
        .map_err(|e| format!("cannot draw {}: {e}", path.display()))?;
    Ok(true)
}

/// One case of a side-by-side figure: its layers at each of the figure's
/// times (t/t_ref), a panel each, labelled; and its extent (m).
pub struct ComparisonRow {
    panels: Vec<(String, Vec<Layer>)>,
    extent: (f64, f64),
}

/// The panels of `case` at the normalised `times` (a time past the run's
/// end draws its last frame, labelled so). None when the recording holds
/// no points to draw.
pub fn comparison_row(
    case: &Case,
    summary: &RunSummary,
    rec: &Recording,
    times: &[f64],
) -> Result<Option<ComparisonRow>, String> {
    let Some(last) = rec.last_time(main_topic(case)) else { return Ok(None) };
    let mut panels = Vec::new();
    for tn in times {
        let t = (tn * summary.t_ref).min(last);
        let label = if t < tn * summary.t_ref {
            format!("{}, end (t / t_ref = {:.1})", case.name, t / summary.t_ref)
        } else {
            format!("{}, t / t_ref = {tn:.1}", case.name)
        };
        panels.push((label, layers_at(case, summary, rec, t)?));
    }
    Ok(Some(ComparisonRow { panels, extent: extent(case, summary) }))
}

/// Writes a PNG of the rows side by side on common axes: a row per case,
/// a column per time (the paper's Fig. 13 layout).
pub fn comparison(heading: &str, rows: Vec<ComparisonRow>, path: &Path) -> Result<(), String> {
    let extent = rows.iter().fold((0.0, 0.0), |(x, z): (f64, f64), r| (x.max(r.extent.0), z.max(r.extent.1)));
    let grid: Vec<Vec<(String, Vec<Layer>)>> = rows.into_iter().map(|r| r.panels).collect();
    draw_grid(heading, &grid, extent, path).map_err(|e| format!("cannot draw {}: {e}", path.display()))
}

fn main_topic(case: &Case) -> &'static str {
    if case.family() == "MPM" {
        topics::MPM_SOLID
    } else {
        topics::DEM_PARTICLES
    }
}

fn legend(case: &Case) -> &'static str {
    if case.family() == "MPM" {
        "soil points brown, fluidised (n > n_max) orange; pore water blue"
    } else {
        "grains coloured by speed / √(g H0), viridis 0 → 1; water surface blue (middle 80 % of the width)"
    }
}

/// How far a case's panels reach (m): x to its farthest front, solid or
/// liquid, z a little above H0.
fn extent(case: &Case, summary: &RunSummary) -> (f64, f64) {
    let (l0, h0) = (case.column_length, case.column_height);
    let reach = [summary.runout, summary.liquid_front.last().map_or(0.0, |f| f.x_norm), 1.0]
        .into_iter()
        .filter(|x| x.is_finite())
        .fold(0.0, f64::max);
    (case.origin_x + l0 * (1.0 + reach) * 1.08, h0 * 1.15)
}

/// What one panel of `case` draws at time `t` (s): the frames nearest to
/// it within 0.3 t_ref.
fn layers_at(case: &Case, summary: &RunSummary, rec: &Recording, t: f64) -> Result<Vec<Layer>, String> {
    let (l0, h0) = (case.column_length, case.column_height);
    let u_ref = (9.81 * h0).sqrt();
    let tolerance = 0.3 * summary.t_ref;
    let main = main_topic(case);
    let mut layers = Vec::new();
    if case.family() == "MPM" {
        if let Some(f) = rec.frame_near(topics::MPM_LIQUID, t, tolerance)? {
            let spacing = 0.35 * (l0 * h0 / f.points.len().max(1) as f64).sqrt();
            let blue = RGBColor(120, 175, 235);
            layers.push(Layer { points: f.points.iter().map(|p| (p[0] as f64, p[2] as f64, spacing, blue)).collect() });
        }
        if let Some(f) = rec.frame_near(main, t, tolerance)? {
            let spacing = 0.45 * (l0 * h0 / f.points.len().max(1) as f64).sqrt();
            let fluidised = f.array("fluidised").unwrap_or_default();
            let points = f
                .points
                .iter()
                .enumerate()
                .map(|(i, p)| {
                    let c = if fluidised.get(i).is_some_and(|v| *v > 0.5) { PALETTE[1] } else { RGBColor(120, 90, 50) };
                    (p[0] as f64, p[2] as f64, spacing, c)
                })
                .collect();
            layers.push(Layer { points });
        }
    } else {
        if let Some(f) = rec.frame_near(topics::LBM_SURFACE, t, tolerance)? {
            // The side walls hold films of liquid a cell or two thick that
            // drain slowly (docs/lbm.md "Wall films"); seen through the
            // width they would seem to hang over the pile.
            let (lo, hi) = f.points.iter().fold((f32::MAX, f32::MIN), |(lo, hi), p| (lo.min(p[1]), hi.max(p[1])));
            let margin = 0.1 * (hi - lo);
            let blue = RGBColor(90, 160, 230);
            let middle = f.points.iter().filter(|p| p[1] >= lo + margin && p[1] <= hi - margin);
            layers.push(Layer { points: middle.map(|p| (p[0] as f64, p[2] as f64, 4e-4, blue)).collect() });
        }
        if let Some(f) = rec.frame_near(main, t, tolerance)? {
            let (radius, speed) = (f.array("radius").unwrap_or_default(), f.array("speed").unwrap_or_default());
            // Far grains first, so the near wall's are on top.
            let mut order: Vec<usize> = (0..f.points.len()).collect();
            order.sort_by(|&a, &b| f.points[b][1].total_cmp(&f.points[a][1]));
            let points = order
                .into_iter()
                .map(|i| {
                    let s = (speed.get(i).copied().unwrap_or(0.0) as f64 / u_ref).clamp(0.0, 1.0);
                    let r = radius.get(i).copied().unwrap_or(1e-3) as f64;
                    (f.points[i][0] as f64, f.points[i][2] as f64, r, ViridisRGB::get_color(s as f32))
                })
                .collect();
            layers.push(Layer { points });
        }
    }
    Ok(layers)
}

/// Draws `rows` of labelled panels (each a list of layers) on common axes
/// (0..x_max, 0..z_max in m) under a one-line heading.
fn draw_grid(
    heading: &str,
    rows: &[Vec<(String, Vec<Layer>)>],
    (x_max, z_max): (f64, f64),
    path: &Path,
) -> Result<(), Box<dyn std::error::Error>> {
    const PANEL_WIDTH: u32 = 1100;
    const HEADER: u32 = 34;
    let columns = rows.iter().map(Vec::len).max().unwrap_or(1).max(1);
    let panel_width = if columns == 1 { PANEL_WIDTH } else { (1800 / columns as u32).max(360) };
    let plot_width = panel_width as f64 - 70.0;
    let panel_height = ((plot_width * z_max / x_max) as u32 + 44).clamp(110, 420);
    let size = (panel_width * columns as u32, HEADER + panel_height * rows.len() as u32);
    let root = BitMapBackend::new(path, size).into_drawing_area();
    root.fill(&WHITE)?;
    let (header, body) = root.split_vertically(HEADER);
    header.draw(&Text::new(heading.to_string(), (10, 8), (FONT, 17).into_font()))?;
    let areas = body.split_evenly((rows.len(), columns));
    for (row, row_areas) in rows.iter().zip(areas.chunks(columns)) {
        for ((label, layers), area) in row.iter().zip(row_areas) {
            let mut chart = ChartBuilder::on(area)
                .margin_right(12)
                .x_label_area_size(22)
                .y_label_area_size(58)
                .build_cartesian_2d(0.0..x_max, 0.0..z_max)?;
            chart
                .configure_mesh()
                .disable_mesh()
                .x_labels(if columns == 1 { 8 } else { 4 })
                .y_labels(3)
                .label_style((FONT, 12))
                .x_label_formatter(&|x| format!("{x:.2}"))
                .y_label_formatter(&|z| format!("{z:.2}"))
                .draw()?;
            let (xs, _) = chart.plotting_area().get_pixel_range();
            let px_per_m = (xs.end - xs.start) as f64 / x_max;
            for layer in layers {
                let inside = layer.points.iter().filter(|p| p.0 >= 0.0 && p.0 <= x_max && p.1 >= 0.0 && p.1 <= z_max);
                chart.draw_series(
                    inside.map(|&(x, z, r, c)| Circle::new((x, z), ((r * px_per_m).round() as i32).max(1), c.filled())),
                )?;
            }
            area.draw(&Text::new(label.clone(), (70, 4), (FONT, 14).into_font()))?;
        }
    }
    root.present()?;
    Ok(())
}

/// The distribution of the grains' coordination numbers at the snapshot
/// times: fraction of grains against the number of contacts.
pub fn coordination(case: &Case, summary: &RunSummary, rec: &Recording) -> Result<Option<Chart>, String> {
    let Some(last) = rec.last_time(topics::DEM_PARTICLES) else { return Ok(None) };
    let mut series = Vec::new();
    for (k, t) in snapshot_times(summary, last).into_iter().enumerate() {
        let Some(f) = rec.frame_near(topics::DEM_PARTICLES, t, 0.3 * summary.t_ref)? else { continue };
        let Some(z) = f.array("coordination") else { continue };
        let points = coordination_histogram(z);
        let label = format!("t / t_ref = {:.1} (mean {:.2})", t / summary.t_ref, mean(z));
        series.push(Series::new(label, points, PALETTE[k % PALETTE.len()], Stroke::Solid));
    }
    Ok((!series.is_empty()).then(|| Chart {
        title: format!("Coordination numbers, {} (a = {:.2})", case.name, case.aspect()),
        x_label: "contacts per grain".into(),
        y_label: "fraction of grains".into(),
        series,
        log_axes: false,
    }))
}

fn mean(v: &[f32]) -> f64 {
    v.iter().map(|&x| x as f64).sum::<f64>() / v.len().max(1) as f64
}

/// Fraction of grains with 0, 1, … contacts, to the largest seen.
pub fn coordination_histogram(z: &[f32]) -> Vec<(f64, f64)> {
    // A grain touches at most 12 equal spheres; more than 64 is a broken record.
    let bin = |v: f32| (v.round().clamp(0.0, 64.0)) as usize;
    let top = z.iter().map(|&v| bin(v)).max().unwrap_or(0);
    let mut counts = vec![0usize; top + 1];
    for &v in z {
        counts[bin(v)] += 1;
    }
    counts.iter().enumerate().map(|(n, &c)| (n as f64, c as f64 / z.len().max(1) as f64)).collect()
}

/// The share of the soil's points that are fluidised (porosity above
/// n_max) on every recorded frame, against t/t_ref. The MPM's solid
/// points carry equal masses, so this is also the mass share the
/// summary's `fluidised_fraction_max` takes its maximum of.
pub fn fluidised_share(summary: &RunSummary, rec: &Recording) -> Result<Vec<(f64, f64)>, String> {
    let mut share = Vec::new();
    rec.each_frame(topics::MPM_SOLID, |f| {
        if let Some(fl) = f.array("fluidised") {
            let n = fl.iter().filter(|&&v| v > 0.5).count();
            share.push((f.time / summary.t_ref, n as f64 / fl.len().max(1) as f64));
        }
    })?;
    Ok(share)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn coordination_histogram_counts_grains_by_contacts() {
        let h = coordination_histogram(&[0.0, 2.0, 2.0, 4.0]);
        assert_eq!(h, vec![(0.0, 0.25), (1.0, 0.0), (2.0, 0.5), (3.0, 0.0), (4.0, 0.25)]);
        let total: f64 = h.iter().map(|p| p.1).sum();
        assert!((total - 1.0).abs() < 1e-12);
    }
}
