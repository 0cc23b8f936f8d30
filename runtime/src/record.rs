//! MCAP recording off the solver thread.
//!
//! A [`RecorderBuilder`] registers every channel up front (schema, topic,
//! message encoding, channel metadata); [`RecorderBuilder::start`] moves the
//! `mcap::Writer` onto its own thread. The solver hands over encoded message
//! bytes through a bounded queue and never waits on compression or the disk,
//! unless it outruns the disk by more than the queue depth (then it waits:
//! back-pressure rather than unbounded memory).
//!
//! Chunks are zstd-compressed; every chunk is a complete record, so a run
//! killed mid-way leaves a file a streaming MCAP reader still reads up to the
//! last flushed chunk.

use std::collections::BTreeMap;
use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};
use std::sync::mpsc::{sync_channel, Receiver, SyncSender};
use std::thread::JoinHandle;

use foxglove::Encode;
use schemas::topics::metadata;

/// Identifies a registered channel.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ChannelId(u16);

enum Command {
    Message {
        channel: u16,
        log_time: u64,
        data: Vec<u8>,
    },
    Metadata {
        name: String,
        entries: BTreeMap<String, String>,
    },
    /// Close the current chunk and hand it to the OS, then answer.
    Flush {
        done: SyncSender<()>,
    },
}

pub struct RecorderBuilder {
    writer: mcap::Writer<BufWriter<File>>,
    path: PathBuf,
}

#[derive(Debug, thiserror::Error)]
pub enum RecordError {
    #[error("cannot create recording {path}: {source}")]
    Create { path: PathBuf, source: std::io::Error },
    #[error("writing recording {path} failed: {} (is the disk full? free space or choose another --out)", error_chain(.source))]
    Write { path: PathBuf, source: mcap::McapError },
    #[error("the recorder thread stopped early: {0}")]
    Stopped(String),
    /// A checkpoint, the recording's companion for resuming, failed.
    #[error(transparent)]
    Checkpoint(#[from] crate::checkpoint::CheckpointError),
}

/// An error and its causes, "outer: inner: …" (the mcap writer's own
/// message names no cause: "I/O error from writing").
pub fn error_chain(e: &dyn std::error::Error) -> String {
    let mut text = e.to_string();
    let mut source = e.source();
    while let Some(s) = source {
        let next = s.to_string();
        if !text.contains(&next) {
            text = format!("{text}: {next}");
        }
        source = s.source();
    }
    text
}

impl RecorderBuilder {
    /// Creates the file. Chunks of `chunk_bytes` are zstd-compressed on the recorder thread.
    pub fn create(path: &Path, chunk_bytes: u64) -> Result<Self, RecordError> {
        let file = File::create(path).map_err(|source| RecordError::Create { path: path.into(), source })?;
        let writer = mcap::WriteOptions::new()
            .compression(Some(mcap::Compression::Zstd))
            .compression_level(1)
            .chunk_size(Some(chunk_bytes))
            .profile("")
            .library(concat!("saturated-granular ", env!("CARGO_PKG_VERSION")))
            .create(BufWriter::with_capacity(1 << 20, file))
            .map_err(|source| RecordError::Write { path: path.into(), source })?;
        Ok(Self { writer, path: path.into() })
    }

    fn err(&self, source: mcap::McapError) -> RecordError {
        RecordError::Write { path: self.path.clone(), source }
    }

    /// A channel carrying a Foxglove well-known schema (or any `foxglove::Encode` type).
    pub fn channel<T: Encode>(&mut self, topic: &str) -> Result<ChannelId, RecordError> {
        let schema = T::get_schema().expect("recorded types carry a schema");
        let sid = self.writer.add_schema(&schema.name, &schema.encoding, &schema.data).map_err(|e| self.err(e))?;
        let cid = self
            .writer
            .add_channel(sid, topic, &T::get_message_encoding(), &BTreeMap::new())
            .map_err(|e| self.err(e))?;
        Ok(ChannelId(cid))
    }

    /// A channel with a custom encoding and no schema record; describe the
    /// encoding in `metadata` so other readers can decode it.
    pub fn raw_channel(
        &mut self,
        topic: &str,
        message_encoding: &str,
        metadata: BTreeMap<String, String>,
    ) -> Result<ChannelId, RecordError> {
        let cid = self.writer.add_channel(0, topic, message_encoding, &metadata).map_err(|e| self.err(e))?;
        Ok(ChannelId(cid))
    }

