//! A fixed-point scalar for the board's filter on cores without an FPU: [`I32F32`], a signed
//! 64-bit number with 32 fractional bits (Q32.32: range ±2.1e9, resolution 2.3e-10), usable
//! wherever the filter takes a `nalgebra::RealField` (it implements that trait), so the same
//! source runs in `f64`, `f32` and fixed point.
//!
//! **Overflow is counted, never wrapped.** A result outside the range saturates to a
//! non-finite value (the largest raw value is `+inf`, the smallest two are `-inf` and NaN)
//! and adds one to the overflow count ([`overflows`]); so does an invalid operation (a
//! division by zero, the square root of a negative number, a non-finite `f64` converted
//! in). `is_finite` reports the non-finite values, so the filter's existing checks
//! (`s.is_finite()`, the covariance-diagonal test) refuse a saturated result as they refuse
//! a float's overflow. Addition, subtraction and multiplication do not carry them on as IEEE
//! infinities do (that would take two more 64-bit range tests in each, the filter's
//! commonest operations, on a 32-bit core): an infinite operand enters them as its raw
//! extreme. The filter therefore also
//! reads the count around each of its steps ([`crate::scalar::FilterScalar::overflows`])
//! and treats a step that overflowed as a numerical fault. Division, the square root and
//! the functions through `f64` do propagate them. The count is per thread on the host
//! (tests run in parallel) and one for the program on the board.
//!
//! Addition, subtraction, multiplication (rounded to nearest), division (rounded to
//! nearest) and the square root (rounded to nearest) are exact integer arithmetic, which is
//! what a core without an FPU runs fast. The transcendental functions (trigonometry,
//! exponential, logarithm) go through `libm` in `f64`: the filter's cycle does not call them
//! (its rotations use the half-angle form and square roots), only its start and its reports.
//!
//! Written by hand rather than wrapping the `fixed` crate: every operation must report its
//! saturation to one counter and map it to the non-finite values nalgebra's code tests for,
//! so a wrapper would restate each operation anyway; the arithmetic itself is a few lines.
//! `unsafe` appears only because simba's `SimdValue` declares two `unsafe fn` accessors;
//! their bodies are safe.
#![allow(unsafe_code)]

use core::fmt;
use core::ops::{
    Add, AddAssign, Div, DivAssign, Mul, MulAssign, Neg, Rem, RemAssign, Sub, SubAssign,
};

use num_traits::{FromPrimitive, Num, One, Signed, Zero};
use simba::scalar::{Field, RealField, SubsetOf};
use simba::simd::{PrimitiveSimdValue, SimdValue};

/// Fractional bits of [`I32F32`].
pub const FRACTION_BITS: u32 = 32;
const ONE_RAW: i64 = 1 << FRACTION_BITS;
/// `2^32` as `f64`: the raw value of 1.
const SCALE: f64 = ONE_RAW as f64;
const POS_INF_RAW: i64 = i64::MAX;
const NEG_INF_RAW: i64 = i64::MIN + 1;
const NAN_RAW: i64 = i64::MIN;
/// Largest finite raw value.
const MAX_FINITE_RAW: i64 = i64::MAX - 1;
/// Smallest finite raw value.
const MIN_FINITE_RAW: i64 = i64::MIN + 2;

/// Signed fixed point with 32 integer and 32 fractional bits (Q32.32).
///
/// Finite values lie in ±(2^31 - 2^-32); the resolution is 2^-32 ≈ 2.3e-10. See the module
/// documentation for how overflow is reported.
#[derive(Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct I32F32(i64);

#[cfg(any(test, feature = "std"))]
mod counter {
    use std::cell::Cell;
    std::thread_local! {
        static OVERFLOWS: Cell<u64> = const { Cell::new(0) };
    }
    pub fn bump() {
        OVERFLOWS.with(|c| c.set(c.get().saturating_add(1)));
    }
    pub fn get() -> u64 {
        OVERFLOWS.with(Cell::get)
    }
}

#[cfg(not(any(test, feature = "std")))]
mod counter {
    use core::sync::atomic::{AtomicU32, Ordering};
    // Load and store rather than `fetch_add`: Cortex-M0 has no read-modify-write atomics.
    // The filter runs in one context, so no increment is lost to a race.
    static OVERFLOWS: AtomicU32 = AtomicU32::new(0);
    pub fn bump() {
        let n = OVERFLOWS.load(Ordering::Relaxed);
        OVERFLOWS.store(n.saturating_add(1), Ordering::Relaxed);
    }
    pub fn get() -> u64 {
        u64::from(OVERFLOWS.load(Ordering::Relaxed))
    }
}

