//! Direct forcing of listed cells toward target velocities (the fluid side of
//! the particle coupling, Eq. 5; [`crate::coupling`] builds the list).
//!
//! The forced cells are kept in ascending index order with, per x-row, the
//! start of the row's run, so the kernel walks them alongside its chunks and
//! rows without forced cells keep the unforced code path. The kernel writes
//! what it applied to each cell into a parallel list; entries lie in the
//! plane of their cell, so each is written by one task only and the result
//! does not depend on the thread count.

use schemas::scene::ForcingGain;
use serde::{Deserialize, Serialize};

use super::{ConfigError, Fluid};
use crate::real::Real;

/// The gain b of Eq. 5's direct forcing in a cell of covered fraction `w`
/// in [0, 1] at relaxation time `tau` > ½ (the molecular τ0, or the cell's
/// effective τ where [`uses_effective_tau`]), under `rule` (the formulas
/// and their sources are on [`ForcingGain`]'s variants). b = 1 in a fully
/// covered cell under every rule.
#[inline]
pub fn forcing_gain(rule: ForcingGain, w: f64, tau: f64) -> f64 {
    match rule {
        ForcingGain::CoveredFraction => w,
        ForcingGain::CentreInside => {
            if w >= 0.5 {
                1.0
            } else {
                0.0
            }
        }
        ForcingGain::NobleTorczynski | ForcingGain::NobleTorczynskiEffective if w >= 1.0 => 1.0,
        ForcingGain::NobleTorczynski | ForcingGain::NobleTorczynskiEffective => {
            let e = tau - 0.5;
            w * e / ((1.0 - w) + e)
        }
    }
}

/// Whether [`forcing_gain`] takes the cell's effective τ (with the eddy
/// viscosity) rather than the molecular τ0.
pub fn uses_effective_tau(rule: ForcingGain) -> bool {
    rule == ForcingGain::NobleTorczynskiEffective
}

/// A cell to be pushed toward a target velocity in the next steps
/// (lattice units).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ForcedCell {
    /// Cell index, x fastest: `(k * ny + j) * nx + i`.
    pub cell: usize,
    /// The covered fraction, in [0, 1]; an interface cell's fill multiplies
    /// it. The forcing gain follows from it ([`Fluid::set_forcing_gain`]).
    pub weight: f64,
    /// The velocity the cell is forced toward.
    pub target: [f64; 3],
}

/// What the direct forcing did to one forced cell in the last step.
///
/// One cache line each (64 bytes, aligned): the coupling reads them by
/// grain, scattered, and an entry split over two lines cost two misses.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
#[repr(C, align(64))]
pub struct AppliedForce {
    /// Cell index.
    pub cell: usize,
    /// F_IB, the force density added to the fluid (lattice units: per cell,
    /// so also the force on the cell's liquid); 0 in gas and wall cells.
    pub force: [f64; 3],
    /// weight × fill × ρ: the liquid mass the forcing acted on (lattice
    /// units, ρ0Δx³); 0 in gas and wall cells.
    pub liquid: f64,
    /// w (Σ f e + ρa + F_IB) with w = weight × fill: the momentum of the
    /// cell's covered part after this step's collision (lattice units). Its
    /// change over a step, summed over a grain's cells, is the inertia of
    /// the liquid the grain holds (coupling.rs, step 6).
    pub held: [f64; 3],
}

/// The direct forcing as a checkpoint keeps it: the list in force and what
/// the last step applied (the next step reads velocities corrected by it:
/// the gas populations rebuilt at the interface, the conversions).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct ForcingMemory {
    cells: Vec<ForcedCell>,
    rows: Vec<usize>,
    applied: Vec<AppliedForce>,
    applied_rows: Vec<usize>,
}

/// The forcing list and its per-step output, reused (no allocation once grown).
#[derive(Debug, Clone, Default)]
pub(super) struct Forcing {
    /// Ascending cell index, unique.
    pub(super) cells: Vec<ForcedCell>,
    /// `rows[r]..rows[r + 1]`: the entries of x-row r; empty without forcing.
    pub(super) rows: Vec<usize>,
    /// Parallel to `cells` during and after a step: what was applied.
    pub(super) applied: Vec<AppliedForce>,
    /// `rows` of the list `applied` was reset from (a list installed since
    /// has its own `rows`).
    pub(super) applied_rows: Vec<usize>,
    /// How a partly covered cell's gain follows from its covered fraction.
    pub(super) gain: ForcingGain,
    /// Counts the lists installed, so that the coupling can tell its own
    /// list from one set since ([`Fluid::forcing_version`]).
    pub(super) version: u64,
}

