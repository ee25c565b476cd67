//! A car drive of three units and a GNSS receiver, streamed: the simulator's trajectory
//! (exact kinematics) and receiver are built for the whole run, and each sample set is made
//! when it is needed from the trajectory's truth at that instant, moved to each unit by the
//! simulator's mount transfer ([`sensor_kinematics`]), plus the unit's noise drawn sample by
//! sample from its model (white noise, Gauss-Markov biases advanced exactly over a sample,
//! random walks, drifts), rounded to the board's counts (the simulator's default LSBs). A day
//! at 200 Hz is 52 million unit samples, too many to simulate whole; streamed it holds the
//! trajectory's grid and the fixes. The units tick together on GPS time.

use std::collections::BTreeSet;

use nalgebra::Rotation3;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;

use crate::gmwm::model::Process;
use crate::model::{Channel, SimModel};
use crate::sim::board::{gnss_fixes, DEFAULT_ACCEL_LSB_M_S2, DEFAULT_GYRO_LSB_RAD_S};
use crate::sim::effects::{sensor_kinematics, Mount};
use crate::sim::gnss::simulate_gnss;
use crate::sim::trajectory::{Scenario, Trajectory, Truth};
use dynacal_core::board_model::BoardModel;
use dynacal_core::fusion::{UnitReading, UNITS};
use dynacal_core::log::GnssFix;

/// Why a model cannot be driven.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum DriveError {
    #[error("the model has {found} IMUs; the board's fusion needs {UNITS}")]
    Units { found: usize },
    #[error("the model has no GNSS receiver")]
    NoGnss,
    #[error("IMU {imu} samples at {rate_hz} Hz, IMU {first} at {first_rate_hz} Hz: the units tick together")]
    Rates {
        imu: String,
        rate_hz: f64,
        first: String,
        first_rate_hz: f64,
    },
    #[error("IMU {imu} (the first) is mounted off the body frame (lever arm or boresight): it defines the fusion's body frame, so the truth is the body's")]
    FirstUnitMounted { imu: String },
    #[error("IMU {imu}, channel {channel}: {message}")]
    Noise {
        imu: String,
        channel: Channel,
        message: String,
    },
}

/// One channel's noise, drawn sample by sample.
#[derive(Debug, Clone)]
struct ChannelStream {
    /// Standard deviation of the white noise per sample.
    white_sigma: f64,
    /// Each Gauss-Markov bias: its value, its transition over a sample and its driving
    /// standard deviation.
    gauss_markov: Vec<(f64, f64, f64)>,
    /// The random walk's value and its step's standard deviation.
    walk: (f64, f64),
    /// Drift per sample and what it has reached.
    drift: (f64, f64),
}

impl ChannelStream {
    fn new(processes: &[Process], dt_s: f64, rng: &mut ChaCha8Rng) -> Result<Self, String> {
        let mut stream = Self {
            white_sigma: 0.0,
            gauss_markov: Vec::new(),
            walk: (0.0, 0.0),
            drift: (0.0, 0.0),
        };
        let mut white_sigma2 = 0.0;
        for p in processes {
            match *p {
                Process::WhiteNoise { sigma2 } => white_sigma2 += sigma2,
                Process::RandomWalk { sigma2 } => stream.walk.1 = sigma2.sqrt(),
                Process::Drift { slope_per_s } => stream.drift.0 = slope_per_s * dt_s,
                Process::GaussMarkov { beta_per_s, sigma2 } => {
                    let phi = (-beta_per_s * dt_s).exp();
                    // Started from its stationary law.
                    let start = sigma2.sqrt() * rng.sample::<f64, _>(StandardNormal);
                    stream
                        .gauss_markov
                        .push((start, phi, (sigma2 * (1.0 - phi * phi)).sqrt()));
                }
                Process::QuantizationNoise { .. } => {
                    return Err("quantization noise is not drawn sample by sample".into())
                }
            }
        }
        stream.white_sigma = white_sigma2.sqrt();
        Ok(stream)
    }

