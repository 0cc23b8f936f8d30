//! How a [`FluidState`] is written (`/lbm/state`, checkpoints) and read back.
//!
//! Only what a continued run reads is stored: the flags as runs of equal
//! values, and the populations and mass of the liquid (fluid and interface)
//! cells, in cell order, population by population. Gas cells store nothing
//! meaningful and are never computed (an interface cell rebuilds what it
//! pulls from gas, a gas cell turned interface is initialised from its
//! neighbours), and no link reads a wall cell's populations (half-way
//! bounce-back reads the cell's own). The lab column's lattice
//! (19.4 M cells, ~0.6 M of them liquid) is written as ~50 MB instead of
//! 1.6 GB, without the dense copy the derived form needed.
//!
//! The stored order is the cells' (x fastest), whatever the memory layout
//! ([`super::Layout`]). Read back, gas and wall cells get the populations of
//! rest (f_i = w_i, stored 0, written nowhere: `memory.rs`) and zero mass. A run continued from the stored state computes what the
//! uninterrupted run computes, bit for bit (the test below; a resumed
//! coupled run in `tests/tests/resume.rs`). Every gas and wall cell of a
//! running lattice holds exactly these values (conversions write them).

use serde::ser::{SerializeSeq, SerializeStruct};
use serde::{Deserialize, Deserializer, Serialize, Serializer};

use super::{flags, Faces, FluidState, Layout};
use crate::lattice::Q;
use crate::memory::{sparse_zeroed, sparse_zeroed_bytes};
use crate::real::Real;

/// Runs of equal flags, x fastest: (stored code of the flag, run length).
fn flag_runs(cells: &[u8]) -> Vec<(u8, u32)> {
    let mut runs: Vec<(u8, u32)> = Vec::new();
    for &f in cells {
        let f = flags::to_stored(f);
        match runs.last_mut() {
            Some((g, n)) if *g == f && *n < u32::MAX => *n += 1,
            _ => runs.push((f, 1)),
        }
    }
    runs
}

/// The values at `slots` of `values`, `blocks` times with the slots moved
/// `stride` further each time: population by population (stride
/// [`Layout::segment`]), or the masses (one block).
struct LiquidValues<'a, V> {
    values: &'a [V],
    slots: &'a [usize],
    blocks: usize,
    stride: usize,
}

impl<V: Serialize> Serialize for LiquidValues<'_, V> {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        let mut seq = s.serialize_seq(Some(self.blocks * self.slots.len()))?;
        for b in 0..self.blocks {
            for &k in self.slots {
                seq.serialize_element(&self.values[k + b * self.stride])?;
            }
        }
        seq.end()
    }
}

impl<T: Real> Serialize for FluidState<T> {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        let ncells = self.flags.len();
        let liquid: Vec<usize> = (0..ncells).filter(|&c| flags::is_liquid(self.flags[c])).collect();
        let layout = self.layout();
        let bases: Vec<usize> = liquid.iter().map(|&c| layout.base(c)).collect();
        let mut st = s.serialize_struct("FluidState", 8)?;
        st.serialize_field("dims", &self.dims)?;
        st.serialize_field("faces", &self.faces)?;
        st.serialize_field("flag_runs", &flag_runs(&self.flags))?;
        st.serialize_field(
            "populations",
            &LiquidValues { values: &self.populations, slots: &bases, blocks: Q, stride: layout.segment() },
        )?;
        st.serialize_field("mass", &LiquidValues { values: &self.mass, slots: &liquid, blocks: 1, stride: 0 })?;
        st.serialize_field("pending_excess", &self.pending_excess)?;
        st.serialize_field("reference_mass", &self.reference_mass)?;
        st.serialize_field("step", &self.step)?;
        st.end()
    }
}

/// The stored form as read.
#[derive(Deserialize)]
#[serde(rename = "FluidState")]
struct Stored<T> {
    dims: [usize; 3],
    faces: [Faces; 3],
    flag_runs: Vec<(u8, u32)>,
    populations: Vec<T>,
    mass: Vec<f64>,
    pending_excess: f64,
    reference_mass: Option<f64>,
    step: u64,
}

