//! `summary.json`: the result of a run, in one form for every method.
//! Field names are a public contract (scripts read them): add, never rename.

use serde::{Deserialize, Deserializer, Serialize};

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
    #[serde(deserialize_with = "nan_if_null")]
    pub sim_time: f64,
    /// Wall time of the solver loop (deposition excluded), s.
    #[serde(deserialize_with = "nan_if_null")]
    pub wall_seconds: f64,
    /// Solver steps taken since the start of the run.
    pub steps: u64,
    pub throughput: Throughput,
    /// Reference time used to normalise t, s.
    #[serde(deserialize_with = "nan_if_null")]
    pub t_ref: f64,
    /// Solid front over time.
    pub front: Vec<FrontSample>,
    /// (L_f − L0)/L0 at the end.
    #[serde(deserialize_with = "nan_if_null")]
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
    /// as `front`; the MPM's per metre of width, its points' grains m/ρ_s
    /// (since session 32); empty for methods without grains.
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
    #[serde(deserialize_with = "nan_if_null")]
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
    /// Coupled runs, merged by the coupler: the LBM's loop wall time, s
    /// (`wall_seconds` is the DEM's).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub wall_seconds_lbm: Option<f64>,
    /// The DEM–LBM exchange: one process's view in its own summary, both
    /// views in the coupler's; absent in uncoupled runs.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub exchange: Option<ExchangeSummary>,
}

/// `exchange` of a summary.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(untagged)]
pub enum ExchangeSummary {
    /// A process's own summary (`dem_summary.json`, `lbm_summary.json`).
    Process(ExchangeDetails),
    /// The coupler's `summary.json`: the schedule and each process's view.
    Run(RunExchange),
}

/// The exchange of a coupled run, as the coupler merges it.
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
pub struct RunExchange {
    /// `sequential` or `concurrent`.
    pub schedule: String,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub dem: Option<ExchangeDetails>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub lbm: Option<ExchangeDetails>,
}

