//! The background grid: square elements of side h over the x–z section of
//! the domain, one ring of ghost nodes outside it, and the per-point
//! stencils of the shape functions (docs/mpm.md, "Shape functions").

use schemas::scene::ShapeFunctions;

/// Ghost node rings on each side: every GIMP stencil (base − 1 .. base + 1
/// around the nearest node) stays inside the stored grid.
pub const GHOST: usize = 1;

/// Geometry of the grid. Node (i, k), i along x and k along z, counted from
/// the box corner, is stored at `(k + GHOST) * row + (i + GHOST)`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Grid {
    /// Box corner (x, z), m.
    pub origin: [f64; 2],
    /// Element side h, m.
    pub h: f64,
    /// Elements along x and z.
    pub elements: [usize; 2],
    pub shape: ShapeFunctions,
}

impl Grid {
    /// Stored nodes along x (a row) and z.
    pub fn node_dims(&self) -> [usize; 2] {
        [self.elements[0] + 1 + 2 * GHOST, self.elements[1] + 1 + 2 * GHOST]
    }

    pub fn node_count(&self) -> usize {
        let [a, b] = self.node_dims();
        a * b
    }

    pub fn element_count(&self) -> usize {
        self.elements[0] * self.elements[1]
    }

    /// Position of stored node (column, row) (ghost offset included), m.
    pub fn node_position(&self, column: usize, row: usize) -> [f64; 2] {
        [
            self.origin[0] + (column as f64 - GHOST as f64) * self.h,
            self.origin[1] + (row as f64 - GHOST as f64) * self.h,
        ]
    }

    /// Upper corner of the box, m.
    pub fn far_corner(&self) -> [f64; 2] {
        [self.origin[0] + self.elements[0] as f64 * self.h, self.origin[1] + self.elements[1] as f64 * self.h]
    }

    /// The element holding `x` (clamped into the box): index e = k·nx + i.
    pub fn element_of(&self, x: [f64; 2]) -> usize {
        // `as usize` truncates toward zero and saturates at 0: the floor of a
        // coordinate inside the box, without a libm call.
        let i = (((x[0] - self.origin[0]) / self.h) as usize).min(self.elements[0] - 1);
        let k = (((x[1] - self.origin[1]) / self.h) as usize).min(self.elements[1] - 1);
        k * self.elements[0] + i
    }

    /// Stored index of the lower-left corner node of element e.
    pub fn element_corner(&self, e: usize) -> usize {
        let (i, k) = (e % self.elements[0], e / self.elements[0]);
        (k + GHOST) * self.node_dims()[0] + i + GHOST
    }

    /// How the square domain of a point at `x` with half-widths `half`
    /// (m, each at most h/2) lies over the elements, per axis: the two
    /// element columns (rows) it can touch and the share of its width in
    /// each. Continuous in `x`, unlike [`Self::element_of`]; a share that
    /// would fall outside the box stays in the element at its edge, so the
    /// shares always sum to 1.
    pub fn domain_overlap(&self, x: [f64; 2], half: [f64; 2]) -> [([usize; 2], [f64; 2]); 2] {
        let axis = |x: f64, x0: f64, l: f64, n: usize| {
            // The element of the domain's lower end and the edge above it;
            // the upper end is not located on its own: at l = h/2 both ends
            // can round onto neighbouring edges and skip an element.
            let lo = ((((x - l) - x0) / self.h).max(0.0) as usize).min(n - 1);
            let edge = x0 + (lo + 1) as f64 * self.h;
            if lo + 1 >= n || x + l <= edge {
                return ([lo, lo], [1.0, 0.0]);
            }
            let share_lo = ((edge - (x - l)) / (2.0 * l)).clamp(0.0, 1.0);
            ([lo, lo + 1], [share_lo, 1.0 - share_lo])
        };
        [axis(x[0], self.origin[0], half[0], self.elements[0]), axis(x[1], self.origin[1], half[1], self.elements[1])]
    }

    /// The GIMP constants along x and z of a point set with half-widths
    /// `half`, m: computed once per set and step, not per point.
    pub fn shape_constants(&self, half: [f64; 2]) -> [GimpConstants; 2] {
        [GimpConstants::new(self.h, half[0]), GimpConstants::new(self.h, half[1])]
    }

    /// Shape-function stencil of a point at `x` of a set with constants `k`
    /// ([`Self::shape_constants`]).
    pub fn stencil(&self, x: [f64; 2], k: &[GimpConstants; 2]) -> Stencil {
        let (bx, wx, gx) = self.axis(x[0], self.origin[0], self.elements[0], &k[0]);
        let (bz, wz, gz) = self.axis(x[1], self.origin[1], self.elements[1], &k[1]);
        Stencil { base: (bz * self.node_dims()[0] + bx) as u32, wx, gx, wz, gz }
    }

