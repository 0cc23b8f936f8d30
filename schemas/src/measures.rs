//! Measures of a collapse shared by every method (paper §2, §5): the front
//! position by the mass rule, its normalisation, and the deposit profile.

use serde::{Deserialize, Serialize};

/// One sample of a front: time, normalised time, position, normalised runout.
#[derive(Debug, Clone, Copy, Serialize, Deserialize, PartialEq)]
pub struct FrontSample {
    /// Simulated time since the start of the run (gates open at their `release_time`), s.
    #[serde(deserialize_with = "crate::summary::nan_if_null")]
    pub t: f64,
    /// t / t_ref.
    #[serde(deserialize_with = "crate::summary::nan_if_null")]
    pub t_norm: f64,
    /// X_f, the x coordinate of the front, m.
    #[serde(deserialize_with = "crate::summary::nan_if_null")]
    pub x: f64,
    /// (X_f − x_min − L0) / L0, with x_min the domain's lower x (the back wall).
    #[serde(deserialize_with = "crate::summary::nan_if_null")]
    pub x_norm: f64,
}

/// The position beyond which `fraction` of the total mass lies.
///
/// `scratch` is reused between calls (no allocation once it has grown).
/// Items are (position, mass). Returns NaN for no mass.
pub fn front_position(items: impl Iterator<Item = (f64, f64)>, fraction: f64, scratch: &mut Vec<(f64, f64)>) -> f64 {
    scratch.clear();
    scratch.extend(items);
    let total: f64 = scratch.iter().map(|p| p.1).sum();
    if scratch.is_empty() || total <= 0.0 {
        return f64::NAN;
    }
    scratch.sort_unstable_by(|a, b| b.0.total_cmp(&a.0));
    let target = fraction * total;
    let mut beyond = 0.0;
    for &(x, m) in scratch.iter() {
        beyond += m;
        if beyond > target {
            return x;
        }
    }
    scratch.last().map(|p| p.0).unwrap_or(f64::NAN)
}

/// Height profile along x: for each bin of width `bin` from `x0`, the highest
/// top of any item (position, top height) in it; empty bins have height 0.
/// Returns (bin centre, height) pairs up to the last non-empty bin.
pub fn deposit_profile(items: impl Iterator<Item = (f64, f64)>, x0: f64, bin: f64, max_bins: usize) -> Vec<[f64; 2]> {
    let mut heights = vec![0.0_f64; max_bins];
    let mut last = 0;
    for (x, top) in items {
        let b = ((x - x0) / bin).floor();
        if b < 0.0 || !b.is_finite() {
            continue;
        }
        let b = (b as usize).min(max_bins - 1);
        heights[b] = heights[b].max(top);
        last = last.max(b + 1);
    }
    heights.truncate(last);
    heights.iter().enumerate().map(|(i, &h)| [x0 + (i as f64 + 0.5) * bin, h]).collect()
}

/// Where the pile ends: scanning bins of width `bin` from `x0` (the back
/// wall) forward, the first x at which the deposit's equivalent height
/// h(x) = V_solid(x) / (bin · `width` · `solid_fraction`) falls below
/// `threshold`, interpolated linearly between bin centres (x0 when the
/// first bin is already below it). Items are (x, solid volume). Averaged
/// over the flume's width, one grain ahead of the pile weighs ~0.04 D in h,
/// so isolated grains do not move this front; the mass-fraction front
/// ([`front_position`]) is the paper's definition, this one the edge of the
/// deposit. `scratch` holds the bins (no allocation once grown). NaN
/// without volume.
pub fn pile_edge(
    items: impl Iterator<Item = (f64, f64)>,
    x0: f64,
    bin: f64,
    width: f64,
    solid_fraction: f64,
    threshold: f64,
    scratch: &mut Vec<f64>,
) -> f64 {
    scratch.clear();
    for (x, volume) in items {
        let b = ((x - x0) / bin).floor();
        if !(b >= 0.0 && b.is_finite()) {
            continue;
        }
        let b = b as usize;
        if b >= scratch.len() {
            scratch.resize(b + 1, 0.0);
        }
        scratch[b] += volume;
    }
    if scratch.is_empty() {
        return f64::NAN;
    }
    let height = |b: usize| scratch.get(b).copied().unwrap_or(0.0) / (bin * width * solid_fraction);
    let centre = |b: usize| x0 + (b as f64 + 0.5) * bin;
    if height(0) < threshold {
        return x0;
    }
    let mut b = 0;
    while height(b + 1) >= threshold {
        b += 1;
    }
    let (h0, h1) = (height(b), height(b + 1));
    centre(b) + bin * (h0 - threshold) / (h0 - h1)
}

