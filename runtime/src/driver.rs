//! The one run loop every solver process uses.
//!
//! A solver ([`Solver`]) knows how to take one step, check itself for a
//! blow-up, record a frame and a full state, and summarise the run.
//! [`drive`] owns everything around that, the same for the DEM, the LBM
//! and the MPM: the exchange with a coupled peer ([`StepExchange`], see
//! [`crate::coupled`]), the stop flag, the recording cadence of frames and
//! states, rest detection, the typed [`RunStatus`] the run ends with, the
//! last frame and state, progress, and writing the summary (into the
//! recording's metadata and beside it).
//!
//! Order of one iteration, fixed here so that it cannot drift between
//! solvers (restart and resume hook in here as well):
//! 1. coupled: the half of the exchange before the step
//!    ([`StepExchange::before_step`]); the peer may end the run
//!    ([`Flow::Stop`], [`StepError::Peer`]);
//! 2. [`Solver::step`]; coupled, the answer to the peer
//!    ([`StepExchange::after_step`]); then [`Solver::finish_step`], the
//!    part of the step the peer does not wait for;
//! 3. the stop flag (SIGINT/SIGTERM): status `interrupted`, the peer told
//!    ([`StepExchange::interrupted`]);
//! 4. at every `steps_per_frame`-th step: [`Solver::check`] (a blow-up
//!    ends the run `unstable`), [`Solver::record_frame`], the state at
//!    every `steps_per_state`-th step, then rest detection;
//! 5. at every `steps_per_checkpoint`-th step, a checkpoint
//!    ([`crate::checkpoint`]): the loop's own state, the exchange's and
//!    [`Solver::checkpoint`];
//! 6. progress, at most every half second of wall time (and once as the
//!    loop begins).
//!
//! A run resumed from a checkpoint ([`Checkpoints::resumed`]) enters the
//! loop as the interrupted run left it after step 5: no first frame (that
//! run recorded it), the same counters, so that it records the same
//! frames and states and ends in the same state, bit for bit.
//!
//! After the loop: the peer told the run stops ([`StepExchange::finish`]),
//! a last frame unless the run failed or the last step was just recorded,
//! a last state unless it was just recorded, then the summary.

use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use schemas::summary::{RunStatus, RunSummary};

use crate::checkpoint::{CheckpointWriter, DriverState, ExchangeState};
use crate::coupled::{Coupled, Exchange, ExchangeFailure, ExchangeFigures};
use crate::record::{log_entry, log_level, ChannelId, RecordError, Recorder, RecorderBuilder};

/// A run's recording as the solver sees it: absent under `--no-record`.
#[derive(Debug)]
pub struct Recording {
    recorder: Option<Recorder>,
    log: Option<ChannelId>,
    source: &'static str,
    /// Wall seconds spent recording frames and states.
    pub seconds: f64,
}

impl Recording {
    /// No recording (`--no-record`, benchmarks): frames are still measured.
    pub fn off(source: &'static str) -> Self {
        Self { recorder: None, log: None, source, seconds: 0.0 }
    }

    /// Records into `recorder`, with `/log` entries named `source` on `log`.
    pub fn on(recorder: Recorder, log: ChannelId, source: &'static str) -> Self {
        Self { recorder: Some(recorder), log: Some(log), source, seconds: 0.0 }
    }

    /// The recording of a run: when `record`, creates `path`, lets
    /// `channels` register the solver's channels, adds `/log` (entries
    /// named `source`), starts the writer thread with `queue` frames of
    /// slack and records the scene as run. Returns the solver's channels
    /// alongside (None when not recording).
    pub fn open<C>(
        record: bool,
        path: &Path,
        source: &'static str,
        scene: &schemas::Scene,
        queue: usize,
        channels: impl FnOnce(&mut RecorderBuilder) -> Result<C, RecordError>,
    ) -> Result<(Self, Option<C>), RecordError> {
        if !record {
            return Ok((Self::off(source), None));
        }
        let mut b = RecorderBuilder::create(path, 8 << 20)?;
        let solver_channels = channels(&mut b)?;
        let log = b.channel::<foxglove::schemas::Log>(schemas::topics::LOG)?;
        let mut recorder = b.start(queue);
        recorder.scene(scene.to_toml())?;
        Ok((Self::on(recorder, log, source), Some(solver_channels)))
    }

    /// The recorder, when recording.
    pub fn recorder(&mut self) -> Option<&mut Recorder> {
        self.recorder.as_mut()
    }

    /// A `/log` entry at simulated time `t` (nothing when not recording).
    pub fn log(&mut self, t: f64, level: i32, message: &str) -> Result<(), RecordError> {
        if let (Some(r), Some(c)) = (self.recorder.as_mut(), self.log) {
            r.log(c, t, &log_entry(t, level, self.source, message))?;
        }
        Ok(())
    }

    fn finish_with_summary(&mut self, json: String) -> Result<(), RecordError> {
        if let Some(rec) = self.recorder.take() {
            rec.finish_with_summary(json)?;
        }
        Ok(())
    }
}

/// Whether the run goes on after a step.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Flow {
    Continue,
    /// The run ends here with this status (a coupled peer announced its
    /// stop): no failure, the last frame and state are recorded.
    Stop(RunStatus),
}

