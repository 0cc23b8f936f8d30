//! The DEM state and its time step.
//!
//! [`World::step`] is built from named stages, in this order:
//! 1. `kick_and_drift`: v += ½Δt F/m, ω += ½Δt T/I, x += Δt v (velocity Verlet);
//! 2. `update_neighbours`: every `sort_interval` steps, re-sort the grain
//!    storage along the cell grid (x slowest) so that neighbours sit close in
//!    memory, and rebuild the list then; otherwise rebuild the Verlet list when
//!    any grain has moved more than half the skin since the last build;
//! 3. `compute_contact_forces`: the contact law on every touching pair. The
//!    grains are cut into [`FORCE_BLOCKS`] fixed blocks of rows; each block
//!    walks its rows in order and adds every pair's force to both grains in
//!    its own buffer (Newton's third law, one evaluation per pair), the blocks
//!    in parallel. Touching pairs are evaluated [`LANES`] at a time
//!    ([`evaluate_lanes`], bit for bit the scalar law) and added in pair order;
//! 4. `sum_and_kick`: per grain, in parallel: gravity + external load + the
//!    block sums in block order + walls, then v += ½Δt F/m, ω += ½Δt T/I.
//!
//! No stage allocates once buffers have grown (the list rebuild reuses its
//! buffers). Every floating-point sum has a fixed order that depends only on
//! the grain indices of the touching pairs, so results are bit-identical for
//! any thread count and whenever the list was rebuilt (the blocks are fixed,
//! not balanced per thread, for this reason). The re-sort happens at fixed
//! step counts and orders grains by (cell, id), so the storage order too is
//! a function of the state alone; a restart carries it in [`World::ids`].
//!
//! Storage is struct-of-arrays in f64: positions in a 0.7 m flume with
//! overlaps of ~1e-5 m need more than f32's 7 digits.

use std::ops::Range;
use std::time::Instant;

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use runtime::isa::Isa;

use crate::lanes::{self, Lanes, Lanes3, LANES};
use crate::law::{evaluate_lanes, ContactLanes, ContactLaw};
use crate::neighbours::{rebuild, CellGrid, PairList};
use crate::vec3::{add, dot, neg, norm2, scale, sub};

/// A frictional plane; grains stay on the side its normal points to.
#[derive(Debug, Clone, PartialEq)]
pub struct Wall {
    pub name: String,
    pub point: [f64; 3],
    /// Unit normal into the allowed half-space.
    pub normal: [f64; 3],
    /// Time at which the wall disappears (gates), s; infinity for fixed walls.
    pub release_time: f64,
    pub active: bool,
    /// Velocity the wall translates with, m/s; zero for the scenes' box
    /// faces and gates. A moving wall (an element test's platen) moves its
    /// point by Δt × velocity each step while active, and its contacts see
    /// that velocity. Saved DEM states keep only which walls are active:
    /// scenes cannot move walls, so a resumed run rebuilds them from the
    /// scene.
    pub velocity: [f64; 3],
}

impl Wall {
    /// A fixed wall, present until `release_time` (infinity: for good).
    pub fn fixed(name: impl Into<String>, point: [f64; 3], normal: [f64; 3], release_time: f64) -> Self {
        Wall { name: name.into(), point, normal, release_time, active: true, velocity: [0.0; 3] }
    }
}

/// Per-grain state (struct of arrays).
#[derive(Debug, Clone, Default, Serialize, Deserialize, PartialEq)]
pub struct Grains {
    pub pos: Vec<[f64; 3]>,
    pub vel: Vec<[f64; 3]>,
    pub omega: Vec<[f64; 3]>,
    /// Total force and torque of the last evaluation (Verlet needs them for the next kick).
    pub force: Vec<[f64; 3]>,
    pub torque: Vec<[f64; 3]>,
    pub radius: Vec<f64>,
    pub mass: Vec<f64>,
}

impl Grains {
    pub fn len(&self) -> usize {
        self.pos.len()
    }
    pub fn is_empty(&self) -> bool {
        self.pos.is_empty()
    }
    pub fn push(&mut self, pos: [f64; 3], vel: [f64; 3], radius: f64, density: f64) {
        self.pos.push(pos);
        self.vel.push(vel);
        self.omega.push([0.0; 3]);
        self.force.push([0.0; 3]);
        self.torque.push([0.0; 3]);
        self.radius.push(radius);
        self.mass.push(density * 4.0 / 3.0 * std::f64::consts::PI * radius.powi(3));
    }
    /// Keeps the grains for which `keep(i)` holds.
    pub fn retain(&mut self, keep: &[bool]) {
        fn f<T: Copy>(v: &mut Vec<T>, keep: &[bool]) {
            let mut k = 0;
            v.retain(|_| {
                k += 1;
                keep[k - 1]
            });
        }
        f(&mut self.pos, keep);
        f(&mut self.vel, keep);
        f(&mut self.omega, keep);
        f(&mut self.force, keep);
        f(&mut self.torque, keep);
        f(&mut self.radius, keep);
        f(&mut self.mass, keep);
    }
}

/// Contact histories in a form independent of the pair list (for states and caches).
#[derive(Debug, Clone, Default, Serialize, Deserialize, PartialEq)]
pub struct Histories {
    /// (i, j, spring) for touching grain pairs, i < j.
    pub pairs: Vec<(u32, u32, [f64; 3])>,
    /// (grain, wall, spring) for touching grain–wall contacts.
    pub walls: Vec<(u32, u32, [f64; 3])>,
}

/// Numerical settings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Numerics {
    pub dt: f64,
    /// Verlet skin, m.
    pub skin: f64,
    /// Steps between spatial re-sorts of the storage; 0 never re-sorts.
    pub sort_interval: u64,
}

/// Scratch buffers and counters, kept apart from the physical state.
#[derive(Debug, Default)]
struct Scratch {
    pairs_next: PairList,
    pos_at_build: Vec<[f64; 3]>,
    /// Per grain, a bit for each wall within reach until the next list build.
    near_walls: Vec<u32>,
    /// Bound on the distance any wall moved along its normal since the last
    /// list build, m (zero unless walls move).
    wall_travel: f64,
    inv_mass: Vec<f64>,
    inv_inertia: Vec<f64>,
    /// Per grain (radius, mass, 1/I) in one record: the pair kernel reads
    /// them for every partner, and one cache line beats three.
    pair_props: Vec<[f64; 3]>,
    blocks: [BlockSums; FORCE_BLOCKS],
    sort: SortScratch,
}

