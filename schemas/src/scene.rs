//! Scene files: the TOML a user writes (`*Spec` types, serde, unknown keys
//! rejected) and the checked [`Scene`] every process runs from.
//!
//! All values are SI (m, s, kg, N, Pa). Loading goes through
//! [`Scene::from_toml_str`] (or [`Scene::load`]), which applies `--set`
//! overrides to the raw TOML, deserialises with the key path of any error,
//! then validates every value once. Keys and defaults are documented in
//! `docs/scenes.md`; keep the two in step.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::error::SceneError;
use crate::overrides::apply_override;

// ---------------------------------------------------------------------------
// Raw file types
// ---------------------------------------------------------------------------

/// The whole scene file.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SceneSpec {
    pub scene: MetaSpec,
    pub domain: DomainSpec,
    #[serde(default)]
    pub gates: Vec<GateSpec>,
    #[serde(default)]
    pub particles: Vec<ParticleBlockSpec>,
    #[serde(default)]
    pub fluids: Vec<FluidBlockSpec>,
    #[serde(default)]
    pub dem: Option<DemSpec>,
    #[serde(default)]
    pub lbm: Option<LbmSpec>,
    /// Two-phase double-point MPM numerics and soil model; read when
    /// `scene.method = "mpm"` (every key has a default, docs/scenes.md).
    #[serde(default)]
    pub mpm: Option<MpmSpec>,
    /// DEM–LBM exchange; only read when the scene has both grains and liquid.
    #[serde(default)]
    pub coupling: CouplingSpec,
    #[serde(default)]
    pub deposition: DepositionSpec,
    pub output: OutputSpec,
    pub analysis: AnalysisSpec,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MetaSpec {
    /// Short identifier, used in file names and recordings.
    pub name: String,
    #[serde(default)]
    pub description: String,
    /// Which method runs the scene: `dem`, `lbm`, `dem_lbm` or `mpm`.
    /// Default: from the blocks (grains only `dem`, liquid only `lbm`, both
    /// `dem_lbm`); MPM is chosen only by name (`coupler run --method mpm`).
    #[serde(default)]
    pub method: Option<Method>,
}

/// Axis-aligned box holding everything, with gravity and the faces that are walls.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DomainSpec {
    /// Lower corner, m.
    pub min: [f64; 3],
    /// Upper corner, m.
    pub max: [f64; 3],
    /// Gravitational acceleration, m/s².
    pub gravity: [f64; 3],
    /// Gravity during the run itself, m/s², where it differs from the
    /// preparation's: the DEM deposits its grains and the MPM runs its
    /// gravity phase under `gravity`; from t = 0 (the run, gates released at
    /// their times) both feel this one. A horizontal part is a uniform push
    /// per unit mass, such as the seepage push a draining liquid gives a
    /// grain pile (docs/RESULTS.md, "A steady push on dry piles"). The
    /// reference time stays √(H0/|gravity|). DEM and MPM scenes only (the
    /// LBM's liquid is prepared hydrostatic under `gravity`). Default: none
    /// (the run under `gravity`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub collapse_gravity: Option<[f64; 3]>,
    /// Faces of the box that are solid walls: any of
    /// `x_min x_max y_min y_max z_min z_max`. Faces not listed are open.
    pub walls: Vec<Face>,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Face {
    XMin,
    XMax,
    YMin,
    YMax,
    ZMin,
    ZMax,
}

impl Face {
    pub const ALL: [Face; 6] = [Face::XMin, Face::XMax, Face::YMin, Face::YMax, Face::ZMin, Face::ZMax];

    pub fn name(self) -> &'static str {
        match self {
            Face::XMin => "x_min",
            Face::XMax => "x_max",
            Face::YMin => "y_min",
            Face::YMax => "y_max",
            Face::ZMin => "z_min",
            Face::ZMax => "z_max",
        }
    }

    /// Axis index (0 = x) and the inward normal sign.
    pub fn axis_and_sign(self) -> (usize, f64) {
        match self {
            Face::XMin => (0, 1.0),
            Face::XMax => (0, -1.0),
            Face::YMin => (1, 1.0),
            Face::YMax => (1, -1.0),
            Face::ZMin => (2, 1.0),
            Face::ZMax => (2, -1.0),
        }
    }
}

/// A plane wall that disappears at `release_time` (the lab's lifted gate).
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GateSpec {
    pub name: String,
    /// Any point of the plane, m.
    pub point: [f64; 3],
    /// Normal pointing to the side the material is held on (normalised at load).
    pub normal: [f64; 3],
    /// Time after the start of the run at which the gate is removed, s.
    pub release_time: f64,
}

/// One group of grains with common material.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ParticleBlockSpec {
    pub name: String,
    /// Grain density, kg/m³.
    pub density: f64,
    /// Grain diameter, m (mean diameter when `diameter_spread > 0`).
    pub diameter: f64,
    /// Relative half-width of a uniform diameter distribution, e.g. 0.1 for
    /// D·(1 ± 0.1). Default 0 (monodisperse).
    #[serde(default)]
    pub diameter_spread: f64,
    pub packing: PackingSpec,
}

/// How the grains of a block are placed.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(tag = "method", rename_all = "snake_case", deny_unknown_fields)]
pub enum PackingSpec {
    /// Grains rain into `region` under gravity (with `[deposition]` settings)
    /// until at rest; grains whose centre ends above the region top are removed.
    Deposit {
        region: BoxSpec,
        /// Target bulk porosity of the region; sets the grain count. Exactly
        /// one of `porosity` and `count`.
        #[serde(default)]
        porosity: Option<f64>,
        #[serde(default)]
        count: Option<usize>,
        /// Seed of the initial placement jitter.
        seed: u64,
    },
    /// Grains at given positions: inline `spheres = [[x, y, z, d], ...]` or a
    /// CSV `file` with columns x,y,z,d (m), relative to the scene file.
    Explicit {
        #[serde(default)]
        spheres: Vec<[f64; 4]>,
        #[serde(default)]
        file: Option<PathBuf>,
        /// Initial velocity of every grain, m/s. Default 0.
        #[serde(default)]
        velocity: [f64; 3],
    },
}

#[derive(Debug, Clone, Copy, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BoxSpec {
    pub min: [f64; 3],
    pub max: [f64; 3],
}

/// A body of liquid (used by the LBM process; validated here).
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FluidBlockSpec {
    pub name: String,
    /// kg/m³.
    pub density: f64,
    /// Dynamic viscosity, Pa·s.
    pub viscosity: f64,
    pub region: BoxSpec,
}

/// Lattice Boltzmann numerics (paper §3.1, Eq. 4).
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LbmSpec {
    /// Lattice spacing Δx, m.
    pub spacing: f64,
    /// Lattice time step Δt, s.
    pub time_step: f64,
    /// Smagorinsky constant C of Eq. 4; 0 switches the eddy viscosity off. Default 0.16.
    #[serde(default = "default_smagorinsky")]
    pub smagorinsky: f64,
    /// Collision operator. Default `bgk`: at the paper's τ = 0.50067 it
    /// survives even without Smagorinsky, where TRT with Λ = 3/16 blows up
    /// (`lbm_proc/tests/stability.rs`).
    #[serde(default)]
    pub collision: Collision,
    /// TRT magic parameter Λ = (τ+ − ½)(τ− − ½). Default 3/16 (bounce-back walls exactly mid-link).
    #[serde(default = "default_trt_magic")]
    pub trt_magic: f64,
    /// Watchdog: stop when |u| exceeds this multiple of the lattice sound
    /// speed. Default 0.5 (|u| ≈ 0.29 lattice units, the usual abort level):
    /// a water dam-break front at the paper's resolution reaches Mach ~0.35.
    #[serde(default = "default_mach_limit")]
    pub mach_limit: f64,
    /// Where the liquid's hydrostatic pressure lives: `lattice` (default)
    /// or `buoyancy` (see [`Hydrostatics`]).
    #[serde(default)]
    pub hydrostatics: Hydrostatics,
    /// The populations' storage: `f32` (default: half the memory and the
    /// memory traffic of the bandwidth-bound kernel) or `f64` (the
    /// reference that measures what f32 costs). Mass, energy and forces
    /// are summed in f64 either way.
    #[serde(default)]
    pub precision: Precision,
}

/// The floating-point type the lattice stores its populations in.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Precision {
    #[default]
    F32,
    F64,
}

impl Precision {
    pub fn name(self) -> &'static str {
        match self {
            Precision::F32 => "f32",
            Precision::F64 => "f64",
        }
    }

    /// Bytes of one stored population.
    pub fn bytes(self) -> usize {
        match self {
            Precision::F32 => 4,
            Precision::F64 => 8,
        }
    }
}

/// How gravity acts on the liquid of a coupled scene.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Hydrostatics {
    /// The liquid feels gravity: its hydrostatic pressure is on the lattice,
    /// and the grains' buoyancy comes from it with the rest of the surface
    /// force. Needed wherever the liquid has a free surface. The head
    /// ρ_L g H must stay small in lattice units (its density varies by
    /// 3 g H Δt²/Δx), which can force a small Δt in a tall tank.
    #[default]
    Lattice,
    /// The liquid feels no gravity, so the lattice carries only the pressure
    /// beyond the hydrostatic (p + ρ_L g·x), and each grain's load gets its
    /// buoyancy −ρ_L V g added (V = πD³/6). The same physics as `lattice`
    /// for liquid that fills a closed box (checked at load), with no
    /// hydrostatic density gradient to limit Δt.
    Buoyancy,
}

impl Hydrostatics {
    pub fn name(self) -> &'static str {
        match self {
            Hydrostatics::Lattice => "lattice",
            Hydrostatics::Buoyancy => "buoyancy",
        }
    }
}

fn default_smagorinsky() -> f64 {
    0.16
}
fn default_trt_magic() -> f64 {
    3.0 / 16.0
}
fn default_mach_limit() -> f64 {
    0.5
}

/// LBM collision operators.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Collision {
    /// Single relaxation time (the paper's).
    #[default]
    Bgk,
    /// Two relaxation times (Ginzburg): walls exactly mid-link with Λ = 3/16.
    Trt,
}

