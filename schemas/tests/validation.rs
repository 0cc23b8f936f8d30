//! Malformed scenes: each must fail with an error that names the key.

use std::path::Path;

use schemas::scene::{Collision, Condition, Method};
use schemas::Scene;

const VALID: &str = r#"
[scene]
name = "t"
[domain]
min = [0.0, 0.0, 0.0]
max = [0.7, 0.05, 0.12]
gravity = [0.0, 0.0, -9.81]
walls = ["x_min", "x_max", "y_min", "y_max", "z_min"]
[[gates]]
name = "gate"
point = [0.04, 0.0, 0.0]
normal = [-2.0, 0.0, 0.0]
release_time = 0.0
[[particles]]
name = "beads"
density = 2600.0
diameter = 2.5e-3
[particles.packing]
method = "deposit"
region = { min = [0.0, 0.0, 0.0], max = [0.04, 0.05, 0.06] }
porosity = 0.42
seed = 1
[dem]
normal_stiffness = 2000.0
restitution = 0.88
friction = 0.577
rolling_friction = 0.05
[output]
end_time = 0.6
record_interval = 0.01
[analysis]
column_length = 0.04
column_height = 0.06
condition = "dry"
"#;

fn load(text: &str, set: &[&str]) -> Result<Scene, schemas::SceneError> {
    let set: Vec<String> = set.iter().map(|s| s.to_string()).collect();
    Scene::from_toml_str(text, Path::new("."), &set)
}

#[test]
fn valid_scene_loads_with_defaults() {
    let s = load(VALID, &[]).unwrap();
    assert_eq!(s.method(), Method::DemDry);
    let dem = s.dem();
    assert!((dem.tangential_stiffness_ratio - 2.0 / 7.0).abs() < 1e-15);
    assert_eq!(s.gate_normals[0], [-1.0, 0.0, 0.0]);
    // t_ref = √(H0/g) for the dry column (analytic-checks.md: 0.0782 s).
    assert!((s.reference_time() - 0.0782).abs() < 5e-5);
}

const WATER: &str = "[[fluids]]\nname = \"water\"\ndensity = 1000.0\nviscosity = 1e-3\nregion = { min = [0.0, 0.0, 0.0], max = [0.04, 0.05, 0.06] }\n[lbm]\nspacing = 6e-4\ntime_step = 8e-5\n";

#[test]
fn saturated_reference_time_uses_reduced_gravity() {
    let text = format!("{VALID}\n{WATER}");
    let s = load(&text, &["analysis.condition=\"saturated\""]).unwrap();
    assert_eq!(s.spec.analysis.condition, Condition::Saturated);
    assert_eq!(s.method(), Method::DemLbm);
    // g' = g (2600 - 1000)/2600 = 6.037 m/s²; t_ref = 0.0997 s for H0 = 0.06 m.
    assert!((s.reference_time() - 0.0997).abs() < 5e-5, "{}", s.reference_time());
}

#[test]
fn overrides_are_applied_and_validated() {
    let s = load(VALID, &["output.end_time=0.2", "particles[0].packing.seed=9", "dem.time_step=1e-6"]).unwrap();
    assert_eq!(s.spec.output.end_time, 0.2);
    assert_eq!(s.dem().time_step, Some(1e-6));
    let e = load(VALID, &["output.end_time=-1"]).unwrap_err();
    assert!(e.names_key("output.end_time"), "{e}");
    let e = load(VALID, &["particles[3].density=1"]).unwrap_err();
    assert!(e.to_string().contains("out of range"), "{e}");
    let e = load(VALID, &["no_equals_sign"]).unwrap_err();
    assert!(e.to_string().contains("KEY.PATH=VALUE"), "{e}");
}

/// (override, key the error must name, words the reason must contain)
const BAD_VALUES: &[(&str, &str, &str)] = &[
    ("dem.friction=-0.2", "dem.friction", "must be >= 0, got -0.2"),
    ("dem.restitution=1.5", "dem.restitution", "(0, 1]"),
    ("dem.restitution=0", "dem.restitution", "(0, 1]"),
    ("dem.normal_stiffness=0", "dem.normal_stiffness", "> 0"),
    ("dem.rolling_friction=-1", "dem.rolling_friction", ">= 0"),
    ("dem.steps_per_contact=2", "dem.steps_per_contact", "[5,"),
    ("dem.time_step=-1e-6", "dem.time_step", "> 0"),
    ("particles[0].density=-2600", "particles[0].density", "> 0"),
    ("particles[0].diameter=0", "particles[0].diameter", "> 0"),
    ("particles[0].packing.porosity=1.2", "particles[0].packing.porosity", "(0.25, 1)"),
    ("particles[0].packing.region.max=[0.04, 0.05, 0.5]", "particles[0].packing.region", "not inside the domain"),
    ("domain.max=[0.7, 0.05, -1.0]", "domain.max[2]", "must be >"),
    (
        "particles[0].packing.region.max=[0.001, 0.05, 0.06]",
        "particles[0].packing.region",
        "narrower than the largest grain",
    ),
    ("particles[0].diameter=2.5", "particles[0].packing.region", "diameters are in metres"),
    ("gates[0].normal=[0.0, 0.0, 0.0]", "gates[0].normal", "non-zero"),
    ("gates[0].release_time=-1", "gates[0].release_time", ">= 0"),
    ("output.record_interval=0", "output.record_interval", "> 0"),
    ("analysis.front_mass_fraction=0.9", "analysis.front_mass_fraction", "(0, 0.5)"),
    ("analysis.condition=\"saturated\"", "analysis.condition", "fluids"),
    ("scene.name=\"has space\"", "scene.name", "letters"),
    ("deposition.max_time=0", "deposition.max_time", "> 0"),
];

