//! Solid–liquid drag of the two-phase MPM: Forchheimer's law with Ergun's
//! non-Darcy coefficient and Kozeny–Carman permeability (Ceccato et al.
//! 2020, Eqs. 7–9; reference `mpm-2pdp.md` §3).
//!
//! Per unit mixture volume, with w = v_L − v_S the interstitial relative
//! velocity and n the porosity,
//!
//! f_d = [ μ n²/κ(n) + β(n) n³ ρ_L |w| ] w,
//! κ(n) = D² n³ / (A (1 − n)²),    β(n) = B / √(κ A n³) = B (1 − n)/(D n³).
//!
//! Why this form: divided by n and written with the Darcy flux q = n w, it is
//! Ergun's (1952) packed-bed pressure gradient exactly,
//! f_d/n = A μ (1 − n)² q/(n³ D²) + B ρ_L (1 − n) q²/(n³ D),
//! since f_d/n is the drag per unit *liquid* volume, i.e. the excess pore
//! pressure gradient. The paper writes the viscosity ν; it is the dynamic
//! viscosity μ [Pa·s].
//!
//! Everything here is SI, plain `f64`, and allocation-free.

/// Lower clamp of the porosity used inside κ and β: keeps κ > 0 and β finite
/// for a (non-physical) fully packed point.
pub const MIN_POROSITY: f64 = 0.05;
/// Upper clamp of the porosity used inside κ and β: κ ∝ 1/(1 − n)² blows up
/// at n = 1; Anura3D caps the same way at 0.95 (`mpm-2pdp.md` §3).
pub const MAX_POROSITY: f64 = 0.95;

/// Ergun's viscous constant A (Ergun 1952; paper §3.2).
pub const ERGUN_A: f64 = 150.0;
/// Ergun's inertial constant B (Ergun 1952; paper §3.2).
pub const ERGUN_B: f64 = 1.75;

/// Eqs. 7–9 for one soil and one liquid.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DragLaw {
    /// Grain diameter D, m.
    pub grain_diameter: f64,
    /// Ergun A (150) and B (1.75).
    pub ergun_a: f64,
    pub ergun_b: f64,
    /// Liquid dynamic viscosity μ, Pa·s, and density ρ_L, kg/m³.
    pub viscosity: f64,
    pub liquid_density: f64,
    /// Keep the quadratic term f2 of Eq. 7.
    pub quadratic: bool,
}

/// Porosity as it enters κ and β (Eqs. 8–9).
#[inline]
fn clamp_skeleton(porosity: f64) -> f64 {
    porosity.clamp(MIN_POROSITY, MAX_POROSITY)
}

/// Porosity as it enters the n², n³ prefactors of Eq. 7: a volume fraction,
/// so outside [0, 1] it can only be a mapping artefact, and a negative value
/// would flip the sign of n³ and turn the drag into propulsion.
#[inline]
fn clamp_fraction(porosity: f64) -> f64 {
    porosity.clamp(0.0, 1.0)
}

impl DragLaw {
    /// Ergun's constants (A = 150, B = 1.75) with the quadratic term on.
    ///
    /// `grain_diameter` D (m), `viscosity` μ (Pa·s), `liquid_density` ρ_L
    /// (kg/m³); all are expected finite and > 0 (not checked here: the scene
    /// validation owns that).
    pub const fn ergun(grain_diameter: f64, viscosity: f64, liquid_density: f64) -> Self {
        DragLaw { grain_diameter, ergun_a: ERGUN_A, ergun_b: ERGUN_B, viscosity, liquid_density, quadratic: true }
    }

    /// Intrinsic permeability κ = D² n³ / (A (1 − n)²), m² (Kozeny–Carman,
    /// Eq. 9; the paper writes A as its value 150).
    ///
    /// Porosity used inside κ and β is clamped to [MIN_POROSITY, MAX_POROSITY]
    /// (0.05, 0.95) so κ stays finite (Anura3D caps at 0.95).
    /// Post: finite and > 0 for any finite `porosity` (NaN propagates).
    pub fn permeability(&self, porosity: f64) -> f64 {
        crate::plan::permeability(self.grain_diameter, clamp_skeleton(porosity), self.ergun_a)
    }

    /// Non-Darcy (Forchheimer) coefficient β = B / √(κ A n³), 1/m (Eq. 8),
    /// with κ from [`Self::permeability`] and the same clamped porosity.
    ///
    /// With Eq. 9 this is B (1 − n)/(D n³): A cancels, which is what makes
    /// f2/n Ergun's inertial term.
    /// Post: finite and > 0 for any finite `porosity`.
    pub fn beta(&self, porosity: f64) -> f64 {
        let n = clamp_skeleton(porosity);
        self.ergun_b / (self.permeability(n) * self.ergun_a * n * n * n).sqrt()
    }

