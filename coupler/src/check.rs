//! `coupler check`: what a run of the scene will be, without running it.

use schemas::scene::{PackingSpec, Scene};
use schemas::Method;

use dem_proc::packing::{cache_path, generate};
use dem_proc::setup::DemSetup;

/// Particle-steps per second measured on the dry H0 = 0.06 m column, 2 cores
/// (docs/BENCHMARKS.md); only used to print a rough duration.
const MEASURED_DEM_RATE: f64 = 8.0e6;

pub fn print(scene: &Scene) {
    let s = &scene.spec;
    let method = scene.method();
    println!("scene        {} — {}", s.scene.name, s.scene.description);
    println!(
        "method       {} ({})",
        method.name(),
        match method {
            Method::DemDry => "dem_proc",
            Method::LbmFluid => "lbm_proc",
            Method::DemLbm => "dem_proc + lbm_proc, coupled over iceoryx2",
        }
    );
    let d = &s.domain;
    println!(
        "domain       [{:.4}, {:.4}] x [{:.4}, {:.4}] x [{:.4}, {:.4}] m, gravity {:?} m/s², walls {}",
        d.min[0],
        d.max[0],
        d.min[1],
        d.max[1],
        d.min[2],
        d.max[2],
        d.gravity,
        d.walls.iter().map(|f| f.name()).collect::<Vec<_>>().join(" ")
    );
    for g in &s.gates {
        println!(
            "gate         {} at {:?}, normal {:?}, removed at t = {} s",
            g.name, g.point, g.normal, g.release_time
        );
    }
    let t_ref = scene.reference_time();
    println!(
        "t_ref        {:.4} s ({:?}); end time {} s = {:.2} t_ref; frames every {} s",
        t_ref,
        s.analysis.condition,
        s.output.end_time,
        s.output.end_time / t_ref,
        s.output.record_interval
    );
    let mut warnings = Vec::new();

    if !s.particles.is_empty() {
        let setup = DemSetup::from_scene(scene);
        let (grains, _) = generate(scene);
        let n = grains.len();
        println!("grains       {n} generated ({} blocks)", s.particles.len());
        let law = &setup.grain_law;
        println!(
            "contact      k_n {} N/m, k_t {} N/m, e {} -> damping ratio {:.5} (no-tension law), mu_s {}, mu_r {}",
            law.normal_stiffness,
            law.tangential_stiffness,
            scene.dem().restitution,
            law.damping_ratio,
            law.friction,
            law.rolling_friction
        );
        println!(
            "time step    {:.3e} s; contact duration {:.3e} s -> {:.1} steps per contact",
            setup.numerics.dt, setup.contact_duration, setup.steps_per_contact
        );
        let steps = (s.output.end_time / setup.numerics.dt).ceil();
        println!(
            "cost         up to {steps:.0} steps = {:.2e} particle-steps (~{:.0} s at {:.0e} particle-steps/s); memory ~{:.0} MB",
            steps * n as f64,
            steps * n as f64 / MEASURED_DEM_RATE,
            MEASURED_DEM_RATE,
            n as f64 * (7.0 * 24.0 + 16.0 + 10.0 * 110.0) / 1e6
        );
        if s.particles.iter().any(|b| matches!(b.packing, PackingSpec::Deposit { .. })) {
            let path = cache_path(scene);
            if s.deposition.cache && path.exists() {
                println!("packing      cached: {}", path.display());
            } else {
                println!(
                    "packing      gravity deposition at friction {} until grains are slower than {} m/s (cached as {})",
                    s.deposition.friction,
                    s.deposition.rest_speed,
                    path.display()
                );
            }
        }
        if setup.steps_per_contact < 20.0 {
            warnings.push(format!(
                "only {:.1} steps per contact: restitution and stability suffer below ~20; lower dem.time_step",
                setup.steps_per_contact
            ));
        }
        // Static overlap at the column base relative to the grain size.
        let rho = s.particles[0].density;
        let dmean = s.particles[0].diameter;
        let base_force = rho * 0.6 * scene.gravity_magnitude() * s.analysis.column_height * dmean * dmean;
        let overlap = base_force / law.normal_stiffness / dmean;
        println!("stiffness    base overlap ~{:.2} % of D under the column weight", overlap * 100.0);
        if overlap > 0.01 {
            warnings.push(format!(
                "grains at the base overlap ~{:.1} % of D: raise dem.normal_stiffness for the rigid limit",
                overlap * 100.0
            ));
        }
    }
    if !s.fluids.is_empty() {
        print_lbm(scene, &mut warnings);
    }
    if method == Method::DemLbm {
        let c = &s.coupling;
        let n = generate(scene).0.len();
        let exchanges = (s.output.end_time / scene.lbm().time_step).ceil();
        println!(
            "exchange     {} schedule, {} DEM steps per LBM step (DEM {:.3e} s, LBM {:.3e} s); {exchanges:.0} exchanges of {:.0} kB grain states + {:.0} kB loads",
            c.schedule.name(),
            c.ratio,
            scene.lbm().time_step / c.ratio as f64,
            scene.lbm().time_step,
            n as f64 * std::mem::size_of::<schemas::exchange::ParticleState>() as f64 / 1e3,
            n as f64 * std::mem::size_of::<schemas::exchange::HydroLoad>() as f64 / 1e3,
        );
        // The coupling resolves grains on the lattice: a few cells per diameter at least.
        let d_min = s.particles.iter().map(|b| b.diameter * (1.0 - b.diameter_spread)).fold(f64::INFINITY, f64::min);
        let cells = d_min / scene.lbm().spacing;
        println!("resolution   smallest grain diameter {cells:.2} lattice cells");
        if cells < 3.0 {
            warnings.push(format!(
                "grains span only {cells:.1} cells: the direct forcing needs ~4 or more for drag within ~10 % (docs/coupling.md); lower lbm.spacing"
            ));
        }
    }
    if warnings.is_empty() {
        println!("warnings     none");
    }
    for w in warnings {
        println!("warning      {w}");
    }
}

