//! `mpm_proc`: runs the two-phase double-point MPM on a scene, alone or under `coupler`.

use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::atomic::AtomicBool;
use std::time::Instant;

use clap::{Parser, Subcommand};

use mpm_proc::run::{gravity_phase, run};
use mpm_proc::setup::MpmSetup;
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
    /// Where the liquid pushes the grains: the gravity phase, every gate
    /// released at t = 0, then the liquid's force on the solid summed node by
    /// node over a window around each --at; prints per window its x- and
    /// z-parts binned by height and by distance from the back wall, split
    /// into the stress share, the implicit pore pressure and the drag, per
    /// the grains' buoyant weight (docs/mpm.md, open point 7).
    Probe {
        scene: PathBuf,
        #[arg(long = "set", value_name = "KEY.PATH=VALUE")]
        set: Vec<String>,
        /// Window centres, t/t_ref, ascending and at least --window apart.
        #[arg(long, value_delimiter = ',', default_values_t = [0.5, 1.0])]
        at: Vec<f64>,
        /// Window length, t/t_ref.
        #[arg(long, default_value_t = 0.2)]
        window: f64,
        /// Keep the gates closed: the column stays at rest, and the push is
        /// the buoyancy alone (a check of the measure).
        #[arg(long)]
        hold_gates: bool,
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

/// The bench's and the probe's start: the scene loaded and checked, the
/// worker threads set, the grid built and its gravity phase run, every gate
/// released at t = 0 unless `hold_gates`.
fn settled(
    scene: &Path,
    set: &[String],
    threads: Option<usize>,
    hold_gates: bool,
) -> Result<(Scene, MpmSetup), ExitCode> {
    let scene = runtime::process::load_scene("mpm_proc", scene, set, not_mpm)?;
    set_global_threads("mpm_proc", threads)?;
    let mut setup = mpm_proc::setup::build(&scene).map_err(|e| {
        tell!("mpm_proc: {e}");
        ExitCode::FAILURE
    })?;
    let mut reporter = Reporter::new("mpm_proc", false);
    gravity_phase(&scene, &mut setup.mpm, &AtomicBool::new(false), &mut reporter);
    if !hold_gates {
        for g in 0..setup.gates.len() {
            setup.mpm.release_gate(g);
        }
    }
    Ok((scene, setup))
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    match cli.command {
        Command::Bench { scene, set, steps, threads } => {
            let result = (|| {
                let (_, mut setup) = settled(&scene, &set, threads, false)?;
                let mpm = &mut setup.mpm;
                mpm.timing = true;
                let points = mpm.state.solid.set.len() + mpm.state.liquid.set.len();
                let started = Instant::now();
                // On a pool thread, so the stages' parallel loops start without
                // a hand-off from (and a wake-up of) the main thread each time,
                // the other workers kept awake between them.
                rayon::scope(|_| {
                    let awake = runtime::process::AwakeWorkers::new();
                    for _ in 0..steps {
                        awake.keep_awake();
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
        Command::Probe { scene, set, at, window, hold_gates, threads } => {
            let result = (|| {
                let (scene, mut setup) = settled(&scene, &set, threads, hold_gates)?;
                let fail = |e: String| {
                    tell!("mpm_proc: {e}");
                    ExitCode::FAILURE
                };
                let spec = &scene.spec;
                let (Some(grains), Some(water)) = (spec.particles.first(), spec.fluids.first()) else {
                    return Err(fail(
                        "the probe measures the liquid's push on the grains: the scene needs a [[particles]] and a \
                         [[fluids]] block (a saturated column)"
                            .into(),
                    ));
                };
                let column = [spec.analysis.column_length, spec.analysis.column_height];
                let frame = mpm_proc::probe::ProbeFrame {
                    x0: spec.domain.min[0],
                    z0: spec.domain.min[2],
                    column,
                    t_ref: scene.reference_time(),
                    buoyant_weight: (1.0 - setup.porosity_initial)
                        * (grains.density - water.density)
                        * scene.gravity_magnitude()
                        * column[0]
                        * column[1],
                };
                let mpm = &mut setup.mpm;
                let windows = rayon::scope(|_| mpm_proc::probe::probe(mpm, &frame, &at, window)).map_err(fail)?;
                let label = format!("{} at h = {:.3} mm", spec.scene.name, mpm.grid.h * 1e3);
                let pushes: Vec<_> = windows.iter().map(|(p, _)| p.clone()).collect();
                say!("{}", mpm_proc::probe::markdown(&pushes, &frame, &label));
                for (p, recorded) in &windows {
                    let summed = |d: usize| p.totals.iter().map(|t| t[d]).sum::<f64>();
                    say!(
                        "check, t/t_ref {:.2}–{:.2}: the recorder's impulse over the same steps {:+.4} / {:+.4}; \
                         the bins' totals differ from it by {:.1e} / {:.1e}",
                        p.window[0],
                        p.window[1],
                        recorded[0],
                        recorded[1],
                        summed(0) - recorded[0],
                        summed(1) - recorded[1]
                    );
                }
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
