//! Fault detection and isolation among N >= 3 units of one sensor type (gyros or
//! accelerometers), sampled together and brought into one frame, and the fused virtual
//! sensor of the healthy ones. Allocation-free: the board runs it on every sample set.
//!
//! Every pair (k, l) and axis keeps a slow mean of its difference (the units' relative
//! bias, which drifts) and a variance of what is left, so each new difference has a
//! z-score that needs no knowledge of the units' noise. A unit is suspected when **every**
//! pair it is in fails a test and no pair of healthy units without it does (a single fault
//! among three or more is isolated; with two units left it is only detected, but for a unit
//! at a rail, which is placed by its own samples). The tests:
//! - dropout (no sample), saturation (at the configured range) and stuck output (all three
//!   axes unchanged while the others move) from the unit's own samples;
//! - spike: one difference beyond `spike_sigma`;
//! - shift: an exponentially weighted mean of the z-score (about `fast_time_constant_s`)
//!   beyond `shift_sigma` times its own learned spread: a bias step, a scale change under
//!   motion, a time slip under vibration;
//! - noise burst: the unit's own white-noise level (products of first differences with two
//!   others, as [`super::LiveNoise`]) rising `burst_ratio` times above its slow level, more
//!   than every other unit's does (the dynamics raise all units' levels together, Fig. 8);
//! - norm (accelerometers): the length of the unit's vector, which needs no alignment, off
//!   the others' by more than `norm_tolerance` of it (a gross scale error).
//!
//! A suspected unit leaves the fused output at once; its kind is decided over the next
//! `confirm_s` by what explains its residual against the healthy units: a constant (bias
//! step), the signal (scale factor), the signal's rate of change (time slip), a few samples
//! (spike), or nothing (noise burst). It is readmitted after `clean_s` without a failed test
//! at half its threshold against at least half the healthy units (against the other units
//! out, when none is healthy); meanwhile its pairs' means keep learning, so a unit whose bias
//! stepped returns with its new bias. Why per-sample tests are not enough for a false-alarm
//! rate: 1e-5 per test at 100 Hz is 4 alarms an hour; the spike and shift thresholds are set for rates measured over
//! hours of fault-free data (BENCHMARKS.md).

// Float methods without std; with std the inherent ones are used instead.
#[allow(unused_imports)]
use nalgebra::ComplexField;

use super::MAX_UNITS;

/// What went wrong with a unit.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FaultKind {
    /// No sample from the unit.
    Dropout,
    /// A sample at the unit's range limit.
    Saturation,
    /// The unit's output stopped changing.
    Stuck,
    /// A few samples far from the others'.
    Spike,
    /// The unit's bias changed.
    BiasStep,
    /// The unit's residual follows the signal: its scale factor changed (or, by the norm
    /// test, differs from the others').
    ScaleFactor,
    /// The unit's noise rose alone.
    NoiseBurst,
    /// The unit's residual follows the signal's rate of change: its samples are late or early.
    TimeSlip,
}

/// A confirmed fault.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FaultEvent {
    /// The faulty unit; None when only two units were healthy: the pair disagrees, and which
    /// of them is wrong cannot be told.
    pub unit: Option<u8>,
    /// Axis of the triad that showed it most (0, 1, 2), where the kind has one.
    pub axis: Option<u8>,
    pub kind: FaultKind,
    /// Sample set at which the unit was first suspected (and left the fused output).
    pub detected_sample: u32,
    /// Sample set at which the kind was decided.
    pub confirmed_sample: u32,
}

/// Settings of the monitor. Times in seconds; thresholds in standard deviations.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FaultConfig {
    pub sample_interval_s: f32,
    /// Per-axis magnitude at which a unit saturates, sensor unit (INFINITY: not tested).
    pub range: [f32; MAX_UNITS],
    /// Relative difference of a unit's vector length from the others' median that is a
    /// fault (None: not tested; meant for accelerometers, whose length is gravity at rest).
    pub norm_tolerance: Option<f32>,
    pub spike_sigma: f32,
    pub shift_sigma: f32,
    /// Ratio of a pair's variance over the last second to its learned spread that is a noise
    /// burst (of the unit every failing pair shares).
    pub burst_ratio: f32,
    /// Time-slip statistic (a correlation, in its standard deviations) that is a slip.
    pub slip_sigma: f32,
    pub stuck_s: f32,
    /// Change of a unit's sample from the previous one, in its own learned spread of such
    /// changes, beyond which the unit jumped; when two or more and at least half of the
    /// healthy units jump together, the platform moved (a bump, a pothole) and no unit is suspected for
    /// `common_hold_s`: units at different places and in different axes see one jolt
    /// differently, which is no fault.
    pub common_sigma: f32,
    pub common_hold_s: f32,
    pub confirm_s: f32,
    pub clean_s: f32,
    /// Time constant of the pairs' relative-bias means.
    pub mean_time_constant_s: f32,
    /// Time constant of the pairs' spread (and of the units' slow noise levels).
    pub spread_time_constant_s: f32,
    /// Time constant of the shift test's mean and of the fast noise level.
    pub fast_time_constant_s: f32,
}

impl FaultConfig {
    /// Defaults for a sample interval: thresholds chosen on fault-free simulated drives and
    /// real recordings (rates in BENCHMARKS.md).
    pub fn new(sample_interval_s: f32) -> Self {
        Self {
            sample_interval_s,
            range: [f32::INFINITY; MAX_UNITS],
            norm_tolerance: None,
            spike_sigma: 9.0,
            shift_sigma: 7.0,
            burst_ratio: 9.0,
            slip_sigma: 8.0,
            stuck_s: 0.1,
            common_sigma: 4.0,
            common_hold_s: 1.0,
            confirm_s: 1.0,
            clean_s: 5.0,
            mean_time_constant_s: 10.0,
            spread_time_constant_s: 5.0,
            fast_time_constant_s: 0.25,
        }
    }

    fn samples(&self, seconds: f32) -> u32 {
        (seconds / self.sample_interval_s) as u32
    }

    /// The weight a sample set gets in a running mean of `time_constant_s`.
    pub fn alpha(&self, time_constant_s: f32) -> f32 {
        1.0 - (-self.sample_interval_s / time_constant_s).exp()
    }
}

/// What one pair's difference on one axis has learned.
#[derive(Debug, Clone, Copy, Default)]
struct PairAxis {
    /// Slow mean of z_k - z_l: the relative bias.
    mean: f32,
    /// Variance of z_k - z_l about its mean.
    spread: f32,
    /// Fast mean of the z-score.
    shift: f32,
    /// Learned variance of `shift`.
    shift_spread: f32,
    /// Fast mean square of the difference about its mean: its variance over the last second.
    fast_spread: f32,
    /// Fast means of the difference about its mean times the pair's signal change per
    /// sample, and of that change squared: their correlation is a time slip's signature.
    slip_cross: f32,
    slip_signal: f32,
    /// Learned variance of that correlation (the series are coloured: a vibration line
    /// makes a second's correlation vary far more than white noise would).
    slip_spread: f32,
}

impl PairAxis {
    /// Correlation of the difference about its mean with the signal change, last second.
    fn slip_correlation(&self) -> f32 {
        self.slip_cross
            / (self.fast_spread * self.slip_signal)
                .max(f32::MIN_POSITIVE)
                .sqrt()
    }
}

/// Which test suspected a unit.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Trigger {
    Spike,
    Shift,
    Burst,
    Slip,
    Norm,
}

/// Evidence gathered over a suspected unit's confirmation window, per axis: the sums of the
/// least squares of its residual r against the healthy units on a constant, the signal x
/// (from its value at the window's start, for conditioning) and the signal's change per
/// sample v.
#[derive(Debug, Clone, Copy, Default)]
struct Episode {
    start: Option<[f32; 3]>,
    /// Per axis: the normal matrix of (1, x, v) and the products with r, and sum of r^2.
    normal: [[[f32; 3]; 3]; 3],
    cross: [[f32; 3]; 3],
    rr: [f32; 3],
    count: u32,
    /// Samples whose largest z-score was beyond the spike threshold.
    excursions: u32,
    /// Sums of the squared residual (over the axes) if the unit were d + 1 samples late
    /// ([0]) or early ([1]), and as it is, over the samples where every lag could be tried.
    lagged: [[f32; 2]; SLIP_LAGS],
    unlagged: f32,
}

/// How many spike thresholds from every other unit a held value is a rail (see
/// [`FaultMonitor::at_rail`]).
const RAIL_SPIKES: f32 = 10.0;

/// Most samples a unit's time slip is sought over, each way.
const SLIP_LAGS: usize = 8;

impl Episode {
    fn add(&mut self, r: [f32; 3], x: [f32; 3], v: [f32; 3]) {
        let start = *self.start.get_or_insert(x);
        for a in 0..3 {
            let g = [1.0, x[a] - start[a], v[a]];
            for i in 0..3 {
                for j in 0..3 {
                    self.normal[a][i][j] += g[i] * g[j];
                }
                self.cross[a][i] += g[i] * r[a];
            }
            self.rr[a] += r[a] * r[a];
        }
        self.count += 1;
    }
}

