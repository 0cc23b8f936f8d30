//! `play_peer`: plays one side of the DEM–LBM exchange over the real
//! iceoryx2 link from a recorded coupled run, so that the other side's real
//! binary is tested alone, transport and protocol handling included
//! (docs/coupling.md "Isolation").
//!
//! usage: play_peer (dem|lbm) SCENE RUN.mcap --run-id ID [--set K=V ...] [--skip N]
//!
//! - `lbm`: plays the LBM to a real `dem_proc`: answers the states of
//!   exchange n with the loads the DEM received for n in the recording, and
//!   checks each state message against the ones the LBM received.
//! - `dem`: plays the DEM to a real `lbm_proc`: sends the recorded states
//!   (and the final stop) in lockstep and checks each answer against the
//!   loads the DEM received.
//! - `--skip N`: at exchange N sends exchange N + 1's message instead (the
//!   peer must refuse it, naming both exchanges).
//!
//! Exit 0 when every message matched the recording bit for bit; 1 with the
//! first difference or link error; 2 on bad arguments.

use std::path::PathBuf;
use std::process::ExitCode;

use runtime::exchange::{decode_loads, decode_states, HydroLoad, ParticleState};
use runtime::link::{DemLink, ExchangeHeader, LbmLink, LinkConfig, LinkError};
use schemas::topics;

struct Args {
    role: String,
    scene: PathBuf,
    recording: PathBuf,
    run_id: String,
    set: Vec<String>,
    skip: Option<u64>,
}

fn parse() -> Result<Args, String> {
    let mut it = std::env::args().skip(1);
    let usage = "usage: play_peer (dem|lbm) SCENE RUN.mcap --run-id ID [--set K=V ...] [--skip N]";
    let role = it.next().ok_or(usage)?;
    if role != "dem" && role != "lbm" {
        return Err(format!("role must be dem or lbm, got {role:?}; {usage}"));
    }
    let scene = PathBuf::from(it.next().ok_or(usage)?);
    let recording = PathBuf::from(it.next().ok_or(usage)?);
    let (mut run_id, mut set, mut skip) = (None, Vec::new(), None);
    while let Some(flag) = it.next() {
        let value = it.next().ok_or_else(|| format!("{flag} needs a value; {usage}"))?;
        match flag.as_str() {
            "--run-id" => run_id = Some(value),
            "--set" => set.push(value),
            "--skip" => skip = Some(value.parse().map_err(|e| format!("--skip {value}: {e}"))?),
            _ => return Err(format!("unknown option {flag}; {usage}")),
        }
    }
    Ok(Args { role, scene, recording, run_id: run_id.ok_or(usage)?, set, skip })
}

fn messages(path: &std::path::Path, topic: &str) -> Result<Vec<Vec<u8>>, String> {
    runtime::exchange::recorded_messages(path, topic).map_err(|e| e.to_string())
}

fn same_header(a: &ExchangeHeader, b: &ExchangeHeader) -> bool {
    a.exchange == b.exchange && a.time.to_bits() == b.time.to_bits() && a.count == b.count && a.flags == b.flags
}

fn play(args: &Args) -> Result<String, String> {
    let scene = schemas::Scene::load(&args.scene, &args.set).map_err(|e| e.to_string())?;
    let hash = runtime::process::scene_hash(&scene);
    let err = |e: LinkError| e.to_string();
    let loads: Vec<(ExchangeHeader, Vec<HydroLoad>)> = messages(&args.recording, topics::DEM_RECEIVED_LOADS)?
        .iter()
        .map(|b| decode_loads(b).map_err(|e| e.to_string()))
        .collect::<Result<_, _>>()?;
    let states: Vec<(ExchangeHeader, Vec<ParticleState>)> = messages(&args.recording, topics::LBM_RECEIVED_STATES)?
        .iter()
        .map(|b| decode_states(b).map_err(|e| e.to_string()))
        .collect::<Result<_, _>>()?;
    let skipped = |n: u64| args.skip == Some(n);
    if args.role == "lbm" {
        let mut link = LbmLink::connect(&LinkConfig::new(args.run_id.clone(), hash, 0)).map_err(err)?;
        let mut got = Vec::new();
        let mut checked = 0;
        for (n, (want_header, want)) in states.iter().enumerate() {
            let n = n as u64;
            match link.receive_states(n, &mut got) {
                Err(LinkError::PeerStopped { .. }) if want_header.is_stopping() => {
                    return Ok(format!("played the LBM: {checked} state messages matched, then the DEM's stop"));
                }
                Err(e) => return Err(format!("exchange {n}: {e}")),
                // The stop carries the last states; the recording keeps only its header.
                Ok(h) if h.is_stopping() && want_header.is_stopping() => {
                    return Ok(format!("played the LBM: {checked} state messages matched, then the DEM's stop"));
                }
                Ok(h) => {
                    if !same_header(&h, want_header) || got != *want {
                        return Err(format!("exchange {n}: dem_proc sent states that differ from the recording"));
                    }
                    checked += 1;
                }
            }
            let send = if skipped(n) { n + 1 } else { n };
            if let Some((h, l)) = loads.iter().find(|(h, _)| h.exchange == send) {
                link.send_loads(*h, l).map_err(err)?;
            }
        }
        Err(format!("the recording ended after {checked} exchanges without the DEM's stop"))
    } else {
        let particles = states.first().map_or(0, |(h, _)| h.count as usize);
        let mut link = DemLink::connect(&LinkConfig::new(args.run_id.clone(), hash, particles)).map_err(err)?;
        let mut got = Vec::new();
        let mut checked = 0;
        for (k, (h, s)) in states.iter().enumerate() {
            let (h, s) = if skipped(h.exchange) { states.get(k + 1).map_or((h, s), |(h, s)| (h, s)) } else { (h, s) };
            if h.is_stopping() {
                link.send_stop(h.exchange, h.time).map_err(err)?;
                return Ok(format!("played the DEM: {checked} load messages matched, then sent the stop"));
            }
            link.send_states(*h, s).map_err(err)?;
            let answer =
                link.receive_loads(h.exchange, &mut got).map_err(|e| format!("exchange {}: {e}", h.exchange))?;
            // Concurrent runs never read the last load: nothing to compare then.
            if let Some((want_header, want)) = loads.iter().find(|(w, _)| w.exchange == h.exchange) {
                if answer.exchange != want_header.exchange || answer.count != want_header.count || got != *want {
                    return Err(format!(
                        "exchange {}: lbm_proc answered loads that differ from the recording",
                        h.exchange
                    ));
                }
                checked += 1;
            }
        }
        Err(format!("the recording ended after {checked} exchanges without the DEM's stop"))
    }
}

fn main() -> ExitCode {
    let args = match parse() {
        Ok(a) => a,
        Err(e) => {
            eprintln!("play_peer: {e}");
            return ExitCode::from(2);
        }
    };
    match play(&args) {
        Ok(summary) => {
            eprintln!("play_peer: {summary}");
            ExitCode::SUCCESS
        }
        Err(e) => {
            eprintln!("play_peer: {e}");
            ExitCode::FAILURE
        }
    }
}
