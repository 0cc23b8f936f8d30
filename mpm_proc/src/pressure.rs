//! Semi-implicit pore pressure on the structured grid: the operator and the
//! linear solver of `docs/design/mpm-implicit-pressure.md` (§1 step 4, §3).
//! [`crate::solver::Mpm::step`] calls it under `mpm.pressure_scheme =
//! "implicit"` (stages `pressure_reference`, `assemble_pressure_problem`,
//! `solve_pressure`, `correct_velocities` of `solver.rs`); tested on its
//! own here and in the whole step in `tests/implicit_pressure.rs`.
//!
//! One pressure p_e per element centre (P0) acts on the bilinear (Q1) nodal
//! velocities of both phases. With the predictor velocities v* (all forces
//! but the pore pressure, drag implicit per node), the corrector and the
//! backward-Euler liquid continuity
//!
//! ```text
//! v = v* + Δt A⁻¹ Dᵀ p,        n_e A_e (p_e − p̄_e)/(K_L Δt) = −(D v)_e
//! ```
//!
//! give one symmetric positive definite system per step (design §1 step 4):
//!
//! ```text
//! S p = [C + Δt D A⁻¹ Dᵀ] p = C p̄ − D v*,     C = diag(n_e A_e /(K_L Δt)),
//! ```
//!
//! on the set P of pressured elements, the given (Dirichlet) pressures moved
//! to the right-hand side. K_L → ∞ is Chorin's (1968) projection; the
//! two-phase predictor–corrector is Kularathna et al. (2021, IJNAMG,
//! doi:10.1002/nag.3207), with the pressure moved from their nodes to the
//! element centres so that the divergence D is exactly the transpose of the
//! pressure force (design, "Proposal").
//!
//! Conventions. Units are SI per metre of out-of-plane width (plane strain):
//! masses kg/m, areas m², forces N/m, velocities m/s, pressures Pa. Nodes are
//! the grid's stored nodes (ghost ring included); element e = k·nx + i has
//! the corners `Grid::element_corner(e)` + {0, 1, row, row + 1} (lower left,
//! lower right, upper left, upper right), as in `solver.rs`. Nodal 2-vectors
//! are `[x, z]`; the two phases are ordered [solid, liquid] throughout.
//! A_e = h² for every element (the grid is uniform), so it is not stored.
//!
//! Where the design note is silent or loose, the choices made here:
//! - "the solid column merges into the liquid one" at nodes without solid
//!   is realised as the mobility [[1, 1], [1, 1]]/(M_S + M_L), which is
//!   exactly the reduced operator D P M_L⁻¹ Pᵀ Dᵀ of v_S = v_L (symmetric);
//!   it needs v*_S = v*_L there ([`PressureProblem::merge_solid_into_liquid`]).
//!   Nodes with solid but no liquid, which the note does not mention, give
//!   the liquid column nothing.
//! - "the Q1-P0 checkerboard lies in null(Dᵀ)" (design §3) holds for the
//!   mixture force and for uniform porosity; with ∇n ≠ 0 the per-phase
//!   forces of a checkerboard do not cancel. That only helps S (C keeps it
//!   definite either way, for K_L < ∞ and n_e > 0).
//! - A saturated column whose predictor has no effective stress is not
//!   hydrostatic after one step: the pressure carries between
//!   g/((1 − n)/ρ_s + n/ρ_L) (no drag) and the mixture's ρ_mix g (locked
//!   phases) per metre of depth (test
//!   `a_saturated_column_carries_the_mixture_or_the_split_weight`); the
//!   hydrostatic ρ_L g needs the skeleton's stress in the predictor.

use crate::grid::Grid;

/// Per node: the forces Dᵀp on [solid, liquid] × (x, z), N/m.
pub type NodeForce = [[f64; 2]; 2];

/// 2h ∇N_I at the element centroid for the corners in the order lower left,
/// lower right, upper left, upper right: the bilinear shape's gradient, the
/// same finite difference as `porosity_fields` and
/// `volumetric_strain_per_element` in `solver.rs`. N_I = ¼ at the centroid.
const CORNER_GRADIENT_SIGNS: [[f64; 2]; 4] = [[-1.0, -1.0], [1.0, -1.0], [-1.0, 1.0], [1.0, 1.0]];

/// The symmetric 2×2 predictor mobility A_I⁻¹ of one node and one velocity
/// component, [solid, liquid] ordered, in m/kg per metre of width (1/(kg/m)):
/// the inverse of A = [[M_S + ΔtQ, −ΔtQ], [−ΔtQ, M_L + ΔtQ]], the matrix the
/// backward-Euler drag of `Mpm::coupled_accelerations` inverts (design §1
/// step 4). Positive semidefinite in every case below.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Mobility {
    /// (A⁻¹)_SS.
    pub solid: f64,
    /// (A⁻¹)_SL = (A⁻¹)_LS.
    pub coupling: f64,
    /// (A⁻¹)_LL.
    pub liquid: f64,
}

impl Mobility {
    /// A⁻¹ = [[M_L + ΔtQ, ΔtQ], [ΔtQ, M_S + ΔtQ]] / (M_S M_L + ΔtQ (M_S + M_L))
    /// for nodal masses `masses` = [M_S, M_L] (kg/m), drag coefficient
    /// `drag` = Q ≥ 0 (force per relative velocity, so that ΔtQ is a mass
    /// per metre) and time step `dt` (s). A phase counts as present where
    /// its mass exceeds `mass_tolerance` (as in `solver.rs`).
    ///
    /// Limits (design §1 step 4): Q → 0 gives diag(1/M_S, 1/M_L), each
    /// phase pushed alone; ΔtQ ≫ M gives 1/(M_S + M_L) in every entry, the
    /// phases locked into one mixture, plus a Darcy term
    /// [[M_L², −M_S M_L], [−M_S M_L, M_S²]] / ((M_S + M_L)² ΔtQ).
    ///
    /// A node with liquid but no solid: the solid column is merged into the
    /// liquid one (the rule "the solid moves with the liquid" of
    /// `remap_momentum`). With P the prolongation v_S = v_L = u, the
    /// operator D P M⁻¹ Pᵀ Dᵀ of the single unknown u is D B Dᵀ with
    /// B = [[1, 1], [1, 1]]/(M_S + M_L): the ΔtQ → ∞ limit above, symmetric
    /// and positive semidefinite, and the correction B Dᵀ p moves both
    /// phases alike, so v_S = v_L is kept. The predictor must satisfy it as
    /// well ([`PressureProblem::merge_solid_into_liquid`]).
    ///
    /// A node with solid but no liquid: the liquid column gets nothing
    /// (its velocity is not defined there; `map_to_grid` sets it to 0) and
    /// the solid 1/M_S. A node with neither: all zero.
    pub fn predictor(masses: [f64; 2], drag: f64, dt: f64, mass_tolerance: f64) -> Self {
        let [mass_s, mass_l] = masses;
        match (mass_s > mass_tolerance, mass_l > mass_tolerance) {
            (true, true) => {
                let dq = dt * drag;
                let det = mass_s * mass_l + dq * (mass_s + mass_l);
                Self { solid: (mass_l + dq) / det, coupling: dq / det, liquid: (mass_s + dq) / det }
            }
            (false, true) => {
                let m = 1.0 / (mass_s + mass_l);
                Self { solid: m, coupling: m, liquid: m }
            }
            (true, false) => Self { solid: 1.0 / mass_s, coupling: 0.0, liquid: 0.0 },
            (false, false) => Self::default(),
        }
    }

    /// The mobility times a fixity `mask` (1 free, 0 fixed, as
    /// `Fixities::base`): a fixed component gets no correction, which makes
    /// a wall impermeable with nothing else to impose (design §1 step 2).
    pub fn masked(self, mask: f64) -> Self {
        Self { solid: mask * self.solid, coupling: mask * self.coupling, liquid: mask * self.liquid }
    }

    /// A⁻¹ f for the forces `f` = [f_S, f_L] along one component: the
    /// velocity change per unit time, m/s².
    #[inline(always)]
    pub fn apply(&self, f: [f64; 2]) -> [f64; 2] {
        [self.solid * f[0] + self.coupling * f[1], self.coupling * f[0] + self.liquid * f[1]]
    }

    /// aᵀ A⁻¹ a.
    #[inline(always)]
    fn quadratic(&self, a: [f64; 2]) -> f64 {
        self.solid * a[0] * a[0] + 2.0 * self.coupling * a[0] * a[1] + self.liquid * a[1] * a[1]
    }
}

/// Bulk modulus of a pore fluid of water (modulus `water`, Pa) and air at
/// absolute pressure `air` (Pa) filling `saturation` S of the pores:
/// 1/K = S/K_w + (1 − S)/p_air (the air isothermal, none dissolved;
/// Verruijt, Soil Mechanics, Delft 2001, "compressibility of the pore
/// fluid"). S ≥ 1 gives K_w. A little air dominates: S = 0.99 at 100 kPa
/// makes water of 2e9 Pa 200× softer.
pub fn pore_fluid_modulus(saturation: f64, water: f64, air: f64) -> f64 {
    assert!(water > 0.0 && air > 0.0, "moduli must be positive: water {water} Pa, air {air} Pa");
    if saturation >= 1.0 {
        return water;
    }
    1.0 / (saturation / water + (1.0 - saturation) / air)
}

/// What an element is in one step's pressure problem (design §1 step 2).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum ElementRole {
    /// Its pressure is solved for: the set P.
    Unknown,
    /// Its pressure is given, Pa: 0 at the free surface, in drained or part
    /// empty elements and where there is no liquid; a saturated layer's
    /// hydrostatic pressure in a part-filled element (the solver's
    /// `surface_elements = "hydrostatic"`); −T at the cavitation cap (a
    /// later active-set loop).
    Given(f64),
}

impl ElementRole {
    /// The rule of design §1 step 2: an element with liquid points and a
    /// filling ratio F_e (`ElementScratch::filling_ratio`, ∞ where the
    /// grains leave no space) of at least `free_surface_fill` is pressured;
    /// every other element is free surface, p = 0 (as the explicit
    /// scheme's free-surface rule in `update_liquid_points`), which the
    /// solver may raise to a saturated layer's pressure.
    pub fn classify(has_liquid: bool, filling_ratio: f64, free_surface_fill: f64) -> Self {
        if has_liquid && filling_ratio >= free_surface_fill {
            Self::Unknown
        } else {
            Self::Given(0.0)
        }
    }
}

