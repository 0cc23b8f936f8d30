//! The `coupler` command line without running a simulation.

use std::process::Command;

fn coupler() -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_coupler"));
    c.current_dir(concat!(env!("CARGO_MANIFEST_DIR"), "/.."));
    c
}

#[test]
fn check_reports_time_step_and_steps_per_contact() {
    let out = coupler().args(["check", "scenes/ceccato2020/dry_h060.toml"]).output().unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let text = String::from_utf8_lossy(&out.stdout);
    // 25 steps per contact of the lightest pair, D = 2.5 mm, ρ = 2600, k_n = 2000 N/m.
    assert!(text.contains("25.0 steps per contact"), "{text}");
    assert!(text.contains("damping ratio 0.0417"), "{text}");
    // 0.58 × 0.04 × 0.05 × 0.06 m³ / (π/6 · 2.5e-3³) = 8507 grains.
    assert!(text.contains("8507 generated"), "{text}");
}

#[test]
fn check_reports_the_lattice_of_a_fluid_scene() {
    let out = coupler().args(["check", "scenes/ceccato2020/water_h060.toml"]).output().unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(text.contains("lbm (lbm_proc)"), "{text}");
    // 0.70 x 0.05 x 0.12 m at 0.6 mm (0.05 m rounds to 83 cells).
    assert!(text.contains("1167 x 83 x 200"), "{text}");
    // tau = 1/2 + 3 nu dt/dx^2 = 0.5 + 3e-6 * 8e-5 / 3.6e-7.
    assert!(text.contains("tau0 = 0.500667"), "{text}");
    // Eq. 4 at sqrt(g/H0) = 12.8 1/s: (0.16 * 6e-4)^2 * 12.79 = 1.178e-7 m²/s.
    assert!(text.contains("1.178e-7 eddy"), "{text}");
    // 2 sqrt(g H0) = 1.534 m/s = 0.2046 lattice = Mach 0.354: warned, not above the 0.5 limit.
    assert!(text.contains("Mach 0.354") && text.contains("warning      2 sqrt(g H0)"), "{text}");
}

/// The five saturated columns of Table 1 load, run both processes, and
/// step the DEM 57 times per LBM step: 8e-5 s / 57 = 1.404e-6 s.
#[test]
fn check_reports_the_exchange_of_the_saturated_columns() {
    for h in ["030", "040", "050", "060", "070"] {
        let scene = format!("scenes/ceccato2020/sat_h{h}.toml");
        let out = coupler().args(["check", &scene]).output().unwrap();
        assert!(out.status.success(), "{scene}: {}", String::from_utf8_lossy(&out.stderr));
        let text = String::from_utf8_lossy(&out.stdout);
        assert!(text.contains("dem_lbm (dem_proc + lbm_proc, coupled over iceoryx2)"), "{scene}: {text}");
        assert!(
            text.contains("sequential schedule, 57 DEM steps per LBM step (DEM 1.404e-6 s, LBM 8.000e-5 s)"),
            "{scene}: {text}"
        );
        assert!(text.contains("tau0 = 0.500667"), "{scene}: {text}");
        // D/dx = 2.5 mm / 0.6 mm.
        assert!(text.contains("smallest grain diameter 4.17 lattice cells"), "{scene}: {text}");
    }
}

#[test]
fn bad_scene_exits_2_naming_the_key() {
    let out =
        coupler().args(["check", "scenes/ceccato2020/dry_h060.toml", "--set", "dem.friction=-0.2"]).output().unwrap();
    assert_eq!(out.status.code(), Some(2));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("dem.friction: must be >= 0, got -0.2"), "{err}");
    let out =
        coupler().args(["run", "scenes/ceccato2020/dry_h060.toml", "--set", "output.end_time=-1"]).output().unwrap();
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("output.end_time"));
    let out = coupler().args(["check", "does/not/exist.toml"]).output().unwrap();
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("cannot read scene file"));
}

#[test]
fn inspect_rejects_a_file_that_is_not_mcap() {
    let path = std::env::temp_dir().join(format!("not-mcap-{}.mcap", std::process::id()));
    std::fs::write(&path, b"hello").unwrap();
    let out = coupler().args(["inspect", path.to_str().unwrap()]).output().unwrap();
    assert_eq!(out.status.code(), Some(1));
    assert!(
        String::from_utf8_lossy(&out.stderr).contains("not an MCAP file"),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let _ = std::fs::remove_file(path);
}
