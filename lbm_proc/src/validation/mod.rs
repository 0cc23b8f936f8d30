//! Validation cases of the grain–fluid coupling, each at a chosen
//! resolution D/Δx, fluid condition and [`ForcingGain`] rule, against a
//! published value (`shared/reference/coupling-references.md`):
//!
//! * [`simple_cubic_drag`]: Stokes drag on a fixed periodic simple-cubic
//!   sphere array, K = F/(3πμDU_s), against Zick & Homsy 1982 (Table 2);
//! * [`packing_flow`] on a [`RandomPacking`]: the superficial velocity of
//!   liquid driven through a fixed random packing, as a Darcy permeability
//!   against Kozeny–Carman ([`kozeny_carman`]) in creeping flow, or as a
//!   drag against Ergun's ([`ergun_gradient`]) at Re_p 1–100;
//! * [`settling::settle`]: one free sphere settling from rest in a closed
//!   tank, its terminal velocity against Schiller–Naumann with the tank's
//!   wall factor, at terminal Re 1–30.
//!
//! Everything is in lattice units (Δx = Δt = ρ0 = 1), f64 populations, BGK
//! (the scenes' collision), periodic boxes. The tests run a few cases at
//! tight bounds on the default rule; `cargo run --release -p lbm_proc
//! --example coupling_study` runs the whole matrix that docs/coupling.md
//! ("Choosing the forcing gain") tabulates.

use std::f64::consts::PI;

use crate::coupling::{Coupling, ForcingGain, Sphere};
use crate::fluid::{Faces, Fluid, FluidParams};
use crate::lattice::{E, Q};
use crate::units::Units;

pub mod settling;

/// The paper's saturated column: water (ν = 1e-6 m²/s) at Δx = 6e-4 m, Δt =
/// 8e-5 s, grains of D = 2.5 mm, so D/Δx = 4.1667 and τ0 = 0.500667.
pub const PAPER_D_CELLS: f64 = 2.5e-3 / 6e-4;

/// The fluid of a validation case, lattice units.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FluidCondition {
    /// Molecular relaxation time τ0 > ½.
    pub tau: f64,
    /// Smagorinsky constant C (0: none).
    pub smagorinsky: f64,
}

impl FluidCondition {
    /// The paper's water with Smagorinsky C = 0.16 at grain resolution
    /// `d_cells` = D/Δx: Δx = D/d_cells and Δt scaled with Δx from the
    /// paper's (fixed Mach number), so τ0 − ½ grows as d_cells/4.1667.
    pub fn paper_water(d_cells: f64) -> Self {
        let dx = 2.5e-3 / d_cells;
        let dt = 8e-5 * dx / 6e-4;
        let units = Units::new(dx, dt, 1000.0).expect("positive units");
        let tau = units.tau_from_viscosity(1e-6).expect("positive viscosity");
        FluidCondition { tau, smagorinsky: 0.16 }
    }

    /// A viscous liquid at relaxation time `tau`, no eddy viscosity.
    pub fn viscous(tau: f64) -> Self {
        FluidCondition { tau, smagorinsky: 0.0 }
    }

    /// Molecular kinematic viscosity (τ0 − ½)/3.
    pub fn nu(&self) -> f64 {
        (self.tau - 0.5) / 3.0
    }

    fn params(&self, acceleration: [f64; 3]) -> FluidParams {
        FluidParams { acceleration, smagorinsky: self.smagorinsky, ..FluidParams::new(self.tau) }
    }
}

/// Zick & Homsy 1982, Table 2: K = F/(6πμaU_s) of a simple-cubic array at
/// solid fraction φ (the values the references agree on to ≤ 0.9 %; 0.45
/// from one source). `None` off the tabulated fractions.
pub fn zick_homsy(phi: f64) -> Option<f64> {
    const TABLE: [(f64, f64); 6] =
        [(0.027, 2.008), (0.064, 2.810), (0.125, 4.292), (0.216, 7.442), (0.343, 15.4), (0.45, 28.1)];
    TABLE.iter().find(|(p, _)| (p - phi).abs() < 1e-9).map(|&(_, k)| k)
}

/// The fractions of [`zick_homsy`] the study uses (0.05–0.5).
pub const ARRAY_FRACTIONS: [f64; 5] = [0.064, 0.125, 0.216, 0.343, 0.45];

/// A measured drag of [`simple_cubic_drag`].
#[derive(Debug, Clone, Copy)]
pub struct ArrayDrag {
    /// Sphere diameter, cells (the requested D/Δx rounded to fit the box).
    pub d: f64,
    /// Periodic box edge, cells.
    pub box_cells: usize,
    /// Spheres per box edge (the box holds copies³ spheres).
    pub copies: usize,
    /// K = F/(3πμDU_s), F the drag per sphere.
    pub k: f64,
    /// Zick & Homsy's K.
    pub reference: f64,
    /// k / reference − 1.
    pub error: f64,
    /// Steps run, and whether the drag settled to 1e-4 within them.
    pub steps: usize,
    pub converged: bool,
}