/// One unit's state.
#[derive(Debug, Clone, Copy)]
struct Unit {
    healthy: bool,
    /// Sample the current fault was detected at, and what triggered it (None: confirmed).
    suspected: Option<(u32, Trigger)>,
    episode: Episode,
    clean_run: u32,
    stuck_run: u32,
    /// Per raw axis: samples the axis has held one value while the others moved, and
    /// whether it came to that value far from every other unit (a jump to a rail).
    pinned_run: [u32; 3],
    pinned_far: [bool; 3],
    /// A direct fault (dropout, saturation, stuck) showed at the last sample set.
    direct: bool,
    /// Own white-noise variance of first differences (2 s^2), slow.
    noise_slow: f32,
    /// Fast mean of the vector's length.
    norm: f32,
    /// Slow mean square of the change from one sample to the next, per axis: the unit's
    /// motion and noise together.
    step_spread: f32,
    /// While the unit is out, its pairs' spreads are not learned; the healthy units' mean
    /// pair spread when it left scales them as the dynamics change (a copter taking off
    /// raises every spread tenfold).
    spread_at_exclusion: Option<f32>,
    /// Slow mean of the unit's sample less the fused output: its bias relative to the fused
    /// output, learned against it so that the healthy units' weighted offsets keep their sum
    /// (a unit whose bias steps moves neither the others' offsets nor the fused output).
    offset: [f32; 3],
}

impl Default for Unit {
    fn default() -> Self {
        Self {
            healthy: true,
            suspected: None,
            episode: Episode::default(),
            clean_run: 0,
            stuck_run: 0,
            pinned_run: [0; 3],
            pinned_far: [false; 3],
            direct: false,
            noise_slow: 0.0,
            norm: 0.0,
            step_spread: 0.0,
            spread_at_exclusion: None,
            offset: [0.0; 3],
        }
    }
}

/// What one sample set changed.
#[derive(Debug, Clone, Default)]
pub struct Step {
    /// Faults whose kind was decided at this sample set.
    pub confirmed: heapless::Vec<FaultEvent, MAX_UNITS>,
    /// Bit k set: unit k was readmitted at this sample set.
    pub readmitted: u32,
}

/// The monitor of N units of one sensor type.
#[derive(Debug, Clone)]
pub struct FaultMonitor<const N: usize> {
    config: FaultConfig,
    pairs: [[[PairAxis; 3]; N]; N],
    units: [Unit; N],
    /// Previous sample set (for first differences and the signal's rate of change).
    previous: [Option<[f32; 3]>; N],
    /// Sample sets pushed before the current one (its index while it is handled).
    sample: u32,
    /// When only two units are healthy, the last sample an unisolated alarm was raised at.
    last_unisolated: Option<u32>,
    /// The last SLIP_LAGS sample sets, `history[(cursor + SLIP_LAGS - d) % SLIP_LAGS]`
    /// d + 1 sets ago.
    history: [[Option<[f32; 3]>; N]; SLIP_LAGS],
    cursor: usize,
    /// No unit is suspected before this sample: the platform jolted.
    hold_until: u32,
}

/// Pair statistics of one sample set: the z-score of every pair's difference per axis.
type Scores<const N: usize> = [[[f32; 3]; N]; N];

impl<const N: usize> FaultMonitor<N> {
    pub fn new(config: FaultConfig) -> Self {
        assert!((3..=MAX_UNITS).contains(&N), "3 to MAX_UNITS units");
        Self {
            config,
            pairs: [[[PairAxis::default(); 3]; N]; N],
            units: [Unit::default(); N],
            previous: [None; N],
            sample: 0,
            last_unisolated: None,
            history: [[None; N]; SLIP_LAGS],
            cursor: 0,
            hold_until: 0,
        }
    }

    /// Whether unit k is in the fused output.
    pub fn healthy(&self, unit: usize) -> bool {
        self.units[unit].healthy
    }

    /// Unit k's own white-noise variance per sample, sensor unit squared (slow level).
    pub fn noise_variance(&self, unit: usize) -> f32 {
        self.units[unit].noise_slow / 2.0
    }

    /// Unit k's bias relative to the fused output, per axis, sensor unit.
    pub fn offset(&self, unit: usize) -> [f32; 3] {
        self.units[unit].offset
    }

    fn pair_mean(&self, k: usize, l: usize, a: usize) -> f32 {
        match k.cmp(&l) {
            core::cmp::Ordering::Less => self.pairs[k][l][a].mean,
            core::cmp::Ordering::Greater => -self.pairs[l][k][a].mean,
            core::cmp::Ordering::Equal => 0.0,
        }
    }

    /// One set of samples (None: the unit's sample did not arrive), in the common frame.
    pub fn push(&mut self, samples: &[Option<[f32; 3]>; N]) -> Step {
        let repeated = core::array::from_fn(|k| match (samples[k], self.previous[k]) {
            (Some(now), Some(before)) => core::array::from_fn(|a| now[a] == before[a]),
            _ => [false; 3],
        });
        self.push_marked(samples, &repeated)
    }

    /// As [`Self::push`], where the samples were transformed (a lever-arm correction moves
    /// with the motion) and `repeated[k][a]` says whether axis a of unit k's raw output
    /// equals its previous raw output: a stuck or clipped unit is seen in what it put out,
    /// not in what was made of it.
    pub fn push_marked(
        &mut self,
        samples: &[Option<[f32; 3]>; N],
        repeated: &[[bool; 3]; N],
    ) -> Step {
        let mut step = Step::default();
        let sample = self.sample;
        let present: [bool; N] = core::array::from_fn(|k| samples[k].is_some());
        let scores = self.scores(samples);
        let mut direct: [Option<(FaultKind, Option<u8>)>; N] = [None; N];
        let mut rail = [false; N];
        for (k, s) in samples.iter().enumerate() {
            let far = self.far_from_all(k, &scores, &present);
            direct[k] = self.direct_fault(k, s, repeated, &present, far);
            rail[k] = self.at_rail(k, &scores, &present, &repeated[k]);
        }
        let triggers = self.screened_triggers(samples, &scores, &present, &rail);
        for k in 0..N {
            if let Some((kind, axis)) = direct[k] {
                self.confirm_now(k, kind, axis, sample, &mut step);
            } else if let Some(trigger) = triggers[k] {
                if self.units[k].healthy {
                    self.units[k].spread_at_exclusion = Some(self.healthy_spread(k));
                    self.units[k].healthy = false;
                    self.units[k].suspected = Some((sample, trigger));
                    self.units[k].episode = Episode::default();
                }
                self.units[k].clean_run = 0;
            }
        }
        self.unisolated_alarm(&scores, &present, sample, &mut step);
        self.gather_evidence(samples, &scores, &mut step, sample);
        self.readmit(&scores, &present, &direct, &mut step);
        let direct_now: [bool; N] = core::array::from_fn(|k| direct[k].is_some());
        for (unit, &now) in self.units.iter_mut().zip(&direct_now) {
            unit.direct = now;
        }
        self.learn(samples, &scores, &direct_now);
        self.previous = *samples;
        self.history[self.cursor] = *samples;
        self.cursor = (self.cursor + 1) % SLIP_LAGS;
        self.sample += 1;
        step
    }

    /// Dropout, saturation or stuck output of unit k, from its own samples; `repeated[l][a]`:
    /// axis a of unit l's output equals its previous one; `far`: unit k's sample is beyond
    /// the spike threshold from every healthy unit's.
    ///
    /// Saturation needs no range: a clipped axis jumps to its rail, far from the others,
    /// and holds it exactly while they move; a frozen unit holds its last value, which
    /// agreed with theirs, on all three axes (stuck).
    fn direct_fault(
        &mut self,
        k: usize,
        sample: &Option<[f32; 3]>,
        repeated: &[[bool; 3]; N],
        present: &[bool; N],
        far: bool,
    ) -> Option<(FaultKind, Option<u8>)> {
        let Some(s) = sample else {
            return Some((FaultKind::Dropout, None));
        };
        if let Some(a) = (0..3).find(|&a| s[a].abs() >= self.config.range[k]) {
            return Some((FaultKind::Saturation, Some(a as u8)));
        }
        let unchanged = |l: usize| repeated[l].iter().all(|&r| r);
        let others_moved =
            (0..N).any(|l| l != k && self.units[l].healthy && present[l] && !unchanged(l));
        let held = self.config.samples(self.config.stuck_s).max(4);
        let unit = &mut self.units[k];
        let pins = unit.pinned_run.iter_mut().zip(&mut unit.pinned_far);
        for ((run, pinned_far), &same) in pins.zip(&repeated[k]) {
            if !same {
                *run = 0;
                *pinned_far = far;
            } else if others_moved {
                *run += 1;
            }
        }
        if let Some(a) = (0..3).find(|&a| unit.pinned_run[a] >= held && unit.pinned_far[a]) {
            return Some((FaultKind::Saturation, Some(a as u8)));
        }
        if !unchanged(k) {
            unit.stuck_run = 0;
        } else if others_moved {
            unit.stuck_run += 1;
        }
        (unit.stuck_run >= held).then_some((FaultKind::Stuck, None))
    }

