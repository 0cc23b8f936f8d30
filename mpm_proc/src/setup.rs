//! A scene on the MPM grid: the x–z section of the box, the soil and
//! liquid points seeded in their blocks, fixities from the walls and
//! gates, and the initial stresses (docs/mpm.md, "Gravity phase and
//! initial stresses").

use crate::plan::SceneMpm;
use schemas::scene::{Face, InitialStress, MpmFloor, MpmLiquidWallShear, MpmSpec, PackingSpec, Scene};

use crate::drag::DragLaw;
use crate::grid::{Grid, GHOST};
use crate::mohr_coulomb::{InertialFriction, MohrCoulomb};
use crate::solver::{FilmDepth, Fixities, LiquidPoints, Mpm, MpmState, Params, PointSet, SolidPoints, WallComponent};

#[derive(Debug, thiserror::Error)]
pub enum SetupError {
    #[error("the scene is not an MPM scene: {0}")]
    NotMpm(String),
}

/// The solver and what the run needs to know about the scene.
#[derive(Debug)]
pub struct MpmSetup {
    pub mpm: Mpm,
    /// Gate names and release times, scene order.
    pub gates: Vec<(String, f64)>,
    /// Initial porosity n0 of the soil (NaN without soil).
    pub porosity_initial: f64,
    /// Top of the soil block, m (NaN without soil).
    pub soil_top: f64,
    /// Lines for the log.
    pub notes: Vec<String>,
}

pub fn build(scene: &Scene) -> Result<MpmSetup, SetupError> {
    let spec = scene.mpm();
    let s = &scene.spec;
    let d = &s.domain;
    // The grid `coupler check` reports (validation ensures at least 2 elements per axis).
    let g = scene.mpm_grid();
    let (h, elements) = (g.element_size, [g.nx, g.nz]);
    let grid = Grid { origin: g.origin, h, elements, shape: spec.shape_functions };
    let soil = s.particles.first();
    let liquid = s.fluids.first();
    let (rho_s, grain, n0, soil_region) = match soil {
        Some(p) => match &p.packing {
            PackingSpec::Deposit { region, porosity: Some(n), .. } => (p.density, p.diameter, *n, Some(*region)),
            _ => {
                return Err(SetupError::NotMpm(
                    "the soil block needs packing.method = \"deposit\" with `porosity`".into(),
                ))
            }
        },
        None => (f64::NAN, f64::NAN, f64::NAN, None),
    };
    let (rho_l, mu, liquid_region) = match liquid {
        Some(f) => (f.density, f.viscosity, Some(f.region)),
        None => (1000.0, 1e-3, None),
    };
    let step = scene.mpm_time_step();
    let (dt, c_max) = (step.dt, step.max_speed);
    // The run's gravity; the gravity phase holds the column under `d.gravity`
    // (`run::gravity_phase`).
    let run_gravity = scene.run_gravity();
    let gravity = [run_gravity[0], run_gravity[2]];
    let g_down = -d.gravity[2];
    let skeleton = MohrCoulomb::new(
        spec.young_modulus,
        spec.poisson_ratio,
        spec.friction_angle,
        spec.cohesion,
        spec.dilatancy_angle,
    );
    let mut params = Params {
        dt,
        gravity,
        solid_density: rho_s,
        liquid_density: rho_l,
        viscosity: mu,
        bulk_modulus: spec.liquid_bulk_modulus,
        cavitation: spec.cavitation_threshold,
        air_pressure: spec.air_pressure,
        max_porosity: spec.max_porosity,
        dilatancy_cutoff_porosity: spec.dilatancy_cutoff_porosity.unwrap_or(f64::INFINITY),
        damping: spec.damping,
        wall_friction: spec.wall_friction,
        unilateral_walls: spec.wall_contact == schemas::scene::MpmWallContact::Unilateral,
        wall_release_speed: spec.wall_release_speed,
        friction_reaches_next_node: spec.wall_friction_reach == schemas::scene::MpmWallFrictionReach::NextNode,
        wall_points_take_grid_tangent: spec.wall_tangent_update == schemas::scene::MpmWallTangentUpdate::Grid,
        liquid_film_shear: match spec.liquid_wall_shear {
            MpmLiquidWallShear::LaminarFilm => Some(FilmDepth::Covered),
            MpmLiquidWallShear::LaminarFilmLineMass => Some(FilmDepth::LineMass),
            MpmLiquidWallShear::None => None,
        },
        free_surface_fill: spec.free_surface_fill,
        hydrostatic_surface: spec.surface_elements_in_effect() == schemas::scene::MpmSurfaceElements::Hydrostatic,
        pic_fraction: spec.pic_fraction,
        xpic_order: spec.xpic_order,
        apic: spec.transfer.is_affine(),
        linear_pressure: spec.pressure_reconstruction == schemas::scene::MpmPressureReconstruction::Linear,
        implicit_pressure: spec.pressure_scheme == schemas::scene::MpmPressureScheme::Implicit,
        flip_share: spec.flip_shares_per_step(),
        soil: skeleton,
        critical_soil: skeleton.without_dilatancy(),
        inertial_friction: inertial_friction(&spec, grain, rho_s),
        drag: DragLaw {
            grain_diameter: if grain.is_finite() { grain } else { 1e-3 },
            ergun_a: spec.ergun_a,
            ergun_b: spec.ergun_b,
            viscosity: mu,
            liquid_density: rho_l,
            quadratic: spec.quadratic_drag,
        },
    };

    let seeds = Seeds { n0, rho_s, rho_l, g_down, soil_region, liquid_region };
    let (solid, liq, soil_top) = seed_points(&grid, &spec, &seeds);
    // Without liquid there is no pressure to solve: the implicit stages
    // would assemble an empty system every step (~5 % of a dry run) and
    // give the explicit path's numbers bit for bit (state_hashes).
    params.implicit_pressure &= !liq.set.is_empty();
    let [row, _] = grid.node_dims();
    let (base, contact, walls) = fixities(&grid, &d.walls, &spec);
    let mut gates = Vec::new();
    let mut gate_nodes = Vec::new();
    for gate in &s.gates {
        let column = ((gate.point[0] - grid.origin[0]) / h).round() as usize + GHOST;
        // The ghost rows too: behind a floor they hold what it holds, which
        // leaves x free, and the gate holds x there as above it.
        gate_nodes.push((GHOST - 1..GHOST + elements[1] + 2).map(|r| r * row + column).collect());
        gates.push((gate.name.clone(), gate.release_time));
    }
    let gates_held = vec![true; s.gates.len()];
    // Mpm::new (apply_gate_fixities) sizes walls_released and wall_push.
    let state = MpmState {
        time: 0.0,
        steps: 0,
        gates_held,
        walls_released: Vec::new(),
        wall_push: Vec::new(),
        solid,
        liquid: liq,
    };
    let mut notes = describe(&spec, &grid, &state, dt, c_max);
    if soil.is_some() && liquid.is_some() {
        notes.push(format!(
            "soil: n0 = {n0}, D = {grain} m, permeability {:.3e} m^2 (hydraulic conductivity {:.3e} m/s), quadratic drag {}",
            params.drag.permeability(n0),
            params.drag.hydraulic_conductivity(n0, g_down.abs()),
            if spec.quadratic_drag { "on" } else { "off" }
        ));
    }
    let mpm = Mpm::new(params, grid, state, Fixities { base, gates: gate_nodes, contact, walls });
    Ok(MpmSetup { mpm, gates, porosity_initial: n0, soil_top, notes })
}

