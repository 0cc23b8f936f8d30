//! Small inline operations on three-component vectors for the hot kernels:
//! plain scalar code the compiler keeps in registers (an early measurement
//! gave ~2x fewer instructions than the generic nalgebra operators in these
//! loops; why this form stays is in docs/ARCHITECTURE.md). Generic over the
//! component so that the contact kernel's lanes ([`crate::lanes::Lanes`],
//! one contact per lane) use the very same operations as `f64`.

use std::ops::{Add, Mul, Neg, Sub};

pub type Vec3 = [f64; 3];

#[inline(always)]
pub fn add<T: Copy + Add<Output = T>>(a: [T; 3], b: [T; 3]) -> [T; 3] {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}
#[inline(always)]
pub fn sub<T: Copy + Sub<Output = T>>(a: [T; 3], b: [T; 3]) -> [T; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}
#[inline(always)]
pub fn scale<T: Copy + Mul<Output = T>>(a: [T; 3], s: T) -> [T; 3] {
    [a[0] * s, a[1] * s, a[2] * s]
}
#[inline(always)]
pub fn dot<T: Copy + Add<Output = T> + Mul<Output = T>>(a: [T; 3], b: [T; 3]) -> T {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}
#[inline(always)]
pub fn cross<T: Copy + Sub<Output = T> + Mul<Output = T>>(a: [T; 3], b: [T; 3]) -> [T; 3] {
    [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
}
#[inline(always)]
pub fn norm2<T: Copy + Add<Output = T> + Mul<Output = T>>(a: [T; 3]) -> T {
    dot(a, a)
}
#[inline(always)]
pub fn neg<T: Copy + Neg<Output = T>>(a: [T; 3]) -> [T; 3] {
    [-a[0], -a[1], -a[2]]
}
