//! Particle coupling, Eq. 5 of Ceccato et al. 2020: direct-forcing immersed
//! boundary (lbm-free-surface.md §6 "Recommended instead"; docs/lbm.md
//! "Particle coupling (Eq. 5)").
//!
//! Per step, for spheres given in SI:
//!
//! 1. **Covered fraction** of each cell by each sphere,
//!    ε_s = clamp(½ − (|x_c − x_p| − R*), 0, 1) (lattice units), with the
//!    radius R* solving R*³ + R*/4 = R³. The linear ramp makes ε_s Lipschitz
//!    in the sphere position (sub-sampling n³ points jumps by 1/n³ as a
//!    sphere moves, a force noise the DEM would feel); summed over a lattice
//!    it gives the volume of a sphere of radius R* plus πR*/3 on average,
//!    which R* cancels: Σε_s = 4πR³/3 within 0.7 % (R = 2Δx) and 0.4 %
//!    (R = 4Δx) for any position.
//! 2. **Cells covered by several spheres**: weight min(1, Σ_s ε_s), target
//!    the ε-weighted mean of the spheres' rigid-body velocities, and the
//!    cell's force is shared in proportion ε_s/Σε_s. Summing weights keeps
//!    a cell half-covered by each of two touching grains fully forced;
//!    capping at 1 keeps the gain ≤ 1 (a larger gain overshoots U); the
//!    shares sum to 1, so the momentum bookkeeping stays exact.
//! 3. **Forcing** (in the fluid kernel, [`Fluid::set_direct_forcing`]):
//!    F_IB = b [2(ρU − Σ f e) − ρa] with U = v_p + ω_p × (x_c − x_p) and
//!    the gain b a function of the covered fraction w = weight × fill
//!    ([`ForcingGain`]): a fully covered liquid cell moves at the
//!    rigid-body velocity in the same step. The default gain is Noble &
//!    Torczynski's (1998) b = w(τ0 − ½)/((1 − w) + (τ0 − ½)): at τ0 → ½ a
//!    partly covered cell is barely forced, so the pore liquid between
//!    grains is not held back by a drag stronger than its viscosity (with
//!    b = w a packing at the paper's τ0 drains ~80× slower than Ergun's
//!    flux, docs/coupling.md). Interface cells are forced in proportion to
//!    their fill, gas cells never.
//! 4. **Sphere force and torque**: F_h = −Σ_c share·F_IB, T_h = −Σ_c
//!    (x_c − x_p) × share·F_IB, each sphere's summed over its own cells in
//!    covering order (ascending cell but for periodic wraps), spheres in
//!    parallel, so they are bit-identical for any thread count.
//! 5. **Buoyancy**: the liquid inside a grain stays in the lattice and is held
//!    up by the same pressure gradient as the liquid around it, so at rest
//!    F_IB = 0 and the pressure on the grain must be added explicitly (the
//!    interior-fluid momentum balance of Uhlmann 2005 / Kempe & Fröhlich
//!    2012): F_b = −m_L a with m_L = Σ_c share·w·ρ_c, the covered liquid
//!    mass. Gas cells and the empty part of interface cells carry no weight,
//!    so a grain half out of the liquid gets the buoyancy of its wetted part.
//!    Steps 4–5 miss the inertia of the liquid inside the grain (m_L dU_p/dt),
//!    and their sum alternates from step to step: with gain 1 the forced
//!    interior liquid overshoots, and the next step pulls it back. Fed to a
//!    free grain that alternation grows (a 4000 kg/m³ sphere settling in
//!    oil blew up within 30 steps). Hence step 6.
//! 6. **Surface force** (what a free grain is given): Kempe & Fröhlich's
//!    (2012) balance of the liquid the grain holds, with that liquid's
//!    momentum measured instead of modelled,
//!    F_s = −ΣF_IB − m_L a + (I_n − I_{n−1})/Δt, I_n = Σ_c share·w·q*_c,
//!    q*_c the cell's momentum after step n's collision (and the matching
//!    angular momentum about the centre for the torque). As cells enter
//!    and leave a moving grain's cover, I changes by the momentum of the
//!    liquid swept in and left behind: counting it keeps the grains and the
//!    liquid outside them in exact momentum balance (tests/coupling.rs), and
//!    the overshoot of step 5 cancels, since it is in both I and F_IB. At
//!    rest F_s is the buoyancy; in steady motion it equals `force +
//!    buoyancy` on average. A sphere not collected in the step before
//!    (the first step, a changed sphere count) gets `force + buoyancy` for
//!    one step. Until session 13 the sum left out the swept liquid
//!    (w_n (q_pulled − q*_{n−1}) per cell): a grain settling at Re 30 under
//!    the default gain was given 0.78–0.87 of the reaction (docs/coupling.md).
//!
//! Lattice cell (i, j, k) has its centre at `origin + (i + ½, j + ½, k + ½) Δx`
//! (as in [`crate::setup`]). Periodic axes wrap the spheres.