#[test]
fn lbm_table_defaults_and_errors() {
    let text = format!("{VALID}\n{WATER}");
    let s = load(&text, &[]).unwrap();
    let lbm = s.lbm();
    assert_eq!((lbm.smagorinsky, lbm.collision, lbm.trt_magic), (0.16, Collision::Bgk, 3.0 / 16.0));
    let without = VALID.to_string() + "\n" + &WATER[..WATER.find("[lbm]").unwrap()];
    let e = load(&without, &[]).unwrap_err();
    assert!(e.names_key("lbm") && e.to_string().contains("spacing"), "{e}");
    for (set, key, reason) in [
        ("lbm.spacing=0", "lbm.spacing", "> 0"),
        ("lbm.spacing=0.03", "lbm.spacing", "cells along y"),
        ("lbm.spacing=1e-6", "lbm.spacing", "lattice cells"),
        ("lbm.time_step=-1", "lbm.time_step", "> 0"),
        ("lbm.smagorinsky=-0.1", "lbm.smagorinsky", ">= 0"),
        ("lbm.mach_limit=1.5", "lbm.mach_limit", "(0, 1)"),
        ("lbm.collision=\"cumulant\"", "lbm.collision", "unknown variant"),
    ] {
        let e = load(&text, &[set]).expect_err(set);
        assert!(e.names_key(key), "{set}: error does not name {key}: {e}");
        assert!(e.to_string().contains(reason), "{set}: reason should mention {reason:?}: {e}");
    }
}

#[test]
fn bad_values_name_their_key() {
    for (set, key, reason) in BAD_VALUES {
        let e = load(VALID, &[set]).expect_err(set);
        assert!(e.names_key(key), "{set}: error does not name {key}: {e}");
        assert!(e.to_string().contains(reason), "{set}: reason should mention {reason:?}: {e}");
    }
}

#[test]
fn structural_errors_name_their_key() {
    // Unknown key (a typo) is rejected, not ignored.
    let e = load(&VALID.replace("friction = 0.577", "frction = 0.577"), &[]).unwrap_err();
    assert!(e.names_key("dem.frction") && e.to_string().contains("unknown field"), "{e}");
    // Wrong type.
    let e = load(&VALID.replace("density = 2600.0", "density = \"heavy\""), &[]).unwrap_err();
    assert!(e.names_key("particles[0].density"), "{e}");
    // Missing required key.
    let e = load(&VALID.replace("restitution = 0.88", ""), &[]).unwrap_err();
    assert!(e.names_key("dem") && e.to_string().contains("restitution"), "{e}");
    // Both porosity and count.
    let e = load(VALID, &["particles[0].packing.count=100"]).unwrap_err();
    assert!(e.names_key("particles[0].packing"), "{e}");
    // Unknown wall face.
    let e = load(&VALID.replace("\"z_min\"]", "\"bottom\"]"), &[]).unwrap_err();
    assert!(e.to_string().contains("domain.walls"), "{e}");
    // Not TOML at all.
    let e = load("this is = = not toml", &[]).unwrap_err();
    assert!(e.to_string().contains("not valid TOML"), "{e}");
    // Particles without a [dem] table.
    let no_dem =
        VALID.split("[dem]").next().unwrap().to_string() + "[output]" + VALID.split("[output]").nth(1).unwrap();
    let e = load(&no_dem, &[]).unwrap_err();
    assert!(e.names_key("dem"), "{e}");
}

#[test]
fn every_problem_is_reported_at_once() {
    let e = load(VALID, &["dem.friction=-1", "output.end_time=0"]).unwrap_err();
    assert!(e.names_key("dem.friction") && e.names_key("output.end_time"), "{e}");
}

#[test]
fn resolved_scene_round_trips() {
    let s = load(VALID, &["output.end_time=0.3"]).unwrap();
    let again = load(&s.to_toml(), &[]).unwrap();
    assert_eq!(again.spec.output.end_time, 0.3);
    assert_eq!(again.to_toml(), s.to_toml());
}
