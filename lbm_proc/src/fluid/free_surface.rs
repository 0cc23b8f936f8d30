//! Free surface by mass tracking (volume of fluid; Körner et al. 2005,
//! Thürey 2007, Janßen & Krafczyk 2011; lbm-free-surface.md §3).
//!
//! Fluid (F) and interface (I) cells collide and stream; gas (G) cells are
//! never computed. The kernel ([`super::Kernel::interface_cell`]) rebuilds
//! the populations an I cell pulls from gas and adds the cell's mass
//! exchange Δm to its mass m (f64). [`Fluid::update_surface`] then runs the
//! rest of the step, in the order of §3 "Recommended step order":
//!
//! 3. ε = m/ρ from the new populations;
//! 4. mark: I → F if m > (1 + κ)ρ, I → G if m < −κρ, plus forced
//!    conversions. A cell with no G neighbour fills whatever its ε
//!    (FluidX3D): it is a pocket of gas the model cannot hold up (there is
//!    no gas pressure), and such pockets do form where a front overruns its
//!    own tip on the floor, leaving rows of half-filled cells under fluid
//!    that no flux ever fills. A cell with no F neighbour empties when it
//!    touches no wall (FluidX3D), and otherwise only when ε < 0.1 or it has
//!    no I neighbour either (waLBerla): one-cell-thick films on a wall (the
//!    tip of a dam-break front on the floor) survive, while a free-standing
//!    film or droplet goes. Such a film cannot move (mass only flows into
//!    cells that are already interface, and it never fills its gas
//!    neighbours) yet gravity keeps accelerating it: at the paper's τ a
//!    curtain left where the gate stood reached 2.6 m/s and tripped the Mach
//!    watchdog at 0.16 s;
//! 5. filled cells: G neighbours become I with f^eq(ρ̄, ū) averaged over
//!    their F and I neighbours and m = 0; neighbours marked I → G are
//!    un-marked;
//! 6. emptied cells: F neighbours become I with m = ρ (populations kept);
//! 7. apply the flags; excess m − ρ (new F, then m = ρ) or m (new G);
//! 8. distribute each positive excess over the I neighbours, weighted by
//!    Thürey's eq. 4.9 (max(0, n·e_i) for a new F cell, max(0, −n·e_i) for
//!    a new G cell, n = −∇ε/|∇ε| by central differences), evenly when all
//!    weights vanish, evenly over the F neighbours when there is no I
//!    neighbour. A deficit (negative excess, mostly from a collapsed
//!    pocket) is taken from the F and I neighbours in proportion to the
//!    liquid they hold (ρ, m), so that no receiver is driven below zero the
//!    way the near-empty cells at a front tip would be. F cells receive
//!    mass as a density change at their velocity, δf_i = δ·f_i^eq(1, u).
//!    An interface receiver takes at most `OVERFILL_CAP`·ρ − m from all
//!    sources together; the rest goes to the source's fluid neighbours.
//!    With no receiver the excess is kept as a counted pending excess,
//!    given back to the bulk once half a cell's mass has gathered;
//! 9. update the interface list, ε and the row classes of touched rows.
//!
//! The marks of step 4 (each reads only the flags and its own cell) and the
//! populations of step 5's new cells (each reads only old fluid and
//! interface cells) are computed in parallel; everything else is
//! sequential over the interface cells in ascending index order. Results
//! do not depend on the thread count, and the work lists are reused, so a
//! step allocates nothing once they have grown.

use rayon::prelude::*;

use super::{flags, wrap, ConfigError, Fluid};
use crate::lattice::{E, Q, W};
use crate::real::Real;

/// Transient marks, set and cleared within [`Fluid::update_surface`]; the
/// kernel never sees them. Each has the liquid bit of what it stood for
/// before the marks (`flags::is_liquid`): an interface cell to empty is
/// read as gas, one to fill and a gas cell turned interface as liquid.
const TO_FLUID: u8 = 5;
const TO_GAS: u8 = 4;
const NEW_INTERFACE: u8 = 7;

/// waLBerla's forced emptying (FindInterfaceCellConversion.h): an I cell
/// with no F neighbour (but an I neighbour) empties once ε falls below this.
const FORCED_EMPTY: f64 = 0.1;

/// Largest fill ε an interface cell may reach by receiving excess mass in
/// one step (it converts in the next and passes the rest on).
const OVERFILL_CAP: f64 = 1.9;

/// Largest share of its liquid a cell gives up in one step to the deficits
/// of neighbours that filled (collapsed gas pockets).
const DEFICIT_CAP: f64 = 0.05;

/// Pending excess (lattice mass, ρ0Δx³) above which it goes back into the
/// liquid: spread over every fluid cell as a uniform density rise.
const PENDING_RETURN: f64 = 0.5;

/// Interface cells per parallel task of the conversion marks.
const MARK_CHUNK: usize = 2048;

/// What step 4 decides for an interface cell.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Mark {
    Stays,
    Fills,
    Empties,
}

