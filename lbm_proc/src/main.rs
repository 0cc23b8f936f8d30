//! `lbm_proc`: runs the free-surface LBM on a scene, alone or under `coupler`.

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Instant;

use clap::{Parser, Subcommand};

use lbm_proc::bench::{bulk_mlups, bytes_per_update, triad_bandwidth};
use lbm_proc::fluid::{Collision, FluidParams};
use lbm_proc::real::Real;
use lbm_proc::run::{initial_fluid, run};
use lbm_proc::setup::LbmSetup;
use runtime::process::{exit_after_run, start_run, Reporter, RunArgs, RunOptions};
use runtime::{say, tell};
use schemas::scene::Precision;
use schemas::Scene;

#[derive(Parser)]
#[command(name = "lbm_proc", version, about = "D3Q19 free-surface lattice Boltzmann solver process")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Run a fluid scene and record it to OUT/lbm.mcap.
    Run(RunArgs),
    /// Throughput: a periodic bulk box (no free surface) against a STREAM
    /// triad measured in the same run, on 1 and 2 threads, with f32
    /// populations (BGK and TRT) and with f64 (BGK); with --scene, also
    /// STEPS steps of that scene counting only the cells updated, stored as
    /// its `lbm.precision` says.
    Bench {
        /// Bulk box cells along x, y, z.
        #[arg(long, num_args = 3, default_values_t = [128, 64, 64])]
        bulk: Vec<usize>,
        /// A fluid scene to time as well (e.g. scenes/validation/water_block.toml).
        #[arg(long)]
        scene: Option<PathBuf>,
        #[arg(long = "set", value_name = "KEY.PATH=VALUE")]
        set: Vec<String>,
        #[arg(long, default_value_t = 200)]
        steps: u64,
    },
}

fn load_scene(path: &std::path::Path, set: &[String]) -> Result<Scene, ExitCode> {
    runtime::process::load_scene("lbm_proc", path, set, no_fluids)
}

fn no_fluids(scene: &Scene) -> Option<String> {
    if scene.method() == schemas::Method::Mpm {
        return Some(
            "the scene selects the MPM (scene.method = \"mpm\"): run it with `coupler run` or mpm_proc".into(),
        );
    }
    scene.spec.fluids.is_empty().then(|| {
        "the scene has no [[fluids]] blocks; nothing for the LBM to do (grain-only scenes run in dem_proc)".into()
    })
}

fn pool(threads: usize) -> Result<rayon::ThreadPool, ExitCode> {
    rayon::ThreadPoolBuilder::new().num_threads(threads.max(1)).build().map_err(|e| {
        tell!("lbm_proc: cannot start {threads} threads: {e}");
        ExitCode::FAILURE
    })
}

fn bench(bulk: &[usize], scene: Option<&PathBuf>, set: &[String], steps: u64) -> Result<(), ExitCode> {
    let dims = [bulk[0], bulk[1], bulk[2]];
    let bytes = bytes_per_update::<f32>();
    let scene = scene.map(|p| load_scene(p, set)).transpose()?;
    let isa = runtime::isa::Isa::detected().map_err(|e| {
        tell!("lbm_proc: {e}");
        ExitCode::from(schemas::EXIT_BAD_SCENE as u8)
    })?;
    for threads in [1, 2] {
        pool(threads)?.install(|| {
            let bandwidth = triad_bandwidth(1 << 24, 5);
            let bound = bandwidth / bytes as f64 / 1e6;
            let mut line = format!(
                "{{\"threads\":{threads},\"isa\":\"{}\",\"triad_bytes_per_s\":{bandwidth:.4e},\"bytes_per_cell_update\":{bytes},\"bound_mlups\":{bound:.2}",
                isa.name()
            );
            for (name, params) in [
                ("bgk_smagorinsky", FluidParams::new(0.6)),
                ("trt_smagorinsky", FluidParams { collision: Collision::TRT_3_16, ..FluidParams::new(0.6) }),
            ] {
                let mlups = bulk_mlups::<f32>(dims, params, 20, 3);
                line += &format!(",\"bulk_{name}_mlups\":{mlups:.2},\"bulk_{name}_fraction_of_bound\":{:.3}", mlups / bound);
            }
            // The same BGK kernel with f64 populations (`lbm.precision`), beside the f32 one.
            let bound_f64 = bandwidth / bytes_per_update::<f64>() as f64 / 1e6;
            let mlups = bulk_mlups::<f64>(dims, FluidParams::new(0.6), 20, 3);
            line += &format!(
                ",\"bulk_bgk_smagorinsky_f64_mlups\":{mlups:.2},\"bulk_bgk_smagorinsky_f64_fraction_of_bound\":{:.3}",
                mlups / bound_f64
            );
            if let Some(scene) = &scene {
                match scene_mlups(scene, steps) {
                    Ok(m) => line += &format!(",\"scene\":\"{}\",\"scene_active_mlups\":{m:.2}", scene.spec.scene.name),
                    Err(e) => tell!("lbm_proc: {e}"),
                }
            }
            say!("{line}}}");
        });
    }
    Ok(())
}

