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

/// The no-tension spring-dashpot rebounds at no less than e = 0.136 (at
/// critical damping, dem_proc::contact): a lower restitution is refused by
/// `coupler` and by `dem_proc` alone, with the same words.
#[test]
fn restitution_below_the_critically_damped_rebound_is_refused_by_coupler_and_dem_proc() {
    let set = ["--set", "dem.restitution=0.1"];
    let out = coupler().args(["check", "scenes/ceccato2020/dry_h060.toml"]).args(set).output().unwrap();
    assert_eq!(out.status.code(), Some(2));
    let want = "dem.restitution: a linear spring-dashpot that never pulls cannot rebound slower than e = 0.136 (at critical damping), got 0.1";
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains(want), "{err}");
    let dem = std::path::Path::new(env!("CARGO_BIN_EXE_coupler")).with_file_name("dem_proc");
    if dem.exists() {
        let out = Command::new(dem)
            .current_dir(concat!(env!("CARGO_MANIFEST_DIR"), "/.."))
            .args(["run", "scenes/ceccato2020/dry_h060.toml", "--out", "/nonexistent/never-written"])
            .args(set)
            .output()
            .unwrap();
        assert_eq!(out.status.code(), Some(2));
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(err.contains(want), "{err}");
    }
    let out = coupler()
        .args(["check", "scenes/ceccato2020/dry_h060.toml", "--set", "dem.restitution=0.14"])
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
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

/// `--method mpm` runs the DEM-LBM column as an MPM scene: default [mpm]
/// (4 mm, 12 points, courant 0.5, implicit pore pressure), n0 = 0.42 from
/// the scene, so the skeleton's wave c_d = sqrt(1.346e7/(0.58 x 2600))
/// = 94.5 m/s limits the step, dt = 0.5 x 0.004 / 94.5 = 2.117e-5 s
/// (the undrained c_u = 178.0 m/s would under the explicit scheme).
#[test]
fn check_method_mpm_prints_the_mpm_time_step() {
    let out = coupler().args(["check", "--method", "mpm", "scenes/ceccato2020/sat_h060.toml"]).output().unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(text.contains("mpm (mpm_proc, two-phase double-point MPM"), "{text}");
    assert!(text.contains("175 x 30 = 5250 elements"), "{text}");
    assert!(text.contains("dt 2.117e-5 s = courant 0.5 x 0.004 m / 94.5 m/s (dry P-wave limits)"), "{text}");
    // 10 x 15 soil elements x 12 points, saturated throughout.
    assert!(text.contains("150 elements, 1800 solid points (150 saturated elements, 0 dry)"), "{text}");
    assert!(!text.contains("grains ") && !text.contains("lattice "), "no DEM or LBM block under mpm: {text}");
    // --method is applied before --set, so --set wins.
    let out = coupler()
        .args(["check", "--method", "mpm", "scenes/ceccato2020/sat_h060.toml", "--set", "scene.method=dem_lbm"])
        .output()
        .unwrap();
    assert!(String::from_utf8_lossy(&out.stdout).contains("dem_lbm (dem_proc + lbm_proc"));
}

