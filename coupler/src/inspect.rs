//! `coupler inspect`: topics, message counts, time span and summary of a recording.
//! Works on a finished file (uses its summary section) and on a file whose
//! writer died (streams the chunks written so far).

use std::collections::BTreeMap;
use std::path::Path;

use runtime::say;
use schemas::topics::metadata;

pub fn inspect(path: &Path) -> Result<(), String> {
    let bytes = std::fs::read(path).map_err(|e| format!("cannot read {}: {e}", path.display()))?;
    if !bytes.starts_with(mcap::MAGIC) {
        return Err(format!("{} is not an MCAP file (no MCAP magic bytes at its start)", path.display()));
    }
    let summary = mcap::Summary::read(&bytes).ok().flatten();
    say!("file         {} ({:.1} MB)", path.display(), bytes.len() as f64 / 1e6);
    let mut topics: BTreeMap<String, (String, String, u64)> = BTreeMap::new();
    let (mut t0, mut t1) = (u64::MAX, 0u64);
    let mut run_summary = None;
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
        }
        None => {
            say!("note         no summary section (the writer did not finish): streaming what was written");
            let stream = mcap::MessageStream::new_with_options(&bytes, mcap::read::Options::IgnoreEndMagic.into())
                .map_err(|e| format!("{} is not an MCAP file: {e}", path.display()))?;
            let mut stream_error = None;
            for msg in stream {
                let msg = match msg {
                    Ok(m) => m,
                    Err(e) => {
                        stream_error = Some(e.to_string());
                        break;
                    }
                };
                let schema = msg.channel.schema.as_ref().map(|s| s.name.clone()).unwrap_or_else(|| "-".into());
                let e = topics.entry(msg.channel.topic.clone()).or_insert((
                    schema,
                    msg.channel.message_encoding.clone(),
                    0,
                ));
                e.2 += 1;
                t0 = t0.min(msg.log_time);
                t1 = t1.max(msg.log_time);
            }
            if let Some((start, claimed_end)) = unfinished_record(&bytes) {
                let missing = claimed_end - bytes.len();
                say!(
                    "cut          the file ends inside a record (bytes {start}..{claimed_end}): its last {missing} bytes ({:.1} % of that record) are missing; the messages listed below are those read before the cut",
                    100.0 * missing as f64 / (claimed_end - start) as f64
                );
            }
            if let Some(e) = stream_error {
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
    Ok(())
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
