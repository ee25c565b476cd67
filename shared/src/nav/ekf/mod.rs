//! Error-state extended Kalman filter for strapdown INS/GNSS navigation with inter-IMU
//! calibration (Stebler, Guerrier, Skaloud, IEEE TIM 2015, Section II).
//!
//! The filter estimates the *errors* of a strapdown mechanization that runs outside it (the
//! nominal navigation state: position, NED velocity, attitude). Its state vector is
//!
//! | index           | state                                  | unit   | frame |
//! |-----------------|----------------------------------------|--------|-------|
//! | 0..3            | position error `δr` (true − nominal)   | m      | NED   |
//! | 3..6            | velocity error `δv`                    | m/s    | NED   |
//! | 6..9            | attitude error `ε`, `C_b^n = (I+[ε×]) Ĉ_b^n` | rad | NED |
//! | 9..12           | accelerometer bias error               | m/s²   | body  |
//! | 12..15          | gyroscope bias error                   | rad/s  | body  |
//! | 15+6i..15+6i+3  | boresight error `δψ_b→s` of extra IMU i| rad    | body  |
//! | 15+6i+3..15+6i+6| lever-arm error `δr_b→s` of extra IMU i| m      | body  |
//!
//! so `N = 15 + 6K` for `K` extra IMUs. Position errors are kept in metres along NED rather
//! than the paper's `δφ, δλ, δh` (radians): the two differ only by the curvature radii, and
//! metres keep the covariance well scaled in `f32`.
//!
//! The filter owns the nominal values of the states the mechanization does not carry (IMU
//! biases, inter-IMU boresight `Ĉ_b^s` and lever arm `r̂_b→s`) and folds its error estimate
//! into them in [`ErrorStateEkf::reset`], which also hands the navigation part back to the
//! caller to correct its mechanization (closed-loop error-state filter).
//!
//! In fixed point ([`crate::fixed::I32F32`]) the covariance is held scaled: each state has a
//! power-of-two scale `2^s_i`, `P_ij = p_ij 2^(s_i + s_j)`, renormalised after every
//! prediction and update batch so each scaled variance stays within [1/4, 4), and the scalar
//! updates are whitened (row and innovation divided by the measurement's sigma). Every
//! number the updates form is then near unit size whatever the state's unit (the design and
//! its measurements: `docs/navigation.md`, "Toward fixed point"). In floating point the
//! scales stay 0 and the filter is the one described below, operation for operation.
//!
//! Numerics follow what works for `f32` on a microcontroller (PX4 EKF2, ArduPilot EKF3):
//! block-sparse covariance prediction (only the 15-state navigation block is dynamic, the
//! calibration states are constant), sequential scalar updates with a chi-square innovation
//! gate, the Joseph form for every scalar update, exact symmetry by computing one triangle
//! and mirroring it, and variance floors once per cycle. Nothing here allocates or panics:
//! numerical trouble is counted in [`FusionStats`] and reported through return values.

mod fuse_gnss;
mod fuse_inter_imu;
mod ins;
mod predict;

pub use fuse_gnss::{geodetic_difference_ned_m, position_innovation_ned_m};
pub use fuse_inter_imu::{AbsorbedMeans, InterImuSample, RateDifferentiator};
pub use ins::{apply_correction, InsEkf};
pub use predict::{gauss_markov_step, CalibrationCoupling, NavLinearization};

use nalgebra::{Matrix3, Quaternion, SMatrix, SVector, UnitQuaternion, Vector3};

use crate::scalar::{FilterScalar, Pow2};

/// Index of the first position-error state (NED, m).
pub const POS: usize = 0;
/// Index of the first velocity-error state (NED, m/s).
pub const VEL: usize = 3;
/// Index of the first attitude-error state (NED, rad).
pub const ATT: usize = 6;
/// Index of the first accelerometer-bias state (body, m/s²).
pub const ACCEL_BIAS: usize = 9;
/// Index of the first gyroscope-bias state (body, rad/s).
pub const GYRO_BIAS: usize = 12;
/// Number of navigation states (the dynamic block).
pub const NAV_STATES: usize = 15;
/// Number of calibration states per extra IMU (boresight 3, lever arm 3).
pub const CALIBRATION_STATES_PER_IMU: usize = 6;

/// Index of the first boresight-error state of extra IMU `imu` (body, rad).
pub const fn boresight_index(imu: usize) -> usize {
    NAV_STATES + CALIBRATION_STATES_PER_IMU * imu
}

/// Index of the first lever-arm-error state of extra IMU `imu` (body, m).
pub const fn lever_arm_index(imu: usize) -> usize {
    boresight_index(imu) + 3
}

