//! The MPM's plan for a scene as `coupler check` prints it
//! ([`schemas::plan`]): the grid and points, the waves, Δt and the cost,
//! the soil, liquid and drag models, the boundaries and the transfer, from
//! the closed forms of [`super`] that `mpm_proc` itself uses.

use schemas::plan::Plan;
use schemas::scene::{
    Face, InitialStress, MpmFloor, MpmLiquidWallShear, MpmPressureReconstruction, MpmPressureScheme,
    MpmSurfaceElements, MpmTransfer, MpmWallContact, MpmWallFrictionReach, MpmWallTangentUpdate, PackingSpec, Scene,
};

use super::{self as mpm, SceneMpm};

/// Point updates per second of the saturated column's bench, 2 threads
/// (docs/BENCHMARKS.md); only used to estimate a duration.
pub const MEASURED_MPM_RATE: f64 = 4.1e6;

/// Rough bytes per material point (position, velocity, mass, volume,
/// stresses, strains, porosity, flags, and its GIMP weights and gradients on
/// 9 nodes) and per grid node and phase (mass, momentum, force, velocity,
/// drag, density fields); only used to print a memory figure.
const MPM_BYTES_PER_POINT: f64 = 500.0;
const MPM_BYTES_PER_NODE_PHASE: f64 = 200.0;

/// The MPM's plan for `scene` (validated as `mpm`): grid, points, waves
/// and Δt, soil model, drag, gravity phase.
pub fn plan(scene: &Scene) -> Plan {
    let mut p = Plan::new("mpm_proc", "point updates");
    let m = scene.mpm();
    let grid = scene.mpm_grid();
    let h = grid.element_size;
    let ppe = m.points_per_element as usize;
    let (a, b) = m.point_grid();
    p.line("grid", format!("{} x {} = {} elements (x, z) of {} m, {} nodes; {} shape functions; {ppe} points per phase per filled element ({a} x {b})",
        grid.nx,
        grid.nz,
        grid.elements(),
        short(h),
        grid.nodes(),
        m.shape_functions.name()
    ));
    let points = plan_points(scene, ppe, &mut p);
    let ts = scene.mpm_time_step();
    plan_waves_and_cost(scene, &ts, points, &mut p);
    plan_materials(scene, &ts, &mut p);
    numerics_warnings(scene, ppe, &mut p);
    plan_boundaries(scene, &mut p);
    p
}

/// The soil's and the liquid's filled elements and points; returns the points of both phases.
fn plan_points(scene: &Scene, ppe: usize, p: &mut Plan) -> usize {
    let s = &scene.spec;
    let grid = scene.mpm_grid();
    // Along x in whole elements; along z in the points' lattice rows, b to
    // an element (a block may end inside one), a points to a row per element.
    let (a, b) = schemas::scene::point_grid_of(ppe as u32);
    let (a, b) = (a.max(1) as usize, b.max(1) as usize);
    let area = |r: &schemas::scene::BoxSpec| -> ((usize, usize), (usize, usize)) {
        (grid.span(0, r.min[0], r.max[0]), grid.rows(r.min[2], r.max[2], b))
    };
    // Elements touched (a part-filled one counted whole) and points seeded.
    let elements =
        |((x0, x1), (z0, z1)): ((usize, usize), (usize, usize))| (x1 - x0) * (z1.div_ceil(b).saturating_sub(z0 / b));
    let points = |((x0, x1), (z0, z1)): ((usize, usize), (usize, usize))| (x1 - x0) * a * z1.saturating_sub(z0);
    let soil_area = s.particles.first().and_then(|p| match &p.packing {
        PackingSpec::Deposit { region, .. } => Some(area(region)),
        PackingSpec::Explicit { .. } => None,
    });
    let liquid_area = s.fluids.first().map(|f| area(&f.region));
    let soil_elements = soil_area.map(elements).unwrap_or(0);
    let liquid_elements = liquid_area.map(elements).unwrap_or(0);
    let shared = match (soil_area, liquid_area) {
        (Some(((sx0, sx1), (sz0, sz1))), Some(((lx0, lx1), (lz0, lz1)))) => {
            let common =
                ((sx0.max(lx0), sx1.min(lx1).max(sx0.max(lx0))), (sz0.max(lz0), sz1.min(lz1).max(sz0.max(lz0))));
            Some(common)
        }
        _ => None,
    };
    let overlap = shared.map(elements).unwrap_or(0);
    let overlap_points = shared.map(points).unwrap_or(0);
    let soil_points = soil_area.map(points).unwrap_or(0);
    let liquid_points = liquid_area.map(points).unwrap_or(0);
    if let Some(soil) = s.particles.first() {
        p.line(
            "soil",
            format!(
                "{}: {soil_elements} elements, {soil_points} solid points ({} saturated elements, {} dry)",
                soil.name,
                overlap,
                soil_elements - overlap
            ),
        );
    }
    if let Some(liquid) = s.fluids.first() {
        let free = liquid_elements - overlap;
        let split = if liquid_points == overlap_points {
            "all in the soil's elements".to_string()
        } else {
            format!(
                "{overlap_points} in the soil's elements, {} in {free} free-water elements",
                liquid_points - overlap_points
            )
        };
        p.line(
            "liquid",
            format!("{}: {liquid_elements} elements, {liquid_points} liquid points ({split})", liquid.name),
        );
    }
    soil_points + liquid_points
}

