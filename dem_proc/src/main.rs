//! `dem_proc`: runs the DEM on a scene, alone or under `coupler`.

use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::atomic::AtomicBool;
use std::time::Instant;

use clap::{Parser, Subcommand};

use dem_proc::biaxial::BiaxialSpec;
use dem_proc::run::{run, RunError};
use runtime::process::{exit_after_run, set_global_threads, start_run, Reporter, RunArgs, RunOptions};
use runtime::{say, tell};
use schemas::{Scene, EXIT_INTERRUPTED};

/// The biaxial test warns when its lateral wall strays further than this
/// from the confining stress (mean over the last quarter of the shear);
/// at the default inertial number it stays within 4–7 % on the lab grains.
const LATERAL_STRESS_TOLERANCE: f64 = 0.1;

#[derive(Parser)]
#[command(name = "dem_proc", version, about = "3D DEM solver process (spheres, Ceccato et al. 2020 contact law)")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Run a scene: deposit (or load) the packing, open the gates, record to OUT/dem.mcap.
    Run(RunArgs),
    /// Throughput of the collapse: deposit (or load) the packing, open the
    /// gates, time STEPS steps without recording; prints one JSON line.
    Bench {
        scene: PathBuf,
        #[arg(long = "set", value_name = "KEY.PATH=VALUE")]
        set: Vec<String>,
        #[arg(long, default_value_t = 20000)]
        steps: u64,
        #[arg(long)]
        threads: Option<usize>,
    },
    /// Plane-strain biaxial test of the scene's grains and contact law
    /// (docs/dem.md, "Element test"): prints the measured friction and
    /// dilatancy angles as one JSON line and writes every sample to OUT.
    Biaxial {
        scene: PathBuf,
        #[arg(long = "set", value_name = "KEY.PATH=VALUE")]
        set: Vec<String>,
        /// JSON file for the record (settings, samples, summary).
        #[arg(long)]
        out: PathBuf,
        /// σ_3, Pa.
        #[arg(long, default_value_t = BiaxialSpec::default().confining_stress)]
        confining_stress: f64,
        /// I = ε̇ D / √(σ_3/ρ_s).
        #[arg(long, default_value_t = BiaxialSpec::default().inertial_number)]
        inertial_number: f64,
        #[arg(long, default_value_t = BiaxialSpec::default().max_axial_strain)]
        max_axial_strain: f64,
        /// Grains along x, y, z on the starting lattice.
        #[arg(long, value_delimiter = ',', default_values_t = BiaxialSpec::default().lattice)]
        lattice: Vec<usize>,
        /// Grain sliding friction while compressing (default: the scene's
        /// deposition friction; 0.1 gives the lab column's core porosity).
        #[arg(long)]
        preparation_friction: Option<f64>,
        #[arg(long, default_value_t = BiaxialSpec::default().seed)]
        seed: u64,
        #[arg(long)]
        threads: Option<usize>,
    },
    /// Write the scene's packing and contact law as a LAMMPS data file and
    /// input (gran/hooke/history), for the side-by-side benchmark.
    ExportLammps {
        scene: PathBuf,
        #[arg(long = "set", value_name = "KEY.PATH=VALUE")]
        set: Vec<String>,
        /// Directory for `packing.data` and `in.collapse`.
        #[arg(long)]
        out: PathBuf,
        /// Steps the LAMMPS input runs.
        #[arg(long, default_value_t = 20000)]
        steps: u64,
        /// Write LAMMPS's `pair_style granular` with its `rolling sds` model
        /// (μ_roll = the scene's rolling friction) instead of
        /// gran/hooke/history, which has no rolling resistance.
        #[arg(long)]
        rolling: bool,
    },
}

fn load_scene(path: &std::path::Path, set: &[String]) -> Result<Scene, ExitCode> {
    runtime::process::load_scene("dem_proc", path, set, no_particles)
}

