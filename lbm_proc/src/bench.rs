//! Throughput of the bulk kernel against the machine's memory bandwidth.
//!
//! The step is memory-bound: per cell update it reads and writes 19
//! populations and reads one flag byte, [`bytes_per_update`] in all (153 B in
//! f32, as FluidX3D counts it). A CPU that write-allocates also reads each
//! written line first, adding 19·size bytes the count leaves out; the STREAM
//! triad is counted the same way (24 B per f64 element), so the ratio of the
//! two is fair. Run inside a rayon pool to choose the thread count.

use std::time::Instant;

use rayon::prelude::*;

use crate::fluid::{Faces, Fluid, FluidParams};
use crate::lattice::Q;
use crate::real::Real;
use runtime::isa::Isa;

/// Bytes moved per cell update: 19 populations read + 19 written, 1 flag byte.
pub fn bytes_per_update<T: Real>() -> usize {
    2 * Q * std::mem::size_of::<T>() + 1
}

/// STREAM triad a = b + s·c over `len` f64 elements, best of `reps`, in bytes/s
/// (24 bytes per element).
pub fn triad_bandwidth(len: usize, reps: usize) -> f64 {
    let b = vec![1.0_f64; len];
    let c = vec![2.0_f64; len];
    let mut a = vec![0.0_f64; len];
    let chunk = (len / (4 * rayon::current_num_threads())).max(4096);
    let mut best = f64::INFINITY;
    for r in 0..reps.max(1) {
        let s = 1.0 + r as f64 * 1e-3;
        let t = Instant::now();
        a.par_chunks_mut(chunk).zip(b.par_chunks(chunk)).zip(c.par_chunks(chunk)).for_each(|((a, b), c)| {
            match Isa::current() {
                #[cfg(target_arch = "x86_64")]
                // SAFETY: `Isa::current` returns Avx2 only where the CPU has AVX2 and FMA.
                Isa::Avx2 => unsafe { triad_avx2(a, b, c, s) },
                _ => triad(a, b, c, s),
            }
        });
        best = best.min(t.elapsed().as_secs_f64());
        std::hint::black_box(&a);
    }
    24.0 * len as f64 / best
}

#[inline(always)]
fn triad(a: &mut [f64], b: &[f64], c: &[f64], s: f64) {
    for i in 0..a.len() {
        a[i] = b[i] + s * c[i];
    }
}

/// The triad in the LBM kernel's instruction set, so the bound is not
/// understated on a CPU whose wide loads move more bytes per cycle.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn triad_avx2(a: &mut [f64], b: &[f64], c: &[f64], s: f64) {
    triad(a, b, c, s)
}

/// Million lattice updates per second of a periodic box of `dims` with the
/// given parameters, best of `reps` runs of `steps` steps (after one warm-up step).
pub fn bulk_mlups<T: Real>(dims: [usize; 3], params: FluidParams, steps: usize, reps: usize) -> f64 {
    let Ok(mut fluid) = Fluid::<T>::new(dims, [Faces::Periodic; 3], params) else {
        return f64::NAN;
    };
    let cells = (dims[0] * dims[1] * dims[2]) as f64;
    fluid.step();
    let mut best = f64::INFINITY;
    for _ in 0..reps.max(1) {
        let t = Instant::now();
        for _ in 0..steps {
            fluid.step();
        }
        best = best.min(t.elapsed().as_secs_f64());
    }
    cells * steps as f64 / best / 1e6
}