/// The scene's rate-dependent friction (`mpm.limit_friction_angle`) for
/// grains of diameter `grain_diameter` (m) and density `grain_density`
/// (kg/m³); None when it is off.
pub fn inertial_friction(spec: &MpmSpec, grain_diameter: f64, grain_density: f64) -> Option<InertialFriction> {
    spec.limit_friction_angle.map(|phi2| InertialFriction {
        sin_static: spec.friction_angle.to_radians().sin(),
        sin_limit: phi2.to_radians().sin(),
        reference_inertial_number: spec.reference_inertial_number_in_effect(),
        grain_diameter,
        grain_density,
    })
}

/// What seeding the points needs to know of the two materials.
#[derive(Clone, Copy)]
struct Seeds {
    /// Initial porosity of the soil (NaN without soil).
    n0: f64,
    /// Grain and liquid densities, kg/m³.
    rho_s: f64,
    rho_l: f64,
    /// −g_z, m/s².
    g_down: f64,
    soil_region: Option<schemas::scene::BoxSpec>,
    liquid_region: Option<schemas::scene::BoxSpec>,
}

/// The solid and liquid points, on the a × b lattice of
/// `mpm.points_per_element` per element, each where it lies in the soil or
/// the liquid block (the scene validation puts its x edges on grid lines
/// and its z edges on the lattice's rows: a block's top or bottom may lie
/// inside an element, which then holds only the rows inside the block),
/// with the K0 stresses and
/// hydrostatic pore pressures of `mpm.initial_stress = "k0"`; and the top
/// of the soil, m (NaN without soil).
fn seed_points(grid: &Grid, spec: &schemas::scene::MpmSpec, seeds: &Seeds) -> (SolidPoints, LiquidPoints, f64) {
    let Seeds { n0, rho_s, rho_l, g_down, soil_region, liquid_region } = *seeds;
    let (h, elements) = (grid.h, grid.elements);
    let (a, b) = spec.point_grid();
    let v0 = h * h / (a * b) as f64;
    let half = [h / (2.0 * a as f64), h / (2.0 * b as f64)];
    let inside =
        |r: &schemas::scene::BoxSpec, x: f64, z: f64| x > r.min[0] && x < r.max[0] && z > r.min[2] && z < r.max[2];
    let soil_top = soil_region.map(|r| r.max[2]).unwrap_or(f64::NAN);
    let k0 = spec.poisson_ratio / (1.0 - spec.poisson_ratio);
    let with_k0 = spec.initial_stress == InitialStress::K0;

    let mut solid = SolidPoints { set: PointSet { half, ..Default::default() }, ..Default::default() };
    let mut liq = LiquidPoints { set: PointSet { half, ..Default::default() }, ..Default::default() };
    let top_row = soil_top - h / b as f64;
    for k in 0..elements[1] {
        for i in 0..elements[0] {
            for jz in 0..b {
                for jx in 0..a {
                    let x = [
                        grid.origin[0] + (i as f64 + (jx as f64 + 0.5) / a as f64) * h,
                        grid.origin[1] + (k as f64 + (jz as f64 + 0.5) / b as f64) * h,
                    ];
                    let in_soil = soil_region.is_some_and(|r| inside(&r, x[0], x[1]));
                    let in_liquid = liquid_region.is_some_and(|r| inside(&r, x[0], x[1]));
                    // Water above this point (in this column) when the liquid block covers it.
                    let water = liquid_region
                        .filter(|r| x[0] > r.min[0] && x[0] < r.max[0])
                        .map(|r| r.max[2])
                        .unwrap_or(f64::NEG_INFINITY);
                    if in_soil {
                        let buoyant = (water.min(soil_top) - x[1]).max(0.0);
                        let sv = if with_k0 {
                            -g_down * (1.0 - n0) * (rho_s * (soil_top - x[1]) - rho_l * buoyant)
                        } else {
                            0.0
                        };
                        solid.set.x.push(x);
                        solid.set.v.push([0.0; 2]);
                        solid.set.mass.push((1.0 - n0) * rho_s * v0);
                        solid.set.volume.push(v0);
                        solid.porosity.push(n0);
                        solid.stress.push([k0 * sv, sv, 0.0, k0 * sv]);
                        solid.fluidised.push(false);
                        let load = if x[1] > top_row { [0.0, -spec.top_load * h / a as f64] } else { [0.0; 2] };
                        solid.load.push(load);
                    }
                    if in_liquid {
                        let n = if in_soil { n0 } else { 1.0 };
                        let p = if with_k0 { rho_l * g_down * (water - x[1]).max(0.0) } else { 0.0 };
                        liq.set.x.push(x);
                        liq.set.v.push([0.0; 2]);
                        liq.set.mass.push(n * rho_l * v0);
                        liq.set.volume.push(v0);
                        liq.pressure.push(p);
                        liq.viscous.push([0.0; 4]);
                        liq.free_surface.push(false);
                    }
                }
            }
        }
    }

    (solid, liq, soil_top)
}

