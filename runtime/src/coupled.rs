//! The exchange of a coupled solver with its peer, owned by the run driver
//! (docs/coupling.md, DESIGN §2).
//!
//! Every exchange is one message each way: the DEM sends grain states and
//! receives hydrodynamic loads, the LBM the reverse. The two sides differ
//! only in which half comes first ([`Side`]); everything else is here once:
//! when an exchange is due, its index, the order check of every received
//! message (whatever the transport: shared memory, the in-process pair, a
//! replayed recording), the count and id-order check, recording the
//! received messages (`output.record_exchange`), the time spent, and the
//! stop messages at the end of a run.
//!
//! A solver takes part through [`Coupled`]: it fills the message it sends
//! and takes the message it receives; [`crate::driver::drive`] calls the
//! halves around [`crate::driver::Solver::step`]:
//!
//! ```text
//! before_step   SendsFirst (DEM): [receive n−1 if lagged] send n [receive n] hold
//!               ReceivesFirst (LBM): receive n, incoming
//! step          the solver's step (the LBM's forced step computes the loads)
//! after_step    ReceivesFirst: send n (the answer)
//! finish_step   the rest of the step, while the peer goes on
//! ```

use std::time::Instant;

use schemas::messages::{check_order, ExchangeHeader, HydroLoad, ParticleState, FLAG_STOPPING};
use schemas::scene::Schedule;
use schemas::summary::RunStatus;

use crate::checkpoint::ExchangeState;
use crate::driver::{Flow, Recording, Solver, StepError};
use crate::exchange::{encode_loads, encode_states, Peer, PeerError};
use crate::record::{log_level, ChannelId, RecordError};

/// An entry of an exchanged message (one per grain).
pub trait Payload: Copy {
    /// The peer's call that sends it, named when a message comes out of order.
    const SENT_BY: &'static str;
    /// The grain it belongs to.
    fn id(&self) -> u32;
    /// The recorded form of a received message ([`schemas::messages::RECEIVED_ENCODING`]).
    fn encode(header: &ExchangeHeader, message: &[Self], out: &mut Vec<u8>);
}

impl Payload for ParticleState {
    const SENT_BY: &'static str = "send_states";
    fn id(&self) -> u32 {
        self.id
    }
    fn encode(header: &ExchangeHeader, message: &[Self], out: &mut Vec<u8>) {
        encode_states(header, message, out);
    }
}

impl Payload for HydroLoad {
    const SENT_BY: &'static str = "send_loads";
    fn id(&self) -> u32 {
        self.id
    }
    fn encode(header: &ExchangeHeader, message: &[Self], out: &mut Vec<u8>) {
        encode_loads(header, message, out);
    }
}

/// A solver that exchanges with a peer.
pub trait Coupled: Solver {
    type Sends: Payload;
    type Receives: Payload;
    /// The message this solver sends now, into `out` (cleared by the
    /// solver): the DEM's grain states, or the loads the LBM's last step
    /// computed.
    fn outgoing(&mut self, out: &mut Vec<Self::Sends>);
    /// The message received with `header` (the DEM holds these loads until
    /// the next exchange; the LBM forces its next step with these grains).
    /// The solver may swap the buffer out; it is refilled at the next
    /// receive.
    fn incoming(&mut self, header: &ExchangeHeader, message: &mut Vec<Self::Receives>) -> Result<(), Self::Error>;
}

/// Which half of an exchange comes first.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Side {
    /// Sends, then receives (the DEM). `lagged` (the concurrent schedule):
    /// exchange n's answer is taken at exchange n + 1, so the peer computes
    /// while this solver steps; exchange 0 still waits for its answer
    /// (there is no earlier load, and starting without buoyancy would drop
    /// every grain), which is then held over two intervals. This side owns
    /// the end of the run: it tells its peer when it stops.
    SendsFirst { lagged: bool },
    /// Receives, steps with it, answers (the LBM): its peer owns the end.
    ReceivesFirst,
}

