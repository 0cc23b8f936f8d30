//! The contact law in the solver's hand-written lanes against the same law
//! in nalgebra's `Vector3<AutoF64x8>`, timed side by side in one run on the
//! same contacts (both bit for bit equal: `tests/law_nalgebra.rs`), in the
//! baseline build and, where the CPU has it, the AVX2 build the pair kernel
//! runs.
//!
//! ```sh
//! cargo run --release -p dem_proc --example law_nalgebra
//! ```

use std::hint::black_box;
use std::time::Instant;

use dem_proc::lanes::{Lanes, LANES};
use dem_proc::law::{evaluate_lanes, ContactLanes, ContactLaw};
use dem_proc::rng::SplitMix64;
use runtime::isa::Isa;

#[path = "../tests/support/contacts.rs"]
mod contacts;
#[path = "../tests/support/law_nalgebra.rs"]
mod law_nalgebra;

use law_nalgebra::{evaluate_lanes_nalgebra, vector, ContactNa, V};

/// Batches per pass: 32k contacts, whose inputs (~3 MB) stay in cache, so
/// the time is the law's arithmetic.
const BATCHES: usize = 4096;
const PASSES: usize = 50;
const ROUNDS: usize = 7;

#[inline(always)]
fn hand_written(law: &ContactLaw, batches: &[ContactLanes], springs: &mut [[Lanes; 3]], dt: f64) -> f64 {
    let mut sum = 0.0;
    for (c, s) in batches.iter().zip(springs) {
        sum += evaluate_lanes(law, c, dt, s).force_i[0].0[0];
    }
    sum
}

#[inline(always)]
fn with_nalgebra(law: &ContactLaw, batches: &[ContactNa], springs: &mut [V], dt: f64) -> f64 {
    let mut sum = 0.0;
    for (c, s) in batches.iter().zip(springs) {
        sum += evaluate_lanes_nalgebra(law, c, dt, s).force_i.x.0[0];
    }
    sum
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn hand_written_avx2(law: &ContactLaw, b: &[ContactLanes], s: &mut [[Lanes; 3]], dt: f64) -> f64 {
    hand_written(law, b, s, dt)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn with_nalgebra_avx2(law: &ContactLaw, b: &[ContactNa], s: &mut [V], dt: f64) -> f64 {
    with_nalgebra(law, b, s, dt)
}

/// Nanoseconds per contact of `pass`, the best of `PASSES` passes.
fn time(mut pass: impl FnMut() -> f64) -> f64 {
    let mut best = f64::INFINITY;
    for _ in 0..PASSES {
        let t = Instant::now();
        black_box(pass());
        best = best.min(t.elapsed().as_secs_f64());
    }
    best / (BATCHES * LANES) as f64 * 1e9
}

fn main() {
    let law = contacts::law(0.05, 571.4);
    let dt = 1.4e-6;
    let mut rng = SplitMix64::new(5);
    let made: Vec<_> = (0..BATCHES as u64).map(|b| contacts::batch(&mut rng, b)).collect();
    let batches: Vec<ContactLanes> = made.iter().map(|b| b.lanes).collect();
    let batches_na: Vec<ContactNa> = batches.iter().map(ContactNa::of).collect();
    let springs: Vec<[Lanes; 3]> = made.iter().map(|b| b.spring_lanes).collect();
    let springs_na: Vec<V> = springs.iter().map(|s| vector(*s)).collect();
    println!("contact law, {LANES} lanes, {} contacts per pass, best of {PASSES} passes per round", BATCHES * LANES);
    println!("| build | round | hand-written ns/contact | nalgebra ns/contact | nalgebra / hand-written |");
    println!("|---|---|---|---|---|");
    for isa in Isa::all_supported() {
        let mut ratios = Vec::new();
        for round in 0..ROUNDS {
            // The law keeps the springs bounded (capped by friction), so
            // passes reuse them rather than pay a copy each.
            let (mut s, mut s_na) = (springs.clone(), springs_na.clone());
            let (a, b) = match isa {
                #[cfg(target_arch = "x86_64")]
                // SAFETY: only levels from `Isa::all_supported` are run.
                Isa::Avx2 => (
                    time(|| unsafe { hand_written_avx2(&law, &batches, &mut s, dt) }),
                    time(|| unsafe { with_nalgebra_avx2(&law, &batches_na, &mut s_na, dt) }),
                ),
                _ => (
                    time(|| hand_written(&law, &batches, &mut s, dt)),
                    time(|| with_nalgebra(&law, &batches_na, &mut s_na, dt)),
                ),
            };
            ratios.push(b / a);
            println!("| {} | {round} | {a:.2} | {b:.2} | {:.3} |", isa.name(), b / a);
        }
        ratios.sort_by(f64::total_cmp);
        println!("| {} | median | | | {:.3} |", isa.name(), ratios[ROUNDS / 2]);
    }
}
