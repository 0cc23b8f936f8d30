//! The DEM ⇄ LBM link: particle states one way, hydrodynamic loads the other,
//! over iceoryx2 shared memory on one machine.
//!
//! One exchange `n` is: DEM [`DemLink::send_states`]`(n)` → LBM
//! [`LbmLink::receive_states`]`(n)` → LBM [`LbmLink::send_loads`]`(n)` → DEM
//! [`DemLink::receive_loads`]`(n)`. Both sides count exchanges from 0 and every
//! message carries its index, so a skipped or repeated call is reported as
//! [`LinkError::OutOfOrder`] instead of silently coupling the wrong steps.
//!
//! Everything lives under a run id: services `sgf/<run_id>/particles`,
//! `…/loads` (slices, one entry per grain), `…/hello` (handshake),
//! `…/particles_ready` and `…/loads_ready` (wake-ups); nodes `sgf/<run_id>/dem`
//! and `sgf/<run_id>/lbm`. Two runs with different ids never see each other.
//!
//! Connecting: each side first removes the resources of dead iceoryx2 nodes
//! (a run after a `kill -9` starts cleanly), refuses to be a second DEM or LBM
//! on the run id, then handshakes on `…/hello` (history 1, so a late peer
//! still reads it): stage 1 compares protocol version, role, scene hash and
//! grain count; stage 2 says "my data ports exist", so nothing is sent before
//! the receiver can get it. A side that finds a mismatch announces it (stage
//! 3) and waits until the peer has seen it, so both report the same error.
//!
//! Waiting spins for [`LinkConfig::spin`] (a wake-up through the kernel costs
//! 50–400 µs here, a spin ~1 µs), then blocks on the event listener in slices
//! of [`LinkConfig::peer_check`], checking between slices our stop flag and
//! whether the peer's process is still alive (iceoryx2 node liveness is an OS
//! file lock, so a `kill -9`ed peer shows as dead at once).
//!
//! Signals: the nodes are created with [`SignalHandlingMode::Disabled`], so
//! iceoryx2 never installs SIGINT/SIGTERM handlers of its own; our processes
//! install theirs ([`crate::process::stop_flag`]) and pass the flag in
//! [`LinkConfig::stop`]. A signal that interrupts a blocking wait only wakes
//! it up; the stop flag decides.
//!
//! The exchange path reuses every buffer: no heap allocation of ours per
//! exchange (iceoryx2's loan makes one small `Rc` per message). Only a wait
//! longer than `peer_check` lists the nodes, which allocates.
//!
//! Ports are `!Send` (iceoryx2 keeps `Rc`s inside): create a link on the
//! thread that uses it.

use std::fmt::Debug;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use iceoryx2::node::NodeView;
use iceoryx2::port::listener::{Listener, ListenerWaitError};
use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::port::update_connections::UpdateConnections;
use iceoryx2::prelude::*;

pub use schemas::messages::{ExchangeHeader, HydroLoad, ParticleState, FLAG_STOPPING, PROTOCOL_VERSION};

/// Handshake message on `sgf/<run_id>/hello`.
///
/// Its layout and type name must never change: it is what tells two builds
/// apart ([`LinkError::ProtocolMismatch`]), so it has to stay readable by both.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend)]
#[type_name("sgf.Hello")]
pub struct Hello {
    /// [`PROTOCOL_VERSION`] of the sender's build.
    pub protocol_version: u32,
    /// 1 = DEM, 2 = LBM.
    pub role: u32,
    /// [`schemas::stable_hash`] of the scene as run (after `--set` overrides).
    pub scene_hash: u64,
    /// Number of grains the sender exchanges per message.
    pub particles: u64,
    /// The sender's iceoryx2 node id (high, low 64 bits): how the peer watches its liveness.
    pub node_id: [u64; 2],
    /// The sender's process id, for messages.
    pub pid: u32,
    /// 1: hello; 2: the sender's data ports exist, it may be sent to;
    /// 3: the sender refuses the peer (mismatch) and leaves.
    pub stage: u32,
}

/// Which side of the link a process is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Role {
    Dem,
    Lbm,
}

impl Role {
    /// The other side.
    pub fn peer(self) -> Role {
        match self {
            Role::Dem => Role::Lbm,
            Role::Lbm => Role::Dem,
        }
    }

    /// Last segment of the node name (`sgf/<run_id>/dem`).
    pub fn node_suffix(self) -> &'static str {
        match self {
            Role::Dem => "dem",
            Role::Lbm => "lbm",
        }
    }

    fn code(self) -> u32 {
        match self {
            Role::Dem => 1,
            Role::Lbm => 2,
        }
    }

    fn from_code(code: u32) -> Option<Role> {
        match code {
            1 => Some(Role::Dem),
            2 => Some(Role::Lbm),
            _ => None,
        }
    }
}

impl std::fmt::Display for Role {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Role::Dem => "DEM",
            Role::Lbm => "LBM",
        })
    }
}

