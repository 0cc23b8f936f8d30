//! Moments and relaxation of one chunk of cells: the per-lane moments of
//! forced cells, Smagorinsky's effective τ (Eq. 4, closed form on the
//! non-equilibrium stress), and BGK or TRT collision with Guo forcing
//! (lbm-free-surface.md §2).

use super::*;

/// Forced cells in a chunk from which their moments are summed for all
/// lanes at once ([`lane_moments`]) instead of one cell at a time.
pub(super) const VECTOR_MOMENTS_FROM: usize = 16;

/// Per lane of a chunk: Σg (= ρ − 1) and Σ g e of the pulled populations
/// (f64 sums).
#[derive(Clone, Copy)]
pub(super) struct LaneMoments {
    pub(super) drho: [f64; LANES],
    pub(super) j: [[f64; LANES]; 3],
}

/// The moments of one forced cell, as [`Kernel::direct_force`] needs them.
pub(super) struct CellMoments {
    pub(super) drho: f64,
    pub(super) j: [f64; 3],
}

impl CellMoments {
    pub(super) fn of_lane(m: &LaneMoments, l: usize) -> CellMoments {
        CellMoments { drho: m.drho[l], j: [m.j[0][l], m.j[1][l], m.j[2][l]] }
    }

    /// Lane `l` of `f` (pulled populations), summed over i in ascending
    /// order as [`lane_moments`] does.
    #[inline(always)]
    pub(super) fn of_cell<T: Real>(f: &[[T; LANES]; Q], l: usize) -> CellMoments {
        let (mut drho, mut j) = (0.0, [0.0; 3]);
        for i in 0..Q {
            let g = f[i][l].to_f64();
            drho += g;
            for a in 0..3 {
                j[a] += E[i][a] as f64 * g;
            }
        }
        CellMoments { drho, j }
    }
}

/// [`CellMoments::of_cell`] for lanes 0..n of a chunk, vectorised over the
/// lanes; lanes from n on are left as they are.
/// Lanes go in blocks of [`MOMENT_BLOCK`] whose four sums stay in registers
/// over the 19 directions (summing all lanes direction by direction loaded
/// and stored every sum 19 times); each lane's sums take the same operations
/// in the same order either way. A block's sums are then added to `m`, so
/// the result is a lane's plain sum only for a zeroed `m` (as the caller
/// passes it; a sum from +0.0 is never −0.0, so adding it to +0.0 is exact).
#[inline(always)]
pub(super) fn lane_moments<T: Real>(f: &[[T; LANES]; Q], n: usize, m: &mut LaneMoments) {
    const B: usize = MOMENT_BLOCK;
    let mut l0 = 0;
    while l0 + B <= n {
        let (mut drho, mut j) = ([0.0; B], [[0.0; B]; 3]);
        for i in 0..Q {
            let e = E[i].map(|x| x as f64);
            let pulled: &[T; B] = f[i][l0..l0 + B].try_into().expect("a block of lanes");
            for b in 0..B {
                let g = pulled[b].to_f64();
                drho[b] += g;
                for a in 0..3 {
                    j[a][b] += e[a] * g;
                }
            }
        }
        for b in 0..B {
            m.drho[l0 + b] += drho[b];
            for a in 0..3 {
                m.j[a][l0 + b] += j[a][b];
            }
        }
        l0 += B;
    }
    for i in 0..Q {
        let e = E[i].map(|x| x as f64);
        for l in l0..n {
            let g = f[i][l].to_f64();
            m.drho[l] += g;
            for a in 0..3 {
                m.j[a][l] += e[a] * g;
            }
        }
    }
}

/// Lanes per register block of [`lane_moments`]: 4 f64 fill one AVX2 register.
pub(super) const MOMENT_BLOCK: usize = 4;