/// The filter with no extra IMU: 15 states.
pub type NavEkf<T> = ErrorStateEkf<T, 0, 15>;
/// The filter with one extra IMU: 21 states.
pub type NavEkf1<T> = ErrorStateEkf<T, 1, 21>;
/// The filter with two extra IMUs: 27 states.
pub type NavEkf2<T> = ErrorStateEkf<T, 2, 27>;

/// Noise, gating and floor settings. Power spectral densities are one-sided and continuous
/// time; variances are in the squared state units of the module table.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EkfConfig<T> {
    /// Accelerometer white noise PSD, (m/s²)²/Hz = (m/s)²/s (velocity random walk squared).
    pub accel_noise_psd: Pow2<T>,
    /// Gyroscope white noise PSD, (rad/s)²/Hz = rad²/s (angle random walk squared).
    pub gyro_noise_psd: Pow2<T>,
    /// Accelerometer bias driving-noise PSD, (m/s²)²/s.
    pub accel_bias_psd: Pow2<T>,
    /// Gyroscope bias driving-noise PSD, (rad/s)²/s.
    pub gyro_bias_psd: Pow2<T>,
    /// Inverse correlation time of the accelerometer bias Gauss–Markov process, 1/s
    /// (0 makes it a random walk).
    pub accel_bias_inv_tau_s: T,
    /// Inverse correlation time of the gyroscope bias Gauss–Markov process, 1/s.
    pub gyro_bias_inv_tau_s: T,
    /// Boresight driving-noise PSD, rad²/s (0: a random constant, as the mount is rigid).
    pub boresight_psd: Pow2<T>,
    /// Lever-arm driving-noise PSD, m²/s.
    pub lever_arm_psd: Pow2<T>,
    /// Chi-square gate on the normalised squared innovation `ν²/S` of one scalar update
    /// (1 degree of freedom: 3.84 is 95 %, 10.83 is 99.9 %, 25 is PX4's 5-sigma gate).
    pub innovation_gate: T,
    /// Variance floors applied to the diagonal once per prediction and after each update
    /// batch, in state order: position, velocity, attitude, accel bias, gyro bias (each for
    /// all three axes), then boresight and lever arm for every extra IMU.
    pub variance_floor: [Pow2<T>; 7],
}

impl<T: FilterScalar> EkfConfig<T> {
    /// Settings for a consumer MEMS IMU in a car (angle random walk 0.3 deg/√h, velocity
    /// random walk 0.1 m/s/√h raised to cover vibration, bias instabilities of tens of mg and
    /// tens of deg/h), with a 5-sigma innovation gate.
    pub fn automotive_mems() -> Self {
        let c = |x: f64| nalgebra::convert::<f64, T>(x);
        let small = Pow2::<T>::from_f64;
        Self {
            accel_noise_psd: small(0.02 * 0.02),
            gyro_noise_psd: small(0.005_f64.to_radians() * 0.005_f64.to_radians()),
            accel_bias_psd: small(1e-4 * 1e-4),
            gyro_bias_psd: small(1e-5 * 1e-5),
            accel_bias_inv_tau_s: c(0.0),
            gyro_bias_inv_tau_s: c(0.0),
            boresight_psd: Pow2::zero(),
            lever_arm_psd: Pow2::zero(),
            innovation_gate: c(25.0),
            variance_floor: [
                small(1e-6),  // position, m²
                small(1e-8),  // velocity, (m/s)²
                small(1e-10), // attitude, rad²
                small(1e-10), // accel bias, (m/s²)²
                small(1e-14), // gyro bias, (rad/s)²
                small(1e-12), // boresight, rad²
                small(1e-10), // lever arm, m²
            ],
        }
    }
}

/// Initial one-sigma uncertainties, in the units of the module table.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct InitialSigmas<T> {
    /// Position, m (NED).
    pub position_m: Vector3<T>,
    /// Velocity, m/s (NED).
    pub velocity_m_s: Vector3<T>,
    /// Attitude, rad (NED axes: roll-like, pitch-like, heading-like).
    pub attitude_rad: Vector3<T>,
    /// Accelerometer bias, m/s² (body).
    pub accel_bias_m_s2: Vector3<T>,
    /// Gyroscope bias, rad/s (body).
    pub gyro_bias_rad_s: Vector3<T>,
    /// Boresight of every extra IMU, rad (body).
    pub boresight_rad: Vector3<T>,
    /// Lever arm of every extra IMU, m (body).
    pub lever_arm_m: Vector3<T>,
}

