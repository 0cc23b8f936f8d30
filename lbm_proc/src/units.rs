//! The one SI ↔ lattice converter.
//!
//! Lattice units set Δx = Δt = ρ0 = 1. Every quantity converts with the power
//! of (Δx, Δt, ρ0) given by its dimension (Krüger et al. 2017, *The Lattice
//! Boltzmann Method*, ch. 7):
//!
//! | quantity | SI unit | SI = lattice × |
//! |---|---|---|
//! | length | m | Δx |
//! | time | s | Δt |
//! | velocity | m/s | Δx/Δt |
//! | acceleration | m/s² | Δx/Δt² |
//! | kinematic viscosity | m²/s | Δx²/Δt |
//! | density | kg/m³ | ρ0 |
//! | pressure | Pa | ρ0 Δx²/Δt² |
//! | force density | N/m³ | ρ0 Δx/Δt² |
//! | force | N | ρ0 Δx⁴/Δt² |
//! | torque | N m | ρ0 Δx⁵/Δt² |
//!
//! Pressure is the deviation from the reference: p − p0 = c_s² (ρ_L − 1) in
//! lattice units, so [`Units::pressure_from_density`] is the one to use on a
//! lattice density.

use serde::{Deserialize, Serialize};

use crate::lattice::CS2;

/// Why a converter or a viscosity cannot be used.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum UnitsError {
    #[error("{name} must be finite and > 0, got {value}")]
    NotPositive { name: &'static str, value: f64 },
}

/// Lattice spacing, time step and reference density.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Units {
    /// Δx, m.
    dx: f64,
    /// Δt, s.
    dt: f64,
    /// ρ0, kg/m³ (the density that maps to lattice density 1).
    rho0: f64,
}

fn positive(name: &'static str, value: f64) -> Result<f64, UnitsError> {
    if value.is_finite() && value > 0.0 {
        Ok(value)
    } else {
        Err(UnitsError::NotPositive { name, value })
    }
}

impl Units {
    /// `dx` (m), `dt` (s), `rho0` (kg/m³); all finite and positive.
    pub fn new(dx: f64, dt: f64, rho0: f64) -> Result<Self, UnitsError> {
        Ok(Units { dx: positive("dx", dx)?, dt: positive("dt", dt)?, rho0: positive("rho0", rho0)? })
    }

    /// The time step that gives relaxation time `tau` for kinematic viscosity
    /// `nu` (m²/s) at spacing `dx` (m): Δt = (τ − ½) Δx²/(3ν).
    pub fn dt_for_tau(dx: f64, nu: f64, tau: f64) -> Result<f64, UnitsError> {
        let excess = positive("tau - 1/2", tau - 0.5)?;
        Ok(excess * positive("dx", dx)?.powi(2) / (3.0 * positive("nu", nu)?))
    }

    pub fn dx(&self) -> f64 {
        self.dx
    }
    pub fn dt(&self) -> f64 {
        self.dt
    }
    pub fn rho0(&self) -> f64 {
        self.rho0
    }

    pub fn length_to_lattice(&self, l: f64) -> f64 {
        l / self.dx
    }
    pub fn length_to_si(&self, l: f64) -> f64 {
        l * self.dx
    }
    pub fn time_to_lattice(&self, t: f64) -> f64 {
        t / self.dt
    }
    pub fn time_to_si(&self, t: f64) -> f64 {
        t * self.dt
    }
    pub fn velocity_to_lattice(&self, u: f64) -> f64 {
        u * self.dt / self.dx
    }
    pub fn velocity_to_si(&self, u: f64) -> f64 {
        u * self.dx / self.dt
    }
    pub fn acceleration_to_lattice(&self, a: f64) -> f64 {
        a * self.dt * self.dt / self.dx
    }
    pub fn acceleration_to_si(&self, a: f64) -> f64 {
        a * self.dx / (self.dt * self.dt)
    }
    pub fn viscosity_to_lattice(&self, nu: f64) -> f64 {
        nu * self.dt / (self.dx * self.dx)
    }
    pub fn viscosity_to_si(&self, nu: f64) -> f64 {
        nu * self.dx * self.dx / self.dt
    }
    pub fn density_to_lattice(&self, rho: f64) -> f64 {
        rho / self.rho0
    }
    pub fn density_to_si(&self, rho: f64) -> f64 {
        rho * self.rho0
    }
    fn pressure_unit(&self) -> f64 {
        self.rho0 * self.dx * self.dx / (self.dt * self.dt)
    }
    pub fn pressure_to_lattice(&self, p: f64) -> f64 {
        p / self.pressure_unit()
    }
    pub fn pressure_to_si(&self, p: f64) -> f64 {
        p * self.pressure_unit()
    }
    /// p − p0 in Pa for a lattice density: c_s² (ρ_L − 1) ρ0 Δx²/Δt².
    pub fn pressure_from_density(&self, rho_lattice: f64) -> f64 {
        self.pressure_to_si(CS2 * (rho_lattice - 1.0))
    }
    fn force_density_unit(&self) -> f64 {
        self.rho0 * self.dx / (self.dt * self.dt)
    }
    pub fn force_density_to_lattice(&self, f: f64) -> f64 {
        f / self.force_density_unit()
    }
    pub fn force_density_to_si(&self, f: f64) -> f64 {
        f * self.force_density_unit()
    }
    fn force_unit(&self) -> f64 {
        self.rho0 * self.dx.powi(4) / (self.dt * self.dt)
    }
    pub fn force_to_lattice(&self, f: f64) -> f64 {
        f / self.force_unit()
    }
    pub fn force_to_si(&self, f: f64) -> f64 {
        f * self.force_unit()
    }
    fn torque_unit(&self) -> f64 {
        self.rho0 * self.dx.powi(5) / (self.dt * self.dt)
    }
    pub fn torque_to_lattice(&self, t: f64) -> f64 {
        t / self.torque_unit()
    }
    pub fn torque_to_si(&self, t: f64) -> f64 {
        t * self.torque_unit()
    }