    /// Whether unit k's sample fails the spike test against every other healthy unit
    /// present (and there is one).
    fn far_from_all(&self, k: usize, z: &Scores<N>, present: &[bool; N]) -> bool {
        let mut others = (0..N).filter(|&l| l != k && present[l] && self.units[l].healthy);
        let limit = self.config.spike_sigma;
        others.clone().next().is_some() && others.all(|l| z[k][l].iter().any(|s| s.abs() > limit))
    }

    /// Whether an axis of unit k holds a value it came to far from every other healthy unit
    /// (it repeated its previous raw value) and is still beyond [`RAIL_SPIKES`] spike
    /// thresholds from each of them: a rail. A quantized unit that stays put while a knock
    /// moves the others holds a value it came to in agreement, which is no rail; a static
    /// unit's glitch that repeats a sample is tens of spreads off, a range's rail thousands.
    fn at_rail(&self, k: usize, z: &Scores<N>, present: &[bool; N], repeated: &[bool; 3]) -> bool {
        let others = (0..N).filter(|&l| l != k && present[l] && self.units[l].healthy);
        let limit = RAIL_SPIKES * self.config.spike_sigma;
        let pinned_far = &self.units[k].pinned_far;
        others.clone().next().is_some()
            && (0..3).any(|a| {
                repeated[a] && pinned_far[a] && others.clone().all(|l| z[k][l][a].abs() > limit)
            })
    }

    /// Which units' samples jumped from their previous ones (see `common_sigma`).
    fn jumps(&self, samples: &[Option<[f32; 3]>; N]) -> [bool; N] {
        core::array::from_fn(|k| match (samples[k], self.previous[k]) {
            (Some(now), Some(before)) if self.units[k].step_spread > 0.0 => {
                let limit = self.config.common_sigma * self.units[k].step_spread.sqrt();
                (0..3).any(|a| (now[a] - before[a]).abs() > limit)
            }
            _ => false,
        })
    }

    /// The statistical tests' suspects, screened for a jolt of the platform, and units at a
    /// rail (`rail[k]`, [`Self::at_rail`]).
    ///
    /// A jolt (two or more and at least half of the healthy units jumping together) holds
    /// the tests for `common_hold_s`, but not for a unit at a rail, which is suspected
    /// whatever the others do: a jolted unit moves, a rail holds. So is one at a rail when
    /// only two healthy units are left, whose disagreement alone cannot say which is wrong.
    /// Without this, a gross fault's samples reach the fused output until a direct test
    /// confirms it (a rail held for `stuck_s`, 0.1 s: a 16 g rail among three units is
    /// 5 m/s of velocity); now only its first sample does. A unit that merely jumped while
    /// the others did not is not blamed: in a copter's vibration, or a knock on a static
    /// rig, one unit's samples jump alone far more often than units fail.
    fn screened_triggers(
        &mut self,
        samples: &[Option<[f32; 3]>; N],
        z: &Scores<N>,
        present: &[bool; N],
        rail: &[bool; N],
    ) -> [Option<Trigger>; N] {
        let sample = self.sample;
        let jumped = self.jumps(samples);
        let mut triggers = self.statistical_triggers(z, present, samples);
        let in_use = (0..N).filter(|&k| self.units[k].healthy && present[k]);
        let with = in_use.clone().filter(|&k| jumped[k]).count();
        if with >= 2 && 2 * with >= in_use.count() {
            self.hold_until = sample + self.config.samples(self.config.common_hold_s);
        }
        let held = sample < self.hold_until;
        for (trigger, &rail) in triggers.iter_mut().zip(rail) {
            if rail {
                *trigger = Some(Trigger::Spike);
            } else if held {
                *trigger = None;
            }
        }
        triggers
    }

    /// The mean spread over the pairs and axes of healthy units other than `excluding`.
    fn healthy_spread(&self, excluding: usize) -> f32 {
        let usable = |i: usize| i != excluding && self.units[i].healthy;
        let (mut spread, mut pairs) = (0.0, 0);
        for k in (0..N).filter(|&k| usable(k)) {
            for l in (k + 1..N).filter(|&l| usable(l)) {
                spread += self.pairs[k][l].iter().map(|p| p.spread).sum::<f32>() / 3.0;
                pairs += 1;
            }
        }
        spread / pairs.max(1) as f32
    }

    /// For a unit that is out, how much the healthy units' pair spread has changed since it
    /// left (1 for a healthy unit, or where nothing was learned).
    fn dynamics_factor(&self, k: usize) -> f32 {
        let unit = &self.units[k];
        match unit.spread_at_exclusion {
            Some(then) if !unit.healthy && then > 0.0 => {
                let now = self.healthy_spread(k);
                if now > 0.0 {
                    now / then
                } else {
                    1.0
                }
            }
            _ => 1.0,
        }
    }

    /// Spread of pair (k, l) for its tests: learned, scaled by the dynamics' change for a
    /// unit that is out.
    fn test_spread(&self, k: usize, l: usize, axis: usize) -> f32 {
        let (i, j) = if k < l { (k, l) } else { (l, k) };
        let factor = self.dynamics_factor(i).max(self.dynamics_factor(j));
        self.pairs[i][j][axis].spread * factor
    }

    /// z-score of every present pair's difference on every axis against what the pair learned.
    fn scores(&self, samples: &[Option<[f32; 3]>; N]) -> Scores<N> {
        let mut z = [[[0.0; 3]; N]; N];
        if self.sample
            < self
                .config
                .samples(self.config.spread_time_constant_s)
                .max(8)
        {
            return z;
        }
        for k in 0..N {
            for l in k + 1..N {
                let (Some(a), Some(b)) = (samples[k], samples[l]) else {
                    continue;
                };
                for axis in 0..3 {
                    let p = &self.pairs[k][l][axis];
                    let spread = self.test_spread(k, l, axis);
                    let s = (a[axis] - b[axis] - p.mean) / spread.max(f32::MIN_POSITIVE).sqrt();
                    z[k][l][axis] = s;
                    z[l][k][axis] = -s;
                }
            }
        }
        z
    }
}

/// Largest |value| over a triad.
fn largest(v: &[f32; 3]) -> f32 {
    v.iter().fold(0.0f32, |m, x| m.max(x.abs()))
}

impl<const N: usize> FaultMonitor<N> {
    /// The statistical test that suspects each unit, where one does: a test isolates unit k
    /// when every pair of k with a present healthy unit fails it and no pair of two present
    /// healthy units without k fails half of it.
    fn statistical_triggers(
        &self,
        z: &Scores<N>,
        present: &[bool; N],
        samples: &[Option<[f32; 3]>; N],
    ) -> [Option<Trigger>; N] {
        let spike = |k: usize, l: usize| largest(&z[k][l]);
        let shift = |k: usize, l: usize| self.shift_score(k, l, z);
        let mut out = [None; N];
        for (k, o) in out.iter_mut().enumerate() {
            if !present[k] {
                continue;
            }
            let isolates = |score: &dyn Fn(usize, usize) -> f32, threshold: f32| {
                self.isolated(k, present, score, threshold)
            };
            *o = if isolates(&spike, self.config.spike_sigma) {
                Some(Trigger::Spike)
            } else if isolates(&shift, self.config.shift_sigma) {
                Some(Trigger::Shift)
            } else if self.sample >= self.config.samples(self.config.spread_time_constant_s)
                && isolates(&|a, b| self.burst_score(a, b), self.config.burst_ratio)
            {
                Some(Trigger::Burst)
            } else if isolates(&|a, b| self.slip_score(a, b), self.config.slip_sigma) {
                Some(Trigger::Slip)
            } else if self.norm_off(k, samples) {
                Some(Trigger::Norm)
            } else {
                None
            };
        }
        out
    }

    /// The shift test's statistic of pair (k, l) after this sample: the updated fast mean of
    /// the z-score over its learned spread, largest over the axes.
    fn shift_score(&self, k: usize, l: usize, z: &Scores<N>) -> f32 {
        self.shift_score_above(k, l, z, &[0.0; 3])
    }

    /// As [`Self::shift_score`], the learned spread per axis no lower than `least`.
    fn shift_score_above(&self, k: usize, l: usize, z: &Scores<N>, least: &[f32; 3]) -> f32 {
        let (i, j) = if k < l { (k, l) } else { (l, k) };
        let alpha = self.config.alpha(self.config.fast_time_constant_s);
        let floor = alpha / (2.0 - alpha);
        (0..3)
            .map(|a| {
                let p = &self.pairs[i][j][a];
                let shift = p.shift + alpha * (z[i][j][a] - p.shift);
                shift.abs() / p.shift_spread.max(floor).max(least[a]).sqrt()
            })
            .fold(0.0, f32::max)
    }

    /// Whether unit k alone fails `score` against `threshold` among the present healthy units.
    fn isolated(
        &self,
        k: usize,
        present: &[bool; N],
        score: impl Fn(usize, usize) -> f32,
        threshold: f32,
    ) -> bool {
        let usable = |l: usize| present[l] && self.units[l].healthy;
        let others: heapless::Vec<usize, MAX_UNITS> =
            (0..N).filter(|&l| l != k && usable(l)).collect();
        if others.len() < 2 {
            return false;
        }
        let all_fail = others.iter().all(|&l| score(k, l) >= threshold);
        let clean_elsewhere = others.iter().all(|&l| {
            others
                .iter()
                .filter(|&&m| m > l)
                .all(|&m| score(l, m) < threshold / 2.0)
        });
        all_fail && clean_elsewhere
    }