/// Why a step failed.
#[derive(Debug)]
pub enum StepError<E> {
    /// The exchange with the peer failed: status `peer_failed`, or
    /// `interrupted` when the stop flag is up (a Ctrl-C reaches both
    /// processes, so the peer's going is no failure then). The last frame
    /// and state are recorded and the summary written.
    Peer(E),
    /// Anything else: the run ends at once with this error.
    Fatal(E),
}

impl<E> From<RecordError> for StepError<E>
where
    E: From<RecordError>,
{
    fn from(e: RecordError) -> Self {
        StepError::Fatal(e.into())
    }
}

/// What a recorded frame tells the driver.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FrameReport {
    /// Mass fraction moving faster than `output.rest_speed`; None for a
    /// solver that never stops at rest (the liquid alone).
    pub moving_fraction: Option<f64>,
    /// Whether rest may count yet (every gate released).
    pub released: bool,
}

/// Wall-clock figures handed to a frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FrameClock {
    /// Work units (grains, cells, points) per wall second since the last frame.
    pub rate: f64,
    /// Wall seconds since the loop started.
    pub wall: f64,
    /// The exchange's totals so far, when coupled.
    pub exchange: Option<ExchangeFigures>,
}

/// How the run ended, for the summary.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RunEnd {
    pub status: RunStatus,
    /// Wall seconds of the loop.
    pub wall: f64,
    /// Work units done by this loop (Σ [`Solver::work_per_step`]; a
    /// resumed run's loop counts from its checkpoint).
    pub work: f64,
    /// The solver's step count and time when this loop began (0, or a
    /// resumed run's checkpoint): rates are over the steps since.
    pub started_at: (u64, f64),
    /// Wall seconds spent recording.
    pub recording_seconds: f64,
    /// The exchange's totals, when coupled.
    pub exchange: Option<ExchangeFigures>,
}

/// The recording cadence and the length of the run, in steps.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Cadence {
    pub steps_per_frame: u64,
    /// None: states only at the start (if [`Cadence::state_at_start`]) and the end.
    pub steps_per_state: Option<u64>,
    /// The loop stops when the solver's step count reaches it.
    pub step_limit: u64,
    /// Record a state with the first frame.
    pub state_at_start: bool,
    /// None: no checkpoints.
    pub steps_per_checkpoint: Option<u64>,
}

impl Cadence {
    /// Steps of `dt` per `interval`, at least 1.
    pub fn steps_in(interval: f64, dt: f64) -> u64 {
        ((interval / dt).round() as u64).max(1)
    }
}

/// A run's checkpoints: where they go, and the one it continues from.
#[derive(Debug, Default)]
pub struct Checkpoints {
    /// Writes one every [`Cadence::steps_per_checkpoint`] steps.
    pub writer: Option<CheckpointWriter>,
    /// The loop's state in the checkpoint this run continues from (the
    /// solver and the exchange were restored by their owners).
    pub resumed: Option<DriverState>,
}

/// When a run ends at rest: `frames` recorded frames in a row with at most
/// `fraction` of the mass moving, once it has moved and every gate is
/// released (one frame is not enough: a bouncing grain is momentarily
/// still at the top of each bounce).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RestRule {
    pub stop_at_rest: bool,
    pub fraction: f64,
    pub frames: u32,
}

/// Consecutive recorded frames at rest that end a run early.
pub const REST_FRAMES: u32 = 3;

impl RestRule {
    /// `output.stop_at_rest` and `output.rest_fraction` of a scene.
    pub fn of(output: &schemas::scene::OutputSpec) -> Self {
        Self { stop_at_rest: output.stop_at_rest, fraction: output.rest_fraction, frames: REST_FRAMES }
    }
}

/// A solver as the driver steps it.
pub trait Solver {
    type Error: From<RecordError> + std::fmt::Display;

    /// Simulated time, s.
    fn time(&self) -> f64;
    /// Steps taken.
    fn steps(&self) -> u64;
    /// Work units (grains, active cells, points) the next step does.
    fn work_per_step(&self) -> f64;
    /// One step (coupled: the part whose result the peer waits for).
    fn step(&mut self, rec: &mut Recording) -> Result<Flow, StepError<Self::Error>>;
    /// The rest of the step, after a coupled solver's answer has gone (the
    /// LBM's free-surface conversions, which do not change the loads,
    /// overlap the DEM's steps).
    fn finish_step(&mut self, _rec: &mut Recording) -> Result<(), StepError<Self::Error>> {
        Ok(())
    }
    /// A reason to stop the run as `unstable`, checked before each frame.
    fn check(&self) -> Result<(), Self::Error>;
    /// Measures and records one frame.
    fn record_frame(&mut self, rec: &mut Recording, clock: FrameClock) -> Result<FrameReport, Self::Error>;
    /// Records the full state (`/…/state`).
    fn record_state(&mut self, rec: &mut Recording) -> Result<(), Self::Error>;
    /// The solver's part of a checkpoint: everything a run continued from
    /// it needs to end in the same state, bit for bit, and to write the
    /// same summary (the state, held loads, what the frames gathered).
    /// Writes it into `out` (streamed: a lattice's state is not copied).
    fn checkpoint(&self, out: &mut dyn std::io::Write) -> std::io::Result<()>;
    /// The run's summary.
    fn summary(&mut self, end: &RunEnd) -> RunSummary;
    /// The `/log` line that closes the run.
    fn closing_line(&self, s: &RunSummary) -> String {
        format!("run {}: t = {:.4} s, {} steps, runout {:.4}", s.status, s.sim_time, s.steps, s.runout)
    }
    /// `summary.json` could not be written.
    fn cannot_write(path: &Path, source: std::io::Error) -> Self::Error;
}

