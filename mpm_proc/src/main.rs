//! `mpm_proc`: runs the two-phase double-point MPM on a scene, alone or under `coupler`.

use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::atomic::AtomicBool;
use std::time::Instant;

use clap::{Parser, Subcommand};

use mpm_proc::run::{gravity_phase, run, Progress};
use runtime::process::{finish_run, progress_line, set_global_threads, start_run, RunArgs, RunOptions};
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

struct Reporter {
    json: bool,
    started: Instant,
}

impl Progress for Reporter {
    fn gravity_phase(&mut self, t: f64, t_max: f64) {
        if self.json {
            say!("{}", progress_line("gravity_phase", t, t_max, 0, self.started.elapsed().as_secs_f64()));
        } else {
            tell!("gravity phase: t = {t:.4} s");
        }
    }
    fn collapse(&mut self, t: f64, t_end: f64, steps: u64) {
        if self.json {
            say!("{}", progress_line("collapse", t, t_end, steps, self.started.elapsed().as_secs_f64()));
        } else {
            tell!(
                "collapse: t = {t:.4} / {t_end} s, {steps} steps, {:.1} s wall",
                self.started.elapsed().as_secs_f64()
            );
        }
    }
    fn log(&mut self, message: &str) {
        tell!("mpm_proc: {message}");
    }
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
                let mut reporter = Reporter { json: false, started: Instant::now() };
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
            let mut reporter = Reporter { json: args.progress_json, started: Instant::now() };
            let out_dir = args.out.clone().unwrap_or_else(|| PathBuf::from("runs/mpm"));
            let opts = RunOptions { out_dir, record: !args.no_record };
            match run(&scene, &opts, &stop, &mut reporter) {
                Ok(summary) => {
                    tell!(
                        "mpm_proc: {} at t = {:.4} s after {} steps in {:.1} s ({:.3e} point-updates/s); runout {:.4}",
                        summary.status,
                        summary.sim_time,
                        summary.steps,
                        summary.wall_seconds,
                        summary.throughput.point_updates_per_s.unwrap_or(0.0),
                        summary.runout
                    );
                    finish_run(args.progress_json, summary.status)
                }
                Err(e) => {
                    tell!("mpm_proc: error: {e}");
                    ExitCode::FAILURE
                }
            }
        }
    }
}