/// The MPM scene of the paper's column: Table 2's n0 = 0.40 gives the
/// wave speeds of mpm-2pdp.md §7 (c_u 180, free water 141, dry 93 m/s).
#[test]
fn check_reports_the_mpm_column() {
    let out = coupler().args(["check", "scenes/ceccato2020/mpm_sat_h060.toml"]).output().unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(text.contains("undrained P 179.9 m/s, liquid 141.4 m/s, dry P 92.9 m/s"), "{text}");
    // The implicit pore pressure (the default): the dry P-wave limits.
    assert!(text.contains("dt 2.153e-5 s = courant 0.5 x 0.004 m / 92.9 m/s (dry P-wave limits)"), "{text}");
    assert!(text.contains("E_oed 1.3462e7 Pa, K0 = nu/(1-nu) = 0.429"), "{text}");
    // analytic-checks.md: kappa = 7.41e-9 m², K = 0.0727 m/s; Re_p = 1918.
    assert!(text.contains("kappa(n0) 7.407e-9 m²") && text.contains("conductivity 7.267e-2 m/s"), "{text}");
    assert!(text.contains("Re_p = D rho_L sqrt(g H0)/mu = 1.918e3"), "{text}");
    assert!(text.contains("warnings     none"), "{text}");
    // The warnings of the MPM.
    let out = coupler()
        .args([
            "check",
            "scenes/mpm_drag_study/drag_s100_d025mm_mu0p001.toml",
            "--set",
            "mpm.quadratic_drag=false",
            "--set",
            "mpm.points_per_element=3",
        ])
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(text.contains("the paper finds the quadratic term matters above ~4e4"), "{text}");
    assert!(text.contains("the paper saw instabilities with 3 points per element"), "{text}");
    let out = coupler()
        .args(["check", "scenes/ceccato2020/mpm_sat_h060.toml", "--set", "particles[0].diameter=1e-5"])
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(text.contains("an explicit drag would be unstable; mpm_proc integrates it implicitly"), "{text}");
    // APIC above its measured stable step; FLIP is not warned at the same step.
    let check_at = |transfer: &str| {
        let out = coupler()
            .args(["check", "scenes/ceccato2020/mpm_dry_h060.toml", "--set", "mpm.courant=0.8", "--set"])
            .arg(format!("mpm.transfer=\"{transfer}\""))
            .output()
            .unwrap();
        String::from_utf8_lossy(&out.stdout).into_owned()
    };
    for affine in ["apic", "aflip"] {
        let text = check_at(affine);
        assert!(
            text.contains("mpm.courant = 0.8 under an affine transfer (APIC, AFLIP): an elastic block held at 0.75"),
            "{text}"
        );
    }
    let flip = check_at("flip");
    assert!(!flip.contains("mpm.courant = 0.8"), "{flip}");
    // The scene's AFLIP share is named as unused under FLIP.
    assert!(flip.contains("mpm.flip_share = 0.9 is unused under mpm.transfer = \"flip\""), "{flip}");
    // FLIP's filter keys set under AFLIP are named as unused.
    let out = coupler()
        .args(["check", "scenes/ceccato2020/mpm_sat_h060.toml", "--set", "mpm.pic_fraction=0"])
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        text.contains("mpm.pic_fraction = 0 and mpm.xpic_order = 2 are unused under mpm.transfer = \"aflip\""),
        "{text}"
    );
    // A release speed set for walls that hold both ways is named as unused.
    let out = coupler()
        .args([
            "check",
            "scenes/ceccato2020/mpm_sat_h060.toml",
            "--set",
            "mpm.wall_contact=\"bilateral\"",
            "--set",
            "mpm.wall_release_speed=1e-4",
        ])
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        text.contains("mpm.wall_release_speed = 0.0001 is unused under mpm.wall_contact = \"bilateral\""),
        "{text}"
    );
}

/// A saturated column topped inside an element (two of the top element's
/// three point rows): checked without a warning under the implicit
/// scheme's default `surface_elements = "hydrostatic"`, warned under
/// `"free"` (at rest its top element drains) and, under either, where the
/// water's top lies inside an element below the soil's (too little water
/// for that soil's pores: drained); `"hydrostatic"` refused under the
/// explicit scheme, naming the key and both fixes.
#[test]
fn check_warns_of_a_top_inside_an_element_only_where_it_would_drain() {
    let inside = "[0.04, 0.05, 0.058666666666666666]";
    let check_tops = |soil: &str, extra: &[&str]| {
        let out = coupler()
            .args(["check", "scenes/ceccato2020/mpm_sat_h060.toml", "--set"])
            .arg(format!("particles[0].packing.region.max={soil}"))
            .arg("--set")
            .arg(format!("fluids[0].region.max={inside}"))
            .args(extra)
            .output()
            .unwrap();
        (out.status.code(), String::from_utf8_lossy(&out.stdout).into_owned() + &String::from_utf8_lossy(&out.stderr))
    };
    let check = |extra: &[&str]| check_tops(inside, extra);
    let (code, text) = check_tops("[0.04, 0.05, 0.06]", &[]);
    assert_eq!(code, Some(0), "{text}");
    assert!(
        text.contains("lies inside an element (0.67 of it below the top) under the soil's top z = 0.06 m: that element starts 0.67 filled"),
        "{text}"
    );
    let (code, text) = check(&[]);
    assert_eq!(code, Some(0), "{text}");
    assert!(text.contains("saturated layers in elements below the fill at their hydrostatic pressure"), "{text}");
    assert!(text.contains("warnings     none"), "{text}");
    let (code, text) = check(&["--set", "mpm.surface_elements=\"free\""]);
    assert_eq!(code, Some(0), "{text}");
    assert!(text.contains("that element starts 0.44 filled, below mpm.free_surface_fill = 0.8"), "{text}");
    let (code, text) =
        check(&["--set", "mpm.surface_elements=\"hydrostatic\"", "--set", "mpm.pressure_scheme=\"explicit\""]);
    assert_eq!(code, Some(2), "{text}");
    assert!(
        text.contains("mpm.surface_elements")
            && text.contains("set mpm.pressure_scheme = \"implicit\", or mpm.surface_elements = \"free\""),
        "{text}"
    );
}

