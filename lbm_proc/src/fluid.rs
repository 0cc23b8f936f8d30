//! The lattice state and its time step.
//!
//! [`Fluid::step`] is one stage, `stream_collide`, fused per cell: pull the 19
//! incoming populations (half-way bounce-back where the source is a wall),
//! take the moments, relax (BGK or TRT, each with the Smagorinsky eddy
//! viscosity), add Guo's forcing, and write the post-collision populations to
//! the second lattice. The lattices are then swapped (A/B pattern). Work is
//! split over z-planes with rayon; the step allocates nothing.
//!
//! Storage, chosen for a bandwidth-bound kernel (lbm-free-surface.md §5):
//! * populations struct-of-arrays, population i of cell c at `i * ncells + c`,
//!   cells x-fastest, so one x-row of one direction is contiguous and the
//!   kernel works on rows of [`LANES`] cells with plain vector loops;
//! * shifted: the stored value is f_i − w_i (ρ0 = 1), as FluidX3D does
//!   (Lehmann et al. 2022, PRE 106, 015308). Near rest f_i − w_i is ~1e-3 of
//!   f_i, so f32 keeps ~3 more significant digits of the non-equilibrium
//!   part and of the density deviation than unshifted f32 would;
//! * the stored populations are post-collision: ρ and u at the current time
//!   are read from them directly (Guo's scheme puts ρu + F/2 into the
//!   post-collision momentum), so no macroscopic field is written in the hot
//!   loop;
//! * one flag byte per cell ([`flags`]), and one class byte per x-row that
//!   says whether the row holds liquid at all and whether its pulls can touch
//!   a non-fluid cell. Rows with no liquid cost nothing, which is where the
//!   free surface's gas cells will go; rows far from walls skip the per-cell
//!   flag checks.
//!
//! Later stages (free-surface mass exchange, particle forcing, Eq. 5) add
//! per-cell arrays next to `populations` in [`FluidState`] and their own
//! stages around `stream_collide`.

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::lattice::{E, OPP, Q, W};
use crate::real::Real;
use crate::watchdog::{Instability, Quantity, WatchdogLimits};

/// Cell flags. Values from 2 up are left for the free surface (interface, gas).
pub mod flags {
    /// A liquid cell: collides and streams.
    pub const FLUID: u8 = 0;
    /// A no-slip obstacle: links into it bounce back half-way.
    pub const WALL: u8 = 1;
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
    /// Body acceleration (gravity), lattice units; the force density is ρ a.
    pub acceleration: [f64; 3],
}

impl FluidParams {
    /// τ0 with the defaults: BGK, C = 0.16, no body force. BGK is the
    /// default because at the paper's τ0 = 0.500667 it survived even without
    /// Smagorinsky where TRT 3/16 (τ− ≈ 280) blew up, and its eddy viscosity
    /// matches Eq. 4 (tests/stability.rs, tests/flows.rs); TRT 3/16 is the
    /// choice when the wall position matters (exact Poiseuille).
    pub fn new(tau: f64) -> Self {
        FluidParams { tau, collision: Collision::Bgk, smagorinsky: 0.16, acceleration: [0.0; 3] }
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
    #[error("box dimensions must be >= 1 cell each, got {0:?}")]
    Dims([usize; 3]),
    #[error("cell {cell:?} lies outside the box {dims:?}")]
    OutOfBox { cell: [usize; 3], dims: [usize; 3] },
    #[error("state is inconsistent: {0}")]
    State(String),
}

/// Everything needed to continue a run exactly (with [`FluidParams`]).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FluidState<T> {
    /// Cells along x, y, z.
    pub dims: [usize; 3],
    pub faces: [Faces; 3],
    /// One of [`flags`] per cell, x fastest.
    pub flags: Vec<u8>,
    /// Post-collision f_i − w_i, population i of cell c at `i * ncells + c`.
    pub populations: Vec<T>,
    /// Steps taken.
    pub step: u64,
}

/// Row classes (bits of `Scratch::rows`).
const ROW_ANY_FLUID: u8 = 1;
const ROW_ALL_FLUID: u8 = 2;
/// Every source row of every pull is all fluid: no per-cell wall checks needed.
const ROW_SOURCES_FLUID: u8 = 4;

/// Buffers the step needs besides the state.
#[derive(Debug, Clone)]
struct Scratch<T> {
    /// The lattice written by the step.
    next: Vec<T>,
    /// Class of each x-row, index `z * ny + y`.
    rows: Vec<u8>,
    rows_stale: bool,
}

