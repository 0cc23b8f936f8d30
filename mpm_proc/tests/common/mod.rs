//! Scenes the MPM tests load from `scenes/validation/` or build from TOML
//! text (validated like a user's file).

/// Progress that reports nothing (tests check numbers, not the log).
#[allow(unused_imports)] // not every test file runs a gravity phase
pub use runtime::process::Quiet;
use schemas::Scene;

/// The shipped scene `scenes/validation/NAME.toml` with `--set` overrides.
#[allow(dead_code)] // not every test file loads one
pub fn validation_scene(name: &str, overrides: &[&str]) -> Scene {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join(format!("../scenes/validation/{name}.toml"));
    let overrides: Vec<String> = overrides.iter().map(|s| s.to_string()).collect();
    Scene::load(&path, &overrides).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// A saturated or dry soil column `width` × `height` (m) in a box `box_height`
/// tall, with the given `[mpm]` lines and liquid up to `water` (None: dry).
#[allow(dead_code)] // not every test file builds a column
pub fn column(
    width: f64,
    height: f64,
    box_height: f64,
    water: Option<f64>,
    grain: f64,
    mpm: &str,
    extra: &[&str],
) -> Scene {
    let fluid = match water {
        Some(top) => format!(
            "[[fluids]]\nname = \"water\"\ndensity = 1000.0\nviscosity = 1.0e-3\nregion = {{ min = [0.0, 0.0, 0.0], max = [{width}, 0.05, {top}] }}\n"
        ),
        None => String::new(),
    };
    let condition = if water.is_some() { "saturated" } else { "dry" };
    let text = format!(
        r#"
[scene]
name = "test_column"
method = "mpm"

[domain]
min = [0.0, 0.0, 0.0]
max = [{width}, 0.05, {box_height}]
gravity = [0.0, 0.0, -9.81]
walls = ["x_min", "x_max", "z_min"]

[[particles]]
name = "soil"
density = 2600.0
diameter = {grain}

[particles.packing]
method = "deposit"
region = {{ min = [0.0, 0.0, 0.0], max = [{width}, 0.05, {height}] }}
porosity = 0.4
seed = 1

{fluid}

[mpm]
{mpm}

[output]
end_time = 0.1
record_interval = 0.01
stop_at_rest = false

[analysis]
column_length = {width}
column_height = {height}
condition = "{condition}"
"#
    );
    let overrides: Vec<String> = extra.iter().map(|s| s.to_string()).collect();
    Scene::from_toml_str(&text, std::path::Path::new("."), &overrides).unwrap_or_else(|e| panic!("test scene: {e}"))
}

/// A free-water column `l0` × `h0` m of density `rho` (the soil removed,
/// its liquid points the water itself, n = 1) in an `l0` × 0.12 m box
/// whose floor and side walls hold the normal velocity, stress free, on
/// the default 4 mm elements, with the given `[mpm]` lines.
#[allow(dead_code)] // not every test file builds one
pub fn free_water_column(l0: f64, h0: f64, rho: f64, mpm: &str) -> mpm_proc::solver::Mpm {
    let lines = format!("initial_stress = \"zero\"\nfloor = \"frictional\"\n{mpm}");
    let scene = column(l0, h0, 0.12, Some(h0), 2.5e-3, &lines, &[]);
    let mut m = mpm_proc::setup::build(&scene).unwrap().mpm;
    let half = m.state.solid.set.half;
    m.state.solid = mpm_proc::solver::SolidPoints::default();
    m.state.solid.set.half = half;
    for (mass, v) in m.state.liquid.set.mass.iter_mut().zip(&m.state.liquid.set.volume) {
        *mass = rho * v;
    }
    m
}
