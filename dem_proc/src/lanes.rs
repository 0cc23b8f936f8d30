//! f64 lanes for evaluating [`LANES`] contacts at once.
//!
//! Every operation is the scalar operation of [`crate::vec3`] applied lane by
//! lane, so a kernel written with these types rounds exactly as its scalar
//! twin: LLVM turns each fixed-length lane loop into vector instructions
//! where the CPU has them (IEEE 754 division and square root are correctly
//! rounded in both forms, and Rust never fuses a multiply and an add on its
//! own). Branches become lane selects: both sides are computed, one kept.
//!
//! The lanes are written out as array expressions, not `std::array::from_fn`:
//! where the law was not inlined into its caller (`examples/law_nalgebra.rs`)
//! `from_fn` stayed an out-of-line closure call per element with a `memmove`
//! per vector, and the law ran 3.4x (baseline) and 3.2x (AVX2) slower. The
//! pair kernel happened to inline it either way (same particle-steps/s).

use std::ops::{Add, Div, Mul, Neg, Sub};

/// Contacts per batch: two AVX2 registers, so that two independent chains
/// of the law's divisions and square roots are in flight. On the lab
/// column (8434 grains, 14k contacts; `late_profile` at t = 0.6 s, one
/// thread) the contact stage took 44–47 ms an exchange one contact at a
/// time, 42–45 with 4 lanes, 33.5–35 with 8 and 42 with 16 (spills).
pub const LANES: usize = 8;

/// One f64 per lane.
#[derive(Clone, Copy, Debug, PartialEq)]
#[repr(C, align(32))]
pub struct Lanes(pub [f64; LANES]);

/// A vector of three components, [`LANES`] lanes each.
pub type Lanes3 = [Lanes; 3];

impl Lanes {
    #[inline(always)]
    pub fn splat(x: f64) -> Lanes {
        Lanes([x; LANES])
    }
    #[inline(always)]
    fn map(self, f: impl Fn(f64) -> f64) -> Lanes {
        let a = self.0;
        Lanes([f(a[0]), f(a[1]), f(a[2]), f(a[3]), f(a[4]), f(a[5]), f(a[6]), f(a[7])])
    }
    #[inline(always)]
    fn zip(self, o: Lanes, f: impl Fn(f64, f64) -> f64) -> Lanes {
        let (a, b) = (self.0, o.0);
        Lanes([
            f(a[0], b[0]),
            f(a[1], b[1]),
            f(a[2], b[2]),
            f(a[3], b[3]),
            f(a[4], b[4]),
            f(a[5], b[5]),
            f(a[6], b[6]),
            f(a[7], b[7]),
        ])
    }
    #[inline(always)]
    pub fn sqrt(self) -> Lanes {
        self.map(f64::sqrt)
    }
    /// `f64::max` per lane.
    #[inline(always)]
    pub fn max(self, o: Lanes) -> Lanes {
        self.zip(o, f64::max)
    }
    /// `f64::min` per lane.
    #[inline(always)]
    pub fn min(self, o: Lanes) -> Lanes {
        self.zip(o, f64::min)
    }
    /// Per lane: `if self > other { then } else { otherwise }`.
    #[inline(always)]
    pub fn if_greater(self, other: Lanes, then: Lanes, otherwise: Lanes) -> Lanes {
        let pick = |l: usize| if self.0[l] > other.0[l] { then.0[l] } else { otherwise.0[l] };
        Lanes([pick(0), pick(1), pick(2), pick(3), pick(4), pick(5), pick(6), pick(7)])
    }
}

impl Add for Lanes {
    type Output = Lanes;
    #[inline(always)]
    fn add(self, o: Lanes) -> Lanes {
        self.zip(o, |a, b| a + b)
    }
}
impl Sub for Lanes {
    type Output = Lanes;
    #[inline(always)]
    fn sub(self, o: Lanes) -> Lanes {
        self.zip(o, |a, b| a - b)
    }
}
impl Mul for Lanes {
    type Output = Lanes;
    #[inline(always)]
    fn mul(self, o: Lanes) -> Lanes {
        self.zip(o, |a, b| a * b)
    }
}
impl Div for Lanes {
    type Output = Lanes;
    #[inline(always)]
    fn div(self, o: Lanes) -> Lanes {
        self.zip(o, |a, b| a / b)
    }
}
impl Neg for Lanes {
    type Output = Lanes;
    #[inline(always)]
    fn neg(self) -> Lanes {
        self.map(|a| -a)
    }
}

/// The vector operations of [`crate::vec3`], lane by lane (they are
/// generic over the component).
pub use crate::vec3::{add, cross, dot, neg, norm2, scale, sub};

/// Per lane: `if s > t { then } else { otherwise }` on all three components.
#[inline(always)]
pub fn if_greater(s: Lanes, t: Lanes, then: Lanes3, otherwise: Lanes3) -> Lanes3 {
    [
        s.if_greater(t, then[0], otherwise[0]),
        s.if_greater(t, then[1], otherwise[1]),
        s.if_greater(t, then[2], otherwise[2]),
    ]
}

/// Lane `l` of a vector.
#[inline(always)]
pub fn lane(v: &Lanes3, l: usize) -> [f64; 3] {
    [v[0].0[l], v[1].0[l], v[2].0[l]]
}
/// Writes `x` into lane `l` of a vector.
#[inline(always)]
pub fn set_lane(v: &mut Lanes3, l: usize, x: [f64; 3]) {
    for a in 0..3 {
        v[a].0[l] = x[a];
    }
}