/// Work lists of the conversions, reused every step.
#[derive(Debug, Clone, Default)]
pub(super) struct Lists {
    filled: Vec<usize>,
    emptied: Vec<usize>,
    from_gas: Vec<usize>,
    from_fluid: Vec<usize>,
    next_interface: Vec<usize>,
    /// (converted cell, excess mass, +1 new fluid / −1 new gas).
    excess: Vec<(usize, f64, f64)>,
    /// (receiving interface or fluid cell, mass it receives).
    shares: Vec<(usize, f64)>,
    /// Index in `excess` of the source of each share.
    share_source: Vec<usize>,
    /// Density and conversion of each cell of the interface list (step 3–4).
    marks: Vec<(f64, Mark)>,
    /// Density of each cell of `next_interface`.
    next_density: Vec<f64>,
    /// Populations of each cell of `from_gas` (step 5).
    new_populations: Vec<[f64; Q]>,
    /// Shares into interface cells, sorted by receiver (capacity pass).
    by_receiver: Vec<usize>,
    /// The sort keys of `by_receiver`.
    receiver_keys: Vec<u128>,
    /// Per source, the mass its interface receivers had no room for.
    overflow: Vec<f64>,
    rows: Vec<usize>,
}

/// One interface cell, for recording the surface.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct InterfaceCell {
    /// Cell (i, j, k).
    pub cell: [usize; 3],
    /// Fill ε = m/ρ.
    pub fill: f64,
    /// Velocity, lattice units.
    pub velocity: [f64; 3],
}

/// What one cell holds, for recording slices of the grid.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sample {
    /// One of [`flags`].
    pub flag: u8,
    /// Fill ε: 1 fluid, m/ρ interface, 0 gas and wall.
    pub fill: f64,
    /// Lattice density ρ (0 in gas and wall cells).
    pub density: f64,
    /// Velocity, lattice units (0 in gas and wall cells).
    pub velocity: [f64; 3],
}

impl<T: Real> Fluid<T> {
    fn coords(&self, c: usize) -> [usize; 3] {
        let [nx, ny, _] = self.state.dims;
        [c % nx, (c / nx) % ny, c / (nx * ny)]
    }

    /// The index of the neighbour of cell `c` along e_i, `None` beyond a wall face.
    fn neighbour(&self, c: usize, i: usize) -> Option<usize> {
        let [nx, ny, nz] = self.state.dims;
        let [x, y, z] = self.coords(c);
        let f = self.state.faces;
        let e = E[i];
        let xs = wrap(x, e[0], nx, f[0])?;
        let ys = wrap(y, e[1], ny, f[1])?;
        let zs = wrap(z, e[2], nz, f[2])?;
        Some((zs * ny + ys) * nx + xs)
    }

    /// The indices of the 18 neighbours of cell `c` (entry i along e_i for
    /// i ≥ 1, entry 0 is `c`), `None` beyond a wall face: [`Fluid::neighbour`]
    /// for all directions at once, by fixed offsets off the box's faces.
    pub(super) fn neighbours(&self, c: usize) -> [Option<usize>; Q] {
        let [nx, ny, nz] = self.state.dims;
        let [x, y, z] = self.coords(c);
        if x > 0 && x + 1 < nx && y > 0 && y + 1 < ny && z > 0 && z + 1 < nz {
            std::array::from_fn(|i| Some((c as isize + super::link_offset(E[i], nx, ny)) as usize))
        } else {
            std::array::from_fn(|i| self.neighbour(c, i))
        }
    }

    /// Step 4's conversion of interface cell `c`, with its density ρ:
    /// fills when m > (1 + κ)ρ or it has no gas neighbour; empties when
    /// m < −κρ or, with no fluid neighbour, when ε < `FORCED_EMPTY`, it has
    /// no interface neighbour or it touches no wall (module comment).
    fn conversion_mark(&self, c: usize, kappa: f64) -> (f64, Mark) {
        let rho = self.scratch.interface_density[c];
        let m = self.state.mass[c];
        let eps = m / rho;
        let (mut has_f, mut has_g, mut has_i, mut has_w) = (false, false, false, false);
        for nb in &self.neighbours(c)[1..] {
            match nb.map(|nb| self.state.flags[nb]) {
                Some(flags::FLUID) => has_f = true,
                Some(flags::GAS) => has_g = true,
                Some(flags::WALL) | None => has_w = true,
                Some(_) => has_i = true,
            }
        }
        let mark = if m > (1.0 + kappa) * rho || !has_g {
            Mark::Fills
        } else if m < -kappa * rho || (!has_f && (eps < FORCED_EMPTY || !has_i || !has_w)) {
            Mark::Empties
        } else {
            Mark::Stays
        };
        (rho, mark)
    }

