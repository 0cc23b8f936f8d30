//! The contact law of Ceccato et al. 2020 (Eqs. 1–3), one kernel shared by
//! grain–grain and grain–wall contacts.
//!
//! * Normal (Eq. 1): F_n = k_n δ + c_n δ̇ with c_n = 2ζ√(k_n m*), clamped at
//!   zero (never attractive). ζ is derived from the restitution e so that the
//!   clamped law rebounds with exactly e ([`crate::contact::damping_ratio_no_tension`]).
//! * Tangential (Eq. 2): history spring ξ (k_t = ratio·k_n) plus dashpot
//!   c_t = 2ζ√(k_t m*), capped by Coulomb μ_s F_n (the paper prints `max`; the
//!   physical law is the cap). While sliding the spring is truncated so that
//!   spring + dashpot equals the cap (as LAMMPS `gran/hooke/history`).
//!   The spring is rotated onto the current tangent plane every step.
//! * Rolling (Eq. 3): torque of magnitude μ_r F_n D_eff/2 against the relative
//!   rolling velocity ω_i − ω_j (its part normal to n), limited to the torque
//!   that would just stop that rolling in one step, so it can stop rolling but
//!   never reverse it. D_eff = 2 D_i D_j/(D_i + D_j) between grains (D for
//!   equal grains) and D_i against a wall. Twisting is not resisted.

use crate::lanes::{self, Lanes, Lanes3};
use crate::vec3::{add, cross, dot, neg, norm2, scale, sub, Vec3};

pub use crate::lanes::LANES;

/// Material constants of one kind of contact (grain–grain or grain–wall).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ContactLaw {
    /// k_n, N/m.
    pub normal_stiffness: f64,
    /// k_t, N/m.
    pub tangential_stiffness: f64,
    /// ζ, the damping ratio of both dashpots.
    pub damping_ratio: f64,
    /// μ_s.
    pub friction: f64,
    /// μ_r.
    pub rolling_friction: f64,
}

/// Geometry and kinematics of one contact, seen from body i.
/// `n` points from i towards j (or towards the wall).
#[derive(Debug, Clone, Copy)]
pub struct ContactInput {
    pub n: Vec3,
    /// Overlap δ > 0, m.
    pub overlap: f64,
    /// Distance from each centre to the contact point, m (0 for j = wall).
    pub arm_i: f64,
    pub arm_j: f64,
    pub vel_i: Vec3,
    pub omega_i: Vec3,
    pub vel_j: Vec3,
    pub omega_j: Vec3,
    /// m* = m_i m_j/(m_i + m_j), kg.
    pub effective_mass: f64,
    /// 1/I_i + 1/I_j, 1/(kg m²).
    pub inv_inertia_sum: f64,
    /// D_eff for the rolling torque, m.
    pub rolling_diameter: f64,
}

/// What a contact does to both bodies.
#[derive(Debug, Clone, Copy)]
pub struct ContactOutput {
    /// Force on i (j receives the opposite), N.
    pub force_i: Vec3,
    /// Torques on i and j, N m.
    pub torque_i: Vec3,
    pub torque_j: Vec3,
}

/// Evaluates the contact and advances its tangential spring `spring` by `dt`.
/// The law as written, one contact with its branches: the reference that
/// [`evaluate_lanes`], which the solver runs, is tested against bit for bit
/// (`tests/pair_lanes.rs`).
///
/// Pre: `overlap > 0`, `n` unit. Post: `|F_t| ≤ μ F_n`, `F_n ≥ 0`; the spring
/// lies in the tangent plane.
#[inline(always)]
pub fn evaluate(law: &ContactLaw, c: &ContactInput, dt: f64, spring: &mut Vec3) -> ContactOutput {
    let n = c.n;
    let ri = scale(n, c.arm_i);
    let rj = scale(n, -c.arm_j);
    let v_contact = sub(add(c.vel_i, cross(c.omega_i, ri)), add(c.vel_j, cross(c.omega_j, rj)));
    let approach = dot(v_contact, n);
    let v_t = sub(v_contact, scale(n, approach));

    let sqrt_m = c.effective_mass.sqrt();
    let c_n = 2.0 * law.damping_ratio * law.normal_stiffness.sqrt() * sqrt_m;
    let f_n = (law.normal_stiffness * c.overlap + c_n * approach).max(0.0);

    // Keep the spring in the tangent plane with its length (the contact frame rotated).
    let old_len2 = norm2(*spring);
    if old_len2 > 0.0 {
        let projected = sub(*spring, scale(n, dot(*spring, n)));
        let new_len2 = norm2(projected);
        *spring = if new_len2 > 0.0 { scale(projected, (old_len2 / new_len2).sqrt()) } else { [0.0; 3] };
    }
    *spring = add(*spring, scale(v_t, dt));

    let k_t = law.tangential_stiffness;
    let c_t = 2.0 * law.damping_ratio * k_t.sqrt() * sqrt_m;
    let mut f_t = sub(scale(*spring, -k_t), scale(v_t, c_t));
    let cap = law.friction * f_n;
    let f_t_len2 = norm2(f_t);
    if f_t_len2 > cap * cap {
        f_t = scale(f_t, cap / f_t_len2.sqrt());
        if k_t > 0.0 {
            *spring = scale(add(f_t, scale(v_t, c_t)), -1.0 / k_t);
        }
    }

    let force_i = add(scale(n, -f_n), f_t);
    let mut torque_i = cross(ri, f_t);
    let mut torque_j = cross(rj, neg(f_t));

    if law.rolling_friction > 0.0 && f_n > 0.0 {
        let w = sub(c.omega_i, c.omega_j);
        let w_roll = sub(w, scale(n, dot(w, n)));
        let w_len = norm2(w_roll).sqrt();
        if w_len > 0.0 {
            let m_full = law.rolling_friction * f_n * 0.5 * c.rolling_diameter;
            let m_stop = w_len / (c.inv_inertia_sum * dt);
            let m = m_full.min(m_stop);
            let t = scale(w_roll, m / w_len);
            torque_i = sub(torque_i, t);
            torque_j = add(torque_j, t);
        }
    }

    ContactOutput { force_i, torque_i, torque_j }
}

