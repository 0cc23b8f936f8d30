//! The LBM's plan for a scene ([`schemas::plan`]): the lattice, relaxation
//! and Mach number the scene resolves to, the cost, and, coupled, how the
//! grains are forced in (resolution, hydrostatics, the Eq. 5 gain), with
//! the warnings each calls for.

use schemas::plan::Plan;
use schemas::scene::{ForcingGain, Hydrostatics, Scene};
use schemas::Method;

use crate::fluid::forcing_gain;
use crate::Units;

/// Lattice updates per second of the LBM on 2 threads (docs/BENCHMARKS.md);
/// only used to estimate a duration.
pub const MEASURED_LBM_RATE: f64 = 4.0e7;

/// Two lattices of 19 populations of `population_bytes` each, f64 mass and
/// fill per cell where the liquid is (the flags are dense, one byte per cell).
fn bytes_per_liquid_cell(population_bytes: usize) -> f64 {
    19.0 * population_bytes as f64 * 2.0 + 16.0
}

/// Memory per cell of the liquid's rows at the start (its x-extent rounded
/// up to whole segments), over [`bytes_per_liquid_cell`]: the
/// liquid spreading, the pages segments straddle, the f64 arrays' page per
/// row. Calibrated on the peak of the whole coupled lab column (lbm_proc
/// 707 MB; 572 MB at 0.05 s; docs/BENCHMARKS.md "The sparse lattice").
const SPREAD_FACTOR: f64 = 3.8;

/// The LBM's plan for `scene` (which has fluid blocks and an `[lbm]` table).
pub fn plan(scene: &Scene) -> Plan {
    let mut p = Plan::new("lbm_proc", "cell updates");
    let s = &scene.spec;
    let lbm = scene.lbm();
    let fluid = &s.fluids[0];
    let (dx, dt) = (lbm.spacing, lbm.time_step);
    let nu = fluid.viscosity / fluid.density;
    let Ok(units) = Units::new(dx, dt, fluid.density) else {
        p.warn("lattice units cannot be built from lbm.spacing and lbm.time_step");
        return p;
    };
    let tau = units.tau_from_viscosity(nu).unwrap_or(f64::NAN);
    let nu_l = units.viscosity_to_lattice(nu);
    let cells = |lo: f64, hi: f64| ((hi - lo) / dx).round().max(1.0);
    let d = &s.domain;
    let dims = [0, 1, 2].map(|a| cells(d.min[a], d.max[a]));
    let ncells = dims[0] * dims[1] * dims[2];
    let liquid: f64 =
        s.fluids.iter().map(|f| (0..3).map(|a| cells(f.region.min[a], f.region.max[a])).product::<f64>()).sum();
    p.time_step = dt;
    p.steps = (s.output.end_time / dt).ceil() as u64;
    p.work = p.steps as f64 * liquid;
    let population_bytes = lbm.precision.bytes();
    // Memory follows the liquid (fluid/layout.rs): its rows, in segments.
    let layout = crate::fluid::Layout::new(dims.map(|n| n as usize));
    let segment = layout.segment() as f64;
    let liquid_rows: f64 = s
        .fluids
        .iter()
        .map(|f| {
            let x = cells(f.region.min[0], f.region.max[0]);
            let rows = cells(f.region.min[1], f.region.max[1]) * cells(f.region.min[2], f.region.max[2]);
            rows * (x / segment).ceil() * segment
        })
        .sum();
    // At most the whole box's arrays (rows padded to whole segments).
    let padded = (layout.len() / crate::lattice::Q) as f64;
    p.memory = (liquid_rows * SPREAD_FACTOR).min(padded) * bytes_per_liquid_cell(population_bytes) + ncells;
    // The kernel is bound by memory traffic, which the population size sets.
    p.wall_estimate = p.work / MEASURED_LBM_RATE * (population_bytes as f64 / 4.0);
    p.line(
        "lattice",
        format!(
            "{} x {} x {} = {:.3e} cells of {:.3e} m, time step {:.3e} s; liquid {:.3e} cells at the start; populations in {}",
            dims[0], dims[1], dims[2], ncells, dx, dt, liquid, lbm.precision.name()
        ),
    );
    p.line(
        "relaxation",
        format!(
            "tau0 = {tau:.6} (nu = {nu:.3e} m²/s = {nu_l:.3e} lattice), {:?}, Smagorinsky C = {}",
            lbm.collision, lbm.smagorinsky
        ),
    );
    // Eq. 4: nu_t = (C dx)^2 |S|, at the collapse's own shear rate sqrt(g/H0) and at 100 1/s.
    let g = scene.gravity_magnitude();
    let h0 = s.analysis.column_height;
    for shear in [(g / h0).sqrt(), 100.0] {
        let nu_t = (lbm.smagorinsky * dx).powi(2) * shear;
        p.line(
            "viscosity",
            format!(
                "at shear {shear:.1} 1/s: nu = {nu:.3e} molecular + {nu_t:.3e} eddy = {:.3e} m²/s = {:.3e} lattice (tau {:.6})",
                nu + nu_t,
                units.viscosity_to_lattice(nu + nu_t),
                units.tau_from_viscosity(nu + nu_t).unwrap_or(f64::NAN)
            ),
        );
    }
    let cs = (1.0_f64 / 3.0).sqrt();
    let wave = (g * h0).sqrt();
    for (what, speed) in [("sqrt(g H0)", wave), ("2 sqrt(g H0) (dam-break front)", 2.0 * wave)] {
        let mach = units.velocity_to_lattice(speed) / cs;
        p.line("mach", format!("{what} = {speed:.3} m/s -> Mach {mach:.3} in lattice units"));
        if mach > lbm.mach_limit {
            p.warn(format!(
                "{what} gives Mach {mach:.2}, above lbm.mach_limit = {}: the watchdog may stop the run; lower lbm.time_step",
                lbm.mach_limit
            ));
        } else if mach > 0.3 {
            p.warn(format!(
                "{what} gives Mach {mach:.2}: compressibility errors grow above ~0.3; lower lbm.time_step for accuracy"
            ));
        }
    }
    if tau < 0.51 && lbm.smagorinsky == 0.0 {
        p.warn(format!(
            "tau0 = {tau:.5} with no eddy viscosity: BGK is at the edge of stability; set lbm.smagorinsky (0.16)"
        ));
    }
    p.line(
        "cost",
        format!(
            "{} steps; memory ~{:.0} MB; ~{:.0} s at {:.0e} lattice updates/s if the liquid stays at its initial volume",
            p.steps,
            p.memory / 1e6,
            p.wall_estimate,
            MEASURED_LBM_RATE
        ),
    );
    if scene.method() == Method::DemLbm {
        plan_forcing(scene, &units, tau, &mut p);
    }
    p
}

