//! A whole MPM run: the scene on the grid, the gravity phase, gates
//! released on time, the collapse to rest or the end time, recorded to
//! MCAP and summarised.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use foxglove::schemas::PointCloud;
use serde::{Deserialize, Serialize};

use crate::plan::SceneMpm;
use runtime::checkpoint::{self, CheckpointWriter};
use runtime::driver::{
    drive, Cadence, Checkpoints, Flow, FrameClock, FrameReport, Recording, RestRule, RunEnd, Solver, StepError,
};
use runtime::metrics::MpmMetrics;
use runtime::process::{Progress, RunOptions};
use runtime::record::{f32_field, identity_pose, log_level, timestamp, ChannelId, RecordError};
use schemas::measures::{deposit_profile, front_position, pile_edge, FrontSample};
use schemas::scene::{InitialStress, Scene};
use schemas::summary::{MpmDetails, RunSummary, Throughput};
use schemas::topics;

use crate::setup::{build, MpmSetup, SetupError};
use crate::solver::{LiquidImpulse, Mpm, MpmState, PointSet};

/// Version of the `/mpm/state` bincode layout (3: `MpmState::walls_released`;
/// 4: `PointSet::id`; 5: `MpmState::wall_push`).
pub const STATE_VERSION: u32 = 5;

/// Full state at a frame (`/mpm/state`): enough to continue the run bit for bit.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
pub struct MpmStateRecord {
    pub version: u32,
    pub state: MpmState,
}

/// The same record borrowing its state: the recorder encodes the solver's
/// state in place instead of copying every point array first.
#[derive(Serialize)]
struct MpmStateRecordRef<'a> {
    version: u32,
    state: &'a MpmState,
}

impl MpmStateRecordRef<'_> {
    fn encode(&self) -> Vec<u8> {
        bincode::serde::encode_to_vec(self, bincode::config::standard()).expect("state encodes")
    }
}

impl MpmStateRecord {
    pub fn encode(&self) -> Vec<u8> {
        MpmStateRecordRef { version: self.version, state: &self.state }.encode()
    }
    /// The bytes of a record of `state` at the current [`STATE_VERSION`].
    pub fn encode_state(state: &MpmState) -> Vec<u8> {
        MpmStateRecordRef { version: STATE_VERSION, state }.encode()
    }
    pub fn decode(bytes: &[u8]) -> Result<Self, String> {
        bincode::serde::decode_from_slice(bytes, bincode::config::standard()).map(|(s, _)| s).map_err(|e| e.to_string())
    }
}

