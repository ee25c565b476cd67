//! The scalars the navigation filter runs in, and what it asks of them beyond nalgebra's
//! `RealField`: `f64` (the host's reference), `f32` (the Cortex-M4F board) and
//! [`I32F32`] (fixed point, for cores without an FPU).
//!
//! A float carries its own exponent, so the filter holds its covariance as it is. A fixed
//! format resolves 2^-32 over a range of 2^31, about 19 decades, while the covariance spans
//! 10 to 14 (`docs/navigation.md`, "Toward fixed point"): there the filter keeps each state's
//! scale apart, as a power of two ([`FilterScalar::SCALED`]), and multiplies by powers of
//! two ([`FilterScalar::mul_pow2`]), which is exact in both kinds of scalar. Constants far
//! below the fixed format's resolution (the noise densities, the variance floors) are held
//! as a mantissa and a power of two ([`Pow2`]).

use nalgebra::RealField;

use crate::fixed::I32F32;

/// A scalar the filter runs in.
pub trait FilterScalar: RealField + Copy {
    /// Whether the filter scales each state by a power of two of its own (fixed point) or
    /// holds the covariance as it is (floating point: the scale is the float's exponent,
    /// and the float path stays what it was, operation for operation).
    const SCALED: bool;

    /// `self · 2^n`, exact unless the result leaves the scalar's range (fixed point then
    /// saturates and counts it) or, in fixed point, falls below its resolution (rounded).
    fn mul_pow2(self, n: i32) -> Self;

    /// `floor(log2 |self|)`; `None` for zero and non-finite values.
    fn exponent(self) -> Option<i32>;

    /// `x` as a mantissa and a power of two this scalar holds to its full precision.
    fn pow2_from_f64(x: f64) -> Pow2<Self>;

    /// `(sin x, cos x)` of `self` in rad. The board's `f32` takes a compact routine
    /// ([`sin_cos_f32`]); the other scalars their own `sin_cos`.
    #[inline(always)]
    fn sin_cos_rad(self) -> (Self, Self) {
        self.sin_cos()
    }

    /// `x` in this scalar: what `nalgebra::convert(f64::from(x))` gives (floats exactly;
    /// fixed point rounded to nearest, saturated and counted out of range), without the
    /// software `f64` a core without an FPU would spend on the way (the fusion's sensor
    /// means go into the filter's scalar this way, a few dozen a step).
    #[inline(always)]
    fn convert_from_f32(x: f32) -> Self {
        nalgebra::convert(f64::from(x))
    }

    /// The value in `f32`, rounded to nearest (NaN for a value `f64` cannot hold).
    #[inline(always)]
    fn convert_to_f32(self) -> f32 {
        nalgebra::try_convert::<Self, f64>(self).map_or(f32::NAN, |v| v as f32)
    }

    /// Results of this scalar that saturated or were invalid so far (never decreasing; 0
    /// for floats, whose overflow the filter sees as non-finite values). The filter reads
    /// it around each step, since fixed-point saturation does not propagate as IEEE
    /// infinities do.
    #[inline(always)]
    fn overflows() -> u64 {
        0
    }
}

/// A number held as `mantissa · 2^exponent`, so a scalar with a narrow range (fixed point)
/// keeps a tiny constant (a gyro-bias noise density of 1e-10 rad²/s³ is half a unit of
/// [`I32F32`]) to its full precision. For floats the exponent is 0 and the mantissa the
/// number itself.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Pow2<T> {
    pub mantissa: T,
    pub exponent: i32,
}

impl<T: FilterScalar> Pow2<T> {
    /// `x`, held to the scalar's precision.
    pub fn from_f64(x: f64) -> Self {
        T::pow2_from_f64(x)
    }

    /// `x` (single precision: the board's configuration), held to the scalar's precision.
    pub fn from_f32(x: f32) -> Self {
        T::pow2_from_f64(f64::from(x))
    }

    /// Zero.
    pub fn zero() -> Self {
        Self {
            mantissa: T::zero(),
            exponent: 0,
        }
    }

    /// The number times `2^n`, in the scalar.
    pub fn times_pow2(self, n: i32) -> T {
        self.mantissa.mul_pow2(self.exponent.saturating_add(n))
    }

    /// The number itself, in the scalar (for fixed point, only where it is in range).
    pub fn value(self) -> T {
        self.times_pow2(0)
    }

