//! The units' common time grid. Units sampled together share their time stamps, but a unit
//! may miss samples (a dropout: its file has no row at that time), and units that each run
//! on their own oscillator (a board that stamps every IMU's data-ready edge) share the
//! rate, not the instants: their samples slide past each other by the clocks' difference,
//! 20 to 100 ppm for crystals, so a thousandth of a sample interval every 10 to 50 samples.
//!
//! The grid is the times of the unit with the most samples (its dropouts filled by evenly
//! spaced times), within the span all units cover. Each unit's samples are placed on it by
//! the unit's phase, its smoothed offset from the grid: a sample goes to the grid time
//! nearest its own time minus that phase, so a stamp's jitter never moves a sample to
//! another slot, and a unit whose phase has slid past three quarters of an interval steps
//! one slot (a slower unit leaves a slot empty, a faster one gives a slot two samples, of
//! which the nearer is kept). The samples a unit gains or loses this way measure its rate
//! against the grid's; a unit more than [`RATE_OFFSET_MAX`] off is on another clock, and
//! refused, as is a unit with more than 1% of its samples at times no other unit has. The
//! grid keeps the times at least two units share.
//!
//! For the run-long analyses (alignment, wavelet variances) a missing sample is filled by
//! linear interpolation of the unit's own neighbours; the fault monitor sees it as missing.
//! A placed sample stands at its grid time; its own offset from it, up to three quarters of
//! an interval, stays in `offset_s` for the analyses that take the motion between.

use super::derivative::SpectralDerivative;
use super::RedundancyError;
use crate::interchange::ImuRecording;

/// The units on their common grid.
pub(super) struct Grid {
    pub t_s: Vec<f64>,
    /// `present[k][i]`: unit k has a sample at grid time i.
    pub present: Vec<Vec<bool>>,
    /// Each unit on the grid, missing samples filled.
    pub filled: Vec<(String, ImuRecording)>,
    /// `offset_s[k][i]`: how much later than grid time i unit k's sample there was taken,
    /// s (0 where it has none).
    pub offset_s: Vec<Vec<f64>>,
    /// The unit whose times the grid follows.
    pub anchor: usize,
    /// Each unit's rate against the grid's, as a fraction (0 for units sampled together;
    /// parts per million of clock difference for units on their own crystals).
    pub rate_offset: Vec<f64>,
}

/// Largest share of a unit's samples at times no other unit has.
const LONELY_MAX: f64 = 0.01;
/// Largest difference of a unit's rate from the grid's, as a fraction: the samples it gains
/// or loses against the grid over those it has. A thousandth is ten times a cheap crystal's
/// tolerance; beyond it a unit is on another clock (a different rate, a timer set wrong).
pub(super) const RATE_OFFSET_MAX: f64 = 1e-3;
/// Fewest samples the units must share: the wavelet variances' shortest record.
const MIN_SHARED_SAMPLES: usize = 64;
/// Smallest share of the grid a unit must cover.
const COVERAGE_MIN: f64 = 0.5;
/// How fast a unit's phase follows its samples' offsets: a time constant of 32 samples,
/// long against a stamp's jitter and short against a crystal's drift.
const PHASE_GAIN: f64 = 1.0 / 32.0;
/// The phase, as a fraction of an interval, past which a unit steps one slot: a quarter of
/// an interval beyond half, so a phase near half an interval does not step back and forth.
const PHASE_STEP: f64 = 0.75;