    /// The time-slip statistic of pair (k, l): the correlation over the last second of its
    /// difference (about its mean) with the pair's signal change per sample, over the
    /// correlation's learned spread, largest over the axes. A unit whose samples are d late
    /// reads x(t - d) - x(t), about -d times the change: correlated near 1.
    fn slip_score(&self, k: usize, l: usize) -> f32 {
        self.slip_score_above(k, l, &[0.0; 3])
    }

    /// As [`Self::slip_score`], the learned spread per axis no lower than `least`.
    fn slip_score_above(&self, k: usize, l: usize, least: &[f32; 3]) -> f32 {
        if self.sample < self.config.samples(self.config.spread_time_constant_s) {
            return 0.0;
        }
        let (i, j) = if k < l { (k, l) } else { (l, k) };
        let floor = self.slip_floor();
        (0..3)
            .map(|a| {
                let p = &self.pairs[i][j][a];
                p.slip_correlation().abs() / p.slip_spread.max(floor).max(least[a]).sqrt()
            })
            .fold(0.0, f32::max)
    }

    /// Variance of a second's correlation of two independent white series.
    fn slip_floor(&self) -> f32 {
        let alpha = self.config.alpha(4.0 * self.config.fast_time_constant_s);
        alpha / (2.0 - alpha)
    }

    /// The noise-burst statistic of pair (k, l): the variance of its difference over the
    /// last second against its test spread, largest over the axes.
    fn burst_score(&self, k: usize, l: usize) -> f32 {
        let (i, j) = if k < l { (k, l) } else { (l, k) };
        (0..3)
            .map(|a| {
                let spread = self.test_spread(i, j, a).max(f32::MIN_POSITIVE);
                self.pairs[i][j][a].fast_spread / spread
            })
            .fold(0.0, f32::max)
    }

    /// Whether unit k's vector length is off the median of the healthy others' by more than
    /// the norm tolerance.
    fn norm_off(&self, k: usize, samples: &[Option<[f32; 3]>; N]) -> bool {
        let Some(tolerance) = self.config.norm_tolerance else {
            return false;
        };
        if self.sample < self.config.samples(1.0).max(8) || samples[k].is_none() {
            return false;
        }
        let mut others: heapless::Vec<f32, MAX_UNITS> = (0..N)
            .filter(|&l| l != k && self.units[l].healthy && samples[l].is_some())
            .map(|l| self.units[l].norm)
            .collect();
        if others.len() < 2 {
            return false;
        }
        super::sort_few(&mut others, |a, b| a.total_cmp(b).is_lt());
        let mid = others.len() / 2;
        let median = if others.len().is_multiple_of(2) {
            (others[mid - 1] + others[mid]) / 2.0
        } else {
            others[mid]
        };
        (self.units[k].norm - median).abs() > tolerance * median
    }
}

impl<const N: usize> FaultMonitor<N> {
    /// A fault seen in the unit's own samples: confirmed at once, reported when the unit was
    /// healthy or only suspected.
    fn confirm_now(
        &mut self,
        k: usize,
        kind: FaultKind,
        axis: Option<u8>,
        sample: u32,
        step: &mut Step,
    ) {
        if self.units[k].healthy {
            self.units[k].spread_at_exclusion = Some(self.healthy_spread(k));
        }
        let unit = &mut self.units[k];
        unit.clean_run = 0;
        let detected_sample = match unit.suspected {
            Some((detected, _)) => detected,
            None if unit.healthy => sample,
            None => return,
        };
        unit.healthy = false;
        unit.suspected = None;
        let _ = step.confirmed.push(FaultEvent {
            unit: Some(k as u8),
            axis,
            kind,
            detected_sample,
            confirmed_sample: sample,
        });
    }

    /// With only two healthy units present, a failed spike or shift test is reported without
    /// a unit (once per clean period): which of the two is wrong cannot be told.
    fn unisolated_alarm(
        &mut self,
        z: &Scores<N>,
        present: &[bool; N],
        sample: u32,
        step: &mut Step,
    ) {
        let mut healthy = (0..N).filter(|&k| present[k] && self.units[k].healthy);
        let (Some(k), Some(l), None) = (healthy.next(), healthy.next(), healthy.next()) else {
            return;
        };
        let kind = if largest(&z[k][l]) >= self.config.spike_sigma {
            FaultKind::Spike
        } else if self.shift_score(k, l, z) >= self.config.shift_sigma {
            FaultKind::BiasStep
        } else {
            return;
        };
        let quiet = self.config.samples(self.config.clean_s);
        if self
            .last_unisolated
            .is_some_and(|last| sample - last < quiet)
        {
            return;
        }
        self.last_unisolated = Some(sample);
        let _ = step.confirmed.push(FaultEvent {
            unit: None,
            axis: None,
            kind,
            detected_sample: sample,
            confirmed_sample: sample,
        });
    }

    /// The healthy present units other than k: their mean signal per axis, and unit k's bias
    /// relative to them.
    fn reference(&self, k: usize, samples: &[Option<[f32; 3]>; N]) -> Option<([f32; 3], [f32; 3])> {
        let others: heapless::Vec<usize, MAX_UNITS> = (0..N)
            .filter(|&l| l != k && self.units[l].healthy && samples[l].is_some())
            .collect();
        if others.is_empty() {
            return None;
        }
        let n = others.len() as f32;
        let signal = core::array::from_fn(|a| {
            others
                .iter()
                .map(|&l| samples[l].map_or(0.0, |s| s[a]))
                .sum::<f32>()
                / n
        });
        let bias = core::array::from_fn(|a| {
            others.iter().map(|&l| self.pair_mean(k, l, a)).sum::<f32>() / n
        });
        Some((signal, bias))
    }

    /// Adds this sample set to every suspected unit's evidence, and decides the kind of those
    /// whose confirmation window is full.
    fn gather_evidence(
        &mut self,
        samples: &[Option<[f32; 3]>; N],
        z: &Scores<N>,
        step: &mut Step,
        sample: u32,
    ) {
        let window = self.config.samples(self.config.confirm_s).max(1);
        for k in 0..N {
            let Some((detected, trigger)) = self.units[k].suspected else {
                continue;
            };
            let (Some(s), Some((x, bias))) = (samples[k], self.reference(k, samples)) else {
                continue;
            };
            let before = self
                .reference(k, &self.previous)
                .map(|(x, _)| x)
                .unwrap_or(x);
            let excursion = (0..N)
                .filter(|&l| l != k && self.units[l].healthy)
                .any(|l| largest(&z[k][l]) >= self.config.spike_sigma);
            let e = &mut self.units[k].episode;
            e.add(
                core::array::from_fn(|a| s[a] - x[a] - bias[a]),
                x,
                core::array::from_fn(|a| x[a] - before[a]),
            );
            e.excursions += excursion as u32;
            self.add_lagged(k, s, x, bias);
            let e = &mut self.units[k].episode;
            if e.count >= window {
                let (kind, axis) = classify(e, trigger);
                self.units[k].suspected = None;
                let _ = step.confirmed.push(FaultEvent {
                    unit: Some(k as u8),
                    axis,
                    kind,
                    detected_sample: detected,
                    confirmed_sample: sample,
                });
            }
        }
    }

    /// Adds to unit k's episode its residual as it is and as if it were late or early by 1
    /// to SLIP_LAGS samples against the same healthy units (`x` their mean now, `bias` unit
    /// k's relative to them), where every lag can be tried.
    fn add_lagged(&mut self, k: usize, now: [f32; 3], x: [f32; 3], bias: [f32; 3]) {
        let others: heapless::Vec<usize, MAX_UNITS> = (0..N)
            .filter(|&l| l != k && self.units[l].healthy)
            .collect();
        let mut lagged = [[0.0f32; 2]; SLIP_LAGS];
        for (d, slot) in lagged.iter_mut().enumerate() {
            let past = &self.history[(self.cursor + SLIP_LAGS - 1 - d) % SLIP_LAGS];
            let (Some(unit_then), true) = (past[k], others.iter().all(|&l| past[l].is_some()))
            else {
                return;
            };
            let n = others.len() as f32;
            let x_then: [f32; 3] = core::array::from_fn(|a| {
                others
                    .iter()
                    .map(|&l| past[l].map_or(0.0, |p| p[a]))
                    .sum::<f32>()
                    / n
            });
            for a in 0..3 {
                let (lagged_unit, lagged_set) =
                    (now[a] - x_then[a] - bias[a], unit_then[a] - x[a] - bias[a]);
                slot[0] += lagged_unit * lagged_unit;
                slot[1] += lagged_set * lagged_set;
            }
        }
        let e = &mut self.units[k].episode;
        for (sum, add) in e.lagged.iter_mut().zip(lagged) {
            sum[0] += add[0];
            sum[1] += add[1];
        }
        e.unlagged += (0..3)
            .map(|a| {
                let d = now[a] - x[a] - bias[a];
                d * d
            })
            .sum::<f32>();
    }