/// Buffers of the spatial re-sort (kept so that a re-sort does not allocate).
#[derive(Debug, Default)]
struct SortScratch {
    /// (cell key, grain id, old slot), sorted.
    keys: Vec<(u64, u32, u32)>,
    /// New slot of each old slot.
    new_slot: Vec<u32>,
    vec3: Vec<[f64; 3]>,
    scalar: Vec<f64>,
    count: Vec<u16>,
    /// Cumulative cost of the rows before each row, for the block balance.
    row_cost: Vec<u64>,
    /// Springs of the touching pairs under the new slots: (i, j, spring), i < j.
    springs: Vec<(u32, u32, [f64; 3])>,
}

/// Contact sums of one block of rows of the pair list.
#[derive(Debug, Default)]
struct BlockSums {
    /// Grains whose rows (pairs i < j) this block evaluates.
    rows: Range<usize>,
    /// Grains its pairs can touch: from the first row to the largest partner.
    window: Range<usize>,
    /// Sums over the block's touching pairs, indexed by grain − `window.start`.
    force: Vec<[f64; 3]>,
    torque: Vec<[f64; 3]>,
    contacts: Vec<u16>,
}

/// The external loads a world holds (per storage slot), with what its
/// next half-kick and its impulse diagnostic carry of them.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct HeldLoads {
    pub force: Vec<[f64; 3]>,
    pub torque: Vec<[f64; 3]>,
    /// Σ force inside the grains' stored forces.
    pub in_forces: [f64; 3],
    /// ∫ Σ force dt so far, N s.
    pub impulse: [f64; 3],
}

/// Everything the DEM integrates.
#[derive(Debug)]
pub struct World {
    /// Per-grain state in storage order (re-sorted in space now and then);
    /// `ids[slot]` is the grain's id, fixed from the packing on.
    pub grains: Grains,
    ids: Vec<u32>,
    /// Storage slot of each grain id.
    slot_of: Vec<u32>,
    /// First row of each force block, and the row count at the end. Part of
    /// the state: the blocks set the order of the force sums. Equal rows at
    /// the start, then balanced by listed pairs at each re-sort.
    block_starts: [u32; FORCE_BLOCKS + 1],
    pub walls: Vec<Wall>,
    /// Tangential springs grain × wall, index `grain * walls.len() + wall`.
    pub wall_springs: Vec<[f64; 3]>,
    pub pairs: PairList,
    /// Grain–grain contacts of each grain at the last evaluation.
    pub coordination: Vec<u16>,
    pub grain_law: ContactLaw,
    pub wall_law: ContactLaw,
    pub gravity: [f64; 3],
    /// External force per grain slot (hydrodynamic load when coupled), N;
    /// held over steps. Set through [`World::set_external_load`]; a world
    /// that never had one does not read them (48 bytes per grain per step).
    external_force: Vec<[f64; 3]>,
    external_torque: Vec<[f64; 3]>,
    has_external_load: bool,
    /// Σ of `external_force` over the grains, N; `None` after a load
    /// changed until the next step sums it again.
    external_total: Option<[f64; 3]>,
    /// The Σ external force inside the grains' stored forces (the last
    /// force sum), which the next step's first half-kick uses.
    external_in_forces: [f64; 3],
    /// ∫ Σ external force dt since this world was made, N s: the momentum
    /// the liquid gave the grains. A diagnostic, not part of the state (a
    /// resumed run counts from its resume).
    pub external_impulse: [f64; 3],
    pub numerics: Numerics,
    pub time: f64,
    pub step_count: u64,
    pub neighbour_builds: u64,
    pub sorts: u64,
    /// Wall seconds spent in each stage since creation.
    pub stage_seconds: StageSeconds,
    grid: CellGrid,
    scratch: Scratch,
    /// Instruction set of the pair kernel (results do not depend on it).
    isa: Isa,
}

/// Wall time per stage of [`World::step`], s.
#[derive(Debug, Clone, Copy, Default, Serialize, Deserialize, PartialEq)]
pub struct StageSeconds {
    pub kick_and_drift: f64,
    pub update_neighbours: f64,
    pub compute_contact_forces: f64,
    pub sum_and_kick: f64,
}

/// Walls (box faces and gates) a world can hold: one bit each in a `u32`.
pub const MAX_WALLS: usize = 32;

/// Number of grains per parallel task (amortises rayon's per-task cost).
const GRAIN_CHUNK: usize = 256;

/// Fixed blocks of pair-list rows evaluated in parallel. More blocks allow
/// more threads but add per-grain sums; the count is part of the summation
/// order, so changing it changes results in the last bits.
pub const FORCE_BLOCKS: usize = 8;

/// Cost of evaluating a touching pair in units of skipping a listed pair
/// that is apart (the contact law against one distance test). Measured on
/// the lab column (dem_proc bench, 2 threads): 3 gave 4.58 s per 10 000
/// steps, 6 gave 4.49–4.52 s, 8 gave 4.55–4.59 s, 0 (listed pairs only) 4.97 s.
const TOUCHING_PAIR_COST: u64 = 6;

impl World {
    pub fn new(
        grains: Grains,
        walls: Vec<Wall>,
        grain_law: ContactLaw,
        wall_law: ContactLaw,
        gravity: [f64; 3],
        numerics: Numerics,
        domain: ([f64; 3], [f64; 3]),
    ) -> Self {
        assert!(walls.len() <= MAX_WALLS, "at most {MAX_WALLS} walls, got {}", walls.len());
        let n = grains.len();
        let r_max = grains.radius.iter().cloned().fold(0.0, f64::max);
        let grid = CellGrid::new(domain.0, domain.1, (2.0 * r_max + numerics.skin).max(1e-12));
        let nw = walls.len();
        let mut w = World {
            grains,
            ids: (0..n as u32).collect(),
            slot_of: (0..n as u32).collect(),
            block_starts: std::array::from_fn(|b| (b * n / FORCE_BLOCKS) as u32),
            walls,
            wall_springs: vec![[0.0; 3]; n * nw.max(1)],
            pairs: PairList::default(),
            coordination: vec![0; n],
            grain_law,
            wall_law,
            gravity,
            external_force: vec![[0.0; 3]; n],
            external_torque: vec![[0.0; 3]; n],
            has_external_load: false,
            external_total: None,
            external_in_forces: [0.0; 3],
            external_impulse: [0.0; 3],
            numerics,
            time: 0.0,
            step_count: 0,
            neighbour_builds: 0,
            sorts: 0,
            stage_seconds: StageSeconds::default(),
            grid,
            scratch: Scratch::default(),
            isa: Isa::current(),
        };
        w.refresh_inverse_properties();
        w.build_neighbours();
        w.balance_blocks();
        w
    }