#[derive(Debug, thiserror::Error)]
pub enum RunError {
    #[error(transparent)]
    Setup(#[from] SetupError),
    #[error(transparent)]
    Record(#[from] RecordError),
    #[error("the run became unstable at t = {t:.5} s: {what}. Lower mpm.courant, raise mpm.points_per_element or mpm.damping; the recording up to the last frame is kept")]
    Unstable { t: f64, what: String },
    #[error("cannot write {path}: {source}")]
    Io { path: PathBuf, source: std::io::Error },
}

/// Where `mpm_proc` writes its recording and its summary.
pub fn output_paths(out_dir: &Path) -> (PathBuf, PathBuf) {
    (out_dir.join("mpm.mcap"), out_dir.join("mpm_summary.json"))
}

/// What the gravity phase did.
#[derive(Debug, Clone, Copy, Serialize, Deserialize)]
pub struct GravityPhase {
    pub steps: u64,
    pub time: f64,
    /// Fastest point at its end, m/s.
    pub max_speed: f64,
    pub wall_seconds: f64,
}

/// Runs the damped gravity phase with the gates held (docs/mpm.md), under
/// `domain.gravity` whatever the run's (`domain.collapse_gravity`), then
/// zeroes the velocities and the clock.
pub fn gravity_phase(scene: &Scene, mpm: &mut Mpm, stop: &AtomicBool, progress: &mut dyn Progress) -> GravityPhase {
    let spec = scene.mpm();
    let started = Instant::now();
    let mut phase = GravityPhase { steps: 0, time: 0.0, max_speed: 0.0, wall_seconds: 0.0 };
    if spec.initial_stress != InitialStress::K0 || spec.gravity_phase_max_time <= 0.0 {
        return phase;
    }
    let (damping, run_gravity) = (mpm.params.damping, mpm.params.gravity);
    mpm.params.damping = spec.gravity_phase_damping;
    let g = scene.spec.domain.gravity;
    mpm.params.gravity = [g[0], g[2]];
    let check_every = ((0.002 / mpm.params.dt).round() as u64).max(1);
    let mut last_progress = Instant::now();
    let awake = runtime::process::AwakeWorkers::new();
    loop {
        awake.keep_awake();
        mpm.step();
        phase.steps += 1;
        if phase.steps.is_multiple_of(check_every) {
            let speed = mpm.state.solid.set.max_speed().max(mpm.state.liquid.set.max_speed());
            phase.max_speed = speed;

            if speed < spec.gravity_phase_rest_speed || mpm.state.time >= spec.gravity_phase_max_time {
                break;
            }
            if stop.load(Ordering::Relaxed) {
                break;
            }
            if last_progress.elapsed().as_secs_f64() > 0.5 {
                progress.phase("gravity_phase", mpm.state.time, spec.gravity_phase_max_time, phase.steps);
                last_progress = Instant::now();
            }
        }
    }
    phase.time = mpm.state.time;
    mpm.params.damping = damping;
    mpm.params.gravity = run_gravity;
    for set in [&mut mpm.state.solid.set, &mut mpm.state.liquid.set] {
        set.set_velocity([0.0; 2]);
    }
    mpm.state.time = 0.0;
    mpm.state.steps = 0;
    phase.wall_seconds = started.elapsed().as_secs_f64();
    phase
}

struct Channels {
    solid: ChannelId,
    liquid: ChannelId,
    metrics: ChannelId,
    state: ChannelId,
}

/// What the frames gather over the run for the summary.
#[derive(Default, Serialize, Deserialize)]
struct Gathered {
    #[serde(skip)]
    scratch: Vec<(f64, f64)>,
    #[serde(skip)]
    bins: Vec<f64>,
    front: Vec<FrontSample>,
    /// The pile's edge at each frame, by the DEM's rule
    /// ([`schemas::measures::pile_edge`]: the first bin of one grain
    /// diameter where the solid's equivalent height falls below a grain).
    front_pile: Vec<FrontSample>,
    liquid_front: Vec<FrontSample>,
    /// Largest kinetic energy seen, J/m.
    max_kinetic_energy: f64,
    max_fluidised: f64,
    max_pore_pressure: f64,
    peak_pore_pressure: f64,
}

/// Measures of one frame.
struct Measures {
    front: f64,
    liquid_front: f64,
    fluidised_fraction: f64,
    moving_fraction: f64,
}

fn measure(mpm: &Mpm, fraction: f64, rest_speed: f64, scratch: &mut Vec<(f64, f64)>) -> Measures {
    let s = &mpm.state.solid;
    let l = &mpm.state.liquid;
    let front = front_position(s.set.x.iter().zip(&s.set.mass).map(|(x, &m)| (x[0], m)), fraction, scratch);
    let liquid_front = front_position(l.set.x.iter().zip(&l.set.mass).map(|(x, &m)| (x[0], m)), fraction, scratch);
    let total = s.set.total_mass().max(f64::MIN_POSITIVE);
    let fluidised: f64 = s.fluidised.iter().zip(&s.set.mass).filter(|(f, _)| **f).map(|(_, m)| m).sum();
    let moving: f64 = s
        .set
        .v
        .iter()
        .zip(&s.set.mass)
        .filter(|(v, _)| v[0] * v[0] + v[1] * v[1] > rest_speed * rest_speed)
        .map(|(_, m)| m)
        .sum();
    let moving_fraction = if s.set.is_empty() {
        let lm = l.set.total_mass().max(f64::MIN_POSITIVE);
        l.set
            .v
            .iter()
            .zip(&l.set.mass)
            .filter(|(v, _)| v[0] * v[0] + v[1] * v[1] > rest_speed * rest_speed)
            .map(|(_, m)| m)
            .sum::<f64>()
            / lm
    } else {
        moving / total
    };
    Measures { front, liquid_front, fluidised_fraction: fluidised / total, moving_fraction }
}

/// Runs the scene; `stop` is polled every step and ends the run at a step
/// boundary with status `interrupted` and a complete recording.
pub fn run(
    scene: &Scene,
    opts: &RunOptions,
    stop: &AtomicBool,
    progress: &mut (dyn Progress + Send),
) -> Result<RunSummary, RunError> {
    // On a pool thread, so the stages' parallel loops start without a
    // hand-off from (and a wake-up of) the calling thread at each one: 2.5x
    // on one thread, 1.3x on two (docs/BENCHMARKS.md). The driver keeps the
    // other workers awake between the loops.
    rayon::scope(|_| run_on_pool(scene, opts, stop, progress))
}

/// The layout version of an MPM checkpoint (`MpmCheckpoint`). bincode
/// stores no field names, so a checkpoint of another layout could decode
/// into wrong numbers rather than fail: bump this whenever
/// `MpmCheckpoint` or anything it holds (`MpmState`, its point sets,
/// `Gathered`, `GravityPhase`, `LiquidImpulse`) changes its fields.
/// Version 1 is the first stored (session 46).
pub const CHECKPOINT_VERSION: u8 = 1;

/// The checkpoint's first four bytes, written as they are: "MPM" and the
/// version. Fixed-width, so that a checkpoint written before they were
/// (whose first bytes are its time's, a float) reads as one by chance
/// once in 2³² rather than once in 2⁸ as a one-byte varint would.
const CHECKPOINT_TAG: [u8; 4] = [b'M', b'P', b'M', CHECKPOINT_VERSION];

/// An MPM run's checkpoint ([`Solver::checkpoint`]): the state, what the
/// frames gathered and what the set-up measured. Written borrowing the
/// run's parts (no copy of the point arrays), read owning them.
#[derive(Serialize, Deserialize)]
struct MpmCheckpoint<S = MpmState, G = Gathered, P = GravityPhase> {
    /// [`CHECKPOINT_TAG`] when written.
    tag: [u8; 4],
    state: S,
    gathered: G,
    gravity: P,
    porosity_initial: f64,
    soil_top: f64,
    solid_mass0: f64,
    liquid_mass0: f64,
    /// The pore-pressure peak since the last frame.
    pore_pressure_peak: f64,
    /// The liquid's impulse on the solid since the last frame.
    liquid_impulse: LiquidImpulse,
}

/// Reads an MPM checkpoint, refusing one of another layout by its version.
fn read_checkpoint(path: &Path, scene: &Scene) -> Result<(checkpoint::CheckpointFile, MpmCheckpoint), RecordError> {
    let file = checkpoint::read(path, "mpm_proc", scene)?;
    Ok(decode_checkpoint(file, path)?)
}

/// The solver part of a checkpoint read from `path`: its layout version
/// first, so that another layout is named as such instead of decoding into
/// wrong numbers (or failing on a field deep inside).
fn decode_checkpoint(
    file: checkpoint::CheckpointFile,
    path: &Path,
) -> Result<(checkpoint::CheckpointFile, MpmCheckpoint), checkpoint::CheckpointError> {
    let found = match file.solver.get(..4) {
        Some(&[b'M', b'P', b'M', v]) if v == CHECKPOINT_VERSION => None,
        Some(&[b'M', b'P', b'M', v]) => Some(format!("layout version {v}")),
        _ => Some("no layout version (one written before the version was stored has none)".to_string()),
    };
    if let Some(found) = found {
        return Err(checkpoint::CheckpointError::Damaged {
            path: path.to_path_buf(),
            why: format!(
                "its MPM state has {found}, this mpm_proc resumes version {CHECKPOINT_VERSION}: resume with the \
                 mpm_proc that wrote it, or start the run again without --resume"
            ),
        });
    }
    checkpoint::decode_solver(file, path, "its MPM state")
}

/// The MPM as the run driver steps it, with what its frames and summary need.
struct MpmRun<'a> {
    scene: &'a Scene,
    mpm: Mpm,
    gates: Vec<(String, f64)>,
    channels: Option<Channels>,
    gathered: Gathered,
    gravity: GravityPhase,
    porosity_initial: f64,
    soil_top: f64,
    solid_mass0: f64,
    liquid_mass0: f64,
    points: f64,
    /// Half the fastest wave speed, m/s: a point faster has left the physics.
    speed_limit: f64,
    /// The section lies at mid-width of the flume, so it overlays a DEM–LBM run.
    mid_width: f32,
}

fn run_on_pool(
    scene: &Scene,
    opts: &RunOptions,
    stop: &AtomicBool,
    progress: &mut (dyn Progress + Send),
) -> Result<RunSummary, RunError> {
    let MpmSetup { mut mpm, gates, porosity_initial, soil_top, notes } = build(scene)?;
    for n in &notes {
        progress.log(n);
    }
    let out = &scene.spec.output;
    std::fs::create_dir_all(&opts.out_dir).map_err(|source| RunError::Io { path: opts.out_dir.clone(), source })?;
    let (mcap_path, summary_path) = output_paths(&opts.out_dir);
    let (mut rec, channels) = Recording::open(opts.record, &mcap_path, "mpm_proc", scene, 16, |b| {
        Ok(Channels {
            solid: b.channel::<PointCloud>(topics::MPM_SOLID)?,
            liquid: b.channel::<PointCloud>(topics::MPM_LIQUID)?,
            metrics: b.channel::<MpmMetrics>(topics::MPM_METRICS)?,
            state: b.state_channel(topics::MPM_STATE, "mpm_proc::run::MpmStateRecord", STATE_VERSION)?,
        })
    })?;
    if opts.resume.is_none() {
        for n in &notes {
            rec.log(0.0, log_level::INFO, n)?;
        }
    }

    let dt = mpm.params.dt;
    let cadence = Cadence {
        steps_per_frame: Cadence::steps_in(out.record_interval, dt),
        steps_per_state: Some(Cadence::steps_in(out.state_interval.unwrap_or(5.0 * out.record_interval), dt)),
        step_limit: (out.end_time / dt).ceil() as u64,
        state_at_start: true,
        steps_per_checkpoint: out.checkpoint_interval.map(|i| Cadence::steps_in(i, dt)),
    };
    let mut checkpoints = Checkpoints::default();
    if out.checkpoint_interval.is_some() {
        checkpoints.writer = Some(CheckpointWriter::new(&opts.out_dir, "mpm_proc", scene).map_err(RecordError::from)?);
    }
    let mut solver = match &opts.resume {
        Some(path) => {
            let (file, c) = read_checkpoint(path, scene)?;
            for set in [&c.state.solid.set, &c.state.liquid.set] {
                set.check_ids().map_err(|why| {
                    RecordError::from(checkpoint::CheckpointError::Damaged { path: path.to_path_buf(), why })
                })?;
            }
            mpm.state = c.state;
            mpm.apply_gate_fixities();
            mpm.restore_pore_pressure_peak(c.pore_pressure_peak);
            mpm.restore_liquid_impulse(c.liquid_impulse);
            let msg = file.resumed_line(path);
            progress.log(&msg);
            rec.log(file.driver.time, log_level::INFO, &msg)?;
            checkpoints.resumed = Some(file.driver);
            MpmRun::new(scene, mpm, gates, channels, c.gravity, c.porosity_initial, c.soil_top).with_gathered(
                c.gathered,
                c.solid_mass0,
                c.liquid_mass0,
            )
        }
        None => {
            let gravity = gravity_phase(scene, &mut mpm, stop, progress);
            if gravity.steps > 0 {
                let msg = format!(
                    "gravity phase: {} steps ({:.4} s simulated, {:.1} s wall), fastest point {:.2e} m/s at its end",
                    gravity.steps, gravity.time, gravity.wall_seconds, gravity.max_speed
                );
                progress.log(&msg);
                rec.log(0.0, log_level::INFO, &msg)?;
            }
            release_gates(&mut mpm, &gates, &mut rec)?;
            mpm.take_pore_pressure_peak(); // the gravity phase's are not the collapse's
            mpm.take_liquid_impulse();
            MpmRun::new(scene, mpm, gates, channels, gravity, porosity_initial, soil_top)
        }
    };
    let end_time = out.end_time;
    // The collapse's stage split for the summary (a few clock reads a step).
    solver.mpm.timing = true;
    let result = drive(
        &mut solver,
        None,
        &mut rec,
        cadence,
        RestRule::of(out),
        &mut checkpoints,
        stop,
        &mut |t, steps| progress.phase("collapse", t, end_time, steps),
        &summary_path,
    );
    if let Some(st) = solver.mpm.pressure_stats() {
        // Gravity phase and collapse together.
        progress.log(&format!(
            "implicit pressure: {} solves, {:.1} PCG iterations per solve (at most {}), {} above the tolerance (worst residual {:.1e}), up to {} pressured elements, {} element-steps clamped at the tension cap, {:.1} s wall in the pressure stages",
            st.solves,
            st.iterations as f64 / st.solves.max(1) as f64,
            st.max_iterations,
            st.unconverged,
            st.worst_residual,
            st.max_unknowns,
            st.clamped,
            st.seconds
        ));
    }
    result
}

impl<'a> MpmRun<'a> {
    fn new(
        scene: &'a Scene,
        mpm: Mpm,
        gates: Vec<(String, f64)>,
        channels: Option<Channels>,
        gravity: GravityPhase,
        porosity_initial: f64,
        soil_top: f64,
    ) -> Self {
        MpmRun {
            scene,
            solid_mass0: mpm.state.solid.set.total_mass(),
            liquid_mass0: mpm.state.liquid.set.total_mass(),
            points: (mpm.state.solid.set.len() + mpm.state.liquid.set.len()) as f64,
            speed_limit: 0.5 * scene.mpm_time_step().fastest_present(),
            mid_width: (0.5 * (scene.spec.domain.min[1] + scene.spec.domain.max[1])) as f32,
            mpm,
            gates,
            channels,
            gathered: Gathered::default(),
            gravity,
            porosity_initial,
            soil_top,
        }
    }

