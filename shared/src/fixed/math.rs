//! [`I32F32`] as a `nalgebra` real field: the elementary functions. The square root and the
//! rounding functions are integer arithmetic; the transcendental functions are `libm`'s in
//! `f64` (see the parent module for why that is off the filter's cycle).

use super::{FRACTION_BITS, I32F32, NAN_RAW, ONE_RAW};
use num_traits::Signed;
use simba::scalar::{ComplexField, RealField};

impl I32F32 {
    /// The square root rounded to nearest; NaN (counted) for a negative number.
    pub fn sqrt_fixed(self) -> Self {
        if !self.is_finite_value() {
            return self.via_f64(libm::sqrt);
        }
        if self.0 < 0 {
            return Self::invalid();
        }
        // sqrt(raw / 2^32) * 2^32 = sqrt(raw * 2^32).
        let n = (self.0 as u128) << FRACTION_BITS;
        let root = u128::from(root_of_raw_times_2_32(self.0 as u64));
        // Nearest: root + 1 if n lies past the midpoint (root + 1/2)^2 = root^2 + root + 1/4.
        let rounded = if n - root * root > root {
            root + 1
        } else {
            root
        };
        Self(rounded as i64)
    }

    /// Rounds towards minus infinity to a multiple of one.
    fn floor_fixed(self) -> Self {
        if !self.is_finite_value() {
            return self;
        }
        Self(self.0 & !(ONE_RAW - 1))
    }
}

/// `floor(sqrt(raw 2^32))` for `raw < 2^63`: the root's high bits are `raw`'s own 64-bit
/// root times 2^16 (`sqrt(raw) 2^16` lies within 2^16 above it), its low 16 bits are set one
/// at a time against 96-bit squares. A 128-bit integer root (`u128::isqrt`) is library
/// arithmetic on 128-bit words on a 32-bit core, and several times longer.
fn root_of_raw_times_2_32(raw: u64) -> u64 {
    let n = u128::from(raw) << FRACTION_BITS;
    let mut root = raw.isqrt() << 16;
    for bit in (0..16).rev() {
        let candidate = root | (1 << bit);
        if u128::from(candidate) * u128::from(candidate) <= n {
            root = candidate;
        }
    }
    root
}

impl ComplexField for I32F32 {
    type RealField = Self;