/// Wave speeds, the time step and the cost of the run.
fn plan_waves_and_cost(scene: &Scene, ts: &mpm::MpmTimeStep, points: usize, p: &mut Plan) {
    let (s, m) = (&scene.spec, scene.mpm());
    let grid = scene.mpm_grid();
    let h = grid.element_size;
    let speed = |c: Option<f64>| c.map(|c| format!("{c:.1} m/s")).unwrap_or_else(|| "–".into());
    p.line(
        "waves",
        format!(
            "undrained P {}, liquid {}, dry P {}; the step is limited by {:.1} m/s ({}){}",
            speed(ts.undrained),
            speed(ts.liquid),
            speed(ts.dry),
            ts.max_speed,
            ts.limiting.name(),
            // Only the implicit scheme lets the dry wave limit a scene with
            // liquid (c_u > c_d whenever both exist).
            if ts.limiting == mpm::Wave::Dry && ts.liquid.is_some() {
                ": the pore pressure is implicit, so the liquid's waves do not limit it"
            } else {
                ""
            }
        ),
    );
    p.line(
        "time step",
        format!(
            "dt {:.3e} s = courant {} x {} m / {:.1} m/s ({} limits)",
            ts.dt,
            m.courant,
            short(h),
            ts.max_speed,
            ts.limiting.name()
        ),
    );
    let gravity_steps = match m.initial_stress {
        InitialStress::K0 => (m.gravity_phase_max_time / ts.dt).ceil(),
        InitialStress::Zero => 0.0,
    };
    p.time_step = ts.dt;
    p.steps = ts.steps;
    p.work = ts.steps as f64 * points as f64;
    p.memory = points as f64 * MPM_BYTES_PER_POINT + grid.nodes() as f64 * 2.0 * MPM_BYTES_PER_NODE_PHASE;
    p.wall_estimate = p.work / MEASURED_MPM_RATE;
    p.line(
        "cost",
        format!(
            "{} steps to the end time {} s, {:.2e} point-updates (~{:.0} s at {:.1e} point-updates/s); gravity phase up to {gravity_steps:.0} steps more; memory ~{:.0} MB",
            ts.steps,
            s.output.end_time,
            p.work,
            p.wall_estimate,
            MEASURED_MPM_RATE,
            p.memory / 1e6
        ),
    );
}

