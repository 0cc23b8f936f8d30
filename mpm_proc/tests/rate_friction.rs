//! Rate-dependent friction (`mpm.limit_friction_angle`, the μ(I) rheology)
//! in the solver: its two limits are the rate-independent soils it spans.
//! The constitutive update itself (τ/p′ = sin φ(I) in steady simple shear)
//! is tested in `mohr_coulomb.rs`.

mod common;

use mpm_proc::setup::build;

/// Front (the farthest solid point's x, m) of `scenes/validation/mpm_slump.toml`
/// without its water, a dry block 2 × 3 cm slumping at once, after 0.05 s.
fn front(overrides: &[&str]) -> f64 {
    let mut sets = vec!["fluids=[]", "analysis.condition=\"dry\""];
    sets.extend_from_slice(overrides);
    let mut mpm = build(&common::validation_scene("mpm_slump", &sets)).unwrap().mpm;
    while mpm.state.time < 0.05 {
        mpm.step();
    }
    mpm.state.solid.set.x.iter().map(|x| x[0]).fold(f64::NEG_INFINITY, f64::max)
}

/// With I_0 far below any inertial number of the flow every yielding point
/// takes φ_2, with I_0 far above it φ_s: the slump's front then matches the
/// rate-independent soil's at that angle, and with a real I_0 it lies
/// between the two. A law that swapped the limits, or a solver that never
/// called it, fails one of the three.
#[test]
fn the_rate_dependent_soil_spans_its_two_rate_independent_limits() {
    let static_soil = front(&["mpm.friction_angle=25"]);
    let limit_soil = front(&["mpm.friction_angle=45"]);
    let rate = |i0: &str| {
        front(&["mpm.friction_angle=25", "mpm.limit_friction_angle=45", &format!("mpm.reference_inertial_number={i0}")])
    };
    let (slow, fast, lab) = (rate("1e9"), rate("1e-9"), rate("0.279"));
    println!("front at 0.05 s: phi 25 {static_soil:.5}, phi 45 {limit_soil:.5}; mu(I): I0 1e9 {slow:.5}, 1e-9 {fast:.5}, 0.279 {lab:.5} m");
    assert!(static_soil - limit_soil > 2e-3, "the two angles must slump apart to test anything");
    let spread = static_soil - limit_soil;
    assert!((slow - static_soil).abs() < 0.02 * spread, "I_0 = 1e9 is the static soil: {slow} against {static_soil}");
    assert!((fast - limit_soil).abs() < 0.02 * spread, "I_0 = 1e-9 is the limit soil: {fast} against {limit_soil}");
    assert!(lab < static_soil - 0.02 * spread && lab > limit_soil + 0.02 * spread, "I_0 = 0.279 lies between: {lab}");
}
