//! Hard cases of the DEM–LBM coupling with an answer to check, beyond the
//! outcome the hard-case campaign asserts (`scenes/hard/campaign.toml`):
//! a grain that leaves the lattice, and a grain barely heavier than water.

use integration_tests::{coupler_run, dem_states, repo_root};
use schemas::Scene;

const G: f64 = 9.81;

/// `scenes/hard/grain_leaving_lattice.toml`: a grain thrown up at 1 m/s from
/// the gas above a tank flies out of the box's open top (apex 0.096 m above
/// the floor of a 0.06 m box), comes back and settles in the water. While it
/// is out of the liquid, in the gas cells or beyond the lattice, nothing but
/// gravity may act on it: its height must be z0 + v0 t − g t²/2 to 1 µm
/// (the DEM's integrator is exact for a constant force; a spurious force of
/// a thousandth of its weight would be 1e-4 g t²/2 ≈ 20 µm by the apex).
/// It must then come back through the liquid to rest on the floor, not be
/// lost.
#[test]
fn a_grain_thrown_out_of_the_lattice_flies_ballistically_and_falls_back() {
    let scene_path = "scenes/hard/grain_leaving_lattice.toml";
    let scene = Scene::load(&repo_root().join(scene_path), &[]).expect("scene loads");
    let out = coupler_run("grain_leaving_lattice", scene_path, &[]);
    let states = dem_states(&out.join("run.mcap"));
    assert!(states.len() > 40, "{} states recorded", states.len());

    let first = &states[0];
    let (z0, w0) = (first.grains.pos[0][2], first.grains.vel[0][2]);
    let radius = 0.5 * scene.spec.particles[0].diameter;
    let liquid_top = scene.spec.fluids[0].region.max[2];
    let box_top = scene.spec.domain.max[2];
    // Out of the liquid with a margin of two lattice cells for the cover's ramp.
    let clear = liquid_top + radius + 2.0 * scene.lbm().spacing;
    let mut flight = 0;
    let mut apex = f64::MIN;
    for s in &states {
        let t = s.time - first.time;
        let ballistic = z0 + w0 * t - 0.5 * G * t * t;
        if ballistic < clear {
            if t > w0 / G {
                break;
            }
            continue;
        }
        let z = s.grains.pos[0][2];
        apex = apex.max(z);
        flight += 1;
        assert!(
            (z - ballistic).abs() < 1e-6,
            "t = {t:.3} s: z = {z:.7} m against the ballistic {ballistic:.7} m ({:+.2e} m): a force other than gravity out of the liquid",
            z - ballistic
        );
        let drift = (s.grains.pos[0][0] - first.grains.pos[0][0]).hypot(s.grains.pos[0][1] - first.grains.pos[0][1]);
        assert!(drift < 1e-9, "t = {t:.3} s: the grain moved {drift:e} m sideways in flight");
    }
    let expected_apex = z0 + w0 * w0 / (2.0 * G);
    eprintln!("{flight} states in flight; apex {apex:.5} m (ballistic {expected_apex:.5} m, box top {box_top} m)");
    assert!(flight > 20, "only {flight} states in flight");
    assert!(apex > box_top + radius, "apex {apex} m: the grain never left the lattice");
    // The states are 5 ms apart: the highest lies within g (2.5 ms)²/2 of the apex.
    assert!((apex - expected_apex).abs() < 0.5 * G * 0.0025_f64.powi(2), "apex {apex} against {expected_apex}");

    let last = states.last().expect("states");
    let (z_end, w_end) = (last.grains.pos[0][2], last.grains.vel[0][2]);
    eprintln!("at t = {:.3} s: z = {z_end:.5} m, w = {w_end:.5} m/s", last.time);
    // On the floor: its weight in water presses it in by a few µm (stiffness 2000 N/m).
    assert!((z_end - radius).abs() < 0.02 * radius, "the grain ended at z = {z_end} m, not on the floor");
    assert!(w_end.abs() < 0.01, "the grain still moves at {w_end} m/s");
}

/// `scenes/hard/neutral_grain.toml`: a 1001 kg/m³ grain released in water.
/// From rest the drag and the history force are nil, so in an
/// incompressible liquid it starts sinking with dw/dt = Δρ g / (ρ_p + C_A
/// ρ_L), C_A = ½ the added-mass coefficient of a sphere: w(t) ≤ a₀ t, the
/// drag and the (under-resolved) Basset force only slowing it. The
/// lattice's liquid is compressible (sound at Δx/(√3 Δt) = 1.15 m/s), so
/// the liquid the grain carries is set moving by pressure waves, over the
/// time they take to cross the grain and come back from the box: in the
/// first 10 ms the grain sinks faster than a₀ t, yet slower than with no
/// added mass (w = Δρ g t / ρ_p = 1.5 a₀ t). From 20 ms on it must sink at
/// between half and all of a₀ t. A grain that rose (the buoyancy wrong by
/// more than 0.1 %), lost its added mass or amplified it (the explicit
/// coupling's instability of light grains) fails. Measured: 1.15, 0.98 and
/// 0.90 a₀ t at 10, 20 and 30 ms.
#[test]
fn a_grain_barely_heavier_than_water_sinks_with_its_added_mass() {
    let scene_path = "scenes/hard/neutral_grain.toml";
    let scene = Scene::load(&repo_root().join(scene_path), &[]).expect("scene loads");
    let out = coupler_run("neutral_grain", scene_path, &["--set", "output.end_time=0.03"]);
    let states = dem_states(&out.join("run.mcap"));
    let (rho_p, rho_l) = (scene.spec.particles[0].density, scene.spec.fluids[0].density);
    let a0 = (rho_p - rho_l) * G / (rho_p + 0.5 * rho_l);
    let mut checked = 0;
    for s in states.iter().filter(|s| s.time > 0.0) {
        let w = s.grains.vel[0][2];
        let ratio = -w / (a0 * s.time);
        eprintln!("t = {:.3} s: w = {w:.4e} m/s = {ratio:.3} a0 t", s.time);
        let bounds = if s.time < 0.015 { 0.5..=1.5 } else { 0.5..=1.0 };
        assert!(bounds.contains(&ratio), "t = {:.3} s: w = {w:e} m/s is {ratio:.3} of a0 t, not in {bounds:?}", s.time);
        checked += 1;
    }
    assert!(checked >= 3, "only {checked} states after the start");
    // On the lattice form the water at depth is compressed by far more than
    // 0.1 %: the plan must say the grain would rise.
    let lattice = Scene::load(&repo_root().join(scene_path), &["lbm.hydrostatics=lattice".to_string()])
        .expect("lattice form loads");
    let plan = lbm_proc::plan::plan(&lattice);
    assert!(
        plan.warnings.iter().any(|w| w.contains("denser than the liquid") && w.contains("\"buoyancy\"")),
        "no warning that the grain would float: {:?}",
        plan.warnings
    );
}
