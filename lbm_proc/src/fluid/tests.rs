use super::collision::*;
use super::*;
use crate::lattice::{equilibrium, CS2};

fn periodic<T: Real>(dims: [usize; 3], params: FluidParams) -> Fluid<T> {
    Fluid::new(dims, [Faces::Periodic; 3], params).expect("valid parameters")
}

#[test]
fn smagorinsky_tau_reads_the_non_equilibrium_stress() {
    // f = f_eq(ρ, u) + w_i 9/2 (e_i e_i − I/3) : Π with a traceless Π:
    // its second moment beyond equilibrium is exactly Π, so |Π^neq| = |Π|
    // and τ follows the closed form; the shift g = f − w of the storage.
    let (rho, u) = (1.02, [0.03, -0.01, 0.02]);
    let pi = [[2e-4, 1e-3, 0.0], [1e-3, -3e-4, -5e-4], [0.0, -5e-4, 1e-4]];
    let feq = equilibrium(rho, u);
    let g: [f64; Q] = std::array::from_fn(|i| {
        let contraction: f64 = (0..3)
            .flat_map(|x| (0..3).map(move |y| (x, y)))
            .map(|(x, y)| {
                let q = (E[i][x] * E[i][y]) as f64 - if x == y { CS2 } else { 0.0 };
                q * pi[x][y]
            })
            .sum();
        feq[i] + W[i] * contraction / (2.0 * CS2 * CS2) - W[i]
    });
    let norm = pi.iter().flatten().map(|p| p * p).sum::<f64>().sqrt();
    let (tau0, smag) = (0.500667, 18.0 * std::f64::consts::SQRT_2 * 0.16 * 0.16);
    let expected = 0.5 * (tau0 + (tau0 * tau0 + smag * norm / rho).sqrt());
    let tau = smagorinsky_tau(&g, [0.0; 3], tau0, smag);
    assert!((tau - expected).abs() < 1e-12, "{tau} vs {expected}");
    assert!(tau > tau0 + 4e-4, "the strain must raise tau: {tau}");
    // At equilibrium τ_eff is τ0.
    let g0: [f64; Q] = std::array::from_fn(|i| feq[i] - W[i]);
    assert!((smagorinsky_tau(&g0, [0.0; 3], tau0, smag) - tau0).abs() < 1e-9);
}

#[test]
fn uniform_flow_is_a_fixed_point_of_the_kernel() {
    // A uniform equilibrium has no gradients: streaming moves identical
    // cells and Π^neq = 0, so collision must return f^eq exactly. This
    // pins the kernel's hand-written moments, weights and equilibrium to
    // lattice::equilibrium.
    let u = [0.05, -0.03, 0.02];
    for collision in [Collision::Bgk, Collision::TRT_3_16] {
        let params = FluidParams { collision, ..FluidParams::new(0.53) };
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
                let f = fluid.state().population(i, c) + W[i];
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
        let params = FluidParams { collision, acceleration: a, ..FluidParams::new(0.7) };
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
    let slot = fluid.state.layout().index(7, 0);
    fluid.state.populations[slot] = f32::NAN;
    let e = fluid.check(&WatchdogLimits::default()).expect_err("NaN");
    assert_eq!((e.cell, e.quantity), ([0, 0, 0], Quantity::Population(7)));
    let msg = e.to_string();
    assert!(msg.contains("cell (0, 0, 0)") && msg.contains("f_7") && msg.contains("Smagorinsky"), "{msg}");
}

#[test]
fn watchdog_checks_the_interface_fill_and_set_up_errors_are_typed() {
    let params = FluidParams { acceleration: [0.0, 0.0, -1e-4], ..FluidParams::new(0.6) };
    let mut fluid = Fluid::<f32>::new([6, 5, 8], [Faces::Walls; 3], params).expect("valid parameters");
    fluid.init_liquid(|c| c[2] < 4).expect("in box");
    assert_eq!(fluid.interface_cells(), 30, "one layer of 6 x 5 interface cells at z = 3");
    assert_eq!(fluid.active_cells(), 120);
    assert!((fluid.fill([2, 2, 3]).expect("in box") - 0.5).abs() < 1e-12);
    assert_eq!(fluid.check(&WatchdogLimits::default()), Ok(()));
    let c = (3 * 5 + 2) * 6 + 4;
    fluid.state.mass[c] = 2.2;
    let e = fluid.check(&WatchdogLimits::default()).expect_err("fill 2.2");
    assert_eq!((e.cell, e.quantity), ([4, 2, 3], Quantity::Fill));
    assert!(e.to_string().contains("interface fill"), "{e}");
    assert_eq!(fluid.set_flag([0, 0, 0], flags::GAS), Err(ConfigError::Flag(flags::GAS)));
    assert!(matches!(fluid.remove_walls(&[[1, 1, 1]]), Err(ConfigError::NotWall([1, 1, 1]))));
    // The kernel lets only interface cells pull from gas: a fluid cell
    // next to gas is refused, from set-up and from a saved state.
    assert_eq!(fluid.set_flag([2, 2, 3], flags::FLUID), Err(ConfigError::FluidNextToGas([2, 2, 3])));
    assert_eq!(fluid.flag([2, 2, 3]), Ok(flags::INTERFACE), "a refused change leaves the cell as it was");
    let mut state = fluid.state().clone();
    state.flags[(4 * 5 + 2) * 6 + 2] = flags::FLUID;
    assert!(matches!(Fluid::from_state(state, params), Err(ConfigError::FluidNextToGas([2, 2, 4]))));
    let p = FluidParams { kappa: 0.7, ..params };
    assert_eq!(fluid.set_params(p), Err(ConfigError::Kappa(0.7)));
}

#[test]
fn results_do_not_depend_on_thread_count_and_restart_is_exact() {
    let params = FluidParams { acceleration: [1e-5, 0.0, -2e-5], ..FluidParams::new(0.52) };
    let mut fluid =
        Fluid::<f32>::new([20, 6, 9], [Faces::Periodic, Faces::Walls, Faces::Walls], params).expect("valid parameters");
    fluid.set_flag([5, 2, 4], flags::WALL).expect("in box");
    for c in 0..fluid.ncells() {
        let (x, y, z) = (c % 20, (c / 20) % 6, c / 120);
        let u = [0.03 * (y as f64 * 0.7).sin(), 0.02 * (x as f64 * 0.3).cos(), 0.01 * (z as f64).sin()];
        if [x, y, z] == [5, 2, 4] {
            assert_eq!(fluid.set_equilibrium([x, y, z], 1.0, u), Err(ConfigError::NotLiquid([x, y, z])));
        } else {
            fluid.set_equilibrium([x, y, z], 1.0, u).expect("in box");
        }
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