/// The grid of `units` (3 or more, checked by the caller), or why they were not sampled
/// together; its times are those of unit `anchor`, or where None of the unit with the most
/// samples (a long run's stretches all follow the run's anchor, so their grids join).
pub(super) fn common_grid(
    units: &[(String, ImuRecording)],
    anchor: Option<usize>,
) -> Result<Grid, RedundancyError> {
    let dt_s = units
        .iter()
        .map(|(_, r)| r.median_dt_s())
        .fold(f64::INFINITY, f64::min);
    let (start_s, end_s) = shared_span(units, dt_s)?;
    // A unit's first and last samples may stand up to its phase from the others'.
    let tolerance = PHASE_STEP * dt_s;
    let in_span = |t: f64| t >= start_s - tolerance && t <= end_s + tolerance;
    let anchor = anchor.unwrap_or_else(|| {
        (0..units.len())
            .max_by_key(|&k| {
                let count = units[k].1.t_s.iter().filter(|t| in_span(**t)).count();
                (count, std::cmp::Reverse(k))
            })
            .expect("three or more units")
    });
    let anchor_t: Vec<f64> = units[anchor]
        .1
        .t_s
        .iter()
        .copied()
        .filter(|t| in_span(*t))
        .collect();
    let slots = timeline(&anchor_t, dt_s);
    let placements: Vec<Placement> = units
        .iter()
        .map(|(_, r)| place(&r.t_s, &slots, dt_s, in_span))
        .collect();
    // The grid keeps the slots two or more units share; a sample in any other is lonely.
    // A slot a unit's clock stepped over counts as the unit's: it missed no sample there.
    let holds = |p: &Placement, i: usize| p.sample[i].is_some() || p.slipped[i];
    let shared: Vec<bool> = (0..slots.len())
        .map(|i| placements.iter().filter(|p| holds(p, i)).count() >= 2)
        .collect();
    for (k, (name, r)) in units.iter().enumerate() {
        let p = &placements[k];
        let lonely = (0..slots.len())
            .filter(|&i| !shared[i] && p.sample[i].is_some())
            .count();
        check_unit(name, r, p, lonely, &units[anchor].0)?;
    }
    let keep = |column: &[Option<usize>]| -> Vec<Option<usize>> {
        column
            .iter()
            .zip(&shared)
            .filter(|(_, s)| **s)
            .map(|(c, _)| *c)
            .collect()
    };
    let t_s: Vec<f64> = slots
        .iter()
        .zip(&shared)
        .filter(|(_, s)| **s)
        .map(|(t, _)| *t)
        .collect();
    let index: Vec<Vec<Option<usize>>> = placements.iter().map(|p| keep(&p.sample)).collect();
    let offset_s: Vec<Vec<f64>> = units
        .iter()
        .zip(&index)
        .map(|((_, r), idx)| {
            idx.iter()
                .zip(&t_s)
                .map(|(i, t)| i.map_or(0.0, |i| r.t_s[i] - t))
                .collect()
        })
        .collect();
    let coverage_min = (COVERAGE_MIN * t_s.len() as f64).ceil() as usize;
    for ((name, _), idx) in units.iter().zip(&index) {
        let covered = idx.iter().filter(|i| i.is_some()).count();
        if covered < coverage_min {
            return Err(RedundancyError::Unit {
                name: name.clone(),
                message: format!(
                    "has samples at {covered} of the {} times the units share: the units must be \
                     sampled together",
                    t_s.len()
                ),
            });
        }
    }
    let filled = units
        .iter()
        .zip(&index)
        .zip(&offset_s)
        .map(|(((name, r), idx), offsets)| {
            let mut on_grid = fill(r, idx, &t_s);
            move_to_grid_times(&mut on_grid, offsets, dt_s);
            (name.clone(), on_grid)
        })
        .collect();
    // Where a unit's clock stepped over a slot it has no sample, but nothing is wrong with
    // it: the monitors take the slot's filled value as its sample.
    let present = placements
        .iter()
        .map(|p| {
            (0..slots.len())
                .filter(|&i| shared[i])
                .map(|i| holds(p, i))
                .collect()
        })
        .collect();
    Ok(Grid {
        t_s,
        present,
        filled,
        offset_s,
        anchor,
        rate_offset: placements.iter().map(|p| p.rate_offset).collect(),
    })
}

