//! Truncated Taylor jets: a value with its first three time derivatives, carried through
//! arithmetic and elementary functions by the chain and Leibniz rules. The trajectory is
//! written once as smooth functions of time on jets, and angular rate, angular acceleration,
//! specific force and jerk fall out exactly, with no finite differences.
//!
//! Hand-written rather than taken from a dual-number crate because only order 3 in one
//! variable is needed, on the hot path of the simulator, and `num-dual` would pull a second
//! nalgebra version into the build.

use std::ops::{Add, Div, Mul, Neg, Sub};

/// `[f, f', f'', f''']` of a function of time at one instant.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Jet(pub [f64; 4]);

impl Jet {
    /// A constant.
    #[inline]
    pub const fn constant(value: f64) -> Self {
        Jet([value, 0.0, 0.0, 0.0])
    }
    /// The independent variable itself at `t`.
    #[inline]
    pub const fn variable(t: f64) -> Self {
        Jet([t, 1.0, 0.0, 0.0])
    }
    /// The value.
    #[inline]
    pub fn value(self) -> f64 {
        self.0[0]
    }
    /// The k-th derivative (k <= 3).
    #[inline]
    pub fn d(self, k: usize) -> f64 {
        self.0[k]
    }
    /// The jet of the derivative. Its third derivative is unknown and set to 0, so only
    /// orders 0..=2 of the result are exact.
    #[inline]
    pub fn derivative(self) -> Self {
        Jet([self.0[1], self.0[2], self.0[3], 0.0])
    }
    /// g(self) for a scalar function g with derivatives `g = [g, g', g'', g''']` at the value.
    #[inline]
    fn compose(self, g: [f64; 4]) -> Self {
        let [_, f1, f2, f3] = self.0;
        Jet([
            g[0],
            g[1] * f1,
            g[2] * f1 * f1 + g[1] * f2,
            g[3] * f1 * f1 * f1 + 3.0 * g[2] * f1 * f2 + g[1] * f3,
        ])
    }
    #[inline]
    pub fn sin(self) -> Self {
        let (s, c) = self.0[0].sin_cos();
        self.compose([s, c, -s, -c])
    }
    #[inline]
    pub fn cos(self) -> Self {
        let (s, c) = self.0[0].sin_cos();
        self.compose([c, -s, -c, s])
    }
    /// (sin, cos) sharing one evaluation.
    #[inline]
    pub fn sin_cos(self) -> (Self, Self) {
        let (s, c) = self.0[0].sin_cos();
        (self.compose([s, c, -s, -c]), self.compose([c, -s, -c, s]))
    }
    #[inline]
    pub fn tan(self) -> Self {
        let t = self.0[0].tan();
        let sec2 = 1.0 + t * t;
        self.compose([t, sec2, 2.0 * t * sec2, 2.0 * sec2 * (1.0 + 3.0 * t * t)])
    }
    #[inline]
    pub fn recip(self) -> Self {
        let r = 1.0 / self.0[0];
        self.compose([r, -r * r, 2.0 * r * r * r, -6.0 * r * r * r * r])
    }
    #[inline]
    pub fn sqrt(self) -> Self {
        let s = self.0[0].sqrt();
        let x = self.0[0];
        self.compose([s, 0.5 / s, -0.25 / (s * x), 0.375 / (s * x * x)])
    }
    #[inline]
    pub fn scale(self, k: f64) -> Self {
        Jet(self.0.map(|v| v * k))
    }
}