/// Two-phase double-point MPM (paper §3.2, §4.2; docs/mpm.md). The soil is
/// the first particle block (its `density`, `diameter` as the grain size D
/// of Eqs. 8–9, `packing.region` and `packing.porosity` as n0); the liquid
/// is the fluid blocks (density, viscosity, region). The x–z section of the
/// domain is simulated in plane strain.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MpmSpec {
    /// Side of the square background-grid elements, m. Default 0.004.
    #[serde(default = "default_mpm_element")]
    pub element_size: f64,
    /// Material points of each phase per initially filled element, laid on
    /// a regular a × b sub-grid (a·b = this, a ≥ b as close as possible;
    /// a along x). Default 12 (4 × 3).
    #[serde(default = "default_mpm_points")]
    pub points_per_element: u32,
    /// `gimp` (uniform GIMP, default: smooth across cell crossings) or
    /// `linear` (plain bilinear, Anura3D's).
    #[serde(default)]
    pub shape_functions: ShapeFunctions,
    /// Fraction of the CFL step h / c_max taken, c_max the fastest wave
    /// (undrained P-wave, liquid compression, dry P-wave; under
    /// `pressure_scheme = "implicit"` with soil, the dry P-wave alone, ~1.9×
    /// the step on the lab column: set 0.26 there to step as the explicit
    /// scheme does, with `flip_share_basis = "step"` to blend as it does at
    /// its 0.5). Default 0.5:
    /// APIC's stable limit is lower than FLIP's; an elastic block settling
    /// under gravity held at 0.75 and blew up at 0.8 (FLIP and PIC held at
    /// 0.8). Under FLIP the saturated lab column's runout moved by 2.5 %
    /// between 0.5, 0.8 and 0.98 (Anura3D's) (docs/mpm.md, "Time step").
    #[serde(default = "default_mpm_courant")]
    pub courant: f64,
    /// Skeleton Young's modulus E, Pa. Default 1e7.
    #[serde(default = "default_mpm_young")]
    pub young_modulus: f64,
    /// Skeleton Poisson ratio ν. Default 0.3.
    #[serde(default = "default_mpm_poisson")]
    pub poisson_ratio: f64,
    /// Mohr–Coulomb friction angle φ, degrees. Default 35.
    #[serde(default = "default_mpm_friction")]
    pub friction_angle: f64,
    /// Mohr–Coulomb cohesion c, Pa. Default 0.
    #[serde(default)]
    pub cohesion: f64,
    /// Dilatancy angle ψ of the plastic potential, degrees (ψ ≤ φ). Default 0.
    #[serde(default)]
    pub dilatancy_angle: f64,
    /// Porosity at which a dilating soil reaches its critical state
    /// (PLAXIS's dilatancy cut-off, e_max): ψ applies at points whose
    /// porosity is below it and 0 at and above, so a dense soil dilates by
    /// a bounded volume and then shears at constant volume. Needs
    /// `dilatancy_angle` > 0. Default: none (ψ at every porosity). The
    /// lab grains' measured value: 0.428 with ψ = 9° (docs/dem.md, "Element
    /// test").
    #[serde(default)]
    pub dilatancy_cutoff_porosity: Option<f64>,
    /// Rate-dependent friction, the μ(I) rheology (GDR MiDi 2004; Jop et
    /// al. 2006): the friction angle φ_2, degrees, that a point tends to as
    /// its inertial number I = γ̇ D / √(p′/ρ_s) grows, `friction_angle`
    /// being the quasi-static φ_s: sin φ = sin φ_s + (sin φ_2 − sin φ_s) /
    /// (1 + I_0/I). Default: none (rate-independent Mohr–Coulomb). The lab
    /// grains' measured rise: docs/dem.md, "Element test".
    #[serde(default)]
    pub limit_friction_angle: Option<f64>,
    /// I_0 of the rate-dependent friction: the inertial number at which
    /// half of the rise from φ_s to `limit_friction_angle` is reached.
    /// Needs `limit_friction_angle`. Default 0.279 (Jop, Forterre &
    /// Pouliquen 2006, glass beads): see
    /// [`MpmSpec::reference_inertial_number_in_effect`].
    #[serde(default)]
    pub reference_inertial_number: Option<f64>,
    /// Liquid bulk modulus K_L of Eq. 11, Pa. Default 2e7 (the paper's reduced value).
    #[serde(default = "default_mpm_bulk")]
    pub liquid_bulk_modulus: f64,
    /// Liquid tension tolerated before cavitation, Pa (pore pressure is kept
    /// ≥ −this). Default 0: no tension.
    #[serde(default)]
    pub cavitation_threshold: f64,
    /// Porosity n_max above which the skeleton is fluidised (zero effective
    /// stress, Beenakker viscosity in the liquid). Default 0.5.
    #[serde(default = "default_mpm_nmax")]
    pub max_porosity: f64,
    /// Local (Cundall) damping coefficient α of the out-of-balance forces. Default 0.02.
    #[serde(default = "default_mpm_damping")]
    pub damping: f64,
    /// How the floor (the `z_min` wall) holds the soil: `rough` (default,
    /// the paper's §4.2: both phases fixed in both directions) or
    /// `frictional` (the normal velocity held, the solid sliding with
    /// Coulomb friction `wall_friction`, the liquid slipping freely).
    #[serde(default)]
    pub floor: MpmFloor,
    /// Coulomb friction coefficient μ of the soil on the walls: the floor
    /// when `floor = "frictional"`, and the side walls (x_min, x_max,
    /// z_max). Default 0: smooth side walls, as rollers.
    #[serde(default)]
    pub wall_friction: f64,
    /// Whether a wall that holds only the normal velocity (x_min, x_max,
    /// z_max, and the floor when `floor = "frictional"`) lets the soil and
    /// water go when they move off it: `unilateral` (default: a held
    /// component is released when the mixture there moves off the wall,
    /// and held again, its phases' velocities into the wall stopped, as
    /// soon as the mixture moves into it; docs/mpm.md, "Walls that let
    /// go") or `bilateral` (the normal component held both ways, so
    /// material pulled away stays on the wall: the behaviour before
    /// session 35). A rough floor and the gates hold both ways under
    /// either.
    #[serde(default)]
    pub wall_contact: MpmWallContact,
    /// Under `wall_contact = "unilateral"`, m/s: a held wall component is
    /// released for the step, right after the map, when its mixture is
    /// carried off the wall within the step (its mapped momentum plus Δt
    /// times the force it felt there in the last step) faster than this
    /// per unit mass; the solve's own test (its end velocity off the wall)
    /// asks no speed and releases it from the next step. Where liquid may
    /// hold tension (`cavitation_threshold` > 0) only the solve's test
    /// acts. Default: 0, no tolerance: the force keeps a layer resting on
    /// a wall held against its step-to-step noise (docs/mpm.md, "What the
    /// bar stood for, and the force that replaces it"; on the lab column
    /// 0 and 2.1e-4 m/s give the same fronts to 0.1 %).
    #[serde(default)]
    pub wall_release_speed: Option<f64>,
    /// Where a frictional wall's Coulomb impulse μ Δt N acts: `wall_node`
    /// (default: on the wall node alone, which it stops at most) or
    /// `next_node` (what the wall node's own mass cannot take passes to the
    /// next node off the wall, up to stopping the fraction of that node's
    /// mass by which the wall node falls short of its support's share of a
    /// node under the same material; a block landing while it slides then gets
    /// 0.97 of the friction impulse Coulomb's law asks for, against 0.24,
    /// but a μ = 10 floor holds a column 27 % shorter than the rough floor;
    /// docs/mpm.md, "Limit: impacts carry too little friction").
    #[serde(default)]
    pub wall_friction_reach: MpmWallFrictionReach,
    /// How the points touching a frictional wall update their velocity
    /// along it:
    /// `blend` (default since session 38: the grid's velocity only along
    /// the components a wall holds; along the wall the transfer's own
    /// update, whose FLIP increment carries the wall's friction) or `grid`
    /// (the grid's velocity in both directions every step, the default
    /// before). Under `grid` each step re-projects the layer on the wall
    /// onto the grid, and a sliding layer's runout grows as the step
    /// shrinks (the saturated lab column on 4 mm elements: 75 % share
    /// 0.72 → 1.00 L0 from courant 0.5 to 0.125; under `blend` 0.66 →
    /// 0.60); docs/mpm.md, "A re-projection once a step".
    #[serde(default)]
    pub wall_tangent_update: MpmWallTangentUpdate,
    /// The shear a slip wall puts on the liquid flowing along it:
    /// `laminar_film` (default since session 45) or `none` (free slip,
    /// before). The liquid's viscous stress is resolved only across
    /// elements, so a film thinner than one, such as the water running
    /// ahead of a deposit, felt no wall at all and coasted on: on the
    /// saturated lab column the liquid front then grew by +0.27 and +0.42
    /// L0 per halving of the step and was still moving when the grains
    /// stopped. `laminar_film` gives each line of nodes off a wall the
    /// depth-averaged wall shear of a laminar film (Nusselt), τ = 3 μ Ū / d,
    /// d the liquid points' water volume over the part of the line's
    /// strip they cover (since session 46; a film's end has its own
    /// depth), implicit in the step: dŪ/dt = −3 ν Ū / d².
    /// Its only parameter is the liquid's viscosity; under the soil the
    /// drag outweighs it by orders of magnitude. `laminar_film_line_mass`
    /// reads d over the whole strip (session 45's rule), which slows a
    /// film's end too fast. docs/mpm.md, "The liquid's wall shear".
    #[serde(default)]
    pub liquid_wall_shear: MpmLiquidWallShear,
    /// Ergun coefficients A and B of Eqs. 8–9. Defaults 150 and 1.75.
    #[serde(default = "default_ergun_a")]
    pub ergun_a: f64,
    #[serde(default = "default_ergun_b")]
    pub ergun_b: f64,
    /// Keep the quadratic (Forchheimer) drag term f2 of Eq. 7. Default true.
    #[serde(default = "default_true")]
    pub quadratic_drag: bool,
    /// An element is pressured when its filling ratio (the water over the
    /// space its grains leave, each point counted by the share of its
    /// domain inside it) is at least this, else its liquid points are on
    /// the free surface with zero pore pressure (or, under
    /// `surface_elements = "hydrostatic"`, a saturated layer's pressure
    /// where the water fills at least this share of its soil's pores); the
    /// explicit scheme also frees a point whose interpolated (nodal)
    /// filling ratio is below it (docs/mpm.md, "Pore pressure"). Default 0.8.
    #[serde(default = "default_mpm_fill")]
    pub free_surface_fill: f64,
    /// How the pore pressures of an element's liquid points are tied
    /// together each step: `linear` (default), a volume-weighted
    /// least-squares plane through the element's pressured points (free ones
    /// stay at 0), so a pressure carried into an element keeps no excess
    /// its increments can never remove (a single point held 4.4 kPa among
    /// neighbours at 41 Pa), while a hydrostatic gradient is kept exactly;
    /// or `none`, each point's own history (docs/mpm.md, "Pore pressure").
    #[serde(default)]
    pub pressure_reconstruction: MpmPressureReconstruction,
    /// How the pore pressure enters the momentum balance: `implicit`
    /// (default since session 27), one pressure per pressured element
    /// solved each step from the mixture continuity with the drag inside
    /// the mobility (docs/design/mpm-implicit-pressure.md), the liquid
    /// points taking their element's pressure, the step limited by the
    /// skeleton's wave alone; or `explicit`, each liquid point's weakly
    /// compressible law updated from the element's strain after the step
    /// (the paper's and Anura3D's scheme; it leaves isolated pressure
    /// spikes, docs/mpm.md "Pore pressure"; with the element fill by the
    /// points' domains since session 27, so not bit for bit the earlier
    /// default). Under `implicit`,
    /// `pressure_reconstruction` is not used.
    #[serde(default)]
    pub pressure_scheme: MpmPressureScheme,
    /// Under `pressure_scheme = "implicit"`: the pore pressure of an
    /// element below `free_surface_fill` whose water fills the pores of
    /// the soil it holds (or that holds water alone), a saturated layer
    /// at the bottom of the element: the surface of a column or of a
    /// flow's front lying inside it. `free`: p = 0, as in a draining
    /// element (its water is held by drag alone and drains through the
    /// grains); `hydrostatic`: p = ρ_L g_z θ² h/2, θ the element's
    /// occupied share (grains and water over its area), the pressure that
    /// holds such a layer's water at rest on the element's nodes, where
    /// the floor or the element below (pressured, or a layer held up
    /// itself) holds the layer up; a detached wet element falls free at
    /// p = 0. Drained
    /// elements (water below `free_surface_fill` of their soil's pores)
    /// stay free under both (docs/mpm.md, "Pore pressure"). Default
    /// `hydrostatic` under the implicit scheme (since session 40: a column
    /// topped inside an element then stays hydrostatic at rest, where
    /// under `free` its top element's water sank 1 mm); the explicit
    /// scheme has `free` only.
    #[serde(default)]
    pub surface_elements: Option<MpmSurfaceElements>,
    /// Under `pressure_scheme = "implicit"`: the absolute pressure of the
    /// air in the pores, Pa. A pressured element that is part empty
    /// (filling ratio S below 1) holds water and air, whose bulk modulus
    /// is 1/K = S/K_L + (1 − S)/(p_air + max(p̄, 0)) (Verruijt, Soil
    /// Mechanics, the compressibility of water with a little air): such an
    /// element is ~34× softer than K_L = 2e7 Pa at S = 0.83, so it fills
    /// without the pressure pulse a switch from free to incompressible
    /// makes. Default 101325 (the lab's atmosphere); a huge value gives
    /// K_L/S, the water's own compressibility over the water present.
    #[serde(default = "default_mpm_air_pressure")]
    pub air_pressure: f64,
    /// Under `transfer = "flip"`: share of the grid (PIC) velocity blended
    /// into each point's FLIP update, per step. Pure FLIP (0) keeps
    /// point-velocity components the grid cannot see: next to the rough
    /// floor they grew to 1 m/s while the points moved at 1 cm/s, and no
    /// deposit came to rest. Default 0.001: the lab columns then stop by
    /// 5 t_ref; 0.01 already takes a third of the saturated column's peak
    /// kinetic energy (docs/mpm.md, "FLIP, XPIC and fixed nodes"). Unused
    /// under `apic`, which keeps no grid-invisible velocity to filter.
    #[serde(default = "default_mpm_pic")]
    pub pic_fraction: f64,
    /// How the share `pic_fraction` is taken: 1, plain PIC blended into
    /// FLIP; 2, XPIC(2) (Hammerquist & Nairn 2017), which removes that share
    /// of the grid-invisible part of the point velocities and damps resolved
    /// motion far less (saturated lab runout 2.03 against PIC's 1.86 at the
    /// same share, pure FLIP 2.20). Default 2.
    #[serde(default = "default_xpic_order")]
    pub xpic_order: u32,
    /// Point–grid transfer: `aflip` (default; affine PIC with a share
    /// `flip_share` of the FLIP update blended in, the AFLIP of Fei et al.
    /// 2021: no grid-invisible velocities, so no filter, and little of
    /// APIC's own dissipation), `apic` (affine PIC alone, Jiang et al.
    /// 2015, the affine part C = B D⁻¹ carried per point) or `flip` (FLIP
    /// with the share `pic_fraction`). `pic_fraction` and `xpic_order` are
    /// unused but under `flip`. Why AFLIP: the lab columns' runout under
    /// APIC moved by 10–12 % when its dissipation was halved, under AFLIP
    /// by 0.3–2.6 %; FLIP + XPIC runs them out 2.3–3.0× further on the DEM's
    /// frictional floor and does not hold as the rough floor when the
    /// floor's friction is far above the soil's (docs/mpm.md, "Which
    /// transfer").
    #[serde(default)]
    pub transfer: MpmTransfer,
    /// Under `transfer = "aflip"` (unused, with a note, otherwise): share β
    /// of the FLIP update blended into APIC's for the solid points,
    /// v_p ← (1 − β) v_APIC + β v_FLIP, away from held nodes (points next to
    /// them, or to a frictional wall, take APIC's). APIC drops the part of
    /// the point velocities the grid cannot see each step (its numerical
    /// dissipation); β keeps that share of it over a step at courant 0.5
    /// (β^(C/0.5) over a step at courant C, `flip_share_basis`), so the
    /// dissipation scales with −ln β ≈ 1 − β: 0.95 halves the default's,
    /// 0.8 doubles it. Default 0.9 (`DEFAULT_FLIP_SHARE`), in [0, 1) (1
    /// would be FLIP without a filter).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub flip_share: Option<f64>,
    /// Under `transfer = "aflip"`: the same share for the liquid points.
    /// Default 0: the pore water stays on APIC. With K_L = 2e7 Pa a
    /// velocity the grid cannot see of 1 cm/s is ρ_L c Δv = 1.4 kPa of
    /// pore pressure; at 0.9 (0.95) for both phases the saturated lab
    /// column's worst liquid point reached 1.10× (1.19×) the spike bar,
    /// against 0.47× with the water on APIC, and the solid's runout moved
    /// by 3 % (docs/mpm.md, "Which transfer"). In [0, 1).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub liquid_flip_share: Option<f64>,
    /// What `flip_share` and `liquid_flip_share` are a share of:
    /// `reference_step` (default), the share kept over one step at
    /// courant 0.5 on this grid, so that a step of courant c keeps
    /// β^(c/0.5) and the dissipation is a rate per second whatever the
    /// step; `step`, the share kept over each step taken (before session
    /// 47), whose dissipation per second grows as 1/Δt. The same at the
    /// default courant 0.5. The reference step 0.5 h / c_max depends on
    /// c_max, so on the pressure scheme (the implicit scheme's is ~1.9×
    /// the explicit one's on the lab column): to compare the schemes at
    /// one step, set `"step"` (docs/mpm.md, "AFLIP's share per second").
    #[serde(default)]
    pub flip_share_basis: MpmFlipShareBasis,
    /// `k0` (default): effective stresses σ'_h = K0 σ'_v with K0 = ν/(1−ν)
    /// and hydrostatic pore pressure, then the gravity phase; `zero`:
    /// stress-free start (gravity applied suddenly at t = 0, no gravity phase).
    #[serde(default)]
    pub initial_stress: InitialStress,
    /// Gravity phase before t = 0, gates held: it ends when the fastest
    /// point is slower than `gravity_phase_rest_speed` (m/s, default 1e-4)
    /// or after `gravity_phase_max_time` (s, default 0.2), with local
    /// damping `gravity_phase_damping` (default 0.7).
    #[serde(default = "default_gravity_phase_time")]
    pub gravity_phase_max_time: f64,
    #[serde(default = "default_gravity_phase_damping")]
    pub gravity_phase_damping: f64,
    #[serde(default = "default_gravity_phase_rest")]
    pub gravity_phase_rest_speed: f64,
    /// Uniform vertical pressure on the top of the soil block from t = 0, Pa
    /// (a 1D consolidation load). Default 0.
    #[serde(default)]
    pub top_load: f64,
}

