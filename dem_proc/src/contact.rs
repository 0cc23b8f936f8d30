//! Closed forms of the linear spring–dashpot contact (paper Eq. 1): the
//! solver derives its damping from them, [`crate::setup::check_scene`]
//! refuses a restitution the law cannot reach, `coupler check` reports them.
//!
//! Normal force F = k δ + c δ̇ with c = 2ζ√(k m*). Two end-of-contact criteria
//! exist (see `shared/reference/analytic-checks.md`):
//! * overlap criterion: contact ends when δ returns to 0 (the textbook
//!   e = exp(−πζ/√(1−ζ²)));
//! * no-tension criterion: contact ends when F returns to 0, because the law
//!   never pulls grains together. This is what the solver does, so the solver
//!   derives ζ from the user's restitution with [`damping_ratio_no_tension`],
//!   and the measured restitution equals the input.

use std::f64::consts::PI;

/// ζ giving restitution `e` under the overlap criterion.
pub fn damping_ratio_overlap(e: f64) -> f64 {
    let l = e.ln();
    -l / (PI * PI + l * l).sqrt()
}

/// Restitution under the overlap criterion for damping ratio ζ < 1.
pub fn restitution_overlap(zeta: f64) -> f64 {
    (-PI * zeta / (1.0 - zeta * zeta).sqrt()).exp()
}

/// ω0·t_c under the overlap criterion.
pub fn contact_time_overlap_scaled(zeta: f64) -> f64 {
    PI / (1.0 - zeta * zeta).sqrt()
}

/// ω0·t_c when contact ends at zero force (ζ < 1).
pub fn contact_time_no_tension_scaled(zeta: f64) -> f64 {
    let s = (1.0 - zeta * zeta).sqrt();
    let phase = PI - (2.0 * zeta * s).atan2(1.0 - 2.0 * zeta * zeta);
    phase / s
}

/// Restitution when contact ends at zero force (ζ < 1).
pub fn restitution_no_tension(zeta: f64) -> f64 {
    let s = (1.0 - zeta * zeta).sqrt();
    let t = contact_time_no_tension_scaled(zeta); // in units of 1/ω0
    let wd_t = s * t;
    let decay = (-zeta * t).exp();
    -decay * (wd_t.cos() - zeta / s * wd_t.sin())
}

/// ζ such that the no-tension contact rebounds with restitution `e` ∈ (0, 1].
/// Bisection: e(ζ) is monotone decreasing on [0, 0.999].
pub fn damping_ratio_no_tension(e: f64) -> f64 {
    if e >= 1.0 {
        return 0.0;
    }
    let (mut lo, mut hi) = (0.0_f64, 0.999_f64);
    for _ in 0..200 {
        let mid = 0.5 * (lo + hi);
        if restitution_no_tension(mid) > e {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    0.5 * (lo + hi)
}

/// Lowest restitution the no-tension law can reach (at ζ → 1).
pub fn min_restitution_no_tension() -> f64 {
    restitution_no_tension(0.999)
}

/// Effective mass m1 m2 / (m1 + m2); a wall is `f64::INFINITY`.
pub fn effective_mass(m1: f64, m2: f64) -> f64 {
    if m2.is_infinite() {
        m1
    } else {
        m1 * m2 / (m1 + m2)
    }
}

/// Contact duration (no-tension criterion) of a pair with effective mass m*.
pub fn contact_duration(k: f64, m_eff: f64, zeta: f64) -> f64 {
    contact_time_no_tension_scaled(zeta) / (k / m_eff).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Table of `analytic-checks.md` (ζ and ω0·t_c, overlap criterion), 5 digits printed.
    #[test]
    #[allow(clippy::approx_constant)] // 3.1416 is the table's value, not π
    fn overlap_criterion_matches_reference_table() {
        let table = [
            (0.1, 0.59116, 3.8951),
            (0.3, 0.35786, 3.3644),
            (0.5, 0.21545, 3.2172),
            (0.88, 0.04066, 3.1442),
            (0.99, 0.00320, 3.1416),
        ];
        for (e, zeta, wt) in table {
            let z = damping_ratio_overlap(e);
            assert!((z - zeta).abs() < 6e-6, "e={e}: zeta {z} vs {zeta}");
            assert!((contact_time_overlap_scaled(z) - wt).abs() < 6e-5);
            assert!((restitution_overlap(z) - e).abs() < 1e-12);
        }
    }

    /// The reference gives, for ζ = 0.1, e = 0.7441 and ω0·t_c = 2.956 under
    /// the force criterion.
    #[test]
    fn no_tension_criterion_matches_reference() {
        assert!((restitution_no_tension(0.1) - 0.7441).abs() < 5e-5);
        assert!((contact_time_no_tension_scaled(0.1) - 2.956).abs() < 5e-4);
        assert!((restitution_overlap(0.1) - 0.7292).abs() < 5e-5);
        for e in [0.3, 0.88, 0.99] {
            let z = damping_ratio_no_tension(e);
            assert!((restitution_no_tension(z) - e).abs() < 1e-12);
            // Cutting the tensile tail loses less energy, so it needs more damping.
            assert!(z > damping_ratio_overlap(e));
        }
    }
}
