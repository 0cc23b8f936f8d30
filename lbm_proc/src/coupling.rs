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
//! 6. **Surface force** (what a free grain is given): the momentum the
//!    streaming brings into the covered cells, F_s = Σ_c share·w·(Σ_i f_i e_i
//!    pulled − Σ_i f*_i e_i left in the cell by the last collision). By
//!    momentum conservation this equals −ΣF_IB − m_L a + (change of the
//!    interior liquid's momentum): drag, pressure, buoyancy and the
//!    interior inertia of Kempe & Fröhlich 2012, measured instead of
//!    modelled, so nothing is lagged and the overshoot cancels exactly. At
//!    rest it is the buoyancy; in steady motion it equals `force + buoyancy`
//!    on average (tests/coupling.rs).
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
    /// Σ share·inflow, N: the momentum flux into the grain's covered cells
    /// (step 6 of the module docs). What the grain feels from the liquid.
    pub surface_force: [f64; 3],
    /// Σ (x_c − x_p) × share·inflow, N m.
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

/// One (cell, sphere) overlap.
#[derive(Debug, Clone, Copy)]
struct Overlap {
    cell: u32,
    sphere: u32,
    eps: f64,
    /// x_c − x_p, lattice units.
    r: [f64; 3],
}

/// The coupling kernel with its reused buffers.
#[derive(Debug, Clone)]
pub struct Coupling {
    units: Units,
    origin: [f64; 3],
    /// Every (cell, sphere) overlap of the step, in sphere order and, per
    /// sphere, in covering order (ascending cell but for periodic wraps).
    overlaps: Vec<Overlap>,
    /// `overlaps[sphere_start[s]..sphere_start[s + 1]]` are sphere s's.
    sphere_start: Vec<usize>,
    /// Per sphere: centre in lattice coordinates and ramp radius.
    placed: Vec<([f64; 3], f64)>,
    /// Overlaps of each chunk of spheres, reused.
    chunk_overlaps: Vec<Vec<Overlap>>,
    /// Radix-sort scratch: (cell, overlap index) keys and digit counts.
    keys: [Vec<(u32, u32)>; 2],
    counts: Vec<u32>,
    /// Per overlap (same order as `overlaps`): its forced-cell entry and its
    /// share ε_s/Σε of that cell's force.
    entry_of: Vec<u32>,
    share_of: Vec<f64>,
    /// Where each parallel grouping part starts in the sorted keys, and its
    /// first forced-cell entry.
    part_starts: Vec<usize>,
    part_entries: Vec<usize>,
    forced: Vec<ForcedCell>,
    /// Lattice-unit rigid-body velocity and angular velocity per sphere.
    motion: Vec<([f64; 3], [f64; 3])>,
    results: Vec<SphereForce>,
    /// The fluid's step count when [`Coupling::apply`] last ran.
    applied_at: Option<u64>,
    /// How partly covered cells are forced (installed in the fluid by `apply`).
    gain: ForcingGain,
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

/// Appends the cells sphere `index` covers (centre `p` in lattice
/// coordinates, ramp radius `radius`) in ascending cell order.
fn cover(index: usize, p: [f64; 3], radius: f64, dims: [usize; 3], faces: [Faces; 3], out: &mut Vec<Overlap>) {
    let reach = radius + 0.5;
    let lo: [i64; 3] = std::array::from_fn(|a| (p[a] - reach).ceil() as i64);
    let hi: [i64; 3] = std::array::from_fn(|a| (p[a] + reach).floor() as i64);
    // The cell index along one axis, wrapped on periodic axes, None outside walls.
    let wrap = |a: usize, i: i64| -> Option<usize> {
        let n = dims[a] as i64;
        match faces[a] {
            Faces::Periodic => Some(i.rem_euclid(n) as usize),
            Faces::Walls => (0..n).contains(&i).then_some(i as usize),
        }
    };
    for k in lo[2]..=hi[2] {
        let Some(kz) = wrap(2, k) else { continue };
        for j in lo[1]..=hi[1] {
            let Some(jy) = wrap(1, j) else { continue };
            for i in lo[0]..=hi[0] {
                let Some(ix) = wrap(0, i) else { continue };
                let r = [i as f64 - p[0], j as f64 - p[1], k as f64 - p[2]];
                let d = (r[0] * r[0] + r[1] * r[1] + r[2] * r[2]).sqrt() - radius;
                let eps = (0.5 - d).clamp(0.0, 1.0);
                if eps > 0.0 {
                    let cell = ((kz * dims[1] + jy) * dims[0] + ix) as u32;
                    out.push(Overlap { cell, sphere: index as u32, eps, r });
                }
            }
        }
    }
}

/// Stable LSD radix sort of the (cell, index) keys of `items` by cell, the
/// result in `keys[0]`: ~600k overlaps a step in the paper's column, where
/// a comparison sort cost more than covering the cells. 11-bit digits keep
/// the counts in L1; the overlaps themselves are not moved.
fn radix_sort_by_cell(items: &[Overlap], keys: &mut [Vec<(u32, u32)>; 2], counts: &mut Vec<u32>) {
    const BITS: u32 = 11;
    const BUCKETS: usize = 1 << BITS;
    let [a, b] = keys;
    a.clear();
    a.extend(items.iter().enumerate().map(|(k, o)| (o.cell, k as u32)));
    let max = a.iter().map(|k| k.0).max().unwrap_or(0);
    let passes = (u32::BITS - max.leading_zeros()).div_ceil(BITS).max(1);
    for pass in 0..passes {
        let shift = pass * BITS;
        counts.clear();
        counts.resize(BUCKETS + 1, 0);
        for k in a.iter() {
            counts[((k.0 >> shift) as usize & (BUCKETS - 1)) + 1] += 1;
        }
        for d in 1..=BUCKETS {
            counts[d] += counts[d - 1];
        }
        b.clear();
        b.resize(a.len(), (0, 0));
        for k in a.iter() {
            let d = (k.0 >> shift) as usize & (BUCKETS - 1);
            b[counts[d] as usize] = *k;
            counts[d] += 1;
        }
        std::mem::swap(a, b);
    }
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
            overlaps: Vec::new(),
            sphere_start: Vec::new(),
            placed: Vec::new(),
            chunk_overlaps: Vec::new(),
            keys: [Vec::new(), Vec::new()],
            counts: Vec::new(),
            entry_of: Vec::new(),
            share_of: Vec::new(),
            part_starts: Vec::new(),
            part_entries: Vec::new(),
            forced: Vec::new(),
            motion: Vec::new(),
            results: Vec::new(),
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
    pub fn apply<T: Real>(&mut self, fluid: &mut Fluid<T>, spheres: &[Sphere]) -> Result<(), CouplingError> {
        let dims = fluid.dims();
        let faces = fluid.state().faces;
        let dx = self.units.dx();
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
            // Lattice coordinates: cell i's centre sits at i.
            let p: [f64; 3] = std::array::from_fn(|a| (s.position[a] - self.origin[a]) / dx - 0.5);
            self.motion.push((
                s.velocity.map(|v| self.units.velocity_to_lattice(v)),
                s.angular_velocity.map(|w| w * self.units.dt()),
            ));
            self.placed.push((p, radius));
        }
        // Covering is independent per sphere: chunks of spheres in parallel,
        // each into its own reused buffer, concatenated in sphere order.
        // Overlaps store cell and sphere indices as u32.
        if dims.iter().product::<usize>() > u32::MAX as usize || spheres.len() > u32::MAX as usize {
            return Err(CouplingError::TooLarge);
        }
        let chunks = spheres.len().div_ceil(COVER_CHUNK);
        self.chunk_overlaps.resize_with(chunks.max(self.chunk_overlaps.len()), Vec::new);
        self.chunk_overlaps[..chunks].par_iter_mut().zip(self.placed.par_chunks(COVER_CHUNK)).enumerate().for_each(
            |(c, (buffer, placed))| {
                buffer.clear();
                for (k, &(p, radius)) in placed.iter().enumerate() {
                    cover(c * COVER_CHUNK + k, p, radius, dims, faces, buffer);
                }
            },
        );
        self.overlaps.clear();
        for buffer in &self.chunk_overlaps[..chunks] {
            self.overlaps.extend_from_slice(buffer);
        }
        if self.overlaps.len() > u32::MAX as usize {
            return Err(CouplingError::TooLarge);
        }
        self.sphere_start.clear();
        self.sphere_start.resize(spheres.len() + 1, 0);
        for o in &self.overlaps {
            self.sphere_start[o.sphere as usize + 1] += 1;
        }
        for s in 1..=spheres.len() {
            self.sphere_start[s] += self.sphere_start[s - 1];
        }
        // Spheres were covered in index order, so a stable sort by cell
        // leaves each cell's overlaps in ascending sphere order.
        radix_sort_by_cell(&self.overlaps, &mut self.keys, &mut self.counts);
        self.group_by_cell();
        self.results.clear();
        self.results.resize(spheres.len(), SphereForce::default());
        self.applied_at = None;
        fluid.set_forcing_gain(self.gain);
        fluid.set_direct_forcing_built(&self.forced);
        self.applied_at = Some(fluid.steps());
        Ok(())
    }

