//! The lattice state and its time step.
//!
//! [`Fluid::step`] is one stage, `stream_collide`, fused per cell: pull the 19
//! incoming populations (half-way bounce-back where the source is a wall),
//! take the moments, relax (BGK or TRT, each with the Smagorinsky eddy
//! viscosity), add Guo's forcing, and write the post-collision populations to
//! the second lattice. The lattices are then swapped (A/B pattern). Work is
//! split over z-planes with rayon; the step allocates nothing.
//!
//! Storage, chosen for a bandwidth-bound kernel (lbm-free-surface.md §5) and
//! for memory that follows the liquid:
//! * populations in x-segments of up to [`SEGMENT`] cells ([`Layout`]): a
//!   segment's 19 populations together, struct of arrays inside it, so one
//!   x-run of one direction is contiguous and the kernel works on chunks of
//!   up to [`LANES`] cells with plain vector loops; segments the liquid
//!   never reaches are never written and cost no memory (`memory.rs`);
//! * shifted: the stored value is f_i − w_i (ρ0 = 1), as FluidX3D does
//!   (Lehmann et al. 2022, PRE 106, 015308). Near rest f_i − w_i is ~1e-3 of
//!   f_i, so f32 keeps ~3 more significant digits of the non-equilibrium
//!   part and of the density deviation than unshifted f32 would;
//! * the stored populations are post-collision: ρ and u at the current time
//!   are read from them directly (Guo's scheme puts ρu + F/2 into the
//!   post-collision momentum), so no macroscopic field is written in the hot
//!   loop;
//! * one flag byte per cell ([`flags`]), and one class byte per x-row that
//!   says whether the row holds liquid at all, whether it holds interface
//!   cells, and whether its pulls can touch a non-fluid cell. Rows with no
//!   liquid (gas above the free surface) cost nothing; rows far from walls
//!   and the surface skip the per-cell flag checks.
//!
//! The free surface (mass tracking, `free_surface`) adds interface and gas
//! cells: the kernel rebuilds the populations an interface cell pulls from
//! gas and accumulates its mass exchange in the same pass; conversions run
//! after it. Direct forcing of particle-covered cells (Eq. 5, [`ForcedCell`],
//! driven by [`crate::coupling`]) is computed in the same pass, between the
//! pull and the collision, for the listed cells only.

use rayon::prelude::*;
use runtime::isa::Isa;

use crate::memory::{release_zero_pages, release_zeros, sparse_zeroed, sparse_zeroed_bytes};
use schemas::scene::ForcingGain;
use serde::{Deserialize, Serialize};
use std::time::Instant;

use crate::lattice::{E, OPP, Q, W};
use crate::real::Real;
use crate::watchdog::{Instability, Quantity, WatchdogLimits};

mod collision;
mod forcing;
mod free_surface;
#[cfg(test)]
mod isa_tests;
mod kernel;
mod layout;
mod stored;
#[cfg(test)]
mod tests;

pub use forcing::{forcing_gain, uses_effective_tau, AppliedForce, ForcedCell, ForcingMemory};
pub use free_surface::{InterfaceCell, Sample};
use kernel::*;
pub use layout::{Layout, SEGMENT};
pub(crate) use stored::DenseV1;

/// Cell flags. Liquid cells (fluid, interface) have bit 0 set, so the
/// kernel tells "pull from here" from "bounce back" with one bit test, and
/// gas is 0, so that the flags of a box's gas are memory never written
/// (`memory.rs`): a flume's flags cost memory only where the liquid has
/// been, like its populations.
///
/// These are the values in memory. A stored or recorded state keeps the
/// codes it has always had (0 fluid, 1 wall, 2 interface, 3 gas:
/// [`flags::to_stored`], [`flags::from_stored`]).
pub mod flags {
    /// An empty cell: stores nothing meaningful and is never computed.
    pub const GAS: u8 = 0;
    /// A liquid cell: collides and streams.
    pub const FLUID: u8 = 1;
    /// A no-slip obstacle: links into it bounce back half-way.
    pub const WALL: u8 = 2;
    /// A partly filled cell of the free surface: collides and streams, and
    /// tracks its liquid mass m; populations pulled from gas are rebuilt.
    pub const INTERFACE: u8 = 3;

    /// Fluid or interface: the cells that collide, stream and hold liquid.
    #[inline(always)]
    pub fn is_liquid(flag: u8) -> bool {
        flag & 1 == 1
    }

    /// One of the four flags above (and not a mark of a conversion).
    pub fn is_known(flag: u8) -> bool {
        flag <= INTERFACE
    }

    /// The code of `flag` in a stored or recorded state (docs/recording.md).
    pub fn to_stored(flag: u8) -> u8 {
        match flag {
            FLUID => 0,
            WALL => 1,
            INTERFACE => 2,
            GAS => 3,
            other => other,
        }
    }

    /// The flag of a stored code, `None` for an unknown one.
    pub fn from_stored(code: u8) -> Option<u8> {
        match code {
            0 => Some(FLUID),
            1 => Some(WALL),
            2 => Some(INTERFACE),
            3 => Some(GAS),
            _ => None,
        }
    }
}

/// Cells per vector chunk of a row: long enough that each of the 38 streams
/// moves 512 B (f32) per visit, which the hardware prefetchers need (32 lanes
/// ran ~30 % slower), short enough that the 19-row buffer stays in L1.
pub const LANES: usize = 128;

/// What lies beyond the two faces of the box normal to one axis.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum Faces {
    /// The box wraps around.
    Periodic,
    /// No-slip walls half a cell beyond the first and last nodes.
    Walls,
}

/// The collision operator.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub enum Collision {
    /// Single relaxation time 1/τ.
    Bgk,
    /// Two relaxation times (Ginzburg): τ+ sets the viscosity, τ− = ½ + Λ/(τ+ − ½).
    /// Λ = 3/16 puts the half-way bounce-back wall exactly mid-link for
    /// Poiseuille flow; Λ = 1/4 is the most stable choice.
    Trt {
        /// The magic parameter Λ.
        magic: f64,
    },
}

