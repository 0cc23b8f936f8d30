//! Bulk D3Q19 throughput against a STREAM triad, for 1 and 2 threads.
//!
//! `cargo run --release -p lbm_proc --example bench_bulk [nx ny nz steps]`

use lbm_proc::bench::{bulk_mlups, bytes_per_update, triad_bandwidth};
use lbm_proc::fluid::{Collision, FluidParams};

fn main() {
    let args: Vec<usize> = std::env::args().skip(1).filter_map(|a| a.parse().ok()).collect();
    let dims = if args.len() >= 3 { [args[0], args[1], args[2]] } else { [128, 64, 64] };
    let steps = args.get(3).copied().unwrap_or(20);
    let bytes = bytes_per_update::<f32>();
    println!(
        "box {}x{}x{} periodic, {steps} steps per run, best of 3; f32, {bytes} B per cell update",
        dims[0], dims[1], dims[2]
    );
    let configs = [
        ("BGK, C = 0", FluidParams { smagorinsky: 0.0, ..FluidParams::new(0.6) }),
        ("TRT 3/16 + Smagorinsky 0.16", FluidParams { collision: Collision::TRT_3_16, ..FluidParams::new(0.6) }),
    ];
    for threads in [1, 2] {
        let pool = match rayon::ThreadPoolBuilder::new().num_threads(threads).build() {
            Ok(p) => p,
            Err(e) => {
                eprintln!("cannot build a pool of {threads} threads: {e}");
                continue;
            }
        };
        pool.install(|| {
            let bw = triad_bandwidth(1 << 24, 5);
            let bound = bw / bytes as f64 / 1e6;
            println!("{threads} thread(s): triad {:.2} GB/s -> bound {bound:.1} MLUPS", bw / 1e9);
            for (name, params) in configs {
                let mlups = bulk_mlups::<f32>(dims, params, steps, 3);
                println!("  {name:<30} {mlups:7.2} MLUPS  ({:.0} % of bound)", 100.0 * mlups / bound);
            }
            let mlups = bulk_mlups::<f64>(dims, configs[1].1, steps / 2, 3);
            let bound64 = bw / bytes_per_update::<f64>() as f64 / 1e6;
            println!(
                "  {:<30} {mlups:7.2} MLUPS  ({:.0} % of f64 bound {bound64:.1})",
                "f64 TRT + Smagorinsky",
                100.0 * mlups / bound64
            );
        });
    }
}
