//! ROS's frames (REP 103: bodies forward-left-up, the world east-north-up) and the
//! interchange's (bodies forward-right-down, the navigation frame north-east-down): the one
//! home of the turns between them, for reading bags and for writing them.

use nalgebra::{Matrix3, Quaternion, Rotation3, UnitQuaternion, Vector3};

/// Forward-left-up <-> forward-right-down (its own inverse): y and z negated.
pub fn flu_to_frd(v: [f64; 3]) -> [f64; 3] {
    [v[0], -v[1], -v[2]]
}

/// East-north-up <-> north-east-down (its own inverse).
pub fn enu_to_ned() -> Matrix3<f64> {
    Matrix3::new(0.0, 1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, -1.0)
}

fn frd_to_flu() -> Matrix3<f64> {
    Matrix3::from_diagonal(&Vector3::new(1.0, -1.0, -1.0))
}

/// Roll, pitch, yaw (Z-Y-X, rad) of forward-right-down in north-east-down from a ROS
/// orientation `[x, y, z, w]` of forward-left-up in east-north-up: `R_ned_frd = T R_enu_flu F`.
pub fn ned_rpy_of_ros(q: [f64; 4]) -> [f64; 3] {
    let [x, y, z, w] = q;
    let enu_from_flu = UnitQuaternion::from_quaternion(Quaternion::new(w, x, y, z));
    let ned_from_frd = enu_to_ned() * enu_from_flu.to_rotation_matrix().matrix() * frd_to_flu();
    let (roll, pitch, yaw) = Rotation3::from_matrix_unchecked(ned_from_frd).euler_angles();
    [roll, pitch, yaw]
}

/// The ROS orientation `[x, y, z, w]` (forward-left-up in east-north-up) of roll, pitch, yaw
/// (Z-Y-X, rad) of forward-right-down in north-east-down: the inverse of [`ned_rpy_of_ros`].
pub fn ros_of_ned_rpy(rpy: [f64; 3]) -> [f64; 4] {
    let ned_from_frd = Rotation3::from_euler_angles(rpy[0], rpy[1], rpy[2]);
    let enu_from_flu = enu_to_ned() * ned_from_frd.matrix() * frd_to_flu();
    let q = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(enu_from_flu));
    [q.i, q.j, q.k, q.w]
}

/// A ROS orientation `[x, y, z, w]` turning body (forward-left-up) vectors into the world.
pub fn rotate_by_ros(q: [f64; 4], v: [f64; 3]) -> [f64; 3] {
    let [x, y, z, w] = q;
    let r = UnitQuaternion::from_quaternion(Quaternion::new(w, x, y, z)) * Vector3::from(v);
    [r.x, r.y, r.z]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn orientations_turn_back_and_forth() {
        for rpy in [[0.1, -0.2, 2.5], [0.0, 0.0, -3.0], [-0.4, 0.3, 0.7]] {
            let back = ned_rpy_of_ros(ros_of_ned_rpy(rpy));
            for k in 0..3 {
                assert!((back[k] - rpy[k]).abs() < 1e-12, "{rpy:?} -> {back:?}");
            }
        }
        // Facing north, level: the body's x axis along ENU's y (north), heading 0.
        let q = ros_of_ned_rpy([0.0, 0.0, 0.0]);
        let forward = rotate_by_ros(q, [1.0, 0.0, 0.0]);
        assert!((forward[1] - 1.0).abs() < 1e-12 && forward[0].abs() < 1e-12);
        // Its left (FLU y) is west: ENU x negative.
        let left = rotate_by_ros(q, [0.0, 1.0, 0.0]);
        assert!((left[0] + 1.0).abs() < 1e-12);
    }
}
