//! From a raw PX4 sensor's axes to the body's (forward-right-down): the board rotation.
//!
//! PX4's drivers publish `sensor_gyro` / `sensor_accel` in the chip's own axes. PX4 turns them
//! into the body frame with a rotation matrix `R_b_s` (sensor to body) and corrects
//! `v_b = R_b_s * ((v_s - offset) .* scale)` (`lib/sensor_calibration`, `Accelerometer` /
//! `Gyroscope::Correct`), where
//! - `R_b_s = L * R(rot)`: `R(rot)` is `get_rot_matrix` of a value of PX4's `enum Rotation`
//!   (`lib/conversion/rotation.h`): the direction cosine matrix of the Euler angles roll,
//!   pitch, yaw (degrees) of its table [`ROTATIONS_DEG`], Z-Y-X (`R = Rz(yaw) Ry(pitch)
//!   Rx(roll)`, PX4's `Dcmf(Eulerf(...))`, nalgebra's `Rotation3::from_euler_angles`);
//! - `rot` is `SENS_BOARD_ROT` for a sensor on the board; a sensor whose calibration slot
//!   (`CAL_ACCn_ID` / `CAL_GYROn_ID` equal to its `device_id`) has `CAL_ACCn_ROT` /
//!   `CAL_GYROn_ROT` >= 0 is external (PX4 v1.12 on writes -1 there for internal sensors) and
//!   uses that rotation instead;
//! - `L` is the level trim, the Euler angles `SENS_BOARD_X_OFF`, `SENS_BOARD_Y_OFF`,
//!   `SENS_BOARD_Z_OFF` (degrees, roll, pitch, yaw, Z-Y-X as above), applied after `R(rot)`
//!   (`GetSensorLevelAdjustment() * get_rot_matrix(rot)`), each 0 where the log lacks it.
//!
//! The importer applies `R_b_s` only, not the calibration's offsets and scales: those are
//! the errors dynacal estimates. The value each parameter has at the start of the log is
//! used; a log in which one changes later is refused (one rotation could not describe it).

use nalgebra::Rotation3;

use super::{corrupt, ImportError, ULog};

/// Roll, pitch, yaw (degrees, Z-Y-X) of every value of PX4's `enum Rotation`, indexed by the
/// value (`ROTATION_NONE` = 0 ... `ROTATION_ROLL_270_YAW_315` = 47; `ROTATION_MAX` = 48).
/// PX4 appends new values at the end, so an older log uses a prefix of this list.
pub const ROTATIONS_DEG: [[u16; 3]; 48] = [
    [0, 0, 0],     // 0 NONE
    [0, 0, 45],    // 1 YAW_45
    [0, 0, 90],    // 2 YAW_90
    [0, 0, 135],   // 3 YAW_135
    [0, 0, 180],   // 4 YAW_180
    [0, 0, 225],   // 5 YAW_225
    [0, 0, 270],   // 6 YAW_270
    [0, 0, 315],   // 7 YAW_315
    [180, 0, 0],   // 8 ROLL_180
    [180, 0, 45],  // 9 ROLL_180_YAW_45
    [180, 0, 90],  // 10 ROLL_180_YAW_90
    [180, 0, 135], // 11 ROLL_180_YAW_135
    [0, 180, 0],   // 12 PITCH_180
    [180, 0, 225], // 13 ROLL_180_YAW_225
    [180, 0, 270], // 14 ROLL_180_YAW_270
    [180, 0, 315], // 15 ROLL_180_YAW_315
    [90, 0, 0],    // 16 ROLL_90
    [90, 0, 45],   // 17 ROLL_90_YAW_45
    [90, 0, 90],   // 18 ROLL_90_YAW_90
    [90, 0, 135],  // 19 ROLL_90_YAW_135
    [270, 0, 0],   // 20 ROLL_270
    [270, 0, 45],  // 21 ROLL_270_YAW_45
    [270, 0, 90],  // 22 ROLL_270_YAW_90
    [270, 0, 135], // 23 ROLL_270_YAW_135
    [0, 90, 0],    // 24 PITCH_90
    [0, 270, 0],   // 25 PITCH_270
    [0, 180, 90],  // 26 PITCH_180_YAW_90
    [0, 180, 270], // 27 PITCH_180_YAW_270
    [90, 90, 0],   // 28 ROLL_90_PITCH_90
    [180, 90, 0],  // 29 ROLL_180_PITCH_90
    [270, 90, 0],  // 30 ROLL_270_PITCH_90
    [90, 180, 0],  // 31 ROLL_90_PITCH_180
    [270, 180, 0], // 32 ROLL_270_PITCH_180
    [90, 270, 0],  // 33 ROLL_90_PITCH_270
    [180, 270, 0], // 34 ROLL_180_PITCH_270
    [270, 270, 0], // 35 ROLL_270_PITCH_270
    [90, 180, 90], // 36 ROLL_90_PITCH_180_YAW_90
    [90, 0, 270],  // 37 ROLL_90_YAW_270
    [90, 68, 293], // 38 ROLL_90_PITCH_68_YAW_293
    [0, 315, 0],   // 39 PITCH_315
    [90, 315, 0],  // 40 ROLL_90_PITCH_315
    [270, 0, 180], // 41 ROLL_270_YAW_180
    [270, 0, 270], // 42 ROLL_270_YAW_270
    [0, 90, 180],  // 43 PITCH_90_YAW_180
    [0, 9, 180],   // 44 PITCH_9_YAW_180
    [0, 45, 0],    // 45 PITCH_45
    [270, 0, 225], // 46 ROLL_270_YAW_225
    [270, 0, 315], // 47 ROLL_270_YAW_315
];