/// The span every unit covers (a unit that starts late or stops early has no dropouts
/// outside it), or why the units share too little of their time.
fn shared_span(units: &[(String, ImuRecording)], dt_s: f64) -> Result<(f64, f64), RedundancyError> {
    let start_s = units
        .iter()
        .map(|(_, r)| r.t_s[0])
        .fold(f64::NEG_INFINITY, f64::max);
    let end_s = units
        .iter()
        .map(|(_, r)| r.t_s[r.len() - 1])
        .fold(f64::INFINITY, f64::min);
    if end_s - start_s >= MIN_SHARED_SAMPLES as f64 * dt_s {
        return Ok((start_s, end_s));
    }
    let spans: Vec<String> = units
        .iter()
        .map(|(name, r)| format!("{name} {} .. {} s", r.t_s[0], r.t_s[r.len() - 1]))
        .collect();
    Err(RedundancyError::NoOverlap(format!(
        "the units' recordings share {:.3} s, fewer than {MIN_SHARED_SAMPLES} samples: {}",
        (end_s - start_s).max(0.0),
        spans.join(", ")
    )))
}

/// Offsets below this share of an interval are left alone: units stamped together, with a
/// board's jitter of microseconds.
const OFFSET_CORRECTED_FROM: f64 = 0.02;
/// Samples on each side of the windowed sinc that delays the motion.
const SINC_HALF_WIDTH: usize = 16;

/// Each sample of `unit` (on the grid, taken `offsets_s` after its grid time) carried back
/// to its grid time: a unit half an interval late on a car's turn differs from the others
/// by the turn's angular acceleration times that half interval, which at 100 Hz is the
/// units' noise. Only the motion is moved ([`SpectralDerivative::motion`]: the bins that
/// stand above the noise), by a Lanczos-windowed sinc at each sample's own delay: a
/// first-order step along the derivative left the vertical accelerometer's noise 3.5 times
/// its truth, as a car's vibration at 20 Hz turns a third of a cycle in 7.5 ms. The noise
/// stays each sample's own: an interpolation of the whole signal would average it away.
fn move_to_grid_times(unit: &mut ImuRecording, offsets_s: &[f64], dt_s: f64) {
    let moved = |o: &f64| o.abs() >= OFFSET_CORRECTED_FROM * dt_s;
    if !offsets_s.iter().any(moved) {
        return;
    }
    let mut series: Vec<&mut Vec<f64>> = [&mut unit.gyro_rad_s, &mut unit.accel_m_s2]
        .into_iter()
        .flatten()
        .flat_map(|triad| triad.iter_mut())
        .collect();
    let motions: Vec<Option<Vec<f64>>> = series
        .iter()
        .map(|s| SpectralDerivative::fit(s, dt_s).map(|filter| filter.motion(s)))
        .collect();
    let last = offsets_s.len() as i64 - 1;
    let mut weights = [0.0; 2 * SINC_HALF_WIDTH];
    for (i, offset) in offsets_s.iter().enumerate().filter(|(_, o)| moved(o)) {
        let first = lanczos_weights(i as f64 - offset / dt_s, &mut weights);
        for (s, motion) in series.iter_mut().zip(&motions) {
            let Some(motion) = motion else { continue };
            let at_grid_time: f64 = weights
                .iter()
                .enumerate()
                .map(|(j, w)| w * motion[(first + j as i64).clamp(0, last) as usize])
                .sum();
            s[i] += at_grid_time - motion[i];
        }
    }
}

/// The weights, into `weights`, of a Lanczos-windowed sinc ([`SINC_HALF_WIDTH`] samples
/// each side, normalised to sum to one) that give an evenly sampled band-limited series at
/// fractional sample position `x`; returns the sample the first weight is for.
fn lanczos_weights(x: f64, weights: &mut [f64; 2 * SINC_HALF_WIDTH]) -> i64 {
    use std::f64::consts::PI;
    let a = SINC_HALF_WIDTH as f64;
    let below = x.floor();
    let first = below as i64 - SINC_HALF_WIDTH as i64 + 1;
    // sin(pi (x - k)) is +-sin(pi fraction), its sign alternating with k: one sine a sample.
    let sine = (PI * (x - below)).sin();
    let mut total = 0.0;
    for (j, w) in weights.iter_mut().enumerate() {
        let k = first + j as i64;
        let u = x - k as f64;
        *w = if u.abs() < 1e-12 {
            1.0
        } else {
            let sign = if (below as i64 - k) % 2 == 0 {
                1.0
            } else {
                -1.0
            };
            sign * sine / (PI * u) * (PI * u / a).sin() / (PI * u / a)
        };
        total += *w;
    }
    weights.iter_mut().for_each(|w| *w /= total);
    first
}

