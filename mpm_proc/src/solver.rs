//! One explicit step of the two-phase double-point MPM, built from the
//! named stages of docs/mpm.md ("One step"). State (what a restart needs)
//! is kept apart from scratch (what every step rebuilds).

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::drag::DragLaw;
use crate::grid::{Grid, Stencil};
use crate::mohr_coulomb::{InertialFriction, MohrCoulomb};
use crate::pressure::{pore_fluid_modulus, ElementRole, PressureProblem, PressureSolver};
use schemas::scene::ShapeFunctions;

/// Porosity bounds of the solid points: grains are incompressible, so n
/// cannot leave (0, 1); the bounds keep κ and the volumes finite.
pub const POROSITY_BOUNDS: (f64, f64) = (0.05, 0.99);
/// Largest nodal solid fraction (docs/mpm.md, "Porosity fields").
const MAX_SOLID_FRACTION: f64 = 0.95;
/// Points per parallel work item: below this a stage is not worth splitting.
/// Small enough that a thread that runs out of work waits less than rayon's
/// ~32 rounds before it sleeps: 256 made a leaf of the solid update ~15 µs
/// and the waits slept, ~1 context switch a step (docs/BENCHMARKS.md,
/// session 41: 64 against 256, 1.84-1.92 s against 2.11-2.15 s for 3000
/// steps of the lab column on two threads; 32 no faster, 128 between).
const CHUNK: usize = 64;
/// Nodes per parallel work item of the node loops, over the touched range
/// taken row after row. Rows were the items until session 41: a spread,
/// low pile has few rows, most of its points in the bottom ones, and the
/// map over them did not split (1.06x on two threads over the lab column's
/// whole run).
const NODE_CHUNK: usize = 32;

/// Steps between two reorderings of the points into the grid's order
/// (`Mpm::sort_points`). Every 10, 100 or 1000 steps ran the lab column
/// within 2 % of each other (session 43): points cross an element in ~400 steps.
const SORT_INTERVAL: u64 = 100;

/// Material and numerical parameters, SI.
#[derive(Debug, Clone)]
pub struct Params {
    /// Time step Δt, s.
    pub dt: f64,
    /// Gravity (x, z), m/s².
    pub gravity: [f64; 2],
    /// Grain density ρ_s and liquid density ρ_L, kg/m³.
    pub solid_density: f64,
    pub liquid_density: f64,
    /// Liquid dynamic viscosity μ, Pa·s.
    pub viscosity: f64,
    /// Liquid bulk modulus K_L, Pa.
    pub bulk_modulus: f64,
    /// Liquid tension tolerated, Pa (p ≥ −this).
    pub cavitation: f64,
    /// Absolute pressure of the air in part-empty pressured elements, Pa
    /// (`mpm.air_pressure`; implicit scheme only).
    pub air_pressure: f64,
    /// Fluidisation porosity n_max.
    pub max_porosity: f64,
    /// Dilatancy cut-off: points at or above this porosity yield with
    /// `critical_soil` (ψ = 0) instead of `soil`; +∞ without a cut-off.
    pub dilatancy_cutoff_porosity: f64,
    /// Local damping α.
    pub damping: f64,
    /// Coulomb friction μ of the solid on the walls listed in
    /// `Fixities::contact` (0: they hold only the normal velocity).
    pub wall_friction: f64,
    /// Unilateral walls (`mpm.wall_contact = "unilateral"`): the
    /// components of `Fixities::walls` hold only while the material
    /// pushes into the wall (`Mpm::update_wall_contacts`). false: they
    /// hold both ways.
    pub unilateral_walls: bool,
    /// `mpm.wall_release_speed`, m/s: how fast the mixture at a held wall
    /// component must be set to move off the wall within the step (its
    /// mapped momentum and the last step's force) for
    /// `release_walls_moved_off` to release it in the step. None: 0.
    pub wall_release_speed: Option<f64>,
    /// `mpm.wall_friction_reach = "next_node"`: the friction impulse a
    /// wall node's own mass cannot take passes to the next node off the
    /// wall (`Mpm::apply_wall_friction`). false: it acts on the wall node only.
    pub friction_reaches_next_node: bool,
    /// `mpm.wall_tangent_update = "grid"`: points touching a wall node
    /// take the grid's velocity in both directions every step, which
    /// re-projects the layer on the wall onto the grid once a step, an
    /// effect per second that grows as Δt shrinks. false (`"blend"`, the
    /// default): only along the components held; along the wall they
    /// update as elsewhere (docs/mpm.md, "A re-projection once a step").
    pub wall_points_take_grid_tangent: bool,
    /// `mpm.liquid_wall_shear`: whether slip walls put a laminar film's
    /// depth-averaged shear on the liquid along them
    /// (`Mpm::apply_liquid_wall_shear`; None: free slip), and how a line
    /// of nodes reads the film's depth.
    pub liquid_film_shear: Option<FilmDepth>,
    /// Filling ratio below which a liquid point is on the free surface: its
    /// own (interpolated from the nodes) or its element's
    /// (`ElementScratch::filling_ratio`).
    pub free_surface_fill: f64,
    /// `mpm.surface_elements = "hydrostatic"`: an element below
    /// `free_surface_fill` whose occupied part is saturated
    /// (`ElementScratch::saturated_layer`) gets its layer's hydrostatic
    /// pressure on its nodes instead of 0 (implicit scheme only).
    pub hydrostatic_surface: bool,
    /// PIC share α of the point velocity update: v ← (1 − α) v_FLIP + α v_PIC.
    pub pic_fraction: f64,
    /// 1: the share α blends plain PIC; 2: XPIC(2) (Hammerquist & Nairn
    /// 2017), which removes α of the null-space part of the point velocities
    /// while damping resolved motion far less.
    pub xpic_order: u32,
    /// APIC transfers (Jiang et al. 2015): points take the grid's new
    /// velocity and its affine part C_p = B_p D_p⁻¹, and give the grid
    /// v_p + C_p (x_I − x_p); no grid-invisible velocity is kept, so no
    /// filter is needed and `pic_fraction` is not used. false: FLIP.
    pub apic: bool,
    /// Under APIC, the share β of the FLIP update blended in away from held
    /// nodes, v ← (1 − β) v_APIC + β v_FLIP, for the solid and the liquid
    /// points (`mpm.flip_share`, `mpm.liquid_flip_share`; AFLIP, Fei et al.
    /// 2021), kept over each step taken: the scene's shares raised to
    /// courant / 0.5 under `mpm.flip_share_basis = "reference_step"`
    /// (`MpmSpec::flip_shares_per_step`).
    pub flip_share: [f64; 2],
    /// Refit each element's pore pressures to a least-squares plane every
    /// step (`mpm.pressure_reconstruction = "linear"`).
    pub linear_pressure: bool,
    /// Semi-implicit pore pressure (`mpm.pressure_scheme = "implicit"`,
    /// docs/design/mpm-implicit-pressure.md §1): the nodal solve without
    /// the pore pressure, one pressure per pressured element from the
    /// mixture continuity, then damping and wall friction on the total
    /// force. false: the explicit per-point law, and always without
    /// liquid points (`setup::build`).
    pub implicit_pressure: bool,
    pub soil: MohrCoulomb,
    /// The same soil without dilatancy, for points past the dilatancy
    /// cut-off.
    pub critical_soil: MohrCoulomb,
    /// Rate-dependent friction (`mpm.limit_friction_angle`): each yielding
    /// point's φ from its inertial number, φ_s the soil's friction angle.
    /// None: rate-independent.
    pub inertial_friction: Option<InertialFriction>,
    pub drag: DragLaw,
}

/// Kinematics shared by both point sets.
#[derive(Debug, Clone, Default, Serialize, Deserialize, PartialEq)]
pub struct PointSet {
    /// Position (x, z), m.
    pub x: Vec<[f64; 2]>,
    /// Velocity, m/s.
    pub v: Vec<[f64; 2]>,
    /// Mass per metre of width, kg/m (constant).
    pub mass: Vec<f64>,
    /// Represented (mixture) area per metre of width, m².
    pub volume: Vec<f64>,
    /// GIMP half-widths (x, z), m.
    pub half: [f64; 2],
    /// APIC (`Params::apic`): the affine velocity each point carries,
    /// C = B D⁻¹ at the last update (row a: ∂v_a/∂x, ∂v_a/∂z), 1/s.
    /// Empty under FLIP.
    pub affine: Vec<[[f64; 2]; 2]>,
    /// Each point's id, its index when the set was made. The solver keeps
    /// the points in the grid's order ([`Mpm::step`]'s `sort_points`), so
    /// a point's index changes over a run and its id does not. Empty until
    /// the first sort: ids are then the indices.
    pub id: Vec<u32>,
}

impl PointSet {
    pub fn len(&self) -> usize {
        self.x.len()
    }
    pub fn is_empty(&self) -> bool {
        self.x.is_empty()
    }
    /// Sets every point's velocity to `v`, a uniform translation, and
    /// clears the affine part APIC carries (a velocity set by hand has none).
    pub fn set_velocity(&mut self, v: [f64; 2]) {
        self.v.iter_mut().for_each(|p| *p = v);
        self.affine.iter_mut().for_each(|c| *c = [[0.0; 2]; 2]);
    }
    /// ½ Σ m v², J/m.
    pub fn kinetic_energy(&self) -> f64 {
        self.v.iter().zip(&self.mass).map(|(v, m)| 0.5 * m * (v[0] * v[0] + v[1] * v[1])).sum()
    }
    /// Σ m v, kg m/s per metre of width: what the grid receives (APIC's
    /// affine part maps none, its weights summing to zero for shapes that
    /// reproduce linear fields).
    pub fn momentum(&self) -> [f64; 2] {
        self.v.iter().zip(&self.mass).fold([0.0; 2], |a, (v, m)| [a[0] + m * v[0], a[1] + m * v[1]])
    }
    /// −Σ m g·(x − origin), J per metre of width.
    pub fn potential_energy(&self, gravity: [f64; 2], origin: [f64; 2]) -> f64 {
        -self
            .x
            .iter()
            .zip(&self.mass)
            .map(|(x, m)| m * (gravity[0] * (x[0] - origin[0]) + gravity[1] * (x[1] - origin[1])))
            .sum::<f64>()
    }
    pub fn max_speed(&self) -> f64 {
        self.v.iter().map(|v| (v[0] * v[0] + v[1] * v[1]).sqrt()).fold(0.0, f64::max)
    }
    pub fn total_mass(&self) -> f64 {
        self.mass.iter().sum()
    }
    /// The id of the point at index `p` (its index when the set was made).
    pub fn id_of(&self, p: usize) -> u32 {
        self.id.get(p).copied().unwrap_or(p as u32)
    }
    /// The index of each id: `by_id()[id]` is the point's index now.
    /// Pre: [`Self::check_ids`] holds (panics on an id out of range).
    pub fn by_id(&self) -> Vec<usize> {
        let mut index = vec![usize::MAX; self.len()];
        for p in 0..self.len() {
            index[self.id_of(p) as usize] = p;
        }
        debug_assert!(!index.contains(&usize::MAX), "point ids repeat");
        index
    }
    /// Whether the ids are empty (not yet reordered: ids are the indices)
    /// or each of 0..n once.
    pub fn check_ids(&self) -> Result<(), String> {
        if self.id.is_empty() {
            return Ok(());
        }
        if self.id.len() != self.len() {
            return Err(format!("{} point ids for {} points", self.id.len(), self.len()));
        }
        let mut seen = vec![false; self.len()];
        for &id in &self.id {
            match seen.get_mut(id as usize) {
                Some(s) if !*s => *s = true,
                _ => return Err(format!("point id {id} out of range or repeated ({} points)", self.len())),
            }
        }
        Ok(())
    }
    /// Swaps points `a` and `b` in every per-point array.
    fn swap(&mut self, a: usize, b: usize) {
        self.x.swap(a, b);
        self.v.swap(a, b);
        self.mass.swap(a, b);
        self.volume.swap(a, b);
        swap_if_per_point(&mut self.affine, self.x.len(), a, b);
        self.id.swap(a, b);
    }
}

/// Swaps `a` and `b` in `values` when it holds one value per point (of `n`);
/// optional per-point arrays (APIC's affine part, the top load) are empty
/// when unused.
fn swap_if_per_point<T>(values: &mut [T], n: usize, a: usize, b: usize) {
    debug_assert!(values.is_empty() || values.len() == n, "a per-point array of {} for {n} points", values.len());
    if values.len() == n {
        values.swap(a, b);
    }
}

/// Solid material points (the skeleton).
#[derive(Debug, Clone, Default, Serialize, Deserialize, PartialEq)]
pub struct SolidPoints {
    pub set: PointSet,
    /// Porosity n.
    pub porosity: Vec<f64>,
    /// Effective stress (σ_xx, σ_zz, σ_xz, σ_yy), Pa, tension positive.
    pub stress: Vec<[f64; 4]>,
    /// Fluidised (n > n_max): no effective stress.
    pub fluidised: Vec<bool>,
    /// External force (x, z), N/m (the top load).
    pub load: Vec<[f64; 2]>,
}

impl SolidPoints {
    fn swap(&mut self, a: usize, b: usize) {
        let n = self.set.len();
        self.set.swap(a, b);
        swap_if_per_point(&mut self.porosity, n, a, b);
        swap_if_per_point(&mut self.stress, n, a, b);
        swap_if_per_point(&mut self.fluidised, n, a, b);
        swap_if_per_point(&mut self.load, n, a, b);
    }
}

/// Liquid material points.
#[derive(Debug, Clone, Default, Serialize, Deserialize, PartialEq)]
pub struct LiquidPoints {
    pub set: PointSet,
    /// Pore pressure p, Pa, compression positive.
    pub pressure: Vec<f64>,
    /// Viscous stress (τ_xx, τ_zz, τ_xz, τ_yy), Pa.
    pub viscous: Vec<[f64; 4]>,
    /// Out of the pressure solve at the last step: p held at 0, or under
    /// the implicit scheme's `surface_elements = "hydrostatic"` at a
    /// saturated layer's given pressure (`ElementScratch::saturated_layer`).
    pub free_surface: Vec<bool>,
}

impl LiquidPoints {
    fn swap(&mut self, a: usize, b: usize) {
        let n = self.set.len();
        self.set.swap(a, b);
        swap_if_per_point(&mut self.pressure, n, a, b);
        swap_if_per_point(&mut self.viscous, n, a, b);
        swap_if_per_point(&mut self.free_surface, n, a, b);
    }
}

/// Everything that determines the rest of a run.
#[derive(Debug, Clone, Default, Serialize, Deserialize, PartialEq)]
pub struct MpmState {
    /// Simulated time, s (negative during the gravity phase is not used: it restarts at 0).
    pub time: f64,
    pub steps: u64,
    pub solid: SolidPoints,
    pub liquid: LiquidPoints,
    /// Whether each gate (scene order) still holds.
    pub gates_held: Vec<bool>,
    /// Under unilateral walls, whether each of `Fixities::walls` is
    /// released for the next step (the material there moved off the wall);
    /// empty otherwise.
    pub walls_released: Vec<bool>,
    /// Under unilateral walls, each of `Fixities::walls`' component of the
    /// last step's undamped force on the mixture there (both phases, the
    /// implicit pore pressure's included), N/m, along `WallComponent::into`
    /// (positive: pressing into the wall); 0 where the map did not touch it
    /// or it had no mass. What
    /// `Mpm::release_walls_moved_off` expects the wall to push against in
    /// the step; empty otherwise.
    pub wall_push: Vec<f64>,
}

/// Per-node sums of the first map.
#[derive(Debug, Clone, Copy, Default)]
struct NodeSums {
    mass_s: f64,
    momentum_s: [f64; 2],
    mass_l: f64,
    momentum_l: [f64; 2],
    /// Σ N V of the solid and of the liquid points, and Σ N m_s/ρ_s.
    volume_s: f64,
    volume_l: f64,
    solid_volume: f64,
}

/// Point data of one phase the grid needs each step.
#[derive(Debug, Default)]
struct PointScratch {
    stencil: Vec<Stencil>,
    element: Vec<u32>,
    /// Points sorted by stencil base node: `order[start[b]..start[b+1]]`.
    start: Vec<u32>,
    order: Vec<u32>,
    /// Next free slot per bin while sorting.
    cursor: Vec<u32>,
    /// Force data prepared for the second map.
    force: Vec<[f64; 6]>,
}

impl PointScratch {
    fn bin(&self, base: usize) -> &[u32] {
        &self.order[self.start[base] as usize..self.start[base + 1] as usize]
    }
}

/// What the node solve leaves for the point update.
#[derive(Debug, Clone, Copy, Default)]
struct NodeUpdate {
    /// Acceleration of [solid, liquid], m/s².
    a: [[f64; 2]; 2],
    /// XPIC(2): S w1, the mass-weighted map of the points' S⁺v_g, m/s.
    filtered: [[f64; 2]; 2],
    /// On a wall node: the grains' normal load on the wall, N.
    wall_load: f64,
    /// The undamped nodal forces on [solid, liquid] the accelerations came
    /// from (N/m; without the pore pressure under the implicit scheme), and
    /// the nodal drag coefficient Q (N·s/m³ per metre of width).
    force: [[f64; 2]; 2],
    drag: f64,
    /// The liquid's stress share in `force[0]` (N/m): −(1 − n) ∇·σ_L and
    /// the porosity-gradient term, without the pore pressure under the
    /// implicit scheme (there in `Implicit::pressure_force[0]`).
    liquid_on_solid: [f64; 2],
}

/// What the grid-to-points map reads at one node, gathered once per node
/// and step (each node is read by ~10 points of each phase).
#[derive(Debug, Clone, Copy, Default)]
struct GridVelocity {
    /// The end-of-step velocity of [solid, liquid], m/s (0 on fixed components).
    v: [[f64; 2]; 2],
    /// Acceleration of [solid, liquid], m/s².
    a: [[f64; 2]; 2],
    /// The node's position, m.
    x: [f64; 2],
    /// Per component: fixed (a wall or the gate).
    fixed: [bool; 2],
    /// On a frictional wall whose points take the grid velocity in both
    /// directions (`Params::wall_points_take_grid_tangent`).
    wall: bool,
}

/// Relative residual and iteration cap of the implicit pressure's PCG.
const PRESSURE_TOLERANCE: f64 = 1e-8;
const PRESSURE_MAX_ITERATIONS: usize = 2000;

/// What the implicit pressure solves cost over a run.
#[derive(Debug, Clone, Copy, Default, Serialize)]
pub struct PressureStats {
    pub solves: u64,
    /// CG iterations, summed and the largest of one solve.
    pub iterations: u64,
    pub max_iterations: usize,
    /// Solves that stopped at the cap above the tolerance.
    pub unconverged: u64,
    pub worst_residual: f64,
    /// Largest number of pressured elements in one step.
    pub max_unknowns: usize,
    /// Element-steps whose solved pressure was below the tension cap −T
    /// and was clamped to it.
    pub clamped: u64,
    /// Wall seconds in the pressure stages (reference, assembly, solve,
    /// corrector).
    pub seconds: f64,
}

