//! Fault injection for the replay board: a plan of board faults, read from a short text, and
//! the wrappers that apply it to a [`SampleSource`] and a [`LogSink`], so the recorder and
//! the fusion meet, under emulation, the failures a real board meets: an IMU whose
//! data-ready line goes quiet, one that answers with a stuck or saturated output, one whose
//! samples come late, SPI reads that fail, the PPS lost for minutes, the receiver's bytes
//! corrupted or absent, and the log sink full. A hang (the main loop stuck in a transfer) is
//! in the plan too, but only a board can hang: [`FaultPlan::hang_at_s`] tells it when.
//!
//! The plan's text has one fault a line, a kind and `key=value` fields; `#` starts a
//! comment. Times are seconds from the source's first event; `unit` is the IMU's 0-based
//! place in the header:
//!
//! ```text
//! seed=7
//! imu-silent    unit=1 from=40  to=70
//! imu-stuck     unit=2 from=100 to=115
//! imu-saturated unit=0 from=130 to=132 gyro_rad_s=34.9 accel_m_s2=156.9
//! imu-late      unit=1 from=150 to=170 delay_us=7000
//! spi-errors    unit=2 from=190 to=220 rate=0.05
//! pps-lost      from=240 to=420
//! gnss-corrupt  from=250 to=280 rate=0.002
//! gnss-absent   from=300 to=360
//! log-full      from=380 to=383
//! hang          at=400
//! ```
//!
//! Random choices (which reads fail, which bytes flip) come from ChaCha8 seeded by `seed`
//! (default 1), so a plan always injects the same faults.

use core::fmt;
use core::sync::atomic::{AtomicU32, Ordering};

use rand_chacha::rand_core::{RngCore, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::log::{ImuConfig, ImuSampleSet, MAX_IMUS};
use crate::recorder::{Accepted, LogSink, SampleSource, SourceEvent};

/// Most faults a plan holds.
pub const MAX_FAULTS: usize = 16;
/// Longest plan text, bytes.
pub const MAX_PLAN_LEN: usize = 2048;
/// Longest delay of a late unit, microseconds: the injector holds its samples meanwhile.
pub const MAX_DELAY_US: u64 = 20_000;
/// Samples held back at once (a unit at up to 1 kHz delayed by [`MAX_DELAY_US`]).
const HELD: usize = 24;
/// Default saturation levels: the ICM-42688-P's largest ranges, 2000 deg/s and 16 g.
const DEFAULT_GYRO_RAIL_RAD_S: f64 = 2000.0 * core::f64::consts::PI / 180.0;
const DEFAULT_ACCEL_RAIL_M_S2: f64 = 16.0 * 9.80665;

/// What goes wrong.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum FaultAction {
    /// The unit's data-ready line goes quiet: no sample at all.
    ImuSilent { unit: u8 },
    /// The unit repeats its last sample from before the fault.
    ImuStuck { unit: u8 },
    /// Every channel of the unit reads its rail, with the sign of its reading when the fault began.
    ImuSaturated {
        unit: u8,
        gyro_rad_s: f64,
        accel_m_s2: f64,
    },
    /// The unit's samples are stamped `delay_us` late (a late data-ready, a lagging FIFO).
    ImuLate { unit: u8, delay_us: u64 },
    /// Each of the unit's reads fails with probability `rate`: the sample is lost and counted.
    SpiErrors { unit: u8, rate: f64 },
    /// No PPS edge.
    PpsLost,
    /// Each receiver byte is changed with probability `rate`.
    GnssCorrupt { rate: f64 },
    /// No receiver byte.
    GnssAbsent,
    /// The log sink takes nothing: every frame is dropped.
    LogFull,
    /// The main loop hangs (the board acts on it; see [`FaultPlan::hang_at_s`]).
    Hang,
}

