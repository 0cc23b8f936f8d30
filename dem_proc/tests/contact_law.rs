//! Analytic checks of the contact law on one or two grains
//! (`shared/reference/analytic-checks.md`).

use dem_proc::contact::{contact_time_no_tension_scaled, damping_ratio_no_tension, restitution_no_tension};
use dem_proc::law::ContactLaw;
use dem_proc::world::{Grains, Numerics, Wall, World};

/// The lab grain: D = 2.5 mm, ρ = 2625 kg/m³ (analytic-checks.md).
const R: f64 = 1.25e-3;
const RHO: f64 = 2625.0;
const KN: f64 = 2000.0;
const G: f64 = 9.81;

fn law(e: f64, mu: f64, mu_r: f64) -> ContactLaw {
    ContactLaw {
        normal_stiffness: KN,
        tangential_stiffness: 2.0 / 7.0 * KN,
        damping_ratio: damping_ratio_no_tension(e),
        friction: mu,
        rolling_friction: mu_r,
    }
}

fn floor() -> Wall {
    Wall::fixed("floor", [0.0; 3], [0.0, 0.0, 1.0], f64::INFINITY)
}

fn world(grains: Grains, walls: Vec<Wall>, law: ContactLaw, gravity: [f64; 3], dt: f64) -> World {
    let mut w = World::new(
        grains,
        walls,
        law,
        law,
        gravity,
        Numerics { dt, skin: 0.2 * R, sort_interval: 0 },
        ([-0.05; 3], [0.05; 3]),
    );
    w.prime_forces();
    w
}

fn mass() -> f64 {
    RHO * 4.0 / 3.0 * std::f64::consts::PI * R.powi(3)
}

/// Measured (restitution, contact duration) of a head-on impact at `v0`.
/// The contact lasts while the normal force is non-zero (the law's own end criterion).
fn impact(e: f64, on_wall: bool, steps_per_contact: f64) -> (f64, f64, f64) {
    let m_eff = if on_wall { mass() } else { 0.5 * mass() };
    let zeta = damping_ratio_no_tension(e);
    let tc = contact_time_no_tension_scaled(zeta) / (KN / m_eff).sqrt();
    let dt = tc / steps_per_contact;
    let v0 = 0.1;
    let mut g = Grains::default();
    let walls = if on_wall {
        g.push([0.0, 0.0, R + 1e-5], [0.0, 0.0, -v0], R, RHO);
        vec![floor()]
    } else {
        g.push([0.0, 0.0, -R - 1e-5], [0.0, 0.0, v0 / 2.0], R, RHO);
        g.push([0.0, 0.0, R + 1e-5], [0.0, 0.0, -v0 / 2.0], R, RHO);
        vec![]
    };
    let mut w = world(g, walls, law(e, 0.5, 0.0), [0.0; 3], dt);
    let mut in_contact_steps = 0u64;
    let mut started = false;
    for _ in 0..(20.0 * steps_per_contact) as usize {
        w.step();
        let touching = w.grains.force[0][2].abs() > 0.0;
        if touching {
            started = true;
            in_contact_steps += 1;
        } else if started {
            break;
        }
    }
    let v_after = if on_wall { w.grains.vel[0][2] } else { w.grains.vel[1][2] - w.grains.vel[0][2] };
    (v_after / v0, in_contact_steps as f64 * dt, tc)
}

/// Velocity Verlet with the dashpot evaluated at the half-step velocity is
/// first-order in Δt/t_c for the damping (0.5 % at 200 steps per contact
/// for e = 0.3); at 1000 steps per contact the restitution is within 0.15 %
/// and the duration within two steps (0.2 %).
#[test]
fn normal_impact_restitution_and_duration() {
    for e in [0.3, 0.88, 0.99] {
        for on_wall in [true, false] {
            let (e_meas, tc_meas, tc) = impact(e, on_wall, 1000.0);
            assert!((e_meas - e).abs() / e < 1.5e-3, "e={e} wall={on_wall}: measured {e_meas}");
            assert!((tc_meas - tc).abs() / tc < 2e-3, "e={e} wall={on_wall}: t_c {tc_meas} vs {tc}");
        }
    }
    // The error converges with the step: 10x more steps, at least 4x smaller.
    let err = |spc| (impact(0.3, true, spc).0 - 0.3).abs();
    assert!(err(1000.0) < err(100.0) / 4.0, "{} vs {}", err(1000.0), err(100.0));
    // The lab grain on a wall: undamped π√(m/k) = 3.26e-4 s (analytic-checks.md);
    // the damped, no-tension contact ends ~3 % earlier, when the force reaches zero.
    let (_, tc_meas, tc) = impact(0.88, true, 1000.0);
    assert!(tc_meas < 3.26e-4 && tc_meas > 0.95 * 3.26e-4, "{tc_meas}");
    assert!((tc_meas - tc).abs() / tc < 2e-3);
}

