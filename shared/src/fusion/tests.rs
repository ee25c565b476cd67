//! The fusion at rest, where the truth is simple: three units mounted three ways, each with
//! its own noise; what the fusion reports of their noise, their faults and the standstill.
//! Its navigation on a drive is tested against the simulator's truth in `tests/`.

use super::*;
use crate::board_model::BoardModel;
use rand::SeedableRng;
use rand_distr::{Distribution, Normal};

const RATE_HZ: f32 = 1000.0;
const GYRO_SIGMA: [f32; UNITS] = [0.01, 0.02, 0.03];
const ACCEL_SIGMA: [f32; UNITS] = [0.02, 0.04, 0.06];
/// Each unit's mounting: roll, pitch, yaw of its axes from the first unit's, rad.
const MOUNTING_RPY: [[f32; 3]; UNITS] = [
    [0.0; 3],
    [0.0, 0.0, core::f32::consts::FRAC_PI_2],
    [core::f32::consts::PI, 0.0, 0.3],
];

fn model() -> BoardModel {
    let mut model = BoardModel::built_in(&[0, 1, 2]);
    for (unit, rpy) in model.units.iter_mut().zip(MOUNTING_RPY) {
        unit.rotation_rpy_rad = rpy;
    }
    model
}

fn c_b_k(k: usize) -> Matrix3<f32> {
    let [r, p, y] = MOUNTING_RPY[k];
    UnitQuaternion::from_euler_angles(r, p, y)
        .to_rotation_matrix()
        .into_inner()
}

/// Unit k's reading at rest, level, with its own noise and a small bias.
fn at_rest(k: usize, rng: &mut rand_chacha::ChaCha8Rng) -> UnitReading {
    let normal = Normal::new(0.0f32, 1.0).unwrap();
    let mut noise = |s: f32| {
        Vector3::new(
            s * normal.sample(rng),
            s * normal.sample(rng),
            s * normal.sample(rng),
        )
    };
    let gyro_bias = Vector3::new(0.002, -0.001, 0.003) * (k as f32 + 1.0);
    let omega = c_b_k(k) * (Vector3::new(5e-5, 0.0, -5e-5) + gyro_bias) + noise(GYRO_SIGMA[k]);
    let force = c_b_k(k) * Vector3::new(0.0, 0.0, -9.806) + noise(ACCEL_SIGMA[k]);
    UnitReading {
        gyro_rad_s: omega.into(),
        accel_m_s2: force.into(),
    }
}

#[test]
fn at_rest_each_units_own_noise_is_reported_and_a_stuck_gyro_is_isolated() {
    // GIVEN three units mounted three ways (as the board model says), at rest, with gyro
    // noise 0.01, 0.02, 0.03 rad/s and accelerometer noise 0.02, 0.04, 0.06 m/s^2 per sample
    let mut fusion = BoardFusion::<f32>::new(FusionConfig::at_rate(RATE_HZ), &model());
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(0xf05e);
    let mut outputs = std::vec::Vec::new();
    let mut stuck: Option<UnitReading> = None;
    for i in 0..25_000u64 {
        let t_us = 1_000_000 + i * 1000;
        let mut set: [Option<UnitReading>; UNITS] =
            core::array::from_fn(|k| Some(at_rest(k, &mut rng)));
        // WHEN unit 2's gyro output freezes after 20 s
        if i >= 20_000 {
            let frozen = *stuck.get_or_insert(set[2].unwrap());
            set[2] = set[2].map(|r| UnitReading {
                gyro_rad_s: frozen.gyro_rad_s,
                ..r
            });
        }
        fusion.push_set(t_us, &set, &mut |o| outputs.push((t_us, o)));
    }
    // THEN the noise frames of the 8 s before the fault give each unit's own level to 10% on
    // average (each frame is a 2 s live level, of 400 interval means: a quarter of that
    // apart from frame to frame for the quietest unit, whose level is a small difference)
    let noise_at = |t: u64| {
        outputs
            .iter()
            .rev()
            .filter_map(|(at, o)| match o {
                FusionOutput::Noise(n) if *at <= t => Some(*n),
                _ => None,
            })
            .next()
            .unwrap()
    };
    let frames: std::vec::Vec<NoiseFrame> = outputs
        .iter()
        .filter_map(|(at, o)| match o {
            FusionOutput::Noise(n) if (12_500_000..20_500_000).contains(at) => Some(*n),
            _ => None,
        })
        .collect();
    assert_eq!(frames.len(), 8);
    let mean = |f: fn(&NoiseFrame) -> f32| frames.iter().map(f).sum::<f32>() / 8.0;
    let gyro_levels = [
        mean(|n| n.gyro_sigma_rad_s[0]),
        mean(|n| n.gyro_sigma_rad_s[1]),
        mean(|n| n.gyro_sigma_rad_s[2]),
    ];
    let accel_levels = [
        mean(|n| n.accel_sigma_m_s2[0]),
        mean(|n| n.accel_sigma_m_s2[1]),
        mean(|n| n.accel_sigma_m_s2[2]),
    ];
    for k in 0..UNITS {
        let g = gyro_levels[k] / GYRO_SIGMA[k];
        let a = accel_levels[k] / ACCEL_SIGMA[k];
        assert!((0.9..1.1).contains(&g), "unit {k} gyro level ratio {g}");
        assert!((0.9..1.1).contains(&a), "unit {k} accel level ratio {a}");
    }
    let before = noise_at(20_900_000);
    assert!(before.still);
    assert_eq!(before.in_use, 0b11_1111);
    // AND no fault before it; then exactly the stuck gyro of unit 2, within 0.2 s, which
    // leaves the fused output
    let faults: std::vec::Vec<(u64, FaultFrame)> = outputs
        .iter()
        .filter_map(|(at, o)| match o {
            FusionOutput::Fault(f) => Some((*at, *f)),
            _ => None,
        })
        .collect();
    assert!(!faults.is_empty(), "the stuck gyro was not reported");
    for (at, f) in &faults {
        assert!(*at > 21_000_000, "a fault before the freeze: {f:?}");
        assert_eq!(
            (f.sensor, f.unit, f.kind_name()),
            (FaultFrame::SENSOR_GYRO, Some(2), "stuck")
        );
    }
    assert!(faults[0].1.detected_t_us < 21_200_000, "{:?}", faults[0]);
    assert_eq!(noise_at(26_000_000).in_use, 0b11_1011);
}

#[test]
fn fault_codes_follow_the_monitors_kinds() {
    use crate::redundancy::FaultKind::*;
    let kinds = [
        Dropout,
        Saturation,
        Stuck,
        Spike,
        BiasStep,
        ScaleFactor,
        NoiseBurst,
        TimeSlip,
    ];
    for (code, kind) in kinds.into_iter().enumerate() {
        let event = FaultEvent {
            unit: Some(1),
            axis: None,
            kind,
            detected_sample: 10,
            confirmed_sample: 30,
        };
        let frame = fault_frame(5_000_000, 1000, FaultFrame::SENSOR_ACCEL, &event);
        assert_eq!(usize::from(frame.kind), code);
        assert_eq!(frame.detected_t_us, 5_000_000 - 20_000);
        let name = frame.kind_name().replace('_', "");
        assert_eq!(name, std::format!("{kind:?}").to_lowercase());
    }
}
