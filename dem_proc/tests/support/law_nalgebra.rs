//! [`dem_proc::law::evaluate_lanes`] written with nalgebra: `Vector3` over
//! simba's `AutoF64x8` (eight f64 lanes, the hand-written kernel's width),
//! the same operations in the same order. Kept to measure, side by side,
//! whether nalgebra could replace the hand-written `vec3`/`lanes`
//! (docs/ARCHITECTURE.md, `vec3`): `tests/law_nalgebra.rs` checks it rounds
//! bit for bit as the solver's kernel, `examples/law_nalgebra.rs` times both.

#![allow(dead_code)] // each user takes what it needs

use dem_proc::lanes::{Lanes, Lanes3, LANES};
use dem_proc::law::{ContactLanes, ContactLaw};
use nalgebra::{SimdComplexField, SimdPartialOrd, SimdValue, Vector3};
use simba::simd::AutoF64x8;

pub type V = Vector3<AutoF64x8>;

/// [`ContactLanes`] as nalgebra vectors.
#[derive(Clone, Copy)]
pub struct ContactNa {
    pub n: V,
    pub overlap: AutoF64x8,
    pub arm_i: AutoF64x8,
    pub arm_j: AutoF64x8,
    pub vel_i: V,
    pub omega_i: V,
    pub vel_j: V,
    pub omega_j: V,
    pub effective_mass: AutoF64x8,
    pub inv_inertia_sum: AutoF64x8,
    pub rolling_diameter: AutoF64x8,
}

pub fn scalar(l: Lanes) -> AutoF64x8 {
    simba::simd::AutoSimd(l.0)
}

pub fn vector(v: Lanes3) -> V {
    V::new(scalar(v[0]), scalar(v[1]), scalar(v[2]))
}

pub fn lanes3(v: &V) -> Lanes3 {
    [Lanes(v.x.0), Lanes(v.y.0), Lanes(v.z.0)]
}

impl ContactNa {
    pub fn of(c: &ContactLanes) -> Self {
        ContactNa {
            n: vector(c.n),
            overlap: scalar(c.overlap),
            arm_i: scalar(c.arm_i),
            arm_j: scalar(c.arm_j),
            vel_i: vector(c.vel_i),
            omega_i: vector(c.omega_i),
            vel_j: vector(c.vel_j),
            omega_j: vector(c.omega_j),
            effective_mass: scalar(c.effective_mass),
            inv_inertia_sum: scalar(c.inv_inertia_sum),
            rolling_diameter: scalar(c.rolling_diameter),
        }
    }
}

/// Force on i, torques on i and j.
pub struct OutputNa {
    pub force_i: V,
    pub torque_i: V,
    pub torque_j: V,
}

#[inline(always)]
fn splat(x: f64) -> AutoF64x8 {
    AutoF64x8::splat(x)
}

/// Per lane: `if s > t { then } else { otherwise }`.
#[inline(always)]
fn if_greater(s: AutoF64x8, t: AutoF64x8, then: V, otherwise: V) -> V {
    let cond = s.simd_gt(t);
    then.zip_map(&otherwise, |a, b| a.select(cond, b))
}

/// The law of `dem_proc::law::evaluate_lanes`, line by line.
#[inline(always)]
pub fn evaluate_lanes_nalgebra(law: &ContactLaw, c: &ContactNa, dt: f64, spring: &mut V) -> OutputNa {
    let zero = splat(0.0);
    let n = c.n;
    let ri = n * c.arm_i;
    let rj = n * -c.arm_j;
    let v_contact = (c.vel_i + c.omega_i.cross(&ri)) - (c.vel_j + c.omega_j.cross(&rj));
    let approach = v_contact.dot(&n);
    let v_t = v_contact - n * approach;

    let sqrt_m = c.effective_mass.simd_sqrt();
    let c_n = splat(2.0 * law.damping_ratio * law.normal_stiffness.sqrt()) * sqrt_m;
    let f_n = (splat(law.normal_stiffness) * c.overlap + c_n * approach).simd_max(zero);

    let old_len2 = spring.dot(spring);
    let projected = *spring - n * spring.dot(&n);
    let new_len2 = projected.dot(&projected);
    let rotated = if_greater(new_len2, zero, projected * (old_len2 / new_len2).simd_sqrt(), V::repeat(zero));
    *spring = if_greater(old_len2, zero, rotated, *spring);
    *spring += v_t * splat(dt);

    let k_t = law.tangential_stiffness;
    let c_t = splat(2.0 * law.damping_ratio * k_t.sqrt()) * sqrt_m;
    let f_t = *spring * splat(-k_t) - v_t * c_t;
    let cap = splat(law.friction) * f_n;
    let f_t_len2 = f_t.dot(&f_t);
    let cap2 = cap * cap;
    let capped = f_t * (cap / f_t_len2.simd_sqrt());
    if k_t > 0.0 {
        let slid = (capped + v_t * c_t) * splat(-1.0 / k_t);
        *spring = if_greater(f_t_len2, cap2, slid, *spring);
    }
    let f_t = if_greater(f_t_len2, cap2, capped, f_t);

    let force_i = n * -f_n + f_t;
    let mut torque_i = ri.cross(&f_t);
    let mut torque_j = rj.cross(&-f_t);

    if law.rolling_friction > 0.0 {
        let w = c.omega_i - c.omega_j;
        let w_roll = w - n * w.dot(&n);
        let w_len = w_roll.dot(&w_roll).simd_sqrt();
        let m_full = splat(law.rolling_friction) * f_n * splat(0.5) * c.rolling_diameter;
        let m_stop = w_len / (c.inv_inertia_sum * splat(dt));
        let m = m_full.simd_min(m_stop);
        let t = w_roll * (m / w_len);
        let rolled_i = if_greater(f_n, zero, torque_i - t, torque_i);
        let rolled_j = if_greater(f_n, zero, torque_j + t, torque_j);
        torque_i = if_greater(w_len, zero, rolled_i, torque_i);
        torque_j = if_greater(w_len, zero, rolled_j, torque_j);
    }
    OutputNa { force_i, torque_i, torque_j }
}

const _: () = assert!(LANES == 8, "AutoF64x8 is the kernel's width");