/// Fractions of grains with 0, 1, … 5 and ≥ 6 contacts (paper Fig. 7).
pub fn coordination_shares(coordination: &[u16]) -> [f64; 7] {
    let mut counts = [0usize; 7];
    for &c in coordination {
        counts[(c as usize).min(6)] += 1;
    }
    let n = coordination.len().max(1) as f64;
    counts.map(|c| c as f64 / n)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pile_edge_is_where_the_averaged_height_drops_below_the_threshold() {
        // A wedge of unit width and solid fraction 1: the height is the
        // volume per unit length, 10 − x in bins of 1 (centres at 0.5, 1.5 …),
        // plus one far straggler the mass rule would follow.
        let mut scratch = Vec::new();
        let wedge = (0..10).map(|b| (b as f64 + 0.5, 10.0 - (b as f64 + 0.5)));
        let straggler = std::iter::once((30.5, 0.5));
        let edge = pile_edge(wedge.chain(straggler), 0.0, 1.0, 1.0, 1.0, 2.0, &mut scratch);
        // h = 2.5 at 7.5 and 1.5 at 8.5: 2 is crossed at 8.0.
        assert!((edge - 8.0).abs() < 1e-12, "{edge}");
        // The same volume over twice the width is half as high: h = 2.25 at
        // 5.5 and 1.75 at 6.5, so 2 is crossed at 6.0.
        let wedge = (0..10).map(|b| (b as f64 + 0.5, 10.0 - (b as f64 + 0.5)));
        let edge = pile_edge(wedge, 0.0, 1.0, 2.0, 1.0, 2.0, &mut scratch);
        assert!((edge - 6.0).abs() < 1e-12, "{edge}");
        assert_eq!(pile_edge(std::iter::once((0.2, 0.1)), 0.0, 1.0, 1.0, 1.0, 2.0, &mut scratch), 0.0);
        assert!(pile_edge(std::iter::empty(), 0.0, 1.0, 1.0, 1.0, 2.0, &mut scratch).is_nan());
    }

    #[test]
    fn coordination_shares_sum_to_one() {
        let s = coordination_shares(&[0, 0, 1, 3, 6, 9, 12, 4]);
        assert_eq!(s, [0.25, 0.125, 0.0, 0.125, 0.125, 0.0, 0.375]);
        assert!((s.iter().sum::<f64>() - 1.0).abs() < 1e-15);
    }

    #[test]
    fn front_is_the_mass_quantile() {
        // 1000 equal masses at x = 0.001 .. 1.000: 0.5 % beyond means 5 items beyond.
        let items = (1..=1000).map(|i| (i as f64 * 1e-3, 1.0));
        let mut s = Vec::new();
        let x = front_position(items, 0.005, &mut s);
        assert!((x - 0.995).abs() < 1e-12, "{x}");
    }

    #[test]
    fn deposit_takes_the_highest_top_per_bin() {
        let items = [(0.01, 0.2), (0.012, 0.3), (0.025, 0.1)].into_iter();
        let p = deposit_profile(items, 0.0, 0.01, 100);
        assert_eq!(p.len(), 3);
        assert!((p[1][1] - 0.3).abs() < 1e-15 && (p[2][1] - 0.1).abs() < 1e-15 && p[0][1] == 0.0);
    }
}
