//! A whole fluid-only run: the scene on the lattice, gates released on time,
//! the free-surface flow to the end time, recorded to MCAP, summarised.

use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicBool;

use foxglove::schemas::{Grid, PointCloud, Pose, Quaternion, Vector2, Vector3};
use serde::{Deserialize, Serialize};

use runtime::checkpoint::{self, CheckpointFile, CheckpointWriter};
use runtime::coupled::{Coupled, Exchange, ExchangeFailure, Side};
use runtime::driver::{
    drive, Cadence, Checkpoints, Flow, FrameClock, FrameReport, Recording, RestRule, RunEnd, Solver, StepError,
    StepExchange,
};
use runtime::exchange::{ExchangeHeader, HydroLoad, ParticleState, StatePeer};
use runtime::metrics::{CouplingTimings, LbmMetrics};
use runtime::process::{Progress, RunOptions};
use runtime::record::{f32_field, identity_pose, log_level, timestamp, ChannelId, Payload, RecordError};
use schemas::measures::{front_position, FrontSample};
use schemas::scene::{Precision, Scene};
use schemas::summary::{ExchangeDetails, ExchangeSummary, LbmDetails, RunSummary, Throughput};
use schemas::topics;

use crate::coupling::{Coupling, CouplingError, HeldLiquid};
use crate::fluid::{flags, Fluid, FluidState, ForcingMemory, Sample};
use crate::grains::GrainForcing;
use crate::lattice::CS2;
use crate::real::Real;
use crate::setup::{LbmSetup, SetupError};
use crate::watchdog::Instability;

/// Version of the `/lbm/state` bincode layout: 2 stores the liquid cells
/// only (`fluid/stored.rs`); version 1 (every cell) is still read.
pub const STATE_VERSION: u32 = 2;

/// Full state, enough to continue a fluid-only run bit for bit
/// (`/lbm/state`); a coupled run's checkpoint adds the forcing memory.
/// `T` is the populations' storage (`lbm.precision`).
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(bound(serialize = "T: Real", deserialize = "T: Real"))]
pub struct LbmState<T = f32> {
    pub version: u32,
    /// Simulated time since the start of the run, s.
    pub time: f64,
    /// Which gates (in scene order) have been removed.
    pub gates_removed: Vec<bool>,
    pub fluid: FluidState<T>,
}

/// The type `/lbm/state` names in its channel's `encoding` metadata for
/// populations stored as `T`: the f32 name is the one recordings have
/// always had.
pub fn state_schema_name<T: Real>() -> String {
    match std::any::type_name::<T>() {
        "f32" => "lbm_proc::run::LbmState".to_string(),
        other => format!("lbm_proc::run::LbmState<{other}>"),
    }
}

impl<T: Real> LbmState<T> {
    /// This version's layout, whatever layout the state was read from.
    pub fn encode(&self) -> Vec<u8> {
        let state = LbmStateRef {
            version: STATE_VERSION,
            time: self.time,
            gates_removed: &self.gates_removed,
            fluid: &self.fluid,
        };
        bincode::serde::encode_to_vec(&state, bincode::config::standard()).expect("state encodes")
    }

    /// Decodes a state whose populations are stored as `T`, of this layout
    /// or version 1's.
    pub fn from_bytes(bytes: &[u8]) -> Result<Self, String> {
        let config = bincode::config::standard();
        let (version, _) = bincode::serde::decode_from_slice::<u32, _>(bytes, config).map_err(|e| e.to_string())?;
        match version {
            1 => {
                #[derive(Deserialize)]
                struct V1<T> {
                    version: u32,
                    time: f64,
                    gates_removed: Vec<bool>,
                    fluid: crate::fluid::DenseV1<T>,
                }
                let (v, _) = bincode::serde::decode_from_slice::<V1<T>, _>(bytes, config).map_err(|e| e.to_string())?;
                Ok(LbmState { version: v.version, time: v.time, gates_removed: v.gates_removed, fluid: v.fluid.try_into()? })
            }
            STATE_VERSION => bincode::serde::decode_from_slice(bytes, config).map(|(s, _)| s).map_err(|e| e.to_string()),
            other => Err(format!(
                "/lbm/state version {other} is not one this lbm_proc reads (1 and {STATE_VERSION}): read it with the version that wrote it"
            )),
        }
    }

    /// The last `/lbm/state` of a recording and its log time (ns), reading
    /// up to the first damaged record (a recording whose writer died). A
    /// recording whose lattice is stored in another precision is refused
    /// by its schema name.
    pub fn last_of_recording(mcap_bytes: &[u8]) -> Result<(u64, Self), String> {
        let stream = mcap::MessageStream::new_with_options(mcap_bytes, mcap::read::Options::IgnoreEndMagic.into())
            .map_err(|e| format!("not an MCAP recording: {e}"))?;
        let mut last = None;
        for m in stream {
            let Ok(m) = m else { break };
            if m.channel.topic == schemas::topics::LBM_STATE {
                // The channel's `encoding` metadata names the type (`Recording::state_channel`).
                let encoding = m.channel.metadata.get("encoding").map(String::as_str).unwrap_or_default();
                let wanted = state_schema_name::<T>();
                if !encoding.contains(&format!(" of {wanted} version ")) {
                    return Err(format!(
                        "the recording's /lbm/state is {encoding:?}, not {wanted:?}: its lattice was stored in \
                         another lbm.precision; read it as that"
                    ));
                }
                last = Some((m.log_time, Self::from_bytes(&m.data)?));
            }
        }
        last.ok_or_else(|| "the recording holds no /lbm/state".to_string())
    }
}

