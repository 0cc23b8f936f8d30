//! The D3Q19 velocity set.
//!
//! Direction 0 is rest; every other direction i has its opposite in the
//! adjacent slot (1↔2, 3↔4, …), the order of HYBIRD's `lattice.h`
//! (lbm-free-surface.md §1). Pairing opposites lets the TRT kernel split each
//! pair into its symmetric and antisymmetric parts with no lookup.

/// Number of discrete velocities.
pub const Q: usize = 19;

/// Lattice speed of sound squared, c_s² = 1/3.
pub const CS2: f64 = 1.0 / 3.0;

/// Discrete velocities e_i.
pub const E: [[i32; 3]; Q] = [
    [0, 0, 0],
    [1, 0, 0],
    [-1, 0, 0],
    [0, 1, 0],
    [0, -1, 0],
    [0, 0, 1],
    [0, 0, -1],
    [1, 1, 0],
    [-1, -1, 0],
    [-1, 1, 0],
    [1, -1, 0],
    [0, 1, 1],
    [0, -1, -1],
    [0, -1, 1],
    [0, 1, -1],
    [1, 0, 1],
    [-1, 0, -1],
    [1, 0, -1],
    [-1, 0, 1],
];

const W0: f64 = 1.0 / 3.0;
const W1: f64 = 1.0 / 18.0;
const W2: f64 = 1.0 / 36.0;

/// Weights w_i.
pub const W: [f64; Q] = [W0, W1, W1, W1, W1, W1, W1, W2, W2, W2, W2, W2, W2, W2, W2, W2, W2, W2, W2];

/// Index of −e_i.
pub const OPP: [usize; Q] = [0, 2, 1, 4, 3, 6, 5, 8, 7, 10, 9, 12, 11, 14, 13, 16, 15, 18, 17];

/// Second-order equilibrium f_i^eq = w_i ρ [1 + 3 e_i·u + 4.5 (e_i·u)² − 1.5 u·u].
#[inline]
pub fn equilibrium(rho: f64, u: [f64; 3]) -> [f64; Q] {
    let usq = u[0] * u[0] + u[1] * u[1] + u[2] * u[2];
    std::array::from_fn(|i| {
        let eu = E[i][0] as f64 * u[0] + E[i][1] as f64 * u[1] + E[i][2] as f64 * u[2];
        W[i] * rho * (1.0 + 3.0 * eu + 4.5 * eu * eu - 1.5 * usq)
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn e(i: usize, a: usize) -> f64 {
        E[i][a] as f64
    }

    #[test]
    fn opposites_are_opposite_and_adjacent() {
        for i in 0..Q {
            let j = OPP[i];
            assert_eq!(OPP[j], i);
            assert_eq!(W[i], W[j]);
            for a in 0..3 {
                assert_eq!(E[i][a], -E[j][a]);
            }
            if i > 0 {
                assert_eq!(j, if i % 2 == 1 { i + 1 } else { i - 1 });
            }
        }
    }

    #[test]
    fn velocities_are_the_19_distinct_short_links() {
        for i in 0..Q {
            let len2: i32 = E[i].iter().map(|c| c * c).sum();
            assert!(len2 <= 2);
            assert_eq!(W[i], [W0, W1, W2][len2 as usize]);
            for j in 0..i {
                assert_ne!(E[i], E[j]);
            }
        }
    }

    #[test]
    fn weight_moments_are_isotropic() {
        let sum: f64 = W.iter().sum();
        assert!((sum - 1.0).abs() < 1e-15);
        for a in 0..3 {
            let m1: f64 = (0..Q).map(|i| W[i] * e(i, a)).sum();
            assert_eq!(m1, 0.0);
            for b in 0..3 {
                let m2: f64 = (0..Q).map(|i| W[i] * e(i, a) * e(i, b)).sum();
                let expect = if a == b { CS2 } else { 0.0 };
                assert!((m2 - expect).abs() < 1e-15, "Σ w e_{a} e_{b} = {m2}");
            }
        }
    }

    #[test]
    fn equilibrium_reproduces_density_momentum_and_momentum_flux() {
        let rho = 1.037;
        let u = [0.05, -0.02, 0.031];
        let f = equilibrium(rho, u);
        let m0: f64 = f.iter().sum();
        assert!((m0 - rho).abs() < 1e-14);
        for a in 0..3 {
            let m1: f64 = (0..Q).map(|i| f[i] * e(i, a)).sum();
            assert!((m1 - rho * u[a]).abs() < 1e-15);
            for b in 0..3 {
                let m2: f64 = (0..Q).map(|i| f[i] * e(i, a) * e(i, b)).sum();
                let expect = rho * (if a == b { CS2 } else { 0.0 } + u[a] * u[b]);
                assert!((m2 - expect).abs() < 1e-15, "Π_{a}{b} = {m2}, expected {expect}");
            }
        }
    }
}
