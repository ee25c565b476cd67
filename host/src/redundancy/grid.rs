//! The units' common time grid. Units sampled together share their time stamps, but a unit
//! may miss samples (a dropout: its file has no row at that time). The grid is every time
//! at least two units share (to a quarter of the sample interval) within the span all units
//! cover; a unit with more than 1% of its samples at times no other unit has is on another
//! clock, and refused. For the
//! run-long analyses (alignment, wavelet variances) a missing sample is filled by linear
//! interpolation of the unit's own neighbours; the fault monitor sees it as missing.

use super::RedundancyError;
use crate::interchange::ImuRecording;

/// The units on their common grid.
pub(super) struct Grid {
    pub t_s: Vec<f64>,
    /// `present[k][i]`: unit k has a sample at grid time i.
    pub present: Vec<Vec<bool>>,
    /// Each unit on the grid, missing samples filled.
    pub filled: Vec<(String, ImuRecording)>,
}

/// Largest share of a unit's samples at times no other unit has.
const LONELY_MAX: f64 = 0.01;
/// Fewest samples the units must share: the wavelet variances' shortest record.
const MIN_SHARED_SAMPLES: usize = 64;
/// Smallest share of the grid a unit must cover.
const COVERAGE_MIN: f64 = 0.5;

/// The grid of `units` (3 or more, checked by the caller), or why they were not sampled
/// together.
pub(super) fn common_grid(units: &[(String, ImuRecording)]) -> Result<Grid, RedundancyError> {
    let dt_s = units
        .iter()
        .map(|(_, r)| r.median_dt_s())
        .fold(f64::INFINITY, f64::min);
    // The span every unit covers: a unit that starts late or stops early has no dropouts
    // outside it.
    let start_s = units
        .iter()
        .map(|(_, r)| r.t_s[0])
        .fold(f64::NEG_INFINITY, f64::max);
    let end_s = units
        .iter()
        .map(|(_, r)| r.t_s[r.len() - 1])
        .fold(f64::INFINITY, f64::min);
    if !(end_s - start_s >= MIN_SHARED_SAMPLES as f64 * dt_s) {
        let spans: Vec<String> = units
            .iter()
            .map(|(name, r)| format!("{name} {} .. {} s", r.t_s[0], r.t_s[r.len() - 1]))
            .collect();
        return Err(RedundancyError::NoOverlap(format!(
            "the units' recordings share {:.3} s, fewer than {MIN_SHARED_SAMPLES} samples: {}",
            (end_s - start_s).max(0.0),
            spans.join(", ")
        )));
    }
    let tolerance = 0.25 * dt_s;
    let mut stamps: Vec<(f64, usize, usize)> = units
        .iter()
        .enumerate()
        .flat_map(|(k, (_, r))| r.t_s.iter().enumerate().map(move |(i, t)| (*t, k, i)))
        .filter(|(t, _, _)| *t >= start_s - tolerance && *t <= end_s + tolerance)
        .collect();
    stamps.sort_by(|a, b| a.0.total_cmp(&b.0));
    let n_units = units.len();
    let mut t_s = Vec::new();
    let mut index: Vec<Vec<Option<usize>>> = vec![Vec::new(); n_units];
    let mut lonely = vec![0usize; n_units];
    let mut start = 0;
    while start < stamps.len() {
        let mut end = start + 1;
        while end < stamps.len() && stamps[end].0 - stamps[start].0 <= tolerance {
            end += 1;
        }
        let cluster = &stamps[start..end];
        if cluster.len() >= 2 {
            t_s.push(cluster[0].0);
            for column in index.iter_mut() {
                column.push(None);
            }
            for &(_, k, i) in cluster {
                let slot = index[k].last_mut().expect("pushed");
                slot.get_or_insert(i);
            }
        } else {
            lonely[cluster[0].1] += 1;
        }
        start = end;
    }
    for (k, (name, r)) in units.iter().enumerate() {
        let fail = |message: String| RedundancyError::Unit {
            name: name.clone(),
            message,
        };
        let in_span = r
            .t_s
            .iter()
            .filter(|t| **t >= start_s - tolerance && **t <= end_s + tolerance)
            .count();
        if lonely[k] as f64 > LONELY_MAX * in_span as f64 {
            return Err(fail(format!(
                "{} of its {} samples are at times no other unit has (first times {} s and {} s): \
                 the units must be sampled together, on one clock",
                lonely[k],
                r.len(),
                r.t_s[0],
                units[(k + 1) % n_units].1.t_s[0]
            )));
        }
        let covered = index[k].iter().filter(|i| i.is_some()).count();
        if (covered as f64) < COVERAGE_MIN * t_s.len() as f64 {
            return Err(fail(format!(
                "has samples at {covered} of the {} times the units share: the units must be \
                 sampled together",
                t_s.len()
            )));
        }
    }
    let filled = units
        .iter()
        .zip(&index)
        .map(|((name, r), idx)| (name.clone(), fill(r, idx, &t_s)))
        .collect();
    let present = index
        .iter()
        .map(|idx| idx.iter().map(Option::is_some).collect())
        .collect();
    Ok(Grid {
        t_s,
        present,
        filled,
    })
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