    /// Stage of [`Coupling::apply`]: one forced cell per run of equal cells
    /// in the sorted keys (weight min(1, Σε), target the ε-weighted mean
    /// velocity, summed in ascending sphere order), and each overlap's entry
    /// and share. Parts of the key list, split between cells, run in
    /// parallel; every entry and share is written by one part only, so the
    /// result does not depend on the thread count.
    fn group_by_cell(&mut self) {
        let sorted = &self.keys[0];
        let len = sorted.len();
        let parts = if len < 4096 { 1 } else { 4 * rayon::current_num_threads() };
        self.part_starts.clear();
        for p in 0..parts {
            let mut b = p * len / parts;
            while b > 0 && b < len && sorted[b].0 == sorted[b - 1].0 {
                b += 1;
            }
            self.part_starts.push(b.max(self.part_starts.last().copied().unwrap_or(0)));
        }
        self.part_starts.push(len);
        let starts = &self.part_starts;
        let runs = |range: std::ops::Range<usize>| {
            let keys = &sorted[range.clone()];
            let mut n = 0;
            for k in 0..keys.len() {
                if k == 0 || keys[k].0 != keys[k - 1].0 {
                    n += 1;
                }
            }
            n
        };
        self.part_entries.clear();
        self.part_entries.resize(parts, 0);
        self.part_entries.par_iter_mut().enumerate().for_each(|(p, n)| *n = runs(starts[p]..starts[p + 1]));
        let mut total = 0;
        for e in self.part_entries.iter_mut() {
            let n = *e;
            *e = total;
            total += n;
        }
        let default = ForcedCell { cell: 0, weight: 0.0, target: [0.0; 3] };
        self.forced.clear();
        self.forced.resize(total, default);
        self.entry_of.clear();
        self.entry_of.resize(self.overlaps.len(), 0);
        self.share_of.clear();
        self.share_of.resize(self.overlaps.len(), 0.0);
        let forced = SharedOut::new(&mut self.forced);
        let entry_of = SharedOut::new(&mut self.entry_of);
        let share_of = SharedOut::new(&mut self.share_of);
        let (overlaps, motion, part_entries) = (&self.overlaps, &self.motion, &self.part_entries);
        (0..parts).into_par_iter().for_each(|p| {
            let keys = &sorted[starts[p]..starts[p + 1]];
            let mut entry = part_entries[p];
            let mut start = 0;
            while start < keys.len() {
                let cell = keys[start].0;
                let end = start + keys[start..].iter().take_while(|k| k.0 == cell).count();
                let group = &keys[start..end];
                let total: f64 = group.iter().map(|k| overlaps[k.1 as usize].eps).sum();
                let mut target = [0.0; 3];
                for k in group {
                    let o = &overlaps[k.1 as usize];
                    let (v, w) = motion[o.sphere as usize];
                    let rot = cross(w, o.r);
                    for a in 0..3 {
                        target[a] += o.eps * (v[a] + rot[a]);
                    }
                    // SAFETY: overlap k.1 appears once in the keys, so only this part writes it.
                    unsafe {
                        entry_of.slice(k.1 as usize, 1)[0] = entry as u32;
                        share_of.slice(k.1 as usize, 1)[0] = o.eps / total;
                    }
                }
                let cell =
                    ForcedCell { cell: cell as usize, weight: total.min(1.0), target: target.map(|t| t / total) };
                // SAFETY: the parts' entry ranges are disjoint (prefix sums of their run counts).
                unsafe { forced.slice(entry, 1)[0] = cell };
                entry += 1;
                start = end;
            }
        });
    }

