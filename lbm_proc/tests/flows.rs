//! Analytic flows: Poiseuille (convergence order), shear-wave decay (with and
//! without Smagorinsky), hydrostatic tank. Reference formulas:
//! `analytic-checks.md` and `lbm-free-surface.md` §9. Each test prints its
//! measured numbers (`cargo test -- --nocapture`); docs/lbm.md records them.

use lbm_proc::fluid::{Collision, Faces, Fluid, FluidParams};
use lbm_proc::lattice::CS2;
use lbm_proc::real::Real;
use lbm_proc::Units;

/// Steady body-force-driven flow between bounce-back plates at y = 0 and y = h
/// (the walls lie half a cell beyond the first and last nodes), periodic in x
/// and z. Returns (LBM u_x at node centres, acceleration, ν).
fn poiseuille<T: Real>(h: usize, tau: f64, collision: Collision, u_max: f64) -> (Vec<f64>, f64, f64) {
    let nu = (tau - 0.5) / 3.0;
    let accel = 8.0 * nu * u_max / (h * h) as f64;
    let params = FluidParams { collision, smagorinsky: 0.0, acceleration: [accel, 0.0, 0.0], ..FluidParams::new(tau) };
    let mut fluid =
        Fluid::<T>::new([1, h, 1], [Faces::Periodic, Faces::Walls, Faces::Periodic], params).expect("valid parameters");
    // The slowest transient decays as exp(−π²ν t/h²): 18 h²/(π²ν) steps leave e⁻¹⁸ ≈ 1.5e-8 of it.
    let steps = (18.0 * (h * h) as f64 / (std::f64::consts::PI.powi(2) * nu)).ceil() as usize;
    for _ in 0..steps {
        fluid.step();
    }
    let u = (0..h).map(|j| fluid.moments([0, j, 0]).expect("in box").1[0]).collect();
    (u, accel, nu)
}

fn parabola(h: usize, accel: f64, nu: f64) -> Vec<f64> {
    (0..h)
        .map(|j| {
            let y = j as f64 + 0.5;
            accel * y * (h as f64 - y) / (2.0 * nu)
        })
        .collect()
}

fn rel_l2(u: &[f64], exact: &[f64]) -> f64 {
    let num: f64 = u.iter().zip(exact).map(|(a, b)| (a - b).powi(2)).sum();
    let den: f64 = exact.iter().map(|b| b * b).sum();
    (num / den).sqrt()
}

/// Diffusive scaling: ν and the physical body force fixed, Δt ∝ Δx², so τ is
/// the same at every resolution and u_L ∝ Δx (u_max = 0.02 at h = 8).
fn bgk_poiseuille_errors<T: Real>() -> Vec<(usize, f64, f64)> {
    let tau = 0.8;
    [8, 16, 32]
        .iter()
        .map(|&h| {
            let (u, accel, nu) = poiseuille::<T>(h, tau, Collision::Bgk, 0.02 * 8.0 / h as f64);
            let exact = parabola(h, accel, nu);
            // Half-way bounce-back under BGK adds a uniform slip
            // G(16Λ − 3)/(24ν), Λ = (τ − ½)² (lbm-free-surface.md §9, derived for
            // the D2Q9/D3Q19 unidirectional flow).
            let lambda = (tau - 0.5) * (tau - 0.5);
            let slip = accel * (16.0 * lambda - 3.0) / (24.0 * nu);
            let with_slip: Vec<f64> = exact.iter().map(|e| e + slip).collect();
            (h, rel_l2(&u, &exact), rel_l2(&u, &with_slip))
        })
        .collect()
}

/// f32 keeps ~7 digits of f_i − w_i ~ 1e-3, while the forcing adds ~1e-6 per
/// step: the steady profile carries a round-off floor of ~1e-4 of u_max
/// (measured 1.0e-4 at h = 32, where u_max = 0.005). f64 has none.
const F32_FLOOR: f64 = 2e-4;

