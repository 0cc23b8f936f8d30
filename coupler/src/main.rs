//! `coupler`: one command to check, run, supervise and inspect a scene.

mod campaign;
mod check;
mod export;
mod inspect;
mod merge;
mod supervise;

use std::path::PathBuf;
use std::process::ExitCode;

use clap::{Parser, Subcommand};

use schemas::{Scene, EXIT_BAD_SCENE};

/// The scene `coupler run` uses when none is given.
pub const DEFAULT_SCENE: &str = "scenes/ceccato2020/dry_h060.toml";

#[derive(Parser)]
#[command(
    name = "coupler",
    version,
    about = "Runs saturated granular flow scenes (DEM, LBM, MPM) and records them to MCAP"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Validate a scene, start the solver processes it needs, and record the run.
    Run {
        /// Scene file (TOML). Default: the dry H0 = 0.06 m column of Ceccato et al. 2020.
        scene: Option<PathBuf>,
        /// Output directory (default: `runs/<scene name>`).
        #[arg(long)]
        out: Option<PathBuf>,
        /// Override a scene value, validated like the file (repeatable): --set output.end_time=0.2
        #[arg(long = "set", value_name = "KEY.PATH=VALUE")]
        set: Vec<String>,
        /// Run the scene with this method: `--set scene.method=…`, applied before the other --set values.
        #[arg(long, value_parser = METHODS)]
        method: Option<String>,
        /// Worker threads per solver process (default: all cores).
        #[arg(long)]
        threads: Option<usize>,
        /// Plain progress lines instead of a progress bar.
        #[arg(long)]
        quiet: bool,
        /// Continue the run in DIR (killed, interrupted or failed) from the
        /// last checkpoint all its processes wrote (`output.checkpoint_interval`),
        /// under its `DIR/scene.toml`; `--set` may change only `output.*`
        /// (run longer, record differently). The recording is continued:
        /// `DIR/run.mcap` ends as the uninterrupted run's would.
        #[arg(long, value_name = "DIR", conflicts_with_all = ["scene", "out", "method"])]
        resume: Option<PathBuf>,
    },
    /// Print what a run of the scene would be, without running it.
    Check {
        #[arg(default_value = DEFAULT_SCENE)]
        scene: PathBuf,
        #[arg(long = "set", value_name = "KEY.PATH=VALUE")]
        set: Vec<String>,
        /// Check the scene as run with this method: `--set scene.method=…`, applied before the other --set values.
        #[arg(long, value_parser = METHODS)]
        method: Option<String>,
    },
    /// Run a campaign: every case of a campaign file (e.g. the paper's
    /// Table 1 matrix, `scenes/ceccato2020`), each a normal run in
    /// `OUT/cases/<name>`, then `OUT/report.md` with figures. Resumable:
    /// the same command again skips finished cases and continues stopped ones.
    Campaign {
        /// A campaign file, or a folder holding `campaign.toml`.
        campaign: PathBuf,
        /// The coarse version of the same matrix (the file's `[quick]`
        /// overrides): minutes instead of hours, to check the whole chain.
        #[arg(long)]
        quick: bool,
        /// Output directory (default: `runs/campaign-<name>[-quick]`).
        #[arg(long)]
        out: Option<PathBuf>,
        /// Cases run at once, the cores shared evenly among them
        /// (default: one case per core).
        #[arg(long, value_name = "N", value_parser = clap::value_parser!(u16).range(1..))]
        jobs: Option<u16>,
        /// Validate the campaign file and every case's scene, print the
        /// cases and what is already finished, and run nothing.
        #[arg(long)]
        check: bool,
    },
    /// Write a recording's points as VTK files for ParaView: grains,
    /// the water's surface, MPM points, each a time series (`.pvd`).
    Export {
        /// A run directory or its run.mcap.
        run: PathBuf,
        /// VTK XML unstructured grids (`.vtu`) with a `.pvd` per series: the only format so far.
        #[arg(long)]
        vtk: bool,
        /// Every K-th frame of each series.
        #[arg(long, default_value_t = 1, value_name = "K")]
        every: usize,
        /// Output directory (default: `vtk/` beside the recording).
        #[arg(long)]
        out: Option<PathBuf>,
    },
    /// Summarise a recording: topics, message counts, time span, and the run
    /// summary; what a cut or damaged file still holds (exit status 1 when a
    /// finished file no longer reads as recorded).
    Inspect {
        /// A run.mcap written by `coupler run`.
        recording: PathBuf,
    },
}