/// The soil, liquid and drag models, with the warnings they call for.
fn plan_materials(scene: &Scene, ts: &mpm::MpmTimeStep, p: &mut Plan) {
    let (s, m) = (&scene.spec, scene.mpm());
    if !s.particles.is_empty() {
        let n0 = scene.mpm_porosity().unwrap_or(f64::NAN);
        p.line("soil model", format!("E {:.3e} Pa, nu {}, E_oed {:.4e} Pa, K0 = nu/(1-nu) = {:.3}; Mohr-Coulomb phi {} deg (K_a {:.3}), c {} Pa, psi {} deg; n0 {}, n_max {}",
            m.young_modulus,
            m.poisson_ratio,
            ts.oedometric_modulus,
            mpm::at_rest_coefficient(m.poisson_ratio),
            m.friction_angle,
            mpm::active_coefficient(m.friction_angle),
            m.cohesion,
            m.dilatancy_angle,
            n0,
            m.max_porosity
        ));
        let soil = &s.particles[0];
        if let (Some(phi2), Some(law)) =
            (m.limit_friction_angle, crate::setup::inertial_friction(&m, soil.diameter, soil.density))
        {
            let i0 = law.reference_inertial_number;
            let at = |i: f64| law.sin_friction(i).asin().to_degrees();
            p.line(
                "rate-dependent friction",
                format!(
                    "mu(I): phi {} deg at rest to {phi2} deg, I_0 = {}; phi {:.1}, {:.1}, {:.1} deg at I = 0.01, 0.1, 1",
                    m.friction_angle,
                    i0,
                    at(0.01),
                    at(0.1),
                    at(1.0)
                ),
            );
        }
        if let Some(n_cs) = m.dilatancy_cutoff_porosity {
            p.line("dilatancy cut-off", format!("psi {} deg below porosity {n_cs}, 0 at and above", m.dilatancy_angle));
            if n_cs >= m.max_porosity {
                p.warn(format!(
                    "mpm.dilatancy_cutoff_porosity = {n_cs} is not below mpm.max_porosity = {}: the soil fluidises before its dilatancy stops",
                    m.max_porosity
                ));
            }
            if n0 >= n_cs {
                p.warn(format!(
                    "n0 = {n0} is not below mpm.dilatancy_cutoff_porosity = {n_cs}: the soil starts at its critical state and never dilates"
                ));
            }
        }
        if n0 >= m.max_porosity {
            p.warn(format!(
                "n0 = {n0} is not below mpm.max_porosity = {}: the soil starts fluidised (no effective stress)",
                m.max_porosity
            ));
        }
        if mpm::at_rest_coefficient(m.poisson_ratio) < mpm::active_coefficient(m.friction_angle) {
            p.warn(format!(
                "K0 = {:.3} is below K_a = {:.3}: the K0 initial stresses violate Mohr-Coulomb before the gate opens; raise mpm.poisson_ratio",
                mpm::at_rest_coefficient(m.poisson_ratio),
                mpm::active_coefficient(m.friction_angle)
            ));
        }
    }
    if let Some(liquid) = s.fluids.first() {
        p.line("liquid model", format!("K_L {:.3e} Pa, rho_L {} kg/m³, mu {:e} Pa s; tension up to {} Pa; free surface below fill {} (point or element); {}",
            m.liquid_bulk_modulus,
            liquid.density,
            liquid.viscosity,
            m.cavitation_threshold,
            m.free_surface_fill,
            match (m.pressure_scheme, m.pressure_reconstruction) {
                (MpmPressureScheme::Implicit, _) => format!(
                    "pore pressure semi-implicit, one per pressured element; air in part-filled ones at {} Pa; saturated layers in elements below the fill {}",
                    m.air_pressure,
                    match m.surface_elements_in_effect() {
                        MpmSurfaceElements::Hydrostatic => "at their hydrostatic pressure",
                        MpmSurfaceElements::Free => "free (p = 0)",
                    }
                ),
                (_, MpmPressureReconstruction::Linear) => "pore pressure a least-squares plane per element".to_string(),
                (_, MpmPressureReconstruction::None) => "pore pressure per point".to_string(),
            }
        ));
    }
    if let Some(drag) = scene.mpm_drag() {
        let n0 = scene.mpm_porosity().unwrap_or(f64::NAN);
        p.line("drag", format!("Ergun A {}, B {}, D {} m: kappa(n0) {:.3e} m² (Eq. 9), hydraulic conductivity {:.3e} m/s; quadratic term {}",
            m.ergun_a,
            m.ergun_b,
            s.particles[0].diameter,
            drag.permeability,
            drag.conductivity,
            if m.quadratic_drag { "on" } else { "off" }
        ));
        p.line(
            "reynolds",
            format!(
                "Re_p = D rho_L sqrt(g H0)/mu = {:.3e} (Eq. 12, sqrt(g H0) = {:.3} m/s)",
                drag.reynolds, drag.reference_velocity
            ),
        );
        p.line(
            "drag step",
            format!("dt mu n0²/kappa (1/((1-n0) rho_s) + 1/(n0 rho_L)) = {:.3e} (n0 = {n0})", drag.stiffness),
        );
        if drag.reynolds > 4e4 && !m.quadratic_drag {
            p.warn(format!(
                "Re_p = {:.2e} with mpm.quadratic_drag = false: the paper finds the quadratic term matters above ~4e4",
                drag.reynolds
            ));
        }
        if drag.stiffness > 1.0 {
            p.warn(format!(
                "drag stiffness dt mu n0²/kappa (...) = {:.2} > 1: an explicit drag would be unstable; mpm_proc integrates it implicitly per node, so this is handled, but the phases are locked together within a step",
                drag.stiffness
            ));
        }
    }
}