/// Scratch of the implicit pressure (`Params::implicit_pressure`).
#[derive(Debug, Clone)]
struct ImplicitPressure {
    problem: PressureProblem,
    solver: PressureSolver,
    /// Per element: the pressures of the step, Pa (given ones included).
    pressure: Vec<f64>,
    /// Per element: Σ V and Σ V p over its pressured liquid points, then
    /// over its free ones (which carry a saturated layer's given pressure
    /// under `Params::hydrostatic_surface`, else 0).
    reference: Vec<[f64; 4]>,
    /// Per node: the predictor velocities v*, then the corrected ones, m/s.
    velocity: [Vec<[f64; 2]>; 2],
    /// Per node: the pressure forces Dᵀp on [solid, liquid], N/m.
    pressure_force: [Vec<[f64; 2]>; 2],
    /// Per element column, for the row below the one being assembled and
    /// that row: whether its element holds up a layer above it (pressured,
    /// or a saturated layer held up itself).
    holds_up: [Vec<bool>; 2],
    stats: PressureStats,
}

impl ImplicitPressure {
    fn new(grid: Grid, params: &Params) -> Self {
        let (ne, nodes) = (grid.element_count(), grid.node_count());
        Self {
            problem: PressureProblem::new(grid, params.dt, params.bulk_modulus),
            solver: PressureSolver::new(PRESSURE_TOLERANCE, PRESSURE_MAX_ITERATIONS),
            pressure: vec![0.0; ne],
            reference: vec![[0.0; 4]; ne],
            velocity: [vec![[0.0; 2]; nodes], vec![[0.0; 2]; nodes]],
            pressure_force: [vec![[0.0; 2]; nodes], vec![[0.0; 2]; nodes]],
            holds_up: [vec![false; grid.elements[0]], vec![false; grid.elements[0]]],
            stats: PressureStats::default(),
        }
    }
}

/// A node with wall friction (`Fixities::contact` non-zero), and where
/// the friction its own solid mass cannot take goes (`Mpm::apply_wall_friction`).
#[derive(Debug, Clone, Copy)]
struct ContactNode {
    node: usize,
    /// The axis along the wall (0: x, 1: z).
    tangent: usize,
    /// The next node off the wall, along the normal.
    inward: usize,
    /// Whether `inward` is a contact node of the same wall (this one is a
    /// ghost node behind it).
    inward_is_contact: bool,
    /// The share of the box in this node's support over the inward node's
    /// (½ on a wall, whose support is half outside the box): a wall node
    /// under the same material as the node inside holds this much of its mass.
    support_ratio: f64,
}

/// The line of nodes along a wall's normal through one of its in-box
/// nodes, by position q along that axis (stored column or row index).
#[derive(Debug, Clone, Copy)]
struct WallLine {
    wall_node: usize,
    /// The wall node's position, the first ghost's behind it, the
    /// opposite wall's; `inward` is +1 from a min wall, −1 from a max one.
    position: isize,
    first: isize,
    opposite: isize,
    inward: isize,
    /// Index step between positions, and the positions stored.
    stride: isize,
    count: isize,
}

impl WallLine {
    fn node_at(&self, q: isize) -> usize {
        (self.wall_node as isize + (q - self.position) * self.stride) as usize
    }

    /// (position, node) of the line's nodes that carry liquid in this step:
    /// the ghosts behind the wall (which may hold none), then from the
    /// wall node inward to the first without (outside the touched range
    /// a node's sums are stale and count as none).
    fn nodes<'a>(
        &self,
        sums: &'a [NodeSums],
        touched: impl Fn(usize) -> bool + 'a,
        tol: f64,
    ) -> impl Iterator<Item = (isize, usize)> + 'a {
        let line = *self;
        (0..)
            .map(move |k| (k, line.first + line.inward * k as isize))
            .take_while(move |&(_, q)| (0..line.count).contains(&q))
            .map_while(move |(k, q)| {
                let node = line.node_at(q);
                if touched(node) && sums[node].mass_l > tol {
                    Some(Some((q, node)))
                } else if k < crate::grid::GHOST {
                    Some(None)
                } else {
                    None
                }
            })
            .flatten()
    }
}

/// How the liquid's wall shear reads a film's depth at a line of nodes
/// off a wall (`Params::liquid_film_shear`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FilmDepth {
    /// The liquid points' water volume within the line's strip over the
    /// part of the strip they cover (`"laminar_film"`).
    Covered,
    /// The line's liquid mass over its whole strip
    /// (`"laminar_film_line_mass"`, session 45).
    LineMass,
}

/// A slip wall's line of nodes carrying liquid in this step, for the
/// liquid's wall shear (`Mpm::apply_liquid_wall_shear`).
#[derive(Debug, Clone, Copy)]
struct FilmLine {
    line: WallLine,
    /// The wall component's axis (its normal), and its wall node's
    /// stored index along the wall (column or row).
    axis: usize,
    along: usize,
    /// Position of the last node inward that carries liquid.
    last: isize,
    /// The liquid mass on the line's nodes, kg/m.
    mass: f64,
    /// The wall's coordinate along `axis`, and how far off it a liquid
    /// point may lie and count for this line (half an element past the
    /// last node with liquid), m.
    wall: f64,
    reach: f64,
    /// The line's strip along the wall: its node ± h/2, clipped to the
    /// box, m.
    strip: [f64; 2],
    /// Along the wall, the lowest and highest reach of the counted liquid
    /// points' domains within the strip, m (empty: lowest ≥ highest).
    covered: [f64; 2],
    /// The counted points' water volume within the strip (each point's
    /// m/ρ_L times the share of its domain inside the strip), m²/m.
    volume: f64,
    /// The film's depth the line's shear uses, m.
    depth: f64,
}

/// One chunk of liquid points' share of a [`FilmLine`]'s `volume` and
/// `covered`.
#[derive(Debug, Clone, Copy)]
struct FilmSum {
    volume: f64,
    covered: [f64; 2],
}

impl FilmSum {
    const EMPTY: FilmSum = FilmSum { volume: 0.0, covered: [f64::INFINITY, f64::NEG_INFINITY] };
}

/// Liquid points per chunk of the film depth's pass
/// (`Mpm::measure_film_depths`): fixed, so the sums' order is.
const FILM_CHUNK: usize = 512;

impl FilmLine {
    /// The length of the strip the counted points cover, m (0: none).
    fn covered_length(&self) -> f64 {
        (self.covered[1] - self.covered[0]).max(0.0)
    }
}

/// Per-element fields.
#[derive(Debug, Default)]
struct ElementScratch {
    porosity: Vec<f64>,
    grad_porosity: Vec<[f64; 2]>,
    liquid_points: Vec<u32>,
    solid_mass_solid: Vec<f64>,
    solid_mass_fluidised: Vec<f64>,
    /// Σ m_s/ρ_s and Σ V_s of the solid points in the element: their ratio
    /// is the skeleton's own porosity there, sharp at a soil–water boundary.
    grain_volume: Vec<f64>,
    solid_point_volume: Vec<f64>,
    /// The grains' and the water's own volumes, Σ m/ρ, each point's shared
    /// among the elements its GIMP domain covers (`Grid::domain_overlap`):
    /// the filling ratio's measure, continuous as points cross element
    /// edges.
    domain_volume: [Vec<f64>; 2],
    /// The solid points' pore volume V − m/ρ_s, shared by domain as
    /// `domain_volume` (only with liquid, under
    /// `Params::hydrostatic_surface`): the space the soil's own skeleton
    /// leaves, dilated or not, which its water should fill.
    domain_pores: Vec<f64>,
    /// Volume-weighted moments of the pressured liquid points about the
    /// element's centre, offsets in elements: Σw, Σwξ, Σwζ, Σwξ², Σwξζ,
    /// Σwζ², Σwp, Σwξp, Σwζp, and the number of points.
    pressure_moments: Vec<[f64; 10]>,
    /// The lowest fitted plane pressure among the element's pressured
    /// points, before the slope limiter.
    pressure_low: Vec<f64>,
    /// Δε_w of the pressure update.
    volumetric_strain: Vec<f64>,
}

impl ElementScratch {
    /// Filling ratio F_e of element `e` (area `area`): the share of the
    /// space its grains leave that water fills, Σ m_L/ρ_L / (area − Σ m_s/ρ_s),
    /// from the points' masses alone (the points' own porosities and
    /// volumes drift from the element's packing in a flow), each point
    /// counted by the part of its domain inside the element. (Counted
    /// whole in the element holding its centre, the fill jumped by a
    /// point's volume, ~8 %, in the step the point crossed in, and an
    /// element crossing `free_surface_fill` so was switched into the
    /// pressure solve with water still flowing in: the last pressure
    /// spikes, docs/mpm.md "Pore pressure", session 27.) 1 in a
    /// saturated element however dilated; below 1 where the pores have
    /// drained (the element of the lab column's 5.7 kPa spike: 0.40) or
    /// the element is part empty (a flow's surface, a thinning layer on
    /// the floor); the water's own fill in free water. Infinite where the
    /// grains leave no space.
    fn filling_ratio(&self, e: usize, area: f64) -> f64 {
        let (grains, water) = (self.domain_volume[0][e], self.domain_volume[1][e]);
        let space = area - grains;
        if space > 0.0 {
            water / space
        } else {
            f64::INFINITY
        }
    }

    /// The occupied share θ of element `e` (area `area`), grains and water
    /// over its area (at most 1), when the water fills at least `fill` of
    /// the pores of the soil it holds, or there is no soil: a saturated
    /// layer, as the top of a column or a flow's front inside the element.
    /// None where the soil's pores have drained. θ² h/2 is the depth, in
    /// units of ρ_L g, of the element pressure that holds a horizontal
    /// layer θh thick at rest on its nodes: its water's weight on the two
    /// top nodes is ρ_L g θ² h²/2 per unit width (bilinear and GIMP
    /// weights alike, the points' domains inside the element).
    fn saturated_layer(&self, e: usize, area: f64, fill: f64) -> Option<f64> {
        let (grains, water, pores) = (self.domain_volume[0][e], self.domain_volume[1][e], self.domain_pores[e]);
        (pores <= 0.0 || water >= fill * pores).then(|| ((grains + water) / area).min(1.0))
    }
}

/// Nodal fixities: 1 free, 0 fixed, per component (both phases alike).
#[derive(Debug, Clone)]
pub struct Fixities {
    /// Walls and ghost nodes.
    pub base: Vec<[f64; 2]>,
    /// Stored node indices each gate fixes in x while it holds.
    pub gates: Vec<Vec<usize>>,
    /// Per node, the unit vector into the wall whose Coulomb friction
    /// (`Params::wall_friction`) acts on the solid there; zero where none.
    /// Its component along the wall normal is fixed in `base`.
    pub contact: Vec<[f64; 2]>,
    /// The components walls hold along their normal only (corners give
    /// two; a rough floor's nodes none): those a unilateral contact
    /// releases (`Params::unilateral_walls`): the in-box ones in node
    /// order, then the ghost nodes'.
    pub walls: Vec<WallComponent>,
}

/// One node component a wall holds along its normal.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WallComponent {
    /// Stored node index.
    pub node: usize,
    /// The component held: 0 (x) or 1 (z).
    pub axis: usize,
    /// The direction into the wall along `axis`: ±1.
    pub into: f64,
}

/// Wall seconds per stage of [`Mpm::step`], summed over the steps taken
/// with [`Mpm::timing`] on (the `bench` subcommand's split).
#[derive(Debug, Clone, Copy, Default, Serialize)]
pub struct StageSeconds {
    /// Stencils, elements, bins and element sums of both point sets.
    pub locate: f64,
    /// Points to grid (mass, momentum, volumes) and the porosity fields.
    pub map: f64,
    /// Per-point stress, drag and porosity terms.
    pub prepare_forces: f64,
    /// Nodal forces, damping, drag and accelerations.
    pub solve_nodes: f64,
    /// The implicit pore pressure: reference, assembly, solve, corrector.
    pub pressure: f64,
    /// The liquid's force on the solid (`Mpm::take_liquid_impulse`), a diagnostic.
    pub liquid_force: f64,
    /// Coulomb friction on the walls.
    pub wall_friction: f64,
    /// Grid to points: the points' velocities.
    pub update_velocities: f64,
    /// The points' momenta mapped again and the nodal velocities (MUSL).
    pub remap: f64,
    /// Strains and stresses, volumes, pore pressure of the points.
    pub update_points: f64,
}

/// The solver: parameters, grid, state and scratch.
pub struct Mpm {
    pub params: Params,
    pub grid: Grid,
    pub state: MpmState,
    pub fixities: Fixities,
    mask: Vec<[f64; 2]>,
    /// ∫ N_I over the box per node (h² inside, less on the walls and on a
    /// held gate, which bounds the material like a wall), m².
    full_volume: Vec<f64>,
    box_volume: Vec<f64>,
    solid_scratch: PointScratch,
    liquid_scratch: PointScratch,
    elements: ElementScratch,
    sums: Vec<NodeSums>,
    velocity_s: Vec<[f64; 2]>,
    velocity_l: Vec<[f64; 2]>,
    relative: Vec<[f64; 2]>,
    solid_fraction: Vec<f64>,
    fill: Vec<f64>,
    /// Nodal accelerations and displacement increments, [solid, liquid].
    accel: Vec<NodeUpdate>,
    /// What the grid-to-points map reads per node (APIC/AFLIP).
    grid_velocity: Vec<GridVelocity>,
    disp: Vec<[[f64; 2]; 2]>,
    liquid_fill: Vec<f64>,
    /// XPIC(2): S⁺v_g at the points of each set.
    xpic_points: [Vec<[f64; 2]>; 2],
    /// Node rows and columns touched by any stencil this step (inclusive).
    rows: (usize, usize),
    columns: (usize, usize),
    /// Nodes with wall friction (`Mpm::contact_nodes`: in node order, or
    /// ghost rows first when friction passes on).
    contact_nodes: Vec<ContactNode>,
    /// Per node: the friction impulse passed on to it by the contact node
    /// behind it in this step, N s/m (zero between steps).
    friction_carry: Vec<f64>,
    /// The friction impulses passed on to the first nodes off the walls in
    /// this step: (node, axis along the wall, N s/m, the wall node's solid
    /// mass over its support ratio, kg/m: what it would hold of a node
    /// under the same material; see `apply_wall_friction`).
    interior_friction_carry: Vec<(usize, usize, f64, f64)>,
    mass_tolerance: f64,
    pub stage_seconds: StageSeconds,
    pub timing: bool,
    /// The frictional walls' forces on the solid in the last step.
    pub wall_forces: WallForces,
    /// Largest pore pressure at the end of any step since the recorder last
    /// took it (`take_pore_pressure_peak`), Pa: a diagnostic, not state.
    pore_pressure_peak: f64,
    /// What the map's release test did since the last
    /// `take_wall_release_stats`: a diagnostic, not state.
    wall_release_stats: WallReleaseStats,
    /// The liquid's impulse on the solid since the recorder last took it
    /// (`take_liquid_impulse`), N s/m along [x, z], and the time it covers, s:
    /// a diagnostic, not state.
    liquid_impulse: LiquidImpulse,
    /// Where that impulse acts, node by node and by part, while a probe
    /// has started it ([`Mpm::start_liquid_force_field`]): a diagnostic,
    /// not state; None (and no cost) otherwise.
    liquid_force_field: Option<LiquidForceField>,
    /// The implicit pressure's scratch (`Params::implicit_pressure`).
    implicit: Option<Box<ImplicitPressure>>,
    /// `sort_points`' scratch: which points the reordering has placed.
    sort_done: Vec<bool>,
    /// `apply_liquid_wall_shear`'s scratch: this step's lines, and per
    /// wall side (x_min, x_max, z_min, z_max) and tangent node the line's
    /// index (`u32::MAX`: none).
    film_lines: Vec<FilmLine>,
    film_lookup: Vec<u32>,
    /// `measure_film_depths`' per-chunk sums, line by line, chunk after
    /// chunk.
    film_partial: Vec<FilmSum>,
}

/// What the map's release test of unilateral walls
/// (`Mpm::release_walls_moved_off`) did over an interval of steps.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct WallReleaseStats {
    /// Wall components released right after the map, summed over the steps.
    pub released_at_map: u64,
    /// The largest speed off the wall, m/s, at which a held component with
    /// mass that the test kept held was carried within the step ((mapped
    /// momentum + Δt × `MpmState::wall_push`) off the wall over its mass;
    /// at most `Params::wall_release_speed`), or 0 if none was carried off:
    /// 0 where the material rests, pressed into its walls. Components
    /// skipped (cavitation allowed, held by a gate) are not counted.
    pub largest_speed_kept: f64,
}

/// The liquid's impulse on the solid node by node, split into the parts
/// [`Mpm::take_liquid_impulse`] sums, over the steps since
/// [`Mpm::start_liquid_force_field`] (`mpm_proc probe`, docs/mpm.md): each
/// step adds, at each node with solid and along each axis the node is free
/// in, its part times Δt, N s/m, [x, z]. The three parts summed over the
/// nodes are the [`LiquidImpulse`] of the same steps (the same terms in the
/// same order).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct LiquidForceField {
    /// The liquid's stress share on the solid (the explicit scheme's pore
    /// pressure, the viscous stress, the porosity-gradient term), per node.
    pub stress: Vec<[f64; 2]>,
    /// The implicit scheme's solved pore pressure's share, per node (zero
    /// under the explicit scheme).
    pub pressure: Vec<[f64; 2]>,
    /// The drag Q (v_L − v_S) at the step's end velocities, per node.
    pub drag: Vec<[f64; 2]>,
    /// Σ Δt, s.
    pub time: f64,
}

/// The liquid's impulse on the solid over an interval of steps
/// ([`Mpm::take_liquid_impulse`]): each step adds the force the liquid put
/// on the solid (its stress share and the drag, over the nodes free along
/// each axis) times Δt.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct LiquidImpulse {
    /// Σ F Δt over the interval's steps, N s/m, [x, z].
    pub impulse: [f64; 2],
    /// Σ Δt, s.
    pub time: f64,
}

impl LiquidImpulse {
    /// The interval's mean force, N/m; [0, 0] over an empty interval.
    pub fn mean_force(&self) -> [f64; 2] {
        if self.time > 0.0 {
            [self.impulse[0] / self.time, self.impulse[1] / self.time]
        } else {
            [0.0; 2]
        }
    }
}

/// Sums over the frictional wall nodes (`Fixities::contact`) of one step,
/// N per metre of width.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct WallForces {
    /// The grains' normal load on the walls.
    pub normal_load: f64,
    /// The friction force the walls applied, in magnitude (under
    /// `Params::friction_reaches_next_node`, what the nodes next to the
    /// walls took included).
    pub friction: f64,
}

impl std::fmt::Debug for Mpm {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Mpm")
            .field("grid", &self.grid)
            .field("solid_points", &self.state.solid.set.len())
            .field("liquid_points", &self.state.liquid.set.len())
            .field("time", &self.state.time)
            .finish()
    }
}

