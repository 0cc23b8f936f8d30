//! The fused stream–collide kernel: one z-plane at a time, rows in chunks
//! of up to [`LANES`] cells inside one segment ([`Layout`]), half-way bounce-back, the free surface's gas
//! reconstruction and mass exchange and the direct forcing in the same
//! pass; compiled for the baseline and the AVX2 instruction sets
//! ([`runtime::isa`]), bit-identical (`fluid/isa_tests.rs`).
//!
//! Pre: the source lattice holds post-collision populations of every
//! liquid cell, flags and row classes are current. Post: the destination
//! lattice holds the next post-collision populations of every liquid cell;
//! interface cells' mass exchange, forced cells' applied forces and the
//! per-plane sums are written to their own buffers (disjoint per plane).

use super::collision::*;
use super::*;

pub(super) struct Kernel<'a, T> {
    pub(super) src: &'a [T],
    pub(super) flags: &'a [u8],
    pub(super) rows: &'a [u8],
    pub(super) spans: &'a [(u32, u32)],
    pub(super) fill: &'a [f64],
    pub(super) nx: usize,
    pub(super) ny: usize,
    pub(super) nz: usize,
    pub(super) layout: Layout,
    pub(super) faces: [Faces; 3],
    pub(super) coef: Coefficients<T>,
    pub(super) accel: [f64; 3],
    /// Forced cells, ascending index, and where each row's run of them
    /// starts (`forced_rows[r]..forced_rows[r + 1]`; empty without forcing).
    pub(super) forced: &'a [ForcedCell],
    pub(super) forced_rows: &'a [usize],
    pub(super) gain: ForcingGain,
    /// The molecular τ0 in f64, for the forcing gain (the f32 `coef.tau0`
    /// would round τ0 − ½ = 6.7e-4 to 4 digits).
    pub(super) tau0: f64,
    /// 18√2 C² of the closed-form τ_eff in f64, for the gain rules that
    /// take a cell's effective τ.
    pub(super) smag: f64,
}