/// Warnings on the numerics: points per element, unused keys, the Courant number.
fn numerics_warnings(scene: &Scene, ppe: usize, p: &mut Plan) {
    let (s, m) = (&scene.spec, scene.mpm());
    if !s.particles.is_empty() && !s.fluids.is_empty() && ppe < 4 {
        p.warn(format!(
            "{ppe} points per element with two phases: the paper saw instabilities with 3 points per element (12 work; here 3 ran the saturated lab column stably, but its runout is 18 % longer than with 12, docs/results/convergence); raise mpm.points_per_element"
        ));
    }
    if let Some(unused) = schemas::scene::unused_flip_keys(&m) {
        p.warn(unused);
    }
    if let (Some(v), MpmWallContact::Bilateral) = (m.wall_release_speed, m.wall_contact) {
        p.warn(format!(
            "mpm.wall_release_speed = {v} is unused under mpm.wall_contact = \"bilateral\" (walls hold both ways); remove it or set wall_contact = \"unilateral\""
        ));
    }
    // A liquid top inside an element: that element starts part-filled, its
    // filling ratio (the water's share of the space its grains leave) f n /
    // (1 − f (1 − n)) for a filled share f of saturated soil, f alone above
    // free water or under soil that fills the element. Below
    // `free_surface_fill` it is out of the pressure solve: at p = 0 under
    // `surface_elements = "free"`, and at rest its water sinks
    // (docs/RESULTS.md, session 39). Under "hydrostatic" (the implicit
    // scheme's default) a saturated layer keeps its pressure, but water
    // below the soil's top fills too little of that soil's pores and
    // drains as before.
    if let Some(water) = s.fluids.first() {
        let (h, top) = (m.element_size, water.region.max[2] - s.domain.min[2]);
        let filled = top / h - (top / h).floor();
        let soil_top = s.particles.first().and_then(|p| match &p.packing {
            PackingSpec::Deposit { region, porosity: Some(n), .. } => Some((region.max[2], *n)),
            _ => None,
        });
        let soil_above = soil_top.filter(|&(st, _)| st > water.region.max[2] + 1e-9);
        let hydrostatic = m.surface_elements_in_effect() == MpmSurfaceElements::Hydrostatic;
        if filled > 1e-6 && filled < 1.0 - 1e-6 && (!hydrostatic || soil_above.is_some()) {
            let fill = match soil_top {
                Some((st, n)) if (st - water.region.max[2]).abs() < 1e-9 => filled * n / (1.0 - filled * (1.0 - n)),
                _ => filled,
            };
            let (why, other_fix) = match soil_above {
                Some((st, _)) if hydrostatic => (format!(" under the soil's top z = {st} m"), ""),
                _ => (
                    " under mpm.surface_elements = \"free\"".to_string(),
                    ", or use the implicit scheme's surface_elements = \"hydrostatic\"",
                ),
            };
            if fill < m.free_surface_fill {
                p.warn(format!(
                    "the liquid's top z = {} m lies inside an element ({filled:.2} of it below the top){why}: that element starts {fill:.2} filled, below mpm.free_surface_fill = {}, so it is out of the pressure solve at p = 0 and at rest its water sinks by about one point row (docs/RESULTS.md, session 39); put the top on a grid line or set mpm.free_surface_fill below {fill:.2}{other_fix}",
                    water.region.max[2], m.free_surface_fill
                ));
            }
        }
    }
    if m.transfer.is_affine() && m.courant > 0.7 {
        p.warn(format!(
            "mpm.courant = {} under an affine transfer (APIC, AFLIP): an elastic block held at 0.75 and blew up at 0.8 (docs/mpm.md, \"Time step\"); soil that yields may survive it, stiff or cohesive parts may not; use 0.7 or less",
            m.courant
        ));
    }
}

