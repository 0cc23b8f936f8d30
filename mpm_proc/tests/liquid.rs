//! The liquid points' pressure law, tension cap and volume rule on free
//! water (no skeleton): Joukowsky's water hammer, the impulse a cavitating
//! block passes through its cavity, and a soft column compressed by its
//! own weight (docs/mpm.md, "Pore pressure").

mod common;

use mpm_proc::solver::Mpm;

const G: f64 = 9.81;
const RHO: f64 = 1000.0;
/// Column of water: width and height, m.
const L0: f64 = 0.04;
const H0: f64 = 0.06;

/// A free-water column L0 × H0 in a 0.04 × 0.12 m box (floor and side
/// walls hold the normal velocity, the soil removed), stress free, with
/// the given `[mpm]` lines.
fn water_column(mpm: &str) -> Mpm {
    common::free_water_column(L0, H0, RHO, mpm)
}

/// The `[mpm]` keys of `transfer`: under AFLIP the water points take the
/// FLIP share too (the scenes keep the pore water on APIC,
/// `liquid_flip_share = 0`, which here would be APIC again).
fn transfer_keys(transfer: &str) -> String {
    match transfer {
        "aflip" => "transfer = \"aflip\"\nliquid_flip_share = 0.9".to_string(),
        other => format!("transfer = \"{other}\""),
    }
}

/// Both transfers under the default implicit pore pressure (free water
/// steps at its own wave, so the scheme resolves the hammer too: a
/// backward-Euler step damps only what it does not resolve), and APIC
/// under the explicit per-point law.
const TRANSFERS_AND_SCHEMES: [(&str, &str); 3] = [("apic", "implicit"), ("aflip", "implicit"), ("apic", "explicit")];

/// A free-water block L0 × H0 lifted to mid-box (no wall above or below
/// it, gravity off) whose halves fly apart at ±v0: a tension wave runs
/// from the mid-plane into each half, behind it the water at rest under
/// p = −ρ c v0 (Joukowsky), c = √(K/ρ), unless the tension cap T stops it
/// at −T and a cavity opens. Returns, at 0.9 of the half-height's transit
/// time (H0/2)/c, the mean pressure of the points within h/2 of the
/// mid-plane, the momentum the upper half beyond the plane's element lost,
/// the least pressure of any point, and the time over which that loss was
/// counted (from 2h/c, when the front has passed the plane's element).
fn split_block(cavitation: f64, transfer: &str, scheme: &str) -> (f64, f64, f64, f64) {
    let k = 2.0e7;
    let mut m = water_column(&format!(
        "element_size = 0.002\nliquid_bulk_modulus = {k:e}\ncavitation_threshold = {cavitation:e}\ndamping = 0.0\n\
         pressure_scheme = \"{scheme}\"\n{}",
        transfer_keys(transfer)
    ));
    m.params.gravity = [0.0, 0.0];
    let (v0, lift, mid) = (0.05, 0.03, 0.03 + 0.5 * H0);
    let l = &mut m.state.liquid.set;
    for (x, v) in l.x.iter_mut().zip(l.v.iter_mut()) {
        x[1] += lift;
        *v = [0.0, if x[1] > mid { v0 } else { -v0 }];
    }
    let upper: Vec<usize> = (0..l.len()).filter(|&p| l.x[p][1] > mid).collect();
    // Points in the plane's element share its nodes with the other half and
    // cannot part from it within the element (a cavity is resolved one
    // element wide): the force through the plane is read off the points
    // beyond that element, which the front reaches at h/c.
    let h = m.grid.h;
    let beyond: Vec<usize> = upper.iter().copied().filter(|&p| l.x[p][1] > mid + h).collect();
    // By id (the indices before the first step): the solver reorders its points.
    let up_momentum = |m: &Mpm| -> f64 {
        let (set, index) = (&m.state.liquid.set, m.state.liquid.set.by_id());
        beyond.iter().map(|&p| set.mass[index[p]] * set.v[index[p]][1]).sum()
    };
    let c = (k / RHO).sqrt();
    let steps = (0.9 * 0.5 * H0 / c / m.params.dt).round() as usize;
    // The momentum is read from when the front has crossed the plane's
    // element and one more (2h/c): before, the first transfers' projection
    // of the velocity jump onto the grid moves momentum across the set's
    // edge by an amount that depends on the transfer (APIC projects it
    // all, AFLIP a tenth), not on the pull through the plane.
    let start = (2.0 * h / c / m.params.dt).round() as usize;
    let mut p0 = 0.0;
    let mut least: f64 = 0.0;
    for step in 0..steps {
        if step == start {
            p0 = up_momentum(&m);
        }
        m.step();
        least = least.min(m.state.liquid.pressure.iter().cloned().fold(0.0, f64::min));
    }
    let l = &m.state.liquid;
    let near: Vec<f64> =
        (0..l.set.len()).filter(|&p| (l.set.x[p][1] - mid).abs() < 0.5 * h).map(|p| l.pressure[p]).collect();
    let plane = near.iter().sum::<f64>() / near.len() as f64;
    (plane, p0 - up_momentum(&m), least, (steps - start) as f64 * m.params.dt)
}