    /// BGK relaxation time for kinematic viscosity `nu` [m²/s]:
    /// τ = 3 ν Δt/Δx² + ½ (from ν_L = c_s² (τ − ½)).
    pub fn tau_from_viscosity(&self, nu: f64) -> Result<f64, UnitsError> {
        Ok(3.0 * self.viscosity_to_lattice(positive("nu", nu)?) + 0.5)
    }
    /// Kinematic viscosity [m²/s] of relaxation time `tau`.
    pub fn viscosity_from_tau(&self, tau: f64) -> f64 {
        self.viscosity_to_si((tau - 0.5) / 3.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn paper() -> Units {
        Units::new(6e-4, 8e-5, 1000.0).expect("valid")
    }

    #[test]
    fn paper_water_case_gives_tau_0_500667() {
        // Ceccato et al. 2020: Δx = 0.6 mm, Δt = 80 µs, water ν = 1e-6 m²/s.
        // ν_L = 1e-6 · 8e-5 / 3.6e-7 = 2.222e-4, τ = 0.5 + 3 ν_L = 0.5006667.
        let tau = paper().tau_from_viscosity(1e-6).expect("valid");
        assert!((tau - 0.500_666_666_7).abs() < 1e-9, "tau = {tau}");
        assert!((paper().viscosity_from_tau(tau) - 1e-6).abs() < 1e-18);
        let dt = Units::dt_for_tau(6e-4, 1e-6, tau).expect("valid");
        assert!((dt - 8e-5).abs() < 1e-15, "dt = {dt}");
    }

    #[test]
    fn paper_scale_reference_values() {
        // lbm-free-surface.md §1: speed unit 7.5 m/s, g_L = 1.046e-4.
        let u = paper();
        assert!((u.velocity_to_si(1.0) - 7.5).abs() < 1e-12);
        assert!((u.acceleration_to_lattice(9.81) - 1.0464e-4).abs() < 1e-8);
        // 7 cm of water: δρ_L = ρ g h / (c_s² · ρ0 Δx²/Δt²) = 0.0366.
        let drho = u.pressure_to_lattice(1000.0 * 9.81 * 0.07) / CS2;
        assert!((drho - 0.0366).abs() < 1e-4, "drho = {drho}");
    }

    #[test]
    fn every_conversion_round_trips() {
        let u = Units::new(1.3e-3, 2.7e-5, 998.0).expect("valid");
        let x = 0.37;
        type Conversion = fn(&Units, f64) -> f64;
        let pairs: [(Conversion, Conversion); 10] = [
            (Units::length_to_lattice, Units::length_to_si),
            (Units::time_to_lattice, Units::time_to_si),
            (Units::velocity_to_lattice, Units::velocity_to_si),
            (Units::acceleration_to_lattice, Units::acceleration_to_si),
            (Units::viscosity_to_lattice, Units::viscosity_to_si),
            (Units::density_to_lattice, Units::density_to_si),
            (Units::pressure_to_lattice, Units::pressure_to_si),
            (Units::force_density_to_lattice, Units::force_density_to_si),
            (Units::force_to_lattice, Units::force_to_si),
            (Units::torque_to_lattice, Units::torque_to_si),
        ];
        for (to_l, to_si) in pairs {
            assert!((to_si(&u, to_l(&u, x)) - x).abs() < 1e-15);
            assert_ne!(to_l(&u, x), x, "a conversion that does nothing");
        }
        // Force = force density × cell volume; torque = force × length.
        let rel = |a: f64, b: f64| (a - b).abs() / b.abs();
        assert!(rel(u.force_to_si(1.0), u.force_density_to_si(1.0) * u.dx().powi(3)) < 1e-14);
        assert!(rel(u.torque_to_si(1.0), u.force_to_si(1.0) * u.dx()) < 1e-14);
        // Pressure = force / area; acceleration = velocity / time.
        assert!(rel(u.pressure_to_si(1.0), u.force_to_si(1.0) / u.dx().powi(2)) < 1e-14);
        assert!(rel(u.acceleration_to_si(1.0), u.velocity_to_si(1.0) / u.dt()) < 1e-14);
    }

    #[test]
    fn bad_inputs_are_errors() {
        assert!(Units::new(0.0, 1.0, 1.0).is_err());
        assert!(Units::new(1.0, f64::NAN, 1.0).is_err());
        assert!(paper().tau_from_viscosity(-1.0).is_err());
        assert!(Units::dt_for_tau(1e-3, 1e-6, 0.5).is_err());
    }
}
