//! The lane form of the contact law against the scalar law, bit for bit:
//! the pair kernel evaluates contacts `LANES` at a time and must round
//! exactly as one contact at a time, in every regime of the law (springs
//! new and old, sticking and sliding, rolling and not, touching and
//! separating fast enough that the normal force clamps to zero).

use dem_proc::lanes::{self, Lanes, LANES};
use dem_proc::law::{evaluate, evaluate_lanes, ContactInput, ContactLanes, ContactLaw, OutputLanes};
use dem_proc::rng::SplitMix64;
use runtime::isa::Isa;

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

fn law(rolling_friction: f64, tangential_stiffness: f64) -> ContactLaw {
    ContactLaw {
        normal_stiffness: 2000.0,
        tangential_stiffness,
        damping_ratio: dem_proc::law::damping_ratio_for(0.88),
        friction: 0.577,
        rolling_friction,
    }
}

/// A contact of the lab column's scale (2.5 mm grains, overlaps up to 1e-5 m,
/// speeds up to 0.5 m/s), with each regime switched on by `kind`.
fn contact(rng: &mut SplitMix64, kind: u64) -> (ContactInput, [f64; 3]) {
    let mut v3 = |s: f64| [s * rng.symmetric(), s * rng.symmetric(), s * rng.symmetric()];
    let d = v3(1.0);
    let len = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
    let n = [d[0] / len, d[1] / len, d[2] / len];
    let (vel_i, vel_j) = (v3(0.5), v3(0.5));
    // Kinds 0–1: no rolling (equal spins); 2: no spring yet; 3: a spring
    // long enough to slide; 4: separating faster than the spring pushes.
    let omega_i = v3(200.0);
    let omega_j = if kind <= 1 { omega_i } else { v3(200.0) };
    let spring = match kind {
        2 => [0.0; 3],
        3 => v3(1e-3),
        _ => v3(1e-6),
    };
    let (vel_i, vel_j) = if kind == 4 { ([-n[0], -n[1], -n[2]], [n[0], n[1], n[2]]) } else { (vel_i, vel_j) };
    let mut rng2 = SplitMix64::new(kind);
    let (ri, rj) = (1.25e-3 * (1.0 + 0.1 * rng2.symmetric()), 1.25e-3 * (1.0 + 0.1 * rng2.symmetric()));
    let overlap = 1e-5 * rng2.uniform() + 1e-9;
    let (mi, mj) = (2600.0 * 4.19 * ri * ri * ri, 2600.0 * 4.19 * rj * rj * rj);
    let input = ContactInput {
        n,
        overlap,
        arm_i: ri - 0.5 * overlap,
        arm_j: rj - 0.5 * overlap,
        vel_i,
        omega_i,
        vel_j,
        omega_j,
        effective_mass: mi * mj / (mi + mj),
        inv_inertia_sum: 1.0 / (0.4 * mi * ri * ri) + 1.0 / (0.4 * mj * rj * rj),
        rolling_diameter: 4.0 * ri * rj / (ri + rj),
    };
    (input, spring)
}

fn gather(inputs: &[ContactInput], f: impl Fn(&ContactInput) -> f64) -> Lanes {
    Lanes(std::array::from_fn(|l| f(&inputs[l])))
}

fn gather3(inputs: &[ContactInput], f: impl Fn(&ContactInput) -> [f64; 3]) -> [Lanes; 3] {
    std::array::from_fn(|a| Lanes(std::array::from_fn(|l| f(&inputs[l])[a])))
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
            let (inputs, springs): (Vec<_>, Vec<_>) =
                (0..LANES as u64).map(|l| contact(&mut rng, (batch + l) % 5)).unzip();
            let lanes_in = ContactLanes {
                n: gather3(&inputs, |c| c.n),
                overlap: gather(&inputs, |c| c.overlap),
                arm_i: gather(&inputs, |c| c.arm_i),
                arm_j: gather(&inputs, |c| c.arm_j),
                vel_i: gather3(&inputs, |c| c.vel_i),
                omega_i: gather3(&inputs, |c| c.omega_i),
                vel_j: gather3(&inputs, |c| c.vel_j),
                omega_j: gather3(&inputs, |c| c.omega_j),
                effective_mass: gather(&inputs, |c| c.effective_mass),
                inv_inertia_sum: gather(&inputs, |c| c.inv_inertia_sum),
                rolling_diameter: gather(&inputs, |c| c.rolling_diameter),
            };
            let mut spring_lanes = [Lanes::splat(0.0); 3];
            for (l, s) in springs.iter().enumerate() {
                lanes::set_lane(&mut spring_lanes, l, *s);
            }
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