/// Fixed-point results that saturated or were invalid so far (this thread on the host, the
/// program on the board). Never decreases: take differences to count over a span.
pub fn overflows() -> u64 {
    counter::get()
}

impl I32F32 {
    /// Positive infinity: what a positive overflow saturates to.
    pub const INFINITY: Self = Self(POS_INF_RAW);
    /// Negative infinity.
    pub const NEG_INFINITY: Self = Self(NEG_INF_RAW);
    /// Not a number: what an invalid operation gives.
    pub const NAN: Self = Self(NAN_RAW);
    /// Largest finite value.
    pub const MAX: Self = Self(MAX_FINITE_RAW);
    /// Smallest finite value.
    pub const MIN: Self = Self(MIN_FINITE_RAW);
    /// Smallest positive value, 2^-32.
    pub const EPSILON: Self = Self(1);
    pub const ZERO: Self = Self(0);
    pub const ONE: Self = Self(ONE_RAW);

    /// The number whose raw two's-complement bits are `raw` (value `raw / 2^32`).
    pub const fn from_raw(raw: i64) -> Self {
        Self(raw)
    }

    /// The raw bits (value times 2^32).
    pub const fn to_raw(self) -> i64 {
        self.0
    }

    /// Whether this is neither infinite nor NaN.
    pub const fn is_finite_value(self) -> bool {
        self.0 >= MIN_FINITE_RAW && self.0 <= MAX_FINITE_RAW
    }

    /// `x` rounded to the nearest representable value; out of range or non-finite
    /// saturates (and is counted).
    pub fn from_f64(x: f64) -> Self {
        if x.is_nan() {
            counter::bump();
            return Self::NAN;
        }
        let scaled = libm::round(x * SCALE);
        if scaled >= MAX_FINITE_RAW as f64 {
            counter::bump();
            Self::INFINITY
        } else if scaled <= MIN_FINITE_RAW as f64 {
            counter::bump();
            Self::NEG_INFINITY
        } else {
            Self(scaled as i64)
        }
    }

    /// `x` rounded to the nearest representable value (half away from zero), as
    /// [`I32F32::from_f64`] rounds `f64::from(x)`, to the bit; out of range or non-finite
    /// saturates (and is counted). Integer operations only: on a core without an FPU the
    /// way through `f64` costs a software multiply and a rounding.
    pub fn from_f32(x: f32) -> Self {
        let bits = x.to_bits();
        let negative = bits >> 31 == 1;
        let biased = ((bits >> 23) & 0xff) as i32;
        if biased == 0xff {
            if bits & 0x7f_ffff != 0 {
                counter::bump();
                return Self::NAN;
            }
            return Self::saturated(!negative);
        }
        if biased == 0 {
            return Self::ZERO; // Zero or subnormal: below 2^-126, far under 2^-32.
        }
        // |x| = m 2^(biased - 150); its raw value is that times 2^32.
        let m = u64::from(bits & 0x7f_ffff | 0x80_0000);
        let shift = biased - 118;
        let magnitude = if shift >= 0 {
            if shift > 39 {
                return Self::saturated(!negative); // 2^63 or more.
            }
            m << shift
        } else if shift < -25 {
            0 // Below half of 2^-32.
        } else {
            let right = shift.unsigned_abs();
            (m + (1 << (right - 1))) >> right
        };
        let raw = magnitude as i64; // Below 2^63 - 2^39: finite.
        Self(if negative { -raw } else { raw })
    }

    /// The value in `f32`, rounded to nearest once (infinities and NaN carried).
    pub fn to_f32(self) -> f32 {
        match self.0 {
            POS_INF_RAW => f32::INFINITY,
            NEG_INF_RAW => f32::NEG_INFINITY,
            NAN_RAW => f32::NAN,
            // `raw as f32` rounds once; the power of two is exact above f32's subnormals.
            raw => raw as f32 * (1.0 / SCALE as f32),
        }
    }