#[test]
fn poiseuille_bgk_converges_at_second_order() {
    let e32 = bgk_poiseuille_errors::<f32>();
    let e64 = bgk_poiseuille_errors::<f64>();
    for (name, errs) in [("f32", &e32), ("f64", &e64)] {
        for w in errs.windows(2) {
            let order = (w[0].1 / w[1].1).ln() / (w[1].0 as f64 / w[0].0 as f64).ln();
            eprintln!(
                "Poiseuille BGK tau=0.8 {name}: h={} err={:.3e} -> h={} err={:.3e}: order {order:.3}",
                w[0].0, w[0].1, w[1].0, w[1].1
            );
            if name == "f64" {
                assert!((1.8..=2.2).contains(&order), "{name}: observed order {order}");
            }
        }
    }
    for (&(h, err32, slip32), &(_, err64, slip64)) in e32.iter().zip(&e64) {
        eprintln!(
            "  h={h}: rel. L2 vs parabola f32 {err32:.3e} f64 {err64:.3e}; vs parabola + BGK slip f32 {slip32:.2e} f64 {slip64:.2e}"
        );
        // The whole f64 error is the predicted slip: what is left is the
        // unconverged transient (1.5e-8 of u_max) and round-off.
        assert!(slip64 < 1e-7, "h={h}: residual {slip64:e} beyond the slip model");
        assert!(slip32 < F32_FLOOR, "h={h}: f32 residual {slip32:e}");
        assert!((err32 - err64).abs() < F32_FLOOR, "h={h}: f32 {err32:e} vs f64 {err64:e}");
    }
    // The slip makes the BGK error 0.52/h² of u_max here: 1.1e-2 at h = 8.
    assert!((e64[0].1 - 1.1e-2).abs() < 1e-3, "h=8 error {}", e64[0].1);
}

#[test]
fn poiseuille_trt_3_16_is_exact_at_every_resolution() {
    // Λ = 3/16 cancels the slip for any τ: the parabola is the exact discrete
    // solution, so only round-off and the transient (1.5e-8) remain.
    for tau in [0.55, 0.8, 1.4] {
        for h in [8, 16, 32] {
            let (u32, accel, nu) = poiseuille::<f32>(h, tau, Collision::TRT_3_16, 0.02 * 8.0 / h as f64);
            let (u64, ..) = poiseuille::<f64>(h, tau, Collision::TRT_3_16, 0.02 * 8.0 / h as f64);
            let exact = parabola(h, accel, nu);
            let (e32, e64) = (rel_l2(&u32, &exact), rel_l2(&u64, &exact));
            eprintln!("Poiseuille TRT 3/16 tau={tau} h={h}: rel. L2 f32 {e32:.2e}, f64 {e64:.2e}");
            assert!(e32 < F32_FLOOR, "f32 error {e32:e}");
            assert!(e64 < 1e-7, "f64 error {e64:e}");
        }
    }
}

/// Amplitude of the first sine mode of u_x(y), averaged over x and z.
fn shear_amplitude<T: Real>(fluid: &Fluid<T>) -> f64 {
    let [nx, ny, nz] = fluid.dims();
    let k = 2.0 * std::f64::consts::PI / ny as f64;
    let mut s = 0.0;
    for z in 0..nz {
        for y in 0..ny {
            for x in 0..nx {
                s += fluid.moments([x, y, z]).expect("in box").1[0] * (k * (y as f64 + 0.5)).sin();
            }
        }
    }
    2.0 * s / (nx * ny * nz) as f64
}

fn shear_wave<T: Real>(params: FluidParams, l: usize, amplitude: f64, t0: usize, t1: usize) -> (Vec<f64>, f64) {
    let dims = [4, l, 4];
    let mut fluid = Fluid::<T>::new(dims, [Faces::Periodic; 3], params).expect("valid parameters");
    let k = 2.0 * std::f64::consts::PI / l as f64;
    for z in 0..dims[2] {
        for y in 0..dims[1] {
            for x in 0..dims[0] {
                let u = amplitude * (k * (y as f64 + 0.5)).sin();
                fluid.set_equilibrium([x, y, z], 1.0, [u, 0.0, 0.0]).expect("in box");
            }
        }
    }
    let mut amps = Vec::new();
    for t in 0..=t1 {
        if t >= t0 {
            amps.push(shear_amplitude(&fluid));
        }
        if t < t1 {
            fluid.step();
        }
    }
    (amps, k)
}

fn decay_rate(amps: &[f64]) -> f64 {
    (amps[0] / amps[amps.len() - 1]).ln() / (amps.len() - 1) as f64
}

