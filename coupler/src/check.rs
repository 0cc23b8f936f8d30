//! `coupler check`: what a run of the scene will be, without running it.

use mpm_proc::plan::{self as mpm, SceneMpm};
use schemas::scene::{Face, InitialStress, MpmFloor, MpmPressureReconstruction, MpmTransfer, PackingSpec, Scene};
use schemas::Method;

use dem_proc::packing::{cache_path, generate};
use dem_proc::setup::DemSetup;

/// Particle-steps per second measured on the dry H0 = 0.06 m column, 2 cores
/// (docs/BENCHMARKS.md); only used to print a rough duration.
const MEASURED_DEM_RATE: f64 = 8.0e6;

pub fn print(scene: &Scene) {
    let s = &scene.spec;
    let method = scene.method();
    println!("scene        {} — {}", s.scene.name, s.scene.description);
    println!(
        "method       {} ({})",
        method.name(),
        match method {
            Method::DemDry => "dem_proc",
            Method::LbmFluid => "lbm_proc",
            Method::DemLbm => "dem_proc + lbm_proc, coupled over iceoryx2",
            Method::Mpm if s.particles.is_empty() || s.fluids.is_empty() =>
                "mpm_proc, one-phase MPM, 2D plane strain in x-z",
            Method::Mpm => "mpm_proc, two-phase double-point MPM, 2D plane strain in x-z",
        }
    );
    let d = &s.domain;
    println!(
        "domain       [{:.4}, {:.4}] x [{:.4}, {:.4}] x [{:.4}, {:.4}] m, gravity {:?} m/s², walls {}",
        d.min[0],
        d.max[0],
        d.min[1],
        d.max[1],
        d.min[2],
        d.max[2],
        d.gravity,
        d.walls.iter().map(|f| f.name()).collect::<Vec<_>>().join(" ")
    );
    for g in &s.gates {
        println!(
            "gate         {} at {:?}, normal {:?}, removed at t = {} s",
            g.name, g.point, g.normal, g.release_time
        );
    }
    let t_ref = scene.reference_time();
    println!(
        "t_ref        {:.4} s ({:?}); end time {} s = {:.2} t_ref; frames every {} s",
        t_ref,
        s.analysis.condition,
        s.output.end_time,
        s.output.end_time / t_ref,
        s.output.record_interval
    );
    let mut warnings = Vec::new();

    if method == Method::Mpm {
        print_mpm(scene, &mut warnings);
    } else {
        print_dem_lbm(scene, &mut warnings);
    }
    if warnings.is_empty() {
        println!("warnings     none");
    }
    for w in warnings {
        println!("warning      {w}");
    }
}