/// At the run's default 25 steps per contact the restitution stays within 2 %.
#[test]
fn restitution_at_production_time_step() {
    let (e_meas, _, _) = impact(0.88, false, 25.0);
    assert!((e_meas - 0.88).abs() < 0.02 * 0.88, "{e_meas}");
    // The no-tension law with the textbook ζ would rebound harder than asked:
    let zeta_textbook = dem_proc::contact::damping_ratio_overlap(0.88);
    let e_textbook = restitution_no_tension(zeta_textbook);
    assert!(e_textbook > 0.881, "{e_textbook}");
}

/// A sphere launched sliding without spin on a flat floor decelerates at μg
/// until it rolls, at v = 5/7 v0 after t = 2 v0/(7 μ g).
#[test]
fn sliding_turns_into_rolling_at_five_sevenths() {
    let mu = 0.3;
    let v0 = 0.2;
    let m = mass();
    let dt = std::f64::consts::PI * (m / KN).sqrt() / 50.0;
    let sink = m * G / KN; // static overlap
    let mut g = Grains::default();
    g.push([0.0, 0.0, R - sink], [v0, 0.0, 0.0], R, RHO);
    let mut w = world(g, vec![floor()], law(0.5, mu, 0.0), [0.0, 0.0, -G], dt);
    let t_roll = 2.0 * v0 / (7.0 * mu * G);
    while w.time < 3.0 * t_roll {
        w.step();
    }
    let v = w.grains.vel[0][0];
    let slip = v - w.grains.omega[0][1] * R;
    assert!((v - 5.0 / 7.0 * v0).abs() < 0.005 * v0, "v = {v}, expected {}", 5.0 / 7.0 * v0);
    assert!(slip.abs() < 1e-3 * v0, "still slipping at {slip}");
}

/// A sphere with rolling blocked (μ_r large) on an incline sticks below the
/// friction angle and slides above it at g(sin θ − μ cos θ).
#[test]
fn incline_sticks_below_and_slides_above_friction_angle() {
    let mu: f64 = 0.5;
    let m = mass();
    let dt = std::f64::consts::PI * (m / KN).sqrt() / 50.0;
    let angle = mu.atan();
    for (factor, slides) in [(0.9, false), (1.1, true)] {
        let th = factor * angle;
        let gravity = [G * th.sin(), 0.0, -G * th.cos()];
        let sink = m * G * th.cos() / KN;
        let mut g = Grains::default();
        g.push([0.0, 0.0, R - sink], [0.0; 3], R, RHO);
        let mut w = world(g, vec![floor()], law(0.5, mu, 1e3), gravity, dt);
        // Let the contact settle, then measure the motion over 0.2 s.
        while w.time < 0.02 {
            w.step();
        }
        let (x0, v0, t0) = (w.grains.pos[0][0], w.grains.vel[0][0], w.time);
        while w.time < t0 + 0.2 {
            w.step();
        }
        let dx = w.grains.pos[0][0] - x0;
        let t = w.time - t0;
        if slides {
            let a = G * (th.sin() - mu * th.cos());
            let expected = v0 * t + 0.5 * a * t * t;
            assert!((dx - expected).abs() < 0.01 * expected, "θ = {factor} θ_f: slid {dx}, expected {expected}");
        } else {
            // The limited constant-torque rolling model holds rolling only to
            // within one step's worth of spin: it creeps at most at
            // g sin θ Δt / 0.4 (friction torque over I, times R, per step).
            let creep = G * th.sin() * dt / 0.4 * t;
            assert!(dx.abs() < creep, "θ = {factor} θ_f: moved {dx} m, creep bound {creep}");
            assert!(dx.abs() < 1e-3 * 0.5 * G * (1.1 * angle).sin() * t * t, "moved {dx} m");
        }
    }
}

