//! What `dem_proc` and `lbm_proc` exchange once per LBM step, and the two
//! views of a peer each solver steps against (docs/coupling.md).
//!
//! The solvers never see the transport: the DEM talks to a [`LoadPeer`], the
//! LBM to a [`StatePeer`]. Over shared memory both are the iceoryx2 link of
//! [`crate::link`]; in one process (the test-only driver) the DEM's peer
//! steps the LBM directly; for isolation runs a peer replays a recording.
//! The same messages in the same order reach the solver in every case, so
//! the transport cannot change a result.

pub use crate::link::{ExchangeHeader, HydroLoad, ParticleState, FLAG_STOPPING};

/// Why an exchange failed; the message names the cause and the fix.
pub type PeerError = Box<dyn std::error::Error + Send + Sync>;

/// The DEM's side of an exchange.
pub trait LoadPeer {
    /// Publishes the grain states of exchange `header.exchange`.
    fn send_states(&mut self, header: ExchangeHeader, states: &[ParticleState]) -> Result<(), PeerError>;
    /// The loads of exchange `exchange` (waits for them); `out` is resized to the count.
    fn receive_loads(&mut self, exchange: u64, out: &mut Vec<HydroLoad>) -> Result<ExchangeHeader, PeerError>;
}

/// The LBM's side of an exchange.
pub trait StatePeer {
    /// The grain states of exchange `exchange` (waits for them); a header
    /// with [`FLAG_STOPPING`] ends the run.
    fn receive_states(&mut self, exchange: u64, out: &mut Vec<ParticleState>) -> Result<ExchangeHeader, PeerError>;
    /// Publishes the loads of exchange `header.exchange`.
    fn send_loads(&mut self, header: ExchangeHeader, loads: &[HydroLoad]) -> Result<(), PeerError>;
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

fn check_order(side: &str, expected: u64, header: &ExchangeHeader) -> Result<(), PeerError> {
    if header.exchange != expected && !header.is_stopping() {
        return Err(format!(
            "{side} expected exchange {expected}, got {}: both processes must step the same scene in lockstep",
            header.exchange
        )
        .into());
    }
    Ok(())
}

impl LoadPeer for MemoryDemEnd {
    fn send_states(&mut self, header: ExchangeHeader, states: &[ParticleState]) -> Result<(), PeerError> {
        self.states.send((header, states.to_vec())).map_err(|_| "the LBM end of the in-process exchange is gone".into())
    }
    fn receive_loads(&mut self, exchange: u64, out: &mut Vec<HydroLoad>) -> Result<ExchangeHeader, PeerError> {
        let (header, loads) =
            self.loads.recv().map_err(|_| PeerError::from("the LBM end of the in-process exchange is gone"))?;
        check_order("DEM", exchange, &header)?;
        *out = loads;
        Ok(header)
    }
}

impl StatePeer for MemoryLbmEnd {
    fn receive_states(&mut self, exchange: u64, out: &mut Vec<ParticleState>) -> Result<ExchangeHeader, PeerError> {
        let (header, states) =
            self.states.recv().map_err(|_| PeerError::from("the DEM end of the in-process exchange is gone"))?;
        check_order("LBM", exchange, &header)?;
        *out = states;
        Ok(header)
    }
    fn send_loads(&mut self, header: ExchangeHeader, loads: &[HydroLoad]) -> Result<(), PeerError> {
        // The DEM may have finished and dropped its end: not an error for the sender.
        let _ = self.loads.send((header, loads.to_vec()));
        Ok(())
    }
}

impl LoadPeer for crate::link::DemLink {
    fn send_states(&mut self, header: ExchangeHeader, states: &[ParticleState]) -> Result<(), PeerError> {
        crate::link::DemLink::send_states(self, header, states).map_err(Into::into)
    }
    fn receive_loads(&mut self, exchange: u64, out: &mut Vec<HydroLoad>) -> Result<ExchangeHeader, PeerError> {
        match crate::link::DemLink::receive_loads(self, exchange, out) {
            // The LBM stopped (interrupted): the DEM stops too, not an error.
            Err(crate::link::LinkError::PeerStopped { .. }) => Ok(ExchangeHeader::new(exchange, f64::NAN).stopping()),
            r => r.map_err(Into::into),
        }
    }
}

impl StatePeer for crate::link::LbmLink {
    fn receive_states(&mut self, exchange: u64, out: &mut Vec<ParticleState>) -> Result<ExchangeHeader, PeerError> {
        match crate::link::LbmLink::receive_states(self, exchange, out) {
            Err(crate::link::LinkError::PeerStopped { .. }) => Ok(ExchangeHeader::new(exchange, f64::NAN).stopping()),
            r => r.map_err(Into::into),
        }
    }
    fn send_loads(&mut self, header: ExchangeHeader, loads: &[HydroLoad]) -> Result<(), PeerError> {
        crate::link::LbmLink::send_loads(self, header, loads).map_err(Into::into)
    }
}

/// Encoding of one received exchange message for the recording
/// (`/dem/received_loads`, `/lbm/received_states`), little-endian, no
/// padding: the header as `exchange` u64, `time` f64, `count` u32, `flags`
/// u32, then `count` records of u32 id and f64 fields in declaration order
/// (a load: force (3), torque (3), liquid_mass; a state: position (3),
/// velocity (3), angular_velocity (3), radius). docs/coupling.md "Isolation".
pub const RECEIVED_ENCODING: &str = "sgf exchange v1 (little-endian; see docs/coupling.md)";

fn put_header(h: &ExchangeHeader, count: usize, out: &mut Vec<u8>) {
    out.extend_from_slice(&h.exchange.to_le_bytes());
    out.extend_from_slice(&h.time.to_le_bytes());
    out.extend_from_slice(&(count as u32).to_le_bytes());
    out.extend_from_slice(&h.flags.to_le_bytes());
}

fn put_f64s(values: &[f64], out: &mut Vec<u8>) {
    for v in values {
        out.extend_from_slice(&v.to_le_bytes());
    }
}

/// Reads little-endian fields off a message, with the message's name in errors.
struct Cursor<'a> {
    bytes: &'a [u8],
    at: usize,
    what: &'static str,
}

