//! The forcing-gain study of docs/coupling.md ("Choosing the forcing gain"):
//! every [`ForcingGain`] rule on the validation cases of
//! `lbm_proc::validation` at D/Δx = 4.17, 6 and 8, for the paper's water
//! (τ0 → ½ with Smagorinsky, Δt scaled with Δx) and viscous liquids (τ =
//! 0.6, 1), printed as markdown tables of errors.
//!
//! ```sh
//! cargo run --release -p lbm_proc --example coupling_study -- [arrays] [permeability] [ergun] [settling] [tank-width] [--quick]
//! ```
//!
//! No section named: all five. `--quick`: D/Δx = 4.17 only. Cases run in
//! parallel on the machine's cores; each is deterministic.

use std::time::Instant;

use rayon::prelude::*;

use lbm_proc::coupling::ForcingGain;
use lbm_proc::validation::settling::{settle, SettlingCase, SettlingLiquid};
use lbm_proc::validation::{
    column_packing, kozeny_carman, packing_ergun, packing_permeability, simple_cubic_drag, FluidCondition,
    ARRAY_FRACTIONS, PAPER_D_CELLS,
};

/// Step caps: the arrays' slowest mode decays over ~L²/(4π²ν) steps (tens
/// of thousands at τ0 → ½); a packing's flow settles within its Darcy time
/// k/ν (hundreds of steps), or never at Re_p = 100 (then the mean of the
/// last 4000 steps).
const MAX_STEPS: usize = 400_000;
const PACKING_MAX_STEPS: usize = 40_000;

fn conditions(d: f64) -> Vec<(&'static str, FluidCondition)> {
    vec![
        ("paper water", FluidCondition::paper_water(d)),
        ("tau 0.6", FluidCondition::viscous(0.6)),
        ("tau 1", FluidCondition::viscous(1.0)),
    ]
}

/// The rules worth running in `fluid`: the effective-τ rule is the molecular
/// one without eddy viscosity.
fn rules(fluid: FluidCondition) -> impl Iterator<Item = ForcingGain> {
    ForcingGain::ALL
        .into_iter()
        .filter(move |&gain| fluid.smagorinsky > 0.0 || gain != ForcingGain::NobleTorczynskiEffective)
}

fn pct(x: f64) -> String {
    format!("{:+.1} %", 100.0 * x)
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let quick = args.iter().any(|a| a == "--quick");
    let sections: Vec<&str> = args.iter().filter(|a| !a.starts_with("--")).map(String::as_str).collect();
    let wants = |s: &str| sections.is_empty() || sections.contains(&s);
    let resolutions: Vec<f64> = if quick { vec![PAPER_D_CELLS] } else { vec![PAPER_D_CELLS, 6.0, 8.0] };
    let started = Instant::now();
    let studies: [(&str, &dyn Fn()); 5] = [
        ("arrays", &|| arrays(&resolutions)),
        ("permeability", &|| permeability(&resolutions)),
        ("ergun", &|| ergun(&resolutions)),
        ("settling", &|| settling(&resolutions, quick)),
        ("tank-width", &tank_width),
    ];
    for (name, study) in studies {
        if wants(name) {
            study();
            eprintln!("{name} done after {:.0} s", started.elapsed().as_secs_f64());
        }
    }
}

/// Simple-cubic arrays: Stokes drag against Zick & Homsy 1982, every rule.
fn arrays(resolutions: &[f64]) {
    println!("\n## Simple-cubic array, Stokes drag K = F/(3 pi mu D U_s) against Zick & Homsy 1982\n");
    let mut cases = Vec::new();
    for &d in resolutions {
        for (name, fluid) in conditions(d) {
            for &phi in &ARRAY_FRACTIONS {
                cases.extend(rules(fluid).map(|gain| (d, name, fluid, phi, gain)));
            }
        }
    }
    let results: Vec<_> = cases
        .par_iter()
        .map(|&(d, name, fluid, phi, gain)| {
            (d, name, fluid, phi, gain, simple_cubic_drag(phi, d, fluid, gain, MAX_STEPS))
        })
        .collect();
    println!("| D/dx | fluid | tau0 | rule | {} | mean abs |", ARRAY_FRACTIONS.map(|p| format!("phi {p}")).join(" | "));
    println!("|---|---|---|---|{}---|", "---|".repeat(ARRAY_FRACTIONS.len()));
    for &d in resolutions {
        for (name, fluid) in conditions(d) {
            for gain in ForcingGain::ALL {
                let row: Vec<_> =
                    results.iter().filter(|r| r.0 == d && r.1 == name && r.4 == gain).map(|r| &r.5).collect();
                if row.is_empty() {
                    continue;
                }
                let cells: Vec<String> =
                    row.iter().map(|r| format!("{}{}", pct(r.error), if r.converged { "" } else { " (nc)" })).collect();
                let mean = row.iter().map(|r| r.error.abs()).sum::<f64>() / row.len() as f64;
                println!(
                    "| {d:.2} | {name} | {:.5} | {} | {} | {:.1} % |",
                    fluid.tau,
                    gain.name(),
                    cells.join(" | "),
                    100.0 * mean
                );
            }
        }
    }
    println!("\nBoxes (D actual / box / spheres per edge / steps):");
    for r in &results {
        println!(
            "  D/dx {:.2} {} {} phi {}: D = {:.3}, box {}, {}^3 spheres, {} steps, K = {:.4} (ZH {})",
            r.0,
            r.1,
            r.4.name(),
            r.3,
            r.5.d,
            r.5.box_cells,
            r.5.copies,
            r.5.steps,
            r.5.k,
            r.5.reference
        );
    }
}