impl Collision {
    /// TRT with Λ = 3/16 (as FluidX3D).
    pub const TRT_3_16: Collision = Collision::Trt { magic: 3.0 / 16.0 };
}

/// Physical parameters, lattice units.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct FluidParams {
    /// Molecular relaxation time τ0 = 3ν_L + ½ (see [`crate::units::Units::tau_from_viscosity`]); > ½.
    pub tau: f64,
    pub collision: Collision,
    /// Smagorinsky constant C of Eq. 4 (paper: 0.16); 0 switches the eddy viscosity off.
    pub smagorinsky: f64,
    /// Body acceleration (gravity), lattice units; the force density is ρ a,
    /// in interface cells too (docs/lbm.md, "Free surface").
    pub acceleration: [f64; 3],
    /// Free-surface conversion margin κ: an interface cell fills when
    /// m > (1 + κ)ρ and empties when m < −κρ (Thürey 2007: 1e-3). The margin
    /// stops cells from toggling between states on round-off-sized flux.
    #[serde(default = "default_kappa")]
    pub kappa: f64,
}

fn default_kappa() -> f64 {
    1e-3
}

impl FluidParams {
    /// τ0 with the defaults: BGK, C = 0.16, no body force. BGK is the
    /// default because at the paper's τ0 = 0.500667 it survived even without
    /// Smagorinsky where TRT 3/16 (τ− ≈ 280) blew up, and its eddy viscosity
    /// matches Eq. 4 (tests/stability.rs, tests/flows.rs); TRT 3/16 is the
    /// choice when the wall position matters (exact Poiseuille).
    pub fn new(tau: f64) -> Self {
        FluidParams {
            tau,
            collision: Collision::Bgk,
            smagorinsky: 0.16,
            acceleration: [0.0; 3],
            kappa: default_kappa(),
        }
    }

    fn validate(&self) -> Result<(), ConfigError> {
        if !(self.tau.is_finite() && self.tau > 0.5) {
            return Err(ConfigError::Tau(self.tau));
        }
        if !(self.smagorinsky.is_finite() && self.smagorinsky >= 0.0) {
            return Err(ConfigError::Smagorinsky(self.smagorinsky));
        }
        if let Collision::Trt { magic } = self.collision {
            if !(magic.is_finite() && magic > 0.0) {
                return Err(ConfigError::Magic(magic));
            }
        }
        if !self.acceleration.iter().all(|a| a.is_finite()) {
            return Err(ConfigError::Acceleration(self.acceleration));
        }
        if !(0.0..0.5).contains(&self.kappa) {
            return Err(ConfigError::Kappa(self.kappa));
        }
        Ok(())
    }
}

/// Why a fluid cannot be built or changed as asked.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ConfigError {
    #[error("relaxation time tau must be finite and > 0.5, got {0} (tau = 0.5 is zero viscosity)")]
    Tau(f64),
    #[error("Smagorinsky constant must be finite and >= 0, got {0}")]
    Smagorinsky(f64),
    #[error("TRT magic parameter must be finite and > 0, got {0}")]
    Magic(f64),
    #[error("body acceleration must be finite, got {0:?}")]
    Acceleration([f64; 3]),
    #[error("free-surface conversion margin kappa must lie in [0, 0.5), got {0}")]
    Kappa(f64),
    #[error("set_flag takes FLUID or WALL (interface and gas come from init_liquid / remove_walls), got {0}")]
    Flag(u8),
    #[error("cell {0:?} holds no liquid (a wall or gas cell stores rest and is never computed), so it has no equilibrium to set")]
    NotLiquid([usize; 3]),
    #[error("cell {0:?} is not a wall, so it cannot be removed")]
    NotWall([usize; 3]),
    #[error("box dimensions must be >= 1 cell each, got {0:?}")]
    Dims([usize; 3]),
    #[error("cell {cell:?} lies outside the box {dims:?}")]
    OutOfBox { cell: [usize; 3], dims: [usize; 3] },
    #[error("state is inconsistent: {0}")]
    State(String),
    #[error("cell {0:?} would be a fluid cell next to gas: an interface cell must separate them (set geometry before init_liquid)")]
    FluidNextToGas([usize; 3]),
    #[error("forced cell {cell}: {why}")]
    Forcing { cell: usize, why: &'static str },
}

/// Everything needed to continue a run exactly (with [`FluidParams`]).
/// Serialised in its stored form (`fluid/stored.rs`): the liquid cells only.
#[derive(Debug, Clone, PartialEq)]
pub struct FluidState<T> {
    /// Cells along x, y, z.
    pub dims: [usize; 3],
    pub faces: [Faces; 3],
    /// One of [`flags`] per cell, x fastest.
    pub flags: Vec<u8>,
    /// Post-collision f_i − w_i, population i of cell c at
    /// [`Layout::index`]`(i, c)` of [`FluidState::layout`]; 0 (rest) in gas
    /// and wall cells.
    pub populations: Vec<T>,
    /// Liquid mass m of each interface cell (f64 whatever `T` is, so that
    /// mass is conserved to f64 round-off); 0 in all other cells (a fluid
    /// cell's mass is its density ρ).
    pub mass: Vec<f64>,
    /// Excess mass of conversions that found no interface neighbour to take
    /// it; counted in [`Fluid::liquid_mass`], never dropped.
    pub pending_excess: f64,
    /// Liquid mass when the liquid was set up, for [`Fluid::mass_drift`].
    pub reference_mass: Option<f64>,
    /// Steps taken.
    pub step: u64,
}

impl<T: Real> FluidState<T> {
    /// Where each population of each cell lies in `populations`.
    pub fn layout(&self) -> Layout {
        Layout::new(self.dims)
    }

    /// Stored f_i − w_i of cell index `c` (x fastest).
    pub fn population(&self, i: usize, c: usize) -> T {
        self.populations[self.layout().index(i, c)]
    }
}

/// Steps between two [`Fluid::release_dry_memory`]: 0.04 s of the lab
/// column, in which its front moves some tens of cells (a segment is 128),
/// and a release costs a pass over the flags (~5 ms on the lab column).
pub const RELEASE_EVERY: u64 = 500;