    /// The value in `f64` (exact to 53 significant bits; infinities and NaN carried).
    pub fn to_f64(self) -> f64 {
        match self.0 {
            POS_INF_RAW => f64::INFINITY,
            NEG_INF_RAW => f64::NEG_INFINITY,
            NAN_RAW => f64::NAN,
            raw => raw as f64 / SCALE,
        }
    }

    /// `self · 2^n`: a shift, rounded to nearest when it drops bits, saturated (and
    /// counted) when it leaves the range.
    pub fn shifted(self, n: i32) -> Self {
        if !self.is_finite_value() || n == 0 {
            return self;
        }
        if n > 0 {
            // In range only while the magnitude keeps its top n + 1 bits clear.
            let magnitude = self.0.unsigned_abs();
            if n >= 63 || magnitude.leading_zeros() <= n as u32 {
                return Self::saturated(self.0 > 0);
            }
            return Self(self.0 << n);
        }
        let right = n.unsigned_abs();
        if right >= 64 {
            return Self::ZERO;
        }
        // Nearest: the last bit shifted out rounds (an arithmetic shift: ties go up).
        Self((self.0 >> right) + ((self.0 >> (right - 1)) & 1))
    }

    /// `floor(log2 |self|)`; `None` for zero and non-finite values.
    pub fn log2_floor(self) -> Option<i32> {
        if self.0 == 0 || !self.is_finite_value() {
            return None;
        }
        let magnitude = self.0.unsigned_abs();
        Some(63 - magnitude.leading_zeros() as i32 - FRACTION_BITS as i32)
    }

    /// An operation with a non-finite operand, done as IEEE `f64` does it (not counted
    /// again: the operand's own saturation was).
    fn non_finite(self, other: Self, op: impl Fn(f64, f64) -> f64) -> Self {
        let r = op(self.to_f64(), other.to_f64());
        if r.is_nan() {
            Self::NAN
        } else if r == f64::INFINITY {
            Self::INFINITY
        } else if r == f64::NEG_INFINITY {
            Self::NEG_INFINITY
        } else {
            Self::from_f64(r)
        }
    }

    fn both_finite(self, other: Self) -> bool {
        self.is_finite_value() && other.is_finite_value()
    }

    /// An invalid operation's result: NaN, counted.
    fn invalid() -> Self {
        counter::bump();
        Self::NAN
    }

    /// A function `f64` computes, applied through `f64` (for the transcendental functions).
    fn via_f64(self, f: impl Fn(f64) -> f64) -> Self {
        if !self.is_finite_value() {
            return self.non_finite(self, |a, _| f(a));
        }
        let r = f(self.to_f64());
        if r.is_nan() {
            Self::invalid()
        } else {
            Self::from_f64(r)
        }
    }
}

impl fmt::Debug for I32F32 {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        fmt::Debug::fmt(&self.to_f64(), f)
    }
}

impl fmt::Display for I32F32 {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        fmt::Display::fmt(&self.to_f64(), f)
    }
}

impl PartialOrd for I32F32 {
    /// Ordered as the values; NaN is unordered, as a float's.
    fn partial_cmp(&self, other: &Self) -> Option<core::cmp::Ordering> {
        if self.0 == NAN_RAW || other.0 == NAN_RAW {
            None
        } else {
            Some(self.0.cmp(&other.0))
        }
    }
}

impl I32F32 {
    /// A raw sum or difference and whether it overflowed, saturated (and counted) towards
    /// `sign_if_overflowed`'s sign when it did or when it landed on a non-finite value.
    #[inline(always)]
    fn wrapped(raw: i64, overflowed: bool, sign_if_overflowed: i64) -> Self {
        if overflowed || !Self(raw).is_finite_value() {
            Self::saturated(sign_if_overflowed >= 0)
        } else {
            Self(raw)
        }
    }

    /// The extreme finite-range value of a sign, counted as an overflow.
    #[cold]
    fn saturated(positive: bool) -> Self {
        counter::bump();
        if positive {
            Self::INFINITY
        } else {
            Self::NEG_INFINITY
        }
    }
}

impl Add for I32F32 {
    type Output = Self;
    /// The exact sum (saturated and counted out of range). Not sticky: an infinite operand is
    /// added as its raw extreme (see the module documentation).
    #[inline]
    fn add(self, other: Self) -> Self {
        let (raw, overflowed) = self.0.overflowing_add(other.0);
        Self::wrapped(raw, overflowed, self.0)
    }
}