    /// The populations of a cell that was gas and becomes interface (step
    /// 5): f^eq(ρ̄, ū) − w (stored as deviations), ρ̄ and ū averaged over its
    /// F and I neighbours, the velocity shifted by half the acceleration.
    fn equilibrium_from_neighbours(&self, c: usize) -> [f64; Q] {
        let (mut rho, mut u, mut count) = (0.0, [0.0; 3], 0.0);
        for nb in self.neighbours(c)[1..].iter().flatten() {
            if matches!(self.state.flags[*nb], flags::FLUID | flags::INTERFACE | TO_FLUID) {
                let (r, v) = self.moments_at(*nb);
                rho += r;
                (0..3).for_each(|a| u[a] += v[a]);
                count += 1.0;
            }
        }
        // count ≥ 1: the filled cell that made c an interface cell is a neighbour.
        let (rho, u) = (rho / count, u.map(|v| v / count));
        let accel = self.params.acceleration;
        let feq = crate::lattice::equilibrium(rho, std::array::from_fn(|a| u[a] + 0.5 * accel[a]));
        std::array::from_fn(|i| feq[i] - W[i])
    }

    /// Rebuilds the interface list, the fluid count and the fill of every
    /// liquid cell from the flags and masses (after set-up or a restart).
    ///
    /// Pre: gas and wall cells have fill 0, as every change of flag leaves
    /// them (and a fresh fill array holds); they are not visited, so the
    /// gas's pages stay unbacked (memory.rs).
    pub(super) fn rebuild_lists(&mut self) {
        self.scratch.interface.clear();
        self.scratch.fluid_count = 0;
        for c in 0..self.ncells() {
            match self.state.flags[c] {
                flags::FLUID => {
                    self.scratch.fluid_count += 1;
                    self.scratch.fill[c] = 1.0;
                }
                flags::INTERFACE => {
                    self.scratch.interface.push(c);
                    self.scratch.fill[c] = self.state.mass[c] / self.density_at(c);
                }
                _ => debug_assert_eq!(self.scratch.fill[c], 0.0, "gas or wall cell {c} with a fill"),
            }
        }
    }

    /// Sets up the liquid: every non-wall cell for which `liquid(cell)` is
    /// true holds liquid at rest, every other non-wall cell is gas.
    ///
    /// * Liquid cells with a gas neighbour (any of the 18 links) become
    ///   interface cells with fill ½, i.e. the surface lies at their centres;
    ///   the rest are fluid. The liquid volume is therefore the number of
    ///   liquid cells less half the number of interface cells.
    /// * Density is hydrostatic, ρ = 1 + 3 g_L·depth, depth counted in cells
    ///   along the dominant axis of the acceleration from the top liquid cell
    ///   of the same column (ρ = 1 there, matching the gas ρ_A = 1); the
    ///   populations are at equilibrium with u = 0.
    /// * The liquid mass so set is the reference of [`Fluid::mass_drift`].
    pub fn init_liquid(&mut self, liquid: impl Fn([usize; 3]) -> bool) -> Result<(), ConfigError> {
        // A begun step's conversions read the kernel's interface densities: finish it first.
        self.finish_step();
        let n = self.ncells();
        for c in 0..n {
            let old = self.state.flags[c];
            if old != flags::WALL {
                let new = if liquid(self.coords(c)) { flags::FLUID } else { flags::GAS };
                // Written only where it changes: a fresh box's gas flags stay unbacked memory.
                if new != old {
                    self.state.flags[c] = new;
                }
                // Gas holds rest and no mass, as it already does where it
                // was gas: only a liquid cell turned gas is written (the
                // gas of a fresh box stays unbacked memory, memory.rs).
                if new == flags::GAS && flags::is_liquid(old) {
                    self.write_cell(c, &[0.0; Q]);
                    self.state.mass[c] = 0.0;
                    self.scratch.fill[c] = 0.0;
                }
            }
        }
        for c in 0..n {
            if self.state.flags[c] == flags::FLUID && self.borders_gas(c) {
                self.state.flags[c] = flags::INTERFACE;
            }
        }
        // Hydrostatic density from the top liquid cell of each column.
        let a = self.params.acceleration;
        let k = (0..3).fold(0, |k, d| if a[d].abs() > a[k].abs() { d } else { k });
        let (p, q) = ((k + 1) % 3, (k + 2) % 3);
        let dims = self.state.dims;
        let mut top: Vec<Option<usize>> = vec![None; dims[p] * dims[q]];
        for c in 0..n {
            if flags::is_liquid(self.state.flags[c]) {
                let x = self.coords(c);
                let t = &mut top[x[p] + dims[p] * x[q]];
                // "Up" is against the acceleration: larger x_k when a_k < 0.
                *t = Some(match *t {
                    None => x[k],
                    Some(t) if a[k] < 0.0 => t.max(x[k]),
                    Some(t) => t.min(x[k]),
                });
            }
        }
        for c in 0..n {
            match self.state.flags[c] {
                flags::FLUID | flags::INTERFACE => {
                    let x = self.coords(c);
                    let depth = top[x[p] + dims[p] * x[q]].map_or(0, |t| t.abs_diff(x[k])) as f64;
                    let rho = 1.0 + 3.0 * a[k].abs() * depth;
                    self.set_equilibrium(x, rho, [0.0; 3])?;
                    // A fluid cell's mass is its density: its slot stays 0 (and unbacked).
                    if self.state.flags[c] == flags::INTERFACE {
                        self.state.mass[c] = 0.5 * rho;
                    } else if self.state.mass[c].to_bits() != 0 {
                        self.state.mass[c] = 0.0;
                    }
                }
                _ => {}
            }
        }
        self.state.pending_excess = 0.0;
        self.rebuild_lists();
        self.scratch.rows_stale = true;
        self.mark_reference_mass();
        Ok(())
    }