/// Nominal calibration of one extra IMU (the `s` frame) against the filter's body frame `b`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct InterImuCalibration<T: FilterScalar> {
    /// Rotation taking body-frame vectors into the extra IMU's frame: `v_s = C_b^s v_b`.
    pub q_b_to_s: UnitQuaternion<T>,
    /// Lever arm from the body origin to the extra IMU's origin, m, body axes.
    pub lever_arm_b_m: Vector3<T>,
}

impl<T: FilterScalar> InterImuCalibration<T> {
    /// Identity boresight and zero lever arm (the paper's initialisation).
    pub fn identity() -> Self {
        Self {
            q_b_to_s: UnitQuaternion::identity(),
            lever_arm_b_m: Vector3::zeros(),
        }
    }

    /// `C_b^s`, the direction cosine matrix from body to extra-IMU axes.
    pub fn c_b_s(&self) -> Matrix3<T> {
        self.q_b_to_s.to_rotation_matrix().into_inner()
    }

    /// Boresight angles `ψ_b→s`, rad: the rotation vector turning the body axes into the
    /// extra IMU's axes, `C_s^b = exp([ψ×])`, so that for small angles
    /// `C_b^s ≈ I − [ψ×]` as in the paper's eq. (10).
    pub fn boresight_rad(&self) -> Vector3<T> {
        self.q_b_to_s.inverse().scaled_axis()
    }
}

/// Counters of one kind of scalar measurement.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct FusionCounters {
    /// Scalar updates applied.
    pub accepted: u32,
    /// Scalar updates refused by the innovation gate.
    pub rejected: u32,
    /// Scalar updates refused because the innovation variance was not finite and positive.
    pub numerical_faults: u32,
}

/// Per-measurement-kind statistics since the filter was created.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct FusionStats {
    /// GNSS position components.
    pub gnss_position: FusionCounters,
    /// GNSS velocity components.
    pub gnss_velocity: FusionCounters,
    /// Zero-velocity update components.
    pub zero_velocity: FusionCounters,
    /// Extra-IMU angular-rate components (eq. 10).
    pub inter_imu_rate: FusionCounters,
    /// Extra-IMU specific-force components (eq. 11).
    pub inter_imu_force: FusionCounters,
    /// Attitude-update components (eq. 7).
    pub attitude: FusionCounters,
    /// Predictions refused (non-finite input or non-positive step).
    pub rejected_predictions: u32,
    /// Times a non-finite value was found on the covariance diagonal (the covariance was then
    /// re-initialised to its floors plus the initial sigmas; see [`ErrorStateEkf::reset_covariance`]).
    pub covariance_resets: u32,
}

impl FusionStats {
    /// Scalar updates refused for numerical reasons, over every kind of measurement.
    pub fn numerical_faults(&self) -> u32 {
        [
            self.gnss_position,
            self.gnss_velocity,
            self.zero_velocity,
            self.inter_imu_rate,
            self.inter_imu_force,
            self.attitude,
        ]
        .iter()
        .map(|c| c.numerical_faults)
        .fold(0, u32::saturating_add)
    }
}

/// What happened to a batch of scalar updates (one measurement vector).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct BatchOutcome {
    /// Components applied.
    pub accepted: u8,
    /// Components refused by the innovation gate.
    pub rejected: u8,
    /// Components refused for numerical reasons.
    pub faults: u8,
}

/// The result of one scalar update.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum ScalarOutcome<T> {
    /// Applied; carries the normalised squared innovation `ν²/S`.
    Accepted(T),
    /// Refused by the gate; carries `ν²/S`.
    Rejected(T),
    /// Refused: the innovation variance was not finite and positive.
    NumericalFault,
}

/// Errors folded into the mechanization by the caller after [`ErrorStateEkf::reset`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct NavCorrection<T> {
    /// Add to the nominal position, m, NED (north and east via the curvature radii; down is
    /// minus height).
    pub position_ned_m: Vector3<T>,
    /// Add to the nominal NED velocity, m/s.
    pub velocity_ned_m_s: Vector3<T>,
    /// Rotate the nominal attitude: `C_b^n ← exp([ε×]) C_b^n`, rad, NED axes.
    pub attitude_ned_rad: Vector3<T>,
}

/// A row of the measurement matrix with at most nine non-zero entries (three 3-blocks).
#[derive(Clone, Copy, Debug)]
pub(crate) struct SparseRow<T> {
    pub index: [usize; SPARSE_ROW_MAX],
    pub value: [T; SPARSE_ROW_MAX],
    pub len: usize,
}

/// Most non-zero entries of a [`SparseRow`].
pub(crate) const SPARSE_ROW_MAX: usize = 9;

impl<T: FilterScalar> SparseRow<T> {
    pub fn unit(index: usize) -> Self {
        let mut row = Self {
            index: [0; SPARSE_ROW_MAX],
            value: [T::zero(); SPARSE_ROW_MAX],
            len: 1,
        };
        row.index[0] = index;
        row.value[0] = T::one();
        row
    }