/// What a link needs to connect and to wait.
#[derive(Debug, Clone)]
pub struct LinkConfig {
    /// Namespace of every service and node: 1–40 characters of `[A-Za-z0-9_-]`.
    pub run_id: String,
    /// [`schemas::stable_hash`] of the scene as run; both sides must agree.
    pub scene_hash: u64,
    /// Grains per message, both directions: every message sent or received
    /// has exactly this many (the shared-memory slices are sized for it).
    /// 0: take the peer's count at the handshake (the LBM's case).
    pub particles: usize,
    /// How long [`DemLink::connect`]/[`LbmLink::connect`] wait for the peer (default 10 s).
    pub connect_timeout: Duration,
    /// Busy-spin on the subscriber before blocking (default 100 µs): a kernel
    /// wake-up costs 50–400 µs on this VM, a spin ~1 µs per check; longer only
    /// burns a core the solver could use.
    pub spin: Duration,
    /// Longest block between checks of the stop flag and of the peer's
    /// liveness (default 100 ms): bounds how late Ctrl-C or a dead peer is noticed.
    pub peer_check: Duration,
    /// Our own SIGINT/SIGTERM flag; waiting returns [`LinkError::Interrupted`] once it is raised.
    pub stop: Option<Arc<AtomicBool>>,
    /// Test hook: announce this protocol version instead of [`PROTOCOL_VERSION`].
    #[doc(hidden)]
    pub protocol_version_override: Option<u32>,
}

impl LinkConfig {
    /// Defaults for everything but what must match the peer.
    pub fn new(run_id: impl Into<String>, scene_hash: u64, particles: usize) -> Self {
        Self {
            run_id: run_id.into(),
            scene_hash,
            particles,
            connect_timeout: Duration::from_secs(10),
            spin: Duration::from_micros(100),
            peer_check: Duration::from_millis(100),
            stop: None,
            protocol_version_override: None,
        }
    }
}

/// Every way the link fails; each message names the cause and the fix.
#[derive(Debug, thiserror::Error)]
pub enum LinkError {
    #[error(
        "run id {run_id:?} is not usable: it must be 1 to 40 characters of A-Z, a-z, 0-9, '_' or '-' (e.g. --run-id collapse_01)"
    )]
    InvalidRunId { run_id: String },
    #[error(
        "the peer speaks link protocol {theirs}, this process speaks {ours}: rebuild both binaries from the same source and start them again"
    )]
    ProtocolMismatch { ours: u32, theirs: u32 },
    #[error(
        "the peer runs scene {theirs:016x}, this process scene {ours:016x}: start both processes with the same scene file and the same --set overrides"
    )]
    SceneMismatch { ours: u64, theirs: u64 },
    #[error(
        "the peer exchanges {theirs} grains, this process {ours}, with the same scene: both must pass the scene's grain count to connect (a bug in the caller)"
    )]
    ParticlesMismatch { ours: usize, theirs: usize },
    #[error(
        "another {role} process (pid {pid}) already uses run id {run_id:?}: stop it, or give this run another --run-id (one DEM and one LBM per run id)"
    )]
    RoleTaken { role: Role, run_id: String, pid: u32 },
    #[error(
        "no {role} process answered on run id {run_id:?} within {waited:?}: start the {role} with the same --run-id {run_id}{}",
        others_hint(.others)
    )]
    NoPeer { role: Role, run_id: String, waited: Duration, others: Vec<String> },
    #[error(
        "the {role} process (pid {pid}) of run {run_id:?} {how}: look at its output for the cause, then start both again (its shared memory is cleaned at the next connect)"
    )]
    PeerDead { role: Role, pid: u32, run_id: String, how: &'static str },
    #[error(
        "the {role} process stopped (end of its run, or Ctrl-C) before exchange {exchange}: give both processes the same end time; if it was interrupted, stop this one as well"
    )]
    PeerStopped { role: Role, exchange: u64 },
    #[error(
        "waiting for the peer was interrupted by a stop request (SIGINT/SIGTERM): stop at this exchange and finish the run's output"
    )]
    Interrupted,
    #[error(
        "received exchange {got} but expected exchange {expected}: the {peer} must call {call}({expected}) exactly once per exchange, in order; check that both sides count exchanges from 0 and neither skipped nor repeated one"
    )]
    OutOfOrder { expected: u64, got: u64, peer: Role, call: &'static str },
    #[error(
        "the {peer} sent {got} entries in exchange {exchange}, this process expects {expected} (one per grain, as given to connect): grains cannot be added or removed while linked; connect both with the scene's grain count"
    )]
    CountMismatch { exchange: u64, expected: usize, got: usize, peer: Role },
    #[error("{particles} grains cannot be linked, at most 4294967295 (u32 ids): split the scene")]
    TooManyGrains { particles: usize },
    #[error(
        "{call}({exchange}) got {got} entries, the link was connected for {expected} (one per grain): pass exactly one entry per grain, in id order"
    )]
    SendLength { call: &'static str, exchange: u64, expected: usize, got: usize },
    #[error(
        "shared-memory transport failed while {0}: check that /dev/shm has free space and is writable; files of killed runs are removed at the next connect or with cleanup_stale"
    )]
    Transport(String),
}

