//! `coupler inspect`: topics, message counts, time span and summary of a recording.
//! Works on a finished file (uses its summary section) and on a file whose
//! writer died (streams the chunks written so far).

use std::collections::BTreeMap;
use std::path::Path;

use schemas::topics::metadata;

pub fn inspect(path: &Path) -> Result<(), String> {
    let bytes = std::fs::read(path).map_err(|e| format!("cannot read {}: {e}", path.display()))?;
    if !bytes.starts_with(mcap::MAGIC) {
        return Err(format!("{} is not an MCAP file (no MCAP magic bytes at its start)", path.display()));
    }
    let summary = mcap::Summary::read(&bytes).ok().flatten();
    println!("file         {} ({:.1} MB)", path.display(), bytes.len() as f64 / 1e6);
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
            println!("note         no summary section (the writer did not finish): streaming what was written");
            let stream = mcap::MessageStream::new_with_options(&bytes, mcap::read::Options::IgnoreEndMagic.into())
                .map_err(|e| format!("{} is not an MCAP file: {e}", path.display()))?;
            for msg in stream {
                let Ok(msg) = msg else { break };
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
        }
    }
    if t0 <= t1 {
        println!("time span    {:.4} s .. {:.4} s (simulated)", t0 as f64 * 1e-9, t1 as f64 * 1e-9);
    }
    println!("{:<18} {:>8}  {:<24} encoding", "topic", "messages", "schema");
    for (topic, (schema, enc, count)) in &topics {
        println!("{topic:<18} {count:>8}  {schema:<24} {enc}");
    }
    match run_summary {
        Some(json) => {
            let v: serde_json::Value = serde_json::from_str(&json).map_err(|e| format!("summary is not JSON: {e}"))?;
            println!("summary");
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
                    println!("  {key:<16} {x}");
                }
            }
            if let Some(x) = v.get("throughput") {
                println!("  {:<16} {x}", "throughput");
            }
            if let Some(f) = v.get("front").and_then(|f| f.as_array()) {
                println!(
                    "  {:<16} {} samples, last {}",
                    "front",
                    f.len(),
                    f.last().map(|x| x.to_string()).unwrap_or_default()
                );
            }
        }
        None => println!("summary      none recorded (run interrupted before the end or still running)"),
    }
    Ok(())
}