impl Mpm {
    /// A solver over `grid` from `state`. Preconditions: points inside the
    /// box; `fixities.base` sized to the grid's nodes; GIMP shapes under
    /// APIC; point ids empty or each point's once (`PointSet::check_ids`;
    /// panics otherwise).
    pub fn new(params: Params, grid: Grid, state: MpmState, fixities: Fixities) -> Self {
        let wall_count = fixities.walls.len();
        // Scene validation refuses the pair with the fix; this guards a
        // hand-built `Params` (bilinear D_p is singular on grid lines).
        assert!(
            !(params.apic && grid.shape == ShapeFunctions::Linear),
            "APIC needs GIMP shape functions (mpm.shape_functions = \"gimp\")"
        );
        for set in [&state.solid.set, &state.liquid.set] {
            if let Err(e) = set.check_ids() {
                panic!("Mpm::new: {e} (ids are empty or each point's index when the set was made)");
            }
        }
        let nodes = grid.node_count();
        let [row, rows] = grid.node_dims();
        let mut full_volume = vec![0.0; nodes];
        let h = grid.h;
        for r in 0..rows {
            for c in 0..row {
                // Fraction of the node's hat support inside the box, per axis.
                let inside = |i: usize, n: usize| -> f64 {
                    let i = i as isize - crate::grid::GHOST as isize;
                    if i < 0 || i > n as isize {
                        0.0
                    } else if i == 0 || i == n as isize {
                        0.5
                    } else {
                        1.0
                    }
                };
                full_volume[r * row + c] = h * h * inside(c, grid.elements[0]) * inside(r, grid.elements[1]);
            }
        }
        let min_mass = state.solid.set.mass.iter().chain(&state.liquid.set.mass).cloned().fold(f64::INFINITY, f64::min);
        let ne = grid.element_count();
        let contact_nodes =
            Self::contact_nodes(&grid, &fixities.contact, &full_volume, params.friction_reaches_next_node);
        let mut mpm = Mpm {
            params,
            grid,
            box_volume: full_volume.clone(),
            mask: fixities.base.clone(),
            fixities,
            full_volume,
            solid_scratch: PointScratch::default(),
            liquid_scratch: PointScratch::default(),
            elements: ElementScratch {
                porosity: vec![1.0; ne],
                grad_porosity: vec![[0.0; 2]; ne],
                liquid_points: vec![0; ne],
                solid_mass_solid: vec![0.0; ne],
                solid_mass_fluidised: vec![0.0; ne],
                grain_volume: vec![0.0; ne],
                solid_point_volume: vec![0.0; ne],
                domain_volume: [vec![0.0; ne], vec![0.0; ne]],
                domain_pores: vec![0.0; ne],
                pressure_moments: vec![[0.0; 10]; ne],
                pressure_low: vec![0.0; ne],
                volumetric_strain: vec![0.0; ne],
            },
            sums: vec![NodeSums::default(); nodes],
            velocity_s: vec![[0.0; 2]; nodes],
            velocity_l: vec![[0.0; 2]; nodes],
            relative: vec![[0.0; 2]; nodes],
            solid_fraction: vec![0.0; nodes],
            fill: vec![0.0; nodes],
            accel: vec![NodeUpdate::default(); nodes],
            grid_velocity: vec![GridVelocity::default(); nodes],
            disp: vec![[[0.0; 2]; 2]; nodes],
            liquid_fill: Vec::new(),
            xpic_points: [Vec::new(), Vec::new()],
            rows: (0, 0),
            columns: (0, 0),
            interior_friction_carry: Vec::with_capacity(contact_nodes.len()),
            contact_nodes,
            friction_carry: vec![0.0; nodes],
            mass_tolerance: if min_mass.is_finite() { 1e-6 * min_mass } else { 0.0 },
            stage_seconds: StageSeconds::default(),
            timing: false,
            wall_forces: WallForces::default(),
            pore_pressure_peak: 0.0,
            wall_release_stats: WallReleaseStats::default(),
            liquid_impulse: LiquidImpulse::default(),
            liquid_force_field: None,
            implicit: None,
            sort_done: Vec::new(),
            film_lines: Vec::with_capacity(wall_count),
            film_lookup: vec![u32::MAX; 4 * grid.node_dims()[0].max(grid.node_dims()[1])],
            film_partial: Vec::with_capacity(state.liquid.set.x.len().div_ceil(FILM_CHUNK) * wall_count),
            state,
        };
        if mpm.params.implicit_pressure {
            mpm.implicit = Some(Box::new(ImplicitPressure::new(grid, &mpm.params)));
        }
        mpm.apply_gate_fixities();
        mpm
    }

    /// The nodes with wall friction, in node order; when the friction a
    /// wall node cannot take passes on (`reach`), ordered so that a node
    /// comes after every contact node behind it on the same wall (ghost
    /// rows first). Post: each node's `inward` is stored (with the ghost
    /// layer, a wall's nodes always have a node off the wall).
    fn contact_nodes(grid: &Grid, contact: &[[f64; 2]], full_volume: &[f64], reach: bool) -> Vec<ContactNode> {
        let row = grid.node_dims()[0] as isize;
        // The node one step off the wall from `node`; itself if not stored.
        let inward = |node: usize, into: [f64; 2]| {
            let i = node as isize - into[0] as isize - into[1] as isize * row;
            if (0..contact.len() as isize).contains(&i) {
                i as usize
            } else {
                node
            }
        };
        let mut nodes: Vec<(usize, ContactNode)> = contact
            .iter()
            .enumerate()
            .filter(|(_, into)| **into != [0.0; 2])
            .map(|(node, &into)| {
                let next = inward(node, into);
                // Contact nodes of the same wall between this one and the box.
                let (mut behind, mut at) = (0, node);
                while inward(at, into) != at && contact[inward(at, into)] == into {
                    behind += 1;
                    at = inward(at, into);
                }
                let tangent = if into[0] != 0.0 { 1 } else { 0 };
                let support_ratio =
                    if next != node && full_volume[next] > 0.0 { full_volume[node] / full_volume[next] } else { 0.0 };
                let inward_is_contact = next != node && contact[next] == into;
                (behind, ContactNode { node, tangent, inward: next, inward_is_contact, support_ratio })
            })
            .collect();
        if reach {
            nodes.sort_by_key(|&(behind, c)| (std::cmp::Reverse(behind), c.node));
        }
        nodes.into_iter().map(|(_, c)| c).collect()
    }

    /// Rebuilds the mask from the walls (less the components a unilateral
    /// contact has released, `MpmState::walls_released`) and the gates
    /// that still hold.
    pub fn apply_gate_fixities(&mut self) {
        // Sized here for a new state, and for one from elsewhere (a
        // checkpoint) whose wall count would leave walls out of the zip.
        let walls = if self.params.unilateral_walls { self.fixities.walls.len() } else { 0 };
        self.state.walls_released.resize(walls, false);
        self.state.wall_push.resize(walls, 0.0);
        self.mask.copy_from_slice(&self.fixities.base);
        self.full_volume.copy_from_slice(&self.box_volume);
        self.hold_walls_and_gates();
    }

    /// The mask's wall components from `MpmState::walls_released`, then the
    /// gates' holds over them (a gate on a wall holds it both ways).
    fn hold_walls_and_gates(&mut self) {
        for (w, &released) in self.fixities.walls.iter().zip(&self.state.walls_released) {
            self.mask[w.node][w.axis] = if released { 1.0 } else { 0.0 };
        }
        for (g, nodes) in self.fixities.gates.iter().enumerate() {
            if self.state.gates_held.get(g).copied().unwrap_or(false) {
                for &n in nodes {
                    self.mask[n][0] = 0.0;
                    // Only the material side of the gate counts toward the fill.
                    self.full_volume[n] = 0.5 * self.box_volume[n];
                }
            }
        }
    }

    /// Releases gate `g` (its fixity is removed from the next step on).
    pub fn release_gate(&mut self, g: usize) {
        if let Some(h) = self.state.gates_held.get_mut(g) {
            *h = false;
        }
        self.apply_gate_fixities();
    }

    /// The largest pore pressure since the last [`Mpm::take_pore_pressure_peak`], Pa.
    pub fn pore_pressure_peak(&self) -> f64 {
        self.pore_pressure_peak
    }

    /// Sets the running peak (a resumed run continues the interrupted one's).
    pub fn restore_pore_pressure_peak(&mut self, peak: f64) {
        self.pore_pressure_peak = peak;
    }

    /// The largest pore pressure at the end of any step since the last
    /// call (0 before any liquid pressure), and starts a new interval.
    pub fn take_pore_pressure_peak(&mut self) -> f64 {
        std::mem::take(&mut self.pore_pressure_peak)
    }

    /// What the map's release test (`Params::wall_release_speed`) did
    /// since the last call, and starts a new interval.
    pub fn take_wall_release_stats(&mut self) -> WallReleaseStats {
        std::mem::take(&mut self.wall_release_stats)
    }

    /// The liquid's impulse on the solid since the last
    /// [`Mpm::take_liquid_impulse`] (a checkpoint carries it).
    pub fn liquid_impulse(&self) -> LiquidImpulse {
        self.liquid_impulse
    }

    /// Sets the running impulse (a resumed run continues the interrupted one's).
    pub fn restore_liquid_impulse(&mut self, impulse: LiquidImpulse) {
        self.liquid_impulse = impulse;
    }

    /// The liquid's impulse on the solid since the last call, and starts a
    /// new interval.
    pub fn take_liquid_impulse(&mut self) -> LiquidImpulse {
        std::mem::take(&mut self.liquid_impulse)
    }

    /// Starts (or restarts) summing the liquid's impulse on the solid node
    /// by node ([`LiquidForceField`]); each step then adds three sums per
    /// free node and axis to the force's own loop.
    pub fn start_liquid_force_field(&mut self) {
        let nodes = self.grid.node_count();
        self.liquid_force_field = Some(LiquidForceField {
            stress: vec![[0.0; 2]; nodes],
            pressure: vec![[0.0; 2]; nodes],
            drag: vec![[0.0; 2]; nodes],
            time: 0.0,
        });
    }

    /// The field summed since [`Mpm::start_liquid_force_field`], and stops
    /// summing; None when it was not started.
    pub fn take_liquid_force_field(&mut self) -> Option<LiquidForceField> {
        self.liquid_force_field.take()
    }

    /// What the implicit pressure solves have cost so far (None under the
    /// explicit scheme).
    pub fn pressure_stats(&self) -> Option<PressureStats> {
        self.implicit.as_ref().map(|i| i.stats)
    }

    /// Advances one step of Δt.
    pub fn step(&mut self) {
        let implicit = self.params.implicit_pressure;
        let mut clock = self.timing.then(std::time::Instant::now);
        // Adds the time since the last lap to one stage's total.
        let mut lap = |total: &mut f64| {
            if let Some(then) = clock.as_mut() {
                let now = std::time::Instant::now();
                *total += (now - *then).as_secs_f64();
                *then = now;
            }
        };
        let mut seconds = self.stage_seconds;
        if self.params.unilateral_walls {
            self.hold_walls_and_gates();
        }
        if self.state.steps.is_multiple_of(SORT_INTERVAL) {
            self.sort_points();
        }
        self.locate();
        lap(&mut seconds.locate);
        self.map_to_grid();
        if self.params.unilateral_walls {
            self.release_walls_moved_off();
        }
        self.porosity_fields();
        lap(&mut seconds.map);
        self.prepare_forces();
        lap(&mut seconds.prepare_forces);
        self.solve_nodes();
        lap(&mut seconds.solve_nodes);
        self.apply_liquid_wall_shear();
        lap(&mut seconds.wall_friction);
        if implicit {
            let started = std::time::Instant::now();
            self.pressure_reference();
            self.assemble_pressure_problem();
            self.solve_pressure();
            self.correct_velocities();
            if let Some(i) = self.implicit.as_mut() {
                i.stats.seconds += started.elapsed().as_secs_f64();
            }
            lap(&mut seconds.pressure);
        }
        if self.params.unilateral_walls {
            self.update_wall_contacts();
            lap(&mut seconds.wall_friction);
        }
        if !self.state.liquid.set.is_empty() {
            // Before the walls' friction changes the contact nodes' solid velocity.
            let mut field = self.liquid_force_field.take();
            let force = self.liquid_force_on_solid(field.as_mut());
            self.liquid_force_field = field;
            let dt = self.params.dt;
            let i = &mut self.liquid_impulse;
            i.impulse = [i.impulse[0] + force[0] * dt, i.impulse[1] + force[1] * dt];
            i.time += dt;
            lap(&mut seconds.liquid_force);
        }
        self.apply_wall_friction();
        lap(&mut seconds.wall_friction);
        self.update_velocities();
        lap(&mut seconds.update_velocities);
        self.remap_momentum();
        lap(&mut seconds.remap);
        self.volumetric_strain_per_element();
        self.update_points();
        if !implicit {
            self.reconstruct_pressure();
        }
        self.pore_pressure_peak = self.state.liquid.pressure.iter().fold(self.pore_pressure_peak, |m, &p| m.max(p));
        lap(&mut seconds.update_points);
        self.stage_seconds = seconds;
        self.state.time += self.params.dt;
        self.state.steps += 1;
    }

    /// The force the liquid puts on the solid in the current step, once its
    /// velocities are solved and before the walls' friction, summed over
    /// the nodes, N/m (per metre of width), [x, z]: at each node with solid,
    /// the liquid's stress share (pore pressure and viscous stress, with
    /// the porosity-gradient term) and the drag Q (v_L − v_S) at the
    /// step's end velocities (the drag is implicit in them), over the
    /// nodes free along each axis. Where a wall holds a node the wall takes
    /// its share: the nodal forces of a stress field sum to zero over all
    /// nodes (the shape functions partition unity), so the pressure's
    /// resultant on the grains is what the free nodes carry and the held
    /// ones balance. At rest in still water it is the buoyancy
    /// ρ_L g (1 − n) A, A the submerged area, less the half element row on
    /// the floor's nodes; a water table sloping at i adds the seepage push
    /// ρ_L g i per unit volume along it. `step` adds it, times Δt, to the
    /// impulse the recorder takes ([`Mpm::take_liquid_impulse`]). With a
    /// `field`, each node's parts times Δt are added to it as well.
    fn liquid_force_on_solid(&self, mut field: Option<&mut LiquidForceField>) -> [f64; 2] {
        let (dt, tol) = (self.params.dt, self.mass_tolerance);
        let pressure = self.implicit.as_ref().map(|i| &i.pressure_force[0]);
        let mut total = [0.0; 2];
        for node in self.active_nodes() {
            let s = &self.sums[node];
            if s.mass_s <= tol {
                continue;
            }
            let u = &self.accel[node];
            let drag = if s.mass_l > tol { u.drag } else { 0.0 };
            for d in (0..2).filter(|&d| self.mask[node][d] != 0.0) {
                let vs = self.velocity_s[node][d] + dt * u.a[0][d];
                let vl = self.velocity_l[node][d] + dt * u.a[1][d];
                let p = pressure.map_or(0.0, |f| f[node][d]);
                let friction = drag * (vl - vs);
                total[d] += u.liquid_on_solid[d] + p + friction;
                if let Some(f) = field.as_deref_mut() {
                    f.stress[node][d] += u.liquid_on_solid[d] * dt;
                    f.pressure[node][d] += p * dt;
                    f.drag[node][d] += friction * dt;
                }
            }
        }
        if let Some(f) = field {
            f.time += dt;
        }
        total
    }

    /// Kinetic energy of the solid and of the liquid momenta as the grid
    /// holds them, Σ_I |p_I|²/(2 m_I) over the nodes, J/m, from the map at
    /// the start of the last step (fixities not applied). Under FLIP never
    /// above the points' own (Jensen); the difference is motion the grid
    /// cannot see (the null space of the map, which FLIP keeps and nothing
    /// acts on). Under APIC it can exceed ½ Σ m v², which leaves out the
    /// points' affine part.
    pub fn grid_kinetic_energy(&self) -> (f64, f64) {
        let tol = self.mass_tolerance;
        let (mut solid, mut liquid) = (0.0, 0.0);
        for node in self.active_nodes() {
            let Some(s) = self.sums.get(node) else { continue };
            if s.mass_s > tol {
                solid += 0.5 * (s.momentum_s[0].powi(2) + s.momentum_s[1].powi(2)) / s.mass_s;
            }
            if s.mass_l > tol {
                liquid += 0.5 * (s.momentum_l[0].powi(2) + s.momentum_l[1].powi(2)) / s.mass_l;
            }
        }
        (solid, liquid)
    }

    // -- stage 0 ---------------------------------------------------------

    /// Both point sets put in the order of their stencils' base nodes, row
    /// by row (a stable counting sort, [`Self::bin_points`]), every
    /// [`SORT_INTERVAL`] steps. The point stages split the points by index
    /// and the node stages split the nodes by position; in the grid's order
    /// a thread's points and the nodes it gathers into lie in one region,
    /// so a node stage reads mostly what its own core wrote in the stage
    /// before, and a node's points lie together in memory (LAMMPS's atom
    /// sort). Post: `PointSet::id` keeps each point's identity. Sums over
    /// the points run in index order, so the order changes results at
    /// round-off only (docs/mpm.md, "Parallel work and determinism").
    fn sort_points(&mut self) {
        let Self { grid, state, solid_scratch, liquid_scratch, sort_done, .. } = self;
        for set in [&mut state.solid.set, &mut state.liquid.set] {
            // `Mpm::new` checked the ids: empty or each point's once.
            if set.id.is_empty() {
                set.id = (0..set.len() as u32).collect();
            }
        }
        Self::bin_points(grid, &state.solid.set, solid_scratch);
        reorder(&solid_scratch.order, sort_done, |a, b| state.solid.swap(a, b));
        Self::bin_points(grid, &state.liquid.set, liquid_scratch);
        reorder(&liquid_scratch.order, sort_done, |a, b| state.liquid.swap(a, b));
    }

    // -- stage 1 ---------------------------------------------------------

    /// Stencils, elements and bins of both point sets; the node range touched.
    fn locate(&mut self) {
        let grid = self.grid;
        let params = &self.params;
        let (solid, liquid) = (&self.state.solid, &self.state.liquid.set);
        let e = &mut self.elements;
        let liquid_points = &mut e.liquid_points;
        let (mass_solid, mass_fluidised) = (&mut e.solid_mass_solid, &mut e.solid_mass_fluidised);
        let (grain_volume, solid_point_volume) = (&mut e.grain_volume, &mut e.solid_point_volume);
        let [domain_grains, domain_water] = &mut e.domain_volume;
        let domain_pores = &mut e.domain_pores;
        // The two sets share nothing here: one thread each for the serial
        // counting sorts and element sums.
        let (solid_span, liquid_span) = rayon::join(
            || {
                let span = Self::bin_points(&grid, &solid.set, &mut self.solid_scratch);
                mass_solid.fill(0.0);
                mass_fluidised.fill(0.0);
                grain_volume.fill(0.0);
                solid_point_volume.fill(0.0);
                for (p, &el) in self.solid_scratch.element.iter().enumerate() {
                    let (el, m) = (el as usize, solid.set.mass[p]);
                    if solid.fluidised[p] {
                        mass_fluidised[el] += m;
                    } else {
                        mass_solid[el] += m;
                    }
                    grain_volume[el] += m / params.solid_density;
                    solid_point_volume[el] += solid.set.volume[p];
                }
                // The grains' domains only enter the liquid's filling ratio,
                // and their pores the saturated layers' rule.
                if !liquid.is_empty() {
                    let rho = params.solid_density;
                    let set = &solid.set;
                    if params.hydrostatic_surface {
                        let own = |p: usize| [set.mass[p] / rho, set.volume[p] - set.mass[p] / rho];
                        Self::spread_over_domains(&grid, set, own, [domain_grains, domain_pores]);
                    } else {
                        Self::spread_over_domains(&grid, set, |p| [set.mass[p] / rho], [domain_grains]);
                    }
                }
                span
            },
            || {
                let span = Self::bin_points(&grid, liquid, &mut self.liquid_scratch);
                liquid_points.fill(0);
                for &el in &self.liquid_scratch.element {
                    liquid_points[el as usize] += 1;
                }
                let rho = params.liquid_density;
                Self::spread_over_domains(&grid, liquid, |p| [liquid.mass[p] / rho], [domain_water]);
                span
            },
        );
        let [row_len, row_count] = grid.node_dims();
        let (rows, columns) = match (solid_span, liquid_span) {
            (Some((r0, c0)), Some((r1, c1))) => ((r0.0.min(r1.0), r0.1.max(r1.1)), (c0.0.min(c1.0), c0.1.max(c1.1))),
            (Some(span), None) | (None, Some(span)) => span,
            (None, None) => ((0, 0), (0, 0)),
        };
        self.rows = (rows.0, (rows.1 + 2).min(row_count - 1));
        self.columns = (columns.0, (columns.1 + 2).min(row_len - 1));
    }