    /// The next sample's error.
    fn next(&mut self, rng: &mut ChaCha8Rng) -> f64 {
        let mut z = || rng.sample::<f64, _>(StandardNormal);
        let mut error = 0.0;
        for (value, phi, drive) in self.gauss_markov.iter_mut() {
            *value = *phi * *value + *drive * z();
            error += *value;
        }
        error += self.white_sigma * z();
        if self.walk.1 > 0.0 {
            self.walk.0 += self.walk.1 * z();
        }
        self.drift.1 += self.drift.0;
        error + self.walk.0 + self.drift.1
    }
}

/// One unit: its mount and its channels' noise.
struct UnitStream {
    mount: Mount,
    rng: ChaCha8Rng,
    channels: [ChannelStream; 6],
}

/// The drive, streamed.
pub struct StreamedDrive {
    trajectory: Trajectory,
    units: Vec<UnitStream>,
    board_model: BoardModel,
    rate_hz: f64,
    fixes: Vec<GnssFix>,
    next_fix: usize,
    next_sample: u64,
    outages: Vec<[f64; 2]>,
}

impl StreamedDrive {
    /// `seconds` of car driving of the first [`UNITS`] IMUs of `model` and its receiver,
    /// without fixes over `outages` ([start, end] s), seeded by `seed`. The first unit
    /// defines the body frame (it must be mounted at the body's origin, unturned).
    pub fn new(
        model: &SimModel,
        seconds: f64,
        outages: Vec<[f64; 2]>,
        seed: u64,
    ) -> Result<Self, DriveError> {
        if model.imus.len() != UNITS {
            return Err(DriveError::Units {
                found: model.imus.len(),
            });
        }
        let first = &model.imus[0];
        if first.lever_arm_b_m != [0.0; 3] || first.boresight_rpy_deg != [0.0; 3] {
            return Err(DriveError::FirstUnitMounted {
                imu: first.name.clone(),
            });
        }
        if let Some(other) = model.imus.iter().find(|u| u.rate_hz != first.rate_hz) {
            return Err(DriveError::Rates {
                imu: other.name.clone(),
                rate_hz: other.rate_hz,
                first: first.name.clone(),
                first_rate_hz: first.rate_hz,
            });
        }
        let mut gnss = model.gnss.clone().ok_or(DriveError::NoGnss)?;
        gnss.outages = outages.clone();
        let trajectory = Trajectory::new(
            Scenario::Car,
            model.trajectory.clone(),
            seconds,
            seconds + 1.0,
            seed,
        );
        let disabled = BTreeSet::new();
        let fixes = gnss_fixes(&simulate_gnss(&trajectory, &gnss, seconds, seed, &disabled));
        let units = (0..UNITS)
            .map(|k| unit_stream(model, k, seed))
            .collect::<Result<Vec<_>, _>>()?;
        Ok(Self {
            board_model: board_model(model, true),
            rate_hz: first.rate_hz,
            trajectory,
            units,
            fixes,
            next_fix: 0,
            next_sample: 0,
            outages,
        })
    }

    /// The units' sample rate, Hz.
    pub fn rate_hz(&self) -> f64 {
        self.rate_hz
    }

    /// The board model that describes the units to the fusion: their noise as the model
    /// states it and their mounts relative to the first unit.
    pub fn board_model(&self) -> BoardModel {
        self.board_model.clone()
    }

    /// Whether `t_s` is in an outage.
    pub fn in_outage(&self, t_s: f64) -> bool {
        self.outages.iter().any(|o| t_s >= o[0] && t_s < o[1])
    }

    /// Whether the navigation at `t_s` is "with GNSS": outside every outage and `settle_s`
    /// after it (the filter needs a few fixes to pull a drifted position back).
    pub fn with_gnss(&self, t_s: f64, settle_s: f64) -> bool {
        !self
            .outages
            .iter()
            .any(|o| t_s >= o[0] && t_s < o[1] + settle_s)
    }

    /// The outages, [start, end] s.
    pub fn outages(&self) -> &[[f64; 2]] {
        &self.outages
    }

