//! What `dem_proc` and `lbm_proc` exchange once per LBM step (paper §2.3,
//! docs/coupling.md): the grain states one way, the hydrodynamic loads the
//! other, each slice behind an [`ExchangeHeader`]; and the byte layout in
//! which a process records what it received (`output.record_exchange`).
//!
//! Plain `#[repr(C)]` data with explicit padding: the transport (iceoryx2
//! shared memory in the `runtime` crate) sends these layouts as they are.

/// Why a recorded exchange message could not be decoded.
pub type DecodeError = Box<dyn std::error::Error + Send + Sync>;

/// Version of the messages and of the exchange sequence. Bump it (and the
/// `.vN` type names) whenever a message layout or the order of calls changes.
pub const PROTOCOL_VERSION: u32 = 1;

/// [`ExchangeHeader::flags`] bit: the sender stops after this message (end of
/// run, or interrupted). A stopping message with `count == 0` carries no data.
pub const FLAG_STOPPING: u32 = 1;

/// DEM → LBM, one per grain, SI units, f64.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct ParticleState {
    /// Grain id (index in the DEM's particle array).
    pub id: u32,
    /// Explicit padding so the layout has no hidden bytes.
    pub _pad: u32,
    /// Centre, m.
    pub position: [f64; 3],
    /// Centre velocity, m/s.
    pub velocity: [f64; 3],
    /// Angular velocity, rad/s.
    pub angular_velocity: [f64; 3],
    /// Radius, m.
    pub radius: f64,
}

/// LBM → DEM, one per grain, SI units.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct HydroLoad {
    /// Grain id, as received in [`ParticleState::id`].
    pub id: u32,
    /// Explicit padding so the layout has no hidden bytes.
    pub _pad: u32,
    /// Hydrodynamic force, N: the momentum flux through the grain's surface
    /// (drag, pressure, buoyancy and the inertia of the liquid inside it).
    pub force: [f64; 3],
    /// Hydrodynamic torque about the centre, N m.
    pub torque: [f64; 3],
    /// Liquid mass covered by the grain, kg (ρ_L times its wetted volume).
    pub liquid_mass: f64,
}

/// User header of every exchange message.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct ExchangeHeader {
    /// Exchange index n, 0-based.
    pub exchange: u64,
    /// Simulated time t_n, s.
    pub time: f64,
    /// Number of entries in the slice (set by the send functions).
    pub count: u32,
    /// Bit 0 ([`FLAG_STOPPING`]): the sender stops after this message.
    pub flags: u32,
}

impl ExchangeHeader {
    /// Header of exchange `exchange` at simulated time `time` (s).
    pub fn new(exchange: u64, time: f64) -> Self {
        Self { exchange, time, count: 0, flags: 0 }
    }

    /// The same header with [`FLAG_STOPPING`] set (the last message of a run).
    pub fn stopping(mut self) -> Self {
        self.flags |= FLAG_STOPPING;
        self
    }

    /// True if the sender stops after this message.
    pub fn is_stopping(&self) -> bool {
        self.flags & FLAG_STOPPING != 0
    }
}

/// A message that arrived out of the exchange's order.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[error("received exchange {got} while exchange {expected} was due")]
pub struct OutOfOrder {
    pub expected: u64,
    pub got: u64,
}

/// The exchange's one order rule, which every transport applies to what it
/// receives (the iceoryx2 link, the in-process pair, a replayed
/// recording): a message taken while exchange `expected` is due carries
/// that index, unless it is its sender's stop ([`FLAG_STOPPING`]), which
/// may come at any exchange. Each transport words the fix for its case.
pub fn check_order(expected: u64, header: &ExchangeHeader) -> Result<(), OutOfOrder> {
    if header.exchange != expected && !header.is_stopping() {
        return Err(OutOfOrder { expected, got: header.exchange });
    }
    Ok(())
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
    fn take<const N: usize>(&mut self) -> Result<[u8; N], DecodeError> {
        let end = self.at + N;
        let b = self.bytes.get(self.at..end).ok_or_else(|| {
            DecodeError::from(format!("{}: message truncated at byte {} of {}", self.what, self.at, self.bytes.len()))
        })?;
        self.at = end;
        Ok(b.try_into().expect("slice of N bytes"))
    }
    fn u32(&mut self) -> Result<u32, DecodeError> {
        Ok(u32::from_le_bytes(self.take()?))
    }
    fn u64(&mut self) -> Result<u64, DecodeError> {
        Ok(u64::from_le_bytes(self.take()?))
    }
    fn f64(&mut self) -> Result<f64, DecodeError> {
        Ok(f64::from_le_bytes(self.take()?))
    }
    fn vec3(&mut self) -> Result<[f64; 3], DecodeError> {
        Ok([self.f64()?, self.f64()?, self.f64()?])
    }
    fn header(&mut self) -> Result<ExchangeHeader, DecodeError> {
        Ok(ExchangeHeader { exchange: self.u64()?, time: self.f64()?, count: self.u32()?, flags: self.u32()? })
    }
    /// Checks that `count` records of `size` bytes fit in what is left
    /// before anything is allocated for them (a corrupt count must not
    /// claim gigabytes).
    fn records(&self, count: u32, size: usize) -> Result<usize, DecodeError> {
        let left = self.bytes.len() - self.at;
        if (count as usize).saturating_mul(size) > left {
            return Err(format!(
                "{}: the header announces {count} records of {size} bytes, the message holds {left} bytes",
                self.what
            )
            .into());
        }
        Ok(count as usize)
    }
    fn end(&self) -> Result<(), DecodeError> {
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
pub fn decode_loads(bytes: &[u8]) -> Result<(ExchangeHeader, Vec<HydroLoad>), DecodeError> {
    let mut c = Cursor { bytes, at: 0, what: "received loads" };
    let header = c.header()?;
    // id, force (3), torque (3), liquid mass.
    let mut loads = Vec::with_capacity(c.records(header.count, 4 + 7 * 8)?);
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
pub fn decode_states(bytes: &[u8]) -> Result<(ExchangeHeader, Vec<ParticleState>), DecodeError> {
    let mut c = Cursor { bytes, at: 0, what: "received states" };
    let header = c.header()?;
    // id, position (3), velocity (3), angular velocity (3), radius.
    let mut states = Vec::with_capacity(c.records(header.count, 4 + 10 * 8)?);
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn order_rule_takes_the_due_exchange_or_a_stop() {
        let h = ExchangeHeader::new(4, 0.0);
        assert_eq!(check_order(4, &h), Ok(()));
        assert_eq!(check_order(5, &h), Err(OutOfOrder { expected: 5, got: 4 }));
        assert_eq!(check_order(5, &h.stopping()), Ok(()), "a stop may come at any exchange");
        assert_eq!(OutOfOrder { expected: 5, got: 4 }.to_string(), "received exchange 4 while exchange 5 was due");
    }

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
        assert!(err.contains("received states"), "{err}");
        // A corrupt count is refused before anything is allocated for it
        // (found by tests/fuzz_inputs.rs: 4e9 records aborted the process).
        let mut corrupt = bytes.clone();
        corrupt[16..20].copy_from_slice(&u32::MAX.to_le_bytes());
        let err = decode_states(&corrupt).unwrap_err().to_string();
        assert!(err.contains("announces 4294967295 records of 84 bytes, the message holds 84 bytes"), "{err}");
        assert!(decode_loads(&corrupt).is_err());
    }
}
