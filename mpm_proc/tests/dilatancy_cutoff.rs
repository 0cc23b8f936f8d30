//! The dilatancy cut-off (`mpm.dilatancy_cutoff_porosity`, PLAXIS's e_max):
//! a dilatant soil (ψ > 0) gains volume only until its points reach the
//! cut-off porosity, then shears at constant volume (ψ = 0), as the DEM's
//! grains do in their element test (docs/dem.md, "Element test").

mod common;

use mpm_proc::setup::build;
use mpm_proc::solver::Mpm;

/// `scenes/validation/mpm_slump.toml` without its water: a dry soil block
/// 2 × 3 cm (n0 = 0.4, φ = 35°) slumping at once in a 6 × 4 cm box, with
/// the given overrides.
fn slump(overrides: &[&str]) -> Mpm {
    let mut sets = vec!["fluids=[]", "analysis.condition=\"dry\""];
    sets.extend_from_slice(overrides);
    build(&common::validation_scene("mpm_slump", &sets)).unwrap().mpm
}

/// The solid's volume after `t` s over its volume at the start.
fn volume_ratio(overrides: &[&str], t: f64) -> f64 {
    let mut mpm = slump(overrides);
    let start: f64 = mpm.state.solid.set.volume.iter().sum();
    while mpm.state.time < t {
        mpm.step();
    }
    mpm.state.solid.set.volume.iter().sum::<f64>() / start
}

/// Without dilatancy the slumping block still gains volume where its
/// surface points return to the apex (zero stress: grains parting); ψ > 0
/// adds the dilation of shear, without bound unless cut off. With the
/// cut-off at n_cs every point's dilation stops at n_cs, so the volume
/// dilatancy adds is at most (1 − n0)/(1 − n_cs) − 1 = 3.45 % for
/// n0 = 0.40, n_cs = 0.42.
#[test]
fn a_dilating_soil_gains_no_more_volume_than_its_cutoff_allows() {
    let t = 0.05;
    let plain = volume_ratio(&[], t);
    let free = volume_ratio(&["mpm.dilatancy_angle=20"], t);
    let capped = volume_ratio(&["mpm.dilatancy_angle=20", "mpm.dilatancy_cutoff_porosity=0.42"], t);
    println!("volume ratio at {t} s: psi = 0 {plain:.4}, psi = 20 {free:.4}, psi = 20 cut off at 0.42 {capped:.4}");
    let bound = 0.6 / 0.58 - 1.0;
    assert!(free - plain > 2.0 * bound, "ψ = 20° without the cut-off dilates past the bound: {free} against {plain}");
    assert!(capped - plain < bound, "the cut-off bounds the dilation: {capped} against {plain} (bound {bound:.4})");
    assert!(capped - plain > 0.2 * bound, "below the cut-off the soil dilates: {capped} against {plain}");
}