impl Default for MpmSpec {
    fn default() -> Self {
        toml::from_str("").expect("every [mpm] key has a default")
    }
}

/// I_0 of the rate-dependent friction when the scene gives none: Jop,
/// Forterre & Pouliquen (2006), glass beads down an incline.
pub const DEFAULT_REFERENCE_INERTIAL_NUMBER: f64 = 0.279;

impl MpmSpec {
    /// I_0 of the rate-dependent friction: `reference_inertial_number`,
    /// default [`DEFAULT_REFERENCE_INERTIAL_NUMBER`].
    pub fn reference_inertial_number_in_effect(&self) -> f64 {
        self.reference_inertial_number.unwrap_or(DEFAULT_REFERENCE_INERTIAL_NUMBER)
    }

    /// The FLIP share β in effect: `flip_share` (default 0.9) under `aflip`,
    /// 0 otherwise.
    pub fn flip_share_in_effect(&self) -> f64 {
        match self.transfer {
            MpmTransfer::Aflip => self.flip_share.unwrap_or(DEFAULT_FLIP_SHARE),
            _ => 0.0,
        }
    }

    /// `surface_elements` in effect: as set, else `hydrostatic` under the
    /// implicit scheme and `free` under the explicit one.
    pub fn surface_elements_in_effect(&self) -> MpmSurfaceElements {
        self.surface_elements.unwrap_or(match self.pressure_scheme {
            MpmPressureScheme::Implicit => MpmSurfaceElements::Hydrostatic,
            MpmPressureScheme::Explicit => MpmSurfaceElements::Free,
        })
    }

    /// The liquid points' FLIP share in effect: `liquid_flip_share`
    /// (default 0) under `aflip`, 0 otherwise.
    pub fn liquid_flip_share_in_effect(&self) -> f64 {
        match self.transfer {
            MpmTransfer::Aflip => self.liquid_flip_share.unwrap_or(0.0),
            _ => 0.0,
        }
    }

    /// The FLIP shares (solid, liquid) kept over each step taken: the
    /// shares in effect under `flip_share_basis = "step"`, raised to
    /// `courant / FLIP_SHARE_REFERENCE_COURANT` under `"reference_step"`
    /// (exactly the shares at the reference courant).
    pub fn flip_shares_per_step(&self) -> [f64; 2] {
        let shares = [self.flip_share_in_effect(), self.liquid_flip_share_in_effect()];
        match self.flip_share_basis {
            MpmFlipShareBasis::Step => shares,
            MpmFlipShareBasis::ReferenceStep if self.courant == FLIP_SHARE_REFERENCE_COURANT => shares,
            MpmFlipShareBasis::ReferenceStep => {
                shares.map(|beta| beta.powf(self.courant / FLIP_SHARE_REFERENCE_COURANT))
            }
        }
    }

    /// The sub-grid of the material points of one phase in an initially
    /// filled element: (a along x, b along z) with a·b =
    /// `points_per_element`, a ≥ b and a − b as small as possible (12 →
    /// (4, 3), 8 → (4, 2), 9 → (3, 3)). Validation accepts a count only
    /// when a ≤ 3b ([`point_grid_of`]); (0, 0) for 0.
    pub fn point_grid(&self) -> (u32, u32) {
        point_grid_of(self.points_per_element)
    }
}

/// (a, b) with a·b = n, a ≥ b, a − b minimal: b is the largest divisor of n
/// not above √n. (0, 0) for n = 0.
pub fn point_grid_of(n: u32) -> (u32, u32) {
    if n == 0 {
        return (0, 0);
    }
    let mut b = (n as f64).sqrt().floor() as u32;
    while b * b > n {
        b -= 1;
    }
    while !n.is_multiple_of(b) {
        b -= 1;
    }
    (n / b, b)
}

/// Whether `n` material points per element make a sub-grid `MpmSpec`
/// accepts: a·b = n with a ≤ 3b (so no sliver of 5 × 1 or 7 × 1 points).
pub fn point_count_fits(n: u32) -> bool {
    let (a, b) = point_grid_of(n);
    n > 0 && a <= 3 * b
}

fn default_mpm_element() -> f64 {
    0.004
}
fn default_mpm_points() -> u32 {
    12
}
fn default_mpm_courant() -> f64 {
    DEFAULT_MPM_COURANT
}
fn default_mpm_young() -> f64 {
    1.0e7
}
fn default_mpm_poisson() -> f64 {
    0.3
}
fn default_mpm_friction() -> f64 {
    35.0
}
fn default_mpm_bulk() -> f64 {
    2.0e7
}
fn default_mpm_nmax() -> f64 {
    0.5
}
fn default_mpm_damping() -> f64 {
    0.02
}
fn default_ergun_a() -> f64 {
    150.0
}
fn default_ergun_b() -> f64 {
    1.75
}
fn default_xpic_order() -> u32 {
    2
}
fn default_mpm_pic() -> f64 {
    0.001
}
fn default_mpm_fill() -> f64 {
    0.8
}
fn default_mpm_air_pressure() -> f64 {
    101_325.0
}
fn default_gravity_phase_time() -> f64 {
    0.2
}
fn default_gravity_phase_damping() -> f64 {
    0.7
}
fn default_gravity_phase_rest() -> f64 {
    1.0e-4
}

/// MPM shape functions.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ShapeFunctions {
    /// Uniform GIMP (Bardenhagen & Kober 2004): each point a square of its
    /// initial spacing; weights and gradients continuous across cell edges.
    #[default]
    Gimp,
    /// Bilinear nodal functions evaluated at the point (plain MPM).
    Linear,
}