/// The rotation of Euler angles roll, pitch, yaw in degrees, Z-Y-X.
fn euler_deg(roll_deg: f64, pitch_deg: f64, yaw_deg: f64) -> Rotation3<f64> {
    Rotation3::from_euler_angles(
        roll_deg.to_radians(),
        pitch_deg.to_radians(),
        yaw_deg.to_radians(),
    )
}

/// `R(rot)`, sensor to board-corrected body, of PX4's rotation value `rotation`; `None` for a
/// value PX4 does not define.
pub fn rotation_matrix(rotation: i64) -> Option<Rotation3<f64>> {
    let [roll, pitch, yaw] = *ROTATIONS_DEG.get(usize::try_from(rotation).ok()?)?;
    Some(euler_deg(f64::from(roll), f64::from(pitch), f64::from(yaw)))
}

/// The level trim `L` of `SENS_BOARD_X_OFF`, `_Y_OFF`, `_Z_OFF` (degrees).
pub fn level_adjustment(offsets_deg: [f64; 3]) -> Rotation3<f64> {
    euler_deg(offsets_deg[0], offsets_deg[1], offsets_deg[2])
}

/// Which raw sensor: it names the calibration parameters (`CAL_GYRO0_ID`, `CAL_ACC0_ID`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SensorKind {
    Gyro,
    Accel,
}

impl SensorKind {
    fn calibration_prefix(self) -> &'static str {
        match self {
            Self::Gyro => "CAL_GYRO",
            Self::Accel => "CAL_ACC",
        }
    }
}

/// How one raw sensor's axes are turned into the body's.
#[derive(Debug, Clone, PartialEq)]
pub struct SensorToBody {
    /// The PX4 rotation value applied.
    pub rotation: i64,
    /// The parameter it came from: `SENS_BOARD_ROT`, or `CAL_ACCn_ROT` / `CAL_GYROn_ROT` for
    /// an external sensor.
    pub rotation_parameter: String,
    /// `SENS_BOARD_X_OFF`, `_Y_OFF`, `_Z_OFF`, degrees (0 where the log lacks one).
    pub level_offsets_deg: [f64; 3],
    /// `R_b_s = L * R(rotation)`: `v_body = r_b_s * v_sensor`.
    pub r_b_s: Rotation3<f64>,
}

/// The value of parameter `name` at the start of the log, refused if it changes later.
fn constant_parameter(log: &ULog, name: &str) -> Result<Option<f64>, ImportError> {
    let Some(values) = log.parameter_values(name) else {
        return Ok(None);
    };
    if let Some(k) = values.iter().position(|v| *v != values[0]) {
        let offset = log
            .parameter_offsets(name)
            .and_then(|o| o.get(k).copied())
            .unwrap_or(0);
        return Err(corrupt(
            log.path(),
            offset,
            format!(
                "parameter {name} changes from {} to {} during the log; the importer rotates \
                 the raw sensors with one board rotation",
                values[0], values[k]
            ),
        ));
    }
    Ok(values.first().copied())
}

/// `R_b_s` of the raw sensor `kind` with the `device_id` given, from the log's parameters;
/// `None` when the log has no `SENS_BOARD_ROT` and no external rotation for it (its data
/// then stay in the sensor's axes). A rotation value PX4 does not define is an error.
pub fn sensor_to_body(
    log: &ULog,
    kind: SensorKind,
    device_id: Option<f64>,
) -> Result<Option<SensorToBody>, ImportError> {
    let prefix = kind.calibration_prefix();
    let slot = device_id
        .and_then(|id| (0..10).find(|n| log.parameter(&format!("{prefix}{n}_ID")) == Some(id)));
    let mut source = "SENS_BOARD_ROT".to_string();
    if let Some(n) = slot {
        let name = format!("{prefix}{n}_ROT");
        if constant_parameter(log, &name)?.is_some_and(|r| r >= 0.0) {
            source = name;
        }
    }
    let Some(value) = constant_parameter(log, &source)? else {
        return Ok(None);
    };
    let rotation = value as i64;
    let r = rotation_matrix(rotation)
        .filter(|_| rotation as f64 == value)
        .ok_or_else(|| {
            let offset = log
                .parameter_offsets(&source)
                .and_then(|o| o.first().copied())
                .unwrap_or(0);
            corrupt(
                log.path(),
                offset,
                format!(
                    "parameter {source} is {value}, not a rotation PX4 defines (0 to {})",
                    ROTATIONS_DEG.len() - 1
                ),
            )
        })?;
    let mut level_offsets_deg = [0.0; 3];
    for (v, axis) in level_offsets_deg.iter_mut().zip(["X", "Y", "Z"]) {
        *v = constant_parameter(log, &format!("SENS_BOARD_{axis}_OFF"))?.unwrap_or(0.0);
    }
    Ok(Some(SensorToBody {
        rotation,
        rotation_parameter: source,
        level_offsets_deg,
        r_b_s: level_adjustment(level_offsets_deg) * r,
    }))
}