/// A unit's refusals: on another clock (its rate, or its samples at times no other unit has).
fn check_unit(
    name: &str,
    r: &ImuRecording,
    p: &Placement,
    lonely: usize,
    anchor: &str,
) -> Result<(), RedundancyError> {
    let fail = |message: String| RedundancyError::Unit {
        name: name.to_string(),
        message,
    };
    if p.rate_offset.abs() > RATE_OFFSET_MAX {
        return Err(fail(format!(
            "its rate is {:+.3}% off {anchor}'s ({} samples gained or lost in {}; first times \
             {} s and {} s): more than {}%, so not a crystal's tolerance but another clock \
             or rate; the units must be sampled together",
            p.rate_offset * 100.0,
            p.steps,
            p.placed,
            r.t_s[0],
            p.first_slot_s,
            RATE_OFFSET_MAX * 100.0,
        )));
    }
    if lonely as f64 > LONELY_MAX * p.placed as f64 {
        return Err(fail(format!(
            "{lonely} of its {} samples are at times no other unit has (first times {} s and \
             {} s): the units must be sampled together, on one clock",
            r.len(),
            r.t_s[0],
            p.first_slot_s,
        )));
    }
    Ok(())
}

/// The grid's times: the anchor unit's stamps, each gap of more than one and a half
/// intervals filled with evenly spaced times (where the anchor missed samples the others
/// may have them).
fn timeline(anchor_t: &[f64], dt_s: f64) -> Vec<f64> {
    let mut slots = Vec::with_capacity(anchor_t.len());
    for (i, &t) in anchor_t.iter().enumerate() {
        if let Some(&previous) = i.checked_sub(1).map(|p| &anchor_t[p]) {
            let gap = t - previous;
            if gap > 1.5 * dt_s {
                let steps = (gap / dt_s).round() as usize;
                slots.extend((1..steps).map(|j| previous + gap * j as f64 / steps as f64));
            }
        }
        slots.push(t);
    }
    slots
}

/// One unit's samples on the grid.
struct Placement {
    /// `sample[i]`: the unit's sample placed at grid slot i.
    sample: Vec<Option<usize>>,
    /// `slipped[i]`: slot i is empty because the unit's slower clock stepped over it (not a
    /// dropout: the unit missed nothing).
    slipped: Vec<bool>,
    /// Samples placed (within the shared span).
    placed: usize,
    /// Slots the unit's phase stepped: the samples it gained or lost against the grid.
    steps: usize,
    /// The unit's rate against the grid's, as a fraction: how fast its phase, unwrapped,
    /// slid over the span (positive: the unit's clock runs fast).
    rate_offset: f64,
    /// The grid time its first sample went to, s.
    first_slot_s: f64,
}