impl Forcing {
    /// Sizes the output list to the current cells. The kernel writes every
    /// entry, gas, wall and skipped cells with zero force (the reset this
    /// replaced wrote ~30 MB a step in the paper's column).
    pub(super) fn start_step(&mut self) {
        self.applied.resize(self.cells.len(), AppliedForce::default());
        self.applied_rows.clone_from(&self.rows);
    }

    /// A walk over the last step's applied forces from the first cell ≥ `start`,
    /// for callers that visit cells in ascending order.
    pub(super) fn cursor_from(&self, start: usize) -> AppliedCursor<'_> {
        AppliedCursor { applied: &self.applied, k: self.applied.partition_point(|a| a.cell < start) }
    }

    /// The force applied to cell index `c` of a lattice `nx` cells long in
    /// the last step (0 if unforced): a search in the cell's row.
    pub(super) fn last_force(&self, c: usize, nx: usize) -> [f64; 3] {
        let r = c / nx;
        let Some(row) = self.applied_rows.get(r..r + 2).and_then(|b| self.applied.get(b[0]..b[1])) else {
            return [0.0; 3];
        };
        match row.binary_search_by_key(&c, |a| a.cell) {
            Ok(k) => row[k].force,
            Err(_) => [0.0; 3],
        }
    }
}

/// [`Forcing::last_force`] for cells visited in ascending order: one merge
/// step per call instead of a binary search.
pub(super) struct AppliedCursor<'a> {
    applied: &'a [AppliedForce],
    k: usize,
}

impl AppliedCursor<'_> {
    /// The force applied to cell `c` in the last step (0 if unforced).
    /// Pre: `c` is not below the cell of any earlier call.
    pub(super) fn force_at(&mut self, c: usize) -> [f64; 3] {
        while self.k < self.applied.len() && self.applied[self.k].cell < c {
            self.k += 1;
        }
        match self.applied.get(self.k) {
            Some(a) if a.cell == c => a.force,
            _ => [0.0; 3],
        }
    }
}

impl<T: Real> Fluid<T> {
    /// Replaces the direct forcing applied from the next step on (until
    /// replaced or cleared). `cells` must come in strictly ascending cell
    /// order, inside the box, with weight in [0, 1] and a finite target;
    /// otherwise the forcing is cleared and the first offending cell named.
    ///
    /// In each step every listed fluid or interface cell receives, between
    /// the pull and the collision, the force density
    /// F_IB = b [2(ρU − Σ f e) − ρa] with b the [`ForcingGain`] of
    /// w = weight × fill, so that its velocity becomes U when w = 1; gas and
    /// wall cells are never forced.
    /// [`Fluid::applied_forcing`] then reports every F_IB. Not part of
    /// [`super::FluidState`]: the coupling sets it before every step.
    pub fn set_direct_forcing(&mut self, cells: impl IntoIterator<Item = ForcedCell>) -> Result<(), ConfigError> {
        let ncells = self.ncells();
        let forcing = &mut self.scratch.forcing;
        forcing.version += 1;
        forcing.cells.clear();
        forcing.rows.clear();
        let check = || {
            for cell in cells {
                let why = if cell.cell >= ncells {
                    Some("outside the box")
                } else if forcing.cells.last().is_some_and(|last| last.cell >= cell.cell) {
                    Some("not in strictly ascending order")
                } else if !(0.0..=1.0).contains(&cell.weight) {
                    Some("weight outside [0, 1]")
                } else if !cell.target.iter().all(|u| u.is_finite()) {
                    Some("target velocity not finite")
                } else {
                    None
                };
                if let Some(why) = why {
                    return Err(ConfigError::Forcing { cell: cell.cell, why });
                }
                forcing.cells.push(cell);
            }
            Ok(())
        };
        if let Err(e) = check() {
            forcing.cells.clear();
            return Err(e);
        }
        self.index_forcing_rows();
        Ok(())
    }

    /// [`Fluid::set_direct_forcing`] for a list the coupling built sorted,
    /// inside the box, with weights in [0, 1] and finite targets, and its
    /// row index (`rows[r]`: the first entry of x-row r, `ny·nz + 1` of
    /// them): both swapped in (the arguments get the previous ones back, for
    /// their buffers), checked in debug builds only. Returns the new
    /// [`Fluid::forcing_version`].
    pub(crate) fn swap_direct_forcing(&mut self, cells: &mut Vec<ForcedCell>, rows: &mut Vec<usize>) -> u64 {
        let [nx, ny, nz] = self.state.dims;
        debug_assert!(
            cells.windows(2).all(|w| w[0].cell < w[1].cell)
                && cells.iter().all(|c| c.cell < self.ncells()
                    && (0.0..=1.0).contains(&c.weight)
                    && c.target.iter().all(|u| u.is_finite())),
            "the coupling built an invalid forcing list"
        );
        debug_assert!(
            rows.len() == ny * nz + 1
                && rows[ny * nz] == cells.len()
                && (0..ny * nz)
                    .all(|r| rows[r] <= rows[r + 1] && cells[rows[r]..rows[r + 1]].iter().all(|c| c.cell / nx == r)),
            "the coupling built an invalid forcing row index"
        );
        let forcing = &mut self.scratch.forcing;
        std::mem::swap(&mut forcing.cells, cells);
        std::mem::swap(&mut forcing.rows, rows);
        if forcing.cells.is_empty() {
            forcing.rows.clear();
        }
        forcing.version += 1;
        forcing.version
    }

