//! Frame conversions for the importers: from the PSINS toolbox's East-North-Up navigation
//! frame and right-forward-up (RFU) body frame to dynacal's North-East-Down (NED) and
//! forward-right-down (FRD).
//!
//! Both changes of frame are the same permutation matrix
//! `P = [[0, 1, 0], [1, 0, 0], [0, 0, -1]]`: it swaps the first two axes and negates the
//! third (`ned = P enu`, `frd = P rfu`). `P` is its own inverse and a proper rotation
//! (det +1: 180 degrees about (1, 1, 0)/sqrt 2), so rotation matrices convert by
//! `C_frd^ned = P C_rfu^enu P`.
//!
//! Also the attitude between two logged samples ([`attitude_at`]), which the flight-log
//! importers interpolate to their GPS fixes.

use nalgebra::{Matrix3, Rotation3, UnitQuaternion, Vector3};

/// The axis permutation `P` shared by ENU -> NED and RFU -> FRD (see the module docs).
pub fn enu_ned_permutation() -> Matrix3<f64> {
    Matrix3::new(0.0, 1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, -1.0)
}

/// A body vector in right-forward-up axes -> forward-right-down axes: `[y, x, -z]`.
pub fn rfu_to_frd(v_rfu: [f64; 3]) -> [f64; 3] {
    [v_rfu[1], v_rfu[0], -v_rfu[2]]
}

/// A navigation vector in East-North-Up axes -> North-East-Down axes: `[y, x, -z]`.
pub fn enu_to_ned(v_enu: [f64; 3]) -> [f64; 3] {
    [v_enu[1], v_enu[0], -v_enu[2]]
}

/// The PSINS body (RFU) to navigation (ENU) rotation `C_b^n = Rz(yaw) Rx(pitch) Ry(roll)`,
/// with the toolbox's angles in radians (yaw positive counter-clockwise, north towards west).
pub fn psins_c_rfu_to_enu(pitch_rad: f64, roll_rad: f64, yaw_rad: f64) -> Matrix3<f64> {
    let rz = Rotation3::from_axis_angle(&Vector3::z_axis(), yaw_rad);
    let rx = Rotation3::from_axis_angle(&Vector3::x_axis(), pitch_rad);
    let ry = Rotation3::from_axis_angle(&Vector3::y_axis(), roll_rad);
    (rz * rx * ry).into_inner()
}

/// The FRD body to NED rotation equal to a PSINS attitude:
/// `C_frd^ned = T_enu->ned C_rfu^enu T_frd->rfu = P C_rfu^enu P`.
pub fn psins_c_frd_to_ned(pitch_rad: f64, roll_rad: f64, yaw_rad: f64) -> Matrix3<f64> {
    let p = enu_ned_permutation();
    p * psins_c_rfu_to_enu(pitch_rad, roll_rad, yaw_rad) * p
}

/// Roll, pitch, yaw (rad) of the body w.r.t. NED, Z-Y-X convention:
/// `C_b^n = Rz(yaw) Ry(pitch) Rx(roll)`; roll and yaw in (-pi, pi], pitch in [-pi/2, pi/2].
pub fn euler_zyx_from_c_b_to_n(c_b_n: &Matrix3<f64>) -> [f64; 3] {
    // roll = atan2(C32, C33), pitch = -asin(C31), yaw = atan2(C21, C11); nalgebra's
    // `euler_angles` computes exactly this (with a gimbal-lock branch), so use it.
    let (roll, pitch, yaw) = Rotation3::from_matrix_unchecked(*c_b_n).euler_angles();
    [roll, pitch, yaw]
}

/// A PSINS attitude (pitch, roll, yaw of RFU w.r.t. ENU, rad) as roll, pitch, yaw (rad) of
/// the FRD body w.r.t. NED. Since `P Rz(a) P = Rz(-a)`, `P Rx(a) P = Ry(a)` and
/// `P Ry(a) P = Rx(a)`, this is roll = roll, pitch = pitch, yaw = -yaw (wrapped), but it is
/// computed through the rotation matrices so the derivation is the code.
pub fn psins_attitude_to_ned(pitch_rad: f64, roll_rad: f64, yaw_rad: f64) -> [f64; 3] {
    euler_zyx_from_c_b_to_n(&psins_c_frd_to_ned(pitch_rad, roll_rad, yaw_rad))
}