    /// The force and torque on each sphere (in the order given to
    /// [`Coupling::apply`]) from the one step that ran since.
    ///
    /// Spheres in parallel; each sums its own cells in covering order, so
    /// the result does not depend on the thread count.
    pub fn collect<T: Real>(&mut self, fluid: &Fluid<T>) -> Result<&[SphereForce], CouplingError> {
        let applied = fluid.applied_forcing();
        if self.applied_at.map(|s| s + 1) != Some(fluid.steps())
            || applied.len() != self.forced.len()
            || applied.iter().zip(&self.forced).any(|(a, f)| a.cell != f.cell)
        {
            return Err(CouplingError::Stale);
        }
        let g = fluid.params().acceleration;
        let mass_unit = self.units.rho0() * self.units.dx().powi(3);
        let units = &self.units;
        let (overlaps, starts, entry_of, share_of) =
            (&self.overlaps, &self.sphere_start, &self.entry_of, &self.share_of);
        self.results.par_iter_mut().enumerate().for_each(|(s, out)| {
            *out = SphereForce::default();
            for q in starts[s]..starts[s + 1] {
                let (o, a, share) = (&overlaps[q], &applied[entry_of[q] as usize], share_of[q]);
                let f = a.force.map(|x| -share * x);
                let t = cross(o.r, f);
                for d in 0..3 {
                    out.force[d] += f[d];
                    out.torque[d] += t[d];
                }
                out.liquid_mass += share * a.liquid;
                let inflow = a.inflow.map(|x| share * x);
                let t = cross(o.r, inflow);
                for d in 0..3 {
                    out.surface_force[d] += inflow[d];
                    out.surface_torque[d] += t[d];
                }
            }
            out.buoyancy = g.map(|a| units.force_to_si(-out.liquid_mass * a));
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

    /// The cells forced in the next step (ascending index), lattice units.
    pub fn forced_cells(&self) -> &[ForcedCell] {
        &self.forced
    }
}