impl ShapeFunctions {
    /// The scene name: `gimp` or `linear`.
    pub fn name(self) -> &'static str {
        match self {
            ShapeFunctions::Gimp => "gimp",
            ShapeFunctions::Linear => "linear",
        }
    }
}

/// How the MPM floor holds the soil.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum MpmFloor {
    /// Both phases fixed in both directions (no slip).
    #[default]
    Rough,
    /// Normal velocity fixed; the solid slides with Coulomb friction
    /// `wall_friction`, the liquid under `liquid_wall_shear`.
    Frictional,
}

/// How an MPM wall holds the normal velocity (`mpm.wall_contact`).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum MpmWallContact {
    /// Held both ways: material pulled off the wall stays on it.
    Bilateral,
    /// Held only while the material pushes into the wall.
    #[default]
    Unilateral,
}

/// Where an MPM wall's friction acts (`mpm.wall_friction_reach`).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum MpmWallFrictionReach {
    /// On the wall node only.
    #[default]
    WallNode,
    /// On the wall node, and what it cannot take on the next node off the wall.
    NextNode,
}

/// How MPM points touching a frictional wall update their velocity along
/// it (`mpm.wall_tangent_update`).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum MpmWallTangentUpdate {
    /// The grid's velocity in both directions, every step.
    Grid,
    /// The grid's velocity along held components only; along the wall
    /// the transfer's own update.
    #[default]
    Blend,
}

/// The shear slip walls put on the MPM liquid (`mpm.liquid_wall_shear`).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum MpmLiquidWallShear {
    /// Free slip: the walls hold the liquid's normal velocity only.
    None,
    /// A laminar film's depth-averaged wall shear, 3 μ Ū / d, d the
    /// liquid's depth over the part of each line's strip it covers.
    #[default]
    LaminarFilm,
    /// The same with d the depth the line's liquid mass stands for over
    /// its whole strip (session 45's reading): a line the liquid covers
    /// only in part is slowed too fast, by 1/c² at a share c covered.
    LaminarFilmLineMass,
}

/// How MPM points and grid exchange velocities.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum MpmTransfer {
    /// FLIP with a PIC/XPIC share (`pic_fraction`, `xpic_order`).
    Flip,
    /// Affine PIC: points take the grid velocity and its affine part.
    Apic,
    /// Affine PIC with a share `flip_share` of the FLIP update (Fei et al. 2021).
    #[default]
    Aflip,
}

impl MpmTransfer {
    /// Whether points carry an affine velocity part (APIC and AFLIP).
    pub fn is_affine(self) -> bool {
        self != MpmTransfer::Flip
    }
}

/// The FLIP share of the default `aflip` transfer (`MpmSpec::flip_share`):
/// raised to 0.95 (the remaining dissipation halved) it moves the lab
/// columns' runouts by +0.3 % dry and −0.7 % saturated at 4 mm, +1.7 % and
/// −2.6 % at 2 mm (docs/mpm.md, "Which transfer (session 18)").
pub const DEFAULT_FLIP_SHARE: f64 = 0.9;

/// The default `mpm.courant`.
pub const DEFAULT_MPM_COURANT: f64 = 0.5;

/// The courant number at whose step `flip_share` is the share kept under
/// `flip_share_basis = "reference_step"`: the default `courant`, so that
/// the default scenes blend as before session 47, bit for bit.
pub const FLIP_SHARE_REFERENCE_COURANT: f64 = DEFAULT_MPM_COURANT;

/// What AFLIP's FLIP share is a share of (`MpmSpec::flip_share_basis`).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum MpmFlipShareBasis {
    /// The share kept over one step at courant 0.5: a dissipation per
    /// second, whatever the step.
    #[default]
    ReferenceStep,
    /// The share kept over every step taken: a dissipation per step.
    Step,
}

impl MpmFlipShareBasis {
    /// What the share is kept over, for logs and plans.
    pub fn kept_over(self) -> &'static str {
        match self {
            MpmFlipShareBasis::ReferenceStep => "kept over a courant-0.5 step",
            MpmFlipShareBasis::Step => "kept over each step",
        }
    }
}

/// How the pore pressure is advanced (`MpmSpec::pressure_scheme`).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum MpmPressureScheme {
    /// Weakly compressible, per liquid point, from the last step's strain.
    Explicit,
    /// Semi-implicit: one SPD system per step for the element pressures.
    #[default]
    Implicit,
}

/// The pore pressure of a part-filled element whose occupied part is
/// saturated (`MpmSpec::surface_elements`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum MpmSurfaceElements {
    /// p = 0, as a drained element.
    Free,
    /// The hydrostatic pressure of its layer on the element's nodes.
    Hydrostatic,
}

/// How an element's liquid points' pore pressures are tied together.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum MpmPressureReconstruction {
    /// A least-squares plane per element, refitted every step.
    #[default]
    Linear,
    /// Each point keeps its own pressure history.
    None,
}

/// A note when keys of another transfer are set but unused: the FLIP-only
/// `pic_fraction` and `xpic_order` (differing from their defaults) under
/// APIC or AFLIP, and the AFLIP-only `flip_share` under APIC or FLIP (a
/// scene written for one transfer, run with `--set mpm.transfer=...`).
pub fn unused_flip_keys(m: &MpmSpec) -> Option<String> {
    let name = match m.transfer {
        MpmTransfer::Flip => "flip",
        MpmTransfer::Apic => "apic",
        MpmTransfer::Aflip => "aflip",
    };
    let changed = m.pic_fraction != default_mpm_pic() || m.xpic_order != default_xpic_order();
    let mut notes = Vec::new();
    if m.transfer.is_affine() && changed {
        notes.push(format!(
            "mpm.pic_fraction = {} and mpm.xpic_order = {} are unused under mpm.transfer = \"{name}\" (no filter); set mpm.transfer = \"flip\" to use them, or remove them",
            m.pic_fraction, m.xpic_order
        ));
    }
    for (key, set) in [("flip_share", m.flip_share), ("liquid_flip_share", m.liquid_flip_share)] {
        if let (Some(share), MpmTransfer::Apic | MpmTransfer::Flip) = (set, m.transfer) {
            notes.push(format!(
                "mpm.{key} = {share} is unused under mpm.transfer = \"{name}\" (it blends FLIP into APIC under \"aflip\"; under \"flip\" the PIC share is mpm.pic_fraction)"
            ));
        }
    }
    if m.flip_share_basis != MpmFlipShareBasis::default() && m.transfer != MpmTransfer::Aflip {
        notes.push(format!(
            "mpm.flip_share_basis = \"step\" is unused under mpm.transfer = \"{name}\" (it says what AFLIP's mpm.flip_share is a share of)"
        ));
    }
    (!notes.is_empty()).then(|| notes.join("; "))
}

/// How the MPM soil's stresses start.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum InitialStress {
    /// K0 effective stresses and hydrostatic pore pressure, then a damped gravity phase.
    #[default]
    K0,
    /// No initial stress, no gravity phase.
    Zero,
}

/// DEM contact law and numerics (paper Eqs. 1–3, Table 2).
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DemSpec {
    /// k_n, N/m.
    pub normal_stiffness: f64,
    /// k_t / k_n. Default 2/7.
    #[serde(default = "default_tangential_ratio")]
    pub tangential_stiffness_ratio: f64,
    /// Normal coefficient of restitution e ∈ (0, 1]; the damping is derived from it.
    pub restitution: f64,
    /// Sliding friction μ_s between grains.
    pub friction: f64,
    /// Rolling friction μ_r between grains.
    pub rolling_friction: f64,
    /// Sliding friction grain–wall. Default: `friction`.
    #[serde(default)]
    pub wall_friction: Option<f64>,
    /// Rolling friction grain–wall. Default: `rolling_friction`.
    #[serde(default)]
    pub wall_rolling_friction: Option<f64>,
    /// Time step, s. Default: contact duration / `steps_per_contact`.
    #[serde(default)]
    pub time_step: Option<f64>,
    /// Steps per grain–grain contact duration when `time_step` is not given. Default 25.
    #[serde(default = "default_steps_per_contact")]
    pub steps_per_contact: f64,
    /// Verlet skin as a fraction of the largest diameter. Default 0.15.
    #[serde(default = "default_skin")]
    pub neighbour_skin: f64,
    /// Steps between spatial re-sorts of the grain storage (cache locality,
    /// as LAMMPS's `atom_modify sort`); 0 never re-sorts. Grain ids stay
    /// fixed; only the storage order (and so the summation order) changes.
    /// Default 1000.
    #[serde(default = "default_sort_interval")]
    pub sort_interval: u64,
}

fn default_tangential_ratio() -> f64 {
    2.0 / 7.0
}
fn default_steps_per_contact() -> f64 {
    25.0
}
fn default_skin() -> f64 {
    0.15
}
fn default_sort_interval() -> u64 {
    1000
}

/// How `dem_proc` and `lbm_proc` exchange particle states and hydrodynamic
/// loads (DESIGN §2, docs/coupling.md).
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CouplingSpec {
    /// DEM steps per LBM step: the DEM time step is `lbm.time_step / ratio`.
    /// Default 57 (the paper's 8e-5 s / 1.4e-6 s).
    #[serde(default = "default_coupling_ratio")]
    pub ratio: u32,
    /// `sequential` (LBM step n sees the grains at t_n, then the DEM advances
    /// `ratio` steps with that load) or `concurrent` (both advance at once,
    /// the DEM holding the load of the previous exchange). Default `sequential`.
    #[serde(default)]
    pub schedule: Schedule,
    /// How strongly a cell that a grain covers only partly is forced toward
    /// the grain's velocity: `noble_torczynski` (default),
    /// `noble_torczynski_effective`, `covered_fraction` or `centre_inside`
    /// (see [`ForcingGain`]).
    #[serde(default)]
    pub forcing_gain: ForcingGain,
}

impl Default for CouplingSpec {
    fn default() -> Self {
        Self { ratio: default_coupling_ratio(), schedule: Schedule::default(), forcing_gain: ForcingGain::default() }
    }
}

/// The rule for the gain b of the direct forcing F_IB = b [2(ρU − Σ f e) − ρa] in a cell
/// whose covered fraction is w (weight × fill). A fully covered cell
/// (w = 1) has b = 1 under every rule: its liquid moves with the grain.
/// The rules differ in how a grain's surface cells (0 < w < 1) are pulled;
/// their errors against sphere-array drag, packed-bed permeability and
/// Ergun's drag are measured in docs/coupling.md, "Choosing the forcing
/// gain" (`cargo run --release -p lbm_proc --example coupling_study`).
/// The LBM evaluates it (`lbm_proc::fluid::forcing_gain`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ForcingGain {
    /// b = w(τ0 − ½)/((1 − w) + (τ0 − ½)), the solid-fraction weighting of
    /// Noble & Torczynski (1998) with the molecular τ0. A partly covered
    /// cell's liquid is pulled to the grain's velocity at the rate viscosity
    /// would pull it: as τ0 → ½ (water at the paper's Δx, Δt: τ0 = 0.50067)
    /// only the fully covered cells are forced, and the pore liquid between
    /// grains flows as freely as its inertia allows.
    #[default]
    NobleTorczynski,
    /// Noble & Torczynski's weighting with each cell's effective τ, eddy
    /// viscosity included: τ_eff from the Smagorinsky closure (Eq. 4) on the
    /// cell's populations before the forcing (uniform body force only), so
    /// that a grain surface in a sheared pore is pulled as strongly as the
    /// pore's effective viscosity would pull it. Equal to
    /// `noble_torczynski` without Smagorinsky.
    NobleTorczynskiEffective,
    /// b = w: every covered cell is pulled the covered fraction of the way
    /// each step, whatever the viscosity (the immersed-boundary weighting
    /// of Feng & Michaelides 2005 and of HYBIRD's Eq. 5 with a solid
    /// fraction). At τ0 → ½ it is a drag far stronger than the viscous one
    /// on the pore liquid.
    CoveredFraction,
    /// b = 1 where the cell centre lies inside the grain (w ≥ ½ under the
    /// coupling's linear covering ramp), else 0: Eq. 5 applied to "the
    /// fluid cells within each particle", a staircase sphere of the right
    /// volume, independent of τ.
    CentreInside,
}