/// The nodes' fixities: a rough z_min wall fixed in both directions; the
/// other walls (and a frictional floor) hold the normal velocity, with
/// Coulomb friction on the solid where μ > 0; a ghost node behind a wall
/// holds what that wall holds, one behind an open face is fixed.
/// Returns the per-node free directions, the contact normals and the
/// components a wall holds along its normal only (those a unilateral
/// contact may release; corners and the ghost nodes behind the walls
/// included, a rough floor's nodes not).
fn fixities(
    grid: &Grid,
    walls: &[Face],
    spec: &schemas::scene::MpmSpec,
) -> (Vec<[f64; 2]>, Vec<[f64; 2]>, Vec<WallComponent>) {
    let elements = grid.elements;
    let [row, rows] = grid.node_dims();
    let mut base = vec![[1.0, 1.0]; row * rows];
    let mut contact = vec![[0.0, 0.0]; row * rows];
    let mut normal_only = Vec::new();
    let rough_floor = spec.floor == MpmFloor::Rough;
    for r in 0..rows {
        for c in 0..row {
            let node = &mut base[r * row + c];
            let (i, k) = (c as isize - GHOST as isize, r as isize - GHOST as isize);
            let (nx, nz) = (elements[0] as isize, elements[1] as isize);
            if i < 0 || k < 0 || i > nx || k > nz {
                *node = [0.0, 0.0];
                continue;
            }
            let into = &mut contact[r * row + c];
            let mut on_rough_floor = false;
            let first = normal_only.len();
            for face in walls {
                let held = |axis: usize, sign: f64| WallComponent { node: r * row + c, axis, into: sign };
                match face {
                    Face::XMin if i == 0 => {
                        (node[0], *into) = (0.0, [-1.0, 0.0]);
                        normal_only.push(held(0, -1.0));
                    }
                    Face::XMax if i == nx => {
                        (node[0], *into) = (0.0, [1.0, 0.0]);
                        normal_only.push(held(0, 1.0));
                    }
                    Face::ZMin if k == 0 && rough_floor => {
                        *node = [0.0, 0.0];
                        on_rough_floor = true;
                    }
                    Face::ZMin if k == 0 => {
                        (node[1], *into) = (0.0, [0.0, -1.0]);
                        normal_only.push(held(1, -1.0));
                    }
                    Face::ZMax if k == nz => {
                        (node[1], *into) = (0.0, [0.0, 1.0]);
                        normal_only.push(held(1, 1.0));
                    }
                    _ => {}
                }
            }
            if on_rough_floor {
                // No slip holds both components both ways.
                normal_only.truncate(first);
            }
            if node[0] == 0.0 && node[1] == 0.0 || spec.wall_friction == 0.0 {
                // A corner holds both directions: nothing left to slide;
                // without friction a wall is a plain roller.
                *into = [0.0, 0.0];
            }
        }
    }
    let mut ghosts = Vec::new();
    // A point within its half-width of a wall puts weight on the ghost node
    // behind it. Fixed both ways, that node stopped the point's velocity
    // along the wall every step: a frictionless floor took 6 % of a
    // sliding layer's momentum in 0.15 s through the ghost row under its
    // slumping front. A ghost node behind a wall holds what the wall holds.
    for r in 0..rows {
        for c in 0..row {
            let (i, k) = (c as isize - GHOST as isize, r as isize - GHOST as isize);
            let (nx, nz) = (elements[0] as isize, elements[1] as isize);
            let outside = [i < 0 || i > nx, k < 0 || k > nz];
            if outside == [false; 2] {
                continue;
            }
            let inside = (k.clamp(0, nz) as usize + GHOST) * row + i.clamp(0, nx) as usize + GHOST;
            let wall = base[inside];
            let behind_walls = (0..2).all(|a| !outside[a] || wall[a] == 0.0);
            if behind_walls {
                base[r * row + c] = wall;
                contact[r * row + c] = contact[inside];
                // Every normal-only component of the node in front (a
                // corner's two), so the ghost lets go when it does.
                for w in normal_only.iter().filter(|w| w.node == inside) {
                    ghosts.push(WallComponent { node: r * row + c, ..*w });
                }
            }
        }
    }
    normal_only.extend(ghosts);
    (base, contact, normal_only)
}