/// One step's pressure problem on the structured grid: per element the
/// coefficients of the mixture divergence (design §1, D_e) and of the
/// compressibility C_e, per node and component the masked mobility A_I⁻¹,
/// and which elements are unknown.
///
/// Use: [`Self::new`] once per grid (or [`Self::reset`] per step, which
/// keeps the allocations), [`Self::set_node`] for every node with mass,
/// [`Self::set_element`] for every element with liquid, then
/// [`Self::index_elements`]; the operator methods panic if that last call
/// is missing. Unknown vectors ("compact") are indexed by the position of
/// the element in [`Self::unknowns`]; element vectors ("full") by e.
#[derive(Debug, Clone)]
pub struct PressureProblem {
    grid: Grid,
    /// Stored nodes per row.
    row: usize,
    /// Δt, s.
    dt: f64,
    /// K_L, Pa (∞ allowed: incompressible, C = 0).
    bulk_modulus: f64,
    /// Per element, the pore fluid's bulk modulus, Pa (K_L but where set).
    fluid_modulus: Vec<f64>,
    /// n_e and ∇n_e (1/m) at the centroid, from the corner nodes as in
    /// `porosity_fields`.
    porosity: Vec<f64>,
    grad_porosity: Vec<[f64; 2]>,
    /// p̄_e, Pa: the mean pressure the element's liquid carried in.
    reference_pressure: Vec<f64>,
    /// p_e of the elements not in P, Pa (0 in P).
    given_pressure: Vec<f64>,
    unknown: Vec<bool>,
    /// Per node, per component (x, z): A_I⁻¹ × mask.
    mobility: Vec<[Mobility; 2]>,
    /// Nodes with liquid but no solid: the solid column merged into the liquid one.
    merged: Vec<bool>,
    /// The elements of P, ascending; the elements with a non-zero given pressure.
    unknowns: Vec<u32>,
    given: Vec<u32>,
    /// Corner nodes and divergence coefficients of `unknowns` and of
    /// `given` (same order), and C_e of `unknowns`: built once per step by
    /// [`Self::index_elements`] instead of once per element per operator
    /// application (the same values, so the same arithmetic).
    unknown_stencils: Vec<ElementStencil>,
    given_stencils: Vec<ElementStencil>,
    unknown_compressibility: Vec<f64>,
    /// The distinct corner nodes of `unknowns`, where the operator applies
    /// the mobility once per node, and of `unknowns` and `given` together.
    unknown_corners: Vec<u32>,
    listed_corners: Vec<u32>,
    /// Per node, the `stamp` of the last list it was put in (deduplication
    /// without clearing a node-sized array).
    node_stamp: Vec<u32>,
    stamp: u32,
    /// The elements and nodes written since the last [`Self::reset`]: the
    /// only ones it has to restore (most of the grid is never touched).
    touched_elements: Vec<u32>,
    touched_nodes: Vec<u32>,
    indexed: bool,
}

/// One element's corner nodes and its coefficients of the mixture
/// divergence ([`PressureProblem::divergence_coefficients`]).
#[derive(Debug, Clone, Copy)]
struct ElementStencil {
    nodes: [usize; 4],
    d: [[[f64; 2]; 2]; 4],
}

/// Appends to `out` the corners of `stencils` not yet stamped with `stamp`,
/// stamping them: each node once, in first-seen order.
fn add_new_corners(stencils: &[ElementStencil], node_stamp: &mut [u32], stamp: u32, out: &mut Vec<u32>) {
    for node in stencils.iter().flat_map(|st| st.nodes) {
        if node_stamp[node] != stamp {
            node_stamp[node] = stamp;
            out.push(node as u32);
        }
    }
}

impl PressureProblem {
    /// An empty problem over `grid` (every element given p = 0, n = 1, every
    /// node without mobility) for time step `dt` (s) and liquid bulk
    /// modulus `bulk_modulus` (Pa, > 0; ∞ for the incompressible limit).
    pub fn new(grid: Grid, dt: f64, bulk_modulus: f64) -> Self {
        let (ne, nodes) = (grid.element_count(), grid.node_count());
        let mut problem = Self {
            grid,
            row: grid.node_dims()[0],
            dt,
            bulk_modulus,
            fluid_modulus: vec![bulk_modulus; ne],
            porosity: vec![1.0; ne],
            grad_porosity: vec![[0.0; 2]; ne],
            reference_pressure: vec![0.0; ne],
            given_pressure: vec![0.0; ne],
            unknown: vec![false; ne],
            mobility: vec![[Mobility::default(); 2]; nodes],
            merged: vec![false; nodes],
            unknowns: Vec::new(),
            given: Vec::new(),
            unknown_stencils: Vec::new(),
            given_stencils: Vec::new(),
            unknown_compressibility: Vec::new(),
            unknown_corners: Vec::new(),
            listed_corners: Vec::new(),
            node_stamp: vec![0; nodes],
            stamp: 0,
            touched_elements: Vec::new(),
            touched_nodes: Vec::new(),
            indexed: true,
        };
        problem.reset(dt, bulk_modulus);
        problem
    }

    /// Back to the empty problem of [`Self::new`] for a new step, keeping
    /// the allocations. Restores the elements and nodes set since the last
    /// reset (all of them where K_L changed), not the whole grid.
    pub fn reset(&mut self, dt: f64, bulk_modulus: f64) {
        assert!(dt > 0.0 && bulk_modulus > 0.0, "Δt = {dt} s and K_L = {bulk_modulus} Pa must be positive");
        self.dt = dt;
        if bulk_modulus.to_bits() != self.bulk_modulus.to_bits() {
            self.fluid_modulus.fill(bulk_modulus);
        }
        self.bulk_modulus = bulk_modulus;
        for &e in &self.touched_elements {
            let e = e as usize;
            self.fluid_modulus[e] = bulk_modulus;
            self.porosity[e] = 1.0;
            self.grad_porosity[e] = [0.0; 2];
            self.reference_pressure[e] = 0.0;
            self.given_pressure[e] = 0.0;
            self.unknown[e] = false;
        }
        for &node in &self.touched_nodes {
            self.mobility[node as usize] = [Mobility::default(); 2];
            self.merged[node as usize] = false;
        }
        self.touched_elements.clear();
        self.touched_nodes.clear();
        self.unknowns.clear();
        self.given.clear();
        self.unknown_stencils.clear();
        self.given_stencils.clear();
        self.unknown_compressibility.clear();
        self.unknown_corners.clear();
        self.listed_corners.clear();
        self.indexed = true;
    }

    /// The grid the problem lives on.
    pub fn grid(&self) -> &Grid {
        &self.grid
    }

    /// Δt, s.
    pub fn dt(&self) -> f64 {
        self.dt
    }

    /// Node `node`: masses [M_S, M_L] (kg/m), drag coefficient Q (see
    /// [`Mobility::predictor`]), fixity `mask` per component (1 free, 0
    /// fixed) and the mass below which a phase is absent (kg/m).
    pub fn set_node(&mut self, node: usize, masses: [f64; 2], drag: f64, mask: [f64; 2], mass_tolerance: f64) {
        let b = Mobility::predictor(masses, drag, self.dt, mass_tolerance);
        self.mobility[node] = [b.masked(mask[0]), b.masked(mask[1])];
        self.merged[node] = masses[0] <= mass_tolerance && masses[1] > mass_tolerance;
        self.touched_nodes.push(node as u32);
    }

    /// Element `e`: porosity n_e and its gradient ∇n_e (1/m) at the
    /// centroid, from the corner nodes (`porosity_fields`); the reference
    /// pressure p̄_e (Pa, the Σ V p / Σ V of its non-free liquid points,
    /// design §1 step 1); its role. Call [`Self::index_elements`] after the
    /// last element.
    pub fn set_element(
        &mut self,
        e: usize,
        porosity: f64,
        grad_porosity: [f64; 2],
        reference_pressure: f64,
        role: ElementRole,
    ) {
        self.touched_elements.push(e as u32);
        self.porosity[e] = porosity;
        self.grad_porosity[e] = grad_porosity;
        self.reference_pressure[e] = reference_pressure;
        (self.unknown[e], self.given_pressure[e]) = match role {
            ElementRole::Unknown => (true, 0.0),
            ElementRole::Given(p) => (false, p),
        };
        self.indexed = false;
    }

    /// Builds the lists of unknown elements and of elements with a non-zero
    /// given pressure, with their divergence coefficients and corner nodes;
    /// the operators loop over those alone (the saturated elements are a
    /// fraction of the grid, design §3). Call after the last
    /// [`Self::set_element`] and [`Self::set_fluid_modulus`].
    pub fn index_elements(&mut self) {
        self.unknowns.clear();
        self.given.clear();
        self.touched_elements.sort_unstable();
        self.touched_elements.dedup();
        // Only set elements can be unknown or carry a non-zero given pressure.
        for &e in &self.touched_elements {
            let e = e as usize;
            if self.unknown[e] {
                self.unknowns.push(e as u32);
            } else if self.given_pressure[e] != 0.0 {
                self.given.push(e as u32);
            }
        }
        self.unknown_stencils.clear();
        self.unknown_compressibility.clear();
        for k in 0..self.unknowns.len() {
            let e = self.unknowns[k] as usize;
            let (st, c) = (self.stencil(e), self.compressibility(e));
            self.unknown_stencils.push(st);
            self.unknown_compressibility.push(c);
        }
        self.given_stencils.clear();
        for k in 0..self.given.len() {
            let st = self.stencil(self.given[k] as usize);
            self.given_stencils.push(st);
        }
        self.stamp = self.stamp.wrapping_add(1);
        if self.stamp == 0 {
            // Wrapped round to the value of never-stamped nodes.
            self.node_stamp.fill(0);
            self.stamp = 1;
        }
        self.unknown_corners.clear();
        add_new_corners(&self.unknown_stencils, &mut self.node_stamp, self.stamp, &mut self.unknown_corners);
        self.listed_corners.clone_from(&self.unknown_corners);
        add_new_corners(&self.given_stencils, &mut self.node_stamp, self.stamp, &mut self.listed_corners);
        self.indexed = true;
    }