impl FaultAction {
    /// The kind's name in a plan.
    pub fn name(&self) -> &'static str {
        match self {
            FaultAction::ImuSilent { .. } => "imu-silent",
            FaultAction::ImuStuck { .. } => "imu-stuck",
            FaultAction::ImuSaturated { .. } => "imu-saturated",
            FaultAction::ImuLate { .. } => "imu-late",
            FaultAction::SpiErrors { .. } => "spi-errors",
            FaultAction::PpsLost => "pps-lost",
            FaultAction::GnssCorrupt { .. } => "gnss-corrupt",
            FaultAction::GnssAbsent => "gnss-absent",
            FaultAction::LogFull => "log-full",
            FaultAction::Hang => "hang",
        }
    }

    /// The IMU it acts on, if one.
    pub fn unit(&self) -> Option<u8> {
        match *self {
            FaultAction::ImuSilent { unit }
            | FaultAction::ImuStuck { unit }
            | FaultAction::ImuSaturated { unit, .. }
            | FaultAction::ImuLate { unit, .. }
            | FaultAction::SpiErrors { unit, .. } => Some(unit),
            _ => None,
        }
    }
}

/// One planned fault, active from `from_us` up to `to_us` after the first event.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PlannedFault {
    pub action: FaultAction,
    pub from_us: u64,
    pub to_us: u64,
    /// The plan's line it came from (1-based).
    pub line: u16,
}

impl PlannedFault {
    fn active(&self, since_start_us: u64) -> bool {
        (self.from_us..self.to_us).contains(&since_start_us)
    }
}

/// A plan's faults.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct FaultPlan {
    pub faults: heapless::Vec<PlannedFault, MAX_FAULTS>,
    pub seed: u64,
}

/// Why a plan does not read.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum PlanError {
    TooLong,
    NotUtf8,
    TooManyFaults {
        line: u16,
    },
    UnknownKind {
        line: u16,
    },
    UnknownField {
        line: u16,
    },
    Missing {
        line: u16,
        field: &'static str,
    },
    BadValue {
        line: u16,
        field: &'static str,
    },
    Empty {
        line: u16,
    },
    /// A unit the header does not declare.
    NoSuchUnit {
        line: u16,
        unit: u8,
        units: usize,
    },
}

impl fmt::Display for PlanError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            PlanError::TooLong => write!(f, "longer than {MAX_PLAN_LEN} bytes"),
            PlanError::NotUtf8 => write!(f, "not UTF-8 text"),
            PlanError::TooManyFaults { line } => {
                write!(f, "line {line}: more than {MAX_FAULTS} faults")
            }
            PlanError::UnknownKind { line } => write!(
                f,
                "line {line}: unknown fault kind (imu-silent, imu-stuck, imu-saturated, imu-late, \
                 spi-errors, pps-lost, gnss-corrupt, gnss-absent, log-full, hang)"
            ),
            PlanError::UnknownField { line } => {
                write!(f, "line {line}: a field this kind does not take")
            }
            PlanError::Missing { line, field } => write!(f, "line {line}: `{field}` missing"),
            PlanError::BadValue { line, field } => {
                write!(
                    f,
                    "line {line}: field `{field}` is out of range or not a number"
                )
            }
            PlanError::Empty { line } => write!(f, "line {line}: `to` is not after `from`"),
            PlanError::NoSuchUnit { line, unit, units } => write!(
                f,
                "line {line}: unit {unit}, but the recording declares {units} IMU(s) (0-based)"
            ),
        }
    }
}

/// The fields of one plan line.
#[derive(Default)]
struct Fields {
    unit: Option<u8>,
    from_s: Option<f64>,
    to_s: Option<f64>,
    at_s: Option<f64>,
    rate: Option<f64>,
    delay_us: Option<f64>,
    gyro_rad_s: Option<f64>,
    accel_m_s2: Option<f64>,
}

impl FaultPlan {
    /// Reads a plan's text.
    pub fn parse(bytes: &[u8]) -> Result<Self, PlanError> {
        if bytes.len() > MAX_PLAN_LEN {
            return Err(PlanError::TooLong);
        }
        let text = core::str::from_utf8(bytes).map_err(|_| PlanError::NotUtf8)?;
        let mut plan = FaultPlan {
            faults: heapless::Vec::new(),
            seed: 1,
        };
        for (index, raw) in text.lines().enumerate() {
            let line = u16::try_from(index + 1).unwrap_or(u16::MAX);
            let content = raw.split('#').next().unwrap_or("").trim();
            let mut words = content.split_whitespace();
            let Some(kind) = words.next() else { continue };
            if let Some(seed) = kind.strip_prefix("seed=") {
                plan.seed = seed.parse().map_err(|_| PlanError::BadValue {
                    line,
                    field: "seed",
                })?;
                continue;
            }
            let fields = parse_fields(words, line)?;
            let fault = planned(kind, &fields, line)?;
            plan.faults
                .push(fault)
                .map_err(|_| PlanError::TooManyFaults { line })?;
        }
        Ok(plan)
    }