/// The damping ratio for restitution `e` under this law's no-tension clamp.
pub fn damping_ratio_for(e: f64) -> f64 {
    crate::contact::damping_ratio_no_tension(e)
}

/// [`ContactInput`] of [`LANES`] contacts, field by field.
#[derive(Debug, Clone, Copy)]
pub struct ContactLanes {
    pub n: Lanes3,
    pub overlap: Lanes,
    pub arm_i: Lanes,
    pub arm_j: Lanes,
    pub vel_i: Lanes3,
    pub omega_i: Lanes3,
    pub vel_j: Lanes3,
    pub omega_j: Lanes3,
    pub effective_mass: Lanes,
    pub inv_inertia_sum: Lanes,
    pub rolling_diameter: Lanes,
}

/// [`ContactOutput`] of [`LANES`] contacts.
#[derive(Debug, Clone, Copy)]
pub struct OutputLanes {
    pub force_i: Lanes3,
    pub torque_i: Lanes3,
    pub torque_j: Lanes3,
}

/// [`evaluate`] on [`LANES`] contacts at once, bit for bit the same in
/// every lane: the same operations in the same order, its branches turned
/// into lane selects (both sides computed, one kept). The pair kernel
/// spends most of its time in this law's chain of divisions and square
/// roots, whose latency one contact at a time left the CPU idle; a batch
/// runs them as vector instructions, two independent chains at once.
///
/// Pre: as [`evaluate`] in every lane whose result is used; other lanes
/// may hold any finite contact. Post: as [`evaluate`], lane by lane.
#[inline(always)]
pub fn evaluate_lanes(law: &ContactLaw, c: &ContactLanes, dt: f64, spring: &mut Lanes3) -> OutputLanes {
    let zero = Lanes::splat(0.0);
    let n = c.n;
    let ri = lanes::scale(n, c.arm_i);
    let rj = lanes::scale(n, -c.arm_j);
    let v_contact =
        lanes::sub(lanes::add(c.vel_i, lanes::cross(c.omega_i, ri)), lanes::add(c.vel_j, lanes::cross(c.omega_j, rj)));
    let approach = lanes::dot(v_contact, n);
    let v_t = lanes::sub(v_contact, lanes::scale(n, approach));

    let sqrt_m = c.effective_mass.sqrt();
    let c_n = Lanes::splat(2.0 * law.damping_ratio * law.normal_stiffness.sqrt()) * sqrt_m;
    let f_n = (Lanes::splat(law.normal_stiffness) * c.overlap + c_n * approach).max(zero);

    let old_len2 = lanes::norm2(*spring);
    let projected = lanes::sub(*spring, lanes::scale(n, lanes::dot(*spring, n)));
    let new_len2 = lanes::norm2(projected);
    let rotated = lanes::if_greater(new_len2, zero, lanes::scale(projected, (old_len2 / new_len2).sqrt()), [zero; 3]);
    *spring = lanes::if_greater(old_len2, zero, rotated, *spring);
    *spring = lanes::add(*spring, lanes::scale(v_t, Lanes::splat(dt)));

    let k_t = law.tangential_stiffness;
    let c_t = Lanes::splat(2.0 * law.damping_ratio * k_t.sqrt()) * sqrt_m;
    let f_t = lanes::sub(lanes::scale(*spring, Lanes::splat(-k_t)), lanes::scale(v_t, c_t));
    let cap = Lanes::splat(law.friction) * f_n;
    let f_t_len2 = lanes::norm2(f_t);
    let cap2 = cap * cap;
    let capped = lanes::scale(f_t, cap / f_t_len2.sqrt());
    if k_t > 0.0 {
        let slid = lanes::scale(lanes::add(capped, lanes::scale(v_t, c_t)), Lanes::splat(-1.0 / k_t));
        *spring = lanes::if_greater(f_t_len2, cap2, slid, *spring);
    }
    let f_t = lanes::if_greater(f_t_len2, cap2, capped, f_t);

    let force_i = lanes::add(lanes::scale(n, -f_n), f_t);
    let mut torque_i = lanes::cross(ri, f_t);
    let mut torque_j = lanes::cross(rj, lanes::neg(f_t));

    if law.rolling_friction > 0.0 {
        let w = lanes::sub(c.omega_i, c.omega_j);
        let w_roll = lanes::sub(w, lanes::scale(n, lanes::dot(w, n)));
        let w_len = lanes::norm2(w_roll).sqrt();
        let m_full = Lanes::splat(law.rolling_friction) * f_n * Lanes::splat(0.5) * c.rolling_diameter;
        let m_stop = w_len / (c.inv_inertia_sum * Lanes::splat(dt));
        let m = m_full.min(m_stop);
        let t = lanes::scale(w_roll, m / w_len);
        let rolled_i = lanes::if_greater(f_n, zero, lanes::sub(torque_i, t), torque_i);
        let rolled_j = lanes::if_greater(f_n, zero, lanes::add(torque_j, t), torque_j);
        torque_i = lanes::if_greater(w_len, zero, rolled_i, torque_i);
        torque_j = lanes::if_greater(w_len, zero, rolled_j, torque_j);
    }

    OutputLanes { force_i, torque_i, torque_j }
}