/// Stokes drag on a fixed simple-cubic array at solid fraction `phi` (one
/// of [`ARRAY_FRACTIONS`]) with spheres of about `d_target` cells: the box
/// holds n³ spheres (n = 1–4, the fewest that put D within 3 % of
/// `d_target` with an integer box), each off the lattice symmetry by a
/// different sub-cell offset. A uniform body force, set every step from
/// the tracked momentum (deadbeat), holds the mean velocity over the box (sphere interiors at 0
/// included) at the superficial U_s of Re_p = U_s D/ν = 0.05; the body
/// force on the whole box is then the drag, F = G L³ as Zick & Homsy
/// define it. Runs until the drag changes by < 1e-4 over 4000 steps, at
/// most `max_steps`.
pub fn simple_cubic_drag(
    phi: f64,
    d_target: f64,
    fluid: FluidCondition,
    gain: ForcingGain,
    max_steps: usize,
) -> ArrayDrag {
    let reference = zick_homsy(phi).expect("a tabulated solid fraction");
    // D over the array's spacing.
    let chi = (phi / (PI / 6.0)).cbrt();
    // The fewest copies that bring D within 3 % of the target (each copy
    // multiplies the cells by n³), else the closest of n = 1–4; the box must
    // be wider than a sphere's covering (D + 2 cells).
    let fit = |n: usize| {
        let l = ((n as f64 * d_target / chi).round() as usize).max(2);
        (n, l, (chi * l as f64 / n as f64 / d_target - 1.0).abs())
    };
    let fits = || (1..=4).map(fit).filter(|&(n, l, _)| l as f64 >= chi * l as f64 / n as f64 + 2.5);
    let (copies, box_cells, _) = fits()
        .find(|c| c.2 < 0.03)
        .unwrap_or_else(|| fits().min_by(|a, b| a.2.total_cmp(&b.2)).expect("a box that holds the spheres"));
    let spacing = box_cells as f64 / copies as f64;
    let d = chi * spacing;
    let nu = fluid.nu();
    let u = 0.05 * nu / d;
    let dims = [box_cells; 3];
    let mut lattice = Fluid::<f64>::new(dims, [Faces::Periodic; 3], fluid.params([0.0; 3])).expect("valid fluid");
    for k in 0..box_cells {
        for j in 0..box_cells {
            for i in 0..box_cells {
                lattice.set_equilibrium([i, j, k], 1.0, [u, 0.0, 0.0]).expect("in box");
            }
        }
    }
    let mut spheres = Vec::new();
    for k in 0..copies {
        for j in 0..copies {
            for i in 0..copies {
                let n = spheres.len() as f64;
                spheres.push(Sphere {
                    position: [
                        (i as f64 + 0.5) * spacing + 0.23 - 0.05 * n,
                        (j as f64 + 0.5) * spacing + 0.11 + 0.03 * n,
                        (k as f64 + 0.5) * spacing - 0.07 + 0.02 * n,
                    ],
                    velocity: [0.0; 3],
                    angular_velocity: [0.0; 3],
                    radius: 0.5 * d,
                });
            }
        }
    }
    let (steps, converged, drag) = drive_at_fixed_flux(&mut lattice, &spheres, gain, u, max_steps);
    let k = drag / spheres.len() as f64 / (3.0 * PI * nu * d * u);
    ArrayDrag { d, box_cells, copies, k, reference, error: k / reference - 1.0, steps, converged }
}

/// Holds the box's mean x-velocity at `u` with a deadbeat body force and
/// returns (steps, converged, the body force on the whole box averaged over
/// the last 500 steps).
fn drive_at_fixed_flux(
    lattice: &mut Fluid<f64>,
    spheres: &[Sphere],
    gain: ForcingGain,
    u: f64,
    max_steps: usize,
) -> (usize, bool, f64) {
    let params = *lattice.params();
    let mass = lattice.ncells() as f64;
    let target = mass * u;
    let mut p = momentum_x(lattice);
    let mut coupling = Coupling::new(lattice_units(), [0.0; 3]).expect("finite origin").with_gain(gain);
    let mut last_ib = 0.0;
    let block = 500;
    let mut blocks: Vec<f64> = Vec::new();
    let mut sum = 0.0;
    for step in 1..=max_steps {
        // This step's F_IB predicted by the last: the total momentum stays at target.
        let a = (target - p - last_ib) / mass;
        lattice.set_params(FluidParams { acceleration: [a, 0.0, 0.0], ..params }).expect("finite");
        coupling.step(lattice, spheres).expect("valid spheres");
        last_ib = lattice.applied_forcing().iter().map(|c| c.force[0]).sum();
        p += mass * a + last_ib;
        sum += mass * a;
        if step % block == 0 {
            blocks.push(sum / block as f64);
            sum = 0.0;
            if settled(&blocks, 8, 1e-4) {
                return (step, true, *blocks.last().expect("a block"));
            }
        }
    }
    (max_steps, false, blocks.last().copied().unwrap_or(f64::NAN))
}

