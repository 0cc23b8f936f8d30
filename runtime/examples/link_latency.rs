//! Round-trip latency of the DEM ⇄ LBM link: a DEM thread sends N particle
//! states, an LBM thread answers N loads, both in this process over the same
//! shared-memory path two processes use.
//!
//! `cargo run -p schemas --release --example link_latency -- [--particles 8000] [--exchanges 1000] [--spin-us 100]`

use std::time::{Duration, Instant};

use runtime::link::{DemLink, ExchangeHeader, HydroLoad, LbmLink, LinkConfig, LinkError, ParticleState};

fn arg(args: &[String], name: &str, default: u64) -> Result<u64, String> {
    match args.iter().position(|a| a == name) {
        None => Ok(default),
        Some(i) => args
            .get(i + 1)
            .and_then(|v| v.parse().ok())
            .ok_or_else(|| format!("{name} needs a whole number, e.g. {name} {default}")),
    }
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let particles = arg(&args, "--particles", 8000)? as usize;
    let exchanges = arg(&args, "--exchanges", 1000)?;
    let spin = Duration::from_micros(arg(&args, "--spin-us", 100)?);
    if exchanges == 0 || particles == 0 {
        return Err("--particles and --exchanges must be at least 1".into());
    }

    let mut cfg = LinkConfig::new(format!("latency-{}", std::process::id()), 1, particles);
    cfg.spin = spin;
    let lbm_cfg = cfg.clone();
    let lbm = std::thread::spawn(move || -> Result<(), LinkError> {
        let mut link = LbmLink::connect(&lbm_cfg)?;
        let mut states = Vec::with_capacity(particles);
        let mut loads = vec![HydroLoad::default(); particles];
        for n in 0..exchanges {
            let h = link.receive_states(n, &mut states)?;
            for (l, s) in loads.iter_mut().zip(&states) {
                l.id = s.id;
                l.force = s.position.map(|p| 2.0 * p);
            }
            link.send_loads(ExchangeHeader::new(n, h.time), &loads)?;
        }
        Ok(())
    });

    let mut dem = DemLink::connect(&cfg)?;
    let mut states: Vec<ParticleState> =
        (0..particles).map(|i| ParticleState { id: i as u32, radius: 1e-3, ..Default::default() }).collect();
    let mut loads = Vec::with_capacity(particles);
    let mut times = Vec::with_capacity(exchanges as usize);
    for n in 0..exchanges {
        for s in &mut states {
            s.position[0] = n as f64;
        }
        let t0 = Instant::now();
        dem.send_states(ExchangeHeader::new(n, n as f64 * 1e-4), &states)?;
        dem.receive_loads(n, &mut loads)?;
        times.push(t0.elapsed());
        if loads.first().is_some_and(|l| l.force[0] != 2.0 * n as f64) {
            return Err(format!("wrong load in exchange {n}").into());
        }
    }
    lbm.join().map_err(|_| "the LBM thread panicked")??;

    times.sort();
    let at = |q: f64| times[((times.len() - 1) as f64 * q).round() as usize].as_secs_f64() * 1e6;
    println!(
        "{particles} particles ({} KiB out, {} KiB back), {exchanges} round trips, spin {} µs: median {:.1} µs, p99 {:.1} µs, max {:.1} µs",
        particles * std::mem::size_of::<ParticleState>() / 1024,
        particles * std::mem::size_of::<HydroLoad>() / 1024,
        spin.as_micros(),
        at(0.5),
        at(0.99),
        at(1.0)
    );
    Ok(())
}