    fn refresh_inverse_properties(&mut self) {
        let g = &self.grains;
        self.scratch.inv_mass = g.mass.iter().map(|m| 1.0 / m).collect();
        self.scratch.inv_inertia = g.mass.iter().zip(&g.radius).map(|(m, r)| 1.0 / (0.4 * m * r * r)).collect();
        self.scratch.pair_props = (0..g.len()).map(|p| [g.radius[p], g.mass[p], self.scratch.inv_inertia[p]]).collect();
    }

    pub fn len(&self) -> usize {
        self.grains.len()
    }
    pub fn is_empty(&self) -> bool {
        self.grains.is_empty()
    }

    /// Holds `force` (N) and `torque` (N m) on the grain in `slot` until changed.
    pub fn set_external_load(&mut self, slot: usize, force: [f64; 3], torque: [f64; 3]) {
        self.external_force[slot] = force;
        self.external_torque[slot] = torque;
        self.has_external_load = true;
        self.external_total = None;
    }

    /// The external loads held now, for a checkpoint (None: never set).
    pub fn held_loads(&self) -> Option<HeldLoads> {
        self.has_external_load.then(|| HeldLoads {
            force: self.external_force.clone(),
            torque: self.external_torque.clone(),
            in_forces: self.external_in_forces,
            impulse: self.external_impulse,
        })
    }

    /// Holds the loads of a checkpoint, as the world that wrote it held them.
    pub fn set_held_loads(&mut self, held: &HeldLoads) {
        self.external_force.clone_from(&held.force);
        self.external_torque.clone_from(&held.torque);
        self.has_external_load = true;
        self.external_total = None;
        self.external_in_forces = held.in_forces;
        self.external_impulse = held.impulse;
    }

    /// Σ over the grains of the external force held now, N (zero if none).
    pub fn external_force_total(&self) -> [f64; 3] {
        self.external_total.unwrap_or_else(|| {
            self.external_force.iter().fold([0.0; 3], |a, f| [a[0] + f[0], a[1] + f[1], a[2] + f[2]])
        })
    }

    /// Σ m v over the grains, kg m/s.
    pub fn momentum(&self) -> [f64; 3] {
        let g = &self.grains;
        (0..g.len()).fold([0.0; 3], |a, p| [0, 1, 2].map(|k| a[k] + g.mass[p] * g.vel[p][k]))
    }

    /// Chooses the pair kernel's instruction set (for tests and benchmarks:
    /// results are the same on each). Pre: the CPU has it.
    pub fn set_isa(&mut self, isa: Isa) {
        assert!(isa <= Isa::best_supported(), "this CPU lacks {}", isa.name());
        self.isa = isa;
    }

    /// Grain id of each storage slot.
    pub fn ids(&self) -> &[u32] {
        &self.ids
    }

    /// Storage slot of grain `id`.
    #[inline]
    pub fn slot(&self, id: usize) -> usize {
        self.slot_of[id] as usize
    }

    /// Takes the storage order of a saved state: `ids[slot]` is the id of the
    /// grain in `slot`. Pre: a permutation of 0..len. Rebuilds the lists.
    pub fn set_ids(&mut self, ids: &[u32]) -> Result<(), String> {
        let n = self.len();
        let mut slot_of = vec![u32::MAX; n];
        if ids.len() != n {
            return Err(format!("{} grain ids for {n} grains", ids.len()));
        }
        for (slot, &id) in ids.iter().enumerate() {
            match slot_of.get_mut(id as usize) {
                Some(s) if *s == u32::MAX => *s = slot as u32,
                _ => return Err(format!("grain ids are not a permutation of 0..{n} (id {id} at slot {slot})")),
            }
        }
        self.ids.clear();
        self.ids.extend_from_slice(ids);
        self.slot_of = slot_of;
        Ok(())
    }

    /// Restores contact histories (from a state or cache) into the current lists.
    pub fn set_histories(&mut self, h: &Histories) {
        self.build_neighbours();
        for s in self.pairs.spring.iter_mut() {
            *s = [0.0; 3];
        }
        let n = self.len();
        for &(i, j, s) in &h.pairs {
            if i >= j || j as usize >= n {
                continue; // not a pair of this world (foreign cache or state)
            }
            if let Some(k) = self.pairs.find(i as usize, j as usize) {
                self.pairs.spring[k] = s;
            }
        }
        self.wall_springs.iter_mut().for_each(|s| *s = [0.0; 3]);
        let nw = self.walls.len();
        for &(p, w, s) in &h.walls {
            if (w as usize) < nw && (p as usize) < self.len() {
                self.wall_springs[p as usize * nw + w as usize] = s;
            }
        }
    }

    /// Histories of the contacts touching now.
    pub fn histories(&self) -> Histories {
        let pairs = (0..self.pairs.len())
            .filter(|&k| self.pairs.spring[k] != [0.0; 3] || self.pairs.touching[k])
            .map(|k| (self.pairs.i[k], self.pairs.j[k], self.pairs.spring[k]))
            .collect();
        let nw = self.walls.len();
        let walls = self
            .wall_springs
            .iter()
            .enumerate()
            .filter(|(_, s)| **s != [0.0; 3])
            .map(|(k, s)| ((k / nw.max(1)) as u32, (k % nw.max(1)) as u32, *s))
            .collect();
        Histories { pairs, walls }
    }

    /// Advances by one time step.
    pub fn step(&mut self) {
        let t0 = Instant::now();
        self.release_gates();
        let max_move = self.kick_and_drift();
        self.move_walls();
        let t1 = Instant::now();
        let interval = self.numerics.sort_interval;
        let skin = self.numerics.skin;
        if interval > 0 && self.step_count > 0 && self.step_count.is_multiple_of(interval) {
            self.sort_in_space();
            self.build_neighbours();
            self.balance_blocks();
        } else if 2.0 * max_move > skin || max_move + self.scratch.wall_travel > skin {
            // Pairs: two grains close by at most 2 × max_move. A wall left out
            // of a grain's near walls was farther than radius + skin, and
            // the gap closes by at most max_move + the wall's travel.
            self.build_neighbours();
        }
        let t2 = Instant::now();
        self.compute_contact_forces();
        let t3 = Instant::now();
        self.sum_and_kick();
        let t4 = Instant::now();
        let st = &mut self.stage_seconds;
        st.kick_and_drift += (t1 - t0).as_secs_f64();
        st.update_neighbours += (t2 - t1).as_secs_f64();
        st.compute_contact_forces += (t3 - t2).as_secs_f64();
        st.sum_and_kick += (t4 - t3).as_secs_f64();
        if self.has_external_load {
            // Velocity Verlet kicks half a step with the force of the last
            // sum and half with this one's: a load set between steps counts
            // half its old and half its new value, as the velocities do.
            let total = self.external_force_total();
            self.external_total = Some(total);
            let half = 0.5 * self.numerics.dt;
            let before = self.external_in_forces;
            self.external_impulse = [0, 1, 2].map(|k| self.external_impulse[k] + half * (before[k] + total[k]));
            self.external_in_forces = total;
        }
        self.time += self.numerics.dt;
        self.step_count += 1;
    }