    /// Readmits confirmed faulty units after a clean period: present, no direct fault, and
    /// its pairs with at least half the healthy units within half of every test's threshold.
    /// With no healthy unit present (overlapping faults), the units out are judged against
    /// each other instead, and those that agree come back together: otherwise none could
    /// ever return.
    fn readmit(
        &mut self,
        z: &Scores<N>,
        present: &[bool; N],
        direct: &[Option<(FaultKind, Option<u8>)>; N],
        step: &mut Step,
    ) {
        if self.units.iter().all(|u| u.healthy) {
            // Nothing to readmit: the per-sample path carries none of what follows.
            return;
        }
        let needed = self.config.samples(self.config.clean_s);
        let healthy: [bool; N] = core::array::from_fn(|k| present[k] && self.units[k].healthy);
        let candidate: [bool; N] = core::array::from_fn(|k| {
            let unit = &self.units[k];
            !unit.healthy && unit.suspected.is_none() && present[k] && direct[k].is_none()
        });
        let judges = if healthy.contains(&true) {
            healthy
        } else {
            candidate
        };
        let (shift_least, slip_least) = self.healthy_colour();
        for (k, &is_candidate) in candidate.iter().enumerate() {
            if self.units[k].healthy || self.units[k].suspected.is_some() {
                continue;
            }
            let others = (0..N).filter(|&l| l != k && judges[l]);
            let agreeing = others
                .clone()
                .filter(|&l| self.agrees(k, l, z, &shift_least, &slip_least))
                .count();
            // Clean with at least half the healthy units: where two healthy units disagree
            // (one noisier in flight), agreeing with one of them is what a sound unit can do.
            let clean = is_candidate && agreeing >= 1 && 2 * agreeing >= others.count();
            let factor = self.dynamics_factor(k);
            let unit = &mut self.units[k];
            unit.clean_run = if clean { unit.clean_run + 1 } else { 0 };
            if unit.clean_run >= needed {
                unit.healthy = true;
                unit.clean_run = 0;
                step.readmitted |= 1 << k;
                // Its pairs' spreads were not learned while it was out: they return as
                // the dynamics have scaled the healthy ones.
                for l in (0..N).filter(|&l| l != k) {
                    let (i, j) = if k < l { (k, l) } else { (l, k) };
                    for p in &mut self.pairs[i][j] {
                        p.spread *= factor;
                    }
                }
            }
        }
    }

    /// Whether unit k's pair with unit l is within half of every test's threshold, the
    /// shift and slip statistics' spreads no lower than `shift_least` and `slip_least`.
    fn agrees(
        &self,
        k: usize,
        l: usize,
        z: &Scores<N>,
        shift_least: &[f32; 3],
        slip_least: &[f32; 3],
    ) -> bool {
        let c = &self.config;
        largest(&z[k][l]) < c.spike_sigma / 2.0
            && self.shift_score_above(k, l, z, shift_least) < c.shift_sigma / 2.0
            && self.burst_score(k, l) < c.burst_ratio / 2.0
            && self.slip_score_above(k, l, slip_least) < c.slip_sigma / 2.0
    }

    /// The mean learned spreads of the shift and slip statistics per axis over the pairs of
    /// healthy units (zero where there is no such pair). A unit that is out learns none for
    /// its pairs, and these statistics follow the dynamics' colour more than their level: a
    /// manoeuvre's slow residuals of misalignment and lever arm move a quarter second's mean
    /// z-score by a spread where, parked, it moves by a tenth; so a sound unit coming back
    /// in a manoeuvre is judged by what the healthy pairs show now.
    fn healthy_colour(&self) -> ([f32; 3], [f32; 3]) {
        let (mut shift, mut slip, mut pairs) = ([0.0f32; 3], [0.0f32; 3], 0);
        for k in (0..N).filter(|&k| self.units[k].healthy) {
            for l in (k + 1..N).filter(|&l| self.units[l].healthy) {
                for (a, p) in self.pairs[k][l].iter().enumerate() {
                    shift[a] += p.shift_spread;
                    slip[a] += p.slip_spread;
                }
                pairs += 1;
            }
        }
        let n = pairs.max(1) as f32;
        (shift.map(|v| v / n), slip.map(|v| v / n))
    }
}

/// t-statistic beyond which a term of the confirmation window's least squares is there.
const TERM_T: f32 = 5.0;

/// The kind of a statistically suspected fault from its confirmation window, and the axis
/// that showed it. A spike shows in a few samples only; a time slip of up to SLIP_LAGS
/// samples, as the unit's samples moved by a whole number of samples halving its residual
/// (a slip of a vibration line is a phase shift, which no linear term explains); otherwise
/// each axis's residual is
/// fitted on a constant, the signal and the signal's change per sample, and the kind is the
/// strongest term that stands out on any axis: the change (a time slip: x(t - d) - x(t) is
/// about -d v), else the signal (a scale change, which also shifts the constant), else the
/// constant (a bias step), else none (a noise burst). Over a window where the signal hardly
/// changes, a scale change cannot be told from a bias step (an accelerometer's gravity at
/// rest) and is reported as one.
fn classify(e: &Episode, trigger: Trigger) -> (FaultKind, Option<u8>) {
    if trigger == Trigger::Norm {
        return (FaultKind::ScaleFactor, None);
    }
    let loudest = (0..3).fold(0, |best, a| if e.rr[a] > e.rr[best] { a } else { best });
    if trigger == Trigger::Spike && e.excursions <= 2 {
        return (FaultKind::Spike, Some(loudest as u8));
    }
    // A scale error on a ramp is a lead of the unit (x (1 + s) = x(t + s x / x')): a slip
    // must also fit better than the linear terms do.
    let best_lag = e
        .lagged
        .iter()
        .flatten()
        .copied()
        .fold(f32::INFINITY, f32::min);
    let linear: f32 = (0..3).map(|a| linear_residual(e, a)).sum();
    if e.unlagged > 0.0 && best_lag < 0.5 * e.unlagged && best_lag < linear {
        return (FaultKind::TimeSlip, Some(loudest as u8));
    }
    let t: [[f32; 3]; 3] = core::array::from_fn(|a| term_t_statistics(e, a));
    // Only axes that carry a good part of the residual: another axis's misalignment leak in
    // a turn must not name the kind of a step on this one.
    let carries = |a: usize| e.rr[a] >= 0.25 * e.rr[loudest];
    let find = |term: usize, beats: &dyn Fn(&[f32; 3]) -> bool| {
        (0..3)
            .filter(|&a| carries(a) && t[a][term] >= TERM_T && beats(&t[a]))
            .fold(None, |best: Option<usize>, a| match best {
                Some(b) if t[b][term] >= t[a][term] => Some(b),
                _ => Some(a),
            })
    };
    if let Some(a) = find(2, &|t| t[2] >= t[1]) {
        (FaultKind::TimeSlip, Some(a as u8))
    } else if let Some(a) = find(1, &|_| true) {
        (FaultKind::ScaleFactor, Some(a as u8))
    } else if let Some(a) = find(0, &|_| true) {
        (FaultKind::BiasStep, Some(a as u8))
    } else {
        (FaultKind::NoiseBurst, Some(loudest as u8))
    }
}

/// What the least squares of axis a on the constant, the signal and its change leaves of the
/// residual's sum of squares.
fn linear_residual(e: &Episode, a: usize) -> f32 {
    let normal = nalgebra::Matrix3::from_fn(|i, j| e.normal[a][i][j]);
    let cross = nalgebra::Vector3::from(e.cross[a]);
    match normal.try_inverse() {
        Some(inverse) => (e.rr[a] - (inverse * cross).dot(&cross)).max(0.0),
        None => e.rr[a],
    }
}

/// |t| of the constant, the signal and its change in axis a's least squares; only the
/// constant's where the signal did not change over the window.
fn term_t_statistics(e: &Episode, a: usize) -> [f32; 3] {
    let normal = nalgebra::Matrix3::from_fn(|i, j| e.normal[a][i][j]);
    let cross = nalgebra::Vector3::from(e.cross[a]);
    match normal.try_inverse() {
        Some(inverse) if e.count > 3 => {
            let beta = inverse * cross;
            let residual = (e.rr[a] - beta.dot(&cross)).max(0.0) / (e.count - 3) as f32;
            core::array::from_fn(|j| {
                let se = (residual * inverse[(j, j)]).max(f32::MIN_POSITIVE).sqrt();
                (beta[j] / se).abs()
            })
        }
        _ => {
            let n = e.count.max(1) as f32;
            let mean = e.cross[a][0] / n;
            let variance = (e.rr[a] / n - mean * mean).max(f32::MIN_POSITIVE);
            [mean.abs() / (variance / n).sqrt(), 0.0, 0.0]
        }
    }
}