    /// The elements of P in the order of the compact vectors.
    pub fn unknowns(&self) -> &[u32] {
        self.check_indexed();
        &self.unknowns
    }

    /// Whether element `e` is in P.
    pub fn is_unknown(&self, e: usize) -> bool {
        self.unknown[e]
    }

    /// The given pressure of an element not in P, Pa (0 in P).
    pub fn given_pressure(&self, e: usize) -> f64 {
        self.given_pressure[e]
    }

    /// The masked mobility of `node` along component `d` (0: x, 1: z).
    pub fn mobility(&self, node: usize, d: usize) -> Mobility {
        self.mobility[node][d]
    }

    /// C_e = n_e A_e / (K_e Δt), m²/(Pa·s): the pore fluid's compressibility
    /// over the step, backward Euler (design §1 step 4), K_e = K_L unless
    /// set ([`Self::set_fluid_modulus`]). 0 for K_e = ∞.
    pub fn compressibility(&self, e: usize) -> f64 {
        self.porosity[e] * self.grid.h * self.grid.h / (self.fluid_modulus[e] * self.dt)
    }

    /// The pore fluid of element `e` has bulk modulus `k` (Pa, > 0) instead
    /// of K_L (`pore_fluid_modulus` for water with air). Call after
    /// [`Self::set_element`], before [`Self::index_elements`].
    pub fn set_fluid_modulus(&mut self, e: usize, k: f64) {
        debug_assert!(k > 0.0);
        self.touched_elements.push(e as u32);
        self.fluid_modulus[e] = k;
        self.indexed = false;
    }

    /// The four corner nodes of element `e` and the coefficients of its
    /// mixture divergence at the centroid (design §1), m, indexed
    /// `[corner][phase][component]`:
    /// D_S,eI = A_e [(1 − n_e) ∇N_I(c) − N_I(c) ∇n_e],
    /// D_L,eI = A_e [n_e ∇N_I(c) + N_I(c) ∇n_e],
    /// so that (D v)_e = A_e [(1 − n_e) div v_S + n_e div v_L + (v_L − v_S)·∇n_e]
    /// (m²/s), `volumetric_strain_per_element` × n_e A_e / Δt. Their sum
    /// over the phases is A_e ∇N_I: the mixture feels the plain pressure
    /// gradient.
    ///
    /// The operators read them from the lists [`Self::index_elements`]
    /// builds.
    pub fn divergence_coefficients(&self, e: usize) -> ([usize; 4], [[[f64; 2]; 2]; 4]) {
        let n0 = self.grid.element_corner(e);
        let nodes = [n0, n0 + 1, n0 + self.row, n0 + self.row + 1];
        let h = self.grid.h;
        let area = h * h;
        let (n, grad_n) = (self.porosity[e], self.grad_porosity[e]);
        let mut d = [[[0.0; 2]; 2]; 4];
        for (c, signs) in CORNER_GRADIENT_SIGNS.iter().enumerate() {
            for k in 0..2 {
                let grad_shape = signs[k] * 0.5 / h;
                d[c][0][k] = area * ((1.0 - n) * grad_shape - 0.25 * grad_n[k]);
                d[c][1][k] = area * (n * grad_shape + 0.25 * grad_n[k]);
            }
        }
        (nodes, d)
    }

    fn stencil(&self, e: usize) -> ElementStencil {
        let (nodes, d) = self.divergence_coefficients(e);
        ElementStencil { nodes, d }
    }

    /// (D v)_e of one element from nodal velocities `vs`, `vl` (m/s), m²/s.
    fn element_divergence(st: &ElementStencil, vs: &[[f64; 2]], vl: &[[f64; 2]]) -> f64 {
        let (nodes, d) = (&st.nodes, &st.d);
        let mut div = 0.0;
        for c in 0..4 {
            let (s, l) = (vs[nodes[c]], vl[nodes[c]]);
            div += d[c][0][0] * s[0] + d[c][0][1] * s[1] + d[c][1][0] * l[0] + d[c][1][1] * l[1];
        }
        div
    }

    /// D: the mixture divergence (D v)_e of every element (m²/s, the rate
    /// of change of the element's mixture volume the nodal velocities
    /// imply) from the nodal velocities `vs`, `vl` (m/s) of the solid and
    /// the liquid. Pre: slices sized to the grid's nodes and elements.
    pub fn divergence(&self, vs: &[[f64; 2]], vl: &[[f64; 2]], out: &mut [f64]) {
        assert_eq!(out.len(), self.porosity.len());
        for (e, o) in out.iter_mut().enumerate() {
            *o = Self::element_divergence(&self.stencil(e), vs, vl);
        }
    }

    /// Dᵀ: the nodal forces (N/m) of the element pressures `pressure` (Pa,
    /// every element, whatever its role) on the solid (`force_s`) and the
    /// liquid (`force_l`), written over every node. The exact transpose of
    /// [`Self::divergence`]: Σ_I f·v = Σ_e p_e (D v)_e. The same forces as
    /// the explicit scheme's −(1 − n) div σ_L + N σ_L ∇n and
    /// −n div σ_L − N σ_L ∇n with σ_L = −p (`solve_nodes`), one point at
    /// the centroid.
    pub fn pressure_forces(&self, pressure: &[f64], force_s: &mut [[f64; 2]], force_l: &mut [[f64; 2]]) {
        assert_eq!(pressure.len(), self.porosity.len());
        force_s.fill([0.0; 2]);
        force_l.fill([0.0; 2]);
        for (e, &p) in pressure.iter().enumerate() {
            // Most of the grid is empty or free (p = 0): adding their ±0
            // leaves every sum as it is, so they are skipped.
            if p != 0.0 {
                self.add_element_forces(e, p, force_s, force_l);
            }
        }
    }

    /// Adds element `e`'s pressure `p` (Pa) to its corners' forces (Dᵀ's
    /// column of `e`).
    #[inline]
    fn add_element_forces(&self, e: usize, p: f64, force_s: &mut [[f64; 2]], force_l: &mut [[f64; 2]]) {
        let (corners, d) = self.divergence_coefficients(e);
        for c in 0..4 {
            for k in 0..2 {
                force_s[corners[c]][k] += d[c][0][k] * p;
                force_l[corners[c]][k] += d[c][1][k] * p;
            }
        }
    }

    /// [`Self::pressure_forces`] after a [`PressureSolver::solve`], over
    /// the nodes `nodes` alone: the same forces, summed in the same order,
    /// in less time. Pre: `pressure` is 0 on every element not set since
    /// the reset (as the solve leaves it: the given pressure, 0 there),
    /// and `nodes` holds every corner of the elements set since it; the
    /// forces outside `nodes` are left as they are.
    pub fn pressure_forces_of_set_elements(
        &self,
        pressure: &[f64],
        nodes: std::ops::Range<usize>,
        force_s: &mut [[f64; 2]],
        force_l: &mut [[f64; 2]],
    ) {
        self.check_indexed();
        assert_eq!(pressure.len(), self.porosity.len());
        force_s[nodes.clone()].fill([0.0; 2]);
        force_l[nodes.clone()].fill([0.0; 2]);
        // Sorted by `index_elements`: the ascending order of `pressure_forces`.
        for &e in &self.touched_elements {
            let (e, p) = (e as usize, pressure[e as usize]);
            if p != 0.0 {
                debug_assert!(
                    self.divergence_coefficients(e).0.iter().all(|c| nodes.contains(c)),
                    "element {e}'s corners outside {nodes:?}"
                );
                self.add_element_forces(e, p, force_s, force_l);
            }
        }
    }

    /// Gives the solid the liquid's predictor velocity at the nodes with
    /// liquid but no solid (see [`Mobility::predictor`]): the precondition
    /// of [`Self::right_hand_side`] there, as `remap_momentum` sets
    /// Δu_S = Δu_L (`map_to_grid` leaves v_S = 0 at such nodes).
    pub fn merge_solid_into_liquid(&self, vs: &mut [[f64; 2]], vl: &[[f64; 2]]) {
        // Only nodes set since the reset can be merged.
        for &node in &self.touched_nodes {
            let node = node as usize;
            if self.merged[node] {
                vs[node] = vl[node];
            }
        }
    }

    fn check_indexed(&self) {
        assert!(self.indexed, "PressureProblem: call index_elements after set_element and set_fluid_modulus");
    }

    /// Zeroes the scratch forces at `nodes`.
    fn clear(nodes: &[u32], force: &mut [NodeForce]) {
        for &node in nodes {
            force[node as usize] = [[0.0; 2]; 2];
        }
    }

    /// Adds Dᵀ p over the elements of `stencils`, p = `pressure(k)` for the
    /// k-th of them.
    fn scatter(stencils: &[ElementStencil], pressure: impl Fn(usize) -> f64, force: &mut [NodeForce]) {
        for (k, st) in stencils.iter().enumerate() {
            let p = pressure(k);
            for c in 0..4 {
                let f = &mut force[st.nodes[c]];
                for phase in 0..2 {
                    f[phase][0] += st.d[c][phase][0] * p;
                    f[phase][1] += st.d[c][phase][1] * p;
                }
            }
        }
    }

    /// Replaces the scratch forces f at `nodes` by A⁻¹ f, per component:
    /// once per node, where each of its up to four elements would otherwise
    /// apply it again.
    fn apply_mobility(&self, nodes: &[u32], force: &mut [NodeForce]) {
        for &node in nodes {
            let (f, b) = (&mut force[node as usize], &self.mobility[node as usize]);
            for k in 0..2 {
                let a = b[k].apply([f[0][k], f[1][k]]);
                (f[0][k], f[1][k]) = (a[0], a[1]);
            }
        }
    }

    /// (D a)_e for the scratch A⁻¹ f at the corners of one element
    /// (after [`Self::apply_mobility`] on them).
    fn divergence_of_mobility(st: &ElementStencil, velocity: &[NodeForce]) -> f64 {
        let mut sum = 0.0;
        for c in 0..4 {
            let a = &velocity[st.nodes[c]];
            for k in 0..2 {
                sum += st.d[c][0][k] * a[0][k] + st.d[c][1][k] * a[1][k];
            }
        }
        sum
    }