    /// Computes forces for the current positions without moving anything
    /// (needed once before the first step, since Verlet's first kick uses them).
    pub fn prime_forces(&mut self) {
        self.build_neighbours();
        let dt = self.numerics.dt;
        self.numerics.dt = 0.0;
        self.compute_contact_forces();
        self.sum_forces_only();
        self.numerics.dt = dt;
        self.external_in_forces = if self.has_external_load { self.external_force_total() } else { [0.0; 3] };
    }

    fn release_gates(&mut self) {
        let nw = self.walls.len();
        for (w, wall) in self.walls.iter_mut().enumerate() {
            if wall.active && self.time >= wall.release_time {
                wall.active = false;
                for p in 0..self.grains.len() {
                    self.wall_springs[p * nw + w] = [0.0; 3];
                }
            }
        }
    }

    /// Part of stage 1: moving walls translate by Δt × velocity. The travel
    /// kept for the list rebuild adds the fastest wall's step each step, a
    /// bound on every wall's travel.
    fn move_walls(&mut self) {
        let dt = self.numerics.dt;
        let mut fastest = 0.0_f64;
        for wall in self.walls.iter_mut().filter(|w| w.active && w.velocity != [0.0; 3]) {
            wall.point = [0, 1, 2].map(|a| wall.point[a] + dt * wall.velocity[a]);
            fastest = fastest.max((dt * dot(wall.velocity, wall.normal)).abs());
        }
        self.scratch.wall_travel += fastest;
    }