    /// One axis: stored index of the first of three nodes, their weights and derivatives.
    fn axis(&self, x: f64, x0: f64, elements: usize, k: &GimpConstants) -> (usize, [f64; 3], [f64; 3]) {
        let h = self.h;
        let inv_h = k.inv_h;
        let xi = (x - x0) * inv_h;
        let mut w = [0.0; 3];
        let mut g = [0.0; 3];
        match self.shape {
            ShapeFunctions::Gimp => {
                // ξ ≥ 0 inside the box: truncating ξ + ½ rounds it.
                let nearest = ((xi + 0.5) as usize).min(elements);
                // Stored index of node nearest − 1 (ghost offset GHOST = 1).
                let base = nearest + GHOST - 1;
                for j in 0..3 {
                    let node_x = x0 + (nearest as f64 + j as f64 - 1.0) * h;
                    let (s, ds) = k.eval(x - node_x);
                    w[j] = s;
                    g[j] = ds;
                }
                (base, w, g)
            }
            ShapeFunctions::Linear => {
                let left = (xi as usize).min(elements - 1);
                let t = xi - left as f64;
                w[0] = 1.0 - t;
                w[1] = t;
                g[0] = -inv_h;
                g[1] = inv_h;
                (left + GHOST, w, g)
            }
        }
    }
}

/// The uniform GIMP function of element side h and half-width l with its
/// reciprocals precomputed.
#[derive(Debug, Clone, Copy)]
pub struct GimpConstants {
    h: f64,
    l: f64,
    inv_h: f64,
    inv_2hl: f64,
    inv_hl: f64,
    inv_4hl: f64,
}

impl GimpConstants {
    fn new(h: f64, l: f64) -> Self {
        Self { h, l, inv_h: 1.0 / h, inv_2hl: 0.5 / (h * l), inv_hl: 1.0 / (h * l), inv_4hl: 0.25 / (h * l) }
    }

    #[inline(always)]
    fn eval(&self, d: f64) -> (f64, f64) {
        let (h, l) = (self.h, self.l);
        let a = d.abs();
        let sign = if d < 0.0 { -1.0 } else { 1.0 };
        if a < l {
            (1.0 - (d * d + l * l) * self.inv_2hl, -d * self.inv_hl)
        } else if a < h - l {
            (1.0 - a * self.inv_h, -sign * self.inv_h)
        } else if a < h + l {
            let r = h + l - a;
            (r * r * self.inv_4hl, -sign * r * self.inv_2hl)
        } else {
            (0.0, 0.0)
        }
    }
}

/// Uniform GIMP weight and derivative at distance d from a node (element
/// side h, point half-width l < h/2), Bardenhagen & Kober 2004: the hat
/// function averaged over the point's extent.
pub fn gimp(d: f64, h: f64, l: f64) -> (f64, f64) {
    GimpConstants::new(h, l).eval(d)
}

/// Three nodes per axis from `base` (stored index of the lowest node), with
/// weights w and derivatives g: N = wx\[j\]·wz\[l\], ∇N = (gx\[j\]·wz\[l\], wx\[j\]·gz\[l\])
/// for node base + l·row + j. Linear shapes use the first two of each.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Stencil {
    pub base: u32,
    pub wx: [f64; 3],
    pub gx: [f64; 3],
    pub wz: [f64; 3],
    pub gz: [f64; 3],
}

impl Stencil {
    /// Calls `f(node, N, ∇N)` for the nine (or four) nodes.
    #[inline(always)]
    pub fn for_each(&self, row: usize, mut f: impl FnMut(usize, f64, [f64; 2])) {
        for l in 0..3 {
            for j in 0..3 {
                let n = self.wx[j] * self.wz[l];
                let grad = [self.gx[j] * self.wz[l], self.wx[j] * self.gz[l]];
                f(self.base as usize + l * row + j, n, grad);
            }
        }
    }

    /// Σ N_I a_I over the stencil of a nodal field of 2-vectors.
    #[inline(always)]
    pub fn interpolate(&self, row: usize, field: impl Fn(usize) -> [f64; 2]) -> [f64; 2] {
        let mut out = [0.0; 2];
        self.for_each(row, |node, n, _| {
            let a = field(node);
            out[0] += n * a[0];
            out[1] += n * a[1];
        });
        out
    }

