//! Free surface (mass tracking): hydrostatic tank with a surface, collapsing
//! water block (dam break), the paper's water case with a surface, gate
//! removal, thread-count independence and exact restart. Each test prints
//! its numbers (`cargo test -- --nocapture`); docs/lbm.md records them.

use lbm_proc::fluid::{flags, Faces, Fluid, FluidParams};
use lbm_proc::real::Real;
use lbm_proc::{Units, WatchdogLimits};

/// Relative drift of the liquid mass since set-up.
fn drift<T: Real>(fluid: &Fluid<T>) -> f64 {
    fluid.mass_drift().expect("liquid was set up").abs()
}

/// Front position along x in cells from the wall face at x = 0: the largest,
/// over y, liquid length Σ_x ε of the bottom row (volume-based, so it moves
/// smoothly as the tip cells fill).
fn front<T: Real>(fluid: &Fluid<T>) -> f64 {
    let [nx, ny, _] = fluid.dims();
    let fill = fluid.fill_field();
    (0..ny).map(|y| (0..nx).map(|x| fill[y * nx + x]).sum::<f64>()).fold(0.0, f64::max)
}

/// z of every interface cell.
fn interface_layers<T: Real>(fluid: &Fluid<T>) -> (usize, usize) {
    fluid.interface().fold((usize::MAX, 0), |(lo, hi), c| (lo.min(c.cell[2]), hi.max(c.cell[2])))
}

struct Tank {
    max_u: f64,
    drift: f64,
    layers: (usize, usize),
    fill: (f64, f64),
    /// Mean p − p_surface per layer of the liquid, Pa.
    pressure: Vec<f64>,
}

fn tank<T: Real>(params: FluidParams, dims: [usize; 3], depth: usize, steps: usize, units: &Units) -> Tank {
    let mut fluid = Fluid::<T>::new(dims, [Faces::Walls; 3], params).expect("valid parameters");
    fluid.init_liquid(|c| c[2] < depth).expect("in box");
    for s in 0..steps {
        fluid.step();
        if s % 500 == 0 {
            fluid.check(&WatchdogLimits::default()).expect("stable");
        }
    }
    fluid.check(&WatchdogLimits::default()).expect("stable");
    let fill = fluid.interface().fold((f64::MAX, f64::MIN), |(lo, hi), c| (lo.min(c.fill), hi.max(c.fill)));
    let [nx, ny, _] = dims;
    let pressure = (0..depth)
        .map(|z| {
            let mut s = 0.0;
            for y in 0..ny {
                for x in 0..nx {
                    s += units.pressure_from_density(fluid.sample([x, y, z]).expect("in box").density);
                }
            }
            s / (nx * ny) as f64
        })
        .collect();
    Tank { max_u: fluid.max_speed(), drift: drift(&fluid), layers: interface_layers(&fluid), fill, pressure }
}

#[test]
fn hydrostatic_tank_with_a_free_surface_stays_flat_and_at_rest() {
    // The paper's lattice (g_L = 1.046e-4) with a viscous liquid (τ = 1) so
    // that start-up acoustic waves die within the run; 8 × 8 × 24 cells,
    // liquid in z < 12: the top liquid layer z = 11 is the interface (ε = ½).
    let units = Units::new(6e-4, 8e-5, 1000.0).expect("valid");
    let g = 9.81;
    let g_l = units.acceleration_to_lattice(g);
    let params = FluidParams { acceleration: [0.0, 0.0, -g_l], ..FluidParams::new(1.0) };
    let (dims, depth, steps) = ([8, 8, 24], 12, 6000);
    for name in ["f32", "f64"] {
        let t = if name == "f32" {
            tank::<f32>(params, dims, depth, steps, &units)
        } else {
            tank::<f64>(params, dims, depth, steps, &units)
        };
        let surface = t.pressure[depth - 1];
        let mut worst = 0.0_f64;
        for (z, &p) in t.pressure.iter().enumerate().take(depth - 1) {
            let exact = 1000.0 * g * units.length_to_si((depth - 1 - z) as f64);
            worst = worst.max(((p - surface) - exact).abs() / exact);
        }
        eprintln!(
            "free-surface tank {name}: interface layers z = {:?}, fill in [{:.6}, {:.6}], max|u| = {:.2e}, \
             p vs rho0 g h max rel. error {worst:.2e}, mass drift {:.1e}",
            t.layers, t.fill.0, t.fill.1, t.max_u, t.drift
        );
        assert_eq!(t.layers, (depth - 1, depth - 1), "{name}: the surface must stay one flat layer");
        assert!(t.max_u < 1e-6, "{name}: max |u| = {:e}", t.max_u);
        assert!(worst < 3.0 * g_l * depth as f64, "{name}: rho g h error {worst}");
        let mass_bound = if name == "f32" { 1e-6 } else { 1e-12 };
        assert!(t.drift < mass_bound, "{name}: mass drift {:e}", t.drift);
    }
}