/// Lattice updates per second of the LBM on this machine, 2 threads
/// (docs/BENCHMARKS.md); only used to print a rough duration.
const MEASURED_LBM_RATE: f64 = 4.0e7;

fn print_lbm(scene: &Scene, warnings: &mut Vec<String>) {
    let s = &scene.spec;
    let lbm = scene.lbm();
    let fluid = &s.fluids[0];
    let (dx, dt) = (lbm.spacing, lbm.time_step);
    let nu = fluid.viscosity / fluid.density;
    let Ok(units) = lbm_proc::Units::new(dx, dt, fluid.density) else {
        warnings.push("lattice units cannot be built from lbm.spacing and lbm.time_step".into());
        return;
    };
    let tau = units.tau_from_viscosity(nu).unwrap_or(f64::NAN);
    let nu_l = units.viscosity_to_lattice(nu);
    let cells = |lo: f64, hi: f64| ((hi - lo) / dx).round().max(1.0);
    let d = &s.domain;
    let dims = [0, 1, 2].map(|a| cells(d.min[a], d.max[a]));
    let ncells = dims[0] * dims[1] * dims[2];
    let liquid: f64 =
        s.fluids.iter().map(|f| (0..3).map(|a| cells(f.region.min[a], f.region.max[a])).product::<f64>()).sum();
    println!(
        "lattice      {} x {} x {} = {:.3e} cells of {:.3e} m, time step {:.3e} s; liquid {:.3e} cells at the start",
        dims[0], dims[1], dims[2], ncells, dx, dt, liquid
    );
    println!(
        "relaxation   tau0 = {tau:.6} (nu = {nu:.3e} m²/s = {nu_l:.3e} lattice), {:?}, Smagorinsky C = {}",
        lbm.collision, lbm.smagorinsky
    );
    // Eq. 4: nu_t = (C dx)^2 |S|, at the collapse's own shear rate sqrt(g/H0) and at 100 1/s.
    let g = scene.gravity_magnitude();
    let h0 = s.analysis.column_height;
    for shear in [(g / h0).sqrt(), 100.0] {
        let nu_t = (lbm.smagorinsky * dx).powi(2) * shear;
        println!(
            "viscosity    at shear {shear:.1} 1/s: nu = {nu:.3e} molecular + {nu_t:.3e} eddy = {:.3e} m²/s = {:.3e} lattice (tau {:.6})",
            nu + nu_t,
            units.viscosity_to_lattice(nu + nu_t),
            units.tau_from_viscosity(nu + nu_t).unwrap_or(f64::NAN)
        );
    }
    let cs = (1.0_f64 / 3.0).sqrt();
    let wave = (g * h0).sqrt();
    for (what, speed) in [("sqrt(g H0)", wave), ("2 sqrt(g H0) (dam-break front)", 2.0 * wave)] {
        let mach = units.velocity_to_lattice(speed) / cs;
        println!("mach         {what} = {speed:.3} m/s -> Mach {mach:.3} in lattice units");
        if mach > lbm.mach_limit {
            warnings.push(format!(
                "{what} gives Mach {mach:.2}, above lbm.mach_limit = {}: the watchdog may stop the run; lower lbm.time_step",
                lbm.mach_limit
            ));
        } else if mach > 0.3 {
            warnings.push(format!(
                "{what} gives Mach {mach:.2}: compressibility errors grow above ~0.3; lower lbm.time_step for accuracy"
            ));
        }
    }
    if tau < 0.51 && lbm.smagorinsky == 0.0 {
        warnings.push(format!(
            "tau0 = {tau:.5} with no eddy viscosity: BGK is at the edge of stability; set lbm.smagorinsky (0.16)"
        ));
    }
    // Two f32 lattices, flags, f64 mass and fill per cell.
    let bytes_per_cell = 19.0 * 4.0 * 2.0 + 1.0 + 16.0;
    let steps = (s.output.end_time / dt).ceil();
    println!(
        "cost         {steps:.0} steps; memory ~{:.0} MB; ~{:.0} s at {:.0e} lattice updates/s if the liquid stays at its initial volume",
        ncells * bytes_per_cell / 1e6,
        steps * liquid / MEASURED_LBM_RATE,
        MEASURED_LBM_RATE
    );
}