/// The exchange with a coupled peer as the driver calls it: the halves
/// around the solver's step and the messages at the end of a run
/// ([`Exchange`] for any [`Coupled`] solver).
pub trait StepExchange<S: Solver> {
    /// Before the step: send and/or receive, as the side requires.
    fn before_step(&mut self, solver: &mut S, rec: &mut Recording) -> Result<Flow, StepError<S::Error>>;
    /// After the step: the answer, for a side that receives first.
    fn after_step(&mut self, solver: &mut S) -> Result<(), StepError<S::Error>>;
    /// The stop flag ended the run.
    fn interrupted(&mut self, time: f64);
    /// After the loop, before the last frame.
    fn finish(&mut self, solver: &mut S, status: RunStatus, failed: bool, rec: &mut Recording) -> Result<(), S::Error>;
    /// Totals so far.
    fn figures(&self) -> ExchangeFigures;
    /// Its position, for a checkpoint.
    fn state(&self) -> ExchangeState;
}

impl<C> StepExchange<C> for Exchange<'_, C::Sends, C::Receives>
where
    C: Coupled,
    C::Error: From<ExchangeFailure>,
{
    fn before_step(&mut self, solver: &mut C, rec: &mut Recording) -> Result<Flow, StepError<C::Error>> {
        Exchange::before_step(self, solver, rec)
    }
    fn after_step(&mut self, solver: &mut C) -> Result<(), StepError<C::Error>> {
        Exchange::after_step(self, solver).map_err(|e| StepError::Peer(e.into()))
    }
    fn interrupted(&mut self, time: f64) {
        Exchange::interrupted(self, time);
    }
    fn finish(&mut self, solver: &mut C, status: RunStatus, failed: bool, rec: &mut Recording) -> Result<(), C::Error> {
        Ok(Exchange::finish(self, solver, status, failed, rec)?)
    }
    fn figures(&self) -> ExchangeFigures {
        Exchange::figures(self)
    }
    fn state(&self) -> ExchangeState {
        Exchange::state(self)
    }
}