    /// y = S x on P (compact vectors, m²/s for x in Pa): C x + Δt D A⁻¹ Dᵀ x
    /// with x zero outside P. Two element↔node sweeps over P, no
    /// allocation; `force` is node-sized scratch (its content on return is
    /// unspecified). Symmetric, and positive definite where every element
    /// of P has n_e > 0 and K_L < ∞ (C > 0; D A⁻¹ Dᵀ is semidefinite).
    pub fn apply_operator(&self, x: &[f64], y: &mut [f64], force: &mut [NodeForce]) {
        self.check_indexed();
        assert!(x.len() == self.unknowns.len() && y.len() == x.len() && force.len() == self.mobility.len());
        Self::clear(&self.unknown_corners, force);
        Self::scatter(&self.unknown_stencils, |k| x[k], force);
        self.apply_mobility(&self.unknown_corners, force);
        for (k, st) in self.unknown_stencils.iter().enumerate() {
            y[k] = self.unknown_compressibility[k] * x[k] + self.dt * Self::divergence_of_mobility(st, force);
        }
    }

    /// The right-hand side on P (compact, m²/s): b = C p̄ − D v* − Δt D A⁻¹
    /// Dᵀ p_given, the last the given pressures' push moved over (design §1
    /// step 4). Pre: `vs`, `vl` the predictor velocities v*_S, v*_L (m/s)
    /// at every node, zero (or the wall's velocity) on fixed components,
    /// v*_S = v*_L at merged nodes ([`Self::merge_solid_into_liquid`]).
    pub fn right_hand_side(&self, vs: &[[f64; 2]], vl: &[[f64; 2]], b: &mut [f64], force: &mut [NodeForce]) {
        self.check_indexed();
        assert!(b.len() == self.unknowns.len() && force.len() == self.mobility.len());
        Self::clear(&self.listed_corners, force);
        Self::scatter(&self.given_stencils, |k| self.given_pressure[self.given[k] as usize], force);
        self.apply_mobility(&self.unknown_corners, force);
        for (k, (st, &e)) in self.unknown_stencils.iter().zip(&self.unknowns).enumerate() {
            b[k] = self.unknown_compressibility[k] * self.reference_pressure[e as usize]
                - Self::element_divergence(st, vs, vl)
                - self.dt * Self::divergence_of_mobility(st, force);
        }
    }

    /// The diagonal of S on P (compact): C_e + Δt Σ_I Σ_d D_eI,d A_I,d⁻¹ D_eI,dᵀ,
    /// the Jacobi preconditioner (design §3).
    pub fn diagonal(&self, out: &mut [f64]) {
        self.check_indexed();
        assert_eq!(out.len(), self.unknowns.len());
        for (k, st) in self.unknown_stencils.iter().enumerate() {
            let (nodes, d) = (&st.nodes, &st.d);
            let mut sum = 0.0;
            for c in 0..4 {
                for k in 0..2 {
                    sum += self.mobility[nodes[c]][k].quadratic([d[c][0][k], d[c][1][k]]);
                }
            }
            out[k] = self.unknown_compressibility[k] + self.dt * sum;
        }
    }

    /// The corrector v ← v + Δt A⁻¹ Dᵀ p (design §1 step 5, before damping
    /// and wall friction): `pressure` (Pa, full) is read on P, the given
    /// elements push with their given pressures. Fixed components and nodes
    /// without mass are left as they are; merged nodes get the same
    /// correction in both phases. Post, with `pressure` from
    /// [`PressureSolver::solve`]: (D v)_e + C_e (p_e − p̄_e) = (S p − b)_e on
    /// P, i.e. the continuity holds to the solver's residual.
    pub fn correct_velocities(
        &self,
        pressure: &[f64],
        vs: &mut [[f64; 2]],
        vl: &mut [[f64; 2]],
        force: &mut [NodeForce],
    ) {
        self.check_indexed();
        assert!(pressure.len() == self.porosity.len() && force.len() == self.mobility.len());
        Self::clear(&self.listed_corners, force);
        Self::scatter(&self.unknown_stencils, |k| pressure[self.unknowns[k] as usize], force);
        Self::scatter(&self.given_stencils, |k| self.given_pressure[self.given[k] as usize], force);
        self.apply_mobility(&self.listed_corners, force);
        for &node in &self.listed_corners {
            let (node, a) = (node as usize, &force[node as usize]);
            for k in 0..2 {
                vs[node][k] += self.dt * a[0][k];
                vl[node][k] += self.dt * a[1][k];
            }
        }
    }

    /// The continuity residual ‖(D v)_e + C_e (p_e − p̄_e)‖₂ over P, m²/s:
    /// the volume rate the step leaves unbalanced (0 for the exact
    /// solution), from velocities `vs`, `vl` (m/s) and pressures `pressure`
    /// (Pa, full). The diagnostic of design §2.
    pub fn continuity_residual(&self, vs: &[[f64; 2]], vl: &[[f64; 2]], pressure: &[f64]) -> f64 {
        self.check_indexed();
        let mut sum = 0.0;
        for (k, (st, &e)) in self.unknown_stencils.iter().zip(&self.unknowns).enumerate() {
            let e = e as usize;
            let r = Self::element_divergence(st, vs, vl)
                + self.unknown_compressibility[k] * (pressure[e] - self.reference_pressure[e]);
            sum += r * r;
        }
        sum.sqrt()
    }
}

/// What one [`PressureSolver::solve`] did.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SolveReport {
    /// CG iterations (operator applications less the two for the initial
    /// and the final residual).
    pub iterations: usize,
    /// ‖b − S p‖₂ / ‖b‖₂ recomputed from the returned p (0 for b = 0).
    pub relative_residual: f64,
    /// `relative_residual` ≤ the tolerance.
    pub converged: bool,
}

/// Jacobi-preconditioned conjugate gradients for [`PressureProblem`]
/// (design §3: ~10–15 iterations to 1e-8 at c_L Δt/h ≈ 0.76). The scratch
/// vectors are kept between solves and only grow: no allocation inside the
/// iterations, none at all once they have reached the largest P.
#[derive(Debug, Clone)]
pub struct PressureSolver {
    /// Stop at ‖b − S p‖₂ ≤ tolerance · ‖b‖₂.
    pub tolerance: f64,
    /// Iteration cap (a solve that reaches it returns its last iterate).
    pub max_iterations: usize,
    rhs: Vec<f64>,
    solution: Vec<f64>,
    residual: Vec<f64>,
    preconditioned: Vec<f64>,
    direction: Vec<f64>,
    image: Vec<f64>,
    inverse_diagonal: Vec<f64>,
    force: Vec<NodeForce>,
}

impl PressureSolver {
    /// A solver to relative residual `tolerance` in at most `max_iterations`.
    pub fn new(tolerance: f64, max_iterations: usize) -> Self {
        Self {
            tolerance,
            max_iterations,
            rhs: Vec::new(),
            solution: Vec::new(),
            residual: Vec::new(),
            preconditioned: Vec::new(),
            direction: Vec::new(),
            image: Vec::new(),
            inverse_diagonal: Vec::new(),
            force: Vec::new(),
        }
    }

    fn resize(&mut self, unknowns: usize, nodes: usize) {
        for v in [
            &mut self.rhs,
            &mut self.solution,
            &mut self.residual,
            &mut self.preconditioned,
            &mut self.direction,
            &mut self.image,
            &mut self.inverse_diagonal,
        ] {
            v.resize(unknowns, 0.0);
        }
        self.force.resize(nodes, [[0.0; 2]; 2]);
    }

    /// Solves S p = b of `problem` for the predictor velocities `vs`, `vl`
    /// (m/s; pre as [`PressureProblem::right_hand_side`]). `pressure` (Pa,
    /// one per element) is the initial guess on P (the last step's field
    /// or p̄ make a warm start; non-finite values count as 0); on return it
    /// holds the solution on P and the given pressure everywhere else.
    pub fn solve(
        &mut self,
        problem: &PressureProblem,
        vs: &[[f64; 2]],
        vl: &[[f64; 2]],
        pressure: &mut [f64],
    ) -> SolveReport {
        let unknowns = problem.unknowns();
        assert_eq!(pressure.len(), problem.porosity.len());
        for (e, p) in pressure.iter_mut().enumerate() {
            if !problem.unknown[e] {
                *p = problem.given_pressure[e];
            }
        }
        self.resize(unknowns.len(), problem.mobility.len());
        let done = |iterations, relative_residual: f64| SolveReport {
            iterations,
            relative_residual,
            converged: relative_residual <= self.tolerance,
        };
        if unknowns.is_empty() {
            return done(0, 0.0);
        }
        problem.right_hand_side(vs, vl, &mut self.rhs, &mut self.force);
        let rhs_norm = dot(&self.rhs, &self.rhs).sqrt();
        if rhs_norm == 0.0 {
            // S is nonsingular: b = 0 has p = 0 on P.
            for &e in unknowns {
                pressure[e as usize] = 0.0;
            }
            return done(0, 0.0);
        }
        problem.diagonal(&mut self.inverse_diagonal);
        for d in &mut self.inverse_diagonal {
            // A row without coupling or compressibility (every corner fixed,
            // K_L = ∞) is singular; leave it unscaled rather than divide by 0.
            *d = if *d > 0.0 { 1.0 / *d } else { 1.0 };
        }
        for (x, &e) in self.solution.iter_mut().zip(unknowns) {
            let p = pressure[e as usize];
            *x = if p.is_finite() { p } else { 0.0 };
        }
        problem.apply_operator(&self.solution, &mut self.image, &mut self.force);
        for k in 0..unknowns.len() {
            self.residual[k] = self.rhs[k] - self.image[k];
            self.preconditioned[k] = self.inverse_diagonal[k] * self.residual[k];
        }
        self.direction.copy_from_slice(&self.preconditioned);
        let mut rz = dot(&self.residual, &self.preconditioned);
        let target = self.tolerance * rhs_norm;
        let mut residual_norm = dot(&self.residual, &self.residual).sqrt();
        let mut iterations = 0;
        while residual_norm > target && iterations < self.max_iterations {
            problem.apply_operator(&self.direction, &mut self.image, &mut self.force);
            let curvature = dot(&self.direction, &self.image);
            if curvature.is_nan() || curvature <= 0.0 {
                break; // S not positive definite along d (or d = 0): nothing left to gain.
            }
            let alpha = rz / curvature;
            for k in 0..unknowns.len() {
                self.solution[k] += alpha * self.direction[k];
                self.residual[k] -= alpha * self.image[k];
                self.preconditioned[k] = self.inverse_diagonal[k] * self.residual[k];
            }
            let rz_next = dot(&self.residual, &self.preconditioned);
            let beta = rz_next / rz;
            rz = rz_next;
            for k in 0..unknowns.len() {
                self.direction[k] = self.preconditioned[k] + beta * self.direction[k];
            }
            residual_norm = dot(&self.residual, &self.residual).sqrt();
            iterations += 1;
        }
        // The recursive residual drifts from b − S p by round-off; report the true one.
        problem.apply_operator(&self.solution, &mut self.image, &mut self.force);
        let true_norm = self.rhs.iter().zip(&self.image).map(|(b, s)| (b - s) * (b - s)).sum::<f64>().sqrt();
        for (&x, &e) in self.solution.iter().zip(unknowns) {
            pressure[e as usize] = x;
        }
        done(iterations, true_norm / rhs_norm)
    }