use rayon::prelude::*;

use crate::fluid::{Faces, Fluid, ForcedCell, SharedOut};
use crate::real::Real;
use crate::units::Units;
pub use schemas::scene::ForcingGain;

/// A rigid sphere, SI.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sphere {
    /// Centre, m.
    pub position: [f64; 3],
    /// m/s.
    pub velocity: [f64; 3],
    /// rad/s.
    pub angular_velocity: [f64; 3],
    /// m, > 0.
    pub radius: f64,
}

/// What the liquid does to one sphere in one step, SI.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct SphereForce {
    /// −Σ share·F_IB, N: the hydrodynamic force of the forcing (drag, lift,
    /// and the non-hydrostatic pressure).
    pub force: [f64; 3],
    /// −Σ (x_c − x_p) × share·F_IB, N m, about the sphere centre.
    pub torque: [f64; 3],
    /// −m_L a, N: the hydrostatic pressure on the wetted part of the grain.
    pub buoyancy: [f64; 3],
    /// m_L, kg: the covered liquid mass (ρ_L times the wetted volume).
    pub liquid_mass: f64,
    /// `force + buoyancy` + the change over the step of the momentum of the
    /// liquid the grain holds, N (step 6 of the module docs): what a free
    /// grain feels from the liquid.
    pub surface_force: [f64; 3],
    /// `torque` + the change of the held liquid's angular momentum about
    /// the centre, N m.
    pub surface_torque: [f64; 3],
}

impl SphereForce {
    /// `force + buoyancy`, N: the surface force of a grain whose interior
    /// liquid does not accelerate (at rest or in steady motion).
    pub fn total(&self) -> [f64; 3] {
        std::array::from_fn(|a| self.force[a] + self.buoyancy[a])
    }
}