impl ForcingGain {
    /// Every rule, in the order docs/coupling.md lists them.
    pub const ALL: [ForcingGain; 4] = [
        ForcingGain::NobleTorczynski,
        ForcingGain::NobleTorczynskiEffective,
        ForcingGain::CoveredFraction,
        ForcingGain::CentreInside,
    ];

    pub fn name(self) -> &'static str {
        match self {
            ForcingGain::NobleTorczynski => "noble_torczynski",
            ForcingGain::NobleTorczynskiEffective => "noble_torczynski_effective",
            ForcingGain::CoveredFraction => "covered_fraction",
            ForcingGain::CentreInside => "centre_inside",
        }
    }
}

fn default_coupling_ratio() -> u32 {
    57
}

/// Order of the DEM and LBM work within one exchange.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Schedule {
    /// LBM step n uses the grains at t_n; the DEM then advances with its load.
    #[default]
    Sequential,
    /// DEM and LBM advance at once; the DEM holds the load of exchange n − 1.
    Concurrent,
}

impl Schedule {
    pub fn name(self) -> &'static str {
        match self {
            Schedule::Sequential => "sequential",
            Schedule::Concurrent => "concurrent",
        }
    }
}

/// Gravity deposition that builds the initial packing.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DepositionSpec {
    /// Grain–grain and grain–wall sliding friction during deposition. Lower
    /// values give denser packings. Default 0.1.
    #[serde(default = "default_deposition_friction")]
    pub friction: f64,
    /// Rolling friction during deposition. Default 0.
    #[serde(default)]
    pub rolling_friction: f64,
    /// The packing is at rest when the fastest grain is slower than this, m/s. Default 0.01.
    #[serde(default = "default_rest_speed")]
    pub rest_speed: f64,
    /// Give up (with an error) after this much simulated time, s. Default 3.
    #[serde(default = "default_deposition_time")]
    pub max_time: f64,
    /// Reuse a packing settled before from the same inputs. Default true.
    #[serde(default = "default_true")]
    pub cache: bool,
}

impl Default for DepositionSpec {
    fn default() -> Self {
        Self {
            friction: default_deposition_friction(),
            rolling_friction: 0.0,
            rest_speed: default_rest_speed(),
            max_time: default_deposition_time(),
            cache: true,
        }
    }
}

fn default_deposition_friction() -> f64 {
    0.1
}
fn default_rest_speed() -> f64 {
    0.01
}
fn default_deposition_time() -> f64 {
    3.0
}
fn default_true() -> bool {
    true
}

#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct OutputSpec {
    /// Simulated time of the run after the packing is ready, s.
    pub end_time: f64,
    /// Interval between recorded frames, s.
    pub record_interval: f64,
    /// Interval between full-precision state frames, s. Default: 5 × `record_interval`.
    #[serde(default)]
    pub state_interval: Option<f64>,
    /// Interval between checkpoints, s of simulated time: each process's
    /// full state on disk (`checkpoints/` in the output directory), from
    /// which `coupler run --resume DIR` continues a killed run bit for bit
    /// (docs/RELIABILITY.md). Rounded to whole steps (coupled: whole
    /// exchanges). Default: none.
    #[serde(default)]
    pub checkpoint_interval: Option<f64>,
    /// End early, after all gates are released, once at most `rest_fraction`
    /// of the grain mass moves faster than `rest_speed` on three recorded
    /// frames in a row. Default true.
    #[serde(default = "default_true")]
    pub stop_at_rest: bool,
    /// m/s. Default 0.005.
    #[serde(default = "default_final_rest_speed")]
    pub rest_speed: f64,
    /// Mass fraction allowed to keep moving at rest. Default 0.01: in the dry
    /// columns ~0.5 % of the mass, grains thrown off the front, rolls on the
    /// floor for seconds after the pile has stopped (μ_r = 0.05 decelerates a
    /// lone sphere at only ~0.35 m/s²).
    #[serde(default = "default_rest_fraction")]
    pub rest_fraction: f64,
    /// Also record every grain as a sphere of its true radius
    /// (`foxglove.SceneUpdate`, ~0.1 kB per grain per frame). Default false.
    #[serde(default)]
    pub spheres: bool,
    /// Coupled runs: each process also records every message it receives
    /// from its peer (`/dem/received_loads`, `/lbm/received_states`), so that
    /// either process can later run alone against the recording
    /// (`--replay-peer RUN.mcap`) and reproduce its part bit for bit.
    /// ~0.4 MB per exchange for 8000 grains. Default false.
    #[serde(default)]
    pub record_exchange: bool,
}

fn default_final_rest_speed() -> f64 {
    0.005
}
fn default_rest_fraction() -> f64 {
    0.01
}

/// Measures of the collapse (paper §2).
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AnalysisSpec {
    /// Initial column length L0 along x, m (from the back wall to the gate).
    pub column_length: f64,
    /// Initial column height H0, m.
    pub column_height: f64,
    /// `dry` (t_ref = √(H0/g)), `saturated` (t_ref = √(H0/g′)) or `liquid` (t_ref = √(H0/g)).
    pub condition: Condition,
    /// Mass fraction beyond the front, default 0.005 (0.5 %).
    #[serde(default = "default_front_fraction")]
    pub front_mass_fraction: f64,
    /// Bin width of the deposit profile along x, m. Default: largest grain diameter.
    #[serde(default)]
    pub deposit_bin: Option<f64>,
}

fn default_front_fraction() -> f64 {
    0.005
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Condition {
    /// Grains in air: t_ref = √(H0/g).
    Dry,
    /// Grains in liquid: t_ref = √(H0/g′), g′ = g(ρ_s − ρ_L)/ρ_s.
    Saturated,
    /// A liquid column without grains (dam break): t_ref = √(H0/g).
    Liquid,
}

// ---------------------------------------------------------------------------
// Checked scene
// ---------------------------------------------------------------------------

/// A validated scene. Constructed only by [`Scene::from_toml_str`] / [`Scene::load`].
#[derive(Debug, Clone)]
pub struct Scene {
    /// The spec after overrides, as validated (serialise it to reproduce the run).
    pub spec: SceneSpec,
    /// Directory relative paths in the scene resolve against.
    pub base_dir: PathBuf,
    /// Unit normals of the gates, in `spec.gates` order.
    pub gate_normals: Vec<[f64; 3]>,
    /// Explicit grains loaded from files or inline, per block (empty for deposit blocks).
    pub explicit_spheres: Vec<Vec<[f64; 4]>>,
}

/// Which solver processes a scene needs.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Method {
    /// Grains only: `dem_proc`. Scene name `dem`.
    #[serde(rename = "dem")]
    DemDry,
    /// Liquid only: `lbm_proc`. Scene name `lbm`.
    #[serde(rename = "lbm")]
    LbmFluid,
    /// Grains and liquid: `dem_proc` + `lbm_proc`.
    DemLbm,
    /// Two-phase double-point MPM (2D plane strain): `mpm_proc`.
    Mpm,
}

impl Method {
    pub fn name(self) -> &'static str {
        match self {
            Method::DemDry => "dem",
            Method::LbmFluid => "lbm",
            Method::DemLbm => "dem_lbm",
            Method::Mpm => "mpm",
        }
    }
}

impl Scene {
    /// Reads, overrides and validates a scene file.
    pub fn load(path: &Path, overrides: &[String]) -> Result<Scene, SceneError> {
        let text = std::fs::read_to_string(path)
            .map_err(|e| SceneError::new("", format!("cannot read scene file {}: {e}", path.display())))?;
        let base = path.parent().map(Path::to_path_buf).unwrap_or_default();
        Self::from_toml_str(&text, &base, overrides)
    }

    /// Parses TOML text, applies `KEY.PATH=VALUE` overrides, validates.
    pub fn from_toml_str(text: &str, base_dir: &Path, overrides: &[String]) -> Result<Scene, SceneError> {
        let mut value: toml::Value =
            toml::from_str(text).map_err(|e| SceneError::new("", format!("not valid TOML: {}", e.message().trim())))?;
        for ov in overrides {
            apply_override(&mut value, ov)?;
        }
        let spec: SceneSpec = serde_path_to_error::deserialize(value).map_err(|e| {
            let path = e.path().to_string();
            let path = if path == "." { String::new() } else { path };
            SceneError::new(path, e.into_inner().message().trim().to_string())
        })?;
        Self::validate(spec, base_dir)
    }

    fn validate(spec: SceneSpec, base_dir: &Path) -> Result<Scene, SceneError> {
        let mut v = Validator::default();
        v.nonempty("scene.name", &spec.scene.name);
        if !spec.scene.name.chars().all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-') {
            v.fail("scene.name", format!("use letters, digits, '_' and '-' only, got {:?}", spec.scene.name));
        }

        check_domain(&mut v, &spec.domain);
        let gate_normals = check_gates(&mut v, &spec.gates);
        let explicit_spheres = check_particles(&mut v, &spec, base_dir);
        // The MPM reads neither [dem] nor [lbm]: one file can drive both
        // methods, and under `mpm` those tables are ignored, not checked.
        let mpm = method_of(&spec) == Method::Mpm;
        check_solver_tables(&mut v, &spec, mpm);
        check_run_tables(&mut v, &spec, mpm);
        if let Some(m) = &spec.mpm {
            check_mpm_values(&mut v, m);
        }
        if mpm {
            check_mpm_scene(&mut v, &spec, &gate_normals);
        } else if let Some(named) = spec.scene.method {
            check_method_matches_blocks(&mut v, &spec, named);
        }
        check_collapse_gravity(&mut v, &spec);

        v.finish()?;
        Ok(Scene { spec, base_dir: base_dir.to_path_buf(), gate_normals, explicit_spheres })
    }

    /// The processes this scene needs: `scene.method` when set, else from
    /// the blocks (grains only `dem`, liquid only `lbm`, both `dem_lbm`).
    pub fn method(&self) -> Method {
        method_of(&self.spec)
    }

    /// The DEM table; present whenever the scene has grains and the method
    /// is not `mpm` (checked at load).
    pub fn dem(&self) -> &DemSpec {
        self.spec.dem.as_ref().expect("validated: non-MPM scenes with particles have [dem]")
    }

    /// The MPM table, its defaults where the scene has none.
    pub fn mpm(&self) -> MpmSpec {
        self.spec.mpm.clone().unwrap_or_default()
    }

    /// The LBM table; present whenever the scene has fluids and the method
    /// is not `mpm` (checked at load).
    pub fn lbm(&self) -> &LbmSpec {
        self.spec.lbm.as_ref().expect("validated: non-MPM scenes with fluids have [lbm]")
    }

    /// The gravity the run itself feels, m/s²: `domain.collapse_gravity`
    /// where the scene sets one, else `domain.gravity` (the preparation's).
    pub fn run_gravity(&self) -> [f64; 3] {
        self.spec.domain.collapse_gravity.unwrap_or(self.spec.domain.gravity)
    }

    /// |g|, m/s².
    pub fn gravity_magnitude(&self) -> f64 {
        norm(self.spec.domain.gravity)
    }

    /// Reference time of the collapse: √(H0/g) dry, √(H0/g′) saturated with
    /// g′ = g(ρ_s − ρ_L)/ρ_s using the first particle and fluid blocks.
    pub fn reference_time(&self) -> f64 {
        let g = self.gravity_magnitude();
        let h0 = self.spec.analysis.column_height;
        let g_eff = match self.spec.analysis.condition {
            Condition::Dry | Condition::Liquid => g,
            Condition::Saturated => {
                let rho_s = self.spec.particles.first().map(|p| p.density).unwrap_or(f64::NAN);
                let rho_l = self.spec.fluids.first().map(|f| f.density).unwrap_or(0.0);
                g * (rho_s - rho_l) / rho_s
            }
        };
        (h0 / g_eff).sqrt()
    }

    /// The scene as TOML, after overrides: what a run actually used. Self-contained:
    /// grains read from files are written inline, so the file reloads anywhere.
    pub fn to_toml(&self) -> String {
        let mut spec = self.spec.clone();
        for (b, block) in spec.particles.iter_mut().enumerate() {
            if let PackingSpec::Explicit { spheres, file, .. } = &mut block.packing {
                *spheres = self.explicit_spheres[b].clone();
                *file = None;
            }
        }
        toml::to_string_pretty(&spec).expect("scene spec serialises")
    }
}