/// The attitude (body to NED) at `t_s` by slerp between the samples `(t_s, q)` around it
/// (sorted by time), if they are at most `max_gap_s` apart; a sample at `t_s` itself as is.
pub(crate) fn attitude_at(
    att: &[(f64, UnitQuaternion<f64>)],
    t_s: f64,
    max_gap_s: f64,
) -> Option<UnitQuaternion<f64>> {
    let after = att.partition_point(|s| s.0 < t_s);
    let (t1, q1) = att.get(after)?;
    if *t1 == t_s {
        return Some(*q1);
    }
    let (t0, q0) = att.get(after.checked_sub(1)?)?;
    if t1 - t0 > max_gap_s {
        return None;
    }
    Some(q0.slerp(q1, (t_s - t0) / (t1 - t0)))
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_abs_diff_eq;
    use std::f64::consts::FRAC_PI_2;

    const DEG: f64 = std::f64::consts::PI / 180.0;

    /// Body FRD axes expressed in NED: columns of C_frd^ned.
    fn axes(c: &Matrix3<f64>) -> [[f64; 3]; 3] {
        [0, 1, 2].map(|j| [c[(0, j)], c[(1, j)], c[(2, j)]])
    }

    fn close(a: [f64; 3], b: [f64; 3]) {
        for k in 0..3 {
            assert_abs_diff_eq!(a[k], b[k], epsilon = 1e-12);
        }
    }

    #[test]
    fn permutation_is_a_proper_involution() {
        let p = enu_ned_permutation();
        assert_abs_diff_eq!(p * p, Matrix3::identity(), epsilon = 0.0);
        assert_abs_diff_eq!(p.determinant(), 1.0, epsilon = 0.0);
        close(rfu_to_frd([1.0, 2.0, 3.0]), [2.0, 1.0, -3.0]);
        close(enu_to_ned([-0.5, 11.0, 0.25]), [11.0, -0.5, -0.25]);
    }

    #[test]
    fn level_heading_north_is_identity() {
        let c = psins_c_frd_to_ned(0.0, 0.0, 0.0);
        assert_abs_diff_eq!(c, Matrix3::identity(), epsilon = 1e-15);
        close(psins_attitude_to_ned(0.0, 0.0, 0.0), [0.0, 0.0, 0.0]);
    }

    #[test]
    fn source_yaw_plus_90_faces_west() {
        // PSINS yaw +90 deg: forward (body Y) points west in ENU.
        let src = psins_c_rfu_to_enu(0.0, 0.0, 90.0 * DEG);
        close([src[(0, 1)], src[(1, 1)], src[(2, 1)]], [-1.0, 0.0, 0.0]);
        // FRD: forward = west = NED (0, -1, 0); right = north; down = down.
        let c = psins_c_frd_to_ned(0.0, 0.0, 90.0 * DEG);
        let [fwd, right, down] = axes(&c);
        close(fwd, [0.0, -1.0, 0.0]);
        close(right, [1.0, 0.0, 0.0]);
        close(down, [0.0, 0.0, 1.0]);
        close(
            psins_attitude_to_ned(0.0, 0.0, 90.0 * DEG),
            [0.0, 0.0, -FRAC_PI_2],
        );
    }

    #[test]
    fn pitch_up_raises_the_nose() {
        // Heading north, nose up 30 deg: forward has a negative down component.
        let c = psins_c_frd_to_ned(30.0 * DEG, 0.0, 0.0);
        let [fwd, right, down] = axes(&c);
        close(fwd, [(30.0 * DEG).cos(), 0.0, -(30.0 * DEG).sin()]);
        close(right, [0.0, 1.0, 0.0]);
        close(down, [(30.0 * DEG).sin(), 0.0, (30.0 * DEG).cos()]);
        close(
            psins_attitude_to_ned(30.0 * DEG, 0.0, 0.0),
            [0.0, 30.0 * DEG, 0.0],
        );
    }

    #[test]
    fn roll_right_lowers_the_right_side() {
        // Heading north, rolled 20 deg right: the right axis points partly down.
        let c = psins_c_frd_to_ned(0.0, 20.0 * DEG, 0.0);
        let [fwd, right, down] = axes(&c);
        close(fwd, [1.0, 0.0, 0.0]);
        close(right, [0.0, (20.0 * DEG).cos(), (20.0 * DEG).sin()]);
        close(down, [0.0, -(20.0 * DEG).sin(), (20.0 * DEG).cos()]);
        close(
            psins_attitude_to_ned(0.0, 20.0 * DEG, 0.0),
            [20.0 * DEG, 0.0, 0.0],
        );
    }

    #[test]
    fn general_attitude_matches_closed_form_and_zyx_extraction() {
        for &(p, r, y) in &[(0.3, -0.5, 2.9), (-1.2, 2.5, -3.0), (0.01, 0.6, 0.0)] {
            let got = psins_attitude_to_ned(p, r, y);
            let yaw = (-y + std::f64::consts::PI).rem_euclid(std::f64::consts::TAU)
                - std::f64::consts::PI;
            close(got, [r, p, yaw]);
            // Rebuilding Rz(yaw) Ry(pitch) Rx(roll) gives the matrix back.
            let rebuilt = Rotation3::from_euler_angles(got[0], got[1], got[2]).into_inner();
            assert_abs_diff_eq!(rebuilt, psins_c_frd_to_ned(p, r, y), epsilon = 1e-12);
            // Hand extraction: roll = atan2(C32, C33), pitch = -asin(C31), yaw = atan2(C21, C11).
            let c = psins_c_frd_to_ned(p, r, y);
            close(
                got,
                [
                    c[(2, 1)].atan2(c[(2, 2)]),
                    -c[(2, 0)].asin(),
                    c[(1, 0)].atan2(c[(0, 0)]),
                ],
            );
        }
    }
}