/// The samples `t_s` (in order) of one unit within the span placed on the grid `slots` by
/// the unit's phase (the module's note).
fn place(t_s: &[f64], slots: &[f64], dt_s: f64, in_span: impl Fn(f64) -> bool) -> Placement {
    let mut placement = Placement {
        sample: vec![None; slots.len()],
        slipped: vec![false; slots.len()],
        placed: 0,
        steps: 0,
        rate_offset: 0.0,
        first_slot_s: f64::NAN,
    };
    let nearest = |t: f64| {
        let above = slots.partition_point(|s| *s < t).min(slots.len() - 1);
        match above.checked_sub(1) {
            Some(below) if t - slots[below] < slots[above] - t => below,
            _ => above,
        }
    };
    let mut phase_s: Option<f64> = None;
    let mut first: Option<(f64, f64)> = None;
    let mut last_t = f64::NAN;
    // The slot a slower clock's step leaves empty, if the next sample passes over it.
    let mut stepped_over: Option<usize> = None;
    let mut gained = 0i64;
    for (j, &t) in t_s.iter().enumerate().filter(|(_, t)| in_span(**t)) {
        let phase = *phase_s.get_or_insert_with(|| t - slots[nearest(t)]);
        first.get_or_insert((t, phase));
        last_t = t;
        let slot = nearest(t - phase);
        if let Some(over) = stepped_over.take().filter(|over| *over < slot) {
            placement.slipped[over] = true;
        }
        let offset = t - slots[slot];
        let mut next = phase + PHASE_GAIN * (offset - phase);
        if next.abs() > PHASE_STEP * dt_s {
            next -= dt_s * next.signum();
            placement.steps += 1;
            if next < 0.0 {
                stepped_over = Some(slot + 1);
                gained -= 1;
            } else {
                gained += 1;
            }
        }
        phase_s = Some(next);
        placement.placed += 1;
        if placement.first_slot_s.is_nan() {
            placement.first_slot_s = slots[slot];
        }
        let nearer =
            placement.sample[slot].is_none_or(|k| (t_s[k] - slots[slot]).abs() > offset.abs());
        if nearer {
            placement.sample[slot] = Some(j);
        }
    }
    if let (Some((first_t, first_phase)), Some(phase)) = (first, phase_s) {
        // The stepped slots put back: how much later than the grid the unit's samples came.
        let slid_s = phase - first_phase - gained as f64 * dt_s;
        if last_t > first_t {
            placement.rate_offset = -slid_s / (last_t - first_t);
        }
    }
    placement
}