/// A D3Q19 fluid in a box of cells.
#[derive(Debug, Clone)]
pub struct Fluid<T: Real = f32> {
    state: FluidState<T>,
    params: FluidParams,
    scratch: Scratch<T>,
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

impl<T: Real> Fluid<T> {
    /// A box of fluid cells at rest (u = 0 under the body force), ρ = 1.
    pub fn new(dims: [usize; 3], faces: [Faces; 3], params: FluidParams) -> Result<Self, ConfigError> {
        params.validate()?;
        let ncells = dims[0]
            .checked_mul(dims[1])
            .and_then(|n| n.checked_mul(dims[2]))
            .filter(|&n| n > 0 && n.checked_mul(Q).is_some())
            .ok_or(ConfigError::Dims(dims))?;
        let rest = crate::lattice::equilibrium(1.0, params.acceleration.map(|a| 0.5 * a));
        let populations = (0..Q * ncells).map(|k| T::from_f64(rest[k / ncells] - W[k / ncells])).collect();
        let state = FluidState { dims, faces, flags: vec![flags::FLUID; ncells], populations, step: 0 };
        Self::from_state(state, params)
    }

    /// Continues from a saved state.
    pub fn from_state(state: FluidState<T>, params: FluidParams) -> Result<Self, ConfigError> {
        params.validate()?;
        let [nx, ny, nz] = state.dims;
        let ncells = nx * ny * nz;
        if ncells == 0 || state.flags.len() != ncells || state.populations.len() != Q * ncells {
            return Err(ConfigError::State(format!(
                "dims {:?} need {} flags and {} populations, got {} and {}",
                state.dims,
                ncells,
                Q * ncells,
                state.flags.len(),
                state.populations.len()
            )));
        }
        let scratch = Scratch { next: state.populations.clone(), rows: vec![0; ny * nz], rows_stale: true };
        let mut fluid = Fluid { state, params, scratch };
        fluid.classify_rows();
        Ok(fluid)
    }