impl Sub for I32F32 {
    type Output = Self;
    /// The exact difference (saturated and counted out of range).
    #[inline]
    fn sub(self, other: Self) -> Self {
        let (raw, overflowed) = self.0.overflowing_sub(other.0);
        Self::wrapped(raw, overflowed, self.0)
    }
}

impl Mul for I32F32 {
    type Output = Self;
    /// The product rounded to nearest (ties away from zero), saturated and counted out of
    /// range.
    ///
    /// Four 32 x 32 -> 64-bit multiplications of the magnitudes' halves (one `UMULL` each on
    /// a Cortex-M3) rather than a 128-bit product, which a 32-bit core computes in a
    /// library call several times longer.
    #[inline]
    fn mul(self, other: Self) -> Self {
        const LOW: u64 = 0xFFFF_FFFF;
        let negative = (self.0 ^ other.0) < 0;
        let (x, y) = (self.0.unsigned_abs(), other.0.unsigned_abs());
        let (xh, xl, yh, yl) = (x >> 32, x & LOW, y >> 32, y & LOW);
        let (ll, lh, hl, hh) = (xl * yl, xl * yh, xh * yl, xh * yh);
        // The product shifted right by 32: hh 2^32 + lh + hl + ll 2^-32, rounded at ll's
        // bit 31. Its low 32 bits, then what carries above them (at most 2^34).
        let low = (ll >> 32) + ((ll >> 31) & 1) + (lh & LOW) + (hl & LOW);
        // x, y < 2^63, so hh < 2^62 and `high` cannot wrap.
        let high = hh + (lh >> 32) + (hl >> 32) + (low >> 32);
        if high >> 31 != 0 {
            return Self::saturated(!negative);
        }
        let magnitude = ((high << 32) | (low & LOW)) as i64;
        if magnitude > MAX_FINITE_RAW {
            return Self::saturated(!negative);
        }
        Self(if negative { -magnitude } else { magnitude })
    }
}

impl Div for I32F32 {
    type Output = Self;
    /// The quotient rounded to nearest; a division by zero is infinite (NaN for 0/0) and
    /// counted.
    fn div(self, other: Self) -> Self {
        if !self.both_finite(other) {
            return self.non_finite(other, |a, b| a / b);
        }
        if other.0 == 0 {
            counter::bump();
            return match self.0.signum() {
                1 => Self::INFINITY,
                -1 => Self::NEG_INFINITY,
                _ => Self::NAN,
            };
        }
        let negative = (self.0 ^ other.0) < 0;
        match quotient_magnitude(self.0.unsigned_abs(), other.0.unsigned_abs()) {
            Some(q) if q <= MAX_FINITE_RAW as u64 => {
                let q = q as i64;
                Self(if negative { -q } else { q })
            }
            _ => Self::saturated(!negative),
        }
    }
}

/// `round(a 2^32 / b)` for magnitudes `a < 2^63` and `0 < b < 2^63`, by restoring binary
/// long division over the quotient's bits only (about 33 steps when `a` and `b` are alike),
/// rather than a general 128-bit division, which a 32-bit core runs in a library call
/// several times longer; `None` when the quotient does not fit 64 bits.
fn quotient_magnitude(a: u64, b: u64) -> Option<u64> {
    let numerator = u128::from(a) << FRACTION_BITS;
    let divisor = u128::from(b);
    if numerator < divisor {
        // Below one unit: rounds to one unit or to zero.
        return Some(u64::from(2 * numerator >= divisor));
    }
    let steps = divisor.leading_zeros() - numerator.leading_zeros();
    if steps >= 64 {
        return None;
    }
    let (mut remainder, mut shifted, mut q) = (numerator, divisor << steps, 0u64);
    for _ in 0..=steps {
        q <<= 1;
        if remainder >= shifted {
            remainder -= shifted;
            q |= 1;
        }
        shifted >>= 1;
    }
    // Nearest, ties away from zero.
    q.checked_add(u64::from(2 * remainder >= divisor))
}

impl Rem for I32F32 {
    type Output = Self;
    /// The remainder of the truncated quotient, as `f64`'s `%`.
    fn rem(self, other: Self) -> Self {
        if !self.both_finite(other) {
            return self.non_finite(other, |a, b| a % b);
        }
        if other.0 == 0 {
            return Self::invalid();
        }
        Self(self.0 % other.0)
    }
}

