//! Fault detection and isolation over a whole recording, and the fused virtual IMU: the
//! core's [`FaultMonitor`] (the code the board runs) on the aligned units, one monitor for
//! the gyros and one for the accelerometers, with each unit's range found in its own data
//! where it clips.

use dynacal_core::redundancy::{FaultConfig, FaultKind, FaultMonitor, MAX_UNITS};
use serde::Serialize;

use crate::interchange::ImuRecording;

/// A fault found in the set.
#[derive(Debug, Clone, Serialize)]
pub struct FaultRecord {
    /// 0-based input index of the faulty unit; None when only two units were healthy, so the
    /// disagreement could not be placed.
    pub imu: Option<usize>,
    /// The channel that showed it (`gz`, `ax`, ...), or the sensor (`gyro`, `accel`) when the
    /// fault is the unit's, not an axis's (a dropout, stuck output, a vector length off).
    pub channel: String,
    pub kind: String,
    /// When the unit was first suspected and left the fused output, s.
    pub t_detected_s: f64,
    /// When the kind was decided, s.
    pub t_confirmed_s: f64,
    /// When the unit was readmitted after a clean period, s; None if it never was.
    pub t_readmitted_s: Option<f64>,
}

/// The name a fault kind has in the JSON.
pub fn kind_name(kind: FaultKind) -> &'static str {
    match kind {
        FaultKind::Dropout => "dropout",
        FaultKind::Saturation => "saturation",
        FaultKind::Stuck => "stuck",
        FaultKind::Spike => "spike",
        FaultKind::BiasStep => "bias_step",
        FaultKind::ScaleFactor => "scale_factor",
        FaultKind::NoiseBurst => "noise_burst",
        FaultKind::TimeSlip => "time_slip",
    }
}

/// A sensor's per-axis range for every unit, or where none is given, the one its data show.
pub type Ranges = [Option<f64>; 2];

/// The magnitude at which a unit's triad clips, if its data show one: the largest |value|
/// of the triad, held by two consecutive samples of one axis (a clipped signal sits at its
/// limit), and standing more than ten robust standard deviations above the median |value|
/// (a quantised signal at rest repeats its largest value too, but a few counts from the
/// rest).
pub fn clipping_level(triad: &[Vec<f64>; 3]) -> Option<f64> {
    let mut magnitudes: Vec<f64> = triad.iter().flatten().map(|v| v.abs()).collect();
    if magnitudes.is_empty() {
        return None;
    }
    let largest = magnitudes.iter().copied().fold(0.0, f64::max);
    let held = triad.iter().any(|axis| {
        axis.windows(2)
            .any(|w| w[0].abs() == largest && w[1].abs() == largest)
    });
    let mid = magnitudes.len() / 2;
    let median = *magnitudes.select_nth_unstable_by(mid, f64::total_cmp).1;
    let mut deviations: Vec<f64> = magnitudes.iter().map(|m| (m - median).abs()).collect();
    let mad = *deviations.select_nth_unstable_by(mid, f64::total_cmp).1;
    (held && largest > 0.0 && largest - median > 10.0 * 1.4826 * mad).then_some(largest)
}

/// What the monitors found, and the fused virtual IMU on the grid.
pub(super) struct Monitoring {
    pub faults: Vec<FaultRecord>,
    /// None where the units' rotations are not determined.
    pub fused: Option<ImuRecording>,
    /// Samples where no unit was healthy, so the fused output is the plain mean of the
    /// present units.
    pub unfused: usize,
}

/// Inputs of the monitors: per unit the six aligned channels (gx..az) on the grid, whether
/// each sample is present, and each unit's clipping levels (gyro, accel) in its own axes.
pub(super) struct MonitorInput<'a> {
    pub signals: &'a [[Vec<f64>; 6]],
    /// The units' own outputs on the grid (for stuck output: the aligned signals move with
    /// the lever-arm correction even when a unit's output does not).
    pub raw: &'a [(String, ImuRecording)],
    pub present: &'a [Vec<bool>],
    pub t_s: &'a [f64],
    pub dt_s: f64,
    pub ranges: &'a [Ranges],
    /// The units' rotations are not all determined: their axes differ, so a motion common to
    /// all (a bump of a static rig) would not cancel in an axis's difference. The monitors
    /// then compare the rotation-invariant lengths of the vectors, and there is no fused
    /// output in one frame.
    pub lengths_only: bool,
}

/// Runs both monitors over the whole recording.
pub(super) fn monitor(input: &MonitorInput) -> Monitoring {
    match input.signals.len() {
        3 => monitor_n::<3>(input),
        4 => monitor_n::<4>(input),
        5 => monitor_n::<5>(input),
        6 => monitor_n::<6>(input),
        7 => monitor_n::<7>(input),
        _ => monitor_n::<8>(input),
    }
}