/// Rolling resistance: a sphere rolling without slip at v0 stops after
/// v0² / ((10/7) μ_r g), and does not roll back.
#[test]
fn rolling_resistance_stopping_distance() {
    let (mu, mu_r, v0) = (0.577, 0.05, 0.1);
    let m = mass();
    let dt = std::f64::consts::PI * (m / KN).sqrt() / 50.0;
    let sink = m * G / KN;
    let mut g = Grains::default();
    g.push([0.0, 0.0, R - sink], [v0, 0.0, 0.0], R, RHO);
    g.omega[0] = [0.0, v0 / (R - sink), 0.0];
    let mut w = world(g, vec![floor()], law(0.5, mu, mu_r), [0.0, 0.0, -G], dt);
    let expected = v0 * v0 / (10.0 / 7.0 * mu_r * G);
    let t_stop = v0 / (5.0 / 7.0 * mu_r * G);
    while w.time < 1.5 * t_stop {
        w.step();
    }
    let d = w.grains.pos[0][0];
    assert!((d - expected).abs() < 0.02 * expected, "stopped after {d} m, expected {expected}");
    assert!(w.grains.vel[0][0].abs() < 1e-3 * v0, "still moving at {}", w.grains.vel[0][0]);
    let x_stop = d;
    while w.time < 2.0 * t_stop {
        w.step();
    }
    assert!((w.grains.pos[0][0] - x_stop).abs() < 1e-6, "rolled back");
}

/// Elastic (e = 1), frictionless grains in a closed box without gravity:
/// total energy (kinetic + springs) is conserved by velocity Verlet to
/// O((ω0 Δt)²); at 50 steps per contact the drift stays below 0.5 %.
#[test]
fn elastic_frictionless_gas_conserves_energy() {
    let mut rng = dem_proc::rng::SplitMix64::new(7);
    let mut g = Grains::default();
    let half = 0.01;
    for ix in 0..6 {
        for iy in 0..6 {
            for iz in 0..6 {
                let p = [
                    -half + (ix as f64 + 0.5) * 2.0 * half / 6.0,
                    -half + (iy as f64 + 0.5) * 2.0 * half / 6.0,
                    -half + (iz as f64 + 0.5) * 2.0 * half / 6.0,
                ];
                let v = [rng.symmetric() * 0.3, rng.symmetric() * 0.3, rng.symmetric() * 0.3];
                g.push(p, v, R, RHO);
            }
        }
    }
    let walls = (0..3)
        .flat_map(|a| {
            [1.0, -1.0].map(|s| {
                let mut point = [0.0; 3];
                point[a] = -s * half;
                let mut normal = [0.0; 3];
                normal[a] = s;
                Wall::fixed(format!("w{a}{s}"), point, normal, f64::INFINITY)
            })
        })
        .collect();
    let m = mass();
    let dt = std::f64::consts::PI * (0.5 * m / KN).sqrt() / 50.0;
    let mut w = world(g, walls, law(1.0, 0.0, 0.0), [0.0; 3], dt);
    let e0 = w.kinetic_energy() + w.elastic_energy();
    let mut collisions = 0u64;
    for _ in 0..20_000 {
        w.step();
        collisions += w.coordination.iter().map(|&c| c as u64).sum::<u64>();
    }
    let e1 = w.kinetic_energy() + w.elastic_energy();
    assert!(collisions > 1000, "too few contacts to test anything: {collisions}");
    assert!((e1 - e0).abs() / e0 < 5e-3, "energy {e0} -> {e1}");
}