    /// Finite and not negative: usable as a variance or a density.
    pub fn is_usable(self) -> bool {
        self.mantissa.is_finite() && self.mantissa >= T::zero()
    }
}

// The floats' powers of two are built from their bits (no library call: the board's
// `f32` filter never scales, and must not carry the code to).
impl FilterScalar for f64 {
    const SCALED: bool = false;
    fn convert_from_f32(x: f32) -> Self {
        f64::from(x)
    }
    fn mul_pow2(self, n: i32) -> Self {
        // Two factors, each a normal power of two, cover any shift a finite value survives.
        let half = n / 2;
        let factor = |k: i32| f64::from_bits(((k.clamp(-1022, 1023) + 1023) as u64) << 52);
        self * factor(half) * factor(n - half)
    }
    fn exponent(self) -> Option<i32> {
        (self != 0.0 && self.is_finite()).then(|| libm::ilogb(self))
    }
    fn pow2_from_f64(x: f64) -> Pow2<Self> {
        Pow2 {
            mantissa: x,
            exponent: 0,
        }
    }
}

impl FilterScalar for f32 {
    const SCALED: bool = false;
    fn convert_from_f32(x: f32) -> Self {
        x
    }
    fn convert_to_f32(self) -> f32 {
        self
    }
    fn sin_cos_rad(self) -> (Self, Self) {
        sin_cos_f32(self)
    }
    fn mul_pow2(self, n: i32) -> Self {
        let half = n / 2;
        let factor = |k: i32| f32::from_bits(((k.clamp(-126, 127) + 127) as u32) << 23);
        self * factor(half) * factor(n - half)
    }
    fn exponent(self) -> Option<i32> {
        (self != 0.0 && self.is_finite()).then(|| libm::ilogbf(self))
    }
    fn pow2_from_f64(x: f64) -> Pow2<Self> {
        Pow2 {
            mantissa: x as f32,
            exponent: 0,
        }
    }
}