impl<'de, T: Real> Deserialize<'de> for FluidState<T> {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        use serde::de::Error;
        let stored = Stored::<T>::deserialize(d)?;
        let [nx, ny, nz] = stored.dims;
        let ncells = nx
            .checked_mul(ny)
            .and_then(|n| n.checked_mul(nz))
            .filter(|&n| n <= u32::MAX as usize && n.checked_mul(Q).is_some())
            .ok_or_else(|| {
                D::Error::custom(format!("lattice dims {:?}: more cells than a state holds (2^32)", stored.dims))
            })?;
        let runs: u64 = stored.flag_runs.iter().map(|&(_, n)| n as u64).sum();
        if runs != ncells as u64 {
            return Err(D::Error::custom(format!("flag runs cover {runs} cells, the dims {ncells}")));
        }
        // The dims are claimed, not backed by data (gas is not stored): a
        // damaged state must not abort on an impossible allocation.
        let mut probe: Vec<T> = Vec::new();
        if probe.try_reserve_exact(Layout::new(stored.dims).len()).is_err() {
            return Err(D::Error::custom(format!("a lattice of {ncells} cells does not fit in memory")));
        }
        drop(probe);
        let cells = flags_of_runs(ncells, &stored.flag_runs).map_err(D::Error::custom)?;
        let liquid: Vec<usize> = (0..ncells).filter(|&c| flags::is_liquid(cells[c])).collect();
        if stored.populations.len() != Q * liquid.len() || stored.mass.len() != liquid.len() {
            return Err(D::Error::custom(format!(
                "{} liquid cells need {} populations and {} masses, got {} and {}",
                liquid.len(),
                Q * liquid.len(),
                liquid.len(),
                stored.populations.len(),
                stored.mass.len()
            )));
        }
        Ok(FluidState {
            dims: stored.dims,
            faces: stored.faces,
            populations: liquid_populations(stored.dims, &liquid, |i, k| stored.populations[i * liquid.len() + k]),
            mass: liquid_masses(ncells, &liquid, |k| stored.mass[k]),
            flags: cells,
            pending_excess: stored.pending_excess,
            reference_mass: stored.reference_mass,
            step: stored.step,
        })
    }
}

/// The flags of `runs` of stored codes (`flag_runs`), written only where
/// not gas (`memory.rs`). Pre: the runs cover `ncells` cells.
fn flags_of_runs(ncells: usize, runs: &[(u8, u32)]) -> Result<Vec<u8>, String> {
    let mut cells = sparse_zeroed_bytes(ncells);
    let mut start = 0;
    for &(code, n) in runs {
        let flag =
            flags::from_stored(code).ok_or_else(|| format!("cell index {start} has unknown flag code {code}"))?;
        let end = start + n as usize;
        if flag != flags::GAS {
            cells[start..end].fill(flag);
        }
        start = end;
    }
    Ok(cells)
}

/// A lattice's populations with `value(i, k)` for population i of the k-th
/// of the `liquid` cells and 0 (rest) elsewhere, written only there.
fn liquid_populations<T: Real>(dims: [usize; 3], liquid: &[usize], value: impl Fn(usize, usize) -> T) -> Vec<T> {
    let layout = Layout::new(dims);
    let mut populations = sparse_zeroed(layout.len());
    for (k, &c) in liquid.iter().enumerate() {
        let base = layout.base(c);
        for i in 0..Q {
            populations[base + i * layout.segment()] = value(i, k);
        }
    }
    populations
}

/// The masses of the `liquid` cells (`value(k)`), 0 elsewhere, written only there.
fn liquid_masses(ncells: usize, liquid: &[usize], value: impl Fn(usize) -> f64) -> Vec<f64> {
    let mut mass = sparse_zeroed(ncells);
    for (k, &c) in liquid.iter().enumerate() {
        mass[c] = value(k);
    }
    mass
}