    /// A solver's full-state channel (`/…/state`): bincode of `type_path`
    /// at layout `version`, described in the channel metadata.
    pub fn state_channel(&mut self, topic: &str, type_path: &str, version: u32) -> Result<ChannelId, RecordError> {
        let encoding =
            format!("bincode 2 (serde, standard config) of {type_path} version {version}; see docs/recording.md");
        self.raw_channel(topic, "bincode", BTreeMap::from([("encoding".to_string(), encoding)]))
    }

    /// A channel of received exchange messages (`output.record_exchange`),
    /// in [`schemas::messages::RECEIVED_ENCODING`].
    pub fn received_channel(&mut self, topic: &str) -> Result<ChannelId, RecordError> {
        let encoding = schemas::messages::RECEIVED_ENCODING.to_string();
        self.raw_channel(topic, "sgf-exchange", BTreeMap::from([("encoding".to_string(), encoding)]))
    }

    /// Moves the writer to its own thread. `queue` frames may wait in memory.
    pub fn start(self, queue: usize) -> Recorder {
        let (tx, rx) = sync_channel(queue);
        let path = self.path.clone();
        let writer = self.writer;
        let handle = std::thread::Builder::new()
            .name("recorder".into())
            .spawn(move || writer_loop(writer, rx, path))
            .expect("spawn recorder thread");
        Recorder { tx: Some(tx), handle: Some(handle), sequence: 0 }
    }
}

/// Longest wall time between chunk flushes of a recording.
pub const FLUSH_EVERY: std::time::Duration = std::time::Duration::from_secs(2);

fn writer_loop(
    mut writer: mcap::Writer<BufWriter<File>>,
    rx: Receiver<Command>,
    path: PathBuf,
) -> Result<u64, RecordError> {
    let mut bytes = 0_u64;
    let werr = |source| RecordError::Write { path: path.clone(), source };
    let mut sequence = 0_u32;
    let mut last_flush = std::time::Instant::now();
    for cmd in rx {
        // A process killed outright (SIGKILL) loses only its unfinished
        // chunk: close one every FLUSH_EVERY of wall time.
        if last_flush.elapsed() >= FLUSH_EVERY {
            writer.flush().map_err(werr)?;
            last_flush = std::time::Instant::now();
        }
        match cmd {
            Command::Message { channel, log_time, data } => {
                sequence = sequence.wrapping_add(1);
                bytes += data.len() as u64;
                writer
                    .write_to_known_channel(
                        &mcap::records::MessageHeader {
                            channel_id: channel,
                            sequence,
                            log_time,
                            publish_time: log_time,
                        },
                        &data,
                    )
                    .map_err(werr)?;
            }
            Command::Metadata { name, entries } => {
                writer.write_metadata(&mcap::records::Metadata { name, metadata: entries }).map_err(werr)?;
            }
            Command::Flush { done } => {
                writer.flush().map_err(werr)?;
                last_flush = std::time::Instant::now();
                let _ = done.send(());
            }
        }
    }
    writer.finish().map_err(werr)?;
    Ok(bytes)
}

/// Handle the solver logs through; cheap to call, never blocks on I/O unless
/// the queue is full.
pub struct Recorder {
    tx: Option<SyncSender<Command>>,
    handle: Option<JoinHandle<Result<u64, RecordError>>>,
    sequence: u64,
}

impl std::fmt::Debug for Recorder {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Recorder").field("messages", &self.sequence).finish()
    }
}

impl Recorder {
    fn send(&mut self, cmd: Command) -> Result<(), RecordError> {
        let tx = self.tx.as_ref().ok_or_else(|| RecordError::Stopped("recorder already finished".into()))?;
        if tx.send(cmd).is_err() {
            // The thread ended: collect its error.
            return Err(self.join_error());
        }
        Ok(())
    }

    fn join_error(&mut self) -> RecordError {
        self.tx = None;
        match self.handle.take().map(|h| h.join()) {
            Some(Ok(Err(e))) => e,
            Some(Err(_)) => RecordError::Stopped("recorder thread panicked".into()),
            _ => RecordError::Stopped("recorder thread ended".into()),
        }
    }

    /// Logs an encodable message at simulated time `t` (s).
    pub fn log<T: Encode>(&mut self, channel: ChannelId, t: f64, msg: &T) -> Result<(), RecordError> {
        let mut data = Vec::with_capacity(msg.encoded_len().unwrap_or(256));
        msg.encode(&mut data).map_err(|e| RecordError::Stopped(format!("encoding failed: {e}")))?;
        self.log_bytes(channel, t, data)
    }