    /// Each point's own volumes `own(p)` (m/ρ, a pore volume) shared among
    /// the elements its GIMP domain covers, in proportion to the area it
    /// covers in each, into `out` (one array per volume).
    fn spread_over_domains<const K: usize>(
        grid: &Grid,
        set: &PointSet,
        own: impl Fn(usize) -> [f64; K],
        mut out: [&mut Vec<f64>; K],
    ) {
        for volume in out.iter_mut() {
            volume.fill(0.0);
        }
        let nx = grid.elements[0];
        for (p, x) in set.x.iter().enumerate() {
            let [(cols, wx), (rows, wz)] = grid.domain_overlap(*x, set.half);
            let own = own(p);
            for (r, fz) in rows.into_iter().zip(wz) {
                for (c, fx) in cols.into_iter().zip(wx) {
                    for (volume, v) in out.iter_mut().zip(own) {
                        volume[r * nx + c] += v * fx * fz;
                    }
                }
            }
        }
    }

    /// Stencils and elements of one point set, and its points binned by
    /// stencil base node (a stable counting sort: bins hold points in index
    /// order). Returns the base nodes' (row, column) span, None when empty.
    #[allow(clippy::type_complexity)]
    fn bin_points(grid: &Grid, set: &PointSet, scratch: &mut PointScratch) -> Option<((usize, usize), (usize, usize))> {
        let nodes = grid.node_count();
        let row = grid.node_dims()[0];
        let n = set.len();
        scratch.stencil.resize(n, Stencil::default());
        scratch.element.resize(n, 0);
        scratch.order.resize(n, 0);
        scratch.start.clear();
        scratch.start.resize(nodes + 1, 0);
        let constants = grid.shape_constants(set.half);
        scratch
            .stencil
            .par_iter_mut()
            .zip(scratch.element.par_iter_mut())
            .zip(set.x.par_iter())
            .with_min_len(CHUNK)
            .for_each(|((st, el), &x)| {
                *st = grid.stencil(x, &constants);
                *el = grid.element_of(x) as u32;
            });
        let (mut rows, mut columns) = ((usize::MAX, 0), (usize::MAX, 0));
        for st in &scratch.stencil {
            scratch.start[st.base as usize + 1] += 1;
            let (c, r) = (st.base as usize % row, st.base as usize / row);
            rows = (rows.0.min(r), rows.1.max(r));
            columns = (columns.0.min(c), columns.1.max(c));
        }
        // The running total in a register: `start[b + 1] += start[b]` waits
        // on its own store every node (a tenth of a dry step).
        let mut total = 0;
        for s in &mut scratch.start[1..] {
            total += *s;
            *s = total;
        }
        scratch.cursor.clear();
        scratch.cursor.extend_from_slice(&scratch.start[..nodes]);
        for (p, st) in scratch.stencil.iter().enumerate() {
            let slot = &mut scratch.cursor[st.base as usize];
            scratch.order[*slot as usize] = p as u32;
            *slot += 1;
        }
        (n > 0).then_some((rows, columns))
    }

    // -- stage 2 ---------------------------------------------------------

    /// Calls `f(point, N, ∇N)` for every point of `scratch` whose stencil reaches stored node `node`.
    #[inline(always)]
    fn gather(scratch: &PointScratch, row: usize, node: usize, mut f: impl FnMut(usize, f64, [f64; 2])) {
        let (c, r) = (node % row, node / row);
        for l in 0..3 {
            if r < l {
                break;
            }
            for j in 0..3 {
                if c < j {
                    break;
                }
                let base = node - l * row - j;
                for &p in scratch.bin(base) {
                    let st = &scratch.stencil[p as usize];
                    let n = st.wx[j] * st.wz[l];
                    let grad = [st.gx[j] * st.wz[l], st.wx[j] * st.gz[l]];
                    f(p as usize, n, grad);
                }
            }
        }
    }

    /// The stored nodes of the touched range (`rows` × `columns`), row by
    /// row: the serial counterpart of [`Self::for_active_nodes`].
    /// Whether a node lies in the range the last map touched (outside it
    /// the node scratch is stale: no material there), as a closure that
    /// borrows nothing of `self`.
    fn touched_range(&self) -> impl Fn(usize) -> bool + use<> {
        let ((r0, r1), (c0, c1), row) = (self.rows, self.columns, self.grid.node_dims()[0]);
        move |node| (r0..=r1).contains(&(node / row)) && (c0..=c1).contains(&(node % row))
    }

    fn active_nodes(&self) -> impl Iterator<Item = usize> + use<> {
        let row = self.grid.node_dims()[0];
        let ((r0, r1), (c0, c1)) = (self.rows, self.columns);
        (r0..=r1).flat_map(move |r| (c0..=c1).map(move |c| r * row + c))
    }

    /// The nodes from the first to the last active one (`active_nodes`),
    /// whole rows between: a contiguous range of node indices.
    fn active_node_range(&self) -> std::ops::Range<usize> {
        let row = self.grid.node_dims()[0];
        let ((r0, r1), (c0, c1)) = (self.rows, self.columns);
        r0 * row + c0..r1 * row + c1 + 1
    }

    /// The elements of the rows the touched nodes span (`Mpm::rows`): every
    /// element a point lies in and every one `assemble_pressure_problem`
    /// sets, as a contiguous range of element indices.
    fn touched_element_range(&self) -> std::ops::Range<usize> {
        let (nx, nz) = (self.grid.elements[0], self.grid.elements[1]);
        let (r0, r1) = self.rows;
        // Node row r (ghost row 0) is the bottom of element row r − 1.
        let first = (r0.max(1) - 1).min(nz);
        let end = r1.min(nz + 1).saturating_sub(1).max(first);
        first * nx..end * nx
    }

    /// Runs `f(node)` over the touched node range in parallel, writing `out[node]`.
    fn for_active_nodes<T: Send>(&self, out: &mut [T], f: impl Fn(usize, &mut T) + Sync) {
        let row = self.grid.node_dims()[0];
        let (c0, c1) = self.columns;
        let range = self.active_node_range();
        let first = range.start;
        out[range].par_chunks_mut(NODE_CHUNK).enumerate().for_each(|(k, chunk)| {
            let start = first + k * NODE_CHUNK;
            for (node, slot) in (start..).zip(chunk) {
                if (c0..=c1).contains(&(node % row)) {
                    f(node, slot);
                }
            }
        });
    }

    /// Mass, momentum and volumes of both phases at the nodes; nodal
    /// velocities, relative velocity, solid fraction and filling ratio.
    fn map_to_grid(&mut self) {
        let row = self.grid.node_dims()[0];
        let (solid, liquid) = (&self.state.solid.set, &self.state.liquid.set);
        let (ss, ls) = (&self.solid_scratch, &self.liquid_scratch);
        let rho_s = self.params.solid_density;
        let (grid, apic) = (&self.grid, self.params.apic);
        let mut sums = std::mem::take(&mut self.sums);
        self.for_active_nodes(&mut sums, |node, out| {
            let mut s = NodeSums::default();
            let at = grid.node_position(node % row, node / row);
            Self::gather(ss, row, node, |p, n, _| {
                let m = n * solid.mass[p];
                let v = point_velocity_at(solid, p, at, apic);
                s.mass_s += m;
                s.momentum_s[0] += m * v[0];
                s.momentum_s[1] += m * v[1];
                s.volume_s += n * solid.volume[p];
                s.solid_volume += m / rho_s;
            });
            Self::gather(ls, row, node, |p, n, _| {
                let m = n * liquid.mass[p];
                let v = point_velocity_at(liquid, p, at, apic);
                s.mass_l += m;
                s.momentum_l[0] += m * v[0];
                s.momentum_l[1] += m * v[1];
                s.volume_l += n * liquid.volume[p];
            });
            *out = s;
        });
        self.sums = sums;
        let tol = self.mass_tolerance;
        let (r0, r1) = self.rows;
        let (c0, c1) = self.columns;
        let rows = r0 * row..(r1 + 1) * row;
        let (sums, mask, full_volume) = (&self.sums, &self.mask, &self.full_volume);
        self.velocity_s[rows.clone()]
            .par_chunks_mut(row)
            .zip(self.velocity_l[rows.clone()].par_chunks_mut(row))
            .zip(self.relative[rows.clone()].par_chunks_mut(row))
            .zip(self.solid_fraction[rows.clone()].par_chunks_mut(row))
            .zip(self.fill[rows].par_chunks_mut(row))
            .enumerate()
            .for_each(|(k, ((((velocity_s, velocity_l), relative), solid_fraction), fill))| {
                for c in c0..=c1 {
                    let i = (r0 + k) * row + c;
                    let (s, m) = (&sums[i], mask[i]);
                    let vs = if s.mass_s > tol {
                        [m[0] * s.momentum_s[0] / s.mass_s, m[1] * s.momentum_s[1] / s.mass_s]
                    } else {
                        [0.0; 2]
                    };
                    let vl = if s.mass_l > tol {
                        [m[0] * s.momentum_l[0] / s.mass_l, m[1] * s.momentum_l[1] / s.mass_l]
                    } else {
                        [0.0; 2]
                    };
                    velocity_s[c] = vs;
                    velocity_l[c] = vl;
                    relative[c] =
                        if s.mass_s > tol && s.mass_l > tol { [vl[0] - vs[0], vl[1] - vs[1]] } else { [0.0; 2] };
                    let v = s.volume_s.max(s.volume_l);
                    solid_fraction[c] = if v > 0.0 { (s.solid_volume / v).min(MAX_SOLID_FRACTION) } else { 0.0 };
                    let full = full_volume[i];
                    fill[c] = if full > 0.0 { s.volume_l / full } else { 0.0 };
                }
            });
    }

    /// Element porosity and its gradient from the corner nodes at the centroid.
    fn porosity_fields(&mut self) {
        let grid = self.grid;
        let row = grid.node_dims()[0];
        let h = grid.h;
        let c = &self.solid_fraction;
        let (r0, r1) = self.rows;
        let (c0, c1) = self.columns;
        let nx = grid.elements[0];
        for r in r0.max(1)..r1.min(grid.elements[1] + 1) {
            for col in c0.max(1)..c1.min(nx + 1) {
                let e = (r - 1) * nx + (col - 1);
                let n0 = r * row + col;
                let (a, b, d, f) = (c[n0], c[n0 + 1], c[n0 + row], c[n0 + row + 1]);
                let mean = 0.25 * (a + b + d + f);
                self.elements.porosity[e] = 1.0 - mean;
                self.elements.grad_porosity[e] = [-((b - a) + (f - d)) / (2.0 * h), -((d - a) + (f - b)) / (2.0 * h)];
            }
        }
    }

    // -- stage 3 ---------------------------------------------------------

    /// Per-point force data: stress × volume, the drag coefficient of solid
    /// points, porosity terms and filling ratio of liquid points.
    fn prepare_forces(&mut self) {
        let row = self.grid.node_dims()[0];
        let solid = &self.state.solid;
        let drag = &self.params.drag;
        let relative = &self.relative;
        let liquid_points = &self.elements.liquid_points;
        let xpic = self.xpic_active();
        let (vs, vl) = (&self.velocity_s, &self.velocity_l);
        let [w_s, w_l] = &mut self.xpic_points;
        let ss = &mut self.solid_scratch;
        ss.force.resize(solid.set.len(), [0.0; 6]);
        w_s.resize(if xpic { solid.set.len() } else { 0 }, [0.0; 2]);
        let solid_point = |p: usize, f: &mut [f64; 6]| -> [f64; 2] {
            let st = &ss.stencil[p];
            let v = solid.set.volume[p];
            let s = solid.stress[p];
            let mut w1 = [0.0; 2];
            let q = if liquid_points[ss.element[p] as usize] > 0 {
                let mut w = [0.0; 2];
                st.for_each(row, |node, n, _| {
                    w[0] += n * relative[node][0];
                    w[1] += n * relative[node][1];
                    w1[0] += n * vs[node][0];
                    w1[1] += n * vs[node][1];
                });
                v * drag.coefficient(solid.porosity[p], (w[0] * w[0] + w[1] * w[1]).sqrt())
            } else {
                if xpic {
                    w1 = st.interpolate(row, |i| vs[i]);
                }
                0.0
            };
            *f = [s[0] * v, s[1] * v, s[2] * v, q, 0.0, 0.0];
            w1
        };
        if xpic {
            ss.force.par_iter_mut().zip(w_s.par_iter_mut()).enumerate().with_min_len(CHUNK).for_each(|(p, (f, w))| {
                *w = solid_point(p, f);
            });
        } else {
            ss.force.par_iter_mut().enumerate().with_min_len(CHUNK).for_each(|(p, f)| {
                solid_point(p, f);
            });
        }
        let liquid = &self.state.liquid;
        let fill = &self.fill;
        let el = &self.elements;
        let implicit = self.params.implicit_pressure;
        let ls = &mut self.liquid_scratch;
        ls.force.resize(liquid.set.len(), [0.0; 6]);
        self.liquid_fill.resize(liquid.set.len(), 0.0);
        w_l.resize(liquid.set.len(), [0.0; 2]);
        ls.force
            .par_iter_mut()
            .zip(self.liquid_fill.par_iter_mut())
            .zip(w_l.par_iter_mut())
            .enumerate()
            .with_min_len(CHUNK)
            .for_each(|(p, ((f, fl), w1))| {
                let st = &ls.stencil[p];
                let e = ls.element[p] as usize;
                let (n, gn) = (el.porosity[e], el.grad_porosity[e]);
                let v = liquid.set.volume[p];
                // The implicit scheme's predictor leaves the pore pressure out.
                let pr = if implicit { 0.0 } else { liquid.pressure[p] };
                let t = liquid.viscous[p];
                let (sxx, szz, sxz) = (t[0] - pr, t[1] - pr, t[2]);
                *f = [sxx * v, szz * v, sxz * v, n, (sxx * gn[0] + sxz * gn[1]) * v, (sxz * gn[0] + szz * gn[1]) * v];
                let mut w = 0.0;
                let mut u = [0.0; 2];
                st.for_each(row, |node, n, _| {
                    w += n * fill[node];
                    u[0] += n * vl[node][0];
                    u[1] += n * vl[node][1];
                });
                *fl = w;
                *w1 = u;
            });
    }

    /// Nodal forces, local damping, drag implicit per node, accelerations.
    fn solve_nodes(&mut self) {
        let row = self.grid.node_dims()[0];
        let p = &self.params;
        let (dt, g, alpha) = (p.dt, p.gravity, p.damping);
        let (solid, liquid) = (&self.state.solid, &self.state.liquid);
        let (ss, ls) = (&self.solid_scratch, &self.liquid_scratch);
        let (sums, mask, vs_all, vl_all) = (&self.sums, &self.mask, &self.velocity_s, &self.velocity_l);
        let (contact, solid_fraction, mu) = (&self.fixities.contact, &self.solid_fraction, p.wall_friction);
        let tol = self.mass_tolerance;
        let xpic = self.xpic_active();
        let implicit = p.implicit_pressure;
        let [w_s, w_l] = &self.xpic_points;
        let mut accel = std::mem::take(&mut self.accel);
        self.for_active_nodes(&mut accel, |node, out| {
            let mut fs = [0.0; 2];
            let mut fl = [0.0; 2];
            let mut from_liquid = [0.0; 2];
            let mut q = 0.0;
            let mut back = [[0.0; 2]; 2];
            Self::gather(ss, row, node, |pt, n, gr| {
                let f = &ss.force[pt];
                let m = solid.set.mass[pt];
                let load = solid.load[pt];
                fs[0] += n * (m * g[0] + load[0]) - (f[0] * gr[0] + f[2] * gr[1]);
                fs[1] += n * (m * g[1] + load[1]) - (f[2] * gr[0] + f[1] * gr[1]);
                q += n * f[3];
                if xpic {
                    back[0][0] += n * m * w_s[pt][0];
                    back[0][1] += n * m * w_s[pt][1];
                }
            });
            Self::gather(ls, row, node, |pt, n, gr| {
                let f = &ls.force[pt];
                let m = liquid.set.mass[pt];
                if xpic {
                    back[1][0] += n * m * w_l[pt][0];
                    back[1][1] += n * m * w_l[pt][1];
                }
                let porosity = f[3];
                let div = [f[0] * gr[0] + f[2] * gr[1], f[2] * gr[0] + f[1] * gr[1]];
                fl[0] += n * m * g[0] - porosity * div[0] - n * f[4];
                fl[1] += n * m * g[1] - porosity * div[1] - n * f[5];
                let share = [-(1.0 - porosity) * div[0] + n * f[4], -(1.0 - porosity) * div[1] + n * f[5]];
                // Added to the solid's force point by point, as before the
                // diagnostic sum existed: the force's rounding is unchanged.
                fs[0] += share[0];
                fs[1] += share[1];
                from_liquid[0] += share[0];
                from_liquid[1] += share[1];
            });
            let s = &sums[node];
            let (vs, vl) = (vs_all[node], vl_all[node]);
            let mut a = [[0.0; 2]; 2];
            let into = contact[node];
            let normal_axis = wall_normal_axis(into);
            // Momentum per unit time the wall takes from each phase along its normal.
            let mut reaction = [0.0; 2];
            for d in 0..2 {
                let m = mask[node][d];
                if m == 0.0 {
                    // Implicit: the wall's reaction needs the pressure (`correct_velocities`).
                    if !implicit && normal_axis == Some(d) && mu > 0.0 {
                        reaction = Self::wall_reaction(s, d, [fs[d], fl[d]], q, into[d], dt, tol);
                    }
                    // A fixed component ends the step at rest: its "acceleration"
                    // takes the mapped velocity to zero, so that the FLIP update
                    // carries the constraint to the points. With a = 0 the points
                    // on a wall kept their velocity, drifted while the wall held
                    // their positions, and fed it back through the next map: the
                    // deposit never came to rest.
                    if s.mass_s > tol {
                        a[0][d] = -s.momentum_s[d] / s.mass_s / dt;
                    }
                    if s.mass_l > tol {
                        a[1][d] = -s.momentum_l[d] / s.mass_l / dt;
                    }
                    continue;
                }
                if implicit {
                    // The predictor: no damping, which needs the total force.
                    [a[0][d], a[1][d]] = Self::coupled_accelerations(s, [fs[d], fl[d]], [vs[d], vl[d]], q, dt, tol);
                    continue;
                }
                let damp = |f: f64, v: f64| if v != 0.0 { f - alpha * f.abs() * v.signum() } else { f };
                let force = [damp(fs[d], vs[d]), damp(fl[d], vl[d])];
                [a[0][d], a[1][d]] = Self::coupled_accelerations(s, force, [vs[d], vl[d]], q, dt, tol);
            }
            // The grains' share of the wall's normal reaction: the solid's
            // less the pore pressure's share (1 − n)/n of the liquid's.
            let mut wall_load = 0.0;
            if normal_axis.is_some() {
                wall_load = Self::grains_wall_load(s, solid_fraction[node], reaction, tol);
            }
            for (phase, mass) in [(0, s.mass_s), (1, s.mass_l)] {
                back[phase] = if mass > tol { [back[phase][0] / mass, back[phase][1] / mass] } else { [0.0; 2] };
            }
            *out = NodeUpdate { a, filtered: back, wall_load, force: [fs, fl], drag: q, liquid_on_solid: from_liquid };
        });
        self.accel = accel;
    }