/// The layout of `/lbm/state` version 1 (sessions before 28): every
/// cell's flag, populations and mass.
#[derive(Deserialize)]
pub(crate) struct DenseV1<T> {
    dims: [usize; 3],
    faces: [Faces; 3],
    flags: Vec<u8>,
    populations: Vec<T>,
    mass: Vec<f64>,
    pending_excess: f64,
    reference_mass: Option<f64>,
    step: u64,
}

impl<T: Real> TryFrom<DenseV1<T>> for FluidState<T> {
    type Error = String;

    /// Version 1 held population i of cell c at `i * ncells + c`; the
    /// liquid cells' values are moved to the current layout, gas and wall
    /// cells read back as rest, as a version 2 state does.
    fn try_from(v: DenseV1<T>) -> Result<Self, String> {
        let ncells = v.dims.iter().try_fold(1usize, |n, &d| n.checked_mul(d)).unwrap_or(usize::MAX);
        if v.flags.len() != ncells || v.mass.len() != ncells || Some(v.populations.len()) != ncells.checked_mul(Q) {
            return Err(format!(
                "a version 1 lattice of dims {:?} needs {ncells} flags and masses and {Q} populations per cell, got {}, {} and {}",
                v.dims,
                v.flags.len(),
                v.mass.len(),
                v.populations.len()
            ));
        }
        // Written only where not gas, as `flags_of_runs` does.
        let mut cells = sparse_zeroed_bytes(ncells);
        for (c, &code) in v.flags.iter().enumerate() {
            let flag =
                flags::from_stored(code).ok_or_else(|| format!("cell index {c} has unknown flag code {code}"))?;
            if flag != flags::GAS {
                cells[c] = flag;
            }
        }
        let liquid: Vec<usize> = (0..ncells).filter(|&c| flags::is_liquid(cells[c])).collect();
        Ok(FluidState {
            dims: v.dims,
            faces: v.faces,
            populations: liquid_populations(v.dims, &liquid, |i, k| v.populations[i * ncells + liquid[k]]),
            mass: liquid_masses(ncells, &liquid, |k| v.mass[liquid[k]]),
            flags: cells,
            pending_excess: v.pending_excess,
            reference_mass: v.reference_mass,
            step: v.step,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fluid::{Fluid, FluidParams};

    fn encode<T: Real>(s: &FluidState<T>) -> Vec<u8> {
        bincode::serde::encode_to_vec(s, bincode::config::standard()).unwrap()
    }

    fn decode<T: Real>(b: &[u8]) -> FluidState<T> {
        bincode::serde::decode_from_slice(b, bincode::config::standard()).unwrap().0
    }

    #[test]
    fn flag_runs_cover_every_cell_in_order_in_the_recorded_codes() {
        use flags::{FLUID, GAS, INTERFACE, WALL};
        let cells = [GAS, GAS, GAS, FLUID, FLUID, INTERFACE, GAS, WALL, WALL];
        let runs = flag_runs(&cells);
        // docs/recording.md: 0 fluid, 1 wall, 2 interface, 3 gas.
        assert_eq!(runs, vec![(3, 3), (0, 2), (2, 1), (3, 1), (1, 2)]);
        assert_eq!(flags_of_runs(cells.len(), &runs).unwrap(), cells);
        assert!(flag_runs(&[]).is_empty());
    }

    /// A breaking dam: liquid, interface, gas and the walls of the box.
    fn dam() -> Fluid<f32> {
        let params = FluidParams { acceleration: [0.0, 0.0, -1e-4], ..FluidParams::new(0.55) };
        let mut fluid = Fluid::<f32>::new([12, 4, 10], [Faces::Walls; 3], params).unwrap();
        fluid.init_liquid(|[x, _, z]| x < 5 && z < 7).unwrap();
        for _ in 0..30 {
            fluid.step();
        }
        fluid
    }

    #[test]
    fn the_stored_state_keeps_the_liquid_cells_and_continues_bit_for_bit() {
        let mut run = dam();
        let bytes = encode(run.state());
        let state = run.state();
        let back: FluidState<f32> = decode(&bytes);
        let n = state.flags.len();
        assert_eq!(back.flags, state.flags);
        let (mut liquid, mut gas) = (0, 0);
        for c in 0..n {
            if flags::is_liquid(state.flags[c]) {
                liquid += 1;
                assert_eq!(back.mass[c], state.mass[c]);
                for i in 0..Q {
                    assert_eq!(back.population(i, c).to_bits(), state.population(i, c).to_bits());
                }
            } else {
                gas += 1;
            }
        }
        assert!(liquid > 100 && gas > 100, "{liquid} liquid and {gas} other cells");
        // Smaller than the dense layout by about the share of liquid cells.
        assert!(bytes.len() < 4 * (Q + 2) * liquid + 8 * liquid + 64 * 1024, "{} bytes", bytes.len());
        let mut resumed = Fluid::from_state(back, *run.params()).unwrap();
        for _ in 0..40 {
            run.step();
            resumed.step();
        }
        // Every value a run reads is the same (gas cells hold nothing
        // meaningful in either).
        let (a, b) = (run.state(), resumed.state());
        assert_eq!(a.flags, b.flags);
        assert_eq!(a.pending_excess.to_bits(), b.pending_excess.to_bits());
        for c in (0..n).filter(|&c| flags::is_liquid(a.flags[c])) {
            assert_eq!(a.mass[c].to_bits(), b.mass[c].to_bits(), "mass of cell {c}");
            for i in 0..Q {
                assert_eq!(a.population(i, c).to_bits(), b.population(i, c).to_bits(), "f_{i} of cell {c}");
            }
        }
        assert_eq!(run.liquid_mass().to_bits(), resumed.liquid_mass().to_bits());
    }

    #[test]
    fn a_damaged_stored_state_is_refused() {
        let run = dam();
        let mut stored: Stored<f32> = decode_stored(&encode(run.state()));
        stored.flag_runs[0].1 += 1;
        let bytes = encode_stored(&stored);
        let err =
            bincode::serde::decode_from_slice::<FluidState<f32>, _>(&bytes, bincode::config::standard()).unwrap_err();
        assert!(err.to_string().contains("flag runs cover"), "{err}");
        stored.flag_runs[0].1 -= 1;
        let code = stored.flag_runs[1].0;
        stored.flag_runs[1].0 = 7;
        let err = bincode::serde::decode_from_slice::<FluidState<f32>, _>(
            &encode_stored(&stored),
            bincode::config::standard(),
        )
        .unwrap_err();
        assert!(err.to_string().contains("unknown flag code 7"), "{err}");
        stored.flag_runs[1].0 = code;
        stored.mass.pop();
        let err = bincode::serde::decode_from_slice::<FluidState<f32>, _>(
            &encode_stored(&stored),
            bincode::config::standard(),
        )
        .unwrap_err();
        assert!(err.to_string().contains("liquid cells need"), "{err}");
    }

    fn decode_stored(b: &[u8]) -> Stored<f32> {
        bincode::serde::decode_from_slice(b, bincode::config::standard()).unwrap().0
    }

    fn encode_stored(s: &Stored<f32>) -> Vec<u8> {
        #[derive(Serialize)]
        struct Out<'a> {
            dims: [usize; 3],
            faces: [Faces; 3],
            flag_runs: &'a [(u8, u32)],
            populations: &'a [f32],
            mass: &'a [f64],
            pending_excess: f64,
            reference_mass: Option<f64>,
            step: u64,
        }
        bincode::serde::encode_to_vec(
            Out {
                dims: s.dims,
                faces: s.faces,
                flag_runs: &s.flag_runs,
                populations: &s.populations,
                mass: &s.mass,
                pending_excess: s.pending_excess,
                reference_mass: s.reference_mass,
                step: s.step,
            },
            bincode::config::standard(),
        )
        .unwrap()
    }
}