impl LbmState<f32> {
    /// [`LbmState::from_bytes`] for the default f32 lattice.
    pub fn decode(bytes: &[u8]) -> Result<Self, String> {
        Self::from_bytes(bytes)
    }

    /// [`LbmState::last_of_recording`] for the default f32 lattice.
    pub fn last_in_recording(mcap_bytes: &[u8]) -> Result<(u64, Self), String> {
        Self::last_of_recording(mcap_bytes)
    }
}

#[derive(Debug, thiserror::Error)]
pub enum RunError {
    #[error(transparent)]
    Setup(#[from] SetupError),
    #[error(transparent)]
    Record(#[from] RecordError),
    #[error("the flow became unstable at t = {t:.5} s: {instability}. The recording up to the last frame is kept")]
    Unstable { t: f64, instability: Box<Instability> },
    #[error("cannot build the lattice: {0}")]
    Lattice(String),
    #[error("grain coupling at exchange {exchange}: {source}")]
    Coupling { exchange: u64, source: CouplingError },
    #[error("exchange with dem_proc failed at step {exchange}: {source}")]
    Peer { exchange: u64, source: runtime::exchange::PeerError },
    #[error("cannot write {path}: {source}")]
    Io { path: PathBuf, source: std::io::Error },
}

/// Where `lbm_proc` writes its recording and its summary.
pub fn output_paths(out_dir: &Path) -> (PathBuf, PathBuf) {
    (out_dir.join("lbm.mcap"), out_dir.join("lbm_summary.json"))
}

struct Channels {
    surface: ChannelId,
    slice: ChannelId,
    metrics: ChannelId,
    state: ChannelId,
    /// `/lbm/received_states` (`output.record_exchange` in a coupled run).
    received: Option<ChannelId>,
    /// `/lbm/coupling` (coupled runs).
    coupling: Option<ChannelId>,
}

/// What the frames gather over the run for the summary.
#[derive(Default, Serialize, Deserialize)]
struct Gathered {
    #[serde(skip)]
    scratch: Vec<(f64, f64)>,
    front: Vec<FrontSample>,
    max_mach: f64,
}

/// The run's lattice, ready to step: walls, gates, the initial liquid at hydrostatic density.
pub fn initial_fluid<T: Real>(scene: &Scene, setup: &LbmSetup) -> Result<Fluid<T>, RunError> {
    // A box of gas: only the cells the liquid and the gates take are written.
    let mut fluid =
        Fluid::<T>::empty(setup.dims, setup.faces, setup.params).map_err(|e| RunError::Lattice(e.to_string()))?;
    for gate in &setup.gates {
        for &c in &gate.cells {
            fluid.set_flag(c, flags::WALL).map_err(|e| RunError::Lattice(e.to_string()))?;
        }
    }
    fluid.init_liquid(|c| setup.starts_liquid(scene, c)).map_err(|e| RunError::Lattice(e.to_string()))?;
    Ok(fluid)
}

/// A run's lattice, its initial liquid mass and active cells: the scene's
/// initial liquid, or the checkpoint's lattice (moved out of it: a copy
/// would double the memory) with the rest of the checkpoint.
type Lattice<T> = (Fluid<T>, f64, usize, Option<(CheckpointFile, LbmCheckpoint<LbmState<T>>)>);

fn lattice<T: Real>(scene: &Scene, setup: &LbmSetup, resume: Option<&Path>) -> Result<Lattice<T>, RunError> {
    match resume {
        Some(path) => {
            let (file, mut c) = read_checkpoint(path, scene)?;
            let state = std::mem::replace(&mut c.state.fluid, empty_fluid_state());
            let mut fluid = Fluid::from_state(state, setup.params).map_err(|e| RunError::Lattice(e.to_string()))?;
            fluid.restore_returned_excess(c.returned.0, c.returned.1);
            fluid.restore_forcing_memory(std::mem::take(&mut c.forcing));
            Ok((fluid, c.mass_initial, c.active_initial, Some((file, c))))
        }
        None => {
            let fluid = initial_fluid(scene, setup)?;
            let (m, a) = (fluid.liquid_mass(), fluid.active_cells());
            Ok((fluid, m, a, None))
        }
    }
}

/// The grains' forcing of a coupled scene.
fn grain_forcing(scene: &Scene, setup: &LbmSetup) -> Result<GrainForcing, RunError> {
    Ok(GrainForcing::new(
        Coupling::new(setup.units, setup.origin)
            .map_err(|source| RunError::Coupling { exchange: 0, source })?
            .with_gain(scene.spec.coupling.forcing_gain),
    )
    .with_added_buoyancy(setup.grain_buoyancy))
}

/// Runs the scene. `stop` is polled every step; when set the run ends at the
/// step boundary with status `interrupted` and a complete recording.
///
/// With a `peer` (a coupled scene), every step is one exchange: the grain
/// states of step n come from the peer, are forced in ([`GrainForcing`]),
/// and the loads go back; the run ends when the peer sends the stop flag.
///
/// The lattice stores its populations as `lbm.precision` says.
pub fn run(
    scene: &Scene,
    opts: &RunOptions,
    stop: &AtomicBool,
    progress: &mut dyn Progress,
    peer: Option<&mut dyn StatePeer>,
) -> Result<RunSummary, RunError> {
    match scene.lbm().precision {
        Precision::F32 => run_stored_as::<f32>(scene, opts, stop, progress, peer),
        Precision::F64 => run_stored_as::<f64>(scene, opts, stop, progress, peer),
    }
}

fn run_stored_as<T: Real>(
    scene: &Scene,
    opts: &RunOptions,
    stop: &AtomicBool,
    progress: &mut dyn Progress,
    peer: Option<&mut dyn StatePeer>,
) -> Result<RunSummary, RunError> {
    let setup = LbmSetup::from_scene(scene)?;
    let out = &scene.spec.output;
    for note in &setup.notes {
        progress.log(note);
    }
    let (fluid, mass_initial, active_initial, resumed) = lattice::<T>(scene, &setup, opts.resume.as_deref())?;

    std::fs::create_dir_all(&opts.out_dir).map_err(|source| RunError::Io { path: opts.out_dir.clone(), source })?;
    let (mcap_path, summary_path) = output_paths(&opts.out_dir);
    let coupled = peer.is_some();
    let (mut rec, channels) = Recording::open(opts.record, &mcap_path, "lbm_proc", scene, 16, |b| {
        Ok(Channels {
            surface: b.channel::<PointCloud>(topics::LBM_SURFACE)?,
            slice: b.channel::<Grid>(topics::LBM_SLICE)?,
            metrics: b.channel::<LbmMetrics>(topics::LBM_METRICS)?,
            state: b.state_channel(topics::LBM_STATE, &state_schema_name::<T>(), STATE_VERSION)?,
            coupling: if coupled { Some(b.channel::<CouplingTimings>(topics::LBM_COUPLING)?) } else { None },
            received: if coupled && out.record_exchange {
                Some(b.received_channel(topics::LBM_RECEIVED_STATES)?)
            } else {
                None
            },
        })
    })?;
    if let Some((file, _)) = &resumed {
        let line = file.resumed_line(opts.resume.as_ref().expect("resuming"));
        progress.log(&line);
        rec.log(file.driver.time, log_level::INFO, &line)?;
    } else {
        for note in &setup.notes {
            rec.log(0.0, log_level::INFO, note)?;
        }
    }

    let dt = setup.units.dt();
    let total_steps = (out.end_time / dt).ceil() as u64;
    let cadence = Cadence {
        steps_per_frame: Cadence::steps_in(out.record_interval, dt),
        steps_per_state: out.state_interval.map(|s| Cadence::steps_in(s, dt)),
        // Coupled, the DEM decides when the run ends; the bound only guards a runaway peer.
        step_limit: if peer.is_some() { total_steps + 1 } else { total_steps },
        state_at_start: false,
        // Coupled: one step per exchange, as the DEM's whole exchanges.
        steps_per_checkpoint: out.checkpoint_interval.map(|i| Cadence::steps_in(i, dt)),
    };
    let mut checkpoints = Checkpoints::default();
    if out.checkpoint_interval.is_some() {
        checkpoints.writer = Some(CheckpointWriter::new(&opts.out_dir, "lbm_proc", scene).map_err(RecordError::from)?);
    }
    let forcing = match peer {
        Some(_) => Some(grain_forcing(scene, &setup)?),
        None => None,
    };
    let mut fluid = fluid;
    let lagged_peer = scene.spec.coupling.schedule == schemas::scene::Schedule::Concurrent;
    let mut exchange = peer.map(|p| {
        let x = Exchange::new(Box::new(p), Side::ReceivesFirst, 1, "dem_proc")
            .recording_into(channels.as_ref().and_then(|c| c.received));
        match resumed.as_ref().and_then(|(f, _)| f.exchange) {
            Some(state) => x.resuming(state, lagged_peer),
            None => x,
        }
    });
    let coupling_before = [exchange.as_ref().map_or(0.0, |x| x.figures().exchanges as f64), 0.0, 0.0, 0.0];
    let mut solver = match resumed {
        Some((file, c)) => {
            checkpoints.resumed = Some(file.driver);
            let mut forcing = forcing;
            if let Some(f) = forcing.as_mut() {
                f.restore_held_liquid(c.held_liquid);
            }
            LbmRun {
                scene,
                setup,
                fluid,
                gates_removed: c.state.gates_removed,
                time: c.state.time,
                steps: c.steps,
                forcing,
                header: ExchangeHeader::new(c.header.0, c.header.1),
                states: Vec::new(),
                loads: runtime::exchange::decode_loads(&c.loads)
                    .map_err(|e| RunError::Lattice(format!("the checkpoint's last loads do not decode: {e}")))?
                    .1,
                coupling_before,
                channels,
                gathered: c.gathered,
                mass_initial,
                active_initial,
            }
        }
        None => {
            let mut gates_removed = vec![false; setup.gates.len()];
            release_gates(&mut fluid, &setup, &mut gates_removed, 0.0, &mut rec)?;
            LbmRun {
                scene,
                setup,
                fluid,
                gates_removed,
                time: 0.0,
                steps: 0,
                forcing,
                header: ExchangeHeader::new(0, 0.0),
                states: Vec::new(),
                loads: Vec::new(),
                coupling_before,
                channels,
                gathered: Gathered::default(),
                mass_initial,
                active_initial,
            }
        }
    };
    let end_time = out.end_time;
    drive(
        &mut solver,
        exchange.as_mut().map(|x| x as &mut dyn StepExchange<LbmRun<T>>),
        &mut rec,
        cadence,
        RestRule::of(out),
        &mut checkpoints,
        stop,
        &mut |t, steps| progress.phase("flow", t, end_time, steps),
        &summary_path,
    )
}

/// An LBM run's checkpoint ([`Solver::checkpoint`]): the lattice, the
/// exchange's last header and answer (coupled), what the frames gathered.
/// Written borrowing the lattice (no copy of the populations:
/// `LbmCheckpoint<LbmStateRef, &Gathered>`), read owning it.
#[derive(Serialize, Deserialize)]
struct LbmCheckpoint<S = LbmState, G = Gathered> {
    state: S,
    steps: u64,
    /// Index and time of the last exchange received.
    header: (u64, f64),
    /// The loads of the last step (a lagged peer takes them after a resume),
    /// in the exchange's recorded form.
    loads: Vec<u8>,
    gathered: G,
    mass_initial: f64,
    active_initial: usize,
    /// The fluid's pending-excess diagnostics (returns, mass).
    returned: (u64, f64),
    /// The direct forcing and the grains' held liquid of the last step.
    forcing: ForcingMemory,
    held_liquid: HeldLiquid,
}

/// [`LbmState`] borrowing the lattice.
#[derive(Serialize)]
#[serde(bound(serialize = "T: Real"))]
struct LbmStateRef<'a, T> {
    version: u32,
    time: f64,
    gates_removed: &'a [bool],
    fluid: &'a FluidState<T>,
}

/// A lattice of no cells: what a checkpoint holds once its lattice is taken.
fn empty_fluid_state<T>() -> FluidState<T> {
    FluidState {
        dims: [0; 3],
        faces: [crate::fluid::Faces::Walls; 3],
        flags: Vec::new(),
        populations: Vec::new(),
        mass: Vec::new(),
        pending_excess: 0.0,
        reference_mass: None,
        step: 0,
    }
}

fn read_checkpoint<T: Real>(
    path: &Path,
    scene: &Scene,
) -> Result<(CheckpointFile, LbmCheckpoint<LbmState<T>>), RunError> {
    // The lattice's layout version leads the solver part (LbmState's first
    // field): a checkpoint of another layout is named as such.
    let file = checkpoint::read(path, "lbm_proc", scene).map_err(RecordError::from)?;
    let version =
        bincode::serde::decode_from_slice::<u32, _>(&file.solver, bincode::config::standard()).map(|(v, _)| v);
    if let Ok(v) = version {
        if v != STATE_VERSION {
            return Err(RecordError::from(checkpoint::CheckpointError::Damaged {
                path: path.to_path_buf(),
                why: format!(
                    "its lattice is stored in layout version {v}, this lbm_proc resumes version {STATE_VERSION}: \
                     resume with the lbm_proc that wrote it, or start the run again"
                ),
            })
            .into());
        }
    }
    Ok(checkpoint::decode_solver(file, path, "its lattice").map_err(RecordError::from)?)
}

/// The lattice as the run driver steps it.
struct LbmRun<'a, T: Real> {
    scene: &'a Scene,
    setup: LbmSetup,
    fluid: Fluid<T>,
    gates_removed: Vec<bool>,
    time: f64,
    steps: u64,
    /// Coupled: the grains forced into each step (the driver holds the exchange).
    forcing: Option<GrainForcing>,
    /// Coupled: the last message received, and the loads the step computed.
    header: ExchangeHeader,
    states: Vec<ParticleState>,
    loads: Vec<HydroLoad>,
    /// Cumulative (exchanges, wall s, wait s, coupling s) at the last frame.
    coupling_before: [f64; 4],
    channels: Option<Channels>,
    gathered: Gathered,
    mass_initial: f64,
    active_initial: usize,
}