    /// The grains' share of a wall's normal reaction `reaction` on
    /// [solid, liquid] (`wall_reaction`) at a node whose nodal solid
    /// fraction is `solid_share`: the solid's less the pore pressure's share
    /// (1 − n)/n of the liquid's, N; 0 without solid.
    #[inline(always)]
    fn grains_wall_load(s: &NodeSums, solid_share: f64, reaction: [f64; 2], tol: f64) -> f64 {
        if s.mass_s > tol {
            let pore =
                if s.mass_l > tol && solid_share < 1.0 { solid_share / (1.0 - solid_share) * reaction[1] } else { 0.0 };
            (reaction[0] - pore).max(0.0)
        } else {
            0.0
        }
    }

    /// Unilateral walls (`Params::unilateral_walls`), after the map: a
    /// held wall component whose mixture would move off the wall within
    /// the step, its mapped momentum plus Δt times the force it felt in
    /// the last step (`MpmState::wall_push`) pointing off the wall faster
    /// than `Params::wall_release_speed` (default 0) per unit mass, is
    /// released for this step (its nodal velocities unmasked), so that
    /// material thrown off a wall leaves with its momentum; the test after
    /// the solve (`update_wall_contacts`) holds it again if it turns back
    /// into the wall. Skipped where liquid may hold tension
    /// (`Params::cavitation` > 0): the test after the solve sees its pull.
    /// The force is what keeps a layer resting on a wall held: its mapped
    /// velocity off the wall carries its step-to-step noise, of order
    /// g Δt, and a release on that alone opens the wall in the implicit
    /// pressure's solve (a layer sliding on the floor kept 0.86 of its
    /// hydrostatic pore pressure with the velocity alone tested against
    /// g Δt/20, 0.96 with the force; session 44, docs/mpm.md "The release
    /// speed"). With no tolerance, a component the force barely presses
    /// (a side wall at a free surface, a sheet's tip) may flip on
    /// round-off; the solve's test corrects it within the step. Counts
    /// into `Mpm::wall_release_stats`.
    fn release_walls_moved_off(&mut self) {
        let tol = self.mass_tolerance;
        let (bar, dt) = (self.params.wall_release_speed.unwrap_or(0.0), self.params.dt);
        let gated = |node: usize, d: usize, gates: &[Vec<usize>], held: &[bool]| {
            d == 0 && gates.iter().zip(held).any(|(g, &h)| h && g.contains(&node))
        };
        let touched = self.touched_range();
        let stats = &mut self.wall_release_stats;
        let state = &mut self.state;
        for ((w, released), push) in
            self.fixities.walls.iter().zip(state.walls_released.iter_mut()).zip(&state.wall_push)
        {
            let (node, d) = (w.node, w.axis);
            if *released || !touched(node) {
                continue;
            }
            let s = &self.sums[node];
            if s.mass_l > tol && self.params.cavitation > 0.0 {
                // Liquid that holds tension may stick to the wall: the
                // test after the solve, which sees its pull, decides.
                continue;
            }
            let mass = s.mass_s + s.mass_l;
            if mass <= tol {
                // Nothing there to let go (`update_wall_contacts` holds it).
                continue;
            }
            let speed_off = -(s.momentum_s[d] + s.momentum_l[d]) * w.into - dt * push;
            if speed_off <= bar * mass {
                stats.largest_speed_kept = stats.largest_speed_kept.max(speed_off / mass);
                continue;
            }
            if gated(node, d, &self.fixities.gates, &state.gates_held) {
                continue;
            }
            *released = true;
            stats.released_at_map += 1;
            self.mask[node][d] = 1.0;
            let vs = if s.mass_s > tol { s.momentum_s[d] / s.mass_s } else { 0.0 };
            let vl = if s.mass_l > tol { s.momentum_l[d] / s.mass_l } else { 0.0 };
            self.velocity_s[node][d] = vs;
            self.velocity_l[node][d] = vl;
            if s.mass_s > tol && s.mass_l > tol {
                self.relative[node][d] = vl - vs;
            }
        }
    }

    /// Unilateral walls (`Params::unilateral_walls`, Bardenhagen et al.
    /// 2001's release criterion against a rigid wall), once the step's
    /// velocities are solved (step 5; after the corrector under the
    /// implicit pressure). A held wall component whose mixture would move
    /// off the wall (its mapped momentum plus Δt times the undamped force,
    /// the pore pressure's included, points away) is released from the
    /// next step on, unless its liquid pulls on the wall with less than
    /// the tension it holds (`Params::cavitation` over h): water sticks
    /// to a wall until it cavitates there. The release lags one step
    /// because the implicit pressure is solved with the step's mask. A
    /// released component whose liquid pulls so, or whose mixture moves
    /// into the wall, is held now (both phases' normal velocities stopped)
    /// and from the next step on; one whose mixture moves off it but one
    /// phase into it has that phase's normal velocity stopped. The force
    /// a stop replaces (the phase's mass times its solved acceleration
    /// into the wall; not the mapped velocity's impulse, as in
    /// `wall_reaction`) is the wall's normal reaction, whose grains' share
    /// loads the wall's friction (`apply_wall_friction`). A component
    /// without mass, or outside the range the map touched (whose node
    /// scratch is stale), is held.
    /// Post: no end velocity of a phase at a wall component points into
    /// the wall.
    fn update_wall_contacts(&mut self) {
        let (dt, tol, gravity) = (self.params.dt, self.mass_tolerance, self.params.gravity);
        let pressure = self.implicit.as_ref().map(|i| &i.pressure_force);
        // What the liquid can pull on a node's share h of the wall before
        // it cavitates there (a corner's share is h/2: it holds on longer).
        let tension_cap = self.params.cavitation * self.grid.h;
        let touched = self.touched_range();
        let state = &mut self.state;
        for ((w, released), push) in
            self.fixities.walls.iter().zip(state.walls_released.iter_mut()).zip(state.wall_push.iter_mut())
        {
            let (node, d, into) = (w.node, w.axis, w.into);
            let s = &self.sums[node];
            let masses = [if s.mass_s > tol { s.mass_s } else { 0.0 }, if s.mass_l > tol { s.mass_l } else { 0.0 }];
            if !touched(node) || masses == [0.0; 2] {
                *released = false;
                *push = 0.0;
                continue;
            }
            let u = &mut self.accel[node];
            let mut force = u.force[0][d] + u.force[1][d];
            // The liquid's stress on the mixture there (on the solid, its
            // share, and on itself), less its weight.
            let mut liquid = u.liquid_on_solid[d] + u.force[1][d] - masses[1] * gravity[d];
            if let Some([fps, fpl]) = pressure {
                force += fps[node][d] + fpl[node][d];
                liquid += fps[node][d] + fpl[node][d];
            }
            *push = force * into;
            let tension = if masses[1] > 0.0 { -liquid * into } else { 0.0 };
            let adheres = tension > 0.0 && tension < tension_cap;
            if self.mask[node][d] == 0.0 {
                *released = (s.momentum_s[d] + s.momentum_l[d] + dt * force) * into < 0.0 && !adheres;
                continue;
            }
            let v0 = [self.velocity_s[node][d], self.velocity_l[node][d]];
            let end = [v0[0] + dt * u.a[0][d], v0[1] + dt * u.a[1][d]];
            let into_wall = adheres || (masses[0] * end[0] + masses[1] * end[1]) * into > 0.0;
            let mut reaction = [0.0; 2];
            for phase in 0..2 {
                if masses[phase] > 0.0 && (into_wall || end[phase] * into > 0.0) {
                    // The force that holds it, as `wall_reaction` counts it:
                    // not the mapped velocity's impulse.
                    reaction[phase] = masses[phase] * (u.a[phase][d] * into).max(0.0);
                    u.a[phase][d] = -v0[phase] / dt;
                }
            }
            if into_wall {
                self.mask[node][d] = 0.0;
                *released = false;
            }
            if reaction != [0.0; 2] {
                u.wall_load = Self::grains_wall_load(s, self.solid_fraction[node], reaction, tol);
            }
        }
    }

    /// Coulomb friction of the walls on the solid (`Fixities::contact`,
    /// μ = `Params::wall_friction`): at each wall node whose tangential
    /// component is free, the end-of-step tangential velocity of the solid
    /// is reduced by at most μ Δt N / m, N the grains' normal load there
    /// (`NodeUpdate::wall_load`), and stopped if that is enough (stick):
    /// the grid form of Bardenhagen et al. (2001)'s contact against a
    /// rigid wall. The points next to the wall take the grid's velocity
    /// along the held normal (`update_velocities`), so the load is not
    /// counted again from momentum the wall already stopped.
    ///
    /// Under `Params::friction_reaches_next_node`, what a node's own solid
    /// mass cannot take of its impulse μ Δt N
    /// before it sticks passes to the next node off the wall (a ghost
    /// node's to the wall node in front of it, a wall node's to the first
    /// node inside), which takes it up to its own stick. GIMP's stencil
    /// reaches a wall node from points up to h + l away, so material
    /// landing on a wall presses on it through the stress of points that
    /// map mostly to the node inside while the wall node holds a sliver of
    /// their mass: there the impulse a node could take was its own
    /// momentum, and a block landing while sliding on a μ = 0.1 floor got
    /// 0.24 of the friction impulse Coulomb's law asks for (μ times the
    /// normal impulse; 0.97 with the impulse passed on, the test in
    /// `tests/wall_friction.rs`). The node inside (mass m_i) takes at most
    /// what stops the fraction 1 − m_w/(r m_i) of its mass, the fraction by
    /// which the wall node (m_w) falls short of holding its support's
    /// share r (½) of a node under the same material: all of it under a
    /// sliver, none under a layer resting or flowing on the wall. No node takes
    /// more than stops it, so the friction stays within μ N summed over
    /// each wall node's line. Not the default: a μ = 10 floor then holds
    /// the dry lab column 27 % shorter than the rough floor, a gap that
    /// does not close with h (docs/mpm.md, "Limit: impacts carry too little
    /// friction").
    /// Post: every contact node's and every receiving node's tangential
    /// solid velocity keeps its sign or is zero; `friction_carry` is zero.
    fn apply_wall_friction(&mut self) {
        let mu = self.params.wall_friction;
        if mu == 0.0 {
            self.wall_forces = WallForces::default();
            return;
        }
        let dt = self.params.dt;
        let tol = self.mass_tolerance;
        let reach = self.params.friction_reaches_next_node;
        let mut totals = WallForces::default();
        self.interior_friction_carry.clear();
        for c in &self.contact_nodes {
            let carried = std::mem::take(&mut self.friction_carry[c.node]);
            let s = &self.sums[c.node];
            if self.mask[c.node][c.tangent] == 0.0 || s.mass_s <= tol {
                continue;
            }
            let load = self.accel[c.node].wall_load;
            let impulse = mu * dt * load + carried;
            let a = &mut self.accel[c.node].a[0][c.tangent];
            let (taken, left) = Self::friction_stop(a, self.velocity_s[c.node][c.tangent], s.mass_s, impulse, dt);
            totals.normal_load += load;
            totals.friction += taken / dt;
            if reach && left > 0.0 {
                if c.inward_is_contact {
                    self.friction_carry[c.inward] += left;
                } else if c.support_ratio > 0.0 {
                    let wall_share = s.mass_s / c.support_ratio;
                    self.interior_friction_carry.push((c.inward, c.tangent, left, wall_share));
                }
            }
        }
        for &(node, t, impulse, wall_share) in &self.interior_friction_carry {
            let s = &self.sums[node];
            if self.mask[node][t] == 0.0 || s.mass_s <= wall_share + tol {
                continue;
            }
            // The node inside takes only what stops the fraction of its mass
            // by which the wall node falls short of its support's share of a
            // node under the same material: under a layer resting or flowing
            // on the wall none, and the wall's friction stays on the wall.
            let short = 1.0 - wall_share / s.mass_s;
            let trial = self.velocity_s[node][t] + dt * self.accel[node].a[0][t];
            let impulse = impulse.min(short * s.mass_s * trial.abs());
            let (taken, _) =
                Self::friction_stop(&mut self.accel[node].a[0][t], self.velocity_s[node][t], s.mass_s, impulse, dt);
            totals.friction += taken / dt;
        }
        self.wall_forces = totals;
    }

    /// The laminar film's wall shear on the liquid (`Params::liquid_film_shear`;
    /// Nusselt's film, e.g. Bird, Stewart & Lightfoot, *Transport
    /// Phenomena*, §2.2): a film of depth d flowing at the depth-averaged
    /// velocity Ū over a no-slip wall has the parabolic profile and the
    /// wall shear τ = 3 μ Ū / d, so dŪ/dt = −3 ν Ū / d² without other
    /// forces. The grid resolves the liquid's viscous stress only across
    /// elements, so a film thinner than one needs it as a wall law.
    ///
    /// Per wall component held along its normal whose tangent is free, the
    /// line of nodes off the wall (the ghost nodes behind it, the wall
    /// node, then inward while the nodes carry liquid; a wall node without
    /// liquid has no film on it) reads a film depth d
    /// (`walk_film_lines`): under [`FilmDepth::Covered`] the water volume
    /// of the liquid points over the part of the line's strip they cover
    /// (`measure_film_depths`; a film's ends at their own depth), under
    /// [`FilmDepth::LineMass`] the line's nodal liquid mass over ρ_L h
    /// (session 45's reading: a line covered only in part, by a share c,
    /// reads c d and is slowed 1/c² too fast, and the line past a film's
    /// end, holding a sliver, is all but stopped; docs/mpm.md, "The
    /// film's ends"). Every node on the line has its tangential liquid
    /// velocity scaled by 1 / (1 + Δt · 3 ν / d²), backward Euler, so no
    /// step reverses it. Where the liquid fills the line up to a held
    /// wall opposite, a gap W away, both walls' lines cover it: each
    /// applies half of a channel's rate 12 ν / W² (plane Poiseuille flow,
    /// a film of depth W/2 on each wall), d = W the gap itself.
    ///
    /// Limit: the law acts only where the wall holds the normal in the
    /// step; a unilateral wall that lets go (nothing presses the liquid
    /// on it) leaves the liquid there free to slip for that step.
    ///
    /// Precondition: the nodes' accelerations from `solve_nodes`, before
    /// the implicit pore pressure's projection (which then sees the wall's
    /// shear as it sees the other forces) and the walls' friction on the
    /// solid. Postcondition: a uniform film's Ū decays as
    /// (1 + Δt · 3 ν / d²)^(−t/Δt) → e^(−3νt/d²). Where the line crosses
    /// soil, d is the water's equivalent depth n D and the drag exceeds
    /// this by orders of magnitude; where a deep flow runs along a wall,
    /// 3 ν / d² is small.
    fn apply_liquid_wall_shear(&mut self) {
        let Some(reading) = self.params.liquid_film_shear else { return };
        if self.state.liquid.set.is_empty() {
            return;
        }
        let (dt, h, tol) = (self.params.dt, self.grid.h, self.mass_tolerance);
        let nu = self.params.viscosity / self.params.liquid_density;
        let mut lines = std::mem::take(&mut self.film_lines);
        self.walk_film_lines(&mut lines);
        match reading {
            FilmDepth::Covered => self.measure_film_depths(&mut lines),
            FilmDepth::LineMass => {
                let rho_h = self.params.liquid_density * h;
                lines.iter_mut().for_each(|f| f.depth = f.mass / rho_h);
            }
        }
        for f in &lines {
            let (line, tangent) = (f.line, 1 - f.axis);
            let reaches_a_wall =
                (f.last - line.opposite) * line.inward >= 0 && self.mask[line.node_at(line.opposite)][f.axis] == 0.0;
            let rate = if reaches_a_wall {
                let gap = (line.opposite - line.position).abs() as f64 * h;
                6.0 * nu / (gap * gap)
            } else {
                let depth = f.depth;
                3.0 * nu / (depth * depth)
            };
            let decay = 1.0 / (1.0 + dt * rate);
            for (_, node) in line.nodes(&self.sums, self.touched_range(), tol) {
                if self.mask[node][tangent] == 0.0 {
                    continue;
                }
                let v = self.velocity_l[node][tangent];
                let a = &mut self.accel[node].a[1][tangent];
                *a = ((v + dt * *a) * decay - v) / dt;
            }
        }
        self.film_lines = lines;
    }

    /// The slip walls' lines of nodes that carry liquid in this step
    /// (`lines`, cleared first), each with its liquid mass and last node,
    /// and `film_lookup` pointing at them by wall side and tangent node.
    fn walk_film_lines(&mut self, lines: &mut Vec<FilmLine>) {
        lines.clear();
        self.film_lookup.fill(u32::MAX);
        let stride = self.film_lookup.len() / 4;
        let (h, origin, row) = (self.grid.h, self.grid.origin, self.grid.node_dims()[0]);
        let far = self.grid.far_corner();
        for w in &self.fixities.walls {
            let Some(line) = self.wall_line(w) else { continue };
            let tangent = 1 - w.axis;
            if self.mask[w.node][w.axis] != 0.0 || self.mask[w.node][tangent] == 0.0 {
                continue;
            }
            let (mut mass, mut last) = (0.0, line.first);
            for (q, node) in line.nodes(&self.sums, self.touched_range(), self.mass_tolerance) {
                mass += self.sums[node].mass_l;
                last = q;
            }
            if mass <= self.mass_tolerance {
                continue;
            }
            let along = if w.axis == 0 { w.node / row } else { w.node % row };
            let at = self.grid.node_position(w.node % row, w.node / row);
            let slot = Self::film_slot(w.axis, line.inward) * stride + along;
            // Only the box's walls are wall components (a gate's nodes are
            // held apart, ghosts have no line): one line per slot.
            debug_assert_eq!(self.film_lookup[slot], u32::MAX, "two lines at one wall node");
            self.film_lookup[slot] = lines.len() as u32;
            lines.push(FilmLine {
                line,
                axis: w.axis,
                along,
                last,
                mass,
                wall: at[w.axis],
                reach: ((last - line.position) * line.inward) as f64 * h + 0.5 * h,
                strip: [(at[tangent] - 0.5 * h).max(origin[tangent]), (at[tangent] + 0.5 * h).min(far[tangent])],
                covered: [f64::INFINITY, f64::NEG_INFINITY],
                volume: 0.0,
                depth: 0.0,
            });
        }
    }

    /// The wall side's slot in `film_lookup`: x_min, x_max, z_min, z_max.
    fn film_slot(axis: usize, inward: isize) -> usize {
        2 * axis + usize::from(inward < 0)
    }

