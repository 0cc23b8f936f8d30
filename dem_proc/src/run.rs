//! A whole DEM run: packing, gate release, collapse to rest or end time, with
//! recording and the measures of the summary.

use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicBool;

use foxglove::schemas::{Color, PointCloud, Pose, SceneEntity, SceneUpdate, SpherePrimitive, Vector3};
use serde::{Deserialize, Serialize};

use runtime::checkpoint::{self, CheckpointFile, CheckpointWriter};
use runtime::coupled::{Coupled, Exchange, ExchangeFailure, Side};
use runtime::driver::{
    drive, Cadence, Checkpoints, Flow, FrameClock, FrameReport, Recording, RestRule, RunEnd, Solver, StepError,
    StepExchange,
};
use runtime::exchange::{ExchangeHeader, HydroLoad, ParticleState};
use runtime::metrics::{CouplingTimings, DemMetrics};
use runtime::process::{Progress, RunOptions};
use runtime::record::{f32_field, identity_pose, identity_quaternion, log_level, timestamp, ChannelId, RecordError};
use schemas::measures::{coordination_shares, deposit_profile, front_position, pile_edge, FrontSample};
use schemas::scene::Scene;
use schemas::summary::{DemDetails, ExchangeDetails, ExchangeSummary, RunSummary, Throughput};
use schemas::topics;

use crate::hydro::{capture_states, hold_loads, Connect};
use crate::packing::{self, Packing, PackingError, PackingReport};
use crate::setup::{walls, DemSetup};
use crate::world::{Grains, HeldLoads, Histories, World};

/// Version of the `/dem/state` bincode layout.
pub const STATE_VERSION: u32 = 2;

/// Full-precision state, enough to continue a run bit for bit (`/dem/state`).
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
pub struct DemState {
    pub version: u32,
    /// Simulated time since the start of the run, s.
    pub time: f64,
    pub step: u64,
    /// Per-grain state in the solver's storage order; `ids[slot]` is the grain id.
    pub grains: Grains,
    pub ids: Vec<u32>,
    /// First storage row of each force block, then the grain count.
    pub block_starts: Vec<u32>,
    /// Contact histories by storage slot.
    pub histories: Histories,
    /// Which walls (box faces, then gates) are still present.
    pub walls_active: Vec<bool>,
}

impl DemState {
    pub fn capture(world: &World) -> Self {
        DemState {
            version: STATE_VERSION,
            time: world.time,
            step: world.step_count,
            grains: world.grains.clone(),
            ids: world.ids().to_vec(),
            block_starts: world.block_starts().to_vec(),
            histories: world.histories(),
            walls_active: world.walls.iter().map(|w| w.active).collect(),
        }
    }

    pub fn encode(&self) -> Vec<u8> {
        bincode::serde::encode_to_vec(self, bincode::config::standard()).expect("state encodes")
    }

    pub fn decode(bytes: &[u8]) -> Result<Self, String> {
        bincode::serde::decode_from_slice(bytes, bincode::config::standard()).map(|(s, _)| s).map_err(|e| e.to_string())
    }

    /// A world continuing from this state under `scene`.
    pub fn restore(&self, scene: &Scene) -> World {
        let setup = DemSetup::from_scene(scene);
        let mut ws = walls(scene, false);
        for (w, active) in ws.iter_mut().zip(&self.walls_active) {
            w.active = *active;
        }
        let mut world = World::new(
            self.grains.clone(),
            ws,
            setup.grain_law,
            setup.wall_law,
            setup.gravity,
            setup.numerics,
            setup.domain,
        );
        world.set_ids(&self.ids).expect("a state's grain ids are a permutation of its grains");
        world.set_block_starts(&self.block_starts).expect("a state's force blocks cut its grains");
        world.set_histories(&self.histories);
        world.time = self.time;
        world.step_count = self.step;
        world
    }
}

