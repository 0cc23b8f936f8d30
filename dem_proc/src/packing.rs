//! The initial packing: explicit grains, or gravity deposition behind the
//! closed gates until at rest, trimmed at the column top, cached on disk by a
//! hash of everything that determines it.
//!
//! Deposition uses the scene's stiffness and restitution with
//! `deposition.friction` (lower friction packs denser). Grains start on a
//! jittered lattice (spacing 1.2 D_max, lateral jitter ±0.1 D_max, seeded)
//! stacked upward from the region's floor. When the fastest grain is slower
//! than `deposition.rest_speed`, grains of a deposit block whose centre lies
//! above the block region's top are removed, velocities are zeroed, and the
//! contact springs are kept with the packing.
//!
//! The grains are poured into an open box: a lid (`z_max` among the
//! domain's walls, which a coupled scene closes for its liquid) is inactive
//! while they settle, so the dry and the saturated scene of one column,
//! which differ in nothing else the deposition reads, settle into the same
//! packing and share one cache file.

use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use serde::{Deserialize, Serialize};

use schemas::scene::{DomainSpec, Face, PackingSpec, Scene};

use crate::rng::SplitMix64;
use crate::setup::{walls, DemSetup};
use crate::world::{Grains, Histories, World};

/// Bump when the deposition algorithm changes, so old caches are not reused.
const PACKING_VERSION: u32 = 3;