    /// Opens a gate: the wall cells `cells` become gas, and fluid cells now
    /// next to them become interface cells with m = ρ (full); the ordinary
    /// conversions take over from the next step (lbm-free-surface.md §4
    /// "Gate"). Checks every cell first, so an error changes nothing.
    pub fn remove_walls(&mut self, cells: &[[usize; 3]]) -> Result<(), ConfigError> {
        // A begun step's conversions read the kernel's interface densities: finish it first.
        self.finish_step();
        for &cell in cells {
            if self.state.flags[self.index(cell)?] != flags::WALL {
                return Err(ConfigError::NotWall(cell));
            }
        }
        for &cell in cells {
            let c = self.index(cell)?;
            self.state.flags[c] = flags::GAS;
            // A wall holds 0 in its mass, fill and populations (`set_flag`):
            // nothing else to write, and memory never written stays unbacked.
            debug_assert!(self.state.mass[c] == 0.0 && self.scratch.fill[c] == 0.0, "wall cell {c} holds a mass");
            self.write_cell(c, &[0.0; Q]);
        }
        for &cell in cells {
            let c = self.index(cell)?;
            for i in 1..Q {
                if let Some(nb) = self.neighbour(c, i) {
                    if self.state.flags[nb] == flags::FLUID {
                        self.state.flags[nb] = flags::INTERFACE;
                        self.state.mass[nb] = self.density_at(nb);
                        self.scratch.fill[nb] = 1.0;
                        self.scratch.fluid_count -= 1;
                        self.scratch.interface.push(nb);
                    }
                }
            }
        }
        self.scratch.interface.sort_unstable();
        self.scratch.rows_stale = true;
        // The removed walls' flags are gas (0) again: their pages go back.
        crate::memory::release_zero_pages(&mut self.state.flags);
        Ok(())
    }

    /// Steps 3–9 of the free-surface step (module comment), each a stage
    /// below. Pre: the kernel has streamed, collided and added Δm to every
    /// interface mass; the interface list is the step's before. Post: flags,
    /// masses, fills and the interface list consistent again, the liquid
    /// mass conserved up to the pending excess (step 8).
    // Kept out of line: inlined into `Fluid::finish_step` (once its stages
    // became small functions) it cost the bulk stream–collide 20 % through
    // the step's code layout (docs/BENCHMARKS.md, session 21).
    #[inline(never)]
    pub(super) fn update_surface(&mut self) {
        let mut l = std::mem::take(&mut self.scratch.lists);
        self.mark_conversions(&mut l);
        self.fill_marked(&mut l);
        self.empty_marked(&mut l);
        self.apply_conversions(&mut l);
        let mut pending = 0.0;
        self.share_excess(&mut l, &mut pending);
        self.cap_shares(&mut l, &mut pending);
        self.overflow_to_liquid(&mut l, &mut pending);
        self.add_shares(&l, pending);
        // 9. Row classes of the rows whose flags changed.
        l.rows.sort_unstable();
        l.rows.dedup();
        self.reclassify_rows(&l.rows);
        self.scratch.lists = l;
    }

    /// Steps 3–4: marks the interface cells that fill or empty.
    fn mark_conversions(&mut self, l: &mut Lists) {
        // In parallel: a cell's mark reads only the
        // flags (all marks are written after) and its own populations, so it
        // does not depend on the order. The densities are kept for the fills
        // (step 7) and the pending return (step 8).
        l.filled.clear();
        l.emptied.clear();
        l.marks.resize(self.scratch.interface.len(), (0.0, Mark::Stays));
        let fluid = &*self;
        fluid.scratch.interface.par_chunks(MARK_CHUNK).zip(l.marks.par_chunks_mut(MARK_CHUNK)).for_each(
            |(cells, marks)| {
                for (&c, mark) in cells.iter().zip(marks) {
                    *mark = fluid.conversion_mark(c, self.params.kappa);
                }
            },
        );
        for (&c, &(_, mark)) in self.scratch.interface.iter().zip(&l.marks) {
            match mark {
                Mark::Fills => {
                    self.state.flags[c] = TO_FLUID;
                    l.filled.push(c);
                }
                Mark::Empties => {
                    self.state.flags[c] = TO_GAS;
                    l.emptied.push(c);
                }
                Mark::Stays => {}
            }
        }
    }