    /// The next sample set: its GPS time (us), the truth then, and each unit's reading as
    /// the board reads it (the value rounded to the simulator's default LSB, in f32).
    pub fn next_set(&mut self) -> (u64, Truth, [Option<UnitReading>; UNITS]) {
        let t_s = self.next_sample as f64 / self.rate_hz;
        self.next_sample += 1;
        let truth = self.trajectory.truth(t_s);
        let readings = core::array::from_fn(|k| {
            let unit = &mut self.units[k];
            let kinematics = sensor_kinematics(&truth, &unit.mount);
            let rng = &mut unit.rng;
            let mut value = |i: usize, lsb: f64| {
                let counts = ((kinematics.channel(i) + unit.channels[i].next(rng)) / lsb).round();
                (counts * lsb) as f32
            };
            let gyro_rad_s = core::array::from_fn(|a| value(a, DEFAULT_GYRO_LSB_RAD_S));
            let accel_m_s2 = core::array::from_fn(|a| value(3 + a, DEFAULT_ACCEL_LSB_M_S2));
            Some(UnitReading {
                gyro_rad_s,
                accel_m_s2,
            })
        });
        ((t_s * 1e6).round() as u64, truth, readings)
    }

    /// The fixes stamped at or before `t_us` not handed out yet.
    pub fn fixes_until(&mut self, t_us: u64) -> &[GnssFix] {
        let first = self.next_fix;
        while self
            .fixes
            .get(self.next_fix)
            .is_some_and(|f| f.t_us <= t_us)
        {
            self.next_fix += 1;
        }
        &self.fixes[first..self.next_fix]
    }
}

/// Unit `k`'s mount and noise streams (one ChaCha8 stream per unit, from `seed`).
fn unit_stream(model: &SimModel, k: usize, seed: u64) -> Result<UnitStream, DriveError> {
    let imu = &model.imus[k];
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0xda7_0000);
    rng.set_stream(k as u64);
    let dt_s = 1.0 / imu.rate_hz;
    let mut channels = Vec::with_capacity(6);
    for channel in Channel::ALL {
        let noise_error = |message: String| DriveError::Noise {
            imu: imu.name.clone(),
            channel,
            message,
        };
        let spec = imu
            .model_of(channel)
            .stochastic
            .as_ref()
            .ok_or_else(|| noise_error("no stochastic model".into()))?;
        channels.push(ChannelStream::new(&spec.processes, dt_s, &mut rng).map_err(noise_error)?);
    }
    Ok(UnitStream {
        mount: Mount::of(imu, &BTreeSet::new()),
        rng,
        channels: channels
            .try_into()
            .unwrap_or_else(|_| unreachable!("six channels")),
    })
}

/// The board model of the first [`UNITS`] units of `model`: with `noise_from_model`, each
/// channel's noise as the board's filter runs it ([`crate::refit::channel_noise`]),
/// otherwise the board's built-in noise; the units turned and offset from the body as the
/// model mounts them: rotation as roll, pitch, yaw of C_b^k (body to unit axes), lever arm
/// in body axes.
pub fn board_model(model: &SimModel, noise_from_model: bool) -> BoardModel {
    let ids: Vec<u8> = (0..UNITS as u8).collect();
    let mut board = BoardModel::built_in(&ids);
    for (unit, imu) in board.units.iter_mut().zip(&model.imus) {
        for channel in Channel::ALL.into_iter().filter(|_| noise_from_model) {
            if let Some(spec) = &imu.model_of(channel).stochastic {
                unit.channels[channel.index()] = crate::refit::channel_noise(spec).0;
            }
        }
        let [r, p, y] = imu.boresight_rpy_deg.map(f64::to_radians);
        let c_b_k = Rotation3::from_euler_angles(r, p, y).transpose();
        let (r, p, y) = c_b_k.euler_angles();
        unit.rotation_rpy_rad = [r as f32, p as f32, y as f32];
        unit.lever_arm_m = imu.lever_arm_b_m.map(|x| x as f32);
    }
    board
}