    /// A row with three entries at `first..first + 3`, plus optionally three at `second`.
    pub fn from_blocks(first: usize, a: [T; 3], second: Option<(usize, [T; 3])>) -> Self {
        let mut row = Self {
            index: [0; SPARSE_ROW_MAX],
            value: [T::zero(); SPARSE_ROW_MAX],
            len: 0,
        };
        row.push_block(first, a);
        if let Some((start, b)) = second {
            row.push_block(start, b);
        }
        row
    }

    /// Appends three entries at `start..start + 3`; a row already full is left as it is
    /// (three blocks are the most any measurement here needs).
    pub fn push_block(&mut self, start: usize, values: [T; 3]) {
        if self.len + 3 > SPARSE_ROW_MAX {
            return;
        }
        for (m, v) in values.into_iter().enumerate() {
            self.index[self.len + m] = start + m;
            self.value[self.len + m] = v;
        }
        self.len += 3;
    }
}

/// The error-state EKF with `K` extra IMUs and `N = 15 + 6K` states (checked at compile time).
#[derive(Clone, Debug)]
pub struct ErrorStateEkf<T: FilterScalar, const K: usize, const N: usize> {
    config: EkfConfig<T>,
    initial: InitialSigmas<T>,
    /// Error-state covariance, exactly symmetric, as scaled: `P_ij = p_ij 2^(s_i + s_j)`
    /// with `s` = [`Self::scale`] (all 0 in floating point).
    p: SMatrix<T, N, N>,
    /// Each state's power-of-two scale exponent `s_i` (a sigma of about `2^s_i`).
    scale: [i32; N],
    /// Error-state mean since the last reset.
    dx: SVector<T, N>,
    accel_bias_b_m_s2: Vector3<T>,
    gyro_bias_b_rad_s: Vector3<T>,
    calibration: [InterImuCalibration<T>; K],
    /// The navigation block of the last prediction's transition matrix, as 5×5 blocks of 3×3.
    transition: predict::BlockTransition<T>,
    stats: FusionStats,
    /// Predictions run, and the physical covariance right after the last one.
    #[cfg(feature = "probe")]
    probe: (u64, SMatrix<f64, N, N>),
    /// The last prediction's calibration-to-navigation rows (see
    /// [`Self::last_transition_coupling`]).
    #[cfg(feature = "probe")]
    probe_coupling: SMatrix<f64, 6, N>,
}

impl<T: FilterScalar, const K: usize, const N: usize> ErrorStateEkf<T, K, N> {
    const STATE_COUNT_CHECK: () = assert!(
        N == NAV_STATES + CALIBRATION_STATES_PER_IMU * K,
        "ErrorStateEkf<T, K, N> needs N = 15 + 6K"
    );

    /// A filter with zero error estimate, zero biases, identity boresights, zero lever arms
    /// and a diagonal covariance from `initial`.
    pub fn new(config: EkfConfig<T>, initial: InitialSigmas<T>) -> Self {
        #[allow(clippy::let_unit_value)]
        let () = Self::STATE_COUNT_CHECK;
        let mut filter = Self {
            config,
            initial,
            p: SMatrix::zeros(),
            scale: [0; N],
            dx: SVector::zeros(),
            accel_bias_b_m_s2: Vector3::zeros(),
            gyro_bias_b_rad_s: Vector3::zeros(),
            calibration: [InterImuCalibration::identity(); K],
            transition: predict::BlockTransition::identity(),
            stats: FusionStats::default(),
            #[cfg(feature = "probe")]
            probe: (0, SMatrix::zeros()),
            #[cfg(feature = "probe")]
            probe_coupling: SMatrix::zeros(),
        };
        filter.reset_covariance();
        filter
    }

    /// Re-initialises the covariance to the initial sigmas (diagonal). Used after a
    /// numerical fault; callable by the application too (e.g. after a long GNSS outage).
    pub fn reset_covariance(&mut self) {
        self.p = SMatrix::zeros();
        self.scale = [0; N];
        let blocks = [
            (POS, self.initial.position_m),
            (VEL, self.initial.velocity_m_s),
            (ATT, self.initial.attitude_rad),
            (ACCEL_BIAS, self.initial.accel_bias_m_s2),
            (GYRO_BIAS, self.initial.gyro_bias_rad_s),
        ];
        for (start, sigma) in blocks {
            for axis in 0..3 {
                self.set_lone_sigma(start + axis, sigma[axis]);
            }
        }
        for imu in 0..K {
            for axis in 0..3 {
                self.set_lone_sigma(
                    boresight_index(imu) + axis,
                    self.initial.boresight_rad[axis],
                );
                self.set_lone_sigma(lever_arm_index(imu) + axis, self.initial.lever_arm_m[axis]);
            }
        }
        self.apply_variance_floors();
    }