    /// Step 5: the gas neighbours of filled cells become interface, with
    /// populations from their liquid neighbours.
    fn fill_marked(&mut self, l: &mut Lists) {
        // Gas neighbours become interface; neighbours
        // marked to empty stay interface (else F would touch G).
        l.from_gas.clear();
        for &c in &l.filled {
            for i in 1..Q {
                if let Some(nb) = self.neighbour(c, i) {
                    match self.state.flags[nb] {
                        TO_GAS => self.state.flags[nb] = flags::INTERFACE,
                        flags::GAS => {
                            self.state.flags[nb] = NEW_INTERFACE;
                            l.from_gas.push(nb);
                        }
                        _ => {}
                    }
                }
            }
        }
        // New cells read only old F and I cells (the new ones are marked
        // NEW_INTERFACE), so they are computed in parallel, then written.
        let fluid = &*self;
        l.from_gas.par_iter().map(|&c| fluid.equilibrium_from_neighbours(c)).collect_into_vec(&mut l.new_populations);
        for (&c, g) in l.from_gas.iter().zip(&l.new_populations) {
            self.write_cell(c, g);
            self.state.mass[c] = 0.0;
            self.scratch.interface_density[c] = self.density_at(c);
        }
    }

    /// Step 6: the fluid neighbours of emptied cells become interface.
    fn empty_marked(&mut self, l: &mut Lists) {
        // Fluid neighbours become interface, full. A
        // neighbour marked to fill cannot remain here: it would have
        // un-marked this cell in step 5 (neighbourhoods are symmetric).
        l.from_fluid.clear();
        for &c in &l.emptied {
            if self.state.flags[c] != TO_GAS {
                continue;
            }
            for i in 1..Q {
                if let Some(nb) = self.neighbour(c, i) {
                    if self.state.flags[nb] == flags::FLUID {
                        self.state.flags[nb] = NEW_INTERFACE;
                        let rho = self.density_at(nb);
                        self.state.mass[nb] = rho;
                        self.scratch.interface_density[nb] = rho;
                        l.from_fluid.push(nb);
                    }
                }
            }
        }
    }

    /// Step 7: the new flags, each converted cell's excess mass, and the
    /// new interface list with its fills.
    fn apply_conversions(&mut self, l: &mut Lists) {
        l.excess.clear();
        l.rows.clear();
        let nx = self.state.dims[0];
        for &c in &l.filled {
            self.state.flags[c] = flags::FLUID;
            l.excess.push((c, self.state.mass[c] - self.scratch.interface_density[c], 1.0));
            self.state.mass[c] = 0.0;
            self.scratch.fill[c] = 1.0;
            l.rows.push(c / nx);
        }
        self.scratch.fluid_count += l.filled.len();
        for &c in &l.emptied {
            if self.state.flags[c] == TO_GAS {
                self.state.flags[c] = flags::GAS;
                l.excess.push((c, self.state.mass[c], -1.0));
                self.state.mass[c] = 0.0;
                self.scratch.fill[c] = 0.0;
                self.write_cell(c, &[0.0; Q]);
                l.rows.push(c / nx);
            }
        }
        self.scratch.fluid_count -= l.from_fluid.len();
        for &c in l.from_gas.iter().chain(&l.from_fluid) {
            self.state.flags[c] = flags::INTERFACE;
            l.rows.push(c / nx);
        }
        // The new interface list: survivors (ascending) merged with the new
        // cells (sorted here), then ε of every interface cell. A survivor's
        // populations are those it was marked with, so its density is the
        // one step 3 found.
        l.from_gas.extend_from_slice(&l.from_fluid);
        l.from_gas.sort_unstable();
        l.next_interface.clear();
        l.next_density.clear();
        {
            let fluid = &*self;
            let survivors = fluid
                .scratch
                .interface
                .iter()
                .zip(&l.marks)
                .filter(|&(&c, _)| fluid.state.flags[c] == flags::INTERFACE)
                .map(|(&c, &(rho, _))| (c, rho));
            let new = l.from_gas.iter().map(|&c| (c, fluid.scratch.interface_density[c]));
            merge_sorted(survivors, new, &mut l.next_interface, &mut l.next_density);
        }
        std::mem::swap(&mut self.scratch.interface, &mut l.next_interface);
        for (&c, &rho) in self.scratch.interface.iter().zip(&l.next_density) {
            self.scratch.fill[c] = self.state.mass[c] / rho;
        }
    }

