//! A plane-strain biaxial test of the DEM's grains: the element test that
//! measures the friction and dilatancy angles a continuum (the MPM's
//! Mohr–Coulomb soil) should carry for the same grains, without using any
//! column's runout.
//!
//! A box of grains between six frictionless walls, without gravity:
//! 1. **prepare**: grains start on a jittered lattice (spacing 1.2 D,
//!    seeded), and the x, y and z walls at the box's far side close in
//!    under stress control until every wall carries the confining stress
//!    and the grains are at rest. The grains' sliding friction meanwhile is
//!    the preparation friction (lower packs denser; default the scene's
//!    deposition friction), their rolling friction the contact law's.
//!    Isotropic compression packs looser than the column's gravity
//!    deposition at the same friction (core porosity 0.434 against 0.400
//!    at 0.3): the column's porosity takes 0.1 (docs/dem.md, "Element test");
//! 2. **hold**: the contact law's friction is restored and the sample held
//!    under the same control until at rest again;
//! 3. **shear**: the top wall moves down at a constant true axial strain
//!    rate, set by an inertial number I = ε̇ D / √(p/ρ) (quasi-static below
//!    ~1e-3, GDR MiDi 2004), the far x wall keeps σ_xx at the confining
//!    stress, and the y walls stay where they are: ε_yy = 0, the plane
//!    strain of the MPM's 2D soil.
//!
//! Stresses are the walls' elastic loads over their current areas, each axis
//! the mean of its two walls, averaged over the steps between two samples.
//! Strains are logarithmic, compression positive: ε_1 = ε_zz, ε_3 = ε_xx,
//! ε_v = ε_1 + ε_3, γ = ε_1 − ε_3. The mobilised angles are those of a
//! Mohr–Coulomb soil in plane strain:
//! sin φ = (σ_1 − σ_3)/(σ_1 + σ_3) and sin ψ = −dε_v/dγ (dilation positive).
//!
//! Pre: a scene with one particle block (diameter, spread, density) and a
//! `[dem]` contact law. Post: the record lists every sample and the angles
//! summarised in [`BiaxialSummary`].

use std::sync::atomic::{AtomicBool, Ordering};

use serde::{Deserialize, Serialize};

use schemas::scene::Scene;

use crate::law::ContactLaw;
use crate::rng::SplitMix64;
use crate::setup::DemSetup;
use crate::world::{Grains, Numerics, Wall, World};

/// The test's settings. Defaults: [`BiaxialSpec::default`].
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
pub struct BiaxialSpec {
    /// Grains along x, y and z on the starting lattice. Default 10 × 8 × 20
    /// (1600 grains, a sample about twice as tall as it is wide).
    pub lattice: [usize; 3],
    /// σ_3, the stress every wall carries before shear and the x walls
    /// during it, Pa. Default 300 Pa: the mean effective stress of the lab's
    /// saturated H0 = 0.06 m column at mid-height.
    pub confining_stress: f64,
    /// I = ε̇ D / √(σ_3/ρ_s), which sets the axial strain rate ε̇. Default 1e-3.
    pub inertial_number: f64,
    /// The axial strain ε_zz at which shear stops. Default 0.3.
    pub max_axial_strain: f64,
    /// Axial strain between two samples. Default 0.002.
    pub sample_strain: f64,
    /// Grain sliding friction μ_s while the sample is compressed (`None`:
    /// the scene's deposition friction; 0.1 gives the lab column's core
    /// porosity, 0.3 its deposition friction a looser sample).
    pub preparation_friction: Option<f64>,
    /// Seed of the lattice jitter. Default 1.
    pub seed: u64,
}

impl Default for BiaxialSpec {
    fn default() -> Self {
        BiaxialSpec {
            lattice: [10, 8, 20],
            confining_stress: 300.0,
            inertial_number: 1e-3,
            max_axial_strain: 0.3,
            sample_strain: 0.002,
            preparation_friction: None,
            seed: 1,
        }
    }
}

