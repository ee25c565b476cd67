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

/// What the monitors found.
pub(super) struct Monitoring {
    pub faults: Vec<FaultRecord>,
    /// Samples where no unit was healthy, so the fused output is the plain mean of the
    /// present units.
    pub unfused: usize,
}

/// The monitors' configuration: each unit's clipping levels (gyro, accel) in its own axes,
/// and whether only the vectors' lengths can be compared.
pub(super) struct MonitorSetup<'a> {
    pub dt_s: f64,
    pub ranges: &'a [Ranges],
    /// The units' rotations are not all determined: their axes differ, so a motion common to
    /// all (a bump of a static rig) would not cancel in an axis's difference. The monitors
    /// then compare the rotation-invariant lengths of the vectors, and there is no fused
    /// output in one frame.
    pub lengths_only: bool,
}

/// One stretch of the units for the monitors: per unit the six aligned channels (gx..az) on
/// the stretch's grid, whether each sample is present, and the units' own outputs (for
/// stuck output: the aligned signals move with the lever-arm correction even when a unit's
/// output does not).
pub(super) struct MonitorStretch<'a> {
    pub signals: &'a [[Vec<f64>; 6]],
    pub raw: &'a [(String, ImuRecording)],
    pub present: &'a [Vec<bool>],
    pub t_s: &'a [f64],
    /// The grid samples that are the stretch's own, and the run's index of the first.
    pub own: std::ops::Range<usize>,
    pub first_epoch: usize,
}

/// Where the fused virtual IMU goes: t_s, then gx..az in the first unit's frame.
pub(super) type FusedSink<'a> = dyn FnMut(f64, [f64; 6]) -> Result<(), super::RedundancyError> + 'a;

/// Both monitors over a run, fed stretch by stretch in order.
pub(super) trait Monitors {
    fn push(
        &mut self,
        stretch: &MonitorStretch,
        fused: &mut FusedSink,
    ) -> Result<(), super::RedundancyError>;
    fn finish(self: Box<Self>) -> Monitoring;
}

/// Both monitors for `units` units (3..=MAX_UNITS).
pub(super) fn monitors(units: usize, setup: &MonitorSetup) -> Box<dyn Monitors> {
    match units {
        3 => Box::new(RunMonitors::<3>::new(setup)),
        4 => Box::new(RunMonitors::<4>::new(setup)),
        5 => Box::new(RunMonitors::<5>::new(setup)),
        6 => Box::new(RunMonitors::<6>::new(setup)),
        7 => Box::new(RunMonitors::<7>::new(setup)),
        _ => Box::new(RunMonitors::<8>::new(setup)),
    }
}