/// `coupler check` accepts every MPM scene shipped.
#[test]
fn check_accepts_every_mpm_scene() {
    let root = concat!(env!("CARGO_MANIFEST_DIR"), "/../scenes");
    let mut scenes = Vec::new();
    for dir in ["ceccato2020", "mpm_drag_study"] {
        for e in std::fs::read_dir(format!("{root}/{dir}")).unwrap() {
            let p = e.unwrap().path();
            let name = p.file_name().unwrap().to_string_lossy().into_owned();
            // Scenes, not the campaign files beside them (docs/campaign.md).
            let scene = name.ends_with(".toml") && !name.ends_with("campaign.toml");
            if (name.starts_with("mpm_") || name.starts_with("drag_")) && scene {
                scenes.push(format!("scenes/{dir}/{name}"));
            }
        }
    }
    scenes.sort();
    assert_eq!(scenes.len(), 14, "{scenes:?}");
    for scene in &scenes {
        let out = coupler().args(["check", scene]).output().unwrap();
        assert!(out.status.success(), "{scene}: {}", String::from_utf8_lossy(&out.stderr));
        let text = String::from_utf8_lossy(&out.stdout);
        assert!(text.contains("method       mpm (mpm_proc") && text.contains("time step    dt "), "{scene}: {text}");
        assert!(text.contains("warnings     none"), "{scene}: {text}");
    }
}

#[test]
fn method_that_contradicts_the_blocks_exits_2() {
    let out = coupler().args(["check", "--method", "dem", "scenes/ceccato2020/sat_h060.toml"]).output().unwrap();
    assert_eq!(out.status.code(), Some(2));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("scene.method: is \"dem\"") && err.contains("implies \"dem_lbm\""), "{err}");
    // H0 = 0.03 m is neither on the default 4 mm grid nor on a row of its
    // 12 points (4 × 3, rows every 4/3 mm): the error says what fits.
    let out = coupler().args(["run", "--method", "mpm", "scenes/ceccato2020/sat_h030.toml"]).output().unwrap();
    assert_eq!(out.status.code(), Some(2));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("particles[0].packing.region.max[2]")
            && err.contains("the nearest are 0.029333333 and 0.030666667 m")
            && err.contains("mpm.points_per_element = 12"),
        "{err}"
    );
}

/// A tall tank at a viscous scene's Δt compresses the liquid by its own
/// weight: `check` says by how much and what to do; with the weight off
/// the lattice the warning goes. A free-surface scene cannot take that
/// form: refused at load, naming the key.
#[test]
fn check_warns_of_a_compressed_tank_and_buoyancy_form_needs_a_full_closed_box() {
    let out = coupler().args(["check", "scenes/validation/settling_sphere.toml"]).output().unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let text = String::from_utf8_lossy(&out.stdout);
    // 3 g H dt²/dx² = 3 · 9.81 · 0.06 · (2.5e-4)² / (5e-4)² = 0.441.
    assert!(text.contains("density varies by 44.1"), "{text}");
    assert!(text.contains("lbm.hydrostatics = \"buoyancy\""), "{text}");
    let out = coupler()
        .args(["check", "scenes/validation/settling_sphere.toml", "--set", "lbm.hydrostatics=buoyancy"])
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(text.contains("hydrostatics buoyancy") && !text.contains("density varies by"), "{text}");
    let out = coupler()
        .args(["check", "scenes/ceccato2020/sat_h060.toml", "--set", "lbm.hydrostatics=buoyancy"])
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("lbm.hydrostatics") && err.contains("closed box"), "{err}");
}