    /// Sets state `i`'s variance to `sigma²` (its row and column otherwise zero), choosing
    /// its scale so the scaled variance is near 1.
    fn set_lone_sigma(&mut self, i: usize, sigma: T) {
        let s = if T::SCALED {
            sigma.exponent().unwrap_or(0)
        } else {
            0
        };
        self.scale[i] = s;
        let scaled = if T::SCALED { sigma.mul_pow2(-s) } else { sigma };
        self.p[(i, i)] = scaled * scaled;
    }

    /// The configuration in use.
    pub fn config(&self) -> &EkfConfig<T> {
        &self.config
    }

    /// Sets the accelerometer and gyroscope white-noise PSDs ((m/s²)²/Hz, (rad/s)²/Hz) the
    /// next predictions use: an adaptive filter drives them from the units' live noise level
    /// (a level s per sample at interval dt is a PSD of s² dt). Non-finite or negative
    /// values are ignored.
    pub fn set_sensor_noise_psd(&mut self, accel_noise_psd: Pow2<T>, gyro_noise_psd: Pow2<T>) {
        if accel_noise_psd.is_usable() && gyro_noise_psd.is_usable() {
            self.config.accel_noise_psd = accel_noise_psd;
            self.config.gyro_noise_psd = gyro_noise_psd;
        }
    }

    /// The error-state covariance (symmetric, units of the module table). In fixed point
    /// its smallest elements round to zero and its largest may saturate: read it with
    /// [`Self::covariance_f64`] there.
    pub fn covariance(&self) -> SMatrix<T, N, N> {
        if !T::SCALED {
            return self.p;
        }
        SMatrix::from_fn(|i, j| self.p[(i, j)].mul_pow2(self.scale[i] + self.scale[j]))
    }

    /// The error-state covariance in `f64`, whatever the scalar (for reports: exact from
    /// the scaled form).
    pub fn covariance_f64(&self) -> SMatrix<f64, N, N> {
        SMatrix::from_fn(|i, j| {
            let v = nalgebra::try_convert::<T, f64>(self.p[(i, j)]).unwrap_or(f64::NAN);
            libm::ldexp(v, self.scale[i] + self.scale[j])
        })
    }

    /// The covariance as the filter holds it: scaled by each state's power of two in fixed
    /// point (`P_ij 2^-(s_i + s_j)`, see [`Self::scale`]), the covariance itself in floating
    /// point.
    pub fn held_covariance(&self) -> &SMatrix<T, N, N> {
        &self.p
    }

    /// Each state's power-of-two scale exponent (all 0 in floating point).
    pub fn scale(&self) -> &[i32; N] {
        &self.scale
    }

    /// Replaces the covariance (e.g. to restore a saved filter). It is symmetrised and floored.
    pub fn set_covariance(&mut self, p: &SMatrix<T, N, N>) {
        let half: T = nalgebra::convert(0.5);
        for i in 0..N {
            // A variance v in [2^k, 2^(k+1)) gets the scale (k + 1) div 2, so v 2^(-2s) lies
            // in [1/2, 2).
            self.scale[i] = if T::SCALED {
                p[(i, i)].exponent().map_or(0, |k| (k + 1).div_euclid(2))
            } else {
                0
            };
        }
        for i in 0..N {
            for j in i..N {
                let mut v = (p[(i, j)] + p[(j, i)]) * half;
                if T::SCALED {
                    v = v.mul_pow2(-(self.scale[i] + self.scale[j]));
                }
                self.p[(i, j)] = v;
                self.p[(j, i)] = v;
            }
        }
        self.apply_variance_floors();
    }

    /// Forgets what the filter knew of the three states at `first..first + 3` (and their
    /// correlations with the rest): their error estimate is zeroed and their covariance
    /// becomes `diag(sigma²)`. For a reset of those states to an outside measurement, as
    /// after GNSS returns to a position far from the filter's (PX4 EKF2 and ArduPilot EKF3
    /// reset to GNSS in the same case).
    pub fn forget_block(&mut self, first: usize, sigma: &Vector3<T>) {
        for a in 0..3 {
            let i = first + a;
            if i >= N {
                return;
            }
            for j in 0..N {
                self.p[(i, j)] = T::zero();
                self.p[(j, i)] = T::zero();
            }
            self.set_lone_sigma(i, sigma[a]);
            self.dx[i] = T::zero();
        }
        self.apply_variance_floors();
    }

