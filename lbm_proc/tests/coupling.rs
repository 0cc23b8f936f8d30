//! Particle coupling (Eq. 5): sphere drag against Stokes with the periodic
//! array correction, momentum bookkeeping, buoyancy, thread independence.
//! Formulas: analytic-checks.md, lbm-free-surface.md §6 and §9. Each test
//! prints its numbers (`-- --nocapture`); docs/lbm.md records them.

use std::f64::consts::PI;

use lbm_proc::coupling::{Coupling, CouplingError, ForcingGain, Sphere};
use lbm_proc::fluid::{Faces, Fluid, FluidParams};
use lbm_proc::lattice::{E, Q};
use lbm_proc::real::Real;
use lbm_proc::Units;

fn lattice_units() -> Units {
    Units::new(1.0, 1.0, 1.0).expect("valid")
}

/// Σ_c Σ_i f_i e_i of the stored (post-collision) populations, f64 sums.
fn momentum<T: Real>(fluid: &Fluid<T>) -> [f64; 3] {
    let n = fluid.ncells();
    let p = fluid.state();
    std::array::from_fn(|a| {
        (0..Q).map(|i| E[i][a] as f64 * (0..n).map(|c| p.population(i, c).to_f64()).sum::<f64>()).sum()
    })
}

/// Sangani & Acrivos 1982 / Hasimoto 1959: drag on a simple cubic array of
/// spheres at solid fraction φ over Stokes' 6πμaU, χ = φ^{1/3}.
fn hasimoto(phi: f64) -> f64 {
    let x = phi.cbrt();
    1.0 / (1.0 - 1.7601 * x + x.powi(3) - 1.5593 * x.powi(6) + 3.9799 * x.powi(8) - 3.0734 * x.powi(10))
}

struct Drag {
    /// Mean drag over the averaging window, lattice units.
    force: f64,
    /// Drag / (3πμDU K(φ)) − 1.
    error: f64,
    /// Radius a_h with F = 6πμ a_h U K(4πa_h³/3L³), cells.
    hydrodynamic_radius: f64,
    re: f64,
}

/// A sphere of diameter `d` cells in a periodic box of `l`³ cells (τ = 1, BGK,
/// no Smagorinsky, f64), Re_p = 0.1. `moving`: the sphere moves at U along x
/// through fluid at rest; otherwise it is held fixed and the fluid streams
/// past at U. Either way a uniform body force, recomputed every step from the
/// tracked total momentum, holds the mean velocity of everything in the box
/// (sphere interior included) at its start value: the mean pressure gradient
/// of a periodic array, which is Hasimoto's set-up, and the sphere then sees
/// the superficial relative velocity U. Returns the drag averaged over the
/// last `average` of `steps` steps.
fn drag(d: f64, l: usize, moving: bool, steps: usize, average: usize, gain: ForcingGain) -> Drag {
    drag_at(d, l, moving, steps, average, 1.0, 0.1, gain)
}