    /// A resumed run's figures, as the interrupted run had gathered them.
    fn with_gathered(mut self, gathered: Gathered, solid_mass0: f64, liquid_mass0: f64) -> Self {
        self.gathered = gathered;
        self.solid_mass0 = solid_mass0;
        self.liquid_mass0 = liquid_mass0;
        self
    }
}

impl Solver for MpmRun<'_> {
    type Error = RunError;

    fn time(&self) -> f64 {
        self.mpm.state.time
    }

    fn steps(&self) -> u64 {
        self.mpm.state.steps
    }

    fn work_per_step(&self) -> f64 {
        self.points
    }

    fn step(&mut self, rec: &mut Recording) -> Result<Flow, StepError<RunError>> {
        self.mpm.step();
        release_gates(&mut self.mpm, &self.gates, rec)?;
        Ok(Flow::Continue)
    }

    fn check(&self) -> Result<(), RunError> {
        match watchdog(&self.mpm, self.speed_limit) {
            Some(what) => Err(RunError::Unstable { t: self.mpm.state.time, what }),
            None => Ok(()),
        }
    }

    fn record_frame(&mut self, rec: &mut Recording, clock: FrameClock) -> Result<FrameReport, RunError> {
        let m = record_frame(self, rec, clock.rate)?;
        let released = self.mpm.state.gates_held.iter().all(|h| !h);
        Ok(FrameReport { moving_fraction: Some(m.moving_fraction), released })
    }