#[test]
fn shear_wave_decays_at_nu_k2() {
    // u_x = U sin(ky) is an exact Navier–Stokes solution (no advection), so
    // A(t) = U exp(−νk²t). U = 1e-4 keeps the O(u²) lattice errors at 1e-8.
    // L = 64: the O(k²) lattice dispersion is below 0.1 %. The first 200
    // steps are skipped: initialising at equilibrium (no f^neq) starts a
    // kinetic transient that decays in a few τ.
    for collision in [Collision::Bgk, Collision::TRT_3_16] {
        for tau in [0.6, 1.0] {
            let params = FluidParams { collision, smagorinsky: 0.0, ..FluidParams::new(tau) };
            let nu = (tau - 0.5) / 3.0;
            for (name, rate) in [
                ("f32", decay_rate(&shear_wave::<f32>(params, 64, 1e-4, 200, 2200).0)),
                ("f64", decay_rate(&shear_wave::<f64>(params, 64, 1e-4, 200, 2200).0)),
            ] {
                let k = 2.0 * std::f64::consts::PI / 64.0;
                let rel = rate / (nu * k * k) - 1.0;
                eprintln!(
                    "shear wave {collision:?} tau={tau} {name}: rate {rate:.6e}, nu k^2 {:.6e}, rel. error {rel:+.2e}",
                    nu * k * k
                );
                assert!(rel.abs() < 0.01, "{collision:?} tau={tau} {name}: rate off by {rel:e}");
            }
        }
    }
}

#[test]
fn shear_wave_with_smagorinsky_matches_the_eddy_viscosity() {
    // With ν_t = C²|∂u/∂y| the flow stays unidirectional, and projecting
    // ∂u/∂t = ∂y[(ν0 + C²|u'|)u'] on sin(ky) gives
    //   dA/dt = −k²A(ν0 + (8/3π) C² k A)
    // (⟨|cos|³⟩ = 4/3π; the sin(3ky)… harmonics that |u'| creates feed back
    // only at second order in ν_t/ν). Integrated exactly:
    //   A(t) = ν0 A0 e^{−ν0k²t} / (ν0 + βA0(1 − e^{−ν0k²t})), β = (8/3π)C²k.
    // The molecular rate is measured with C = 0 on the same lattice, so the
    // lattice's own O(k²) and start-up errors cancel in the eddy part.
    let (tau, c, l, a0) = (0.505, 0.16, 32, 0.08);
    let nu0 = (tau - 0.5) / 3.0;
    let (t0, t1) = (100, 3100);
    for collision in [Collision::Bgk, Collision::TRT_3_16] {
        let run = |c| {
            let params = FluidParams { collision, smagorinsky: c, ..FluidParams::new(tau) };
            shear_wave::<f32>(params, l, a0, 0, t1)
        };
        let ((amps, k), (amps0, _)) = (run(c), run(0.0));
        let beta = 8.0 / (3.0 * std::f64::consts::PI) * c * c * k;
        let model = |t: f64| {
            let e = (-nu0 * k * k * t).exp();
            nu0 * a0 * e / (nu0 + beta * a0 * (1.0 - e))
        };
        let measured = decay_rate(&amps[t0..]);
        let molecular = decay_rate(&amps0[t0..]);
        let predicted = (model(t0 as f64) / model(t1 as f64)).ln() / (t1 - t0) as f64;
        let eddy_measured = measured / molecular - 1.0;
        let eddy_predicted = predicted / (nu0 * k * k) - 1.0;
        eprintln!(
            "Smagorinsky shear wave {collision:?} tau0={tau} C={c} A0={a0} L={l}: rate {measured:.4e}; C=0 rate {molecular:.4e} \
             (nu0 k^2 {:.4e}); eddy/molecular measured {eddy_measured:.4}, predicted {eddy_predicted:.4}",
            nu0 * k * k
        );
        assert!(eddy_measured > 0.1, "Smagorinsky adds too little: {eddy_measured}");
        // BGK matches the model to 0.1 %. TRT (Λ = 3/16, so τ− ≈ 32 here)
        // measured 12 % more eddy viscosity than the model: its slowly relaxed
        // antisymmetric non-equilibrium streams into the next step's Π^neq,
        // which the local strain estimate does not correct for. Not
        // explained further yet (docs/lbm.md, open points); the bound keeps
        // it from drifting.
        let tolerance = if collision == Collision::Bgk { 0.05 } else { 0.15 };
        assert!(
            (eddy_measured / eddy_predicted - 1.0).abs() < tolerance,
            "eddy part measured {eddy_measured} vs predicted {eddy_predicted}"
        );
    }
}

