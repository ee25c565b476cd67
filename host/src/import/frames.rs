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
//! importers interpolate to their GPS fixes, and the same as a log is walked
//! ([`AttitudeTrack`]).

use std::collections::VecDeque;

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

/// Longest a GPS fix may be written into a log after the attitude samples around its time
/// and still be given its attitude by an [`AttitudeTrack`], s. A log writes a fix within a
/// second or so of its time; older attitude samples are let go, so that a log with attitude
/// and no fix holds a minute of it, not all of it.
pub const MAX_FIX_LATENESS_S: f64 = 60.0;

/// The attitude at each GPS fix of a log walked once: attitude samples and fixes come each in
/// time order, interleaved as the log holds them. A fix gets what [`attitude_at`] gives on
/// the whole attitude series (held whole, the same) once a sample at or after its time has
/// come; only the samples a later fix can still need are held (those since the last fix, or
/// [`MAX_FIX_LATENESS_S`]), and the fixes waiting for the attitude to pass them.
pub(crate) struct AttitudeTrack<F> {
    max_gap_s: f64,
    /// Attitude samples (time s, body to NED), in time order.
    recent: VecDeque<(f64, UnitQuaternion<f64>)>,
    /// Fixes later than every attitude sample so far: time s and what the caller keeps.
    waiting: VecDeque<(f64, F)>,
    /// Fixes given an attitude, in time order.
    resolved: Vec<(f64, UnitQuaternion<f64>, F)>,
}

impl<F> AttitudeTrack<F> {
    /// Interpolating between samples at most `max_gap_s` apart ([`attitude_at`]).
    pub(crate) fn new(max_gap_s: f64) -> Self {
        Self {
            max_gap_s,
            recent: VecDeque::new(),
            waiting: VecDeque::new(),
            resolved: Vec::new(),
        }
    }

    /// An attitude sample at `t_s`, after every earlier one.
    pub(crate) fn attitude(&mut self, t_s: f64, q: UnitQuaternion<f64>) {
        self.recent.push_back((t_s, q));
        while self.waiting.front().is_some_and(|(fix_s, _)| *fix_s <= t_s) {
            let (fix_s, data) = self.waiting.pop_front().expect("a waiting fix");
            self.resolve(fix_s, data);
        }
        let horizon_s = t_s - MAX_FIX_LATENESS_S;
        while self.recent.len() >= 2 && self.recent[1].0 < horizon_s {
            self.recent.pop_front();
        }
    }

    /// A fix at `t_s`, after every earlier one, and what the caller keeps of it.
    pub(crate) fn fix(&mut self, t_s: f64, data: F) {
        // Later fixes are later still: a sample before the one before this fix is of no use.
        while self.recent.len() >= 2 && self.recent[1].0 < t_s {
            self.recent.pop_front();
        }
        if self.recent.back().is_some_and(|(s, _)| *s >= t_s) {
            self.resolve(t_s, data);
        } else {
            self.waiting.push_back((t_s, data));
        }
    }

    fn resolve(&mut self, t_s: f64, data: F) {
        if let Some(q) = attitude_at(self.recent.make_contiguous(), t_s, self.max_gap_s) {
            self.resolved.push((t_s, q, data));
        }
    }

    /// The fixes given an attitude since the last call, in time order (a fix after the
    /// attitude's last sample never gets one).
    pub(crate) fn drain_resolved(&mut self) -> std::vec::Drain<'_, (f64, UnitQuaternion<f64>, F)> {
        self.resolved.drain(..)
    }
}

/// What a fix keeps until it has its attitude: its position (lat, lon rad, height m) and
/// NED velocity (m/s), or the error they gave (a fix that gets no attitude is left out unread,
/// so its error is not raised).
pub(crate) type FixValues = Result<[f64; 6], super::ImportError>;

/// The reference row of a fix: `t_s`, then attitude (roll, pitch, yaw rad, body FRD w.r.t.
/// NED, Z-Y-X), position (lat, lon rad, height m) and NED velocity (m/s), in the interchange
/// columns' order ([`reference_layout`]).
pub(crate) type ReferenceRow = [f64; 10];

/// The layout of a flight log's reference rows ([`ReferenceRow`]), named `name`.
pub(crate) fn reference_layout(name: &str) -> super::rows::SensorLayout {
    let empty = crate::interchange::ImuRecording {
        attitude_rad: Some(Default::default()),
        position: Some(Default::default()),
        velocity_ned_m_s: Some(Default::default()),
        ..Default::default()
    };
    super::rows::layout(name, &empty)
}

/// A flight log's reference as the log is walked: one GPS series' fixes given their attitude
/// ([`AttitudeTrack`]) and made rows, counted (a first walk, which only asks whether there
/// are any) or kept until taken (a walk that writes them). Its first error is kept: the
/// reference fails on it.
pub(crate) struct ReferenceRows {
    track: AttitudeTrack<FixValues>,
    keeps_rows: bool,
    rows: Vec<ReferenceRow>,
    pub(crate) count: usize,
    pub(crate) error: Option<super::ImportError>,
    /// The last fix's time, s.
    pub(crate) previous_fix_s: Option<f64>,
}

