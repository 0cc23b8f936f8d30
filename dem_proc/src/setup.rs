//! From a checked [`Scene`] to the solver's laws, walls and time step.

use crate::contact::{contact_duration, effective_mass, min_restitution_no_tension};
use schemas::scene::{Face, Scene};
use schemas::Method;
use schemas::SceneError;

use crate::law::{damping_ratio_for, ContactLaw};
use crate::world::{Numerics, Wall};

/// Everything the DEM derives from a scene before it has grains.
#[derive(Debug, Clone)]
pub struct DemSetup {
    pub grain_law: ContactLaw,
    pub wall_law: ContactLaw,
    pub numerics: Numerics,
    /// Grain–grain contact duration of the lightest pair, s (no-tension criterion).
    pub contact_duration: f64,
    pub steps_per_contact: f64,
    pub domain: ([f64; 3], [f64; 3]),
    /// Gravity of the run, m/s²: `domain.collapse_gravity` where the scene
    /// sets it, else `domain.gravity` (the deposition's, see
    /// [`DemSetup::for_deposition`]).
    pub gravity: [f64; 3],
    pub max_diameter: f64,
}

/// What the DEM refuses in a scene that the vocabulary's checks let pass:
/// a scene with no grains, one that selects the MPM, and a restitution below
/// what a spring–dashpot that never pulls can reach (its rebound at
/// critical damping, [`min_restitution_no_tension`]). `dem_proc` and
/// `coupler` both call it, so the two refuse with the same words.
pub fn check_scene(scene: &Scene) -> Result<(), SceneError> {
    if scene.method() == Method::Mpm {
        return Err(SceneError::new(
            "scene.method",
            "the scene selects the MPM (scene.method = \"mpm\"): run it with `coupler run` or mpm_proc",
        ));
    }
    if scene.spec.particles.is_empty() {
        return Err(SceneError::new(
            "particles",
            "the scene has no [[particles]] blocks; nothing for the DEM to do (fluid-only scenes run in lbm_proc)",
        ));
    }
    let e = scene.spec.dem.as_ref().map_or(1.0, |d| d.restitution);
    let e_min = min_restitution_no_tension();
    if e > 0.0 && e < e_min {
        return Err(SceneError::new(
            "dem.restitution",
            format!(
                "a linear spring-dashpot that never pulls cannot rebound slower than e = {e_min:.3} (at critical damping), got {e}"
            ),
        ));
    }
    Ok(())
}

/// Mass of the lightest grain any block can produce, kg.
fn lightest_grain(scene: &Scene) -> f64 {
    let mut m = f64::INFINITY;
    for (b, block) in scene.spec.particles.iter().enumerate() {
        let mut d_min = block.diameter * (1.0 - block.diameter_spread);
        for s in &scene.explicit_spheres[b] {
            d_min = d_min.min(s[3]);
        }
        m = m.min(block.density * std::f64::consts::PI / 6.0 * d_min.powi(3));
    }
    m
}

fn largest_diameter(scene: &Scene) -> f64 {
    let mut d = 0.0_f64;
    for (b, block) in scene.spec.particles.iter().enumerate() {
        d = d.max(block.diameter * (1.0 + block.diameter_spread));
        for s in &scene.explicit_spheres[b] {
            d = d.max(s[3]);
        }
    }
    d
}

impl DemSetup {
    pub fn from_scene(scene: &Scene) -> Self {
        let dem = scene.dem();
        let zeta = damping_ratio_for(dem.restitution);
        let kn = dem.normal_stiffness;
        let grain_law = ContactLaw {
            normal_stiffness: kn,
            tangential_stiffness: dem.tangential_stiffness_ratio * kn,
            damping_ratio: zeta,
            friction: dem.friction,
            rolling_friction: dem.rolling_friction,
        };
        let wall_law = ContactLaw {
            friction: dem.wall_friction.unwrap_or(dem.friction),
            rolling_friction: dem.wall_rolling_friction.unwrap_or(dem.rolling_friction),
            ..grain_law
        };
        let m = lightest_grain(scene);
        let tc = contact_duration(kn, effective_mass(m, m), zeta);
        // A coupled run steps the DEM `ratio` times per LBM step (checked at load).
        let dt = match scene.method() {
            Method::DemLbm => scene.lbm().time_step / scene.spec.coupling.ratio as f64,
            _ => dem.time_step.unwrap_or(tc / dem.steps_per_contact),
        };
        let max_diameter = largest_diameter(scene);
        DemSetup {
            grain_law,
            wall_law,
            numerics: Numerics { dt, skin: dem.neighbour_skin * max_diameter, sort_interval: dem.sort_interval },
            contact_duration: tc,
            steps_per_contact: tc / dt,
            domain: (scene.spec.domain.min, scene.spec.domain.max),
            gravity: scene.run_gravity(),
            max_diameter,
        }
    }

    /// The same setup with the deposition's friction (denser packings) and
    /// `domain.gravity` (grains settle under it whatever the run's gravity).
    pub fn for_deposition(&self, scene: &Scene) -> Self {
        let dep = &scene.spec.deposition;
        let mut s = self.clone();
        s.gravity = scene.spec.domain.gravity;
        // Deposition is dry even in a coupled scene: its step needs no LBM alignment.
        let dem = scene.dem();
        s.numerics.dt = dem.time_step.unwrap_or(s.contact_duration / dem.steps_per_contact);
        for law in [&mut s.grain_law, &mut s.wall_law] {
            law.friction = dep.friction;
            law.rolling_friction = dep.rolling_friction;
        }
        s
    }
}

/// Box walls, then gates (in scene order). With `gates_closed`, gates never release.
pub fn walls(scene: &Scene, gates_closed: bool) -> Vec<Wall> {
    let d = &scene.spec.domain;
    let mut out = Vec::new();
    for face in Face::ALL {
        if !d.walls.contains(&face) {
            continue;
        }
        let (axis, sign) = face.axis_and_sign();
        let mut point = [0.0; 3];
        point[axis] = if sign > 0.0 { d.min[axis] } else { d.max[axis] };
        let mut normal = [0.0; 3];
        normal[axis] = sign;
        out.push(Wall::fixed(face.name(), point, normal, f64::INFINITY));
    }
    for (g, gate) in scene.spec.gates.iter().enumerate() {
        let release_time = if gates_closed { f64::INFINITY } else { gate.release_time };
        out.push(Wall::fixed(gate.name.clone(), gate.point, scene.gate_normals[g], release_time));
    }
    out
}