fn no_particles(scene: &Scene) -> Option<String> {
    dem_proc::setup::check_scene(scene).err().map(|e| e.to_string())
}

/// The packing of a scene and the world ready to collapse.
fn collapse_world(scene: &Scene) -> Result<dem_proc::world::World, ExitCode> {
    use dem_proc::{packing, setup};
    let s = setup::DemSetup::from_scene(scene);
    let p =
        packing::build(scene, &s, &AtomicBool::new(false), |t, _| tell!("deposition: t = {t:.4} s")).map_err(|e| {
            tell!("dem_proc: error: {e}");
            ExitCode::FAILURE
        })?;
    Ok(dem_proc::run::collapse_world(scene, &s, &p))
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    match cli.command {
        Command::Bench { scene, set, steps, threads } => {
            let result = (|| {
                let scene = load_scene(&scene, &set)?;
                set_global_threads("dem_proc", threads)?;
                let mut w = collapse_world(&scene)?;
                let started = Instant::now();
                let awake = runtime::process::AwakeWorkers::new();
                for _ in 0..steps {
                    awake.keep_awake();
                    w.step();
                }
                let seconds = started.elapsed().as_secs_f64();
                say!(
                    "{{\"particles\":{},\"steps\":{steps},\"seconds\":{seconds},\"particle_steps_per_s\":{},\"threads\":{},\"neighbour_builds\":{},\"pairs\":{},\"sim_time\":{},\"stage_seconds\":{}}}",
                    w.len(),
                    steps as f64 * w.len() as f64 / seconds,
                    rayon::current_num_threads(),
                    w.neighbour_builds,
                    w.pairs.len(),
                    w.time,
                    serde_json::to_string(&w.stage_seconds).expect("serialises")
                );
                Ok::<(), ExitCode>(())
            })();
            result.err().unwrap_or(ExitCode::SUCCESS)
        }
        Command::Biaxial {
            scene,
            set,
            out,
            confining_stress,
            inertial_number,
            max_axial_strain,
            lattice,
            preparation_friction,
            seed,
            threads,
        } => {
            let result = (|| {
                let scene = load_scene(&scene, &set)?;
                set_global_threads("dem_proc", threads)?;
                let [nx, ny, nz] = lattice[..] else {
                    tell!("dem_proc: --lattice takes three counts, NX,NY,NZ; got {lattice:?}");
                    return Err(ExitCode::FAILURE);
                };
                let stop = runtime::process::stop_flag().map_err(|e| {
                    tell!("dem_proc: cannot install signal handler: {e}");
                    ExitCode::FAILURE
                })?;
                let spec = BiaxialSpec {
                    lattice: [nx, ny, nz],
                    confining_stress,
                    inertial_number,
                    max_axial_strain,
                    preparation_friction,
                    seed,
                    ..BiaxialSpec::default()
                };
                let started = Instant::now();
                let mut last_report = started;
                let record = dem_proc::biaxial::run(&scene, &spec, &stop, |phase, x| {
                    if last_report.elapsed().as_secs_f64() < 2.0 {
                        return;
                    }
                    last_report = Instant::now();
                    match phase {
                        "shear" => tell!("biaxial: shear, axial strain {x:.3}"),
                        _ => tell!("biaxial: {phase}, walls {:.1} % off the confining stress", 100.0 * x),
                    }
                })
                .map_err(|e| {
                    tell!("dem_proc: error: {e}");
                    if matches!(e, dem_proc::biaxial::BiaxialError::Interrupted) {
                        ExitCode::from(EXIT_INTERRUPTED as u8)
                    } else {
                        ExitCode::FAILURE
                    }
                })?;
                let text = serde_json::to_string_pretty(&record).expect("serialises");
                std::fs::write(&out, text).map_err(|e| {
                    tell!("dem_proc: cannot write {}: {e}", out.display());
                    ExitCode::FAILURE
                })?;
                let lateral_error = record.summary.final_lateral_stress_error;
                if lateral_error.is_nan() {
                    tell!("dem_proc: warning: no sample in the last quarter of the shear: the lateral stress and the final friction are not measured; raise --max-axial-strain");
                } else if lateral_error > LATERAL_STRESS_TOLERANCE {
                    tell!(
                        "dem_proc: warning: the lateral wall held sigma_3 only to {:.0} % over the last quarter of the shear: the test was not stress-controlled there and its friction is not the soil's at this inertial number; lower --inertial-number (on the lab grains it holds at the default 1e-3, not at 3e-3)",
                        100.0 * lateral_error
                    );
                }
                let mut summary = serde_json::to_value(&record.summary).expect("serialises");
                summary["seconds"] = started.elapsed().as_secs_f64().into();
                say!("{summary}");
                Ok::<(), ExitCode>(())
            })();
            result.err().unwrap_or(ExitCode::SUCCESS)
        }
        Command::ExportLammps { scene, set, out, steps, rolling } => {
            let result = (|| {
                let scene = load_scene(&scene, &set)?;
                let w = collapse_world(&scene)?;
                let setup = dem_proc::setup::DemSetup::from_scene(&scene);
                std::fs::create_dir_all(&out).map_err(|e| {
                    tell!("dem_proc: cannot create {}: {e}", out.display());
                    ExitCode::FAILURE
                })?;
                let data = dem_proc::lammps::data_file(&w.grains, setup.domain);
                let input = dem_proc::lammps::input_file(
                    &scene,
                    &setup,
                    &w.grains,
                    "packing.data",
                    steps,
                    "final.dump",
                    rolling,
                );
                for (name, text) in [("packing.data", data), ("in.collapse", input)] {
                    std::fs::write(out.join(name), text).map_err(|e| {
                        tell!("dem_proc: cannot write {name}: {e}");
                        ExitCode::FAILURE
                    })?;
                }
                tell!("dem_proc: wrote {}/packing.data and in.collapse ({} grains)", out.display(), w.len());
                Ok::<(), ExitCode>(())
            })();
            result.err().unwrap_or(ExitCode::SUCCESS)
        }
        Command::Run(args) => {
            let (stop, scene) = match start_run("dem_proc", &args, no_particles) {
                Ok(started) => started,
                Err(code) => return code,
            };
            let progress_json = args.progress_json;
            let mut reporter = Reporter::new("dem_proc", progress_json);
            let out_dir = args.out.clone().unwrap_or_else(|| PathBuf::from("runs/dem"));
            let opts = RunOptions { out_dir, record: !args.no_record, resume: args.resume.clone() };
            // Coupled: connect once the packing has its grain count.
            let link = match runtime::process::link_config("dem_proc", &args, &scene, &stop, 0) {
                Ok(l) => l,
                Err(code) => return code,
            };
            let replay = args.replay_peer.clone().map(|path| {
                Box::new(move |_grains: usize| {
                    let peer = runtime::exchange::ReplayLoads::from_recording(&path)?;
                    Ok(Box::new(peer) as Box<dyn runtime::exchange::LoadPeer>)
                }) as dem_proc::hydro::Connect
            });
            let connect: Option<dem_proc::hydro::Connect> = replay.or_else(|| {
                link.map(|cfg| {
                    Box::new(move |grains: usize| {
                        let cfg = runtime::link::LinkConfig { particles: grains, ..cfg };
                        let link = runtime::link::DemLink::connect(&cfg)?;
                        Ok(Box::new(link) as Box<dyn runtime::exchange::LoadPeer>)
                    }) as dem_proc::hydro::Connect
                })
            });
            match run(&scene, &opts, &stop, &mut reporter, connect) {
                Err(RunError::Packing(dem_proc::packing::PackingError::Interrupted)) => {
                    tell!("dem_proc: interrupted during deposition; nothing recorded");
                    ExitCode::from(EXIT_INTERRUPTED as u8)
                }
                result => exit_after_run("dem_proc", progress_json, result),
            }
        }
    }
}
