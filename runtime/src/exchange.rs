//! What `dem_proc` and `lbm_proc` exchange once per LBM step, and the two
//! views of a peer each solver steps against (docs/coupling.md).
//!
//! The solvers never see the transport: the DEM talks to a [`LoadPeer`], the
//! LBM to a [`StatePeer`]. Over shared memory both are the iceoryx2 link of
//! [`crate::link`]; in one process (the test-only driver) the DEM's peer
//! steps the LBM directly; for isolation runs a peer replays a recording.
//! The same messages in the same order reach the solver in every case, so
//! the transport cannot change a result.

pub use schemas::messages::{
    check_order, decode_loads, decode_states, encode_loads, encode_states, ExchangeHeader, HydroLoad, ParticleState,
    FLAG_STOPPING, RECEIVED_ENCODING,
};

/// Why an exchange failed; the message names the cause and the fix.
pub type PeerError = Box<dyn std::error::Error + Send + Sync>;

/// One side's view of its peer: it sends `Sends` and receives `Receives`,
/// one message each per exchange. Transports deliver; they do not judge
/// the order: the run driver's [`crate::coupled::Exchange`] checks every
/// received header once, whatever the transport.
pub trait Peer<Sends, Receives> {
    /// Publishes the message of exchange `header.exchange`.
    fn send(&mut self, header: ExchangeHeader, message: &[Sends]) -> Result<(), PeerError>;
    /// The message of exchange `exchange` (waits for it); `out` holds its
    /// entries. A header with [`FLAG_STOPPING`] says the peer stops.
    fn receive(&mut self, exchange: u64, out: &mut Vec<Receives>) -> Result<ExchangeHeader, PeerError>;
}

/// The DEM's side of an exchange: grain states out, loads in.
pub trait LoadPeer: Peer<ParticleState, HydroLoad> {}
impl<T: Peer<ParticleState, HydroLoad> + ?Sized> LoadPeer for T {}

/// The LBM's side of an exchange: loads out, grain states in.
pub trait StatePeer: Peer<HydroLoad, ParticleState> {}
impl<T: Peer<HydroLoad, ParticleState> + ?Sized> StatePeer for T {}

impl<S, R, P: Peer<S, R> + ?Sized> Peer<S, R> for &mut P {
    fn send(&mut self, header: ExchangeHeader, message: &[S]) -> Result<(), PeerError> {
        (**self).send(header, message)
    }
    fn receive(&mut self, exchange: u64, out: &mut Vec<R>) -> Result<ExchangeHeader, PeerError> {
        (**self).receive(exchange, out)
    }
}

/// Both ends of an exchange inside one process, over `std::sync::mpsc`
/// channels: the test-only driver that runs `dem_proc::run::run` and
/// `lbm_proc::run::run` on two threads of one process. Against the
/// iceoryx2 run it shows that the transport adds nothing.
pub fn memory_pair() -> (MemoryDemEnd, MemoryLbmEnd) {
    let (state_tx, state_rx) = std::sync::mpsc::channel();
    let (load_tx, load_rx) = std::sync::mpsc::channel();
    (MemoryDemEnd { states: state_tx, loads: load_rx }, MemoryLbmEnd { states: state_rx, loads: load_tx })
}

/// The DEM's end of [`memory_pair`].
#[derive(Debug)]
pub struct MemoryDemEnd {
    states: std::sync::mpsc::Sender<(ExchangeHeader, Vec<ParticleState>)>,
    loads: std::sync::mpsc::Receiver<(ExchangeHeader, Vec<HydroLoad>)>,
}

/// The LBM's end of [`memory_pair`].
#[derive(Debug)]
pub struct MemoryLbmEnd {
    states: std::sync::mpsc::Receiver<(ExchangeHeader, Vec<ParticleState>)>,
    loads: std::sync::mpsc::Sender<(ExchangeHeader, Vec<HydroLoad>)>,
}

impl Peer<ParticleState, HydroLoad> for MemoryDemEnd {
    fn send(&mut self, header: ExchangeHeader, states: &[ParticleState]) -> Result<(), PeerError> {
        self.states.send((header, states.to_vec())).map_err(|_| "the LBM end of the in-process exchange is gone".into())
    }
    fn receive(&mut self, _exchange: u64, out: &mut Vec<HydroLoad>) -> Result<ExchangeHeader, PeerError> {
        let (header, loads) =
            self.loads.recv().map_err(|_| PeerError::from("the LBM end of the in-process exchange is gone"))?;
        *out = loads;
        Ok(header)
    }
}

impl Peer<HydroLoad, ParticleState> for MemoryLbmEnd {
    fn receive(&mut self, _exchange: u64, out: &mut Vec<ParticleState>) -> Result<ExchangeHeader, PeerError> {
        let (header, states) =
            self.states.recv().map_err(|_| PeerError::from("the DEM end of the in-process exchange is gone"))?;
        *out = states;
        Ok(header)
    }
    fn send(&mut self, header: ExchangeHeader, loads: &[HydroLoad]) -> Result<(), PeerError> {
        // The DEM may have finished and dropped its end: not an error for the sender.
        let _ = self.loads.send((header, loads.to_vec()));
        Ok(())
    }
}