fn others_hint(others: &[String]) -> String {
    if others.is_empty() {
        String::from(" (no other sgf run is alive on this machine)")
    } else {
        format!(" (sgf runs alive on this machine: {})", others.join(", "))
    }
}

/// A vocabulary message's versioned type name on the wire (iceoryx2
/// refuses to connect a publisher and a subscriber whose names differ).
pub trait WireName: Debug + Copy + 'static {
    /// `sgf.<Type>.v<N>`; bump with [`PROTOCOL_VERSION`].
    const TYPE_NAME: &'static str;
}

impl WireName for ParticleState {
    const TYPE_NAME: &'static str = "sgf.ParticleState.v1";
}

impl WireName for HydroLoad {
    const TYPE_NAME: &'static str = "sgf.HydroLoad.v1";
}

impl WireName for ExchangeHeader {
    const TYPE_NAME: &'static str = "sgf.ExchangeHeader.v1";
}

/// A vocabulary message ([`schemas::messages`]) as it lies in shared
/// memory: the same bytes, under iceoryx2's marker trait, which the
/// vocabulary crate does not depend on.
#[repr(transparent)]
#[derive(Debug, Clone, Copy, Default)]
struct Wire<T>(T);

// SAFETY: `Wire<T>` has `T`'s layout (`repr(transparent)`), and every
// `WireName` type is `repr(C)` plain data (u32, u64, f64 and arrays of
// them, padding explicit): no pointers, nothing process-local, the same
// bytes in both processes of one build; the handshake refuses a peer of
// another build ([`PROTOCOL_VERSION`]).
unsafe impl<T: WireName> ZeroCopySend for Wire<T> {
    unsafe fn type_name() -> &'static str {
        T::TYPE_NAME
    }
}

impl<T> Wire<T> {
    fn wrap_slice(data: &[T]) -> &[Wire<T>] {
        // SAFETY: `Wire<T>` is `repr(transparent)` over `T`: same size,
        // alignment and validity, so the slice reinterprets exactly.
        unsafe { std::slice::from_raw_parts(data.as_ptr().cast::<Wire<T>>(), data.len()) }
    }

    fn unwrap_slice(data: &[Wire<T>]) -> &[T] {
        // SAFETY: as in `wrap_slice`.
        unsafe { std::slice::from_raw_parts(data.as_ptr().cast::<T>(), data.len()) }
    }
}

/// Message types that travel over the link, with the names of their services.
pub trait Message: WireName {
    /// Last segment of the data service name.
    const SERVICE: &'static str;
    /// Last segment of the wake-up event service name.
    const READY: &'static str;
    /// Who sends it.
    const SENDER: Role;
    /// The sender's call, for [`LinkError::OutOfOrder`].
    const SEND_CALL: &'static str;
}

impl Message for ParticleState {
    const SERVICE: &'static str = "particles";
    const READY: &'static str = "particles_ready";
    const SENDER: Role = Role::Dem;
    const SEND_CALL: &'static str = "send_states";
}

impl Message for HydroLoad {
    const SERVICE: &'static str = "loads";
    const READY: &'static str = "loads_ready";
    const SENDER: Role = Role::Lbm;
    const SEND_CALL: &'static str = "send_loads";
}

type Ipc = ipc::Service;

/// Subscriber queue depth of the data services: the exchange is lock-step
/// (one message in flight per direction), 2 leaves room for a stop message.
const DATA_BUFFER: usize = 2;
/// Hello queue: stage 1 and stage 2 of up to two senders.
const HELLO_BUFFER: usize = 8;
/// [`Hello::stage`] of a sender that found a mismatch and leaves.
const STAGE_REJECTED: u32 = 3;
/// Poll period of the handshake (no event service there: it is rare and short).
const HANDSHAKE_POLL: Duration = Duration::from_millis(1);

/// One side of the link: publishes `Out`, receives `In`. Use [`DemLink`] or [`LbmLink`].
pub struct Link<Out: Message, In: Message> {
    role: Role,
    run_id: String,
    particles: usize,
    spin: Duration,
    peer_check: Duration,
    stop: Option<Arc<AtomicBool>>,
    peer_node: u128,
    peer_pid: u32,
    publisher: Publisher<Ipc, [Wire<Out>], Wire<ExchangeHeader>>,
    subscriber: Subscriber<Ipc, [Wire<In>], Wire<ExchangeHeader>>,
    notifier: Notifier<Ipc>,
    listener: Listener<Ipc>,
    // Dropped last: ports are released before their node.
    node: Node<Ipc>,
}

/// The DEM's side: sends [`ParticleState`]s, receives [`HydroLoad`]s.
pub struct DemLink(Link<ParticleState, HydroLoad>);

/// The LBM's side: receives [`ParticleState`]s, sends [`HydroLoad`]s.
pub struct LbmLink(Link<HydroLoad, ParticleState>);

impl DemLink {
    /// Creates node `sgf/<run_id>/dem`, removes stale resources of dead
    /// processes, and handshakes with the LBM (waits up to `connect_timeout`).
    pub fn connect(cfg: &LinkConfig) -> Result<Self, LinkError> {
        Link::connect(cfg, Role::Dem).map(DemLink)
    }