    /// Checks every unit the plan names against the `units` IMUs a recording declares.
    pub fn check_units(&self, units: usize) -> Result<(), PlanError> {
        for fault in &self.faults {
            if let Some(unit) = fault.action.unit() {
                if usize::from(unit) >= units {
                    return Err(PlanError::NoSuchUnit {
                        line: fault.line,
                        unit,
                        units,
                    });
                }
            }
        }
        Ok(())
    }

    /// Seconds from the first event at which the board's main loop is to hang, if planned.
    pub fn hang_at_s(&self) -> Option<f64> {
        self.faults
            .iter()
            .filter(|f| f.action == FaultAction::Hang)
            .map(|f| f.from_us as f64 * 1e-6)
            .reduce(f64::min)
    }

    /// Whether a fault of this kind's test is active at `since_start_us`.
    fn active(&self, since_start_us: u64, wanted: impl Fn(&FaultAction) -> bool) -> bool {
        self.faults
            .iter()
            .any(|f| wanted(&f.action) && f.active(since_start_us))
    }
}

fn parse_fields<'a>(words: impl Iterator<Item = &'a str>, line: u16) -> Result<Fields, PlanError> {
    let mut fields = Fields::default();
    for word in words {
        let (key, value) = word
            .split_once('=')
            .ok_or(PlanError::UnknownField { line })?;
        let number = |field: &'static str| -> Result<Option<f64>, PlanError> {
            match value.parse::<f64>() {
                Ok(v) if v.is_finite() && v >= 0.0 => Ok(Some(v)),
                _ => Err(PlanError::BadValue { line, field }),
            }
        };
        match key {
            "unit" => {
                fields.unit = Some(value.parse().map_err(|_| PlanError::BadValue {
                    line,
                    field: "unit",
                })?)
            }
            "from" => fields.from_s = number("from")?,
            "to" => fields.to_s = number("to")?,
            "at" => fields.at_s = number("at")?,
            "rate" => fields.rate = number("rate")?,
            "delay_us" => fields.delay_us = number("delay_us")?,
            "gyro_rad_s" => fields.gyro_rad_s = number("gyro_rad_s")?,
            "accel_m_s2" => fields.accel_m_s2 = number("accel_m_s2")?,
            _ => return Err(PlanError::UnknownField { line }),
        }
    }
    Ok(fields)
}

/// One line's fault from its kind and fields.
fn planned(kind: &str, f: &Fields, line: u16) -> Result<PlannedFault, PlanError> {
    let need =
        |value: Option<f64>, field: &'static str| value.ok_or(PlanError::Missing { line, field });
    let unit = || {
        f.unit.ok_or(PlanError::Missing {
            line,
            field: "unit",
        })
    };
    let probability = |field: &'static str| -> Result<f64, PlanError> {
        let rate = need(f.rate, field)?;
        if rate > 1.0 {
            return Err(PlanError::BadValue { line, field });
        }
        Ok(rate)
    };
    let action = match kind {
        "imu-silent" => FaultAction::ImuSilent { unit: unit()? },
        "imu-stuck" => FaultAction::ImuStuck { unit: unit()? },
        "imu-saturated" => FaultAction::ImuSaturated {
            unit: unit()?,
            gyro_rad_s: f.gyro_rad_s.unwrap_or(DEFAULT_GYRO_RAIL_RAD_S),
            accel_m_s2: f.accel_m_s2.unwrap_or(DEFAULT_ACCEL_RAIL_M_S2),
        },
        "imu-late" => {
            let delay = need(f.delay_us, "delay_us")?;
            if delay > MAX_DELAY_US as f64 {
                return Err(PlanError::BadValue {
                    line,
                    field: "delay_us",
                });
            }
            FaultAction::ImuLate {
                unit: unit()?,
                delay_us: delay as u64,
            }
        }
        "spi-errors" => FaultAction::SpiErrors {
            unit: unit()?,
            rate: probability("rate")?,
        },
        "pps-lost" => FaultAction::PpsLost,
        "gnss-corrupt" => FaultAction::GnssCorrupt {
            rate: probability("rate")?,
        },
        "gnss-absent" => FaultAction::GnssAbsent,
        "log-full" => FaultAction::LogFull,
        "hang" => {
            let at = need(f.at_s, "at")?;
            return Ok(PlannedFault {
                action: FaultAction::Hang,
                from_us: seconds_to_us(at),
                to_us: u64::MAX,
                line,
            });
        }
        _ => return Err(PlanError::UnknownKind { line }),
    };
    let (from_s, to_s) = (need(f.from_s, "from")?, need(f.to_s, "to")?);
    if to_s <= from_s {
        return Err(PlanError::Empty { line });
    }
    Ok(PlannedFault {
        action,
        from_us: seconds_to_us(from_s),
        to_us: seconds_to_us(to_s),
        line,
    })
}