impl From<ExchangeFailure> for RunError {
    fn from(e: ExchangeFailure) -> Self {
        RunError::Peer { exchange: e.exchange, source: e.source }
    }
}

/// The LBM takes the grain states of a step, forces them in, answers the
/// loads.
impl<T: Real> Coupled for LbmRun<'_, T> {
    type Sends = HydroLoad;
    type Receives = ParticleState;
    fn outgoing(&mut self, out: &mut Vec<HydroLoad>) {
        // Copied, not swapped: a checkpoint keeps the last answer (a lagged
        // DEM takes it one exchange late, so after a resume it is sent again).
        out.clone_from(&self.loads);
    }
    fn incoming(&mut self, header: &ExchangeHeader, states: &mut Vec<ParticleState>) -> Result<(), RunError> {
        self.header = *header;
        std::mem::swap(states, &mut self.states);
        Ok(())
    }
}

impl<T: Real> Solver for LbmRun<'_, T> {
    type Error = RunError;

    fn time(&self) -> f64 {
        self.time
    }

    fn steps(&self) -> u64 {
        self.steps
    }

    fn work_per_step(&self) -> f64 {
        self.fluid.active_cells() as f64
    }

    /// Coupled, the part of the step the DEM waits for: the lattice step
    /// with the grains of this exchange forced in, the loads computed.
    fn step(&mut self, _rec: &mut Recording) -> Result<Flow, StepError<RunError>> {
        match self.forcing.as_mut() {
            Some(f) => f
                .step(&mut self.fluid, &self.header, &self.states, &mut self.loads)
                .map_err(|source| StepError::Fatal(RunError::Coupling { exchange: self.steps, source }))?,
            None => self.fluid.begin_step(),
        }
        Ok(Flow::Continue)
    }

    /// The free-surface conversions (they do not change the loads: done
    /// while the DEM steps), then the gates due.
    fn finish_step(&mut self, rec: &mut Recording) -> Result<(), StepError<RunError>> {
        self.fluid.finish_step();
        self.steps += 1;
        self.time = self.steps as f64 * self.setup.units.dt();
        release_gates(&mut self.fluid, &self.setup, &mut self.gates_removed, self.time, rec).map_err(StepError::Fatal)
    }

    fn check(&self) -> Result<(), RunError> {
        self.fluid
            .check(&self.setup.limits)
            .map_err(|instability| RunError::Unstable { t: self.time, instability: Box::new(instability) })
    }

    fn record_frame(&mut self, rec: &mut Recording, clock: FrameClock) -> Result<FrameReport, RunError> {
        record_frame(
            &mut self.gathered,
            rec,
            self.channels.as_ref(),
            &self.fluid,
            self.scene,
            &self.setup,
            self.time,
            self.mass_initial,
            clock.rate / 1e6,
        )?;
        if let (Some(f), Some(x), Some(r), Some(Some(ch))) =
            (self.forcing.as_ref(), clock.exchange, rec.recorder(), self.channels.as_ref().map(|c| c.coupling))
        {
            if self.steps > 0 {
                let now = [x.exchanges as f64, clock.wall, x.seconds, f.coupling_seconds];
                r.log(ch, self.time, &CouplingTimings::between(self.time, now, self.coupling_before))?;
                self.coupling_before = now;
            }
        }
        Ok(FrameReport { moving_fraction: None, released: true })
    }

    fn record_state(&mut self, rec: &mut Recording) -> Result<(), RunError> {
        if let (Some(r), Some(ch)) = (rec.recorder(), self.channels.as_ref()) {
            // Borrowed, not cloned: a clone would back the whole box (1.6 GB on
            // the lab column), where the lattice backs only the liquid's pages.
            let state = LbmStateRef {
                version: STATE_VERSION,
                time: self.time,
                gates_removed: &self.gates_removed,
                fluid: self.fluid.state(),
            };
            let bytes = bincode::serde::encode_to_vec(&state, bincode::config::standard()).expect("state encodes");
            r.log_bytes(ch.state, self.time, bytes)?;
        }
        Ok(())
    }

    fn checkpoint(&self, out: &mut dyn std::io::Write) -> std::io::Result<()> {
        let c: LbmCheckpoint<LbmStateRef<T>, &Gathered> = LbmCheckpoint {
            state: LbmStateRef {
                version: STATE_VERSION,
                time: self.time,
                gates_removed: &self.gates_removed,
                fluid: self.fluid.state(),
            },
            steps: self.steps,
            header: (self.header.exchange, self.header.time),
            loads: {
                let mut bytes = Vec::new();
                runtime::exchange::encode_loads(&self.header, &self.loads, &mut bytes);
                bytes
            },
            gathered: &self.gathered,
            mass_initial: self.mass_initial,
            active_initial: self.active_initial,
            returned: (self.fluid.pending_returns(), self.fluid.returned_excess()),
            forcing: self.fluid.forcing_memory(),
            held_liquid: self.forcing.as_ref().map(|f| f.held_liquid()).unwrap_or_default(),
        };
        checkpoint::encode_into(&c, out)
    }

    fn summary(&mut self, end: &RunEnd) -> RunSummary {
        let (scene, setup, fluid) = (self.scene, &self.setup, &self.fluid);
        let (time, steps, wall) = (self.time, self.steps, end.wall);
        let mass_final = fluid.liquid_mass();
        let mass_si = |m: f64| m * setup.density * setup.units.dx().powi(3);
        RunSummary {
            scene: scene.spec.scene.name.clone(),
            method: if self.forcing.is_some() { "dem_lbm" } else { "lbm" }.into(),
            status: end.status,
            sim_time: time,
            wall_seconds: wall,
            steps,
            throughput: Throughput {
                particle_steps_per_s: None,
                cell_updates_per_s: Some(end.work / wall.max(1e-9)),
                point_updates_per_s: None,
                wall_per_sim_second: wall / (time - end.started_at.1).max(1e-12),
            },
            t_ref: scene.reference_time(),
            front: Vec::new(),
            runout: f64::NAN,
            front_connected: Vec::new(),
            runout_connected: None,
            front_pile: Vec::new(),
            runout_pile: None,
            deposit: Vec::new(),
            porosity_initial: f64::NAN,
            liquid_front: std::mem::take(&mut self.gathered.front),
            dem: None,
            lbm: Some(LbmDetails {
                dims: setup.dims,
                spacing: setup.units.dx(),
                time_step: setup.units.dt(),
                tau: setup.params.tau,
                collision: format!("{:?}", setup.params.collision),
                smagorinsky: setup.params.smagorinsky,
                active_cells_initial: self.active_initial,
                active_cells_final: fluid.active_cells(),
                mass_initial: mass_si(self.mass_initial),
                mass_final: mass_si(mass_final),
                mass_relative_change: (mass_final - self.mass_initial) / self.mass_initial,
                pending_mass_final: mass_si(fluid.pending_excess()),
                returned_mass: mass_si(fluid.returned_excess()),
                max_mach: self.gathered.max_mach,
                recording_fraction: end.recording_seconds / wall.max(1e-9),
                threads: rayon::current_num_threads(),
                stage_seconds: schemas::summary::stage_seconds_map(&fluid.stage_seconds),
            }),
            mpm: None,
            wall_seconds_total: None,
            wall_seconds_lbm: None,
            exchange: self.forcing.as_ref().zip(end.exchange).map(|(f, x)| {
                ExchangeSummary::Process(ExchangeDetails {
                    schedule: scene.spec.coupling.schedule.name().into(),
                    ratio: scene.spec.coupling.ratio,
                    exchanges: x.exchanges,
                    seconds: x.seconds,
                    fraction: x.seconds / wall.max(1e-9),
                    kernel_seconds: f.coupling_seconds,
                    forcing_gain: Some(scene.spec.coupling.forcing_gain.name().into()),
                })
            }),
        }
    }

    fn closing_line(&self, s: &RunSummary) -> String {
        let change = s.lbm.as_ref().map_or(f64::NAN, |l| l.mass_relative_change);
        format!("run {}: t = {:.4} s, {} steps, mass change {change:.3e}", s.status, s.sim_time, s.steps)
    }

    fn cannot_write(path: &Path, source: std::io::Error) -> RunError {
        RunError::Io { path: path.to_path_buf(), source }
    }
}

