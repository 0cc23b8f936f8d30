//! Prints the lattice around one cell of the last `/lbm/state` of a
//! recording: what a watchdog stop looked like. `cargo run --release -p lbm_proc --example
//! inspect_cell -- run.mcap I J K` (or `max` for the fastest liquid cell).

use lbm_proc::fluid::flags;
use lbm_proc::lattice::{E, Q};
use lbm_proc::run::LbmState;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let path = &args[1];
    let bytes = std::fs::read(path).unwrap();
    let (t, s) = LbmState::last_in_recording(&bytes).expect("a recording with an /lbm/state");
    // `max` instead of I J K: the liquid cell with the largest speed.
    let c: [usize; 3] = if args[2] == "max" {
        let f = &s.fluid;
        let [nx, ny, nz] = f.dims;
        let n = nx * ny * nz;
        let mut best = (0.0, 0);
        for cell in 0..n {
            if !flags::is_liquid(f.flags[cell]) {
                continue;
            }
            let (mut rho, mut jm) = (1.0, [0.0f64; 3]);
            for q in 0..Q {
                let g = f.population(q, cell) as f64;
                rho += g;
                for a in 0..3 {
                    jm[a] += E[q][a] as f64 * g;
                }
            }
            let u2 = (jm[0] * jm[0] + jm[1] * jm[1] + jm[2] * jm[2]) / (rho * rho);
            if u2 > best.0 {
                best = (u2, cell);
            }
        }
        let cell = best.1;
        println!(
            "fastest liquid cell {:?}: |u| = {:.4} lattice",
            [cell % nx, (cell / nx) % ny, cell / (nx * ny)],
            best.0.sqrt()
        );
        [cell % nx, (cell / nx) % ny, cell / (nx * ny)]
    } else {
        [args[2].parse().unwrap(), args[3].parse().unwrap(), args[4].parse().unwrap()]
    };
    println!("LBM state at t = {} s, step {}", t as f64 * 1e-9, s.fluid.step);
    let f = &s.fluid;
    let [nx, ny, nz] = f.dims;
    for dz in -2i64..=2 {
        for dy in -1i64..=1 {
            let mut line = String::new();
            for dxx in -3i64..=3 {
                let (i, j, k) = (c[0] as i64 + dxx, c[1] as i64 + dy, c[2] as i64 + dz);
                if i < 0 || j < 0 || k < 0 || i >= nx as i64 || j >= ny as i64 || k >= nz as i64 {
                    continue;
                }
                let cell = (k as usize * ny + j as usize) * nx + i as usize;
                let fl = f.flags[cell];
                let mut rho = 1.0;
                let mut jm = [0.0; 3];
                for q in 0..Q {
                    let g = f.population(q, cell) as f64;
                    rho += g;
                    for a in 0..3 {
                        jm[a] += E[q][a] as f64 * g;
                    }
                }
                let tag = match fl {
                    flags::FLUID => "F",
                    flags::INTERFACE => "I",
                    flags::GAS => "G",
                    _ => "W",
                };
                let fill = if fl == flags::INTERFACE { f.mass[cell] / rho } else { 1.0 };
                line += &format!(
                    "{tag}{:>6.3}/{:>5.2}/{:>6.3},{:>6.3},{:>6.3} ",
                    rho,
                    fill,
                    jm[0] / rho,
                    jm[1] / rho,
                    jm[2] / rho
                );
            }
            println!("z{:+} y{:+}: {line}", dz, dy);
        }
    }
}
