//! `summary.json`: the result of a run, in one form for every method.
//! Field names are a public contract (scripts read them): add, never rename.

use serde::{Deserialize, Serialize};

use crate::measures::FrontSample;

/// How a run ended; written as the snake_case word in `summary.json`, the
/// progress events and the terminal.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum RunStatus {
    /// The scene's end time was reached.
    Completed,
    /// Stopped early: the material came to rest (`output.stop_at_rest`).
    AtRest,
    /// Stopped by a signal (Ctrl-C, SIGTERM); what was recorded is kept.
    Interrupted,
    /// Stopped by the solver's watchdog (a blow-up, named in `/log`).
    Unstable,
    /// A process failed (set by `coupler` on the merged summary).
    Failed,
    /// In a coupled process's own summary: the peer ended the run (its end
    /// time, rest, or a stop of its own).
    PeerStopped,
    /// In a coupled process's own summary: the exchange with the peer failed.
    PeerFailed,
}

impl RunStatus {
    /// The word `summary.json` holds.
    pub fn as_str(self) -> &'static str {
        match self {
            RunStatus::Completed => "completed",
            RunStatus::AtRest => "at_rest",
            RunStatus::Interrupted => "interrupted",
            RunStatus::Unstable => "unstable",
            RunStatus::Failed => "failed",
            RunStatus::PeerStopped => "peer_stopped",
            RunStatus::PeerFailed => "peer_failed",
        }
    }
}