    /// Each line's film `depth`: the water volume of the liquid points
    /// within its strip (each point's m/ρ_L times the share of its domain
    /// inside the strip) over the length c of the strip their domains
    /// cover, d = V / c: the mean depth of the film where it is, whether
    /// it covers the strip wholly (then V / h, which for a film is the
    /// line's nodal mass over ρ_L h) or in part (a film's end). A line
    /// whose strip no point's domain enters (the node past a film's end,
    /// which holds only what the end's points' shape functions map onto
    /// it) takes the deeper of its neighbours' depths along the wall, or
    /// M / (ρ_L h) if neither has points. Counted are the points off the
    /// wall no farther than half an element past the last node the line's
    /// walk reached (a drop above an empty node is not the film).
    /// Postcondition: a film of depth d gives every line d, wherever its
    /// ends lie in the strips (`covered` treats the points over a strip
    /// as one run along the wall).
    ///
    /// The points are read in fixed chunks of [`FILM_CHUNK`] on the
    /// threads at hand, each chunk's sums kept apart and merged in chunk
    /// order: the depths do not depend on the thread count.
    fn measure_film_depths(&mut self, lines: &mut [FilmLine]) {
        const GHOST: isize = crate::grid::GHOST as isize;
        if lines.is_empty() {
            return;
        }
        let (h, origin, dims) = (self.grid.h, self.grid.origin, self.grid.node_dims());
        let lookup = &self.film_lookup;
        let stride = lookup.len() / 4;
        let set = &self.state.liquid.set;
        let rho = self.params.liquid_density;
        let mut sides = [false; 4];
        for f in lines.iter() {
            sides[Self::film_slot(f.axis, f.line.inward)] = true;
        }
        let inv_h = 1.0 / h;
        // Per side: (axis, tangent, the points' half-width along the wall,
        // the water volume per kg and metre of domain inside a strip).
        let side = [0, 1, 2, 3].map(|slot: usize| {
            let (axis, tangent) = (slot / 2, 1 - slot / 2);
            let half = set.half[tangent];
            (axis, tangent, half, 1.0 / (rho * 2.0 * half))
        });
        let count = lines.len();
        let chunks = set.x.len().div_ceil(FILM_CHUNK);
        let partial = &mut self.film_partial;
        partial.clear();
        partial.resize(chunks * count, FilmSum::EMPTY);
        let lines_read: &[FilmLine] = lines;
        partial.par_chunks_mut(count).zip(set.x.par_chunks(FILM_CHUNK).zip(set.mass.par_chunks(FILM_CHUNK))).for_each(
            |(sums, (xs, masses))| {
                for (x, &m) in xs.iter().zip(masses) {
                    for slot in (0..4).filter(|&k| sides[k]) {
                        let (axis, tangent, half, per_kg_m) = side[slot];
                        let domain = [x[tangent] - half, x[tangent] + half];
                        // A domain is at most an element wide: it spans the
                        // strip of its centre's nearest node and at most one
                        // beside it.
                        let at = (x[tangent] - origin[tangent]) * inv_h;
                        let nearest = (at + 0.5).floor();
                        let (reach_back, reach_on) =
                            (at - half * inv_h < nearest - 0.5, at + half * inv_h > nearest + 0.5);
                        let nearest = nearest as isize + GHOST;
                        for along in nearest - isize::from(reach_back)..=nearest + isize::from(reach_on) {
                            if !(0..dims[tangent] as isize).contains(&along) {
                                continue;
                            }
                            let k = lookup[slot * stride + along as usize];
                            if k == u32::MAX {
                                continue;
                            }
                            let f = &lines_read[k as usize];
                            let inside = [domain[0].max(f.strip[0]), domain[1].min(f.strip[1])];
                            if inside[1] <= inside[0] || (x[axis] - f.wall) * f.line.inward as f64 > f.reach {
                                continue;
                            }
                            let sum = &mut sums[k as usize];
                            sum.volume += m * per_kg_m * (inside[1] - inside[0]);
                            sum.covered = [sum.covered[0].min(inside[0]), sum.covered[1].max(inside[1])];
                        }
                    }
                }
            },
        );
        for sums in partial.chunks(count) {
            for (f, sum) in lines.iter_mut().zip(sums) {
                f.volume += sum.volume;
                f.covered = [f.covered[0].min(sum.covered[0]), f.covered[1].max(sum.covered[1])];
            }
        }
        for f in lines.iter_mut() {
            let covered = f.covered_length();
            f.depth = if covered > 0.0 { f.volume / covered } else { 0.0 };
        }
        for k in 0..lines.len() {
            let f = lines[k];
            if f.covered_length() > 0.0 {
                continue;
            }
            let slot = Self::film_slot(f.axis, f.line.inward);
            let mut deeper = 0.0f64;
            for beside in [f.along.wrapping_sub(1), f.along + 1] {
                if beside >= dims[1 - f.axis] {
                    continue;
                }
                let b = self.film_lookup[slot * stride + beside];
                if b != u32::MAX && lines[b as usize].covered_length() > 0.0 {
                    deeper = deeper.max(lines[b as usize].depth);
                }
            }
            lines[k].depth = if deeper > 0.0 { deeper } else { f.mass / (rho * h) };
        }
    }

    /// The line of nodes along the normal of the in-box wall component
    /// `w` (None for a ghost node's component).
    fn wall_line(&self, w: &WallComponent) -> Option<WallLine> {
        const GHOST: usize = crate::grid::GHOST;
        let [row, rows] = self.grid.node_dims();
        let elements = self.grid.elements;
        let (column, line) = (w.node % row, w.node / row);
        let in_box = |c: usize, n: usize| (GHOST..=GHOST + n).contains(&c);
        if !in_box(column, elements[0]) || !in_box(line, elements[1]) {
            return None;
        }
        let (stride, count) = if w.axis == 0 { (1, row) } else { (row, rows) };
        let position = if w.axis == 0 { column } else { line } as isize;
        let inward = -w.into as isize;
        Some(WallLine {
            wall_node: w.node,
            position,
            stride: stride as isize,
            count: count as isize,
            inward,
            first: position - inward * GHOST as isize,
            opposite: if inward > 0 { (GHOST + elements[w.axis]) as isize } else { GHOST as isize },
        })
    }

    /// Applies a friction impulse (N s/m) against the solid's tangential
    /// end velocity at a node of solid mass `mass` whose start velocity is
    /// `v` and acceleration `a`: the velocity is reduced by at most
    /// impulse / mass and not past zero. Returns the impulse taken and the
    /// impulse left over (what stopping did not need).
    #[inline(always)]
    fn friction_stop(a: &mut f64, v: f64, mass: f64, impulse: f64, dt: f64) -> (f64, f64) {
        let trial = v + dt * *a;
        let slip = trial.abs() - impulse / mass;
        let end = if slip > 0.0 { slip.copysign(trial) } else { 0.0 };
        *a = (end - v) / dt;
        (mass * (trial - end).abs(), (-slip * mass).max(0.0))
    }

    /// The normal reaction of a wall on [solid, liquid] at a node, N: the
    /// force along the wall normal `into` (±1, the direction into the
    /// wall) that holds each phase there, its free acceleration (undamped
    /// forces `f`, the phases coupled by the same implicit drag `q` as at
    /// a free node) times its mass; zero for a phase pulled away. The
    /// mapped velocity into the wall is not counted as an impulse: at a
    /// held node it is the interpolation of the layer moving above, not an
    /// impact (counting it loaded the floor under the dry lab column with
    /// 2.1–2.7 times its weight while it spread, against 1.0–1.26 from the
    /// forces).
    fn wall_reaction(s: &NodeSums, d: usize, f: [f64; 2], q: f64, into: f64, dt: f64, tol: f64) -> [f64; 2] {
        let mapped = [
            if s.mass_s > tol { s.momentum_s[d] / s.mass_s } else { 0.0 },
            if s.mass_l > tol { s.momentum_l[d] / s.mass_l } else { 0.0 },
        ];
        let a = Self::coupled_accelerations(s, f, mapped, q, dt, tol);
        [(a[0] * into).max(0.0) * s.mass_s, (a[1] * into).max(0.0) * s.mass_l]
    }

    /// Accelerations of [solid, liquid] along one component at a node from
    /// the forces `f` and start velocities `v`, the drag `q` implicit in the
    /// relative velocity (backward Euler, docs/mpm.md step 5); a phase
    /// without mass gets 0.
    #[inline(always)]
    fn coupled_accelerations(s: &NodeSums, f: [f64; 2], v: [f64; 2], q: f64, dt: f64, tol: f64) -> [f64; 2] {
        let (has_s, has_l) = (s.mass_s > tol, s.mass_l > tol);
        if has_s && has_l && q > 0.0 {
            let w1 = (v[1] - v[0] + dt * (f[1] / s.mass_l - f[0] / s.mass_s))
                / (1.0 + dt * q * (1.0 / s.mass_l + 1.0 / s.mass_s));
            [(f[0] + q * w1) / s.mass_s, (f[1] - q * w1) / s.mass_l]
        } else {
            [if has_s { f[0] / s.mass_s } else { 0.0 }, if has_l { f[1] / s.mass_l } else { 0.0 }]
        }
    }

    /// Whether the point update filters with XPIC(2).
    fn xpic_active(&self) -> bool {
        !self.params.apic && self.params.xpic_order >= 2 && self.params.pic_fraction > 0.0
    }

    // -- stage 4 ---------------------------------------------------------

    /// FLIP with a PIC share α: v_p ← (1 − α)(v_p + Δt Σ N_I a_I) + α Σ N_I v_I^new,
    /// v_I^new the end-of-step nodal velocity (zero on fixed components);
    /// with `xpic_order` 2, v_p ← v_p + Δt Σ N_I a_I − α Q² v_p instead,
    /// Q = I − S⁺S the part of the point velocities the grid cannot carry
    /// (PIC is v_FLIP − Q v_p). A point whose stencil touches a node held
    /// in a direction takes the grid's velocity in it (PIC): under FLIP it
    /// kept the part of its velocity the wall had stopped, mapped it back
    /// each step, and the wall stopped it again (a sliding block
    /// decelerated at 5 μg from these phantom normal impulses; docs/mpm.md,
    /// "Frictional walls"). Under `wall_tangent_update = "grid"` it does so
    /// in both directions next to a frictional wall.
    fn update_velocities(&mut self) {
        if self.params.apic {
            self.update_velocities_apic();
            return;
        }
        if self.xpic_active() {
            self.update_velocities_xpic2();
            return;
        }
        let row = self.grid.node_dims()[0];
        let dt = self.params.dt;
        let alpha = self.params.pic_fraction;
        let grid_tangent = self.params.wall_points_take_grid_tangent;
        let (accel, mask, contact) = (&self.accel, &self.mask, &self.fixities.contact);
        let (vs, vl) = (&self.velocity_s, &self.velocity_l);
        let g2p = |set: &mut PointSet, scratch: &PointScratch, phase: usize| {
            let velocity = if phase == 0 { vs } else { vl };
            set.v.par_iter_mut().zip(scratch.stencil.par_iter()).with_min_len(CHUNK).for_each(|(v, st)| {
                let mut a = [0.0; 2];
                let mut pic = [0.0; 2];
                let mut held = [false; 2];
                st.for_each(row, |node, n, _| {
                    let (acc, k, v0) = (accel[node].a[phase], mask[node], velocity[node]);
                    a[0] += n * acc[0];
                    a[1] += n * acc[1];
                    pic[0] += n * k[0] * (v0[0] + dt * acc[0]);
                    pic[1] += n * k[1] * (v0[1] + dt * acc[1]);
                    let touches_wall = grid_tangent && n > 0.0 && contact[node] != [0.0; 2];
                    held[0] |= n > 0.0 && k[0] == 0.0 || touches_wall;
                    held[1] |= n > 0.0 && k[1] == 0.0 || touches_wall;
                });
                for d in 0..2 {
                    v[d] = if held[d] { pic[d] } else { (1.0 - alpha) * (v[d] + dt * a[d]) + alpha * pic[d] };
                }
            });
        };
        let (solid, liquid) = (&mut self.state.solid.set, &mut self.state.liquid.set);
        let (ss, ls) = (&self.solid_scratch, &self.liquid_scratch);
        rayon::join(|| g2p(solid, ss, 0), || g2p(liquid, ls, 1));
    }

    /// XPIC(2): w1 = S⁺v_g (v_g the mapped nodal velocity, fixities applied;
    /// at the points in `prepare_forces`), S w1 at the nodes (in
    /// `solve_nodes`), w2 = S⁺S w1, Q² v = v − 2 w1 + w2, and
    /// v ← v_FLIP − α Q² v. Both maps ride on loops the step runs anyway.
    fn update_velocities_xpic2(&mut self) {
        let row = self.grid.node_dims()[0];
        let dt = self.params.dt;
        let alpha = self.params.pic_fraction;
        let grid_tangent = self.params.wall_points_take_grid_tangent;
        let (accel, mask, contact) = (&self.accel, &self.mask, &self.fixities.contact);
        let (vs, vl) = (&self.velocity_s, &self.velocity_l);
        let w = &self.xpic_points;
        let g2p = |set: &mut PointSet, scratch: &PointScratch, phase: usize| {
            let velocity = if phase == 0 { vs } else { vl };
            set.v.par_iter_mut().zip(scratch.stencil.par_iter()).enumerate().with_min_len(CHUNK).for_each(
                |(p, (v, st))| {
                    let mut a = [0.0; 2];
                    let mut w2 = [0.0; 2];
                    let mut pic = [0.0; 2];
                    let mut held = [false; 2];
                    st.for_each(row, |node, n, _| {
                        let u = &accel[node];
                        a[0] += n * u.a[phase][0];
                        a[1] += n * u.a[phase][1];
                        w2[0] += n * u.filtered[phase][0];
                        w2[1] += n * u.filtered[phase][1];
                        let (k, v0) = (mask[node], velocity[node]);
                        pic[0] += n * k[0] * (v0[0] + dt * u.a[phase][0]);
                        pic[1] += n * k[1] * (v0[1] + dt * u.a[phase][1]);
                        let touches_wall = grid_tangent && n > 0.0 && contact[node] != [0.0; 2];
                        held[0] |= n > 0.0 && k[0] == 0.0 || touches_wall;
                        held[1] |= n > 0.0 && k[1] == 0.0 || touches_wall;
                    });
                    let w1 = w[phase][p];
                    for d in 0..2 {
                        let null_part = v[d] - 2.0 * w1[d] + w2[d];
                        v[d] = if held[d] { pic[d] } else { v[d] + dt * a[d] - alpha * null_part };
                    }
                },
            );
        };
        let (solid, liquid) = (&mut self.state.solid.set, &mut self.state.liquid.set);
        let (ss, ls) = (&self.solid_scratch, &self.liquid_scratch);
        rayon::join(|| g2p(solid, ss, 0), || g2p(liquid, ls, 1));
    }

    /// APIC (Jiang et al. 2015, Eqs. 7–10): v_p ← Σ N_I v_I and
    /// C_p ← B_p D_p⁻¹ with B_p = Σ N_I v_I ⊗ (x_I − x_p) and
    /// D_p = Σ N_I (x_I − x_p) ⊗ (x_I − x_p), v_I the end-of-step nodal
    /// velocity with fixities applied (as PIC's). D_p is formed per point
    /// because GIMP's is not the constant of B-splines; GIMP's D_p is never
    /// singular (bilinear D_p is, on grid lines, and APIC with bilinear
    /// shapes blew up at cell crossings: `Mpm::new` refuses the pair).
    fn update_velocities_apic(&mut self) {
        let row = self.grid.node_dims()[0];
        let dt = self.params.dt;
        let grid_tangent = self.params.wall_points_take_grid_tangent;
        let (accel, mask, contact) = (&self.accel, &self.mask, &self.fixities.contact);
        let (vs, vl, grid) = (&self.velocity_s, &self.velocity_l, &self.grid);
        let mut nodes = std::mem::take(&mut self.grid_velocity);
        self.for_active_nodes(&mut nodes, |node, out| {
            let (a, m) = (accel[node].a, mask[node]);
            let v = |v0: [f64; 2], acc: [f64; 2]| [m[0] * (v0[0] + dt * acc[0]), m[1] * (v0[1] + dt * acc[1])];
            *out = GridVelocity {
                v: [v(vs[node], a[0]), v(vl[node], a[1])],
                a,
                x: grid.node_position(node % row, node / row),
                fixed: [m[0] == 0.0, m[1] == 0.0],
                wall: grid_tangent && contact[node] != [0.0; 2],
            };
        });
        self.grid_velocity = nodes;
        let (nodes, shares) = (&self.grid_velocity, self.params.flip_share);
        let g2p = |set: &mut PointSet, scratch: &PointScratch, phase: usize| {
            let beta = shares[phase];
            let blend = beta > 0.0;
            set.affine.resize(set.v.len(), [[0.0; 2]; 2]);
            set.v
                .par_iter_mut()
                .zip(set.affine.par_iter_mut())
                .zip(scratch.stencil.par_iter().zip(set.x.par_iter()))
                .with_min_len(CHUNK)
                .for_each(|((v, c), (st, xp))| {
                    let mut new_v = [0.0; 2];
                    let mut b = [[0.0; 2]; 2];
                    let mut d = [[0.0; 2]; 2];
                    let mut flip = *v;
                    let mut held = [false; 2];
                    st.for_each(row, |node, n, _| {
                        let g = &nodes[node];
                        let (vi, acc, xi) = (g.v[phase], g.a[phase], g.x);
                        let r = [xi[0] - xp[0], xi[1] - xp[1]];
                        for a in 0..2 {
                            new_v[a] += n * vi[a];
                            for e in 0..2 {
                                b[a][e] += n * vi[a] * r[e];
                                d[a][e] += n * r[a] * r[e];
                            }
                        }
                        if blend {
                            for a in 0..2 {
                                flip[a] += n * dt * acc[a];
                                held[a] |= n > 0.0 && (g.fixed[a] || g.wall);
                            }
                        }
                    });
                    for a in 0..2 {
                        v[a] = if !blend || held[a] { new_v[a] } else { (1.0 - beta) * new_v[a] + beta * flip[a] };
                    }
                    let det = d[0][0] * d[1][1] - d[0][1] * d[1][0];
                    let inv = [[d[1][1] / det, -d[0][1] / det], [-d[1][0] / det, d[0][0] / det]];
                    for a in 0..2 {
                        for e in 0..2 {
                            c[a][e] = b[a][0] * inv[0][e] + b[a][1] * inv[1][e];
                        }
                    }
                });
        };
        let (solid, liquid) = (&mut self.state.solid.set, &mut self.state.liquid.set);
        let (ss, ls) = (&self.solid_scratch, &self.liquid_scratch);
        rayon::join(|| g2p(solid, ss, 0), || g2p(liquid, ls, 1));
    }

    /// MUSL: the new point momenta mapped back give the nodal velocities the
    /// points move with; Δu = Δt v′.
    fn remap_momentum(&mut self) {
        let row = self.grid.node_dims()[0];
        let dt = self.params.dt;
        let tol = self.mass_tolerance;
        let (solid, liquid) = (&self.state.solid.set, &self.state.liquid.set);
        let (ss, ls) = (&self.solid_scratch, &self.liquid_scratch);
        let (sums, mask) = (&self.sums, &self.mask);
        let (grid, apic) = (&self.grid, self.params.apic);
        let mut disp = std::mem::take(&mut self.disp);
        self.for_active_nodes(&mut disp, |node, out| {
            let mut ps = [0.0; 2];
            let mut pl = [0.0; 2];
            let at = grid.node_position(node % row, node / row);
            Self::gather(ss, row, node, |p, n, _| {
                let m = n * solid.mass[p];
                let v = point_velocity_at(solid, p, at, apic);
                ps[0] += m * v[0];
                ps[1] += m * v[1];
            });
            Self::gather(ls, row, node, |p, n, _| {
                let m = n * liquid.mass[p];
                let v = point_velocity_at(liquid, p, at, apic);
                pl[0] += m * v[0];
                pl[1] += m * v[1];
            });
            let s = &sums[node];
            let k = mask[node];
            let mut d = [[0.0; 2]; 2];
            if s.mass_s > tol {
                d[0] = [dt * k[0] * ps[0] / s.mass_s, dt * k[1] * ps[1] / s.mass_s];
            }
            if s.mass_l > tol {
                d[1] = [dt * k[0] * pl[0] / s.mass_l, dt * k[1] * pl[1] / s.mass_l];
                if s.mass_s <= tol {
                    // No solid here: for the mixture balance the solid moves with the liquid.
                    d[0] = d[1];
                }
            }
            *out = d;
        });
        self.disp = disp;
    }