    fn from_real(re: Self) -> Self {
        re
    }
    fn real(self) -> Self {
        self
    }
    fn imaginary(self) -> Self {
        Self::ZERO
    }
    fn modulus(self) -> Self {
        Signed::abs(&self)
    }
    fn modulus_squared(self) -> Self {
        self * self
    }
    fn argument(self) -> Self {
        if self.0 >= 0 {
            Self::ZERO
        } else {
            Self::pi()
        }
    }
    fn norm1(self) -> Self {
        Signed::abs(&self)
    }
    fn scale(self, factor: Self) -> Self {
        self * factor
    }
    fn unscale(self, factor: Self) -> Self {
        self / factor
    }
    fn floor(self) -> Self {
        self.floor_fixed()
    }
    fn ceil(self) -> Self {
        -(-self).floor_fixed()
    }
    fn round(self) -> Self {
        // Half away from zero, as f64::round.
        let half = Self(ONE_RAW / 2);
        if self.0 >= 0 {
            (self + half).floor_fixed()
        } else {
            -((-self) + half).floor_fixed()
        }
    }
    fn trunc(self) -> Self {
        if self.0 >= 0 {
            self.floor_fixed()
        } else {
            -(-self).floor_fixed()
        }
    }
    fn fract(self) -> Self {
        self - self.trunc()
    }
    fn mul_add(self, a: Self, b: Self) -> Self {
        self * a + b
    }
    fn abs(self) -> Self {
        Signed::abs(&self)
    }
    fn hypot(self, other: Self) -> Self {
        // Scaled by the larger magnitude so the squares cannot overflow.
        let (a, b) = (Signed::abs(&self), Signed::abs(&other));
        let (big, small) = if a >= b { (a, b) } else { (b, a) };
        if big.0 == 0 || !big.is_finite_value() {
            return big;
        }
        let ratio = small / big;
        big * (Self::ONE + ratio * ratio).sqrt_fixed()
    }
    fn recip(self) -> Self {
        Self::ONE / self
    }
    fn conjugate(self) -> Self {
        self
    }
    fn sin(self) -> Self {
        self.via_f64(libm::sin)
    }
    fn cos(self) -> Self {
        self.via_f64(libm::cos)
    }
    fn sin_cos(self) -> (Self, Self) {
        (self.sin(), self.cos())
    }
    fn tan(self) -> Self {
        self.via_f64(libm::tan)
    }
    fn asin(self) -> Self {
        self.via_f64(libm::asin)
    }
    fn acos(self) -> Self {
        self.via_f64(libm::acos)
    }
    fn atan(self) -> Self {
        self.via_f64(libm::atan)
    }
    fn sinh(self) -> Self {
        self.via_f64(libm::sinh)
    }
    fn cosh(self) -> Self {
        self.via_f64(libm::cosh)
    }
    fn tanh(self) -> Self {
        self.via_f64(libm::tanh)
    }
    fn asinh(self) -> Self {
        self.via_f64(libm::asinh)
    }
    fn acosh(self) -> Self {
        self.via_f64(libm::acosh)
    }
    fn atanh(self) -> Self {
        self.via_f64(libm::atanh)
    }
    fn log(self, base: Self) -> Self {
        let b = base.to_f64();
        self.via_f64(|x| libm::log(x) / libm::log(b))
    }
    fn log2(self) -> Self {
        self.via_f64(libm::log2)
    }
    fn log10(self) -> Self {
        self.via_f64(libm::log10)
    }
    fn ln(self) -> Self {
        self.via_f64(libm::log)
    }
    fn ln_1p(self) -> Self {
        self.via_f64(libm::log1p)
    }
    fn sqrt(self) -> Self {
        self.sqrt_fixed()
    }
    fn exp(self) -> Self {
        self.via_f64(libm::exp)
    }
    fn exp2(self) -> Self {
        self.via_f64(libm::exp2)
    }
    fn exp_m1(self) -> Self {
        self.via_f64(libm::expm1)
    }
    fn powi(self, n: i32) -> Self {
        // Square and multiply: exact products, each rounded once.
        let mut base = if n < 0 { self.recip() } else { self };
        let mut e = n.unsigned_abs();
        let mut acc = Self::ONE;
        while e > 0 {
            if e & 1 == 1 {
                acc *= base;
            }
            e >>= 1;
            if e > 0 {
                base *= base;
            }
        }
        acc
    }
    fn powf(self, n: Self) -> Self {
        let e = n.to_f64();
        self.via_f64(|x| libm::pow(x, e))
    }
    fn powc(self, n: Self) -> Self {
        self.powf(n)
    }
    fn cbrt(self) -> Self {
        self.via_f64(libm::cbrt)
    }
    fn is_finite(&self) -> bool {
        self.is_finite_value()
    }
    fn try_sqrt(self) -> Option<Self> {
        (self.0 >= 0).then(|| self.sqrt_fixed())
    }
}

/// A constant, rounded to nearest.
fn constant(x: f64) -> I32F32 {
    I32F32::from_f64(x)
}