    /// The corrector v ← v + Δt A⁻¹ Dᵀ p with this solver's scratch
    /// ([`PressureProblem::correct_velocities`]).
    pub fn correct(&mut self, problem: &PressureProblem, pressure: &[f64], vs: &mut [[f64; 2]], vl: &mut [[f64; 2]]) {
        self.force.resize(problem.mobility.len(), [[0.0; 2]; 2]);
        problem.correct_velocities(pressure, vs, vl, &mut self.force);
    }
}

fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

#[cfg(test)]
mod tests {
    use super::*;

    use crate::grid::GHOST;
    use schemas::scene::ShapeFunctions;

    const G: f64 = 9.81;

    /// Verruijt's example: water (2e9 Pa) with 1 % air at 100 kPa is 200×
    /// softer, 1/(0.99/2e9 + 0.01/1e5) = 9.951e6 Pa; the lab's K_L = 2e7 at
    /// S = 0.83 and one atmosphere: 5.82e5 Pa; saturated or over-full (a
    /// point-count F_e above 1): the water's own.
    #[test]
    fn a_little_air_makes_the_pore_fluid_soft() {
        let k = pore_fluid_modulus(0.99, 2e9, 1e5);
        assert!((k / 9.95074e6 - 1.0).abs() < 1e-5, "{k}");
        let k = pore_fluid_modulus(0.83, 2e7, 101_325.0);
        assert!((k / 5.816e5 - 1.0).abs() < 1e-3, "{k}");
        assert_eq!(pore_fluid_modulus(1.0, 2e7, 1e5), 2e7);
        assert_eq!(pore_fluid_modulus(1.07, 2e7, 1e5), 2e7);
    }

    /// SplitMix64: reproducible uniform numbers without a dependency.
    struct Random(u64);

    impl Random {
        fn uniform(&mut self) -> f64 {
            self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
            let mut z = self.0;
            z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
            z ^= z >> 31;
            (z >> 11) as f64 / (1u64 << 53) as f64
        }

        fn range(&mut self, a: f64, b: f64) -> f64 {
            a + (b - a) * self.uniform()
        }

        fn vectors(&mut self, n: usize, scale: f64) -> Vec<[f64; 2]> {
            (0..n).map(|_| [self.range(-scale, scale), self.range(-scale, scale)]).collect()
        }
    }

    fn grid(nx: usize, nz: usize) -> Grid {
        Grid { origin: [0.3, -0.2], h: 0.01, elements: [nx, nz], shape: ShapeFunctions::Linear }
    }

    fn is_ghost(grid: &Grid, node: usize) -> bool {
        let [row, rows] = grid.node_dims();
        let (c, r) = (node % row, node / row);
        c < GHOST || r < GHOST || c >= row - GHOST || r >= rows - GHOST
    }

    /// A problem with everything varied: nodes without solid (merged),
    /// without liquid, without mass; ΔtQ/M from 1e-3 to 1e3; fixed
    /// components; porosity 0.35–1 with gradients of up to 30 /m (Δn ≈ 0.3
    /// across an element); a quarter of the elements given, half of those
    /// at a non-zero pressure. Element area h² = 1e-4 m², masses ~ρh².
    fn random_problem(random: &mut Random, nx: usize, nz: usize, dt: f64, bulk_modulus: f64) -> PressureProblem {
        let grid = grid(nx, nz);
        let mut problem = PressureProblem::new(grid, dt, bulk_modulus);
        for node in 0..grid.node_count() {
            if is_ghost(&grid, node) {
                continue;
            }
            let mass_s = if random.uniform() < 0.25 { 0.0 } else { random.range(0.05, 0.3) };
            let mass_l = if random.uniform() < 0.1 { 0.0 } else { random.range(0.02, 0.15) };
            let drag = (mass_s + mass_l) * 10f64.powf(random.range(-3.0, 3.0)) / dt;
            let mut mask = [1.0; 2];
            for m in &mut mask {
                if random.uniform() < 0.15 {
                    *m = 0.0;
                }
            }
            problem.set_node(node, [mass_s, mass_l], drag, mask, 1e-9);
        }
        for e in 0..grid.element_count() {
            let role = if random.uniform() < 0.75 {
                ElementRole::Unknown
            } else if random.uniform() < 0.5 {
                ElementRole::Given(0.0)
            } else {
                ElementRole::Given(random.range(-500.0, 2000.0))
            };
            let (n, grad) = (random.range(0.35, 1.0), [random.range(-30.0, 30.0), random.range(-30.0, 30.0)]);
            problem.set_element(e, n, grad, random.range(-1e3, 5e3), role);
        }
        problem.index_elements();
        problem
    }

    /// Sets a random third of the nodes and elements of `problem` (some
    /// with a fluid modulus of their own), then indexes it.
    fn set_some(problem: &mut PressureProblem, random: &mut Random) {
        let grid = *problem.grid();
        for node in 0..grid.node_count() {
            if !is_ghost(&grid, node) && random.uniform() < 0.3 {
                let masses = [random.range(0.0, 0.3), random.range(0.0, 0.15)];
                let mask = [if random.uniform() < 0.2 { 0.0 } else { 1.0 }, 1.0];
                problem.set_node(node, masses, random.range(0.0, 1e3), mask, 0.01);
            }
        }
        for e in 0..grid.element_count() {
            if random.uniform() < 0.3 {
                let role = if random.uniform() < 0.7 {
                    ElementRole::Unknown
                } else {
                    ElementRole::Given(random.range(-500.0, 2000.0))
                };
                let grad = [random.range(-30.0, 30.0), random.range(-30.0, 30.0)];
                problem.set_element(e, random.range(0.35, 1.0), grad, random.range(-1e3, 5e3), role);
                if random.uniform() < 0.3 {
                    problem.set_fluid_modulus(e, random.range(1e5, 2e7));
                }
            }
        }
        problem.index_elements();
    }

    /// After a solve, the forces of the set elements over the node range
    /// their corners span are `pressure_forces`' bit for bit, and the
    /// nodes outside the range are left as they were.
    #[test]
    fn the_set_elements_forces_after_a_solve_are_the_full_ones() {
        let mut random = Random(5);
        let grid = grid(9, 6);
        let mut problem = PressureProblem::new(grid, 1e-4, 2e7);
        for _ in 0..3 {
            problem.reset(1e-4, 2e7);
            set_some(&mut problem, &mut random);
            let (vs, vl) = (random.vectors(grid.node_count(), 0.1), random.vectors(grid.node_count(), 0.1));
            // A stale field on every element, as the last step leaves it.
            let mut pressure: Vec<f64> = (0..grid.element_count()).map(|_| random.range(-1e3, 5e3)).collect();
            PressureSolver::new(1e-10, 500).solve(&problem, &vs, &vl, &mut pressure);
            let nodes = grid.node_count();
            let (mut fs, mut fl) = (vec![[0.0; 2]; nodes], vec![[0.0; 2]; nodes]);
            problem.pressure_forces(&pressure, &mut fs, &mut fl);
            let corners: Vec<usize> =
                problem.touched_elements.iter().flat_map(|&e| problem.divergence_coefficients(e as usize).0).collect();
            let range = *corners.iter().min().unwrap()..corners.iter().max().unwrap() + 1;
            let stale = [f64::NAN; 2];
            let (mut gs, mut gl) = (vec![stale; nodes], vec![stale; nodes]);
            problem.pressure_forces_of_set_elements(&pressure, range.clone(), &mut gs, &mut gl);
            for node in 0..nodes {
                if range.contains(&node) {
                    let bits = |f: [f64; 2]| f.map(f64::to_bits);
                    assert_eq!(bits(fs[node]), bits(gs[node]), "solid force at node {node}");
                    assert_eq!(bits(fl[node]), bits(gl[node]), "liquid force at node {node}");
                } else {
                    assert!(gs[node][0].is_nan() && gl[node][1].is_nan(), "node {node} outside the range written");
                    assert_eq!(fs[node], [0.0; 2], "a force at node {node}, outside the set elements' corners");
                }
            }
        }
    }

