//! Same scene, same result: on 1 and 2 threads, and after a restart from a
//! recorded state (the `/mpm/state` record), bit for bit.

mod common;

use mpm_proc::run::MpmStateRecord;
use mpm_proc::setup::build;
use mpm_proc::solver::MpmState;
use schemas::Scene;

/// `scenes/validation/mpm_slump.toml`: a saturated block with free water
/// beside it that slumps at once, so points cross elements, the soil
/// fluidises at its surface and liquid leaves the soil.
fn scene() -> Scene {
    scene_with(&[])
}

fn scene_with(overrides: &[&str]) -> Scene {
    common::validation_scene("mpm_slump", overrides)
}

fn run(threads: usize, steps: usize, from: Option<&MpmState>) -> MpmState {
    let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
    pool.install(|| {
        let mut setup = build(&scene()).unwrap();
        if let Some(s) = from {
            setup.mpm.state = s.clone();
            setup.mpm.apply_gate_fixities();
        }
        for _ in 0..steps {
            setup.mpm.step();
        }
        setup.mpm.state
    })
}

#[test]
fn thread_count_does_not_change_the_result() {
    let one = run(1, 300, None);
    let two = run(2, 300, None);
    // The block has moved: the comparison is of a flow, not of a state at rest.
    let moved = one.solid.set.v.iter().map(|v| v[0].hypot(v[1])).fold(0.0, f64::max);
    assert!(moved > 1e-3, "fastest solid point {moved} m/s");
    assert!(one == two, "1 and 2 threads differ");
}

#[test]
fn restart_from_a_recorded_state_continues_bit_for_bit() {
    let straight = run(2, 300, None);
    let half = run(2, 150, None);
    // Through the recording's encoding, as a restart from run.mcap would.
    let record = MpmStateRecord { version: mpm_proc::run::STATE_VERSION, state: half };
    let decoded = MpmStateRecord::decode(&record.encode()).unwrap();
    let resumed = run(2, 150, Some(&decoded.state));
    assert!(resumed == straight, "restart differs from the straight run");
}

/// Every per-point array of `state` in reverse order, each point keeping
/// its id.
fn reversed(state: &MpmState) -> MpmState {
    let mut s = state.clone();
    for set in [&mut s.solid.set, &mut s.liquid.set] {
        set.id = (0..set.len() as u32).collect();
        set.x.reverse();
        set.v.reverse();
        set.mass.reverse();
        set.volume.reverse();
        set.affine.reverse();
        set.id.reverse();
    }
    s.solid.porosity.reverse();
    s.solid.stress.reverse();
    s.solid.fluidised.reverse();
    s.solid.load.reverse();
    s.liquid.pressure.reverse();
    s.liquid.viscous.reverse();
    s.liquid.free_surface.reverse();
    s
}

