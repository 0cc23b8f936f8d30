//! The lane form of the contact law against the scalar law, bit for bit:
//! the pair kernel evaluates contacts `LANES` at a time and must round
//! exactly as one contact at a time, in every regime of the law (springs
//! new and old, sticking and sliding, rolling and not, touching and
//! separating fast enough that the normal force clamps to zero).

use dem_proc::lanes::{self, Lanes, LANES};
use dem_proc::law::{evaluate, evaluate_lanes, ContactLanes, ContactLaw, OutputLanes};
use dem_proc::rng::SplitMix64;
use runtime::isa::Isa;

#[path = "support/contacts.rs"]
mod contacts;
use contacts::{batch as contact_batch, law};

/// The law built for AVX2, as the pair kernel's AVX2 build inlines it.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn evaluate_lanes_avx2(law: &ContactLaw, c: &ContactLanes, dt: f64, spring: &mut [Lanes; 3]) -> OutputLanes {
    evaluate_lanes(law, c, dt, spring)
}

fn evaluate_lanes_on(isa: Isa, law: &ContactLaw, c: &ContactLanes, dt: f64, spring: &mut [Lanes; 3]) -> OutputLanes {
    match isa {
        #[cfg(target_arch = "x86_64")]
        // SAFETY: only levels from `Isa::all_supported` are passed.
        Isa::Avx2 => unsafe { evaluate_lanes_avx2(law, c, dt, spring) },
        _ => evaluate_lanes(law, c, dt, spring),
    }
}

#[test]
fn lanes_round_exactly_as_the_scalar_law() {
    let mut rng = SplitMix64::new(11);
    let dt = 1.4e-6;
    let mut regimes = [0usize; 3]; // sliding, rolling, clamped
    for (isa, law) in Isa::all_supported()
        .into_iter()
        .flat_map(|isa| [law(0.05, 571.4), law(0.0, 571.4), law(0.05, 0.0)].map(|law| (isa, law)))
    {
        for batch in 0..400u64 {
            let contacts::Batch { inputs, springs, lanes: lanes_in, mut spring_lanes } = contact_batch(&mut rng, batch);
            let out = evaluate_lanes_on(isa, &law, &lanes_in, dt, &mut spring_lanes);
            for l in 0..LANES {
                let mut spring = springs[l];
                let expected = evaluate(&law, &inputs[l], dt, &mut spring);
                let bits = |v: [f64; 3]| v.map(f64::to_bits);
                assert_eq!(
                    bits(lanes::lane(&out.force_i, l)),
                    bits(expected.force_i),
                    "force, {} batch {batch} lane {l}",
                    isa.name()
                );
                assert_eq!(
                    bits(lanes::lane(&out.torque_i, l)),
                    bits(expected.torque_i),
                    "torque i, batch {batch} lane {l}"
                );
                assert_eq!(
                    bits(lanes::lane(&out.torque_j, l)),
                    bits(expected.torque_j),
                    "torque j, batch {batch} lane {l}"
                );
                assert_eq!(bits(lanes::lane(&spring_lanes, l)), bits(spring), "spring, batch {batch} lane {l}");
                let dot = |a: [f64; 3], b: [f64; 3]| a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
                let f_n = -dot(expected.force_i, inputs[l].n);
                let f_t2 = dot(expected.force_i, expected.force_i) - f_n * f_n;
                if f_n == 0.0 {
                    regimes[2] += 1;
                } else if f_t2.sqrt() > 0.999 * law.friction * f_n {
                    regimes[0] += 1;
                }
                if law.rolling_friction > 0.0 && inputs[l].omega_i != inputs[l].omega_j && f_n > 0.0 {
                    regimes[1] += 1;
                }
            }
        }
    }
    // Every regime was exercised, so a select that kept the wrong side in
    // any of them would have failed above.
    assert!(regimes.iter().all(|&c| c > 100), "regimes sliding/rolling/clamped hit {regimes:?} times");
}