    /// Sends exchange `header.exchange`'s states (`header.count` is set from the slice).
    pub fn send_states(&mut self, header: ExchangeHeader, states: &[ParticleState]) -> Result<(), LinkError> {
        self.0.send(header, states)
    }

    /// Waits for the LBM's loads of exchange `expect_exchange`; `out` gets one per grain.
    pub fn receive_loads(
        &mut self,
        expect_exchange: u64,
        out: &mut Vec<HydroLoad>,
    ) -> Result<ExchangeHeader, LinkError> {
        self.0.receive(expect_exchange, out)
    }

    /// Tells the LBM this process stops (interrupted) before sending `exchange`.
    pub fn send_stop(&mut self, exchange: u64, time: f64) -> Result<(), LinkError> {
        self.0.send(ExchangeHeader::new(exchange, time).stopping(), &[])
    }

    /// Process id of the connected LBM.
    pub fn peer_pid(&self) -> u32 {
        self.0.peer_pid
    }
}

impl LbmLink {
    /// Creates node `sgf/<run_id>/lbm`, removes stale resources of dead
    /// processes, and handshakes with the DEM (waits up to `connect_timeout`).
    pub fn connect(cfg: &LinkConfig) -> Result<Self, LinkError> {
        Link::connect(cfg, Role::Lbm).map(LbmLink)
    }

    /// Waits for the DEM's states of exchange `expect_exchange`; `out` gets one per grain.
    pub fn receive_states(
        &mut self,
        expect_exchange: u64,
        out: &mut Vec<ParticleState>,
    ) -> Result<ExchangeHeader, LinkError> {
        self.0.receive(expect_exchange, out)
    }

    /// Sends exchange `header.exchange`'s loads (`header.count` is set from the slice).
    pub fn send_loads(&mut self, header: ExchangeHeader, loads: &[HydroLoad]) -> Result<(), LinkError> {
        self.0.send(header, loads)
    }

    /// Tells the DEM this process stops (interrupted) before sending `exchange`.
    pub fn send_stop(&mut self, exchange: u64, time: f64) -> Result<(), LinkError> {
        self.0.send(ExchangeHeader::new(exchange, time).stopping(), &[])
    }

    /// Process id of the connected DEM.
    pub fn peer_pid(&self) -> u32 {
        self.0.peer_pid
    }
}

/// Checks a run id: 1–40 characters of `[A-Za-z0-9_-]` (it becomes part of
/// shared-memory file names).
pub fn validate_run_id(run_id: &str) -> Result<(), LinkError> {
    let ok =
        (1..=40).contains(&run_id.len()) && run_id.bytes().all(|b| b.is_ascii_alphanumeric() || b == b'_' || b == b'-');
    if ok {
        Ok(())
    } else {
        Err(LinkError::InvalidRunId { run_id: run_id.to_string() })
    }
}

/// Removes the shared memory and files left by dead (killed) sgf processes of
/// `run_id`, or of every run when `None`; returns how many dead nodes were
/// cleaned. For the supervisor after it killed its children; connecting does
/// the same for every dead iceoryx2 node on its own.
pub fn cleanup_stale(run_id: Option<&str>) -> usize {
    set_log_level_from_env_or(LogLevel::Error);
    let prefix = match run_id {
        Some(id) => format!("sgf/{id}/"),
        None => String::from("sgf/"),
    };
    let mut dead = Vec::new();
    let listed = Node::<Ipc>::list(Config::global_config(), |state| {
        if let NodeState::Dead(view) = state {
            if view.details().as_ref().is_some_and(|d| d.name().as_str().starts_with(&prefix)) {
                dead.push(view);
            }
        }
        CallbackProgression::Continue
    });
    if listed.is_err() {
        return 0;
    }
    dead.into_iter().filter(|view| view.clone().try_remove_stale_resources().is_ok()).count()
}

/// Run ids of sgf nodes alive on this machine other than `except`, sorted, once each.
fn alive_runs(config: &Config, except: &str) -> Vec<String> {
    let mut runs = Vec::new();
    let _ = Node::<Ipc>::list(config, |state| {
        if let NodeState::Alive(view) = &state {
            if let Some(run) = view.details().as_ref().and_then(|d| run_of(d.name().as_str())) {
                if run != except {
                    runs.push(run.to_string());
                }
            }
        }
        CallbackProgression::Continue
    });
    runs.sort();
    runs.dedup();
    runs
}

/// `sgf/<run>/<role>` → `<run>`.
fn run_of(node_name: &str) -> Option<&str> {
    let rest = node_name.strip_prefix("sgf/")?;
    let (run, role) = rest.rsplit_once('/')?;
    (role == "dem" || role == "lbm").then_some(run)
}