/// The DEM, the LBM or both, from the scene's blocks.
fn print_dem_lbm(scene: &Scene, warnings: &mut Vec<String>) {
    let s = &scene.spec;
    let method = scene.method();
    if !s.particles.is_empty() {
        let setup = DemSetup::from_scene(scene);
        let (grains, _) = generate(scene);
        let n = grains.len();
        println!("grains       {n} generated ({} blocks)", s.particles.len());
        let law = &setup.grain_law;
        println!(
            "contact      k_n {} N/m, k_t {} N/m, e {} -> damping ratio {:.5} (no-tension law), mu_s {}, mu_r {}",
            law.normal_stiffness,
            law.tangential_stiffness,
            scene.dem().restitution,
            law.damping_ratio,
            law.friction,
            law.rolling_friction
        );
        println!(
            "time step    {:.3e} s; contact duration {:.3e} s -> {:.1} steps per contact",
            setup.numerics.dt, setup.contact_duration, setup.steps_per_contact
        );
        let steps = (s.output.end_time / setup.numerics.dt).ceil();
        println!(
            "cost         up to {steps:.0} steps = {:.2e} particle-steps (~{:.0} s at {:.0e} particle-steps/s); memory ~{:.0} MB",
            steps * n as f64,
            steps * n as f64 / MEASURED_DEM_RATE,
            MEASURED_DEM_RATE,
            n as f64 * (7.0 * 24.0 + 16.0 + 10.0 * 110.0) / 1e6
        );
        if s.particles.iter().any(|b| matches!(b.packing, PackingSpec::Deposit { .. })) {
            let path = cache_path(scene);
            if s.deposition.cache && path.exists() {
                println!("packing      cached: {}", path.display());
            } else {
                println!(
                    "packing      gravity deposition at friction {} until grains are slower than {} m/s (cached as {})",
                    s.deposition.friction,
                    s.deposition.rest_speed,
                    path.display()
                );
            }
        }
        if setup.steps_per_contact < 20.0 {
            warnings.push(format!(
                "only {:.1} steps per contact: restitution and stability suffer below ~20; lower dem.time_step",
                setup.steps_per_contact
            ));
        }
        // Static overlap at the column base relative to the grain size.
        let rho = s.particles[0].density;
        let dmean = s.particles[0].diameter;
        let base_force = rho * 0.6 * scene.gravity_magnitude() * s.analysis.column_height * dmean * dmean;
        let overlap = base_force / law.normal_stiffness / dmean;
        println!("stiffness    base overlap ~{:.2} % of D under the column weight", overlap * 100.0);
        if overlap > 0.01 {
            warnings.push(format!(
                "grains at the base overlap ~{:.1} % of D: raise dem.normal_stiffness for the rigid limit",
                overlap * 100.0
            ));
        }
    }
    if !s.fluids.is_empty() {
        print_lbm(scene, warnings);
    }
    if method == Method::DemLbm {
        let c = &s.coupling;
        let n = generate(scene).0.len();
        let exchanges = (s.output.end_time / scene.lbm().time_step).ceil();
        println!(
            "exchange     {} schedule, {} DEM steps per LBM step (DEM {:.3e} s, LBM {:.3e} s); {exchanges:.0} exchanges of {:.0} kB grain states + {:.0} kB loads",
            c.schedule.name(),
            c.ratio,
            scene.lbm().time_step / c.ratio as f64,
            scene.lbm().time_step,
            n as f64 * std::mem::size_of::<runtime::exchange::ParticleState>() as f64 / 1e3,
            n as f64 * std::mem::size_of::<runtime::exchange::HydroLoad>() as f64 / 1e3,
        );
        // The coupling resolves grains on the lattice: a few cells per diameter at least.
        let d_min = s.particles.iter().map(|b| b.diameter * (1.0 - b.diameter_spread)).fold(f64::INFINITY, f64::min);
        let cells = d_min / scene.lbm().spacing;
        println!("resolution   smallest grain diameter {cells:.2} lattice cells");
        // The gain of a half-covered cell tells whether the pore liquid can move past the grains.
        let fluid = &s.fluids[0];
        let tau0 = lbm_proc::Units::new(scene.lbm().spacing, scene.lbm().time_step, fluid.density)
            .and_then(|u| u.tau_from_viscosity(fluid.viscosity / fluid.density))
            .unwrap_or(f64::NAN);
        // The lattice's hydrostatic density varies by 3 g H Δt²/Δx² over a liquid H tall.
        let lbm = scene.lbm();
        let height = s.fluids.iter().map(|f| f.region.max[2] - f.region.min[2]).fold(0.0, f64::max);
        let head = 3.0 * scene.gravity_magnitude() * height * lbm.time_step.powi(2) / lbm.spacing.powi(2);
        match lbm.hydrostatics {
            schemas::scene::Hydrostatics::Lattice => {
                println!(
                    "hydrostatics lattice: the liquid's density varies by {:.2} % over its {height} m (3 g H dt^2/dx^2)",
                    100.0 * head
                );
                if head > 0.05 {
                    warnings.push(format!(
                        "the lattice's hydrostatic density varies by {:.0} % over the liquid's height: the liquid is that much compressed at depth, with its buoyancy and viscosity (docs/coupling.md \"Submerged scenes\"); use lbm.hydrostatics = \"buoyancy\" (liquid filling a closed box) or a smaller lbm.time_step",
                        100.0 * head
                    ));
                }
            }
            schemas::scene::Hydrostatics::Buoyancy => {
                println!("hydrostatics buoyancy: the liquid feels no gravity; each grain's load gets -rho_L V g")
            }
        }
        let half = lbm_proc::fluid::forcing_gain(c.forcing_gain, 0.5, tau0);
        println!(
            "forcing      {} gain: a half-covered cell is pulled {half:.3} of the way to the grain per step (tau0 = {tau0:.6})",
            c.forcing_gain.name()
        );
        use schemas::scene::ForcingGain;
        match c.forcing_gain {
            ForcingGain::CoveredFraction | ForcingGain::CentreInside if tau0 < 0.55 => warnings.push(format!(
                "coupling.forcing_gain = \"{}\" at tau0 = {tau0:.4}: the grains' surface cells hold the pore liquid far more than its viscosity would (packed-bed permeability 0.007-0.14x Kozeny-Carman at tau0 -> 1/2, docs/coupling.md \"Choosing the forcing gain\"); use \"noble_torczynski\"",
                c.forcing_gain.name()
            )),
            ForcingGain::NobleTorczynski | ForcingGain::NobleTorczynskiEffective if tau0 >= 0.55 => warnings.push(format!(
                "coupling.forcing_gain = \"{}\" at tau0 = {tau0:.4}: in a viscous liquid its partly covered cells pull too little (array drag 9-48 % low at tau 0.6-1, D/dx 4-8, docs/coupling.md \"Choosing the forcing gain\"); \"centre_inside\" (tau ~0.6) or \"covered_fraction\" (tau ~1) is closer",
                c.forcing_gain.name()
            )),
            _ => {}
        }
        if cells < 3.0 {
            warnings.push(format!(
                "grains span only {cells:.1} cells: the direct forcing needs ~4 or more for drag within ~10 % (docs/coupling.md); lower lbm.spacing"
            ));
        }
    }
}

