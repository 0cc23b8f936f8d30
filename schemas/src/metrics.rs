//! Plottable metric messages (protobuf via `foxglove::Encode`).

/// `/dem/metrics`, one per recorded frame.
#[derive(Debug, Clone, Copy, Default, foxglove::Encode)]
pub struct DemMetrics {
    /// Simulated time since the start of the run, s.
    pub t: f64,
    /// t / t_ref.
    pub t_norm: f64,
    /// Solid front X_f, m.
    pub front_x: f64,
    /// (X_f − L0)/L0.
    pub front_norm: f64,
    /// Translational + rotational kinetic energy, J.
    pub kinetic_energy: f64,
    /// Largest grain speed, m/s.
    pub max_speed: f64,
    /// Mean grain–grain contacts per grain.
    pub mean_coordination: f64,
    /// Throughput since the last frame.
    pub particle_steps_per_s: f64,
    /// Front of the grains in contact with another grain, m, and normalised.
    pub front_connected_x: f64,
    pub front_connected_norm: f64,
    /// Fraction of grains with 0, 1, … 5 and ≥ 6 grain–grain contacts (paper Fig. 7).
    pub coordination_0: f64,
    pub coordination_1: f64,
    pub coordination_2: f64,
    pub coordination_3: f64,
    pub coordination_4: f64,
    pub coordination_5: f64,
    pub coordination_6_or_more: f64,
}

/// `/lbm/metrics`, one per recorded frame.
#[derive(Debug, Clone, Copy, Default, foxglove::Encode)]
pub struct LbmMetrics {
    /// Simulated time since the start of the run, s.
    pub t: f64,
    /// t / t_ref.
    pub t_norm: f64,
    /// Liquid mass (fluid cells + interface-cell masses + pending excess), kg.
    pub liquid_mass: f64,
    /// (mass − initial mass)/initial mass: zero to round-off when mass is conserved.
    pub liquid_mass_change: f64,
    /// Kinetic energy of the liquid, J.
    pub kinetic_energy: f64,
    /// Liquid front X_f (0.5 % of the liquid mass beyond it), m.
    pub liquid_front_x: f64,
    /// (X_f − L0)/L0.
    pub liquid_front_norm: f64,
    /// Largest liquid speed, m/s.
    pub max_speed: f64,
    /// Largest |u|/c_s in lattice units (the watchdog's quantity).
    pub max_mach: f64,
    /// Cells updated per step (fluid + interface).
    pub active_cells: f64,
    /// Interface cells.
    pub interface_cells: f64,
    /// Throughput since the last frame, million lattice updates per second (active cells).
    pub mlups: f64,
    /// Liquid mass held as excess that found no receiving cell (emptied
    /// droplets with no liquid neighbour), kg; part of `liquid_mass`.
    pub pending_mass: f64,
}

/// `/mpm/metrics`, one per recorded frame. Energies and masses are per
/// metre of out-of-plane width (the MPM is plane strain).
#[derive(Debug, Clone, Copy, Default, foxglove::Encode)]
pub struct MpmMetrics {
    /// Simulated time since the start of the run, s.
    pub t: f64,
    /// t / t_ref.
    pub t_norm: f64,
    /// Solid front X_f (0.5 % of the solid mass beyond it), m, and (X_f − L0)/L0.
    pub front_x: f64,
    pub front_norm: f64,
    /// Liquid front, m, and normalised.
    pub liquid_front_x: f64,
    pub liquid_front_norm: f64,
    /// Kinetic energy of the solid and of the liquid points, J/m.
    pub kinetic_energy_solid: f64,
    pub kinetic_energy_liquid: f64,
    /// Largest point speed of each phase, m/s.
    pub max_speed_solid: f64,
    pub max_speed_liquid: f64,
    /// Mass fraction of the solid points that are fluidised (n > n_max).
    pub fluidised_fraction: f64,
    /// Largest pore pressure, Pa, and mean porosity of the solid points.
    pub max_pore_pressure: f64,
    pub mean_porosity: f64,
    /// Solid and liquid mass, kg/m: constant (points carry fixed masses).
    pub solid_mass: f64,
    pub liquid_mass: f64,
    /// Material-point updates per second since the last frame (both phases).
    pub point_updates_per_s: f64,
}