/// Coupled: how the grains are forced into the lattice.
fn plan_forcing(scene: &Scene, units: &Units, tau0: f64, p: &mut Plan) {
    let s = &scene.spec;
    let lbm = scene.lbm();
    // The coupling resolves grains on the lattice: a few cells per diameter at least.
    let d_min = s.particles.iter().map(|b| b.diameter * (1.0 - b.diameter_spread)).fold(f64::INFINITY, f64::min);
    let cells = d_min / units.dx();
    p.line("resolution", format!("smallest grain diameter {cells:.2} lattice cells"));
    // The lattice's hydrostatic density varies by 3 g H Δt²/Δx² over a liquid H tall.
    let height = s.fluids.iter().map(|f| f.region.max[2] - f.region.min[2]).fold(0.0, f64::max);
    let head = 3.0 * scene.gravity_magnitude() * height * lbm.time_step.powi(2) / lbm.spacing.powi(2);
    match lbm.hydrostatics {
        Hydrostatics::Lattice => {
            p.line(
                "hydrostatics",
                format!(
                    "lattice: the liquid's density varies by {:.2} % over its {height} m (3 g H dt^2/dx^2)",
                    100.0 * head
                ),
            );
            if head > 0.05 {
                p.warn(format!(
                    "the lattice's hydrostatic density varies by {:.0} % over the liquid's height: the liquid is that much compressed at depth, with its buoyancy and viscosity (docs/coupling.md \"Submerged scenes\"); use lbm.hydrostatics = \"buoyancy\" (liquid filling a closed box) or a smaller lbm.time_step",
                    100.0 * head
                ));
            }
            // The lattice's mean density is the liquid's, so the liquid at
            // the bottom is ~head/2 denser; a grain lighter than that floats.
            let rho_l = s.fluids[0].density;
            for block in &s.particles {
                let excess = block.density / rho_l - 1.0;
                if excess < 0.5 * head {
                    p.warn(format!(
                        "grains \"{}\" are {:.2} % denser than the liquid, less than the lattice's compression at depth (up to {:.1} %): they would rise or sink too slowly there; use lbm.hydrostatics = \"buoyancy\" (liquid filling a closed box) or a smaller lbm.time_step (the compression goes as dt^2)",
                        block.name,
                        100.0 * excess,
                        50.0 * head
                    ));
                }
            }
        }
        Hydrostatics::Buoyancy => {
            p.line("hydrostatics", "buoyancy: the liquid feels no gravity; each grain's load gets -rho_L V g")
        }
    }
    let c = &s.coupling;
    let half = forcing_gain(c.forcing_gain, 0.5, tau0);
    p.line(
        "forcing",
        format!(
            "{} gain: a half-covered cell is pulled {half:.3} of the way to the grain per step (tau0 = {tau0:.6})",
            c.forcing_gain.name()
        ),
    );
    match c.forcing_gain {
        ForcingGain::CoveredFraction | ForcingGain::CentreInside if tau0 < 0.55 => p.warn(format!(
            "coupling.forcing_gain = \"{}\" at tau0 = {tau0:.4}: the grains' surface cells hold the pore liquid far more than its viscosity would (packed-bed permeability 0.007-0.14x Kozeny-Carman at tau0 -> 1/2, docs/coupling.md \"Choosing the forcing gain\"); use \"noble_torczynski\"",
            c.forcing_gain.name()
        )),
        ForcingGain::NobleTorczynski | ForcingGain::NobleTorczynskiEffective if tau0 >= 0.55 => p.warn(format!(
            "coupling.forcing_gain = \"{}\" at tau0 = {tau0:.4}: in a viscous liquid its partly covered cells pull too little (array drag 9-48 % low at tau 0.6-1, D/dx 4-8, docs/coupling.md \"Choosing the forcing gain\"); \"centre_inside\" (tau ~0.6) or \"covered_fraction\" (tau ~1) is closer",
            c.forcing_gain.name()
        )),
        _ => {}
    }
    if cells < 3.0 {
        p.warn(format!(
            "grains span only {cells:.1} cells: the direct forcing needs ~4 or more for drag within ~10 % (docs/coupling.md); lower lbm.spacing"
        ));
    }
}