/// Reads a number back that serde_json wrote as `null` (it writes NaN and
/// ±∞ so: a runout the LBM does not measure, a porosity of an explicit
/// packing) as NaN, so that a summary reads back into its type. Binary
/// formats (bincode: checkpoints) keep NaN as it is and are read as written.
pub fn nan_if_null<'de, D: Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
    if !d.is_human_readable() {
        return f64::deserialize(d);
    }
    Ok(Option::<f64>::deserialize(d)?.unwrap_or(f64::NAN))
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
    #[serde(deserialize_with = "nan_if_null")]
    pub seconds: f64,
    /// Share of this process's run wall time spent in the exchange.
    #[serde(deserialize_with = "nan_if_null")]
    pub fraction: f64,
    /// Wall seconds in the coupling kernel itself (LBM: covering cells,
    /// forcing bookkeeping, force sums; DEM: 0).
    #[serde(deserialize_with = "nan_if_null")]
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
    #[serde(deserialize_with = "nan_if_null")]
    pub wall_per_sim_second: f64,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct DemDetails {
    pub particles: usize,
    #[serde(deserialize_with = "nan_if_null")]
    pub time_step: f64,
    /// Damping ratio ζ derived from the restitution.
    #[serde(deserialize_with = "nan_if_null")]
    pub damping_ratio: f64,
    #[serde(deserialize_with = "nan_if_null")]
    pub restitution: f64,
    /// Grain–grain contact duration, s, and steps per contact.
    #[serde(deserialize_with = "nan_if_null")]
    pub contact_duration: f64,
    #[serde(deserialize_with = "nan_if_null")]
    pub steps_per_contact: f64,
    /// Porosity of the column core: one diameter from the side walls and the
    /// floor, two diameters below the region top.
    #[serde(deserialize_with = "nan_if_null")]
    pub porosity_core: f64,
    /// Height of the initial column (highest grain top), m.
    #[serde(deserialize_with = "nan_if_null")]
    pub initial_height: f64,
    /// Whether the packing came from the cache.
    pub packing_from_cache: bool,
    /// Wall time of the deposition (0 if cached), s.
    #[serde(deserialize_with = "nan_if_null")]
    pub deposition_seconds: f64,
    /// Mean coordination number at the start and the end.
    #[serde(deserialize_with = "nan_if_null")]
    pub coordination_initial: f64,
    #[serde(deserialize_with = "nan_if_null")]
    pub coordination_final: f64,
    /// Fraction of the run's wall time spent handing frames to the recorder.
    #[serde(deserialize_with = "nan_if_null")]
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
    #[serde(deserialize_with = "nan_if_null")]
    pub spacing: f64,
    #[serde(deserialize_with = "nan_if_null")]
    pub time_step: f64,
    /// Molecular relaxation time τ0.
    #[serde(deserialize_with = "nan_if_null")]
    pub tau: f64,
    pub collision: String,
    #[serde(deserialize_with = "nan_if_null")]
    pub smagorinsky: f64,
    /// Fluid + interface cells at the start and the end.
    pub active_cells_initial: usize,
    pub active_cells_final: usize,
    /// Liquid mass at the start and the end, kg, and (end − start)/start.
    #[serde(deserialize_with = "nan_if_null")]
    pub mass_initial: f64,
    #[serde(deserialize_with = "nan_if_null")]
    pub mass_final: f64,
    #[serde(deserialize_with = "nan_if_null")]
    pub mass_relative_change: f64,
    /// Part of `mass_final` held as excess that found no receiving cell, kg.
    #[serde(deserialize_with = "nan_if_null")]
    pub pending_mass_final: f64,
    /// Liquid mass that found no receiving cell during the run (one-cell
    /// droplets, sheets too thin to hold) and was given back to the bulk as
    /// a uniform density rise, kg (docs/lbm.md "Splashes").
    #[serde(default)]
    #[serde(deserialize_with = "nan_if_null")]
    pub returned_mass: f64,
    /// Largest |u|/c_s seen on the recorded frames.
    #[serde(deserialize_with = "nan_if_null")]
    pub max_mach: f64,
    /// Fraction of the run's wall time spent handing frames to the recorder.
    #[serde(deserialize_with = "nan_if_null")]
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
    #[serde(deserialize_with = "nan_if_null")]
    pub element_size: f64,
    /// `gimp` or `linear`.
    pub shape_functions: String,
    pub solid_points: usize,
    pub liquid_points: usize,
    /// CFL step, s.
    #[serde(deserialize_with = "nan_if_null")]
    pub time_step: f64,
    /// The gravity phase before t = 0: steps, simulated and wall seconds.
    pub gravity_phase_steps: u64,
    #[serde(deserialize_with = "nan_if_null")]
    pub gravity_phase_time: f64,
    #[serde(deserialize_with = "nan_if_null")]
    pub gravity_phase_seconds: f64,
    /// Top of the soil block, m.
    #[serde(deserialize_with = "nan_if_null")]
    pub soil_top: f64,
    /// Solid and liquid mass at the end, kg/m, and their change over the run
    /// (zero: points carry fixed masses).
    #[serde(deserialize_with = "nan_if_null")]
    pub solid_mass: f64,
    #[serde(deserialize_with = "nan_if_null")]
    pub liquid_mass: f64,
    #[serde(deserialize_with = "nan_if_null")]
    pub solid_mass_relative_change: f64,
    #[serde(deserialize_with = "nan_if_null")]
    pub liquid_mass_relative_change: f64,
    /// Largest and final kinetic energy of both phases on the recorded frames, J/m.
    #[serde(deserialize_with = "nan_if_null")]
    pub max_kinetic_energy: f64,
    #[serde(deserialize_with = "nan_if_null")]
    pub final_kinetic_energy: f64,
    /// Largest fluidised share of the solid mass on the recorded frames.
    #[serde(deserialize_with = "nan_if_null")]
    pub fluidised_fraction_max: f64,
    /// Largest pore pressure of any liquid point on the recorded frames, Pa
    /// (against ρ_L g H0 at rest: the spikes of cell crossings show here).
    #[serde(default)]
    #[serde(deserialize_with = "nan_if_null")]
    pub max_pore_pressure: f64,
    /// Largest pore pressure of any liquid point at the end of any step of
    /// the collapse, Pa: with the pulses of two or three steps that fall
    /// between frames.
    #[serde(default)]
    #[serde(deserialize_with = "nan_if_null")]
    pub peak_pore_pressure: f64,
    /// Whether the quadratic drag term was on.
    pub quadratic_drag: bool,
    /// Fraction of the run's wall time spent handing frames to the recorder.
    #[serde(deserialize_with = "nan_if_null")]
    pub recording_fraction: f64,
    pub threads: usize,
    /// Wall seconds in each stage of the step over the collapse (locate,
    /// map, prepare_forces, solve_nodes, pressure, wall_friction,
    /// update_velocities, remap, update_points; a resumed run's since the
    /// resume); empty in summaries written before it existed.
    #[serde(default)]
    pub stage_seconds: std::collections::BTreeMap<String, f64>,
}

