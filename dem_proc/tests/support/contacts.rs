//! Contacts of the lab column's scale in every regime of the law, one at a
//! time and gathered into lanes: shared by the law's bit-for-bit tests and
//! the nalgebra comparison (`examples/law_nalgebra.rs`).

#![allow(dead_code)] // each user takes what it needs

use dem_proc::lanes::{self, Lanes, Lanes3, LANES};
use dem_proc::law::{ContactInput, ContactLanes, ContactLaw};
use dem_proc::rng::SplitMix64;

/// The lab column's grain law with the given μ_r and k_t.
pub fn law(rolling_friction: f64, tangential_stiffness: f64) -> ContactLaw {
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
pub fn contact(rng: &mut SplitMix64, kind: u64) -> (ContactInput, [f64; 3]) {
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

fn gather3(inputs: &[ContactInput], f: impl Fn(&ContactInput) -> [f64; 3]) -> Lanes3 {
    std::array::from_fn(|a| Lanes(std::array::from_fn(|l| f(&inputs[l])[a])))
}

/// [`LANES`] contacts of kinds `batch`, `batch + 1`, … (mod 5): one at a
/// time and gathered into lanes, with their springs.
pub struct Batch {
    pub inputs: Vec<ContactInput>,
    pub springs: Vec<[f64; 3]>,
    pub lanes: ContactLanes,
    pub spring_lanes: Lanes3,
}

pub fn batch(rng: &mut SplitMix64, batch: u64) -> Batch {
    let (inputs, springs): (Vec<_>, Vec<_>) = (0..LANES as u64).map(|l| contact(rng, (batch + l) % 5)).unzip();
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
    Batch { inputs, springs, lanes: lanes_in, spring_lanes }
}