    /// Stage 1. Returns the largest displacement since the last list build.
    fn kick_and_drift(&mut self) -> f64 {
        let dt = self.numerics.dt;
        let half = 0.5 * dt;
        let g = &mut self.grains;
        let inv_m = &self.scratch.inv_mass;
        let inv_i = &self.scratch.inv_inertia;
        let built = &self.scratch.pos_at_build;
        let max2 = g
            .pos
            .par_chunks_mut(GRAIN_CHUNK)
            .zip(g.vel.par_chunks_mut(GRAIN_CHUNK))
            .zip(g.omega.par_chunks_mut(GRAIN_CHUNK))
            .enumerate()
            .map(|(c, ((pos, vel), omega))| {
                let base = c * GRAIN_CHUNK;
                let mut max2 = 0.0_f64;
                for k in 0..pos.len() {
                    let p = base + k;
                    let (f, t) = (&g.force[p], &g.torque[p]);
                    for a in 0..3 {
                        vel[k][a] += half * f[a] * inv_m[p];
                        omega[k][a] += half * t[a] * inv_i[p];
                        pos[k][a] += dt * vel[k][a];
                    }
                    let d = [pos[k][0] - built[p][0], pos[k][1] - built[p][1], pos[k][2] - built[p][2]];
                    max2 = max2.max(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
                }
                max2
            })
            .reduce(|| 0.0, f64::max);
        max2.sqrt()
    }

    /// Part of stage 2: reorders every per-grain array by (cell, id), cells
    /// walked with x slowest (the flume's long axis), then z, then y, so that
    /// a grain's partners and each force block's window are close in memory.
    /// Post: the pair list holds the touching pairs' springs under the new
    /// slots (a list build must follow); ids and slots are permuted alike.
    fn sort_in_space(&mut self) {
        let n = self.len();
        let sc = &mut self.scratch.sort;
        sc.keys.clear();
        sc.keys.extend((0..n).map(|slot| (self.grid.sort_key(&self.grains.pos[slot]), self.ids[slot], slot as u32)));
        sc.keys.sort_unstable();
        sc.new_slot.clear();
        sc.new_slot.resize(n, 0);
        for (new, &(_, _, old)) in sc.keys.iter().enumerate() {
            sc.new_slot[old as usize] = new as u32;
        }
        let order = &sc.keys;
        fn permute<T: Copy>(v: &mut Vec<T>, order: &[(u64, u32, u32)], tmp: &mut Vec<T>) {
            tmp.clear();
            tmp.extend(order.iter().map(|&(_, _, old)| v[old as usize]));
            std::mem::swap(v, tmp);
        }
        let g = &mut self.grains;
        for v in [
            &mut g.pos,
            &mut g.vel,
            &mut g.omega,
            &mut g.force,
            &mut g.torque,
            &mut self.external_force,
            &mut self.external_torque,
        ] {
            permute(v, order, &mut sc.vec3);
        }
        permute(&mut self.scratch.pair_props, order, &mut sc.vec3);
        for v in [&mut g.radius, &mut g.mass, &mut self.scratch.inv_mass, &mut self.scratch.inv_inertia] {
            permute(v, order, &mut sc.scalar);
        }
        permute(&mut self.coordination, order, &mut sc.count);
        let nw = self.walls.len().max(1);
        sc.vec3.clear();
        for &(_, _, old) in order.iter() {
            sc.vec3.extend_from_slice(&self.wall_springs[old as usize * nw..(old as usize + 1) * nw]);
        }
        std::mem::swap(&mut self.wall_springs, &mut sc.vec3);
        for (slot, &(_, id, _)) in order.iter().enumerate() {
            self.ids[slot] = id;
            self.slot_of[id as usize] = slot as u32;
        }
        // The springs of touching pairs under the new slots, as a fresh list
        // without candidates: the build that follows carries them over.
        let pl = &self.pairs;
        sc.springs.clear();
        sc.springs.extend((0..pl.len()).filter(|&k| pl.spring[k] != [0.0; 3] || pl.touching[k]).map(|k| {
            let (a, b) = (sc.new_slot[pl.i[k] as usize], sc.new_slot[pl.j[k] as usize]);
            // The spring is the tangential displacement of i relative to j:
            // a pair whose order flips gets the opposite spring.
            if a < b {
                (a, b, pl.spring[k])
            } else {
                (b, a, neg(pl.spring[k]))
            }
        }));
        sc.springs.sort_unstable_by_key(|&(i, j, _)| (i, j));
        let pl = &mut self.pairs;
        pl.row_start.clear();
        pl.i.clear();
        pl.j.clear();
        pl.spring.clear();
        pl.touching.clear();
        pl.row_start.push(0);
        let mut k = 0;
        for row in 0..n as u32 {
            while k < sc.springs.len() && sc.springs[k].0 == row {
                let (i, j, s) = sc.springs[k];
                pl.i.push(i);
                pl.j.push(j);
                pl.spring.push(s);
                pl.touching.push(true);
                k += 1;
            }
            pl.row_start.push(pl.j.len() as u32);
        }
        self.sorts += 1;
    }

    /// Stage 2.
    pub fn build_neighbours(&mut self) {
        rebuild(
            &mut self.grid,
            &self.grains.pos,
            &self.grains.radius,
            self.numerics.skin,
            &self.pairs,
            &mut self.scratch.pairs_next,
        );
        std::mem::swap(&mut self.pairs, &mut self.scratch.pairs_next);
        self.scratch.pos_at_build.clear();
        self.scratch.pos_at_build.extend_from_slice(&self.grains.pos);
        // Grains move less than half the skin before the next build, so a wall
        // farther than radius + skin cannot be reached before then.
        let skin = self.numerics.skin;
        let walls = &self.walls;
        let g = &self.grains;
        self.scratch.wall_travel = 0.0;
        self.scratch.near_walls.clear();
        self.scratch.near_walls.extend((0..g.len()).map(|p| {
            walls.iter().enumerate().fold(0u32, |mask, (w, wall)| {
                let gap = dot(sub(g.pos[p], wall.point), wall.normal);
                if wall.active && gap < g.radius[p] + skin {
                    mask | (1 << w)
                } else {
                    mask
                }
            })
        }));
        self.assign_blocks();
        self.neighbour_builds += 1;
    }

    /// First row of each force block (and the row count), as saved in a state.
    pub fn block_starts(&self) -> &[u32] {
        &self.block_starts
    }

    /// Takes the force blocks of a saved state. Pre: starts at 0, ends at
    /// the grain count, non-decreasing.
    pub fn set_block_starts(&mut self, starts: &[u32]) -> Result<(), String> {
        let ok = starts.len() == FORCE_BLOCKS + 1
            && starts[0] == 0
            && starts[FORCE_BLOCKS] as usize == self.len()
            && starts.windows(2).all(|w| w[0] <= w[1]);
        if !ok {
            return Err(format!(
                "force blocks {starts:?} do not cut 0..{} into {FORCE_BLOCKS} ordered parts",
                self.len()
            ));
        }
        self.block_starts.copy_from_slice(starts);
        self.assign_blocks();
        Ok(())
    }

    /// Part of stage 2, after a re-sort's list build: moves the block
    /// boundaries so that each block costs about the same, a cost of one
    /// per row, one per listed pair and [`TOUCHING_PAIR_COST`] more per
    /// pair touching now. Equal rows put 2680 listed pairs in the last block
    /// of the lab column against 4287 in the first (a half list has no
    /// partners past the last row; the spreading front is sparse); equal
    /// listed pairs still left the first block (the dense back of the
    /// column, where every listed pair touches) 2.3× as long as the last,
    /// and one thread idle for a quarter of the contact stage.
    /// Deterministic: it reads only the state.
    fn balance_blocks(&mut self) {
        let n = self.len();
        let (pl, g) = (&self.pairs, &self.grains);
        let cumulative = &mut self.scratch.sort.row_cost;
        cumulative.clear();
        cumulative.push(0u64);
        for i in 0..n {
            let pairs = pl.row_start[i] as usize..pl.row_start[i + 1] as usize;
            let touching = pairs
                .clone()
                .filter(|&k| {
                    let j = pl.j[k] as usize;
                    let reach = g.radius[i] + g.radius[j];
                    norm2(sub(g.pos[j], g.pos[i])) < reach * reach
                })
                .count() as u64;
            cumulative.push(cumulative[i] + 1 + pairs.len() as u64 + TOUCHING_PAIR_COST * touching);
        }
        let cumulative = &self.scratch.sort.row_cost;
        let cost = |row: usize| cumulative[row];
        let total = cost(n);
        let mut row = 0;
        for b in 1..FORCE_BLOCKS {
            let target = total * b as u64 / FORCE_BLOCKS as u64;
            while row < n && cost(row) < target {
                row += 1;
            }
            self.block_starts[b] = row as u32;
        }
        self.block_starts[FORCE_BLOCKS] = n as u32;
        self.assign_blocks();
    }

    /// Cuts the rows into the blocks and sizes each block's window.
    fn assign_blocks(&mut self) {
        let pl = &self.pairs;
        let starts = self.block_starts;
        for (b, block) in self.scratch.blocks.iter_mut().enumerate() {
            block.rows = starts[b] as usize..starts[b + 1] as usize;
            // Rows are sorted, so each row's last partner is its largest.
            let reach = block
                .rows
                .clone()
                .filter(|&i| pl.row_start[i + 1] > pl.row_start[i])
                .map(|i| pl.j[pl.row_start[i + 1] as usize - 1] as usize + 1)
                .max()
                .unwrap_or(0);
            block.window = block.rows.start..reach.max(block.rows.end);
            let len = block.window.len();
            block.force.resize(len, [0.0; 3]);
            block.torque.resize(len, [0.0; 3]);
            block.contacts.resize(len, 0);
        }
    }

    /// Stage 3. Pre: the pair list covers every pair within reach.
    /// Post: each block's buffers hold the sums of its touching pairs, in row order.
    fn compute_contact_forces(&mut self) {
        let g = &self.grains;
        let pl = &mut self.pairs;
        let kernel = PairKernel {
            law: self.grain_law,
            dt: self.numerics.dt,
            pos: &g.pos,
            vel: &g.vel,
            omega: &g.omega,
            props: &self.scratch.pair_props,
            row_start: &pl.row_start,
            partner: &pl.j,
        };
        let row_start = &pl.row_start;
        // Each block owns the contiguous pair range of its rows.
        let mut parts: [(&mut [[f64; 3]], &mut [bool]); FORCE_BLOCKS] = Default::default();
        let (mut springs, mut touchings) = (pl.spring.as_mut_slice(), pl.touching.as_mut_slice());
        for (part, block) in parts.iter_mut().zip(&self.scratch.blocks) {
            let len = (row_start[block.rows.end] - row_start[block.rows.start]) as usize;
            let (s, s_rest) = std::mem::take(&mut springs).split_at_mut(len);
            let (t, t_rest) = std::mem::take(&mut touchings).split_at_mut(len);
            *part = (s, t);
            (springs, touchings) = (s_rest, t_rest);
        }
        let isa = self.isa;
        self.scratch.blocks.par_iter_mut().zip(parts).for_each(|(block, (spring, touching))| match isa {
            #[cfg(target_arch = "x86_64")]
            // SAFETY: `isa` is AVX2 only where the CPU has AVX2 and FMA (`Isa::best_supported`).
            Isa::Avx2 => unsafe { kernel.block_avx2(block, spring, touching) },
            _ => kernel.block(block, spring, touching),
        });
    }

    /// Stage 4 without the kick (for `prime_forces`).
    fn sum_forces_only(&mut self) {
        self.sum(false);
    }

    /// Stage 4. Pre: block sums of the current positions.
    /// Post: total force and torque per grain, velocities at the full step.
    fn sum_and_kick(&mut self) {
        self.sum(true);
    }

    fn sum(&mut self, kick: bool) {
        let nw = self.walls.len();
        let g = &mut self.grains;
        let kernel = GrainSumKernel {
            wall_law: self.wall_law,
            dt: self.numerics.dt,
            kick,
            gravity: self.gravity,
            walls: &self.walls,
            blocks: &self.scratch.blocks,
            inv_mass: &self.scratch.inv_mass,
            inv_inertia: &self.scratch.inv_inertia,
            external: self.has_external_load.then_some((&self.external_force[..], &self.external_torque[..])),
            near_walls: &self.scratch.near_walls,
            pos: &g.pos,
            radius: &g.radius,
            mass: &g.mass,
        };
        let isa = self.isa;
        g.force
            .par_chunks_mut(GRAIN_CHUNK)
            .zip(g.torque.par_chunks_mut(GRAIN_CHUNK))
            .zip(g.vel.par_chunks_mut(GRAIN_CHUNK))
            .zip(g.omega.par_chunks_mut(GRAIN_CHUNK))
            .zip(self.coordination.par_chunks_mut(GRAIN_CHUNK))
            .zip(self.wall_springs.par_chunks_mut(GRAIN_CHUNK * nw.max(1)))
            .enumerate()
            .for_each(|(c, (((((force, torque), vel), omega), contacts), wall_springs))| {
                let chunk = GrainChunk { first: c * GRAIN_CHUNK, force, torque, vel, omega, contacts, wall_springs };
                match isa {
                    #[cfg(target_arch = "x86_64")]
                    // SAFETY: `isa` is AVX2 only where the CPU has AVX2 and FMA (`Isa::best_supported`).
                    Isa::Avx2 => unsafe { kernel.chunk_avx2(chunk) },
                    _ => kernel.chunk(chunk),
                }
            });
    }

    /// Translational and rotational kinetic energy, J (serial: fixed summation order).
    pub fn kinetic_energy(&self) -> f64 {
        let g = &self.grains;
        (0..g.len())
            .map(|p| {
                let v2 = norm2(g.vel[p]);
                let w2 = norm2(g.omega[p]);
                0.5 * g.mass[p] * v2 + 0.5 * 0.4 * g.mass[p] * g.radius[p] * g.radius[p] * w2
            })
            .sum()
    }

    /// Gravitational potential energy relative to the origin, J.
    pub fn potential_energy(&self) -> f64 {
        let g = &self.grains;
        (0..g.len()).map(|p| -g.mass[p] * dot(self.gravity, g.pos[p])).sum()
    }

    /// Energy stored in normal and tangential springs, J.
    pub fn elastic_energy(&self) -> f64 {
        let g = &self.grains;
        let (kn, kt) = (self.grain_law.normal_stiffness, self.grain_law.tangential_stiffness);
        let mut e = 0.0;
        for k in 0..self.pairs.len() {
            let (i, j) = (self.pairs.i[k] as usize, self.pairs.j[k] as usize);
            let overlap = g.radius[i] + g.radius[j] - norm2(sub(g.pos[j], g.pos[i])).sqrt();
            if overlap > 0.0 {
                e += 0.5 * kn * overlap * overlap + 0.5 * kt * norm2(self.pairs.spring[k]);
            }
        }
        let nw = self.walls.len();
        let (kn, kt) = (self.wall_law.normal_stiffness, self.wall_law.tangential_stiffness);
        for p in 0..g.len() {
            for (w, wall) in self.walls.iter().enumerate().filter(|(_, w)| w.active) {
                let gap = dot(sub(g.pos[p], wall.point), wall.normal);
                let overlap = g.radius[p] - gap;
                if overlap > 0.0 {
                    e += 0.5 * kn * overlap * overlap + 0.5 * kt * norm2(self.wall_springs[p * nw + w]);
                }
            }
        }
        e
    }

    /// Each wall's elastic normal load k_n δ summed over its grains, N, and
    /// the number of grains touching it. The dashpot's share is left out: it
    /// follows the grains' speeds against the wall, which an element test
    /// keeps small, and it averages out at rest.
    pub fn wall_loads(&self) -> Vec<(f64, usize)> {
        let g = &self.grains;
        let kn = self.wall_law.normal_stiffness;
        self.walls
            .iter()
            .map(|wall| {
                if !wall.active {
                    return (0.0, 0);
                }
                (0..g.len()).fold((0.0, 0), |(load, touching), p| {
                    let overlap = g.radius[p] - dot(sub(g.pos[p], wall.point), wall.normal);
                    if overlap > 0.0 {
                        (load + kn * overlap, touching + 1)
                    } else {
                        (load, touching)
                    }
                })
            })
            .collect()
    }

    /// Largest grain speed, m/s.
    pub fn max_speed(&self) -> f64 {
        self.grains.vel.iter().map(|v| norm2(*v).sqrt()).fold(0.0, f64::max)
    }

    /// Mean number of grain–grain contacts per grain.
    pub fn mean_coordination(&self) -> f64 {
        if self.is_empty() {
            return 0.0;
        }
        self.coordination.iter().map(|&c| c as f64).sum::<f64>() / self.len() as f64
    }
}

/// What the pair kernel (stage 3) reads: the grains and the pair list.
struct PairKernel<'a> {
    law: ContactLaw,
    dt: f64,
    pos: &'a [[f64; 3]],
    vel: &'a [[f64; 3]],
    omega: &'a [[f64; 3]],
    /// (radius, mass, 1/I) per grain.
    props: &'a [[f64; 3]],
    row_start: &'a [u32],
    partner: &'a [u32],
}