/// The core's monitor configuration for one sensor: the units' clipping levels, less 1% for
/// the alignment's rotation, which mixes a little of the other axes into each; the
/// accelerometers' lengths compared to 10% (gravity at rest needs no alignment; MEMS
/// units a few percent apart in their length at rest are calibrated badly, not faulty).
fn config(setup: &MonitorSetup, sensor: usize) -> FaultConfig {
    let mut c = FaultConfig::new(setup.dt_s as f32);
    for (k, r) in setup.ranges.iter().enumerate().take(MAX_UNITS) {
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

/// Epochs between the times kept of stretches already passed.
const TIME_STRIDE: usize = 1024;

/// The time of any epoch of the run: exact within the current stretch, from every
/// [`TIME_STRIDE`]-th epoch's time before it (a fault found late in a long run was
/// suspected a few samples before, usually in the same stretch).
#[derive(Default)]
struct EpochTimes {
    strided: Vec<f64>,
    dt_s: f64,
}

impl EpochTimes {
    fn keep(&mut self, stretch: &MonitorStretch) {
        for (e, t) in (stretch.first_epoch..).zip(&stretch.t_s[stretch.own.clone()]) {
            if e.is_multiple_of(TIME_STRIDE) {
                self.strided.push(*t);
            }
        }
    }

    fn time_s(&self, epoch: usize, stretch: &MonitorStretch) -> f64 {
        if let Some(i) = epoch.checked_sub(stretch.first_epoch) {
            return stretch.t_s[stretch.own.start + i.min(stretch.own.len() - 1)];
        }
        let (s, within) = (epoch / TIME_STRIDE, epoch % TIME_STRIDE);
        match (self.strided.get(s), self.strided.get(s + 1)) {
            (Some(a), Some(b)) => a + (b - a) * within as f64 / TIME_STRIDE as f64,
            (Some(a), None) => a + within as f64 * self.dt_s,
            _ => stretch.t_s[stretch.own.start],
        }
    }
}

struct RunMonitors<const N: usize> {
    monitors: [FaultMonitor<N>; 2],
    lengths_only: bool,
    faults: Vec<FaultRecord>,
    open: [[Option<usize>; N]; 2],
    unfused: usize,
    /// Each unit's raw gyro and accelerometer at the run's last epoch, if present there.
    last_raw: [Option<[[f64; 3]; 2]>; N],
    times: EpochTimes,
}

impl<const N: usize> RunMonitors<N> {
    fn new(setup: &MonitorSetup) -> Self {
        Self {
            monitors: [0, 1].map(|sensor| FaultMonitor::<N>::new(config(setup, sensor))),
            lengths_only: setup.lengths_only,
            faults: Vec::new(),
            open: [[None; N]; 2],
            unfused: 0,
            last_raw: [None; N],
            times: EpochTimes {
                strided: Vec::new(),
                dt_s: setup.dt_s,
            },
        }
    }

    /// The units' samples of one sensor at grid index i.
    fn samples(&self, stretch: &MonitorStretch, sensor: usize, i: usize) -> [Option<[f32; 3]>; N] {
        std::array::from_fn(|k| {
            stretch.present[k][i].then(|| {
                let v: [f32; 3] =
                    std::array::from_fn(|a| stretch.signals[k][3 * sensor + a][i] as f32);
                if self.lengths_only {
                    [v.iter().map(|x| x * x).sum::<f32>().sqrt(), 0.0, 0.0]
                } else {
                    v
                }
            })
        })
    }

    /// Each unit's raw triads at grid index i, if present.
    fn raw(stretch: &MonitorStretch, i: usize) -> [Option<[[f64; 3]; 2]>; N] {
        std::array::from_fn(|k| {
            let r = &stretch.raw[k].1;
            let triad = |t: &Option<[Vec<f64>; 3]>| {
                t.as_ref()
                    .map_or([f64::NAN; 3], |t| [t[0][i], t[1][i], t[2][i]])
            };
            stretch.present[k][i].then(|| [triad(&r.gyro_rad_s), triad(&r.accel_m_s2)])
        })
    }

    /// One epoch: both monitors, the faults they confirm and readmit, the fused sample.
    fn epoch(&mut self, stretch: &MonitorStretch, i: usize) -> Option<[f64; 6]> {
        let t = stretch.t_s[i];
        let raw = Self::raw(stretch, i);
        let mut row = [0.0; 6];
        let mut any = false;
        for sensor in 0..2 {
            let samples = self.samples(stretch, sensor, i);
            let repeated: [[bool; 3]; N] =
                std::array::from_fn(|k| match (raw[k], self.last_raw[k]) {
                    (Some(now), Some(before)) => {
                        std::array::from_fn(|a| now[sensor][a] == before[sensor][a])
                    }
                    _ => [false; 3],
                });
            let step = self.monitors[sensor].push_marked(&samples, &repeated);
            for e in &step.confirmed {
                let mut e = *e;
                if self.lengths_only {
                    e.axis = None;
                }
                let at = |sample: u32| self.times.time_s(sample as usize, stretch);
                let record = record(&e, sensor, at);
                if let Some(k) = record.imu {
                    self.open[sensor][k] = Some(self.faults.len());
                }
                self.faults.push(record);
            }
            for (k, slot) in self.open[sensor].iter_mut().enumerate() {
                if step.readmitted >> k & 1 == 1 {
                    if let Some(f) = slot.take() {
                        self.faults[f].t_readmitted_s = Some(t);
                    }
                }
            }
            let fused = self.monitors[sensor].fused(&samples).or_else(|| {
                self.unfused += 1;
                plain_mean(&samples)
            });
            if let Some(f) = fused {
                row[3 * sensor..3 * sensor + 3].copy_from_slice(&f.map(f64::from));
                any = true;
            }
        }
        self.last_raw = raw;
        (any && !self.lengths_only).then_some(row)
    }
}

/// The plain mean of the units present, if any.
fn plain_mean<const N: usize>(samples: &[Option<[f32; 3]>; N]) -> Option<[f32; 3]> {
    let present: Vec<[f32; 3]> = samples.iter().flatten().copied().collect();
    (!present.is_empty()).then(|| {
        std::array::from_fn(|a| present.iter().map(|s| s[a]).sum::<f32>() / present.len() as f32)
    })
}

impl<const N: usize> Monitors for RunMonitors<N> {
    fn push(
        &mut self,
        stretch: &MonitorStretch,
        fused: &mut FusedSink,
    ) -> Result<(), super::RedundancyError> {
        for i in stretch.own.clone() {
            if let Some(row) = self.epoch(stretch, i) {
                fused(stretch.t_s[i], row)?;
            }
        }
        self.times.keep(stretch);
        Ok(())
    }

    fn finish(self: Box<Self>) -> Monitoring {
        Monitoring {
            faults: self.faults,
            unfused: self.unfused,
        }
    }
}

/// The JSON record of a core event of `sensor` (0 gyro, 1 accel), `at` the time of a sample.
fn record(
    e: &dynacal_core::redundancy::FaultEvent,
    sensor: usize,
    at: impl Fn(u32) -> f64,
) -> FaultRecord {
    const CHANNELS: [[&str; 3]; 2] = [["gx", "gy", "gz"], ["ax", "ay", "az"]];
    let channel = match e.axis {
        Some(a) => CHANNELS[sensor][a as usize].to_string(),
        None => ["gyro", "accel"][sensor].to_string(),
    };
    FaultRecord {
        imu: e.unit.map(usize::from),
        channel,
        kind: kind_name(e.kind).to_string(),
        t_detected_s: at(e.detected_sample),
        t_confirmed_s: at(e.confirmed_sample),
        t_readmitted_s: None,
    }
}