    /// `rows[r]`: the first forcing entry of x-row r (a counting pass).
    fn index_forcing_rows(&mut self) {
        let [nx, ny, nz] = self.state.dims;
        let forcing = &mut self.scratch.forcing;
        forcing.rows.clear();
        if !forcing.cells.is_empty() {
            // Counting pass: rows[r] = number of entries in rows < r.
            forcing.rows.resize(ny * nz + 1, 0);
            let mut k = 0;
            for r in 0..=ny * nz {
                forcing.rows[r] = k;
                while k < forcing.cells.len() && forcing.cells[k].cell < (r + 1) * nx {
                    k += 1;
                }
            }
        }
    }

    /// Sets how a partly covered cell's forcing gain follows from its
    /// covered fraction (default [`ForcingGain::NobleTorczynski`]).
    pub fn set_forcing_gain(&mut self, gain: ForcingGain) {
        self.scratch.forcing.gain = gain;
    }

    pub fn forcing_gain(&self) -> ForcingGain {
        self.scratch.forcing.gain
    }

    /// Removes the direct forcing.
    pub fn clear_direct_forcing(&mut self) {
        self.scratch.forcing.version += 1;
        self.scratch.forcing.cells.clear();
        self.scratch.forcing.rows.clear();
    }

    /// How many forcing lists have been installed (set, swapped in or
    /// cleared): a list is still the one installed while this is unchanged.
    pub fn forcing_version(&self) -> u64 {
        self.scratch.forcing.version
    }

    /// The forcing for a checkpoint ([`ForcingMemory`]).
    pub fn forcing_memory(&self) -> ForcingMemory {
        let f = &self.scratch.forcing;
        ForcingMemory {
            cells: f.cells.clone(),
            rows: f.rows.clone(),
            applied: f.applied.clone(),
            applied_rows: f.applied_rows.clone(),
        }
    }

    /// Continues with a checkpoint's forcing, as the fluid that wrote it had it.
    pub fn restore_forcing_memory(&mut self, memory: ForcingMemory) {
        let f = &mut self.scratch.forcing;
        f.version += 1;
        (f.cells, f.rows, f.applied, f.applied_rows) = (memory.cells, memory.rows, memory.applied, memory.applied_rows);
    }

    /// The cells forced from the next step on.
    pub fn direct_forcing(&self) -> &[ForcedCell] {
        &self.scratch.forcing.cells
    }

    /// What the forcing did in the last step, one entry per forced cell in
    /// ascending cell order (empty before the first forced step).
    pub fn applied_forcing(&self) -> &[AppliedForce] {
        &self.scratch.forcing.applied
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A fully covered cell moves with its grain under every rule; a half
    /// covered one at water's τ0 = 0.500667 is pulled by Noble–Torczynski
    /// at w(τ0 − ½)/((1 − w) + τ0 − ½) = 6.66e-4, by the covered fraction at
    /// ½, and by the centre rule fully (its centre is on the surface).
    #[test]
    fn gains_of_the_four_rules() {
        let tau0 = 0.5 + 2.0 / 3.0 * 1e-3;
        for rule in ForcingGain::ALL {
            assert_eq!(forcing_gain(rule, 1.0, tau0), 1.0, "{rule:?}");
            assert_eq!(forcing_gain(rule, 0.0, tau0), 0.0, "{rule:?}");
        }
        let nt = forcing_gain(ForcingGain::NobleTorczynski, 0.5, tau0);
        assert!((nt - 0.5 * (tau0 - 0.5) / (0.5 + tau0 - 0.5)).abs() < 1e-15 && (nt - 6.658e-4).abs() < 1e-6, "{nt}");
        assert_eq!(forcing_gain(ForcingGain::CoveredFraction, 0.5, tau0), 0.5);
        assert_eq!(forcing_gain(ForcingGain::CentreInside, 0.5, tau0), 1.0);
        assert_eq!(forcing_gain(ForcingGain::CentreInside, 0.49, tau0), 0.0);
        assert!(uses_effective_tau(ForcingGain::NobleTorczynskiEffective));
        assert!(!uses_effective_tau(ForcingGain::NobleTorczynski));
    }
}