/// Rough bytes per material point (position, velocity, mass, volume,
/// stresses, strains, porosity, flags, and its GIMP weights and gradients on
/// 9 nodes) and per grid node and phase (mass, momentum, force, velocity,
/// drag, density fields); only used to print a memory figure.
const MPM_BYTES_PER_POINT: f64 = 500.0;
const MPM_BYTES_PER_NODE_PHASE: f64 = 200.0;

/// The MPM: grid, points, waves and Δt, soil model, drag, gravity phase.
/// Computed from the scene by `mpm_proc::plan`, the closed forms the solver itself uses.
fn print_mpm(scene: &Scene, warnings: &mut Vec<String>) {
    let m = scene.mpm();
    let grid = scene.mpm_grid();
    let h = grid.element_size;
    let ppe = m.points_per_element as usize;
    let (a, b) = m.point_grid();
    println!(
        "grid         {} x {} = {} elements (x, z) of {} m, {} nodes; {} shape functions; {ppe} points per phase per filled element ({a} x {b})",
        grid.nx,
        grid.nz,
        grid.elements(),
        short(h),
        grid.nodes(),
        m.shape_functions.name()
    );
    let points = print_mpm_points(scene, ppe);
    let ts = scene.mpm_time_step();
    print_mpm_waves_and_cost(scene, &ts, points);
    print_mpm_materials(scene, &ts, warnings);
    mpm_numerics_warnings(scene, ppe, warnings);
    print_mpm_boundaries(scene);
}

/// The soil's and the liquid's filled elements and points; returns the points of both phases.
fn print_mpm_points(scene: &Scene, ppe: usize) -> usize {
    let s = &scene.spec;
    let grid = scene.mpm_grid();
    // Filled elements: the soil's and the liquid's regions in whole elements.
    let area = |r: &schemas::scene::BoxSpec| -> ((usize, usize), (usize, usize)) {
        (grid.span(0, r.min[0], r.max[0]), grid.span(2, r.min[2], r.max[2]))
    };
    let count = |((x0, x1), (z0, z1)): ((usize, usize), (usize, usize))| (x1 - x0) * (z1 - z0);
    let soil_area = s.particles.first().and_then(|p| match &p.packing {
        PackingSpec::Deposit { region, .. } => Some(area(region)),
        PackingSpec::Explicit { .. } => None,
    });
    let liquid_area = s.fluids.first().map(|f| area(&f.region));
    let soil_elements = soil_area.map(count).unwrap_or(0);
    let liquid_elements = liquid_area.map(count).unwrap_or(0);
    let overlap = match (soil_area, liquid_area) {
        (Some(((sx0, sx1), (sz0, sz1))), Some(((lx0, lx1), (lz0, lz1)))) => {
            sx1.min(lx1).saturating_sub(sx0.max(lx0)) * sz1.min(lz1).saturating_sub(sz0.max(lz0))
        }
        _ => 0,
    };
    let soil_points = soil_elements * ppe;
    let liquid_points = liquid_elements * ppe;
    if let Some(soil) = s.particles.first() {
        println!(
            "soil         {}: {soil_elements} elements, {soil_points} solid points ({} saturated elements, {} dry)",
            soil.name,
            overlap,
            soil_elements - overlap
        );
    }
    if let Some(liquid) = s.fluids.first() {
        let free = liquid_elements - overlap;
        let split = if free == 0 {
            "all in the soil's elements".to_string()
        } else {
            format!("{} in the soil's elements, {} in {free} free-water elements", overlap * ppe, free * ppe)
        };
        println!("liquid       {}: {liquid_elements} elements, {liquid_points} liquid points ({split})", liquid.name);
    }
    soil_points + liquid_points
}