/// Alive nodes named `name` other than `us`: their pids.
fn alive_named(config: &Config, name: &str, us: u128) -> Option<u32> {
    let mut pid = None;
    let _ = Node::<Ipc>::list(config, |state| {
        if let NodeState::Alive(view) = &state {
            if let Some(d) = view.details() {
                if view.id().value() != us && d.name().as_str() == name {
                    pid = Some(d.process_id().value() as u32);
                    return CallbackProgression::Stop;
                }
            }
        }
        CallbackProgression::Continue
    });
    pid
}

enum Liveness {
    Alive,
    Dead,
    Gone,
    Unknown,
}

/// State of node `id`: one listing of the node directory (allocates; only
/// called while blocked, every `peer_check`).
fn liveness(config: &Config, id: u128) -> Liveness {
    let mut found = Liveness::Gone;
    let listed = Node::<Ipc>::list(config, |state| {
        if state.node_id().value() != id {
            return CallbackProgression::Continue;
        }
        found = match state {
            NodeState::Alive(_) => Liveness::Alive,
            NodeState::Dead(_) => Liveness::Dead,
            NodeState::Inaccessible(_) | NodeState::Undefined(_) => Liveness::Unknown,
        };
        CallbackProgression::Stop
    });
    match listed {
        Ok(()) => found,
        Err(_) => Liveness::Unknown,
    }
}

fn transport<E: Debug>(what: &'static str) -> impl FnOnce(E) -> LinkError {
    move |e| LinkError::Transport(format!("{what} ({e:?})"))
}

fn split_id(id: u128) -> [u64; 2] {
    [(id >> 64) as u64, id as u64]
}

fn join_id(id: [u64; 2]) -> u128 {
    ((id[0] as u128) << 64) | id[1] as u128
}

fn service_name(run_id: &str, last: &str) -> Result<ServiceName, LinkError> {
    ServiceName::new(&format!("sgf/{run_id}/{last}")).map_err(transport("forming a service name"))
}

impl<Out: Message, In: Message> Link<Out, In> {
    fn connect(cfg: &LinkConfig, role: Role) -> Result<Self, LinkError> {
        debug_assert!(Out::SENDER == role && In::SENDER == role.peer());
        validate_run_id(&cfg.run_id)?;
        if u32::try_from(cfg.particles).is_err() {
            return Err(LinkError::TooManyGrains { particles: cfg.particles });
        }
        let run_id = cfg.run_id.as_str();
        let started = Instant::now();
        let node = create_node(run_id, role)?;
        let hello_ports = HelloPorts::open(&node, run_id)?;
        let mut hello = Hello {
            protocol_version: cfg.protocol_version_override.unwrap_or(PROTOCOL_VERSION),
            role: role.code(),
            scene_hash: cfg.scene_hash,
            particles: cfg.particles as u64,
            node_id: split_id(node.id().value()),
            pid: std::process::id(),
            stage: 1,
        };
        hello_ports.publisher.send_copy(hello).map_err(transport("publishing the hello"))?;
        let peer = await_peer_hello(&node, &hello_ports, hello, cfg, role, started)?;
        let peer_node = join_id(peer.node_id);

        // 0 on one side: that side learns the count from the peer (the LBM
        // cannot know how many grains the DEM's deposition kept).
        let particles = if cfg.particles == 0 { peer.particles as usize } else { cfg.particles };
        if particles == 0 {
            return Err(LinkError::Transport(String::from(
                "handshaking: neither process gave a grain count; the DEM must connect with its grain count",
            )));
        }
        let (publisher, notifier) = Self::open_out(&node, run_id, particles)?;
        let (subscriber, listener) = Self::open_in(&node, run_id)?;

        // Stage 2: tell the peer our ports exist, wait until its ports exist.
        hello.stage = 2;
        hello_ports.publisher.send_copy(hello).map_err(transport("publishing the hello"))?;
        await_peer_ports(&node, &hello_ports, &peer, cfg, role, started)?;
        // A peer that read our stage 1 only from the history gets stage 2 the same way.
        hello_ports.publisher.update_connections().map_err(transport("delivering the hello"))?;
        // Connect to the peer's ports now that they exist: a message whose
        // publisher is gone before our first receive would otherwise be lost
        // (a peer that sends its last message and exits at once).
        subscriber.update_connections().map_err(transport("connecting to the peer's publisher"))?;
        publisher.update_connections().map_err(transport("connecting to the peer's subscriber"))?;

        Ok(Self {
            role,
            run_id: run_id.to_string(),
            particles,
            spin: cfg.spin,
            peer_check: cfg.peer_check.max(Duration::from_millis(1)),
            stop: cfg.stop.clone(),
            peer_node,
            peer_pid: peer.pid,
            publisher,
            subscriber,
            notifier,
            listener,
            node,
        })
    }