/// Million updates of liquid (fluid + interface) cells per second over
/// `steps` steps of a scene, its populations stored as `lbm.precision` says.
fn scene_mlups(scene: &Scene, steps: u64) -> Result<f64, String> {
    match scene.lbm().precision {
        Precision::F32 => scene_mlups_stored_as::<f32>(scene, steps),
        Precision::F64 => scene_mlups_stored_as::<f64>(scene, steps),
    }
}

fn scene_mlups_stored_as<T: Real>(scene: &Scene, steps: u64) -> Result<f64, String> {
    let setup = LbmSetup::from_scene(scene).map_err(|e| e.to_string())?;
    let mut fluid = initial_fluid::<T>(scene, &setup).map_err(|e| e.to_string())?;
    for gate in &setup.gates {
        fluid.remove_walls(&gate.cells).map_err(|e| e.to_string())?;
    }
    let started = Instant::now();
    let mut updates = 0.0;
    let awake = runtime::process::AwakeWorkers::new();
    for _ in 0..steps {
        awake.keep_awake();
        updates += fluid.active_cells() as f64;
        fluid.step();
    }
    Ok(updates / started.elapsed().as_secs_f64() / 1e6)
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    match cli.command {
        Command::Bench { bulk, scene, set, steps } => {
            bench(&bulk, scene.as_ref(), &set, steps).err().unwrap_or(ExitCode::SUCCESS)
        }
        Command::Run(args) => {
            let (stop, scene) = match start_run("lbm_proc", &args, no_fluids) {
                Ok(started) => started,
                Err(code) => return code,
            };
            let progress_json = args.progress_json;
            let mut reporter = Reporter::new("lbm_proc", progress_json);
            let out_dir = args.out.clone().unwrap_or_else(|| PathBuf::from("runs/lbm"));
            let opts = RunOptions { out_dir, record: !args.no_record, resume: args.resume.clone() };
            let mut link = match runtime::process::link_config("lbm_proc", &args, &scene, &stop, 0) {
                Ok(None) => None,
                Ok(Some(cfg)) => {
                    tell!("lbm_proc: waiting for dem_proc on run id {} (up to {} s)", cfg.run_id, args.connect_timeout);
                    match runtime::link::LbmLink::connect(&cfg) {
                        Ok(l) => Some(l),
                        Err(runtime::link::LinkError::Interrupted) => {
                            tell!("lbm_proc: interrupted while waiting for dem_proc; nothing recorded");
                            return ExitCode::from(schemas::EXIT_INTERRUPTED as u8);
                        }
                        Err(e) => {
                            tell!("lbm_proc: error: {e}");
                            return ExitCode::FAILURE;
                        }
                    }
                }
                Err(code) => return code,
            };
            let mut replay = match args.replay_peer.as_deref().map(runtime::exchange::ReplayStates::from_recording) {
                Some(Ok(r)) => Some(r),
                Some(Err(e)) => {
                    tell!("lbm_proc: error: {e}");
                    return ExitCode::FAILURE;
                }
                None => None,
            };
            let peer = match (link.as_mut(), replay.as_mut()) {
                (Some(l), _) => Some(l as &mut dyn runtime::exchange::StatePeer),
                (None, Some(r)) => Some(r as &mut dyn runtime::exchange::StatePeer),
                (None, None) => None,
            };
            exit_after_run("lbm_proc", progress_json, run(&scene, &opts, &stop, &mut reporter, peer))
        }
    }
}