impl std::fmt::Display for RunStatus {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct RunSummary {
    /// Scene name.
    pub scene: String,
    /// `dem`, `lbm`, `dem_lbm`, `mpm`.
    pub method: String,
    /// How the run ended (`completed`, `at_rest`, `interrupted`, `unstable`;
    /// `failed`, `peer_stopped`, `peer_failed` in coupled runs).
    pub status: RunStatus,
    /// Simulated time reached since the start of the run, s.
    pub sim_time: f64,
    /// Wall time of the solver loop (deposition excluded), s.
    pub wall_seconds: f64,
    /// Solver steps taken since the start of the run.
    pub steps: u64,
    pub throughput: Throughput,
    /// Reference time used to normalise t, s.
    pub t_ref: f64,
    /// Solid front over time.
    pub front: Vec<FrontSample>,
    /// (L_f − L0)/L0 at the end.
    pub runout: f64,
    /// The front of the grains touching at least one other grain: the edge of
    /// the continuous mass, blind to isolated grains rolling ahead (closer to
    /// what a camera calls the front). Same form as `front`; empty for methods
    /// without contacts.
    #[serde(default)]
    pub front_connected: Vec<FrontSample>,
    /// (L_f − L0)/L0 of `front_connected` at the end.
    #[serde(default)]
    pub runout_connected: Option<f64>,
    /// The pile's edge: where the deposit's height averaged over the
    /// flume's width (solid volume per bin over bin × width × (1 − n0))
    /// first falls below one grain diameter, from the back wall on
    /// ([`crate::measures::pile_edge`]). Robust to stray grains. Same form
    /// as `front`; empty for methods without grains.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub front_pile: Vec<FrontSample>,
    /// (L_f − L0)/L0 of `front_pile` at the end.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub runout_pile: Option<f64>,
    /// Final deposit profile: [x, height] pairs, m.
    pub deposit: Vec<[f64; 2]>,
    /// Bulk porosity of the initial column: 1 − V_solid / V_region of the first
    /// deposit block (its region is the column L0 × W × H0 in the lab scenes);
    /// null for explicit packings.
    pub porosity_initial: f64,
    /// Liquid front over time (0.5 % of the liquid mass beyond it), same form
    /// as `front`; empty for methods without liquid.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub liquid_front: Vec<FrontSample>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub dem: Option<DemDetails>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub lbm: Option<LbmDetails>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mpm: Option<MpmDetails>,
    /// Wall time of the whole run as the coupler saw it, s (set by the coupler).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub wall_seconds_total: Option<f64>,
    /// The DEM–LBM exchange as this process saw it; absent in uncoupled runs.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub exchange: Option<ExchangeDetails>,
}

/// One process's view of the DEM–LBM exchange.
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
pub struct ExchangeDetails {
    /// `sequential` or `concurrent`.
    pub schedule: String,
    /// DEM steps per LBM step.
    pub ratio: u32,
    /// Exchanges completed.
    pub exchanges: u64,
    /// Wall seconds this process spent sending and waiting for its peer.
    pub seconds: f64,
    /// Share of this process's run wall time spent in the exchange.
    pub fraction: f64,
    /// Wall seconds in the coupling kernel itself (LBM: covering cells,
    /// forcing bookkeeping, force sums; DEM: 0).
    pub kernel_seconds: f64,
    /// The direct forcing's gain rule (`coupling.forcing_gain`; LBM only).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub forcing_gain: Option<String>,
}

#[derive(Debug, Clone, Default, Serialize, Deserialize)]
pub struct Throughput {
    /// DEM particle-steps per second of wall time.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub particle_steps_per_s: Option<f64>,
    /// LBM cell updates per second of wall time, counting only the cells
    /// actually updated (fluid and interface).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cell_updates_per_s: Option<f64>,
    /// MPM material-point updates per second of wall time, both phases.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub point_updates_per_s: Option<f64>,
    /// Wall seconds per simulated second.
    pub wall_per_sim_second: f64,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct DemDetails {
    pub particles: usize,
    pub time_step: f64,
    /// Damping ratio ζ derived from the restitution.
    pub damping_ratio: f64,
    pub restitution: f64,
    /// Grain–grain contact duration, s, and steps per contact.
    pub contact_duration: f64,
    pub steps_per_contact: f64,
    /// Porosity of the column core: one diameter from the side walls and the
    /// floor, two diameters below the region top.
    pub porosity_core: f64,
    /// Height of the initial column (highest grain top), m.
    pub initial_height: f64,
    /// Whether the packing came from the cache.
    pub packing_from_cache: bool,
    /// Wall time of the deposition (0 if cached), s.
    pub deposition_seconds: f64,
    /// Mean coordination number at the start and the end.
    pub coordination_initial: f64,
    pub coordination_final: f64,
    /// Fraction of the run's wall time spent handing frames to the recorder.
    pub recording_fraction: f64,
    pub threads: usize,
    /// Wall seconds in each stage of the step over the collapse
    /// (kick_and_drift, update_neighbours, compute_contact_forces,
    /// sum_and_kick); empty in summaries written before it existed.
    #[serde(default)]
    pub stage_seconds: std::collections::BTreeMap<String, f64>,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct LbmDetails {
    /// Cells along x, y, z and the lattice spacing, m, and time step, s.
    pub dims: [usize; 3],
    pub spacing: f64,
    pub time_step: f64,
    /// Molecular relaxation time τ0.
    pub tau: f64,
    pub collision: String,
    pub smagorinsky: f64,
    /// Fluid + interface cells at the start and the end.
    pub active_cells_initial: usize,
    pub active_cells_final: usize,
    /// Liquid mass at the start and the end, kg, and (end − start)/start.
    pub mass_initial: f64,
    pub mass_final: f64,
    pub mass_relative_change: f64,
    /// Part of `mass_final` held as excess that found no receiving cell, kg.
    pub pending_mass_final: f64,
    /// Liquid mass that found no receiving cell during the run (one-cell
    /// droplets, sheets too thin to hold) and was given back to the bulk as
    /// a uniform density rise, kg (docs/lbm.md "Splashes").
    #[serde(default)]
    pub returned_mass: f64,
    /// Largest |u|/c_s seen on the recorded frames.
    pub max_mach: f64,
    /// Fraction of the run's wall time spent handing frames to the recorder.
    pub recording_fraction: f64,
    pub threads: usize,
    /// Wall seconds in each stage of the fluid step (prepare,
    /// stream_collide, update_surface; the coupling kernel is
    /// `exchange.kernel_seconds` here, `exchange.lbm.kernel_seconds` in the
    /// coupler's merged summary); empty in summaries written before it existed.
    #[serde(default)]
    pub stage_seconds: std::collections::BTreeMap<String, f64>,
}

/// A struct of wall-second stage timers (f64 fields) as the summaries'
/// `stage_seconds` map, keyed by field name.
pub fn stage_seconds_map(stages: &impl Serialize) -> std::collections::BTreeMap<String, f64> {
    serde_json::to_value(stages)
        .and_then(serde_json::from_value)
        .expect("stage timers serialise as a map of f64 fields")
}

/// The MPM run (plane strain: masses and energies per metre of width).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct MpmDetails {
    /// Elements along x and z, and their side, m.
    pub elements: [usize; 2],
    pub element_size: f64,
    /// `gimp` or `linear`.
    pub shape_functions: String,
    pub solid_points: usize,
    pub liquid_points: usize,
    /// CFL step, s.
    pub time_step: f64,
    /// The gravity phase before t = 0: steps, simulated and wall seconds.
    pub gravity_phase_steps: u64,
    pub gravity_phase_time: f64,
    pub gravity_phase_seconds: f64,
    /// Top of the soil block, m.
    pub soil_top: f64,
    /// Solid and liquid mass at the end, kg/m, and their change over the run
    /// (zero: points carry fixed masses).
    pub solid_mass: f64,
    pub liquid_mass: f64,
    pub solid_mass_relative_change: f64,
    pub liquid_mass_relative_change: f64,
    /// Largest and final kinetic energy of both phases on the recorded frames, J/m.
    pub max_kinetic_energy: f64,
    pub final_kinetic_energy: f64,
    /// Largest fluidised share of the solid mass on the recorded frames.
    pub fluidised_fraction_max: f64,
    /// Largest pore pressure of any liquid point on the recorded frames, Pa
    /// (against ρ_L g H0 at rest: the spikes of cell crossings show here).
    #[serde(default)]
    pub max_pore_pressure: f64,
    /// Largest pore pressure of any liquid point at the end of any step of
    /// the collapse, Pa: with the pulses of two or three steps that fall
    /// between frames.
    #[serde(default)]
    pub peak_pore_pressure: f64,
    /// Whether the quadratic drag term was on.
    pub quadratic_drag: bool,
    /// Fraction of the run's wall time spent handing frames to the recorder.
    pub recording_fraction: f64,
    pub threads: usize,
}

#[cfg(test)]
mod tests {
    use super::RunStatus;

    /// The words are a public contract (scripts and `coupler` read them):
    /// serde, `as_str` and `Display` agree, and each reads back.
    #[test]
    fn run_status_words_are_the_summary_contract() {
        let all = [
            (RunStatus::Completed, "completed"),
            (RunStatus::AtRest, "at_rest"),
            (RunStatus::Interrupted, "interrupted"),
            (RunStatus::Unstable, "unstable"),
            (RunStatus::Failed, "failed"),
            (RunStatus::PeerStopped, "peer_stopped"),
            (RunStatus::PeerFailed, "peer_failed"),
        ];
        for (status, word) in all {
            assert_eq!(serde_json::to_string(&status).unwrap(), format!("\"{word}\""));
            assert_eq!((status.as_str(), status.to_string()), (word, word.to_string()));
            assert_eq!(serde_json::from_str::<RunStatus>(&format!("\"{word}\"")).unwrap(), status);
        }
        assert!(serde_json::from_str::<RunStatus>("\"done\"").is_err());
    }
}