/// One sample of the shear phase.
#[derive(Debug, Clone, Copy, Serialize, Deserialize, PartialEq)]
pub struct BiaxialSample {
    /// ε_1 = ln(H_0/H), compression positive.
    pub axial_strain: f64,
    /// ε_3 = ln(L_0/L) along x (negative as the sample widens).
    pub lateral_strain: f64,
    /// ε_v = ε_1 + ε_3 (ε_yy = 0); negative when the sample dilates.
    pub volumetric_strain: f64,
    /// Mean stress on the x, y and z walls over the steps since the last sample, Pa.
    pub stress: [f64; 3],
    /// 1 − V_grains/V_box.
    pub porosity: f64,
    /// Mean grain–grain contacts per grain.
    pub coordination: f64,
    /// φ_mob = asin((σ_zz − σ_xx)/(σ_zz + σ_xx)), degrees.
    pub mobilised_friction_deg: f64,
}

/// What the test measured.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
pub struct BiaxialSummary {
    pub grains: usize,
    /// Porosity and coordination at the end of the hold, before shear; the
    /// core's porosity leaves out the grains within one diameter of a wall.
    pub initial_porosity: f64,
    pub initial_core_porosity: f64,
    pub initial_coordination: f64,
    /// Largest mobilised friction angle (over [`SMOOTHING`] samples), degrees,
    /// and the axial strain where it is reached.
    pub peak_friction_deg: f64,
    pub peak_axial_strain: f64,
    /// Mean mobilised friction angle over the last quarter of the axial
    /// strain, degrees: the critical state's when the volume has stopped
    /// changing there (see `final_dilatancy_deg`).
    pub final_friction_deg: f64,
    /// Largest dilatancy angle, from the slope of ε_v against γ over
    /// [`SMOOTHING`] samples, degrees, and where it is reached.
    pub peak_dilatancy_deg: f64,
    pub peak_dilatancy_axial_strain: f64,
    /// Dilatancy angle over the last quarter of the axial strain, degrees.
    pub final_dilatancy_deg: f64,
    /// Mean of |σ_xx/σ_3 − 1| over the last quarter of the axial strain:
    /// how well the lateral wall held the confining stress where
    /// `final_friction_deg` is measured. Above a few per cent the test is
    /// no longer stress-controlled (the shear outruns the servo: on the lab
    /// grains from I ≈ 3e-3, docs/dem.md "Element test"). NaN (`null` in
    /// JSON) without samples there, and in records written before
    /// session 32.
    #[serde(default = "not_measured", deserialize_with = "schemas::summary::nan_if_null")]
    pub final_lateral_stress_error: f64,
    /// Final porosity of the box and of its core.
    pub final_porosity: f64,
    pub final_core_porosity: f64,
    /// Axial strain rate, 1/s, and the simulated time of the shear, s.
    pub strain_rate: f64,
    pub shear_time: f64,
    pub steps: u64,
}

#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
pub struct BiaxialRecord {
    pub spec: BiaxialSpec,
    /// The contact law sheared (grain friction μ_s, rolling μ_r, ...).
    pub friction: f64,
    pub rolling_friction: f64,
    pub preparation_friction: f64,
    pub diameter: f64,
    pub density: f64,
    pub samples: Vec<BiaxialSample>,
    pub summary: BiaxialSummary,
}

