//! A synthetic board log for decoder tests: a header for two IMUs, then time-ordered IMU
//! samples, PPS edges, GNSS fixes, filter states and health reports, as the board writes them.

#![allow(dead_code)]

use dynacal_core::log::{
    FilterState, Frame, GnssFix, Header, Health, ImuConfig, ImuSampleSet, PpsEvent,
    PROTOCOL_VERSION,
};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// GPS time of the first sample, microseconds (mid-2024).
pub const T0_US: u64 = 1_403_000_000_000_000;

pub fn header() -> Header {
    let imu = |imu_id: u8, model: &str, rate: f32, gyro: f64, accel: f64| ImuConfig {
        imu_id,
        model: model.try_into().unwrap(),
        sample_rate_hz: rate,
        gyro_scale_rad_s_per_count: gyro,
        accel_scale_m_s2_per_count: accel,
    };
    Header {
        protocol_version: PROTOCOL_VERSION,
        board: "dynacal-test rev A".try_into().unwrap(),
        imus: [
            // ICM-42688-P at +-2000 dps / +-16 g; BMI088 at +-1000 dps / +-6 g.
            imu(
                0,
                "ICM-42688-P",
                200.0,
                (2000.0f64 / 32768.0).to_radians(),
                16.0 * 9.80665 / 32768.0,
            ),
            imu(
                2,
                "BMI088",
                100.0,
                (1000.0f64 / 32768.0).to_radians(),
                6.0 * 9.80665 / 32768.0,
            ),
        ]
        .into_iter()
        .collect(),
    }
}

/// `seconds` of log; `seed` picks the sensor values.
pub fn frames(seed: u64, seconds: u64) -> Vec<Frame> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut timed: Vec<(u64, u8, Frame)> = Vec::new();
    let end_us = seconds * 1_000_000;
    for (imu_id, dt_us) in [(0u8, 5_000u64), (2, 10_000)] {
        for t in (0..end_us).step_by(dt_us as usize) {
            timed.push((
                t,
                1,
                Frame::Imu(ImuSampleSet {
                    t_us: T0_US + t,
                    imu_id,
                    gyro_counts: [0; 3].map(|_| rng.random_range(-3000..3000)),
                    accel_counts: [0, 0, -2048].map(|g| g + rng.random_range(-300..300)),
                }),
            ));
        }
    }
    for s in 0..seconds {
        let t = s * 1_000_000;
        timed.push((
            t,
            0,
            Frame::Pps(PpsEvent {
                t_us: T0_US + t + rng.random_range(0..3),
                sequence: s as u32,
            }),
        ));
        timed.push((
            t,
            3,
            Frame::Health(Health {
                t_us: T0_US + t,
                frames_dropped: 0,
                samples_overrun: rng.random_range(0..2),
                flags: Health::FLAG_TIME_GPS | Health::FLAG_PPS_LOCKED | Health::FLAG_GNSS_FIX,
                cpu_load_permille: rng.random_range(100..400),
                imu_temperature_deg_c: [31.5, 29.25, f32::NAN],
            }),
        ));
    }
    for t in (0..end_us).step_by(200_000) {
        timed.push((
            t,
            2,
            Frame::Gnss(GnssFix {
                t_us: T0_US + t,
                lat_rad: 0.8107 + rng.random_range(-1e-7..1e-7),
                lon_rad: 0.1147 + rng.random_range(-1e-7..1e-7),
                h_m: 420.0 + rng.random_range(-1.0..1.0),
                vel_ned_m_s: [10.0, 0.5, 0.0],
                pos_sigma_m: 1.5,
                vel_sigma_m_s: 0.1,
                num_sats: rng.random_range(8..20),
                fix_type: 3,
            }),
        ));
    }
    for t in (0..end_us).step_by(100_000) {
        timed.push((
            t,
            4,
            Frame::Filter(FilterState {
                t_us: T0_US + t,
                imu_id: 0,
                q_nb: [
                    std::f32::consts::FRAC_1_SQRT_2,
                    0.0,
                    0.0,
                    std::f32::consts::FRAC_1_SQRT_2,
                ],
                vel_ned_m_s: [10.0, 0.5, rng.random_range(-0.1..0.1)],
                lat_rad: 0.8107,
                lon_rad: 0.1147,
                h_m: 420.0,
                gyro_bias_rad_s: [1e-4, -2e-4, 5e-5],
                accel_bias_m_s2: [0.01, -0.02, 0.03],
                attitude_sigma_rad: [0.01, 0.01, 0.05],
                vel_sigma_m_s: [0.1; 3],
                pos_sigma_m: [1.5, 1.5, 3.0],
                gyro_bias_sigma_rad_s: [1e-5; 3],
                accel_bias_sigma_m_s2: [1e-3; 3],
            }),
        ));
    }
    timed.sort_by_key(|(t, order, _)| (*t, *order));
    std::iter::once(Frame::Header(header()))
        .chain(timed.into_iter().map(|(_, _, f)| f))
        .collect()
}
