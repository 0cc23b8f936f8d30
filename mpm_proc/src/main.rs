//! `mpm_proc`: runs the two-phase double-point MPM on a scene, alone or under `coupler`.

use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::atomic::AtomicBool;
use std::time::Instant;

use clap::{Parser, Subcommand};

use mpm_proc::run::{gravity_phase, run};
use runtime::process::{exit_after_run, set_global_threads, start_run, Reporter, RunArgs, RunOptions};
use runtime::{say, tell};
use schemas::{Method, Scene};

#[derive(Parser)]
#[command(name = "mpm_proc", version, about = "2D two-phase double-point MPM solver process (Ceccato et al. 2020)")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Run a scene (scene.method = "mpm"): gravity phase, gates, collapse; records to OUT/mpm.mcap.
    Run(RunArgs),
    /// Throughput: the gravity phase, then STEPS steps of the collapse without
    /// recording; prints one JSON line (point-updates per second, both phases).
    Bench {
        scene: PathBuf,
        #[arg(long = "set", value_name = "KEY.PATH=VALUE")]
        set: Vec<String>,
        #[arg(long, default_value_t = 5000)]
        steps: u64,
        #[arg(long)]
        threads: Option<usize>,
    },
}

fn not_mpm(scene: &Scene) -> Option<String> {
    (scene.method() != Method::Mpm).then(|| {
        "the scene does not select the MPM: set `method = \"mpm\"` in [scene], or run `coupler run --method mpm SCENE`"
            .into()
    })
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    match cli.command {
        Command::Bench { scene, set, steps, threads } => {
            let result = (|| {
                let scene = runtime::process::load_scene("mpm_proc", &scene, &set, not_mpm)?;
                set_global_threads("mpm_proc", threads)?;
                let mut setup = mpm_proc::setup::build(&scene).map_err(|e| {
                    tell!("mpm_proc: {e}");
                    ExitCode::FAILURE
                })?;
                let mut reporter = Reporter::new("mpm_proc", false);
                gravity_phase(&scene, &mut setup.mpm, &AtomicBool::new(false), &mut reporter);
                let mpm = &mut setup.mpm;
                for g in 0..setup.gates.len() {
                    mpm.release_gate(g);
                }
                mpm.timing = true;
                let points = mpm.state.solid.set.len() + mpm.state.liquid.set.len();
                let started = Instant::now();
                // On a pool thread, so the stages' parallel loops start without
                // a hand-off from (and a wake-up of) the main thread each time.
                rayon::scope(|_| {
                    for _ in 0..steps {
                        mpm.step();
                    }
                });
                let seconds = started.elapsed().as_secs_f64();
                say!(
                    "{{\"points\":{points},\"steps\":{steps},\"seconds\":{seconds},\"point_updates_per_s\":{},\"threads\":{},\"sim_time\":{},\"stage_seconds\":{}}}",
                    steps as f64 * points as f64 / seconds,
                    rayon::current_num_threads(),
                    mpm.state.time,
                    serde_json::to_string(&mpm.stage_seconds).expect("serialises")
                );
                Ok::<(), ExitCode>(())
            })();
            result.err().unwrap_or(ExitCode::SUCCESS)
        }
        Command::Run(args) => {
            let (stop, scene) = match start_run("mpm_proc", &args, not_mpm) {
                Ok(started) => started,
                Err(code) => return code,
            };
            if args.run_id.is_some() {
                tell!("mpm_proc: --run-id is for coupled DEM-LBM runs; the MPM runs alone");
                return ExitCode::from(schemas::EXIT_BAD_SCENE as u8);
            }
            let mut reporter = Reporter::new("mpm_proc", args.progress_json);
            let out_dir = args.out.clone().unwrap_or_else(|| PathBuf::from("runs/mpm"));
            let opts = RunOptions { out_dir, record: !args.no_record, resume: args.resume.clone() };
            exit_after_run("mpm_proc", args.progress_json, run(&scene, &opts, &stop, &mut reporter))
        }
    }
}