#[derive(Debug, thiserror::Error)]
pub enum BiaxialError {
    #[error("the {phase} did not come to rest within {steps} steps (walls {worst:.1} % off the confining stress, kinetic energy {energy:.1}× the rest bound): lower the inertial number, and keep k_n / (σ_3 D) above ~100 (lower the confining stress or raise dem.normal_stiffness)")]
    NotAtRest { phase: &'static str, steps: u64, worst: f64, energy: f64 },
    #[error("the biaxial test became unstable (non-finite grain state at t = {t:.4} s): lower dem.time_step or raise dem.steps_per_contact")]
    Unstable { t: f64 },
    #[error("interrupted")]
    Interrupted,
    #[error("invalid biaxial setting: {0}")]
    Invalid(String),
}

/// Samples a running mean or slope spans (an odd count).
pub const SMOOTHING: usize = 11;

/// Walls in the order the test builds them.
const X_MIN: usize = 0;
const X_MAX: usize = 1;
const Y_MIN: usize = 2;
const Y_MAX: usize = 3;
const Z_MIN: usize = 4;
const Z_MAX: usize = 5;

/// Fraction of the stress error a servo wall corrects per step, given the
/// stiffness of the grains touching it: small enough that the grains follow.
const SERVO_GAIN: f64 = 0.02;
/// Steps between two servo updates and load samples.
const SERVO_INTERVAL: u64 = 10;
/// Integral time of the servo, steps (~ 10 of the proportional loop's).
const SERVO_INTEGRAL_STEPS: f64 = 2000.0;
/// A phase is at rest when every controlled wall's load, averaged over
/// `REST_WINDOW` steps, is within this fraction of the confining stress and
/// the grains' mean kinetic energy below `REST_ENERGY` σ_3 D³ (the work of
/// the confining stress over a grain's volume; 1e-5 of it is a grain moving
/// at ~0.5 % of √(σ_3/ρ_s)).
const REST_TOLERANCE: f64 = 0.02;
const REST_WINDOW: u64 = 1000;
const REST_ENERGY: f64 = 1e-5;
/// The servo's walls move at most this many times faster than the shear's
/// axial strain rate (the preparation's at most that of
/// `QUASI_STATIC_INERTIAL_NUMBER`).
const PREPARATION_SPEEDUP: f64 = 10.0;
/// The preparation and hold run at this inertial number or the shear's,
/// whichever is lower, so that a test at a high inertial number shears the
/// same quasi-statically prepared sample (a preparation at the shear's
/// rate packs another porosity, or never comes to rest).
const QUASI_STATIC_INERTIAL_NUMBER: f64 = 1e-3;
/// Step budget of each rest phase, in units of the lattice's closing time.
const REST_BUDGET: f64 = 20.0;

/// Runs the test on the grains and contact law of `scene` (its first
/// particle block; walls frictionless and without rolling resistance, so
/// that they only carry normal stress).
pub fn run(
    scene: &Scene,
    spec: &BiaxialSpec,
    stop: &AtomicBool,
    mut progress: impl FnMut(&str, f64),
) -> Result<BiaxialRecord, BiaxialError> {
    check(spec)?;
    let block =
        scene.spec.particles.first().ok_or_else(|| BiaxialError::Invalid("the scene has no particle block".into()))?;
    let setup = DemSetup::from_scene(scene);
    let preparation = setup.for_deposition(scene);
    let prep_friction = spec.preparation_friction.unwrap_or(preparation.grain_law.friction);
    let sheared_law = setup.grain_law;
    let wall_law = ContactLaw { friction: 0.0, rolling_friction: 0.0, ..sheared_law };
    let (d, spread, density) = (block.diameter, block.diameter_spread, block.density);

    let (grains, box_max) = lattice(spec, d, spread, density);
    let walls = box_walls(box_max);
    let numerics = Numerics { dt: preparation.numerics.dt, ..setup.numerics };
    let margin = [d; 3];
    let domain = ([-margin[0], -margin[1], -margin[2]], [box_max[0] + d, box_max[1] + d, box_max[2] + d]);
    let mut world = World::new(
        grains,
        walls,
        ContactLaw { friction: prep_friction, ..sheared_law },
        wall_law,
        [0.0; 3],
        numerics,
        domain,
    );
    world.prime_forces();

    let sigma3 = spec.confining_stress;
    let stress_speed = (sigma3 / density).sqrt();
    let strain_rate = spec.inertial_number * stress_speed / d;
    let preparation_rate = spec.inertial_number.min(QUASI_STATIC_INERTIAL_NUMBER) * stress_speed / d;
    let servo_rate = PREPARATION_SPEEDUP * preparation_rate;
    let closing_steps = (1.0 / (servo_rate * world.numerics.dt)).ceil() as u64;
    let budget = (REST_BUDGET * closing_steps as f64) as u64;
    let mut control = Control { sigma3, servo_rate, rest_energy: REST_ENERGY * sigma3 * d.powi(3), integral: [0.0; 6] };

    control.settle(&mut world, &[X_MAX, Y_MAX, Z_MAX], "preparation", budget, stop, &mut progress)?;
    world.grain_law = sheared_law;
    control.settle(&mut world, &[X_MAX, Y_MAX, Z_MAX], "hold", budget, stop, &mut progress)?;
    control.servo_rate = PREPARATION_SPEEDUP * strain_rate;

    let size0 = size(&world);
    let initial_porosity = porosity(&world);
    let initial_core_porosity = core_porosity(&world);
    let initial_coordination = world.mean_coordination();
    let shear_steps = (spec.max_axial_strain / (strain_rate * world.numerics.dt)).ceil() as u64;
    let sample_every = ((spec.sample_strain / (strain_rate * world.numerics.dt)).round() as u64).max(SERVO_INTERVAL);
    let mut samples = Vec::new();
    let mut loads = LoadAverage::default();
    let start_step = world.step_count;
    let t0 = world.time;
    for k in 1..=shear_steps {
        if k % SERVO_INTERVAL == 1 || SERVO_INTERVAL == 1 {
            let l = size(&world);
            world.walls[Z_MAX].velocity = [0.0, 0.0, -strain_rate * l[2]];
            let wall_loads = world.wall_loads();
            control.servo(&mut world, &wall_loads, &[X_MAX], true);
            loads.add(&wall_loads);
        }
        world.step();
        if k % 1000 == 0 {
            if stop.load(Ordering::Relaxed) {
                return Err(BiaxialError::Interrupted);
            }
            if !world.grains.pos.iter().flatten().all(|x| x.is_finite()) {
                return Err(BiaxialError::Unstable { t: world.time });
            }
        }
        if k % sample_every == 0 || k == shear_steps {
            if loads.count == 0 {
                // A last sample closer to the one before than a servo update.
                loads.add(&world.wall_loads());
            }
            let l = size(&world);
            let eps1 = (size0[2] / l[2]).ln();
            let eps3 = (size0[0] / l[0]).ln();
            let stress = loads.stress(&l);
            loads = LoadAverage::default();
            let sin_phi = (stress[2] - stress[0]) / (stress[2] + stress[0]);
            samples.push(BiaxialSample {
                axial_strain: eps1,
                lateral_strain: eps3,
                volumetric_strain: eps1 + eps3,
                stress,
                porosity: porosity(&world),
                coordination: world.mean_coordination(),
                mobilised_friction_deg: sin_phi.clamp(-1.0, 1.0).asin().to_degrees(),
            });
            progress("shear", eps1);
        }
    }
    let summary = summarise(
        &samples,
        SummaryContext {
            grains: world.len(),
            initial_porosity,
            initial_core_porosity,
            initial_coordination,
            final_core_porosity: core_porosity(&world),
            strain_rate,
            shear_time: world.time - t0,
            steps: world.step_count - start_step,
            confining_stress: sigma3,
        },
    );
    Ok(BiaxialRecord {
        spec: spec.clone(),
        friction: sheared_law.friction,
        rolling_friction: sheared_law.rolling_friction,
        preparation_friction: prep_friction,
        diameter: d,
        density,
        samples,
        summary,
    })
}

fn check(spec: &BiaxialSpec) -> Result<(), BiaxialError> {
    let positive = |v: f64, name: &str| {
        if v.is_finite() && v > 0.0 {
            Ok(())
        } else {
            Err(BiaxialError::Invalid(format!("{name} must be positive and finite, got {v}")))
        }
    };
    positive(spec.confining_stress, "confining_stress (Pa)")?;
    positive(spec.inertial_number, "inertial_number")?;
    positive(spec.max_axial_strain, "max_axial_strain")?;
    positive(spec.sample_strain, "sample_strain")?;
    if spec.max_axial_strain >= 1.0 || spec.sample_strain * SMOOTHING as f64 > spec.max_axial_strain {
        return Err(BiaxialError::Invalid(format!(
            "max_axial_strain {} must lie below 1 and hold at least {SMOOTHING} samples of {}",
            spec.max_axial_strain, spec.sample_strain
        )));
    }
    if spec.lattice.iter().any(|&n| n < 3) {
        return Err(BiaxialError::Invalid(format!("lattice {:?}: at least 3 grains along each axis", spec.lattice)));
    }
    if let Some(mu) = spec.preparation_friction {
        if !(mu.is_finite() && mu >= 0.0) {
            return Err(BiaxialError::Invalid(format!("preparation_friction must be ≥ 0, got {mu}")));
        }
    }
    Ok(())
}

/// Grains on a lattice of spacing 1.2 D_max jittered by ±0.1 D_max in every
/// direction, and the far corner of the box that holds them.
fn lattice(spec: &BiaxialSpec, d: f64, spread: f64, density: f64) -> (Grains, [f64; 3]) {
    let d_max = d * (1.0 + spread);
    let spacing = 1.2 * d_max;
    let mut rng = SplitMix64::new(spec.seed);
    let mut grains = Grains::default();
    let [nx, ny, nz] = spec.lattice;
    for k in 0..nz {
        for j in 0..ny {
            for i in 0..nx {
                let at = |n: usize| 0.5 * spacing + n as f64 * spacing;
                let mut jitter = || 0.1 * d_max * rng.symmetric();
                let pos = [at(i) + jitter(), at(j) + jitter(), at(k) + jitter()];
                let diameter = d * (1.0 + spread * rng.symmetric());
                grains.push(pos, [0.0; 3], 0.5 * diameter, density);
            }
        }
    }
    (grains, [nx, ny, nz].map(|n| n as f64 * spacing))
}

/// Six walls: x, y, z at the origin, then at `max`, in the order of the constants above.
fn box_walls(max: [f64; 3]) -> Vec<Wall> {
    let mut walls = Vec::new();
    for (a, name) in ["x", "y", "z"].iter().enumerate() {
        let mut normal = [0.0; 3];
        normal[a] = 1.0;
        walls.push(Wall::fixed(format!("{name}_min"), [0.0; 3], normal, f64::INFINITY));
        let mut point = [0.0; 3];
        point[a] = max[a];
        normal[a] = -1.0;
        walls.push(Wall::fixed(format!("{name}_max"), point, normal, f64::INFINITY));
    }
    walls
}

/// The box's edge lengths from its walls, m.
fn size(world: &World) -> [f64; 3] {
    let w = &world.walls;
    [
        w[X_MAX].point[0] - w[X_MIN].point[0],
        w[Y_MAX].point[1] - w[Y_MIN].point[1],
        w[Z_MAX].point[2] - w[Z_MIN].point[2],
    ]
}

/// Porosity of the core: grains centred at least one largest diameter
/// from every wall, over the core's volume (the box's porosity counts the
/// looser layers along its walls).
fn core_porosity(world: &World) -> f64 {
    let l = size(world);
    let o = [world.walls[X_MIN].point[0], world.walls[Y_MIN].point[1], world.walls[Z_MIN].point[2]];
    let d = 2.0 * world.grains.radius.iter().cloned().fold(0.0, f64::max);
    let g = &world.grains;
    let solid: f64 = (0..g.len())
        .filter(|&p| (0..3).all(|a| g.pos[p][a] >= o[a] + d && g.pos[p][a] < o[a] + l[a] - d))
        .map(|p| 4.0 / 3.0 * std::f64::consts::PI * g.radius[p].powi(3))
        .sum();
    1.0 - solid / l.iter().map(|x| x - 2.0 * d).product::<f64>()
}

fn porosity(world: &World) -> f64 {
    let l = size(world);
    let solid: f64 = world.grains.radius.iter().map(|r| 4.0 / 3.0 * std::f64::consts::PI * r.powi(3)).sum();
    1.0 - solid / (l[0] * l[1] * l[2])
}

/// Wall loads summed over the steps between two samples.
#[derive(Default)]
struct LoadAverage {
    sum: [f64; 6],
    count: usize,
}

impl LoadAverage {
    fn add(&mut self, loads: &[(f64, usize)]) {
        for (s, l) in self.sum.iter_mut().zip(loads) {
            *s += l.0;
        }
        self.count += 1;
    }