/// `[domain]`: finite bounds, max above min, each wall face once.
fn check_domain(v: &mut Validator, d: &DomainSpec) {
    for a in 0..3 {
        v.finite(&format!("domain.min[{a}]"), d.min[a]);
        v.finite(&format!("domain.max[{a}]"), d.max[a]);
        v.finite(&format!("domain.gravity[{a}]"), d.gravity[a]);
        if let Some(g) = d.collapse_gravity {
            v.finite(&format!("domain.collapse_gravity[{a}]"), g[a]);
        }
        if d.max[a] <= d.min[a] {
            v.fail(&format!("domain.max[{a}]"), format!("must be > domain.min[{a}] = {}, got {}", d.min[a], d.max[a]));
        }
    }
    for (i, f) in d.walls.iter().enumerate() {
        if d.walls[..i].contains(f) {
            v.fail("domain.walls", format!("face {} listed twice", f.name()));
        }
    }
}

/// `domain.collapse_gravity`: only where no LBM runs (its liquid starts
/// hydrostatic under `gravity`), in the MPM's plane for the MPM.
fn check_collapse_gravity(v: &mut Validator, spec: &SceneSpec) {
    let Some(g) = spec.domain.collapse_gravity else { return };
    if norm(g) == 0.0 {
        v.fail(
            "domain.collapse_gravity",
            "a run without gravity has nothing to collapse: give a non-zero vector, or remove the key to run under domain.gravity".into(),
        );
    }
    match method_of(spec) {
        Method::DemDry => {}
        Method::Mpm if g[1] != 0.0 => v.fail(
            "domain.collapse_gravity",
            format!("the MPM is 2D in the x–z plane: collapse_gravity[1] must be 0, got {g:?}"),
        ),
        Method::Mpm => {}
        Method::LbmFluid | Method::DemLbm => v.fail(
            "domain.collapse_gravity",
            "the LBM's liquid is prepared hydrostatic under domain.gravity and cannot change gravity at release: remove collapse_gravity, or run the grains alone (method dem or mpm)".into(),
        ),
    }
}

/// `[[gates]]`: at most 26, named, finite, a non-zero normal (returned
/// normalised, one per gate), a release time ≥ 0.
fn check_gates(v: &mut Validator, gates: &[GateSpec]) -> Vec<[f64; 3]> {
    if gates.len() > 26 {
        v.fail("gates", format!("at most 26 gates (32 walls with the box faces), got {}", gates.len()));
    }
    let mut gate_normals = Vec::new();
    for (g, gate) in gates.iter().enumerate() {
        let key = format!("gates[{g}]");
        v.nonempty(&format!("{key}.name"), &gate.name);
        v.finite_vec(&format!("{key}.point"), &gate.point);
        v.finite_vec(&format!("{key}.normal"), &gate.normal);
        let n = norm(gate.normal);
        if n == 0.0 || !n.is_finite() {
            v.fail(&format!("{key}.normal"), "must be a non-zero vector".into());
            gate_normals.push([1.0, 0.0, 0.0]);
        } else {
            gate_normals.push([gate.normal[0] / n, gate.normal[1] / n, gate.normal[2] / n]);
        }
        v.at_least(&format!("{key}.release_time"), gate.release_time, 0.0);
    }

    gate_normals
}

/// `[[particles]]`: material values and the packing, deposited in a region
/// or explicit (inline or from a CSV beside the scene). Returns each
/// block's explicit spheres (empty for deposits).
fn check_particles(v: &mut Validator, spec: &SceneSpec, base_dir: &Path) -> Vec<Vec<[f64; 4]>> {
    let d = &spec.domain;
    let mut explicit_spheres = Vec::new();
    for (b, block) in spec.particles.iter().enumerate() {
        let key = format!("particles[{b}]");
        v.nonempty(&format!("{key}.name"), &block.name);
        v.positive(&format!("{key}.density"), block.density);
        v.positive(&format!("{key}.diameter"), block.diameter);
        v.in_range(&format!("{key}.diameter_spread"), block.diameter_spread, 0.0, 0.9);
        let mut spheres = Vec::new();
        match &block.packing {
            PackingSpec::Deposit { region, porosity, count, .. } => {
                v.region(&format!("{key}.packing.region"), region, d);
                let d_max = block.diameter * (1.0 + block.diameter_spread);
                for a in 0..2 {
                    let width = region.max[a] - region.min[a];
                    if width < d_max {
                        v.fail(
                            &format!("{key}.packing.region"),
                            format!("is {width} m wide along {}, narrower than the largest grain ({d_max} m); diameters are in metres", ["x", "y"][a]),
                        );
                    }
                }
                match (porosity, count) {
                    (Some(_), Some(_)) | (None, None) => {
                        v.fail(&format!("{key}.packing"), "give exactly one of `porosity` and `count`".into())
                    }
                    (Some(n), None) => v.open_range(&format!("{key}.packing.porosity"), *n, 0.25, 1.0),
                    (None, Some(c)) => {
                        if *c == 0 {
                            v.fail(&format!("{key}.packing.count"), "must be > 0, got 0".into());
                        }
                    }
                }
            }
            PackingSpec::Explicit { spheres: inline, file, velocity } => {
                v.finite_vec(&format!("{key}.packing.velocity"), velocity);
                spheres.extend_from_slice(inline);
                if let Some(f) = file {
                    let p = base_dir.join(f);
                    match read_sphere_csv(&p) {
                        Ok(s) => spheres.extend(s),
                        Err(e) => v.fail(&format!("{key}.packing.file"), e),
                    }
                }
                if spheres.is_empty() {
                    v.fail(
                        &format!("{key}.packing"),
                        "an explicit packing needs `spheres` or `file` with at least one grain".into(),
                    );
                }
                for (i, s) in spheres.iter().enumerate() {
                    let k = format!("{key}.packing.spheres[{i}]");
                    if s.iter().any(|x| !x.is_finite()) || s[3] <= 0.0 {
                        v.fail(&k, format!("needs finite x, y, z and a diameter > 0, got {s:?}"));
                    } else if (0..3).any(|a| s[a] < d.min[a] || s[a] > d.max[a]) {
                        v.fail(&k, format!("centre {:?} lies outside the domain", &s[..3]));
                    }
                }
            }
        }
        explicit_spheres.push(spheres);
    }

    for (f, fluid) in spec.fluids.iter().enumerate() {
        let key = format!("fluids[{f}]");
        v.nonempty(&format!("{key}.name"), &fluid.name);
        v.positive(&format!("{key}.density"), fluid.density);
        v.positive(&format!("{key}.viscosity"), fluid.viscosity);
        v.region(&format!("{key}.region"), &fluid.region, d);
    }

    explicit_spheres
}

/// `[[fluids]]`, `[dem]`, `[lbm]` and `[coupling]` (the last three only
/// outside the MPM, which reads none of them).
fn check_solver_tables(v: &mut Validator, spec: &SceneSpec, mpm: bool) {
    let d = &spec.domain;
    if !mpm && !spec.particles.is_empty() && spec.dem.is_none() {
        v.fail("dem", "the scene has particle blocks, so it needs a [dem] table with the contact parameters".into());
    }
    if let Some(dem) = spec.dem.as_ref().filter(|_| !mpm) {
        v.positive("dem.normal_stiffness", dem.normal_stiffness);
        v.in_range("dem.tangential_stiffness_ratio", dem.tangential_stiffness_ratio, 0.0, 1.0);
        v.half_open("dem.restitution", dem.restitution, 0.0, 1.0);
        v.at_least("dem.friction", dem.friction, 0.0);
        v.at_least("dem.rolling_friction", dem.rolling_friction, 0.0);
        if let Some(x) = dem.wall_friction {
            v.at_least("dem.wall_friction", x, 0.0);
        }
        if let Some(x) = dem.wall_rolling_friction {
            v.at_least("dem.wall_rolling_friction", x, 0.0);
        }
        if let Some(dt) = dem.time_step {
            v.positive("dem.time_step", dt);
        }
        v.in_range("dem.steps_per_contact", dem.steps_per_contact, 5.0, 1e6);
        v.in_range("dem.neighbour_skin", dem.neighbour_skin, 0.01, 2.0);
    }

    if !mpm && !spec.fluids.is_empty() && spec.lbm.is_none() {
        v.fail(
            "lbm",
            "the scene has fluid blocks, so it needs an [lbm] table with at least `spacing` and `time_step`".into(),
        );
    }
    if let Some(lbm) = spec.lbm.as_ref().filter(|_| !mpm) {
        v.positive("lbm.spacing", lbm.spacing);
        v.positive("lbm.time_step", lbm.time_step);
        v.at_least("lbm.smagorinsky", lbm.smagorinsky, 0.0);
        v.open_range("lbm.trt_magic", lbm.trt_magic, 0.0, 10.0);
        v.open_range("lbm.mach_limit", lbm.mach_limit, 0.0, 1.0);
        if lbm.hydrostatics == Hydrostatics::Buoyancy {
            let fills =
                spec.fluids.iter().any(|f| (0..3).all(|a| f.region.min[a] <= d.min[a] && f.region.max[a] >= d.max[a]));
            let closed = Face::ALL.iter().all(|face| d.walls.contains(face));
            if !fills || !closed || !spec.gates.is_empty() {
                v.fail(
                    "lbm.hydrostatics",
                    "\"buoyancy\" leaves the liquid's weight off the lattice, which holds only where liquid fills a closed box: give one fluid block the whole domain as its region, list all six faces in domain.walls and remove the gates, or use \"lattice\"".into(),
                );
            }
        }
        // The lattice closes every face of the box (lbm_proc::setup); an open
        // face is open to the grains only. Where liquid lies against it, a
        // grain reaching it would be held by a wall the DEM does not have
        // (measured: a sphere settling onto an open floor stopped 0.4 mm
        // past it, held by the liquid's no-slip edge).
        if !spec.particles.is_empty() {
            for face in Face::ALL.iter().filter(|f| !d.walls.contains(f)) {
                let (a, sign) = face.axis_and_sign();
                let touches = spec.fluids.iter().any(|f| {
                    let gap = if sign > 0.0 { f.region.min[a] - d.min[a] } else { d.max[a] - f.region.max[a] };
                    gap < lbm.spacing
                });
                if touches {
                    v.fail(
                        "domain.walls",
                        format!(
                            "{} is open but liquid lies against it: the lattice is closed on every face, so grains reaching it would be held there by the liquid's wall, which the DEM does not have; list {} in domain.walls, or keep the fluid regions at least one lattice cell from it",
                            face.name(),
                            face.name()
                        ),
                    );
                }
            }
        }
        if lbm.spacing > 0.0 && lbm.time_step > 0.0 {
            for a in 0..3 {
                let cells = (d.max[a] - d.min[a]) / lbm.spacing;
                if cells.is_finite() && cells < 3.0 {
                    v.fail(
                        "lbm.spacing",
                        format!("leaves {cells:.1} cells along {} (at least 3 needed); lower it", ["x", "y", "z"][a]),
                    );
                }
            }
            let (lo, hi) = (d.min, d.max);
            let cells: f64 = (0..3).map(|a| ((hi[a] - lo[a]) / lbm.spacing).ceil()).product();
            if cells > 2e9 {
                v.fail(
                    "lbm.spacing",
                    format!(
                        "gives {cells:.3e} lattice cells in the domain (at most 2e9); raise it or shrink the domain"
                    ),
                );
            }
        }
    }

    let c = &spec.coupling;
    if !(1..=10_000).contains(&c.ratio) {
        v.fail("coupling.ratio", format!("must be between 1 and 10000 DEM steps per LBM step, got {}", c.ratio));
    }
    if let (Some(dem), Some(lbm)) = (&spec.dem, &spec.lbm) {
        if !mpm && !spec.particles.is_empty() && !spec.fluids.is_empty() {
            if let Some(dt) = dem.time_step {
                let coupled = lbm.time_step / c.ratio as f64;
                if (dt - coupled).abs() > 1e-9 * coupled {
                    v.fail(
                        "dem.time_step",
                        format!(
                            "a coupled scene takes its DEM step from lbm.time_step / coupling.ratio = {coupled:.6e} s, got {dt:.6e} s; remove dem.time_step or change coupling.ratio"
                        ),
                    );
                }
            }
        }
    }
}