/// Why the coupling cannot run.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CouplingError {
    #[error("sphere {index}: {why}")]
    Sphere { index: usize, why: &'static str },
    #[error("origin must be finite, got {0:?}")]
    Origin([f64; 3]),
    #[error("collect must follow apply and exactly one fluid step with that forcing")]
    Stale,
    #[error("more than 2^32 cells or sphere-cell overlaps: split the box or coarsen the lattice")]
    TooLarge,
    #[error(transparent)]
    Fluid(#[from] crate::fluid::ConfigError),
}

/// One row of cells (fixed y and z) that a sphere's reach crosses, and the
/// run of cells along x it may cover there.
#[derive(Debug, Clone, Copy, Default)]
struct Crossing {
    sphere: u32,
    /// Row index `z * ny + y` (wrapped).
    row: u32,
    /// Unwrapped lattice y and z of the row, and the first unwrapped x of the run.
    j: i32,
    k: i32,
    i_lo: i32,
    /// Cells in the run (an upper bound on the covered ones).
    run: u32,
    /// First slot of the run in `Coupling::slots`; the row pass writes the
    /// covered cells' slots from there, `covered` of them.
    slot: u32,
    covered: u32,
}

/// One (cell, sphere) overlap, as `collect` reads it: 16 bytes, as the
/// ~600k of the paper's column are written and read once a step (x_c − x_p
/// is recomputed from the crossing, to the same bits).
#[derive(Debug, Clone, Copy, Default)]
struct Slot {
    /// The cell's forced-cell entry, counted from its row's `row_base`.
    entry: u32,
    /// The cell's place in its crossing's run: x = `i_lo + offset`.
    offset: u32,
    /// ε_s/Σε of the cell: this sphere's share of the cell's force.
    share: f64,
}

/// Per parallel part of the row pass: a dense buffer over one row, and the
/// forced cells the part's rows produced.
#[derive(Debug, Clone, Default)]
struct RowScratch {
    /// Per x of the row: Σε, Σε(v + ω × r), the cell's entry in `cells`.
    /// Σε > 0 marks the row's covered cells (ε > 0 wherever a slot is made).
    total: Vec<f64>,
    target: Vec<[f64; 3]>,
    entry: Vec<u32>,
    cells: Vec<ForcedCell>,
}

/// The coupling kernel with its reused buffers.
#[derive(Debug, Clone)]
pub struct Coupling {
    units: Units,
    origin: [f64; 3],
    /// Per sphere: centre in lattice coordinates and ramp radius.
    placed: Vec<([f64; 3], f64)>,
    /// Lattice-unit rigid-body velocity and angular velocity per sphere.
    motion: Vec<([f64; 3], [f64; 3])>,
    /// The rows each sphere crosses, in sphere order and, per sphere, in
    /// covering order (z, then y, ascending but for periodic wraps);
    /// `crossings[sphere_start[s]..sphere_start[s + 1]]` are sphere s's.
    crossings: Vec<Crossing>,
    sphere_start: Vec<usize>,
    /// Crossings of each chunk of spheres, reused, and where each chunk's
    /// crossings and slots start in `crossings` and `slots`.
    chunk_crossings: Vec<Vec<Crossing>>,
    chunk_starts: Vec<(usize, usize)>,
    /// Crossing indices by row (a stable counting sort: ascending sphere
    /// within a row); `by_row[row_start[r]..row_start[r + 1]]` are row r's.
    by_row: Vec<u32>,
    row_start: Vec<u32>,
    /// Row ranges of the parallel parts of the row pass, and each part's
    /// first forced-cell entry.
    part_rows: Vec<usize>,
    part_entries: Vec<usize>,
    /// Per row, the first forced-cell entry of its part (slot entries count from it).
    row_base: Vec<u32>,
    parts: Vec<RowScratch>,
    slots: Vec<Slot>,
    /// The forced cells being built and their row index (`forced_rows[r]`:
    /// the first entry of row r); both swapped into the fluid by `apply`.
    forced: Vec<ForcedCell>,
    forced_rows: Vec<usize>,
    results: Vec<SphereForce>,
    /// Per sphere, the momentum and angular momentum (about its centre) of
    /// the liquid it held after the last collected step, lattice units, and
    /// the fluid's step count then: the start of the next step's interior
    /// inertia (step 6 of the module docs).
    held: Vec<([f64; 3], [f64; 3])>,
    held_at: Option<u64>,
    /// The fluid's step count and forcing version when [`Coupling::apply`]
    /// last installed its list (the fluid holds the list from then on).
    applied_at: Option<(u64, u64)>,
    /// How partly covered cells are forced (installed in the fluid by `apply`).
    gain: ForcingGain,
}

/// The liquid each sphere held after a collected step (momentum and
/// angular momentum about its centre, lattice units) and that step's count.
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct HeldLiquid {
    pub per_sphere: Vec<([f64; 3], [f64; 3])>,
    pub step: Option<u64>,
}

/// R* with R*³ + R*/4 = R³ (Newton from R; the map is monotone and convex).
fn ramp_radius(r: f64) -> f64 {
    let mut x = r;
    for _ in 0..8 {
        x -= (x * x * x + 0.25 * x - r * r * r) / (3.0 * x * x + 0.25);
    }
    x
}

/// Spheres per parallel covering task.
const COVER_CHUNK: usize = 256;

/// Appends the rows sphere `index` (centre `p` in lattice coordinates,
/// ramp radius `radius`) crosses, each with the run of x its reach can
/// cover there: the chord of the reach sphere, widened by a millionth of
/// the reach so that rounding never drops a covered cell (the rounding of
/// the chord is at most ~1e-8 of the reach, where the row grazes the
/// sphere; the row pass tests every cell of the run exactly as a
/// cell-by-cell cover would).
fn crossings_of(index: usize, p: [f64; 3], radius: f64, dims: [usize; 3], faces: [Faces; 3], out: &mut Vec<Crossing>) {
    let reach = radius + 0.5;
    let lo: [i64; 3] = std::array::from_fn(|a| (p[a] - reach).ceil() as i64);
    let hi: [i64; 3] = std::array::from_fn(|a| (p[a] + reach).floor() as i64);
    let inside = |a: usize, i: i64| -> Option<usize> { wrap_axis(dims[a], faces[a], i) };
    for k in lo[2]..=hi[2] {
        let Some(kz) = inside(2, k) else { continue };
        let dz = k as f64 - p[2];
        for j in lo[1]..=hi[1] {
            let Some(jy) = inside(1, j) else { continue };
            let dy = j as f64 - p[1];
            let h2 = reach * reach - dy * dy - dz * dz;
            let margin = 1e-6 * reach;
            if h2 < -margin * margin {
                continue;
            }
            let h = h2.max(0.0).sqrt() + margin;
            let i_lo = ((p[0] - h).ceil() as i64).max(lo[0]);
            let i_hi = ((p[0] + h).floor() as i64).min(hi[0]);
            if i_hi < i_lo {
                continue;
            }
            out.push(Crossing {
                sphere: index as u32,
                row: (kz * dims[1] + jy) as u32,
                j: j as i32,
                k: k as i32,
                i_lo: i_lo as i32,
                run: (i_hi - i_lo + 1) as u32,
                slot: 0,
                covered: 0,
            });
        }
    }
}

/// The cell index along an axis of `n` cells, wrapped on a periodic axis,
/// None outside walls.
fn wrap_axis(n: usize, faces: Faces, i: i64) -> Option<usize> {
    let n = n as i64;
    match faces {
        Faces::Periodic => Some(i.rem_euclid(n) as usize),
        Faces::Walls => (0..n).contains(&i).then_some(i as usize),
    }
}

/// ε_s of the cell at unwrapped lattice point (i, j, k) for a sphere at `p`
/// with ramp radius `radius`, and x_c − x_p.
#[inline(always)]
fn covered_fraction(i: i64, j: i64, k: i64, p: [f64; 3], radius: f64) -> (f64, [f64; 3]) {
    let r = offset_from(i, j, k, p);
    let d = (r[0] * r[0] + r[1] * r[1] + r[2] * r[2]).sqrt() - radius;
    ((0.5 - d).clamp(0.0, 1.0), r)
}

/// x_c − x_p of the cell at unwrapped lattice point (i, j, k), lattice units.
#[inline(always)]
fn offset_from(i: i64, j: i64, k: i64, p: [f64; 3]) -> [f64; 3] {
    [i as f64 - p[0], j as f64 - p[1], k as f64 - p[2]]
}

/// Asks for the cache line holding `x` (a hint; no effect on results).
#[inline(always)]
fn prefetch<T>(x: &T) {
    #[cfg(target_arch = "x86_64")]
    // SAFETY: a prefetch reads nothing architecturally; `x` is a valid reference anyway.
    unsafe {
        std::arch::x86_64::_mm_prefetch::<{ std::arch::x86_64::_MM_HINT_T0 }>(x as *const T as *const i8)
    };
}

fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
}