/// Row classes (bits of `Scratch::rows`).
/// The row holds a fluid or interface cell; rows without are skipped.
const ROW_ANY_LIQUID: u8 = 1;
const ROW_ALL_FLUID: u8 = 2;
/// Every source row of every pull is all fluid: no per-cell wall checks needed.
const ROW_SOURCES_FLUID: u8 = 4;
/// The row holds an interface cell (reconstruction and mass exchange).
const ROW_ANY_INTERFACE: u8 = 8;
/// The row holds a wall cell (an obstacle inside the box).
const ROW_ANY_WALL: u8 = 16;
/// No source row of any pull holds a wall cell: sources are liquid or gas.
const ROW_SOURCES_NO_WALL: u8 = 32;

/// Buffers the step needs besides the state.
#[derive(Debug, Clone)]
struct Scratch<T> {
    /// The lattice written by the step.
    next: Vec<T>,
    /// Class of each x-row, index `z * ny + y`.
    rows: Vec<u8>,
    /// Liquid span of each x-row: its first liquid cell and one past its
    /// last (0..0 without liquid), kept with the classes.
    spans: Vec<(u32, u32)>,
    rows_stale: bool,
    /// Fill ε = m/ρ of every cell (1 fluid, 0 gas and wall) as of the end of
    /// the last step: the old-level ε both sides of an interface–interface
    /// link use, which makes the exchange antisymmetric.
    fill: Vec<f64>,
    /// Density ρ of every interface cell (stale elsewhere), summed by the
    /// kernel from the populations it writes, as [`Fluid::density_at`] sums
    /// them, and kept by the conversions for the cells they make interface:
    /// the conversions read one value instead of 19 scattered ones.
    interface_density: Vec<f64>,
    /// Interface cells, ascending index.
    interface: Vec<usize>,
    /// Number of fluid cells.
    fluid_count: usize,
    /// Times the pending excess was given back to the liquid, and the mass
    /// given back (lattice units): diagnostics, not part of the state.
    pending_returned: u64,
    returned_mass: f64,
    /// Conversion work lists, reused every step.
    lists: free_surface::Lists,
    /// Per segment, whether it holds no liquid ([`Fluid::release_dry_memory`]).
    dry_segments: Vec<bool>,
    /// Direct forcing for the next steps and what it did in the last one.
    forcing: forcing::Forcing,
}

/// A D3Q19 fluid in a box of cells.
#[derive(Debug, Clone)]
pub struct Fluid<T: Real = f32> {
    state: FluidState<T>,
    params: FluidParams,
    scratch: Scratch<T>,
    /// The instruction set the stream-collide kernel runs with (results do
    /// not depend on it); `Isa::current()` unless set.
    isa: Isa,
    /// Wall seconds spent in each stage of [`Fluid::step`] since creation.
    pub stage_seconds: FluidStageSeconds,
    /// A step begun by [`Fluid::begin_step`] still needs its free-surface
    /// conversions ([`Fluid::finish_step`]).
    surface_pending: bool,
}

/// Wall time per stage of [`Fluid::step`], s.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct FluidStageSeconds {
    /// Row classification after flag changes, and sizing the applied-force list.
    pub prepare: f64,
    pub stream_collide: f64,
    /// Fill conversions, excess distribution, interface list (the mass
    /// exchange Δm is part of `stream_collide`), and the release of dry
    /// segments every [`RELEASE_EVERY`] steps.
    pub update_surface: f64,
}

/// Per-step constants of the collision, in the kernel's float type.
#[derive(Clone, Copy)]
struct Coefficients<T> {
    tau0: T,
    tau0_sq: T,
    /// 18√2 C² of the closed-form τ_eff.
    smag: T,
    magic: T,
    accel: [T; 3],
}

/// Stores `v` in `slot` unless it holds those bits already (compared bit
/// for bit: -0 is not +0), so that memory never written stays unbacked
/// (`memory.rs`).
fn write_if_changed(slot: &mut f64, v: f64) {
    if slot.to_bits() != v.to_bits() {
        *slot = v;
    }
}

impl<T: Real> Fluid<T> {
    /// A box of fluid cells at rest (u = 0 under the body force), ρ = 1.
    pub fn new(dims: [usize; 3], faces: [Faces; 3], params: FluidParams) -> Result<Self, ConfigError> {
        params.validate()?; // before the fill writes the whole box
        let mut state = Self::blank(dims, faces, flags::FLUID)?;
        let rest = crate::lattice::equilibrium(1.0, params.acceleration.map(|a| 0.5 * a));
        let rest: [T; Q] = std::array::from_fn(|i| T::from_f64(rest[i] - W[i]));
        let layout = state.layout();
        state.populations.par_chunks_mut(Q * layout.segment()).enumerate().for_each(|(k, segment)| {
            // The segment's cells (the padding of a row's last one stays 0).
            let cells = layout.segment_cells(k).1.len();
            for (i, run) in segment.chunks_exact_mut(layout.segment()).enumerate() {
                run[..cells].fill(rest[i]);
            }
        });
        Self::from_state(state, params)
    }

    /// A box of gas: no liquid until [`Fluid::init_liquid`]. Nothing is
    /// written to the populations, so set-up costs memory and time only
    /// where the liquid is put (`memory.rs`).
    pub fn empty(dims: [usize; 3], faces: [Faces; 3], params: FluidParams) -> Result<Self, ConfigError> {
        Self::from_state(Self::blank(dims, faces, flags::GAS)?, params)
    }

    /// A state of `dims` cells all flagged `flag`, populations and masses 0
    /// (allocated, not written).
    fn blank(dims: [usize; 3], faces: [Faces; 3], flag: u8) -> Result<FluidState<T>, ConfigError> {
        let ncells = dims[0]
            .checked_mul(dims[1])
            .and_then(|n| n.checked_mul(dims[2]))
            .filter(|&n| n > 0 && n.checked_mul(Q).is_some())
            .ok_or(ConfigError::Dims(dims))?;
        Ok(FluidState {
            dims,
            faces,
            flags: if flag == flags::GAS { sparse_zeroed_bytes(ncells) } else { vec![flag; ncells] },
            populations: sparse_zeroed(Layout::new(dims).len()),
            mass: sparse_zeroed(ncells),
            pending_excess: 0.0,
            reference_mass: None,
            step: 0,
        })
    }