/// The values of `--method`: the names `scene.method` takes.
const METHODS: [&str; 4] = ["dem", "lbm", "dem_lbm", "mpm"];

/// `--method M` as the first override, then the `--set` values in order.
fn overrides(method: Option<String>, set: Vec<String>) -> Vec<String> {
    method.map(|m| format!("scene.method=\"{m}\"")).into_iter().chain(set).collect()
}

fn load(scene: &std::path::Path, set: &[String]) -> Result<Scene, ExitCode> {
    let bad = |e: schemas::SceneError| {
        eprintln!("coupler: invalid scene {}:\n{e}", scene.display());
        ExitCode::from(EXIT_BAD_SCENE as u8)
    };
    let loaded = Scene::load(scene, set).map_err(bad)?;
    // What a solver refuses beyond the vocabulary's checks, before any
    // process starts: the same words the solver would exit with.
    if matches!(loaded.method(), schemas::Method::DemDry | schemas::Method::DemLbm) {
        dem_proc::setup::check_scene(&loaded).map_err(bad)?;
    }
    Ok(loaded)
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    match cli.command {
        Command::Run { scene, out, set, method, threads, quiet, resume } => {
            let scene = match &resume {
                Some(dir) => dir.join("scene.toml"),
                None => scene.unwrap_or_else(|| PathBuf::from(DEFAULT_SCENE)),
            };
            if resume.is_some() && !scene.exists() {
                eprintln!(
                    "coupler: {} does not exist: --resume takes the output directory of a run started by `coupler run`",
                    scene.display()
                );
                return ExitCode::FAILURE;
            }
            let loaded = match load(&scene, &overrides(method, set)) {
                Ok(s) => s,
                Err(code) => return code,
            };
            let out = resume.clone().or(out).unwrap_or_else(|| PathBuf::from("runs").join(&loaded.spec.scene.name));
            let runtime = match tokio::runtime::Builder::new_multi_thread().worker_threads(1).enable_all().build() {
                Ok(r) => r,
                Err(e) => {
                    eprintln!("coupler: cannot start the async runtime: {e}");
                    return ExitCode::FAILURE;
                }
            };
            runtime.block_on(supervise::run(loaded, out, threads, quiet, resume.is_some()))
        }
        Command::Campaign { campaign: source, quick, out, jobs, check } => {
            let command_line =
                std::iter::once("coupler".to_string()).chain(std::env::args().skip(1)).collect::<Vec<_>>().join(" ");
            let args = campaign::Args { source, quick, out, jobs: jobs.map(usize::from) };
            if check {
                campaign::check(&args)
            } else {
                campaign::run(args, command_line)
            }
        }
        Command::Check { scene, set, method } => match load(&scene, &overrides(method, set)) {
            Ok(s) => {
                check::print(&s);
                ExitCode::SUCCESS
            }
            Err(code) => code,
        },
        Command::Export { run, vtk, every, out } => {
            if !vtk {
                eprintln!("coupler: export needs a format: --vtk (VTK files for ParaView) is the one there is");
                return ExitCode::from(EXIT_BAD_SCENE as u8);
            }
            let recording = if run.is_dir() { run.join("run.mcap") } else { run };
            let out = out.unwrap_or_else(|| recording.parent().unwrap_or(std::path::Path::new(".")).join("vtk"));
            match export::export_vtk(&recording, &out, every) {
                Ok(e) if e.series.is_empty() => {
                    eprintln!("coupler: {} holds no points to export", recording.display());
                    ExitCode::FAILURE
                }
                Ok(e) => {
                    for (name, frames) in &e.series {
                        println!("{name:<16} {frames} frames: {}", out.join(format!("{name}.pvd")).display());
                    }
                    ExitCode::SUCCESS
                }
                Err(e) => {
                    eprintln!("coupler: {e}");
                    ExitCode::FAILURE
                }
            }
        }
        Command::Inspect { recording } => match inspect::inspect(&recording) {
            Ok(false) => ExitCode::SUCCESS,
            Ok(true) => {
                eprintln!(
                    "coupler: {} is damaged (see 'damaged' above); what is readable can still be read by streaming MCAP readers",
                    recording.display()
                );
                ExitCode::FAILURE
            }
            Err(e) => {
                eprintln!("coupler: {e}");
                ExitCode::FAILURE
            }
        },
    }
}