impl Coupling {
    /// `origin`: the SI position of the low corner of cell (0, 0, 0).
    pub fn new(units: Units, origin: [f64; 3]) -> Result<Self, CouplingError> {
        if !origin.iter().all(|o| o.is_finite()) {
            return Err(CouplingError::Origin(origin));
        }
        Ok(Coupling {
            units,
            origin,
            placed: Vec::new(),
            motion: Vec::new(),
            crossings: Vec::new(),
            sphere_start: Vec::new(),
            chunk_crossings: Vec::new(),
            chunk_starts: Vec::new(),
            by_row: Vec::new(),
            row_start: Vec::new(),
            part_rows: Vec::new(),
            part_entries: Vec::new(),
            row_base: Vec::new(),
            parts: Vec::new(),
            slots: Vec::new(),
            forced: Vec::new(),
            forced_rows: Vec::new(),
            results: Vec::new(),
            held: Vec::new(),
            held_at: None,
            applied_at: None,
            gain: ForcingGain::default(),
        })
    }

    /// Forces partly covered cells with `gain` (default
    /// [`ForcingGain::NobleTorczynski`]).
    pub fn with_gain(mut self, gain: ForcingGain) -> Self {
        self.gain = gain;
        self
    }

    pub fn gain(&self) -> ForcingGain {
        self.gain
    }

    /// Covers the cells of `spheres` and installs their forcing in `fluid`
    /// for the next step. A sphere must be finite with radius > 0, and no
    /// wider than a periodic axis (2R + 2 cells) so that it never covers a
    /// cell twice. Parts outside a walled box cover nothing.
    ///
    /// Stages: `Coupling::place` (per sphere), `Coupling::find_crossings`
    /// (the rows each sphere crosses, in parallel), `Coupling::sort_by_row`
    /// (a counting sort), `Coupling::cover_rows` (rows in parallel: the
    /// forced cells come out in ascending cell order, so nothing is sorted
    /// by cell; ~600k overlaps a step in the paper's column, where a sort by
    /// cell and the random access of grouping by it cost more than the
    /// fluid step).
    pub fn apply<T: Real>(&mut self, fluid: &mut Fluid<T>, spheres: &[Sphere]) -> Result<(), CouplingError> {
        let dims = fluid.dims();
        let faces = fluid.state().faces;
        // Forced cells and sphere indices are stored as u32.
        if dims.iter().product::<usize>() > u32::MAX as usize || spheres.len() > u32::MAX as usize {
            return Err(CouplingError::TooLarge);
        }
        self.place(spheres, dims, faces)?;
        self.find_crossings(dims, faces)?;
        self.sort_by_row(dims);
        self.cover_rows(dims, faces);
        self.results.clear();
        self.results.resize(spheres.len(), SphereForce::default());
        fluid.set_forcing_gain(self.gain);
        let version = fluid.swap_direct_forcing(&mut self.forced, &mut self.forced_rows);
        self.applied_at = Some((fluid.steps(), version));
        Ok(())
    }