    /// Continues from a saved state.
    ///
    /// Pre: gas and wall cells hold 0 in `populations` and `mass` (what a
    /// stored state reads back as and every step leaves them with; checked
    /// in debug builds). The memory of a box's gas is never written, and
    /// [`Fluid::release_dry_memory`] relies on it.
    pub fn from_state(state: FluidState<T>, params: FluidParams) -> Result<Self, ConfigError> {
        params.validate()?;
        let [nx, ny, nz] = state.dims;
        let ncells = nx * ny * nz;
        let layout = state.layout();
        if ncells == 0
            || state.flags.len() != ncells
            || state.populations.len() != layout.len()
            || state.mass.len() != ncells
        {
            return Err(ConfigError::State(format!(
                "dims {:?} need {} flags, {} populations and {} masses, got {}, {} and {}",
                state.dims,
                ncells,
                layout.len(),
                ncells,
                state.flags.len(),
                state.populations.len(),
                state.mass.len()
            )));
        }
        if let Some(c) = state.flags.iter().position(|&f| !flags::is_known(f)) {
            return Err(ConfigError::State(format!("cell index {c} has unknown flag {}", state.flags[c])));
        }
        if !state.pending_excess.is_finite() || state.mass.iter().any(|m| !m.is_finite()) {
            return Err(ConfigError::State("liquid masses must be finite".into()));
        }
        // Only for boxes of unit-test size: the check reads the whole box,
        // which maps every page of the gas (to the shared zero page).
        debug_assert!(
            ncells > 1 << 16
                || (0..ncells)
                    .filter(|&c| !flags::is_liquid(state.flags[c]))
                    .all(|c| state.mass[c].to_bits() == 0
                        && (0..Q).all(|i| state.population(i, c).to_f64().to_bits() == 0)),
            "a gas or wall cell of the state holds a value (they must hold 0)"
        );
        let scratch = Scratch {
            // The step writes every liquid cell of `next` before it is read;
            // gas and wall cells hold 0 in both lattices.
            next: sparse_zeroed(layout.len()),
            rows: vec![0; ny * nz],
            spans: vec![(0, 0); ny * nz],
            rows_stale: true,
            fill: sparse_zeroed(ncells),
            interface_density: sparse_zeroed(ncells),
            interface: Vec::new(),
            fluid_count: 0,
            pending_returned: 0,
            returned_mass: 0.0,
            lists: Default::default(),
            dry_segments: Vec::new(),
            forcing: Default::default(),
        };
        let mut fluid = Fluid {
            state,
            params,
            scratch,
            isa: Isa::current(),
            stage_seconds: FluidStageSeconds::default(),
            surface_pending: false,
        };
        // The kernel relies on it: only interface cells pull from gas.
        let [nx, ny, _] = fluid.state.dims;
        let flags = &fluid.state.flags;
        if let Some(c) = (0..ncells).into_par_iter().find_first(|&c| flags[c] == flags::FLUID && fluid.borders_gas(c)) {
            return Err(ConfigError::FluidNextToGas([c % nx, (c / nx) % ny, c / (nx * ny)]));
        }
        fluid.rebuild_lists();
        fluid.classify_rows();
        Ok(fluid)
    }

    pub fn state(&self) -> &FluidState<T> {
        debug_assert!(!self.surface_pending, "a step begun by begin_step needs finish_step before its state is read");
        &self.state
    }
    /// Runs the kernel with `isa`, lowered to what the CPU supports.
    pub fn set_isa(&mut self, isa: Isa) {
        self.isa = isa.min(Isa::best_supported());
    }
    pub fn isa(&self) -> Isa {
        self.isa
    }
    pub fn params(&self) -> &FluidParams {
        &self.params
    }
    pub fn set_params(&mut self, params: FluidParams) -> Result<(), ConfigError> {
        params.validate()?;
        self.params = params;
        Ok(())
    }
    pub fn dims(&self) -> [usize; 3] {
        self.state.dims
    }
    pub fn ncells(&self) -> usize {
        self.state.flags.len()
    }
    pub fn steps(&self) -> u64 {
        self.state.step
    }

    fn index(&self, cell: [usize; 3]) -> Result<usize, ConfigError> {
        let [nx, ny, nz] = self.state.dims;
        if cell[0] < nx && cell[1] < ny && cell[2] < nz {
            Ok((cell[2] * ny + cell[1]) * nx + cell[0])
        } else {
            Err(ConfigError::OutOfBox { cell, dims: self.state.dims })
        }
    }

    pub fn flag(&self, cell: [usize; 3]) -> Result<u8, ConfigError> {
        Ok(self.state.flags[self.index(cell)?])
    }

    /// Makes `cell` a wall (`flags::WALL`) or a fluid cell (`flags::FLUID`):
    /// geometry set-up. An interface cell overwritten here loses its tracked
    /// mass; set walls before [`Fluid::init_liquid`], and open a gate during a
    /// run with [`Fluid::remove_walls`].
    pub fn set_flag(&mut self, cell: [usize; 3], flag: u8) -> Result<(), ConfigError> {
        // A begun step's conversions read the kernel's interface densities: finish it first.
        self.finish_step();
        let c = self.index(cell)?;
        if flag != flags::FLUID && flag != flags::WALL {
            return Err(ConfigError::Flag(flag));
        }
        if flag == flags::FLUID && self.borders_gas(c) {
            return Err(ConfigError::FluidNextToGas(cell));
        }
        let old = self.state.flags[c];
        if old == flags::INTERFACE {
            if let Ok(k) = self.scratch.interface.binary_search(&c) {
                self.scratch.interface.remove(k);
            }
        }
        if old == flags::FLUID {
            self.scratch.fluid_count -= 1;
        }
        self.state.flags[c] = flag;
        // Zeros are written only over values that are not: a gate's wall
        // cells above the liquid keep their masses' memory unbacked.
        write_if_changed(&mut self.state.mass[c], 0.0);
        self.scratch.rows_stale = true;
        if flag == flags::FLUID {
            self.scratch.fluid_count += 1;
            self.scratch.fill[c] = 1.0;
        } else {
            write_if_changed(&mut self.scratch.fill[c], 0.0);
            // The step never writes non-liquid cells; keeping them equal in
            // both lattices makes the state independent of the step parity.
            self.write_cell(c, &[0.0; Q]);
        }
        Ok(())
    }