impl Neg for I32F32 {
    type Output = Self;
    #[inline]
    fn neg(self) -> Self {
        match self.0 {
            POS_INF_RAW => Self::NEG_INFINITY,
            NEG_INF_RAW => Self::INFINITY,
            NAN_RAW => Self::NAN,
            // The finite range is symmetric, so a finite value's negation is finite.
            raw => Self(-raw),
        }
    }
}

macro_rules! assign_op {
    ($trait:ident, $method:ident, $op:tt) => {
        impl $trait for I32F32 {
            #[inline]
            fn $method(&mut self, other: Self) {
                *self = *self $op other;
            }
        }
    };
}
assign_op!(AddAssign, add_assign, +);
assign_op!(SubAssign, sub_assign, -);
assign_op!(MulAssign, mul_assign, *);
assign_op!(DivAssign, div_assign, /);
assign_op!(RemAssign, rem_assign, %);

impl Zero for I32F32 {
    fn zero() -> Self {
        Self::ZERO
    }
    fn is_zero(&self) -> bool {
        self.0 == 0
    }
}

impl One for I32F32 {
    fn one() -> Self {
        Self::ONE
    }
}

/// Why a string is not an [`I32F32`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum ParseFixedError {
    /// Only decimal strings are read.
    RadixNotTen,
    /// The text is not a decimal number.
    NotANumber,
}

impl Num for I32F32 {
    type FromStrRadixErr = ParseFixedError;
    fn from_str_radix(text: &str, radix: u32) -> Result<Self, ParseFixedError> {
        if radix != 10 {
            return Err(ParseFixedError::RadixNotTen);
        }
        text.parse::<f64>()
            .map(Self::from_f64)
            .map_err(|_| ParseFixedError::NotANumber)
    }
}

impl Signed for I32F32 {
    fn abs(&self) -> Self {
        if self.0 < 0 {
            -*self
        } else {
            *self
        }
    }
    fn abs_sub(&self, other: &Self) -> Self {
        if *self <= *other {
            Self::ZERO
        } else {
            *self - *other
        }
    }
    fn signum(&self) -> Self {
        match self.0 {
            NAN_RAW => Self::NAN,
            raw if raw > 0 => Self::ONE,
            raw if raw < 0 => -Self::ONE,
            _ => Self::ZERO,
        }
    }
    fn is_positive(&self) -> bool {
        self.0 > 0
    }
    fn is_negative(&self) -> bool {
        self.0 < 0 && self.0 != NAN_RAW
    }
}

impl FromPrimitive for I32F32 {
    fn from_i64(n: i64) -> Option<Self> {
        let wide = i128::from(n) << FRACTION_BITS;
        (wide <= i128::from(MAX_FINITE_RAW) && wide >= i128::from(MIN_FINITE_RAW))
            .then_some(Self(wide as i64))
    }
    fn from_u64(n: u64) -> Option<Self> {
        i64::try_from(n).ok().and_then(Self::from_i64)
    }
    fn from_f64(x: f64) -> Option<Self> {
        Some(I32F32::from_f64(x))
    }
    fn from_f32(x: f32) -> Option<Self> {
        Some(I32F32::from_f64(f64::from(x)))
    }
}

impl approx::AbsDiffEq for I32F32 {
    type Epsilon = Self;
    fn default_epsilon() -> Self {
        Self::EPSILON
    }
    fn abs_diff_eq(&self, other: &Self, epsilon: Self) -> bool {
        Signed::abs(&(*self - *other)) <= epsilon
    }
}

impl approx::RelativeEq for I32F32 {
    fn default_max_relative() -> Self {
        Self::EPSILON
    }
    fn relative_eq(&self, other: &Self, epsilon: Self, max_relative: Self) -> bool {
        if self == other {
            return true;
        }
        let diff = Signed::abs(&(*self - *other));
        if diff <= epsilon {
            return true;
        }
        let largest = RealField::max(Signed::abs(self), Signed::abs(other));
        diff <= largest * max_relative
    }
}

impl approx::UlpsEq for I32F32 {
    fn default_max_ulps() -> u32 {
        4
    }
    fn ulps_eq(&self, other: &Self, epsilon: Self, max_ulps: u32) -> bool {
        if approx::AbsDiffEq::abs_diff_eq(self, other, epsilon) {
            return true;
        }
        self.is_finite_value()
            && other.is_finite_value()
            && self.0.abs_diff(other.0) <= u64::from(max_ulps)
    }
}