    /// Stage of [`Coupling::apply`]: checks each sphere and stores its centre
    /// in lattice coordinates (cell i's centre at i), ramp radius and motion.
    fn place(&mut self, spheres: &[Sphere], dims: [usize; 3], faces: [Faces; 3]) -> Result<(), CouplingError> {
        let dx = self.units.dx();
        self.applied_at = None;
        self.motion.clear();
        self.placed.clear();
        for (index, s) in spheres.iter().enumerate() {
            let finite = s.position.iter().chain(&s.velocity).chain(&s.angular_velocity).all(|v| v.is_finite());
            if !finite {
                return Err(CouplingError::Sphere { index, why: "position, velocity or angular velocity not finite" });
            }
            if !(s.radius.is_finite() && s.radius > 0.0) {
                return Err(CouplingError::Sphere { index, why: "radius must be finite and > 0" });
            }
            let radius = ramp_radius(s.radius / dx);
            let reach = radius + 0.5;
            if (0..3).any(|a| faces[a] == Faces::Periodic && 2.0 * reach + 1.0 > dims[a] as f64) {
                return Err(CouplingError::Sphere { index, why: "wider than a periodic axis of the box" });
            }
            let p: [f64; 3] = std::array::from_fn(|a| (s.position[a] - self.origin[a]) / dx - 0.5);
            self.motion.push((
                s.velocity.map(|v| self.units.velocity_to_lattice(v)),
                s.angular_velocity.map(|w| w * self.units.dt()),
            ));
            self.placed.push((p, radius));
        }
        Ok(())
    }

    /// Stage of [`Coupling::apply`]: every sphere's crossings (chunks of
    /// spheres in parallel, concatenated in sphere order, also in parallel),
    /// where each crossing's run of slots starts, and where each sphere's
    /// crossings start.
    fn find_crossings(&mut self, dims: [usize; 3], faces: [Faces; 3]) -> Result<(), CouplingError> {
        let n = self.placed.len();
        let chunks = n.div_ceil(COVER_CHUNK);
        self.chunk_crossings.resize_with(chunks.max(self.chunk_crossings.len()), Vec::new);
        self.chunk_crossings[..chunks].par_iter_mut().zip(self.placed.par_chunks(COVER_CHUNK)).enumerate().for_each(
            |(c, (buffer, placed))| {
                buffer.clear();
                for (k, &(p, radius)) in placed.iter().enumerate() {
                    crossings_of(c * COVER_CHUNK + k, p, radius, dims, faces, buffer);
                }
            },
        );
        // Where each chunk's crossings and slots go.
        self.chunk_starts.clear();
        let (mut crossings, mut slots) = (0usize, 0usize);
        for buffer in &self.chunk_crossings[..chunks] {
            self.chunk_starts.push((crossings, slots));
            crossings += buffer.len();
            slots += buffer.iter().map(|c| c.run as usize).sum::<usize>();
        }
        if slots > u32::MAX as usize {
            return Err(CouplingError::TooLarge);
        }
        self.crossings.clear();
        self.crossings.reserve(crossings);
        self.sphere_start.clear();
        self.sphere_start.resize(n + 1, 0);
        self.sphere_start[n] = crossings;
        {
            let out = SharedOut::new(&mut self.crossings.spare_capacity_mut()[..crossings]);
            let starts = SharedOut::new(&mut self.sphere_start[..n]);
            let (buffers, chunk_starts) = (&self.chunk_crossings, &self.chunk_starts);
            (0..chunks).into_par_iter().for_each(|chunk| {
                let (first, mut slot) = chunk_starts[chunk];
                let buffer = &buffers[chunk];
                // SAFETY: the chunks' ranges of crossings are disjoint (prefix sums of their counts).
                let out = unsafe { out.slice(first, buffer.len()) };
                let spheres = chunk * COVER_CHUNK..((chunk + 1) * COVER_CHUNK).min(n);
                // SAFETY: each chunk writes the starts of its own spheres.
                let starts = unsafe { starts.slice(spheres.start, spheres.len()) };
                let mut k = 0;
                for (s, start) in spheres.zip(starts) {
                    // A sphere with no crossing (outside a walled box) starts where the next one does.
                    *start = first + k;
                    while k < buffer.len() && buffer[k].sphere as usize == s {
                        out[k].write(Crossing { slot: slot as u32, ..buffer[k] });
                        slot += buffer[k].run as usize;
                        k += 1;
                    }
                }
                // Every crossing written, or `set_len` below would expose uninitialised ones.
                assert_eq!(k, buffer.len(), "a chunk's crossings come in the order of its spheres");
            });
        }
        // SAFETY: the chunks wrote every crossing in 0..crossings (their ranges tile it).
        unsafe { self.crossings.set_len(crossings) };
        self.slots.resize(slots, Slot::default());
        Ok(())
    }

