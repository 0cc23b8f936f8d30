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
    /// Σ m v of the grains along x and z, kg m/s.
    pub momentum_x: f64,
    pub momentum_z: f64,
    /// Σ of the hydrodynamic loads the grains hold now along x and z, N
    /// (zero in a dry run; buoyancy included).
    pub fluid_force_x: f64,
    pub fluid_force_z: f64,
    /// ∫ of that sum over time since the run started, N s: the momentum the
    /// liquid has given the grains.
    pub fluid_impulse_x: f64,
    pub fluid_impulse_z: f64,
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

/// `/dem/coupling` and `/lbm/coupling`: where a coupled process's wall time
/// went since the previous frame, one per recorded frame.
#[derive(Debug, Clone, Copy, Default, foxglove::Encode)]
pub struct CouplingTimings {
    /// Simulated time, s.
    pub t: f64,
    /// Exchanges done since the start of the run.
    pub exchanges: f64,
    /// Exchanges since the previous frame.
    pub frame_exchanges: f64,
    /// Wall seconds since the previous frame.
    pub frame_seconds: f64,
    /// Of those, seconds spent sending to and waiting for the peer (its work
    /// on a sequential schedule, plus the transport).
    pub wait_seconds: f64,
    /// Of those, seconds of the coupling kernel (LBM: covering, forcing and
    /// force sums; DEM: 0).
    pub coupling_seconds: f64,
    /// wait_seconds / frame_seconds.
    pub wait_fraction: f64,
    /// Wall milliseconds per exchange over the frame.
    pub exchange_ms: f64,
}

impl CouplingTimings {
    /// The frame from cumulative counters now and at the previous frame:
    /// (exchanges, wall seconds, wait seconds, coupling seconds).
    pub fn between(t: f64, now: [f64; 4], before: [f64; 4]) -> Self {
        let [exchanges, frame_exchanges, frame_seconds, wait_seconds, coupling_seconds] =
            [now[0], now[0] - before[0], now[1] - before[1], now[2] - before[2], now[3] - before[3]];
        CouplingTimings {
            t,
            exchanges,
            frame_exchanges,
            frame_seconds,
            wait_seconds,
            coupling_seconds,
            wait_fraction: if frame_seconds > 0.0 { wait_seconds / frame_seconds } else { 0.0 },
            exchange_ms: if frame_exchanges > 0.0 { 1e3 * frame_seconds / frame_exchanges } else { 0.0 },
        }
    }
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
    /// Largest pore pressure of any liquid point at the end of any step
    /// since the previous frame, Pa: pulses two or three steps long (cell
    /// crossings, a drained element refilling) fall between frames and
    /// show here only.
    pub peak_pore_pressure: f64,
    /// Solid and liquid mass, kg/m: constant (points carry fixed masses).
    pub solid_mass: f64,
    pub liquid_mass: f64,
    /// Material-point updates per second since the last frame (both phases).
    pub point_updates_per_s: f64,
    /// Kinetic energy of the solid and liquid momenta mapped to the grid at
    /// the start of the last step, J/m: the part of the points' kinetic
    /// energy the grid carries; the rest is invisible to it.
    pub kinetic_energy_solid_grid: f64,
    pub kinetic_energy_liquid_grid: f64,
    /// Gravitational potential energy of the solid and of the liquid
    /// points, −Σ m g·x, J/m (x from the domain's origin): the energy
    /// released by the collapse is its fall from the first frame.
    pub potential_energy_solid: f64,
    pub potential_energy_liquid: f64,
    /// Over the frictional walls' nodes in the last step (`mpm.floor =
    /// "frictional"`, `mpm.wall_friction` > 0): the grains' normal load and
    /// the friction force applied, N/m; 0 without wall friction.
    pub wall_normal_load: f64,
    pub wall_friction_force: f64,
    /// The force the liquid put on the solid, N/m, along x and z, the mean
    /// over the steps since the previous frame (`Mpm::take_liquid_impulse`):
    /// buoyancy upward at rest, and the seepage push of a sloping water
    /// table; 0 dry and in the first frame.
    pub liquid_force_on_solid_x: f64,
    pub liquid_force_on_solid_z: f64,
    /// Σ m v of the solid and of the liquid points at the frame, kg m/s
    /// per metre of width, along x and z. With the liquid's force it closes
    /// the solid's momentum budget: what the liquid gave, what gravity
    /// gave, and the rest from the walls, the floor and the damping
    /// (`bench/momentum_budget.py`).
    pub momentum_solid_x: f64,
    pub momentum_solid_z: f64,
    pub momentum_liquid_x: f64,
    pub momentum_liquid_z: f64,
}
