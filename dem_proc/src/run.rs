//! A whole DEM run: packing, gate release, collapse to rest or end time, with
//! recording and the measures of the summary.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use foxglove::schemas::{Color, Log, PointCloud, Pose, SceneEntity, SceneUpdate, SpherePrimitive, Vector3};
use serde::{Deserialize, Serialize};

use runtime::metrics::{CouplingTimings, DemMetrics};
use runtime::process::RunOptions;
use runtime::record::{
    f32_field, identity_pose, identity_quaternion, log_entry, log_level, timestamp, ChannelId, RecordError, Recorder,
    RecorderBuilder,
};
use schemas::measures::{coordination_shares, deposit_profile, front_position, pile_edge, FrontSample};
use schemas::scene::Scene;
use schemas::summary::{DemDetails, ExchangeDetails, RunStatus, RunSummary, Throughput};
use schemas::topics;

use crate::hydro::{Connect, Flow, HydroExchange};
use crate::packing::{self, Packing, PackingError};
use crate::setup::{walls, DemSetup};
use crate::world::{Grains, Histories, World};

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

/// How the run reports progress to whoever launched it.
pub trait Progress {
    fn deposition(&mut self, t: f64, t_max: f64);
    fn collapse(&mut self, t: f64, t_end: f64, steps: u64);
    fn log(&mut self, message: &str);
}

struct Channels {
    particles: ChannelId,
    spheres: Option<ChannelId>,
    metrics: ChannelId,
    state: ChannelId,
    log: ChannelId,
    /// `/dem/received_loads` (`output.record_exchange` in a coupled run).
    received: Option<ChannelId>,
    /// `/dem/coupling` (coupled runs).
    coupling: Option<ChannelId>,
}

struct Frames {
    recorder: Option<Recorder>,
    channels: Option<Channels>,
    seconds: f64,
    scratch: Vec<(f64, f64)>,
}

impl Frames {
    fn log(&mut self, t: f64, level: i32, message: &str) -> Result<(), RecordError> {
        if let (Some(r), Some(c)) = (self.recorder.as_mut(), self.channels.as_ref()) {
            r.log(c.log, t, &log_entry(t, level, "dem_proc", message))?;
        }
        Ok(())
    }
}

/// Consecutive recorded frames at rest that end a run early.
pub const REST_FRAMES: u32 = 3;

/// Where `dem_proc` writes its recording and its summary.
pub fn output_paths(out_dir: &Path) -> (PathBuf, PathBuf) {
    (out_dir.join("dem.mcap"), out_dir.join("dem_summary.json"))
}