/// The Smagorinsky relaxation time of [`collide`] in f64 for one cell's
/// populations `g` (stored as f − w) under body acceleration `a`:
/// τ = ½(τ0 + √(τ0² + 18√2 C² |Π^neq|/ρ)), `smag` = 18√2 C², with the
/// force-corrected Π^neq = Σ g e e − δρ/3 − ρuu + ½ρ(au + ua) and Guo's
/// u = Σ g e/ρ + a/2. Used by the gain rules that take a cell's τ_eff.
pub(crate) fn smagorinsky_tau(g: &[f64; Q], a: [f64; 3], tau0: f64, smag: f64) -> f64 {
    let (mut drho, mut j, mut p) = (0.0, [0.0; 3], [[0.0; 3]; 3]);
    for i in 0..Q {
        drho += g[i];
        for x in 0..3 {
            j[x] += E[i][x] as f64 * g[i];
            for y in 0..3 {
                p[x][y] += (E[i][x] * E[i][y]) as f64 * g[i];
            }
        }
    }
    let rho = 1.0 + drho;
    let u: [f64; 3] = std::array::from_fn(|k| j[k] / rho + 0.5 * a[k]);
    let mut q = 0.0;
    for x in 0..3 {
        for y in 0..3 {
            let diagonal = if x == y { drho / 3.0 } else { 0.0 };
            let neq = p[x][y] - diagonal - rho * u[x] * u[y] + 0.5 * rho * (a[x] * u[y] + u[x] * a[y]);
            q += neq * neq;
        }
    }
    0.5 * (tau0 + (tau0 * tau0 + smag * q.sqrt() / rho).sqrt())
}