/// Newton's second law for the whole set: with no gravity and no walls the
/// contact forces cancel in pairs, so the grains' momentum changes by
/// exactly the impulse of the external loads, which `external_impulse`
/// must count as the integrator applies it (half the old and half the new
/// load in a step where it changes), here through a collision and three
/// load changes.
#[test]
fn momentum_gained_equals_the_counted_external_impulse() {
    let mut g = Grains::default();
    g.push([0.0, 0.0, -R - 1e-5], [0.0, 0.0, 0.05], R, RHO);
    g.push([0.0, 0.0, R + 1e-5], [0.0, 0.0, -0.05], R, RHO);
    let dt = 2e-6;
    let mut w = world(g, vec![], law(0.5, 0.5, 0.05), [0.0; 3], dt);
    let p0 = w.momentum();
    let loads = [[1e-4, 0.0, 2e-4], [-3e-4, 1e-4, 5e-5], [2e-5, -2e-5, -4e-4]];
    for (change, load) in loads.iter().enumerate() {
        w.set_external_load(0, *load, [0.0; 3]);
        w.set_external_load(1, [0.5 * load[2], load[0], -load[1]], [0.0; 3]);
        for _ in 0..(200 + 37 * change) {
            w.step();
        }
    }
    let gained = w.momentum();
    let scale = 4e-4 * 400.0 * dt;
    for k in 0..3 {
        let d = gained[k] - p0[k] - w.external_impulse[k];
        assert!(
            d.abs() < 1e-9 * scale,
            "axis {k}: momentum change {} vs impulse {}",
            gained[k] - p0[k],
            w.external_impulse[k]
        );
    }
    assert!(w.external_impulse[0].abs() > 0.01 * scale, "the loads gave momentum along x");
}

/// A grain resting on a floor that rises at a constant speed rides it with
/// the static overlap m g / k_n: the dashpot sees the grain's speed
/// relative to the wall, which is nil once the grain moves with it. (A wall
/// whose contacts took it for fixed would hold the grain at
/// (m g + c_n v)/k_n, over 20× deeper at v = 0.05 m/s: 2.8e-6 m against
/// 1.05e-7 m when the wall's velocity is left out, checked.) The floor
/// travels ~140 skins, so the neighbour list's wall bookkeeping is exercised
/// too.
#[test]
fn a_grain_rides_a_moving_floor_at_the_static_overlap() {
    let m = mass();
    let zeta = damping_ratio_no_tension(0.5);
    let tc = contact_time_no_tension_scaled(zeta) / (KN / m).sqrt();
    let dt = tc / 50.0;
    let v = 0.05;
    let static_overlap = m * G / KN;
    let mut g = Grains::default();
    g.push([0.0, 0.0, R - static_overlap], [0.0, 0.0, 0.0], R, RHO);
    let mut rising = floor();
    rising.point = [0.0, 0.0, -0.02];
    rising.velocity = [0.0, 0.0, v];
    let mut w = world(g, vec![floor(), rising], law(0.5, 0.5, 0.0), [0.0, 0.0, -G], dt);
    // The fixed floor at z = 0 holds the grain until the rising one reaches
    // it at t = 0.02 / v = 0.4 s; then 0.3 s more (~ 170 contact times).
    // The rising floor meets the grain at v: the impact's overlap is at
    // most v √(m/k_n) (undamped), 50× the static one. A wall the neighbour
    // list had left out would reach the grain unseen and push in by up to
    // a skin (2.5e-4 m) before the next rebuild.
    let steps = (0.7 / dt) as usize;
    let impact_bound = v * (m / KN).sqrt();
    let mut deepest = 0.0_f64;
    for _ in 0..steps {
        w.step();
        deepest = deepest.max(R - (w.grains.pos[0][2] - w.walls[1].point[2]));
    }
    assert!(deepest < impact_bound, "deepest overlap {deepest:.3e} m against the impact's bound {impact_bound:.3e} m");
    let floor_z = w.walls[1].point[2];
    assert!((floor_z - (-0.02 + v * w.time)).abs() < 1e-9, "the floor moved with its velocity: {floor_z}");
    let overlap = R - (w.grains.pos[0][2] - floor_z);
    assert!((w.grains.vel[0][2] - v).abs() < 1e-4 * v, "grain speed {} against the floor's {v}", w.grains.vel[0][2]);
    assert!(
        (overlap / static_overlap - 1.0).abs() < 1e-3,
        "overlap {overlap:.4e} against m g / k_n = {static_overlap:.4e}"
    );
}