struct DamBreak {
    /// (step, front in cells) every `every` steps.
    front: Vec<(usize, f64)>,
    max_drift: f64,
    max_ke: f64,
    conversions_seen: usize,
    pending: f64,
}

/// A block `block` = [length, height] of liquid against the x = 0 wall of a
/// closed box (periodic in y), gravity −z.
fn dam_break<T: Real>(params: FluidParams, dims: [usize; 3], block: [usize; 2], steps: usize, every: usize) -> DamBreak {
    let faces = [Faces::Walls, Faces::Periodic, Faces::Walls];
    let mut fluid = Fluid::<T>::new(dims, faces, params).expect("valid parameters");
    fluid.init_liquid(|c| c[0] < block[0] && c[2] < block[1]).expect("in box");
    let mut out = DamBreak { front: vec![(0, front(&fluid))], max_drift: 0.0, max_ke: 0.0, conversions_seen: 0, pending: 0.0 };
    let mut last_active = fluid.active_cells();
    for s in 1..=steps {
        fluid.step();
        if fluid.active_cells() != last_active {
            out.conversions_seen += 1;
            last_active = fluid.active_cells();
        }
        if s % every == 0 {
            if let Err(e) = fluid.check(&WatchdogLimits::default()) {
                panic!("{e}");
            }
            out.front.push((s, front(&fluid)));
            out.max_drift = out.max_drift.max(drift(&fluid));
            out.max_ke = out.max_ke.max(fluid.kinetic_energy());
        }
    }
    out.pending = fluid.pending_excess();
    out
}

#[test]
fn collapsing_water_block_conserves_mass_and_its_front_obeys_ritter() {
    // Quasi-2D box 96 × 2 × 40, block 16 × 32, g_L = 5e-5: Ritter's front
    // speed 2√(g h0) = 0.080 (Mach 0.14), time unit √(h0/g) = 800 steps.
    let g = 5e-5;
    let (h0, l0) = (32usize, 16usize);
    let params = FluidParams { acceleration: [0.0, 0.0, -g], ..FluidParams::new(0.51) };
    let ritter = 2.0 * (g * h0 as f64).sqrt();
    for name in ["f64", "f32"] {
        let run = if name == "f64" {
            dam_break::<f64>(params, [96, 2, 40], [l0, h0], 2400, 50)
        } else {
            dam_break::<f32>(params, [96, 2, 40], [l0, h0], 2400, 50)
        };
        let speeds: Vec<f64> = run.front.windows(2).map(|w| (w[1].1 - w[0].1) / (w[1].0 - w[0].0) as f64).collect();
        let fronts: Vec<String> = run.front.iter().step_by(4).map(|(s, x)| format!("{s}:{x:.2}")).collect();
        let max_speed = speeds.iter().cloned().fold(f64::MIN, f64::max);
        let min_speed = speeds.iter().cloned().fold(f64::MAX, f64::min);
        eprintln!(
            "dam break {name}: front {}; speed range [{min_speed:.4}, {max_speed:.4}] vs Ritter {ritter:.4}; \
             max mass drift {:.2e}; steps with conversions {}; pending excess {:.2e}; max KE {:.3e}",
            fronts.join(" "),
            run.max_drift,
            run.conversions_seen,
            run.pending,
            run.max_ke
        );
    }
}