fn release_gates<T: Real>(
    fluid: &mut Fluid<T>,
    setup: &LbmSetup,
    removed: &mut [bool],
    time: f64,
    rec: &mut Recording,
) -> Result<(), RunError> {
    for (g, gate) in setup.gates.iter().enumerate() {
        if !removed[g] && time >= gate.release_time {
            fluid.remove_walls(&gate.cells).map_err(|e| RunError::Lattice(e.to_string()))?;
            removed[g] = true;
            rec.log(time, log_level::INFO, &format!("gate {} removed ({} cells)", gate.name, gate.cells.len()))?;
        }
    }
    Ok(())
}

/// Bytes per cell of `/lbm/slice`: four little-endian f32 fields.
const SLICE_CELL_BYTES: usize = 16;

/// One cell of the recorded slice, SI except `speed` (lattice units).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
struct SliceCell {
    fill: f64,
    speed: f64,
    /// Gauge pressure c_s² (ρ − 1) ρ_L (Δx/Δt)², Pa: zero at the free
    /// surface, where the interface cells are rebuilt at ρ = 1.
    pressure: f64,
    /// `pressure` less the hydrostatic pressure of the liquid above the
    /// cell in its own vertical run of liquid cells, Pa: the pore pressure
    /// the flow adds, the quantity that lifts grains (positive) or holds
    /// them (negative).
    excess_pressure: f64,
}

