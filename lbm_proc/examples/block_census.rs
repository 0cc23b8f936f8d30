//! What a block-sparse lattice would hold, from the `/lbm/state` frames of
//! a recording: for cubic blocks of 4, 8, 16 and 32 cells and for the
//! lattice's own x-segments of 128 × 1 × 1 (`fluid/layout.rs`), the blocks
//! that hold liquid, the blocks a step needs (those within one cell of a
//! liquid cell: where the surface can move to and what its cells pull
//! from), the share of their cells that hold liquid, the memory of the
//! populations (two lattices of 19 f32) and the flags and masses, the same
//! for every block needed at any frame so far (what a lattice that never
//! frees a block holds); and, for a split of the needed blocks into N slabs
//! along x balanced by block count, the cells on the cut faces (each face
//! sends 5 of its 19 populations each way every step). docs/SCALING.md.
//!
//! `cargo run --release -p lbm_proc --example block_census -- RUN/run.mcap`
//! (a run recorded with `--set output.state_interval=...`).

use lbm_proc::fluid::flags;
use lbm_proc::run::LbmState;

const BYTES_PER_CELL: usize = 2 * 19 * 4 + 1 + 8;

fn main() {
    let path = std::env::args().nth(1).expect("usage: block_census RUN/run.mcap");
    let bytes = std::fs::read(&path).expect("readable recording");
    let stream = mcap::MessageStream::new(&bytes).expect("an MCAP recording");
    println!("t_s,block,liquid_cells,liquid_blocks,needed_blocks,fill,memory_mb,dense_mb,ever_needed_mb,slabs,cut_cells_per_cut,max_over_mean");
    const SHAPES: [[usize; 3]; 5] = [[4, 4, 4], [8, 8, 8], [16, 16, 16], [32, 32, 32], [128, 1, 1]];
    let mut ever: Vec<Vec<bool>> = Vec::new();
    for m in stream {
        let m = m.expect("a readable message");
        if m.channel.topic != schemas::topics::LBM_STATE {
            continue;
        }
        let state = LbmState::decode(&m.data).expect("an /lbm/state");
        let f = &state.fluid;
        let [nx, ny, nz] = f.dims;
        let liquid: Vec<bool> = f.flags.iter().map(|&g| flags::is_liquid(g)).collect();
        let liquid_cells = liquid.iter().filter(|&&l| l).count();
        // The one-cell dilation of the liquid: the cells a step can touch.
        let mut near = liquid.clone();
        for z in 0..nz {
            for y in 0..ny {
                for x in 0..nx {
                    if !liquid[(z * ny + y) * nx + x] {
                        continue;
                    }
                    for dz in z.saturating_sub(1)..=(z + 1).min(nz - 1) {
                        for dy in y.saturating_sub(1)..=(y + 1).min(ny - 1) {
                            for dx in x.saturating_sub(1)..=(x + 1).min(nx - 1) {
                                near[(dz * ny + dy) * nx + dx] = true;
                            }
                        }
                    }
                }
            }
        }
        for (s, shape) in SHAPES.iter().enumerate() {
            let [sx, sy, sz] = *shape;
            let [bx, by, bz] = [nx.div_ceil(sx), ny.div_ceil(sy), nz.div_ceil(sz)];
            let (mut has_liquid, mut needed) = (vec![false; bx * by * bz], vec![false; bx * by * bz]);
            for z in 0..nz {
                for y in 0..ny {
                    for x in 0..nx {
                        let c = (z * ny + y) * nx + x;
                        let k = ((z / sz) * by + y / sy) * bx + x / sx;
                        has_liquid[k] |= liquid[c];
                        needed[k] |= near[c];
                    }
                }
            }
            if ever.len() <= s {
                ever.push(vec![false; needed.len()]);
            }
            ever[s].iter_mut().zip(&needed).for_each(|(e, &n)| *e |= n);
            let liquid_blocks = has_liquid.iter().filter(|&&v| v).count();
            let needed_blocks = needed.iter().filter(|&&v| v).count();
            let block_cells = sx * sy * sz;
            let cells = needed_blocks * block_cells;
            let memory = (cells * BYTES_PER_CELL) as f64 / 1e6;
            let ever_memory = (ever[s].iter().filter(|&&v| v).count() * block_cells * BYTES_PER_CELL) as f64 / 1e6;
            let dense = (nx * ny * nz * BYTES_PER_CELL) as f64 / 1e6;
            // Blocks per x-column of blocks, to cut into slabs of equal count.
            let per_column: Vec<usize> =
                (0..bx).map(|i| (0..by * bz).filter(|&r| needed[r * bx + i]).count()).collect();
            for slabs in [2usize, 4, 8, 16] {
                let target = needed_blocks as f64 / slabs as f64;
                let (mut cuts, mut acc, mut loads, mut load) = (Vec::new(), 0usize, Vec::new(), 0usize);
                for (i, &n) in per_column.iter().enumerate() {
                    acc += n;
                    load += n;
                    if acc as f64 >= target * (cuts.len() + 1) as f64 && cuts.len() + 1 < slabs && i + 1 < bx {
                        cuts.push(i + 1);
                        loads.push(load);
                        load = 0;
                    }
                }
                loads.push(load);
                // Cells on a cut: needed cells in the x-plane of the cut's first cell.
                let cut_cells: usize = cuts
                    .iter()
                    .map(|&i| {
                        let x = i * sx;
                        (0..ny * nz).filter(|&r| near[r * nx + x.min(nx - 1)]).count()
                    })
                    .sum();
                let mean = needed_blocks as f64 / loads.len() as f64;
                let max = *loads.iter().max().unwrap_or(&0) as f64;
                println!(
                    "{:.3},{sx}x{sy}x{sz},{liquid_cells},{liquid_blocks},{needed_blocks},{:.3},{memory:.0},{dense:.0},{ever_memory:.0},{slabs},{:.0},{:.2}",
                    state.time,
                    liquid_cells as f64 / cells as f64,
                    cut_cells as f64 / cuts.len().max(1) as f64,
                    if mean > 0.0 { max / mean } else { 0.0 }
                );
            }
        }
    }
}