/// Runs the scene. `stop` is polled every step; when set the run ends at the
/// step boundary with status `interrupted` and a complete recording.
///
/// With `connect` (a coupled scene), the peer is connected once the packing
/// is ready; then every `coupling.ratio`-th step exchanges grain states for
/// hydrodynamic loads ([`HydroExchange`]); at the end the peer gets the stop flag.
pub fn run(
    scene: &Scene,
    opts: &RunOptions,
    stop: &AtomicBool,
    progress: &mut dyn Progress,
    connect: Option<Connect<'_>>,
) -> Result<RunSummary, RunError> {
    let setup = DemSetup::from_scene(scene);
    let t_ref = scene.reference_time();
    let l0 = scene.spec.analysis.column_length;
    let x0 = scene.spec.domain.min[0];
    let out = &scene.spec.output;

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
    let packing = packing::build(scene, &setup, stop, |t, tmax| progress.deposition(t, tmax))?;
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

    let mut world = collapse_world(scene, &setup, &packing);
    let coordination_initial = world.mean_coordination();
    let mut peer = match connect {
        Some(c) => {
            progress.log(&format!("connecting to lbm_proc with {} grains", world.len()));
            Some(c(world.len()).map_err(|source| RunError::Peer { t: 0.0, source })?)
        }
        None => None,
    };

    std::fs::create_dir_all(&opts.out_dir).map_err(|source| RunError::Io { path: opts.out_dir.clone(), source })?;
    let (mcap_path, summary_path) = output_paths(&opts.out_dir);
    let mut frames = Frames { recorder: None, channels: None, seconds: 0.0, scratch: Vec::new() };
    if opts.record {
        let mut b = RecorderBuilder::create(&mcap_path, 8 << 20)?;
        let mut state_meta = BTreeMap::new();
        state_meta.insert("encoding".into(), format!("bincode 2 (serde, standard config) of dem_proc::run::DemState version {STATE_VERSION}; see docs/recording.md"));
        let channels = Channels {
            particles: b.channel::<PointCloud>(topics::DEM_PARTICLES)?,
            spheres: if out.spheres { Some(b.channel::<SceneUpdate>(topics::DEM_SPHERES)?) } else { None },
            metrics: b.channel::<DemMetrics>(topics::DEM_METRICS)?,
            state: b.raw_channel(topics::DEM_STATE, "bincode", state_meta)?,
            log: b.channel::<Log>(topics::LOG)?,
            coupling: if peer.is_some() { Some(b.channel::<CouplingTimings>(topics::DEM_COUPLING)?) } else { None },
            received: if peer.is_some() && out.record_exchange {
                let meta = BTreeMap::from([("encoding".to_string(), runtime::exchange::RECEIVED_ENCODING.to_string())]);
                Some(b.raw_channel(topics::DEM_RECEIVED_LOADS, "sgf-exchange", meta)?)
            } else {
                None
            },
        };
        let mut rec = b.start(64);
        rec.scene(scene.to_toml())?;
        frames.recorder = Some(rec);
        frames.channels = Some(channels);
    }

    let dt = setup.numerics.dt;
    let steps_per_frame = ((out.record_interval / dt).round() as u64).max(1);
    let steps_per_state = ((out.state_interval.unwrap_or(5.0 * out.record_interval) / dt).round() as u64).max(1);
    let total_steps = (out.end_time / dt).ceil() as u64;
    let last_release = world.walls.iter().map(|w| w.release_time).filter(|t| t.is_finite()).fold(0.0, f64::max);

    let mut front = Fronts {
        solid_fraction: if rep.porosity_bulk.is_finite() { 1.0 - rep.porosity_bulk } else { 0.6 },
        width: scene.spec.domain.max[1] - scene.spec.domain.min[1],
        bin: setup.max_diameter,
        ..Fronts::default()
    };
    let started = Instant::now();
    let mut last_frame = (Instant::now(), 0u64);
    let mut last_progress = Instant::now();
    let mut status = RunStatus::Completed;
    let mut last_recorded_step = 0u64;
    let mut last_state_step = 0u64;
    // Frames in a row that met the rest criterion: one is not enough, a
    // bouncing grain is momentarily still at the top of each bounce.
    let mut frames_at_rest = 0;
    let mut has_moved = false;
    for line in &early_log {
        frames.log(0.0, log_level::INFO, line)?;
    }
    frames.log(
        0.0,
        log_level::INFO,
        &format!("collapse starts with {} grains, porosity {:.4}", world.len(), rep.porosity_bulk),
    )?;
    record_frame(&mut frames, &world, scene, t_ref, &mut front, 0.0, true)?;

    let mut hydro = peer.is_some().then(|| HydroExchange::from_scene(scene, dt));
    // Cumulative (exchanges, wall s, wait s, coupling s) at the last frame.
    let mut coupling_before = [0.0; 4];
    if let Some(h) = hydro.as_mut() {
        h.record_received = frames.channels.as_ref().is_some_and(|c| c.received.is_some());
    }
    let mut failure = None;
    while world.step_count < total_steps {
        if let (Some(h), Some(p)) = (hydro.as_mut(), peer.as_deref_mut()) {
            if h.due(&world) {
                let result = h.exchange(&mut world, p);
                if let (Some(rec), Some(Some(ch))) =
                    (frames.recorder.as_mut(), frames.channels.as_ref().map(|c| c.received))
                {
                    for (t, bytes) in h.received.drain(..) {
                        rec.log_bytes(ch, t, bytes)?;
                    }
                }
                match result {
                    Ok(Flow::Continue) => {}
                    Ok(Flow::PeerStopped) => {
                        status = RunStatus::PeerStopped;
                        frames.log(world.time, log_level::WARNING, "lbm_proc stopped; recording the last state")?;
                        break;
                    }
                    // Ctrl-C reaches both processes: waiting for the LBM ends with it.
                    Err(_) if stop.load(Ordering::Relaxed) => {
                        status = RunStatus::Interrupted;
                        frames.log(
                            world.time,
                            log_level::WARNING,
                            "interrupted by signal; recording the last state",
                        )?;
                        break;
                    }
                    Err(source) => {
                        status = RunStatus::PeerFailed;
                        frames.log(world.time, log_level::ERROR, &format!("exchange: {source}"))?;
                        failure = Some(RunError::Peer { t: world.time, source });
                        break;
                    }
                }
            }
        }
        world.step();
        let s = world.step_count;
        if stop.load(Ordering::Relaxed) {
            status = RunStatus::Interrupted;
            frames.log(world.time, log_level::WARNING, "interrupted by signal; recording the last state")?;
            break;
        }
        if s.is_multiple_of(steps_per_frame) {
            let elapsed = last_frame.0.elapsed().as_secs_f64();
            let rate = (s - last_frame.1) as f64 * world.len() as f64 / elapsed.max(1e-9);
            last_frame = (Instant::now(), s);
            let with_state = s.is_multiple_of(steps_per_state);
            record_frame(&mut frames, &world, scene, t_ref, &mut front, rate, with_state)?;
            if let (Some(h), Some(rec), Some(Some(ch))) =
                (hydro.as_ref(), frames.recorder.as_mut(), frames.channels.as_ref().map(|c| c.coupling))
            {
                let now = [h.exchanges as f64, started.elapsed().as_secs_f64(), h.exchange_seconds, 0.0];
                rec.log(ch, world.time, &CouplingTimings::between(world.time, now, coupling_before))?;
                coupling_before = now;
            }
            last_recorded_step = s;
            if with_state {
                last_state_step = s;
            }
            check_blow_up(&world, &setup)?;
            let moving = moving_mass_fraction(&world, out.rest_speed);
            // The grains start at rest: only a stop after they have moved counts.
            has_moved |= moving > out.rest_fraction;
            if out.stop_at_rest && has_moved && world.time > last_release && moving <= out.rest_fraction {
                frames_at_rest += 1;
                if frames_at_rest >= REST_FRAMES {
                    status = RunStatus::AtRest;
                    break;
                }
            } else {
                frames_at_rest = 0;
            }
        }
        if last_progress.elapsed().as_secs_f64() > 0.5 {
            progress.collapse(world.time, out.end_time, s);
            last_progress = Instant::now();
        }
    }
    if let (Some(h), Some(p), None) = (hydro.as_mut(), peer.as_deref_mut(), failure.as_ref()) {
        if status != RunStatus::PeerStopped {
            if let Err(source) = h.finish(&world, p) {
                frames.log(world.time, log_level::WARNING, &format!("could not tell lbm_proc to stop: {source}"))?;
            }
        }
    }
    let wall = started.elapsed().as_secs_f64();
    progress.collapse(world.time, out.end_time, world.step_count);
    // The run always ends with a recorded frame and a full state.
    if last_recorded_step != world.step_count {
        record_frame(&mut frames, &world, scene, t_ref, &mut front, 0.0, true)?;
    } else if last_state_step != world.step_count {
        if let (Some(rec), Some(ch)) = (frames.recorder.as_mut(), frames.channels.as_ref()) {
            rec.log_bytes(ch.state, world.time, DemState::capture(&world).encode())?;
        }
    }

    let final_front = front.all.last().map(|f: &FrontSample| f.x).unwrap_or(f64::NAN);
    let final_connected = front.connected.last().map(|f: &FrontSample| f.x_norm);
    let bin = scene.spec.analysis.deposit_bin.unwrap_or(setup.max_diameter);
    let max_bins = (((scene.spec.domain.max[0] - x0) / bin).ceil() as usize).max(1);
    let g = &world.grains;
    let deposit = deposit_profile((0..g.len()).map(|p| (g.pos[p][0], g.pos[p][2] + g.radius[p])), x0, bin, max_bins);
    let particle_steps = world.step_count as f64 * world.len() as f64;
    let summary = RunSummary {
        scene: scene.spec.scene.name.clone(),
        method: if hydro.is_some() { "dem_lbm" } else { "dem" }.into(),
        status,
        sim_time: world.time,
        wall_seconds: wall,
        steps: world.step_count,
        throughput: Throughput {
            particle_steps_per_s: Some(particle_steps / wall.max(1e-9)),
            cell_updates_per_s: None,
            point_updates_per_s: None,
            wall_per_sim_second: wall / world.time.max(1e-12),
        },
        t_ref,
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
            time_step: dt,
            damping_ratio: setup.grain_law.damping_ratio,
            restitution: scene.dem().restitution,
            contact_duration: setup.contact_duration,
            steps_per_contact: setup.steps_per_contact,
            porosity_core: rep.porosity_core,
            initial_height: rep.height,
            packing_from_cache: rep.from_cache,
            deposition_seconds: if rep.from_cache { 0.0 } else { rep.deposition_seconds },
            coordination_initial,
            coordination_final: world.mean_coordination(),
            recording_fraction: frames.seconds / wall.max(1e-9),
            threads: rayon::current_num_threads(),
            stage_seconds: schemas::summary::stage_seconds_map(&world.stage_seconds),
        }),
        liquid_front: Vec::new(),
        lbm: None,
        mpm: None,
        wall_seconds_total: None,
        exchange: hydro.as_ref().map(|h| ExchangeDetails {
            schedule: h.schedule.name().into(),
            ratio: h.ratio as u32,
            exchanges: h.exchanges,
            seconds: h.exchange_seconds,
            fraction: h.exchange_seconds / wall.max(1e-9),
            kernel_seconds: 0.0,
            forcing_gain: None,
        }),
    };
    let json = serde_json::to_string_pretty(&summary).expect("summary serialises");
    frames.log(
        world.time,
        log_level::INFO,
        &format!("run {status}: t = {:.4} s, runout {:.4}", world.time, summary.runout),
    )?;
    if let Some(rec) = frames.recorder.take() {
        rec.finish_with_summary(json.clone())?;
    }
    std::fs::write(&summary_path, json).map_err(|source| RunError::Io { path: summary_path.clone(), source })?;
    match failure {
        Some(e) => Err(e),
        None => Ok(summary),
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

/// Records one frame; returns the largest grain speed.
/// Front samples of a run: all grains, and grains touching another grain.
#[derive(Default)]
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

fn record_frame(
    frames: &mut Frames,
    world: &World,
    scene: &Scene,
    t_ref: f64,
    front: &mut Fronts,
    rate: f64,
    with_state: bool,
) -> Result<f64, RecordError> {
    let started = Instant::now();
    let g = &world.grains;
    let t = world.time;
    let x0 = scene.spec.domain.min[0];
    let l0 = scene.spec.analysis.column_length;
    let fx = front_position(
        (0..g.len()).map(|p| (g.pos[p][0] + g.radius[p], g.mass[p])),
        scene.spec.analysis.front_mass_fraction,
        &mut frames.scratch,
    );
    let fraction = scene.spec.analysis.front_mass_fraction;
    let touching = (0..g.len()).filter(|&p| world.coordination[p] > 0);
    let fc = front_position(touching.map(|p| (g.pos[p][0] + g.radius[p], g.mass[p])), fraction, &mut frames.scratch);
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

    if let (Some(rec), Some(ch)) = (frames.recorder.as_mut(), frames.channels.as_ref()) {
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
        if with_state {
            rec.log_bytes(ch.state, t, DemState::capture(world).encode())?;
        }
    }
    frames.seconds += started.elapsed().as_secs_f64();
    Ok(max_speed)
}
