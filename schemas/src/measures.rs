//! Measures of a collapse shared by every method (paper §2, §5): the front
//! position by the mass rule, its normalisation, and the deposit profile.

use serde::{Deserialize, Serialize};

/// One sample of a front: time, normalised time, position, normalised runout.
#[derive(Debug, Clone, Copy, Serialize, Deserialize, PartialEq)]
pub struct FrontSample {
    /// Simulated time since the start of the run (gates open at their `release_time`), s.
    pub t: f64,
    /// t / t_ref.
    pub t_norm: f64,
    /// X_f, the x coordinate of the front, m.
    pub x: f64,
    /// (X_f − x_min − L0) / L0, with x_min the domain's lower x (the back wall).
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