    /// Step 8, first part: each converted cell's excess as shares to its
    /// neighbours; what no neighbour can take goes to `pending`.
    fn share_excess(&self, l: &mut Lists, pending: &mut f64) {
        // All shares first (from the ε above),
        // then add them, so the result does not depend on the order.
        l.shares.clear();
        let fluid = self;
        l.share_source.clear();
        for (k, &(c, excess, sign)) in l.excess.iter().enumerate() {
            let nbs = &fluid.neighbours(c);
            let normal = fluid.normal(c, nbs);
            let weight = |i: usize| {
                let ne: f64 = (0..3).map(|a| normal[a] * E[i][a] as f64).sum();
                (sign * ne).max(0.0)
            };
            let receivers = |flag: u8| {
                (1..Q).filter_map(move |i| nbs[i].filter(|&nb| fluid.state.flags[nb] == flag).map(|nb| (i, nb)))
            };
            let start = l.shares.len();
            let total: f64 = receivers(flags::INTERFACE).map(|(i, _)| weight(i)).sum();
            if excess < 0.0 {
                let held = |nb: usize| match fluid.state.flags[nb] {
                    flags::INTERFACE => fluid.state.mass[nb].max(0.0),
                    _ => fluid.density_at(nb),
                };
                let liquid = receivers(flags::INTERFACE).chain(receivers(flags::FLUID)).map(|(_, nb)| nb);
                let total: f64 = liquid.clone().map(held).sum();
                if total > 0.0 {
                    l.shares.extend(liquid.filter(|&nb| held(nb) > 0.0).map(|nb| (nb, held(nb) / total)));
                }
            } else if total > 0.0 {
                let weighted = receivers(flags::INTERFACE).filter(|&(i, _)| weight(i) > 0.0);
                l.shares.extend(weighted.map(|(i, nb)| (nb, weight(i) / total)));
            } else {
                let flag = if receivers(flags::INTERFACE).next().is_some() { flags::INTERFACE } else { flags::FLUID };
                let count = receivers(flag).count() as f64;
                l.shares.extend(receivers(flag).map(|(_, nb)| (nb, 1.0 / count)));
            }
            let Some(last) = l.shares.len().checked_sub(1).filter(|&last| last >= start) else {
                *pending += excess;
                continue;
            };
            // The last receiver takes what is left, so the shares sum to the excess.
            let mut given = 0.0;
            for share in &mut l.shares[start..last] {
                share.1 *= excess;
                given += share.1;
            }
            l.shares[last].1 = excess - given;
            l.share_source.resize(l.shares.len(), k);
        }
    }

    /// Step 8, second part: the capacity of each receiver.
    fn cap_shares(&self, l: &mut Lists, pending: &mut f64) {
        let fluid = self;
        // Capacity: an interface cell takes at most the room it has before it
        // would fill, (1 + κ)ρ − m, from all sources together; its shares are
        // scaled down to fit and each source's cut goes to the source's fluid
        // neighbours (as density) or, with none, to the pending excess.
        // Without this, forced emptying of a free-standing sheet in a splash
        // piled 0.2–0.7 of a cell from each of six cells onto the few that
        // survived (fill up to 3.9; docs/lbm.md "Splashes").
        // Sorted by (receiver, taking, share index), packed in one key.
        l.receiver_keys.clear();
        l.receiver_keys.extend(l.shares.iter().enumerate().filter_map(|(s, &(nb, m))| {
            (m < 0.0 || (m > 0.0 && fluid.state.flags[nb] == flags::INTERFACE))
                .then_some(((nb as u128) << 64) | (u128::from(m < 0.0) << 63) | s as u128)
        }));
        l.receiver_keys.sort_unstable();
        l.by_receiver.clear();
        l.by_receiver.extend(l.receiver_keys.iter().map(|&key| (key as u64 & !(1 << 63)) as usize));
        l.overflow.clear();
        l.overflow.resize(l.excess.len(), 0.0);
        let mut g = 0;
        while g < l.by_receiver.len() {
            let (nb, first) = l.shares[l.by_receiver[g]];
            let taking = first < 0.0;
            let end = g + l.by_receiver[g..]
                .iter()
                .take_while(|&&s| l.shares[s].0 == nb && (l.shares[s].1 < 0.0) == taking)
                .count();
            let total: f64 = l.by_receiver[g..end].iter().map(|&s| l.shares[s].1).sum();
            // Giving: the room before the cell holds OVERFILL_CAP cells.
            // Taking: at most DEFICIT_CAP of the liquid the cell holds; the
            // rest of the deficit goes to the pending excess, which takes it
            // from the free surface.
            let (limit, amount) = if taking {
                let held = match fluid.state.flags[nb] {
                    flags::INTERFACE => fluid.state.mass[nb].max(0.0),
                    _ => fluid.density_at(nb),
                };
                (DEFICIT_CAP * held, -total)
            } else {
                ((OVERFILL_CAP * fluid.scratch.interface_density[nb] - fluid.state.mass[nb]).max(0.0), total)
            };
            if amount > limit {
                let factor = limit / amount;
                for &s in &l.by_receiver[g..end] {
                    let keep = l.shares[s].1 * factor;
                    let cut = l.shares[s].1 - keep;
                    if taking {
                        *pending += cut;
                    } else {
                        l.overflow[l.share_source[s]] += cut;
                    }
                    l.shares[s].1 = keep;
                }
            }
            g = end;
        }
    }

