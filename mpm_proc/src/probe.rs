//! `mpm_proc probe`: where the liquid pushes the grains (issue 20,
//! docs/mpm.md open point 7). The saturated columns' bodies move with the
//! element size only while their water drains through the grains, and the
//! liquid's impulse on the grains grows with refinement; this tells where
//! on the flume, at what height and by which part (the pore pressure's
//! share, the stress share, the drag) that push acts, so two grids can be
//! set side by side.
//!
//! The run is the bench's (the gravity phase, every gate released at
//! t = 0, the collapse under the scene's `domain.collapse_gravity` when it
//! sets one, no recording), with [`Mpm::start_liquid_force_field`] on over
//! each window. Forces are scaled by the grains' buoyant weight under
//! `domain.gravity` and times by its t_ref, as the run summary's are.

use crate::solver::{LiquidForceField, Mpm};

/// Heights of the rows the field is binned in, as fractions of the
/// column's height H0: the floor's node row (z = 0, where the floor holds
/// the vertical), then (0, 0.1], (0.1, 0.25], (0.25, 0.5], above 0.5.
pub const Z_EDGES: [f64; 4] = [0.0, 0.1, 0.25, 0.5];
/// Distances from the back wall the field is binned in, in column lengths
/// L0: the column's two halves, then the flume beyond the gate line.
pub const X_EDGES: [f64; 6] = [0.5, 1.0, 1.5, 2.0, 3.0, 4.0];

/// What the probe reads from the scene.
#[derive(Debug, Clone, Copy)]
pub struct ProbeFrame {
    /// Back wall (the domain's x minimum), m.
    pub x0: f64,
    /// Floor (the domain's z minimum), m.
    pub z0: f64,
    /// Column length L0 and height H0, m.
    pub column: [f64; 2],
    /// Reference time t_ref, s.
    pub t_ref: f64,
    /// The grains' buoyant weight per metre of width,
    /// (1 − n0)(ρ_s − ρ_L) g L0 H0, N/m: the scale of every force printed.
    pub buoyant_weight: f64,
}

/// One window's field, binned: `[axis][part][z row][x column]` of the
/// mean force over the window per buoyant weight, axes x and z, parts
/// stress, pressure, drag.
#[derive(Debug, Clone, PartialEq)]
pub struct BinnedPush {
    /// Window, t/t_ref.
    pub window: [f64; 2],
    /// The three parts' x- and z-totals over all nodes, per buoyant weight.
    pub totals: [[f64; 2]; 3],
    /// `[axis][part][row][column]`, rows as [`Z_EDGES`] (5), columns as
    /// [`X_EDGES`] (7: the last beyond 4 L0).
    pub bins: [Bins; 2],
}

/// One axis's `[part][row][column]`.
pub type Bins = [[[f64; X_EDGES.len() + 1]; Z_EDGES.len() + 1]; 3];

/// The parts' names, in [`BinnedPush`] order.
pub const PARTS: [&str; 3] = ["stress share", "pore pressure (implicit)", "drag"];

fn bin(edges: &[f64], v: f64) -> usize {
    edges.iter().take_while(|&&e| v > e).count()
}

/// Bins a summed field: each node's impulse by its position, divided by the
/// window's time and the buoyant weight.
pub fn bin_field(mpm: &Mpm, field: &LiquidForceField, frame: &ProbeFrame, window: [f64; 2]) -> BinnedPush {
    let [nx, _] = mpm.grid.node_dims();
    // An empty window (no step summed) bins to zeros, as
    // `LiquidImpulse::mean_force` gives over an empty interval.
    let scale = if field.time > 0.0 { 1.0 / (field.time * frame.buoyant_weight) } else { 0.0 };
    let mut push =
        BinnedPush { window, totals: [[0.0; 2]; 3], bins: [[[[0.0; X_EDGES.len() + 1]; Z_EDGES.len() + 1]; 3]; 2] };
    let half_row = 0.5 * mpm.grid.h;
    for (part, values) in [&field.stress, &field.pressure, &field.drag].into_iter().enumerate() {
        for (node, f) in values.iter().enumerate() {
            if f[0] == 0.0 && f[1] == 0.0 {
                continue;
            }
            let [x, z] = mpm.grid.node_position(node % nx, node / nx);
            let (along, up) = ((x - frame.x0) / frame.column[0], (z - frame.z0) / frame.column[1]);
            // The floor's node row is its own bin; the rows above by height.
            let row = if z - frame.z0 < half_row { 0 } else { 1 + bin(&Z_EDGES[1..], up) };
            let column = bin(&X_EDGES, along);
            for d in 0..2 {
                push.bins[d][part][row][column] += f[d] * scale;
                push.totals[part][d] += f[d] * scale;
            }
        }
    }
    push
}