impl Side {
    /// The DEM's side under `schedule`.
    pub fn dem(schedule: Schedule) -> Self {
        Side::SendsFirst { lagged: schedule == Schedule::Concurrent }
    }
}

/// An exchange failed: the transport, the peer's message, or its order.
#[derive(Debug)]
pub struct ExchangeFailure {
    /// The exchange's index.
    pub exchange: u64,
    /// Simulated time, s.
    pub time: f64,
    pub source: PeerError,
}

/// Totals of the exchange so far, for frames and the summary.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct ExchangeFigures {
    /// Exchanges completed.
    pub exchanges: u64,
    /// Wall seconds in the transport (sending, waiting, receiving).
    pub seconds: f64,
}

/// The exchange with a peer, with the buffers it reuses (no allocation
/// after the first exchange, apart from recorded messages).
pub struct Exchange<'p, S, R> {
    peer: Box<dyn Peer<S, R> + 'p>,
    side: Side,
    /// Solver steps per exchange (the DEM: `coupling.ratio`; the LBM: 1).
    ratio: u64,
    /// The peer's name in messages ("lbm_proc").
    peer_name: &'static str,
    /// Entries every received message must have, in id order.
    count: Option<usize>,
    /// Index of the next exchange.
    next: u64,
    /// Header of the last message received.
    last: ExchangeHeader,
    sends: Vec<S>,
    receives: Vec<R>,
    /// Channel that records each received message, when recording them.
    record_into: Option<ChannelId>,
    figures: ExchangeFigures,
    /// A side that receives first, resumed under a lagged peer: its last
    /// answer was in flight when the checkpoint was taken, and is sent again
    /// before the next receive.
    resend_answer: bool,
}

impl<S, R> std::fmt::Debug for Exchange<'_, S, R> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Exchange")
            .field("side", &self.side)
            .field("ratio", &self.ratio)
            .field("next", &self.next)
            .field("figures", &self.figures)
            .finish_non_exhaustive()
    }
}

impl<'p, S: Payload, R: Payload> Exchange<'p, S, R> {
    /// An exchange with `peer` every `ratio` steps of the solver.
    pub fn new(peer: Box<dyn Peer<S, R> + 'p>, side: Side, ratio: u64, peer_name: &'static str) -> Self {
        assert!(ratio >= 1, "an exchange needs at least one step per exchange");
        Exchange {
            peer,
            side,
            ratio,
            peer_name,
            count: None,
            next: 0,
            last: ExchangeHeader::new(0, 0.0),
            sends: Vec::new(),
            receives: Vec::new(),
            record_into: None,
            figures: ExchangeFigures::default(),
            resend_answer: false,
        }
    }

    /// Continues from a checkpoint's position. `peer_lagged`: the peer
    /// takes each answer one exchange late (the concurrent schedule), so a
    /// side that receives first sends its last answer again first (the
    /// solver restored from the same checkpoint gives the same message).
    pub fn resuming(mut self, state: ExchangeState, peer_lagged: bool) -> Self {
        self.next = state.next;
        self.last = ExchangeHeader::new(state.last_exchange, state.last_time);
        self.figures.exchanges = state.exchanges;
        // Exchange 1 of a lagged peer re-holds 0's answer: nothing is in flight before 2.
        self.resend_answer = self.side == Side::ReceivesFirst && peer_lagged && state.next >= 2;
        self
    }

    /// Its position, for a checkpoint.
    pub fn state(&self) -> ExchangeState {
        ExchangeState {
            next: self.next,
            last_exchange: self.last.exchange,
            last_time: self.last.time,
            exchanges: self.figures.exchanges,
        }
    }

    /// Every received message must hold `count` entries in id order.
    pub fn expecting(mut self, count: usize) -> Self {
        self.count = Some(count);
        self
    }

    /// Records every received message on `channel` (None: not recorded).
    pub fn recording_into(mut self, channel: Option<ChannelId>) -> Self {
        self.record_into = channel;
        self
    }