/// The world at the start of the run: the packing with its contact springs,
/// the walls with the gates until their release, forces primed for Verlet.
pub fn collapse_world(scene: &Scene, setup: &DemSetup, packing: &Packing) -> World {
    let mut world = World::new(
        packing.grains.clone(),
        walls(scene, false),
        setup.grain_law,
        setup.wall_law,
        setup.gravity,
        setup.numerics,
        setup.domain,
    );
    world.set_histories(&packing.histories);
    world.prime_forces();
    world
}

#[derive(Debug, thiserror::Error)]
pub enum RunError {
    #[error(transparent)]
    Packing(#[from] PackingError),
    #[error(transparent)]
    Record(#[from] RecordError),
    #[error("numerical blow-up at t = {t:.5} s: grain {grain} reached {speed:.3e} m/s (overlap unbounded). The time step {dt:.3e} s gives {steps_per_contact:.1} steps per contact; lower dem.time_step or raise dem.steps_per_contact (>= 20 recommended)")]
    BlowUp { t: f64, grain: usize, speed: f64, dt: f64, steps_per_contact: f64 },
    #[error("cannot write {path}: {source}")]
    Io { path: PathBuf, source: std::io::Error },
    #[error("exchange with lbm_proc failed at t = {t:.5} s: {source}")]
    Peer { t: f64, source: runtime::exchange::PeerError },
}

struct Channels {
    particles: ChannelId,
    spheres: Option<ChannelId>,
    metrics: ChannelId,
    state: ChannelId,
    /// `/dem/received_loads` (`output.record_exchange` in a coupled run).
    received: Option<ChannelId>,
    /// `/dem/coupling` (coupled runs).
    coupling: Option<ChannelId>,
}

/// Consecutive recorded frames at rest that end a run early.
pub use runtime::driver::REST_FRAMES;

/// Where `dem_proc` writes its recording and its summary.
pub fn output_paths(out_dir: &Path) -> (PathBuf, PathBuf) {
    (out_dir.join("dem.mcap"), out_dir.join("dem_summary.json"))
}

/// Runs the scene. `stop` is polled every step; when set the run ends at the
/// step boundary with status `interrupted` and a complete recording.
///
/// With `connect` (a coupled scene), the peer is connected once the packing
/// is ready; then every `coupling.ratio`-th step exchanges grain states for
/// hydrodynamic loads (the driver's [`Exchange`], the DEM sending first);
/// at the end the peer gets the stop flag.
pub fn run(
    scene: &Scene,
    opts: &RunOptions,
    stop: &AtomicBool,
    progress: &mut dyn Progress,
    connect: Option<Connect<'_>>,
) -> Result<RunSummary, RunError> {
    let setup = DemSetup::from_scene(scene);
    let out = &scene.spec.output;
    let resumed = match &opts.resume {
        Some(path) => Some(read_checkpoint(path, scene)?),
        None => None,
    };
    let (world, rep, early_log, coordination_initial, fronts) = match &resumed {
        Some((file, c)) => {
            let mut world = c.state.restore(scene);
            if let Some(held) = &c.held {
                world.set_held_loads(held);
            }
            let line = file.resumed_line(opts.resume.as_ref().expect("resuming"));
            progress.log(&line);
            (world, c.packing.clone(), vec![line], c.coordination_initial, Some(c.fronts.clone()))
        }
        None => {
            let (packing, early_log) = prepare_packing(scene, &setup, stop, progress)?;
            let rep = packing.report.clone();
            let world = collapse_world(scene, &setup, &packing);
            drop(packing);
            let coordination_initial = world.mean_coordination();
            (world, rep, early_log, coordination_initial, None)
        }
    };
    let peer = match connect {
        Some(c) => {
            progress.log(&format!("connecting to lbm_proc with {} grains", world.len()));
            Some(c(world.len()).map_err(|source| RunError::Peer { t: 0.0, source })?)
        }
        None => None,
    };

    std::fs::create_dir_all(&opts.out_dir).map_err(|source| RunError::Io { path: opts.out_dir.clone(), source })?;
    let (mcap_path, summary_path) = output_paths(&opts.out_dir);
    let coupled = peer.is_some();
    let (mut rec, channels) = Recording::open(opts.record, &mcap_path, "dem_proc", scene, 64, |b| {
        Ok(Channels {
            particles: b.channel::<PointCloud>(topics::DEM_PARTICLES)?,
            spheres: if out.spheres { Some(b.channel::<SceneUpdate>(topics::DEM_SPHERES)?) } else { None },
            metrics: b.channel::<DemMetrics>(topics::DEM_METRICS)?,
            state: b.state_channel(topics::DEM_STATE, "dem_proc::run::DemState", STATE_VERSION)?,
            coupling: if coupled { Some(b.channel::<CouplingTimings>(topics::DEM_COUPLING)?) } else { None },
            received: if coupled && out.record_exchange {
                Some(b.received_channel(topics::DEM_RECEIVED_LOADS)?)
            } else {
                None
            },
        })
    })?;

    let dt = setup.numerics.dt;
    let cadence = Cadence {
        steps_per_frame: Cadence::steps_in(out.record_interval, dt),
        steps_per_state: Some(Cadence::steps_in(out.state_interval.unwrap_or(5.0 * out.record_interval), dt)),
        step_limit: (out.end_time / dt).ceil() as u64,
        state_at_start: true,
        // Coupled: whole exchanges, so that both processes' checkpoints meet.
        steps_per_checkpoint: out.checkpoint_interval.map(|i| {
            let ratio = if coupled { scene.spec.coupling.ratio as u64 } else { 1 };
            ratio * Cadence::steps_in(i, dt * ratio as f64)
        }),
    };
    let mut checkpoints = Checkpoints::default();
    if out.checkpoint_interval.is_some() {
        checkpoints.writer = Some(CheckpointWriter::new(&opts.out_dir, "dem_proc", scene).map_err(RecordError::from)?);
    }
    let last_release = world.walls.iter().map(|w| w.release_time).filter(|t| t.is_finite()).fold(0.0, f64::max);
    let front = fronts.unwrap_or_else(|| Fronts {
        solid_fraction: if rep.porosity_bulk.is_finite() { 1.0 - rep.porosity_bulk } else { 0.6 },
        width: scene.spec.domain.max[1] - scene.spec.domain.min[1],
        bin: setup.max_diameter,
        ..Fronts::default()
    });
    let t0 = world.time;
    for line in &early_log {
        rec.log(t0, log_level::INFO, line)?;
    }
    if resumed.is_none() {
        rec.log(
            0.0,
            log_level::INFO,
            &format!("collapse starts with {} grains, porosity {:.4}", world.len(), rep.porosity_bulk),
        )?;
    }
    let mut exchange = peer.map(|p| {
        let c = &scene.spec.coupling;
        let x = Exchange::new(p, Side::dem(c.schedule), c.ratio as u64, "lbm_proc")
            .expecting(world.len())
            .recording_into(channels.as_ref().and_then(|c| c.received));
        match resumed.as_ref().and_then(|(f, _)| f.exchange) {
            Some(state) => x.resuming(state, false),
            None => x,
        }
    });
    let coupling_before = [exchange.as_ref().map_or(0.0, |x| x.figures().exchanges as f64), 0.0, 0.0, 0.0];
    checkpoints.resumed = resumed.map(|(f, _)| f.driver);
    let mut solver = DemRun {
        scene,
        setup,
        world,
        coupled,
        channels,
        front,
        scratch: Vec::new(),
        last_release,
        coordination_initial,
        packing: rep,
        coupling_before,
    };
    let end_time = out.end_time;
    drive(
        &mut solver,
        exchange.as_mut().map(|x| x as &mut dyn StepExchange<DemRun>),
        &mut rec,
        cadence,
        RestRule::of(out),
        &mut checkpoints,
        stop,
        &mut |t, steps| progress.phase("collapse", t, end_time, steps),
        &summary_path,
    )
}

/// The packing (deposited or from the cache), with the lines that report it.
fn prepare_packing(
    scene: &Scene,
    setup: &DemSetup,
    stop: &AtomicBool,
    progress: &mut dyn Progress,
) -> Result<(Packing, Vec<String>), RunError> {
    // Lines logged before the recorder exists go to /log at t = 0 as well.
    let mut early_log = Vec::new();
    let mut note = |progress: &mut dyn Progress, line: String| {
        progress.log(&line);
        early_log.push(line);
    };
    note(progress, format!(
        "contact law: k_n = {} N/m, k_t = {} N/m, e = {} -> damping ratio {:.5}; contact {:.3e} s; dt {:.3e} s ({:.1} steps per contact)",
        setup.grain_law.normal_stiffness,
        setup.grain_law.tangential_stiffness,
        scene.dem().restitution,
        setup.grain_law.damping_ratio,
        setup.contact_duration,
        setup.numerics.dt,
        setup.steps_per_contact
    ));
    let packing = packing::build(scene, setup, stop, |t, tmax| progress.phase("deposition", t, tmax, 0))?;
    let rep = &packing.report;
    note(
        progress,
        if rep.from_cache {
            format!(
                "packing: {} grains from cache {}",
                rep.kept,
                rep.cache_file.as_ref().map(|p| p.display().to_string()).unwrap_or_default()
            )
        } else {
            format!(
                "packing: deposited {} grains in {:.3} s simulated ({:.1} s wall), kept {}",
                rep.generated, rep.deposition_time, rep.deposition_seconds, rep.kept
            )
        },
    );
    if rep.porosity_bulk.is_finite() {
        note(
            progress,
            format!(
                "packing porosity: bulk {:.4}, core {:.4}, height {:.4} m",
                rep.porosity_bulk, rep.porosity_core, rep.height
            ),
        );
    }
    Ok((packing, early_log))
}

/// A DEM run's checkpoint ([`Solver::checkpoint`]): the state, the loads
/// it holds (coupled), the fronts so far and what the packing measured.
/// Written borrowing the run's parts (`DemCheckpoint<&Fronts, &PackingReport>`),
/// read owning them.
#[derive(Serialize, Deserialize)]
struct DemCheckpoint<F = Fronts, P = PackingReport> {
    state: DemState,
    held: Option<HeldLoads>,
    fronts: F,
    coordination_initial: f64,
    packing: P,
}

fn read_checkpoint(path: &Path, scene: &Scene) -> Result<(CheckpointFile, DemCheckpoint), RunError> {
    Ok(checkpoint::read_solver(path, "dem_proc", scene, "its DEM state").map_err(RecordError::from)?)
}

/// The DEM as the run driver steps it.
struct DemRun<'a> {
    scene: &'a Scene,
    setup: DemSetup,
    world: World,
    /// Coupled with an LBM peer (the driver holds the exchange).
    coupled: bool,
    channels: Option<Channels>,
    front: Fronts,
    scratch: Vec<(f64, f64)>,
    /// The last gate's release, s: rest counts only after it.
    last_release: f64,
    coordination_initial: f64,
    packing: PackingReport,
    /// Cumulative (exchanges, wall s, wait s, coupling s) at the last frame.
    coupling_before: [f64; 4],
}

impl From<ExchangeFailure> for RunError {
    fn from(e: ExchangeFailure) -> Self {
        RunError::Peer { t: e.time, source: e.source }
    }
}

/// The DEM sends its grain states and holds the loads answered.
impl Coupled for DemRun<'_> {
    type Sends = ParticleState;
    type Receives = HydroLoad;
    fn outgoing(&mut self, out: &mut Vec<ParticleState>) {
        capture_states(&self.world, out);
    }
    fn incoming(&mut self, _header: &ExchangeHeader, loads: &mut Vec<HydroLoad>) -> Result<(), RunError> {
        hold_loads(&mut self.world, loads);
        Ok(())
    }
}

