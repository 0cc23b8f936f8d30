//! Two-phase double-point material point method, 2D plane strain
//! (Ceccato et al. 2020 §3.2; Abe et al. 2013, Bandara & Soga 2015,
//! Martinelli & Rohe 2015). The discrete equations and the order of one
//! step are in `docs/mpm.md`.

pub mod drag;
pub mod grid;
pub mod mohr_coulomb;
pub mod plan;
pub mod pressure;
pub mod probe;
pub mod run;
pub mod setup;
pub mod solver;