    /// `reset` restores only what was set since the last one; a problem
    /// reset after others (fluid moduli set, K_L changed and back) and set
    /// again must act exactly (bit for bit) as a fresh problem set the same
    /// way, in every operator and every per-element figure.
    #[test]
    fn a_reset_problem_acts_as_a_fresh_one() {
        let mut random = Random(41);
        let (dt, k) = (1e-4, 2e7);
        let mut reused = random_problem(&mut random, 9, 6, dt, k);
        reused.reset(dt, 0.5 * k);
        set_some(&mut reused, &mut Random(3));
        reused.reset(dt, k);
        set_some(&mut reused, &mut Random(5));
        // A modulus of its own on every element, set or not.
        for e in 0..reused.grid().element_count() {
            reused.set_fluid_modulus(e, 1e5);
        }
        reused.index_elements();
        reused.reset(dt, k);
        let grid = *reused.grid();
        let mut fresh = PressureProblem::new(grid, dt, k);
        set_some(&mut reused, &mut Random(7));
        set_some(&mut fresh, &mut Random(7));
        assert_eq!(reused.unknowns(), fresh.unknowns());
        assert_eq!(reused.given, fresh.given);
        assert!(!fresh.unknowns().is_empty() && !fresh.given.is_empty());
        let m = fresh.unknowns().len();
        let x: Vec<f64> = (0..m).map(|_| random.range(-1e4, 1e4)).collect();
        let full: Vec<f64> = (0..grid.element_count()).map(|_| random.range(-1e4, 1e4)).collect();
        let vs = random.vectors(grid.node_count(), 0.1);
        let vl = random.vectors(grid.node_count(), 0.1);
        let bits = |v: &[f64]| v.iter().map(|a| a.to_bits()).collect::<Vec<_>>();
        let flat = |v: &[[f64; 2]]| bits(&v.concat());
        let results = [&reused, &fresh].map(|problem| {
            let mut force = forces(problem);
            let (mut y, mut b, mut diagonal) = (vec![0.0; m], vec![0.0; m], vec![0.0; m]);
            problem.apply_operator(&x, &mut y, &mut force);
            problem.right_hand_side(&vs, &vl, &mut b, &mut force);
            problem.diagonal(&mut diagonal);
            let mut pressure = vec![0.0; grid.element_count()];
            for (&e, &p) in problem.unknowns().iter().zip(&x) {
                pressure[e as usize] = p;
            }
            let (mut cs, mut cl) = (vs.clone(), vl.clone());
            problem.merge_solid_into_liquid(&mut cs, &cl);
            problem.correct_velocities(&pressure, &mut cs, &mut cl, &mut force);
            let mut divergence = vec![0.0; grid.element_count()];
            problem.divergence(&vs, &vl, &mut divergence);
            let (mut fs, mut fl) = (vec![[0.0; 2]; grid.node_count()], vec![[0.0; 2]; grid.node_count()]);
            problem.pressure_forces(&full, &mut fs, &mut fl);
            let compressibility: Vec<f64> = (0..grid.element_count()).map(|e| problem.compressibility(e)).collect();
            let given: Vec<f64> = (0..grid.element_count()).map(|e| problem.given_pressure(e)).collect();
            let continuity = problem.continuity_residual(&vs, &vl, &pressure);
            (
                [bits(&y), bits(&b), bits(&diagonal), flat(&cs), flat(&cl)],
                [bits(&divergence), flat(&fs), flat(&fl), bits(&compressibility), bits(&given)],
                continuity.to_bits(),
            )
        });
        assert!(results[0] == results[1], "a reset problem differs from a fresh one");
    }

    fn forces(problem: &PressureProblem) -> Vec<NodeForce> {
        vec![[[0.0; 2]; 2]; problem.grid().node_count()]
    }

    /// The coefficients are those of a divergence: a rigid translation of
    /// the mixture has none, a linear field (x, z) in both phases has
    /// div = 2 whatever n, and the liquid alone moving as (x, z) gives
    /// A_e [2 n_e + x_c·∇n_e] (the drift term with the centroid's
    /// velocity). And a lone pressured element pushes its corners outward.
    #[test]
    fn the_divergence_of_known_fields() {
        let mut random = Random(7);
        let g = grid(4, 3);
        let mut problem = PressureProblem::new(g, 1e-4, 2e7);
        for e in 0..g.element_count() {
            let grad = [random.range(-30.0, 30.0), random.range(-30.0, 30.0)];
            problem.set_element(e, random.range(0.35, 1.0), grad, 0.0, ElementRole::Unknown);
        }
        problem.index_elements();
        let [row, _] = g.node_dims();
        let nodes = g.node_count();
        let area = g.h * g.h;
        let mut div = vec![0.0; g.element_count()];
        let position: Vec<[f64; 2]> = (0..nodes).map(|i| g.node_position(i % row, i / row)).collect();
        let zero = vec![[0.0; 2]; nodes];

        let translation = vec![[0.7, -1.3]; nodes];
        problem.divergence(&translation, &translation, &mut div);
        // Each term is ~A |v|/h·1e-16 = 1e-18 before cancelling.
        assert!(div.iter().all(|d| d.abs() < 1e-16), "{div:?}");

        problem.divergence(&position, &position, &mut div);
        for d in &div {
            assert!((d / (2.0 * area) - 1.0).abs() < 1e-12, "{d} vs {}", 2.0 * area);
        }

        problem.divergence(&zero, &position, &mut div);
        for (e, d) in div.iter().enumerate() {
            let corner = g.element_corner(e);
            let c = [position[corner][0] + 0.5 * g.h, position[corner][1] + 0.5 * g.h];
            let (n, gn) = (problem.porosity[e], problem.grad_porosity[e]);
            let expected = area * (2.0 * n + c[0] * gn[0] + c[1] * gn[1]);
            assert!((d - expected).abs() < 1e-12 * expected.abs().max(area), "element {e}: {d} vs {expected}");
        }

        // p = 1000 Pa in element 0 alone: the mixture force on its lower-left
        // corner is p A ∇N = p h²(−1, −1)/(2h) = (−5, −5) mN/m.
        let mut pressure = vec![0.0; g.element_count()];
        pressure[0] = 1000.0;
        let (mut fs, mut fl) = (vec![[0.0; 2]; nodes], vec![[0.0; 2]; nodes]);
        problem.pressure_forces(&pressure, &mut fs, &mut fl);
        let corner = g.element_corner(0);
        for k in 0..2 {
            let mixture = fs[corner][k] + fl[corner][k];
            assert!((mixture + 1000.0 * g.h / 2.0).abs() < 1e-15, "{mixture}");
        }
    }

    /// ⟨Dᵀx, y⟩ = ⟨x, D y⟩ for random element pressures and random nodal
    /// velocities of both phases: the pressure force is the exact transpose
    /// of the divergence (design, "Proposal"). Relative to the sum of the
    /// magnitudes of the terms, round-off is ~1e-16 per term.
    #[test]
    fn the_pressure_force_is_the_transpose_of_the_divergence() {
        let mut random = Random(11);
        for _ in 0..5 {
            let problem = random_problem(&mut random, 7, 5, 1e-4, 2e7);
            let g = *problem.grid();
            let x: Vec<f64> = (0..g.element_count()).map(|_| random.range(-1e4, 1e4)).collect();
            let (ys, yl) = (random.vectors(g.node_count(), 1.0), random.vectors(g.node_count(), 1.0));
            let mut div = vec![0.0; g.element_count()];
            problem.divergence(&ys, &yl, &mut div);
            let (mut fs, mut fl) = (vec![[0.0; 2]; g.node_count()], vec![[0.0; 2]; g.node_count()]);
            problem.pressure_forces(&x, &mut fs, &mut fl);
            let left: f64 = (0..g.node_count())
                .map(|i| fs[i][0] * ys[i][0] + fs[i][1] * ys[i][1] + fl[i][0] * yl[i][0] + fl[i][1] * yl[i][1])
                .sum();
            let right: f64 = x.iter().zip(&div).map(|(p, d)| p * d).sum();
            let mut scale = 0.0;
            for e in 0..g.element_count() {
                let (nodes, d) = problem.divergence_coefficients(e);
                for c in 0..4 {
                    for k in 0..2 {
                        scale +=
                            x[e].abs() * ((d[c][0][k] * ys[nodes[c]][k]).abs() + (d[c][1][k] * yl[nodes[c]][k]).abs());
                    }
                }
            }
            assert!((left - right).abs() <= 1e-13 * scale, "{left} vs {right} (scale {scale})");
        }
    }

    /// S is symmetric, ⟨S x, x⟩ = ⟨C x, x⟩ + Δt Σ_I fᵀ A_I⁻¹ f (f = Dᵀx)
    /// ≥ ⟨C x, x⟩ > 0, and `diagonal` is its diagonal. Random problems
    /// with merged, solid-only and fixed nodes.
    #[test]
    fn the_operator_is_symmetric_positive_definite() {
        let mut random = Random(23);
        for _ in 0..5 {
            let problem = random_problem(&mut random, 7, 5, 1e-4, 2e7);
            let g = *problem.grid();
            let m = problem.unknowns().len();
            let x: Vec<f64> = (0..m).map(|_| random.range(-1e4, 1e4)).collect();
            let y: Vec<f64> = (0..m).map(|_| random.range(-1e4, 1e4)).collect();
            let (mut sx, mut sy) = (vec![0.0; m], vec![0.0; m]);
            let mut force = forces(&problem);
            problem.apply_operator(&x, &mut sx, &mut force);
            problem.apply_operator(&y, &mut sy, &mut force);
            let (sxy, xsy) = (dot(&sx, &y), dot(&x, &sy));
            let scale = (dot(&sx, &sx) * dot(&y, &y)).sqrt();
            assert!((sxy - xsy).abs() <= 1e-13 * scale, "⟨Sx,y⟩ {sxy} vs ⟨x,Sy⟩ {xsy}");

            // The energy split: C part and the nodal quadratic forms of Dᵀx.
            let mut full = vec![0.0; g.element_count()];
            for (k, &e) in problem.unknowns().iter().enumerate() {
                full[e as usize] = x[k];
            }
            let (mut fs, mut fl) = (vec![[0.0; 2]; g.node_count()], vec![[0.0; 2]; g.node_count()]);
            problem.pressure_forces(&full, &mut fs, &mut fl);
            let compressive: f64 =
                problem.unknowns().iter().zip(&x).map(|(&e, x)| problem.compressibility(e as usize) * x * x).sum();
            let kinetic: f64 = (0..g.node_count())
                .map(|i| (0..2).map(|k| problem.mobility(i, k).quadratic([fs[i][k], fl[i][k]])).sum::<f64>())
                .sum::<f64>()
                * problem.dt();
            let sxx = dot(&sx, &x);
            assert!(compressive > 0.0 && kinetic > 0.0);
            assert!(sxx >= compressive, "{sxx} < {compressive}");
            assert!((sxx - (compressive + kinetic)).abs() <= 1e-12 * sxx, "{sxx} vs {}", compressive + kinetic);

            let mut diagonal = vec![0.0; m];
            problem.diagonal(&mut diagonal);
            let (mut unit, mut column) = (vec![0.0; m], vec![0.0; m]);
            for k in 0..m {
                unit[k] = 1.0;
                problem.apply_operator(&unit, &mut column, &mut force);
                unit[k] = 0.0;
                assert!((column[k] - diagonal[k]).abs() <= 1e-13 * diagonal[k], "{} vs {}", column[k], diagonal[k]);
            }
        }
    }