/// Touching pairs waiting for [`evaluate_lanes`]: the raw inputs of up to
/// [`LANES`] contacts and where their results go.
struct PairBatch {
    len: usize,
    /// Pair index within the block, and both grains' places in its window.
    pair: [usize; LANES],
    window_i: [usize; LANES],
    window_j: [usize; LANES],
    /// x_j − x_i and its squared length.
    d: Lanes3,
    dist2: Lanes,
    radius_i: Lanes,
    radius_j: Lanes,
    mass_i: Lanes,
    mass_j: Lanes,
    inv_inertia_i: Lanes,
    inv_inertia_j: Lanes,
    vel_i: Lanes3,
    omega_i: Lanes3,
    vel_j: Lanes3,
    omega_j: Lanes3,
    spring: Lanes3,
}

impl PairBatch {
    /// Empty, its unused lanes holding a harmless contact (unit grains
    /// overlapping by 1 at rest), so that a part-full batch computes nothing
    /// but finite numbers in them.
    fn new() -> Self {
        let (zero, one) = (Lanes::splat(0.0), Lanes::splat(1.0));
        PairBatch {
            len: 0,
            pair: [0; LANES],
            window_i: [0; LANES],
            window_j: [0; LANES],
            d: [one, zero, zero],
            dist2: one,
            radius_i: one,
            radius_j: one,
            mass_i: one,
            mass_j: one,
            inv_inertia_i: one,
            inv_inertia_j: one,
            vel_i: [zero; 3],
            omega_i: [zero; 3],
            vel_j: [zero; 3],
            omega_j: [zero; 3],
            spring: [zero; 3],
        }
    }

