//! Where a coupled exchange spends its time at a given moment of a recorded
//! run: restores the last `/dem/state` and `/lbm/state` at or before TIME
//! from a coupled `run.mcap` and runs EXCHANGES exchanges of the sequential
//! schedule in this process (the LBM step with the grains forced in, then
//! the DEM's `coupling.ratio` steps under the loads it returned), timing
//! every stage of both solvers. Most of a 19-minute run's time goes late in
//! it; this times that part in seconds instead of re-running to it.
//!
//! ```sh
//! cargo run --release -p integration-tests --example late_profile -- RUN_DIR TIME [EXCHANGES]
//! ```
//!
//! RUN_DIR holds the run's `scene.toml` and `run.mcap` (states every
//! `output.state_interval`; the LBM's full state may only be at the end).
//! One untimed exchange first (the work lists grow on it), then one JSON
//! line of milliseconds per exchange. `RAYON_NUM_THREADS` sets the threads.

use std::path::PathBuf;
use std::time::Instant;

use runtime::exchange::ExchangeHeader;

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    if args.len() < 2 {
        eprintln!("usage: late_profile RUN_DIR TIME [EXCHANGES]");
        std::process::exit(2);
    }
    let dir = PathBuf::from(&args[0]);
    let time: f64 = args[1].parse().expect("TIME in seconds");
    let exchanges: u64 = args.get(2).map_or(20, |s| s.parse().expect("EXCHANGES a count"));
    if runtime::process::set_global_threads("late_profile", None).is_err() {
        std::process::exit(1);
    }
    let scene = schemas::Scene::load(&dir.join("scene.toml"), &[]).expect("scene loads");
    let bytes = std::fs::read(dir.join("run.mcap")).expect("run.mcap readable");
    let (mut dem_state, mut lbm_state) = (None, None);
    let stream = mcap::MessageStream::new(&bytes).expect("an MCAP recording");
    for m in stream {
        let m = m.expect("message");
        let t = m.log_time as f64 * 1e-9;
        if t > time + 1e-9 {
            continue;
        }
        if m.channel.topic == schemas::topics::DEM_STATE {
            dem_state = Some(dem_proc::run::DemState::decode(&m.data).expect("dem state"));
        } else if m.channel.topic == schemas::topics::LBM_STATE {
            lbm_state = Some(lbm_proc::run::LbmState::decode(&m.data).expect("lbm state"));
        }
    }
    let dem_state = dem_state.expect("a /dem/state at or before TIME");
    // Without a fluid state at the same time (a run records the LBM's full
    // state less often), only the DEM is timed, its loads held at zero.
    let lbm_state = lbm_state.filter(|s| (s.time - dem_state.time).abs() < 1e-9);

    let mut world = dem_state.restore(&scene);
    world.prime_forces();
    let setup = lbm_proc::setup::LbmSetup::from_scene(&scene).expect("LBM setup");
    let mut lbm = lbm_state.map(|s| {
        let fluid = lbm_proc::fluid::Fluid::from_state(s.fluid, setup.params).expect("fluid state");
        let coupling = lbm_proc::coupling::Coupling::new(setup.units, setup.origin)
            .expect("coupling")
            .with_gain(scene.spec.coupling.forcing_gain);
        (fluid, lbm_proc::grains::GrainForcing::new(coupling))
    });
    let ratio = scene.spec.coupling.ratio as u64;
    let (mut states, mut loads) = (Vec::new(), Vec::new());
    let (mut dem_seconds, mut lbm_seconds) = (0.0, 0.0);
    let (mut dem_before, mut lbm_before, mut coupling_before) = Default::default();
    for n in 0..=exchanges {
        if n == 1 {
            (dem_seconds, lbm_seconds) = (0.0, 0.0);
            dem_before = world.stage_seconds;
            if let Some((fluid, forcing)) = &lbm {
                (lbm_before, coupling_before) = (fluid.stage_seconds, forcing.coupling_seconds);
            }
        }
        dem_proc::hydro::capture_states(&world, &mut states);
        let header = ExchangeHeader { exchange: n, time: world.time, count: states.len() as u32, flags: 0 };
        if let Some((fluid, forcing)) = lbm.as_mut() {
            let started = Instant::now();
            forcing.step(fluid, &header, &states, &mut loads).expect("coupled step");
            fluid.finish_step();
            lbm_seconds += started.elapsed().as_secs_f64();
        }
        for l in &loads {
            let p = world.slot(l.id as usize);
            world.set_external_load(p, l.force, l.torque);
        }
        let started = Instant::now();
        for _ in 0..ratio {
            world.step();
        }
        dem_seconds += started.elapsed().as_secs_f64();
    }
    let per = |s: f64| s / exchanges as f64 * 1e3;
    let d = world.stage_seconds;
    let mut line = format!(
        "{{\"time\":{},\"exchanges\":{exchanges},\"dem_grains\":{},\"dem_listed_pairs\":{},\"dem_mean_coordination\":{:.3},\"dem_neighbour_builds\":{},\"ms_per_exchange\":{{\"dem\":{:.2},\"dem_kick_and_drift\":{:.2},\"dem_update_neighbours\":{:.2},\"dem_contact_forces\":{:.2},\"dem_sum_and_kick\":{:.2}",
        dem_state.time,
        world.len(),
        world.pairs.len(),
        world.mean_coordination(),
        world.neighbour_builds,
        per(dem_seconds),
        per(d.kick_and_drift - dem_before.kick_and_drift),
        per(d.update_neighbours - dem_before.update_neighbours),
        per(d.compute_contact_forces - dem_before.compute_contact_forces),
        per(d.sum_and_kick - dem_before.sum_and_kick),
    );
    if let Some((fluid, forcing)) = &lbm {
        let f = fluid.stage_seconds;
        line += &format!(
            ",\"lbm\":{:.2},\"lbm_coupling\":{:.2},\"lbm_prepare\":{:.2},\"lbm_stream_collide\":{:.2},\"lbm_update_surface\":{:.2}}},\"active_cells\":{},\"interface_cells\":{},\"forced_cells\":{}",
            per(lbm_seconds),
            per(forcing.coupling_seconds - coupling_before),
            per(f.prepare - lbm_before.prepare),
            per(f.stream_collide - lbm_before.stream_collide),
            per(f.update_surface - lbm_before.update_surface),
            fluid.active_cells(),
            fluid.interface_cells(),
            fluid.direct_forcing().len(),
        );
    } else {
        line += "}";
    }
    println!("{line}}}");
}
