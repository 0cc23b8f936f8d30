//! The DEM's half of the DEM–LBM coupling: at every `ratio`-th step it sends
//! the grain states to its [`LoadPeer`], takes the hydrodynamic loads back
//! and holds them as the world's external force and torque until the next
//! exchange (docs/coupling.md).
//!
//! Schedules (DESIGN §2):
//! - `sequential`: the load held over exchange interval n is the one the
//!   LBM computed from the grains at t_n.
//! - `concurrent`: the LBM works on exchange n while the DEM advances, so
//!   the DEM holds the load of exchange n − 1 (n = 0 waits once: there is no
//!   earlier load, and starting without buoyancy would drop every grain).
//!
//! The load is the momentum flux through each grain's surface as the LBM
//! measured it (lbm_proc `coupling`, step 6): drag, pressure, buoyancy and
//! the inertia of the liquid inside the grain, so the DEM adds nothing.

use runtime::exchange::{ExchangeHeader, HydroLoad, LoadPeer, ParticleState, PeerError, FLAG_STOPPING};
use schemas::scene::{Scene, Schedule};

use crate::world::World;

/// Opens the DEM's side of the exchange once the grain count is known
/// (after the packing): an iceoryx2 link, or an in-process channel in tests.
pub type Connect<'a> = Box<dyn FnOnce(usize) -> Result<Box<dyn LoadPeer + 'a>, PeerError> + 'a>;

/// State of the exchange kept between calls (no allocation after the first).
#[derive(Debug, Clone)]
pub struct HydroExchange {
    /// DEM steps per exchange.
    pub ratio: u64,
    pub schedule: Schedule,
    /// Exchange interval, s (= the LBM step).
    pub interval: f64,
    /// Index of the next exchange.
    pub next: u64,
    states: Vec<ParticleState>,
    loads: Vec<HydroLoad>,
    /// Wall seconds spent sending and waiting.
    pub exchange_seconds: f64,
    /// Exchanges done.
    pub exchanges: u64,
    /// Keep every received message, encoded, for the recording
    /// (`output.record_exchange`); the run drains [`Self::received`].
    pub record_received: bool,
    /// (simulated time, encoded loads) received since the last drain.
    pub received: Vec<(f64, Vec<u8>)>,
}

/// Whether the run goes on after an exchange.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Flow {
    Continue,
    /// The peer announced it stops (its load message carried the stop flag).
    PeerStopped,
}

impl HydroExchange {
    pub fn from_scene(scene: &Scene, dem_dt: f64) -> Self {
        let c = &scene.spec.coupling;
        HydroExchange {
            ratio: c.ratio as u64,
            schedule: c.schedule,
            interval: dem_dt * c.ratio as f64,
            next: 0,
            states: Vec::new(),
            loads: Vec::new(),
            exchange_seconds: 0.0,
            exchanges: 0,
            record_received: scene.spec.output.record_exchange,
            received: Vec::new(),
        }
    }

    /// True when `world` stands at an exchange boundary.
    pub fn due(&self, world: &World) -> bool {
        world.step_count.is_multiple_of(self.ratio)
    }

    /// Exchange index of a DEM step count (at a boundary).
    pub fn index_of(&self, step: u64) -> u64 {
        step / self.ratio
    }

    /// The exchange at the current boundary: send the states, take the load
    /// the schedule asks for, hold it in `world.external_*`.
    ///
    /// Pre: `self.due(world)`. Post: the world's external load is the one to
    /// hold until the next boundary.
    pub fn exchange(&mut self, world: &mut World, peer: &mut dyn LoadPeer) -> Result<Flow, PeerError> {
        let started = std::time::Instant::now();
        let n = self.index_of(world.step_count);
        if n != self.next {
            return Err(format!(
                "DEM at step {} expected exchange {}, not {n}: exchanges must come every {} steps in order",
                world.step_count, self.next, self.ratio
            )
            .into());
        }
        let mut flow = Flow::Continue;
        // Concurrent: the load of n − 1 was computed while the DEM advanced.
        let lagged = self.schedule == Schedule::Concurrent && n >= 1;
        if lagged && n >= 2 && self.receive(world, n - 1, peer)? {
            flow = Flow::PeerStopped;
        }
        self.capture_states(world);
        let header = ExchangeHeader { exchange: n, time: world.time, count: self.states.len() as u32, flags: 0 };
        peer.send_states(header, &self.states)?;
        if flow == Flow::Continue && !lagged && self.receive(world, n, peer)? {
            flow = Flow::PeerStopped;
        }
        self.apply_loads(world);
        self.next = n + 1;
        self.exchanges += 1;
        self.exchange_seconds += started.elapsed().as_secs_f64();
        Ok(flow)
    }

    /// Tells the peer the DEM stops: a state message with the stop flag.
    pub fn finish(&mut self, world: &World, peer: &mut dyn LoadPeer) -> Result<(), PeerError> {
        self.capture_states(world);
        let header = ExchangeHeader {
            exchange: self.next,
            time: world.time,
            count: self.states.len() as u32,
            flags: FLAG_STOPPING,
        };
        peer.send_states(header, &self.states)
    }

    fn capture_states(&mut self, world: &World) {
        capture_states(world, &mut self.states);
    }

    /// Receives exchange `n`; true when the peer stops.
    fn receive(&mut self, world: &World, n: u64, peer: &mut dyn LoadPeer) -> Result<bool, PeerError> {
        let header = peer.receive_loads(n, &mut self.loads)?;
        if self.record_received {
            let mut bytes = Vec::new();
            let loads: &[HydroLoad] = if header.is_stopping() { &[] } else { &self.loads };
            runtime::exchange::encode_loads(&header, loads, &mut bytes);
            self.received.push((world.time, bytes));
        }
        if header.is_stopping() {
            return Ok(true);
        }
        if self.loads.len() != world.len() || self.loads.iter().enumerate().any(|(p, l)| l.id as usize != p) {
            return Err(format!(
                "exchange {n}: the LBM answered {} loads for {} grains (or out of id order); both processes must run the same scene",
                self.loads.len(),
                world.len()
            )
            .into());
        }
        Ok(false)
    }

    /// Holds the last loads received as the grains' external force and torque.
    fn apply_loads(&self, world: &mut World) {
        for id in 0..world.len() {
            let (force, torque) = self.loads.get(id).map(|l| (l.force, l.torque)).unwrap_or_default();
            let p = world.slot(id);
            world.set_external_load(p, force, torque);
        }
    }
}

/// Every grain's state as the exchange sends it, in id order (the peer sees
/// fixed ids whatever the storage order), into `out` (cleared first).
pub fn capture_states(world: &World, out: &mut Vec<ParticleState>) {
    let g = &world.grains;
    out.clear();
    out.extend((0..g.len()).map(|id| {
        let p = world.slot(id);
        ParticleState {
            id: id as u32,
            _pad: 0,
            position: g.pos[p],
            velocity: g.vel[p],
            angular_velocity: g.omega[p],
            radius: g.radius[p],
        }
    }));
}