/// Wave speeds, the time step and the cost of the run.
fn print_mpm_waves_and_cost(scene: &Scene, ts: &mpm::MpmTimeStep, points: usize) {
    let (s, m) = (&scene.spec, scene.mpm());
    let grid = scene.mpm_grid();
    let h = grid.element_size;
    let speed = |c: Option<f64>| c.map(|c| format!("{c:.1} m/s")).unwrap_or_else(|| "–".into());
    println!(
        "waves        undrained P {}, liquid {}, dry P {}; fastest {:.1} m/s ({})",
        speed(ts.undrained),
        speed(ts.liquid),
        speed(ts.dry),
        ts.max_speed,
        ts.limiting.name()
    );
    println!(
        "time step    dt {:.3e} s = courant {} x {} m / {:.1} m/s ({} limits)",
        ts.dt,
        m.courant,
        short(h),
        ts.max_speed,
        ts.limiting.name()
    );
    let gravity_steps = match m.initial_stress {
        InitialStress::K0 => (m.gravity_phase_max_time / ts.dt).ceil(),
        InitialStress::Zero => 0.0,
    };
    println!(
        "cost         {} steps to the end time {} s, {:.2e} point-updates; gravity phase up to {gravity_steps:.0} steps more; memory ~{:.0} MB",
        ts.steps,
        s.output.end_time,
        ts.steps as f64 * points as f64,
        (points as f64 * MPM_BYTES_PER_POINT
            + grid.nodes() as f64 * 2.0 * MPM_BYTES_PER_NODE_PHASE)
            / 1e6
    );
}

/// The soil, liquid and drag models, with the warnings they call for.
fn print_mpm_materials(scene: &Scene, ts: &mpm::MpmTimeStep, warnings: &mut Vec<String>) {
    let (s, m) = (&scene.spec, scene.mpm());
    if !s.particles.is_empty() {
        let n0 = scene.mpm_porosity().unwrap_or(f64::NAN);
        println!(
            "soil model   E {:.3e} Pa, nu {}, E_oed {:.4e} Pa, K0 = nu/(1-nu) = {:.3}; Mohr-Coulomb phi {} deg (K_a {:.3}), c {} Pa, psi {} deg; n0 {}, n_max {}",
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
        );
        if n0 >= m.max_porosity {
            warnings.push(format!(
                "n0 = {n0} is not below mpm.max_porosity = {}: the soil starts fluidised (no effective stress)",
                m.max_porosity
            ));
        }
        if mpm::at_rest_coefficient(m.poisson_ratio) < mpm::active_coefficient(m.friction_angle) {
            warnings.push(format!(
                "K0 = {:.3} is below K_a = {:.3}: the K0 initial stresses violate Mohr-Coulomb before the gate opens; raise mpm.poisson_ratio",
                mpm::at_rest_coefficient(m.poisson_ratio),
                mpm::active_coefficient(m.friction_angle)
            ));
        }
    }
    if let Some(liquid) = s.fluids.first() {
        println!(
            "liquid model K_L {:.3e} Pa, rho_L {} kg/m³, mu {:e} Pa s; tension up to {} Pa; free surface below fill {} (point or element); {}",
            m.liquid_bulk_modulus,
            liquid.density,
            liquid.viscosity,
            m.cavitation_threshold,
            m.free_surface_fill,
            match m.pressure_reconstruction {
                MpmPressureReconstruction::Linear => "pore pressure a least-squares plane per element",
                MpmPressureReconstruction::None => "pore pressure per point",
            }
        );
    }
    if let Some(drag) = scene.mpm_drag() {
        let n0 = scene.mpm_porosity().unwrap_or(f64::NAN);
        println!(
            "drag         Ergun A {}, B {}, D {} m: kappa(n0) {:.3e} m² (Eq. 9), hydraulic conductivity {:.3e} m/s; quadratic term {}",
            m.ergun_a,
            m.ergun_b,
            s.particles[0].diameter,
            drag.permeability,
            drag.conductivity,
            if m.quadratic_drag { "on" } else { "off" }
        );
        println!(
            "reynolds     Re_p = D rho_L sqrt(g H0)/mu = {:.3e} (Eq. 12, sqrt(g H0) = {:.3} m/s)",
            drag.reynolds, drag.reference_velocity
        );
        println!("drag step    dt mu n0²/kappa (1/((1-n0) rho_s) + 1/(n0 rho_L)) = {:.3e} (n0 = {n0})", drag.stiffness);
        if drag.reynolds > 4e4 && !m.quadratic_drag {
            warnings.push(format!(
                "Re_p = {:.2e} with mpm.quadratic_drag = false: the paper finds the quadratic term matters above ~4e4",
                drag.reynolds
            ));
        }
        if drag.stiffness > 1.0 {
            warnings.push(format!(
                "drag stiffness dt mu n0²/kappa (...) = {:.2} > 1: an explicit drag would be unstable; mpm_proc integrates it implicitly per node, so this is handled, but the phases are locked together within a step",
                drag.stiffness
            ));
        }
    }
}

