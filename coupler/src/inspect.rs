//! `coupler inspect`: topics, message counts, time span and summary of a recording.
//! Works on a finished file (its summary section says what was recorded;
//! every chunk is also read, so a file damaged since is told apart, with
//! what of it is still readable) and on a file whose writer died (streams
//! the chunks written so far).

use std::collections::BTreeMap;
use std::path::Path;

use runtime::say;
use schemas::topics::metadata;

/// What streaming a file read: per topic (schema, encoding, messages), the
/// time span, and the error reading stopped at, if any.
struct Streamed {
    topics: BTreeMap<String, (String, String, u64)>,
    span: (u64, u64),
    error: Option<String>,
}

/// A finished file is read with every chunk's CRC checked before its
/// messages count (damage since it was written); an unfinished one (a
/// killed writer) as far as its last chunk decompresses, complete or not.
fn stream(bytes: &[u8], finished: bool) -> Streamed {
    let stream: Box<dyn Iterator<Item = Result<mcap::Message<'_>, mcap::McapError>>> = if finished {
        Box::new(runtime::record::verified_messages(bytes))
    } else {
        match mcap::MessageStream::new_with_options(bytes, mcap::read::Options::IgnoreEndMagic.into()) {
            Ok(s) => Box::new(s),
            Err(e) => Box::new(std::iter::once(Err(e))),
        }
    };
    let mut out = Streamed { topics: BTreeMap::new(), span: (u64::MAX, 0), error: None };
    for msg in stream {
        let msg = match msg {
            Ok(m) => m,
            Err(e) => {
                out.error = Some(e.to_string());
                break;
            }
        };
        let schema = msg.channel.schema.as_ref().map(|s| s.name.clone()).unwrap_or_else(|| "-".into());
        let e =
            out.topics.entry(msg.channel.topic.clone()).or_insert((schema, msg.channel.message_encoding.clone(), 0));
        e.2 += 1;
        out.span = (out.span.0.min(msg.log_time), out.span.1.max(msg.log_time));
    }
    out
}

/// Prints the report; Err only for a file that is not MCAP or cannot be
/// read. Returns whether the file is damaged (a finished file whose
/// chunks no longer read as recorded).
pub fn inspect(path: &Path) -> Result<bool, String> {
    let bytes = std::fs::read(path).map_err(|e| format!("cannot read {}: {e}", path.display()))?;
    if !bytes.starts_with(mcap::MAGIC) {
        return Err(format!("{} is not an MCAP file (no MCAP magic bytes at its start)", path.display()));
    }
    let summary = mcap::Summary::read(&bytes).ok().flatten();
    say!("file         {} ({:.1} MB)", path.display(), bytes.len() as f64 / 1e6);
    let mut topics: BTreeMap<String, (String, String, u64)> = BTreeMap::new();
    let (mut t0, mut t1) = (u64::MAX, 0u64);
    let mut run_summary = None;
    let streamed = stream(&bytes, summary.is_some());
    let mut damaged = false;
    match &summary {
        Some(s) => {
            let stats = s.stats.as_ref();
            for (id, ch) in &s.channels {
                let count = stats.and_then(|st| st.channel_message_counts.get(id).copied()).unwrap_or(0);
                let schema = ch.schema.as_ref().map(|s| s.name.clone()).unwrap_or_else(|| "-".into());
                topics.insert(ch.topic.clone(), (schema, ch.message_encoding.clone(), count));
            }
            if let Some(st) = stats {
                t0 = st.message_start_time;
                t1 = st.message_end_time;
            }
            for idx in &s.metadata_indexes {
                if idx.name == metadata::SUMMARY {
                    if let Ok(m) = mcap::read::metadata(&bytes, idx) {
                        run_summary = m.metadata.get("json").cloned();
                    }
                }
            }
            let readable = |t: &str| streamed.topics.get(t).map_or(0, |e| e.2);
            damaged = streamed.error.is_some() || topics.iter().any(|(t, e)| readable(t) != e.2);
            if damaged {
                let (read, recorded): (u64, u64) =
                    topics.iter().map(|(t, e)| (readable(t), e.2)).fold((0, 0), |a, b| (a.0 + b.0, a.1 + b.1));
                let upto = if read > 0 {
                    format!("up to t = {:.4} s", streamed.span.1 as f64 * 1e-9)
                } else {
                    "none of them".to_string()
                };
                say!(
                    "damaged      the file was finished, but reading its chunks stopped at: {}; {read} of its {recorded} messages are readable, {upto} (per topic below: readable / recorded)",
                    streamed.error.as_deref().unwrap_or("fewer messages than its summary counts"),
                );
                for (t, e) in topics.iter_mut() {
                    e.1 = format!("{}   readable {} / {}", e.1, readable(t), e.2);
                }
            }
        }
        None => {
            say!("note         no summary section (the writer did not finish): streaming what was written");
            topics = streamed.topics;
            (t0, t1) = streamed.span;
            if let Some((start, claimed_end)) = unfinished_record(&bytes) {
                let missing = claimed_end - bytes.len();
                say!(
                    "cut          the file ends inside a record (bytes {start}..{claimed_end}): its last {missing} bytes ({:.1} % of that record) are missing; the messages listed below are those read before the cut",
                    100.0 * missing as f64 / (claimed_end - start) as f64
                );
            }
            if let Some(e) = streamed.error {
                say!("damaged      reading stopped at: {e}; the messages listed below were read before it");
            }
        }
    }
    if t0 <= t1 {
        say!("time span    {:.4} s .. {:.4} s (simulated)", t0 as f64 * 1e-9, t1 as f64 * 1e-9);
    }
    say!("{:<18} {:>8}  {:<24} encoding", "topic", "messages", "schema");
    for (topic, (schema, enc, count)) in &topics {
        say!("{topic:<18} {count:>8}  {schema:<24} {enc}");
    }
    match run_summary {
        Some(json) => {
            let v: serde_json::Value = serde_json::from_str(&json).map_err(|e| format!("summary is not JSON: {e}"))?;
            say!("summary");
            for key in [
                "scene",
                "method",
                "status",
                "sim_time",
                "steps",
                "wall_seconds",
                "t_ref",
                "runout",
                "porosity_initial",
            ] {
                if let Some(x) = v.get(key) {
                    say!("  {key:<16} {x}");
                }
            }
            if let Some(x) = v.get("throughput") {
                say!("  {:<16} {x}", "throughput");
            }
            if let Some(f) = v.get("front").and_then(|f| f.as_array()) {
                say!(
                    "  {:<16} {} samples, last {}",
                    "front",
                    f.len(),
                    f.last().map(|x| x.to_string()).unwrap_or_default()
                );
            }
        }
        None => say!("summary      none recorded (run interrupted before the end or still running)"),
    }
    Ok(damaged)
}

/// The top-level record the file ends inside, if any, as (its start, the
/// end its length field claims): each record is an opcode byte, a u64
/// little-endian length and that many bytes (MCAP specification,
/// "Records"). A writer killed mid-chunk, or a full disk, leaves one.
fn unfinished_record(bytes: &[u8]) -> Option<(usize, usize)> {
    let mut at = mcap::MAGIC.len();
    while let Some(len) = bytes.get(at + 1..at + 9).map(|b| u64::from_le_bytes(b.try_into().expect("8 bytes"))) {
        let end = (at + 9).saturating_add(usize::try_from(len).unwrap_or(usize::MAX));
        if end > bytes.len() {
            return Some((at, end));
        }
        at = end;
    }
    // A record header itself cut short.
    (at < bytes.len()).then_some((at, at + 9))
}