#[test]
fn water_hammer_follows_joukowsky() {
    let (k, v0) = (2.0e7, 0.05);
    let joukowsky = RHO * (k / RHO).sqrt() * v0; // 7.07 kPa
    for (transfer, scheme) in TRANSFERS_AND_SCHEMES {
        let (plane, lost, least, t) = split_block(1e9, transfer, scheme);
        eprintln!(
            "{transfer} {scheme}, no cap: mid-plane p {plane:.0} Pa (−ρcv0 = {:.0}), upper half's momentum lost {lost:.4e} (ρcv0 L0 t = {:.4e}), least p {least:.0}",
            -joukowsky,
            joukowsky * L0 * t
        );
        // The plateau behind the front: 2 % (the points within h/2 of the
        // plane average over the front's first element; measured 0.05 %
        // explicit under APIC (0.4 % explicit under AFLIP, session 18, no
        // longer run); 1.6 % implicit under both, whose backward-Euler
        // step at c Δt/h = 0.5 smears the front).
        assert!(
            (plane + joukowsky).abs() < 0.02 * joukowsky,
            "{transfer} {scheme}: mid-plane pressure {plane} vs {}",
            -joukowsky
        );
        // The lower half's pull through the plane is the only force on the
        // upper half: it loses ρ c v0 L0 t of momentum (measured 0.1 %
        // explicit, 2.2 % implicit). 3 %: the pull ramps up over the
        // front's first element.
        assert!(
            (lost - joukowsky * L0 * t).abs() < 0.03 * joukowsky * L0 * t,
            "{transfer} {scheme}: momentum lost {lost}"
        );
    }
}

#[test]
fn cavitating_water_holds_no_more_tension_than_its_threshold() {
    let (k, v0, cap) = (2.0e7, 0.05, 1000.0);
    for (transfer, scheme) in TRANSFERS_AND_SCHEMES {
        let (plane, lost, least, t) = split_block(cap, transfer, scheme);
        eprintln!(
            "{transfer} {scheme}, cap 1 kPa: mid-plane p {plane:.1} Pa, momentum lost {lost:.4e} (T L0 t = {:.4e}), least p {least:.1}",
            cap * L0 * t
        );
        // No point below −T, and the mid-plane sits at the cap (a cavity
        // opens there instead of the −7.07 kPa of the uncapped hammer).
        assert!(least >= -cap * (1.0 + 1e-12), "{transfer} {scheme}: a point at {least} Pa");
        assert!((plane + cap).abs() < 0.02 * cap, "{transfer} {scheme}: mid-plane at {plane} Pa");
        // The plane pulls with T L0 only, 1/7 of the uncapped hammer's pull.
        assert!(lost < 0.2 * RHO * (k / RHO).sqrt() * v0 * L0 * t, "{transfer} {scheme}: momentum lost {lost}");
        // Under APIC the upper half keeps v0 less T/(ρc) and loses T L0 t
        // of momentum (measured 99.8 %). Under AFLIP the cavity element's
        // points keep 90 % of their own velocities each step, so its layer
        // does not settle and the loss depends on where it is counted:
        // 94.8 % beyond the plane's element, 109 % over the whole half.
        if transfer == "apic" {
            assert!((lost - cap * L0 * t).abs() < 0.03 * cap * L0 * t, "momentum lost {lost} vs {}", cap * L0 * t);
        }
    }
}