    #[allow(clippy::type_complexity)]
    fn open_out(
        node: &Node<Ipc>,
        run_id: &str,
        particles: usize,
    ) -> Result<(Publisher<Ipc, [Wire<Out>], Wire<ExchangeHeader>>, Notifier<Ipc>), LinkError> {
        let service = data_service::<Out>(node, run_id)?;
        let publisher = service
            .publisher_builder()
            .initial_max_slice_len(particles.max(1))
            // Static, not PowerOfTwo: a growable segment is mapped by the
            // receiver only when it first reads from it, so a peer that sends
            // its last message and exits at once loses it ("Lost chunk").
            .allocation_strategy(AllocationStrategy::Static)
            .max_loaned_samples(1)
            .create()
            .map_err(transport("creating the data publisher"))?;
        let notifier = event_service(node, run_id, Out::READY)?
            .notifier_builder()
            .create()
            .map_err(transport("creating the wake-up notifier"))?;
        Ok((publisher, notifier))
    }

    #[allow(clippy::type_complexity)]
    fn open_in(
        node: &Node<Ipc>,
        run_id: &str,
    ) -> Result<(Subscriber<Ipc, [Wire<In>], Wire<ExchangeHeader>>, Listener<Ipc>), LinkError> {
        let service = data_service::<In>(node, run_id)?;
        let subscriber = service
            .subscriber_builder()
            .buffer_size(DATA_BUFFER)
            .create()
            .map_err(transport("creating the data subscriber"))?;
        let listener = event_service(node, run_id, In::READY)?
            .listener_builder()
            .create()
            .map_err(transport("creating the wake-up listener"))?;
        Ok((subscriber, listener))
    }

    /// Loans a slice in shared memory, copies `data` into it, sends it and
    /// wakes the peer. Allocates nothing itself; iceoryx2 0.10's loan makes
    /// one small `Rc` per message (its sample bookkeeping), measured in the tests.
    fn send(&mut self, mut header: ExchangeHeader, data: &[Out]) -> Result<(), LinkError> {
        let bye = header.is_stopping() && data.is_empty();
        if data.len() != self.particles && !bye {
            return Err(LinkError::SendLength {
                call: Out::SEND_CALL,
                exchange: header.exchange,
                expected: self.particles,
                got: data.len(),
            });
        }
        header.count = data.len() as u32;
        let sent = (|| {
            let mut sample = self.publisher.loan_slice_uninit(data.len()).map_err(transport("loaning a slice"))?;
            *sample.user_header_mut() = Wire(header);
            let sample = sample.write_from_slice(Wire::wrap_slice(data));
            sample.send().map_err(transport("sending a message"))?;
            self.notifier.notify().map_err(transport("waking the peer"))?;
            Ok(())
        })();
        // A send into a dead peer is best reported as that.
        if sent.is_err() {
            self.check_peer()?;
        }
        sent
    }

    /// Spins, then blocks, until exchange `expect`'s message arrives; copies
    /// it into `out` (resized to the count; no allocation once `out` has the capacity).
    fn receive(&mut self, expect: u64, out: &mut Vec<In>) -> Result<ExchangeHeader, LinkError> {
        let start = Instant::now();
        loop {
            if let Some(h) = self.take(expect, out)? {
                return Ok(h);
            }
            if start.elapsed() >= self.spin {
                break;
            }
            std::hint::spin_loop();
        }
        let mut last_check = Instant::now();
        loop {
            match self.listener.timed_wait(|_| {}, self.peer_check) {
                // A signal only wakes us: the stop flag decides.
                Ok(_) | Err(ListenerWaitError::InterruptSignal) => {}
                Err(e) => return Err(transport("waiting for the wake-up event")(e)),
            }
            if let Some(h) = self.take(expect, out)? {
                return Ok(h);
            }
            if self.stop.as_ref().is_some_and(|s| s.load(Ordering::Relaxed)) {
                return Err(LinkError::Interrupted);
            }
            if last_check.elapsed() >= self.peer_check {
                last_check = Instant::now();
                self.check_peer()?;
            }
        }
    }

    /// One non-blocking look at the subscriber.
    fn take(&mut self, expect: u64, out: &mut Vec<In>) -> Result<Option<ExchangeHeader>, LinkError> {
        let Some(sample) = self.subscriber.receive().map_err(transport("receiving a message"))? else {
            return Ok(None);
        };
        let h = sample.user_header().0;
        let payload = Wire::unwrap_slice(sample.payload());
        let peer = self.role.peer();
        if h.is_stopping() && payload.is_empty() {
            return Err(LinkError::PeerStopped { role: peer, exchange: expect });
        }
        if let Err(e) = schemas::messages::check_order(expect, &h) {
            return Err(LinkError::OutOfOrder { expected: e.expected, got: e.got, peer, call: In::SEND_CALL });
        }
        if payload.len() != self.particles || h.count as usize != payload.len() {
            return Err(LinkError::CountMismatch {
                exchange: h.exchange,
                expected: self.particles,
                got: payload.len(),
                peer,
            });
        }
        out.clear();
        out.extend_from_slice(payload);
        Ok(Some(h))
    }

    fn check_peer(&self) -> Result<(), LinkError> {
        match gone(self.node.config(), self.peer_node) {
            None => Ok(()),
            Some(how) => Err(LinkError::PeerDead {
                role: self.role.peer(),
                pid: self.peer_pid,
                run_id: self.run_id.clone(),
                how,
            }),
        }
    }
}