impl<T: Real> Kernel<'_, T> {
    /// Streams and collides plane z, compiled for instruction set `isa`.
    #[inline(always)]
    pub(super) fn plane<const TRT: bool>(
        &self,
        isa: Isa,
        z: usize,
        out: &SharedOut<T>,
        mass: &SharedOut<f64>,
        density: &SharedOut<f64>,
        applied: &SharedOut<AppliedForce>,
        f: &mut [[T; LANES]; Q],
        accel: &mut [[T; LANES]; 4],
    ) {
        match isa {
            #[cfg(target_arch = "x86_64")]
            // SAFETY: `Isa::detected` returns Avx2 only where the CPU has AVX2 and FMA.
            Isa::Avx2 => unsafe { self.plane_avx2::<TRT>(z, out, mass, density, applied, f, accel) },
            _ => self.plane_rows::<TRT, false>(z, out, mass, density, applied, f, accel),
        }
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    unsafe fn plane_avx2<const TRT: bool>(
        &self,
        z: usize,
        out: &SharedOut<T>,
        mass: &SharedOut<f64>,
        density: &SharedOut<f64>,
        applied: &SharedOut<AppliedForce>,
        f: &mut [[T; LANES]; Q],
        accel: &mut [[T; LANES]; 4],
    ) {
        self.plane_rows::<TRT, true>(z, out, mass, density, applied, f, accel)
    }

    #[inline(always)]
    pub(super) fn plane_rows<const TRT: bool, const AVX2: bool>(
        &self,
        z: usize,
        out: &SharedOut<T>,
        mass: &SharedOut<f64>,
        density: &SharedOut<f64>,
        applied: &SharedOut<AppliedForce>,
        f: &mut [[T; LANES]; Q],
        accel: &mut [[T; LANES]; 4],
    ) {
        for y in 0..self.ny {
            self.row::<TRT, AVX2>(y, z, out, mass, density, applied, f, accel);
        }
    }

    /// Streams and collides the fluid and interface cells of row (y, z).
    /// `AVX2`: the caller runs the AVX2 build (the CPU has AVX2 and FMA), so
    /// the out-of-line paths are called in their AVX2 builds too.
    #[inline(always)]
    fn row<const TRT: bool, const AVX2: bool>(
        &self,
        y: usize,
        z: usize,
        out: &SharedOut<T>,
        mass: &SharedOut<f64>,
        density: &SharedOut<f64>,
        applied: &SharedOut<AppliedForce>,
        f: &mut [[T; LANES]; Q],
        accel: &mut [[T; LANES]; 4],
    ) {
        let class = self.rows[z * self.ny + y];
        // This row's forced cells; `k` walks them along with the chunks.
        // Every entry is written here (those of cells not computed with
        // zeros), so the list needs no reset before the step.
        let (mut k, k_end) = match self.forced_rows.get(z * self.ny + y..z * self.ny + y + 2) {
            Some(&[a, b]) => (a, b),
            _ => (0, 0),
        };
        if class & ROW_ANY_LIQUID == 0 {
            self.unforced(k, k_end, applied);
            return;
        }
        let all_fluid = class & ROW_ALL_FLUID != 0;
        // A pull from gas needs no test here: only interface cells border
        // gas, and `interface_cell` rebuilds those pulls whatever they
        // brought. So only wall cells among the sources need the per-cell
        // test. In a flume no row is fluid end to end, and with the test on
        // every pull of every row the paper's column ran at 9 MLUPS against
        // the bulk box's 125.
        let check_walls = class & (ROW_SOURCES_FLUID | ROW_SOURCES_NO_WALL) == 0;
        let r = z * self.ny + y;
        let row_start = r * self.nx;
        // A mixed row is worked only over its liquid span: with a short
        // column in a long flume most of a row is gas.
        let (mut x0, end) = if all_fluid {
            (0, self.nx)
        } else {
            let (first, end) = self.spans[z * self.ny + y];
            (first as usize, end as usize)
        };
        if y + PREFETCH_AHEAD < self.ny && end - x0 < PREFETCH_ROWS_UNDER {
            self.prefetch_row(y + PREFETCH_AHEAD, z, x0, end, out);
        }
        while x0 < end {
            // A chunk never spans two segments (layout.rs).
            let segment = self.layout.segment();
            let n = (segment - (x0 & (segment - 1))).min(end - x0);
            let own = row_start + x0;
            // Forced cells before this chunk lie outside the liquid span or in skipped chunks.
            let skipped = k + self.forced[k..k_end].iter().take_while(|c| c.cell < own).count();
            self.unforced(k, skipped, applied);
            k = skipped;
            // One pass over a mixed row's chunk flags (liquid flags have bit
            // 0 set): a chunk of gas and wall only (the liquid front in a
            // long flume) is skipped, an all-liquid one is copied out whole.
            let (some_liquid, own_liquid) = if all_fluid {
                (true, true)
            } else {
                let (and, or) = self.flags[own..own + n].iter().fold((1, 0), |(and, or), &fl| (and & fl, or | fl));
                (or & 1 == 1, and & 1 == 1)
            };
            if !some_liquid {
                x0 += n;
                continue;
            }
            for i in 0..Q {
                self.gather(i, y, z, x0, n, check_walls, &mut f[i]);
            }
            if class & ROW_ANY_INTERFACE != 0 {
                for l in 0..n {
                    if self.flags[own + l] == flags::INTERFACE {
                        #[cfg(target_arch = "x86_64")]
                        if AVX2 {
                            // SAFETY: AVX2 is set only under `plane_avx2`, run only where the CPU has AVX2 and FMA.
                            unsafe { self.interface_cell_avx2(x0 + l, y, z, l, f, mass) };
                            continue;
                        }
                        self.interface_cell(x0 + l, y, z, l, f, mass);
                    }
                }
            }
            // Whole vectors of lanes; the lanes past n, and gas or wall
            // lanes, hold finite leftovers and are not written.
            let lanes = n.next_multiple_of(8).min(LANES);
            if k < k_end && self.forced[k].cell < own + n {
                k = match AVX2 {
                    #[cfg(target_arch = "x86_64")]
                    // SAFETY: AVX2 is set only under `plane_avx2`, run only where the CPU has AVX2 and FMA.
                    true => unsafe { self.forced_chunk_avx2::<TRT>(k, k_end, own, n, lanes, applied, f, accel) },
                    _ => self.forced_chunk::<TRT>(k, k_end, own, n, lanes, applied, f, accel),
                };
            } else {
                collide::<T, TRT, false>(f, lanes, &self.coef, accel);
            }
            if class & ROW_ANY_INTERFACE != 0 {
                for l in 0..n {
                    if self.flags[own + l] == flags::INTERFACE {
                        // The values written below, summed as `Fluid::density_at` sums them.
                        // SAFETY: cell own + l lies in plane z, which only this task writes.
                        unsafe { density.slice(own + l, 1)[0] = density_of(|i| f[i][l].to_f64()) };
                    }
                }
            }
            for i in 0..Q {
                // SAFETY: cell indices own..own+n lie in plane z, which only this task writes.
                let dst = unsafe { out.slice(self.layout.at(i, r, x0), n) };
                if own_liquid {
                    copy_lanes(dst, &f[i][..n]);
                } else {
                    for l in 0..n {
                        if flags::is_liquid(self.flags[own + l]) {
                            dst[l] = f[i][l];
                        }
                    }
                }
            }
            x0 += n;
        }
        self.unforced(k, k_end, applied);
    }

    /// Writes "no force" for forced entries `k..k_end`, whose cells are not
    /// liquid or lie outside the row's liquid span.
    #[inline(always)]
    fn unforced(&self, k: usize, k_end: usize, applied: &SharedOut<AppliedForce>) {
        if k < k_end {
            // SAFETY: the entries of a row lie in its plane, which only this task writes.
            let out = unsafe { applied.slice(k, k_end - k) };
            for (a, c) in out.iter_mut().zip(&self.forced[k..k_end]) {
                *a = AppliedForce { cell: c.cell, ..Default::default() };
            }
        }
    }

    /// Collides a chunk holding forced cells (entries `k..` up to the
    /// chunk's end) with per-lane accelerations; returns the next entry.
    /// Out of line so that the unforced chunk loop keeps its code.
    #[inline(never)]
    fn forced_chunk<const TRT: bool>(
        &self,
        k: usize,
        k_end: usize,
        own: usize,
        n: usize,
        lanes: usize,
        applied: &SharedOut<AppliedForce>,
        f: &mut [[T; LANES]; Q],
        accel: &mut [[T; LANES]; 4],
    ) -> usize {
        self.forced_chunk_body::<TRT>(k, k_end, own, n, lanes, applied, f, accel)
    }

    /// [`Kernel::forced_chunk`] in the AVX2 build.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    #[inline(never)]
    unsafe fn forced_chunk_avx2<const TRT: bool>(
        &self,
        k: usize,
        k_end: usize,
        own: usize,
        n: usize,
        lanes: usize,
        applied: &SharedOut<AppliedForce>,
        f: &mut [[T; LANES]; Q],
        accel: &mut [[T; LANES]; 4],
    ) -> usize {
        self.forced_chunk_body::<TRT>(k, k_end, own, n, lanes, applied, f, accel)
    }

    #[inline(always)]
    fn forced_chunk_body<const TRT: bool>(
        &self,
        mut k: usize,
        k_end: usize,
        own: usize,
        n: usize,
        lanes: usize,
        applied: &SharedOut<AppliedForce>,
        f: &mut [[T; LANES]; Q],
        accel: &mut [[T; LANES]; 4],
    ) -> usize {
        for a in 0..3 {
            accel[a] = [self.coef.accel[a]; LANES];
        }
        accel[3] = [T::ZERO; LANES];
        // A linear scan, not a binary search: the entries are read in order
        // right after, and the search's dependent loads each missed the cache.
        let chunk_end = k + self.forced[k..k_end].iter().take_while(|c| c.cell < own + n).count();
        // A chunk inside a packing is mostly forced cells: their moments are
        // then summed for all lanes at once, vectorised (same operations in the
        // same order per lane, so the same bits as one lane at a time).
        let mut moments = None;
        if chunk_end - k >= VECTOR_MOMENTS_FROM {
            let mut m = LaneMoments { drho: [0.0; LANES], j: [[0.0; LANES]; 3] };
            lane_moments(f, n, &mut m);
            moments = Some(m);
        }
        while k < chunk_end {
            let cell = self.forced[k];
            if flags::is_liquid(self.flags[cell.cell]) {
                let l = cell.cell - own;
                let m = match &moments {
                    Some(m) => CellMoments::of_lane(m, l),
                    None => CellMoments::of_cell(f, l),
                };
                let force = self.direct_force(&cell, l, &m, f, accel);
                // SAFETY: entry k's cell lies in plane z, which only this task writes.
                unsafe { applied.slice(k, 1)[0] = force };
            } else {
                self.unforced(k, k + 1, applied);
            }
            k += 1;
        }
        collide::<T, TRT, true>(f, lanes, &self.coef, accel);
        k
    }

    /// The direct force density on forced liquid cell `cell` (lane `l` of
    /// `f`, which holds its pulled pre-collision populations, gas pulls
    /// already rebuilt), folded into the lane's acceleration for the
    /// collision:
    ///
    /// F_IB = b [2(ρU − Σ f e) − ρa] with w = weight × fill (fill 1 in a
    /// fluid cell, the old-level ε clamped to [0, 1] in an interface cell)
    /// the covered fraction and b its [`ForcingGain`].
    ///
    /// Guo's shifted velocity is u = (Σ f e + (ρa + F_IB)/2)/ρ, so b = 1 gives
    /// u = U exactly in this step; b < 1 moves u that fraction of the way.
    /// The clamp keeps the gain at most 1 (beyond it u would overshoot U).
    /// The covered volume w (not b) sets the liquid the grain holds and the
    /// split of the momentum balance below, so buoyancy does not depend on
    /// the gain.
    #[inline(always)]
    fn direct_force(
        &self,
        cell: &ForcedCell,
        l: usize,
        m: &CellMoments,
        f: &[[T; LANES]; Q],
        accel: &mut [[T; LANES]; 4],
    ) -> AppliedForce {
        let fill = if self.flags[cell.cell] == flags::INTERFACE { self.fill[cell.cell].clamp(0.0, 1.0) } else { 1.0 };
        let w = cell.weight * fill;
        let tau = if forcing::uses_effective_tau(self.gain) && w < 1.0 { self.effective_tau(f, l) } else { self.tau0 };
        let b = forcing::forcing_gain(self.gain, w, tau);
        let j = m.j;
        let rho = 1.0 + m.drho;
        let force: [f64; 3] = std::array::from_fn(|a| b * (2.0 * (rho * cell.target[a] - j[a]) - rho * self.accel[a]));
        for a in 0..3 {
            accel[a][l] = T::from_f64(self.accel[a] + force[a] / rho);
        }
        // A fully covered cell holds the liquid inside a grain, which only
        // follows the grain: it relaxes at τ = 1 (row 3 of `accel`), so no
        // non-equilibrium survives there. At the paper's τ0 = 0.50067 that
        // non-equilibrium fed a growing pore-scale mode that fluidised a
        // saturated packing at rest within 10 ms (docs/coupling.md). Mass and
        // momentum are conserved at any τ, so F_IB and the surface force are
        // unchanged; partly covered cells (the grain's surface) keep τ.
        accel[3][l] = T::from_f64(if w >= 1.0 { 1.0 } else { 0.0 });
        // Guo's forcing adds ρa + F_IB to the momentum over the step; the
        // covered part's share is what the grain holds (coupling.rs, step 6).
        let held = std::array::from_fn(|a| w * (j[a] + rho * self.accel[a] + force[a]));
        AppliedForce { cell: cell.cell, force, liquid: w * rho, held }
    }

    /// τ_eff of lane `l` of `f` (pulled populations, stored as f − w) under
    /// the uniform body force alone: [`smagorinsky_tau`] evaluated before the
    /// direct force is added (the gain that sets the force cannot wait for
    /// the strain the force produces).
    #[inline(always)]
    fn effective_tau(&self, f: &[[T; LANES]; Q], l: usize) -> f64 {
        smagorinsky_tau(&std::array::from_fn(|i| f[i][l].to_f64()), self.accel, self.tau0, self.smag)
    }

    /// The free-surface part of the pull for interface cell (x, y, z), lane
    /// `l` of `f` (which holds the pulled, pre-collision populations):
    ///
    /// * a population pulled from a gas cell is rebuilt (Körner et al. 2005)
    ///   as f_i = f_i^eq(ρ_A, u) + f_ī^eq(ρ_A, u) − f_ī*(x) with ρ_A = 1 and u
    ///   the cell's velocity before this step; in the stored shift g = f − w
    ///   that is g_i = w_i[9(e_i·u)² − 3u²] − g_ī*(x);
    /// * the mass exchange Δm = Σ_i s_i [f_i*(x − e_i) − f_ī*(x)] (what
    ///   arrives from the neighbour minus what leaves toward it) with s = 1
    ///   for a fluid neighbour, ½(ε(x) + ε(x − e_i)) for an interface
    ///   neighbour, 0 for gas and wall, is added to the cell's mass. Both
    ///   cells of a link see the same s and opposite differences, bit for
    ///   bit, so Σm changes only by f64 round-off.
    #[inline(never)]
    fn interface_cell(&self, x: usize, y: usize, z: usize, l: usize, f: &mut [[T; LANES]; Q], mass: &SharedOut<f64>) {
        self.interface_cell_body(x, y, z, l, f, mass)
    }

    /// [`Kernel::interface_cell`] in the AVX2 build.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    #[inline(never)]
    unsafe fn interface_cell_avx2(
        &self,
        x: usize,
        y: usize,
        z: usize,
        l: usize,
        f: &mut [[T; LANES]; Q],
        mass: &SharedOut<f64>,
    ) {
        self.interface_cell_body(x, y, z, l, f, mass)
    }

    #[inline(always)]
    fn interface_cell_body(
        &self,
        x: usize,
        y: usize,
        z: usize,
        l: usize,
        f: &mut [[T; LANES]; Q],
        mass: &SharedOut<f64>,
    ) {
        let (nx, ny) = (self.nx, self.ny);
        let c = (z * ny + y) * nx + x;
        let base = self.layout.at(0, z * ny + y, x);
        let own: [f64; Q] = std::array::from_fn(|j| self.src[base + j * self.layout.segment()].to_f64());
        let rho = 1.0 + own.iter().sum::<f64>();
        let u: [f64; 3] = std::array::from_fn(|a| {
            let j: f64 = (0..Q).map(|i| E[i][a] as f64 * own[i]).sum();
            j / rho - 0.5 * self.accel[a]
        });
        let usq = u[0] * u[0] + u[1] * u[1] + u[2] * u[2];
        let eps = self.fill[c];
        let mut dm = 0.0;
        // Off the box's faces every source lies at a fixed offset.
        let inside = x > 0 && x + 1 < nx && y > 0 && y + 1 < ny && z > 0 && z + 1 < self.nz;
        for i in 1..Q {
            let e = E[i];
            let s = if inside {
                (c as isize - link_offset(e, nx, ny)) as usize
            } else {
                let (Some(xs), Some(ys), Some(zs)) = (
                    wrap(x, -e[0], nx, self.faces[0]),
                    wrap(y, -e[1], ny, self.faces[1]),
                    wrap(z, -e[2], self.nz, self.faces[2]),
                ) else {
                    continue; // beyond a wall face: bounced back, no exchange
                };
                (zs * ny + ys) * nx + xs
            };
            let outgoing = own[OPP[i]];
            match self.flags[s] {
                flags::FLUID => dm += f[i][l].to_f64() - outgoing,
                flags::INTERFACE => dm += 0.5 * (eps + self.fill[s]) * (f[i][l].to_f64() - outgoing),
                flags::GAS => {
                    let eu = e[0] as f64 * u[0] + e[1] as f64 * u[1] + e[2] as f64 * u[2];
                    f[i][l] = T::from_f64(W[i] * (9.0 * eu * eu - 3.0 * usq) - outgoing);
                }
                _ => {} // wall: bounced back in `gather`
            }
        }
        // SAFETY: cell c lies in plane z, which only this task writes.
        unsafe { mass.slice(c, 1)[0] += dm };
    }

    /// Asks for the cache lines that row (y, z) will pull from and write
    /// over x0..end (the span of the row before it, a guess). A short
    /// liquid span in a long row (a column in a flume: 67 of 1167 cells)
    /// is 38 streams of a few cache lines each, 4.7 kB apart: too short
    /// for the hardware prefetchers, so every line waited on memory.
    #[inline(always)]
    fn prefetch_row(&self, y: usize, z: usize, x0: usize, end: usize, out: &SharedOut<T>) {
        #[cfg(target_arch = "x86_64")]
        {
            use std::arch::x86_64::{_mm_prefetch, _MM_HINT_T0};
            let per_line = 64 / std::mem::size_of::<T>();
            let (lo, hi) = (x0.saturating_sub(1), (end + 1).min(self.nx));
            let r = z * self.ny + y;
            // Interface cells read their own populations (their velocity and
            // the outgoing half of the mass exchange), off the pulls' rows.
            let own_read = self.rows[r] & ROW_ANY_INTERFACE != 0;
            for i in 0..Q {
                let e = E[i];
                if let (Some(ys), Some(zs)) =
                    (wrap(y, -e[1], self.ny, self.faces[1]), wrap(z, -e[2], self.nz, self.faces[2]))
                {
                    let row = zs * self.ny + ys;
                    for x in (lo..hi).step_by(per_line).chain(std::iter::once(hi - 1)) {
                        let k = self.layout.at(i, row, x);
                        // SAFETY: a prefetch reads nothing architecturally; the index is in bounds anyway.
                        unsafe { _mm_prefetch::<_MM_HINT_T0>(self.src.as_ptr().add(k) as *const i8) };
                    }
                }
                for x in (x0..end).step_by(per_line) {
                    let k = self.layout.at(i, r, x);
                    // SAFETY: as above, `out` spans every population of every cell.
                    unsafe { _mm_prefetch::<_MM_HINT_T0>(out.0.add(k) as *const i8) };
                    if own_read {
                        // SAFETY: as above.
                        unsafe { _mm_prefetch::<_MM_HINT_T0>(self.src.as_ptr().add(k) as *const i8) };
                    }
                }
            }
        }
    }

    /// Pulls population `i` for cells x0..x0+n of row (y, z) into `dst`:
    /// f_i(x) = f_i*(x − e_i), or f_ī*(x) (half-way bounce-back) when x − e_i
    /// is not liquid or lies beyond a wall face. Gas sources are then rebuilt
    /// by [`Kernel::interface_cell`] (a fluid cell never borders gas).
    #[inline(always)]
    fn gather(&self, i: usize, y: usize, z: usize, x0: usize, n: usize, check_walls: bool, dst: &mut [T; LANES]) {
        let (nx, src, layout) = (self.nx, self.src, self.layout);
        let bounce = layout.at(OPP[i], z * self.ny + y, x0);
        let e = E[i];
        let (Some(ys), Some(zs)) = (wrap(y, -e[1], self.ny, self.faces[1]), wrap(z, -e[2], self.nz, self.faces[2]))
        else {
            copy_lanes(&mut dst[..n], &src[bounce..bounce + n]);
            return;
        };
        let source_row = zs * self.ny + ys;
        let src_row = source_row * nx;
        // Lanes whose source x lies outside this chunk's segment: lane 0 for
        // e_x = +1 at a segment's start, lane n−1 for e_x = −1 at its end;
        // off the row's ends they wrap or bounce back.
        // The segment length is a power of two: `& mask` is `% segment`.
        let mask = layout.segment() - 1;
        let lo = usize::from(e[0] == 1 && x0 & mask == 0);
        let hi = if e[0] == -1 && ((x0 + n) & mask == 0 || x0 + n == nx) { n - 1 } else { n };
        if hi > lo {
            let start = layout.at(i, source_row, ((x0 + lo) as isize - e[0] as isize) as usize);
            copy_lanes(&mut dst[lo..hi], &src[start..start + (hi - lo)]);
        }
        let periodic_x = self.faces[0] == Faces::Periodic;
        if lo == 1 {
            dst[0] = if x0 > 0 {
                src[layout.at(i, source_row, x0 - 1)]
            } else if periodic_x {
                src[layout.at(i, source_row, nx - 1)]
            } else {
                src[bounce]
            };
        }
        if hi == n - 1 {
            dst[n - 1] = if x0 + n < nx {
                src[layout.at(i, source_row, x0 + n)]
            } else if periodic_x {
                src[layout.at(i, source_row, 0)]
            } else {
                src[bounce + n - 1]
            };
        }
        if check_walls {
            for l in 0..n {
                if let Some(xs) = wrap(x0 + l, -e[0], nx, self.faces[0]) {
                    if !flags::is_liquid(self.flags[src_row + xs]) {
                        dst[l] = src[bounce + l];
                    }
                }
            }
        }
    }
}

/// Liquid spans shorter than this are prefetched a row ahead (longer ones
/// are long enough streams for the hardware prefetchers).
pub(super) const PREFETCH_ROWS_UNDER: usize = 512;
pub(super) const PREFETCH_AHEAD: usize = 1;