    fn record_state(&mut self, rec: &mut Recording) -> Result<(), RunError> {
        if let (Some(r), Some(ch)) = (rec.recorder(), self.channels.as_ref()) {
            r.log_bytes(ch.state, self.mpm.state.time, MpmStateRecord::encode_state(&self.mpm.state))?;
        }
        Ok(())
    }

    fn checkpoint(&self, out: &mut dyn std::io::Write) -> std::io::Result<()> {
        let c: MpmCheckpoint<&MpmState, &Gathered, &GravityPhase> = MpmCheckpoint {
            tag: CHECKPOINT_TAG,
            state: &self.mpm.state,
            gathered: &self.gathered,
            gravity: &self.gravity,
            porosity_initial: self.porosity_initial,
            soil_top: self.soil_top,
            solid_mass0: self.solid_mass0,
            liquid_mass0: self.liquid_mass0,
            pore_pressure_peak: self.mpm.pore_pressure_peak(),
            liquid_impulse: self.mpm.liquid_impulse(),
        };
        checkpoint::encode_into(&c, out)
    }

    fn summary(&mut self, end: &RunEnd) -> RunSummary {
        summary(self, end)
    }

    fn cannot_write(path: &Path, source: std::io::Error) -> RunError {
        RunError::Io { path: path.to_path_buf(), source }
    }
}