/// The windows' tables as markdown, one table per part and axis, rows by
/// height, columns by distance from the back wall; a part none of whose
/// bins reaches 1e-4 of the buoyant weight on either axis is left out (the
/// stress share under the implicit scheme, the implicit pressure under the
/// explicit one).
pub fn markdown(pushes: &[BinnedPush], frame: &ProbeFrame, label: &str) -> String {
    use std::fmt::Write;
    let mut out = String::new();
    let mut columns = vec![format!("0–{} L0", X_EDGES[0])];
    columns.extend(X_EDGES.windows(2).map(|w| format!("{}–{}", w[0], w[1])));
    columns.push(format!("> {}", X_EDGES[X_EDGES.len() - 1]));
    let rows = ["floor nodes", "(0, 0.1] H0", "(0.1, 0.25] H0", "(0.25, 0.5] H0", "> 0.5 H0"];
    for p in pushes {
        let _ = writeln!(
            out,
            "\n{label}: the liquid's mean force on the grains over t/t_ref {:.2}–{:.2}, per buoyant weight \
             (1 − n0)(ρ_s − ρ_L) g L0 H0 = {:.3} N/m; x along the flume from the back wall, z above the floor",
            p.window[0], p.window[1], frame.buoyant_weight
        );
        let total = |d: usize| p.totals.iter().map(|t| t[d]).sum::<f64>();
        let _ = writeln!(
            out,
            "totals x / z: {} ; all parts {:+.4} / {:+.4}",
            PARTS
                .iter()
                .zip(&p.totals)
                .map(|(n, t)| format!("{n} {:+.4} / {:+.4}", t[0], t[1]))
                .collect::<Vec<_>>()
                .join(", "),
            total(0),
            total(1)
        );
        for (part, name) in PARTS.iter().enumerate() {
            let largest =
                p.bins.iter().flat_map(|axis| axis[part].iter().flatten()).fold(0.0f64, |m, v| m.max(v.abs()));
            if largest < 1e-4 {
                continue;
            }
            for (d, axis) in ["x", "z"].iter().enumerate() {
                let _ = writeln!(out, "\n{name}, {axis}-force:\n\n| height | {} |", columns.join(" | "));
                let _ = writeln!(out, "|---|{}", "---|".repeat(columns.len()));
                for (r, name) in rows.iter().enumerate() {
                    let cells: Vec<String> = p.bins[d][part][r].iter().map(|v| format!("{v:+.4}")).collect();
                    let _ = writeln!(out, "| {name} | {} |", cells.join(" | "));
                }
            }
        }
    }
    out
}

/// Steps `mpm` (gates released, t = 0 at the release) through each window
/// `[c − w/2, c + w/2]` t/t_ref, `centres` ascending and the windows apart,
/// summing the field over each. Returns the binned windows and, per window,
/// the liquid impulse's x- and z-mean force the recorder would have taken
/// over the same steps (per buoyant weight), which the field's totals must
/// equal.
pub fn probe(
    mpm: &mut Mpm,
    frame: &ProbeFrame,
    centres: &[f64],
    width: f64,
) -> Result<Vec<(BinnedPush, [f64; 2])>, String> {
    if !(frame.t_ref.is_finite() && frame.t_ref > 0.0 && frame.buoyant_weight.is_finite() && frame.buoyant_weight > 0.0)
    {
        return Err(format!(
            "t_ref = {} s and the grains' buoyant weight = {} N/m: the probe scales by both, so give the scene a \
             non-zero `domain.gravity`, grains denser than the fluid and a column ([analysis] column_length and \
             column_height > 0)",
            frame.t_ref, frame.buoyant_weight
        ));
    }
    if let Some(c) = centres.iter().find(|c| !c.is_finite() || **c < 0.0) {
        return Err(format!("--at {c}: give window centres as finite times t/t_ref ≥ 0"));
    }
    if mpm.state.liquid.set.is_empty() {
        return Err("the scene has no liquid points: the probe measures the liquid's push on the grains, \
                    so give the scene a [[fluids]] block (a saturated column)"
            .into());
    }
    let step = mpm.params.dt / frame.t_ref;
    if !width.is_finite() || width < step {
        return Err(format!("--window {width}: give a finite window length of at least one step, {step:.2e} t/t_ref"));
    }
    let windows: Vec<[f64; 2]> = centres.iter().map(|&c| [(c - 0.5 * width).max(0.0), c + 0.5 * width]).collect();
    for pair in windows.windows(2) {
        if pair[1][0] < pair[0][1] {
            return Err(format!(
                "the windows around --at overlap ({:.2}–{:.2} and {:.2}–{:.2} t/t_ref): give the centres \
                 ascending and at least --window apart",
                pair[0][0], pair[0][1], pair[1][0], pair[1][1]
            ));
        }
    }
    let mut out = Vec::with_capacity(windows.len());
    let half_step = |mpm: &Mpm| 0.5 * mpm.params.dt;
    let awake = runtime::process::AwakeWorkers::new();
    for window in windows {
        while mpm.state.time + half_step(mpm) < window[0] * frame.t_ref {
            awake.keep_awake();
            mpm.step();
        }
        mpm.start_liquid_force_field();
        mpm.take_liquid_impulse();
        while mpm.state.time + half_step(mpm) < window[1] * frame.t_ref {
            awake.keep_awake();
            mpm.step();
        }
        let impulse = mpm.take_liquid_impulse();
        let field = mpm.take_liquid_force_field().expect("started above");
        let force = impulse.mean_force();
        let actual = [mpm.state.time / frame.t_ref - field.time / frame.t_ref, mpm.state.time / frame.t_ref];
        out.push((
            bin_field(mpm, &field, frame, actual),
            [force[0] / frame.buoyant_weight, force[1] / frame.buoyant_weight],
        ));
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bins_split_at_their_edges() {
        assert_eq!(bin(&X_EDGES, 0.2), 0);
        assert_eq!(bin(&X_EDGES, 0.5), 0);
        assert_eq!(bin(&X_EDGES, 0.51), 1);
        assert_eq!(bin(&X_EDGES, 3.5), 5);
        assert_eq!(bin(&X_EDGES, 9.0), 6);
        assert_eq!(bin(&Z_EDGES[1..], 0.05), 0);
        assert_eq!(bin(&Z_EDGES[1..], 0.3), 2);
        assert_eq!(bin(&Z_EDGES[1..], 0.9), 3);
    }
}