impl Cursor<'_> {
    fn take<const N: usize>(&mut self) -> Result<[u8; N], PeerError> {
        let end = self.at + N;
        let b = self.bytes.get(self.at..end).ok_or_else(|| {
            PeerError::from(format!("{}: message truncated at byte {} of {}", self.what, self.at, self.bytes.len()))
        })?;
        self.at = end;
        Ok(b.try_into().expect("slice of N bytes"))
    }
    fn u32(&mut self) -> Result<u32, PeerError> {
        Ok(u32::from_le_bytes(self.take()?))
    }
    fn u64(&mut self) -> Result<u64, PeerError> {
        Ok(u64::from_le_bytes(self.take()?))
    }
    fn f64(&mut self) -> Result<f64, PeerError> {
        Ok(f64::from_le_bytes(self.take()?))
    }
    fn vec3(&mut self) -> Result<[f64; 3], PeerError> {
        Ok([self.f64()?, self.f64()?, self.f64()?])
    }
    fn header(&mut self) -> Result<ExchangeHeader, PeerError> {
        Ok(ExchangeHeader { exchange: self.u64()?, time: self.f64()?, count: self.u32()?, flags: self.u32()? })
    }
    fn end(&self) -> Result<(), PeerError> {
        if self.at != self.bytes.len() {
            return Err(
                format!("{}: {} bytes left over after the last record", self.what, self.bytes.len() - self.at).into()
            );
        }
        Ok(())
    }
}

/// Encodes received loads (see [`RECEIVED_ENCODING`]).
pub fn encode_loads(header: &ExchangeHeader, loads: &[HydroLoad], out: &mut Vec<u8>) {
    out.clear();
    put_header(header, loads.len(), out);
    for l in loads {
        out.extend_from_slice(&l.id.to_le_bytes());
        put_f64s(&l.force, out);
        put_f64s(&l.torque, out);
        put_f64s(&[l.liquid_mass], out);
    }
}

/// Decodes a message of [`encode_loads`].
pub fn decode_loads(bytes: &[u8]) -> Result<(ExchangeHeader, Vec<HydroLoad>), PeerError> {
    let mut c = Cursor { bytes, at: 0, what: "received loads" };
    let header = c.header()?;
    let mut loads = Vec::with_capacity(header.count as usize);
    for _ in 0..header.count {
        loads.push(HydroLoad { id: c.u32()?, _pad: 0, force: c.vec3()?, torque: c.vec3()?, liquid_mass: c.f64()? });
    }
    c.end()?;
    Ok((header, loads))
}

