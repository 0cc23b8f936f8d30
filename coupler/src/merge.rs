//! One `run.mcap` from the recordings of a coupled run's processes: every
//! message of `dem.mcap` and `lbm.mcap` on one timeline (log time order),
//! the channels with their schemas and metadata as recorded, the scene and
//! the combined summary as metadata.
//!
//! The inputs are read as streams, so a file whose writer died (no summary
//! section) still gives every message of its complete chunks.

use std::collections::{BTreeMap, HashMap};
use std::fs::File;
use std::io::BufWriter;
use std::path::Path;

use schemas::topics::metadata;

/// What went into the merged file.
#[derive(Debug, Default, Clone)]
pub struct Merged {
    pub messages: u64,
    /// Inputs that ended early (no summary section, or a damaged tail).
    pub truncated: Vec<String>,
}

type Key = (String, String, Vec<u8>, String, String, BTreeMap<String, String>);

/// A recording to merge.
pub struct Source<'a> {
    pub path: &'a Path,
    /// Keep only what was recorded up to this checkpoint (log time, ns): an
    /// earlier recording of a resumed run. Messages at the checkpoint's own
    /// time are kept but for the received exchange messages, which the run
    /// receives after its checkpoint (and the resumed run records again).
    pub until: Option<u64>,
}

/// Whether a message of `topic` at `log_time` was recorded before the checkpoint at `until`.
fn before_checkpoint(topic: &str, log_time: u64, until: Option<u64>) -> bool {
    match until {
        None => true,
        Some(t) => {
            log_time < t
                || (log_time == t
                    && topic != schemas::topics::DEM_RECEIVED_LOADS
                    && topic != schemas::topics::LBM_RECEIVED_STATES)
        }
    }
}

/// Merges `inputs` (missing files are skipped) into `output`.
pub fn merge_recordings(
    inputs: &[Source<'_>],
    output: &Path,
    scene_toml: &str,
    summary_json: Option<&str>,
) -> Result<Merged, String> {
    let mut files = Vec::new();
    for source in inputs {
        let path = source.path;
        if path.exists() {
            let bytes = std::fs::read(path).map_err(|e| format!("cannot read {}: {e}", path.display()))?;
            files.push((path.display().to_string(), bytes, source.until));
        }
    }
    let out = File::create(output).map_err(|e| format!("cannot create {}: {e}", output.display()))?;
    let werr = |e: mcap::McapError| {
        format!("writing {} failed: {} (is the disk full?)", output.display(), runtime::record::error_chain(&e))
    };
    let mut writer = mcap::WriteOptions::new()
        .compression(Some(mcap::Compression::Zstd))
        .compression_level(1)
        .chunk_size(Some(8 << 20))
        .profile("")
        .library(concat!("saturated-granular coupler ", env!("CARGO_PKG_VERSION")))
        .create(BufWriter::with_capacity(1 << 20, out))
        .map_err(werr)?;
    writer
        .write_metadata(&mcap::records::Metadata {
            name: metadata::SCENE.into(),
            metadata: BTreeMap::from([("toml".to_string(), scene_toml.to_string())]),
        })
        .map_err(werr)?;

    let mut merged = Merged::default();
    let mut streams = Vec::new();
    for (name, bytes, until) in &files {
        let finished = mcap::Summary::read(bytes).ok().flatten().is_some();
        if !finished && until.is_none() {
            merged.truncated.push(name.clone());
        }
        let stream = mcap::MessageStream::new(bytes).map_err(|e| format!("{name} is not an MCAP file: {e}"))?;
        let until = *until;
        let kept =
            stream.filter(move |m| m.as_ref().map_or(true, |m| before_checkpoint(&m.channel.topic, m.log_time, until)));
        streams.push((name.clone(), kept.peekable()));
    }
    // Same topic, schema, encoding and metadata: one channel in the output.
    let mut channels: HashMap<Key, u16> = HashMap::new();
    let mut schemas: HashMap<(String, String, Vec<u8>), u16> = HashMap::new();
    let mut sequence = 0u32;
    loop {
        // The stream whose next message is earliest (ties: input order).
        let mut best: Option<(usize, u64)> = None;
        for (k, (name, stream)) in streams.iter_mut().enumerate() {
            loop {
                match stream.peek() {
                    Some(Ok(m)) => {
                        if best.is_none_or(|(_, t)| m.log_time < t) {
                            best = Some((k, m.log_time));
                        }
                        break;
                    }
                    Some(Err(_)) => {
                        // A damaged tail (the writer died mid-chunk): keep what came before.
                        if !merged.truncated.contains(name) {
                            merged.truncated.push(name.clone());
                        }
                        while stream.next().is_some() {}
                    }
                    None => break,
                }
            }
        }
        let Some((k, _)) = best else { break };
        let msg = streams[k].1.next().expect("peeked").expect("peeked Ok");
        let ch = &msg.channel;
        let (schema_name, schema_encoding, schema_data) = match &ch.schema {
            Some(s) => (s.name.clone(), s.encoding.clone(), s.data.to_vec()),
            None => (String::new(), String::new(), Vec::new()),
        };
        let key: Key = (
            ch.topic.clone(),
            schema_name.clone(),
            schema_data.clone(),
            schema_encoding.clone(),
            ch.message_encoding.clone(),
            ch.metadata.clone(),
        );
        let channel_id = match channels.get(&key) {
            Some(&id) => id,
            None => {
                let schema_id = if schema_name.is_empty() && schema_data.is_empty() {
                    0
                } else {
                    let skey = (schema_name.clone(), schema_encoding.clone(), schema_data.clone());
                    match schemas.get(&skey) {
                        Some(&id) => id,
                        None => {
                            let id = writer.add_schema(&schema_name, &schema_encoding, &schema_data).map_err(werr)?;
                            schemas.insert(skey, id);
                            id
                        }
                    }
                };
                let id = writer.add_channel(schema_id, &ch.topic, &ch.message_encoding, &ch.metadata).map_err(werr)?;
                channels.insert(key, id);
                id
            }
        };
        sequence = sequence.wrapping_add(1);
        writer
            .write_to_known_channel(
                &mcap::records::MessageHeader {
                    channel_id,
                    sequence,
                    log_time: msg.log_time,
                    publish_time: msg.publish_time,
                },
                &msg.data,
            )
            .map_err(werr)?;
        merged.messages += 1;
    }
    if let Some(json) = summary_json {
        writer
            .write_metadata(&mcap::records::Metadata {
                name: metadata::SUMMARY.into(),
                metadata: BTreeMap::from([("json".to_string(), json.to_string())]),
            })
            .map_err(werr)?;
    }
    writer.finish().map_err(werr)?;
    Ok(merged)
}