fn seconds_to_us(seconds: f64) -> u64 {
    (seconds * 1e6 + 0.5) as u64
}

/// Microseconds since the first event, shared by the source and the sink wrappers (the
/// sink sees bytes, not times).
#[derive(Debug, Default)]
pub struct InjectionClock {
    ms: AtomicU32,
}

impl InjectionClock {
    pub const fn new() -> Self {
        Self {
            ms: AtomicU32::new(0),
        }
    }

    fn set(&self, since_start_us: u64) {
        let ms = u32::try_from(since_start_us / 1000).unwrap_or(u32::MAX);
        self.ms.store(ms, Ordering::Relaxed);
    }

    fn since_start_us(&self) -> u64 {
        u64::from(self.ms.load(Ordering::Relaxed)) * 1000
    }
}

/// A source with the plan's IMU, PPS and GNSS faults applied.
pub struct InjectingSource<'a, S> {
    inner: S,
    plan: FaultPlan,
    clock: &'a InjectionClock,
    /// Each header unit's imu_id and scale factors (rad/s and m/s^2 per count).
    units: heapless::Vec<(u8, f64, f64), MAX_IMUS>,
    t0_us: Option<u64>,
    /// The inner source's next event, faults applied, not yet handed on.
    next: Option<SourceEvent>,
    /// Late samples, held until their stamp comes.
    held: heapless::Vec<SourceEvent, HELD>,
    inner_ended: bool,
    /// Each unit's last sample before a stuck fault, as the unit keeps repeating it.
    last_counts: [Option<([i32; 3], [i32; 3])>; MAX_IMUS],
    /// Each saturated unit's rail signs (gyro x y z, accel x y z), from its reading when
    /// the fault began: a rail holds, whatever the noise does.
    rail_signs: [Option<[bool; 6]>; MAX_IMUS],
    reads_failed: u32,
    failed_since_asked: bool,
    rng: ChaCha8Rng,
}

impl<'a, S: SampleSource> InjectingSource<'a, S> {
    /// Applies `plan` to `inner`, whose IMUs are `imus` (the header's).
    pub fn new(inner: S, plan: FaultPlan, imus: &[ImuConfig], clock: &'a InjectionClock) -> Self {
        let rng = ChaCha8Rng::seed_from_u64(plan.seed);
        Self {
            inner,
            plan,
            clock,
            units: imus
                .iter()
                .map(|i| {
                    (
                        i.imu_id,
                        i.gyro_scale_rad_s_per_count,
                        i.accel_scale_m_s2_per_count,
                    )
                })
                .collect(),
            t0_us: None,
            next: None,
            held: heapless::Vec::new(),
            inner_ended: false,
            last_counts: [None; MAX_IMUS],
            rail_signs: [None; MAX_IMUS],
            reads_failed: 0,
            failed_since_asked: false,
            rng,
        }
    }

    /// The wrapped source.
    pub fn inner_mut(&mut self) -> &mut S {
        &mut self.inner
    }

    /// Samples the plan's SPI errors lost.
    pub fn reads_failed(&self) -> u32 {
        self.reads_failed
    }

    fn since_start(&mut self, t_us: u64) -> u64 {
        t_us.saturating_sub(*self.t0_us.get_or_insert(t_us))
    }

    /// Draws true with probability `rate`.
    fn chance(&mut self, rate: f64) -> bool {
        (self.rng.next_u32() as f64) < rate * 4_294_967_296.0
    }