impl SimdValue for I32F32 {
    const LANES: usize = 1;
    type Element = Self;
    type SimdBool = bool;
    fn splat(val: Self) -> Self {
        val
    }
    fn extract(&self, _: usize) -> Self {
        *self
    }
    unsafe fn extract_unchecked(&self, _: usize) -> Self {
        *self
    }
    fn replace(&mut self, _: usize, val: Self) {
        *self = val;
    }
    unsafe fn replace_unchecked(&mut self, _: usize, val: Self) {
        *self = val;
    }
    fn select(self, cond: bool, other: Self) -> Self {
        if cond {
            self
        } else {
            other
        }
    }
}

impl PrimitiveSimdValue for I32F32 {}
impl Field for I32F32 {}

impl SubsetOf<I32F32> for I32F32 {
    fn to_superset(&self) -> Self {
        *self
    }
    fn from_superset_unchecked(element: &Self) -> Self {
        *element
    }
    fn is_in_subset(_: &Self) -> bool {
        true
    }
}

impl SubsetOf<I32F32> for f64 {
    fn to_superset(&self) -> I32F32 {
        I32F32::from_f64(*self)
    }
    fn from_superset_unchecked(element: &I32F32) -> f64 {
        element.to_f64()
    }
    fn is_in_subset(_: &I32F32) -> bool {
        true
    }
}

impl SubsetOf<I32F32> for f32 {
    fn to_superset(&self) -> I32F32 {
        I32F32::from_f64(f64::from(*self))
    }
    fn from_superset_unchecked(element: &I32F32) -> f32 {
        element.to_f64() as f32
    }
    fn is_in_subset(_: &I32F32) -> bool {
        true
    }
}

/// So a filter value can be read back in `f64` (`nalgebra::try_convert::<I32F32, f64>`).
impl SubsetOf<f64> for I32F32 {
    fn to_superset(&self) -> f64 {
        self.to_f64()
    }
    fn from_superset_unchecked(element: &f64) -> Self {
        I32F32::from_f64(*element)
    }
    fn is_in_subset(element: &f64) -> bool {
        element.is_nan() || element.abs() < MAX_FINITE_RAW as f64 / SCALE
    }
}