/// Random packings: creeping-flow permeability against Kozeny–Carman.
fn permeability(resolutions: &[f64]) {
    println!("\n## Random packing (64 grains, porosity ~0.40), creeping-flow permeability against Kozeny-Carman\n");
    let mut cases = Vec::new();
    for &d in resolutions {
        for (name, fluid) in conditions(d) {
            cases.extend(rules(fluid).map(|gain| (d, name, fluid, gain)));
        }
    }
    let results: Vec<_> = cases
        .par_iter()
        .map(|&(d, name, fluid, gain)| {
            let packing = column_packing(d);
            let (k, flow) = packing_permeability(&packing, fluid, gain, PACKING_MAX_STEPS);
            (d, name, fluid, gain, packing.porosity, k / kozeny_carman(packing.porosity, packing.d), flow)
        })
        .collect();
    println!("| D/dx | fluid | tau0 | rule | porosity | k / k_KC | steps |");
    println!("|---|---|---|---|---|---|---|");
    for r in &results {
        println!(
            "| {:.2} | {} | {:.5} | {} | {:.4} | {:.3}{} | {} |",
            r.0,
            r.1,
            r.2.tau,
            r.3.name(),
            r.4,
            r.5,
            if r.6.converged { "" } else { " (nc)" },
            r.6.steps
        );
    }
}

/// Random packings in the paper's water: drag against Ergun at Re_p 1–100.
fn ergun(resolutions: &[f64]) {
    println!("\n## Random packing, paper water: drag against Ergun at Re_p = q D/nu\n");
    let reynolds = [1.0, 10.0, 100.0];
    let mut cases = Vec::new();
    for &d in resolutions {
        for &re in &reynolds {
            for gain in ForcingGain::ALL {
                cases.push((d, re, gain));
            }
        }
    }
    let results: Vec<_> = cases
        .par_iter()
        .map(|&(d, re, gain)| {
            let packing = column_packing(d);
            let fluid = FluidCondition::paper_water(d);
            let (error, flow) = packing_ergun(&packing, fluid, gain, re, PACKING_MAX_STEPS);
            (d, re, gain, fluid, error, flow, packing.d)
        })
        .collect();
    println!("| D/dx | tau0 | rule | {} |", reynolds.map(|r| format!("Re_p {r}: drag err (Re_p got)")).join(" | "));
    println!("|---|---|---|{}", "---|".repeat(reynolds.len()));
    for &d in resolutions {
        for gain in ForcingGain::ALL {
            let row: Vec<_> = results.iter().filter(|r| r.0 == d && r.2 == gain).collect();
            let cells: Vec<String> = row
                .iter()
                .map(|r| {
                    format!("{} ({:.2}){}", pct(r.4), r.5.q * r.6 / r.3.nu(), if r.5.converged { "" } else { " (nc)" })
                })
                .collect();
            println!("| {d:.2} | {:.5} | {} | {} |", row[0].3.tau, gain.name(), cells.join(" | "));
        }
    }
}

