//! The refit loop's host half (`dynacal refit`): from a board log, each unit's error model
//! and alignment, as the typed model (`model.json`) and the blob the board runs
//! (`board-model.bin`, `dynacal_core::board_model`).
//!
//! 1. The board's streaming wavelet variances are checked against the same variances
//!    computed here from the logged samples: the full (overlapping) levels must equal the
//!    batch estimator's to rounding; a decimated level is a different estimator of the same
//!    variance, so its 95% interval must overlap the batch one's. A disagreement means the
//!    log lost samples or the board's accumulators are wrong, and the refit stops (unless
//!    the log itself says it dropped frames, which is then noted).
//! 2. The units' own errors come from their differences (`crate::redundancy`): the motion
//!    cancels, so a log of a drive gives the units' error wavelet variances, which a raw
//!    variance of a moving sensor would not; the alignment of each unit to the first comes
//!    from the same analysis.
//! 3. Each unit's channels are fitted by the GMWM (`crate::gmwm`) on those own variances,
//!    with intervals from a bootstrap of the whole hat ([`hat_bootstrap`]), and mapped to
//!    what the board's filter runs ([`channel_noise`]).

use std::collections::BTreeMap;

use dynacal_core::board_model::{BoardModel, ChannelNoise, UnitModel};
use dynacal_core::Channel;
use serde::Serialize;

use std::path::Path;

use crate::calibration::{Samples, SpillBuilder, SpilledRecording};
use crate::decode::{decode_file_streamed, sample_si, BoardChannelWv, DecodedLog};
use crate::gmwm::fit::{FitInput, FitOptions};
use crate::gmwm::inference::{
    analyze, refit_replicate, set_bootstrap_intervals, BootstrapOptions, ChannelFit, ModelChoice,
};
use crate::gmwm::model::{ModelSimulation, ModelSpec, Process, Structure};
use crate::interchange::ImuRecording;
use crate::model::SimModel;
use crate::redundancy::{redundancy, Alignment, OwnWv, RedundancyOptions, RotationBasis};
use crate::wv::stream::HaarWvStream;
use crate::wv::{haar_wv, level_coefficients, WaveletVariance, WvOptions};