/// Encodes received grain states (see [`RECEIVED_ENCODING`]).
pub fn encode_states(header: &ExchangeHeader, states: &[ParticleState], out: &mut Vec<u8>) {
    out.clear();
    put_header(header, states.len(), out);
    for s in states {
        out.extend_from_slice(&s.id.to_le_bytes());
        put_f64s(&s.position, out);
        put_f64s(&s.velocity, out);
        put_f64s(&s.angular_velocity, out);
        put_f64s(&[s.radius], out);
    }
}

/// Decodes a message of [`encode_states`].
pub fn decode_states(bytes: &[u8]) -> Result<(ExchangeHeader, Vec<ParticleState>), PeerError> {
    let mut c = Cursor { bytes, at: 0, what: "received states" };
    let header = c.header()?;
    let mut states = Vec::with_capacity(header.count as usize);
    for _ in 0..header.count {
        states.push(ParticleState {
            id: c.u32()?,
            _pad: 0,
            position: c.vec3()?,
            velocity: c.vec3()?,
            angular_velocity: c.vec3()?,
            radius: c.f64()?,
        });
    }
    c.end()?;
    Ok((header, states))
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

fn replay_order(side: &str, expected: u64, header: &ExchangeHeader) -> Result<(), PeerError> {
    if header.exchange != expected && !header.is_stopping() {
        return Err(format!(
            "{side} replay expected exchange {expected}, the recording has {}: replay the scene, overrides and schedule the recording ran",
            header.exchange
        )
        .into());
    }
    Ok(())
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
        Ok(ReplayLoads { messages: recorded_messages(path, crate::record::topics::DEM_RECEIVED_LOADS)?.into_iter() })
    }
}

impl LoadPeer for ReplayLoads {
    fn send_states(&mut self, _header: ExchangeHeader, _states: &[ParticleState]) -> Result<(), PeerError> {
        Ok(())
    }
    fn receive_loads(&mut self, exchange: u64, out: &mut Vec<HydroLoad>) -> Result<ExchangeHeader, PeerError> {
        let Some(bytes) = self.messages.next() else {
            return Ok(ExchangeHeader::new(exchange, f64::NAN).stopping());
        };
        let (header, loads) = decode_loads(&bytes)?;
        replay_order("DEM", exchange, &header)?;
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
        Ok(ReplayStates { messages: recorded_messages(path, crate::record::topics::LBM_RECEIVED_STATES)?.into_iter() })
    }
}

impl StatePeer for ReplayStates {
    fn receive_states(&mut self, exchange: u64, out: &mut Vec<ParticleState>) -> Result<ExchangeHeader, PeerError> {
        let Some(bytes) = self.messages.next() else {
            return Ok(ExchangeHeader::new(exchange, f64::NAN).stopping());
        };
        let (header, states) = decode_states(&bytes)?;
        replay_order("LBM", exchange, &header)?;
        *out = states;
        Ok(header)
    }
    fn send_loads(&mut self, _header: ExchangeHeader, _loads: &[HydroLoad]) -> Result<(), PeerError> {
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn received_messages_round_trip_exactly() {
        let header = ExchangeHeader { exchange: 7, time: 5.6e-4, count: 2, flags: FLAG_STOPPING };
        let loads = [
            HydroLoad {
                id: 0,
                _pad: 0,
                force: [1e-3, -2.5e-7, f64::MIN_POSITIVE],
                torque: [0.0, -0.0, 3.0],
                liquid_mass: 1.4e-5,
            },
            HydroLoad { id: 1, _pad: 0, force: [0.1, 0.2, 0.3], torque: [4.0, 5.0, 6.0], liquid_mass: 0.0 },
        ];
        let mut bytes = Vec::new();
        encode_loads(&header, &loads, &mut bytes);
        assert_eq!(bytes.len(), 24 + 2 * 60);
        let (h, l) = decode_loads(&bytes).unwrap();
        assert_eq!((h, l.as_slice()), (header, &loads[..]));
        let states = [ParticleState {
            id: 3,
            _pad: 0,
            position: [0.1, 0.2, 0.3],
            velocity: [1.0, 2.0, 3.0],
            angular_velocity: [-1.0, 0.0, 1e300],
            radius: 1.25e-3,
        }];
        encode_states(&ExchangeHeader { count: 1, ..header }, &states, &mut bytes);
        let (h, s) = decode_states(&bytes).unwrap();
        assert_eq!((h.exchange, s.as_slice()), (7, &states[..]));
        // A cut message is an error naming what was cut, not a panic.
        let err = decode_states(&bytes[..bytes.len() - 3]).unwrap_err().to_string();
        assert!(err.contains("received states: message truncated"), "{err}");
    }
}