/// The log's first line: grid, shape functions, transfer, points, Δt.
fn describe(spec: &schemas::scene::MpmSpec, grid: &Grid, state: &MpmState, dt: f64, c_max: f64) -> Vec<String> {
    let (h, elements) = (grid.h, grid.elements);
    let (a, b) = spec.point_grid();
    let mut notes = vec![format!(
        "grid {} x {} elements of {h} m ({:?} shape functions; transfer {}); {} solid and {} liquid points ({a} x {b} per element); dt = {dt:.3e} s (c_max = {c_max:.1} m/s, courant {})",
        elements[0],
        elements[1],
        spec.shape_functions,
        match spec.transfer {
            schemas::scene::MpmTransfer::Aflip => {
                let [solid, liquid] = spec.flip_shares_per_step();
                let basis = spec.flip_share_basis.kept_over();
                format!(
                    "AFLIP, FLIP share {} solid, {} liquid {basis}: {solid:.4} and {liquid:.4} a step",
                    spec.flip_share_in_effect(),
                    spec.liquid_flip_share_in_effect()
                )
            }
            schemas::scene::MpmTransfer::Apic => "APIC".to_string(),
            schemas::scene::MpmTransfer::Flip => format!("FLIP, PIC share {} (order {})", spec.pic_fraction, spec.xpic_order),
        },
        state.solid.set.len(),
        state.liquid.set.len(),
        spec.courant
    )];
    notes.extend(schemas::scene::unused_flip_keys(spec));
    notes
}