/// `[deposition]`, `[output]`, `[analysis]`, and the blocks a scene needs at all.
fn check_run_tables(v: &mut Validator, spec: &SceneSpec, mpm: bool) {
    let d = &spec.domain;
    let dep = &spec.deposition;
    v.at_least("deposition.friction", dep.friction, 0.0);
    v.at_least("deposition.rolling_friction", dep.rolling_friction, 0.0);
    v.positive("deposition.rest_speed", dep.rest_speed);
    v.positive("deposition.max_time", dep.max_time);

    let o = &spec.output;
    v.positive("output.end_time", o.end_time);
    v.positive("output.record_interval", o.record_interval);
    if let Some(s) = o.checkpoint_interval {
        v.positive("output.checkpoint_interval", s);
    }
    if let Some(s) = o.state_interval {
        v.positive("output.state_interval", s);
    }
    v.positive("output.rest_speed", o.rest_speed);
    v.in_range("output.rest_fraction", o.rest_fraction, 0.0, 0.5);

    let a = &spec.analysis;
    v.positive("analysis.column_length", a.column_length);
    v.positive("analysis.column_height", a.column_height);
    v.open_range("analysis.front_mass_fraction", a.front_mass_fraction, 0.0, 0.5);
    if let Some(b) = a.deposit_bin {
        v.positive("analysis.deposit_bin", b);
    }
    if a.condition == Condition::Liquid && (spec.fluids.is_empty() || !spec.particles.is_empty()) {
        v.fail(
            "analysis.condition",
            "`liquid` is for a column of liquid alone: [[fluids]] and no [[particles]]".into(),
        );
    }
    if a.condition == Condition::Saturated && spec.fluids.is_empty() {
        v.fail("analysis.condition", "`saturated` needs at least one [[fluids]] block".into());
    }
    if spec.particles.is_empty() && spec.fluids.is_empty() {
        v.fail("", "the scene has neither [[particles]] nor [[fluids]]: nothing to simulate".into());
    }
    if !mpm && norm(d.gravity) == 0.0 && spec.particles.iter().any(|p| matches!(p.packing, PackingSpec::Deposit { .. }))
    {
        v.fail("domain.gravity", "gravity deposition needs non-zero gravity".into());
    }
}

/// `scene.method` when set, else what the blocks imply.
fn method_of(spec: &SceneSpec) -> Method {
    spec.scene.method.unwrap_or_else(|| implied_method(spec).unwrap_or(Method::DemLbm))
}

/// The method the blocks imply (grains only `dem`, liquid only `lbm`, both
/// `dem_lbm`); None for a scene with neither.
fn implied_method(spec: &SceneSpec) -> Option<Method> {
    match (spec.particles.is_empty(), spec.fluids.is_empty()) {
        (false, true) => Some(Method::DemDry),
        (true, false) => Some(Method::LbmFluid),
        (false, false) => Some(Method::DemLbm),
        (true, true) => None,
    }
}

/// An explicit `scene.method` other than `mpm` must be the one the blocks imply.
fn check_method_matches_blocks(v: &mut Validator, spec: &SceneSpec, named: Method) {
    let Some(implied) = implied_method(spec) else { return };
    if implied == named {
        return;
    }
    let has = match implied {
        Method::DemDry => "[[particles]] and no [[fluids]]",
        Method::LbmFluid => "[[fluids]] and no [[particles]]",
        _ => "both [[particles]] and [[fluids]]",
    };
    let needs = match named {
        Method::DemDry => "`dem` needs [[particles]] and no [[fluids]]",
        Method::LbmFluid => "`lbm` needs [[fluids]] and no [[particles]]",
        _ => "`dem_lbm` needs both [[particles]] and [[fluids]]",
    };
    v.fail(
        "scene.method",
        format!(
            "is \"{}\" but the scene has {has}, which implies \"{}\" ({needs}): set scene.method = \"{}\" (or \"mpm\"), or remove it to infer the method",
            named.name(),
            implied.name(),
            implied.name()
        ),
    );
}

/// Most background-grid elements an MPM scene may have.
pub const MPM_MAX_ELEMENTS: f64 = 4.0e6;

/// Tolerance, as a fraction of `mpm.element_size`, of a coordinate that must
/// lie on a grid line (or on a row of the points' lattice).
const MPM_GRID_TOLERANCE: f64 = 1e-6;

/// A length rounded to 1e-9 m for messages (0.04 rather than 0.04000000000000001).
fn tidy(x: f64) -> f64 {
    (x * 1e9).round() / 1e9
}

/// The `[mpm]` values, whatever the method (the table is checked when present).
fn check_mpm_values(v: &mut Validator, m: &MpmSpec) {
    v.positive("mpm.element_size", m.element_size);
    if !point_count_fits(m.points_per_element) {
        let (a, b) = point_grid_of(m.points_per_element);
        let fits: Vec<String> = (1..=16).filter(|&n| point_count_fits(n)).map(|n| n.to_string()).collect();
        let grid = if m.points_per_element == 0 { String::new() } else { format!(" (its closest grid is {a} x {b})") };
        v.fail(
            "mpm.points_per_element",
            format!(
                "{} points cannot be laid on an a x b sub-grid with a >= b and a <= 3b{grid}; counts that work: {}, … (the paper uses 12 = 4 x 3)",
                m.points_per_element,
                fits.join(", ")
            ),
        );
    }
    v.half_open("mpm.courant", m.courant, 0.0, 1.0);
    v.positive("mpm.young_modulus", m.young_modulus);
    v.open_range("mpm.poisson_ratio", m.poisson_ratio, 0.0, 0.5);
    v.open_range("mpm.friction_angle", m.friction_angle, 0.0, 90.0);
    v.at_least("mpm.cohesion", m.cohesion, 0.0);
    if !(m.dilatancy_angle >= 0.0 && m.dilatancy_angle <= m.friction_angle) {
        v.fail(
            "mpm.dilatancy_angle",
            format!(
                "must be in [0, mpm.friction_angle] = [0, {}] degrees, got {}",
                m.friction_angle, m.dilatancy_angle
            ),
        );
    }
    if let Some(n_cs) = m.dilatancy_cutoff_porosity {
        v.open_range("mpm.dilatancy_cutoff_porosity", n_cs, 0.0, 1.0);
        if m.dilatancy_angle == 0.0 {
            v.fail(
                "mpm.dilatancy_cutoff_porosity",
                format!(
                    "= {n_cs} stops a dilatancy that mpm.dilatancy_angle = 0 never starts: set mpm.dilatancy_angle > 0, or remove the cut-off"
                ),
            );
        }
    }
    if let Some(i0) = m.reference_inertial_number {
        v.positive("mpm.reference_inertial_number", i0);
        if m.limit_friction_angle.is_none() {
            v.fail(
                "mpm.reference_inertial_number",
                format!(
                    "= {i0} shapes a rate-dependent friction that is off: set mpm.limit_friction_angle, or remove it"
                ),
            );
        }
    }
    if let Some(phi2) = m.limit_friction_angle {
        if m.cohesion > 0.0 {
            v.fail(
                "mpm.limit_friction_angle",
                format!(
                    "= {phi2} needs a cohesionless soil (the rate-dependent friction is the mu(I) of dry grains), got mpm.cohesion = {}: set mpm.cohesion = 0, or remove mpm.limit_friction_angle",
                    m.cohesion
                ),
            );
        }
        if !(phi2 >= m.friction_angle && phi2 < 90.0) {
            v.fail(
                "mpm.limit_friction_angle",
                format!(
                    "must be in [mpm.friction_angle, 90) = [{}, 90) degrees (the friction at high inertial number is not below the quasi-static one), got {phi2}",
                    m.friction_angle
                ),
            );
        }
    }
    v.positive("mpm.liquid_bulk_modulus", m.liquid_bulk_modulus);
    v.at_least("mpm.cavitation_threshold", m.cavitation_threshold, 0.0);
    v.open_range("mpm.max_porosity", m.max_porosity, 0.0, 1.0);
    v.closed_open("mpm.damping", m.damping, 0.0, 1.0);
    v.at_least("mpm.wall_friction", m.wall_friction, 0.0);
    v.positive("mpm.ergun_a", m.ergun_a);
    v.positive("mpm.ergun_b", m.ergun_b);
    v.half_open("mpm.free_surface_fill", m.free_surface_fill, 0.0, 1.0);
    v.positive("mpm.air_pressure", m.air_pressure);
    if m.surface_elements == Some(MpmSurfaceElements::Hydrostatic) && m.pressure_scheme == MpmPressureScheme::Explicit {
        v.fail(
            "mpm.surface_elements",
            "= \"hydrostatic\" gives part-filled elements a pressure in the element-pressure solve, which the explicit scheme does not have; set mpm.pressure_scheme = \"implicit\", or mpm.surface_elements = \"free\"".to_string(),
        );
    }
    v.in_range("mpm.pic_fraction", m.pic_fraction, 0.0, 1.0);
    if m.transfer.is_affine() && m.shape_functions == ShapeFunctions::Linear {
        // Measured: a block sliding on a frictional floor blew up once its
        // points crossed a grid line (the bilinear gradient jumps there and
        // APIC carries it); the GIMP weights and gradients are continuous.
        v.fail(
            "mpm.transfer",
            "APIC with shape_functions = \"linear\" is unstable when points cross grid lines; use shape_functions = \"gimp\" or transfer = \"flip\"".to_string(),
        );
    }
    for (key, set) in [("mpm.flip_share", m.flip_share), ("mpm.liquid_flip_share", m.liquid_flip_share)] {
        if let Some(share) = set {
            if !(0.0..1.0).contains(&share) {
                v.fail(key, format!("must be in [0, 1) (1 would be FLIP without a filter), got {share}"));
            }
        }
    }
    if !(1..=2).contains(&m.xpic_order) {
        v.fail("mpm.xpic_order", format!("must be 1 (PIC) or 2 (XPIC(2)), got {}", m.xpic_order));
    }
    v.at_least("mpm.gravity_phase_max_time", m.gravity_phase_max_time, 0.0);
    v.closed_open("mpm.gravity_phase_damping", m.gravity_phase_damping, 0.0, 1.0);
    v.positive("mpm.gravity_phase_rest_speed", m.gravity_phase_rest_speed);
    v.at_least("mpm.top_load", m.top_load, 0.0);
    if let Some(speed) = m.wall_release_speed {
        v.at_least("mpm.wall_release_speed", speed, 0.0);
    }
}