    /// Stage of [`Coupling::apply`]: crossing indices grouped by row, a
    /// stable counting sort, so each row lists its spheres in ascending order.
    fn sort_by_row(&mut self, dims: [usize; 3]) {
        let rows = dims[1] * dims[2];
        self.row_start.clear();
        self.row_start.resize(rows + 1, 0);
        for c in &self.crossings {
            self.row_start[c.row as usize + 1] += 1;
        }
        for r in 1..=rows {
            self.row_start[r] += self.row_start[r - 1];
        }
        self.by_row.clear();
        self.by_row.resize(self.crossings.len(), 0);
        // Place from each row's end, walking backwards, which keeps the
        // order stable and leaves each row's start one entry up.
        let ends = &mut self.row_start;
        for (index, c) in self.crossings.iter().enumerate().rev() {
            let end = &mut ends[c.row as usize + 1];
            *end -= 1;
            self.by_row[*end as usize] = index as u32;
        }
        // ends[r + 1] moved back to row r's start: shift down by one.
        ends.rotate_left(1);
        ends[rows] = self.crossings.len() as u32;
    }

    /// Stage of [`Coupling::apply`]: each row's covered cells, rows in
    /// parallel parts. Per row, its spheres in ascending order add their ε
    /// and ε(v + ω × r) to a dense buffer over the row; the row's forced
    /// cells (weight min(1, Σε), target the ε-weighted mean velocity) then
    /// come out in ascending x, and each overlap gets its share ε/Σε and its
    /// cell's entry. Summing weights keeps a cell half-covered by each of
    /// two touching grains fully forced; capping at 1 keeps the gain ≤ 1.
    /// Every row is worked by one part whatever the part count, so the
    /// result does not depend on the thread count.
    fn cover_rows(&mut self, dims: [usize; 3], faces: [Faces; 3]) {
        let (nx, rows) = (dims[0], dims[1] * dims[2]);
        let total_crossings = self.crossings.len();
        let parts = if total_crossings < 1024 { 1 } else { 4 * rayon::current_num_threads() };
        self.part_rows.clear();
        let mut row = 0;
        self.part_rows.push(0);
        for p in 1..parts {
            let target = (total_crossings * p / parts) as u32;
            while row < rows && self.row_start[row] < target {
                row += 1;
            }
            self.part_rows.push(row);
        }
        self.part_rows.push(rows);
        self.parts.resize_with(parts.max(self.parts.len()), RowScratch::default);
        let slots = SharedOut::new(&mut self.slots);
        self.forced_rows.clear();
        self.forced_rows.resize(rows + 1, 0);
        // Each row's first entry, counted from its part's first for now.
        let row_first = SharedOut::new(&mut self.forced_rows);
        let mut crossings = std::mem::take(&mut self.crossings);
        let covered = SharedOut::new(&mut crossings);
        let (by_row, row_start, part_rows) = (&self.by_row, &self.row_start, &self.part_rows);
        let (placed, motion) = (&self.placed, &self.motion);
        self.parts[..parts].par_iter_mut().enumerate().for_each(|(part, scratch)| {
            let RowScratch { total, target, entry, cells } = scratch;
            if total.len() < nx {
                total.resize(nx, 0.0);
                target.resize(nx, [0.0; 3]);
                entry.resize(nx, 0);
            }
            cells.clear();
            for r in part_rows[part]..part_rows[part + 1] {
                // SAFETY: row r belongs to this part only.
                unsafe { row_first.slice(r, 1)[0] = cells.len() };
                let list = &by_row[row_start[r] as usize..row_start[r + 1] as usize];
                if list.is_empty() {
                    continue;
                }
                // The covered x lie in lo..hi; scanning that range for Σε > 0
                // finds them in order (a sort of the covered x cost more:
                // ~200 covered cells a row in a packed bed).
                let (mut lo, mut hi) = (nx, 0);
                for &ci in list {
                    // SAFETY: crossing ci lies in row r, which only this part works.
                    let c = unsafe { &mut covered.slice(ci as usize, 1)[0] };
                    let (p, radius) = placed[c.sphere as usize];
                    let (v, w) = motion[c.sphere as usize];
                    // SAFETY: crossing ci's run of slots is its own.
                    let run = unsafe { slots.slice(c.slot as usize, c.run as usize) };
                    let mut m = 0;
                    for t in 0..c.run as i64 {
                        let i = c.i_lo as i64 + t;
                        let Some(ix) = wrap_axis(nx, faces[0], i) else { continue };
                        let (eps, rr) = covered_fraction(i, c.j as i64, c.k as i64, p, radius);
                        if eps > 0.0 {
                            lo = lo.min(ix);
                            hi = hi.max(ix + 1);
                            total[ix] += eps;
                            let rot = cross(w, rr);
                            for a in 0..3 {
                                target[ix][a] += eps * (v[a] + rot[a]);
                            }
                            // The cell's x and ε for now; entry and share below.
                            run[m] = Slot { entry: ix as u32, offset: t as u32, share: eps };
                            m += 1;
                        }
                    }
                    c.covered = m as u32;
                }
                for ix in lo..hi {
                    let sum = total[ix];
                    if sum == 0.0 {
                        continue;
                    }
                    entry[ix] = cells.len() as u32;
                    cells.push(ForcedCell {
                        cell: r * nx + ix,
                        weight: sum.min(1.0),
                        target: target[ix].map(|t| t / sum),
                    });
                }
                for &ci in list {
                    // SAFETY: as above.
                    let c = unsafe { &covered.slice(ci as usize, 1)[0] };
                    let run = unsafe { slots.slice(c.slot as usize, c.covered as usize) };
                    for slot in run {
                        let ix = slot.entry as usize;
                        slot.share /= total[ix];
                        slot.entry = entry[ix];
                    }
                }
                if lo < hi {
                    total[lo..hi].fill(0.0);
                    target[lo..hi].fill([0.0; 3]);
                }
            }
        });
        // Each part's cells follow the cells of the parts before it (rows
        // ascend across parts); a slot's entry is local to its row's part.
        self.part_entries.clear();
        let mut sum = 0;
        for scratch in &self.parts[..parts] {
            self.part_entries.push(sum);
            sum += scratch.cells.len();
        }
        // Not initialised first: that serial pass over ~500k entries (20 MB)
        // cost more than the parallel copy.
        self.forced.clear();
        self.forced.reserve(sum);
        let forced = SharedOut::new(&mut self.forced.spare_capacity_mut()[..sum]);
        let part_entries = &self.part_entries;
        self.parts[..parts].par_iter().enumerate().for_each(|(part, scratch)| {
            // SAFETY: the parts' entry ranges are disjoint (prefix sums of their counts).
            let out = unsafe { forced.slice(part_entries[part], scratch.cells.len()) };
            for (o, cell) in out.iter_mut().zip(&scratch.cells) {
                o.write(*cell);
            }
        });
        // SAFETY: the parts wrote every entry in 0..sum (their ranges tile it).
        unsafe { self.forced.set_len(sum) };
        self.row_base.clear();
        self.row_base.resize(rows, 0);
        for part in 0..parts {
            let rows = part_rows[part]..part_rows[part + 1];
            self.row_base[rows.clone()].fill(part_entries[part] as u32);
            self.forced_rows[rows].iter_mut().for_each(|first| *first += part_entries[part]);
        }
        self.forced_rows[rows] = sum;
        self.crossings = crossings;
    }