/// The run's summary: the fronts, the deposit, the MPM's details.
fn summary(r: &mut MpmRun<'_>, end: &RunEnd) -> RunSummary {
    let (scene, mpm) = (r.scene, &r.mpm);
    let an = &scene.spec.analysis;
    let x0 = scene.spec.domain.min[0];
    let (t, steps, wall) = (mpm.state.time, mpm.state.steps, end.wall);
    let s = &mpm.state.solid;
    let bin = an.deposit_bin.unwrap_or(mpm.grid.h);
    let half_z = s.set.half[1];
    let deposit = deposit_profile(
        s.set.x.iter().map(|x| (x[0], x[1] + half_z - scene.spec.domain.min[2])),
        x0,
        bin,
        ((scene.spec.domain.max[0] - x0) / bin).ceil() as usize + 1,
    );
    let g = &r.gathered;
    let runout = g.front.last().map(|f| f.x_norm).unwrap_or(f64::NAN);
    RunSummary {
        scene: scene.spec.scene.name.clone(),
        method: "mpm".into(),
        status: end.status,
        sim_time: t,
        wall_seconds: wall,
        steps,
        throughput: Throughput {
            particle_steps_per_s: None,
            cell_updates_per_s: None,
            // Over this process's steps (a resumed run's from its checkpoint).
            point_updates_per_s: Some(r.points * (steps - end.started_at.0) as f64 / wall.max(1e-9)),
            wall_per_sim_second: wall / (t - end.started_at.1).max(1e-12),
        },
        t_ref: scene.reference_time(),
        front: if s.set.is_empty() { Vec::new() } else { g.front.clone() },
        runout: if s.set.is_empty() { f64::NAN } else { runout },
        front_connected: Vec::new(),
        runout_connected: None,
        front_pile: if s.set.is_empty() { Vec::new() } else { g.front_pile.clone() },
        runout_pile: g.front_pile.last().filter(|_| !s.set.is_empty()).map(|f| f.x_norm),
        deposit: if s.set.is_empty() { Vec::new() } else { deposit },
        porosity_initial: r.porosity_initial,
        liquid_front: g.liquid_front.clone(),
        dem: None,
        lbm: None,
        mpm: Some(MpmDetails {
            elements: mpm.grid.elements,
            element_size: mpm.grid.h,
            shape_functions: format!("{:?}", mpm.grid.shape).to_lowercase(),
            solid_points: s.set.len(),
            liquid_points: mpm.state.liquid.set.len(),
            time_step: mpm.params.dt,
            gravity_phase_steps: r.gravity.steps,
            gravity_phase_time: r.gravity.time,
            gravity_phase_seconds: r.gravity.wall_seconds,
            soil_top: r.soil_top,
            solid_mass: s.set.total_mass(),
            liquid_mass: mpm.state.liquid.set.total_mass(),
            solid_mass_relative_change: rel(s.set.total_mass(), r.solid_mass0),
            liquid_mass_relative_change: rel(mpm.state.liquid.set.total_mass(), r.liquid_mass0),
            max_kinetic_energy: g.max_kinetic_energy,
            final_kinetic_energy: s.set.kinetic_energy() + mpm.state.liquid.set.kinetic_energy(),
            fluidised_fraction_max: g.max_fluidised,
            max_pore_pressure: g.max_pore_pressure,
            peak_pore_pressure: g.peak_pore_pressure,
            quadratic_drag: mpm.params.drag.quadratic,
            recording_fraction: end.recording_seconds / wall.max(1e-9),
            threads: rayon::current_num_threads(),
            stage_seconds: schemas::summary::stage_seconds_map(&mpm.stage_seconds),
        }),
        wall_seconds_total: None,
        wall_seconds_lbm: None,
        exchange: None,
    }
}

