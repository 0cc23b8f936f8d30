//! `coupler check`: what a run of the scene will be, without running it.

//!
//! Each solver resolves the scene into its plan the way it will when it
//! runs (`dem_proc::plan`, `lbm_proc::plan`, `mpm_proc::plan`); this prints
//! the plans of the method's solvers alike, the exchange between them when
//! coupled, and every warning.

use schemas::plan::Plan;
use schemas::scene::Scene;
use schemas::Method;

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
            Method::Mpm if s.particles.is_empty() || s.fluids.is_empty() =>
                "mpm_proc, one-phase MPM, 2D plane strain in x-z",
            Method::Mpm => "mpm_proc, two-phase double-point MPM, 2D plane strain in x-z",
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
    if let Some(g) = d.collapse_gravity {
        // The push as a share of the run's weight: what the seepage comparison quotes.
        let push =
            if g[2] < 0.0 { format!(": a push of {:.3} of the weight along x", -g[0] / g[2]) } else { String::new() };
        println!("run gravity  {g:?} m/s² from t = 0 (the preparation under gravity){push}");
    }
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
    let plans = plans(scene);
    for plan in &plans {
        print!("{}", plan.render());
    }
    if method == Method::DemLbm {
        print_exchange(scene, &plans);
    }
    let estimate: Vec<String> = plans
        .iter()
        .map(|p| {
            format!(
                "{} ~{:.0} s ({:.2e} {}, ~{:.0} MB)",
                p.solver,
                p.wall_estimate,
                p.work,
                p.work_unit,
                p.memory / 1e6
            )
        })
        .collect();
    println!("estimate     {}", estimate.join("; "));
    let out = &scene.spec.output;
    match out.checkpoint_interval {
        Some(interval) => {
            // A checkpoint is the solvers' state: less than their memory (no scratch).
            let state: f64 = plans.iter().map(|p| p.memory).sum();
            println!(
                "checkpoints  every {interval} s simulated, up to {}, each under ~{:.0} MB (the newest two per process kept; removed when the run completes); resume with `coupler run --resume OUT`",
                (out.end_time / interval).floor(),
                state / 1e6
            );
        }
        None => println!("checkpoints  none: set output.checkpoint_interval to make a killed run resumable"),
    }
    let warnings: Vec<&String> = plans.iter().flat_map(|p| &p.warnings).collect();
    if warnings.is_empty() {
        println!("warnings     none");
    }
    for w in warnings {
        println!("warning      {w}");
    }
}

/// The plans of the solvers the scene's method runs.
pub(crate) fn plans(scene: &Scene) -> Vec<Plan> {
    let s = &scene.spec;
    match scene.method() {
        Method::Mpm => vec![mpm_proc::plan::plan(scene)],
        _ => {
            let mut plans = Vec::new();
            if !s.particles.is_empty() {
                plans.push(dem_proc::plan::plan(scene));
            }
            if !s.fluids.is_empty() {
                plans.push(lbm_proc::plan::plan(scene));
            }
            plans
        }
    }
}

/// The exchange of a coupled scene: schedule, ratio and message sizes.
fn print_exchange(scene: &Scene, plans: &[Plan]) {
    let c = &scene.spec.coupling;
    let of = |solver: &str| plans.iter().find(|p| p.solver == solver);
    let (Some(dem), Some(lbm)) = (of("dem_proc"), of("lbm_proc")) else {
        return;
    };
    let grains = dem_proc::packing::generate(scene).0.len() as f64;
    println!(
        "exchange     {} schedule, {} DEM steps per LBM step (DEM {:.3e} s, LBM {:.3e} s); {} exchanges of {:.0} kB grain states + {:.0} kB loads",
        c.schedule.name(),
        c.ratio,
        dem.time_step,
        lbm.time_step,
        lbm.steps,
        grains * std::mem::size_of::<runtime::exchange::ParticleState>() as f64 / 1e3,
        grains * std::mem::size_of::<runtime::exchange::HydroLoad>() as f64 / 1e3,
    );
}