    /// Sets liquid `cell` to equilibrium with density `rho` and velocity `u`
    /// (lattice units); a gas or wall cell is refused.
    ///
    /// The stored populations are post-collision, whose momentum is ρ(u + a/2)
    /// under Guo forcing, so the equilibrium is taken at u + a/2; the cell
    /// then reports exactly (ρ, u).
    pub fn set_equilibrium(&mut self, cell: [usize; 3], rho: f64, u: [f64; 3]) -> Result<(), ConfigError> {
        // A begun step's conversions read the kernel's interface densities: finish it first.
        self.finish_step();
        let c = self.index(cell)?;
        // Gas and wall cells hold 0 (rest) in both lattices: what a stored
        // state reads back and what memory never written holds (memory.rs).
        if !flags::is_liquid(self.state.flags[c]) {
            return Err(ConfigError::NotLiquid(cell));
        }
        let a = self.params.acceleration;
        let feq = crate::lattice::equilibrium(rho, [u[0] + 0.5 * a[0], u[1] + 0.5 * a[1], u[2] + 0.5 * a[2]]);
        self.write_cell(c, &std::array::from_fn(|i| feq[i] - W[i]));
        if self.state.flags[c] == flags::INTERFACE {
            self.scratch.fill[c] = self.state.mass[c] / self.density_at(c);
        }
        Ok(())
    }

    /// Sets the stored f_i − w_i of cell index `c` in both lattices. A
    /// value already there is not written again, so zeroing gas that was
    /// never liquid backs no memory (`memory.rs`).
    fn write_cell(&mut self, c: usize, g: &[f64; Q]) {
        let layout = self.state.layout();
        let base = layout.base(c);
        for i in 0..Q {
            let v = T::from_f64(g[i]);
            for lattice in [&mut self.state.populations, &mut self.scratch.next] {
                let slot = &mut lattice[base + i * layout.segment()];
                // Compared bit for bit: -0 is not +0.
                if slot.to_f64().to_bits() != v.to_f64().to_bits() {
                    *slot = v;
                }
            }
        }
    }

    /// Whether a D3Q19 neighbour of cell index `c` is gas.
    fn borders_gas(&self, c: usize) -> bool {
        self.neighbours(c)[1..].iter().flatten().any(|&nb| self.state.flags[nb] == flags::GAS)
    }

    /// Density and velocity of cell index `c` (lattice units), from the
    /// post-collision populations: ρ = Σf, u = (Σ f e − F/2)/ρ.
    fn moments_at(&self, c: usize) -> (f64, [f64; 3]) {
        self.moments_with(c, self.scratch.forcing.last_force(c, self.state.dims[0]))
    }

    /// [`Fluid::moments_at`] with the cell's last direct force `ib` given.
    fn moments_with(&self, c: usize, ib: [f64; 3]) -> (f64, [f64; 3]) {
        let layout = self.state.layout();
        let p = &self.state.populations[layout.base(c)..];
        let mut drho = 0.0;
        let mut j = [0.0; 3];
        for i in 0..Q {
            let g = p[i * layout.segment()].to_f64();
            drho += g;
            for a in 0..3 {
                j[a] += E[i][a] as f64 * g;
            }
        }
        let rho = 1.0 + drho;
        let acc = self.params.acceleration;
        // A forced cell's stored momentum also holds half its last direct force.
        (rho, std::array::from_fn(|a| (j[a] - 0.5 * ib[a]) / rho - 0.5 * acc[a]))
    }

    /// Density ρ = Σ f_i of cell index `c`, summed as [`Fluid::moments_at`] does.
    fn density_at(&self, c: usize) -> f64 {
        let layout = self.state.layout();
        let p = &self.state.populations[layout.base(c)..];
        density_of(|i| p[i * layout.segment()].to_f64())
    }

    /// Density and velocity of `cell`, lattice units.
    pub fn moments(&self, cell: [usize; 3]) -> Result<(f64, [f64; 3]), ConfigError> {
        Ok(self.moments_at(self.index(cell)?))
    }

    /// Liquid mass Σ_F ρ + Σ_I m + pending excess (lattice units: ρ0Δx³),
    /// summed in f64 in a fixed order (ascending cell, whatever the thread
    /// count: the terms are found plane by plane in parallel, then added in
    /// order). Without a free surface this is Σρ.
    pub fn liquid_mass(&self) -> f64 {
        let fl = &self.state.flags;
        let terms: Vec<f64> = self
            .liquid_planes()
            .flat_map_iter(|cells| {
                cells.filter_map(move |c| match fl[c] {
                    flags::FLUID => Some(self.density_at(c)),
                    flags::INTERFACE => Some(self.state.mass[c]),
                    _ => None,
                })
            })
            .collect();
        terms.iter().sum::<f64>() + self.state.pending_excess
    }

    /// Each cell holding liquid (fill ε > 0) with its liquid mass ρε
    /// (lattice units), in ascending cell order; planes in parallel.
    pub fn liquid_cell_masses(&self) -> Vec<(usize, f64)> {
        let fill = &self.scratch.fill;
        self.liquid_planes()
            .flat_map_iter(|cells| cells.filter(|&c| fill[c] > 0.0).map(|c| (c, self.density_at(c) * fill[c])))
            .collect()
    }

    /// Per z-plane, in order, the cells of its liquid spans (the rows'
    /// first to last liquid cell; rows without liquid are skipped).
    fn liquid_planes(&self) -> impl IndexedParallelIterator<Item = impl Iterator<Item = usize> + '_> + '_ {
        let [nx, ny, nz] = self.state.dims;
        let stale = self.scratch.rows_stale;
        (0..nz).into_par_iter().map(move |z| {
            (0..ny).flat_map(move |y| {
                let r = z * ny + y;
                // Row spans are valid unless flags changed since the last step.
                let (lo, hi) =
                    if stale { (0, nx) } else { (self.scratch.spans[r].0 as usize, self.scratch.spans[r].1 as usize) };
                (r * nx + lo)..(r * nx + hi)
            })
        })
    }