#[test]
fn hydrostatic_tank_is_at_rest_with_rho_g_h_pressure() {
    // The paper's lattice (Δx = 0.6 mm, Δt = 80 µs, g_L = 1.046e-4) with a
    // viscous liquid (τ = 1, ν = 7.5e-4 m²/s) so that the start-up acoustic
    // waves die in a few thousand steps; 8 × 8 × 40 cells (2.4 cm deep).
    let units = Units::new(6e-4, 8e-5, 1000.0).expect("valid");
    let g = 9.81;
    let g_l = units.acceleration_to_lattice(g);
    let (nx, ny, nz) = (8, 8, 40);
    let params = FluidParams { acceleration: [0.0, 0.0, -g_l], ..FluidParams::new(1.0) };
    for name in ["f32", "f64"] {
        let (max_u, mass_drift, pressure) = if name == "f32" {
            tank::<f32>(params, [nx, ny, nz], g_l, &units)
        } else {
            tank::<f64>(params, [nx, ny, nz], g_l, &units)
        };
        // p(z) − p(top) against ρ0 g (z_top − z), z at the node centres.
        let mut worst_incompressible = 0.0_f64;
        let mut worst_compressible = 0.0_f64;
        let top = pressure[nz - 1];
        for (kz, &p) in pressure.iter().enumerate() {
            let depth = units.length_to_si((nz - 1 - kz) as f64);
            if kz + 1 < nz {
                let exact = 1000.0 * g * depth;
                worst_incompressible = worst_incompressible.max(((p - top) - exact).abs() / exact);
                // dp/dz = −ρg with p = c_s²ρ: ρ grows as exp(3 g_L depth).
                let rho_top = 1.0 + (top / units.pressure_to_si(1.0)) / CS2;
                let exact_c = units.pressure_from_density(rho_top * (3.0 * g_l * (nz - 1 - kz) as f64).exp()) - top;
                worst_compressible = worst_compressible.max(((p - top) - exact_c).abs() / exact_c);
            }
        }
        let u_si = units.velocity_to_si(max_u);
        eprintln!(
            "hydrostatic tank {name}: max|u| = {max_u:.2e} (lattice) = {u_si:.2e} m/s, \
             mass drift {mass_drift:.1e}; p vs rho0 g h max rel. error {worst_incompressible:.2e}, \
             vs compressible exp profile {worst_compressible:.2e}; bottom p - p_top = {:.2} Pa",
            pressure[0] - top
        );
        // Bound on |u|: population deviations are of size g_L·n_z ≈ 4e-3, so
        // round-off on them is ε·4e-3 per operation; 100 ε g_L n_z (5e-8 in
        // f32) is round-off level. In f64 that is 1e-17; the 1e-14 floor
        // leaves room for acoustic transients not fully damped in 12000 steps
        // (measured 2.6e-17, i.e. gone).
        let eps = if name == "f32" { f32::EPSILON as f64 } else { f64::EPSILON };
        let bound = (100.0 * eps * g_l * nz as f64).max(1e-14);
        assert!(max_u < bound, "{name}: max |u| = {max_u:e} above {bound:e}");
        // The incompressible law ρ0 g h ignores that ρ_L = 1 + 3g_L·depth:
        // error up to 3 g_L nz / 2 ≈ 6e-3 on average over the depth.
        assert!(worst_incompressible < 3.0 * g_l * nz as f64, "rho g h error {worst_incompressible}");
        assert!(worst_compressible < 1e-3, "exp profile error {worst_compressible}");
        let mass_bound = if name == "f32" { 1e-6 } else { 1e-12 };
        assert!(mass_drift < mass_bound, "{name}: mass drift {mass_drift:e}");
    }
}

/// Returns (max |u|, relative mass drift, p(z) − p0 in Pa averaged per layer).
fn tank<T: Real>(params: FluidParams, dims: [usize; 3], g_l: f64, units: &Units) -> (f64, f64, Vec<f64>) {
    let mut fluid = Fluid::<T>::new(dims, [Faces::Walls; 3], params).expect("valid parameters");
    let [nx, ny, nz] = dims;
    for z in 0..nz {
        for y in 0..ny {
            for x in 0..nx {
                let depth = (nz - 1 - z) as f64;
                fluid.set_equilibrium([x, y, z], 1.0 + 3.0 * g_l * depth, [0.0; 3]).expect("in box");
            }
        }
    }
    let m0 = fluid.liquid_mass();
    for _ in 0..12000 {
        fluid.step();
    }
    fluid.check(&Default::default()).expect("stable");
    let pressure = (0..nz)
        .map(|z| {
            let mut s = 0.0;
            for y in 0..ny {
                for x in 0..nx {
                    s += units.pressure_from_density(fluid.moments([x, y, z]).expect("in box").0);
                }
            }
            s / (nx * ny) as f64
        })
        .collect();
    (fluid.max_speed(), (fluid.liquid_mass() - m0).abs() / m0, pressure)
}