    /// Design §1 step 4: A⁻¹ inverts A = [[M_S + ΔtQ, −ΔtQ], [−ΔtQ,
    /// M_L + ΔtQ]]; Q → 0 gives diag(1/M_S, 1/M_L); ΔtQ ≫ M gives 1/M
    /// (M = M_S + M_L) in every entry, off by at most M/(ΔtQ) relative, and
    /// its first-order term is the Darcy matrix of `Mobility::predictor`.
    /// It also moves the nodal velocities exactly as the explicit solver's
    /// `coupled_accelerations` (its formula copied here: it is private).
    #[test]
    fn the_mobility_and_its_limits() {
        let (ms, ml, dt, tol) = (0.265, 0.1, 1e-4, 1e-9);
        let m = ms + ml;
        let rel = |a: f64, b: f64| (a - b).abs() / b.abs();

        let b = Mobility::predictor([ms, ml], 0.0, dt, tol);
        assert_eq!((b.solid, b.coupling, b.liquid), (1.0 / ms, 0.0, 1.0 / ml));
        let b = Mobility::predictor([ms, ml], 1e-9 * m / dt, dt, tol);
        assert!(rel(b.solid, 1.0 / ms) < 1e-8 && rel(b.liquid, 1.0 / ml) < 1e-8 && b.coupling * m < 1e-8);

        let dq = 1e8 * m;
        let b = Mobility::predictor([ms, ml], dq / dt, dt, tol);
        for entry in [b.solid, b.coupling, b.liquid] {
            assert!(rel(entry, 1.0 / m) <= m / dq, "{entry} vs {}", 1.0 / m);
        }
        // ΔtQ (A⁻¹ − 1/M) → [[M_L², −M_S M_L], [−M_S M_L, M_S²]]/M², error O(M/ΔtQ) = 1e-6.
        let dq = 1e6 * m;
        let b = Mobility::predictor([ms, ml], dq / dt, dt, tol);
        let darcy = [ml * ml / (m * m), -ms * ml / (m * m), ms * ms / (m * m)];
        for (entry, expected) in [b.solid, b.coupling, b.liquid].into_iter().zip(darcy) {
            assert!(rel(dq * (entry - 1.0 / m), expected) < 1e-5, "{} vs {expected}", dq * (entry - 1.0 / m));
        }

        for dq in [1e-3 * m, 0.7 * m, 40.0 * m] {
            let q = dq / dt;
            let b = Mobility::predictor([ms, ml], q, dt, tol);
            let a = [[ms + dq, -dq], [-dq, ml + dq]];
            let inv = [[b.solid, b.coupling], [b.coupling, b.liquid]];
            for i in 0..2 {
                for j in 0..2 {
                    let product = a[i][0] * inv[0][j] + a[i][1] * inv[1][j];
                    let identity = if i == j { 1.0 } else { 0.0 };
                    assert!((product - identity).abs() < 1e-14, "A·A⁻¹[{i}][{j}] = {product}");
                }
            }
            // solver.rs's coupled_accelerations, for forces f and start velocities v.
            let (f, v) = ([0.3, -0.8], [0.02, -0.05]);
            let w1 = (v[1] - v[0] + dt * (f[1] / ml - f[0] / ms)) / (1.0 + dt * q * (1.0 / ml + 1.0 / ms));
            let explicit = [v[0] + dt * (f[0] + q * w1) / ms, v[1] + dt * (f[1] - q * w1) / ml];
            // Here: v_new = A⁻¹ (M v + Δt f).
            let mine = b.apply([ms * v[0] + dt * f[0], ml * v[1] + dt * f[1]]);
            for k in 0..2 {
                assert!((mine[k] - explicit[k]).abs() < 1e-15, "{mine:?} vs {explicit:?}");
            }
        }

        // No solid: merged, 1/M_L everywhere (= the lock-in limit); no liquid:
        // the solid alone; fixed: nothing.
        let b = Mobility::predictor([0.0, ml], 5.0, dt, tol);
        assert_eq!((b.solid, b.coupling, b.liquid), (1.0 / ml, 1.0 / ml, 1.0 / ml));
        let b = Mobility::predictor([ms, 0.0], 5.0, dt, tol);
        assert_eq!((b.solid, b.coupling, b.liquid), (1.0 / ms, 0.0, 0.0));
        assert_eq!(Mobility::predictor([ms, ml], 5.0, dt, tol).masked(0.0), Mobility::default());
    }

    /// S assembled column by column and solved densely (nalgebra's
    /// Cholesky) against the PCG: the error is bounded by κ(S) times the
    /// returned relative residual. After the corrector the continuity
    /// residual is S p − b, so it is bounded by the same residual; fixed
    /// components keep v*, merged nodes keep v_S = v_L. A warm restart from
    /// the solution takes no iteration, and a second solve reuses the
    /// scratch (same buffers, no reallocation).
    #[test]
    fn the_conjugate_gradients_solve_the_pressure_equation() {
        let mut random = Random(31);
        let mut solver = PressureSolver::new(1e-11, 500);
        // The paper's K_L, water's, and near the incompressible limit (κ(S) stays
        // ~10–30: the scattered given elements pin the pressure everywhere).
        for (round, bulk_modulus) in [2e7, 2.2e9, 1e12].into_iter().enumerate() {
            let problem = random_problem(&mut random, 8, 6, 1e-4, bulk_modulus);
            let g = *problem.grid();
            let (ne, nodes) = (g.element_count(), g.node_count());
            let m = problem.unknowns().len();
            let vl = random.vectors(nodes, 0.05);
            let mut vs = random.vectors(nodes, 0.05);
            problem.merge_solid_into_liquid(&mut vs, &vl);
            // Fixed components at rest, as the predictor leaves them.
            let (mut vs, mut vl) = (vs, vl);
            for i in 0..nodes {
                for k in 0..2 {
                    if problem.mobility(i, k) == Mobility::default() {
                        vs[i][k] = 0.0;
                        vl[i][k] = 0.0;
                    }
                }
            }
            let mut pressure = vec![0.0; ne];
            let report = solver.solve(&problem, &vs, &vl, &mut pressure);
            assert!(report.converged && report.relative_residual <= 1e-11, "{report:?}");
            assert!(report.iterations <= m, "{report:?} for {m} unknowns");

            let mut force = forces(&problem);
            let mut dense = nalgebra::DMatrix::zeros(m, m);
            let (mut unit, mut column) = (vec![0.0; m], vec![0.0; m]);
            for k in 0..m {
                unit[k] = 1.0;
                problem.apply_operator(&unit, &mut column, &mut force);
                unit[k] = 0.0;
                dense.set_column(k, &nalgebra::DVector::from_column_slice(&column));
            }
            let mut b = vec![0.0; m];
            problem.right_hand_side(&vs, &vl, &mut b, &mut force);
            let eigen = dense.clone().symmetric_eigenvalues();
            let kappa = eigen.max() / eigen.min();
            assert!(eigen.min() > 0.0);
            let exact = dense.cholesky().expect("S is SPD").solve(&nalgebra::DVector::from_column_slice(&b));
            let p: Vec<f64> = problem.unknowns().iter().map(|&e| pressure[e as usize]).collect();
            let error = p.iter().zip(exact.iter()).map(|(a, b)| (a - b) * (a - b)).sum::<f64>().sqrt();
            let bound = (kappa * report.relative_residual + 1e-12) * exact.norm();
            assert!(error <= bound, "round {round}: |p − p_dense| {error} > {bound} (κ {kappa:.3e})");
            for e in 0..ne {
                if !problem.is_unknown(e) {
                    assert_eq!(pressure[e], problem.given_pressure(e));
                }
            }

            let (vs0, vl0) = (vs.clone(), vl.clone());
            solver.correct(&problem, &pressure, &mut vs, &mut vl);
            let residual = problem.continuity_residual(&vs, &vl, &pressure);
            let b_norm = dot(&b, &b).sqrt();
            assert!(residual <= (report.relative_residual + 1e-12) * b_norm, "{residual} vs |b| {b_norm}");
            for i in 0..nodes {
                for k in 0..2 {
                    if problem.mobility(i, k) == Mobility::default() {
                        assert_eq!((vs[i][k], vl[i][k]), (vs0[i][k], vl0[i][k]));
                    }
                    if problem.merged[i] {
                        assert_eq!(vs[i][k], vl[i][k]);
                    }
                }
            }

            let buffers = (solver.residual.as_ptr(), solver.force.as_ptr());
            let again = solver.solve(&problem, &vs0, &vl0, &mut pressure);
            assert_eq!(again.iterations, 0, "{again:?}");
            assert_eq!(buffers, (solver.residual.as_ptr(), solver.force.as_ptr()));
        }
    }

    /// Design §3: at the paper's K_L = 2e7 Pa with c_L Δt/h = 0.76 (water,
    /// h = 1 cm), Jacobi-PCG reaches 1e-8 in "~10–15" iterations. A 20 × 10
    /// tank of water with random predictor velocities, walls on three
    /// sides, free top: the bound 25 leaves room for the estimate's
    /// roughness but catches a broken preconditioner or operator (plain CG
    /// on an ill-scaled S needs the unknown count).
    #[test]
    fn few_iterations_at_the_papers_bulk_modulus() {
        let (rho, k_l, h): (f64, f64, f64) = (1000.0, 2e7, 0.01);
        let dt = 0.76 * h / (k_l / rho).sqrt();
        let tank = column(20, 10, Column { dt, bulk_modulus: k_l, porosity: 1.0, solid: 0.0, rho_l: rho, drag: 0.0 });
        let mut random = Random(5);
        let (problem, g) = (&tank.problem, tank.problem.grid());
        let mut vs = random.vectors(g.node_count(), 0.05);
        let mut vl = vs.clone();
        tank.fix(&mut vs, &mut vl);
        let mut pressure = vec![0.0; g.element_count()];
        let report = PressureSolver::new(1e-8, 500).solve(problem, &vs, &vl, &mut pressure);
        assert!(report.converged && report.iterations <= 25, "{report:?}");
    }