/// The solver reorders its points every 100 steps (docs/mpm.md, "Parallel
/// work and determinism"); which order they start in changes the sums'
/// order, so results agree at round-off and no more. A per-point array
/// the reordering left behind would pair a point with another's stress,
/// pressure or mass: errors of the flow's own size (mm, cm/s, kPa).
#[test]
fn the_points_order_changes_results_at_round_off_only() {
    let start = build(&scene()).unwrap().mpm.state;
    let straight = run(2, 300, Some(&start));
    let backwards = run(2, 300, Some(&reversed(&start)));
    let moved = straight.solid.set.v.iter().map(|v| v[0].hypot(v[1])).fold(0.0, f64::max);
    assert!(moved > 1e-3, "fastest solid point {moved} m/s");
    let largest = |a: &[f64], b: &[f64]| a.iter().zip(b).map(|(x, y)| (x - y).abs()).fold(0.0, f64::max);
    // [x, v, stress, porosity, pore pressure, volume, affine, viscous stress]
    let mut worst = [0.0f64; 8];
    for (a, b) in [(&straight.solid.set, &backwards.solid.set), (&straight.liquid.set, &backwards.liquid.set)] {
        let (ia, ib) = (a.by_id(), b.by_id());
        for id in 0..a.len() {
            let (p, q) = (ia[id], ib[id]);
            worst[0] = worst[0].max(largest(&a.x[p], &b.x[q]));
            worst[1] = worst[1].max(largest(&a.v[p], &b.v[q]));
            worst[5] = worst[5].max((a.volume[p] - b.volume[q]).abs() / a.volume[p]);
            worst[6] = worst[6].max(largest(a.affine[p].as_flattened(), b.affine[q].as_flattened()));
            assert_eq!(a.mass[p], b.mass[q], "point {id}'s mass");
        }
    }
    let (s, t) = (&straight.solid, &backwards.solid);
    let (ia, ib) = (s.set.by_id(), t.set.by_id());
    for id in 0..ia.len() {
        let (p, q) = (ia[id], ib[id]);
        worst[2] = worst[2].max(largest(&s.stress[p], &t.stress[q]));
        worst[3] = worst[3].max((s.porosity[p] - t.porosity[q]).abs());
        assert_eq!(s.fluidised[p], t.fluidised[q], "solid point {id} fluidised");
        assert_eq!(s.load[p], t.load[q], "solid point {id}'s load");
    }
    let (s, t) = (&straight.liquid, &backwards.liquid);
    let (ia, ib) = (s.set.by_id(), t.set.by_id());
    for id in 0..ia.len() {
        let (p, q) = (ia[id], ib[id]);
        worst[4] = worst[4].max((s.pressure[p] - t.pressure[q]).abs());
        worst[7] = worst[7].max(largest(&s.viscous[p], &t.viscous[q]));
        assert_eq!(s.free_surface[p], t.free_surface[q], "liquid point {id} on the free surface");
    }
    eprintln!("largest differences by id: {worst:?} (x m, v m/s, stress Pa, porosity, pore pressure Pa, relative volume, affine 1/s, viscous Pa)");
    // The two orders' sums do differ: the test compares different orders.
    assert!(worst.iter().any(|&w| w > 0.0), "the same bits from both orders");
    // Volumes to 1e-10 of their own (5e-13 measured); the affine velocity
    // gradients, ~10 1/s where the block slumps, to 1e-7 1/s (4e-10
    // measured); the viscous stresses, ~0.01 Pa, to 1e-9 Pa (5e-13).
    assert!(worst[5] < 1e-10 && worst[6] < 1e-7 && worst[7] < 1e-9, "{worst:?}");
    let stress_scale = straight.solid.stress.iter().flatten().fold(0.0f64, |m, s| m.max(s.abs()));
    eprintln!("largest effective stress {stress_scale:.3e} Pa");
    // Round-off grown over 300 steps of a flow (measured: 2e-15 m, 6e-13
    // m/s, 1e-9 of the largest stress), against points that moved
    // millimetres at up to `moved` m/s under stresses of ~1 kPa: bars of
    // 1e-9 of each scale, 1e-7 for the stresses.
    assert!(worst[0] < 1e-12 && worst[1] < 1e-9, "positions {} m, velocities {} m/s", worst[0], worst[1]);
    assert!(worst[2] < 1e-7 * stress_scale && worst[3] < 1e-9 && worst[4] < 1e-6, "{worst:?}");
}

/// The grid-held kinetic energy (`/mpm/metrics`): a rigid translation maps
/// to the grid whole (Σ_I |Σ_p N m u|²/2 Σ_p N m = ½ M u², the partition of
/// unity), and in a flow the grid holds at most the points' energy
/// (Jensen), strictly less once points move unlike their neighbours. That
/// bound is FLIP's: APIC's points also carry an affine part, ½ m tr(C D Cᵀ),
/// which the grid holds and ½ m v² leaves out.
#[test]
fn grid_holds_a_translation_whole_and_never_more_than_the_points() {
    let flip = || scene_with(&["mpm.transfer=\"flip\""]);
    let mut setup = build(&flip()).unwrap();
    let u = [0.3, -0.1];
    let mpm = &mut setup.mpm;
    for v in mpm.state.solid.set.v.iter_mut().chain(mpm.state.liquid.set.v.iter_mut()) {
        *v = u;
    }
    let expected = (mpm.state.solid.set.kinetic_energy(), mpm.state.liquid.set.kinetic_energy());
    mpm.step();
    let (solid, liquid) = mpm.grid_kinetic_energy();
    assert!((solid / expected.0 - 1.0).abs() < 1e-12, "solid {solid} vs {}", expected.0);
    assert!((liquid / expected.1 - 1.0).abs() < 1e-12, "liquid {liquid} vs {}", expected.1);

    let mut setup = build(&flip()).unwrap();
    for _ in 0..300 {
        setup.mpm.step();
    }
    let mpm = &mut setup.mpm;
    let points = (mpm.state.solid.set.kinetic_energy(), mpm.state.liquid.set.kinetic_energy());
    mpm.step();
    let (solid, liquid) = mpm.grid_kinetic_energy();
    assert!(solid > 0.0 && solid < points.0, "solid: grid {solid}, points {}", points.0);
    assert!(liquid > 0.0 && liquid < points.1, "liquid: grid {liquid}, points {}", points.1);
}