mod math;

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;
    use simba::scalar::ComplexField;

    /// Half a unit in the last place: the error bound of one rounded operation.
    const HALF_ULP: f64 = 0.5 / SCALE;

    fn fx(x: f64) -> I32F32 {
        I32F32::from_f64(x)
    }

    proptest! {
        #[test]
        fn from_f32_is_from_f64_of_the_widened_value(bits in any::<u32>()) {
            let x = f32::from_bits(bits);
            let before = overflows();
            let direct = I32F32::from_f32(x);
            let direct_counted = overflows() - before;
            let before = overflows();
            let widened = I32F32::from_f64(f64::from(x));
            prop_assert_eq!(direct.to_raw(), widened.to_raw(), "{}", x);
            prop_assert_eq!(direct_counted, overflows() - before, "{}", x);
        }

        #[test]
        fn from_f32_rounds_values_near_the_resolution_and_the_range(
            m in 0x80_0000u32..0x100_0000,
            e in -60i32..40,
            negative in any::<bool>(),
        ) {
            let x = (m as f32) * 2f32.powi(e - 23) * if negative { -1.0 } else { 1.0 };
            prop_assert_eq!(
                I32F32::from_f32(x).to_raw(),
                I32F32::from_f64(f64::from(x)).to_raw(),
                "{}", x
            );
        }

        #[test]
        fn to_f32_rounds_once(raw in -(1i64 << 53)..(1i64 << 53)) {
            // Below 2^53 the raw value is exact in f64, so the f64 way rounds once too.
            let x = I32F32::from_raw(raw);
            prop_assert_eq!(x.to_f32(), x.to_f64() as f32);
        }

        #[test]
        fn arithmetic_is_the_exact_result_rounded(a in -4.0e4f64..4.0e4, b in -4.0e4f64..4.0e4) {
            let (x, y) = (fx(a), fx(b));
            let (xa, yb) = (x.to_f64(), y.to_f64());
            let before = overflows();
            prop_assert_eq!((x + y).to_f64(), xa + yb);
            prop_assert_eq!((x - y).to_f64(), xa - yb);
            // Products and quotients rounded once: within half a unit of the exact value
            // (f64 holds the exact product of two values this size to 1e-16 relative).
            let product = xa * yb;
            prop_assert!(((x * y).to_f64() - product).abs() <= HALF_ULP + product.abs() * 1e-15);
            if yb.abs() > 1e-3 {
                let quotient = xa / yb;
                prop_assert!(((x / y).to_f64() - quotient).abs() <= HALF_ULP + quotient.abs() * 1e-15);
            }
            prop_assert_eq!(overflows(), before);
        }
    }

    #[test]
    fn conversion_rounds_to_the_nearest_step() {
        assert_eq!(fx(1.0).to_raw(), 1 << 32);
        assert_eq!(fx(-0.5).to_raw(), -(1 << 31));
        assert_eq!(fx(0.6 / SCALE).to_raw(), 1);
        assert_eq!(fx(0.4 / SCALE).to_raw(), 0);
        assert_eq!(fx(1.0e9).to_f64(), 1.0e9);
    }

    #[test]
    fn an_overflow_saturates_and_is_counted() {
        let before = overflows();
        let big = fx(2.0e9);
        let sum = big + big;
        assert_eq!(sum, I32F32::INFINITY);
        assert!(!ComplexField::is_finite(&sum));
        assert_eq!(fx(-2.0e9) - big, I32F32::NEG_INFINITY);
        assert_eq!(overflows(), before + 2);
        // Products beyond the range, of either sign, and the smallest number's reciprocal.
        assert_eq!(fx(-5.0e4) * fx(5.0e4), I32F32::NEG_INFINITY);
        assert_eq!(fx(5.0e4) * fx(5.0e4), I32F32::INFINITY);
        assert_eq!(fx(1.0) / I32F32::EPSILON, I32F32::INFINITY);
        assert_eq!(overflows(), before + 5);
        // Division and the square root carry an infinity on, without counting it again.
        assert_eq!(sum / fx(-2.0), I32F32::NEG_INFINITY);
        assert_eq!(sum.sqrt_fixed(), I32F32::INFINITY);
        assert_eq!(overflows(), before + 5);
        // Just inside the range nothing is counted.
        assert_eq!((fx(46_340.0) * fx(46_340.0)).to_f64(), 46_340.0 * 46_340.0);
        assert_eq!(overflows(), before + 5);
    }

    #[test]
    fn invalid_operations_are_nan_and_counted() {
        let before = overflows();
        assert_eq!(fx(1.0) / I32F32::ZERO, I32F32::INFINITY);
        assert_eq!(fx(-1.0) / I32F32::ZERO, I32F32::NEG_INFINITY);
        assert!(!ComplexField::is_finite(&(I32F32::ZERO / I32F32::ZERO)));
        assert!(!ComplexField::is_finite(&fx(f64::NAN)));
        assert!(!ComplexField::is_finite(&fx(f64::INFINITY)));
        assert_eq!(overflows(), before + 5);
    }

    #[test]
    fn nalgebra_runs_on_it() {
        use nalgebra::{Matrix3, UnitQuaternion, Vector3};
        let m = Matrix3::<I32F32>::new(
            fx(4.0),
            fx(1.0),
            fx(0.5),
            fx(1.0),
            fx(3.0),
            fx(0.25),
            fx(0.5),
            fx(0.25),
            fx(2.0),
        );
        let inverse = m.try_inverse().expect("invertible");
        let identity = m * inverse;
        for i in 0..3 {
            for j in 0..3 {
                let want = if i == j { 1.0 } else { 0.0 };
                assert!((identity[(i, j)].to_f64() - want).abs() < 1e-8);
            }
        }
        let q = UnitQuaternion::from_scaled_axis(Vector3::new(fx(0.1), fx(-0.2), fx(0.3)));
        let back = q.scaled_axis();
        assert!((back.x.to_f64() - 0.1).abs() < 1e-8 && (back.z.to_f64() - 0.3).abs() < 1e-8);
        let v: I32F32 = nalgebra::convert(0.125);
        assert_eq!(nalgebra::try_convert::<I32F32, f64>(v), Some(0.125));
    }
}