impl ReferenceRows {
    pub(crate) fn new(max_gap_s: f64, keeps_rows: bool) -> Self {
        Self {
            track: AttitudeTrack::new(max_gap_s),
            keeps_rows,
            rows: Vec::new(),
            count: 0,
            error: None,
            previous_fix_s: None,
        }
    }

    /// An attitude sample ([`AttitudeTrack::attitude`]).
    pub(crate) fn attitude(&mut self, t_s: f64, q: UnitQuaternion<f64>) {
        self.track.attitude(t_s, q);
        self.form_rows();
    }

    /// A fix at `t_s` ([`AttitudeTrack::fix`]).
    pub(crate) fn fix(&mut self, t_s: f64, values: FixValues) {
        self.previous_fix_s = Some(t_s);
        self.track.fix(t_s, values);
        self.form_rows();
    }

    fn form_rows(&mut self) {
        for (t, q, values) in self.track.drain_resolved() {
            match values {
                Ok(v) if self.error.is_none() => {
                    self.count += 1;
                    if self.keeps_rows {
                        let (roll, pitch, yaw) = q.euler_angles();
                        self.rows
                            .push([t, roll, pitch, yaw, v[0], v[1], v[2], v[3], v[4], v[5]]);
                    }
                }
                Ok(_) => {}
                Err(e) => {
                    self.error.get_or_insert(e);
                }
            }
        }
    }

    /// The rows formed since the last call, in time order.
    pub(crate) fn take(&mut self) -> std::vec::Drain<'_, ReferenceRow> {
        self.rows.drain(..)
    }
}

/// A recording of reference rows.
pub(crate) fn reference_recording(rows: &[ReferenceRow]) -> crate::interchange::ImuRecording {
    let column = |k: usize| rows.iter().map(|r| r[k]).collect::<Vec<f64>>();
    let triplet = |k: usize| [column(k), column(k + 1), column(k + 2)];
    crate::interchange::ImuRecording {
        t_s: column(0),
        attitude_rad: Some(triplet(1)),
        position: Some(triplet(4)),
        velocity_ned_m_s: Some(triplet(7)),
        ..Default::default()
    }
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

    /// Attitude samples every 20-80 ms with a few gaps over the slerp limit, and fixes every
    /// 200 ms written up to `lateness_s` after their time, interleaved as a log would hold
    /// them: the track gives every fix what the whole series gives.
    fn track_agrees_with_the_whole_series(seed: u64, lateness_s: f64) {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        let mut att = Vec::new();
        let mut t = 1.0;
        while t < 120.0 {
            let q = UnitQuaternion::from_euler_angles(
                rng.random(),
                rng.random(),
                rng.random::<f64>() * 6.0,
            );
            att.push((t, q));
            t += if rng.random::<f64>() < 0.01 {
                0.7
            } else {
                rng.random_range(0.02..0.08)
            };
        }
        // Fixes from before the attitude's start to after its end.
        let fixes: Vec<f64> = (0..650)
            .map(|k| 0.5 + 0.2 * k as f64 + rng.random_range(0.0..0.1))
            .collect();
        // Each message at the time it is written: attitude at once, a fix up to `lateness_s` on.
        let mut written: Vec<(f64, Option<usize>, Option<usize>)> = att
            .iter()
            .enumerate()
            .map(|(i, (t, _))| (*t, Some(i), None))
            .collect();
        let mut write_s = 0.0f64;
        for (k, f) in fixes.iter().enumerate() {
            // Fixes keep their order when written.
            write_s = write_s.max(f + lateness_s * rng.random::<f64>());
            written.push((write_s, None, Some(k)));
        }
        written.sort_by(|a, b| a.0.total_cmp(&b.0));
        let mut track = AttitudeTrack::new(0.5);
        let mut got = Vec::new();
        for (_, a, f) in written {
            match (a, f) {
                (Some(i), _) => track.attitude(att[i].0, att[i].1),
                (_, Some(k)) => track.fix(fixes[k], k),
                _ => unreachable!(),
            }
            got.extend(track.drain_resolved());
        }
        let want: Vec<(usize, UnitQuaternion<f64>)> = fixes
            .iter()
            .enumerate()
            .filter_map(|(k, f)| Some((k, attitude_at(&att, *f, 0.5)?)))
            .collect();
        assert!(
            want.len() > 400 && want.len() + 60 < fixes.len(),
            "{}",
            want.len()
        );
        assert_eq!(got.len(), want.len(), "seed {seed}");
        for ((t, q, k), (k_want, q_want)) in got.iter().zip(&want) {
            assert_eq!((*k, *t), (*k_want, fixes[*k_want]));
            assert!(q.angle_to(q_want) < 1e-12, "seed {seed}, fix {k}");
        }
    }

    #[test]
    fn a_walked_attitude_track_gives_each_fix_what_the_whole_series_gives() {
        for seed in 0..20 {
            track_agrees_with_the_whole_series(seed, 0.0);
            track_agrees_with_the_whole_series(100 + seed, 3.0);
        }
    }
}