    /// Mean stress on each axis's two walls, Pa.
    fn stress(&self, l: &[f64; 3]) -> [f64; 3] {
        [0, 1, 2].map(|a| 0.5 * (self.wall_stress(2 * a, l) + self.wall_stress(2 * a + 1, l)))
    }

    /// Mean stress on wall `w`, Pa.
    fn wall_stress(&self, w: usize, l: &[f64; 3]) -> f64 {
        let area = [l[1] * l[2], l[0] * l[2], l[0] * l[1]];
        self.sum[w] / self.count.max(1) as f64 / area[w / 2]
    }
}

/// The stress control of the walls at the box's far side.
struct Control {
    sigma3: f64,
    /// Fastest a controlled wall moves, in box lengths per second.
    servo_rate: f64,
    /// Mean kinetic energy per grain at rest, J.
    rest_energy: f64,
    /// The integral part of each wall's speed, m/s (inward positive).
    integral: [f64; 6],
}

impl Control {
    /// Sets each controlled wall's velocity along its normal (inward
    /// positive) by proportional–integral control of its stress: the
    /// proportional part corrects `SERVO_GAIN` of the stress error per step
    /// given the stiffness of the grains touching it (an upper bound on the
    /// sample's, so the loop stays stable), and the integral part, over
    /// `SERVO_INTEGRAL_STEPS`, supplies the steady speed a shearing sample's
    /// side needs, which the proportional part alone would only reach with a
    /// large error. Capped at `servo_rate` box lengths per second.
    /// The preparation runs without the integral part (`integral` false):
    /// its walls come to a stop, and an integral wound up while they close
    /// in on a grain gas would overshoot.
    fn servo(&mut self, world: &mut World, loads: &[(f64, usize)], controlled: &[usize], integral: bool) {
        let l = size(world);
        let area = [l[1] * l[2], l[0] * l[2], l[0] * l[1]];
        let dt = world.numerics.dt;
        let kn = world.wall_law.normal_stiffness;
        for &w in controlled {
            let axis = w / 2;
            let (load, touching) = loads[w];
            let error = self.sigma3 - load / area[axis];
            let stiffness = kn * touching.max(1) as f64;
            let cap = self.servo_rate * l[axis];
            let proportional = SERVO_GAIN * error * area[axis] / (stiffness * dt);
            let sum = &mut self.integral[w];
            if integral {
                *sum = (*sum + proportional * SERVO_INTERVAL as f64 / SERVO_INTEGRAL_STEPS).clamp(-cap, cap);
            }
            let speed = (proportional + *sum).clamp(-cap, cap);
            let wall = &mut world.walls[w];
            wall.velocity = wall.normal.map(|n| n * speed);
        }
    }