    /// The inner source's next event with the faults applied, and whether the plan made it
    /// late; None when the source has ended.
    fn next_from_inner(&mut self) -> Result<Option<(SourceEvent, bool)>, S::Error> {
        loop {
            let Some(event) = self.inner.next_event()? else {
                return Ok(None);
            };
            let since = self.since_start(event.t_us());
            let faulty = match event {
                SourceEvent::Imu(sample) => self
                    .apply_imu(sample, since)
                    .map(|(s, late)| (SourceEvent::Imu(s), late)),
                other => self.apply(other, since).map(|e| (e, false)),
            };
            if faulty.is_some() {
                return Ok(faulty);
            }
        }
    }

    /// A PPS or GNSS event as the faulty board sees it, or None when it is lost.
    fn apply(&mut self, event: SourceEvent, since: u64) -> Option<SourceEvent> {
        match event {
            SourceEvent::Pps(_) if self.plan.active(since, |a| *a == FaultAction::PpsLost) => None,
            SourceEvent::Gnss(_) if self.plan.active(since, |a| *a == FaultAction::GnssAbsent) => {
                None
            }
            SourceEvent::Gnss(mut chunk) => {
                let rate = self.rate_of(since, None, |a| match *a {
                    FaultAction::GnssCorrupt { rate } => Some(rate),
                    _ => None,
                });
                if let Some(rate) = rate {
                    let len = usize::from(chunk.len).min(chunk.data.len());
                    for byte in &mut chunk.data[..len] {
                        if self.chance(rate) {
                            // A nonzero mask: the byte always changes.
                            *byte ^= (self.rng.next_u32() % 255 + 1) as u8;
                        }
                    }
                }
                Some(SourceEvent::Gnss(chunk))
            }
            other => Some(other),
        }
    }

    /// The largest parameter of the active faults that `pick` selects, for one unit (or
    /// none).
    fn rate_of(
        &self,
        since: u64,
        unit: Option<usize>,
        pick: impl Fn(&FaultAction) -> Option<f64>,
    ) -> Option<f64> {
        self.plan
            .faults
            .iter()
            .filter(|f| f.active(since) && f.action.unit().map(usize::from) == unit)
            .filter_map(|f| pick(&f.action))
            .reduce(f64::max)
    }

    /// The sample as the faulty unit gives it, and whether it is late; None when lost.
    fn apply_imu(&mut self, mut sample: ImuSampleSet, since: u64) -> Option<(ImuSampleSet, bool)> {
        let index = self.units.iter().position(|u| u.0 == sample.imu_id)?;
        let on = |a: &FaultAction| a.unit().map(usize::from) == Some(index);
        if self.plan.active(since, |a| {
            on(a) && matches!(a, FaultAction::ImuSilent { .. })
        }) {
            return None;
        }
        let spi = self.rate_of(since, Some(index), |a| match *a {
            FaultAction::SpiErrors { rate, .. } => Some(rate),
            _ => None,
        });
        if spi.is_some_and(|rate| self.chance(rate)) {
            self.reads_failed = self.reads_failed.saturating_add(1);
            self.failed_since_asked = true;
            return None;
        }
        if self.plan.active(since, |a| {
            on(a) && matches!(a, FaultAction::ImuStuck { .. })
        }) {
            if let Some((gyro, accel)) = self.last_counts[index] {
                sample.gyro_counts = gyro;
                sample.accel_counts = accel;
            }
        } else {
            self.last_counts[index] = Some((sample.gyro_counts, sample.accel_counts));
        }
        let rails = self.plan.faults.iter().find_map(|f| match f.action {
            FaultAction::ImuSaturated {
                gyro_rad_s,
                accel_m_s2,
                ..
            } if on(&f.action) && f.active(since) => Some((gyro_rad_s, accel_m_s2)),
            _ => None,
        });
        match rails {
            Some((gyro_rail, accel_rail)) => {
                let (_, gyro_scale, accel_scale) = self.units[index];
                let c = sample.gyro_counts.iter().chain(&sample.accel_counts);
                let mut signs = [false; 6];
                for (sign, &count) in signs.iter_mut().zip(c) {
                    *sign = count < 0;
                }
                let negative = *self.rail_signs[index].get_or_insert(signs);
                sample.gyro_counts =
                    core::array::from_fn(|a| rail(negative[a], gyro_rail, gyro_scale));
                sample.accel_counts =
                    core::array::from_fn(|a| rail(negative[3 + a], accel_rail, accel_scale));
            }
            None => self.rail_signs[index] = None,
        }
        let delay = self.rate_of(since, Some(index), |a| match *a {
            FaultAction::ImuLate { delay_us, .. } => Some(delay_us as f64),
            _ => None,
        });
        if let Some(delay) = delay {
            sample.t_us = sample.t_us.saturating_add(delay as u64);
        }
        Some((sample, delay.is_some()))
    }