    /// The contacts' geometry, lane by lane as the scalar kernel did it.
    #[inline(always)]
    fn inputs(&self) -> ContactLanes {
        let (half, one, four) = (Lanes::splat(0.5), Lanes::splat(1.0), Lanes::splat(4.0));
        let (ri, rj, mi, mj) = (self.radius_i, self.radius_j, self.mass_i, self.mass_j);
        let reach = ri + rj;
        let dist = self.dist2.sqrt();
        let overlap = reach - dist;
        ContactLanes {
            n: lanes::scale(self.d, one / dist),
            overlap,
            arm_i: ri - half * overlap,
            arm_j: rj - half * overlap,
            vel_i: self.vel_i,
            omega_i: self.omega_i,
            vel_j: self.vel_j,
            omega_j: self.omega_j,
            effective_mass: mi * mj / (mi + mj),
            inv_inertia_sum: self.inv_inertia_i + self.inv_inertia_j,
            rolling_diameter: four * ri * rj / (ri + rj),
        }
    }
}

impl PairKernel<'_> {
    /// One block's pairs (see [`World::compute_contact_forces`]).
    fn block(&self, block: &mut BlockSums, spring: &mut [[f64; 3]], touching: &mut [bool]) {
        self.block_body(block, spring, touching)
    }

    /// [`PairKernel::block`] built for AVX2 (same results, bit for bit).
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    unsafe fn block_avx2(&self, block: &mut BlockSums, spring: &mut [[f64; 3]], touching: &mut [bool]) {
        self.block_body(block, spring, touching)
    }

    /// Walks the block's rows in order; touching pairs are evaluated
    /// [`LANES`] at a time and their forces added in pair order, so the
    /// sums are those of one pair at a time.
    #[inline(always)]
    fn block_body(&self, block: &mut BlockSums, spring: &mut [[f64; 3]], touching: &mut [bool]) {
        block.force.iter_mut().for_each(|f| *f = [0.0; 3]);
        block.torque.iter_mut().for_each(|t| *t = [0.0; 3]);
        block.contacts.iter_mut().for_each(|c| *c = 0);
        let w0 = block.window.start;
        let first_pair = self.row_start[block.rows.start] as usize;
        let mut batch = PairBatch::new();
        for i in block.rows.clone() {
            let (pos_i, [ri, mi, inv_ii]) = (self.pos[i], self.props[i]);
            for k in self.row_start[i] as usize..self.row_start[i + 1] as usize {
                let j = self.partner[k] as usize;
                let local = k - first_pair;
                let d = sub(self.pos[j], pos_i);
                let [rj, mj, inv_ij] = self.props[j];
                let dist2 = norm2(d);
                let reach = ri + rj;
                if dist2 >= reach * reach {
                    // Writes only when needed: most candidates stay apart for many steps.
                    if touching[local] {
                        spring[local] = [0.0; 3];
                        touching[local] = false;
                    }
                    continue;
                }
                let l = batch.len;
                batch.pair[l] = local;
                batch.window_i[l] = i - w0;
                batch.window_j[l] = j - w0;
                lanes::set_lane(&mut batch.d, l, d);
                batch.dist2.0[l] = dist2;
                batch.radius_i.0[l] = ri;
                batch.radius_j.0[l] = rj;
                batch.mass_i.0[l] = mi;
                batch.mass_j.0[l] = mj;
                batch.inv_inertia_i.0[l] = inv_ii;
                batch.inv_inertia_j.0[l] = inv_ij;
                lanes::set_lane(&mut batch.vel_i, l, self.vel[i]);
                lanes::set_lane(&mut batch.omega_i, l, self.omega[i]);
                lanes::set_lane(&mut batch.vel_j, l, self.vel[j]);
                lanes::set_lane(&mut batch.omega_j, l, self.omega[j]);
                lanes::set_lane(&mut batch.spring, l, spring[local]);
                batch.len += 1;
                if batch.len == LANES {
                    self.flush(&mut batch, block, spring, touching);
                }
            }
        }
        self.flush(&mut batch, block, spring, touching);
    }

    /// Evaluates the batch and adds its forces, lane (pair) order.
    #[inline(always)]
    fn flush(&self, batch: &mut PairBatch, block: &mut BlockSums, spring: &mut [[f64; 3]], touching: &mut [bool]) {
        if batch.len == 0 {
            return;
        }
        let input = batch.inputs();
        let out = evaluate_lanes(&self.law, &input, self.dt, &mut batch.spring);
        for l in 0..batch.len {
            let (local, qi, qj) = (batch.pair[l], batch.window_i[l], batch.window_j[l]);
            spring[local] = lanes::lane(&batch.spring, l);
            touching[local] = true;
            let force_i = lanes::lane(&out.force_i, l);
            block.force[qi] = add(block.force[qi], force_i);
            block.force[qj] = sub(block.force[qj], force_i);
            block.torque[qi] = add(block.torque[qi], lanes::lane(&out.torque_i, l));
            block.torque[qj] = add(block.torque[qj], lanes::lane(&out.torque_j, l));
            block.contacts[qi] += 1;
            block.contacts[qj] += 1;
        }
        batch.len = 0;
    }
}

