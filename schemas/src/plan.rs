//! What a run of a scene will be, before it runs: each solver's
//! `plan(&Scene)` (`dem_proc::plan`, `lbm_proc::plan`, `mpm_proc::plan`)
//! resolves the scene the way the solver itself will (time step, steps,
//! stability figures) and says what it costs and what looks wrong.
//! `coupler check` prints the plans of the method's solvers alike.

/// One solver's plan for a scene.
#[derive(Debug, Clone, PartialEq)]
pub struct Plan {
    /// The process that will run it (`dem_proc`, `lbm_proc`, `mpm_proc`).
    pub solver: &'static str,
    /// Time step, s.
    pub time_step: f64,
    /// Steps to the end time (the most: a run may stop at rest).
    pub steps: u64,
    /// Work to the end time, in [`Plan::work_unit`].
    pub work: f64,
    /// "particle-steps", "cell updates" (at the initial liquid volume) or "point updates".
    pub work_unit: &'static str,
    /// Rough memory of the solver's state, bytes.
    pub memory: f64,
    /// Rough wall time at a throughput measured on 2 cores (docs/BENCHMARKS.md), s.
    pub wall_estimate: f64,
    /// Labelled lines, in the order `coupler check` prints them.
    pub lines: Vec<(&'static str, String)>,
    /// What looks wrong, each with what to change.
    pub warnings: Vec<String>,
}

impl Plan {
    /// An empty plan of `solver`.
    pub fn new(solver: &'static str, work_unit: &'static str) -> Self {
        Plan {
            solver,
            time_step: f64::NAN,
            steps: 0,
            work: 0.0,
            work_unit,
            memory: 0.0,
            wall_estimate: f64::NAN,
            lines: Vec::new(),
            warnings: Vec::new(),
        }
    }

    /// Adds a labelled line (labels at most 12 characters).
    pub fn line(&mut self, label: &'static str, text: impl Into<String>) {
        self.lines.push((label, text.into()));
    }

    /// Adds a warning.
    pub fn warn(&mut self, warning: impl Into<String>) {
        self.warnings.push(warning.into());
    }

    /// The plan's lines as `coupler check` prints them: the label in a
    /// column of 12, then the text.
    pub fn render(&self) -> String {
        self.lines.iter().map(|(label, text)| format!("{label:<12} {text}\n")).collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lines_render_in_a_column_and_warnings_are_kept() {
        let mut p = Plan::new("dem_proc", "particle-steps");
        p.line("time step", "1e-6 s");
        p.line("hydrostatics", "lattice");
        p.warn("lower dem.time_step");
        assert_eq!(p.render(), "time step    1e-6 s\nhydrostatics lattice\n");
        assert_eq!(p.warnings, ["lower dem.time_step"]);
    }
}
