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