/// Why a log cannot be refitted.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum RefitError {
    #[error("the log has {0} IMUs with samples; the refit needs the board's three (or more)")]
    Units(usize),
    #[error("IMU {imu_id} {channel}: the board's wavelet variance disagrees with the logged samples' ({detail})")]
    WvDisagrees {
        imu_id: u8,
        channel: Channel,
        detail: String,
    },
    #[error(transparent)]
    Redundancy(#[from] crate::redundancy::RedundancyError),
    #[error(transparent)]
    Decode(#[from] crate::decode::DecodeError),
    /// The log's samples could not be spilled or read back (the temporary folder).
    #[error(transparent)]
    Spill(#[from] crate::calibration::ErrorsError),
    #[error("IMU {imu_id} {channel}: {detail}")]
    Fit {
        imu_id: u8,
        channel: Channel,
        detail: String,
    },
}

/// How one channel's board wavelet variance compares with the logged samples'.
#[derive(Debug, Clone, Serialize)]
pub struct WvAgreement {
    pub imu_id: u8,
    pub channel: Channel,
    /// Full levels compared, and their largest relative difference.
    pub full_levels: usize,
    pub full_max_relative_difference: f64,
    /// Decimated levels compared, and those whose 95% interval misses the batch one.
    pub decimated_levels: usize,
    pub decimated_disjoint: usize,
}

/// What the refit found of one unit.
#[derive(Debug, Clone, Serialize)]
pub struct UnitRefit {
    pub imu_id: u8,
    pub name: String,
    pub alignment: Alignment,
    /// The GMWM fit of each channel's own error.
    pub fits: Vec<ChannelFit>,
}

impl UnitRefit {
    /// The fit of `channel` (fits are named `unit/channel`).
    fn fit_of(&self, channel: Channel) -> Option<&ChannelFit> {
        self.fits
            .iter()
            .find(|f| f.channel.ends_with(channel.name()))
    }

    fn fit_mut_of(&mut self, channel: Channel) -> Option<&mut ChannelFit> {
        self.fits
            .iter_mut()
            .find(|f| f.channel.ends_with(channel.name()))
    }
}

/// The refit of a log.
#[derive(Debug, Clone, Serialize)]
pub struct Refit {
    pub agreement: Vec<WvAgreement>,
    pub units: Vec<UnitRefit>,
    /// What the board runs.
    pub board_model: BoardModel,
    pub notes: Vec<String>,
}

/// Options of [`refit`].
#[derive(Debug, Clone)]
pub struct RefitOptions {
    pub choice: ModelChoice,
    /// The intervals' bootstrap of the units' hat ([`hat_bootstrap`]); None: the delta
    /// method's intervals, too narrow for variances from the units' differences.
    pub bootstrap: Option<BootstrapOptions>,
}

/// A unit of the log: its IMU id, name, samples and sampling interval (s).
struct LogUnit {
    imu_id: u8,
    name: String,
    samples: usize,
    dt_s: f64,
}

/// The refit of `log`, its samples held (see the module's note).
pub fn refit(log: &DecodedLog, options: &RefitOptions) -> Result<Refit, RefitError> {
    let units: Vec<(u8, String, ImuRecording)> = log
        .imus
        .iter()
        .filter(|imu| !imu.is_empty())
        .map(|imu| {
            let id = imu.config.imu_id;
            (id, format!("imu{id}"), imu.to_recording())
        })
        .collect();
    if units.len() < 3 {
        return Err(RefitError::Units(units.len()));
    }
    let mut notes = Vec::new();
    let agreement = check_board_wv(log, &mut notes, |snapshot, board| {
        let (_, _, recording) = units.iter().find(|(id, _, _)| *id == snapshot.imu_id)?;
        let values = recording
            .channel(snapshot.channel.name())
            .unwrap_or_default();
        let n = (snapshot.n_samples as usize).min(values.len());
        Some(haar_wv(&values[..n], board.dt_s, &WvOptions::default()).map_err(|e| e.to_string()))
    })?;
    let named: Vec<(String, ImuRecording)> = units
        .iter()
        .map(|(_, n, r)| (n.clone(), r.clone()))
        .collect();
    let report = redundancy(&named, &RedundancyOptions::default())?;
    let log_units = units
        .iter()
        .map(|(imu_id, name, r)| LogUnit {
            imu_id: *imu_id,
            name: name.clone(),
            samples: r.len(),
            dt_s: r.median_dt_s(),
        })
        .collect();
    refit_units(log_units, usize::MAX, report, agreement, notes, options)
}

/// The refit of the board log at `path`, in memory that does not grow with it: the log is
/// decoded once, each IMU's samples written to a spill file as they come; the board's
/// snapshots are checked on one pass over each spill, and the units' analysis reads them
/// stretch by stretch of `stretch_epochs` shared times
/// ([`crate::redundancy::redundancy_of_spills`]).
pub fn refit_file(
    path: &Path,
    options: &RefitOptions,
    stretch_epochs: usize,
) -> Result<Refit, RefitError> {
    let mut spills: BTreeMap<u8, SpillBuilder> = BTreeMap::new();
    let log = decode_file_streamed(path, |config, set| -> Result<(), RefitError> {
        let spill = match spills.entry(config.imu_id) {
            std::collections::btree_map::Entry::Occupied(e) => e.into_mut(),
            std::collections::btree_map::Entry::Vacant(e) => {
                e.insert(SpillBuilder::new(path, [true, true, false, false, false])?)
            }
        };
        spill.push(&sample_si(config, set))?;
        Ok(())
    })?;
    log.validate(path)?;
    let mut units: Vec<(LogUnit, SpilledRecording)> = Vec::new();
    for imu in log.imus.iter().filter(|imu| !imu.is_empty()) {
        let id = imu.config.imu_id;
        let Some(spill) = spills.remove(&id) else {
            continue;
        };
        let spilled = spill.finish()?;
        let unit = LogUnit {
            imu_id: id,
            name: format!("imu{id}"),
            samples: spilled.len(),
            dt_s: spilled.median_step_s()?.unwrap_or(0.0),
        };
        units.push((unit, spilled));
    }
    if units.len() < 3 {
        return Err(RefitError::Units(units.len()));
    }
    let mut notes = Vec::new();
    let batches = snapshot_batches(&log, &units)?;
    let agreement = check_board_wv(&log, &mut notes, |snapshot, _| {
        batches
            .iter()
            .find(|(id, channel, _)| *id == snapshot.imu_id && *channel == snapshot.channel)
            .map(|(_, _, wv)| wv.clone())
    })?;
    let (log_units, named): (Vec<LogUnit>, Vec<(String, SpilledRecording)>) = units
        .into_iter()
        .map(|(unit, spilled)| {
            let name = unit.name.clone();
            (unit, (name, spilled))
        })
        .unzip();
    let report = crate::redundancy::redundancy_of_spills(
        named,
        &RedundancyOptions::default(),
        None,
        stretch_epochs,
    )?
    .report;
    refit_units(log_units, stretch_epochs, report, agreement, notes, options)
}

/// The estimator of the logged samples each board snapshot is checked against, from one
/// pass over each unit's spill: per IMU and channel, the wavelet variance of the samples
/// the snapshot covers, streamed with at least the snapshot's full levels (so those equal
/// the batch estimator's to rounding).
fn snapshot_batches(
    log: &DecodedLog,
    units: &[(LogUnit, SpilledRecording)],
) -> Result<SnapshotBatches, RefitError> {
    let snapshots: Vec<BoardChannelWv> = log
        .wavelet_variance_si()
        .into_iter()
        .filter(|s| s.wv.is_some())
        .collect();
    let mut out = Vec::new();
    for (unit, spilled) in units {
        let mut mine: Vec<&BoardChannelWv> = snapshots
            .iter()
            .filter(|s| s.imu_id == unit.imu_id)
            .collect();
        if mine.is_empty() {
            continue;
        }
        mine.sort_by_key(|s| s.n_samples);
        let full = mine
            .iter()
            .map(|s| u32::from(s.full_levels))
            .max()
            .unwrap_or(0);
        let mut streams: Vec<HaarWvStream> = Channel::ALL
            .iter()
            .map(|_| HaarWvStream::new(full.max(HaarWvStream::COMPACT_FULL_LEVELS)))
            .collect();
        let mut fed = 0usize;
        for snapshot in mine {
            let n = (snapshot.n_samples as usize).min(spilled.len());
            while fed < n {
                let end = (fed + (1 << 16)).min(n);
                let rows = spilled.rows(fed..end)?.0;
                for (c, stream) in streams.iter_mut().enumerate() {
                    if let Some(values) = rows.channel(Channel::ALL[c].name()) {
                        stream.push_block(values);
                    }
                }
                fed = end;
            }
            let c = Channel::ALL.iter().position(|c| *c == snapshot.channel);
            let dt_s = snapshot.wv.as_ref().map_or(unit.dt_s, |w| w.dt_s);
            if let Some(c) = c {
                out.push((
                    snapshot.imu_id,
                    snapshot.channel,
                    streams[c]
                        .wavelet_variance(None, 1.0, dt_s)
                        .map_err(|e| e.to_string()),
                ));
            }
        }
    }
    Ok(out)
}

/// Per IMU and channel, the logged samples' wavelet variance a snapshot is checked against.
type SnapshotBatches = Vec<(u8, Channel, Result<WaveletVariance, String>)>;

/// The refit from the units' analysis: each unit's channels fitted on its own wavelet
/// variances, the bootstrap's intervals (simulated `block` samples at a time,
/// [`hat_bootstrap`]), the board's model.
fn refit_units(
    units: Vec<LogUnit>,
    block: usize,
    report: crate::redundancy::RedundancyReport,
    agreement: Vec<WvAgreement>,
    mut notes: Vec<String>,
    options: &RefitOptions,
) -> Result<Refit, RefitError> {
    notes.extend(report.notes.iter().cloned());
    let mut unit_refits = Vec::new();
    for (unit, own) in units.iter().zip(&report.imus) {
        let fits = fit_unit(unit, &own.wv, options)?;
        unit_refits.push(UnitRefit {
            imu_id: unit.imu_id,
            name: unit.name.clone(),
            alignment: own.alignment.clone(),
            fits,
        });
    }
    if let Some(b) = options.bootstrap.filter(|b| b.replicates > 0) {
        hat_bootstrap(&mut unit_refits, units[0].samples, units[0].dt_s, block, b);
    }
    let board_model = board_model_of(&unit_refits, &mut notes);
    Ok(Refit {
        agreement,
        units: unit_refits,
        board_model,
        notes,
    })
}

/// Checks every board snapshot against the estimator on the logged samples it covers
/// (`batch(snapshot, board)`: None where the log has no samples of its IMU).
fn check_board_wv(
    log: &DecodedLog,
    notes: &mut Vec<String>,
    batch: impl Fn(&BoardChannelWv, &WaveletVariance) -> Option<Result<WaveletVariance, String>>,
) -> Result<Vec<WvAgreement>, RefitError> {
    let board = log.wavelet_variance_si();
    if board.is_empty() {
        notes.push("the log holds no wavelet-variance snapshots: nothing to check".into());
    }
    let frames_dropped =
        log.stream.frames_dropped > 0 || log.health.iter().any(|h| h.frames_dropped > 0);
    let mut out = Vec::new();
    for snapshot in &board {
        let Some(board_wv) = &snapshot.wv else {
            notes.push(format!(
                "imu{} {}: the board's snapshot is unusable: {}",
                snapshot.imu_id,
                snapshot.channel,
                snapshot.error.as_deref().unwrap_or("unknown")
            ));
            continue;
        };
        let Some(logged) = batch(snapshot, board_wv) else {
            continue;
        };
        let logged = logged.map_err(|e| RefitError::WvDisagrees {
            imu_id: snapshot.imu_id,
            channel: snapshot.channel,
            detail: format!("no batch variance of the logged samples: {e}"),
        })?;
        let agreement = compare_wv(snapshot, board_wv, &logged);
        let disagrees =
            agreement.full_max_relative_difference > 1e-6 || agreement.decimated_disjoint > 0;
        if disagrees && !frames_dropped {
            return Err(RefitError::WvDisagrees {
                imu_id: snapshot.imu_id,
                channel: snapshot.channel,
                detail: format!(
                    "full levels differ by up to {:.2e} (relative), {} of {} decimated levels' intervals miss",
                    agreement.full_max_relative_difference,
                    agreement.decimated_disjoint,
                    agreement.decimated_levels
                ),
            });
        }
        if disagrees {
            notes.push(format!(
                "imu{} {}: the board's wavelet variance differs from the logged samples', which the log's dropped frames explain",
                snapshot.imu_id, snapshot.channel
            ));
        }
        out.push(agreement);
    }
    Ok(out)
}

/// One channel's comparison: the board snapshot against the wavelet variance of the
/// samples it covers (the log's samples up to the snapshot's time).
fn compare_wv(
    snapshot: &BoardChannelWv,
    board: &WaveletVariance,
    batch: &WaveletVariance,
) -> WvAgreement {
    let channel = snapshot.channel;
    let mut agreement = WvAgreement {
        imu_id: snapshot.imu_id,
        channel,
        full_levels: 0,
        full_max_relative_difference: 0.0,
        decimated_levels: 0,
        decimated_disjoint: 0,
    };
    for (i, &level) in board.levels.iter().enumerate() {
        let Some(k) = batch.levels.iter().position(|&j| j == level) else {
            continue;
        };
        let (b, h) = (board.variance[i], batch.variance[k]);
        if level <= u32::from(snapshot.full_levels) {
            agreement.full_levels += 1;
            let relative = if h > 0.0 {
                ((b - h) / h).abs()
            } else {
                (b - h).abs()
            };
            agreement.full_max_relative_difference =
                agreement.full_max_relative_difference.max(relative);
        } else {
            agreement.decimated_levels += 1;
            let overlap =
                board.ci_low[i] <= batch.ci_high[k] && batch.ci_low[k] <= board.ci_high[i];
            agreement.decimated_disjoint += usize::from(!overlap);
        }
    }
    agreement
}

/// A unit's own-error WV of one channel as a wavelet variance the GMWM fits: the levels
/// whose variance the least squares did not clamp at zero.
fn own_as_wv(own: &OwnWv, n: usize, dt_s: f64) -> WaveletVariance {
    let mut wv = WaveletVariance {
        scales_s: Vec::new(),
        levels: Vec::new(),
        variance: Vec::new(),
        ci_low: Vec::new(),
        ci_high: Vec::new(),
        allan_variance: Vec::new(),
        n,
        n_coefficients: Vec::new(),
        robust: false,
        dt_s,
    };
    for (i, &scale) in own.scales_s.iter().enumerate() {
        if own.clamped[i] || !(own.variance[i] > 0.0) {
            continue;
        }
        let level = (scale / dt_s).log2().round() as u32;
        wv.scales_s.push(scale);
        wv.levels.push(level);
        wv.variance.push(own.variance[i]);
        wv.ci_low.push(own.ci_low[i]);
        wv.ci_high.push(own.ci_high[i]);
        wv.allan_variance.push(2.0 * own.variance[i]);
        wv.n_coefficients.push(level_coefficients(n, level));
    }
    wv
}

/// The GMWM fit of each of a unit's channels on its own-error variances.
fn fit_unit(
    unit: &LogUnit,
    own: &BTreeMap<String, OwnWv>,
    options: &RefitOptions,
) -> Result<Vec<ChannelFit>, RefitError> {
    let (imu_id, name, dt_s) = (unit.imu_id, unit.name.as_str(), unit.dt_s);
    Channel::ALL
        .into_iter()
        .filter_map(|channel| own.get(channel.name()).map(|w| (channel, w)))
        .map(|(channel, w)| {
            let err = |detail: String| RefitError::Fit {
                imu_id,
                channel,
                detail,
            };
            let wv = own_as_wv(w, unit.samples, dt_s);
            let input = FitInput::from_wv(&wv).map_err(|e| err(e.to_string()))?;
            let unit = if channel.is_gyro() { "rad/s" } else { "m/s^2" };
            // Intervals by the delta method here; a bootstrap must simulate the units'
            // hat, not one series ([`hat_bootstrap`]).
            analyze(
                &format!("{name}/{}", channel.name()),
                unit,
                &input,
                &options.choice,
                None,
                &FitOptions::default(),
            )
            .map_err(|e| err(e.to_string()))
        })
        .collect()
}

/// Intervals that hold what the refit is uncertain of: a parametric bootstrap of the whole
/// analysis. Each replicate simulates every unit's channel from its fitted model (`n`
/// samples, seeded: ChaCha8 from `b.seed`, one stream per channel and replicate, so the
/// draws do not depend on the thread count), takes their own wavelet variances through the
/// same N-cornered hat ([`crate::redundancy::own_wv_of_blocks`]) and refits each unit on
/// the levels its fit used. The series are simulated `block` samples at a time: a log
/// refitted stretch by stretch gives its stretch, so a replicate holds a block of each unit,
/// not the log, and its pairs' wavelet variances are streamed as the log's were (a held
/// log gives `usize::MAX`: one block, the batch estimator). A single-series bootstrap would miss the hat's own variance (the
/// pairs' differences of large numbers, 2.5 times a single unit's at the white noise's
/// scales with three units) and the trade between a short-record Gauss-Markov term and the
/// white noise; the delta method misses both. The simulated units hold no motion, so what
/// the alignment leaves in the real differences is not in the intervals.
fn hat_bootstrap(units: &mut [UnitRefit], n: usize, dt_s: f64, block: usize, b: BootstrapOptions) {
    use rand::SeedableRng;
    use rayon::prelude::*;
    let replicates_each = b.replicates as u64;
    let tally = crate::progress::Tally::default();
    tally.expect(Channel::ALL.len() as u64 * replicates_each);
    for (c, channel) in Channel::ALL.into_iter().enumerate() {
        let fits: Option<Vec<ChannelFit>> =
            units.iter().map(|u| u.fit_of(channel).cloned()).collect();
        let structures: Option<Vec<Structure>> = fits.as_ref().and_then(|fits| {
            fits.iter()
                .map(|f| Structure::parse(&f.model).ok())
                .collect()
        });
        let (Some(fits), Some(structures)) = (fits, structures) else {
            tally.finish(replicates_each);
            continue;
        };
        let draws: Vec<Vec<Option<Vec<f64>>>> = (0..b.replicates)
            .into_par_iter()
            .map(|r| {
                let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(b.seed);
                rng.set_stream((c * b.replicates + r) as u64);
                let mut simulations: Vec<ModelSimulation> = fits
                    .iter()
                    .map(|f| ModelSimulation::new(&f.model_object))
                    .collect();
                let own = crate::redundancy::own_wv_of_blocks(fits.len(), n, block, dt_s, |len| {
                    simulations
                        .iter_mut()
                        .map(|s| s.next_block(len, &mut rng))
                        .collect()
                });
                let refits = fits
                    .iter()
                    .zip(&structures)
                    .zip(&own)
                    .map(|((fit, structure), own)| refit_own(fit, structure, own, n, dt_s))
                    .collect();
                tally.finish_one();
                refits
            })
            .collect();
        for (k, unit) in units.iter_mut().enumerate() {
            let replicates: Vec<Vec<f64>> = draws.iter().filter_map(|d| d[k].clone()).collect();
            let method = format!(
                "bootstrap of the N-cornered hat, bias-corrected percentiles (B={}, seed={}, converged replicates={})",
                b.replicates,
                b.seed,
                replicates.len()
            );
            if let Some(fit) = unit.fit_mut_of(channel) {
                set_bootstrap_intervals(fit, &replicates, method);
            }
        }
    }
}

/// One bootstrap refit of a unit's channel on a simulated own wavelet variance, at the
/// levels its fit used; None when the fit does not converge.
fn refit_own(
    fit: &ChannelFit,
    structure: &Structure,
    own: &OwnWv,
    n: usize,
    dt_s: f64,
) -> Option<Vec<f64>> {
    let input = FitInput::from_wv(&own_as_wv(own, n, dt_s))
        .ok()?
        .at_levels(&fit.levels);
    refit_replicate(structure, &input, &fit.theta, &FitOptions::default())
}

/// Inverse correlation time (1/s) at and below which a Gauss-Markov term is a bias to the
/// board's filter; faster ones are white noise to it.
pub const SLOWEST_WHITE_BETA_PER_S: f64 = 1.0;

/// What the board's filter runs of a fitted channel model: white noise as a PSD, the
/// largest Gauss-Markov term of a second or longer as its bias, a random walk as a PSD. Other Gauss-Markov terms
/// join the white noise when their correlation time is under a second (the filter cannot
/// tell them from it) and the random walk otherwise (their driving PSD); quantization noise
/// joins the white noise; a drift is not run (returned in the second value, named).
pub fn channel_noise(spec: &ModelSpec) -> (ChannelNoise, Vec<&'static str>) {
    let dt_s = 1.0 / spec.sample_rate_hz;
    let mut noise = ChannelNoise {
        white_psd: 0.0,
        gauss_markov_sigma2: 0.0,
        gauss_markov_tau_s: 0.0,
        random_walk_psd: 0.0,
    };
    let mut white = 0.0f64;
    let mut walk = 0.0f64;
    let mut left_out = Vec::new();
    // The filter's bias state is the largest Gauss-Markov term slow enough to be a bias:
    // one of a millisecond is white noise to a filter predicting every 10 ms.
    let main_gm = spec
        .processes
        .iter()
        .filter_map(|p| match *p {
            Process::GaussMarkov { beta_per_s, sigma2 }
                if beta_per_s <= SLOWEST_WHITE_BETA_PER_S =>
            {
                Some((beta_per_s, sigma2))
            }
            _ => None,
        })
        .fold(None, |best: Option<(f64, f64)>, gm| match best {
            Some(b) if b.1 >= gm.1 => Some(b),
            _ => Some(gm),
        });
    for p in &spec.processes {
        match *p {
            Process::WhiteNoise { sigma2 } => white += sigma2 * dt_s,
            Process::QuantizationNoise { q2 } => white += q2 * dt_s,
            Process::RandomWalk { sigma2 } => walk += sigma2 / dt_s,
            Process::Drift { .. } => left_out.push("drift"),
            Process::GaussMarkov { beta_per_s, sigma2 } => {
                if Some((beta_per_s, sigma2)) == main_gm {
                    noise.gauss_markov_sigma2 = sigma2 as f32;
                    noise.gauss_markov_tau_s = (1.0 / beta_per_s) as f32;
                } else if beta_per_s > SLOWEST_WHITE_BETA_PER_S {
                    white += 2.0 * sigma2 / beta_per_s;
                } else {
                    walk += 2.0 * sigma2 * beta_per_s;
                }
            }
        }
    }
    noise.white_psd = white as f32;
    noise.random_walk_psd = walk as f32;
    (noise, left_out)
}

/// The board model of the refitted units: their channels' noise and alignments (a rotation
/// or lever arm the motion did not determine is left at the design's zero, and said).
fn board_model_of(units: &[UnitRefit], notes: &mut Vec<String>) -> BoardModel {
    let ids: Vec<u8> = units.iter().map(|u| u.imu_id).collect();
    let mut model = BoardModel::built_in(&ids);
    for (unit, target) in units.iter().zip(model.units.iter_mut()) {
        for fit in &unit.fits {
            let Some(channel) = fit
                .channel
                .rsplit('/')
                .next()
                .and_then(|c| c.parse::<Channel>().ok())
            else {
                continue;
            };
            let (noise, left_out) = channel_noise(&fit.model_object);
            for what in left_out {
                notes.push(format!(
                    "{}: the fitted {what} is not run on the board",
                    fit.channel
                ));
            }
            target.channels[channel.index()] = noise;
        }
        set_alignment(target, &unit.alignment, &unit.name, notes);
    }
    model
}

fn set_alignment(
    target: &mut UnitModel,
    alignment: &Alignment,
    name: &str,
    notes: &mut Vec<String>,
) {
    if alignment.basis == RotationBasis::Reference {
        // The first unit is the body frame: at its origin, along its axes, nothing to say.
        target.rotation_rpy_rad = [0.0; 3];
        target.lever_arm_m = [0.0; 3];
        return;
    }
    match alignment.rotation_rpy_deg {
        Some(rpy) => target.rotation_rpy_rad = rpy.map(|d| d.to_radians() as f32),
        None => notes.push(format!(
            "{name}: the motion did not determine its rotation; the board keeps the design's"
        )),
    }
    match alignment.lever_arm_m {
        Some(arm) => target.lever_arm_m = arm.map(|x| x as f32),
        None => notes.push(format!(
            "{name}: the motion did not determine its lever arm; the board keeps the design's"
        )),
    }
}

/// The typed model of a refit: each unit's fitted channel models (the simulator's model
/// format, loadable by `dynacal simulate` and `dynacal diagnose`), mounted where the
/// alignment put it relative to the first unit, with the fit statistics beside it.
pub fn typed_model(refit: &Refit) -> SimModel {
    let specs: Vec<(String, ModelSpec)> = refit
        .units
        .iter()
        .flat_map(|u| {
            u.fits
                .iter()
                .map(|f| (f.channel.clone(), f.model_object.clone()))
        })
        .collect();
    let (mut model, _) = SimModel::from_channel_models("imu", &specs);
    for (imu, unit) in model.imus.iter_mut().zip(&refit.units) {
        if let Some(arm) = unit.alignment.lever_arm_m {
            imu.lever_arm_b_m = arm;
        }
        if let Some([r, p, y]) = unit.alignment.rotation_rpy_deg {
            // The alignment's C takes the first unit's axes to this unit's; the model's
            // boresight angles are those of its transpose (the unit's axes to the body's).
            let c = nalgebra::Rotation3::from_euler_angles(
                r.to_radians(),
                p.to_radians(),
                y.to_radians(),
            );
            let (r, p, y) = c.transpose().euler_angles();
            imu.boresight_rpy_deg = [r.to_degrees(), p.to_degrees(), y.to_degrees()];
        }
    }
    model.comment = Some("refitted by dynacal refit from a board log".into());
    model.fit = serde_json::to_value(refit.units.iter().map(|u| &u.fits).collect::<Vec<_>>()).ok();
    model
}

#[cfg(test)]
mod tests {
    use super::*;

    fn spec(processes: Vec<Process>) -> ModelSpec {
        ModelSpec {
            model: String::new(),
            unit: "rad/s".into(),
            sample_rate_hz: 200.0,
            processes,
        }
    }

    #[test]
    fn fitted_processes_map_to_what_the_filter_runs() {
        let (noise, left_out) = channel_noise(&spec(vec![
            Process::WhiteNoise { sigma2: 2e-6 },
            Process::GaussMarkov {
                beta_per_s: 0.01,
                sigma2: 4e-7,
            },
            Process::GaussMarkov {
                beta_per_s: 50.0,
                sigma2: 1e-7,
            },
            Process::GaussMarkov {
                beta_per_s: 0.1,
                sigma2: 1e-8,
            },
            Process::RandomWalk { sigma2: 1e-12 },
            Process::Drift { slope_per_s: 1e-6 },
        ]));
        let dt = 1.0 / 200.0;
        let close = |a: f32, b: f64| ((f64::from(a) - b) / b).abs() < 1e-5;
        assert!(close(noise.white_psd, 2e-6 * dt + 2.0 * 1e-7 / 50.0));
        assert!(close(noise.gauss_markov_sigma2, 4e-7));
        assert!(close(noise.gauss_markov_tau_s, 100.0));
        assert!(close(noise.random_walk_psd, 1e-12 / dt + 2.0 * 1e-8 * 0.1));
        assert_eq!(left_out, vec!["drift"]);
    }

    #[test]
    fn a_fast_gauss_markov_term_is_white_noise_to_the_filter_however_large() {
        // As fitted on a 120 s drive at 1 kHz: a 0.55 ms term larger than the slow one.
        let (noise, _) = channel_noise(&spec(vec![
            Process::WhiteNoise { sigma2: 2.5e-3 },
            Process::GaussMarkov {
                beta_per_s: 1810.0,
                sigma2: 1.1e-3,
            },
            Process::GaussMarkov {
                beta_per_s: 0.05,
                sigma2: 1e-5,
            },
        ]));
        let dt = 1.0 / 200.0;
        let close = |a: f32, b: f64| ((f64::from(a) - b) / b).abs() < 1e-5;
        assert!(close(noise.gauss_markov_tau_s, 20.0));
        assert!(close(noise.gauss_markov_sigma2, 1e-5));
        assert!(close(noise.white_psd, 2.5e-3 * dt + 2.0 * 1.1e-3 / 1810.0));
        // With no slow term the filter's bias state stays off.
        let (noise, _) = channel_noise(&spec(vec![
            Process::WhiteNoise { sigma2: 2.5e-3 },
            Process::GaussMarkov {
                beta_per_s: 1810.0,
                sigma2: 1.1e-3,
            },
        ]));
        assert_eq!(
            (noise.gauss_markov_sigma2, noise.gauss_markov_tau_s),
            (0.0, 0.0)
        );
    }
}