impl RealField for I32F32 {
    fn is_sign_positive(&self) -> bool {
        self.0 >= 0
    }
    fn is_sign_negative(&self) -> bool {
        self.0 < 0 && self.0 != NAN_RAW
    }
    fn copysign(self, sign: Self) -> Self {
        let magnitude = Signed::abs(&self);
        if sign.is_sign_negative() {
            -magnitude
        } else {
            magnitude
        }
    }
    /// The larger; a NaN operand is ignored, as `f64::max` does.
    fn max(self, other: Self) -> Self {
        match (self.0 == NAN_RAW, other.0 == NAN_RAW) {
            (true, _) => other,
            (_, true) => self,
            _ if self.0 >= other.0 => self,
            _ => other,
        }
    }
    /// The smaller; a NaN operand is ignored, as `f64::min` does.
    fn min(self, other: Self) -> Self {
        match (self.0 == NAN_RAW, other.0 == NAN_RAW) {
            (true, _) => other,
            (_, true) => self,
            _ if self.0 <= other.0 => self,
            _ => other,
        }
    }
    fn clamp(self, min: Self, max: Self) -> Self {
        RealField::min(RealField::max(self, min), max)
    }
    fn atan2(self, other: Self) -> Self {
        let x = other.to_f64();
        self.via_f64(|y| libm::atan2(y, x))
    }
    fn min_value() -> Option<Self> {
        Some(Self::MIN)
    }
    fn max_value() -> Option<Self> {
        Some(Self::MAX)
    }
    fn pi() -> Self {
        constant(core::f64::consts::PI)
    }
    fn two_pi() -> Self {
        constant(core::f64::consts::TAU)
    }
    fn frac_pi_2() -> Self {
        constant(core::f64::consts::FRAC_PI_2)
    }
    fn frac_pi_3() -> Self {
        constant(core::f64::consts::FRAC_PI_3)
    }
    fn frac_pi_4() -> Self {
        constant(core::f64::consts::FRAC_PI_4)
    }
    fn frac_pi_6() -> Self {
        constant(core::f64::consts::FRAC_PI_6)
    }
    fn frac_pi_8() -> Self {
        constant(core::f64::consts::FRAC_PI_8)
    }
    fn frac_1_pi() -> Self {
        constant(core::f64::consts::FRAC_1_PI)
    }
    fn frac_2_pi() -> Self {
        constant(core::f64::consts::FRAC_2_PI)
    }
    fn frac_2_sqrt_pi() -> Self {
        constant(core::f64::consts::FRAC_2_SQRT_PI)
    }
    fn e() -> Self {
        constant(core::f64::consts::E)
    }
    fn log2_e() -> Self {
        constant(core::f64::consts::LOG2_E)
    }
    fn log10_e() -> Self {
        constant(core::f64::consts::LOG10_E)
    }
    fn ln_2() -> Self {
        constant(core::f64::consts::LN_2)
    }
    fn ln_10() -> Self {
        constant(core::f64::consts::LN_10)
    }
}

#[cfg(test)]
mod tests {
    use super::super::overflows;
    use super::*;

    fn fx(x: f64) -> I32F32 {
        I32F32::from_f64(x)
    }

    #[test]
    fn the_root_of_a_raw_value_is_the_128_bit_integer_root() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(31);
        let edges = [
            0u64,
            1,
            2,
            3,
            4,
            (1 << 32) - 1,
            1 << 32,
            (1 << 62) + 1,
            (1 << 63) - 1,
        ];
        let random = (0..20_000).map(|_| rng.random::<u64>() >> rng.random_range(1..64));
        for raw in edges.into_iter().chain(random) {
            let n = u128::from(raw) << FRACTION_BITS;
            assert_eq!(u128::from(root_of_raw_times_2_32(raw)), n.isqrt(), "{raw}");
        }
    }

    #[test]
    fn square_root_is_rounded_to_nearest() {
        for x in [0.0, 1e-9, 2.3e-10, 0.25, 2.0, 3.0, 1e4, 2.0e9] {
            // Against the root of the value the format holds (1e-9 is held as 4 steps).
            let held = fx(x).to_f64();
            let got = fx(x).sqrt_fixed().to_f64();
            let bound = 0.5 / (1u64 << 32) as f64 + 1e-15 * held.sqrt();
            assert!((got - held.sqrt()).abs() <= bound, "{x}: {got}");
        }
        let before = overflows();
        assert!(!fx(-1.0).sqrt_fixed().is_finite_value());
        assert_eq!(overflows(), before + 1);
    }

    #[test]
    fn rounding_functions_match_f64() {
        for x in [-2.5, -2.0, -1.75, -0.5, -0.25, 0.0, 0.25, 0.5, 1.5, 2.75] {
            let v = fx(x);
            assert_eq!(v.floor().to_f64(), x.floor(), "floor {x}");
            assert_eq!(v.ceil().to_f64(), x.ceil(), "ceil {x}");
            assert_eq!(v.round().to_f64(), x.round(), "round {x}");
            assert_eq!(v.trunc().to_f64(), x.trunc(), "trunc {x}");
            assert_eq!(v.fract().to_f64(), x.fract(), "fract {x}");
        }
    }

    #[test]
    fn powers_and_hypot_match_f64() {
        let v = fx(1.1);
        assert!((v.powi(5).to_f64() - 1.1f64.powi(5)).abs() < 1e-8);
        assert!((v.powi(-2).to_f64() - 1.1f64.powi(-2)).abs() < 1e-8);
        // hypot of values whose squares would overflow the format.
        let h = fx(4.0e4).hypot(fx(3.0e4)).to_f64();
        assert!((h - 5.0e4).abs() < 1e-4, "{h}");
    }
}