    /// The error estimate accumulated since the last [`reset`](Self::reset).
    pub fn error_estimate(&self) -> &SVector<T, N> {
        &self.dx
    }

    /// Counters of accepted, gated and faulty updates.
    pub fn stats(&self) -> &FusionStats {
        &self.stats
    }

    /// Nominal accelerometer bias, m/s², body axes (subtract from the raw specific force).
    pub fn accel_bias_b_m_s2(&self) -> Vector3<T> {
        self.accel_bias_b_m_s2
    }

    /// Nominal gyroscope bias, rad/s, body axes (subtract from the raw angular rate).
    pub fn gyro_bias_b_rad_s(&self) -> Vector3<T> {
        self.gyro_bias_b_rad_s
    }

    /// Sets the nominal IMU biases (e.g. from a static alignment).
    pub fn set_biases(&mut self, accel_bias_b_m_s2: Vector3<T>, gyro_bias_b_rad_s: Vector3<T>) {
        self.accel_bias_b_m_s2 = accel_bias_b_m_s2;
        self.gyro_bias_b_rad_s = gyro_bias_b_rad_s;
    }

    /// The nominal calibration of extra IMU `imu`, or `None` if `imu >= K`.
    pub fn calibration(&self, imu: usize) -> Option<&InterImuCalibration<T>> {
        self.calibration.get(imu)
    }

    /// Sets the nominal calibration of extra IMU `imu` (e.g. a surveyed prior); returns
    /// `false` if `imu >= K`.
    pub fn set_calibration(&mut self, imu: usize, calibration: InterImuCalibration<T>) -> bool {
        match self.calibration.get_mut(imu) {
            Some(slot) => {
                *slot = calibration;
                true
            }
            None => false,
        }
    }

    /// One-sigma uncertainty of state `index` (units of the module table); `None` if out of
    /// range.
    pub fn sigma(&self, index: usize) -> Option<T> {
        (index < N).then(|| {
            let sigma = self.p[(index, index)].max(T::zero()).sqrt();
            if T::SCALED {
                sigma.mul_pow2(self.scale[index])
            } else {
                sigma
            }
        })
    }

    /// Folds the error estimate into the nominal values the filter owns (biases, boresights,
    /// lever arms), zeroes it, and returns the navigation part for the caller to apply to its
    /// mechanization. Call once after the updates of an epoch.
    ///
    /// The covariance is left unchanged: the reset Jacobian differs from identity only by
    /// `[δψ/2 ×]`-sized terms, which EKF2 and EKF3 neglect too.
    pub fn reset(&mut self) -> NavCorrection<T> {
        let v3 =
            |start: usize| Vector3::new(self.dx[start], self.dx[start + 1], self.dx[start + 2]);
        let correction = NavCorrection {
            position_ned_m: v3(POS),
            velocity_ned_m_s: v3(VEL),
            attitude_ned_rad: v3(ATT),
        };
        self.accel_bias_b_m_s2 += v3(ACCEL_BIAS);
        self.gyro_bias_b_rad_s += v3(GYRO_BIAS);
        for imu in 0..K {
            let delta_psi = v3(boresight_index(imu));
            let delta_lever = v3(lever_arm_index(imu));
            let cal = &mut self.calibration[imu];
            // True C_b^s = (I − [δψ×]) Ĉ_b^s, i.e. exp(−δψ) applied on the s side.
            cal.q_b_to_s = small_rotation(-delta_psi) * cal.q_b_to_s;
            cal.q_b_to_s.renormalize();
            cal.lever_arm_b_m += delta_lever;
        }
        self.dx = SVector::zeros();
        correction
    }