fn rel(a: f64, b: f64) -> f64 {
    if b > 0.0 {
        (a - b) / b
    } else {
        0.0
    }
}

/// A reason to stop: a non-finite value, or a point faster than half the wave speed.
fn watchdog(mpm: &Mpm, speed_limit: f64) -> Option<String> {
    for (name, set) in [("solid", &mpm.state.solid.set), ("liquid", &mpm.state.liquid.set)] {
        for (p, (x, v)) in set.x.iter().zip(&set.v).enumerate() {
            let speed = (v[0] * v[0] + v[1] * v[1]).sqrt();
            if !(x[0].is_finite() && x[1].is_finite() && speed.is_finite()) {
                let p = set.id_of(p);
                return Some(format!("{name} point {p} has a non-finite position or velocity"));
            }
            if speed > speed_limit {
                return Some(format!(
                    "{name} point {} at ({:.4}, {:.4}) m moves at {speed:.2} m/s, over half the fastest wave speed ({:.1} m/s)",
                    set.id_of(p),
                    x[0],
                    x[1],
                    2.0 * speed_limit
                ));
            }
        }
    }
    if let Some(p) = mpm.state.liquid.pressure.iter().position(|p| !p.is_finite()) {
        let p = mpm.state.liquid.set.id_of(p);
        return Some(format!("liquid point {p} has a non-finite pore pressure"));
    }
    None
}

fn release_gates(mpm: &mut Mpm, gates: &[(String, f64)], rec: &mut Recording) -> Result<(), RecordError> {
    for (g, (name, at)) in gates.iter().enumerate() {
        if mpm.state.gates_held[g] && mpm.state.time >= *at - 0.5 * mpm.params.dt {
            mpm.release_gate(g);
            rec.log(mpm.state.time, log_level::INFO, &format!("gate {name} released"))?;
        }
    }
    Ok(())
}

/// Measures one frame into the run's gathered figures and records it.
fn record_frame(r: &mut MpmRun<'_>, rec: &mut Recording, rate: f64) -> Result<Measures, RecordError> {
    let an = &r.scene.spec.analysis;
    let (t_ref, x0, l0) = (r.scene.reference_time(), r.scene.spec.domain.min[0], an.column_length);
    let y = r.mid_width;
    let peak_p = r.mpm.take_pore_pressure_peak();
    let liquid_force = r.mpm.take_liquid_impulse().mean_force();
    let solid_fraction = 1.0 - r.porosity_initial;
    let mpm = &r.mpm;
    let frames = &mut r.gathered;
    let t = mpm.state.time;
    let m = measure(mpm, an.front_mass_fraction, r.scene.spec.output.rest_speed, &mut frames.scratch);
    let norm = |x: f64| (x - x0 - l0) / l0;
    let s = &mpm.state.solid;
    let l = &mpm.state.liquid;
    if !s.set.is_empty() {
        frames.front.push(FrontSample { t, t_norm: t / t_ref, x: m.front, x_norm: norm(m.front) });
        // Per metre of width: a point's grains fill m/ρ_s of the section,
        // shared over the bins its domain spans (binned by centre, points
        // 1 mm apart in 2.5 mm bins would alternate 2 and 3 per bin).
        let (rho_s, d) = (mpm.params.solid_density, mpm.params.drag.grain_diameter);
        let grains = s.set.x.iter().zip(&s.set.mass).flat_map(|(x, &m)| spread(x[0], s.set.half[0], m / rho_s, x0, d));
        let edge = pile_edge(grains, x0, d, 1.0, solid_fraction, d, &mut frames.bins);
        frames.front_pile.push(FrontSample { t, t_norm: t / t_ref, x: edge, x_norm: norm(edge) });
    }
    if !l.set.is_empty() {
        frames.liquid_front.push(FrontSample { t, t_norm: t / t_ref, x: m.liquid_front, x_norm: norm(m.liquid_front) });
    }
    let ke = (s.set.kinetic_energy(), l.set.kinetic_energy());
    let grid_ke = mpm.grid_kinetic_energy();
    let momentum = (s.set.momentum(), l.set.momentum());
    frames.max_kinetic_energy = frames.max_kinetic_energy.max(ke.0 + ke.1);
    frames.max_fluidised = frames.max_fluidised.max(m.fluidised_fraction);
    let max_p = mpm.state.liquid.pressure.iter().cloned().fold(0.0, f64::max);
    frames.max_pore_pressure = frames.max_pore_pressure.max(max_p);
    frames.peak_pore_pressure = frames.peak_pore_pressure.max(peak_p).max(max_p);
    if let (Some(rec), Some(ch)) = (rec.recorder(), r.channels.as_ref()) {
        let solid_fields = |p: usize| {
            let sg = s.stress[p];
            let mean = (sg[0] + sg[1] + sg[3]) / 3.0;
            [speed(&s.set, p), s.porosity[p], -mean, if s.fluidised[p] { 1.0 } else { 0.0 }]
        };
        let cloud = cloud_of(&s.set, t, y, ["speed", "porosity", "mean_effective_stress", "fluidised"], solid_fields);
        rec.log(ch.solid, t, &cloud)?;
        let liquid_fields =
            |p: usize| [speed(&l.set, p), l.pressure[p], if l.free_surface[p] { 1.0 } else { 0.0 }, l.set.volume[p]];
        let cloud = cloud_of(&l.set, t, y, ["speed", "pore_pressure", "free_surface", "volume"], liquid_fields);
        rec.log(ch.liquid, t, &cloud)?;
        let metrics = MpmMetrics {
            t,
            t_norm: t / t_ref,
            front_x: m.front,
            front_norm: norm(m.front),
            liquid_front_x: m.liquid_front,
            liquid_front_norm: norm(m.liquid_front),
            kinetic_energy_solid: ke.0,
            kinetic_energy_liquid: ke.1,
            max_speed_solid: s.set.max_speed(),
            max_speed_liquid: l.set.max_speed(),
            fluidised_fraction: m.fluidised_fraction,
            max_pore_pressure: max_p,
            peak_pore_pressure: peak_p.max(max_p),
            mean_porosity: if s.set.is_empty() {
                f64::NAN
            } else {
                s.porosity.iter().sum::<f64>() / s.set.len() as f64
            },
            solid_mass: s.set.total_mass(),
            liquid_mass: l.set.total_mass(),
            point_updates_per_s: rate,
            kinetic_energy_solid_grid: grid_ke.0,
            kinetic_energy_liquid_grid: grid_ke.1,
            potential_energy_solid: s.set.potential_energy(mpm.params.gravity, mpm.grid.origin),
            potential_energy_liquid: l.set.potential_energy(mpm.params.gravity, mpm.grid.origin),
            wall_normal_load: mpm.wall_forces.normal_load,
            wall_friction_force: mpm.wall_forces.friction,
            liquid_force_on_solid_x: liquid_force[0],
            liquid_force_on_solid_z: liquid_force[1],
            momentum_solid_x: momentum.0[0],
            momentum_solid_z: momentum.0[1],
            momentum_liquid_x: momentum.1[0],
            momentum_liquid_z: momentum.1[1],
        };
        rec.log(ch.metrics, t, &metrics)?;
    }
    Ok(m)
}