    /// Δε_w per element with liquid: the mixture continuity at the centroid.
    fn volumetric_strain_per_element(&mut self) {
        let grid = self.grid;
        let row = grid.node_dims()[0];
        let h = grid.h;
        let nx = grid.elements[0];
        let el = &mut self.elements;
        let (r0, r1) = self.rows;
        let (c0, c1) = self.columns;
        for r in r0.max(1)..r1.min(grid.elements[1] + 1) {
            for col in c0.max(1)..c1.min(nx + 1) {
                let e = (r - 1) * nx + (col - 1);
                if el.liquid_points[e] == 0 {
                    continue;
                }
                let n0 = r * row + col;
                let corners = [n0, n0 + 1, n0 + row, n0 + row + 1];
                let centroid = |u: &dyn Fn(usize) -> [f64; 2]| -> ([f64; 2], f64) {
                    let [a, b, d, f] = corners.map(u);
                    let mean = [0.25 * (a[0] + b[0] + d[0] + f[0]), 0.25 * (a[1] + b[1] + d[1] + f[1])];
                    let div = ((b[0] - a[0]) + (f[0] - d[0])) / (2.0 * h) + ((d[1] - a[1]) + (f[1] - b[1])) / (2.0 * h);
                    (mean, div)
                };
                let (us, es) = centroid(&|i| self.disp[i][0]);
                let (ul, elq) = centroid(&|i| self.disp[i][1]);
                let n = el.porosity[e];
                let gn = el.grad_porosity[e];
                el.volumetric_strain[e] =
                    ((1.0 - n) * es + n * elq + (ul[0] - us[0]) * gn[0] + (ul[1] - us[1]) * gn[1]) / n;
            }
        }
    }

    /// Both point sets at once (their updates share nothing but read-only grid data).
    fn update_points(&mut self) {
        let Self { grid, params, state, solid_scratch, liquid_scratch, elements, disp, liquid_fill, implicit, .. } =
            self;
        let solved = implicit.as_deref().map(|i| (&i.problem, i.pressure.as_slice()));
        rayon::join(
            || Self::update_solid_points(grid, params, &mut state.solid, &solid_scratch.stencil, disp),
            || {
                let l = &mut state.liquid;
                Self::update_liquid_points(grid, params, l, liquid_scratch, elements, disp, liquid_fill, solved)
            },
        );
    }

    /// Strain, porosity, state, Mohr–Coulomb stress and position of solid points.
    fn update_solid_points(grid: &Grid, p: &Params, s: &mut SolidPoints, st: &[Stencil], disp: &[[[f64; 2]; 2]]) {
        let row = grid.node_dims()[0];
        let (lo, hi) = (grid.origin, grid.far_corner());
        let (rho_s, n_max) = (p.solid_density, p.max_porosity);
        let (soil, critical_soil, n_cs) = (&p.soil, &p.critical_soil, p.dilatancy_cutoff_porosity);
        let (rate_friction, dt) = (p.inertial_friction, p.dt);
        s.set
            .x
            .par_iter_mut()
            .zip(s.set.volume.par_iter_mut())
            .zip(s.porosity.par_iter_mut())
            .zip(s.stress.par_iter_mut())
            .zip(s.fluidised.par_iter_mut())
            .zip(s.set.mass.par_iter())
            .zip(st.par_iter())
            .with_min_len(CHUNK)
            .for_each(|((((((x, vol), n), sigma), fl), &m), st)| {
                let de = st.strain(row, |i| disp[i][0]);
                let dv = de[0] + de[1];
                *n = (1.0 - (1.0 - *n) / (1.0 + dv)).clamp(POROSITY_BOUNDS.0, POROSITY_BOUNDS.1);
                *vol = m / ((1.0 - *n) * rho_s);
                *fl = *n > n_max;
                if *fl {
                    *sigma = [0.0; 4];
                } else {
                    let law = if *n < n_cs { soil } else { critical_soil };
                    match rate_friction {
                        None => law.update(sigma, de),
                        Some(r) => {
                            let sin_phi = r.sin_friction(r.inertial_number(sigma, de, dt));
                            law.with_friction_sine(sin_phi).update(sigma, de)
                        }
                    };
                }
                let du = st.interpolate(row, |i| disp[i][0]);
                x[0] = (x[0] + du[0]).clamp(lo[0], hi[0]);
                x[1] = (x[1] + du[1]).clamp(lo[1], hi[1]);
            });
    }

    /// Pore pressure, viscous stress, volume and position of liquid points.
    /// `solved`: under the implicit scheme, the step's pressure problem and
    /// element pressures; a point takes its element's (design §1 step 7),
    /// and is free where the element was not solved for, at its given
    /// pressure (0, or a saturated layer's).
    #[allow(clippy::too_many_arguments)]
    fn update_liquid_points(
        grid: &Grid,
        p: &Params,
        l: &mut LiquidPoints,
        scratch: &PointScratch,
        el: &ElementScratch,
        disp: &[[[f64; 2]; 2]],
        fill: &[f64],
        solved: Option<(&PressureProblem, &[f64])>,
    ) {
        let row = grid.node_dims()[0];
        let (lo, hi) = (grid.origin, grid.far_corner());
        let (k, rho_l, mu, dt, cav, fs_fill) =
            (p.bulk_modulus, p.liquid_density, p.viscosity, p.dt, p.cavitation, p.free_surface_fill);
        let element_area = grid.h * grid.h;
        l.set
            .x
            .par_iter_mut()
            .zip(l.set.volume.par_iter_mut())
            .zip(l.pressure.par_iter_mut())
            .zip(l.viscous.par_iter_mut())
            .zip(l.free_surface.par_iter_mut())
            .zip(l.set.mass.par_iter())
            .enumerate()
            .with_min_len(CHUNK)
            .for_each(|(i, (((((x, vol), pr), tau), free), &m))| {
                let st = &scratch.stencil[i];
                let e = scratch.element[i] as usize;
                // A part-empty element (drained pores, a flow's surface, a
                // thinning layer) is the free surface's: its strain closes
                // the empty part rather than compressing the water.
                if let Some((problem, pressure)) = solved {
                    *free = !problem.is_unknown(e);
                    *pr = if *free { problem.given_pressure(e) } else { pressure[e].max(-cav) };
                } else {
                    *free = fill[i] < fs_fill || el.filling_ratio(e, element_area) < fs_fill;
                    *pr = if *free { 0.0 } else { (*pr - k * el.volumetric_strain[e]).max(-cav) };
                }
                let de = st.strain(row, |i| disp[i][1]);
                let (solid_mass, fluidised_mass) = (el.solid_mass_solid[e], el.solid_mass_fluidised[e]);
                if solid_mass == 0.0 || fluidised_mass > solid_mass {
                    let c = if solid_mass + fluidised_mass > 0.0 { 1.0 - el.porosity[e] } else { 0.0 };
                    let mu_eq = mu * (1.0 + 2.5 * c + 5.2 * c * c);
                    let (exx, ezz, gxz) = (de[0] / dt, de[1] / dt, de[2] / dt);
                    let mean = (exx + ezz) / 3.0;
                    *tau = [2.0 * mu_eq * (exx - mean), 2.0 * mu_eq * (ezz - mean), mu_eq * gxz, -2.0 * mu_eq * mean];
                } else {
                    *tau = [0.0; 4];
                }
                // V = m/(n ρ(p)) with n the porosity of the skeleton's own points
                // in this element (1 in free water): the nodal porosity field is
                // smeared over an element at a soil–free-water boundary, and
                // taking it for the point's own mis-states the pressure there.
                let n_point = if el.solid_point_volume[e] > 0.0 {
                    (1.0 - el.grain_volume[e] / el.solid_point_volume[e]).max(POROSITY_BOUNDS.0)
                } else {
                    1.0
                };
                *vol = m / (n_point * rho_l * (1.0 + *pr / k));
                let du = st.interpolate(row, |i| disp[i][1]);
                x[0] = (x[0] + du[0]).clamp(lo[0], hi[0]);
                x[1] = (x[1] + du[1]).clamp(lo[1], hi[1]);
            });
    }
}

/// The semi-implicit pore pressure's stages (docs/design/mpm-implicit-pressure.md
/// §1 steps 1–5; `Params::implicit_pressure`), between `solve_nodes` (the
/// predictor: no pore pressure, no damping, drag implicit per node) and
/// `apply_wall_friction`.
impl Mpm {
    /// Step 1: per element, Σ V and Σ V p over its pressured (not free)
    /// liquid points, p the pressure each carried in (its element's at the
    /// last step): p̄_e, the backward Euler's old pressure and the solve's
    /// warm start. An element none of whose points was pressured takes
    /// its free points' mean instead: a saturated layer's given pressure
    /// (`Params::hydrostatic_surface`) when it enters the solve, 0 otherwise.
    fn pressure_reference(&mut self) {
        let touched_elements = self.touched_element_range();
        let Some(imp) = self.implicit.as_mut() else { return };
        let l = &self.state.liquid;
        imp.reference[touched_elements].fill([0.0; 4]);
        for (p, &e) in self.liquid_scratch.element.iter().enumerate() {
            let k = if l.free_surface[p] { 2 } else { 0 };
            let (w, r) = (l.set.volume[p], &mut imp.reference[e as usize]);
            r[k] += w;
            r[k + 1] += w * l.pressure[p];
        }
    }

    /// Steps 2 and 4: the pressure problem of the step. Every node with
    /// mass gets its masked predictor mobility (masses, the drag Q of
    /// `solve_nodes`); every element with liquid its porosity field, p̄ and
    /// role: unknown where its filling ratio is at least
    /// `free_surface_fill` (`ElementRole::classify`); otherwise given, a
    /// saturated layer's hydrostatic pressure under
    /// `Params::hydrostatic_surface` (`ElementScratch::saturated_layer`)
    /// where the floor or the element below (pressured, or a layer held
    /// up itself) holds the layer up, p = 0 where the soil has drained,
    /// nothing holds it or under
    /// `"free"`; an
    /// unknown element filled below 1 holds water and air, with the pore
    /// fluid's modulus of `pore_fluid_modulus` at the air's absolute
    /// pressure `air_pressure` + p̄ (design note §7: without it, an element
    /// switched from free to pressured while water still flowed in stopped
    /// that flow in one step, the remaining pressure spikes).
    fn assemble_pressure_problem(&mut self) {
        let grid = self.grid;
        let (nx, area, tol) = (grid.elements[0], grid.h * grid.h, self.mass_tolerance);
        let nodes = self.active_nodes();
        let Some(imp) = self.implicit.as_mut() else { return };
        let p = &self.params;
        // ρ_L g_z h/2: the pressure that holds a full element's water layer.
        let surface_head = p.liquid_density * (-p.gravity[1]).max(0.0) * grid.h / 2.0;
        let problem = &mut imp.problem;
        problem.reset(p.dt, p.bulk_modulus);
        for node in nodes {
            let s = &self.sums[node];
            if s.mass_s > tol || s.mass_l > tol {
                problem.set_node(node, [s.mass_s, s.mass_l], self.accel[node].drag, self.mask[node], tol);
            }
        }
        let ((r0, r1), (c0, c1)) = (self.rows, self.columns);
        let el = &self.elements;
        // What a layer inside element e rests on: a wall holding one of its
        // bottom nodes up this step (the floor), or the element below holding up
        // what lies on it: pressured, or a saturated layer held up itself
        // (an element of a vertical front). A wet element on neither
        // (spray, a drop in free fall) has no layer to hold: its water
        // falls free, at p = 0. Rows are assembled bottom up, so the row
        // below is done; below the first row there are no points.
        let mask = &self.mask;
        let [below, this_row] = &mut imp.holds_up;
        let first = r0.max(1);
        for r in first..r1.min(grid.elements[1] + 1) {
            for col in c0.max(1)..c1.min(nx + 1) {
                let e = (r - 1) * nx + (col - 1);
                this_row[col - 1] = false;
                if el.liquid_points[e] == 0 {
                    continue;
                }
                // Either bottom node held: the same rule whichever way the
                // flow runs when a unilateral floor releases one of them.
                let corner = grid.element_corner(e);
                let supported = if r == 1 {
                    mask[corner][1] == 0.0 || mask[corner + 1][1] == 0.0
                } else {
                    r > first && below[col - 1]
                };
                let saturation = el.filling_ratio(e, area);
                let role = match ElementRole::classify(true, saturation, p.free_surface_fill) {
                    ElementRole::Given(_) if p.hydrostatic_surface && supported => ElementRole::Given(
                        el.saturated_layer(e, area, p.free_surface_fill)
                            .map_or(0.0, |theta| surface_head * theta * theta),
                    ),
                    role => role,
                };
                this_row[col - 1] = match role {
                    ElementRole::Unknown => true,
                    ElementRole::Given(layer) => layer > 0.0,
                };
                let [w, wp, w_free, wp_free] = imp.reference[e];
                let reference = if w > 0.0 {
                    wp / w
                } else if w_free > 0.0 {
                    wp_free / w_free
                } else {
                    0.0
                };
                problem.set_element(e, el.porosity[e], el.grad_porosity[e], reference, role);
                if role == ElementRole::Unknown && saturation < 1.0 {
                    let air = p.air_pressure + reference.max(0.0);
                    problem.set_fluid_modulus(e, pore_fluid_modulus(saturation, p.bulk_modulus, air));
                }
                // Warm start from p̄ (not the last solution: a restart sees the same).
                imp.pressure[e] = reference;
            }
            std::mem::swap(below, this_row);
        }
        problem.index_elements();
    }

    /// Step 4: the predictor velocities v* = v⁰ + Δt a* (0 on fixed
    /// components and for a phase without mass; the solid's = the liquid's
    /// where there is no solid), then S p = C p̄ − D v* by Jacobi-PCG.
    fn solve_pressure(&mut self) {
        let nodes = self.active_nodes();
        let node_range = self.active_node_range();
        let Some(imp) = self.implicit.as_mut() else { return };
        let (dt, tol) = (self.params.dt, self.mass_tolerance);
        let [vs, vl] = &mut imp.velocity;
        // Read at the corners of the set elements and at active nodes alone.
        vs[node_range.clone()].fill([0.0; 2]);
        vl[node_range].fill([0.0; 2]);
        for node in nodes {
            let (s, a, mask) = (&self.sums[node], &self.accel[node].a, self.mask[node]);
            for d in 0..2 {
                if mask[d] == 0.0 {
                    continue;
                }
                if s.mass_s > tol {
                    vs[node][d] = self.velocity_s[node][d] + dt * a[0][d];
                }
                if s.mass_l > tol {
                    vl[node][d] = self.velocity_l[node][d] + dt * a[1][d];
                }
            }
        }
        imp.problem.merge_solid_into_liquid(vs, vl);
        let report = imp.solver.solve(&imp.problem, vs, vl, &mut imp.pressure);
        // The tension cap p ≥ −T as a clamp (design §1 step 4 without the
        // active set): a clamped element pushes with −T and leaves its
        // continuity unbalanced, as a free one does.
        let cap = -self.params.cavitation;
        let mut clamped = 0;
        for &e in imp.problem.unknowns() {
            let p = &mut imp.pressure[e as usize];
            if *p < cap {
                *p = cap;
                clamped += 1;
            }
        }
        let st = &mut imp.stats;
        st.clamped += clamped;
        st.solves += 1;
        st.iterations += report.iterations as u64;
        st.max_iterations = st.max_iterations.max(report.iterations);
        st.unconverged += u64::from(!report.converged);
        st.worst_residual = st.worst_residual.max(report.relative_residual);
        st.max_unknowns = st.max_unknowns.max(imp.problem.unknowns().len());
    }

    /// Step 5: the corrector v = v* + Δt A⁻¹ Dᵀp, then Cundall damping on
    /// the total force f = f* + Dᵀp (the predictor's undamped forces and the
    /// pressure's) as the explicit scheme damps it, taken through the same
    /// mobility (v −= Δt A⁻¹ α|f| sgn v⁰, what the coupled solve gives for
    /// the damped force), the walls' normal reactions with the pressure in
    /// them, and the accelerations a = (v − v⁰)/Δt the point update reads.
    /// Fixed components keep the predictor's (they stop the mapped velocity).
    /// At a node without solid the whole column's force is the liquid's.
    fn correct_velocities(&mut self) {
        let nodes = self.active_nodes();
        let node_range = self.active_node_range();
        let Some(imp) = self.implicit.as_mut() else { return };
        let p = &self.params;
        let (dt, alpha, mu, tol) = (p.dt, p.damping, p.wall_friction, self.mass_tolerance);
        let [vs, vl] = &mut imp.velocity;
        imp.solver.correct(&imp.problem, &imp.pressure, vs, vl);
        let [fps, fpl] = &mut imp.pressure_force;
        // Read at active nodes alone (here, `update_wall_contacts`, `liquid_force_on_solid`).
        imp.problem.pressure_forces_of_set_elements(&imp.pressure, node_range, fps, fpl);
        for node in nodes {
            let s = &self.sums[node];
            let (has_s, has_l) = (s.mass_s > tol, s.mass_l > tol);
            if !has_s && !has_l {
                continue;
            }
            let u = &mut self.accel[node];
            let v0 = [self.velocity_s[node], self.velocity_l[node]];
            let into = self.fixities.contact[node];
            let normal_axis = wall_normal_axis(into);
            let mut reaction = [0.0; 2];
            for d in 0..2 {
                let mut f = [u.force[0][d] + fps[node][d], u.force[1][d] + fpl[node][d]];
                if !has_s {
                    f = [0.0, f[0] + f[1]];
                }
                if self.mask[node][d] == 0.0 {
                    if normal_axis == Some(d) && mu > 0.0 {
                        reaction = Self::wall_reaction(s, d, f, u.drag, into[d], dt, tol);
                    }
                    continue;
                }
                let mut v = [vs[node][d], vl[node][d]];
                if alpha > 0.0 {
                    let damp = |f: f64, v: f64| if v != 0.0 { alpha * f.abs() * v.signum() } else { 0.0 };
                    let damping = [damp(f[0], v0[0][d]), damp(f[1], v0[1][d])];
                    let dv = imp.problem.mobility(node, d).apply(damping);
                    v = [v[0] - dt * dv[0], v[1] - dt * dv[1]];
                }
                u.a[0][d] = if has_s { (v[0] - v0[0][d]) / dt } else { 0.0 };
                u.a[1][d] = if has_l { (v[1] - v0[1][d]) / dt } else { 0.0 };
            }
            if normal_axis.is_some() {
                u.wall_load = Self::grains_wall_load(s, self.solid_fraction[node], reaction, tol);
            }
        }
    }
}