    /// Index of the earliest held event.
    fn earliest_held(&self) -> Option<usize> {
        (0..self.held.len()).min_by_key(|&i| self.held[i].t_us())
    }
}

/// A count at the rail `rail_si` (in the channel's unit), negative or positive.
fn rail(negative: bool, rail_si: f64, scale: f64) -> i32 {
    let counts = if scale > 0.0 {
        (rail_si / scale).min(i32::MAX as f64) as i32
    } else {
        i32::MAX
    };
    if negative {
        -counts
    } else {
        counts
    }
}

impl<S: SampleSource> SampleSource for InjectingSource<'_, S> {
    type Error = S::Error;

    /// Events in time order: a late sample waits among the held ones until the stream
    /// reaches its stamp, as the board's capture queue would hand it on.
    fn next_event(&mut self) -> Result<Option<SourceEvent>, S::Error> {
        loop {
            if self.next.is_none() && !self.inner_ended {
                match self.next_from_inner()? {
                    Some((event, true)) if !self.held.is_full() => {
                        let _ = self.held.push(event);
                        continue;
                    }
                    Some((event, _)) => self.next = Some(event),
                    None => self.inner_ended = true,
                }
            }
            let held = self.earliest_held();
            let take_held = match (held, &self.next) {
                (Some(i), Some(next)) => self.held[i].t_us() <= next.t_us(),
                (Some(_), None) => true,
                (None, _) => false,
            };
            let event = if take_held {
                held.map(|i| self.held.swap_remove(i))
            } else {
                self.next.take()
            };
            let Some(event) = event else { return Ok(None) };
            let since = event.t_us().saturating_sub(self.t0_us.unwrap_or(0));
            self.clock.set(since);
            return Ok(Some(event));
        }
    }

    fn samples_overrun(&self) -> u32 {
        self.inner
            .samples_overrun()
            .saturating_add(self.reads_failed)
    }

    fn imu_fault(&mut self) -> bool {
        let inner = self.inner.imu_fault();
        core::mem::take(&mut self.failed_since_asked) || inner
    }

    fn imu_temperatures_deg_c(&mut self) -> [f32; MAX_IMUS] {
        self.inner.imu_temperatures_deg_c()
    }
}

/// A sink that takes nothing while the plan's `log-full` is active.
pub struct InjectingSink<'a, K> {
    inner: K,
    full: heapless::Vec<(u64, u64), MAX_FAULTS>,
    clock: &'a InjectionClock,
}

impl<'a, K: LogSink> InjectingSink<'a, K> {
    pub fn new(inner: K, plan: &FaultPlan, clock: &'a InjectionClock) -> Self {
        let full = plan
            .faults
            .iter()
            .filter(|f| f.action == FaultAction::LogFull)
            .map(|f| (f.from_us, f.to_us))
            .collect();
        Self { inner, full, clock }
    }

    /// The wrapped sink.
    pub fn inner_mut(&mut self) -> &mut K {
        &mut self.inner
    }
}

impl<K: LogSink> LogSink for InjectingSink<'_, K> {
    type Error = K::Error;

    fn write_frame(&mut self, frame: &[u8]) -> Result<Accepted, K::Error> {
        let now = self.clock.since_start_us();
        if self
            .full
            .iter()
            .any(|&(from, to)| (from..to).contains(&now))
        {
            return Ok(Accepted::Dropped);
        }
        self.inner.write_frame(frame)
    }

    fn flush(&mut self) -> Result<(), K::Error> {
        self.inner.flush()
    }
}

#[cfg(test)]
mod tests;