/// The slice's values up one vertical column of cells into `cells`
/// (`samples[k]` is cell k from the floor; `None` outside the lattice;
/// both of one length).
///
/// Each vertical run of liquid cells (fluid or interface) has its surface
/// at the top cell's bottom face plus its fill times Δx; the hydrostatic
/// pressure of a cell in the run is −ρ_L g_z (z_surface − z_centre), with
/// `weight_z` = ρ_L g_z in N/m³ (zero when the lattice leaves the liquid's
/// weight out, `lbm.hydrostatics = "buoyancy"`, whose pressure is all
/// excess). Gas and wall cells get zeros. A run closed by a wall above is
/// measured to that wall's face.
fn slice_column(samples: &[Option<Sample>], cs2: f64, to_pascal: f64, weight_z: f64, dx: f64, cells: &mut [SliceCell]) {
    let liquid = |k: usize| samples[k].is_some_and(|s| flags::is_liquid(s.flag));
    cells.fill(SliceCell::default());
    let mut k = 0;
    while k < samples.len() {
        if !liquid(k) {
            k += 1;
            continue;
        }
        let start = k;
        while k < samples.len() && liquid(k) {
            k += 1;
        }
        let top = k - 1;
        let surface = top as f64 + samples[top].map_or(0.0, |s| s.fill);
        for (c, cell) in cells.iter_mut().enumerate().take(k).skip(start) {
            let s = samples[c].expect("a liquid cell was sampled");
            let speed = s.velocity.iter().map(|v| v * v).sum::<f64>().sqrt();
            let pressure = cs2 * (s.density - 1.0) * to_pascal;
            let hydrostatic = -weight_z * (surface - (c as f64 + 0.5)) * dx;
            *cell = SliceCell { fill: s.fill, speed, pressure, excess_pressure: pressure - hydrostatic };
        }
    }
}