impl<const N: usize> FaultMonitor<N> {
    /// Updates what the pairs and units have learned from a sample set. The pairs' means
    /// learn from every sample not under a direct fault (dropout, saturation, stuck), also a
    /// unit's that is out: the units' relative biases drift (with temperature), and an
    /// excluded unit must be judged against where they are now, not where they were when it
    /// left; a unit whose bias stepped returns with its new bias. Only pairs of healthy units
    /// teach the spreads the tests divide by.
    fn learn(&mut self, samples: &[Option<[f32; 3]>; N], z: &Scores<N>, direct: &[bool; N]) {
        // This set counted in: a plain mean until the exponential weight is the smaller.
        let seen = self.sample + 1;
        let c = self.config;
        let startup = 1.0 / seen as f32;
        let alpha_mean = c.alpha(c.mean_time_constant_s).max(startup);
        let alpha_spread = c.alpha(c.spread_time_constant_s).max(startup);
        let alpha_fast = c.alpha(c.fast_time_constant_s);
        let alpha_burst = c.alpha(4.0 * c.fast_time_constant_s).max(startup);
        let floor = alpha_fast / (2.0 - alpha_fast);
        let slip_floor = self.slip_floor();
        for k in 0..N {
            for l in k + 1..N {
                let (Some(a), Some(b)) = (samples[k], samples[l]) else {
                    continue;
                };
                // A jolt's samples teach the fast statistics nothing of the units: they would
                // hold its energy for seconds after the hold ends.
                let jolt = self.sample < self.hold_until;
                let healthy = self.units[k].healthy && self.units[l].healthy && !jolt;
                let relearn = !direct[k] && !direct[l];
                for axis in 0..3 {
                    let p = &mut self.pairs[k][l][axis];
                    let u = a[axis] - b[axis] - p.mean;
                    if relearn {
                        // (max/min, not clamp: clamp's panic would bring the formatting
                        // machinery into the board's flash.)
                        // Clipped at the spike threshold: the few samples of a gross fault
                        // before a direct test confirms it (a rail, 7000 spreads away) would
                        // otherwise move the mean by many spreads, and the unit, sound
                        // again, would fail its pairs for a mean time constant. A real
                        // bias step is still learned, at up to that rate.
                        let limit = if p.spread > 0.0 {
                            c.spike_sigma * p.spread.sqrt()
                        } else {
                            f32::INFINITY
                        };
                        p.mean += alpha_mean * u.max(-limit).min(limit);
                    }
                    if !jolt {
                        // Clipped as the mean is: a rail's z-scores of thousands would take
                        // the shift statistic ten time constants to forget.
                        let spike = c.spike_sigma;
                        p.shift += alpha_fast * (z[k][l][axis].max(-spike).min(spike) - p.shift);
                    }
                    if !relearn {
                        // A direct fault's samples (a rail, a frozen value) say nothing of
                        // the pair's noise or timing, and neither do the few before its test
                        // confirmed it: the fast statistics start again from rest, so a unit
                        // sound again is judged on its own samples, not for tens of seconds
                        // on a rail's.
                        p.shift = 0.0;
                        p.fast_spread = p.spread;
                        p.slip_cross = 0.0;
                    } else if !jolt {
                        p.fast_spread += alpha_burst * (u * u - p.fast_spread);
                        if let (Some(pa), Some(pb)) = (self.previous[k], self.previous[l]) {
                            let v = (a[axis] + b[axis] - pa[axis] - pb[axis]) / 2.0;
                            p.slip_cross += alpha_burst * (u * v - p.slip_cross);
                            p.slip_signal += alpha_burst * (v * v - p.slip_signal);
                        }
                    }
                    if healthy {
                        // Clipped at 25 spreads: one outlier moves the spread little.
                        let limit = if p.spread > 0.0 {
                            25.0 * p.spread
                        } else {
                            f32::INFINITY
                        };
                        p.spread += alpha_spread * ((u * u).min(limit) - p.spread);
                        let s2 = (p.shift * p.shift).min(9.0 * p.shift_spread.max(floor));
                        p.shift_spread += alpha_spread * (s2 - p.shift_spread);
                        let r = p.slip_correlation();
                        let r2 = (r * r).min(9.0 * p.slip_spread.max(slip_floor));
                        p.slip_spread += alpha_spread * (r2 - p.slip_spread);
                    }
                }
            }
        }
        self.learn_noise(samples, alpha_spread, direct);
        self.learn_offsets(samples, alpha_mean, direct);
    }

    /// Moves every present unit's offset toward its sample less the fused output, but a
    /// unit's under a direct fault: a rail or a frozen value is no bias to return with.
    fn learn_offsets(&mut self, samples: &[Option<[f32; 3]>; N], alpha: f32, direct: &[bool; N]) {
        let Some(fused) = self.fused(samples) else {
            return;
        };
        let spike = self.config.spike_sigma;
        for ((unit, s), &direct) in self.units.iter_mut().zip(samples).zip(direct) {
            if let (Some(s), false) = (s, direct) {
                // Clipped as the pairs' means are, at the spike threshold of the unit's
                // own noise: a gross fault's first samples are no bias to come back with.
                let limit = if unit.noise_slow > 0.0 {
                    spike * unit.noise_slow.sqrt()
                } else {
                    f32::INFINITY
                };
                for a in 0..3 {
                    let u = s[a] - fused[a] - unit.offset[a];
                    unit.offset[a] += alpha * u.max(-limit).min(limit);
                }
            }
        }
    }

    /// Each unit's own white-noise variance of first differences, fast and slow, from
    /// products with two others (an excluded unit's noise, if independent, leaves the
    /// products' mean alone; one under a direct fault is left out), and the fast mean of its
    /// vector's length.
    fn learn_noise(
        &mut self,
        samples: &[Option<[f32; 3]>; N],
        alpha_slow: f32,
        direct: &[bool; N],
    ) {
        let alpha_fast = self.config.alpha(4.0 * self.config.fast_time_constant_s);
        let delta: [Option<[f32; 3]>; N] =
            core::array::from_fn(|k| match (samples[k], self.previous[k]) {
                (Some(now), Some(before)) => Some(core::array::from_fn(|a| now[a] - before[a])),
                _ => None,
            });
        for k in 0..N {
            if let Some(s) = samples[k] {
                let length = s.iter().map(|v| v * v).sum::<f32>().sqrt();
                let unit = &mut self.units[k];
                let weight = if unit.norm == 0.0 { 1.0 } else { alpha_fast };
                unit.norm += weight * (length - unit.norm);
                if let Some(before) = self.previous[k] {
                    let step2 = (0..3)
                        .map(|a| {
                            let d = s[a] - before[a];
                            d * d
                        })
                        .sum::<f32>()
                        / 3.0;
                    let limit = if unit.step_spread > 0.0 {
                        25.0 * unit.step_spread
                    } else {
                        f32::INFINITY
                    };
                    unit.step_spread += alpha_slow.max(1.0 / (self.sample + 1) as f32)
                        * (step2.min(limit) - unit.step_spread);
                }
            }
            let Some(dk) = delta[k] else { continue };
            let mut sum = 0.0;
            let mut count = 0;
            for l in 0..N {
                for m in l + 1..N {
                    let usable = |i: usize| i != k && !direct[i] && delta[i].is_some();
                    if !(usable(l) && usable(m)) {
                        continue;
                    }
                    let (dl, dm) = (delta[l].unwrap_or_default(), delta[m].unwrap_or_default());
                    sum += (0..3)
                        .map(|a| (dk[a] - dl[a]) * (dk[a] - dm[a]))
                        .sum::<f32>()
                        / 3.0;
                    count += 1;
                }
            }
            if count == 0 {
                continue;
            }
            let product = sum / count as f32;
            let unit = &mut self.units[k];
            if unit.healthy {
                let limit = if unit.noise_slow > 0.0 {
                    25.0 * unit.noise_slow
                } else {
                    f32::INFINITY
                };
                unit.noise_slow += alpha_slow * (product.min(limit) - unit.noise_slow);
            }
        }
    }

    /// The fused sample: the mean of the healthy present units, each less its bias relative
    /// to the set, weighted by the inverse of its own noise variance; None when no healthy
    /// unit is present.
    ///
    /// With no healthy unit present (faults that overlap, a unit slow to be readmitted),
    /// the units present without a direct fault stand in: a suspected unit is a worse
    /// output than none only where its fault is gross, and those are the direct ones; a
    /// board left without a fused output loses its navigation until it can align again.
    pub fn fused(&self, samples: &[Option<[f32; 3]>; N]) -> Option<[f32; 3]> {
        self.fused_and_shares(samples).map(|(fused, _)| fused)
    }

    /// [`Self::fused`] with the units' [`Self::shares`] that made it, computed once.
    pub fn fused_and_shares(
        &self,
        samples: &[Option<[f32; 3]>; N],
    ) -> Option<([f32; 3], [f32; N])> {
        let shares = self.shares(samples)?;
        let mut sum = [0.0f32; 3];
        for (k, s) in samples.iter().enumerate() {
            let Some(s) = s.filter(|_| shares[k] > 0.0) else {
                continue;
            };
            let offset = self.offset(k);
            for a in 0..3 {
                sum[a] += shares[k] * (s[a] - offset[a]);
            }
        }
        Some((sum, shares))
    }