/// What a scene must be for the 2D MPM: one soil, one liquid, x–z gravity,
/// ±x gates, and every boundary on the background grid.
fn check_mpm_scene(v: &mut Validator, spec: &SceneSpec, gate_normals: &[[f64; 3]]) {
    let m = spec.mpm.clone().unwrap_or_default();
    let d = &spec.domain;
    if spec.particles.len() > 1 {
        v.fail(
            "particles",
            format!(
                "the MPM simulates one soil: at most one [[particles]] block, got {}; merge them into one block",
                spec.particles.len()
            ),
        );
    }
    if spec.fluids.len() > 1 {
        v.fail(
            "fluids",
            format!(
                "the MPM simulates one liquid body: at most one [[fluids]] block, got {}; merge them into one region",
                spec.fluids.len()
            ),
        );
    }
    if let Some(soil) = spec.particles.first() {
        match &soil.packing {
            PackingSpec::Deposit { count: Some(_), .. } => v.fail(
                "particles[0].packing.count",
                "the MPM fills packing.region as a continuum of initial porosity n0: replace `count` with `porosity` (the lab columns: 0.40)".into(),
            ),
            PackingSpec::Deposit { .. } => {}
            PackingSpec::Explicit { .. } => v.fail(
                "particles[0].packing.method",
                "the MPM soil is a region of continuum: use method = \"deposit\" with `region` and `porosity` (n0); explicit grains are for the DEM".into(),
            ),
        }
    }
    if d.gravity[1] != 0.0 {
        v.fail(
            "domain.gravity",
            format!(
                "the MPM is 2D in the x–z plane: gravity[1] must be 0, got {:?}; put gravity in x and z, e.g. [0.0, 0.0, -9.81]",
                d.gravity
            ),
        );
    }
    for (g, n) in gate_normals.iter().enumerate() {
        if n[0].abs() <= 1.0 - 1e-9 {
            v.fail(
                &format!("gates[{g}].normal"),
                format!(
                    "the MPM gate is a vertical line of grid nodes: the normal must be +x or -x ([1, 0, 0] or [-1, 0, 0]), got {:?}",
                    spec.gates[g].normal
                ),
            );
        }
    }

    let h = m.element_size;
    if !(h > 0.0 && h.is_finite()) {
        return; // reported with the [mpm] values
    }
    let axes = [(0usize, "x"), (2usize, "z")];
    let mut elements = 1.0;
    for (a, axis) in axes {
        let extent = d.max[a] - d.min[a];
        if !(extent > 0.0 && extent.is_finite()) {
            return; // reported with the domain
        }
        let cells = extent / h;
        elements *= cells.round().max(1.0);
        if cells < 2.0 - MPM_GRID_TOLERANCE {
            v.fail(
                "mpm.element_size",
                format!(
                    "{h} m leaves {cells:.3} elements along {axis} (the domain is {} m; at least 2 needed): lower it",
                    tidy(extent)
                ),
            );
        } else if (cells - cells.round()).abs() > MPM_GRID_TOLERANCE {
            let (lo, hi) = (cells.floor(), cells.ceil());
            v.fail(
                &format!("domain.max[{a}]"),
                format!(
                    "the {axis} extent {} m is {cells:.4} elements of mpm.element_size = {h} m, not a whole number: set domain.max[{a}] = {} or {} m, or mpm.element_size = {} m ({lo:.0} elements) or {} m ({hi:.0} elements)",
                    tidy(extent),
                    tidy(d.min[a] + lo * h),
                    tidy(d.min[a] + hi * h),
                    tidy(extent / lo),
                    tidy(extent / hi),
                ),
            );
        }
    }
    if elements > MPM_MAX_ELEMENTS {
        v.fail(
            "mpm.element_size",
            format!(
                "{h} m gives {elements:.3e} background elements in the x–z section (at most {MPM_MAX_ELEMENTS:.0e}): raise it or shrink the domain"
            ),
        );
    }
    // Grid lines run from domain.min every h, whether or not the extent
    // fits; the points are seeded on a finer lattice, a × b per element
    // (`point_grid`), whose lines a block's edges may lie on.
    let (_, b_points) = m.point_grid();
    let on_lines = |v: &mut Validator, key: String, a: usize, value: f64, what: &str, spacing: f64, lines: &str| {
        if !value.is_finite() {
            return;
        }
        let k = (value - d.min[a]) / spacing;
        if (k - k.round()).abs() > MPM_GRID_TOLERANCE * h / spacing {
            let axis = if a == 0 { "x" } else { "z" };
            v.fail(
                &key,
                format!(
                    "{what} {axis} = {} m is {:.4} elements of mpm.element_size = {h} m from domain.min[{a}]: the MPM needs it on {lines}; the nearest are {} and {} m",
                    tidy(value),
                    (value - d.min[a]) / h,
                    tidy(d.min[a] + k.floor() * spacing),
                    tidy(d.min[a] + k.ceil() * spacing),
                ),
            );
        }
    };
    let on_grid = |v: &mut Validator, key: String, a: usize, value: f64, what: &str| {
        on_lines(v, key, a, value, what, h, "a grid line");
    };
    // The soil's and the liquid's edges: along x on grid lines (a side
    // face inside an element would leave every element of that column
    // part-filled, its water free); along z on a row of the points'
    // lattice, every h/b (a grid line is one of them), so a block's top or
    // bottom may lie inside an element. An invalid point count (reported
    // with the [mpm] values) falls back to grid lines.
    let rows = if point_count_fits(m.points_per_element) { b_points.max(1) } else { 1 };
    let on_seed_lines = |v: &mut Validator, key: String, a: usize, value: f64, what: &str| {
        if a == 0 {
            on_grid(v, key, a, value, what);
        } else {
            let lines = format!(
                "a grid line or, along z, a row of the points' lattice (mpm.points_per_element = {} puts {rows} row{} in each element, every {} m)",
                m.points_per_element,
                if rows == 1 { "" } else { "s" },
                tidy(h / rows as f64)
            );
            on_lines(v, key, a, value, what, h / rows as f64, &lines);
        }
    };
    if let Some(PackingSpec::Deposit { region, .. }) = spec.particles.first().map(|p| &p.packing) {
        for (a, _) in axes {
            on_seed_lines(v, format!("particles[0].packing.region.min[{a}]"), a, region.min[a], "the soil edge");
            on_seed_lines(v, format!("particles[0].packing.region.max[{a}]"), a, region.max[a], "the soil edge");
        }
    }
    for (f, fluid) in spec.fluids.iter().enumerate() {
        for (a, _) in axes {
            on_seed_lines(v, format!("fluids[{f}].region.min[{a}]"), a, fluid.region.min[a], "the liquid edge");
            on_seed_lines(v, format!("fluids[{f}].region.max[{a}]"), a, fluid.region.max[a], "the liquid edge");
        }
    }
    for (g, gate) in spec.gates.iter().enumerate() {
        on_grid(v, format!("gates[{g}].point[0]"), 0, gate.point[0], "the gate");
    }
}

fn norm(v: [f64; 3]) -> f64 {
    (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt()
}

fn read_sphere_csv(path: &Path) -> Result<Vec<[f64; 4]>, String> {
    let text = std::fs::read_to_string(path).map_err(|e| format!("cannot read {}: {e}", path.display()))?;
    let mut out = Vec::new();
    for (ln, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') || line.starts_with('x') {
            continue;
        }
        let vals: Result<Vec<f64>, _> = line.split(',').map(|s| s.trim().parse::<f64>()).collect();
        match vals {
            Ok(v) if v.len() == 4 => out.push([v[0], v[1], v[2], v[3]]),
            _ => return Err(format!("{}:{}: expected `x,y,z,d` in metres, got {line:?}", path.display(), ln + 1)),
        }
    }
    Ok(out)
}

/// Collects every problem of a scene, so one load reports them all.
#[derive(Default)]
struct Validator {
    problems: Vec<(String, String)>,
}

impl Validator {
    fn fail(&mut self, key: &str, reason: String) {
        self.problems.push((key.to_string(), reason));
    }
    fn nonempty(&mut self, key: &str, s: &str) {
        if s.trim().is_empty() {
            self.fail(key, "must not be empty".into());
        }
    }
    fn finite(&mut self, key: &str, x: f64) {
        if !x.is_finite() {
            self.fail(key, format!("must be a finite number, got {x}"));
        }
    }
    fn finite_vec(&mut self, key: &str, x: &[f64; 3]) {
        if x.iter().any(|c| !c.is_finite()) {
            self.fail(key, format!("must be finite, got {x:?}"));
        }
    }
    fn positive(&mut self, key: &str, x: f64) {
        if !(x > 0.0 && x.is_finite()) {
            self.fail(key, format!("must be > 0, got {x}"));
        }
    }
    fn at_least(&mut self, key: &str, x: f64, lo: f64) {
        if !(x >= lo && x.is_finite()) {
            self.fail(key, format!("must be >= {lo}, got {x}"));
        }
    }
    fn in_range(&mut self, key: &str, x: f64, lo: f64, hi: f64) {
        if !(x >= lo && x <= hi) {
            self.fail(key, format!("must be in [{lo}, {hi}], got {x}"));
        }
    }
    fn open_range(&mut self, key: &str, x: f64, lo: f64, hi: f64) {
        if !(x > lo && x < hi) {
            self.fail(key, format!("must be in ({lo}, {hi}), got {x}"));
        }
    }
    fn closed_open(&mut self, key: &str, x: f64, lo: f64, hi: f64) {
        if !(x >= lo && x < hi) {
            self.fail(key, format!("must be in [{lo}, {hi}), got {x}"));
        }
    }
    fn half_open(&mut self, key: &str, x: f64, lo: f64, hi: f64) {
        if !(x > lo && x <= hi) {
            self.fail(key, format!("must be in ({lo}, {hi}], got {x}"));
        }
    }
    fn region(&mut self, key: &str, r: &BoxSpec, d: &DomainSpec) {
        for a in 0..3 {
            if !(r.min[a].is_finite() && r.max[a].is_finite()) {
                self.fail(key, format!("corners must be finite, got min {:?} max {:?}", r.min, r.max));
                return;
            }
            if r.max[a] <= r.min[a] {
                self.fail(&format!("{key}.max[{a}]"), format!("must be > min[{a}] = {}, got {}", r.min[a], r.max[a]));
            }
            if r.min[a] < d.min[a] || r.max[a] > d.max[a] {
                self.fail(
                    key,
                    format!("region {:?}..{:?} is not inside the domain {:?}..{:?}", r.min, r.max, d.min, d.max),
                );
                return;
            }
        }
    }
    fn finish(self) -> Result<(), SceneError> {
        if self.problems.is_empty() {
            Ok(())
        } else {
            Err(SceneError::many(self.problems))
        }
    }
}