/// Whether the last block mean differs from the one `window` blocks before by
/// less than `tolerance` of itself.
fn settled(blocks: &[f64], window: usize, tolerance: f64) -> bool {
    blocks.len() > window && {
        let last = blocks[blocks.len() - 1];
        (last - blocks[blocks.len() - 1 - window]).abs() < tolerance * last.abs()
    }
}

/// Σ_c Σ_i f_i e_ix of the stored populations.
fn momentum_x(lattice: &Fluid<f64>) -> f64 {
    let n = lattice.ncells();
    let f = lattice.state();
    (0..Q).filter(|&i| E[i][0] != 0).map(|i| E[i][0] as f64 * (0..n).map(|c| f.population(i, c)).sum::<f64>()).sum()
}

fn lattice_units() -> Units {
    Units::new(1.0, 1.0, 1.0).expect("valid")
}

/// A fixed random packing of equal spheres in a periodic cube, lattice units.
#[derive(Debug, Clone)]
pub struct RandomPacking {
    /// Sphere centres.
    pub centres: Vec<[f64; 3]>,
    /// Diameter, cells.
    pub d: f64,
    /// Cube edge, cells.
    pub box_cells: usize,
    /// 1 − N πD³/6 / L³.
    pub porosity: f64,
}

impl RandomPacking {
    /// `n` spheres of diameter `d` cells at about `porosity` (the box edge is
    /// rounded to whole cells, so the actual porosity differs a little):
    /// random centres (SplitMix64 from `seed`), then pairwise overlaps pushed
    /// apart along the minimum-image line until none exceeds 2e-3 D.
    pub fn new(n: usize, d: f64, porosity: f64, seed: u64) -> Self {
        let l = (n as f64 * PI * d.powi(3) / 6.0 / (1.0 - porosity)).cbrt().round();
        let mut state = seed;
        let mut uniform = || {
            state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
            let mut z = state;
            z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
            ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64
        };
        let mut p: Vec<[f64; 3]> = (0..n).map(|_| [uniform() * l, uniform() * l, uniform() * l]).collect();
        let image = |x: f64| x - l * (x / l).round();
        for _ in 0..50_000 {
            let mut worst: f64 = 0.0;
            for i in 0..n {
                for j in i + 1..n {
                    let dv: [f64; 3] = std::array::from_fn(|a| image(p[j][a] - p[i][a]));
                    let dist = (dv[0] * dv[0] + dv[1] * dv[1] + dv[2] * dv[2]).sqrt().max(1e-9);
                    let overlap = d - dist;
                    if overlap > 0.0 {
                        worst = worst.max(overlap / d);
                        for a in 0..3 {
                            let push = 0.5 * overlap * dv[a] / dist;
                            p[i][a] = (p[i][a] - push).rem_euclid(l);
                            p[j][a] = (p[j][a] + push).rem_euclid(l);
                        }
                    }
                }
            }
            if worst < 2e-3 {
                let porosity = 1.0 - n as f64 * PI * d.powi(3) / 6.0 / l.powi(3);
                return RandomPacking { centres: p, d, box_cells: l as usize, porosity };
            }
        }
        panic!("packing of {n} spheres of D = {d} in L = {l} did not relax: ask for a higher porosity");
    }

    fn spheres(&self) -> Vec<Sphere> {
        self.centres
            .iter()
            .map(|&position| Sphere { position, velocity: [0.0; 3], angular_velocity: [0.0; 3], radius: 0.5 * self.d })
            .collect()
    }
}

/// The packing of the permeability and Ergun cases: 64 spheres at the
/// paper's porosity 0.40 (its columns: 0.39–0.43).
pub fn column_packing(d: f64) -> RandomPacking {
    RandomPacking::new(64, d, 0.40, 7)
}

/// Kozeny–Carman permeability k = D² n³/(180 (1 − n)²).
pub fn kozeny_carman(porosity: f64, d: f64) -> f64 {
    d * d * porosity.powi(3) / (180.0 * (1.0 - porosity).powi(2))
}