impl Add for Jet {
    type Output = Jet;
    #[inline]
    fn add(self, o: Jet) -> Jet {
        Jet([
            self.0[0] + o.0[0],
            self.0[1] + o.0[1],
            self.0[2] + o.0[2],
            self.0[3] + o.0[3],
        ])
    }
}
impl Sub for Jet {
    type Output = Jet;
    #[inline]
    fn sub(self, o: Jet) -> Jet {
        Jet([
            self.0[0] - o.0[0],
            self.0[1] - o.0[1],
            self.0[2] - o.0[2],
            self.0[3] - o.0[3],
        ])
    }
}
impl Neg for Jet {
    type Output = Jet;
    #[inline]
    fn neg(self) -> Jet {
        Jet(self.0.map(|v| -v))
    }
}
impl Mul for Jet {
    type Output = Jet;
    #[inline]
    fn mul(self, o: Jet) -> Jet {
        let [a0, a1, a2, a3] = self.0;
        let [b0, b1, b2, b3] = o.0;
        Jet([
            a0 * b0,
            a1 * b0 + a0 * b1,
            a2 * b0 + 2.0 * a1 * b1 + a0 * b2,
            a3 * b0 + 3.0 * a2 * b1 + 3.0 * a1 * b2 + a0 * b3,
        ])
    }
}
impl Div for Jet {
    type Output = Jet;
    #[allow(clippy::suspicious_arithmetic_impl)] // a / b is a times the jet of 1/b
    #[inline]
    fn div(self, o: Jet) -> Jet {
        self * o.recip()
    }
}
impl Add<f64> for Jet {
    type Output = Jet;
    #[inline]
    fn add(self, k: f64) -> Jet {
        Jet([self.0[0] + k, self.0[1], self.0[2], self.0[3]])
    }
}
impl Mul<f64> for Jet {
    type Output = Jet;
    #[inline]
    fn mul(self, k: f64) -> Jet {
        self.scale(k)
    }
}

/// A 3-vector of jets.
pub type JetVec3 = [Jet; 3];

/// Cross product of jet vectors.
#[inline]
pub fn cross(a: &JetVec3, b: &JetVec3) -> JetVec3 {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

/// Matrix (rows of jets) times jet vector.
#[inline]
pub fn mat_vec(m: &[JetVec3; 3], v: &JetVec3) -> JetVec3 {
    [0, 1, 2].map(|i| m[i][0] * v[0] + m[i][1] * v[1] + m[i][2] * v[2])
}

/// Transposed matrix times jet vector.
#[inline]
pub fn mat_t_vec(m: &[JetVec3; 3], v: &JetVec3) -> JetVec3 {
    [0, 1, 2].map(|j| m[0][j] * v[0] + m[1][j] * v[1] + m[2][j] * v[2])
}

/// Values, first or second derivatives of a jet vector.
#[inline]
pub fn order(v: &JetVec3, k: usize) -> [f64; 3] {
    [v[0].d(k), v[1].d(k), v[2].d(k)]
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;

    /// Derivatives of a composite function agree with the hand-derived closed form.
    #[test]
    fn jets_match_closed_form_derivatives_of_a_composite() {
        // f(t) = sin(t^2) / (1 + t) * sqrt(2 + cos t) at t = 0.7
        let t = 0.7;
        let x = Jet::variable(t);
        let f = (x * x).sin() / (x + 1.0) * (x.cos() + 2.0).sqrt();
        // reference derivatives by high-order central differences on the plain function
        let g = |t: f64| (t * t).sin() / (1.0 + t) * (2.0 + t.cos()).sqrt();
        let h = 1e-3;
        let d1 = (g(t - 2.0 * h) - 8.0 * g(t - h) + 8.0 * g(t + h) - g(t + 2.0 * h)) / (12.0 * h);
        let d2 = (-g(t - 2.0 * h) + 16.0 * g(t - h) - 30.0 * g(t) + 16.0 * g(t + h)
            - g(t + 2.0 * h))
            / (12.0 * h * h);
        let d3 =
            (g(t + 2.0 * h) - 2.0 * g(t + h) + 2.0 * g(t - h) - g(t - 2.0 * h)) / (2.0 * h * h * h);
        assert_relative_eq!(f.value(), g(t), epsilon = 1e-15);
        assert_relative_eq!(f.d(1), d1, max_relative = 1e-9);
        assert_relative_eq!(f.d(2), d2, max_relative = 1e-6);
        assert_relative_eq!(f.d(3), d3, max_relative = 1e-4);
    }

    #[test]
    fn tan_and_recip_third_derivatives() {
        let x = Jet::variable(0.3);
        // d3/dt3 tan t = 2 sec^2 t (1 + 3 tan^2 t) ... check against sin/cos quotient
        let a = x.tan();
        let b = x.sin() / x.cos();
        for k in 0..4 {
            assert_relative_eq!(a.d(k), b.d(k), max_relative = 1e-12);
        }
    }
}