    /// Drag per unit mixture volume per unit relative velocity, N·s/m⁴:
    /// f_d = coefficient · (v_L − v_S) (Eq. 7),
    /// coefficient = μ n²/κ + (if `quadratic`) β n³ ρ_L |v_L − v_S|.
    ///
    /// `relative_speed` = |v_L − v_S| [m/s] (its sign is ignored). The one
    /// porosity sets the prefactors (clamped to [0, 1]) and κ, β (clamped
    /// to [MIN_POROSITY, MAX_POROSITY]); Anura3D takes the prefactors' from
    /// the liquid mapped to the solid point (`mpm-2pdp.md` §3), equal to it
    /// in saturated soil.
    /// Post: finite and ≥ 0; 0 only for a porosity ≤ 0.
    pub fn coefficient(&self, porosity: f64, relative_speed: f64) -> f64 {
        let nl = clamp_fraction(porosity);
        let linear = self.viscosity * nl * nl / self.permeability(porosity);
        if self.quadratic {
            linear + self.beta(porosity) * nl * nl * nl * self.liquid_density * relative_speed.abs()
        } else {
            linear
        }
    }

    /// d|f_d|/d|w|, N·s/m⁴: the tangent of |f_d| = coefficient(|w|)·|w|, i.e.
    /// the linear part plus *twice* the quadratic part. Explicit stability
    /// needs this, not the secant [`Self::coefficient`] (`mpm-2pdp.md` §3:
    /// Δt·Q(1/M_L + 1/M_S) < 2 with the quadratic part at its tangent value
    /// 2ρ_Lβn³|w|).
    pub fn tangent_coefficient(&self, porosity: f64, relative_speed: f64) -> f64 {
        let nl = clamp_fraction(porosity);
        let linear = self.viscosity * nl * nl / self.permeability(porosity);
        if self.quadratic {
            linear + 2.0 * self.beta(porosity) * nl * nl * nl * self.liquid_density * relative_speed.abs()
        } else {
            linear
        }
    }

    /// Hydraulic conductivity k = κ ρ_L g / μ, m/s, with `gravity` = |g|
    /// [m/s²]: the Darcy flux per unit hydraulic gradient when f2 is
    /// negligible.
    pub fn hydraulic_conductivity(&self, porosity: f64, gravity: f64) -> f64 {
        self.permeability(porosity) * self.liquid_density * gravity / self.viscosity
    }