    /// (liquid mass − reference)/reference, the reference being the liquid
    /// mass when [`Fluid::init_liquid`] (or [`Fluid::mark_reference_mass`])
    /// ran; `None` before either.
    pub fn mass_drift(&self) -> Option<f64> {
        self.state.reference_mass.map(|m0| (self.liquid_mass() - m0) / m0)
    }

    /// Takes the current liquid mass as the reference of [`Fluid::mass_drift`].
    pub fn mark_reference_mass(&mut self) {
        self.state.reference_mass = Some(self.liquid_mass());
    }

    /// Visits the liquid cells of plane z in ascending order with their
    /// density and velocity ([`Fluid::moments_at`]), walking the forced
    /// cells along: a binary search of them per cell cost more than the
    /// moments in a packed bed (every liquid cell forced).
    fn plane_liquid_moments(&self, z: usize, mut visit: impl FnMut(usize, f64, [f64; 3])) {
        let [nx, ny, _] = self.state.dims;
        let (start, end) = (z * nx * ny, (z + 1) * nx * ny);
        let mut forced = self.scratch.forcing.cursor_from(start);
        for c in start..end {
            if flags::is_liquid(self.state.flags[c]) {
                let (rho, u) = self.moments_with(c, forced.force_at(c));
                visit(c, rho, u);
            }
        }
    }

    /// ½ Σ m u² over fluid (m = ρ) and interface cells, lattice units.
    /// Planes in parallel, summed in plane order (the same for any thread count).
    pub fn kinetic_energy(&self) -> f64 {
        let planes: Vec<f64> = (0..self.state.dims[2])
            .into_par_iter()
            .map(|z| {
                let mut e = 0.0;
                self.plane_liquid_moments(z, |c, rho, u| {
                    let m = if self.state.flags[c] == flags::INTERFACE { self.state.mass[c] } else { rho };
                    e += 0.5 * m * (u[0] * u[0] + u[1] * u[1] + u[2] * u[2]);
                });
                e
            })
            .collect();
        planes.iter().sum()
    }

    /// Largest |u| over fluid and interface cells, lattice units.
    pub fn max_speed(&self) -> f64 {
        (0..self.state.dims[2])
            .into_par_iter()
            .map(|z| {
                let mut max = 0.0_f64;
                self.plane_liquid_moments(z, |_, _, u| max = max.max((u[0] * u[0] + u[1] * u[1] + u[2] * u[2]).sqrt()));
                max
            })
            .reduce(|| 0.0, f64::max)
    }

    /// The first fluid or interface cell (lowest index) whose populations are
    /// not finite, whose density leaves the limits, whose speed exceeds the
    /// Mach limit, or (interface) whose fill ε = m/ρ leaves
    /// [−κ − margin, 1 + κ + margin]. Never panics; meant to run every few
    /// steps. Mass drift is reported by [`Fluid::mass_drift`].
    pub fn check(&self, limits: &WatchdogLimits) -> Result<(), Instability> {
        let [nx, ny, nz] = self.state.dims;
        let layout = self.state.layout();
        let cs = crate::lattice::CS2.sqrt();
        let found = (0..nz).into_par_iter().find_map_first(|z| {
            // The forced cells walked along, as in `plane_liquid_moments`.
            let mut forced = self.scratch.forcing.cursor_from(z * nx * ny);
            for c in z * nx * ny..(z + 1) * nx * ny {
                let flag = self.state.flags[c];
                if !flags::is_liquid(flag) {
                    continue;
                }
                let p = &self.state.populations[layout.base(c)..];
                let s = layout.segment();
                let bad = if let Some(i) = (0..Q).find(|&i| !p[i * s].is_finite()) {
                    Some((Quantity::Population(i), p[i * s].to_f64()))
                } else {
                    let (rho, u) = self.moments_with(c, forced.force_at(c));
                    let mach = (u[0] * u[0] + u[1] * u[1] + u[2] * u[2]).sqrt() / cs;
                    // Written so that NaN moments count as out of bounds.
                    if !(limits.min_density..=limits.max_density).contains(&rho) || rho.is_nan() {
                        Some((Quantity::Density, rho))
                    } else if mach.is_nan() || mach > limits.max_mach {
                        Some((Quantity::Mach, mach))
                    } else if flag == flags::INTERFACE {
                        let fill = self.state.mass[c] / rho;
                        let margin = self.params.kappa + limits.fill_margin;
                        (!(-margin..=1.0 + margin).contains(&fill)).then_some((Quantity::Fill, fill))
                    } else {
                        None
                    }
                };
                if let Some((quantity, value)) = bad {
                    let cell = [c % nx, (c / nx) % ny, c / (nx * ny)];
                    return Some(Instability { step: self.state.step, cell, quantity, value, limits: *limits });
                }
            }
            None
        });
        found.map_or(Ok(()), Err)
    }

    /// Advances one time step: [`Fluid::begin_step`], then
    /// [`Fluid::finish_step`].
    pub fn step(&mut self) {
        self.begin_step();
        self.finish_step();
    }

    /// The first part of a step: stream and collide (direct forcing and the
    /// interface cells' mass exchange included), the lattices swapped, the
    /// step counted. What the forcing applied ([`Fluid::applied_forcing`])
    /// is final here, so a coupled run can answer the DEM and let it step
    /// while [`Fluid::finish_step`] does the free-surface conversions, which
    /// do not change the loads. A step still pending is finished first.
    ///
    /// Post: until `finish_step`, only the forcing read-outs are meaningful;
    /// the state's flags and masses are those before the conversions.
    pub fn begin_step(&mut self) {
        self.finish_step();
        let t0 = Instant::now();
        if self.scratch.rows_stale {
            self.classify_rows();
        }
        self.scratch.forcing.start_step();
        let t1 = Instant::now();
        match self.params.collision {
            Collision::Bgk => self.stream_collide::<false>(),
            Collision::Trt { .. } => self.stream_collide::<true>(),
        }
        std::mem::swap(&mut self.state.populations, &mut self.scratch.next);
        self.state.step += 1;
        self.surface_pending = true;
        let t2 = Instant::now();
        let st = &mut self.stage_seconds;
        st.prepare += (t1 - t0).as_secs_f64();
        st.stream_collide += (t2 - t1).as_secs_f64();
    }