    pub fn state(&self) -> &FluidState<T> {
        &self.state
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

    /// Makes `cell` a wall (or a fluid cell again with `flags::FLUID`).
    pub fn set_flag(&mut self, cell: [usize; 3], flag: u8) -> Result<(), ConfigError> {
        let c = self.index(cell)?;
        self.state.flags[c] = flag;
        self.scratch.rows_stale = true;
        if flag != flags::FLUID {
            // The step never writes non-fluid cells; keeping them equal in
            // both lattices makes the state independent of the step parity.
            self.write_cell(c, &[0.0; Q]);
        }
        Ok(())
    }

    /// Sets `cell` to equilibrium with density `rho` and velocity `u` (lattice units).
    ///
    /// The stored populations are post-collision, whose momentum is ρ(u + a/2)
    /// under Guo forcing, so the equilibrium is taken at u + a/2; the cell
    /// then reports exactly (ρ, u).
    pub fn set_equilibrium(&mut self, cell: [usize; 3], rho: f64, u: [f64; 3]) -> Result<(), ConfigError> {
        let c = self.index(cell)?;
        let a = self.params.acceleration;
        let feq = crate::lattice::equilibrium(rho, [u[0] + 0.5 * a[0], u[1] + 0.5 * a[1], u[2] + 0.5 * a[2]]);
        self.write_cell(c, &std::array::from_fn(|i| feq[i] - W[i]));
        Ok(())
    }

    /// Sets the stored f_i − w_i of cell index `c` in both lattices.
    fn write_cell(&mut self, c: usize, g: &[f64; Q]) {
        let n = self.ncells();
        for i in 0..Q {
            self.state.populations[i * n + c] = T::from_f64(g[i]);
            self.scratch.next[i * n + c] = T::from_f64(g[i]);
        }
    }

    /// Density and velocity of cell index `c` (lattice units), from the
    /// post-collision populations: ρ = Σf, u = (Σ f e − F/2)/ρ.
    fn moments_at(&self, c: usize) -> (f64, [f64; 3]) {
        let n = self.ncells();
        let p = &self.state.populations;
        let mut drho = 0.0;
        let mut j = [0.0; 3];
        for i in 0..Q {
            let g = p[i * n + c].to_f64();
            drho += g;
            for a in 0..3 {
                j[a] += E[i][a] as f64 * g;
            }
        }
        let rho = 1.0 + drho;
        let acc = self.params.acceleration;
        (rho, std::array::from_fn(|a| j[a] / rho - 0.5 * acc[a]))
    }

    /// Density and velocity of `cell`, lattice units.
    pub fn moments(&self, cell: [usize; 3]) -> Result<(f64, [f64; 3]), ConfigError> {
        Ok(self.moments_at(self.index(cell)?))
    }

    /// Σρ over fluid cells (lattice mass), summed in f64 in a fixed order.
    pub fn total_mass(&self) -> f64 {
        let n = self.ncells();
        let p = &self.state.populations;
        let fluid = (0..n).filter(|&c| self.state.flags[c] == flags::FLUID);
        fluid.map(|c| 1.0 + (0..Q).map(|i| p[i * n + c].to_f64()).sum::<f64>()).sum()
    }

    /// ½ Σ ρ u² over fluid cells, lattice units.
    pub fn kinetic_energy(&self) -> f64 {
        (0..self.ncells())
            .filter(|&c| self.state.flags[c] == flags::FLUID)
            .map(|c| {
                let (rho, u) = self.moments_at(c);
                0.5 * rho * (u[0] * u[0] + u[1] * u[1] + u[2] * u[2])
            })
            .sum()
    }

    /// Largest |u| over fluid cells, lattice units.
    pub fn max_speed(&self) -> f64 {
        (0..self.ncells())
            .filter(|&c| self.state.flags[c] == flags::FLUID)
            .map(|c| {
                let u = self.moments_at(c).1;
                (u[0] * u[0] + u[1] * u[1] + u[2] * u[2]).sqrt()
            })
            .fold(0.0, f64::max)
    }

    /// The first fluid cell (lowest index) whose populations are not finite,
    /// whose density leaves the limits, or whose speed exceeds the Mach limit.
    /// Never panics; meant to run every few steps.
    pub fn check(&self, limits: &WatchdogLimits) -> Result<(), Instability> {
        let [nx, ny, nz] = self.state.dims;
        let n = self.ncells();
        let cs = crate::lattice::CS2.sqrt();
        let found = (0..nz).into_par_iter().find_map_first(|z| {
            for c in z * nx * ny..(z + 1) * nx * ny {
                if self.state.flags[c] != flags::FLUID {
                    continue;
                }
                let bad = if let Some(i) = (0..Q).find(|&i| !self.state.populations[i * n + c].is_finite()) {
                    Some((Quantity::Population(i), self.state.populations[i * n + c].to_f64()))
                } else {
                    let (rho, u) = self.moments_at(c);
                    let mach = (u[0] * u[0] + u[1] * u[1] + u[2] * u[2]).sqrt() / cs;
                    // Written so that NaN moments count as out of bounds.
                    if !(limits.min_density..=limits.max_density).contains(&rho) || rho.is_nan() {
                        Some((Quantity::Density, rho))
                    } else if mach.is_nan() || mach > limits.max_mach {
                        Some((Quantity::Mach, mach))
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

    /// Advances one time step.
    pub fn step(&mut self) {
        if self.scratch.rows_stale {
            self.classify_rows();
        }
        match self.params.collision {
            Collision::Bgk => self.stream_collide::<false>(),
            Collision::Trt { .. } => self.stream_collide::<true>(),
        }
        std::mem::swap(&mut self.state.populations, &mut self.scratch.next);
        self.state.step += 1;
    }

    /// Recomputes the row classes after flags changed.
    fn classify_rows(&mut self) {
        let [nx, ny, nz] = self.state.dims;
        let fl = &self.state.flags;
        let rows = &mut self.scratch.rows;
        for r in 0..ny * nz {
            let row = &fl[r * nx..(r + 1) * nx];
            let any = row.contains(&flags::FLUID);
            let all = row.iter().all(|&f| f == flags::FLUID);
            rows[r] = if any { ROW_ANY_FLUID } else { 0 } | if all { ROW_ALL_FLUID } else { 0 };
        }
        let faces = self.state.faces;
        for z in 0..nz {
            for y in 0..ny {
                let mut sources_fluid = true;
                for dz in -1..=1 {
                    for dy in -1..=1 {
                        // Rows beyond a wall face are not read: the pull bounces back there.
                        if let (Some(ys), Some(zs)) = (wrap(y, dy, ny, faces[1]), wrap(z, dz, nz, faces[2])) {
                            sources_fluid &= rows[zs * ny + ys] & ROW_ALL_FLUID != 0;
                        }
                    }
                }
                if sources_fluid {
                    rows[z * ny + y] |= ROW_SOURCES_FLUID;
                }
            }
        }
        self.scratch.rows_stale = false;
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
    /// for every fluid cell; non-fluid cells of `next` are left untouched.
    fn stream_collide<const TRT: bool>(&mut self) {
        let [nx, ny, nz] = self.state.dims;
        let kernel = Kernel {
            src: &self.state.populations,
            flags: &self.state.flags,
            rows: &self.scratch.rows,
            nx,
            ny,
            nz,
            ncells: nx * ny * nz,
            faces: self.state.faces,
            coef: self.coefficients(),
        };
        let out = SharedOut(self.scratch.next.as_mut_ptr(), self.scratch.next.len());
        (0..nz).into_par_iter().for_each(|z| {
            let mut buffer = [[T::ZERO; LANES]; Q];
            for y in 0..ny {
                kernel.row::<TRT>(y, z, &out, &mut buffer);
            }
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

/// `dst.copy_from_slice(src)`, inlined as vector moves for the common full
/// chunk (a variable-length copy would call `memmove` 38 times per chunk).
#[inline(always)]
fn copy_lanes<T: Copy>(dst: &mut [T], src: &[T]) {
    if let (Ok(d), Ok(s)) = (<&mut [T; LANES]>::try_from(&mut *dst), <&[T; LANES]>::try_from(src)) {
        *d = *s;
    } else {
        dst.copy_from_slice(src);
    }
}

/// The output lattice, written from several threads.
///
/// Sound because each thread handles whole z-planes and writes only indices
/// `i * ncells + c` with c in its own plane, so no index is written twice and
/// nothing reads `next` during the step.
struct SharedOut<T>(*mut T, usize);
// SAFETY: see the type's comment; T itself is sent between threads.
unsafe impl<T: Send> Sync for SharedOut<T> {}

impl<T> SharedOut<T> {
    /// SAFETY: no other live slice may overlap `start..start + len`, and the
    /// range must lie inside the buffer.
    #[inline(always)]
    #[allow(clippy::mut_from_ref)] // the writer hands out disjoint ranges by contract, as `split_at_mut` would
    unsafe fn slice(&self, start: usize, len: usize) -> &mut [T] {
        assert!(start + len <= self.1);
        // SAFETY: in bounds (checked above) and unaliased (caller's contract).
        unsafe { std::slice::from_raw_parts_mut(self.0.add(start), len) }
    }
}

struct Kernel<'a, T> {
    src: &'a [T],
    flags: &'a [u8],
    rows: &'a [u8],
    nx: usize,
    ny: usize,
    nz: usize,
    ncells: usize,
    faces: [Faces; 3],
    coef: Coefficients<T>,
}

impl<T: Real> Kernel<'_, T> {
    /// Streams and collides the fluid cells of row (y, z).
    #[inline(always)]
    fn row<const TRT: bool>(&self, y: usize, z: usize, out: &SharedOut<T>, f: &mut [[T; LANES]; Q]) {
        let class = self.rows[z * self.ny + y];
        if class & ROW_ANY_FLUID == 0 {
            return;
        }
        let check_walls = class & ROW_SOURCES_FLUID == 0;
        let row_start = (z * self.ny + y) * self.nx;
        let mut x0 = 0;
        while x0 < self.nx {
            let n = LANES.min(self.nx - x0);
            for i in 0..Q {
                self.gather(i, y, z, x0, n, check_walls, &mut f[i]);
            }
            // Whole vectors of lanes; the lanes past n hold finite leftovers and are not written.
            collide::<T, TRT>(f, n.next_multiple_of(8).min(LANES), &self.coef);
            let own = row_start + x0;
            for i in 0..Q {
                // SAFETY: cell indices own..own+n lie in plane z, which only this task writes.
                let dst = unsafe { out.slice(i * self.ncells + own, n) };
                if class & ROW_ALL_FLUID != 0 {
                    copy_lanes(dst, &f[i][..n]);
                } else {
                    for l in 0..n {
                        if self.flags[own + l] == flags::FLUID {
                            dst[l] = f[i][l];
                        }
                    }
                }
            }
            x0 += n;
        }
    }

    /// Pulls population `i` for cells x0..x0+n of row (y, z) into `dst`:
    /// f_i(x) = f_i*(x − e_i), or f_ī*(x) (half-way bounce-back) when x − e_i
    /// is a wall cell or lies beyond a wall face.
    #[inline(always)]
    fn gather(&self, i: usize, y: usize, z: usize, x0: usize, n: usize, check_walls: bool, dst: &mut [T; LANES]) {
        let (nx, ncells, src) = (self.nx, self.ncells, self.src);
        let own = (z * self.ny + y) * nx + x0;
        let bounce = OPP[i] * ncells + own;
        let e = E[i];
        let (Some(ys), Some(zs)) = (wrap(y, -e[1], self.ny, self.faces[1]), wrap(z, -e[2], self.nz, self.faces[2]))
        else {
            copy_lanes(&mut dst[..n], &src[bounce..bounce + n]);
            return;
        };
        let src_row = (zs * self.ny + ys) * nx;
        let base = i * ncells + src_row;
        // Lanes whose source x falls off the row: lane 0 for e_x = +1, lane n−1 for e_x = −1.
        let lo = usize::from(e[0] == 1 && x0 == 0);
        let hi = if e[0] == -1 && x0 + n == nx { n - 1 } else { n };
        let start = (x0 + lo) as isize - e[0] as isize;
        let start = base + start as usize;
        copy_lanes(&mut dst[lo..hi], &src[start..start + (hi - lo)]);
        let periodic_x = self.faces[0] == Faces::Periodic;
        if lo == 1 {
            dst[0] = if periodic_x { src[base + nx - 1] } else { src[bounce] };
        }
        if hi == n - 1 {
            dst[n - 1] = if periodic_x { src[base] } else { src[bounce + n - 1] };
        }
        if check_walls {
            for l in 0..n {
                if let Some(xs) = wrap(x0 + l, -e[0], nx, self.faces[0]) {
                    if self.flags[src_row + xs] != flags::FLUID {
                        dst[l] = src[bounce + l];
                    }
                }
            }
        }
    }
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
#[inline(always)]
fn collide<T: Real, const TRT: bool>(f: &mut [[T; LANES]; Q], lanes: usize, c: &Coefficients<T>) {
    let k = |x: f64| T::from_f64(x);
    let (half, one, third) = (k(0.5), k(1.0), k(1.0 / 3.0));
    let (w0, w1, w2) = (k(W[0]), k(W[1]), k(W[7]));
    let (c3, c45, c15, c9) = (k(3.0), k(4.5), k(1.5), k(9.0));
    let [ax, ay, az] = c.accel;
    for l in 0..lanes {
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
        let tau = half * (c.tau0 + (c.tau0_sq + c.smag * q.sqrt() * inv_rho).sqrt());
        let wp = one / tau;
        let wm = if TRT { (tau - half) / (half * (tau - half) + c.magic) } else { wp };
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::lattice::{equilibrium, CS2};

    fn periodic<T: Real>(dims: [usize; 3], params: FluidParams) -> Fluid<T> {
        Fluid::new(dims, [Faces::Periodic; 3], params).expect("valid parameters")
    }

    #[test]
    fn uniform_flow_is_a_fixed_point_of_the_kernel() {
        // A uniform equilibrium has no gradients: streaming moves identical
        // cells and Π^neq = 0, so collision must return f^eq exactly. This
        // pins the kernel's hand-written moments, weights and equilibrium to
        // lattice::equilibrium.
        let u = [0.05, -0.03, 0.02];
        for collision in [Collision::Bgk, Collision::TRT_3_16] {
            let params = FluidParams { tau: 0.53, collision, smagorinsky: 0.16, acceleration: [0.0; 3] };
            let mut fluid = periodic::<f64>([3, 2, 2], params);
            for c in 0..12 {
                fluid.set_equilibrium([c % 3, (c / 3) % 2, c / 6], 1.02, u).expect("in box");
            }
            for _ in 0..5 {
                fluid.step();
            }
            let feq = equilibrium(1.02, u);
            let n = fluid.ncells();
            for i in 0..Q {
                for c in 0..n {
                    let f = fluid.state().populations[i * n + c] + W[i];
                    assert!((f - feq[i]).abs() < 1e-15, "{collision:?} f_{i} = {f}, f_eq = {}", feq[i]);
                }
            }
        }
    }

    #[test]
    fn body_force_adds_exactly_a_per_step() {
        // Periodic and uniform: Guo forcing must give du/dt = a and keep ρ.
        let a = [1e-5, -2e-5, 3e-5];
        for collision in [Collision::Bgk, Collision::TRT_3_16] {
            let params = FluidParams { tau: 0.7, collision, smagorinsky: 0.16, acceleration: a };
            let mut fluid = periodic::<f64>([2, 2, 2], params);
            for step in 1..=10 {
                fluid.step();
                let (rho, u) = fluid.moments([1, 0, 1]).expect("in box");
                assert!((rho - 1.0).abs() < 1e-14);
                for d in 0..3 {
                    assert!((u[d] - step as f64 * a[d]).abs() < 1e-15, "{collision:?} step {step}: u = {u:?}");
                }
            }
        }
    }

    #[test]
    fn bad_parameters_are_errors_not_panics() {
        let faces = [Faces::Periodic; 3];
        assert_eq!(Fluid::<f32>::new([4, 4, 4], faces, FluidParams::new(0.5)).err(), Some(ConfigError::Tau(0.5)));
        let p = FluidParams { smagorinsky: -0.1, ..FluidParams::new(0.6) };
        assert!(matches!(Fluid::<f32>::new([4, 4, 4], faces, p), Err(ConfigError::Smagorinsky(_))));
        let p = FluidParams { collision: Collision::Trt { magic: f64::NAN }, ..FluidParams::new(0.6) };
        assert!(matches!(Fluid::<f32>::new([4, 4, 4], faces, p), Err(ConfigError::Magic(_))));
        assert!(matches!(Fluid::<f32>::new([0, 4, 4], faces, FluidParams::new(0.6)), Err(ConfigError::Dims(_))));
        let mut fluid = periodic::<f32>([4, 4, 4], FluidParams::new(0.6));
        assert!(matches!(fluid.set_flag([4, 0, 0], flags::WALL), Err(ConfigError::OutOfBox { .. })));
        let mut state = fluid.state().clone();
        state.populations.pop();
        assert!(matches!(Fluid::from_state(state, FluidParams::new(0.6)), Err(ConfigError::State(_))));
    }

    #[test]
    fn watchdog_names_the_cell_the_quantity_and_the_fix() {
        let mut fluid = periodic::<f32>([6, 5, 4], FluidParams::new(0.6));
        assert_eq!(fluid.check(&WatchdogLimits::default()), Ok(()));
        fluid.set_equilibrium([4, 3, 2], 1.0, [0.2, 0.0, 0.0]).expect("in box");
        let e = fluid.check(&WatchdogLimits::default()).expect_err("Mach 0.35");
        assert_eq!((e.cell, e.quantity), ([4, 3, 2], Quantity::Mach));
        assert!((e.value - 0.2 / CS2.sqrt()).abs() < 1e-6);
        fluid.set_equilibrium([1, 1, 1], 2.5, [0.0; 3]).expect("in box");
        let e = fluid.check(&WatchdogLimits::default()).expect_err("density");
        assert_eq!((e.cell, e.quantity), ([1, 1, 1], Quantity::Density), "lowest cell index first");
        let n = fluid.ncells();
        fluid.state.populations[7 * n] = f32::NAN;
        let e = fluid.check(&WatchdogLimits::default()).expect_err("NaN");
        assert_eq!((e.cell, e.quantity), ([0, 0, 0], Quantity::Population(7)));
        let msg = e.to_string();
        assert!(msg.contains("cell (0, 0, 0)") && msg.contains("f_7") && msg.contains("Smagorinsky"), "{msg}");
    }

    #[test]
    fn results_do_not_depend_on_thread_count_and_restart_is_exact() {
        let params = FluidParams { acceleration: [1e-5, 0.0, -2e-5], ..FluidParams::new(0.52) };
        let mut fluid = Fluid::<f32>::new([20, 6, 9], [Faces::Periodic, Faces::Walls, Faces::Walls], params)
            .expect("valid parameters");
        fluid.set_flag([5, 2, 4], flags::WALL).expect("in box");
        for c in 0..fluid.ncells() {
            let (x, y, z) = (c % 20, (c / 20) % 6, c / 120);
            let u = [0.03 * (y as f64 * 0.7).sin(), 0.02 * (x as f64 * 0.3).cos(), 0.01 * (z as f64).sin()];
            fluid.set_equilibrium([x, y, z], 1.0, u).expect("in box");
        }
        let run = |threads: usize, mut f: Fluid<f32>, steps: usize| {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("pool");
            pool.install(|| (0..steps).for_each(|_| f.step()));
            f
        };
        let one = run(1, fluid.clone(), 40);
        let two = run(2, fluid.clone(), 40);
        assert!(one.state() == two.state(), "1 and 2 threads differ");
        let half = run(2, fluid, 17);
        let restarted = Fluid::from_state(half.state().clone(), *half.params()).expect("valid state");
        let resumed = run(2, restarted, 23);
        assert!(resumed.state() == one.state(), "restart from a snapshot is not exact");
    }
}