/// Runs `solver` to its step limit, to rest, to a stop or a failure (see
/// the module docs for the order), then writes the summary into the
/// recording and to `summary_path`. Returns the summary, or the failure
/// the run ended with once the summary is written.
pub fn drive<'x, S: Solver>(
    solver: &mut S,
    mut exchange: Option<&mut (dyn StepExchange<S> + 'x)>,
    rec: &mut Recording,
    cadence: Cadence,
    rest: RestRule,
    checkpoints: &mut Checkpoints,
    stop: &AtomicBool,
    progress: &mut dyn FnMut(f64, u64),
    summary_path: &Path,
) -> Result<RunSummary, S::Error> {
    let mut status = RunStatus::Completed;
    let mut failure: Option<S::Error> = None;
    let started = Instant::now();
    let mut last_progress = Instant::now();
    let started_at = (solver.steps(), solver.time());
    let mut work = 0.0_f64;
    let DriverState { mut last_recorded, mut last_state, mut frames_at_rest, mut has_moved, .. } =
        match checkpoints.resumed {
            Some(state) => state,
            None => {
                let clock0 = FrameClock { rate: 0.0, wall: 0.0, exchange: exchange.as_deref().map(|x| x.figures()) };
                record(rec, |rec| solver.record_frame(rec, clock0))?;
                if cadence.state_at_start {
                    record(rec, |rec| solver.record_state(rec))?;
                }
                DriverState {
                    steps: solver.steps(),
                    time: solver.time(),
                    last_recorded: solver.steps(),
                    last_state: cadence.state_at_start.then(|| solver.steps()),
                    frames_at_rest: 0,
                    has_moved: false,
                }
            }
        };
    let mut last_frame = (Instant::now(), work);
    // At once, not after the first half second: a supervisor learns that
    // the run loop (and its recording) has begun.
    progress(solver.time(), solver.steps());
    // Only a run alone: a coupled process's waiter, spinning on after its
    // turn, took 5-6 % from the peer's (docs/BENCHMARKS.md, session 41).
    let awake = exchange.is_none().then(crate::process::AwakeWorkers::new);
    while solver.steps() < cadence.step_limit {
        if let Some(awake) = &awake {
            awake.keep_awake();
        }
        let step_work = solver.work_per_step();
        match step_once(solver, exchange.as_deref_mut(), rec) {
            Ok(Flow::Continue) => work += step_work,
            Ok(Flow::Stop(s)) => {
                status = s;
                break;
            }
            Err(StepError::Peer(e)) => {
                if stop.load(Ordering::Relaxed) {
                    status = RunStatus::Interrupted;
                    rec.log(solver.time(), log_level::WARNING, "interrupted by signal; recording the last state")?;
                } else {
                    status = RunStatus::PeerFailed;
                    rec.log(solver.time(), log_level::ERROR, &format!("exchange: {e}"))?;
                    failure = Some(e);
                }
                break;
            }
            Err(StepError::Fatal(e)) => return Err(e),
        }
        let (t, steps) = (solver.time(), solver.steps());
        if stop.load(Ordering::Relaxed) {
            status = RunStatus::Interrupted;
            rec.log(t, log_level::WARNING, "interrupted by signal; recording the last state")?;
            if let Some(x) = exchange.as_deref_mut() {
                x.interrupted(t);
            }
            break;
        }
        if steps.is_multiple_of(cadence.steps_per_frame) {
            if let Err(e) = solver.check() {
                status = RunStatus::Unstable;
                rec.log(t, log_level::ERROR, &e.to_string())?;
                failure = Some(e);
                break;
            }
            let clock = frame_clock(&mut last_frame, work, started, exchange.as_deref());
            let report = record(rec, |rec| solver.record_frame(rec, clock))?;
            last_recorded = steps;
            if cadence.steps_per_state.is_some_and(|n| steps.is_multiple_of(n)) {
                record(rec, |rec| solver.record_state(rec))?;
                last_state = Some(steps);
            }
            if let Some(moving) = report.moving_fraction {
                // The mass starts at rest: only a stop after it has moved counts.
                has_moved |= moving > rest.fraction;
                frames_at_rest =
                    if report.released && has_moved && moving <= rest.fraction { frames_at_rest + 1 } else { 0 };
                if rest.stop_at_rest && frames_at_rest >= rest.frames {
                    status = RunStatus::AtRest;
                    rec.log(t, log_level::INFO, "at rest")?;
                    break;
                }
            }
        }
        if let (Some(writer), Some(every)) = (checkpoints.writer.as_mut(), cadence.steps_per_checkpoint) {
            if steps.is_multiple_of(every) {
                let state = DriverState { steps, time: t, last_recorded, last_state, frames_at_rest, has_moved };
                let position = exchange.as_deref().map(|x| x.state());
                if let Some(r) = rec.recorder() {
                    r.sync()?;
                }
                writer.write(state, position, |out| solver.checkpoint(out)).map_err(RecordError::from)?;
            }
        }
        if last_progress.elapsed().as_secs_f64() > 0.5 {
            progress(t, steps);
            last_progress = Instant::now();
        }
    }
    if let Some(x) = exchange.as_deref_mut() {
        x.finish(solver, status, failure.is_some(), rec)?;
    }
    let wall = started.elapsed().as_secs_f64();
    let steps = solver.steps();
    progress(solver.time(), steps);
    // The run always ends with a recorded frame and a full state (after a
    // blow-up the state, not a frame, shows it).
    if last_recorded != steps && failure.is_none() {
        let clock = frame_clock(&mut last_frame, work, started, exchange.as_deref());
        record(rec, |rec| solver.record_frame(rec, clock))?;
    }
    if last_state != Some(steps) {
        record(rec, |rec| solver.record_state(rec))?;
    }
    let figures = exchange.as_deref().map(|x| x.figures());
    let end = RunEnd { status, wall, work, started_at, recording_seconds: rec.seconds, exchange: figures };
    let summary = solver.summary(&end);
    let json = serde_json::to_string_pretty(&summary).expect("summary serialises");
    rec.log(summary.sim_time, log_level::INFO, &solver.closing_line(&summary))?;
    rec.finish_with_summary(json.clone())?;
    std::fs::write(summary_path, json).map_err(|e| S::cannot_write(summary_path, e))?;
    match failure {
        Some(e) => Err(e),
        None => Ok(summary),
    }
}

/// The clock of a frame recorded now; `last_frame` (when, work done) moves here.
fn frame_clock<S: Solver>(
    last_frame: &mut (Instant, f64),
    work: f64,
    started: Instant,
    exchange: Option<&dyn StepExchange<S>>,
) -> FrameClock {
    let elapsed = last_frame.0.elapsed().as_secs_f64();
    let clock = FrameClock {
        rate: (work - last_frame.1) / elapsed.max(1e-9),
        wall: started.elapsed().as_secs_f64(),
        exchange: exchange.map(|x| x.figures()),
    };
    *last_frame = (Instant::now(), work);
    clock
}

/// One iteration's step with the exchange around it (steps 1–2 of the
/// module docs). The last part of the step is done even when the answer
/// failed: the lattice stepped, only the peer did not hear of it.
fn step_once<'x, S: Solver>(
    solver: &mut S,
    mut exchange: Option<&mut (dyn StepExchange<S> + 'x)>,
    rec: &mut Recording,
) -> Result<Flow, StepError<S::Error>> {
    if let Some(x) = exchange.as_deref_mut() {
        if let Flow::Stop(s) = x.before_step(solver, rec)? {
            return Ok(Flow::Stop(s));
        }
    }
    if let Flow::Stop(s) = solver.step(rec)? {
        return Ok(Flow::Stop(s));
    }
    let answered = exchange.map_or(Ok(()), |x| x.after_step(solver));
    let finished = solver.finish_step(rec);
    answered.and(finished).map(|()| Flow::Continue)
}

/// Runs a recording call, adding its wall time to [`Recording::seconds`].
fn record<T, E>(rec: &mut Recording, f: impl FnOnce(&mut Recording) -> Result<T, E>) -> Result<T, E> {
    let started = Instant::now();
    let out = f(rec);
    rec.seconds += started.elapsed().as_secs_f64();
    out
}