    /// Step 8, third part: what a source could not give its interface
    /// neighbours goes to its fluid neighbours (as density), or to `pending`.
    fn overflow_to_liquid(&self, l: &mut Lists, pending: &mut f64) {
        let fluid = self;
        for (k, &(c, _, _)) in l.excess.iter().enumerate() {
            let overflow = l.overflow[k];
            if overflow <= 0.0 {
                continue;
            }
            let fluid_nbs =
                (1..Q).filter_map(|i| fluid.neighbour(c, i)).filter(|&nb| fluid.state.flags[nb] == flags::FLUID);
            let count = fluid_nbs.clone().count();
            if count == 0 {
                *pending += overflow;
                continue;
            }
            let each = overflow / count as f64;
            let mut given = 0.0;
            for (j, nb) in fluid_nbs.enumerate() {
                let share = if j + 1 == count { overflow - given } else { each };
                given += share;
                l.shares.push((nb, share));
            }
        }
    }

    /// Step 8, last part: the shares added, the receivers' fills updated,
    /// the pending excess returned once it is large enough.
    fn add_shares(&mut self, l: &Lists, pending: f64) {
        self.state.pending_excess += pending;
        for &(nb, share) in &l.shares {
            if self.state.flags[nb] == flags::INTERFACE {
                self.state.mass[nb] += share;
            } else {
                self.add_density(nb, share);
            }
        }
        // ε of the interface cells whose mass changed, once each: they are
        // the receivers in `by_receiver` (sorted by cell; the overflow went
        // to fluid cells, and a zero share changes nothing; a NaN share is
        // left out, which the watchdog reports from m/ρ itself).
        let mut last = usize::MAX;
        for &s in &l.by_receiver {
            let nb = l.shares[s].0;
            if nb != last && self.state.flags[nb] == flags::INTERFACE {
                self.scratch.fill[nb] = self.state.mass[nb] / self.scratch.interface_density[nb];
            }
            last = nb;
        }
        if self.state.pending_excess.abs() >= PENDING_RETURN && self.scratch.fluid_count > 0 {
            self.return_pending_excess(&l.next_density);
        }
    }

    /// Gives the pending excess back to the liquid through the free surface:
    /// spread over the interface cells in proportion to what each can take
    /// (its room ρ − m for a surplus, its mass m for a deficit), so that the
    /// liquid's volume, not only its mass, is kept. A surplus is the mass of
    /// one-cell drops thrown off by a splash, which fall back onto the
    /// surface; a deficit is liquid a collapsed gas pocket was filled with,
    /// which came from the surface. Taken next to the pocket instead, it dug
    /// density holes down to 0.47 at a front tip; spread as density over the
    /// whole liquid, it lowered the density everywhere. With too little
    /// capacity at the surface, every fluid cell's density changes alike.
    ///
    /// `densities[k]`: the density of interface cell k (in list order).
    fn return_pending_excess(&mut self, densities: &[f64]) {
        let pending = self.state.pending_excess;
        let capacity = |f: &Self, k: usize| {
            let m = f.state.mass[f.scratch.interface[k]];
            if pending < 0.0 {
                m.max(0.0)
            } else {
                (densities[k] - m).max(0.0)
            }
        };
        let n = self.scratch.interface.len();
        let total: f64 = (0..n).map(|k| capacity(self, k)).sum();
        if total >= pending.abs() && total > 0.0 {
            let last = (0..n).rposition(|k| capacity(self, k) > 0.0).expect("capacity > 0");
            let mut given = 0.0;
            for k in 0..=last {
                let c = self.scratch.interface[k];
                let w = capacity(self, k);
                if w <= 0.0 {
                    continue;
                }
                // The last cell takes the remainder: the total is exact.
                let share = if k == last { pending - given } else { pending * w / total };
                given += share;
                self.state.mass[c] += share;
                self.scratch.fill[c] = self.state.mass[c] / densities[k];
            }
        } else {
            let count = self.scratch.fluid_count;
            let delta = pending / count as f64;
            let (mut given, mut left) = (0.0, count);
            for c in 0..self.ncells() {
                if self.state.flags[c] != flags::FLUID {
                    continue;
                }
                left -= 1;
                let share = if left == 0 { pending - given } else { delta };
                self.add_density(c, share);
                given += share;
                if left == 0 {
                    break;
                }
            }
        }
        self.scratch.returned_mass += pending;
        self.state.pending_excess = 0.0;
        self.scratch.pending_returned += 1;
    }

    /// Adds mass `delta` to fluid cell `c` at its velocity:
    /// f_i += δ·f_i^eq(1, u), which raises ρ by δ and ρu by δu. Written to
    /// the current lattice only: the other one is overwritten by the next
    /// step wherever the cell is liquid.
    fn add_density(&mut self, c: usize, delta: f64) {
        let (_, u) = self.moments_at(c);
        let a = self.params.acceleration;
        let feq = crate::lattice::equilibrium(delta, std::array::from_fn(|d| u[d] + 0.5 * a[d]));
        let layout = self.state.layout();
        let base = layout.base(c);
        for i in 0..Q {
            let f = &mut self.state.populations[base + i * layout.segment()];
            *f = T::from_f64(f.to_f64() + feq[i]);
        }
    }

