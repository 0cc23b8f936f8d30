//! `coupler export RUN --vtk` read back by a reader this project did not
//! write: meshio (PyPI), which reads VTK XML unstructured grids as ParaView
//! does. The exported points and fields must be the recording's.

use std::process::Command;

use foxglove::Decode;
use integration_tests::{binary, coupler_run, python_with, topic_messages};

/// meshio's view of an exported file: point count, its point arrays with
/// their widths, and the sum of `field`.
const READ: &str = r#"
import sys, meshio
m = meshio.read(sys.argv[1])
print(len(m.points))
print(" ".join(sorted(f"{k}:{v.shape[1] if v.ndim > 1 else 1}" for k, v in m.point_data.items())))
print(repr(float(m.point_data[sys.argv[2]].sum())))
print(repr(float(m.points[:, 0].sum())))
"#;

fn read_back(python: &std::path::Path, file: &std::path::Path, field: &str) -> (usize, String, f64, f64) {
    let out = Command::new(python).args(["-c", READ]).arg(file).arg(field).output().expect("python runs");
    assert!(out.status.success(), "meshio cannot read {}: {}", file.display(), String::from_utf8_lossy(&out.stderr));
    let text = String::from_utf8_lossy(&out.stdout).to_string();
    let lines: Vec<&str> = text.lines().collect();
    (lines[0].parse().unwrap(), lines[1].to_string(), lines[2].parse().unwrap(), lines[3].parse().unwrap())
}

#[test]
fn exported_grains_and_mpm_points_read_back_with_meshio() {
    let Some(python) = python_with("meshio", "meshio") else {
        assert!(std::env::var_os("CI").is_none(), "CI must be able to install meshio");
        eprintln!("SKIPPED: python3 with pip is not available on this machine");
        return;
    };
    let dem = coupler_run("export_dem", "scenes/validation/dry_small.toml", &["--set", "output.end_time=0.05"]);
    let mpm = coupler_run(
        "export_mpm",
        "scenes/ceccato2020/mpm_sat_h030.toml",
        &["--set", "output.end_time=0.02", "--set", "output.stop_at_rest=false"],
    );
    for run in [&dem, &mpm] {
        let status = Command::new(binary("coupler")).arg("export").arg(run).args(["--vtk"]).status().unwrap();
        assert!(status.success(), "export of {} failed", run.display());
    }
    // Grains: the last frame, against the recording's last /dem/particles cloud.
    let clouds = topic_messages(&dem.join("run.mcap"), "/dem/particles");
    let last = foxglove::schemas::PointCloud::decode(&clouds.last().unwrap()[..]).unwrap();
    let f32_at =
        |p: usize, off: usize| f32::from_le_bytes(last.data[p * 24 + off..p * 24 + off + 4].try_into().unwrap());
    let n = last.data.len() / last.point_stride as usize;
    let radius_sum: f64 = (0..n).map(|p| f32_at(p, 12) as f64).sum();
    let x_sum: f64 = (0..n).map(|p| f32_at(p, 0) as f64).sum();
    let file = dem.join("vtk").join(format!("grains_{:05}.vtu", clouds.len() - 1));
    let (count, arrays, radii, xs) = read_back(&python, &file, "radius");
    assert_eq!(count, n, "every grain");
    assert_eq!(arrays, "coordination:1 radius:1 speed:1");
    assert!((radii - radius_sum).abs() <= 1e-6 * radius_sum, "radius sum {radii} against {radius_sum}");
    assert!((xs - x_sum).abs() <= 1e-5 * x_sum.abs(), "x sum {xs} against {x_sum}");
    // The full states carry the vectors.
    let (_, arrays, _, _) = read_back(&python, &dem.join("vtk/grains_state_00000.vtu"), "radius");
    assert_eq!(arrays, "angular_velocity:3 radius:1 velocity:3");
    let pvd = std::fs::read_to_string(dem.join("vtk/grains.pvd")).unwrap();
    assert_eq!(pvd.matches("<DataSet ").count(), clouds.len(), "one timestep per frame");
    // MPM: both phases, with their fields.
    for (series, topic) in [("mpm_solid", "/mpm/solid"), ("mpm_liquid", "/mpm/liquid")] {
        let clouds = topic_messages(&mpm.join("run.mcap"), topic);
        let first = foxglove::schemas::PointCloud::decode(&clouds[0][..]).unwrap();
        let n = first.data.len() / first.point_stride as usize;
        let field = first.fields[3].name.clone();
        let (count, arrays, _, _) = read_back(&python, &mpm.join(format!("vtk/{series}_00000.vtu")), &field);
        assert_eq!(count, n, "{series}: every point");
        assert_eq!(arrays.split(' ').count(), first.fields.len() - 3, "{series}: every field: {arrays}");
    }
}