/// A point's `volume` over the domain [x − half, x + half], shared among the
/// bins of width `bin` from `x0` by overlap: (the overlap's centre, its
/// share) per bin it touches. Pre: half ≥ 0, bin > 0.
fn spread(x: f64, half: f64, volume: f64, x0: f64, bin: f64) -> impl Iterator<Item = (f64, f64)> {
    debug_assert!(half.is_finite() && half >= 0.0 && bin > 0.0);
    // A point held at the back wall keeps its whole domain in front of it.
    let lo = (x - half).max(x0);
    let hi = lo + 2.0 * half;
    let first = ((lo - x0) / bin).floor() as i64;
    let shared = half > 0.0 && x.is_finite();
    // A domain ending on a bin's boundary does not reach into the next bin.
    let last = if shared { (((hi - x0) / bin).ceil() as i64 - 1).max(first) } else { first };
    (first..=last).map(move |b| {
        if !shared {
            return (x, volume);
        }
        let (a, z) = (lo.max(x0 + b as f64 * bin), hi.min(x0 + (b + 1) as f64 * bin));
        (0.5 * (a + z), volume * (z - a).max(0.0) / (2.0 * half))
    })
}

fn speed(set: &PointSet, p: usize) -> f64 {
    let v = set.v[p];
    (v[0] * v[0] + v[1] * v[1]).sqrt()
}

/// A point cloud of one phase in the world frame (x, y = mid-width, z) with four named fields.
fn cloud_of(set: &PointSet, t: f64, y: f32, names: [&str; 4], fields: impl Fn(usize) -> [f64; 4]) -> PointCloud {
    const STRIDE: usize = 28;
    let mut data = Vec::with_capacity(set.len() * STRIDE);
    // In id order, so that a point keeps its place in every frame while
    // the solver reorders its arrays.
    for p in set.by_id() {
        let x = set.x[p];
        data.extend_from_slice(&(x[0] as f32).to_le_bytes());
        data.extend_from_slice(&y.to_le_bytes());
        data.extend_from_slice(&(x[1] as f32).to_le_bytes());
        for v in fields(p) {
            data.extend_from_slice(&(v as f32).to_le_bytes());
        }
    }
    let mut fs = vec![f32_field("x", 0), f32_field("y", 4), f32_field("z", 8)];
    for (k, name) in names.iter().enumerate() {
        fs.push(f32_field(name, 12 + 4 * k as u32));
    }
    PointCloud {
        timestamp: Some(timestamp(t)),
        frame_id: "world".into(),
        pose: Some(identity_pose()),
        point_stride: STRIDE as u32,
        fields: fs,
        data: data.into(),
    }
}