    /// Logs `msg` with a large bytes field written in place: see
    /// [`encode_with_payload`].
    pub fn log_with_payload<T: Encode>(
        &mut self,
        channel: ChannelId,
        t: f64,
        msg: &T,
        payload: Payload<impl FnOnce(&mut [u8])>,
    ) -> Result<(), RecordError> {
        let data =
            encode_with_payload(msg, payload).map_err(|e| RecordError::Stopped(format!("encoding failed: {e}")))?;
        self.log_bytes(channel, t, data)
    }

    /// Logs already encoded bytes at simulated time `t` (s).
    pub fn log_bytes(&mut self, channel: ChannelId, t: f64, data: Vec<u8>) -> Result<(), RecordError> {
        self.sequence += 1;
        self.send(Command::Message { channel: channel.0, log_time: sim_time_ns(t), data })
    }

    pub fn metadata(&mut self, name: &str, entries: BTreeMap<String, String>) -> Result<(), RecordError> {
        self.send(Command::Metadata { name: name.into(), entries })
    }

    /// Returns once everything logged so far is in the file as complete
    /// chunks (a checkpoint is written only after what was recorded up to
    /// it is on disk, so a resumed run's recording has no gap).
    pub fn sync(&mut self) -> Result<(), RecordError> {
        let (done, wait) = sync_channel(1);
        self.send(Command::Flush { done })?;
        wait.recv().map_err(|_| self.join_error())
    }

    /// Records the scene as run (metadata `scene`, key `toml`).
    pub fn scene(&mut self, toml: String) -> Result<(), RecordError> {
        self.metadata(metadata::SCENE, BTreeMap::from([("toml".to_string(), toml)]))
    }

    /// Records the run summary (metadata `summary`, key `json`) and closes the file.
    pub fn finish_with_summary(mut self, json: String) -> Result<u64, RecordError> {
        self.metadata(metadata::SUMMARY, BTreeMap::from([("json".to_string(), json)]))?;
        self.finish()
    }

    /// Writes the summary section and closes the file; returns the message bytes written.
    pub fn finish(mut self) -> Result<u64, RecordError> {
        self.tx = None;
        match self.handle.take().map(|h| h.join()) {
            Some(Ok(r)) => r,
            Some(Err(_)) => Err(RecordError::Stopped("recorder thread panicked".into())),
            None => Err(RecordError::Stopped("recorder already finished".into())),
        }
    }
}

/// Simulated seconds to MCAP nanoseconds (the timeline starts at t = 0).
pub fn sim_time_ns(t: f64) -> u64 {
    (t.max(0.0) * 1e9).round() as u64
}

/// Foxglove timestamp of simulated time `t`.
pub fn timestamp(t: f64) -> foxglove::schemas::Timestamp {
    let ns = sim_time_ns(t);
    foxglove::schemas::Timestamp::new((ns / 1_000_000_000) as u32, (ns % 1_000_000_000) as u32)
}

/// `foxglove.Log` levels used by the solvers.
pub mod log_level {
    pub const INFO: i32 = 2;
    pub const WARNING: i32 = 3;
    pub const ERROR: i32 = 4;
}

/// A `/log` message from process `name` at simulated time `t`.
pub fn log_entry(t: f64, level: i32, name: &str, message: &str) -> foxglove::schemas::Log {
    foxglove::schemas::Log {
        timestamp: Some(timestamp(t)),
        level,
        message: message.into(),
        name: name.into(),
        file: String::new(),
        line: 0,
    }
}

/// A little-endian float32 field of a point cloud or grid at byte `offset`.
pub fn f32_field(name: &str, offset: u32) -> foxglove::schemas::PackedElementField {
    use foxglove::schemas::packed_element_field::NumericType;
    foxglove::schemas::PackedElementField { name: name.into(), offset, r#type: NumericType::Float32 as i32 }
}

/// No rotation.
pub fn identity_quaternion() -> foxglove::schemas::Quaternion {
    foxglove::schemas::Quaternion { x: 0.0, y: 0.0, z: 0.0, w: 1.0 }
}

/// The `world` frame's own pose.
pub fn identity_pose() -> foxglove::schemas::Pose {
    foxglove::schemas::Pose {
        position: Some(foxglove::schemas::Vector3 { x: 0.0, y: 0.0, z: 0.0 }),
        orientation: Some(identity_quaternion()),
    }
}

/// The messages of an MCAP file in file order, each chunk's CRC checked
/// before any of its messages is given out: a damaged chunk ends the
/// stream with its error and none of its messages is passed on (the
/// crate's `MessageStream` checks a chunk only after yielding it). A file
/// without its end (a killed writer) reads to its last complete record.
pub fn verified_messages(bytes: &[u8]) -> VerifiedMessages<'_> {
    let options =
        mcap::sans_io::LinearReaderOptions::default().with_skip_end_magic(true).with_prevalidate_chunk_crcs(true);
    VerifiedMessages { reader: mcap::sans_io::MessageReader::new_with_options(options), rest: bytes }
}