/// Force and torque per grain slot.
type ExternalLoads<'a> = (&'a [[f64; 3]], &'a [[f64; 3]]);

/// What the per-grain sum (stage 4) reads.
struct GrainSumKernel<'a> {
    wall_law: ContactLaw,
    dt: f64,
    /// Whether to kick the velocities after summing (not in `prime_forces`).
    kick: bool,
    gravity: [f64; 3],
    walls: &'a [Wall],
    blocks: &'a [BlockSums],
    inv_mass: &'a [f64],
    inv_inertia: &'a [f64],
    /// Held external force and torque per grain, if any were ever set.
    external: Option<ExternalLoads<'a>>,
    near_walls: &'a [u32],
    pos: &'a [[f64; 3]],
    radius: &'a [f64],
    mass: &'a [f64],
}

/// One parallel task of stage 4: [`GRAIN_CHUNK`] grains from `first` on.
struct GrainChunk<'a> {
    first: usize,
    force: &'a mut [[f64; 3]],
    torque: &'a mut [[f64; 3]],
    vel: &'a mut [[f64; 3]],
    omega: &'a mut [[f64; 3]],
    contacts: &'a mut [u16],
    /// The chunk's grain × wall springs.
    wall_springs: &'a mut [[f64; 3]],
}

/// Grain–wall contacts waiting for [`evaluate_lanes`].
struct WallBatch {
    len: usize,
    /// Grain within the chunk, and its spring within the chunk's springs.
    grain: [usize; LANES],
    spring_at: [usize; LANES],
    input: ContactLanes,
    spring: Lanes3,
}

impl WallBatch {
    /// Empty, unused lanes holding a harmless contact (see [`PairBatch::new`]);
    /// the wall's arm and spin are zero for good, its velocity set per contact.
    fn new() -> Self {
        let (zero, one) = (Lanes::splat(0.0), Lanes::splat(1.0));
        WallBatch {
            len: 0,
            grain: [0; LANES],
            spring_at: [0; LANES],
            input: ContactLanes {
                n: [one, zero, zero],
                overlap: one,
                arm_i: one,
                arm_j: zero,
                vel_i: [zero; 3],
                omega_i: [zero; 3],
                vel_j: [zero; 3],
                omega_j: [zero; 3],
                effective_mass: one,
                inv_inertia_sum: one,
                rolling_diameter: one,
            },
            spring: [zero; 3],
        }
    }
}

impl GrainSumKernel<'_> {
    fn chunk(&self, chunk: GrainChunk) {
        self.chunk_body(chunk)
    }

    /// [`GrainSumKernel::chunk`] built for AVX2 (same results, bit for bit).
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    unsafe fn chunk_avx2(&self, chunk: GrainChunk) {
        self.chunk_body(chunk)
    }

    /// Per grain: gravity + external load + the block sums in block order,
    /// then its wall contacts in wall order ([`LANES`] contacts of the chunk
    /// evaluated at a time, each added to its own grain in that order), then
    /// the kick.
    #[inline(always)]
    fn chunk_body(&self, chunk: GrainChunk) {
        let GrainChunk { first, force, torque, vel, omega, contacts, wall_springs } = chunk;
        let nw = self.walls.len();
        let mut batch = WallBatch::new();
        for k in 0..force.len() {
            let p = first + k;
            let (mut f, mut t) = match self.external {
                Some((ext_f, ext_t)) => (add(scale(self.gravity, self.mass[p]), ext_f[p]), ext_t[p]),
                None => (add(scale(self.gravity, self.mass[p]), [0.0; 3]), [0.0; 3]),
            };
            let mut count = 0u16;
            for block in self.blocks.iter().filter(|b| b.window.contains(&p)) {
                let q = p - block.window.start;
                f = add(f, block.force[q]);
                t = add(t, block.torque[q]);
                count += block.contacts[q];
            }
            force[k] = f;
            torque[k] = t;
            contacts[k] = count;
            let (x, r) = (self.pos[p], self.radius[p]);
            let mut near = self.near_walls[p];
            while near != 0 {
                let wi = near.trailing_zeros() as usize;
                near &= near - 1;
                let wall = &self.walls[wi];
                if !wall.active {
                    continue;
                }
                let at = k * nw + wi;
                let gap = dot(sub(x, wall.point), wall.normal);
                let overlap = r - gap;
                if overlap <= 0.0 {
                    if wall_springs[at] != [0.0; 3] {
                        wall_springs[at] = [0.0; 3];
                    }
                    continue;
                }
                let (l, c) = (batch.len, &mut batch.input);
                batch.grain[l] = k;
                batch.spring_at[l] = at;
                lanes::set_lane(&mut c.n, l, neg(wall.normal));
                c.overlap.0[l] = overlap;
                c.arm_i.0[l] = r - overlap;
                lanes::set_lane(&mut c.vel_i, l, vel[k]);
                lanes::set_lane(&mut c.omega_i, l, omega[k]);
                lanes::set_lane(&mut c.vel_j, l, wall.velocity);
                c.effective_mass.0[l] = self.mass[p];
                c.inv_inertia_sum.0[l] = self.inv_inertia[p];
                c.rolling_diameter.0[l] = 2.0 * r;
                lanes::set_lane(&mut batch.spring, l, wall_springs[at]);
                batch.len += 1;
                if batch.len == LANES {
                    self.flush(&mut batch, force, torque, wall_springs);
                }
            }
        }
        self.flush(&mut batch, force, torque, wall_springs);
        if self.kick {
            let half = 0.5 * self.dt;
            for k in 0..force.len() {
                let p = first + k;
                for a in 0..3 {
                    vel[k][a] += half * force[k][a] * self.inv_mass[p];
                    omega[k][a] += half * torque[k][a] * self.inv_inertia[p];
                }
            }
        }
    }

    /// Evaluates the batch and adds each contact to its grain, lane order.
    #[inline(always)]
    fn flush(&self, batch: &mut WallBatch, force: &mut [[f64; 3]], torque: &mut [[f64; 3]], springs: &mut [[f64; 3]]) {
        if batch.len == 0 {
            return;
        }
        let out = evaluate_lanes(&self.wall_law, &batch.input, self.dt, &mut batch.spring);
        for l in 0..batch.len {
            let k = batch.grain[l];
            springs[batch.spring_at[l]] = lanes::lane(&batch.spring, l);
            force[k] = add(force[k], lanes::lane(&out.force_i, l));
            torque[k] = add(torque[k], lanes::lane(&out.torque_i, l));
        }
        batch.len = 0;
    }
}