    /// Sequential scalar update with measurement row `h`, raw innovation
    /// `z − h(x_nominal)`, and the measurement's one-sigma noise `sigma` (its variance is
    /// `r = sigma²`). The current error estimate is taken into account (`ν = raw − h·δx`),
    /// so several updates may precede one reset.
    ///
    /// The covariance update is the Joseph form `(I − k hᵀ) P (I − k hᵀ)ᵀ + k r kᵀ`,
    /// evaluated on one triangle and mirrored so that `P` stays exactly symmetric. Scaled
    /// (fixed point), it runs on the scaled covariance with the whitened row
    /// `h_i 2^(s_i) / sigma`, innovation `ν / sigma` and `r = 1`.
    pub(crate) fn fuse_scalar(
        &mut self,
        h: &SparseRow<T>,
        raw_innovation: T,
        sigma: T,
    ) -> ScalarOutcome<T> {
        let overflows_before = T::overflows();
        let len = h.len.min(SPARSE_ROW_MAX);
        let mut innovation = raw_innovation;
        for m in 0..len {
            innovation -= h.value[m] * self.dx[h.index[m]];
        }
        let (row, innovation, r) = if T::SCALED {
            if !(sigma.is_finite() && sigma > T::zero()) {
                return ScalarOutcome::NumericalFault;
            }
            let whiten = sigma.recip();
            let mut row = h.value;
            for (value, &index) in row.iter_mut().zip(&h.index).take(len) {
                *value = (*value * whiten).mul_pow2(self.scale[index]);
            }
            (row, innovation * whiten, T::one())
        } else {
            (h.value, innovation, sigma * sigma)
        };
        // P h
        let mut pht = SVector::<T, N>::zeros();
        for (&col, &val) in h.index.iter().zip(&row).take(len) {
            for i in 0..N {
                pht[i] += self.p[(i, col)] * val;
            }
        }
        let mut s = r;
        for m in 0..len {
            s += row[m] * pht[h.index[m]];
        }
        if !(s.is_finite() && s > T::zero() && r >= T::zero() && innovation.is_finite()) {
            return ScalarOutcome::NumericalFault;
        }
        if T::overflows() != overflows_before {
            return ScalarOutcome::NumericalFault;
        }
        // A whitened innovation this far out is an outlier whatever the gate; its square
        // would leave the fixed-point range (2^31) and count as an overflow, where the gate
        // must refuse it (repeated refusals are what resets the position after an outage).
        if T::SCALED && innovation.abs() >= T::one().mul_pow2(15) {
            return ScalarOutcome::Rejected(T::max_value().unwrap_or(innovation));
        }
        // In fixed point one division, not N + 1: a division there costs as much as tens of
        // multiplications.
        let inverse_s = if T::SCALED { s.recip() } else { T::one() };
        let test_ratio = if T::SCALED {
            innovation * innovation * inverse_s
        } else {
            innovation * innovation / s
        };
        if test_ratio > self.config.innovation_gate {
            return ScalarOutcome::Rejected(test_ratio);
        }
        if T::SCALED {
            let gain = pht * inverse_s;
            for i in 0..N {
                self.dx[i] += (gain[i] * innovation).mul_pow2(self.scale[i]);
            }
            self.joseph_update(&pht, &gain, s, r);
            if T::overflows() != overflows_before {
                // Saturated numbers went into the state: start the covariance over.
                self.stats.covariance_resets = self.stats.covariance_resets.saturating_add(1);
                self.reset_covariance();
                return ScalarOutcome::NumericalFault;
            }
        } else {
            let gain = pht / s;
            self.dx += gain * innovation;
            self.joseph_update(&pht, &gain, s, r);
        }
        ScalarOutcome::Accepted(test_ratio)
    }

    /// The Joseph-form covariance update of one scalar measurement, from `P h`, the gain,
    /// the innovation variance `s` and the measurement variance `r`.
    fn joseph_update(&mut self, pht: &SVector<T, N>, gain: &SVector<T, N>, s: T, r: T) {
        if T::SCALED {
            return self.joseph_update_whitened(pht, gain, s);
        }
        // Joseph form P⁺ = A − (A h) kᵀ + r k kᵀ with A = (I − k hᵀ) P = P − k (P h)ᵀ, evaluated
        // element by element on the upper triangle without forming A: its needed product is
        // A h = P h − k (hᵀ P h). Each element is then
        // P⁺_ij = P_ij − k_i (Ph)_j − (Ah)_i k_j + r k_i k_j, a sum of the Joseph form's terms,
        // so no N×N temporary is needed.
        let h_p_h = s - r;
        let mut ah = SVector::<T, N>::zeros();
        for i in 0..N {
            ah[i] = pht[i] - gain[i] * h_p_h;
        }
        for j in 0..N {
            let (kj, phtj, rkj) = (gain[j], pht[j], r * gain[j]);
            for i in 0..=j {
                let v = self.p[(i, j)] - gain[i] * phtj - ah[i] * kj + gain[i] * rkj;
                self.p[(i, j)] = v;
                self.p[(j, i)] = v;
            }
        }
    }

    /// [`Self::joseph_update`] for a whitened measurement (`r = 1`): the terms
    /// `− (A h)_i k_j + r k_i k_j` fold into `− w_i k_j` with `w = A h − k`, two products an
    /// element instead of three.
    fn joseph_update_whitened(&mut self, pht: &SVector<T, N>, gain: &SVector<T, N>, s: T) {
        let h_p_h = s - T::one();
        let mut w = SVector::<T, N>::zeros();
        for i in 0..N {
            w[i] = pht[i] - gain[i] * h_p_h - gain[i];
        }
        for j in 0..N {
            let (kj, phtj) = (gain[j], pht[j]);
            for i in 0..=j {
                let v = self.p[(i, j)] - gain[i] * phtj - w[i] * kj;
                self.p[(i, j)] = v;
                self.p[(j, i)] = v;
            }
        }
    }