#[cfg(test)]
mod tests {
    //! The loop's state machine on a toy solver: a point mass whose speed
    //! follows a script, so that every way a run ends can be forced.

    use super::*;
    use crate::coupled::Side;
    use crate::exchange::{Peer, PeerError};
    use schemas::messages::{ExchangeHeader, HydroLoad, ParticleState};
    use schemas::summary::Throughput;

    #[derive(Debug, thiserror::Error)]
    enum ToyError {
        #[error(transparent)]
        Record(#[from] RecordError),
        #[error("blew up at step {0}")]
        BlowUp(u64),
        #[error("peer gone at step {0}")]
        Peer(u64),
        #[error("cannot write {0}")]
        Io(String),
        #[error("{0}")]
        Exchange(String),
    }

    /// `speed(step)` is the moving mass fraction recorded at `step`;
    /// `blow_up_at`, `peer_fails_at`, `peer_stops_at` and `raise_stop_at`
    /// force the other endings.
    struct Toy<'a> {
        steps: u64,
        dt: f64,
        speed: fn(u64) -> f64,
        released_after: u64,
        blow_up_at: Option<u64>,
        peer_fails_at: Option<u64>,
        peer_stops_at: Option<u64>,
        raise_stop_at: Option<(u64, &'a AtomicBool)>,
        frames: Vec<u64>,
        states: Vec<u64>,
        /// Coupled: (step, exchange of the header, load held) at each exchange.
        held: Vec<(u64, u64, f64)>,
        /// Coupled: the exchange totals the last frame was handed.
        frame_figures: Option<ExchangeFigures>,
    }

    impl<'a> Toy<'a> {
        fn new(speed: fn(u64) -> f64) -> Self {
            Toy {
                steps: 0,
                dt: 0.001,
                speed,
                released_after: 0,
                blow_up_at: None,
                peer_fails_at: None,
                peer_stops_at: None,
                raise_stop_at: None,
                frames: Vec::new(),
                states: Vec::new(),
                held: Vec::new(),
                frame_figures: None,
            }
        }
    }

    impl Solver for Toy<'_> {
        type Error = ToyError;
        fn time(&self) -> f64 {
            self.steps as f64 * self.dt
        }
        fn steps(&self) -> u64 {
            self.steps
        }
        fn work_per_step(&self) -> f64 {
            1.0
        }
        fn step(&mut self, _rec: &mut Recording) -> Result<Flow, StepError<ToyError>> {
            if self.peer_fails_at == Some(self.steps) {
                return Err(StepError::Peer(ToyError::Peer(self.steps)));
            }
            if self.peer_stops_at == Some(self.steps) {
                return Ok(Flow::Stop(RunStatus::PeerStopped));
            }
            self.steps += 1;
            if let Some((at, flag)) = self.raise_stop_at {
                if self.steps == at {
                    flag.store(true, Ordering::Relaxed);
                }
            }
            Ok(Flow::Continue)
        }
        fn check(&self) -> Result<(), ToyError> {
            match self.blow_up_at {
                Some(at) if self.steps >= at => Err(ToyError::BlowUp(self.steps)),
                _ => Ok(()),
            }
        }
        fn record_frame(&mut self, _rec: &mut Recording, clock: FrameClock) -> Result<FrameReport, ToyError> {
            self.frames.push(self.steps);
            self.frame_figures = clock.exchange;
            Ok(FrameReport {
                moving_fraction: Some((self.speed)(self.steps)),
                released: self.steps > self.released_after,
            })
        }
        fn record_state(&mut self, _rec: &mut Recording) -> Result<(), ToyError> {
            self.states.push(self.steps);
            Ok(())
        }
        fn checkpoint(&self, out: &mut dyn std::io::Write) -> std::io::Result<()> {
            out.write_all(&self.steps.to_le_bytes())
        }
        fn summary(&mut self, end: &RunEnd) -> RunSummary {
            RunSummary {
                scene: "toy".into(),
                method: "toy".into(),
                status: end.status,
                sim_time: self.time(),
                wall_seconds: end.wall,
                steps: self.steps,
                throughput: Throughput {
                    particle_steps_per_s: None,
                    cell_updates_per_s: None,
                    point_updates_per_s: None,
                    wall_per_sim_second: 0.0,
                },
                t_ref: 1.0,
                front: Vec::new(),
                runout: end.work,
                front_connected: Vec::new(),
                runout_connected: None,
                front_pile: Vec::new(),
                runout_pile: None,
                deposit: Vec::new(),
                porosity_initial: 0.0,
                liquid_front: Vec::new(),
                dem: None,
                lbm: None,
                mpm: None,
                wall_seconds_total: None,
                wall_seconds_lbm: None,
                exchange: None,
            }
        }
        fn cannot_write(path: &Path, source: std::io::Error) -> ToyError {
            ToyError::Io(format!("{}: {source}", path.display()))
        }
    }

    const CADENCE: Cadence = Cadence {
        steps_per_frame: 10,
        steps_per_state: Some(30),
        step_limit: 95,
        state_at_start: true,
        steps_per_checkpoint: None,
    };
    const REST: RestRule = RestRule { stop_at_rest: true, fraction: 0.01, frames: REST_FRAMES };