#[allow(clippy::too_many_arguments)]
fn record_frame<T: Real>(
    frames: &mut Gathered,
    rec: &mut Recording,
    channels: Option<&Channels>,
    fluid: &Fluid<T>,
    scene: &Scene,
    setup: &LbmSetup,
    t: f64,
    mass_initial: f64,
    mlups: f64,
) -> Result<(), RecordError> {
    let t_ref = scene.reference_time();
    let units = &setup.units;
    let dx = units.dx();
    let x0 = scene.spec.domain.min[0];
    let l0 = scene.spec.analysis.column_length;
    let fraction = scene.spec.analysis.front_mass_fraction;
    let mut scratch = std::mem::take(&mut frames.scratch);
    let [nx, ny, _] = setup.dims;
    // Each liquid cell counted at its centre with its mass ρ ε (lattice units; the rule needs ratios only).
    let liquid = fluid.liquid_cell_masses().into_iter().map(|(c, mass)| {
        let cell = [c % nx, (c / nx) % ny, c / (nx * ny)];
        (setup.centre(cell)[0], mass)
    });
    let fx = front_position(liquid, fraction, &mut scratch);
    frames.scratch = scratch;
    let sample = FrontSample { t, t_norm: t / t_ref, x: fx, x_norm: (fx - x0 - l0) / l0 };
    frames.front.push(sample);
    let mass = fluid.liquid_mass();
    let max_speed = fluid.max_speed();
    let max_mach = max_speed / CS2.sqrt();
    frames.max_mach = frames.max_mach.max(max_mach);

    if let (Some(rec), Some(ch)) = (rec.recorder(), channels) {
        // Free surface: interface cells with their fill and speed.
        const STRIDE: usize = 20;
        let mut data = Vec::new();
        let mut interface = 0usize;
        for cell in fluid.interface() {
            let c = setup.centre(cell.cell);
            let u = cell.velocity;
            let speed = units.velocity_to_si((u[0] * u[0] + u[1] * u[1] + u[2] * u[2]).sqrt());
            for v in [c[0], c[1], c[2], speed, cell.fill] {
                data.extend_from_slice(&(v as f32).to_le_bytes());
            }
            interface += 1;
        }
        let cloud = PointCloud {
            timestamp: Some(timestamp(t)),
            frame_id: "world".into(),
            pose: Some(identity_pose()),
            point_stride: STRIDE as u32,
            fields: vec![
                f32_field("x", 0),
                f32_field("y", 4),
                f32_field("z", 8),
                f32_field("speed", 12),
                f32_field("fill", 16),
            ],
            data: data.into(),
        };
        rec.log(ch.surface, t, &cloud)?;

        // Mid-width x–z slice, rows along z: fill, speed, gauge pressure and
        // its excess over the liquid column above (docs/recording.md).
        let nz = setup.dims[2];
        let j = ny / 2;
        let to_pascal = setup.density * (dx / units.dt()).powi(2);
        let gravity_z = units.acceleration_to_si(setup.params.acceleration[2]);
        // The grid lies in its pose's x–y plane: turn it +90° about x so its y runs along z.
        let half = std::f64::consts::FRAC_1_SQRT_2;
        let slice = Grid {
            timestamp: Some(timestamp(t)),
            frame_id: "world".into(),
            pose: Some(Pose {
                position: Some(Vector3 { x: setup.origin[0], y: setup.centre([0, j, 0])[1], z: setup.origin[2] }),
                orientation: Some(Quaternion { x: half, y: 0.0, z: 0.0, w: half }),
            }),
            column_count: nx as u32,
            cell_size: Some(Vector2 { x: dx, y: dx }),
            row_stride: (nx * SLICE_CELL_BYTES) as u32,
            cell_stride: SLICE_CELL_BYTES as u32,
            fields: vec![
                f32_field("fill", 0),
                f32_field("speed", 4),
                f32_field("pressure", 8),
                f32_field("excess_pressure", 12),
            ],
            // Written in place below: one copy of the cells, not two.
            data: Default::default(),
        };
        let fill_cells = |grid: &mut [u8]| {
            let mut column = Vec::with_capacity(nz);
            let mut cells = vec![SliceCell::default(); nz];
            for i in 0..nx {
                column.clear();
                column.extend((0..nz).map(|k| fluid.sample([i, j, k]).ok()));
                slice_column(&column, CS2, to_pascal, setup.density * gravity_z, dx, &mut cells);
                for (k, cell) in cells.iter().enumerate() {
                    let at = (k * nx + i) * SLICE_CELL_BYTES;
                    let values = [cell.fill, units.velocity_to_si(cell.speed), cell.pressure, cell.excess_pressure];
                    for (f, v) in values.into_iter().enumerate() {
                        grid[at + 4 * f..at + 4 * f + 4].copy_from_slice(&(v as f32).to_le_bytes());
                    }
                }
            }
        };
        // Grid's `data` is its last field, number 9.
        let cells = Payload { field: 9, len: nx * nz * SLICE_CELL_BYTES, fill: fill_cells };
        rec.log_with_payload(ch.slice, t, &slice, cells)?;

        let si_mass = setup.density * dx.powi(3);
        let si_energy = si_mass * (dx / units.dt()).powi(2);
        let metrics = LbmMetrics {
            t,
            t_norm: t / t_ref,
            liquid_mass: mass * si_mass,
            liquid_mass_change: (mass - mass_initial) / mass_initial,
            kinetic_energy: fluid.kinetic_energy() * si_energy,
            liquid_front_x: fx,
            liquid_front_norm: sample.x_norm,
            max_speed: units.velocity_to_si(max_speed),
            max_mach,
            active_cells: fluid.active_cells() as f64,
            interface_cells: interface as f64,
            mlups,
            pending_mass: fluid.pending_excess() * si_mass,
        };
        rec.log(ch.metrics, t, &metrics)?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn liquid(fill: f64, density: f64) -> Option<Sample> {
        let flag = if fill < 1.0 { flags::INTERFACE } else { flags::FLUID };
        Some(Sample { flag, fill, density, velocity: [0.0; 3] })
    }

    const GAS: Option<Sample> = Some(Sample { flag: flags::GAS, fill: 0.0, density: 0.0, velocity: [0.0; 3] });

    /// A resting layer 3.4 cells deep with the lattice's hydrostatic
    /// densities (ρ = 1 + 3 g d in lattice units) has the hydrostatic gauge
    /// pressure and no excess; a droplet above it is measured from its own
    /// surface, not from the layer's.
    #[test]
    fn slice_pressure_is_hydrostatic_at_rest_and_excess_is_what_exceeds_it() {
        let (dx, dt, rho_l, g): (f64, f64, f64, f64) = (1e-3, 1e-4, 1000.0, 9.81);
        let g_lattice = g * dt * dt / dx;
        let to_pascal = rho_l * (dx / dt).powi(2);
        // Depth of cell k's centre below the surface at 3.4 cells.
        let density = |depth: f64| 1.0 + g_lattice * depth / CS2;
        let mut column: Vec<Option<Sample>> = (0..3).map(|k| liquid(1.0, density(3.4 - (k as f64 + 0.5)))).collect();
        column.push(liquid(0.4, 1.0));
        column.push(GAS);
        column.push(liquid(0.5, 1.0 + 0.001)); // a droplet with a 0.001 density excess
        column.push(GAS);
        let mut cells = vec![SliceCell::default(); column.len()];
        slice_column(&column, CS2, to_pascal, -rho_l * g, dx, &mut cells);
        for (k, cell) in cells.iter().enumerate().take(3) {
            let depth = (3.4 - (k as f64 + 0.5)) * dx;
            assert!((cell.pressure - rho_l * g * depth).abs() < 1e-9, "cell {k}: {cell:?}");
            assert!(cell.excess_pressure.abs() < 1e-9, "cell {k}: {cell:?}");
        }
        // The interface cell's centre lies 0.1 cells above its surface.
        assert!((cells[3].excess_pressure - rho_l * g * 0.1 * dx).abs() < 1e-9);
        assert_eq!(cells[4], SliceCell::default());
        let droplet = CS2 * 0.001 * to_pascal;
        assert!((cells[5].pressure - droplet).abs() < 1e-9);
        assert!((cells[5].excess_pressure - droplet).abs() < 1e-9, "droplet's own surface: at its centre");
        // Without the liquid's weight on the lattice the pressure is all excess.
        slice_column(&column, CS2, to_pascal, 0.0, dx, &mut cells);
        assert!(cells.iter().all(|c| c.pressure == c.excess_pressure));
    }
}

#[cfg(test)]
mod state_layout_tests {
    use super::*;
    use crate::fluid::{Faces, FluidParams};

    #[test]
    fn a_version_1_state_every_cell_stored_still_reads() {
        let mut fluid = Fluid::<f32>::new([6, 3, 5], [Faces::Walls; 3], FluidParams::new(0.6)).unwrap();
        fluid.init_liquid(|[x, _, z]| x < 3 && z < 3).unwrap();
        fluid.step();
        let s = fluid.state();
        let ncells = s.flags.len();
        let dense: Vec<f32> =
            (0..crate::lattice::Q).flat_map(|i| (0..ncells).map(move |c| s.population(i, c))).collect();
        // Version 1 stored the flags' codes (docs/recording.md), not the values in memory.
        let codes: Vec<u8> = s.flags.iter().map(|&f| flags::to_stored(f)).collect();
        #[derive(Serialize)]
        struct DenseRef<'a> {
            dims: [usize; 3],
            faces: [Faces; 3],
            flags: &'a [u8],
            populations: &'a [f32],
            mass: &'a [f64],
            pending_excess: f64,
            reference_mass: Option<f64>,
            step: u64,
        }
        #[derive(Serialize)]
        struct V1<'a> {
            version: u32,
            time: f64,
            gates_removed: Vec<bool>,
            fluid: DenseRef<'a>,
        }
        let v1 = V1 {
            version: 1,
            time: 0.25,
            gates_removed: vec![true],
            fluid: DenseRef {
                dims: s.dims,
                faces: s.faces,
                flags: &codes,
                populations: &dense,
                mass: &s.mass,
                pending_excess: s.pending_excess,
                reference_mass: s.reference_mass,
                step: s.step,
            },
        };
        let bytes = bincode::serde::encode_to_vec(&v1, bincode::config::standard()).unwrap();
        let read = LbmState::<f32>::from_bytes(&bytes).unwrap();
        assert_eq!((read.version, read.time, read.gates_removed.as_slice()), (1, 0.25, &[true][..]));
        assert_eq!(&read.fluid, s);
        // And this version's layout round-trips the liquid cells.
        let now = LbmState { version: STATE_VERSION, time: 0.5, gates_removed: vec![false], fluid: s.clone() };
        let back = LbmState::<f32>::from_bytes(&now.encode()).unwrap();
        assert_eq!(back.fluid.flags, s.flags);
        assert!(bytes.len() > now.encode().len(), "the liquid-only layout is the smaller");
        // A version from the future is refused by name.
        let mut future = now.encode();
        future[0] = 9;
        assert!(LbmState::<f32>::from_bytes(&future).unwrap_err().contains("version 9"));
        // Read from version 1, written in this version's layout.
        assert_eq!(LbmState::<f32>::from_bytes(&read.encode()).unwrap().fluid.flags, s.flags);
    }
}
