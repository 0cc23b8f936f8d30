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
            Method::LbmFluid => "lbm_proc (not available yet)",
            Method::DemLbm => "dem_proc + lbm_proc (not available yet)",
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
        warnings.push("fluid blocks are validated but not simulated yet (lbm_proc comes with the LBM issue)".into());
    }
    if warnings.is_empty() {
        println!("warnings     none");
    }
    for w in warnings {
        println!("warning      {w}");
    }
}
