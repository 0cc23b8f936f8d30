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
    let mpm = case.family() == "MPM";
    let main = if mpm { topics::MPM_SOLID } else { topics::DEM_PARTICLES };
    let Some(last) = rec.last_time(main) else { return Ok(false) };
    let (l0, h0) = (case.column_length, case.column_height);
    let reach = [summary.runout, summary.liquid_front.last().map_or(0.0, |f| f.x_norm), 1.0]
        .into_iter()
        .filter(|x| x.is_finite())
        .fold(0.0, f64::max);
    let x_max = case.origin_x + l0 * (1.0 + reach) * 1.08;
    let z_max = h0 * 1.15;
    let u_ref = (9.81 * h0).sqrt();
    let tolerance = 0.3 * summary.t_ref;
    let mut panels = Vec::new();
    for t in snapshot_times(summary, last) {
        let mut layers = Vec::new();
        if mpm {
            if let Some(f) = rec.frame_near(topics::MPM_LIQUID, t, tolerance)? {
                let spacing = 0.35 * (l0 * h0 / f.points.len().max(1) as f64).sqrt();
                let blue = RGBColor(120, 175, 235);
                layers.push(Layer {
                    points: f.points.iter().map(|p| (p[0] as f64, p[2] as f64, spacing, blue)).collect(),
                });
            }
            if let Some(f) = rec.frame_near(main, t, tolerance)? {
                let spacing = 0.45 * (l0 * h0 / f.points.len().max(1) as f64).sqrt();
                let fluidised = f.array("fluidised").unwrap_or_default();
                let points = f
                    .points
                    .iter()
                    .enumerate()
                    .map(|(i, p)| {
                        let c =
                            if fluidised.get(i).is_some_and(|v| *v > 0.5) { PALETTE[1] } else { RGBColor(120, 90, 50) };
                        (p[0] as f64, p[2] as f64, spacing, c)
                    })
                    .collect();
                layers.push(Layer { points });
            }
        } else {
            if let Some(f) = rec.frame_near(topics::LBM_SURFACE, t, tolerance)? {
                let blue = RGBColor(90, 160, 230);
                layers
                    .push(Layer { points: f.points.iter().map(|p| (p[0] as f64, p[2] as f64, 4e-4, blue)).collect() });
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
        panels.push((t / summary.t_ref, layers));
    }
    draw_snapshots(case, &panels, (x_max, z_max), path).map_err(|e| format!("cannot draw {}: {e}", path.display()))?;
    Ok(true)
}

fn draw_snapshots(
    case: &Case,
    panels: &[(f64, Vec<Layer>)],
    (x_max, z_max): (f64, f64),
    path: &Path,
) -> Result<(), Box<dyn std::error::Error>> {
    const WIDTH: u32 = 1100;
    const HEADER: u32 = 34;
    let plot_width = WIDTH as f64 - 70.0;
    let panel_height = ((plot_width * z_max / x_max) as u32 + 44).clamp(110, 420);
    let root = BitMapBackend::new(path, (WIDTH, HEADER + panel_height * panels.len() as u32)).into_drawing_area();
    root.fill(&WHITE)?;
    let (header, body) = root.split_vertically(HEADER);
    let legend = if case.family() == "MPM" {
        "soil points brown, fluidised (n > n_max) orange; pore water blue"
    } else {
        "grains coloured by speed / √(g H0), viridis 0 → 1; water surface blue"
    };
    header.draw(&Text::new(
        format!("{}: {} (a = {:.2}); {legend}", case.name, case.method.name(), case.aspect()),
        (10, 8),
        (FONT, 17).into_font(),
    ))?;
    for (area, (t_norm, layers)) in body.split_evenly((panels.len(), 1)).iter().zip(panels) {
        let mut chart = ChartBuilder::on(area)
            .margin_right(12)
            .x_label_area_size(22)
            .y_label_area_size(58)
            .build_cartesian_2d(0.0..x_max, 0.0..z_max)?;
        chart
            .configure_mesh()
            .disable_mesh()
            .x_labels(8)
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
        area.draw(&Text::new(format!("t / t_ref = {t_norm:.1}"), (70, 4), (FONT, 14).into_font()))?;
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