#[derive(Debug, Clone, Default, Serialize, Deserialize)]
pub struct PackingReport {
    /// 1 − V_solid / V_region of the first deposit block's region (bulk, walls included).
    pub porosity_bulk: f64,
    /// Porosity of grains centred at least one diameter from the side walls,
    /// the floor, and two diameters below the region top.
    pub porosity_core: f64,
    /// Highest grain top of the first deposit block, m.
    pub height: f64,
    pub generated: usize,
    pub kept: usize,
    /// Simulated deposition time, s.
    pub deposition_time: f64,
    /// Wall time the deposition took when it ran, s.
    pub deposition_seconds: f64,
    #[serde(skip)]
    pub from_cache: bool,
    #[serde(skip)]
    pub cache_file: Option<PathBuf>,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Packing {
    pub grains: Grains,
    pub histories: Histories,
    pub report: PackingReport,
}

#[derive(Debug, thiserror::Error)]
pub enum PackingError {
    #[error("deposition did not reach rest within deposition.max_time = {max_time} s: the fastest grain still moves at {speed:.3e} m/s (rest is < {rest} m/s). Raise deposition.max_time, or deposition.rest_speed")]
    NotAtRest { max_time: f64, speed: f64, rest: f64 },
    #[error("interrupted during deposition")]
    Interrupted,
    #[error("deposition became unstable (non-finite grain state at t = {t:.4} s): reduce dem.time_step or raise dem.steps_per_contact")]
    Unstable { t: f64 },
}

/// Where settled packings are kept: `$SGF_CACHE_DIR`, else
/// `$XDG_CACHE_HOME/saturated-granular/packings`, else `~/.cache/saturated-granular/packings`.
pub fn cache_dir() -> PathBuf {
    if let Some(d) = std::env::var_os("SGF_CACHE_DIR") {
        return PathBuf::from(d);
    }
    let base = std::env::var_os("XDG_CACHE_HOME")
        .map(PathBuf::from)
        .or_else(|| std::env::var_os("HOME").map(|h| PathBuf::from(h).join(".cache")))
        .unwrap_or_else(std::env::temp_dir);
    base.join("saturated-granular").join("packings")
}

/// Hash of everything that determines the packing.
pub fn packing_key(scene: &Scene) -> u64 {
    let s = &scene.spec;
    let dem = scene.dem();
    // The run's gravity does not touch the deposition: a pushed run shares
    // the packing of the unpushed one.
    let domain = DomainSpec { collapse_gravity: None, ..s.domain.clone() };
    let key = serde_json::json!({
        "version": PACKING_VERSION,
        "domain": domain,
        "gates": s.gates.iter().map(|g| (g.point, g.normal)).collect::<Vec<_>>(),
        "particles": s.particles,
        "explicit": scene.explicit_spheres,
        "dem": [dem.normal_stiffness, dem.tangential_stiffness_ratio, dem.restitution,
                dem.time_step.unwrap_or(-1.0), dem.steps_per_contact, dem.neighbour_skin, dem.sort_interval as f64],
        "deposition": [s.deposition.friction, s.deposition.rolling_friction,
                       s.deposition.rest_speed, s.deposition.max_time],
    });
    schemas::stable_hash(key.to_string().as_bytes())
}

/// The cache file of the scene's packing: named by [`packing_key`] alone,
/// so scenes that deposit alike (a column dry and saturated) share it.
pub fn cache_path(scene: &Scene) -> PathBuf {
    cache_dir().join(format!("packing-{:016x}.bin", packing_key(scene)))
}

/// The walls grains settle against: the scene's box walls and closed gates,
/// the lid (`z_max`) inactive. Indices are those of the run's walls, so the
/// kept contact springs stay with their walls.
pub fn deposition_walls(scene: &Scene) -> Vec<crate::world::Wall> {
    let mut walls = walls(scene, true);
    for wall in &mut walls {
        if wall.name == Face::ZMax.name() {
            wall.active = false;
        }
    }
    walls
}

fn has_deposit(scene: &Scene) -> bool {
    scene.spec.particles.iter().any(|b| matches!(b.packing, PackingSpec::Deposit { .. }))
}

/// Builds (or loads) the packing. `progress(t_sim, t_max)` is called now and then.
pub fn build(
    scene: &Scene,
    setup: &DemSetup,
    stop: &AtomicBool,
    mut progress: impl FnMut(f64, f64),
) -> Result<Packing, PackingError> {
    let (mut grains, blocks) = generate(scene);
    if !has_deposit(scene) {
        let report = PackingReport {
            generated: grains.len(),
            kept: grains.len(),
            porosity_bulk: f64::NAN,
            porosity_core: f64::NAN,
            ..Default::default()
        };
        return Ok(Packing { grains, histories: Histories::default(), report });
    }
    let path = cache_path(scene);
    if scene.spec.deposition.cache {
        if let Some(mut p) = load_cached(&path) {
            p.report.from_cache = true;
            p.report.cache_file = Some(path);
            return Ok(p);
        }
    }

    let started = Instant::now();
    let dep = setup.for_deposition(scene);
    let generated = grains.len();
    let mut world = World::new(
        std::mem::take(&mut grains),
        deposition_walls(scene),
        dep.grain_law,
        dep.wall_law,
        dep.gravity,
        dep.numerics,
        dep.domain,
    );
    world.prime_forces();
    let rest = scene.spec.deposition.rest_speed;
    let max_time = scene.spec.deposition.max_time;
    // Do not test for rest before the highest grain could have fallen to the floor.
    let top = world.grains.pos.iter().map(|p| p[2]).fold(f64::NEG_INFINITY, f64::max);
    let g = world.gravity.iter().map(|x| x * x).sum::<f64>().sqrt();
    let fall_time = (2.0 * (top - setup.domain.0[2]).max(0.0) / g).sqrt();
    let check_every = 200;
    loop {
        for _ in 0..check_every {
            world.step();
        }
        if stop.load(Ordering::Relaxed) {
            return Err(PackingError::Interrupted);
        }
        let speed = world.max_speed();
        if !speed.is_finite() {
            return Err(PackingError::Unstable { t: world.time });
        }
        progress(world.time, max_time);
        if world.time > fall_time && speed < rest {
            break;
        }
        if world.time > max_time {
            return Err(PackingError::NotAtRest { max_time, speed, rest });
        }
    }

    // Trim each deposit block at its region top, keeping contact histories.
    let n = world.len();
    let mut keep = vec![true; n];
    for p in 0..n {
        if let PackingSpec::Deposit { region, .. } =
            &scene.spec.particles[blocks[world.ids()[p] as usize] as usize].packing
        {
            keep[p] = world.grains.pos[p][2] <= region.max[2];
        }
    }
    let mut new_index = vec![u32::MAX; n];
    let mut next = 0u32;
    for p in 0..n {
        if keep[p] {
            new_index[p] = next;
            next += 1;
        }
    }
    let h = world.histories();
    let histories = Histories {
        pairs: h
            .pairs
            .iter()
            .filter(|(i, j, _)| keep[*i as usize] && keep[*j as usize])
            .map(|&(i, j, s)| (new_index[i as usize], new_index[j as usize], s))
            .collect(),
        walls: h
            .walls
            .iter()
            .filter(|(p, _, _)| keep[*p as usize])
            .map(|&(p, w, s)| (new_index[p as usize], w, s))
            .collect(),
    };
    let deposition_time = world.time;
    // The packing is stored in the deposition's final (spatially sorted) order.
    let blocks: Vec<u16> =
        world.ids().iter().zip(&keep).filter(|(_, k)| **k).map(|(&id, _)| blocks[id as usize]).collect();
    let mut grains = world.grains;
    grains.retain(&keep);
    for v in grains.vel.iter_mut().chain(grains.omega.iter_mut()) {
        *v = [0.0; 3];
    }

    let mut report = porosity_report(scene, &grains, &blocks);
    report.generated = generated;
    report.kept = grains.len();
    report.deposition_time = deposition_time;
    report.deposition_seconds = started.elapsed().as_secs_f64();
    let packing = Packing { grains, histories, report };
    if scene.spec.deposition.cache {
        store_cached(&path, &packing);
    }
    Ok(packing)
}

fn load_cached(path: &PathBuf) -> Option<Packing> {
    let bytes = std::fs::read(path).ok()?;
    bincode::serde::decode_from_slice(&bytes, bincode::config::standard()).ok().map(|(p, _)| p)
}

/// Best effort: a cache that cannot be written only costs a later deposition.
fn store_cached(path: &PathBuf, packing: &Packing) {
    let Ok(bytes) = bincode::serde::encode_to_vec(packing, bincode::config::standard()) else { return };
    if let Some(dir) = path.parent() {
        let _ = std::fs::create_dir_all(dir);
    }
    let tmp = path.with_extension(format!("tmp{}", std::process::id()));
    if std::fs::write(&tmp, bytes).is_ok() {
        let _ = std::fs::rename(&tmp, path);
    }
}

/// Initial grains of every block, with the block index of each grain.
pub fn generate(scene: &Scene) -> (Grains, Vec<u16>) {
    let mut grains = Grains::default();
    let mut blocks = Vec::new();
    for (b, block) in scene.spec.particles.iter().enumerate() {
        match &block.packing {
            PackingSpec::Explicit { velocity, .. } => {
                for s in &scene.explicit_spheres[b] {
                    grains.push([s[0], s[1], s[2]], *velocity, 0.5 * s[3], block.density);
                    blocks.push(b as u16);
                }
            }
            PackingSpec::Deposit { region, porosity, count, seed } => {
                let spread = block.diameter_spread;
                let mean_volume = std::f64::consts::PI / 6.0 * block.diameter.powi(3) * (1.0 + spread * spread);
                let volume: f64 = (0..3).map(|a| region.max[a] - region.min[a]).product();
                let n = match (porosity, count) {
                    (Some(p), _) => ((1.0 - p) * volume / mean_volume).round() as usize,
                    (_, Some(c)) => *c,
                    _ => 0,
                };
                let d_max = block.diameter * (1.0 + spread);
                let spacing = 1.2 * d_max;
                let fit = |a: usize| (((region.max[a] - region.min[a] - d_max) / spacing).floor() as usize + 1).max(1);
                let (nx, ny) = (fit(0), fit(1));
                let mut rng = SplitMix64::new(*seed);
                for k in 0..n {
                    let layer = k / (nx * ny);
                    let (ix, iy) = ((k % (nx * ny)) % nx, (k % (nx * ny)) / nx);
                    let x = region.min[0] + 0.5 * d_max + ix as f64 * spacing + 0.1 * d_max * rng.symmetric();
                    let y = region.min[1] + 0.5 * d_max + iy as f64 * spacing + 0.1 * d_max * rng.symmetric();
                    let z = region.min[2] + 0.5 * d_max + layer as f64 * spacing;
                    let d = block.diameter * (1.0 + spread * rng.symmetric());
                    let clamp = |v: f64, a: usize| v.clamp(region.min[a] + 0.5 * d, region.max[a] - 0.5 * d);
                    grains.push([clamp(x, 0), clamp(y, 1), z], [0.0; 3], 0.5 * d, block.density);
                    blocks.push(b as u16);
                }
            }
        }
    }
    (grains, blocks)
}

fn porosity_report(scene: &Scene, grains: &Grains, blocks: &[u16]) -> PackingReport {
    let mut report = PackingReport { porosity_bulk: f64::NAN, porosity_core: f64::NAN, ..Default::default() };
    let Some((b, region, d)) = scene.spec.particles.iter().enumerate().find_map(|(b, blk)| match &blk.packing {
        PackingSpec::Deposit { region, .. } => Some((b as u16, *region, blk.diameter * (1.0 + blk.diameter_spread))),
        _ => None,
    }) else {
        return report;
    };
    let vol = |r: f64| 4.0 / 3.0 * std::f64::consts::PI * r.powi(3);
    let mut solid = 0.0;
    let mut core_solid = 0.0;
    let mut height = 0.0_f64;
    let core_min = [region.min[0] + d, region.min[1] + d, region.min[2] + d];
    let core_max = [region.max[0] - d, region.max[1] - d, region.max[2] - 2.0 * d];
    for p in (0..grains.len()).filter(|&p| blocks[p] == b) {
        let (x, r) = (grains.pos[p], grains.radius[p]);
        solid += vol(r);
        height = height.max(x[2] + r);
        if (0..3).all(|a| x[a] >= core_min[a] && x[a] < core_max[a]) {
            core_solid += vol(r);
        }
    }
    let region_volume: f64 = (0..3).map(|a| region.max[a] - region.min[a]).product();
    let core_volume: f64 = (0..3).map(|a| (core_max[a] - core_min[a]).max(0.0)).product();
    report.porosity_bulk = 1.0 - solid / region_volume;
    report.porosity_core = if core_volume > 0.0 { 1.0 - core_solid / core_volume } else { f64::NAN };
    report.height = height;
    report
}