    /// Totals so far.
    pub fn figures(&self) -> ExchangeFigures {
        self.figures
    }

    /// The exchange due before the solver's step `steps`, if one is; its
    /// index must be the next one (a solver that skipped or repeated steps
    /// is refused here rather than coupled to the wrong step).
    fn due(&self, steps: u64, time: f64) -> Result<Option<u64>, ExchangeFailure> {
        if !steps.is_multiple_of(self.ratio) {
            return Ok(None);
        }
        let n = steps / self.ratio;
        if n != self.next {
            return Err(self.failure(
                n,
                time,
                format!(
                    "step {steps} is exchange {n}, but exchange {} is due: exchanges come every {} steps, in order",
                    self.next, self.ratio
                ),
            ));
        }
        Ok(Some(n))
    }

    fn failure(&self, exchange: u64, time: f64, source: impl Into<PeerError>) -> ExchangeFailure {
        ExchangeFailure { exchange, time, source: source.into() }
    }

    fn send(&mut self, header: ExchangeHeader) -> Result<(), ExchangeFailure> {
        let started = Instant::now();
        let sent = self.peer.send(header, &self.sends);
        self.figures.seconds += started.elapsed().as_secs_f64();
        sent.map_err(|e| self.failure(header.exchange, header.time, e))
    }

    /// Receives exchange `n` at simulated time `time`, checks its order
    /// and entries, records it. True when the peer stops.
    fn receive(&mut self, n: u64, time: f64, rec: &mut Recording) -> Result<bool, ReceiveError> {
        let started = Instant::now();
        let received = self.peer.receive(n, &mut self.receives);
        self.figures.seconds += started.elapsed().as_secs_f64();
        let header = received.map_err(|e| ReceiveError::Peer(self.failure(n, time, e)))?;
        if let (Some(r), Some(ch)) = (rec.recorder(), self.record_into) {
            let entries: &[R] = if header.is_stopping() { &[] } else { &self.receives };
            // The recorder takes the buffer: one allocation per recorded exchange.
            let mut bytes = Vec::new();
            R::encode(&header, entries, &mut bytes);
            r.log_bytes(ch, time, bytes).map_err(ReceiveError::Record)?;
        }
        self.last = header;
        if header.is_stopping() {
            return Ok(true);
        }
        if let Err(e) = check_order(n, &header) {
            let why = format!(
                "{e}: {} must call {}({n}) exactly once per exchange, in order; both sides count exchanges from 0 (a replayed recording must come from the same scene, overrides and schedule)",
                self.peer_name,
                R::SENT_BY
            );
            return Err(ReceiveError::Peer(self.failure(n, time, why)));
        }
        if let Some(count) = self.count {
            if self.receives.len() != count || self.receives.iter().enumerate().any(|(i, e)| e.id() as usize != i) {
                let why = format!(
                    "{} sent {} entries for {count} grains (or out of id order): both processes must run the same scene",
                    self.peer_name,
                    self.receives.len()
                );
                return Err(ReceiveError::Peer(self.failure(n, time, why)));
            }
        }
        Ok(false)
    }