/// BGK (`TRT = false`) or TRT collision with Smagorinsky and Guo forcing on
/// the first `lanes` lanes of `f`, in place; `f` holds f_i − w_i before and after.
///
/// Pre: `f` finite where results are used. Post: mass is conserved exactly
/// up to round-off and the momentum changes by F = ρa per cell.
///
/// * Moments: ρ = 1 + Σg, u = Σ g e/ρ + a/2 (Guo's half-force shift).
/// * Π̃ = Σ e e g − δ(ρ−1)/3 − ρ u u + ½ρ (a u + u a): the non-equilibrium
///   momentum flux with Guo's force correction (Krüger et al. 2017 §6.3;
///   Chapman–Enskog gives Π̃ = −2ρ c_s² τ S), Q = Π̃:Π̃.
/// * τ = ½[τ0 + √(τ0² + 18√2 C² √Q/ρ)]: the local closed form of
///   ν0 + (CΔ)²|S| = c_s²(τ − ½) with |S| = √(2 S:S) (Hou et al. 1996;
///   lbm-free-surface.md §2), i.e. Eq. 4 of the paper with C = 0.16.
/// * TRT: each pair (i, ī) splits into g± = ½(g_i ± g_ī); g+ relaxes with
///   ω+ = 1/τ, g− with ω− = 1/(½ + Λ/(τ − ½)); BGK is ω− = ω+. Guo's source
///   w_i[3(e−u) + 9(e·u)e]·F splits into S+ = w_i ρ[9(e·u)(e·a) − 3u·a] and
///   S− = 3w_i ρ e·a, weighted (1 − ω±/2).
///
/// `FORCED`: the acceleration of lane l is `accel[·][l]` (uniform a plus a
/// direct force over ρ) instead of the uniform `c.accel`; the unforced
/// instance compiles to the same code as before forcing existed.
#[inline(always)]
pub(super) fn collide<T: Real, const TRT: bool, const FORCED: bool>(
    f: &mut [[T; LANES]; Q],
    lanes: usize,
    c: &Coefficients<T>,
    accel: &[[T; LANES]; 4],
) {
    let k = |x: f64| T::from_f64(x);
    let (half, one, third) = (k(0.5), k(1.0), k(1.0 / 3.0));
    let (w0, w1, w2) = (k(W[0]), k(W[1]), k(W[7]));
    let (c3, c45, c15, c9) = (k(3.0), k(4.5), k(1.5), k(9.0));
    for l in 0..lanes {
        let [ax, ay, az] = if FORCED { [accel[0][l], accel[1][l], accel[2][l]] } else { c.accel };
        // Pair sums and differences, one per pair (2p+1, 2p+2).
        let s: [T; 9] = std::array::from_fn(|p| f[2 * p + 1][l] + f[2 * p + 2][l]);
        let d: [T; 9] = std::array::from_fn(|p| f[2 * p + 1][l] - f[2 * p + 2][l]);
        let g0 = f[0][l];
        // Pair p's first direction: 0:+x 1:+y 2:+z 3:(1,1,0) 4:(−1,1,0) 5:(0,1,1) 6:(0,−1,1) 7:(1,0,1) 8:(1,0,−1).
        let drho = g0 + s[0] + s[1] + s[2] + s[3] + s[4] + s[5] + s[6] + s[7] + s[8];
        let rho = one + drho;
        let inv_rho = one / rho;
        let ux = (d[0] + d[3] - d[4] + d[7] + d[8]) * inv_rho + half * ax;
        let uy = (d[1] + d[3] + d[4] + d[5] - d[6]) * inv_rho + half * ay;
        let uz = (d[2] + d[5] + d[6] + d[7] - d[8]) * inv_rho + half * az;

        let hr = half * rho;
        let pxx = s[0] + s[3] + s[4] + s[7] + s[8] - drho * third - rho * ux * ux + hr * (ax * ux + ax * ux);
        let pyy = s[1] + s[3] + s[4] + s[5] + s[6] - drho * third - rho * uy * uy + hr * (ay * uy + ay * uy);
        let pzz = s[2] + s[5] + s[6] + s[7] + s[8] - drho * third - rho * uz * uz + hr * (az * uz + az * uz);
        let pxy = s[3] - s[4] - rho * ux * uy + hr * (ax * uy + ux * ay);
        let pyz = s[5] - s[6] - rho * uy * uz + hr * (ay * uz + uy * az);
        let pxz = s[7] - s[8] - rho * ux * uz + hr * (ax * uz + ux * az);
        let q = pxx * pxx + pyy * pyy + pzz * pzz + k(2.0) * (pxy * pxy + pyz * pyz + pxz * pxz);
        // The same closure as `smagorinsky_tau` (the gain rules' f64 copy, tested there).
        let tau = half * (c.tau0 + (c.tau0_sq + c.smag * q.sqrt() * inv_rho).sqrt());
        let wp = one / tau;
        let wm = if TRT { (tau - half) / (half * (tau - half) + c.magic) } else { wp };
        // Row 3 of a forced chunk's `accel`: 1 where the cell relaxes at τ = 1 instead.
        let (wp, wm) = if FORCED {
            let b = accel[3][l];
            (wp + b * (one - wp), wm + b * (one - wm))
        } else {
            (wp, wm)
        };
        let (kp, km) = (one - half * wp, one - half * wm);

        let usq = ux * ux + uy * uy + uz * uz;
        let ua = ux * ax + uy * ay + uz * az;
        let base = drho - c15 * rho * usq;
        f[0][l] = g0 - wp * (g0 - w0 * base) - kp * w0 * c3 * rho * ua;
        let pair = |w: T, eu: T, ea: T, s: T, d: T| -> (T, T) {
            let eq_p = w * (base + c45 * rho * eu * eu);
            let eq_m = w * c3 * rho * eu;
            let src_p = w * rho * (c9 * eu * ea - c3 * ua);
            let src_m = w * c3 * rho * ea;
            let (gp, gm) = (half * s, half * d);
            let np = gp - wp * (gp - eq_p) + kp * src_p;
            let nm = gm - wm * (gm - eq_m) + km * src_m;
            (np + nm, np - nm)
        };
        let dirs: [(T, T, T); 9] = [
            (w1, ux, ax),
            (w1, uy, ay),
            (w1, uz, az),
            (w2, ux + uy, ax + ay),
            (w2, uy - ux, ay - ax),
            (w2, uy + uz, ay + az),
            (w2, uz - uy, az - ay),
            (w2, ux + uz, ax + az),
            (w2, ux - uz, ax - az),
        ];
        for p in 0..9 {
            let (w, eu, ea) = dirs[p];
            let (a, b) = pair(w, eu, ea, s[p], d[p]);
            f[2 * p + 1][l] = a;
            f[2 * p + 2][l] = b;
        }
    }
}