/// Node `sgf/<run_id>/<role>`, after removing what dead nodes left in
/// shared memory; refuses to be a second process in the same role.
fn create_node(run_id: &str, role: Role) -> Result<Node<Ipc>, LinkError> {
    // iceoryx2 warns at Info that it runs without a config file (it
    // needs none); IOX2_LOG_LEVEL still overrides.
    set_log_level_from_env_or(LogLevel::Error);
    let node_name = format!("sgf/{run_id}/{}", role.node_suffix());
    let node = NodeBuilder::new()
        .name(&NodeName::new(&node_name).map_err(transport("forming the node name"))?)
        // Our processes handle SIGINT/SIGTERM themselves (signal_hook flag).
        .signal_handling_mode(SignalHandlingMode::Disabled)
        .create::<Ipc>()
        .map_err(transport("creating the iceoryx2 node"))?;
    // Shared memory of killed processes (ours or any other) would keep
    // stale publishers and full segments around: remove it first.
    node.try_cleanup_dead_nodes();
    if let Some(pid) = alive_named(node.config(), &node_name, node.id().value()) {
        return Err(LinkError::RoleTaken { role, run_id: run_id.to_string(), pid });
    }
    Ok(node)
}

/// The handshake's ports on `sgf/<run_id>/hello` (history 1, so a late
/// peer still reads the last hello).
struct HelloPorts {
    publisher: Publisher<Ipc, Hello, ()>,
    subscriber: Subscriber<Ipc, Hello, ()>,
}

impl HelloPorts {
    fn open(node: &Node<Ipc>, run_id: &str) -> Result<Self, LinkError> {
        let service = node
            .service_builder(&service_name(run_id, "hello")?)
            .publish_subscribe::<Hello>()
            .history_size(1)
            .subscriber_max_buffer_size(HELLO_BUFFER)
            .max_publishers(4)
            .max_subscribers(4)
            .open_or_create()
            .map_err(transport("opening the hello service"))?;
        let subscriber = service
            .subscriber_builder()
            .buffer_size(HELLO_BUFFER)
            .create()
            .map_err(transport("creating the hello subscriber"))?;
        let publisher = service.publisher_builder().create().map_err(transport("creating the hello publisher"))?;
        Ok(Self { publisher, subscriber })
    }
}

/// No peer answered within the connect timeout.
fn no_peer(node: &Node<Ipc>, cfg: &LinkConfig, role: Role) -> LinkError {
    LinkError::NoPeer {
        role: role.peer(),
        run_id: cfg.run_id.clone(),
        waited: cfg.connect_timeout,
        others: alive_runs(node.config(), &cfg.run_id),
    }
}

/// Handshake stage 1: waits for a peer's hello that agrees with `ours`
/// (protocol version, role, scene hash, grain count). A mismatch is
/// announced to the peer before it is returned.
fn await_peer_hello(
    node: &Node<Ipc>,
    ports: &HelloPorts,
    ours: Hello,
    cfg: &LinkConfig,
    role: Role,
    started: Instant,
) -> Result<Hello, LinkError> {
    let us = join_id(ours.node_id);
    let stopped = || cfg.stop.as_ref().is_some_and(|s| s.load(Ordering::Relaxed));
    loop {
        // Late subscribers get our hello from the history only when our
        // publisher updates its connections.
        ports.publisher.update_connections().map_err(transport("delivering the hello"))?;
        while let Some(sample) = ports.subscriber.receive().map_err(transport("receiving a hello"))? {
            let h = *sample.payload();
            if join_id(h.node_id) == us {
                continue;
            }
            if let Err(e) = check_hello(cfg, role, &h) {
                linger_rejected(node, &ports.publisher, &ports.subscriber, ours, &h, cfg, started);
                return Err(e);
            }
            // A rejecting hello that agrees with us refused a third process.
            if h.stage != STAGE_REJECTED {
                return Ok(h);
            }
        }
        if stopped() {
            return Err(LinkError::Interrupted);
        }
        if started.elapsed() > cfg.connect_timeout {
            return Err(no_peer(node, cfg, role));
        }
        std::thread::sleep(HANDSHAKE_POLL);
    }
}

/// Handshake stage 2: waits until the peer says its data ports exist,
/// watching our stop flag, the peer's liveness and the timeout.
fn await_peer_ports(
    node: &Node<Ipc>,
    ports: &HelloPorts,
    peer: &Hello,
    cfg: &LinkConfig,
    role: Role,
    started: Instant,
) -> Result<(), LinkError> {
    let peer_node = join_id(peer.node_id);
    let stopped = || cfg.stop.as_ref().is_some_and(|s| s.load(Ordering::Relaxed));
    let mut peer_stage = peer.stage;
    let mut last_check = Instant::now();
    while peer_stage < 2 {
        ports.publisher.update_connections().map_err(transport("delivering the hello"))?;
        while let Some(sample) = ports.subscriber.receive().map_err(transport("receiving a hello"))? {
            let h = *sample.payload();
            if join_id(h.node_id) != peer_node {
                continue;
            }
            if h.stage == STAGE_REJECTED {
                return Err(match check_hello(cfg, role, &h) {
                    Err(e) => e,
                    Ok(()) => LinkError::Transport(String::from(
                        "handshaking: the peer refused this process after agreeing; start both again",
                    )),
                });
            }
            peer_stage = peer_stage.max(h.stage);
        }
        if peer_stage >= 2 {
            break;
        }
        if stopped() {
            return Err(LinkError::Interrupted);
        }
        if last_check.elapsed() >= cfg.peer_check {
            last_check = Instant::now();
            if let Some(how) = gone(node.config(), peer_node) {
                return Err(LinkError::PeerDead { role: role.peer(), pid: peer.pid, run_id: cfg.run_id.clone(), how });
            }
        }
        if started.elapsed() > cfg.connect_timeout {
            return Err(no_peer(node, cfg, role));
        }
        std::thread::sleep(HANDSHAKE_POLL);
    }
    Ok(())
}

