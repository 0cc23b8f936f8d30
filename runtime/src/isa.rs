//! The vector instruction set the hot kernels are compiled for, chosen once
//! at run time so that one binary runs on any x86-64 CPU and still uses the
//! wide vectors of the one it runs on.
//!
//! Results do not depend on the choice: Rust never contracts `a * b + c`
//! into a fused multiply-add on its own and the kernels call no `mul_add`,
//! so every instruction set rounds each operation the same way (IEEE 754,
//! `sqrt` and division included). Each solver's tests check its kernels for
//! bit-identical results across the levels this CPU has.
//!
//! AVX-512 is not offered: on the development machine (a Xeon with
//! AVX-512) the LBM kernel built for it ran no faster than the AVX2 build,
//! 1.10–1.18e8 against 1.16–1.37e8 lattice updates/s on two threads.

use std::sync::OnceLock;

/// The environment variable that lowers the level (`baseline` or `avx2`),
/// for measuring what the wide vectors bring; a level the CPU lacks is
/// never used, and an unknown name is an error at start-up.
pub const ENV: &str = "SGF_ISA";

/// A vector instruction set the kernels have a build for.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub enum Isa {
    /// SSE2, the x86-64 baseline (or any other architecture).
    Baseline,
    /// AVX2 with FMA: 8 f32 or 4 f64 lanes per instruction.
    Avx2,
}

impl Isa {
    /// The best level the CPU supports, lowered to `SGF_ISA` if that is set.
    ///
    /// Errors name the bad value; binaries call it at start-up so that a
    /// typo stops the run instead of silently running the default.
    pub fn detected() -> Result<Isa, String> {
        static DETECTED: OnceLock<Result<Isa, String>> = OnceLock::new();
        DETECTED
            .get_or_init(|| {
                let best = Isa::best_supported();
                match std::env::var(ENV) {
                    Err(_) => Ok(best),
                    Ok(name) => match Isa::parse(&name) {
                        Some(asked) => Ok(asked.min(best)),
                        None => {
                            Err(format!("{ENV}={name:?} is not an instruction set: use baseline or avx2 (or unset it)"))
                        }
                    },
                }
            })
            .clone()
    }

    /// [`Isa::detected`], or the baseline if `SGF_ISA` is bad (library
    /// code; the binaries have already reported a bad value).
    pub fn current() -> Isa {
        Isa::detected().unwrap_or(Isa::Baseline)
    }

    /// The best level the CPU supports.
    pub fn best_supported() -> Isa {
        #[cfg(target_arch = "x86_64")]
        {
            if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma") {
                return Isa::Avx2;
            }
        }
        Isa::Baseline
    }

    /// Every level this CPU supports, lowest first (for tests).
    pub fn all_supported() -> Vec<Isa> {
        [Isa::Baseline, Isa::Avx2].into_iter().filter(|&i| i <= Isa::best_supported()).collect()
    }

    /// `baseline` or `avx2`.
    pub fn parse(name: &str) -> Option<Isa> {
        match name {
            "baseline" => Some(Isa::Baseline),
            "avx2" => Some(Isa::Avx2),
            _ => None,
        }
    }

    /// The name `parse` reads.
    pub fn name(self) -> &'static str {
        match self {
            Isa::Baseline => "baseline",
            Isa::Avx2 => "avx2",
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_round_trip_and_levels_are_ordered() {
        for isa in [Isa::Baseline, Isa::Avx2] {
            assert_eq!(Isa::parse(isa.name()), Some(isa));
        }
        assert_eq!(Isa::parse("avx512"), None);
        assert!(Isa::Baseline < Isa::Avx2);
        assert_eq!(Isa::all_supported()[0], Isa::Baseline);
        assert!(Isa::current() <= Isa::best_supported());
    }
}