/// Recording `r` on the grid `t_s`, `idx[i]` its sample at grid time i if it has one; a
/// missing sample is interpolated linearly between the unit's neighbours (held at the ends).
fn fill(r: &ImuRecording, idx: &[Option<usize>], t_s: &[f64]) -> ImuRecording {
    let column = |values: &[f64]| -> Vec<f64> {
        let known: Vec<(f64, f64)> = idx
            .iter()
            .zip(t_s)
            .filter_map(|(i, t)| i.map(|i| (*t, values[i])))
            .collect();
        let mut next = 0;
        t_s.iter()
            .map(|&t| {
                while next < known.len() && known[next].0 < t {
                    next += 1;
                }
                match (next.checked_sub(1).map(|p| known[p]), known.get(next)) {
                    (_, Some(&(tn, vn))) if tn == t => vn,
                    (Some((tp, vp)), Some(&(tn, vn))) => vp + (vn - vp) * (t - tp) / (tn - tp),
                    (Some((_, vp)), None) => vp,
                    (None, Some(&(_, vn))) => vn,
                    (None, None) => 0.0,
                }
            })
            .collect()
    };
    let triad = |t: &Option<[Vec<f64>; 3]>| {
        t.as_ref()
            .map(|t| [column(&t[0]), column(&t[1]), column(&t[2])])
    };
    ImuRecording {
        t_s: t_s.to_vec(),
        gyro_rad_s: triad(&r.gyro_rad_s),
        accel_m_s2: triad(&r.accel_m_s2),
        ..Default::default()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_distr::{Distribution, Normal};

    const DT_S: f64 = 1e-3;

    /// A unit at the stamps `t_s`, each of its six channels `value(t)` at each stamp.
    fn unit_of(
        name: &str,
        t_s: Vec<f64>,
        mut value: impl FnMut(f64) -> f64,
    ) -> (String, ImuRecording) {
        let mut series = || t_s.iter().map(|t| value(*t)).collect::<Vec<f64>>();
        let recording = ImuRecording {
            gyro_rad_s: Some([series(), series(), series()]),
            accel_m_s2: Some([series(), series(), series()]),
            t_s,
            ..Default::default()
        };
        (name.to_string(), recording)
    }

    /// A unit of white noise at the stamps `t_s`.
    fn unit(name: &str, t_s: Vec<f64>) -> (String, ImuRecording) {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(t_s.len() as u64);
        let noise = Normal::new(0.0, 1.0).unwrap();
        unit_of(name, t_s, |_| noise.sample(&mut rng))
    }

    /// Which of unit `k`'s samples stands at each grid time (None: none, a slot its clock
    /// passed over), from the grid's offsets.
    fn held(grid: &Grid, k: usize, r: &ImuRecording) -> Vec<Option<usize>> {
        grid.t_s
            .iter()
            .zip(&grid.offset_s[k])
            .map(|(t, o)| {
                (*o != 0.0 || k == grid.anchor).then(|| {
                    let taken = t + o;
                    let above = r.t_s.partition_point(|s| *s < taken).min(r.len() - 1);
                    if above > 0 && taken - r.t_s[above - 1] < r.t_s[above] - taken {
                        above - 1
                    } else {
                        above
                    }
                })
            })
            .collect()
    }

    /// `n` stamps of a clock `rate_offset` fast (a fraction), starting `start_s`, each
    /// with a Gaussian jitter of `jitter_s`.
    fn stamps(n: usize, rate_offset: f64, start_s: f64, jitter_s: f64, seed: u64) -> Vec<f64> {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        let jitter = Normal::new(0.0, jitter_s).unwrap();
        (0..n)
            .map(|i| start_s + i as f64 * DT_S / (1.0 + rate_offset) + jitter.sample(&mut rng))
            .collect()
    }

    /// Three units on crystals 100 ppm and 160 ppm apart slide through many intervals
    /// against each other over 200 s: every sample is placed once, in order, within three
    /// quarters of an interval; the slots the slower clocks pass over are not dropouts;
    /// each rate is measured.
    #[test]
    fn units_on_their_own_crystals_are_placed_by_their_phase() {
        let n = 200_000;
        let units = [
            unit("a", stamps(n, 0.0, 0.0, 2e-6, 1)),
            unit("b", stamps(n, 100e-6, 0.3e-3, 2e-6, 2)),
            unit("c", stamps(n, -60e-6, -0.2e-3, 2e-6, 3)),
        ];
        let grid = common_grid(&units, None).unwrap();
        assert_eq!(
            grid.anchor, 1,
            "the fastest clock has the most samples in the span"
        );
        for (k, expected) in [(0, -100e-6), (2, -160e-6)] {
            assert!(
                (grid.rate_offset[k] - expected).abs() < 2e-6,
                "unit {k}: {}",
                grid.rate_offset[k]
            );
        }
        for (k, (_, r)) in units.iter().enumerate() {
            let missing: Vec<usize> = (0..grid.t_s.len())
                .filter(|&i| !grid.present[k][i])
                .collect();
            assert!(
                missing.is_empty(),
                "unit {k}: dropouts at {missing:?} of {}",
                grid.t_s.len()
            );
            let furthest = grid.offset_s[k].iter().fold(0.0_f64, |m, o| m.max(o.abs()));
            assert!(furthest < 0.8 * DT_S, "unit {k}: {furthest}");
            // Placed samples in order, none twice; the slower clocks lose 100 and 160 ppm of
            // 200 000 slots: 20 and 32 filled.
            let held = held(&grid, k, r);
            let placed: Vec<usize> = held.iter().flatten().copied().collect();
            assert!(placed.windows(2).all(|w| w[1] > w[0]), "unit {k}");
            let lost = [20, 0, 32][k];
            let empty = held.iter().filter(|h| h.is_none()).count();
            assert!(
                empty.abs_diff(lost) <= 2,
                "unit {k}: {empty} slots passed over"
            );
            // All but those after the fastest clock stopped (the shared span ends there).
            assert!(
                placed.len() + 40 >= r.len(),
                "unit {k}: {} placed",
                placed.len()
            );
        }
    }

    /// A unit half an interval off the others with a jitter of a twentieth of one stays in
    /// its slots: the phase is smoothed, and it steps only past three quarters.
    #[test]
    fn a_phase_near_half_an_interval_does_not_step_back_and_forth() {
        let n = 20_000;
        let units = [
            unit("a", stamps(n, 0.0, 0.0, 1e-6, 4)),
            unit("b", stamps(n, 0.0, 0.0, 1e-6, 5)),
            unit("c", stamps(n, 0.0, 0.5e-3, 0.05e-3, 6)),
        ];
        let grid = common_grid(&units, None).unwrap();
        let held: Vec<Option<usize>> = held(&grid, 2, &units[2].1);
        let stepped = held
            .windows(2)
            .filter(|w| w[1] != w[0].map(|i| i + 1))
            .count();
        assert_eq!(stepped, 0, "unit c stepped");
        assert!(grid.rate_offset[2].abs() < 1e-6);
    }

    /// A unit sampled 0.4 of an interval after the others on a motion of a 3 Hz turn and a
    /// 21 Hz vibration (at 100 Hz) is carried to the shared times: its difference from
    /// another unit is their noises (0.01 each), where as sampled it is 0.12 RMS.
    #[test]
    fn a_late_units_motion_is_carried_to_the_shared_times() {
        let (n, dt) = (20_000, 0.01);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(13);
        let noise = Normal::new(0.0, 0.01).unwrap();
        let tau = std::f64::consts::TAU;
        let mut unit = |name: &str, late: f64| {
            let t_s: Vec<f64> = (0..n).map(|i| (i as f64 + late) * dt).collect();
            unit_of(name, t_s, |t| {
                (tau * 3.0 * t).sin() + 0.5 * (tau * 21.3 * t).sin() + noise.sample(&mut rng)
            })
        };
        let units = [unit("a", 0.0), unit("b", 0.0), unit("c", 0.4)];
        let grid = common_grid(&units, None).unwrap();
        let rms = |x: &[f64], y: &[f64]| {
            let inner = 100..x.len() - 100;
            let sum: f64 = inner.clone().map(|i| (x[i] - y[i]).powi(2)).sum();
            (sum / inner.len() as f64).sqrt()
        };
        let gx = |k: usize| &grid.filled[k].1.gyro_rad_s.as_ref().unwrap()[0];
        let as_sampled = rms(&units[2].1.gyro_rad_s.as_ref().unwrap()[0], gx(0));
        let carried = rms(gx(2), gx(0));
        assert!(as_sampled > 0.1, "{as_sampled}");
        assert!(
            (0.013..0.016).contains(&carried),
            "{carried} (as sampled {as_sampled})"
        );
    }

    /// A unit that misses samples has dropouts there, and nowhere else.
    #[test]
    fn a_dropout_is_missing_and_nothing_else_is() {
        let n = 5_000;
        let mut c = stamps(n, 0.0, 0.0, 2e-6, 9);
        c.drain(2_000..2_005);
        let units = [
            unit("a", stamps(n, 0.0, 0.0, 2e-6, 7)),
            unit("b", stamps(n, 0.0, 0.0, 2e-6, 8)),
            unit("c", c),
        ];
        let grid = common_grid(&units, None).unwrap();
        let missing: Vec<usize> = (0..grid.t_s.len())
            .filter(|&i| !grid.present[2][i])
            .collect();
        assert_eq!(missing, (2_000..2_005).collect::<Vec<_>>());
        assert!(grid.present[..2].iter().flatten().all(|p| *p));
    }

    /// A unit whose clock is 1% off is on another clock: refused, its rate named.
    #[test]
    fn a_unit_at_another_rate_is_refused() {
        let n = 5_000;
        let units = [
            unit("a", stamps(n, 0.0, 0.0, 2e-6, 10)),
            unit("b", stamps(n, 0.0, 0.0, 2e-6, 11)),
            unit("c", stamps(n, -0.01, 0.0, 2e-6, 12)),
        ];
        let Err(RedundancyError::Unit { name, message }) = common_grid(&units, None) else {
            panic!("accepted");
        };
        assert_eq!(name, "c");
        assert!(
            message.contains("-0.99") && message.contains("sampled together"),
            "{message}"
        );
    }
}