/// Under both pore-pressure schemes; the settlement to 1 % under the
/// explicit one only (below).
#[test]
fn a_soft_column_settles_by_its_weight_and_its_volume_follows_its_density() {
    soft_column("explicit");
    soft_column("implicit");
}

fn soft_column(scheme: &str) {
    // K = 1e5 Pa: the base strain ρ g H0/K is 0.59 %, the top settles by
    // 0.18 mm, 4.4 % of an element (much softer and the top element, a
    // free surface's, flickers across the filling-ratio threshold as it
    // empties). A material point first
    // at height z0 carries the weight above it, p = ρ g (H0 − z0), and has
    // settled by the compression below it, ρ g (H0 z0 − z0²/2)/K.
    let k = 1.0e5;
    let mut m = water_column(&format!("liquid_bulk_modulus = {k:e}\ndamping = 0.7\npressure_scheme = \"{scheme}\""));
    let z0: Vec<f64> = m.state.liquid.set.x.iter().map(|x| x[1]).collect();
    let steps = (0.6 / m.params.dt) as usize;
    for _ in 0..steps {
        m.step();
    }
    let h = m.grid.h;
    let l = &m.state.liquid;
    assert!(l.set.max_speed() < 1e-4, "still moving at {} m/s", l.set.max_speed());
    let settled = |z: f64| RHO * G * (H0 * z - 0.5 * z * z) / k;
    // Per element row below the top one (which holds the free surface,
    // p = 0 on its free points): the mean pressure against the weight
    // above the row's centre, and each point's settlement. The increments
    // are per element, so from a stress-free start an element's points
    // share one pressure: the row mean is what the weight fixes.
    let rows = ((H0 / h).round() as usize) - 1;
    let (mut ep, mut es): (f64, f64) = (0.0, 0.0);
    for r in 0..rows {
        // z0 by id: the solver reorders its points.
        let z0 = |p: usize| z0[l.set.id_of(p) as usize];
        let inside: Vec<usize> = (0..l.set.len()).filter(|&p| (z0(p) / h) as usize == r).collect();
        let mean = inside.iter().map(|&p| l.pressure[p]).sum::<f64>() / inside.len() as f64;
        ep = ep.max((mean - RHO * G * (H0 - (r as f64 + 0.5) * h)).abs() / (RHO * G * H0));
        for &p in &inside {
            es = es.max((z0(p) - l.set.x[p][1] - settled(z0(p))).abs() / settled(H0 - h));
        }
    }
    eprintln!(
        "soft column, {scheme}: row pressure vs weight above {ep:.5}, settlement {es:.4} of {:.3} mm",
        settled(H0 - h) * 1e3
    );
    // Force balance with the mass conserved: 0.5 % of ρ g H0.
    assert!(ep < 0.005, "{scheme}: pressure off the weight above by {ep}");
    // The incremental law sums log strains (p = −K ln(V/V0)), the closed
    // form is linear: 1 % of the settlement at a 0.6 % strain. Under the
    // implicit scheme an element's points share its centroid's pressure,
    // each point's volume follows that one pressure, and the settlement
    // profile is the element-wise one (measured 1.2 %): 2 %.
    let bar = if scheme == "explicit" { 0.01 } else { 0.02 };
    assert!(es < bar, "{scheme}: settlement off by {es}");
    // The volume rule V = m/(n ρ_L(p)), ρ_L(p) = ρ_L (1 + p/K): the water
    // first below z_c claims the area it now fills, L0 (z_c − settled(z_c)),
    // to 2e-4: a twentieth of the compression (4.3e-3), which a volume
    // that ignored the pressure would miss whole.
    let zc = 0.032;
    let claimed: f64 = (0..l.set.len()).filter(|&p| z0[p] < zc).map(|p| l.set.volume[p]).sum();
    let filled = L0 * (zc - settled(zc));
    eprintln!("{scheme}: claimed area {claimed:.6e} vs filled {filled:.6e} (uncompressed {:.6e})", L0 * zc);
    assert!((claimed - filled).abs() < 2e-4 * filled, "{scheme}: claimed {claimed} vs {filled}");
}
