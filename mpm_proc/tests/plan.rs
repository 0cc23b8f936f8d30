//! The MPM's plan of the shipped scenes (`mpm_proc::plan`): grid, n0,
//! time step and drag, as `coupler check` reports them and the solver runs
//! them.

use std::path::{Path, PathBuf};

use mpm_proc::plan::SceneMpm;
use schemas::{Method, Scene};

fn scenes() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenes")
}

/// Sec. 5.3: the four (D, mu) pairs span Re_p ~ 2e3 .. 2e6.
#[test]
fn drag_study_spans_the_reynolds_numbers() {
    let root = scenes().join("mpm_drag_study");
    let mut re: Vec<f64> = ["d025mm_mu0p1", "d250mm_mu0p1", "d025mm_mu0p001", "d250mm_mu0p001"]
        .iter()
        .map(|n| {
            let s = Scene::load(&root.join(format!("drag_s100_{n}.toml")), &[]).unwrap();
            // Scaled by 100 with the lab's point count.
            assert_eq!((s.mpm_grid().nx, s.mpm_grid().nz), (175, 30));
            s.mpm_drag().unwrap().reynolds
        })
        .collect();
    re.sort_by(f64::total_cmp);
    for (got, want) in re.iter().zip([1.918e3, 1.918e4, 1.918e5, 1.918e6]) {
        assert!((got / want - 1.0).abs() < 1e-3, "{re:?}");
    }
}

/// Every shipped MPM scene has a finite CFL step and a step count.
#[test]
fn every_mpm_scene_has_a_time_step() {
    let mut n = 0;
    for dir in ["ceccato2020", "mpm_drag_study", "validation"] {
        for entry in std::fs::read_dir(scenes().join(dir)).unwrap() {
            let path = entry.unwrap().path();
            // Campaign files (`campaign.toml`, `*.campaign.toml`) are not scenes.
            if path.extension().is_none_or(|e| e != "toml") || path.to_string_lossy().ends_with("campaign.toml") {
                continue;
            }
            let s = Scene::load(&path, &[]).unwrap();
            if s.method() != Method::Mpm {
                continue;
            }
            n += 1;
            let t = s.mpm_time_step();
            assert!(t.dt > 0.0 && t.dt.is_finite() && t.steps > 0, "{}: {t:?}", path.display());
        }
    }
    assert!(n >= 14, "only {n} MPM scenes found");
}

/// The DEM–LBM column run as MPM: default 4 mm grid, 175 x 30 elements;
/// n0 = 0.42 from the DEM target porosity; Δt = 0.5 (default courant) ·
/// 0.004 / c_d with c_d = 94.48 m/s, the dry P-wave at n0 = 0.42, which
/// limits the step under the default implicit pore pressure (c_u = 178.0
/// m/s would under the explicit one).
#[test]
fn saturated_column_runs_as_mpm() {
    let path = scenes().join("ceccato2020/sat_h060.toml");
    let s = Scene::load(&path, &["scene.method=mpm".to_string()]).unwrap();
    assert_eq!((s.mpm_grid().nx, s.mpm_grid().nz), (175, 30));
    assert_eq!(s.mpm_porosity(), Some(0.42));
    let t = s.mpm_time_step();
    assert!((t.dt - 2.1168e-5).abs() < 1e-8, "{t:?}");
    assert!((t.undrained.unwrap() - 178.0).abs() < 0.01, "{t:?}");
}