/// Ergun's (1952) pressure gradient per unit density, ΔP/(ρL) =
/// 150 ν (1 − n)² q/(n³D²) + 1.75 (1 − n) q²/(n³D), at superficial velocity q.
pub fn ergun_gradient(q: f64, nu: f64, porosity: f64, d: f64) -> f64 {
    let n = porosity;
    150.0 * nu * (1.0 - n).powi(2) * q / (n.powi(3) * d * d) + 1.75 * (1.0 - n) * q * q / (n.powi(3) * d)
}

/// Ergun's superficial velocity under gradient `g` per unit density (the
/// positive root of [`ergun_gradient`] = g).
pub fn ergun_flux(g: f64, nu: f64, porosity: f64, d: f64) -> f64 {
    let n = porosity;
    let a = 150.0 * nu * (1.0 - n).powi(2) / (n.powi(3) * d * d);
    let b = 1.75 * (1.0 - n) / (n.powi(3) * d);
    (-a + (a * a + 4.0 * b * g).sqrt()) / (2.0 * b)
}

/// A measured steady flow through a packing.
#[derive(Debug, Clone, Copy)]
pub struct PackingFlow {
    /// The driving body force per unit mass.
    pub g: f64,
    /// Superficial velocity (mean x-velocity over every cell, grain
    /// interiors included), averaged over the last 500 steps.
    pub q: f64,
    pub steps: usize,
    pub converged: bool,
}

/// Liquid driven along x by body force `g` through the fixed `packing`
/// until the superficial velocity changes by < 1e-4 over 4000 steps (the
/// inertial cases may never settle: then the mean of the last 4000 steps),
/// at most `max_steps`.
pub fn packing_flow(
    packing: &RandomPacking,
    fluid: FluidCondition,
    gain: ForcingGain,
    g: f64,
    max_steps: usize,
) -> PackingFlow {
    let n = packing.box_cells;
    let mut lattice = Fluid::<f64>::new([n; 3], [Faces::Periodic; 3], fluid.params([g, 0.0, 0.0])).expect("valid");
    let mut coupling = Coupling::new(lattice_units(), [0.0; 3]).expect("finite origin").with_gain(gain);
    let spheres = packing.spheres();
    let cells = (n * n * n) as f64;
    // Total x-momentum, tracked: the body force adds ρ g per cell and the
    // forcing its F_IB (mass is conserved, so Σρ = cells).
    let mut p = momentum_x(&lattice);
    let block = 500;
    let mut blocks: Vec<f64> = Vec::new();
    let mut sum = 0.0;
    for step in 1..=max_steps {
        coupling.step(&mut lattice, &spheres).expect("valid spheres");
        p += cells * g + lattice.applied_forcing().iter().map(|c| c.force[0]).sum::<f64>();
        sum += p / cells;
        if step % block == 0 {
            blocks.push(sum / block as f64);
            sum = 0.0;
            if settled(&blocks, 8, 1e-4) {
                return PackingFlow { g, q: *blocks.last().expect("a block"), steps: step, converged: true };
            }
        }
    }
    let tail = &blocks[blocks.len().saturating_sub(8)..];
    let q = tail.iter().sum::<f64>() / tail.len().max(1) as f64;
    PackingFlow { g, q, steps: max_steps, converged: false }
}

/// Darcy permeability of `packing` in creeping flow: the flow under a body
/// force g of Re_p ≈ 0.05 by Kozeny–Carman, k = ν q/g. Returns (k, flow).
pub fn packing_permeability(
    packing: &RandomPacking,
    fluid: FluidCondition,
    gain: ForcingGain,
    max_steps: usize,
) -> (f64, PackingFlow) {
    let nu = fluid.nu();
    let q_target = 0.05 * nu / packing.d;
    let g = nu * q_target / kozeny_carman(packing.porosity, packing.d);
    let flow = packing_flow(packing, fluid, gain, g, max_steps);
    (nu * flow.q / g, flow)
}

/// The flow through `packing` under the gradient that gives Re_p = q D/ν =
/// `re` by Ergun's correlation. Returns (drag / Ergun's drag at the
/// measured q − 1, flow).
pub fn packing_ergun(
    packing: &RandomPacking,
    fluid: FluidCondition,
    gain: ForcingGain,
    re: f64,
    max_steps: usize,
) -> (f64, PackingFlow) {
    let nu = fluid.nu();
    let q_target = re * nu / packing.d;
    let g = ergun_gradient(q_target, nu, packing.porosity, packing.d);
    let flow = packing_flow(packing, fluid, gain, g, max_steps);
    (g / ergun_gradient(flow.q, nu, packing.porosity, packing.d) - 1.0, flow)
}