    #[derive(Clone, Copy)]
    struct Column {
        dt: f64,
        bulk_modulus: f64,
        porosity: f64,
        /// Grain density ρ_s (0: no solid), kg/m³.
        solid: f64,
        rho_l: f64,
        /// ΔtQ / (M_S + M_L) at every node.
        drag: f64,
    }

    struct ColumnProblem {
        problem: PressureProblem,
        /// The nodes whose mask is zero per component.
        fixed: Vec<[bool; 2]>,
    }

    impl ColumnProblem {
        fn fix(&self, vs: &mut [[f64; 2]], vl: &mut [[f64; 2]]) {
            for (i, f) in self.fixed.iter().enumerate() {
                for k in 0..2 {
                    if f[k] {
                        vs[i][k] = 0.0;
                        vl[i][k] = 0.0;
                    }
                }
            }
        }
    }

    /// nx × nz saturated elements of porosity n, uniform (∇n = 0), in a box
    /// with smooth side walls (x fixed) and a floor (z fixed), top free.
    /// Nodal masses lumped from the elements: ρ A_e/4 per corner and phase
    /// (ρ_s (1 − n), ρ_L n). Every element pressured, p̄ = 0.
    fn column(nx: usize, nz: usize, c: Column) -> ColumnProblem {
        let g = Grid { origin: [0.0, 0.0], h: 0.01, elements: [nx, nz], shape: ShapeFunctions::Linear };
        let mut problem = PressureProblem::new(g, c.dt, c.bulk_modulus);
        let [row, _] = g.node_dims();
        let area = g.h * g.h;
        let mut masses = vec![[0.0; 2]; g.node_count()];
        for e in 0..g.element_count() {
            let n0 = g.element_corner(e);
            for node in [n0, n0 + 1, n0 + row, n0 + row + 1] {
                masses[node][0] += 0.25 * area * (1.0 - c.porosity) * c.solid;
                masses[node][1] += 0.25 * area * c.porosity * c.rho_l;
            }
            problem.set_element(e, c.porosity, [0.0; 2], 0.0, ElementRole::Unknown);
        }
        problem.index_elements();
        let mut fixed = vec![[false; 2]; g.node_count()];
        for node in 0..g.node_count() {
            let (col, r) = (node % row, node / row);
            let ghost = is_ghost(&g, node);
            let wall_x = ghost || col == GHOST || col == GHOST + nx;
            let floor = ghost || r == GHOST;
            fixed[node] = [wall_x, floor];
            let m = masses[node][0] + masses[node][1];
            let mask = [if wall_x { 0.0 } else { 1.0 }, if floor { 0.0 } else { 1.0 }];
            problem.set_node(node, masses[node], c.drag * m / c.dt, mask, 1e-12);
        }
        ColumnProblem { problem, fixed }
    }

    /// Predictor at rest under gravity: v* = Δt g in both phases, 0 on
    /// fixed components; solve (p̄ as given) and correct. Returns the
    /// element pressures and the corrected velocities.
    fn settle(column: &ColumnProblem, reference: Option<&[f64]>) -> (Vec<f64>, Vec<[f64; 2]>, Vec<[f64; 2]>) {
        let mut problem = column.problem.clone();
        let g = *problem.grid();
        if let Some(p_bar) = reference {
            for e in 0..g.element_count() {
                problem.set_element(e, problem.porosity[e], [0.0; 2], p_bar[e], ElementRole::Unknown);
            }
            problem.index_elements();
        }
        let dt = problem.dt();
        let mut vs = vec![[0.0, -G * dt]; g.node_count()];
        let mut vl = vs.clone();
        column.fix(&mut vs, &mut vl);
        problem.merge_solid_into_liquid(&mut vs, &vl);
        let mut pressure = vec![0.0; g.element_count()];
        let mut solver = PressureSolver::new(1e-13, 1000);
        let report = solver.solve(&problem, &vs, &vl, &mut pressure);
        assert!(report.converged, "{report:?}");
        solver.correct(&problem, &pressure, &mut vs, &mut vl);
        (pressure, vs, vl)
    }

    /// The pressure ρ g (H − z_c) at each element centre, H the column's height.
    fn hydrostatic(g: &Grid, density: f64) -> Vec<f64> {
        let nx = g.elements[0];
        let height = g.elements[1] as f64 * g.h;
        (0..g.element_count()).map(|e| density * G * (height - ((e / nx) as f64 + 0.5) * g.h)).collect()
    }

    fn max_relative_error(a: &[f64], b: &[f64]) -> f64 {
        a.iter().zip(b).map(|(x, y)| ((x - y) / y).abs()).fold(0.0, f64::max)
    }

    /// A pure water column (n = 1, no solid: every node merged) starting at
    /// rest: the predictor v* = Δt g, the step's pressure stops it. With
    /// Q1 velocities and P0 pressures the discrete balance row by row is
    /// h (p_{k−1} − p_k) = ρ h² g and h p_top = ρ (h²/2) g at the free top
    /// row, so p_e = ρ_L g × the depth of the centroid holds exactly at the
    /// centroids (the design's hydrostatic test, top element ρ g h/2), in
    /// the incompressible limit. K_L = 1e16 Pa: the compressible
    /// deviation is C/λ_min(ΔtDA⁻¹Dᵀ) ≈ (h²/(K_L Δt))/(Δt/ρ·(π/2N)²) ≈
    /// 3e-8 here, so 1e-6 on p (the design's bar is 1 %) and a corrected
    /// speed below 1e-6 of Δt g.
    ///
    /// Second, the water's own K_L = 2.2e9 Pa from p̄ = hydrostatic (the
    /// column already at rest under its pressure): that p̄ is the exact
    /// fixed point (v* + Δt A⁻¹Dᵀp̄ = 0, so D v = 0 and p = p̄), kept to
    /// the solver tolerance.
    #[test]
    fn a_water_column_comes_to_hydrostatic_rest() {
        let dt = 1e-4;
        let water = Column { dt, bulk_modulus: 1e16, porosity: 1.0, solid: 0.0, rho_l: 1000.0, drag: 0.0 };
        let c = column(3, 8, water);
        let g = *c.problem.grid();
        let expected = hydrostatic(&g, 1000.0);
        let (p, vs, vl) = settle(&c, None);
        let error = max_relative_error(&p, &expected);
        assert!(error < 1e-6, "p {p:?} vs {expected:?}: {error:.2e}");
        let speed = vs.iter().chain(&vl).map(|v| v[0].hypot(v[1])).fold(0.0, f64::max);
        assert!(speed < 1e-6 * G * dt, "{speed} m/s");

        let c = column(3, 8, Column { bulk_modulus: 2.2e9, ..water });
        let (p, vs, vl) = settle(&c, Some(&expected));
        assert!(max_relative_error(&p, &expected) < 1e-10, "{p:?}");
        let speed = vs.iter().chain(&vl).map(|v| v[0].hypot(v[1])).fold(0.0, f64::max);
        assert!(speed < 1e-10 * G * dt, "{speed} m/s");
    }

    /// A saturated column, n = 0.4, ρ_s = 2650, ρ_L = 1000 kg/m³, no
    /// effective stress in the predictor (v* = Δt g for both phases), K_L =
    /// 1e16 Pa: which density the step's pressure carries depends on the
    /// drag, and both ends are exact at the centroids (as the water column):
    ///
    /// - ΔtQ = 1e8 M: the phases locked, the pressure stops the mixture:
    ///   p = ρ_mix g depth, ρ_mix = (1 − n) ρ_s + n ρ_L = 1990 kg/m³, and
    ///   both phases at rest (relative velocity O(M/ΔtQ) Δt g).
    /// - Q = 0: each phase is pushed alone by its share, (1 − n) and n, of
    ///   the pressure gradient, and only the mixture flux (1 − n) v_S + n v_L
    ///   is stopped: ∂p/∂z = −g / ((1 − n)/ρ_s + n/ρ_L) (CB-Geo's
    ///   Laplacian coefficient, design §1 step 4), ρ = 1596.4 kg/m³; the
    ///   grains sink at Δt g (1 − ρ/ρ_s), the water rises at
    ///   Δt g (ρ/ρ_L − 1).
    ///
    /// Neither is the hydrostatic ρ_L g depth of a consolidated bed: there
    /// the skeleton's effective stress carries the buoyant weight in the
    /// predictor, which this test leaves out on purpose.
    #[test]
    fn a_saturated_column_carries_the_mixture_or_the_split_weight() {
        let (n, rho_s, rho_l, dt) = (0.4, 2650.0, 1000.0, 1e-4);
        let base = Column { dt, bulk_modulus: 1e16, porosity: n, solid: rho_s, rho_l, drag: 1e8 };
        let rel = |a: f64, b: f64| (a - b).abs() / b.abs();

        let c = column(3, 8, base);
        let g = *c.problem.grid();
        let rho_mix = (1.0 - n) * rho_s + n * rho_l;
        let (p, vs, vl) = settle(&c, None);
        let error = max_relative_error(&p, &hydrostatic(&g, rho_mix));
        assert!(error < 1e-6, "locked: {error:.2e}");
        let speed = vs.iter().chain(&vl).map(|v| v[0].hypot(v[1])).fold(0.0, f64::max);
        assert!(speed < 1e-6 * G * dt, "locked: {speed} m/s");

        let c = column(3, 8, Column { drag: 0.0, ..base });
        let rho_split = 1.0 / ((1.0 - n) / rho_s + n / rho_l);
        let (p, vs, vl) = settle(&c, None);
        let error = max_relative_error(&p, &hydrostatic(&g, rho_split));
        assert!(error < 1e-6, "free: {error:.2e} (ρ = {rho_split})");
        let [row, _] = g.node_dims();
        for node in 0..g.node_count() {
            if c.fixed[node][1] {
                continue;
            }
            let (sink, rise) = (-G * dt * (1.0 - rho_split / rho_s), G * dt * (rho_split / rho_l - 1.0));
            assert!(rel(vs[node][1], sink) < 1e-6 && rel(vl[node][1], rise) < 1e-6, "node {node} (row {row})");
            let flux = (1.0 - n) * vs[node][1] + n * vl[node][1];
            assert!(flux.abs() < 1e-6 * G * dt, "mixture flux {flux}");
        }
    }
}