    /// Each unit's weight in [`Self::fused`] (summing to 1; 0 for a unit left out), None
    /// when no unit is in use.
    pub fn shares(&self, samples: &[Option<[f32; 3]>; N]) -> Option<[f32; N]> {
        let any_healthy = (0..N).any(|k| self.units[k].healthy && samples[k].is_some());
        let in_use = |k: usize| {
            samples[k].is_some()
                && if any_healthy {
                    self.units[k].healthy
                } else {
                    !self.units[k].direct
                }
        };
        // Equal weights until every unit in use has a noise level.
        let levels_known = (0..N).all(|k| !in_use(k) || self.noise_variance(k) > 0.0);
        let weights: [f32; N] = core::array::from_fn(|k| match (in_use(k), levels_known) {
            (false, _) => 0.0,
            (true, true) => 1.0 / self.noise_variance(k),
            (true, false) => 1.0,
        });
        let total: f32 = weights.iter().sum();
        (total > 0.0).then(|| weights.map(|w| w / total))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;
    use rand_distr::{Distribution, StandardNormal};

    const RATE_HZ: f32 = 100.0;
    const NOISE: [f32; 3] = [0.002, 0.004, 0.003];
    const BIAS: [f32; 3] = [0.01, -0.005, 0.002];
    /// The fault starts at 60 s.
    const ONSET: u32 = 6000;

    /// The platform's angular rate at sample i: slow turns of up to 0.3 rad/s and a 26 Hz
    /// vibration line, rad/s.
    fn motion(i: u32) -> [f32; 3] {
        let t = i as f32 / RATE_HZ;
        let vibration = 0.05 * (2.0 * core::f32::consts::PI * 26.0 * t).sin();
        [
            0.1 * (0.7 * t).sin() + vibration,
            0.15 * (0.4 * t + 1.0).sin() + 0.5 * vibration,
            0.3 * (0.25 * t).sin() + 0.3 * vibration,
        ]
    }

    /// What unit 1 reads at sample i under `fault`, from the true rate and its noise.
    type Fault = fn(u32, [f32; 3], &mut ChaCha8Rng) -> Option<[f32; 3]>;

    /// Runs three units for `seconds` with unit 1 read through `fault`: the confirmed events,
    /// the samples unit 1 was readmitted at, and the largest error of the fused output over
    /// 0.1 s means from 10 s before the onset, less its mean error over 10-50 s (the fused
    /// output's own bias, a weighted mean of the units').
    fn run(
        seed: u64,
        seconds: u32,
        fault: Fault,
        config: FaultConfig,
    ) -> (Vec<FaultEvent>, Vec<u32>, f32) {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let mut monitor = FaultMonitor::<3>::new(config);
        let (mut events, mut readmitted, mut worst) = (Vec::new(), Vec::new(), 0.0f32);
        let mut window = ([0.0f32; 3], 0);
        let mut fused_bias = [0.0f32; 3];
        for i in 0..(seconds * RATE_HZ as u32) {
            let truth = motion(i);
            let mut samples: [Option<[f32; 3]>; 3] = core::array::from_fn(|k| {
                Some(core::array::from_fn(|a| {
                    let z: f32 = StandardNormal.sample(&mut rng);
                    truth[a] + BIAS[k] + NOISE[k] * z
                }))
            });
            samples[1] = fault(i, samples[1].unwrap(), &mut rng);
            let step = monitor.push(&samples);
            events.extend(step.confirmed.iter().copied());
            if step.readmitted & 2 != 0 {
                readmitted.push(i);
            }
            let fused = monitor.fused(&samples);
            if let Some(f) = fused.filter(|_| (1000..ONSET - 1000).contains(&i)) {
                for a in 0..3 {
                    fused_bias[a] += (f[a] - truth[a]) / (ONSET - 2000) as f32;
                }
            }
            if let Some(f) = fused.filter(|_| i >= ONSET - 1000) {
                for a in 0..3 {
                    window.0[a] += f[a] - truth[a] - fused_bias[a];
                }
                window.1 += 1;
            }
            if window.1 == 10 {
                worst = worst.max(largest(&window.0.map(|e| e / 10.0)));
                window = ([0.0; 3], 0);
            }
        }
        (events, readmitted, worst)
    }

    fn config() -> FaultConfig {
        FaultConfig::new(1.0 / RATE_HZ)
    }

    /// The first event is unit 1's, of `kind`, detected within `latency` samples of the onset;
    /// no event names another unit.
    fn assert_isolated(events: &[FaultEvent], kind: FaultKind, latency: u32) {
        let first = events
            .first()
            .unwrap_or_else(|| panic!("no event; wanted {kind:?}"));
        assert_eq!(first.unit, Some(1), "{events:?}");
        assert_eq!(first.kind, kind, "{events:?}");
        assert!(
            (ONSET..=ONSET + latency).contains(&first.detected_sample),
            "{events:?}"
        );
        assert!(events.iter().all(|e| e.unit == Some(1)), "{events:?}");
    }

    fn healthy(_: u32, s: [f32; 3], _: &mut ChaCha8Rng) -> Option<[f32; 3]> {
        Some(s)
    }

    #[test]
    fn a_fault_free_run_raises_nothing_and_the_fused_output_is_near_the_truth() {
        for seed in 0..3 {
            let (events, _, worst) = run(seed, 600, healthy, config());
            assert!(events.is_empty(), "seed {seed}: {events:?}");
            // Fused noise about 0.0017 rad/s per sample, 0.0005 over 0.1 s.
            assert!(worst < 0.004, "seed {seed}: {worst}");
        }
    }

    #[test]
    fn each_fault_kind_is_isolated_to_its_unit_and_kept_out_of_the_fused_output() {
        let dropout: Fault = |i, s, _| (!(ONSET..ONSET + 100).contains(&i)).then_some(s);
        let stuck: Fault = |i, s, _| {
            if (ONSET..ONSET + 200).contains(&i) {
                Some(motion(ONSET))
            } else {
                Some(s)
            }
        };
        let spike: Fault = |i, s, _| Some(if i == ONSET { s.map(|v| v + 0.2) } else { s });
        let step: Fault = |i, s, _| Some(if i >= ONSET { s.map(|v| v + 0.03) } else { s });
        // A scale change of the x gyro, whose signal varies (its vibration line); over the
        // 1 s window a scale change on a slowly varying signal is a bias step.
        let scale: Fault = |i, s, _| {
            let truth = motion(i);
            Some(if i >= ONSET {
                [s[0] + 0.2 * truth[0], s[1], s[2]]
            } else {
                s
            })
        };
        let burst: Fault = |i, s, rng| {
            Some(if (ONSET..ONSET + 300).contains(&i) {
                s.map(|v| {
                    v + 0.03
                        * <StandardNormal as Distribution<f32>>::sample(&StandardNormal, &mut *rng)
                })
            } else {
                s
            })
        };
        let slip: Fault = |i, s, _| {
            let (now, before) = (motion(i), motion(i.saturating_sub(1)));
            Some(if i >= ONSET {
                core::array::from_fn(|a| s[a] - now[a] + before[a])
            } else {
                s
            })
        };
        let cases: [(&str, Fault, FaultKind, u32); 7] = [
            ("dropout", dropout, FaultKind::Dropout, 0),
            ("stuck", stuck, FaultKind::Stuck, 12),
            ("spike", spike, FaultKind::Spike, 0),
            ("bias step", step, FaultKind::BiasStep, 20),
            ("scale", scale, FaultKind::ScaleFactor, 300),
            ("noise burst", burst, FaultKind::NoiseBurst, 100),
            ("time slip", slip, FaultKind::TimeSlip, 10),
        ];
        for (name, fault, kind, latency) in cases {
            let (events, readmitted, worst) = run(11, 120, fault, config());
            eprintln!("{name}: {events:?} readmitted {readmitted:?} worst {worst}");
            assert_isolated(&events, kind, latency);
            assert!(worst < 0.01, "{name}: fused error {worst}");
        }
    }

    /// With no range configured, a unit whose output jumps to a rail and holds it is
    /// saturated (on the pinned axis), and one that freezes where it was is stuck.
    #[test]
    fn a_unit_pinned_at_a_rail_is_saturated_without_a_range_and_a_frozen_one_stuck() {
        let rail: Fault = |i, s, _| {
            Some(if (ONSET..ONSET + 100).contains(&i) {
                [s[0], s[1], 34.9]
            } else {
                s
            })
        };
        let (events, _, worst) = run(7, 120, rail, config());
        assert_isolated(&events, FaultKind::Saturation, 12);
        assert_eq!(events[0].axis, Some(2), "{events:?}");
        assert!(worst < 0.01, "fused error {worst}");
        // A unit frozen at its last value: every axis held, none far from the others.
        let frozen: Fault = |i, s, _| {
            Some(if (ONSET..ONSET + 100).contains(&i) {
                motion(ONSET)
            } else {
                s
            })
        };
        let (events, _, _) = run(7, 120, frozen, config());
        assert_isolated(&events, FaultKind::Stuck, 12);
    }

    /// A unit back from a direct fault (10 s frozen, 2 s at a rail) is readmitted within
    /// a few seconds of its clean period, and the fused output is sound meanwhile.
    #[test]
    fn a_unit_back_from_a_direct_fault_is_readmitted() {
        let frozen: Fault = |i, s, _| {
            Some(if (ONSET..ONSET + 1000).contains(&i) {
                motion(ONSET)
            } else {
                s
            })
        };
        let rail: Fault = |i, s, _| {
            Some(if (ONSET..ONSET + 200).contains(&i) {
                [s[0], s[1], 34.9]
            } else {
                s
            })
        };
        for (name, fault, end) in [
            ("frozen", frozen, ONSET + 1000),
            ("rail", rail, ONSET + 200),
        ] {
            let (events, readmitted, worst) = run(3, 180, fault, config());
            eprintln!("{name}: {events:?} readmitted {readmitted:?} worst {worst}");
            let back = readmitted.first().copied();
            assert!(
                back.is_some_and(|b| b > end && b <= end + 1000),
                "{name}: readmitted at {back:?}, the fault ended at {end}"
            );
            assert!(worst < 0.01, "{name}: fused error {worst}");
        }
    }

    #[test]
    fn a_saturated_unit_is_isolated_at_its_range() {
        let mut c = config();
        c.range[1] = 0.28;
        let clip: Fault = |_, s, _| Some(s.map(|v| v.clamp(-0.28, 0.28)));
        let (events, _, _) = run(5, 60, clip, c);
        let first = events.first().expect("saturation");
        assert_eq!((first.unit, first.kind), (Some(1), FaultKind::Saturation));
        // z reaches 0.3 + 0.3 x 0.05 rad/s near t = 6.3 s.
        assert!((400..900).contains(&first.detected_sample), "{events:?}");
    }

    #[test]
    fn transient_faults_are_readmitted_and_a_bias_step_returns_with_its_new_bias() {
        let spike: Fault = |i, s, _| Some(if i == ONSET { s.map(|v| v + 0.2) } else { s });
        let (_, readmitted, _) = run(3, 90, spike, config());
        // Confirmed after 1 s, then clean for 5 s.
        assert!(
            matches!(readmitted.first(), Some(&i) if (ONSET + 600..ONSET + 700).contains(&i)),
            "{readmitted:?}"
        );
        let step: Fault = |i, s, _| Some(if i >= ONSET { s.map(|v| v + 0.03) } else { s });
        let (events, readmitted, _) = run(3, 150, step, config());
        assert_eq!(events.len(), 1, "{events:?}");
        assert!(!readmitted.is_empty(), "the stepped unit never returned");
    }

    #[test]
    fn a_jolt_every_unit_feels_differently_is_no_fault() {
        // Units at different places see a knock of the platform with different sizes: two
        // alike, the third much larger (it would be isolated as a spike without the hold).
        let mut rng = ChaCha8Rng::seed_from_u64(4);
        let mut monitor = FaultMonitor::<3>::new(config());
        let mut events = Vec::new();
        for i in 0..9000u32 {
            let truth = motion(i);
            // A sharp knock of 0.2 rad/s over three samples every 15 s.
            let knock = if (i % 1500) < 3 && i > 1500 { 0.2 } else { 0.0 };
            let s: [Option<[f32; 3]>; 3] = core::array::from_fn(|k| {
                let size = [1.0, 1.1, 2.5][k];
                Some(core::array::from_fn(|a| {
                    let z: f32 = StandardNormal.sample(&mut rng);
                    truth[a] + size * knock + NOISE[k] * z
                }))
            });
            events.extend(monitor.push(&s).confirmed.iter().copied());
        }
        assert!(events.is_empty(), "{events:?}");
    }

    /// Three units over `seconds`, each unit k's sample at i read through `read(i, k, x)`:
    /// the events, the sample each unit was last readmitted at, and the largest error of
    /// the fused output (less the units' mean bias) from `from` on.
    fn run_each(
        seconds: u32,
        read: impl Fn(u32, usize, [f32; 3]) -> Option<[f32; 3]>,
        from: u32,
    ) -> (Vec<FaultEvent>, [Option<u32>; 3], f32) {
        let mut rng = ChaCha8Rng::seed_from_u64(17);
        let mut monitor = FaultMonitor::<3>::new(config());
        let (mut events, mut back, mut worst) = (Vec::new(), [None; 3], 0.0f32);
        let mean_bias = BIAS.iter().sum::<f32>() / 3.0;
        for i in 0..(seconds * RATE_HZ as u32) {
            let truth = motion(i);
            let samples: [Option<[f32; 3]>; 3] = core::array::from_fn(|k| {
                let x = core::array::from_fn(|a| {
                    let z: f32 = StandardNormal.sample(&mut rng);
                    truth[a] + BIAS[k] + NOISE[k] * z
                });
                read(i, k, x)
            });
            let step = monitor.push(&samples);
            events.extend(step.confirmed.iter().copied());
            for (k, b) in back.iter_mut().enumerate() {
                if step.readmitted & (1 << k) != 0 {
                    *b = Some(i);
                }
            }
            if let Some(f) = monitor.fused(&samples).filter(|_| i >= from) {
                worst = worst.max(largest(&core::array::from_fn(|a| {
                    f[a] - truth[a] - mean_bias
                })));
            }
        }
        (events, back, worst)
    }

    /// A unit that goes to a rail while the platform is jolted (every unit jumping, which
    /// holds the statistical tests) leaves the fused output at its second sample there: a
    /// jolted unit moves, a rail holds.
    #[test]
    fn a_rail_during_a_jolt_leaves_the_fused_output_at_once() {
        let jolt = |i: u32| {
            if (ONSET..ONSET + 5).contains(&i) {
                1.0
            } else {
                0.0
            }
        };
        let (events, _, worst) = run_each(
            70,
            |i, k, x| {
                let size = [1.0, 1.2, 2.0][k];
                let mut x = x.map(|v| v + size * jolt(i));
                if k == 1 && (ONSET + 2..ONSET + 100).contains(&i) {
                    x[0] = 8.0;
                }
                Some(x)
            },
            ONSET + 5,
        );
        let rail = events
            .iter()
            .find(|e| e.unit == Some(1))
            .expect("the rail found");
        assert_eq!(rail.kind, FaultKind::Saturation, "{events:?}");
        assert_eq!(rail.detected_sample, ONSET + 3, "{events:?}");
        // The jolt's own samples aside, the fused output is the others'.
        assert!(worst < 0.05, "{worst}");
    }

    /// Overlapping dropouts leave no unit healthy; once all are back and agree, they are
    /// readmitted together after the clean period, not left out for good.
    #[test]
    fn with_every_unit_out_those_that_agree_come_back_together() {
        let (events, back, _) = run_each(
            100,
            |i, k, x| {
                let out_from = ONSET + 200 * k as u32;
                (!(out_from..ONSET + 2000).contains(&i)).then_some(x)
            },
            0,
        );
        assert_eq!(events.len(), 3, "{events:?}");
        let clean = config().samples(config().clean_s);
        for (k, b) in back.iter().enumerate() {
            let b = b.unwrap_or_else(|| panic!("unit {k} never back: {back:?}"));
            assert!(
                (ONSET + 2000 + clean - 1..ONSET + 2000 + clean + 100).contains(&b),
                "{k}: {b}"
            );
        }
    }

    /// Unit 1 drops out for good at 60 s; unit 0's sample i is read through `fault(i, x)`.
    /// The events and whether units 0 and 2 are healthy at the end.
    fn two_left(fault: impl Fn(u32, [f32; 3]) -> [f32; 3]) -> (Vec<FaultEvent>, bool, bool) {
        let mut rng = ChaCha8Rng::seed_from_u64(9);
        let mut monitor = FaultMonitor::<3>::new(config());
        let mut events = Vec::new();
        for i in 0..10000u32 {
            let truth = motion(i);
            let mut s: [Option<[f32; 3]>; 3] = core::array::from_fn(|k| {
                Some(core::array::from_fn(|a| {
                    truth[a]
                        + NOISE[k]
                            * <StandardNormal as Distribution<f32>>::sample(
                                &StandardNormal,
                                &mut rng,
                            )
                }))
            });
            if i >= ONSET {
                s[1] = None;
            }
            s[0] = s[0].map(|x| fault(i, x));
            events.extend(monitor.push(&s).confirmed.iter().copied());
        }
        (events, monitor.healthy(0), monitor.healthy(2))
    }

    /// With two units left, a disagreement (a spike, a drift) is detected but cannot be
    /// placed; a unit that goes to a rail can: it holds a value it came to far from the
    /// other, which moves.
    #[test]
    fn with_two_units_left_a_disagreement_is_detected_and_a_rail_placed() {
        for (name, fault) in [
            (
                "spike",
                (|i| if i == 8000 { 2.0 } else { 0.0 }) as fn(u32) -> f32,
            ),
            ("drift", |i| 5e-5 * i.saturating_sub(8000) as f32),
        ] {
            let (events, healthy_0, _) = two_left(|i, x| x.map(|v| v + fault(i)));
            assert_eq!(events.len(), 2, "{name}: {events:?}");
            assert_eq!(
                (events[0].unit, events[0].kind),
                (Some(1), FaultKind::Dropout)
            );
            assert_eq!(events[1].unit, None, "{name}: {events:?}");
            assert!(events[1].detected_sample >= 8000, "{name}: {events:?}");
            assert!(healthy_0, "{name}: unit 0 never left");
        }
        let (events, healthy_0, healthy_2) = two_left(|i, mut x| {
            if (8000..8300).contains(&i) {
                x[0] = 8.0;
            }
            x
        });
        // Its first sample there is a disagreement not yet placed; its second is the rail.
        assert_eq!(events.len(), 3, "{events:?}");
        assert_eq!((events[1].unit, events[1].detected_sample), (None, 8000));
        assert_eq!(
            (events[2].unit, events[2].kind, events[2].detected_sample),
            (Some(0), FaultKind::Saturation, 8001)
        );
        assert!(healthy_0 && healthy_2, "unit 0 back after the rail");
    }
}