    /// The rest of the step begun by [`Fluid::begin_step`]: the free-surface
    /// conversions (steps 3–9 of `free_surface`). Does nothing when no step
    /// is pending.
    pub fn finish_step(&mut self) {
        if !std::mem::take(&mut self.surface_pending) {
            return;
        }
        let t0 = Instant::now();
        if !self.scratch.interface.is_empty() {
            self.update_surface();
        }
        if self.state.step.is_multiple_of(RELEASE_EVERY) {
            self.release_dry_memory();
        }
        self.stage_seconds.update_surface += t0.elapsed().as_secs_f64();
    }

    /// Gives back the memory of the segments that hold no liquid (both
    /// lattices): a segment the liquid has left holds only zeros (gas and
    /// wall cells hold 0), so its whole pages are handed back and read as
    /// zeros again ([`crate::memory::release_zeros`]); pages shared with a
    /// segment that has liquid stay. So do the whole pages of flags that
    /// are all gas (0). Changes no value: a run that releases and one that
    /// does not compute the same bits. Runs by itself every
    /// [`RELEASE_EVERY`] steps.
    pub fn release_dry_memory(&mut self) {
        let layout = self.state.layout();
        let nx = self.state.dims[0];
        let flags = &self.state.flags;
        let dry = &mut self.scratch.dry_segments;
        dry.resize(layout.segment_count(), false);
        dry.par_iter_mut().enumerate().with_min_len(1024).for_each(|(k, dry)| {
            let (row, xs) = layout.segment_cells(k);
            *dry = !flags[row * nx + xs.start..row * nx + xs.end].iter().any(|&f| flags::is_liquid(f));
        });
        let mut k = 0;
        while k < dry.len() {
            if !dry[k] {
                k += 1;
                continue;
            }
            let first = k;
            while k < dry.len() && dry[k] {
                k += 1;
            }
            let elements = layout.segment_elements(first).start..layout.segment_elements(k - 1).end;
            release_zeros(&mut self.state.populations, elements.clone());
            release_zeros(&mut self.scratch.next, elements);
        }
        release_zero_pages(&mut self.state.flags);
    }

    /// Recomputes the row classes after flags changed.
    fn classify_rows(&mut self) {
        let [_, ny, nz] = self.state.dims;
        for r in 0..ny * nz {
            self.classify_row(r);
        }
        for r in 0..ny * nz {
            self.classify_row_sources(r);
        }
        self.scratch.rows_stale = false;
    }

    /// The bits of row `r` that depend on its own cells.
    fn classify_row(&mut self, r: usize) {
        let nx = self.state.dims[0];
        let row = &self.state.flags[r * nx..(r + 1) * nx];
        // One pass for the four kinds (compares and ORs, vectorised), then
        // the span's ends only where there is liquid.
        let (mut fluid, mut interface, mut wall, mut gas) = (false, false, false, false);
        for &f in row {
            fluid |= f == flags::FLUID;
            interface |= f == flags::INTERFACE;
            wall |= f == flags::WALL;
            gas |= f == flags::GAS;
        }
        let any = fluid || interface;
        let all = !(interface || wall || gas);
        self.scratch.spans[r] = if any {
            let first = row.iter().position(|&f| flags::is_liquid(f)).unwrap_or(0);
            let last = row.iter().rposition(|&f| flags::is_liquid(f)).unwrap_or(0);
            (first as u32, last as u32 + 1)
        } else {
            (0, 0)
        };
        self.scratch.rows[r] = if any { ROW_ANY_LIQUID } else { 0 }
            | if all { ROW_ALL_FLUID } else { 0 }
            | if interface { ROW_ANY_INTERFACE } else { 0 }
            | if wall { ROW_ANY_WALL } else { 0 };
    }

    /// The `ROW_SOURCES_FLUID` bit of row `r`, from its neighbour rows' own bits.
    fn classify_row_sources(&mut self, r: usize) {
        let [_, ny, nz] = self.state.dims;
        let faces = self.state.faces;
        let (y, z) = (r % ny, r / ny);
        let rows = &mut self.scratch.rows;
        let (mut sources_fluid, mut no_wall) = (true, true);
        for dz in -1..=1 {
            for dy in -1..=1 {
                // Rows beyond a wall face are not read: the pull bounces back there.
                if let (Some(ys), Some(zs)) = (wrap(y, dy, ny, faces[1]), wrap(z, dz, nz, faces[2])) {
                    sources_fluid &= rows[zs * ny + ys] & ROW_ALL_FLUID != 0;
                    no_wall &= rows[zs * ny + ys] & ROW_ANY_WALL == 0;
                }
            }
        }
        rows[r] = (rows[r] & !(ROW_SOURCES_FLUID | ROW_SOURCES_NO_WALL))
            | if sources_fluid { ROW_SOURCES_FLUID } else { 0 }
            | if no_wall { ROW_SOURCES_NO_WALL } else { 0 };
    }

    /// Reclassifies the rows in `rows` (sorted, deduplicated by the caller
    /// or not: the work is idempotent) and the source bits of their neighbours.
    fn reclassify_rows(&mut self, rows: &[usize]) {
        if self.scratch.rows_stale {
            return; // the next step reclassifies everything anyway
        }
        let [_, ny, nz] = self.state.dims;
        let faces = self.state.faces;
        for &r in rows {
            self.classify_row(r);
        }
        for &r in rows {
            let (y, z) = (r % ny, r / ny);
            for dz in -1..=1 {
                for dy in -1..=1 {
                    if let (Some(ys), Some(zs)) = (wrap(y, dy, ny, faces[1]), wrap(z, dz, nz, faces[2])) {
                        self.classify_row_sources(zs * ny + ys);
                    }
                }
            }
        }
    }