/// Warnings on the numerics: points per element, unused keys, the Courant number.
fn mpm_numerics_warnings(scene: &Scene, ppe: usize, warnings: &mut Vec<String>) {
    let (s, m) = (&scene.spec, scene.mpm());
    if !s.particles.is_empty() && !s.fluids.is_empty() && ppe < 4 {
        warnings.push(format!(
            "{ppe} points per element with two phases: the paper saw instabilities with 3 points per element (12 work; here 3 ran the saturated lab column stably, its runout 4 % from 12's, docs/mpm.md); raise mpm.points_per_element"
        ));
    }
    if let Some(unused) = schemas::scene::unused_flip_keys(&m) {
        warnings.push(unused);
    }
    if m.transfer.is_affine() && m.courant > 0.7 {
        warnings.push(format!(
            "mpm.courant = {} under an affine transfer (APIC, AFLIP): an elastic block held at 0.75 and blew up at 0.8 (docs/mpm.md, \"Time step\"); soil that yields may survive it, stiff or cohesive parts may not; use 0.7 or less",
            m.courant
        ));
    }
}

/// The gravity phase, the boundaries and the transfer.
fn print_mpm_boundaries(scene: &Scene) {
    let (s, m) = (&scene.spec, scene.mpm());
    match m.initial_stress {
        InitialStress::K0 => println!(
            "gravity      K0 stresses{}, then a gravity phase with the gates held: damping {}, until the fastest point is slower than {} m/s or {} s",
            if s.fluids.is_empty() { "" } else { " and hydrostatic pore pressure" },
            m.gravity_phase_damping,
            m.gravity_phase_rest_speed,
            m.gravity_phase_max_time
        ),
        InitialStress::Zero => println!("gravity      stress-free start, gravity applied at t = 0 (no gravity phase)"),
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
    println!(
        "boundaries   {fixed}; {side} on {}; y faces unused; local damping {}; top load {} Pa",
        if rollers.is_empty() { "none".to_string() } else { rollers.join(" ") },
        m.damping,
        m.top_load
    );
    match m.transfer {
        MpmTransfer::Aflip => println!(
            "transfer     AFLIP: APIC (affine part B D^-1 per point) with {} of the FLIP update blended in for the solid, {} for the liquid, MUSL; pic_fraction and xpic_order unused",
            m.flip_share_in_effect(),
            m.liquid_flip_share_in_effect()
        ),
        MpmTransfer::Apic => {
            println!("transfer     APIC (affine part B D^-1 per point, no filter), MUSL; pic_fraction and xpic_order unused")
        }
        MpmTransfer::Flip => println!(
            "transfer     FLIP less {} of the grid-invisible velocity per step ({}), MUSL (pure FLIP, 0, never lets a deposit rest; docs/mpm.md)",
            m.pic_fraction,
            if m.xpic_order >= 2 { "XPIC(2)" } else { "PIC blend" }
        ),
    }
}

/// Lattice updates per second of the LBM on this machine, 2 threads
/// (docs/BENCHMARKS.md); only used to print a rough duration.
const MEASURED_LBM_RATE: f64 = 4.0e7;

fn print_lbm(scene: &Scene, warnings: &mut Vec<String>) {
    let s = &scene.spec;
    let lbm = scene.lbm();
    let fluid = &s.fluids[0];
    let (dx, dt) = (lbm.spacing, lbm.time_step);
    let nu = fluid.viscosity / fluid.density;
    let Ok(units) = lbm_proc::Units::new(dx, dt, fluid.density) else {
        warnings.push("lattice units cannot be built from lbm.spacing and lbm.time_step".into());
        return;
    };
    let tau = units.tau_from_viscosity(nu).unwrap_or(f64::NAN);
    let nu_l = units.viscosity_to_lattice(nu);
    let cells = |lo: f64, hi: f64| ((hi - lo) / dx).round().max(1.0);
    let d = &s.domain;
    let dims = [0, 1, 2].map(|a| cells(d.min[a], d.max[a]));
    let ncells = dims[0] * dims[1] * dims[2];
    let liquid: f64 =
        s.fluids.iter().map(|f| (0..3).map(|a| cells(f.region.min[a], f.region.max[a])).product::<f64>()).sum();
    println!(
        "lattice      {} x {} x {} = {:.3e} cells of {:.3e} m, time step {:.3e} s; liquid {:.3e} cells at the start",
        dims[0], dims[1], dims[2], ncells, dx, dt, liquid
    );
    println!(
        "relaxation   tau0 = {tau:.6} (nu = {nu:.3e} m²/s = {nu_l:.3e} lattice), {:?}, Smagorinsky C = {}",
        lbm.collision, lbm.smagorinsky
    );
    // Eq. 4: nu_t = (C dx)^2 |S|, at the collapse's own shear rate sqrt(g/H0) and at 100 1/s.
    let g = scene.gravity_magnitude();
    let h0 = s.analysis.column_height;
    for shear in [(g / h0).sqrt(), 100.0] {
        let nu_t = (lbm.smagorinsky * dx).powi(2) * shear;
        println!(
            "viscosity    at shear {shear:.1} 1/s: nu = {nu:.3e} molecular + {nu_t:.3e} eddy = {:.3e} m²/s = {:.3e} lattice (tau {:.6})",
            nu + nu_t,
            units.viscosity_to_lattice(nu + nu_t),
            units.tau_from_viscosity(nu + nu_t).unwrap_or(f64::NAN)
        );
    }
    let cs = (1.0_f64 / 3.0).sqrt();
    let wave = (g * h0).sqrt();
    for (what, speed) in [("sqrt(g H0)", wave), ("2 sqrt(g H0) (dam-break front)", 2.0 * wave)] {
        let mach = units.velocity_to_lattice(speed) / cs;
        println!("mach         {what} = {speed:.3} m/s -> Mach {mach:.3} in lattice units");
        if mach > lbm.mach_limit {
            warnings.push(format!(
                "{what} gives Mach {mach:.2}, above lbm.mach_limit = {}: the watchdog may stop the run; lower lbm.time_step",
                lbm.mach_limit
            ));
        } else if mach > 0.3 {
            warnings.push(format!(
                "{what} gives Mach {mach:.2}: compressibility errors grow above ~0.3; lower lbm.time_step for accuracy"
            ));
        }
    }
    if tau < 0.51 && lbm.smagorinsky == 0.0 {
        warnings.push(format!(
            "tau0 = {tau:.5} with no eddy viscosity: BGK is at the edge of stability; set lbm.smagorinsky (0.16)"
        ));
    }
    // Two f32 lattices, flags, f64 mass and fill per cell.
    let bytes_per_cell = 19.0 * 4.0 * 2.0 + 1.0 + 16.0;
    let steps = (s.output.end_time / dt).ceil();
    println!(
        "cost         {steps:.0} steps; memory ~{:.0} MB; ~{:.0} s at {:.0e} lattice updates/s if the liquid stays at its initial volume",
        ncells * bytes_per_cell / 1e6,
        steps * liquid / MEASURED_LBM_RATE,
        MEASURED_LBM_RATE
    );
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