/// The gravity phase, the boundaries and the transfer.
fn plan_boundaries(scene: &Scene, p: &mut Plan) {
    let (s, m) = (&scene.spec, scene.mpm());
    match m.initial_stress {
        InitialStress::K0 => p.line("gravity", format!("K0 stresses{}, then a gravity phase with the gates held: damping {}, until the fastest point is slower than {} m/s or {} s",
            if s.fluids.is_empty() { "" } else { " and hydrostatic pore pressure" },
            m.gravity_phase_damping,
            m.gravity_phase_rest_speed,
            m.gravity_phase_max_time
        )),
        InitialStress::Zero => p.line("gravity", "stress-free start, gravity applied at t = 0 (no gravity phase)"),
    }
    let walls = &s.domain.walls;
    let fixed = match (walls.contains(&Face::ZMin), m.floor) {
        (false, _) => "no floor".to_string(),
        (true, MpmFloor::Rough) => "z_min rough (no slip, impermeable)".to_string(),
        (true, MpmFloor::Frictional) => {
            format!("z_min Coulomb, soil friction {} (liquid slips; impermeable)", m.wall_friction)
        }
    };
    let rollers: Vec<&str> =
        [Face::XMin, Face::XMax, Face::ZMax].into_iter().filter(|f| walls.contains(f)).map(Face::name).collect();
    let side = if m.wall_friction > 0.0 { format!("soil friction {}", m.wall_friction) } else { "rollers".to_string() };
    p.line(
        "boundaries",
        format!(
            "{fixed}; {side} on {}; {}; {}; {}; {}; y faces unused; local damping {}; top load {} Pa",
            if rollers.is_empty() { "none".to_string() } else { rollers.join(" ") },
            match (m.wall_contact, m.wall_release_speed) {
                (MpmWallContact::Bilateral, _) => "walls hold the normal velocity both ways".to_string(),
                (MpmWallContact::Unilateral, None) =>
                    "walls let go of material moving off them (unilateral: at the map where its momentum and the last step's force carry it off, else a step later)"
                        .to_string(),
                (MpmWallContact::Unilateral, Some(v)) => format!(
                    "walls let go of material moving off them (unilateral: at the map where its momentum and the last step's force carry it off faster than {v} m/s, else a step later)"
                ),
            },
            match m.wall_friction_reach {
                MpmWallFrictionReach::WallNode => "wall friction on the wall nodes",
                MpmWallFrictionReach::NextNode =>
                    "wall friction a wall node cannot take passed to the next node off the wall",
            },
            match m.wall_tangent_update {
                MpmWallTangentUpdate::Grid => "points on a frictional wall take the grid's velocity along it",
                MpmWallTangentUpdate::Blend => "points on a frictional wall update along it as elsewhere",
            },
            match m.liquid_wall_shear {
                MpmLiquidWallShear::LaminarFilm =>
                    "the liquid slipping along a wall feels a laminar film's shear 3 mu U / d (Nusselt), d over the part of a line the liquid covers",
                MpmLiquidWallShear::LaminarFilmLineMass =>
                    "the liquid slipping along a wall feels a laminar film's shear 3 mu U / d (Nusselt), d over the whole line (session 45's reading)",
                MpmLiquidWallShear::None => "the liquid slips freely along the walls",
            },
            m.damping,
            m.top_load
        ),
    );
    match m.transfer {
        MpmTransfer::Aflip => {
            let [solid, liquid] = m.flip_shares_per_step();
            let basis = m.flip_share_basis.kept_over();
            p.line("transfer", format!("AFLIP: APIC (affine part B D^-1 per point) with {} of the FLIP update blended in for the solid, {} for the liquid ({basis}: {solid:.4} and {liquid:.4} a step at courant {}), MUSL; pic_fraction and xpic_order unused",
                m.flip_share_in_effect(),
                m.liquid_flip_share_in_effect(),
                m.courant
            ))
        }
        MpmTransfer::Apic => {
            p.line("transfer", "APIC (affine part B D^-1 per point, no filter), MUSL; pic_fraction and xpic_order unused")
        }
        MpmTransfer::Flip => p.line("transfer", format!("FLIP less {} of the grid-invisible velocity per step ({}), MUSL (pure FLIP, 0, never lets a deposit rest; docs/mpm.md)",
            m.pic_fraction,
            if m.xpic_order >= 2 { "XPIC(2)" } else { "PIC blend" }
        )),
    }
}

/// A length with at most 6 decimals and no trailing zeros (1/300 m → 0.003333).
fn short(x: f64) -> String {
    let t = format!("{x:.6}");
    let t = t.trim_end_matches('0').trim_end_matches('.');
    if t.is_empty() || t == "-" || (t == "0" && x != 0.0) {
        format!("{x:e}")
    } else {
        t.to_string()
    }
}