/// The core's monitor configuration for one sensor: the units' clipping levels, less 1% for
/// the alignment's rotation, which mixes a little of the other axes into each; the
/// accelerometers' lengths compared to 10% (gravity at rest needs no alignment; MEMS
/// units a few percent apart in their length at rest are calibrated badly, not faulty).
fn config(input: &MonitorInput, sensor: usize) -> FaultConfig {
    let mut c = FaultConfig::new(input.dt_s as f32);
    for (k, r) in input.ranges.iter().enumerate().take(MAX_UNITS) {
        if let Some(level) = r[sensor] {
            c.range[k] = 0.99 * level as f32;
        }
    }
    if sensor == 1 {
        c.norm_tolerance = Some(0.1);
    } else {
        // A rigid platform turns as one: a jolt reads the same on every gyro (on the
        // accelerometers it does not, by their lever arms), so gyros that disagree through
        // one are faulty (clipping, a crash's damage) and are not held back.
        c.common_hold_s = 0.0;
    }
    c
}

fn monitor_n<const N: usize>(input: &MonitorInput) -> Monitoring {
    let mut monitors = [0, 1].map(|sensor| FaultMonitor::<N>::new(config(input, sensor)));
    let mut faults: Vec<FaultRecord> = Vec::new();
    let mut open: [[Option<usize>; N]; 2] = [[None; N]; 2];
    let mut fused: [[Vec<f64>; 3]; 2] = Default::default();
    let mut t_fused = Vec::new();
    let mut unfused = 0;
    for (i, &t) in input.t_s.iter().enumerate() {
        let mut row = [[0.0; 3]; 2];
        let mut any = false;
        for (sensor, monitor) in monitors.iter_mut().enumerate() {
            let samples: [Option<[f32; 3]>; N] = std::array::from_fn(|k| {
                input.present[k][i].then(|| {
                    let v: [f32; 3] =
                        std::array::from_fn(|a| input.signals[k][3 * sensor + a][i] as f32);
                    if input.lengths_only {
                        [v.iter().map(|x| x * x).sum::<f32>().sqrt(), 0.0, 0.0]
                    } else {
                        v
                    }
                })
            });
            let repeated: [[bool; 3]; N] = std::array::from_fn(|k| {
                let triad = if sensor == 0 {
                    &input.raw[k].1.gyro_rad_s
                } else {
                    &input.raw[k].1.accel_m_s2
                };
                let both = i > 0 && input.present[k][i] && input.present[k][i - 1];
                std::array::from_fn(|a| {
                    both && triad.as_ref().is_some_and(|t| t[a][i] == t[a][i - 1])
                })
            });
            let step = monitor.push_marked(&samples, &repeated);
            for e in &step.confirmed {
                let mut e = *e;
                if input.lengths_only {
                    e.axis = None;
                }
                let record = record(&e, sensor, input.t_s);
                if let Some(k) = record.imu {
                    open[sensor][k] = Some(faults.len());
                }
                faults.push(record);
            }
            for (k, slot) in open[sensor].iter_mut().enumerate() {
                if step.readmitted >> k & 1 == 1 {
                    if let Some(f) = slot.take() {
                        faults[f].t_readmitted_s = Some(t);
                    }
                }
            }
            let plain_mean = || -> Option<[f32; 3]> {
                let present: Vec<[f32; 3]> = samples.iter().flatten().copied().collect();
                (!present.is_empty()).then(|| {
                    std::array::from_fn(|a| {
                        present.iter().map(|s| s[a]).sum::<f32>() / present.len() as f32
                    })
                })
            };
            match monitor.fused(&samples) {
                Some(f) => row[sensor] = f.map(f64::from),
                None => {
                    unfused += 1;
                    match plain_mean() {
                        Some(f) => row[sensor] = f.map(f64::from),
                        None => continue,
                    }
                }
            }
            any = true;
        }
        if any && !input.lengths_only {
            t_fused.push(t);
            for (sensor, triad) in fused.iter_mut().enumerate() {
                for (a, column) in triad.iter_mut().enumerate() {
                    column.push(row[sensor][a]);
                }
            }
        }
    }
    let [gyro, accel] = fused;
    Monitoring {
        faults,
        fused: (!input.lengths_only).then(|| ImuRecording {
            t_s: t_fused,
            gyro_rad_s: Some(gyro),
            accel_m_s2: Some(accel),
            ..Default::default()
        }),
        unfused,
    }
}

/// The JSON record of a core event of `sensor` (0 gyro, 1 accel).
fn record(e: &dynacal_core::redundancy::FaultEvent, sensor: usize, t_s: &[f64]) -> FaultRecord {
    const CHANNELS: [[&str; 3]; 2] = [["gx", "gy", "gz"], ["ax", "ay", "az"]];
    let channel = match e.axis {
        Some(a) => CHANNELS[sensor][a as usize].to_string(),
        None => ["gyro", "accel"][sensor].to_string(),
    };
    let at = |sample: u32| t_s[(sample as usize).min(t_s.len() - 1)];
    FaultRecord {
        imu: e.unit.map(usize::from),
        channel,
        kind: kind_name(e.kind).to_string(),
        t_detected_s: at(e.detected_sample),
        t_confirmed_s: at(e.confirmed_sample),
        t_readmitted_s: None,
    }
}
