//! Each solver's `plan(&Scene)` resolves a scene as the solver itself will:
//! the plans of a coupled scene agree with each other and with the solvers'
//! own set-up, and each one's cost is its steps times its work per step.

use integration_tests::repo_root;
use schemas::scene::Scene;

fn scene(path: &str) -> Scene {
    Scene::load(&repo_root().join(path), &[]).expect("a shipped scene")
}

/// The DEM step is the LBM step over the ratio, in both plans and in the
/// DEM's set-up; an exchange interval holds `ratio` DEM steps to the end.
#[test]
fn the_coupled_plans_agree_on_the_time_steps() {
    let s = scene("scenes/ceccato2020/sat_h060.toml");
    let dem = dem_proc::plan::plan(&s);
    let lbm = lbm_proc::plan::plan(&s);
    let ratio = s.spec.coupling.ratio as f64;
    assert_eq!(lbm.time_step, s.lbm().time_step);
    assert!((dem.time_step * ratio / lbm.time_step - 1.0).abs() < 1e-12, "{} {}", dem.time_step, lbm.time_step);
    assert_eq!(dem.time_step, dem_proc::setup::DemSetup::from_scene(&s).numerics.dt);
    // Steps to the end time: ceil(T/dt) each, so within one exchange of each other.
    let dem_in_exchanges = dem.steps as f64 / ratio;
    assert!((dem_in_exchanges - lbm.steps as f64).abs() <= 1.0, "{dem_in_exchanges} vs {}", lbm.steps);
    // Coupled, the LBM's plan says how the grains are forced; alone it does not.
    assert!(lbm.lines.iter().any(|(l, _)| *l == "forcing"));
    let water = lbm_proc::plan::plan(&scene("scenes/ceccato2020/water_h060.toml"));
    assert!(water.lines.iter().all(|(l, _)| *l != "forcing"));
}

/// Work is steps × (grains, initial liquid cells, points); the wall
/// estimate is that work at the rate the plan names.
#[test]
fn each_plan_costs_its_steps_times_its_work_per_step() {
    let s = scene("scenes/ceccato2020/sat_h060.toml");
    let grains = dem_proc::packing::generate(&s).0.len() as f64;
    let dem = dem_proc::plan::plan(&s);
    assert_eq!(dem.work, dem.steps as f64 * grains);
    assert_eq!(dem.wall_estimate, dem.work / dem_proc::plan::MEASURED_DEM_RATE);

    let lbm = lbm_proc::plan::plan(&s);
    // The initial liquid: the fluid block's volume in cells of dx³ (whole
    // cells per axis, so within a cell layer per face: ~2 % here).
    let r = &s.spec.fluids[0].region;
    let volume: f64 = (0..3).map(|a| r.max[a] - r.min[a]).product();
    let cells = volume / s.lbm().spacing.powi(3);
    let planned_cells = lbm.work / lbm.steps as f64;
    assert!((planned_cells / cells - 1.0).abs() < 0.03, "{planned_cells} vs {cells}");

    let m = scene("scenes/ceccato2020/mpm_sat_h060.toml");
    let mpm = mpm_proc::plan::plan(&m);
    use mpm_proc::plan::SceneMpm;
    assert_eq!(mpm.time_step, m.mpm_time_step().dt);
    // 150 soil elements and 150 liquid elements at 12 points each (analytic: the column is 0.04 x 0.06 m of 4 mm elements).
    assert_eq!(mpm.work, mpm.steps as f64 * 2.0 * 150.0 * 12.0);
    assert_eq!(mpm.wall_estimate, mpm.work / mpm_proc::plan::MEASURED_MPM_RATE);
}