impl Peer<ParticleState, HydroLoad> for crate::link::DemLink {
    fn send(&mut self, header: ExchangeHeader, states: &[ParticleState]) -> Result<(), PeerError> {
        crate::link::DemLink::send_states(self, header, states).map_err(Into::into)
    }
    fn receive(&mut self, exchange: u64, out: &mut Vec<HydroLoad>) -> Result<ExchangeHeader, PeerError> {
        match crate::link::DemLink::receive_loads(self, exchange, out) {
            // The LBM stopped (interrupted): the DEM stops too, not an error.
            Err(crate::link::LinkError::PeerStopped { .. }) => Ok(ExchangeHeader::new(exchange, f64::NAN).stopping()),
            r => r.map_err(Into::into),
        }
    }
}

impl Peer<HydroLoad, ParticleState> for crate::link::LbmLink {
    fn receive(&mut self, exchange: u64, out: &mut Vec<ParticleState>) -> Result<ExchangeHeader, PeerError> {
        match crate::link::LbmLink::receive_states(self, exchange, out) {
            Err(crate::link::LinkError::PeerStopped { .. }) => Ok(ExchangeHeader::new(exchange, f64::NAN).stopping()),
            r => r.map_err(Into::into),
        }
    }
    fn send(&mut self, header: ExchangeHeader, loads: &[HydroLoad]) -> Result<(), PeerError> {
        crate::link::LbmLink::send_loads(self, header, loads).map_err(Into::into)
    }
}

/// The messages of `topic` in a recording, in log order; an error naming
/// the override that records them when there are none.
pub fn recorded_messages(path: &std::path::Path, topic: &str) -> Result<Vec<Vec<u8>>, PeerError> {
    let bytes = std::fs::read(path).map_err(|e| format!("cannot read the recording {}: {e}", path.display()))?;
    let mut out = Vec::new();
    for msg in
        mcap::MessageStream::new(&bytes).map_err(|e| format!("{} is not a readable MCAP file: {e}", path.display()))?
    {
        let msg = msg
            .map_err(|e| format!("{}: {e} (a recording cut short reads up to its last whole chunk)", path.display()))?;
        if msg.channel.topic == topic {
            out.push(msg.data.into_owned());
        }
    }
    if out.is_empty() {
        return Err(format!(
            "{} has no {topic} messages: record the coupled run with `--set output.record_exchange=true`",
            path.display()
        )
        .into());
    }
    Ok(out)
}

/// The DEM's peer played back from a recording's `/dem/received_loads`: the
/// DEM runs alone and gets, exchange by exchange, the loads the LBM sent.
/// The states it sends are dropped. Past the recording's end it reads a stop.
#[derive(Debug)]
pub struct ReplayLoads {
    messages: std::vec::IntoIter<Vec<u8>>,
}

impl ReplayLoads {
    pub fn from_recording(path: &std::path::Path) -> Result<Self, PeerError> {
        Ok(ReplayLoads { messages: recorded_messages(path, schemas::topics::DEM_RECEIVED_LOADS)?.into_iter() })
    }
}

impl Peer<ParticleState, HydroLoad> for ReplayLoads {
    fn send(&mut self, _header: ExchangeHeader, _states: &[ParticleState]) -> Result<(), PeerError> {
        Ok(())
    }
    fn receive(&mut self, exchange: u64, out: &mut Vec<HydroLoad>) -> Result<ExchangeHeader, PeerError> {
        let Some(bytes) = self.messages.next() else {
            return Ok(ExchangeHeader::new(exchange, f64::NAN).stopping());
        };
        let (header, loads) = decode_loads(&bytes)?;
        *out = loads;
        Ok(header)
    }
}

/// The LBM's peer played back from a recording's `/lbm/received_states`:
/// the LBM runs alone on the grain motion the DEM sent. Loads are dropped.
#[derive(Debug)]
pub struct ReplayStates {
    messages: std::vec::IntoIter<Vec<u8>>,
}

impl ReplayStates {
    pub fn from_recording(path: &std::path::Path) -> Result<Self, PeerError> {
        Ok(ReplayStates { messages: recorded_messages(path, schemas::topics::LBM_RECEIVED_STATES)?.into_iter() })
    }
}

impl Peer<HydroLoad, ParticleState> for ReplayStates {
    fn receive(&mut self, exchange: u64, out: &mut Vec<ParticleState>) -> Result<ExchangeHeader, PeerError> {
        let Some(bytes) = self.messages.next() else {
            return Ok(ExchangeHeader::new(exchange, f64::NAN).stopping());
        };
        let (header, states) = decode_states(&bytes)?;
        *out = states;
        Ok(header)
    }
    fn send(&mut self, _header: ExchangeHeader, _loads: &[HydroLoad]) -> Result<(), PeerError> {
        Ok(())
    }
}