/// [`drag`] at relaxation time `tau` and particle Reynolds number `re`.
fn drag_at(d: f64, l: usize, moving: bool, steps: usize, average: usize, tau: f64, re: f64, gain: ForcingGain) -> Drag {
    let nu = (tau - 0.5) / 3.0;
    let u = re * nu / d;
    let params = FluidParams { smagorinsky: 0.0, ..FluidParams::new(tau) };
    let mut fluid = Fluid::<f64>::new([l; 3], [Faces::Periodic; 3], params).expect("valid parameters");
    let fluid_u = if moving { 0.0 } else { u };
    for c in 0..fluid.ncells() {
        fluid.set_equilibrium([c % l, (c / l) % l, c / (l * l)], 1.0, [fluid_u, 0.0, 0.0]).expect("in box");
    }
    let mass = fluid.ncells() as f64;
    let target = momentum(&fluid)[0];
    let mut p = target;
    let mut coupling = Coupling::new(lattice_units(), [0.0; 3]).expect("finite origin").with_gain(gain);
    // Off the lattice symmetry on purpose.
    let mut sphere = Sphere {
        position: [0.5 * l as f64 + 0.23, 0.5 * l as f64 + 0.11, 0.5 * l as f64 - 0.07],
        velocity: [if moving { u } else { 0.0 }, 0.0, 0.0],
        angular_velocity: [0.0; 3],
        radius: 0.5 * d,
    };
    let mut last_ib = 0.0;
    let mut sum = 0.0;
    let mut sum_surface = 0.0;
    let mut sum_buoy = 0.0;
    for step in 0..steps {
        // Deadbeat on the tracked momentum, with this step's F_IB predicted by the last.
        let a = (target - p - last_ib) / mass;
        fluid.set_params(FluidParams { acceleration: [a, 0.0, 0.0], ..params }).expect("finite");
        let f = coupling.step(&mut fluid, &[sphere]).expect("valid sphere")[0];
        last_ib = fluid.applied_forcing().iter().map(|c| c.force[0]).sum();
        p += mass * a + last_ib;
        if step >= steps - average {
            // The drag opposes the relative motion: −x moving, +x fixed.
            sum += if moving { -f.force[0] } else { f.force[0] };
            sum_surface += if moving { -f.surface_force[0] } else { f.surface_force[0] };
            sum_buoy += if moving { -f.buoyancy[0] } else { f.buoyancy[0] };
        }
        sphere.position[0] += sphere.velocity[0];
    }
    let drift = (momentum(&fluid)[0] - p).abs() / mass;
    assert!(drift < 1e-12, "tracked momentum off the lattice's by {drift:e} per cell");
    let force = sum / average as f64;
    // The surface force (what a free grain is given) carries the buoyancy of
    // the driving pressure gradient and the interior liquid's inertia; in
    // steady motion the latter averages out, leaving force + buoyancy.
    let surface = sum_surface / average as f64;
    let balance = (surface - (force + sum_buoy / average as f64)) / force;
    assert!(balance.abs() < 2e-3, "surface force {surface:e} vs force + buoyancy: off by {balance:e} of the drag");
    let mu = nu; // ρ = 1
    let phi = |r: f64| 4.0 * PI * r.powi(3) / 3.0 / (l as f64).powi(3);
    let expected = 3.0 * PI * mu * d * u * hasimoto(phi(0.5 * d));
    // Solve F = 6πμ a U K(φ(a)) for a: the left side grows monotonically in a.
    let (mut lo, mut hi) = (0.1 * d, 0.45 * l as f64);
    for _ in 0..100 {
        let mid = 0.5 * (lo + hi);
        if 6.0 * PI * mu * mid * u * hasimoto(phi(mid)) < force {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    Drag { force, error: force / expected - 1.0, hydrodynamic_radius: 0.5 * (lo + hi), re: u * d / nu }
}

fn report(name: &str, d: f64, l: usize, r: &Drag) {
    println!(
        "{name}: D/dx = {d}, L = {l}, Re = {:.2}, drag {:.6e}, error vs Stokes-Hasimoto {:+.2} %, \
         hydrodynamic radius {:.3} (R = {}), a_h - R = {:+.3}",
        r.re,
        r.force,
        100.0 * r.error,
        r.hydrodynamic_radius,
        0.5 * d,
        r.hydrodynamic_radius - 0.5 * d
    );
}

/// Stokes drag of one sphere (φ = 0.008) at τ = 1, D/Δx = 4 and 8, for two
/// gain rules: the measured errors (covered fraction −7.2 % and −2.5 %;
/// Noble–Torczynski, whose partly covered cells pull less at τ = 1, −18.1 %
/// and −8.2 %; fixed and moving alike to 0.1 %) ± 1 percentage point. The
/// cases are deterministic: the margin is for a deliberate change, which
/// must then be measured again (docs/coupling.md "Choosing the forcing gain"
/// tabulates every rule at τ = 0.6 and 1 and in the paper's water).
fn stokes_drag_within_bounds(moving: bool) {
    for (gain, coarse_measured, fine_measured) in
        [(ForcingGain::CoveredFraction, -0.0720, -0.0248), (ForcingGain::NobleTorczynski, -0.1810, -0.0823)]
    {
        let name = format!("{} {}", if moving { "moving" } else { "fixed" }, gain.name());
        let coarse = drag(4.0, 16, moving, 800, 200, gain);
        report(&name, 4.0, 16, &coarse);
        let fine = drag(8.0, 32, moving, 1600, 400, gain);
        report(&name, 8.0, 32, &fine);
        assert!((coarse.error - coarse_measured).abs() < 0.01, "{name}, D/dx = 4: {:+.4}", coarse.error);
        assert!((fine.error - fine_measured).abs() < 0.01, "{name}, D/dx = 8: {:+.4}", fine.error);
    }
}

#[test]
fn fixed_sphere_in_slow_uniform_flow_matches_stokes_with_hasimoto() {
    // L = 4D in both: φ = 0.0082, K = 1.52. The slowest box mode decays as
    // exp(−4π²ν t/L²): time constant 155 steps at L = 32, 39 at L = 16.
    stokes_drag_within_bounds(false);
}

#[test]
fn sphere_at_prescribed_velocity_feels_the_same_drag() {
    stokes_drag_within_bounds(true);
}

/// Drag over Stokes' 3πμDU of a fixed sphere (D/dx = 8) in a periodic box
/// of `l` cells at Re = 0.1 (τ = 1) and Re = 10 (τ = 0.6: U = 0.042, Mach
/// 0.07); returns (growth from Re 0.1 to 10, Schiller–Naumann's growth).
fn reynolds_growth(l: usize) -> (f64, f64) {
    let k = (l * l) / (32 * 32);
    // The covered fraction's gain does not change with τ, so the growth is the lattice's inertia alone.
    let gain = ForcingGain::CoveredFraction;
    let creeping = drag(8.0, l, false, 1600 * k, 400 * k, gain);
    let inertial = drag_at(8.0, l, false, 6000 * k, 1500 * k, 0.6, 10.0, gain);
    let normalised = |r: &Drag, tau: f64| {
        let nu = (tau - 0.5) / 3.0;
        r.force / (3.0 * PI * nu * 8.0 * (r.re * nu / 8.0))
    };
    let growth = normalised(&inertial, 0.6) / normalised(&creeping, 1.0);
    let schiller_naumann =
        lbm_proc::validation::settling::schiller_naumann(10.0) / lbm_proc::validation::settling::schiller_naumann(0.1);
    println!(
        "drag vs Re, L = {l}: F/(3 pi mu D U) = {:.4} at Re {:.2}, {:.4} at Re {:.2}: grows {growth:.4}x; \
         an isolated sphere (Schiller-Naumann) {schiller_naumann:.4}x ({:+.1} %)",
        normalised(&creeping, 1.0),
        creeping.re,
        normalised(&inertial, 0.6),
        inertial.re,
        100.0 * (growth / schiller_naumann - 1.0)
    );
    (growth, schiller_naumann)
}

#[test]
fn drag_grows_with_reynolds_number_less_than_for_an_isolated_sphere() {
    // In a periodic array the images screen the wake, so from Re 0.1 to 10
    // the drag grows, but by less than Schiller–Naumann's 1.68 for an
    // isolated sphere, and nearer it in a larger box (ignored study below).
    // Measured at L = 4D: 1.26 (−25 %); a lattice that missed inertia would
    // give 1, one that overshot it more than 1.68.
    let (growth, isolated) = reynolds_growth(32);
    assert!(growth > 1.15 && growth < isolated, "drag growth {growth} from Re 0.1 to 10 (isolated sphere {isolated})");
}

#[test]
#[ignore = "L = 6D box (110k cells, f64, 13.5k steps): ~25 s on 2 cores"]
fn drag_growth_with_reynolds_number_approaches_schiller_naumann_in_larger_boxes() {
    // Measured: 1.26 at L = 4D, 1.32 at 6D (−21 %); an extrapolation in 1/L
    // gives ~1.42, still 15 % under Schiller–Naumann: at D/dx = 8 the
    // boundary layer (~D/√Re = 2.5 cells) is under-resolved.
    let (small, _) = reynolds_growth(32);
    let (large, isolated) = reynolds_growth(48);
    assert!(small < large && large < isolated, "growth {small} (4D), {large} (6D), isolated {isolated}");
}

#[test]
#[ignore = "D/dx = 16 in a 64^3 box (262k cells, f64, 6400 steps): minutes on 2 shared cores"]
fn drag_at_d_16() {
    for gain in [ForcingGain::CoveredFraction, ForcingGain::NobleTorczynski] {
        for moving in [false, true] {
            let r = drag(16.0, 64, moving, 6400, 1600, gain);
            report(&format!("{} {}", if moving { "moving" } else { "fixed" }, gain.name()), 16.0, 64, &r);
        }
    }
}

/// Three spheres in a periodic box with gravity: two overlap (shared cells),
/// one straddles the periodic faces; all move and spin.
fn three_spheres(t: f64) -> [Sphere; 3] {
    [
        Sphere {
            position: [6.3 + 2.0 * t, 7.1, 8.2],
            velocity: [0.02, 0.005, -0.01],
            angular_velocity: [0.003, -0.002, 0.004],
            radius: 3.1,
        },
        Sphere {
            position: [11.0, 8.4 - t, 7.6],
            velocity: [-0.015, 0.0, 0.008],
            angular_velocity: [0.0, 0.006, 0.0],
            radius: 2.4,
        },
        Sphere {
            position: [19.6, 1.0, 14.9],
            velocity: [0.0, -0.01, 0.01],
            angular_velocity: [-0.004, 0.0, 0.002],
            radius: 2.0,
        },
    ]
}

#[test]
fn momentum_given_to_the_fluid_is_minus_what_the_spheres_receive() {
    let gravity = [0.0, 0.0, -2e-5];
    let params = FluidParams { acceleration: gravity, ..FluidParams::new(0.6) };
    let mut fluid = Fluid::<f64>::new([20, 18, 16], [Faces::Periodic; 3], params).expect("valid parameters");
    let mut coupling = Coupling::new(lattice_units(), [0.0; 3]).expect("finite origin");
    let mass = fluid.liquid_mass();
    let mut worst: f64 = 0.0;
    let mut largest: f64 = 0.0;
    for step in 0..60 {
        let spheres = three_spheres(step as f64 * 0.05);
        let before = momentum(&fluid);
        let forces = coupling.step(&mut fluid, &spheres).expect("valid spheres").to_vec();
        let after = momentum(&fluid);
        for a in 0..3 {
            let to_fluid = after[a] - before[a] - mass * gravity[a];
            let to_spheres: f64 = forces.iter().map(|f| f.force[a]).sum();
            worst = worst.max((to_fluid + to_spheres).abs());
            largest = largest.max(to_spheres.abs());
        }
    }
    println!("momentum: largest |sum of sphere forces| {largest:.3e}, worst |fluid gain + sphere forces| {worst:.3e}");
    assert!(largest > 1e-2, "the spheres must actually push the fluid");
    assert!(worst < 1e-12, "momentum bookkeeping off by {worst:e}");

    // A fully covered cell moves at the rigid-body velocity in the step it is forced.
    let spheres = three_spheres(3.0);
    coupling.apply(&mut fluid, &spheres).expect("valid spheres");
    fluid.step();
    let cell = fluid.direct_forcing().iter().find(|c| c.weight == 1.0).copied().expect("an interior cell");
    let (nx, ny) = (20, 18);
    let (_, u) = fluid.moments([cell.cell % nx, (cell.cell / nx) % ny, cell.cell / (nx * ny)]).expect("in box");
    let off = (0..3).map(|a| (u[a] - cell.target[a]).abs()).fold(0.0, f64::max);
    println!("interior cell {}: u {u:?} vs rigid-body {:?}, off by {off:.1e}", cell.cell, cell.target);
    assert!(off < 1e-15);
}

/// Σ_i f_i e_i of each cell's stored populations.
fn cell_momenta<T: Real>(fluid: &Fluid<T>) -> Vec<[f64; 3]> {
    let n = fluid.ncells();
    let p = fluid.state();
    (0..n)
        .map(|c| std::array::from_fn(|a| (0..Q).map(|i| E[i][a] as f64 * p.population(i, c).to_f64()).sum()))
        .collect()
}

#[test]
fn each_exchange_the_liquid_outside_the_grains_loses_what_they_gain() {
    // The surface force (what a free grain is given) measured against the
    // lattice, exchange by exchange: with w_c the covered weight of cell c
    // in a step, the liquid outside the grains after it, Σ_c (1 − w_c) P_c,
    // changes by its own weight (M − m_L) a minus the grains' surface
    // forces, also as cells enter and leave the grains. Moving, spinning,
    // overlapping and wrapping spheres in a periodic box with gravity.
    let gravity = [0.0, 0.0, -2e-5];
    let params = FluidParams { acceleration: gravity, ..FluidParams::new(0.6) };
    let mut fluid = Fluid::<f64>::new([20, 18, 16], [Faces::Periodic; 3], params).expect("valid parameters");
    let mut coupling = Coupling::new(lattice_units(), [0.0; 3]).expect("finite origin");
    let mass = fluid.liquid_mass();
    let outside = |fluid: &Fluid<f64>| -> [f64; 3] {
        let p = cell_momenta(fluid);
        std::array::from_fn(|a| {
            let held: f64 = fluid.direct_forcing().iter().map(|c| c.weight * p[c.cell][a]).sum();
            p.iter().map(|q| q[a]).sum::<f64>() - held
        })
    };
    let (mut worst, mut largest, mut swept) = (0.0_f64, 0.0_f64, 0.0_f64);
    let mut before: Option<[f64; 3]> = None;
    for step in 0..60 {
        let spheres = three_spheres(step as f64 * 0.05);
        let forces = coupling.step(&mut fluid, &spheres).expect("valid spheres").to_vec();
        assert_eq!(coupling.collect(&fluid).expect("the same step"), &forces[..], "asked twice, the same forces");
        let after = outside(&fluid);
        let covered_liquid: f64 = forces.iter().map(|f| f.liquid_mass).sum();
        if let Some(before) = before {
            for a in 0..3 {
                let to_grains: f64 = forces.iter().map(|f| f.surface_force[a]).sum();
                let streamed: f64 = forces.iter().map(|f| f.force[a] + f.buoyancy[a]).sum();
                worst = worst.max((after[a] - before[a] - (mass - covered_liquid) * gravity[a] + to_grains).abs());
                largest = largest.max(to_grains.abs());
                swept = swept.max((to_grains - streamed).abs());
            }
        }
        before = Some(after);
    }
    println!(
        "surface force balance: largest |sum of surface forces| {largest:.3e}, worst imbalance {worst:.3e}, \
         largest interior inertia {swept:.3e}"
    );
    assert!(largest > 1e-2, "the spheres must actually push the fluid");
    assert!(swept > 1e-3 * largest, "the held liquid's inertia must count in the balance");
    assert!(worst < 1e-12 * largest.max(1.0), "outside liquid and grains out of balance by {worst:e}");
}

#[test]
fn results_with_spheres_do_not_depend_on_thread_count() {
    let params = FluidParams { acceleration: [0.0, 0.0, -2e-5], ..FluidParams::new(0.55) };
    let fluid = Fluid::<f32>::new([20, 18, 16], [Faces::Periodic; 3], params).expect("valid parameters");
    let run = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("pool");
        let mut fluid = fluid.clone();
        let mut coupling = Coupling::new(lattice_units(), [0.0; 3]).expect("finite origin");
        let mut forces = Vec::new();
        pool.install(|| {
            for step in 0..40 {
                let f = coupling.step(&mut fluid, &three_spheres(step as f64 * 0.05)).expect("valid spheres");
                forces.extend_from_slice(f);
            }
        });
        (fluid, forces)
    };
    let (one, f1) = run(1);
    let (two, f2) = run(2);
    assert!(one.state() == two.state(), "1 and 2 threads differ");
    assert!(f1 == f2, "sphere forces differ between 1 and 2 threads");
}

/// A 20 × 20 × 30 closed tank, liquid below z = 24 (surface at lattice
/// z = 23.0, the centre of the half-filled top layer), paper-like units:
/// Δx = 1 mm, g_L = 1e-4, ρ0 = 1000 kg/m³, τ = 1; relaxed to rest.
fn tank() -> (Fluid<f64>, Units, f64) {
    let dx = 1e-3;
    let g = 9.81;
    let dt = (1e-4 * dx / g).sqrt();
    let units = Units::new(dx, dt, 1000.0).expect("valid");
    let params = FluidParams { acceleration: [0.0, 0.0, -1e-4], ..FluidParams::new(1.0) };
    let mut fluid = Fluid::<f64>::new([20, 20, 30], [Faces::Walls; 3], params).expect("valid parameters");
    fluid.init_liquid(|c| c[2] < 24).expect("in box");
    // The equilibrium start lacks the non-equilibrium part of the density
    // gradient: let its acoustic transient decay (τ = 1) before a grain goes in.
    for _ in 0..1500 {
        fluid.step();
    }
    (fluid, units, g)
}

/// SI position of lattice point (x, y, z) (cell centres at integers).
fn si(units: &Units, p: [f64; 3]) -> [f64; 3] {
    p.map(|x| (x + 0.5) * units.dx())
}

#[test]
fn sphere_at_rest_in_a_tank_gets_the_buoyancy_of_its_wetted_part() {
    let (fluid, units, g) = tank();
    for (radius, centre_z, wetted) in [(2.0, 12.0, 1.0), (4.0, 12.0, 1.0), (4.0, 23.0, 0.5)] {
        let mut fluid = fluid.clone();
        let mut coupling = Coupling::new(units, [0.0; 3]).expect("finite origin");
        let centre = [9.6, 10.3, centre_z];
        let sphere = Sphere {
            position: si(&units, centre),
            velocity: [0.0; 3],
            angular_velocity: [0.0; 3],
            radius: radius * units.dx(),
        };
        // The liquid density at the centre: hydrostatic, ρ_L = 1 + 3 g_L depth.
        let (rho, _) = fluid.moments([10, 10, centre_z as usize]).expect("in box");
        let expected = units.density_to_si(rho) * g * wetted * 4.0 * PI / 3.0 * sphere.radius.powi(3);
        let mut f = Default::default();
        for _ in 0..200 {
            f = coupling.step(&mut fluid, &[sphere]).expect("valid sphere")[0];
        }
        let up = f.total()[2];
        let residual = f.force.iter().map(|x| x.abs()).fold(0.0, f64::max);
        println!(
            "buoyancy R = {radius} dx, centre z = {centre_z}: {up:.6e} N vs rho_L g V_wet {expected:.6e} N \
             ({:+.3} %), |forcing part| {residual:.2e} N, max|u| {:.1e}",
            100.0 * (up / expected - 1.0),
            fluid.max_speed()
        );
        // Volume of the ramp: within 0.7 % of 4πR³/3 for any position
        // (coupling.rs); a half-wetted sphere also carries the surface
        // layer's fill, so 3 %.
        let tolerance = if wetted < 1.0 { 0.03 } else { 0.01 };
        assert!((up / expected - 1.0).abs() < tolerance);
        // The relaxed tank keeps |u| ~ 1e-9 of its start-up transient.
        assert!(residual < 1e-4 * expected, "a resting grain in resting liquid needs no forcing");
        assert!(f.buoyancy[0] == 0.0 && f.buoyancy[1] == 0.0);
        // The surface force a free grain is given (momentum flux into its
        // covered cells) is the same buoyancy, measured instead of modelled.
        let surface = f.surface_force[2];
        println!("  surface force {surface:.6e} N ({:+.3} % of the modelled buoyancy)", 100.0 * (surface / up - 1.0));
        assert!((surface / up - 1.0).abs() < 1e-3, "surface force {surface:e} vs buoyancy {up:e}");
    }
}

#[test]
fn neutrally_buoyant_sphere_is_in_force_balance() {
    // A grain of density ρ_L held at rest for 500 steps: the net force
    // F_forcing + F_buoyancy + m g must vanish, so a DEM would leave it in
    // place. The grain's mass uses the true volume 4πR³/3, the buoyancy the
    // lattice's covered volume: they differ by the ramp's volume error
    // (< 0.7 %, coupling.rs), the tolerance. Integrating the grain here by
    // explicit Euler instead diverges (NaN within 1000 steps): at ρ_p = ρ_f
    // the interior liquid's reaction −m_L dU/dt cancels the grain's own
    // inertia, the known limit of explicit direct forcing (stable for
    // ρ_p/ρ_f ≳ 1.2 with the m_L dU/dt term, lbm-free-surface.md §6); the
    // free neutrally buoyant grain is the DEM's to handle.
    let (mut fluid, units, g) = tank();
    let mut coupling = Coupling::new(units, [0.0; 3]).expect("finite origin");
    let (rho, _) = fluid.moments([10, 10, 12]).expect("in box");
    let radius = 4.0 * units.dx();
    let mass = units.density_to_si(rho) * 4.0 * PI / 3.0 * radius.powi(3);
    let sphere =
        Sphere { position: si(&units, [9.6, 10.3, 12.0]), velocity: [0.0; 3], angular_velocity: [0.0; 3], radius };
    let (mut worst, mut worst_lattice): (f64, f64) = (0.0, 0.0);
    for _ in 0..500 {
        let f = coupling.step(&mut fluid, &[sphere]).expect("valid sphere")[0];
        let total = f.total();
        let net = [total[0], total[1], total[2] - mass * g];
        worst = worst.max(net.iter().map(|x| x.abs()).fold(0.0, f64::max) / (mass * g));
        // With the mass of the covered liquid itself the balance is exact up to the forcing residual.
        worst_lattice = worst_lattice.max((total[2] - f.liquid_mass * g).abs() / (mass * g));
    }
    println!(
        "neutrally buoyant, held: max |net force| / weight {worst:.2e} (true volume), \
         {worst_lattice:.2e} (covered volume); max|u| {:.1e}",
        fluid.max_speed()
    );
    assert!(worst < 7e-3);
    assert!(worst_lattice < 1e-4);
}

#[test]
fn bad_spheres_are_typed_errors() {
    let mut fluid = Fluid::<f32>::new([12, 12, 12], [Faces::Periodic; 3], FluidParams::new(0.6)).expect("valid");
    let mut coupling = Coupling::new(lattice_units(), [0.0; 3]).expect("finite origin");
    let good = Sphere { position: [6.0; 3], velocity: [0.0; 3], angular_velocity: [0.0; 3], radius: 2.0 };
    assert_eq!(coupling.collect(&fluid).err(), Some(CouplingError::Stale), "nothing applied yet");
    coupling.apply(&mut fluid, &[good]).expect("valid sphere");
    assert_eq!(coupling.collect(&fluid).err(), Some(CouplingError::Stale), "no step since apply");
    coupling.apply(&mut fluid, &[good]).expect("valid sphere");
    fluid.clear_direct_forcing();
    fluid.step();
    assert_eq!(coupling.collect(&fluid).err(), Some(CouplingError::Stale), "the fluid's forcing replaced since apply");
    coupling.apply(&mut fluid, &[good]).expect("valid sphere");
    fluid.step();
    assert!(coupling.collect(&fluid).is_ok(), "apply, one step, collect");
    let cases = [
        Sphere { radius: 0.0, ..good },
        Sphere { radius: f64::NAN, ..good },
        Sphere { position: [f64::INFINITY, 0.0, 0.0], ..good },
        Sphere { radius: 6.0, ..good },
    ];
    for bad in cases {
        assert!(matches!(coupling.apply(&mut fluid, &[good, bad]), Err(CouplingError::Sphere { index: 1, .. })));
    }
    assert!(Coupling::new(lattice_units(), [f64::NAN; 3]).is_err());
    use lbm_proc::fluid::{ConfigError, ForcedCell};
    let cell = |cell, weight| ForcedCell { cell, weight, target: [0.0; 3] };
    let e = fluid.set_direct_forcing([cell(5, 0.5), cell(5, 0.5)]).expect_err("repeated cell");
    assert!(matches!(e, ConfigError::Forcing { cell: 5, .. }));
    assert!(fluid.set_direct_forcing([cell(5, 1.5)]).is_err());
    assert!(fluid.set_direct_forcing([cell(12 * 12 * 12, 0.5)]).is_err());
    assert!(fluid.direct_forcing().is_empty(), "a refused list leaves no forcing behind");
}

/// A sphere spinning at ω in liquid at rest feels the torque −8πμR³ω
/// (Stokes), here in a periodic box of 4D (τ = 1, f64, D/Δx = 8), Re_ω =
/// ωR²/ν = 0.1. Both the forcing reaction and the surface torque (what a
/// free grain is given) must oppose the spin; the box's periodic images and
/// the ramp's hydrodynamic radius (a_h ≈ R − 0.07Δx) make it a few % low.
#[test]
fn spinning_sphere_feels_the_stokes_torque() {
    let (d, l) = (8.0, 32usize);
    let tau = 1.0;
    let nu = (tau - 0.5) / 3.0;
    let r = 0.5 * d;
    let omega = 0.1 * nu / (r * r);
    let params = FluidParams { smagorinsky: 0.0, ..FluidParams::new(tau) };
    let mut fluid = Fluid::<f64>::new([l; 3], [Faces::Periodic; 3], params).expect("valid parameters");
    let mut coupling = Coupling::new(lattice_units(), [0.0; 3]).expect("finite origin");
    let sphere = Sphere {
        position: [0.5 * l as f64 + 0.23, 0.5 * l as f64 + 0.11, 0.5 * l as f64 - 0.07],
        velocity: [0.0; 3],
        angular_velocity: [0.0, 0.0, omega],
        radius: r,
    };
    let (mut torque, mut surface) = (0.0, 0.0);
    let (steps, average) = (1500, 300);
    for step in 0..steps {
        let f = coupling.step(&mut fluid, &[sphere]).expect("valid sphere")[0];
        if step >= steps - average {
            torque += f.torque[2] / average as f64;
            surface += f.surface_torque[2] / average as f64;
        }
    }
    let stokes = -8.0 * PI * nu * r.powi(3) * omega;
    println!(
        "spinning sphere D/dx = {d}: torque {torque:.4e}, surface torque {surface:.4e}, Stokes {stokes:.4e} ({:+.1} %, {:+.1} %)",
        100.0 * (torque / stokes - 1.0),
        100.0 * (surface / stokes - 1.0)
    );
    assert!(torque < 0.0 && surface < 0.0, "the torque must oppose the spin");
    assert!((torque / stokes - 1.0).abs() < 0.15, "torque {torque:e} vs Stokes {stokes:e}");
    assert!((surface / torque - 1.0).abs() < 0.01, "steady spin: surface torque {surface:e} vs reaction {torque:e}");
}

/// The row-by-row covering (`Coupling::apply`) against covering every cell
/// of every sphere's bounding box one at a time: 150 overlapping spheres of
/// radius 1.3–3.1 cells, some across the periodic x and y faces and some
/// partly beyond the walls in z (enough crossings for the parallel parts).
/// Same cells, same weights and targets bit for bit (each cell's sums run
/// over its spheres in ascending order in both), on 1 and 2 threads.
#[test]
fn row_covering_matches_covering_cell_by_cell() {
    let dims = [23, 17, 29];
    let faces = [Faces::Periodic, Faces::Periodic, Faces::Walls];
    let mut state = 12345u64;
    let mut uniform = move |lo: f64, hi: f64| {
        state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        lo + (hi - lo) * ((state >> 11) as f64 / (1u64 << 53) as f64)
    };
    let spheres: Vec<Sphere> = (0..150)
        .map(|_| Sphere {
            position: [uniform(-2.0, 25.0), uniform(-2.0, 19.0), uniform(-1.5, 30.5)],
            velocity: [uniform(-0.02, 0.02), uniform(-0.02, 0.02), uniform(-0.02, 0.02)],
            angular_velocity: [uniform(-0.01, 0.01), uniform(-0.01, 0.01), uniform(-0.01, 0.01)],
            radius: uniform(1.3, 3.1),
        })
        .collect();
    // Cell by cell: lattice units with the origin at 0, so cell i's centre is at i + ½.
    let mut cells: std::collections::BTreeMap<usize, (f64, [f64; 3])> = Default::default();
    for s in &spheres {
        let mut x = s.radius;
        for _ in 0..8 {
            x -= (x * x * x + 0.25 * x - s.radius.powi(3)) / (3.0 * x * x + 0.25);
        }
        let p = s.position.map(|c| c - 0.5);
        let reach = x + 0.5;
        let lo = p.map(|c| (c - reach).ceil() as i64);
        let hi = p.map(|c| (c + reach).floor() as i64);
        for k in lo[2]..=hi[2] {
            for j in lo[1]..=hi[1] {
                for i in lo[0]..=hi[0] {
                    if !(0..dims[2] as i64).contains(&k) {
                        continue;
                    }
                    let r = [i as f64 - p[0], j as f64 - p[1], k as f64 - p[2]];
                    let eps = (0.5 - ((r[0] * r[0] + r[1] * r[1] + r[2] * r[2]).sqrt() - x)).clamp(0.0, 1.0);
                    if eps > 0.0 {
                        let ix = i.rem_euclid(dims[0] as i64) as usize;
                        let jy = j.rem_euclid(dims[1] as i64) as usize;
                        let cell = (k as usize * dims[1] + jy) * dims[0] + ix;
                        let w = s.angular_velocity;
                        let rot = [w[1] * r[2] - w[2] * r[1], w[2] * r[0] - w[0] * r[2], w[0] * r[1] - w[1] * r[0]];
                        let e = cells.entry(cell).or_insert((0.0, [0.0; 3]));
                        e.0 += eps;
                        for a in 0..3 {
                            e.1[a] += eps * (s.velocity[a] + rot[a]);
                        }
                    }
                }
            }
        }
    }
    assert!(cells.len() > 5000, "the spheres cover {} cells", cells.len());
    assert!(cells.values().any(|c| c.0 > 1.0), "some cells are covered by several spheres");
    for threads in [1, 2] {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("pool");
        let forced = pool.install(|| {
            let mut fluid = Fluid::<f32>::new(dims, faces, FluidParams::new(0.6)).expect("valid");
            let mut coupling = Coupling::new(lattice_units(), [0.0; 3]).expect("finite origin");
            coupling.apply(&mut fluid, &spheres).expect("valid spheres");
            fluid.direct_forcing().to_vec()
        });
        assert_eq!(forced.len(), cells.len(), "{threads} threads: number of forced cells");
        for (f, (&cell, &(total, target))) in forced.iter().zip(&cells) {
            assert_eq!(f.cell, cell, "{threads} threads: cells in ascending order");
            assert_eq!(f.weight, total.min(1.0), "{threads} threads: weight of cell {cell}");
            assert_eq!(f.target, target.map(|t| t / total), "{threads} threads: target of cell {cell}");
        }
    }
}

/// The two hydrostatics forms of a submerged scene (docs/coupling.md,
/// "Submerged scenes"): a sphere moving down at constant velocity in a
/// closed tank gets the same load whether the liquid's weight is on the
/// lattice (gravity g, hydrostatic initial density; the surface force
/// carries the buoyancy) or left off it (no gravity; buoyancy ρ0 V g added,
/// V = 4πR³/3, as `GrainForcing::with_added_buoyancy` does). The head is
/// small (3g·48 = 1.4e-3 of the density), so the forms must agree to 1e-3
/// of the drag; measured 2e-4.
#[test]
fn added_buoyancy_equals_the_lattice_hydrostatics_for_a_moving_sphere() {
    let dims = [24, 24, 48];
    let (g, r, u) = (1e-5, 3.0, -2e-3);
    let surface_force = |gravity: f64| {
        let params = FluidParams { acceleration: [0.0, 0.0, -gravity], smagorinsky: 0.0, ..FluidParams::new(1.5) };
        let mut fluid = Fluid::<f64>::new(dims, [Faces::Walls; 3], params).expect("valid parameters");
        for k in 0..dims[2] {
            for j in 0..dims[1] {
                for i in 0..dims[0] {
                    let rho = 1.0 - 3.0 * gravity * (k as f64 + 0.5 - 0.5 * dims[2] as f64);
                    fluid.set_equilibrium([i, j, k], rho, [0.0; 3]).expect("in box");
                }
            }
        }
        let mut coupling =
            Coupling::new(lattice_units(), [0.0; 3]).expect("finite origin").with_gain(ForcingGain::CoveredFraction);
        let mut z = 36.0;
        let mut f = 0.0;
        for _ in 0..3000 {
            let sphere =
                Sphere { position: [12.1, 11.9, z], velocity: [0.0, 0.0, u], angular_velocity: [0.0; 3], radius: r };
            f = coupling.step(&mut fluid, &[sphere]).expect("valid sphere")[0].surface_force[2];
            z += u;
        }
        f
    };
    let on_lattice = surface_force(g);
    let added = surface_force(0.0) + g * 4.0 / 3.0 * PI * r.powi(3);
    let buoyancy = g * 4.0 / 3.0 * PI * r.powi(3);
    let drag = on_lattice - buoyancy;
    println!("surface force: weight on the lattice {on_lattice:.6e}, off it + buoyancy {added:.6e} (drag {drag:.4e})");
    assert!(drag > 10.0 * buoyancy, "the case must be drag-dominated to test the drag's equality");
    assert!((added - on_lattice).abs() < 1e-3 * drag, "{added:e} vs {on_lattice:e}");
}
