//! Prints, from the last `/lbm/state` of a recording, the liquid's pressure
//! against the hydrostatic pressure under its own free surface, averaged
//! over y in boxes of 10 × 5 cells (x × z): where the liquid is under
//! suction. `cargo run --release -p lbm_proc --example pressure_map --
//! run.mcap DX DT` (lattice spacing in m and time step in s).

use lbm_proc::fluid::flags;
use lbm_proc::lattice::Q;
use lbm_proc::run::LbmState;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let bytes = std::fs::read(&args[1]).unwrap();
    let (dx, dt): (f64, f64) = (args[2].parse().unwrap(), args[3].parse().unwrap());
    // `gauge` as a fourth argument: the pressure itself instead of its excess over hydrostatic.
    let gauge = args.get(4).is_some_and(|a| a == "gauge");
    let (t, s) = LbmState::last_in_recording(&bytes).expect("a recording with an /lbm/state");
    let f = &s.fluid;
    let [nx, ny, nz] = f.dims;
    let pa_per_drho = 1000.0 * (dx / dt).powi(2) / 3.0;
    println!("t = {:.4} s; mean (p - rho g (z_top - z)) in kPa, boxes of 10 x 5 cells; '.' no liquid", t as f64 * 1e-9);
    let (bx, bz) = (10, 5);
    let mut sum = vec![0.0; nx.div_ceil(bx) * nz.div_ceil(bz)];
    let mut cnt = vec![0usize; sum.len()];
    let mut min = (f64::INFINITY, [0usize; 3]);
    for y in 0..ny {
        for x in 0..nx {
            let top = (0..nz).rev().find(|&z| flags::is_liquid(f.flags[(z * ny + y) * nx + x]));
            let Some(top) = top else { continue };
            for z in 0..=top {
                let c = (z * ny + y) * nx + x;
                if f.flags[c] != flags::FLUID {
                    continue;
                }
                let rho = 1.0 + (0..Q).map(|q| f.population(q, c) as f64).sum::<f64>();
                let p = (rho - 1.0) * pa_per_drho;
                let hydro = if gauge { 0.0 } else { 1000.0 * 9.81 * (top - z) as f64 * dx };
                let k = (z / bz) * nx.div_ceil(bx) + x / bx;
                sum[k] += p - hydro;
                cnt[k] += 1;
                if p < min.0 {
                    min = (p, [x, y, z]);
                }
            }
        }
    }
    let xmax =
        (0..nx).rev().find(|&x| (0..nz.div_ceil(bz)).any(|zb| cnt[zb * nx.div_ceil(bx) + x / bx] > 0)).unwrap_or(0);
    for zb in (0..nz.div_ceil(bz)).rev() {
        let row: Vec<usize> = (0..=xmax / bx).collect();
        if row.iter().all(|&xb| cnt[zb * nx.div_ceil(bx) + xb] == 0) {
            continue;
        }
        let mut line = format!("z {:3} ", zb * bz);
        for xb in row {
            let k = zb * nx.div_ceil(bx) + xb;
            if cnt[k] == 0 {
                line += "     .";
            } else {
                line += &format!("{:6.2}", sum[k] / cnt[k] as f64 / 1e3);
            }
        }
        println!("{line}");
    }
    println!("lowest fluid pressure {:.2} kPa at cell {:?}", min.0 / 1e3, min.1);
    // Layers of the column's inner part (x < 50 cells): how many cells of each kind, and the fluid's state.
    println!(
        "layers over x < 50: z, fluid / interface / gas cells, mean gauge p of fluid (kPa), mean u_z of liquid (m/s)"
    );
    for z in (0..nz).rev() {
        let (mut nf, mut ni, mut ng, mut p, mut uz) = (0, 0, 0, 0.0, 0.0);
        for y in 0..ny {
            for x in 0..50.min(nx) {
                let c = (z * ny + y) * nx + x;
                match f.flags[c] {
                    flags::FLUID | flags::INTERFACE => {
                        let rho = 1.0 + (0..Q).map(|q| f.population(q, c) as f64).sum::<f64>();
                        let jz: f64 =
                            (0..Q).map(|q| lbm_proc::lattice::E[q][2] as f64 * f.population(q, c) as f64).sum();
                        uz += jz / rho * dx / dt;
                        if f.flags[c] == flags::FLUID {
                            nf += 1;
                            p += (rho - 1.0) * pa_per_drho;
                        } else {
                            ni += 1;
                        }
                    }
                    flags::GAS => ng += 1,
                    _ => {}
                }
            }
        }
        if nf + ni == 0 {
            continue;
        }
        println!(
            "z {z:3}: {nf:5} {ni:5} {ng:5}  p {:7.3}  u_z {:7.4}",
            p / nf.max(1) as f64 / 1e3,
            uz / (nf + ni) as f64
        );
    }
}