/// After a mismatch: make sure the peer sees our hello before we go, so it
/// reports the mismatch too instead of timing out. Samples a subscriber has
/// not picked up yet vanish with their publisher, hence the wait: until the
/// peer rejects us as well (stage 3), is gone, or the connect timeout ends.
fn linger_rejected(
    node: &Node<Ipc>,
    hello_pub: &Publisher<Ipc, Hello, ()>,
    hello_sub: &Subscriber<Ipc, Hello, ()>,
    mut ours: Hello,
    theirs: &Hello,
    cfg: &LinkConfig,
    started: Instant,
) {
    ours.stage = STAGE_REJECTED;
    if hello_pub.send_copy(ours).is_err() || theirs.stage == STAGE_REJECTED {
        return;
    }
    let peer = join_id(theirs.node_id);
    let mut last_check = Instant::now();
    while started.elapsed() < cfg.connect_timeout {
        let _ = hello_pub.update_connections();
        while let Ok(Some(sample)) = hello_sub.receive() {
            if join_id(sample.payload().node_id) == peer && sample.payload().stage == STAGE_REJECTED {
                return;
            }
        }
        if cfg.stop.as_ref().is_some_and(|s| s.load(Ordering::Relaxed)) {
            return;
        }
        if last_check.elapsed() >= HANDSHAKE_POLL * 10 {
            last_check = Instant::now();
            if gone(node.config(), peer).is_some() {
                return;
            }
        }
        std::thread::sleep(HANDSHAKE_POLL);
    }
}

/// How node `id` ended, if it did.
fn gone(config: &Config, id: u128) -> Option<&'static str> {
    match liveness(config, id) {
        Liveness::Alive | Liveness::Unknown => None,
        Liveness::Dead => Some("died (killed or crashed)"),
        Liveness::Gone => Some("is gone (it exited without a stop message, or was killed and already cleaned up)"),
    }
}

fn check_hello(cfg: &LinkConfig, role: Role, h: &Hello) -> Result<(), LinkError> {
    let ours = cfg.protocol_version_override.unwrap_or(PROTOCOL_VERSION);
    if h.protocol_version != ours {
        return Err(LinkError::ProtocolMismatch { ours, theirs: h.protocol_version });
    }
    match Role::from_code(h.role) {
        Some(r) if r == role.peer() => {}
        _ => return Err(LinkError::RoleTaken { role, run_id: cfg.run_id.clone(), pid: h.pid }),
    }
    if h.scene_hash != cfg.scene_hash {
        return Err(LinkError::SceneMismatch { ours: cfg.scene_hash, theirs: h.scene_hash });
    }
    if h.particles != cfg.particles as u64 && h.particles != 0 && cfg.particles != 0 {
        return Err(LinkError::ParticlesMismatch { ours: cfg.particles, theirs: h.particles as usize });
    }
    Ok(())
}

/// The service factory of `T`'s slices behind an exchange header.
type DataService<T> =
    iceoryx2::service::port_factory::publish_subscribe::PortFactory<Ipc, [Wire<T>], Wire<ExchangeHeader>>;

/// The slice service for `T`; both sides open it with the same settings.
fn data_service<T: Message>(node: &Node<Ipc>, run_id: &str) -> Result<DataService<T>, LinkError> {
    node.service_builder(&service_name(run_id, T::SERVICE)?)
        .publish_subscribe::<[Wire<T>]>()
        .user_header::<Wire<ExchangeHeader>>()
        .history_size(0)
        .subscriber_max_buffer_size(DATA_BUFFER)
        .subscriber_max_borrowed_samples(1)
        // Room for a wrong second process to connect and be told so by the handshake.
        .max_publishers(2)
        .max_subscribers(2)
        .open_or_create()
        .map_err(transport("opening a data service"))
}

fn event_service(
    node: &Node<Ipc>,
    run_id: &str,
    last: &str,
) -> Result<iceoryx2::service::port_factory::event::PortFactory<Ipc>, LinkError> {
    node.service_builder(&service_name(run_id, last)?)
        .event()
        .max_notifiers(2)
        .max_listeners(2)
        .open_or_create()
        .map_err(transport("opening a wake-up event service"))
}