#[cfg(test)]
mod pile_tests {
    use super::spread;

    #[test]
    fn a_point_is_shared_among_the_bins_its_domain_spans() {
        // Domain [0.9, 1.1] mm over 0.25 mm bins from 0: all in bin 3 and 4,
        // split at 1.0 mm, half each; the shares sum to the volume.
        let parts: Vec<(f64, f64)> = spread(1.0e-3, 0.1e-3, 6.0, 0.0, 0.25e-3).collect();
        let total: f64 = parts.iter().map(|p| p.1).sum();
        assert!((total - 6.0).abs() < 1e-12, "{parts:?}");
        let in_bin = |b: f64| parts.iter().filter(|p| (p.0 / 0.25e-3).floor() == b).map(|p| p.1).sum::<f64>();
        assert!((in_bin(3.0) - 3.0).abs() < 1e-9 && (in_bin(4.0) - 3.0).abs() < 1e-9, "{parts:?}");
        // Inside one bin: one share, whole.
        let one: Vec<(f64, f64)> = spread(0.6e-3, 0.05e-3, 2.0, 0.0, 0.25e-3).collect();
        assert_eq!(one.len(), 1);
        assert!((one[0].1 - 2.0).abs() < 1e-12);
        // A regular row of points 1 mm apart with 1 mm domains fills 2.5 mm
        // bins evenly (by centre they would hold 2 and 3 points); a domain
        // ending on a bin's boundary gives that bin nothing, not a share of 0
        // beyond it.
        let mut bins = [0.0; 4];
        for i in 0..10 {
            for (x, v) in spread((i as f64 + 0.5) * 1e-3, 0.5e-3, 1.0, 0.0, 2.5e-3) {
                bins[(x / 2.5e-3) as usize] += v;
            }
        }
        assert!(bins.iter().all(|b| (b - 2.5).abs() < 1e-9), "{bins:?}");
        // No domain: the point whole, where it is; not finite: one share, which
        // `pile_edge` skips.
        assert_eq!(spread(1.3e-3, 0.0, 2.0, 0.0, 1e-3).collect::<Vec<_>>(), [(1.3e-3, 2.0)]);
        assert_eq!(spread(f64::NAN, 0.1e-3, 2.0, 0.0, 1e-3).count(), 1);
        // A point clamped to the back wall: its domain lies in front of it.
        let held: Vec<(f64, f64)> = spread(0.0, 0.5e-3, 1.0, 0.0, 2.5e-3).collect();
        assert_eq!(held.len(), 1);
        assert!((held[0].0 - 0.5e-3).abs() < 1e-15 && (held[0].1 - 1.0).abs() < 1e-12, "{held:?}");
    }
}

#[cfg(test)]
mod checkpoint_tests {
    use super::{decode_checkpoint, CHECKPOINT_VERSION};
    use runtime::checkpoint::{CheckpointFile, DriverState};
    use std::path::Path;

    fn file(solver: Vec<u8>) -> CheckpointFile {
        let driver = DriverState {
            steps: 10,
            time: 0.01,
            last_recorded: 0,
            last_state: None,
            frames_at_rest: 0,
            has_moved: false,
        };
        CheckpointFile { process: "mpm_proc".into(), scene_hash: 1, driver, exchange: None, solver }
    }

    fn refusal(solver: Vec<u8>) -> String {
        match decode_checkpoint(file(solver), Path::new("c.ckpt")) {
            Ok(_) => panic!("a checkpoint of another layout must be refused"),
            Err(e) => e.to_string(),
        }
    }

    #[test]
    fn a_checkpoint_of_another_layout_is_refused_by_its_version() {
        let tagged = |v: u8, rest: &[u8]| [&[b'M', b'P', b'M', v][..], rest].concat();
        // Another version, whatever follows it: named, with the way out.
        let why = refusal(tagged(CHECKPOINT_VERSION + 1, &[0u8; 64]));
        assert!(why.contains(&format!("layout version {}", CHECKPOINT_VERSION + 1)), "{why}");
        assert!(why.contains(&format!("resumes version {CHECKPOINT_VERSION}")), "{why}");
        assert!(why.contains("without --resume"), "{why}");
        // Written before the tag: its first bytes are a float's.
        let old = bincode::serde::encode_to_vec(0.0123_f64, bincode::config::standard()).expect("encodes");
        assert!(refusal(old).contains("no layout version"));
        assert!(refusal(Vec::new()).contains("no layout version"));
        // This version with a state cut short: the decoder's own refusal.
        let why = refusal(tagged(CHECKPOINT_VERSION, &[1, 2, 3]));
        assert!(why.contains("does not decode"), "{why}");
    }
}