    /// Particle Reynolds number of Eq. 12: D ρ_L |w| / μ (dimensionless), with
    /// `relative_speed` = |w| [m/s] the interstitial relative speed.
    ///
    /// The inertial to viscous drag ratio is
    /// f2/f1 = (B/A) · Re · n/(1 − n) (derived from Eqs. 7–9), i.e.
    /// Ergun's modified Reynolds number D ρ_L q/(μ (1 − n)) times B/A.
    pub fn reynolds(&self, relative_speed: f64) -> f64 {
        self.grain_diameter * self.liquid_density * relative_speed.abs() / self.viscosity
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The lab bed of Ceccato et al. 2020 (reference `analytic-checks.md`,
    /// "Porous flow"): D = 2.5 mm, water.
    const LAB: DragLaw = DragLaw::ergun(2.5e-3, 1.0e-3, 1000.0);
    const N_LAB: f64 = 0.40;
    const G: f64 = 9.81;

    /// |value − printed| within half a unit of the printed last digit:
    /// the tolerance the reference's rounding itself allows.
    fn assert_printed(value: f64, printed: f64, last_digit: f64, what: &str) {
        let err = (value - printed).abs();
        assert!(err <= 0.5 * last_digit, "{what}: {value} vs printed {printed} (±{})", 0.5 * last_digit);
    }

    fn rel(a: f64, b: f64) -> f64 {
        (a - b).abs() / b.abs()
    }

    /// Excess pore-pressure gradient [Pa/m] at Darcy flux q: f_d/n at w = q/n.
    fn bed_gradient(law: &DragLaw, n: f64, q: f64) -> f64 {
        let w = q / n;
        law.coefficient(n, w) * w / n
    }

    #[test]
    fn lab_bed_permeability_and_conductivity() {
        let kappa = LAB.permeability(N_LAB);
        // Exact: 6.25e-6 · 0.064 / (150 · 0.36) = 4e-7/54.
        assert!(rel(kappa, 4.0e-7 / 54.0) < 1e-14, "κ = {kappa}");
        assert_printed(kappa, 7.41e-9, 0.01e-9, "κ");
        let k = LAB.hydraulic_conductivity(N_LAB, G);
        assert_printed(k, 0.0727, 0.0001, "K");
    }

    #[test]
    fn beta_closed_form() {
        // Eq. 8 with Eq. 9: β = B (1 − n)/(D n³); only rounding separates them.
        for &n in &[0.05, 0.2, 0.4, 0.6, 0.8, 0.95] {
            let exact = ERGUN_B * (1.0 - n) / (LAB.grain_diameter * n * n * n);
            assert!(rel(LAB.beta(n), exact) < 1e-13, "n = {n}");
        }
    }

    #[test]
    fn reproduces_ergun_bed_gradient() {
        // (Darcy flux q m/s, printed Δp/L Pa/m, unit of its last digit)
        let table = [(1e-4, 13.57, 0.01), (1e-3, 141.6, 0.1), (1e-2, 2006.0, 1.0), (0.05, 23156.0, 1.0)];
        for (q, printed, digit) in table {
            let dpdl = bed_gradient(&LAB, N_LAB, q);
            // Ergun's own formula, the identity f_d/n = Ergun: only rounding.
            let ergun =
                ERGUN_A * 1e-3 * 0.36 * q / (0.064 * 6.25e-6) + ERGUN_B * 1000.0 * 0.6 * q * q / (0.064 * 2.5e-3);
            assert!(rel(dpdl, ergun) < 1e-12, "q = {q}: {dpdl} vs Ergun {ergun}");
            // §10.4 coefficients 1.35e5 and 6.5625e6 (6.56e6 printed).
            assert!(rel(dpdl, 1.35e5 * q + 6.5625e6 * q * q) < 1e-12);
            assert_printed(dpdl, printed, digit, "Δp/L");
        }
    }

    #[test]
    fn linear_only_is_darcy() {
        let darcy = DragLaw { quadratic: false, ..LAB };
        for &q in &[1e-4, 1e-3, 1e-2, 0.05] {
            // 150 μ (1−n)²/(n³ D²) = 1.35e5 Pa·s/m² exactly for the lab bed.
            assert!(rel(bed_gradient(&darcy, N_LAB, q), 1.35e5 * q) < 1e-12, "q = {q}");
            // …and equals Darcy's μ q/κ.
            assert!(rel(bed_gradient(&darcy, N_LAB, q), 1e-3 * q / darcy.permeability(N_LAB)) < 1e-12);
        }
        // Independent of the speed without f2.
        assert_eq!(darcy.coefficient(N_LAB, 0.0), darcy.coefficient(N_LAB, 3.0));
        assert_eq!(darcy.tangent_coefficient(N_LAB, 3.0), darcy.coefficient(N_LAB, 3.0));
    }

    #[test]
    fn quadratic_to_linear_ratio() {
        // f1 = μ n²/κ w, f2 = β n³ ρ w², so f2/f1 = β κ n ρ w/μ, and with
        // β κ = B D/(A (1 − n)) (Eqs. 8–9): f2/f1 = (B/A) Re n/(1 − n),
        // Re = D ρ w/μ. Equivalently (B/A) Re_q/(1 − n), Re_q = D ρ q/μ.
        let darcy = DragLaw { quadratic: false, ..LAB };
        for &n in &[0.3, 0.4, 0.6] {
            for &w in &[1e-4, 1e-2, 0.3, 2.0] {
                let f1 = darcy.coefficient(n, w) * w;
                let f2 = LAB.coefficient(n, w) * w - f1;
                let derived = ERGUN_B / ERGUN_A * LAB.reynolds(w) * n / (1.0 - n);
                // Difference of two close numbers at small w: 1e-10 covers the
                // cancellation (f2/f1 ≈ 1e-3 at w = 1e-4 loses ~3 digits).
                assert!(rel(f2 / f1, derived) < 1e-10, "n = {n}, w = {w}: {} vs {derived}", f2 / f1);
                let re_q = LAB.reynolds(n * w);
                assert!(rel(derived, ERGUN_B / ERGUN_A * re_q / (1.0 - n)) < 1e-14);
            }
        }
        // Ergun's crossover f1 = f2 at Re_q/(1 − n) = A/B: q = 0.6·(150/1.75)·μ/(ρ D).
        let q = 0.6 * (ERGUN_A / ERGUN_B) * 1e-3 / (1000.0 * 2.5e-3);
        let w = q / N_LAB;
        assert!(rel(LAB.coefficient(N_LAB, w), 2.0 * darcy.coefficient(N_LAB, w)) < 1e-12);
    }

    #[test]
    fn tangent_is_derivative_of_drag_magnitude() {
        for &n in &[0.3, 0.4, 0.7] {
            for &w in &[1e-3, 0.05, 1.0] {
                // |f_d| is quadratic in |w|, so the central difference is exact
                // but for rounding ~ ε |f|/h = 1e-16/1e-6: 1e-8 is ample.
                let h = 1e-6 * w;
                let f = |s: f64| LAB.coefficient(n, s) * s;
                let fd = (f(w + h) - f(w - h)) / (2.0 * h);
                let t = LAB.tangent_coefficient(n, w);
                assert!(rel(t, fd) < 1e-8, "n = {n}, w = {w}: {t} vs {fd}");
                // Linear part + 2 × quadratic part.
                let lin = DragLaw { quadratic: false, ..LAB }.coefficient(n, w);
                assert!(rel(t - lin, 2.0 * (LAB.coefficient(n, w) - lin)) < 1e-9);
            }
        }
    }

    #[test]
    fn gravity_drainage_at_unit_gradient() {
        // §10.4: f_d/n = ρ_L g: 1.35e5 q + 6.5625e6 q² = 9810 gives q = 0.0297
        // with Ergun; Darcy alone gives q = K exactly.
        let a = 6.5625e6;
        let b = 1.35e5;
        let q = (-b + (b * b + 4.0 * a * 1000.0 * G).sqrt()) / (2.0 * a);
        assert!(rel(bed_gradient(&LAB, N_LAB, q), 1000.0 * G) < 1e-12);
        assert_printed(q, 0.0297, 0.0001, "Ergun drainage flux");
        let darcy = DragLaw { quadratic: false, ..LAB };
        let k = darcy.hydraulic_conductivity(N_LAB, G);
        assert!(rel(bed_gradient(&darcy, N_LAB, k), 1000.0 * G) < 1e-14);
    }

    #[test]
    fn batch_settling_velocity() {
        // §10.5: steady fluidised settling with zero net flux, n = 0.6:
        // coefficient(w) w = n (1 − n)(ρ_s − ρ_L) g, v_S = −n w. The printed
        // −0.353 / −0.063 m/s are for ρ_s = 2600 kg/m³ (ρ_sat = 1960 of §7).
        let n = 0.6;
        let load = n * (1.0 - n) * (2600.0 - 1000.0) * G;
        let darcy = DragLaw { quadratic: false, ..LAB };
        let w_darcy = load / darcy.coefficient(n, 0.0);
        assert_printed(-n * w_darcy, -0.353, 0.001, "Darcy settling");
        // Quadratic: c2 w² + c1 w = load.
        let c1 = darcy.coefficient(n, 0.0);
        let c2 = LAB.coefficient(n, 1.0) - c1;
        let w = (-c1 + (c1 * c1 + 4.0 * c2 * load).sqrt()) / (2.0 * c2);
        assert!(rel(LAB.coefficient(n, w) * w, load) < 1e-12);
        assert_printed(w, 0.105, 0.001, "Ergun relative speed");
        assert_printed(-n * w, -0.063, 0.001, "Ergun settling");
    }

    #[test]
    fn porosity_clamping_keeps_values_finite() {
        for &n in &[-0.5, 0.0, 1e-300, 0.01, 0.99, 1.0, 1.5] {
            for f in [LAB.permeability(n), LAB.beta(n), LAB.coefficient(n, 0.1), LAB.tangent_coefficient(n, 0.1)] {
                assert!(f.is_finite() && f >= 0.0, "n = {n}: {f}");
            }
        }
        // κ and β saturate at the clamps, bit for bit.
        assert_eq!(LAB.permeability(0.0), LAB.permeability(MIN_POROSITY));
        assert_eq!(LAB.permeability(1.0), LAB.permeability(MAX_POROSITY));
        assert_eq!(LAB.beta(1.0), LAB.beta(MAX_POROSITY));
        assert_eq!(LAB.beta(0.0), LAB.beta(MIN_POROSITY));
        // No liquid, no drag; prefactors never go negative or above n = 1.
        assert_eq!(LAB.coefficient(0.0, 0.1), 0.0);
        assert_eq!(LAB.coefficient(-0.2, 0.1), 0.0);
        assert_eq!(LAB.coefficient(1.3, 0.1), LAB.coefficient(1.0, 0.1));
        // At n = 1 the prefactors are 1: μ/κ(0.95) + β(0.95) ρ |w|.
        let expect = 1e-3 / LAB.permeability(0.95) + LAB.beta(0.95) * 1000.0 * 0.1;
        assert!(rel(LAB.coefficient(1.0, 0.1), expect) < 1e-15);
    }

    #[test]
    fn speed_sign_is_ignored_and_reynolds_is_eq_12() {
        assert_eq!(LAB.coefficient(N_LAB, -0.05), LAB.coefficient(N_LAB, 0.05));
        assert!(rel(LAB.reynolds(0.1), 250.0) < 1e-15);
    }
}