    fn coefficients(&self) -> Coefficients<T> {
        let p = &self.params;
        let magic = match p.collision {
            Collision::Bgk => 0.0,
            Collision::Trt { magic } => magic,
        };
        Coefficients {
            tau0: T::from_f64(p.tau),
            tau0_sq: T::from_f64(p.tau * p.tau),
            smag: T::from_f64(18.0 * std::f64::consts::SQRT_2 * p.smagorinsky * p.smagorinsky),
            magic: T::from_f64(magic),
            accel: p.acceleration.map(T::from_f64),
        }
    }

    /// Stage `stream_collide`: reads `state.populations`, writes `scratch.next`
    /// for every fluid and interface cell (non-liquid cells of `next` are left
    /// untouched), adds each interface cell's mass exchange to its mass, and
    /// writes the direct force of each forced liquid cell.
    fn stream_collide<const TRT: bool>(&mut self) {
        let [nx, ny, nz] = self.state.dims;
        let coef = self.coefficients();
        let forcing = &mut self.scratch.forcing;
        let applied = SharedOut(forcing.applied.as_mut_ptr(), forcing.applied.len());
        let kernel = Kernel {
            src: &self.state.populations,
            flags: &self.state.flags,
            rows: &self.scratch.rows,
            spans: &self.scratch.spans,
            fill: &self.scratch.fill,
            nx,
            ny,
            nz,
            layout: self.state.layout(),
            faces: self.state.faces,
            coef,
            accel: self.params.acceleration,
            forced: &forcing.cells,
            forced_rows: &forcing.rows,
            gain: forcing.gain,
            tau0: self.params.tau,
            smag: 18.0 * std::f64::consts::SQRT_2 * self.params.smagorinsky * self.params.smagorinsky,
        };
        let out = SharedOut(self.scratch.next.as_mut_ptr(), self.scratch.next.len());
        let mass = SharedOut(self.state.mass.as_mut_ptr(), self.state.mass.len());
        let density = SharedOut::new(&mut self.scratch.interface_density);
        let isa = self.isa;
        // One task per plane: the liquid's planes cost very different
        // amounts (late in the lab column a sheet a few cells deep holds most
        // of the work), and rayon's default split hands each thread a run of
        // planes it cannot share: 2 threads ran only 1.13× faster than one.
        (0..nz).into_par_iter().with_max_len(1).for_each(|z| {
            let mut buffer = [[T::ZERO; LANES]; Q];
            let mut accel = [[T::ZERO; LANES]; 4];
            kernel.plane::<TRT>(isa, z, &out, &mass, &density, &applied, &mut buffer, &mut accel);
        });
    }
}

/// The neighbour coordinate `x + d` along an axis of `n` cells, or `None`
/// beyond a wall face.
#[inline(always)]
fn wrap(x: usize, d: i32, n: usize, faces: Faces) -> Option<usize> {
    let s = x as isize + d as isize;
    if s >= 0 && (s as usize) < n {
        Some(s as usize)
    } else if faces == Faces::Periodic {
        Some(s.rem_euclid(n as isize) as usize)
    } else {
        None
    }
}

/// ρ = 1 + Σ g_i of one cell from its stored deviations g_i = f_i − w_i,
/// summed in f64 in direction order. Every density the conversions use is
/// summed here (the kernel's kept ones and [`Fluid::density_at`]), so kept
/// and recomputed densities agree bit for bit.
#[inline(always)]
fn density_of(g: impl Fn(usize) -> f64) -> f64 {
    1.0 + (0..Q).map(g).sum::<f64>()
}

/// The index step from a cell to its neighbour along `e` in a box `nx` × `ny`
/// cells wide, for cells off the box's faces (no wrap, no wall face).
#[inline(always)]
fn link_offset(e: [i32; 3], nx: usize, ny: usize) -> isize {
    e[0] as isize + e[1] as isize * nx as isize + e[2] as isize * (nx * ny) as isize
}

/// `dst.copy_from_slice(src)`, inlined as vector moves: a variable-length
/// copy calls `memmove` (38 times per chunk), which took 16–23 % of the
/// free-surface column's time, whose chunks are mostly partial (a liquid
/// span's ends, a segment's).
#[inline(always)]
fn copy_lanes<T: Copy>(dst: &mut [T], src: &[T]) {
    if let (Ok(d), Ok(s)) = (<&mut [T; LANES]>::try_from(&mut *dst), <&[T; LANES]>::try_from(src)) {
        *d = *s;
        return;
    }
    assert_eq!(dst.len(), src.len());
    let mut d = dst.chunks_exact_mut(8);
    let mut s = src.chunks_exact(8);
    for (d, s) in (&mut d).zip(&mut s) {
        // Fixed-size blocks: moves, not a call.
        let d: &mut [T; 8] = d.try_into().expect("8 lanes");
        *d = s.try_into().expect("8 lanes");
    }
    for (d, s) in d.into_remainder().iter_mut().zip(s.remainder()) {
        *d = *s;
    }
}

/// A buffer written from several threads at disjoint indices: the output
/// lattice, the mass array, the applied forces (here) and the coupling's
/// forced-cell lists (`coupling.rs`).
///
/// Sound where each index is written by one task only and nothing reads the
/// buffer while the writers run. In the kernel each thread handles whole
/// z-planes and writes only the populations of cells in its own plane.
pub(crate) struct SharedOut<T>(*mut T, usize);
// SAFETY: see the type's comment; T itself is sent between threads.
unsafe impl<T: Send> Sync for SharedOut<T> {}

impl<T> SharedOut<T> {
    /// Shares `buffer` for disjoint writes (see the type's comment).
    pub(crate) fn new(buffer: &mut [T]) -> Self {
        SharedOut(buffer.as_mut_ptr(), buffer.len())
    }

    /// SAFETY: no other live slice may overlap `start..start + len`, and the
    /// range must lie inside the buffer.
    #[inline(always)]
    #[allow(clippy::mut_from_ref)] // the writer hands out disjoint ranges by contract, as `split_at_mut` would
    pub(crate) unsafe fn slice(&self, start: usize, len: usize) -> &mut [T] {
        assert!(start + len <= self.1);
        // SAFETY: in bounds (checked above) and unaliased (caller's contract).
        unsafe { std::slice::from_raw_parts_mut(self.0.add(start), len) }
    }
}