impl Mpm {
    /// Pore pressure as a plane per element (`Params::linear_pressure`).
    ///
    /// The increments of step 9 are per element, so points in one element
    /// differ only by the pressures they carried in: a point that brings an
    /// excess into an element keeps it for good (4.4 kPa beside
    /// neighbours at 41 Pa in the saturated lab column), a sub-element mode
    /// no nodal force sees. Each element's pressured (not free-surface)
    /// points are given the volume-weighted least-squares plane through
    /// their pressures: the mean pressure × volume of the element is kept,
    /// a linear field (hydrostatic) is reproduced exactly, and the
    /// sub-element outliers are gone. A direction along which the points
    /// spread less than a tenth of an element (a single row) gets no slope,
    /// and an element of three or fewer pressured points (which a plane
    /// would fit exactly, smoothing nothing) gets its mean. Where the plane
    /// would dip below the tension cap −T_cav at one of the points, its
    /// slope is scaled down until it does not (a slope limiter, as
    /// Barth & Jespersen 1989 limit a reconstructed gradient to the
    /// neighbours' bounds): clamping those points instead would add
    /// pressure the element did not have. As the moving-least-squares
    /// density filters of SPH (Colagrossi & Landrini 2003), here with the
    /// element as the kernel.
    /// Post: Σ p V over each element's pressured points unchanged (to
    /// round-off); p ≥ −T_cav at every point; free-surface points keep p = 0.
    fn reconstruct_pressure(&mut self) {
        if !self.params.linear_pressure {
            return;
        }
        let grid = self.grid;
        let (h, nx, origin) = (grid.h, grid.elements[0], grid.origin);
        let offset = move |e: usize, x: [f64; 2]| {
            let (i, k) = ((e % nx) as f64 + 0.5, (e / nx) as f64 + 0.5);
            [(x[0] - origin[0]) / h - i, (x[1] - origin[1]) / h - k]
        };
        let l = &mut self.state.liquid;
        let element = &self.liquid_scratch.element;
        let (moments, low) = (&mut self.elements.pressure_moments, &mut self.elements.pressure_low);
        moments.fill([0.0; 10]);
        for p in 0..l.set.len() {
            if l.free_surface[p] {
                continue;
            }
            let e = element[p] as usize;
            let [a, b] = offset(e, l.set.x[p]);
            let (w, pr) = (l.set.volume[p], l.pressure[p]);
            let m = &mut moments[e];
            for (slot, value) in m.iter_mut().zip([1.0, a, b, a * a, a * b, b * b, pr, a * pr, b * pr]) {
                *slot += w * value;
            }
            m[9] += 1.0;
        }
        let moments = &*moments;
        l.pressure
            .par_iter_mut()
            .zip(l.set.x.par_iter())
            .zip(l.free_surface.par_iter())
            .zip(element.par_iter())
            .with_min_len(CHUNK)
            .for_each(|(((pr, &x), &free), &e)| {
                if !free {
                    let [a, b] = offset(e as usize, x);
                    *pr = plane(&moments[e as usize], a, b);
                }
            });
        low.fill(f64::INFINITY);
        for p in 0..l.set.len() {
            if !l.free_surface[p] {
                let e = element[p] as usize;
                low[e] = low[e].min(l.pressure[p]);
            }
        }
        let (low, cav) = (&*low, self.params.cavitation);
        l.pressure.par_iter_mut().zip(l.free_surface.par_iter()).zip(element.par_iter()).with_min_len(CHUNK).for_each(
            |((pr, &free), &e)| {
                if !free {
                    let m = &moments[e as usize];
                    let mean = m[6] / m[0];
                    // max: round-off only, the limited plane's least value is −T_cav.
                    *pr = (mean + slope_limiter(mean, low[e as usize], cav) * (*pr - mean)).max(-cav);
                }
            },
        );
    }
}

/// Smallest variance of the points' offsets (in elements²) along a
/// direction that gets a pressure slope: a spread of a tenth of an element.
const SPREAD: f64 = 0.01;

/// Reorders in place so that index i holds what index `order[i]` held,
/// through `swap`, one cycle of the permutation at a time (`done`: scratch).
fn reorder(order: &[u32], done: &mut Vec<bool>, mut swap: impl FnMut(usize, usize)) {
    done.clear();
    done.resize(order.len(), false);
    for start in 0..order.len() {
        let mut j = start;
        while !done[j] {
            done[j] = true;
            let k = order[j] as usize;
            if k == start {
                break;
            }
            swap(j, k);
            j = k;
        }
    }
}

/// The axis of a node's wall normal from its `Fixities::contact` vector
/// (the unit vector into the wall): 0 for a side wall, 1 for the floor,
/// None off the walls. The x component is read first.
fn wall_normal_axis(into: [f64; 2]) -> Option<usize> {
    if into[0] != 0.0 {
        Some(0)
    } else if into[1] != 0.0 {
        Some(1)
    } else {
        None
    }
}

/// The weighted least-squares plane p = p̄ + s·(ξ − ξ̄) of the moments `m`
/// (`ElementScratch::pressure_moments`) at offset (a, b). The slope solves
/// the 2 × 2 covariance system along the principal directions whose spread
/// (standard deviation) exceeds a tenth of an element; the others get none.
/// Three or fewer points: the mean.
fn plane(m: &[f64; 10], a: f64, b: f64) -> f64 {
    let w = m[0];
    let (ma, mb, mean) = (m[1] / w, m[2] / w, m[6] / w);
    if m[9] <= 3.0 {
        return mean;
    }
    let (caa, cab, cbb) = (m[3] / w - ma * ma, m[4] / w - ma * mb, m[5] / w - mb * mb);
    let (cap, cbp) = (m[7] / w - ma * mean, m[8] / w - mb * mean);
    let (large, small) = {
        let half_trace = 0.5 * (caa + cbb);
        let root = (0.25 * (caa - cbb) * (caa - cbb) + cab * cab).sqrt();
        (half_trace + root, half_trace - root)
    };
    let d = [a - ma, b - mb];
    if small > SPREAD {
        // Both directions spread: the full 2 × 2 solve (det = λ₁λ₂ > SPREAD²).
        let det = caa * cbb - cab * cab;
        let slope = [(cbb * cap - cab * cbp) / det, (caa * cbp - cab * cap) / det];
        mean + slope[0] * d[0] + slope[1] * d[1]
    } else if large > SPREAD {
        // One direction: the eigenvector of λ₁, of its two forms
        // (λ₁ − cbb, cab) and (cab, λ₁ − caa) the longer (λ₁ − λ₂ > 0 keeps
        // one of them away from zero).
        let (u, v) = ([large - cbb, cab], [cab, large - caa]);
        let (nu, nv) = (u[0].hypot(u[1]), v[0].hypot(v[1]));
        let e = if nu >= nv { [u[0] / nu, u[1] / nu] } else { [v[0] / nv, v[1] / nv] };
        mean + (e[0] * cap + e[1] * cbp) / large * (e[0] * d[0] + e[1] * d[1])
    } else {
        mean
    }
}

/// The share φ ∈ [0, 1] of a plane's slope kept so that its lowest value
/// at the points, `low`, scaled about the mean, stays at or above −`cav`:
/// φ = (p̄ + T) / (p̄ − low) where the plane dips below −T. The mean is
/// never below −T (every pressure the plane is fitted to is capped there).
fn slope_limiter(mean: f64, low: f64, cav: f64) -> f64 {
    if low >= -cav || mean <= low {
        1.0
    } else {
        ((mean + cav) / (mean - low)).clamp(0.0, 1.0)
    }
}

/// The velocity point `p` gives the node at `at`: its own, plus under APIC
/// its carried gradient times the offset to the node.
#[inline(always)]
fn point_velocity_at(set: &PointSet, p: usize, at: [f64; 2], apic: bool) -> [f64; 2] {
    let v = set.v[p];
    if !apic || set.affine.is_empty() {
        return v;
    }
    let (c, x) = (set.affine[p], set.x[p]);
    let d = [at[0] - x[0], at[1] - x[1]];
    [v[0] + c[0][0] * d[0] + c[0][1] * d[1], v[1] + c[1][0] * d[0] + c[1][1] * d[1]]
}

#[cfg(test)]
mod tests {
    use super::{plane, reorder, slope_limiter, ElementScratch, PointSet};

    #[test]
    fn reorder_puts_what_order_names_at_each_index() {
        // Fixed points, a 2-cycle and a 4-cycle: new[i] = old[order[i]].
        let order = [0u32, 2, 1, 5, 3, 6, 4];
        let old: Vec<u32> = (10..17).collect();
        let mut values = old.clone();
        let mut done = Vec::new();
        reorder(&order, &mut done, |a, b| values.swap(a, b));
        let expected: Vec<u32> = order.iter().map(|&k| old[k as usize]).collect();
        assert_eq!(values, expected);
    }

    #[test]
    fn point_ids_are_empty_or_each_point_once() {
        let set = |id: Vec<u32>| PointSet { x: vec![[0.0; 2]; 3], id, ..Default::default() };
        assert!(set(vec![]).check_ids().is_ok());
        assert!(set(vec![2, 0, 1]).check_ids().is_ok());
        assert_eq!(set(vec![2, 0, 1]).by_id(), vec![1, 2, 0]);
        assert_eq!(set(vec![]).by_id(), vec![0, 1, 2]);
        assert!(set(vec![0, 1]).check_ids().is_err(), "too few");
        assert!(set(vec![0, 0, 1]).check_ids().is_err(), "repeated");
        assert!(set(vec![0, 1, 3]).check_ids().is_err(), "out of range");
    }

    /// One element of area 1 with the given grain and water volumes.
    fn element(grains: f64, water: f64) -> ElementScratch {
        ElementScratch { domain_volume: [vec![grains], vec![water]], ..Default::default() }
    }

    #[test]
    fn the_filling_ratio_tells_a_drained_element_from_a_saturated_one() {
        let f = |e: ElementScratch| e.filling_ratio(0, 1.0);
        // 12 + 12 points at n = 0.4, as seeded; the same points dilated to
        // n = 0.5 (their volumes overlap, the element's space is unchanged).
        assert!((f(element(0.6, 0.4)) - 1.0).abs() < 1e-12);
        // Drained: the skeleton stays, 6 of its 12 liquid points have left.
        assert!((f(element(0.6, 0.2)) - 0.5).abs() < 1e-12);
        // The lab column's spikes: 6 liquid and 10 solid points (0.40), and
        // on the rough floor 10 and 5 (0.44), where one filled point took
        // the element's void closure as compression (5.7 and 33 kPa).
        assert!((f(element(10.0 * 0.05, 6.0 * 0.4 / 12.0)) - 0.4).abs() < 1e-12);
        assert!((f(element(5.0 * 0.05, 10.0 * 0.4 / 12.0)) - 4.0 / 9.0).abs() < 1e-12);
        // Free water, half an element of it; grains leaving no space.
        assert!((f(element(0.0, 0.5)) - 0.5).abs() < 1e-12);
        assert_eq!(f(element(1.0, 0.0)), f64::INFINITY);
    }

    /// One element of area 1: grains, water and the solid points' pores.
    fn layer(grains: f64, water: f64, pores: f64) -> Option<f64> {
        let e = ElementScratch {
            domain_volume: [vec![grains], vec![water]],
            domain_pores: vec![pores],
            ..Default::default()
        };
        e.saturated_layer(0, 1.0, 0.8)
    }

    #[test]
    fn a_saturated_layer_is_told_from_a_drained_element() {
        let close = |a: Option<f64>, b: f64| a.is_some_and(|a| (a - b).abs() < 1e-12);
        // The top of a column at rest inside an element: two of its three
        // point rows of soil at n = 0.4 and their water (fill ratio 0.44,
        // below 0.8), the water filling the soil's pores: θ = 2/3.
        let two_thirds = 2.0 / 3.0;
        assert!(close(layer(0.6 * two_thirds, 0.4 * two_thirds, 0.4 * two_thirds), two_thirds));
        // The same soil drained of half its water: no layer, p = 0.
        assert_eq!(layer(0.6 * two_thirds, 0.2 * two_thirds, 0.4 * two_thirds), None);
        // The lab column's spike elements: 10 solid points (pores 10/12 −
        // 0.5) holding 6 liquid points (0.2): drained. 5 solid points
        // under 10 liquid ones: the soil's pores full, water above them.
        assert_eq!(layer(0.5, 0.2, 10.0 / 12.0 - 0.5), None);
        assert!(close(layer(0.25, 10.0 * 0.4 / 12.0, 5.0 / 12.0 - 0.25), 0.25 + 1.0 / 3.0));
        // Free water, a third of an element.
        assert!(close(layer(0.0, 1.0 / 3.0, 0.0), 1.0 / 3.0));
        // A soil dilated to n = 0.5 over half the element: saturated (θ =
        // 0.5), or its pores grown without water flowing in (S = 2/3).
        assert!(close(layer(0.25, 0.25, 0.25), 0.5));
        assert_eq!(layer(0.25, 0.25 * 2.0 / 3.0, 0.25), None);
    }

    /// Moments of `points` (offset, pressure, weight) as `reconstruct_pressure` sums them.
    fn moments(points: &[([f64; 2], f64, f64)]) -> [f64; 10] {
        let mut m = [0.0; 10];
        for &([a, b], p, w) in points {
            for (slot, v) in m.iter_mut().zip([1.0, a, b, a * a, a * b, b * b, p, a * p, b * p]) {
                *slot += w * v;
            }
            m[9] += 1.0;
        }
        m
    }

    #[test]
    fn the_plane_reproduces_a_linear_field_and_keeps_the_weighted_mean() {
        let field = |a: f64, b: f64| 350.0 - 52.3 * b + 7.1 * a;
        // The 4 × 3 sub-grid of a filled element, unequal weights.
        let mut pts = Vec::new();
        for i in 0..4 {
            for k in 0..3 {
                let (a, b) = (-0.375 + 0.25 * i as f64, -1.0 / 3.0 + k as f64 / 3.0);
                pts.push(([a, b], field(a, b), 1.0 + 0.1 * (i * 3 + k) as f64));
            }
        }
        let m = moments(&pts);
        for &([a, b], p, _) in &pts {
            assert!((plane(&m, a, b) - p).abs() < 1e-9, "{} vs {p}", plane(&m, a, b));
        }
        // One outlier: the weighted mean pressure (the element's Σ p V) is kept.
        pts[5].1 += 4000.0;
        let m = moments(&pts);
        let kept: f64 = pts.iter().map(|&([a, b], _, w)| w * plane(&m, a, b)).sum();
        assert!((kept - m[6]).abs() < 1e-9 * m[6], "{kept} vs {}", m[6]);
        // A rotated sub-grid (cross-covariance ≠ 0) still reproduces a plane.
        let rot = |[a, b]: [f64; 2]| [0.8 * a - 0.6 * b, 0.6 * a + 0.8 * b];
        let pts: Vec<_> = pts.iter().map(|&(x, _, w)| (rot(x), field(rot(x)[0], rot(x)[1]), w)).collect();
        let m = moments(&pts);
        for &([a, b], p, _) in &pts {
            assert!((plane(&m, a, b) - p).abs() < 1e-9);
        }
        // A 3 × 3 sub-grid (isotropic spread) and the hydrostatic field of a
        // column at rest (no slope in a, the cross-moment round-off only).
        let hydrostatic = |_: f64, b: f64| 372.78 - 39.24 * b;
        for (nx, nz) in [(3, 3), (4, 3)] {
            let pts: Vec<_> = (0..nx * nz)
                .map(|k| {
                    let (a, b) = (
                        (k % nx) as f64 / nx as f64 - 0.5 + 0.5 / nx as f64,
                        (k / nx) as f64 / nz as f64 - 0.5 + 0.5 / nz as f64,
                    );
                    ([a, b], hydrostatic(a, b), 1.3333e-6)
                })
                .collect();
            let m = moments(&pts);
            for &([a, b], p, _) in &pts {
                assert!((plane(&m, a, b) - p).abs() < 1e-9, "{nx} x {nz}: {} vs {p}", plane(&m, a, b));
            }
        }
        // A single row (no spread in b): its mean and x-slope only.
        let row: Vec<_> =
            (0..4).map(|i| ([-0.375 + 0.25 * i as f64, -0.4], field(-0.375 + 0.25 * i as f64, -0.4), 1.0)).collect();
        let m = moments(&row);
        assert!((plane(&m, 0.125, 0.3) - field(0.125, -0.4)).abs() < 1e-9);
        // A single diagonal row: the slope along it reproduces the field on
        // the line, none across it (the points cannot tell it).
        let along = |t: f64| [t * 0.6, t * 0.8];
        let diag: Vec<_> = (0..5)
            .map(|i| {
                let [a, b] = along(-0.4 + 0.2 * i as f64);
                ([a, b], field(a, b), 1.0)
            })
            .collect();
        let m = moments(&diag);
        for t in [-0.5, 0.1, 0.45] {
            let [a, b] = along(t);
            let across = [a - 0.3 * 0.8, b + 0.3 * 0.6];
            assert!((plane(&m, a, b) - field(a, b)).abs() < 1e-9, "along t = {t}");
            assert!((plane(&m, across[0], across[1]) - field(a, b)).abs() < 1e-9, "across t = {t}");
        }
        // Three points (a plane would fit them exactly): their mean.
        let m = moments(&pts_of(&[([-0.3, -0.3], 100.0), ([0.3, -0.3], 400.0), ([0.0, 0.3], 700.0)]));
        assert!((plane(&m, 0.3, -0.3) - 400.0).abs() < 1e-9);
    }

    fn pts_of(points: &[([f64; 2], f64)]) -> Vec<([f64; 2], f64, f64)> {
        points.iter().map(|&(x, p)| (x, p, 1.0)).collect()
    }

    /// A lone excess in one corner: the plane through it dips below zero at
    /// the opposite corner. The limited slope keeps the element's Σ p V and
    /// puts the least pressure exactly at −T (T = 0 and 1 kPa).
    #[test]
    fn the_slope_limiter_keeps_the_element_load_and_the_tension_cap() {
        let mut pts = Vec::new();
        for i in 0..4 {
            for k in 0..3 {
                let (a, b) = (-0.375 + 0.25 * i as f64, -1.0 / 3.0 + k as f64 / 3.0);
                pts.push(([a, b], if i == 3 && k == 2 { 4400.0 } else { 40.0 }, 1.0 + 0.05 * k as f64));
            }
        }
        let m = moments(&pts);
        let mean = m[6] / m[0];
        let fitted: Vec<f64> = pts.iter().map(|&([a, b], _, _)| plane(&m, a, b)).collect();
        let low = fitted.iter().cloned().fold(f64::INFINITY, f64::min);
        assert!(low < -100.0, "the case must need the limiter: least fitted {low}");
        for cav in [0.0, 1000.0] {
            let phi = slope_limiter(mean, low, cav);
            let limited: Vec<f64> = fitted.iter().map(|&q| mean + phi * (q - mean)).collect();
            let least = limited.iter().cloned().fold(f64::INFINITY, f64::min);
            let load: f64 = limited.iter().zip(&pts).map(|(p, &(_, _, w))| p * w).sum();
            let expected_least = if low < -cav { -cav } else { low };
            assert!((least - expected_least).abs() < 1e-9, "T = {cav}: least {least}");
            assert!((load - m[6]).abs() < 1e-12 * m[6], "T = {cav}: load {load} vs {}", m[6]);
        }
        // A plane that stays above −T is left alone.
        assert_eq!(slope_limiter(500.0, 20.0, 0.0), 1.0);
    }
}