impl FilterScalar for I32F32 {
    const SCALED: bool = true;
    fn mul_pow2(self, n: i32) -> Self {
        self.shifted(n)
    }
    fn exponent(self) -> Option<i32> {
        self.log2_floor()
    }
    fn overflows() -> u64 {
        crate::fixed::overflows()
    }
    fn convert_from_f32(x: f32) -> Self {
        I32F32::from_f32(x)
    }
    fn convert_to_f32(self) -> f32 {
        I32F32::to_f32(self)
    }
    fn pow2_from_f64(x: f64) -> Pow2<Self> {
        if x == 0.0 || !x.is_finite() {
            return Pow2 {
                mantissa: I32F32::from_f64(x),
                exponent: 0,
            };
        }
        // x = m 2^e with |m| in [1/2, 1): the mantissa keeps 31 significant bits.
        let (m, e) = libm::frexp(x);
        Pow2 {
            mantissa: I32F32::from_f64(m),
            exponent: e,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_tiny_constant_keeps_its_digits_in_fixed_point() {
        let psd = 1.0e-10;
        // As a plain fixed-point value it rounds to nothing.
        assert_eq!(I32F32::from_f64(psd).to_f64(), 0.0);
        let held = Pow2::<I32F32>::from_f64(psd);
        // Scaled up by the variance's own exponent it is exact to 31 bits.
        let scaled = held.times_pow2(40).to_f64();
        assert!(
            (scaled / (psd * 2f64.powi(40)) - 1.0).abs() < 1e-9,
            "{scaled}"
        );
    }

    #[test]
    fn powers_of_two_are_exact_and_exponents_agree_across_scalars() {
        for x in [3.0e-7, 0.75, 1.0, 1.5, 6.0e3] {
            let e = f64::exponent(x).unwrap();
            assert_eq!(f32::exponent(x as f32), Some(e));
            assert_eq!(I32F32::from_f64(x).exponent(), Some(e), "{x}");
            assert_eq!(x.mul_pow2(-3), x / 8.0);
            let fixed = I32F32::from_f64(x);
            assert_eq!(fixed.mul_pow2(2).to_f64(), fixed.to_f64() * 4.0);
        }
        assert_eq!(I32F32::ZERO.exponent(), None);
        assert_eq!(f64::exponent(0.0), None);
    }

    #[test]
    fn a_shift_out_of_range_saturates_and_is_counted() {
        let before = crate::fixed::overflows();
        assert_eq!(I32F32::from_f64(3.0).mul_pow2(40), I32F32::INFINITY);
        assert_eq!(I32F32::from_f64(-3.0).mul_pow2(40), I32F32::NEG_INFINITY);
        assert_eq!(crate::fixed::overflows(), before + 2);
        // Below the resolution it rounds to zero, which is not an overflow.
        assert_eq!(I32F32::from_f64(3.0).mul_pow2(-40), I32F32::ZERO);
        assert_eq!(crate::fixed::overflows(), before + 2);
    }
}

/// `(sin x, cos x)` in `f32` for any finite `x` (rad), within 2e-7 of the exact values:
/// the angle reduced by multiples of `π/2` in `f64` (exact enough for `|x|` up to 1e9),
/// then Cephes' minimax polynomials on `[−π/4, π/4]`. Written here because libm's
/// `sincosf` carries a reduction for arguments up to 1e38 (its Payne-Hanek table and code,
/// 6.7 KB of the board's flash) that no angle the board meets needs.
pub fn sin_cos_f32(x: f32) -> (f32, f32) {
    let quarter_turns = libm::round(f64::from(x) * core::f64::consts::FRAC_2_PI);
    let r = (f64::from(x) - quarter_turns * core::f64::consts::FRAC_PI_2) as f32;
    let z = r * r;
    let sin = r + r * z * (-1.666_665_5e-1 + z * (8.332_161e-3 + z * -1.951_529_6e-4));
    let cos = 1.0 - 0.5 * z + z * z * (4.166_664_6e-2 + z * (-1.388_731_6e-3 + z * 2.443_315_7e-5));
    match (quarter_turns as i64).rem_euclid(4) {
        0 => (sin, cos),
        1 => (cos, -sin),
        2 => (-sin, -cos),
        _ => (-cos, sin),
    }
}

/// The rotation of roll, pitch and yaw (rad) as nalgebra's `UnitQuaternion::
/// from_euler_angles` builds it (yaw about z, then pitch about y, then roll about x), with
/// the scalar's [`FilterScalar::sin_cos_rad`].
pub fn quaternion_from_euler<T: FilterScalar>(
    roll: T,
    pitch: T,
    yaw: T,
) -> nalgebra::UnitQuaternion<T> {
    let half: T = nalgebra::convert(0.5);
    let (sr, cr) = (roll * half).sin_cos_rad();
    let (sp, cp) = (pitch * half).sin_cos_rad();
    let (sy, cy) = (yaw * half).sin_cos_rad();
    nalgebra::UnitQuaternion::new_unchecked(nalgebra::Quaternion::new(
        cr * cp * cy + sr * sp * sy,
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
    ))
}

#[cfg(test)]
mod trig_tests {
    use super::*;

    #[test]
    fn the_compact_sine_and_cosine_hold_to_two_parts_in_ten_million() {
        let mut worst = 0.0f64;
        for i in -200_000..=200_000 {
            let x = i as f32 * 1.3e-4 * (1.0 + (i as f32).abs() * 1e-3);
            let (s, c) = sin_cos_f32(x);
            let (es, ec) = (f64::from(x).sin(), f64::from(x).cos());
            worst = worst
                .max((f64::from(s) - es).abs())
                .max((f64::from(c) - ec).abs());
        }
        assert!(worst < 2e-7, "{worst}");
        let (s, c) = sin_cos_f32(f32::NAN);
        assert!(s.is_nan() && c.is_nan());
    }

    #[test]
    fn euler_angles_turn_as_nalgebra_turns_them() {
        for (r, p, y) in [(0.3, -0.2, 2.5), (-3.0, 1.2, -0.7), (0.0, 0.0, 1.2)] {
            let ours = quaternion_from_euler::<f64>(r, p, y);
            let theirs = nalgebra::UnitQuaternion::from_euler_angles(r, p, y);
            assert!(ours.angle_to(&theirs) < 1e-12, "{r} {p} {y}");
            let small = quaternion_from_euler::<f32>(r as f32, p as f32, y as f32);
            let theirs32 =
                nalgebra::UnitQuaternion::from_euler_angles(r as f32, p as f32, y as f32);
            assert!(small.angle_to(&theirs32) < 1e-6, "{r} {p} {y}");
        }
    }
}