#[cfg(test)]
mod tests {
    use super::*;

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

    fn details(schedule: &str, exchanges: u64) -> ExchangeDetails {
        ExchangeDetails { schedule: schedule.into(), ratio: 57, exchanges, ..ExchangeDetails::default() }
    }

    /// A summary written with NaN (the LBM's runout, an explicit packing's
    /// porosity) reads back into its type, NaN for NaN; a process's
    /// exchange reads back as one view, the coupler's as both.
    #[test]
    fn summaries_read_back_into_their_type_with_nan_and_both_exchange_shapes() {
        let json = r#"{"scene": "s", "method": "lbm", "status": "peer_stopped", "sim_time": 0.01,
            "wall_seconds": 2.0, "steps": 125, "throughput": {"cell_updates_per_s": 3e7, "wall_per_sim_second": 200.0},
            "t_ref": 0.0997, "front": [{"t": 0.0, "t_norm": 0.0, "x": null, "x_norm": null}], "runout": null,
            "deposit": [], "porosity_initial": null,
            "exchange": {"schedule": "sequential", "ratio": 57, "exchanges": 125, "seconds": 0.5, "fraction": 0.25, "kernel_seconds": 0.1}}"#;
        let s: RunSummary = serde_json::from_str(json).expect("reads back");
        assert!(s.runout.is_nan() && s.porosity_initial.is_nan() && s.front[0].x.is_nan());
        assert_eq!(s.status, RunStatus::PeerStopped);
        assert!(matches!(&s.exchange, Some(ExchangeSummary::Process(d)) if d.exchanges == 125 && d.ratio == 57));
        // Written again, NaN is null, and it reads back the same.
        let again: RunSummary = serde_json::from_str(&serde_json::to_string(&s).unwrap()).unwrap();
        assert!(again.runout.is_nan());

        let merged = ExchangeSummary::Run(RunExchange {
            schedule: "concurrent".into(),
            dem: Some(details("concurrent", 10)),
            lbm: Some(details("concurrent", 10)),
        });
        let text = serde_json::to_string(&merged).unwrap();
        let v: serde_json::Value = serde_json::from_str(&text).unwrap();
        assert_eq!(v["schedule"], "concurrent");
        assert_eq!(v["dem"]["exchanges"], v["lbm"]["exchanges"]);
        match serde_json::from_str::<ExchangeSummary>(&text).unwrap() {
            ExchangeSummary::Run(r) => assert_eq!(r.dem.map(|d| d.exchanges), Some(10)),
            other => panic!("read as {other:?}"),
        }
    }
}
