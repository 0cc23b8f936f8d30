//! The DEM's plan for a scene ([`schemas::plan`]): the contact law and the
//! time step it resolves to, the grains, the packing, the cost, and the
//! warnings on stiffness and steps per contact.

use schemas::plan::Plan;
use schemas::scene::{PackingSpec, Scene};

use crate::packing::{cache_path, generate};
use crate::setup::DemSetup;

/// Particle-steps per second measured on the dry H0 = 0.06 m column, 2 cores
/// (docs/BENCHMARKS.md); only used to estimate a duration.
pub const MEASURED_DEM_RATE: f64 = 8.0e6;

/// Rough bytes per grain: seven 3-vectors, radius and mass, and ~10
/// contacts of history and neighbour entries.
const BYTES_PER_GRAIN: f64 = 7.0 * 24.0 + 16.0 + 10.0 * 110.0;

/// Steps per contact below which restitution and stability suffer.
const MIN_STEPS_PER_CONTACT: f64 = 20.0;

/// The DEM's plan for `scene` (which has particle blocks), resolved as
/// `dem_proc` resolves it ([`DemSetup::from_scene`], the same grain generator).
pub fn plan(scene: &Scene) -> Plan {
    let s = &scene.spec;
    let setup = DemSetup::from_scene(scene);
    let (grains, _) = generate(scene);
    let n = grains.len();
    let mut p = Plan::new("dem_proc", "particle-steps");
    p.time_step = setup.numerics.dt;
    p.steps = (s.output.end_time / setup.numerics.dt).ceil() as u64;
    p.work = p.steps as f64 * n as f64;
    p.memory = n as f64 * BYTES_PER_GRAIN;
    p.wall_estimate = p.work / MEASURED_DEM_RATE;
    p.line("grains", format!("{n} generated ({} blocks)", s.particles.len()));
    let law = &setup.grain_law;
    p.line(
        "contact",
        format!(
            "k_n {} N/m, k_t {} N/m, e {} -> damping ratio {:.5} (no-tension law), mu_s {}, mu_r {}",
            law.normal_stiffness,
            law.tangential_stiffness,
            scene.dem().restitution,
            law.damping_ratio,
            law.friction,
            law.rolling_friction
        ),
    );
    p.line(
        "time step",
        format!(
            "{:.3e} s; contact duration {:.3e} s -> {:.1} steps per contact",
            setup.numerics.dt, setup.contact_duration, setup.steps_per_contact
        ),
    );
    p.line(
        "cost",
        format!(
            "up to {} steps = {:.2e} particle-steps (~{:.0} s at {:.0e} particle-steps/s); memory ~{:.0} MB",
            p.steps,
            p.work,
            p.wall_estimate,
            MEASURED_DEM_RATE,
            p.memory / 1e6
        ),
    );
    if s.particles.iter().any(|b| matches!(b.packing, PackingSpec::Deposit { .. })) {
        let path = cache_path(scene);
        if s.deposition.cache && path.exists() {
            p.line("packing", format!("cached: {}", path.display()));
        } else {
            p.line(
                "packing",
                format!(
                    "gravity deposition at friction {} until grains are slower than {} m/s (cached as {})",
                    s.deposition.friction,
                    s.deposition.rest_speed,
                    path.display()
                ),
            );
        }
    }
    if setup.steps_per_contact < MIN_STEPS_PER_CONTACT {
        p.warn(format!(
            "only {:.1} steps per contact: restitution and stability suffer below ~{MIN_STEPS_PER_CONTACT:.0}; lower dem.time_step",
            setup.steps_per_contact
        ));
    }
    // Static overlap at the column base relative to the grain size.
    let rho = s.particles[0].density;
    let dmean = s.particles[0].diameter;
    let base_force = rho * 0.6 * scene.gravity_magnitude() * s.analysis.column_height * dmean * dmean;
    let overlap = base_force / law.normal_stiffness / dmean;
    p.line("stiffness", format!("base overlap ~{:.2} % of D under the column weight", overlap * 100.0));
    if overlap > 0.01 {
        p.warn(format!(
            "grains at the base overlap ~{:.1} % of D: raise dem.normal_stiffness for the rigid limit",
            overlap * 100.0
        ));
    }
    p
}
