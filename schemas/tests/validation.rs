//! Malformed scenes: each must fail with an error that names the key.

use std::path::Path;

use schemas::scene::{Collision, Condition, Method};
use schemas::Scene;

/// scenes/validation/minimal_dry_column.toml, as text to mutate.
const VALID: &str = include_str!("../../scenes/validation/minimal_dry_column.toml");
/// scenes/validation/minimal_saturated_column.toml (its lattice table last).
const SATURATED: &str = include_str!("../../scenes/validation/minimal_saturated_column.toml");

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

#[test]
fn saturated_reference_time_uses_reduced_gravity() {
    let text = SATURATED;
    let s = load(text, &[]).unwrap();
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
    let text = SATURATED;
    let s = load(text, &[]).unwrap();
    let lbm = s.lbm();
    assert_eq!((lbm.smagorinsky, lbm.collision, lbm.trt_magic), (0.16, Collision::Bgk, 3.0 / 16.0));
    // The open top is clear of the liquid; filled to the top, it is refused.
    let e = load(text, &["fluids[0].region.max[2]=0.12"]).expect_err("liquid against the open top");
    assert!(e.names_key("domain.walls") && e.to_string().contains("z_max is open"), "{e}");
    let without = &SATURATED[..SATURATED.find("[lbm]").unwrap()];
    let e = load(without, &[]).unwrap_err();
    assert!(e.names_key("lbm") && e.to_string().contains("spacing"), "{e}");
    for (set, key, reason) in [
        ("lbm.spacing=0", "lbm.spacing", "> 0"),
        ("lbm.spacing=0.03", "lbm.spacing", "cells along y"),
        ("lbm.spacing=1e-6", "lbm.spacing", "lattice cells"),
        ("lbm.time_step=-1", "lbm.time_step", "> 0"),
        ("lbm.smagorinsky=-0.1", "lbm.smagorinsky", ">= 0"),
        ("lbm.mach_limit=1.5", "lbm.mach_limit", "(0, 1)"),
        ("lbm.collision=\"cumulant\"", "lbm.collision", "unknown variant"),
        // The lattice is closed on every face: liquid against a face open to the grains.
        (
            "domain.walls=[\"x_max\", \"y_min\", \"y_max\", \"z_min\"]",
            "domain.walls",
            "x_min is open but liquid lies against it",
        ),
    ] {
        let e = load(text, &[set]).expect_err(set);
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

// ---------------------------------------------------------------------------
// MPM scenes
// ---------------------------------------------------------------------------

/// The saturated lab column for the MPM: no [dem] or [lbm], defaults for
/// [mpm] (`scenes/validation/mpm_lab_column_defaults.toml`).
static MPM: std::sync::LazyLock<String> = std::sync::LazyLock::new(|| {
    let path =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenes/validation/mpm_lab_column_defaults.toml");
    std::fs::read_to_string(path).unwrap()
});

#[test]
fn valid_mpm_scene_loads_without_dem_or_lbm() {
    let s = load(&MPM, &[]).unwrap();
    assert_eq!(s.method(), Method::Mpm);
    assert!(s.spec.dem.is_none() && s.spec.lbm.is_none() && s.spec.mpm.is_none());
    let m = s.mpm();
    assert_eq!((m.element_size, m.points_per_element, m.point_grid()), (0.004, 12, (4, 3)));
    assert_eq!((m.transfer, m.flip_share_in_effect()), (schemas::scene::MpmTransfer::Aflip, 0.9));
    // FLIP blended into APIC is an AFLIP setting; under APIC and FLIP a
    // scene's flip_share is unused, and said so (under FLIP the share is
    // pic_fraction).
    for transfer in ["apic", "flip"] {
        let m = load(&MPM, &[&format!("mpm.transfer=\"{transfer}\""), "mpm.flip_share=0.5"]).unwrap().mpm();
        assert_eq!(m.flip_share_in_effect(), 0.0);
        let note = schemas::scene::unused_flip_keys(&m).expect("a note");
        assert!(note.contains("mpm.flip_share = 0.5 is unused") && note.contains("aflip"), "{note}");
    }
    assert!(schemas::scene::unused_flip_keys(&load(&MPM, &["mpm.flip_share=0.5"]).unwrap().mpm()).is_none());
    let apic = load(&MPM, &["mpm.transfer=\"apic\""]).unwrap().mpm();
    assert_eq!(apic.flip_share_in_effect(), 0.0);
    assert_eq!(load(&MPM, &["mpm.flip_share=0.95"]).unwrap().mpm().flip_share_in_effect(), 0.95);
    assert!(load(&MPM, &["mpm.flip_share=1.0"]).unwrap_err().names_key("mpm.flip_share"));
    // The pore water stays on APIC unless asked.
    assert_eq!(m.liquid_flip_share_in_effect(), 0.0);
    let both = load(&MPM, &["mpm.liquid_flip_share=0.9"]).unwrap().mpm();
    assert_eq!((both.flip_share_in_effect(), both.liquid_flip_share_in_effect()), (0.9, 0.9));
    assert!(load(&MPM, &["mpm.liquid_flip_share=1.0"]).unwrap_err().names_key("mpm.liquid_flip_share"));
    // AFLIP's share is what is kept over a step at courant 0.5 (the
    // default): the same at that courant, bit for bit; a quarter of the
    // step keeps β^(1/4) a step, so that four steps keep β as one did
    // (a dissipation per second); under "step" β every step.
    assert_eq!(m.flip_shares_per_step(), [0.9, 0.0]);
    let quarter = load(&MPM, &["mpm.courant=0.125", "mpm.liquid_flip_share=0.8"]).unwrap().mpm();
    let [solid, liquid] = quarter.flip_shares_per_step();
    assert!((solid.powi(4) - 0.9).abs() < 1e-15 && (liquid.powi(4) - 0.8).abs() < 1e-15, "{solid}, {liquid}");
    let per_step = load(&MPM, &["mpm.courant=0.125", "mpm.flip_share_basis=\"step\""]).unwrap().mpm();
    assert_eq!(per_step.flip_shares_per_step(), [0.9, 0.0]);
    let apic_step = load(&MPM, &["mpm.transfer=\"apic\"", "mpm.flip_share_basis=\"step\""]).unwrap().mpm();
    let note = schemas::scene::unused_flip_keys(&apic_step).expect("a note");
    assert!(note.contains("mpm.flip_share_basis = \"step\" is unused"), "{note}");
    assert!(load(&MPM, &["mpm.flip_share_basis=\"second\""]).unwrap_err().names_key("mpm.flip_share_basis"));
    // The resolved scene keeps the method and reloads.
    let again = load(&s.to_toml(), &[]).unwrap();
    assert_eq!(again.method(), Method::Mpm);
    // One phase each: dry soil, water alone.
    assert!(load(&MPM, &["fluids=[]", "analysis.condition=\"dry\""]).is_ok());
    assert!(load(&MPM, &["particles=[]", "analysis.condition=\"liquid\""]).is_ok());
}

#[test]
fn mpm_ignores_the_dem_and_lbm_requirements() {
    // [dem] and [lbm] present but invalid: ignored under mpm.
    let text = format!("{}\n[dem]\nnormal_stiffness = -1.0\nrestitution = 0.88\nfriction = 0.5\nrolling_friction = 0.05\ntime_step = 1.0\n[lbm]\nspacing = 0.0\ntime_step = 8e-5\n", *MPM);
    assert!(load(&text, &[]).is_ok());
    // Gravity deposition's non-zero gravity is not needed.
    assert!(load(&MPM, &["domain.gravity=[0.0, 0.0, 0.0]"]).is_ok());
    // The same file as DEM-LBM does check them.
    let e = load(&text, &["scene.method=\"dem_lbm\""]).unwrap_err();
    assert!(e.names_key("dem.normal_stiffness") && e.names_key("lbm.spacing"), "{e}");
}

#[test]
fn point_grids() {
    use schemas::scene::{point_count_fits, point_grid_of};
    let fits: Vec<u32> = (0..=20).filter(|&n| point_count_fits(n)).collect();
    assert_eq!(fits, [1, 2, 3, 4, 6, 8, 9, 10, 12, 15, 16, 18, 20]);
    assert_eq!(point_grid_of(12), (4, 3));
    assert_eq!(point_grid_of(8), (4, 2));
    assert_eq!(point_grid_of(16), (4, 4));
    assert_eq!(point_grid_of(7), (7, 1));
}

/// (override, key the error must name, words the reason must contain)
const BAD_MPM: &[(&str, &str, &str)] = &[
    ("mpm.element_size=0", "mpm.element_size", "> 0"),
    ("mpm.points_per_element=5", "mpm.points_per_element", "counts that work: 1, 2, 3, 4, 6, 8, 9"),
    ("mpm.points_per_element=7", "mpm.points_per_element", "7 points cannot"),
    ("mpm.points_per_element=11", "mpm.points_per_element", "11 x 1"),
    ("mpm.points_per_element=0", "mpm.points_per_element", "0 points"),
    ("mpm.courant=0", "mpm.courant", "(0, 1]"),
    ("mpm.courant=1.5", "mpm.courant", "(0, 1]"),
    ("mpm.young_modulus=0", "mpm.young_modulus", "> 0"),
    ("mpm.poisson_ratio=0.5", "mpm.poisson_ratio", "(0, 0.5)"),
    ("mpm.poisson_ratio=0", "mpm.poisson_ratio", "(0, 0.5)"),
    ("mpm.friction_angle=90", "mpm.friction_angle", "(0, 90)"),
    ("mpm.friction_angle=0", "mpm.friction_angle", "(0, 90)"),
    ("mpm.cohesion=-1", "mpm.cohesion", ">= 0"),
    ("mpm.dilatancy_angle=40", "mpm.dilatancy_angle", "[0, mpm.friction_angle] = [0, 35]"),
    ("mpm.dilatancy_angle=-1", "mpm.dilatancy_angle", "[0, mpm.friction_angle]"),
    ("mpm.dilatancy_cutoff_porosity=0.43", "mpm.dilatancy_cutoff_porosity", "mpm.dilatancy_angle = 0 never starts"),
    ("mpm.dilatancy_cutoff_porosity=1", "mpm.dilatancy_cutoff_porosity", "(0, 1)"),
    ("mpm.limit_friction_angle=30", "mpm.limit_friction_angle", "[mpm.friction_angle, 90) = [35, 90)"),
    ("mpm.limit_friction_angle=90", "mpm.limit_friction_angle", "[mpm.friction_angle, 90)"),
    ("mpm.reference_inertial_number=0.3", "mpm.reference_inertial_number", "rate-dependent friction that is off"),
    ("mpm.liquid_bulk_modulus=0", "mpm.liquid_bulk_modulus", "> 0"),
    ("mpm.cavitation_threshold=-1", "mpm.cavitation_threshold", ">= 0"),
    ("mpm.max_porosity=1", "mpm.max_porosity", "(0, 1)"),
    ("mpm.damping=1", "mpm.damping", "[0, 1)"),
    ("mpm.damping=-0.1", "mpm.damping", "[0, 1)"),
    ("mpm.ergun_a=0", "mpm.ergun_a", "> 0"),
    ("mpm.ergun_b=-1", "mpm.ergun_b", "> 0"),
    ("mpm.free_surface_fill=0", "mpm.free_surface_fill", "(0, 1]"),
    ("mpm.gravity_phase_max_time=-1", "mpm.gravity_phase_max_time", ">= 0"),
    ("mpm.gravity_phase_damping=1", "mpm.gravity_phase_damping", "[0, 1)"),
    ("mpm.gravity_phase_rest_speed=0", "mpm.gravity_phase_rest_speed", "> 0"),
    ("mpm.top_load=-5", "mpm.top_load", ">= 0"),
    ("mpm.wall_release_speed=-1e-4", "mpm.wall_release_speed", ">= 0"),
    ("mpm.wall_release_speed=nan", "mpm.wall_release_speed", ">= 0"),
    ("mpm.wall_release_speed=inf", "mpm.wall_release_speed", ">= 0"),
    ("mpm.shape_functions=\"cpdi\"", "mpm.shape_functions", "unknown variant"),
    ("mpm.transfer=\"pic\"", "mpm.transfer", "unknown variant"),
    ("mpm.shape_functions=\"linear\"", "mpm.transfer", "unstable when points cross grid lines"),
    ("mpm.flip_share=1", "mpm.flip_share", "[0, 1)"),
    ("mpm.flip_share=-0.5", "mpm.flip_share", "[0, 1)"),
    ("mpm.initial_stress=\"k1\"", "mpm.initial_stress", "unknown variant"),
    ("mpm.elemnt_size=0.004", "mpm.elemnt_size", "unknown field"),
    // The scene as the MPM sees it.
    ("gates[0].normal=[0.0, 0.0, 1.0]", "gates[0].normal", "+x or -x"),
    ("gates[0].normal=[1.0, 0.0, 0.1]", "gates[0].normal", "vertical line of grid nodes"),
    ("domain.gravity=[0.0, -9.81, 0.0]", "domain.gravity", "gravity[1] must be 0"),
    (
        "domain.max=[0.703, 0.05, 0.12]",
        "domain.max[0]",
        "set domain.max[0] = 0.7 or 0.704 m, or mpm.element_size = 0.004017143 m (175 elements) or 0.003994318 m (176 elements)",
    ),
    ("domain.max=[0.7, 0.05, 0.121]", "domain.max[2]", "z extent 0.121 m"),
    ("mpm.element_size=0.1", "mpm.element_size", "elements along z"),
    ("mpm.element_size=1e-4", "mpm.element_size", "at most 4e6"),
    // Block edges lie on grid lines along x, and along z on a row of the
    // points' lattice: 4 × 3 points per 4 mm element, rows every 4/3 mm.
    (
        "particles[0].packing.region.max=[0.04, 0.05, 0.061]",
        "particles[0].packing.region.max[2]",
        "the nearest are 0.06 and 0.061333333 m",
    ),
    ("particles[0].packing.region.min=[0.002, 0.0, 0.0]", "particles[0].packing.region.min[0]", "grid line"),
    ("fluids[0].region.max=[0.042, 0.05, 0.06]", "fluids[0].region.max[0]", "the liquid edge x = 0.042 m"),
    ("gates[0].point=[0.041, 0.0, 0.0]", "gates[0].point[0]", "the gate x = 0.041 m"),
];

#[test]
fn bad_mpm_values_name_their_key() {
    for (set, key, reason) in BAD_MPM {
        let e = load(&MPM, &[set]).expect_err(set);
        assert!(e.names_key(key), "{set}: error does not name {key}: {e}");
        assert!(e.to_string().contains(reason), "{set}: reason should mention {reason:?}: {e}");
    }
    // The rate-dependent friction's pairs: a cohesionless soil, a positive I_0.
    let e = load(&MPM, &["mpm.cohesion=100", "mpm.limit_friction_angle=40"]).unwrap_err();
    assert!(e.names_key("mpm.limit_friction_angle") && e.to_string().contains("cohesionless soil"), "{e}");
    let e = load(&MPM, &["mpm.limit_friction_angle=40", "mpm.reference_inertial_number=0"]).unwrap_err();
    assert!(e.names_key("mpm.reference_inertial_number") && e.to_string().contains("> 0"), "{e}");
    let mu_i = load(&MPM, &["mpm.limit_friction_angle=40"]).unwrap().mpm().reference_inertial_number_in_effect();
    assert_eq!(mu_i, 0.279);
    // The [mpm] values are checked whenever the table is present, whatever the method.
    let e = load(VALID, &["mpm.courant=2"]).unwrap_err();
    assert!(e.names_key("mpm.courant"), "{e}");
    // ... but the grid only under mpm.
    assert!(load(VALID, &["mpm.element_size=0.0033"]).is_ok());
    // A grid that fits the domain but not the gate and the column length.
    let e = load(&MPM, &["domain.max=[0.72, 0.05, 0.12]", "mpm.element_size=0.012"]).unwrap_err();
    assert!(e.names_key("gates[0].point[0]") && e.to_string().contains("the nearest are 0.036 and 0.048 m"), "{e}");
    assert!(e.names_key("particles[0].packing.region.max[0]") && e.names_key("fluids[0].region.max[0]"), "{e}");
    assert!(!e.names_key("particles[0].packing.region.max[2]"), "0.06 m is 5 elements: {e}");
    // A block may end inside an element, on the points' lattice: 58 2/3 mm
    // is 14 elements and two of the three point rows of the next.
    let top = 0.06 - 0.004 / 3.0;
    let inside = [
        format!("particles[0].packing.region.max=[0.04, 0.05, {top}]"),
        format!("fluids[0].region.max=[0.04, 0.05, {top}]"),
    ];
    assert!(load(&MPM, &[inside[0].as_str(), inside[1].as_str()]).is_ok());
    // One point per element: one row, the lattice is the grid itself.
    let e =
        load(&MPM, &["mpm.points_per_element=1", "particles[0].packing.region.max=[0.04, 0.05, 0.061]"]).unwrap_err();
    assert!(
        e.names_key("particles[0].packing.region.max[2]")
            && e.to_string().contains("puts 1 row in each element, every 0.004 m); the nearest are 0.06 and 0.064 m"),
        "{e}"
    );
    // The implicit scheme's saturated layers have no explicit counterpart;
    // left unset, the explicit scheme takes "free".
    let e = load(&MPM, &["mpm.pressure_scheme=\"explicit\"", "mpm.surface_elements=\"hydrostatic\""]).unwrap_err();
    assert!(
        e.names_key("mpm.surface_elements")
            && e.to_string().contains("set mpm.pressure_scheme = \"implicit\", or mpm.surface_elements = \"free\""),
        "{e}"
    );
    let explicit = load(&MPM, &["mpm.pressure_scheme=\"explicit\""]).unwrap().mpm();
    assert_eq!(explicit.surface_elements_in_effect(), schemas::scene::MpmSurfaceElements::Free);
    assert_eq!(
        load(&MPM, &[]).unwrap().mpm().surface_elements_in_effect(),
        schemas::scene::MpmSurfaceElements::Hydrostatic
    );
}

#[test]
fn mpm_takes_one_soil_and_one_liquid() {
    let soil = MPM.split("[[particles]]").nth(1).unwrap().split("[[fluids]]").next().unwrap();
    let two_soils = MPM.replacen("[[fluids]]", &format!("[[particles]]{soil}[[fluids]]"), 1);
    let e = load(&two_soils, &[]).unwrap_err();
    assert!(e.names_key("particles") && e.to_string().contains("at most one [[particles]] block, got 2"), "{e}");
    let water = MPM.split("[[fluids]]").nth(1).unwrap().split("[output]").next().unwrap();
    let two_waters = MPM.replacen("[output]", &format!("[[fluids]]{water}[output]"), 1);
    let e = load(&two_waters, &[]).unwrap_err();
    assert!(e.names_key("fluids") && e.to_string().contains("at most one [[fluids]] block, got 2"), "{e}");
    // Neither block.
    let e = load(&MPM, &["particles=[]", "fluids=[]", "analysis.condition=\"dry\""]).unwrap_err();
    assert!(e.to_string().contains("nothing to simulate"), "{e}");
    // `count` instead of `porosity`.
    let counted = MPM.replace("porosity = 0.4", "count = 5000");
    let e = load(&counted, &[]).unwrap_err();
    assert!(
        e.names_key("particles[0].packing.count") && e.to_string().contains("replace `count` with `porosity`"),
        "{e}"
    );
    // Explicit grains.
    let explicit = MPM.replace(
        "method = \"deposit\"\nregion = { min = [0.0, 0.0, 0.0], max = [0.04, 0.05, 0.06] }\nporosity = 0.4\nseed = 1",
        "method = \"explicit\"\nspheres = [[0.01, 0.01, 0.01, 2.5e-3]]",
    );
    let e = load(&explicit, &[]).unwrap_err();
    assert!(e.names_key("particles[0].packing.method") && e.to_string().contains("method = \"deposit\""), "{e}");
}

#[test]
fn every_mpm_problem_is_reported_at_once() {
    let e = load(&MPM, &["mpm.courant=0", "gates[0].point=[0.041, 0.0, 0.0]", "domain.gravity=[0.0, 1.0, -9.81]"])
        .unwrap_err();
    assert!(e.names_key("mpm.courant") && e.names_key("gates[0].point[0]") && e.names_key("domain.gravity"), "{e}");
}

#[test]
fn explicit_method_must_match_the_blocks() {
    for (set, implied) in [("scene.method=\"lbm\"", "\"dem\""), ("scene.method=\"dem_lbm\"", "\"dem\"")] {
        let e = load(VALID, &[set]).expect_err(set);
        assert!(e.names_key("scene.method") && e.to_string().contains(&format!("implies {implied}")), "{set}: {e}");
    }
    let sat = SATURATED;
    let e = load(sat, &["scene.method=\"dem\""]).unwrap_err();
    assert!(e.names_key("scene.method") && e.to_string().contains("implies \"dem_lbm\""), "{e}");
    // Named as the blocks imply: fine.
    assert_eq!(load(VALID, &["scene.method=\"dem\""]).unwrap().method(), Method::DemDry);
    assert_eq!(load(sat, &["scene.method=dem_lbm"]).unwrap().method(), Method::DemLbm);
    let e = load(VALID, &["scene.method=\"sph\""]).unwrap_err();
    assert!(e.names_key("scene.method") && e.to_string().contains("unknown variant"), "{e}");
}

#[test]
fn saturated_column_runs_as_mpm() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let path = root.join("scenes/ceccato2020/sat_h060.toml");
    let dem_lbm = Scene::load(&path, &[]).unwrap();
    assert_eq!(dem_lbm.method(), Method::DemLbm);
    let s = Scene::load(&path, &["scene.method=mpm".to_string()]).unwrap();
    assert_eq!(s.method(), Method::Mpm);
    assert_eq!(s.mpm().element_size, 0.004);
}

/// `domain.collapse_gravity`: grains alone (DEM or MPM) take it; a scene
/// with a lattice refuses it (its liquid starts hydrostatic under
/// `domain.gravity`), the MPM refuses an out-of-plane part, and NaN is
/// refused like any other value. It leaves t_ref on `domain.gravity`.
#[test]
fn collapse_gravity_is_for_grains_alone() {
    let push = "domain.collapse_gravity=[1.962, 0.0, -9.81]";
    let s = load(VALID, &[push]).unwrap();
    assert_eq!(s.spec.domain.collapse_gravity, Some([1.962, 0.0, -9.81]));
    assert!((s.reference_time() - 0.0782).abs() < 5e-5, "t_ref from domain.gravity");
    let resolved = s.to_toml();
    assert!(resolved.contains("collapse_gravity"), "the resolved scene keeps the push");
    assert!(!load(VALID, &[]).unwrap().to_toml().contains("collapse_gravity"), "and omits it when unset");
    load(SATURATED, &[push, "scene.method=mpm"]).unwrap();

    let e = load(SATURATED, &[push]).unwrap_err();
    assert!(e.to_string().contains("domain.collapse_gravity") && e.to_string().contains("hydrostatic"), "{e}");
    let e = load(SATURATED, &["domain.collapse_gravity=[0.0, 1.0, -9.81]", "scene.method=mpm"]).unwrap_err();
    assert!(e.to_string().contains("collapse_gravity[1] must be 0"), "{e}");
    let e = load(VALID, &["domain.collapse_gravity=[nan, 0.0, -9.81]"]).unwrap_err();
    assert!(e.to_string().contains("domain.collapse_gravity[0]"), "{e}");
    let e = load(VALID, &["domain.collapse_gravity=[0.0, 0.0, 0.0]"]).unwrap_err();
    assert!(e.to_string().contains("nothing to collapse"), "{e}");
}