/// The wall factor's check: the viscous settling cases at D/Δx = 4.17 in
/// tanks 10 D and 20 D wide. If the wall factor is right, the error against
/// Schiller–Naumann × wall factor does not depend on the width (the
/// coupling's error is the same sphere's in both).
fn tank_width() {
    println!("\n## Settling sphere: error against Schiller-Naumann x wall factor in tanks 10 D and 20 D wide\n");
    let viscous = SettlingLiquid::Viscous { velocity: 0.04 };
    let mut cases = Vec::new();
    for re in [1.0, 5.0, 30.0] {
        for gain in [ForcingGain::NobleTorczynski, ForcingGain::CoveredFraction] {
            for width in [10.0, 20.0] {
                cases.push(SettlingCase { width, ..SettlingCase::new(re, PAPER_D_CELLS, viscous, gain) });
            }
        }
    }
    cases.sort_by(|a, b| b.width.total_cmp(&a.width));
    let results: Vec<_> = cases.par_iter().map(|&case| (case, settle(case))).collect();
    println!("| Re_t | rule | width (D) | wall factor | U / U_inf | U / U_expected - 1 |");
    println!("|---|---|---|---|---|---|");
    for (case, result) in &results {
        match result {
            Ok(r) => println!(
                "| {} | {} | {} | {:.4} | {:.4} | {} |",
                case.reynolds,
                case.gain.name(),
                case.width,
                r.expected / r.unbounded,
                r.measured / r.unbounded,
                pct(r.error)
            ),
            Err(e) => println!("| {} | {} | {} | | | {e} |", case.reynolds, case.gain.name(), case.width),
        }
    }
}

/// A sphere (ρ_s/ρ_L = 2.6) settling from rest in a closed tank 10 D wide
/// and 32–39 D tall ([`SettlingCase::new`]): viscous liquids at terminal Re 1, 5 and 30 (lattice terminal
/// velocity 0.04, so τ0 from 0.517 to 1.46) under the molecular and the
/// covered-fraction rules; the paper's water (τ0 → ½, Smagorinsky) at Re 30
/// under the molecular and effective-τ rules. `--quick`: D/Δx = 4.17, Re 5
/// and 30 only.
fn settling(resolutions: &[f64], quick: bool) {
    println!("\n## Sphere settling in a closed tank: terminal velocity against Schiller-Naumann x wall factor\n");
    let reynolds: &[f64] = if quick { &[5.0, 30.0] } else { &[1.0, 5.0, 30.0] };
    let viscous = SettlingLiquid::Viscous { velocity: 0.04 };
    let mut cases = Vec::new();
    for &d in resolutions {
        for &re in reynolds {
            for gain in [ForcingGain::NobleTorczynski, ForcingGain::CoveredFraction] {
                cases.push(SettlingCase::new(re, d, viscous, gain));
            }
        }
    }
    // The paper's water settles slowly (U = 30 nu/D ~ 1.6e-3 cells per
    // step: 40 000 steps), so only at the paper's resolution.
    for gain in [ForcingGain::NobleTorczynski, ForcingGain::NobleTorczynskiEffective] {
        cases.push(SettlingCase::new(30.0, PAPER_D_CELLS, SettlingLiquid::PaperWater, gain));
    }
    // Largest first, so the parallel tail is short.
    cases.sort_by(|a, b| b.d_cells.total_cmp(&a.d_cells));
    let results: Vec<_> = cases.par_iter().map(|&case| (case, settle(case))).collect();
    println!(
        "| D/dx | liquid | Re_t | tau0 | rule | U / U_expected - 1 | trend in window | surface / forcing | steps |"
    );
    println!("|---|---|---|---|---|---|---|---|---|");
    for (case, result) in &results {
        let liquid = match case.liquid {
            SettlingLiquid::Viscous { .. } => "viscous",
            SettlingLiquid::PaperWater => "paper water",
        };
        match result {
            Ok(r) => println!(
                "| {:.2} | {liquid} | {} | {:.5} | {} | {} | {} | {:.3} | {} |",
                case.d_cells,
                case.reynolds,
                r.tau,
                case.gain.name(),
                pct(r.error),
                pct(r.trend),
                r.surface_over_forcing,
                r.steps
            ),
            Err(e) => {
                println!("| {:.2} | {liquid} | {} | | {} | {e} | | | |", case.d_cells, case.reynolds, case.gain.name())
            }
        }
    }
    if let Some((_, Ok(r))) = results.iter().find(|(_, r)| r.is_ok()) {
        println!(
            "\nExpected velocity = Schiller-Naumann x wall factor {:.4} at Re {} (tank {} x {} cells at D/dx {:.2}).",
            r.expected / r.unbounded,
            r.case.reynolds,
            r.cells[0],
            r.cells[1],
            r.case.d_cells
        );
    }
}