    fn run(toy: &mut Toy<'_>, stop: &AtomicBool, rest: RestRule) -> (Result<RunSummary, ToyError>, serde_json::Value) {
        run_with(toy, None, stop, rest)
    }

    fn run_with<'t>(
        toy: &mut Toy<'t>,
        exchange: Option<&mut dyn StepExchange<Toy<'t>>>,
        stop: &AtomicBool,
        rest: RestRule,
    ) -> (Result<RunSummary, ToyError>, serde_json::Value) {
        let dir =
            std::env::temp_dir().join(format!("sgf-driver-{}-{:?}", std::process::id(), std::thread::current().id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("summary.json");
        let _ = std::fs::remove_file(&path);
        let mut rec = Recording::off("toy");
        let mut checkpoints = Checkpoints::default();
        let result = drive(toy, exchange, &mut rec, CADENCE, rest, &mut checkpoints, stop, &mut |_, _| {}, &path);
        let written = serde_json::from_str(&std::fs::read_to_string(&path).expect("summary written")).unwrap();
        let _ = std::fs::remove_dir_all(&dir);
        (result, written)
    }

    /// To the step limit: frames every 10 steps and a last one at 95,
    /// states at 0, every 30 steps and at the end; every step's work counted.
    #[test]
    fn a_run_to_its_end_records_the_cadence_and_the_last_step() {
        let mut toy = Toy::new(|_| 0.5);
        let (r, written) = run(&mut toy, &AtomicBool::new(false), REST);
        let s = r.unwrap();
        assert_eq!((s.status, s.steps, s.runout), (RunStatus::Completed, 95, 95.0));
        assert_eq!(toy.frames, [0, 10, 20, 30, 40, 50, 60, 70, 80, 90, 95]);
        assert_eq!(toy.states, [0, 30, 60, 90, 95]);
        assert_eq!(written["status"], "completed");
    }

    /// Rest counts only once the mass has moved and the gates are open, and
    /// takes three frames in a row; the run then ends at that frame with no
    /// extra frame, and its state is recorded once.
    #[test]
    fn rest_needs_motion_open_gates_and_three_quiet_frames() {
        // Still at 0-20 (has not moved yet), moving at 30-40, still from 50.
        let mut toy = Toy::new(|s| if (30..=40).contains(&s) { 0.5 } else { 0.0 });
        let (r, _) = run(&mut toy, &AtomicBool::new(false), REST);
        assert_eq!(r.unwrap().status, RunStatus::AtRest);
        assert_eq!(toy.steps, 70, "quiet frames at 50, 60, 70");
        assert_eq!(toy.frames.last(), Some(&70));
        assert_eq!(toy.states, [0, 30, 60, 70]);
        // Gates held until step 65: the quiet frames count from 70 on.
        let mut toy = Toy::new(|s| if (30..=40).contains(&s) { 0.5 } else { 0.0 });
        toy.released_after = 65;
        let (r, _) = run(&mut toy, &AtomicBool::new(false), REST);
        assert_eq!((r.unwrap().status, toy.steps), (RunStatus::AtRest, 90));
        // Without stop_at_rest the run goes to its end.
        let mut toy = Toy::new(|s| if (30..=40).contains(&s) { 0.5 } else { 0.0 });
        let (r, _) = run(&mut toy, &AtomicBool::new(false), RestRule { stop_at_rest: false, ..REST });
        assert_eq!((r.unwrap().status, toy.steps), (RunStatus::Completed, 95));
    }

    /// A run resumed from a checkpoint records what the straight run
    /// records after it and ends where it ends: here at rest, which takes
    /// the quiet frames counted before the checkpoint (restored, the run
    /// stops at 70 as the straight one; counted afresh it would go to 80).
    #[test]
    fn a_resumed_loop_continues_the_straight_one() {
        let scene_path =
            std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenes/validation/minimal_dry_column.toml");
        let scene = schemas::Scene::load(&scene_path, &[]).unwrap();
        let dir = std::env::temp_dir().join(format!("sgf-driver-resume-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let speed = |s| if (30..=40).contains(&s) { 0.5 } else { 0.0 };
        let cadence = Cadence { steps_per_checkpoint: Some(20), ..CADENCE };
        let summary = dir.join("summary.json");
        let go = |toy: &mut Toy<'_>, checkpoints: &mut Checkpoints| {
            let mut rec = Recording::off("toy");
            let stop = AtomicBool::new(false);
            drive(toy, None, &mut rec, cadence, REST, checkpoints, &stop, &mut |_, _| {}, &summary).unwrap()
        };
        let mut straight = Toy::new(speed);
        let writer = crate::checkpoint::CheckpointWriter::new(&dir, "toy", &scene).unwrap();
        let s = go(&mut straight, &mut Checkpoints { writer: Some(writer), resumed: None });
        assert_eq!((s.status, straight.steps), (RunStatus::AtRest, 70));
        let files = crate::checkpoint::list(&crate::checkpoint::folder(&dir), "toy");
        assert_eq!(files.iter().map(|f| f.0).collect::<Vec<_>>(), [40, 60], "checkpoints every 20 steps, two kept");
        let file = crate::checkpoint::read(&files[1].1, "toy", &scene).unwrap();
        assert_eq!(file.solver, 60u64.to_le_bytes());
        assert_eq!((file.driver.frames_at_rest, file.driver.has_moved), (2, true));
        let mut resumed = Toy::new(speed);
        resumed.steps = 60;
        let r = go(&mut resumed, &mut Checkpoints { writer: None, resumed: Some(file.driver) });
        assert_eq!((r.status, resumed.steps), (s.status, straight.steps));
        assert_eq!(r.runout, 10.0, "the work of the resumed loop alone (its rates are over it)");
        assert_eq!(resumed.frames, [70], "no first frame: the interrupted run recorded 60");
        assert_eq!(resumed.states, [70]);
        let _ = std::fs::remove_dir_all(&dir);
    }

    /// The stop flag ends the run after the step that saw it and still
    /// records a last frame and state.
    #[test]
    fn the_stop_flag_interrupts_at_a_step_boundary_with_a_last_frame() {
        let stop = AtomicBool::new(false);
        let mut toy = Toy::new(|_| 0.5);
        toy.raise_stop_at = Some((47, &stop));
        let (r, written) = run(&mut toy, &stop, REST);
        assert_eq!((r.unwrap().status, toy.steps), (RunStatus::Interrupted, 47));
        assert_eq!((toy.frames.last(), toy.states.last()), (Some(&47), Some(&47)));
        assert_eq!(written["status"], "interrupted");
    }

    /// A blow-up found at a frame ends the run `unstable`: no frame of the
    /// blown state, its state recorded, the summary written, the error returned.
    #[test]
    fn a_blow_up_ends_unstable_with_its_summary_and_state() {
        let mut toy = Toy::new(|_| 0.5);
        toy.blow_up_at = Some(35);
        let (r, written) = run(&mut toy, &AtomicBool::new(false), REST);
        assert!(matches!(r, Err(ToyError::BlowUp(40))), "{r:?}");
        assert_eq!(written["status"], "unstable");
        assert_eq!(toy.frames.last(), Some(&30));
        assert_eq!(toy.states.last(), Some(&40));
    }

    /// A failed exchange is `peer_failed` with the error returned, unless the
    /// stop flag is up (then the peer's going is the same Ctrl-C:
    /// `interrupted`, no error); a peer's own stop ends the run with the
    /// status the solver gives.
    #[test]
    fn peer_endings_take_their_status() {
        let mut toy = Toy::new(|_| 0.5);
        toy.peer_fails_at = Some(22);
        let (r, written) = run(&mut toy, &AtomicBool::new(false), REST);
        assert!(matches!(r, Err(ToyError::Peer(22))), "{r:?}");
        assert_eq!(written["status"], "peer_failed");
        assert_eq!(
            (toy.frames.last(), toy.states.last()),
            (Some(&20), Some(&22)),
            "no frame after a failure; the state"
        );

        let mut toy = Toy::new(|_| 0.5);
        toy.peer_fails_at = Some(22);
        let (r, _) = run(&mut toy, &AtomicBool::new(true), REST);
        assert_eq!(r.unwrap().status, RunStatus::Interrupted);

        let mut toy = Toy::new(|_| 0.5);
        toy.peer_stops_at = Some(50);
        let (r, _) = run(&mut toy, &AtomicBool::new(false), REST);
        assert_eq!((r.unwrap().status, toy.steps), (RunStatus::PeerStopped, 50));
        assert_eq!(toy.frames.last(), Some(&50), "recorded at the cadence, not twice");
    }

    // The exchange the driver owns, on the toy as a DEM-like side: it sends
    // one state (x = its step) every 10 steps and holds the load answered.

    impl From<ExchangeFailure> for ToyError {
        fn from(e: ExchangeFailure) -> Self {
            ToyError::Exchange(format!("exchange {}: {}", e.exchange, e.source))
        }
    }

    impl Coupled for Toy<'_> {
        type Sends = ParticleState;
        type Receives = HydroLoad;
        fn outgoing(&mut self, out: &mut Vec<ParticleState>) {
            out.clear();
            out.push(ParticleState { position: [self.steps as f64, 0.0, 0.0], ..ParticleState::default() });
        }
        fn incoming(&mut self, header: &ExchangeHeader, message: &mut Vec<HydroLoad>) -> Result<(), ToyError> {
            self.held.push((self.steps, header.exchange, message.first().map_or(f64::NAN, |l| l.force[0])));
            Ok(())
        }
    }

    /// What the scripted peer saw.
    #[derive(Default)]
    struct PeerLog {
        sent_to_peer: Vec<ExchangeHeader>,
        asked: Vec<u64>,
    }

    /// A peer that answers exchange n with one load of force n, except
    /// where told to answer another index, two entries, a stop or an error.
    struct ScriptPeer {
        log: std::rc::Rc<std::cell::RefCell<PeerLog>>,
        wrong_index_at: Option<u64>,
        two_entries_at: Option<u64>,
        stops_at: Option<u64>,
        fails_at: Option<u64>,
    }

    impl ScriptPeer {
        fn new(log: &std::rc::Rc<std::cell::RefCell<PeerLog>>) -> Self {
            ScriptPeer { log: log.clone(), wrong_index_at: None, two_entries_at: None, stops_at: None, fails_at: None }
        }
    }

    impl Peer<ParticleState, HydroLoad> for ScriptPeer {
        fn send(&mut self, header: ExchangeHeader, _message: &[ParticleState]) -> Result<(), PeerError> {
            self.log.borrow_mut().sent_to_peer.push(header);
            Ok(())
        }
        fn receive(&mut self, n: u64, out: &mut Vec<HydroLoad>) -> Result<ExchangeHeader, PeerError> {
            self.log.borrow_mut().asked.push(n);
            if self.fails_at == Some(n) {
                return Err("peer died".into());
            }
            if self.stops_at == Some(n) {
                return Ok(ExchangeHeader::new(n, f64::NAN).stopping());
            }
            out.clear();
            out.push(HydroLoad { force: [n as f64, 0.0, 0.0], ..HydroLoad::default() });
            if self.two_entries_at == Some(n) {
                out.push(HydroLoad { id: 1, ..HydroLoad::default() });
            }
            let index = if self.wrong_index_at == Some(n) { n + 1 } else { n };
            Ok(ExchangeHeader::new(index, n as f64))
        }
    }

    fn coupled_run(
        peer: ScriptPeer,
        side: Side,
        stop: &AtomicBool,
    ) -> (Toy<'static>, Result<RunSummary, ToyError>, serde_json::Value, ExchangeFigures) {
        let mut toy = Toy::new(|_| 0.5);
        let mut exchange = Exchange::new(Box::new(peer), side, 10, "peer").expecting(1);
        let (r, written) = run_with(&mut toy, Some(&mut exchange), stop, REST);
        let figures = exchange.figures();
        (toy, r, written, figures)
    }

    /// Sequential: exchange n at step 10n sends, then holds the load of n;
    /// the run's end sends a stop message with the next index and the
    /// last state. Frames see the totals.
    #[test]
    fn a_sequential_exchange_holds_the_load_of_its_own_step() {
        let log = Default::default();
        let (toy, r, _, figures) =
            coupled_run(ScriptPeer::new(&log), Side::SendsFirst { lagged: false }, &AtomicBool::new(false));
        assert_eq!(r.unwrap().status, RunStatus::Completed);
        let expect: Vec<_> = (0..10).map(|n| (10 * n, n, n as f64)).collect();
        assert_eq!(toy.held, expect);
        assert_eq!(figures.exchanges, 10);
        assert_eq!(toy.frame_figures.map(|f| f.exchanges), Some(10));
        let log = log.borrow();
        assert_eq!(log.asked, (0..10).collect::<Vec<_>>());
        let last = log.sent_to_peer.last().unwrap();
        assert!(last.is_stopping() && last.exchange == 10 && last.count == 1, "{last:?}");
        assert_eq!(log.sent_to_peer.len(), 11);
    }

    /// Concurrent (lagged): exchange 0 waits for its own load, exchange 1
    /// receives nothing and holds it again, exchange n ≥ 2 holds n − 1.
    #[test]
    fn a_lagged_exchange_holds_the_previous_load() {
        let log = Default::default();
        let (toy, r, _, _) =
            coupled_run(ScriptPeer::new(&log), Side::SendsFirst { lagged: true }, &AtomicBool::new(false));
        assert_eq!(r.unwrap().status, RunStatus::Completed);
        let held: Vec<f64> = toy.held.iter().map(|h| h.2).collect();
        assert_eq!(held, [0.0, 0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0]);
        assert_eq!(log.borrow().asked, (0..9).collect::<Vec<_>>());
    }

    /// A message out of order or with the wrong count ends the run
    /// `peer_failed`, naming the call the peer must make; a peer's error
    /// likewise; a peer's stop ends it `peer_stopped` without a stop
    /// message back.
    #[test]
    fn the_exchange_refuses_what_the_peer_got_wrong() {
        let no_stop = AtomicBool::new(false);
        let log = Default::default();
        let (_, r, written, _) = coupled_run(
            ScriptPeer { wrong_index_at: Some(3), ..ScriptPeer::new(&log) },
            Side::SendsFirst { lagged: false },
            &no_stop,
        );
        let e = r.unwrap_err().to_string();
        assert!(e.contains("exchange 3") && e.contains("send_loads(3)"), "{e}");
        assert_eq!(written["status"], "peer_failed");
        assert!(!log.borrow().sent_to_peer.last().unwrap().is_stopping(), "no stop message after a failure");

        let log = Default::default();
        let (_, r, _, _) = coupled_run(
            ScriptPeer { two_entries_at: Some(4), ..ScriptPeer::new(&log) },
            Side::SendsFirst { lagged: false },
            &no_stop,
        );
        let e = r.unwrap_err().to_string();
        assert!(e.contains("sent 2 entries for 1 grains"), "{e}");

        let log = Default::default();
        let (toy, r, _, _) = coupled_run(
            ScriptPeer { fails_at: Some(6), ..ScriptPeer::new(&log) },
            Side::SendsFirst { lagged: false },
            &no_stop,
        );
        assert!(r.unwrap_err().to_string().contains("exchange 6: peer died"));
        assert_eq!(toy.steps, 60);

        let log = Default::default();
        let (toy, r, _, figures) = coupled_run(
            ScriptPeer { stops_at: Some(5), ..ScriptPeer::new(&log) },
            Side::SendsFirst { lagged: false },
            &no_stop,
        );
        assert_eq!((r.unwrap().status, toy.steps, figures.exchanges), (RunStatus::PeerStopped, 50, 6));
        assert!(log.borrow().sent_to_peer.iter().all(|h| !h.is_stopping()));
    }
}