    /// n = −∇ε/|∇ε| at cell `c` by central differences of the fill (a wall or
    /// a face beyond the box counts as the cell's own ε); 0 where ∇ε = 0.
    /// `nbs` are the cell's neighbours ([`Fluid::neighbours`]).
    fn normal(&self, c: usize, nbs: &[Option<usize>; Q]) -> [f64; 3] {
        let own = self.scratch.fill[c];
        let eps =
            |i: usize| nbs[i].filter(|&nb| self.state.flags[nb] != flags::WALL).map_or(own, |nb| self.scratch.fill[nb]);
        // Directions 1..6 are +x, −x, +y, −y, +z, −z.
        let g = [-0.5 * (eps(1) - eps(2)), -0.5 * (eps(3) - eps(4)), -0.5 * (eps(5) - eps(6))];
        let len = (g[0] * g[0] + g[1] * g[1] + g[2] * g[2]).sqrt();
        if len > 0.0 {
            g.map(|v| v / len)
        } else {
            [0.0; 3]
        }
    }

    /// Fluid plus interface cells: the cells a step computes.
    pub fn active_cells(&self) -> usize {
        self.scratch.fluid_count + self.scratch.interface.len()
    }

    /// Number of interface cells.
    pub fn interface_cells(&self) -> usize {
        self.scratch.interface.len()
    }

    /// The interface cells in ascending index order, with fill and velocity.
    pub fn interface(&self) -> impl Iterator<Item = InterfaceCell> + '_ {
        self.scratch.interface.iter().map(|&c| {
            let (rho, velocity) = self.moments_at(c);
            InterfaceCell { cell: self.coords(c), fill: self.state.mass[c] / rho, velocity }
        })
    }

    /// Fill ε of `cell`: 1 fluid, m/ρ interface, 0 gas and wall.
    pub fn fill(&self, cell: [usize; 3]) -> Result<f64, ConfigError> {
        let c = self.index(cell)?;
        Ok(match self.state.flags[c] {
            flags::FLUID => 1.0,
            flags::INTERFACE => self.state.mass[c] / self.density_at(c),
            _ => 0.0,
        })
    }

    /// The fill ε of every cell (x fastest, as the flags), as of the end of
    /// the last step or set-up call; equal to [`Fluid::fill`] cell by cell.
    pub fn fill_field(&self) -> &[f64] {
        &self.scratch.fill
    }

    /// Flag, fill, density and velocity of `cell` (lattice units), for
    /// recording slices such as the mid-width x–z plane.
    pub fn sample(&self, cell: [usize; 3]) -> Result<Sample, ConfigError> {
        let c = self.index(cell)?;
        let flag = self.state.flags[c];
        if !flags::is_liquid(flag) {
            return Ok(Sample { flag, fill: 0.0, density: 0.0, velocity: [0.0; 3] });
        }
        let (density, velocity) = self.moments_at(c);
        let fill = if flag == flags::INTERFACE { self.state.mass[c] / density } else { 1.0 };
        Ok(Sample { flag, fill, density, velocity })
    }

    /// Excess mass kept because no interface cell could take it (lattice
    /// units), until half a cell's worth has gathered and goes back to the
    /// liquid.
    pub fn pending_excess(&self) -> f64 {
        self.state.pending_excess
    }

    /// How many times the pending excess went back to the liquid since this
    /// fluid was created (not part of the state).
    pub fn pending_returns(&self) -> u64 {
        self.scratch.pending_returned
    }

    /// Liquid mass given back from the pending excess since this fluid was
    /// created (lattice units; not part of the state).
    pub fn returned_excess(&self) -> f64 {
        self.scratch.returned_mass
    }

    /// Continues the two diagnostics above from a checkpoint's values.
    pub fn restore_returned_excess(&mut self, returns: u64, mass: f64) {
        self.scratch.pending_returned = returns;
        self.scratch.returned_mass = mass;
    }
}

/// Merges two sequences of (cell, value), each ascending by cell, into
/// `cells` and `values`.
fn merge_sorted(
    a: impl Iterator<Item = (usize, f64)>,
    b: impl Iterator<Item = (usize, f64)>,
    cells: &mut Vec<usize>,
    values: &mut Vec<f64>,
) {
    let (mut a, mut b) = (a.peekable(), b.peekable());
    loop {
        let next = match (a.peek(), b.peek()) {
            (Some(&x), Some(&y)) if x.0 <= y.0 => a.next(),
            (Some(_), Some(_)) | (None, Some(_)) => b.next(),
            (Some(_), None) => a.next(),
            (None, None) => return,
        };
        if let Some((c, v)) = next {
            cells.push(c);
            values.push(v);
        }
    }
}