    /// Clamps the diagonal to the configured floors; re-initialises the covariance if a
    /// non-finite variance appears. Adding to the diagonal keeps `P` positive definite.
    pub(crate) fn apply_variance_floors(&mut self) {
        let floor = self.config.variance_floor;
        let mut finite = true;
        for i in 0..N {
            let class = if i < NAV_STATES {
                i / 3
            } else if (i - NAV_STATES) % CALIBRATION_STATES_PER_IMU < 3 {
                5
            } else {
                6
            };
            let v = self.p[(i, i)];
            let floor = if T::SCALED {
                floor[class].times_pow2(-2 * self.scale[i])
            } else {
                floor[class].mantissa
            };
            if !v.is_finite() {
                finite = false;
            } else if v < floor {
                self.p[(i, i)] = floor;
            }
        }
        if !finite {
            self.stats.covariance_resets = self.stats.covariance_resets.saturating_add(1);
            self.reset_covariance();
        } else if T::SCALED {
            self.renormalise();
        }
    }

    /// Moves each state's scale so its scaled variance lies in [1/2, 2) again once it has
    /// left [1/4, 4): its row and column are shifted, exactly.
    fn renormalise(&mut self) {
        for i in 0..N {
            let Some(k) = self.p[(i, i)].exponent() else {
                continue;
            };
            if (-2..=1).contains(&k) {
                continue;
            }
            // v in [2^k, 2^(k+1)) times 2^(-2d) lies in [1/2, 2).
            let d = (k + 1).div_euclid(2);
            for j in 0..N {
                if j != i {
                    let v = self.p[(i, j)].mul_pow2(-d);
                    self.p[(i, j)] = v;
                    self.p[(j, i)] = v;
                }
            }
            self.p[(i, i)] = self.p[(i, i)].mul_pow2(-2 * d);
            self.scale[i] += d;
        }
    }
}

/// Counts one scalar outcome into `counters` and `batch`.
pub(crate) fn tally<T>(
    outcome: ScalarOutcome<T>,
    counters: &mut FusionCounters,
    batch: &mut BatchOutcome,
) {
    match outcome {
        ScalarOutcome::Accepted(_) => {
            counters.accepted = counters.accepted.saturating_add(1);
            batch.accepted = batch.accepted.saturating_add(1);
        }
        ScalarOutcome::Rejected(_) => {
            counters.rejected = counters.rejected.saturating_add(1);
            batch.rejected = batch.rejected.saturating_add(1);
        }
        ScalarOutcome::NumericalFault => {
            counters.numerical_faults = counters.numerical_faults.saturating_add(1);
            batch.faults = batch.faults.saturating_add(1);
        }
    }
}

/// `exp([θ×])` as a unit quaternion from the half-angle approximation `(1, θ/2)`,
/// normalised: exact to third order in |θ| and free of trigonometry, which matters on the
/// Cortex-M4F where `sinf`/`cosf` run in software double precision. Used for corrections,
/// which are small.
pub fn small_rotation<T: FilterScalar>(theta: Vector3<T>) -> UnitQuaternion<T> {
    let half: T = nalgebra::convert(0.5);
    UnitQuaternion::new_normalize(Quaternion::new(
        T::one(),
        theta.x * half,
        theta.y * half,
        theta.z * half,
    ))
}

/// The inverse of [`small_rotation`]: `2 (x, y, z) / w` of the quaternion (twice the Gibbs
/// vector, `2 tan(θ/2)` along the axis), equal to the rotation vector to third order, free of
/// trigonometry, and independent of the quaternion's sign. Rotations near 180° (|w| below
/// 1e-6) are clamped rather than divided by zero.
pub fn small_rotation_vector<T: FilterScalar>(q: &UnitQuaternion<T>) -> Vector3<T> {
    let tiny: T = nalgebra::convert(1e-6);
    let two: T = nalgebra::convert(2.0);
    let w = if q.w.abs() < tiny {
        if q.w < T::zero() {
            -tiny
        } else {
            tiny
        }
    } else {
        q.w
    };
    Vector3::new(q.i, q.j, q.k) * (two / w)
}

/// The skew-symmetric cross-product matrix `[v×]`.
pub fn skew<T: FilterScalar>(v: &Vector3<T>) -> Matrix3<T> {
    Matrix3::new(
        T::zero(),
        -v.z,
        v.y,
        v.z,
        T::zero(),
        -v.x,
        -v.y,
        v.x,
        T::zero(),
    )
}

#[cfg(test)]
mod tests;
#[cfg(test)]
mod tests_ins;