    /// Stops every wall and forgets the integral.
    fn stop_walls(&mut self, world: &mut World) {
        for wall in &mut world.walls {
            wall.velocity = [0.0; 3];
        }
        self.integral = [0.0; 6];
    }

    /// Steps under stress control on `controlled` until every controlled
    /// wall's load, averaged over `REST_WINDOW` steps, is within
    /// `REST_TOLERANCE` of σ_3 and the grains' mean kinetic energy is below
    /// `REST_ENERGY` σ_3 D³; then stops the walls.
    fn settle(
        &mut self,
        world: &mut World,
        controlled: &[usize],
        phase: &'static str,
        budget: u64,
        stop: &AtomicBool,
        progress: &mut impl FnMut(&str, f64),
    ) -> Result<(), BiaxialError> {
        let mut worst = f64::INFINITY;
        let mut energy = f64::INFINITY;
        let mut window = LoadAverage::default();
        for k in 1..=budget {
            if k % SERVO_INTERVAL == 0 {
                let loads = world.wall_loads();
                window.add(&loads);
                self.servo(world, &loads, controlled, false);
            }
            if k % REST_WINDOW == 0 {
                let l = size(world);
                worst = controlled
                    .iter()
                    .map(|&w| (window.wall_stress(w, &l) / self.sigma3 - 1.0).abs())
                    .fold(0.0, f64::max);
                window = LoadAverage::default();
                energy = world.kinetic_energy() / world.len() as f64;
                if !energy.is_finite() {
                    return Err(BiaxialError::Unstable { t: world.time });
                }
                if worst < REST_TOLERANCE && energy < self.rest_energy {
                    self.stop_walls(world);
                    return Ok(());
                }
                if stop.load(Ordering::Relaxed) {
                    return Err(BiaxialError::Interrupted);
                }
                progress(phase, worst);
            }
            world.step();
        }
        Err(BiaxialError::NotAtRest { phase, steps: budget, worst: 100.0 * worst, energy: energy / self.rest_energy })
    }
}

struct SummaryContext {
    grains: usize,
    initial_porosity: f64,
    initial_core_porosity: f64,
    initial_coordination: f64,
    final_core_porosity: f64,
    strain_rate: f64,
    shear_time: f64,
    steps: u64,
    confining_stress: f64,
}

fn not_measured() -> f64 {
    f64::NAN
}

/// Slope of `y` against `x` by least squares.
fn slope(x: &[f64], y: &[f64]) -> f64 {
    let n = x.len() as f64;
    let (mx, my) = (x.iter().sum::<f64>() / n, y.iter().sum::<f64>() / n);
    let sxy: f64 = x.iter().zip(y).map(|(a, b)| (a - mx) * (b - my)).sum();
    let sxx: f64 = x.iter().map(|a| (a - mx) * (a - mx)).sum();
    sxy / sxx
}

/// ψ from −dε_v/dγ over a run of samples, degrees.
fn dilatancy_deg(samples: &[BiaxialSample]) -> f64 {
    let gamma: Vec<f64> = samples.iter().map(|s| s.axial_strain - s.lateral_strain).collect();
    let ev: Vec<f64> = samples.iter().map(|s| s.volumetric_strain).collect();
    (-slope(&gamma, &ev)).clamp(-1.0, 1.0).asin().to_degrees()
}

fn mean_friction_deg(samples: &[BiaxialSample]) -> f64 {
    let sin: f64 =
        samples.iter().map(|s| s.mobilised_friction_deg.to_radians().sin()).sum::<f64>() / samples.len() as f64;
    sin.asin().to_degrees()
}

fn summarise(samples: &[BiaxialSample], c: SummaryContext) -> BiaxialSummary {
    let windows = samples.windows(SMOOTHING.min(samples.len()));
    let centre = |w: &[BiaxialSample]| w[w.len() / 2].axial_strain;
    let (peak_friction_deg, peak_axial_strain) = windows
        .clone()
        .map(|w| (mean_friction_deg(w), centre(w)))
        .fold((f64::NEG_INFINITY, 0.0), |a, b| if b.0 > a.0 { b } else { a });
    let (peak_dilatancy_deg, peak_dilatancy_axial_strain) = windows
        .map(|w| (dilatancy_deg(w), centre(w)))
        .fold((f64::NEG_INFINITY, 0.0), |a, b| if b.0 > a.0 { b } else { a });
    let last = samples.last().map_or(0.0, |s| s.axial_strain);
    let tail: Vec<BiaxialSample> = samples.iter().copied().filter(|s| s.axial_strain >= 0.75 * last).collect();
    BiaxialSummary {
        grains: c.grains,
        initial_porosity: c.initial_porosity,
        initial_core_porosity: c.initial_core_porosity,
        initial_coordination: c.initial_coordination,
        peak_friction_deg,
        peak_axial_strain,
        final_friction_deg: mean_friction_deg(&tail),
        peak_dilatancy_deg,
        peak_dilatancy_axial_strain,
        final_dilatancy_deg: dilatancy_deg(&tail),
        final_lateral_stress_error: tail.iter().map(|s| (s.stress[0] / c.confining_stress - 1.0).abs()).sum::<f64>()
            / tail.len() as f64,
        final_porosity: samples.last().map_or(f64::NAN, |s| s.porosity),
        final_core_porosity: c.final_core_porosity,
        strain_rate: c.strain_rate,
        shear_time: c.shear_time,
        steps: c.steps,
    }
}