/// See [`verified_messages`].
pub struct VerifiedMessages<'a> {
    reader: mcap::sans_io::MessageReader,
    rest: &'a [u8],
}

impl Iterator for VerifiedMessages<'_> {
    type Item = Result<mcap::Message<'static>, mcap::McapError>;

    fn next(&mut self) -> Option<Self::Item> {
        use mcap::sans_io::MessageReadEvent;
        loop {
            match self.reader.next_event()? {
                Ok(MessageReadEvent::ReadRequest(need)) => {
                    let n = need.min(self.rest.len());
                    self.reader.insert(n).copy_from_slice(&self.rest[..n]);
                    self.reader.notify_read(n);
                    self.rest = &self.rest[n..];
                }
                Ok(MessageReadEvent::Message(m)) => return Some(Ok(m)),
                Err(e) => return Some(Err(e)),
            }
        }
    }
}

/// A protobuf bytes field to write in place after a message's other fields.
pub struct Payload<F> {
    /// Its field number: above every field set in the message, whose own
    /// copy of it is left empty.
    pub field: u32,
    /// Its length in bytes.
    pub len: usize,
    /// Writes its bytes (the slice starts zeroed).
    pub fill: F,
}

/// `msg` encoded and then `payload`'s field: the same bytes as `msg` with
/// that field set (protobuf encodes fields in number order, and an empty
/// bytes field not at all), without a second copy of a large payload, e.g.
/// a grid's cells (the LBM slice of a long flume is 15 MB a frame).
pub fn encode_with_payload<T: Encode>(msg: &T, payload: Payload<impl FnOnce(&mut [u8])>) -> Result<Vec<u8>, T::Error> {
    let Payload { field, len, fill } = payload;
    debug_assert!((1..1 << 29).contains(&field), "protobuf field numbers are 1 to 2^29 - 1, got {field}");
    let mut data = Vec::with_capacity(msg.encoded_len().unwrap_or(256) + 20 + len);
    msg.encode(&mut data)?;
    if len == 0 {
        // An empty bytes field is not encoded at all.
        return Ok(data);
    }
    put_varint(&mut data, (u64::from(field) << 3) | 2);
    put_varint(&mut data, len as u64);
    let start = data.len();
    data.resize(start + len, 0);
    fill(&mut data[start..]);
    Ok(data)
}

fn put_varint(out: &mut Vec<u8>, mut v: u64) {
    while v >= 0x80 {
        out.push((v as u8) | 0x80);
        v >>= 7;
    }
    out.push(v as u8);
}

#[cfg(test)]
mod tests {
    use super::*;
    use foxglove::schemas::{packed_element_field::NumericType, Grid, PackedElementField, Vector2};

    #[test]
    fn a_payload_written_in_place_encodes_as_the_field_set() {
        let cells: Vec<u8> = (0..100_000u32).map(|k| (k * 7 % 251) as u8).collect();
        let grid = |data: Vec<u8>| Grid {
            frame_id: "world".into(),
            column_count: 250,
            cell_size: Some(Vector2 { x: 0.5, y: 0.5 }),
            row_stride: 1000,
            cell_stride: 4,
            fields: vec![PackedElementField { name: "fill".into(), offset: 0, r#type: NumericType::Float32 as i32 }],
            data: data.into(),
            ..Default::default()
        };
        let mut whole = Vec::new();
        grid(cells.clone()).encode(&mut whole).unwrap();
        // Grid's `data` is field 9, its last.
        let payload = Payload { field: 9, len: cells.len(), fill: |out: &mut [u8]| out.copy_from_slice(&cells) };
        let in_place = encode_with_payload(&grid(Vec::new()), payload).unwrap();
        assert_eq!(in_place, whole);
    }
}