    /// The half of the exchange before the solver's step.
    pub fn before_step<C>(&mut self, solver: &mut C, rec: &mut Recording) -> Result<Flow, StepError<C::Error>>
    where
        C: Coupled<Sends = S, Receives = R>,
        C::Error: From<ExchangeFailure>,
    {
        let time = solver.time();
        let Some(n) = self.due(solver.steps(), time).map_err(|e| StepError::Fatal(e.into()))? else {
            return Ok(Flow::Continue);
        };
        match self.side {
            Side::SendsFirst { lagged } => {
                let lagged = lagged && n >= 1;
                let mut stopped =
                    lagged && n >= 2 && self.receive(n - 1, time, rec).map_err(ReceiveError::into_step)?;
                solver.outgoing(&mut self.sends);
                let header = ExchangeHeader { exchange: n, time, count: self.sends.len() as u32, flags: 0 };
                self.send(header).map_err(|e| StepError::Peer(e.into()))?;
                if !stopped && !lagged {
                    stopped = self.receive(n, time, rec).map_err(ReceiveError::into_step)?;
                }
                let last = self.last;
                solver.incoming(&last, &mut self.receives).map_err(StepError::Fatal)?;
                self.next = n + 1;
                self.figures.exchanges += 1;
                if stopped {
                    let line = format!("{} stopped; recording the last state", self.peer_name);
                    rec.log(time, log_level::WARNING, &line)?;
                    return Ok(Flow::Stop(RunStatus::PeerStopped));
                }
            }
            Side::ReceivesFirst => {
                if std::mem::take(&mut self.resend_answer) {
                    solver.outgoing(&mut self.sends);
                    let header = ExchangeHeader {
                        exchange: n - 1,
                        time: self.last.time,
                        count: self.sends.len() as u32,
                        flags: 0,
                    };
                    self.send(header).map_err(|e| StepError::Peer(e.into()))?;
                }
                if self.receive(n, time, rec).map_err(ReceiveError::into_step)? {
                    rec.log(time, log_level::INFO, &format!("{} stopped at exchange {n}", self.peer_name))?;
                    return Ok(Flow::Stop(RunStatus::Completed));
                }
                let last = self.last;
                solver.incoming(&last, &mut self.receives).map_err(StepError::Fatal)?;
            }
        }
        Ok(Flow::Continue)
    }

    /// The half of the exchange after the solver's step: the answer of a
    /// side that receives first (at the peer's time).
    pub fn after_step<C>(&mut self, solver: &mut C) -> Result<(), ExchangeFailure>
    where
        C: Coupled<Sends = S, Receives = R>,
    {
        if self.side != Side::ReceivesFirst {
            return Ok(());
        }
        let n = self.next;
        solver.outgoing(&mut self.sends);
        let header = ExchangeHeader { exchange: n, time: self.last.time, count: self.sends.len() as u32, flags: 0 };
        self.next = n + 1;
        self.figures.exchanges += 1;
        self.send(header)
    }

    /// The stop flag ended the run: a side that receives first tells its
    /// peer, which may be waiting for this step's answer (best effort).
    pub fn interrupted(&mut self, time: f64) {
        if self.side == Side::ReceivesFirst {
            let header = ExchangeHeader { exchange: self.next, time, count: 0, flags: FLAG_STOPPING };
            let _ = self.peer.send(header, &[]);
        }
    }

    /// After the loop: a side that sends first tells its peer it stops (a
    /// message with [`FLAG_STOPPING`] and its last states), unless the run
    /// failed or the peer stopped first. A peer already gone is logged,
    /// not an error.
    pub fn finish<C>(
        &mut self,
        solver: &mut C,
        status: RunStatus,
        failed: bool,
        rec: &mut Recording,
    ) -> Result<(), RecordError>
    where
        C: Coupled<Sends = S, Receives = R>,
    {
        if !matches!(self.side, Side::SendsFirst { .. }) || failed || status == RunStatus::PeerStopped {
            return Ok(());
        }
        solver.outgoing(&mut self.sends);
        let time = solver.time();
        let header = ExchangeHeader { exchange: self.next, time, count: self.sends.len() as u32, flags: FLAG_STOPPING };
        if let Err(e) = self.peer.send(header, &self.sends) {
            rec.log(time, log_level::WARNING, &format!("could not tell {} to stop: {e}", self.peer_name))?;
        }
        Ok(())
    }
}

/// A receive that failed: the peer (the run ends `peer_failed`) or the
/// recording (the run ends at once).
enum ReceiveError {
    Peer(ExchangeFailure),
    Record(RecordError),
}

impl ReceiveError {
    fn into_step<E: From<ExchangeFailure> + From<RecordError>>(self) -> StepError<E> {
        match self {
            ReceiveError::Peer(e) => StepError::Peer(e.into()),
            ReceiveError::Record(e) => StepError::Fatal(e.into()),
        }
    }
}