impl Solver for DemRun<'_> {
    type Error = RunError;

    fn time(&self) -> f64 {
        self.world.time
    }

    fn steps(&self) -> u64 {
        self.world.step_count
    }

    fn work_per_step(&self) -> f64 {
        self.world.len() as f64
    }

    fn step(&mut self, _rec: &mut Recording) -> Result<Flow, StepError<RunError>> {
        self.world.step();
        Ok(Flow::Continue)
    }

    fn check(&self) -> Result<(), RunError> {
        check_blow_up(&self.world, &self.setup)
    }

    fn record_frame(&mut self, rec: &mut Recording, clock: FrameClock) -> Result<FrameReport, RunError> {
        record_frame(self, rec, clock.rate)?;
        if let (Some(x), Some(r), Some(Some(ch))) =
            (clock.exchange, rec.recorder(), self.channels.as_ref().map(|c| c.coupling))
        {
            if self.world.step_count > 0 {
                let t = self.world.time;
                let now = [x.exchanges as f64, clock.wall, x.seconds, 0.0];
                r.log(ch, t, &CouplingTimings::between(t, now, self.coupling_before))?;
                self.coupling_before = now;
            }
        }
        let moving = moving_mass_fraction(&self.world, self.scene.spec.output.rest_speed);
        Ok(FrameReport { moving_fraction: Some(moving), released: self.world.time > self.last_release })
    }

    fn record_state(&mut self, rec: &mut Recording) -> Result<(), RunError> {
        if let (Some(r), Some(ch)) = (rec.recorder(), self.channels.as_ref()) {
            r.log_bytes(ch.state, self.world.time, DemState::capture(&self.world).encode())?;
        }
        Ok(())
    }

    fn checkpoint(&self, out: &mut dyn std::io::Write) -> std::io::Result<()> {
        let c: DemCheckpoint<&Fronts, &PackingReport> = DemCheckpoint {
            state: DemState::capture(&self.world),
            held: self.world.held_loads(),
            fronts: &self.front,
            coordination_initial: self.coordination_initial,
            packing: &self.packing,
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

/// The run's summary: fronts, runouts, deposit, the DEM's details.
fn summary(r: &mut DemRun<'_>, end: &RunEnd) -> RunSummary {
    let (scene, setup, world, rep) = (r.scene, &r.setup, &r.world, &r.packing);
    let (x0, l0) = (scene.spec.domain.min[0], scene.spec.analysis.column_length);
    let wall = end.wall;
    let front = std::mem::take(&mut r.front);
    let final_front = front.all.last().map(|f: &FrontSample| f.x).unwrap_or(f64::NAN);
    let final_connected = front.connected.last().map(|f: &FrontSample| f.x_norm);
    let bin = scene.spec.analysis.deposit_bin.unwrap_or(setup.max_diameter);
    let max_bins = (((scene.spec.domain.max[0] - x0) / bin).ceil() as usize).max(1);
    let g = &world.grains;
    let deposit = deposit_profile((0..g.len()).map(|p| (g.pos[p][0], g.pos[p][2] + g.radius[p])), x0, bin, max_bins);
    // Over this process's steps (a resumed run's from its checkpoint).
    let (first_step, first_time) = end.started_at;
    let particle_steps = (world.step_count - first_step) as f64 * world.len() as f64;
    RunSummary {
        scene: scene.spec.scene.name.clone(),
        method: if r.coupled { "dem_lbm" } else { "dem" }.into(),
        status: end.status,
        sim_time: world.time,
        wall_seconds: wall,
        steps: world.step_count,
        throughput: Throughput {
            particle_steps_per_s: Some(particle_steps / wall.max(1e-9)),
            cell_updates_per_s: None,
            point_updates_per_s: None,
            wall_per_sim_second: wall / (world.time - first_time).max(1e-12),
        },
        t_ref: scene.reference_time(),
        front: front.all,
        runout: (final_front - x0 - l0) / l0,
        runout_pile: front.pile.last().map(|f| f.x_norm),
        front_pile: front.pile,
        front_connected: front.connected,
        runout_connected: final_connected,
        deposit,
        porosity_initial: rep.porosity_bulk,
        dem: Some(DemDetails {
            particles: world.len(),
            time_step: setup.numerics.dt,
            damping_ratio: setup.grain_law.damping_ratio,
            restitution: scene.dem().restitution,
            contact_duration: setup.contact_duration,
            steps_per_contact: setup.steps_per_contact,
            porosity_core: rep.porosity_core,
            initial_height: rep.height,
            packing_from_cache: rep.from_cache,
            deposition_seconds: if rep.from_cache { 0.0 } else { rep.deposition_seconds },
            coordination_initial: r.coordination_initial,
            coordination_final: world.mean_coordination(),
            recording_fraction: end.recording_seconds / wall.max(1e-9),
            threads: rayon::current_num_threads(),
            stage_seconds: schemas::summary::stage_seconds_map(&world.stage_seconds),
        }),
        liquid_front: Vec::new(),
        lbm: None,
        mpm: None,
        wall_seconds_total: None,
        wall_seconds_lbm: None,
        exchange: end.exchange.map(|x| {
            ExchangeSummary::Process(ExchangeDetails {
                schedule: scene.spec.coupling.schedule.name().into(),
                ratio: scene.spec.coupling.ratio,
                exchanges: x.exchanges,
                seconds: x.seconds,
                fraction: x.seconds / wall.max(1e-9),
                kernel_seconds: 0.0,
                forcing_gain: None,
            })
        }),
    }
}

/// Fraction of the grain mass faster than `speed`.
fn moving_mass_fraction(world: &World, speed: f64) -> f64 {
    let g = &world.grains;
    let (mut moving, mut total) = (0.0, 0.0);
    for p in 0..g.len() {
        let v = g.vel[p];
        total += g.mass[p];
        if v[0] * v[0] + v[1] * v[1] + v[2] * v[2] > speed * speed {
            moving += g.mass[p];
        }
    }
    if total > 0.0 {
        moving / total
    } else {
        0.0
    }
}

fn check_blow_up(world: &World, setup: &DemSetup) -> Result<(), RunError> {
    // A grain faster than a free fall through 1000 domain heights has left physics.
    let h = setup.domain.1[2] - setup.domain.0[2];
    let g = world.gravity.iter().map(|x| x * x).sum::<f64>().sqrt().max(1.0);
    let limit = (2.0 * g * 1000.0 * h).sqrt();
    for (p, v) in world.grains.vel.iter().enumerate() {
        let speed = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
        if !speed.is_finite() || speed >= limit {
            return Err(RunError::BlowUp {
                t: world.time,
                grain: world.ids()[p] as usize,
                speed,
                dt: setup.numerics.dt,
                steps_per_contact: setup.steps_per_contact,
            });
        }
    }
    Ok(())
}

/// Front samples of a run: all grains, and grains touching another grain.
#[derive(Default, Clone, Serialize, Deserialize)]
struct Fronts {
    all: Vec<FrontSample>,
    connected: Vec<FrontSample>,
    pile: Vec<FrontSample>,
    /// 1 − n0 of the initial packing (0.6 where it has none), the
    /// flume's width and the bin of the pile's edge, m.
    solid_fraction: f64,
    width: f64,
    bin: f64,
    bins: Vec<f64>,
}

/// Measures one frame (fronts, pile edge) into the run and records it.
fn record_frame(r: &mut DemRun<'_>, rec: &mut Recording, rate: f64) -> Result<(), RecordError> {
    let (world, scene, front) = (&r.world, r.scene, &mut r.front);
    let t_ref = scene.reference_time();
    let g = &world.grains;
    let t = world.time;
    let x0 = scene.spec.domain.min[0];
    let l0 = scene.spec.analysis.column_length;
    let fx = front_position(
        (0..g.len()).map(|p| (g.pos[p][0] + g.radius[p], g.mass[p])),
        scene.spec.analysis.front_mass_fraction,
        &mut r.scratch,
    );
    let fraction = scene.spec.analysis.front_mass_fraction;
    let touching = (0..g.len()).filter(|&p| world.coordination[p] > 0);
    let fc = front_position(touching.map(|p| (g.pos[p][0] + g.radius[p], g.mass[p])), fraction, &mut r.scratch);
    let sample = FrontSample { t, t_norm: t / t_ref, x: fx, x_norm: (fx - x0 - l0) / l0 };
    let connected = FrontSample { t, t_norm: t / t_ref, x: fc, x_norm: (fc - x0 - l0) / l0 };
    let volume = |p: usize| 4.0 / 3.0 * std::f64::consts::PI * g.radius[p].powi(3);
    let pile_x = pile_edge(
        (0..g.len()).map(|p| (g.pos[p][0], volume(p))),
        x0,
        front.bin,
        front.width,
        front.solid_fraction,
        front.bin,
        &mut front.bins,
    );
    front.all.push(sample);
    front.connected.push(connected);
    front.pile.push(FrontSample { t, t_norm: t / t_ref, x: pile_x, x_norm: (pile_x - x0 - l0) / l0 });
    let max_speed = world.max_speed();

    if let (Some(rec), Some(ch)) = (rec.recorder(), r.channels.as_ref()) {
        const STRIDE: usize = 24;
        let mut data = Vec::with_capacity(g.len() * STRIDE);
        for p in 0..g.len() {
            let v = g.vel[p];
            let speed = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
            for x in [g.pos[p][0], g.pos[p][1], g.pos[p][2], g.radius[p], speed, world.coordination[p] as f64] {
                data.extend_from_slice(&(x as f32).to_le_bytes());
            }
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
                f32_field("radius", 12),
                f32_field("speed", 16),
                f32_field("coordination", 20),
            ],
            data: data.into(),
        };
        rec.log(ch.particles, t, &cloud)?;
        if let Some(sph) = ch.spheres {
            let spheres = (0..g.len())
                .map(|p| {
                    let d = 2.0 * g.radius[p];
                    SpherePrimitive {
                        pose: Some(Pose {
                            position: Some(Vector3 { x: g.pos[p][0], y: g.pos[p][1], z: g.pos[p][2] }),
                            orientation: Some(identity_quaternion()),
                        }),
                        size: Some(Vector3 { x: d, y: d, z: d }),
                        color: Some(Color { r: 0.76, g: 0.6, b: 0.42, a: 1.0 }),
                    }
                })
                .collect();
            let update = SceneUpdate {
                deletions: vec![],
                entities: vec![SceneEntity {
                    timestamp: Some(timestamp(t)),
                    frame_id: "world".into(),
                    id: "grains".into(),
                    spheres,
                    ..Default::default()
                }],
            };
            rec.log(sph, t, &update)?;
        }
        let share = coordination_shares(&world.coordination);
        let share = |k: usize| share[k];
        let (momentum, fluid_force) = (world.momentum(), world.external_force_total());
        let metrics = DemMetrics {
            t,
            t_norm: t / t_ref,
            front_x: fx,
            front_norm: sample.x_norm,
            kinetic_energy: world.kinetic_energy(),
            max_speed,
            mean_coordination: world.mean_coordination(),
            particle_steps_per_s: rate,
            front_connected_x: fc,
            front_connected_norm: connected.x_norm,
            coordination_0: share(0),
            coordination_1: share(1),
            coordination_2: share(2),
            coordination_3: share(3),
            coordination_4: share(4),
            coordination_5: share(5),
            coordination_6_or_more: share(6),
            momentum_x: momentum[0],
            momentum_z: momentum[2],
            fluid_force_x: fluid_force[0],
            fluid_force_z: fluid_force[2],
            fluid_impulse_x: world.external_impulse[0],
            fluid_impulse_z: world.external_impulse[2],
        };
        rec.log(ch.metrics, t, &metrics)?;
    }
    Ok(())
}