    /// The liquid the spheres held after the last collected step: what the
    /// next step's interior inertia starts from (a checkpoint keeps it).
    pub fn held_liquid(&self) -> HeldLiquid {
        HeldLiquid { per_sphere: self.held.clone(), step: self.held_at }
    }

    /// Continues from a checkpoint's [`Coupling::held_liquid`].
    pub fn restore_held_liquid(&mut self, held: HeldLiquid) {
        self.results.resize(held.per_sphere.len(), SphereForce::default());
        self.held = held.per_sphere;
        self.held_at = held.step;
    }

    /// The force and torque on each sphere (in the order given to
    /// [`Coupling::apply`]) from the one step that ran since.
    ///
    /// Spheres in parallel; each sums its own cells in covering order, so
    /// the result does not depend on the thread count. Called again before
    /// the next step, it returns the same forces (the held liquid of step 6
    /// is counted once).
    pub fn collect<T: Real>(&mut self, fluid: &Fluid<T>) -> Result<&[SphereForce], CouplingError> {
        let applied = fluid.applied_forcing();
        if self.applied_at != Some((fluid.steps().wrapping_sub(1), fluid.forcing_version())) {
            return Err(CouplingError::Stale);
        }
        let g = fluid.params().acceleration;
        let mass_unit = self.units.rho0() * self.units.dx().powi(3);
        let units = &self.units;
        let (crossings, starts, slots, row_base) = (&self.crossings, &self.sphere_start, &self.slots, &self.row_base);
        let placed = &self.placed;
        // Asked again for the same step: the held liquid has moved on to it.
        if self.held_at == Some(fluid.steps()) {
            return Ok(&self.results);
        }
        // The liquid held after the previous step is this step's start only
        // if that step was collected for the same spheres.
        let continues = self.held_at == Some(fluid.steps().wrapping_sub(1)) && self.held.len() == self.results.len();
        self.held.resize(self.results.len(), ([0.0; 3], [0.0; 3]));
        self.held_at = Some(fluid.steps());
        self.results.par_iter_mut().zip(self.held.par_iter_mut()).enumerate().for_each(|(s, (out, held))| {
            *out = SphereForce::default();
            // The next sphere's cells, one run per row it crosses, are
            // scattered over the forced cells: ask for them all now, so
            // their ~25 cache misses overlap this sphere's sums.
            if s + 1 < starts.len() - 1 {
                for c in &crossings[starts[s + 1]..starts[s + 2]] {
                    let base = row_base[c.row as usize] as usize;
                    for slot in &slots[c.slot as usize..(c.slot + c.covered) as usize] {
                        prefetch(&applied[base + slot.entry as usize]);
                    }
                }
            }
            let p = placed[s].0;
            let (mut momentum, mut angular) = ([0.0; 3], [0.0; 3]);
            for c in &crossings[starts[s]..starts[s + 1]] {
                let base = row_base[c.row as usize] as usize;
                for slot in &slots[c.slot as usize..(c.slot + c.covered) as usize] {
                    let (a, share) = (&applied[base + slot.entry as usize], slot.share);
                    let r = offset_from(c.i_lo as i64 + slot.offset as i64, c.j as i64, c.k as i64, p);
                    let f = a.force.map(|x| -share * x);
                    let t = cross(r, f);
                    for d in 0..3 {
                        out.force[d] += f[d];
                        out.torque[d] += t[d];
                    }
                    out.liquid_mass += share * a.liquid;
                    let q = a.held.map(|x| share * x);
                    let l = cross(r, q);
                    for d in 0..3 {
                        momentum[d] += q[d];
                        angular[d] += l[d];
                    }
                }
            }
            // A sphere first seen gets the reaction and buoyancy alone for
            // this step (its interior inertia from here on).
            let (before, angular_before) = if continues { *held } else { (momentum, angular) };
            *held = (momentum, angular);
            let buoyancy = g.map(|a| -out.liquid_mass * a);
            out.surface_force = std::array::from_fn(|d| momentum[d] - before[d] + out.force[d] + buoyancy[d]);
            out.surface_torque = std::array::from_fn(|d| angular[d] - angular_before[d] + out.torque[d]);
            out.buoyancy = buoyancy.map(|f| units.force_to_si(f));
            out.force = out.force.map(|f| units.force_to_si(f));
            out.torque = out.torque.map(|t| units.torque_to_si(t));
            out.surface_force = out.surface_force.map(|f| units.force_to_si(f));
            out.surface_torque = out.surface_torque.map(|t| units.torque_to_si(t));
            out.liquid_mass *= mass_unit;
        });
        Ok(&self.results)
    }

    /// [`Coupling::apply`], one [`Fluid::step`], [`Coupling::collect`].
    pub fn step<T: Real>(&mut self, fluid: &mut Fluid<T>, spheres: &[Sphere]) -> Result<&[SphereForce], CouplingError> {
        self.apply(fluid, spheres)?;
        fluid.step();
        self.collect(fluid)
    }
}