    /// Σ ∇N_I ⊗ u_I symmetrised: (ε_xx, ε_zz, γ_xz = 2ε_xz) of a nodal displacement field.
    #[inline(always)]
    pub fn strain(&self, row: usize, field: impl Fn(usize) -> [f64; 2]) -> [f64; 3] {
        let mut e = [0.0; 3];
        self.for_each(row, |node, _, g| {
            let u = field(node);
            e[0] += g[0] * u[0];
            e[1] += g[1] * u[1];
            e[2] += g[1] * u[0] + g[0] * u[1];
        });
        e
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn grid(shape: ShapeFunctions) -> Grid {
        Grid { origin: [0.0, 0.0], h: 0.01, elements: [10, 6], shape }
    }

    /// A point's domain lies over at most two elements per axis in
    /// shares that sum to 1, move continuously as it crosses an element
    /// edge (half in each when centred on it) and stay in the box at its
    /// walls; the shares are the overlap lengths.
    #[test]
    fn domain_shares_are_the_overlap_and_continuous() {
        let g = grid(ShapeFunctions::Gimp);
        let half = [0.00125, 0.0016];
        for s in 0..500 {
            let x = [0.1 * (s as f64 * 0.618).fract(), 0.06 * (s as f64 * 0.414).fract()];
            for (axis, (cells, shares)) in g.domain_overlap(x, half).into_iter().enumerate() {
                assert!((shares[0] + shares[1] - 1.0).abs() < 1e-14 && shares.iter().all(|&f| f >= 0.0));
                if shares[1] > 0.0 {
                    assert_eq!(cells[1], cells[0] + 1);
                    let edge = cells[1] as f64 * g.h;
                    let overlap_lo = (edge - (x[axis] - half[axis])) / (2.0 * half[axis]);
                    assert!((shares[0] - overlap_lo).abs() < 1e-12, "{x:?} axis {axis}");
                }
            }
        }
        // Centred on the edge between columns 3 and 4: half each; an
        // ulp either side changes nothing measurable.
        for x in [0.04 - 1e-12, 0.04, 0.04 + 1e-12] {
            let (cells, shares) = g.domain_overlap([x, 0.03], half)[0];
            assert_eq!(cells, [3, 4]);
            assert!((shares[0] - 0.5).abs() < 1e-8, "{shares:?}");
        }
        // A domain as tall as an element (3 points per element: a 3 × 1
        // sub-grid, half-width h/2) seeded at an element's centre lies in
        // that element, every row, on the lab grids (h = 4 mm, 1/300 m)
        // where the ends round onto neighbouring edges.
        for h in [0.004, 1.0 / 300.0] {
            let g = Grid { origin: [0.0, 0.0], h, elements: [10, 40], shape: ShapeFunctions::Gimp };
            for k in 0..40 {
                let z = (k as f64 + 0.5) * h;
                let (cells, shares) = g.domain_overlap([0.05, z], [h / 6.0, h / 2.0])[1];
                let own = if cells[0] == k {
                    shares[0]
                } else if cells[1] == k {
                    shares[1]
                } else {
                    0.0
                };
                assert!(own >= 1.0 - 1e-12, "h {h}, row {k}: {cells:?} {shares:?}");
            }
        }
        // At the floor and the far wall the share outside stays inside.
        assert_eq!(g.domain_overlap([0.05, 0.0005], half)[1], ([0, 0], [1.0, 0.0]));
        assert_eq!(g.domain_overlap([0.0995, 0.03], half)[0], ([9, 9], [1.0, 0.0]));
    }

    #[test]
    fn weights_partition_unity_and_gradients_sum_to_zero() {
        for shape in [ShapeFunctions::Gimp, ShapeFunctions::Linear] {
            let g = grid(shape);
            for s in 0..500 {
                let x = [0.0025 + 0.095 * (s as f64 * 0.618).fract(), 0.0025 + 0.055 * (s as f64 * 0.414).fract()];
                let st = g.stencil(x, &g.shape_constants([0.00125, 0.0016]));
                let (mut sum, mut gs, mut first) = (0.0, [0.0; 2], [0.0; 2]);
                st.for_each(g.node_dims()[0], |node, n, grad| {
                    let row = g.node_dims()[0];
                    let p = g.node_position(node % row, node / row);
                    sum += n;
                    gs[0] += grad[0];
                    gs[1] += grad[1];
                    // Linear completeness: Σ N_I x_I = x.
                    first[0] += n * p[0];
                    first[1] += n * p[1];
                });
                assert!((sum - 1.0).abs() < 1e-13, "{shape:?} sum {sum}");
                assert!(gs[0].abs() < 1e-10 && gs[1].abs() < 1e-10, "{shape:?} {gs:?}");
                assert!(
                    (first[0] - x[0]).abs() < 1e-14 && (first[1] - x[1]).abs() < 1e-14,
                    "{shape:?} {first:?} {x:?}"
                );
            }
        }
    }

    #[test]
    fn gimp_is_continuous_across_element_edges() {
        let (h, l) = (0.01, 0.00125);
        for d0 in [l, h - l, h + l] {
            let (a, da) = gimp(d0 - 1e-12, h, l);
            let (b, db) = gimp(d0 + 1e-12, h, l);
            assert!((a - b).abs() < 1e-9 && (da - db).abs() < 1e-6, "at {d0}: {a} {b} {da} {db}");
        }
        // The gradient of a linear field is exact: Σ ∇N_I x_I = 1.
        let g = grid(ShapeFunctions::Gimp);
        let st = g.stencil([0.0437, 0.021], &g.shape_constants([l, l]));
        let row = g.node_dims()[0];
        let mut d = 0.0;
        st.for_each(row, |node, _, grad| d += grad[0] * g.node_position(node % row, node / row)[0]);
        assert!((d - 1.0).abs() < 1e-12, "{d}");
    }
}
