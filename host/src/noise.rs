//! `dynacal noise`: the workflow of `allan_variance_ros` and `imu_utils` in one step, on one
//! IMU of any importable recording (a ROS bag's Imu topic, a flight log's IMU, an
//! interchange file): find where the sensor is still, fit each axis' GMWM model on the still
//! stretches (their wavelet variances pooled, [`WaveletVariance::pooled`]) and choose it by
//! the WIC, and give what people copy into Kalibr's `imu.yaml`: white-noise density, bias
//! random walk and bias instability per axis with intervals, and the Allan deviation at 1 s.
//! Where the recording moves, the noise in motion is measured the same way as at rest (the
//! finest scale's wavelet variance, which vibration and motion at the sample scale raise) and
//! their ratio per axis is the inflation factor people otherwise guess.
//!
//! Stillness is judged from the IMU alone, window by window ([`NoiseOptions::window_s`]): a
//! window is still when every axis' standard deviation is at most
//! [`NoiseOptions::floor_factor`] times that axis' floor, the 2nd percentile of the windows'
//! (white noise of N samples has a window standard deviation within a few percent of its
//! own, so a static recording is still throughout, and a vehicle's vibration or motion lifts
//! a window well above the floor of its stops). A sampling that is not uniform (a ROS bag's
//! stamps) is taken in order at its median step, and said.

use std::ops::Range;

use crate::gmwm::fit::{FitInput, FitOptions};
use crate::gmwm::inference::{analyze, ChannelFit, ModelChoice};
use crate::gmwm::model::Structure;
use crate::input::stream::StreamMode;
use crate::interchange::{ImuRecording, Sampling, CHANNELS, CHANNEL_COLUMNS};
use crate::wv::WaveletVariance;

pub mod passes;
pub use passes::{BagTopicSamples, DatasetSamples, FileSamples, ImuSamples, RecordingSamples};

/// Errors of [`analyse`].
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum NoiseError {
    #[error("{imu}: {message}")]
    Recording { imu: String, message: String },
    #[error("{imu}: {channel}: {message}")]
    Channel {
        imu: String,
        channel: &'static str,
        message: String,
    },
    #[error(transparent)]
    Read(#[from] crate::import::ImportError),
}

/// Settings of [`analyse`].
#[derive(Debug, Clone)]
pub struct NoiseOptions {
    /// Window of the stillness test, s.
    pub window_s: f64,
    /// A still window's standard deviation is at most this many times the floor, per axis.
    pub floor_factor: f64,
    /// Shortest still stretch used, s.
    pub min_still_s: f64,
    /// The still stretch given (from, to), s of the recording's time, instead of finding it.
    pub still_span_s: Option<(f64, f64)>,
    /// The candidate structures the WIC chooses among.
    pub candidates: Vec<Structure>,
    /// The WIC a structure's every extra parameter must gain over a smaller candidate's for
    /// the larger to be chosen (see [`parsimonious`]).
    pub wic_margin_per_parameter: f64,
    /// Least still time, s, for any candidate beyond white noise: a bias random walk or
    /// instability shows in the Allan deviation's rise and floor over tens to thousands of
    /// seconds, so a shorter stay at rest measures the white noise only.
    pub min_still_for_bias_s: f64,
}

/// The default [`NoiseOptions::wic_margin_per_parameter`]: the 95% point of chi-square with
/// one degree of freedom. The WIC, like the AIC, takes the larger of two nested structures
/// whenever its objective gains more than its optimism (about 2 per parameter), which under
/// the smaller truth happens about one time in six (measured: a random walk's recordings
/// read as a slow Gauss-Markov bias on 20-25% of axes at 1 to 10 h); asking each extra
/// parameter to gain this much more makes that about one in twenty.
pub const WIC_MARGIN_PER_PARAMETER: f64 = 3.84;

/// The structure chosen from `fit`'s ranked candidates: the WIC's best, unless a candidate
/// with fewer parameters is within [`NoiseOptions::wic_margin_per_parameter`] per
/// parameter of it (the fewest such, then the lowest WIC). Also returns the candidates the
/// data hardly tell from the choice (within the margin, either way), for the report.
pub fn parsimonious(fit: &ChannelFit, margin: f64) -> (String, Vec<(String, f64)>) {
    let usable: Vec<(&str, usize, f64)> = fit
        .candidates
        .iter()
        .flatten()
        .filter(|c| c.converged && c.warnings.is_empty())
        .filter_map(|c| {
            let params = Structure::parse(&c.model).ok()?.n_params();
            Some((c.model.as_str(), params, c.wic?))
        })
        .collect();
    let Some(&(best, best_params, best_wic)) = usable.iter().min_by(|a, b| a.2.total_cmp(&b.2))
    else {
        return (fit.model.clone(), Vec::new());
    };
    let within = |params: usize, wic: f64, than_params: usize, than_wic: f64| {
        params < than_params && wic - than_wic <= margin * (than_params - params) as f64
    };
    let chosen = usable
        .iter()
        .filter(|c| within(c.1, c.2, best_params, best_wic))
        .min_by(|a, b| a.1.cmp(&b.1).then(a.2.total_cmp(&b.2)))
        .map_or((best, best_params, best_wic), |c| *c);
    let close = usable
        .iter()
        .filter(|c| c.0 != chosen.0)
        .filter(|c| within(chosen.1, chosen.2, c.1, c.2) || within(c.1, c.2, chosen.1, chosen.2))
        .map(|c| (c.0.to_string(), c.2 - chosen.2))
        .collect();
    (chosen.0.to_string(), close)
}

/// The structures `noise` chooses among: white noise always, a bias random walk or not, and
/// none, one or two Gauss-Markov biases (the bias instability). Drift and quantization noise
/// are left out: Kalibr's `imu.yaml` holds neither, and on a still hour they are told from a
/// random walk and white noise only by the top few levels (measured: BENCHMARKS.md, "Model
/// choice of `dynacal noise`").
pub fn noise_candidates() -> Vec<Structure> {
    [
        "WN",
        "WN+RW",
        "WN+GM",
        "WN+RW+GM",
        "WN+GM+GM",
        "WN+RW+GM+GM",
    ]
    .iter()
    .map(|s| Structure::parse(s).expect("a valid structure"))
    .collect()
}

impl Default for NoiseOptions {
    fn default() -> Self {
        Self {
            window_s: 1.0,
            floor_factor: 2.0,
            min_still_s: 2.0,
            still_span_s: None,
            candidates: noise_candidates(),
            min_still_for_bias_s: 60.0,
            wic_margin_per_parameter: WIC_MARGIN_PER_PARAMETER,
        }
    }
}

/// A stretch of the recording: sample indices and their times, s.
#[derive(Debug, Clone, PartialEq)]
pub struct Stretch {
    pub samples: Range<usize>,
    pub from_s: f64,
    pub to_s: f64,
}

/// Where the sensor is still and where it moves.
#[derive(Debug, Clone, PartialEq)]
pub struct Stillness {
    pub still: Vec<Stretch>,
    pub moving: Vec<Stretch>,
    /// How the still stretches were chosen, for the report.
    pub rule: String,
}

/// One axis' noise.
#[derive(Debug, Clone)]
pub struct AxisNoise {
    /// `gx` ... `az`.
    pub channel: &'static str,
    /// rad/s or m/s^2.
    pub unit: &'static str,
    /// The GMWM fit on the still stretches (its chosen model, parameters, candidates).
    pub fit: ChannelFit,
    /// The still stretches' pooled wavelet variance.
    pub wv: WaveletVariance,
    /// White-noise density, unit/sqrt(Hz), and its 95% interval.
    pub noise_density: (f64, Option<[f64; 2]>),
    /// The bias random walk Kalibr is given ([`exported_random_walk`]), unit/s/sqrt(Hz),
    /// and its 95% interval; None when the chosen model has neither a random walk nor a
    /// Gauss-Markov bias of a second or longer.
    pub random_walk: Option<(f64, Option<[f64; 2]>)>,
    /// The Allan deviation's minimum over 0.664 (the flicker floor's convention), unit, and
    /// the averaging time where it falls, s.
    pub bias_instability: Option<(f64, f64)>,
    /// The Allan deviation at 1 s (log-log between the two nearest averaging times), unit.
    pub allan_deviation_1s: Option<f64>,
    /// The finest scale's white-noise density in motion over at rest; None without motion.
    pub motion_inflation: Option<f64>,
    /// Candidates the data hardly tell from the chosen model: (structure, its WIC minus the
    /// chosen one's), within the parsimony margin.
    pub close_alternatives: Vec<(String, f64)>,
}

/// What `dynacal noise` found on one IMU.
#[derive(Debug, Clone)]
pub struct NoiseReport {
    pub imu: String,
    pub sampling: Sampling,
    pub stillness: Stillness,
    pub axes: Vec<AxisNoise>,
    pub notes: Vec<String>,
}

/// The IMU's axes present: (index into [`CHANNELS`], values).
fn axes_of(rec: &ImuRecording) -> Vec<(usize, &[f64])> {
    let mut out = Vec::new();
    for (offset, triplet) in [(0, &rec.gyro_rad_s), (3, &rec.accel_m_s2)] {
        if let Some(t) = triplet {
            out.extend((0..3).map(|k| (offset + k, t[k].as_slice())));
        }
    }
    out.extend(
        rec.single_axis
            .iter()
            .map(|s| (s.channel, s.values.as_slice())),
    );
    out
}

/// The bias random walk a fit exports (`export`'s and the board's reduction,
/// `refit::channel_noise`): the random walk's PSD `sigma2 / dt` plus each Gauss-Markov bias
/// of a second or longer as the PSD of its driving noise, `2 sigma2 beta`;
/// K = sqrt(PSD), unit/s/sqrt(Hz). Its 95% interval is the delta method's on log K from the
/// fit's transformed parameters (log sigma2, log beta) and their covariance. None when
/// nothing contributes.
pub fn exported_random_walk(fit: &ChannelFit) -> Option<(f64, Option<[f64; 2]>)> {
    use crate::gmwm::model::ProcessKind;
    let structure = Structure::parse(&fit.model).ok()?;
    let dt_s = 1.0 / fit.sample_rate_hz;
    let mut psd = 0.0;
    let mut gradient = vec![0.0; fit.theta.len()];
    let mut k = 0;
    for kind in &structure.kinds {
        match kind {
            ProcessKind::RandomWalk => {
                let term = fit.theta[k].exp() / dt_s;
                psd += term;
                gradient[k] += term;
            }
            ProcessKind::GaussMarkov
                if fit.theta[k].exp() <= crate::refit::SLOWEST_WHITE_BETA_PER_S =>
            {
                let term = 2.0 * fit.theta[k + 1].exp() * fit.theta[k].exp();
                psd += term;
                gradient[k] += term;
                gradient[k + 1] += term;
            }
            _ => {}
        }
        k += kind.n_params();
    }
    if psd <= 0.0 {
        return None;
    }
    let walk = psd.sqrt();
    let interval = fit.theta_covariance.as_ref().and_then(|cov| {
        let n = gradient.len();
        let var: f64 = (0..n)
            .flat_map(|i| (0..n).map(move |j| (i, j)))
            .map(|(i, j)| gradient[i] * cov[i * n + j] * gradient[j])
            .sum();
        // d log K = d PSD / (2 PSD).
        let sd = 0.5 * var.max(0.0).sqrt() / psd;
        sd.is_finite()
            .then(|| [walk * (-1.959964 * sd).exp(), walk * (1.959964 * sd).exp()])
    });
    Some((walk, interval))
}

/// The Allan deviation at 1 s, log-log between its two nearest averaging times.
fn allan_deviation_at_1s(wv: &WaveletVariance) -> Option<f64> {
    let tau = wv.allan_tau_s();
    let adev = wv.allan_deviation();
    let k = tau.windows(2).position(|w| w[0] <= 1.0 && 1.0 <= w[1])?;
    let (t0, t1, a0, a1) = (tau[k], tau[k + 1], adev[k], adev[k + 1]);
    let f = (1.0f64.ln() - t0.ln()) / (t1.ln() - t0.ln());
    Some((a0.ln() + f * (a1.ln() - a0.ln())).exp())
}

/// The fitted parameter `process`.`name` with its interval.
fn parameter(fit: &ChannelFit, process: &str, name: &str) -> Option<(f64, Option<[f64; 2]>)> {
    fit.parameters
        .iter()
        .find(|p| p.process == process && p.name == name)
        .map(|p| (p.value, p.ci95))
}

/// Analyses one IMU recording named `imu`, in memory.
pub fn analyse(
    imu: &str,
    rec: &ImuRecording,
    opts: &NoiseOptions,
) -> Result<NoiseReport, NoiseError> {
    analyse_samples(imu, &mut RecordingSamples::new(rec), opts)
}

/// Analyses the IMU `imu` whose samples `source` reads in passes ([`passes`]).
pub fn analyse_samples(
    imu: &str,
    source: &mut dyn ImuSamples,
    opts: &NoiseOptions,
) -> Result<NoiseReport, NoiseError> {
    let fail = |message: String| NoiseError::Recording {
        imu: imu.to_string(),
        message,
    };
    let mut sampling = source
        .sampling()
        .ok_or_else(|| fail("fewer than two samples".into()))?;
    if source.channels().is_empty() {
        return Err(fail("no gyro or accelerometer channel".into()));
    }
    let dt_s = sampling.median_step_s;
    let (stillness, gaps) = passes::stillness_and_gaps(source, dt_s, opts)?;
    sampling.gaps = gaps;
    let mut notes = Vec::new();
    if !sampling.is_uniform() {
        notes.push(format!(
            "the sampling is not uniform ({sampling}): the samples are taken in order at the median step, {:.6} s",
            dt_s
        ));
    }
    if stillness.still.is_empty() {
        return Err(fail(format!(
            "no still stretch found ({}): give one with --still FROM_S TO_S",
            stillness.rule
        )));
    }
    let still_s: f64 = stillness
        .still
        .iter()
        .map(|s| s.samples.len() as f64 * dt_s)
        .sum();
    notes.push(format!(
        "still: {} stretch(es), {:.1} s in all ({}); moving: {:.1} s",
        stillness.still.len(),
        still_s,
        stillness.rule,
        stillness
            .moving
            .iter()
            .map(|s| s.samples.len() as f64 * dt_s)
            .sum::<f64>()
    ));
    let white_only;
    let too_short_for_bias = still_s < opts.min_still_for_bias_s;
    let opts = if too_short_for_bias {
        notes.push(format!(
            "{still_s:.1} s at rest is under {} s: only the white noise is fitted (a bias random walk or instability needs minutes at rest to show), so no K is given and no imu.yaml can be written; record longer at rest or name a still span with --still",
            opts.min_still_for_bias_s
        ));
        white_only = NoiseOptions {
            candidates: vec![Structure::parse("WN").expect("a valid structure")],
            ..opts.clone()
        };
        &white_only
    } else {
        opts
    };
    let (still_parts, moving_parts) = passes::stretch_wavelet_variances(source, &stillness, dt_s)?;
    let axes = source
        .channels()
        .iter()
        .zip(still_parts.iter().zip(&moving_parts))
        .map(|(&index, (still, moving))| {
            let moving = WaveletVariance::pooled(moving);
            analyse_axis(imu, index, WaveletVariance::pooled(still), moving, opts)
        })
        .collect::<Result<Vec<_>, _>>()?;
    // An Allan deviation minimum within seconds at rest is the white noise's last point,
    // not a bias floor.
    let axes: Vec<AxisNoise> = axes
        .into_iter()
        .map(|a| AxisNoise {
            bias_instability: a.bias_instability.filter(|_| !too_short_for_bias),
            ..a
        })
        .collect();
    for a in &axes {
        if !a.close_alternatives.is_empty() {
            let list: Vec<String> = a
                .close_alternatives
                .iter()
                .map(|(m, d)| format!("{m} (WIC {d:+.2})"))
                .collect();
            notes.push(format!(
                "{}: {} chosen, but the data hardly tell it from {}: they differ at the longest averaging times, where the still stretches hold few independent stretches",
                a.channel,
                a.fit.model,
                list.join(", ")
            ));
        }
    }
    Ok(NoiseReport {
        imu: imu.to_string(),
        sampling,
        stillness,
        axes,
        notes,
    })
}

/// One axis from its still stretches' pooled wavelet variance and its moving stretches'
/// finest level.
fn analyse_axis(
    imu: &str,
    index: usize,
    still: Option<WaveletVariance>,
    moving: Option<WaveletVariance>,
    opts: &NoiseOptions,
) -> Result<AxisNoise, NoiseError> {
    let channel = CHANNELS[index];
    let unit = if index < 3 { "rad/s" } else { "m/s^2" };
    let fail = |message: String| NoiseError::Channel {
        imu: imu.to_string(),
        channel,
        message,
    };
    let wv = still
        .ok_or_else(|| fail("the still stretches are too short for a wavelet variance".into()))?;
    if wv.variance.first().is_some_and(|v| *v == 0.0) {
        return Err(fail(
            "every value is the same over the still stretches: no noise to fit (an axis the sensor does not measure, or one quantised coarser than its noise)".into(),
        ));
    }
    let input = FitInput::from_wv(&wv).map_err(|e| fail(e.to_string()))?;
    let fit_as = |choice: &ModelChoice| {
        analyze(
            CHANNEL_COLUMNS[index],
            unit,
            &input,
            choice,
            None,
            &FitOptions::default(),
        )
        .map_err(|e| fail(format!("the still stretches' {} levels: {e}", wv.len())))
    };
    let mut fit = fit_as(&ModelChoice::Among(opts.candidates.clone()))?;
    let (chosen, close_alternatives) = parsimonious(&fit, opts.wic_margin_per_parameter);
    if chosen != fit.model {
        let candidates = fit.candidates.take();
        let structure = Structure::parse(&chosen).map_err(|e| fail(e.to_string()))?;
        fit = fit_as(&ModelChoice::Fixed(structure))?;
        fit.candidates = candidates;
    }
    let noise_density = parameter(&fit, "WN", "noise_density")
        .ok_or_else(|| fail(format!("the chosen model {} has no white noise", fit.model)))?;
    let random_walk = exported_random_walk(&fit);
    let adev = wv.allan_deviation();
    let tau = wv.allan_tau_s();
    // A floor inside the measured averaging times; a minimum at either end is no floor.
    let bias_instability = adev
        .iter()
        .zip(&tau)
        .enumerate()
        .min_by(|a, b| a.1 .0.total_cmp(b.1 .0))
        .filter(|(k, _)| *k > 0 && *k + 1 < adev.len())
        .map(|(_, (a, t))| (a / 0.664, *t));
    let motion_inflation =
        moving.and_then(|moving| Some((moving.variance.first()? / wv.variance.first()?).sqrt()));
    Ok(AxisNoise {
        channel,
        unit,
        allan_deviation_1s: allan_deviation_at_1s(&wv),
        fit,
        wv,
        noise_density,
        random_walk,
        bias_instability,
        motion_inflation,
        close_alternatives,
    })
}

/// An IMU chosen from an importable input (a file or a folder: a bag, a flight log, an
/// interchange file): its name, recording, and the importer's notes.
pub struct ChosenImu {
    pub name: String,
    /// The ROS topic it came from, where `--topic` named one.
    pub topic: Option<String>,
    pub source: ImuSource,
    pub notes: Vec<String>,
}

/// Where a chosen IMU's samples are.
pub enum ImuSource {
    /// Imported whole.
    Recording(Box<ImuRecording>),
    /// A bag's topic, read anew each pass (memory independent of the bag's length).
    Bag(BagTopicSamples),
    /// An interchange file over [`crate::input::stream::STREAM_THRESHOLD_BYTES`], read anew
    /// each pass.
    File(FileSamples),
    /// A sensor of a flight log or text recording over
    /// [`crate::input::stream::STREAM_THRESHOLD_BYTES`], imported anew each pass.
    Dataset(DatasetSamples),
}

impl ChosenImu {
    /// [`analyse_samples`] of this IMU.
    pub fn analyse(&mut self, opts: &NoiseOptions) -> Result<NoiseReport, NoiseError> {
        match &mut self.source {
            ImuSource::Recording(rec) => analyse(&self.name, rec, opts),
            ImuSource::Bag(bag) => analyse_samples(&self.name, bag, opts),
            ImuSource::File(file) => analyse_samples(&self.name, file, opts),
            ImuSource::Dataset(dataset) => analyse_samples(&self.name, dataset, opts),
        }
    }
}

/// Errors of [`choose_imu`].
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ChooseError {
    #[error(transparent)]
    Import(#[from] crate::import::ImportError),
    #[error("{path}: {message}")]
    Choice { path: String, message: String },
}

/// The IMU of `input` named by `topic` (a ROS topic, `/xsens/imu_data`, or an imported
/// sensor's name, `xsens-imu_data`), or its only IMU.
pub fn choose_imu(
    input: &std::path::Path,
    topic: Option<&str>,
    mode: StreamMode,
) -> Result<ChosenImu, ChooseError> {
    use crate::import::{
        find_datasets, import_bag_topic, import_file_noted, ros_bag::file_name_of_topic, Dataset,
    };
    let (found, _) = find_datasets(input)?;
    let in_passes = |file: &std::path::Path| match mode {
        StreamMode::Always => true,
        StreamMode::Never => false,
        StreamMode::Auto => std::fs::metadata(file)
            .is_ok_and(|m| m.len() > crate::input::stream::STREAM_THRESHOLD_BYTES),
    };
    // A bag's Imu topic is streamed, not imported (only that topic decoded, one decoding a
    // pass): its length then costs no memory.
    let bags: Vec<std::path::PathBuf> = found
        .iter()
        .filter(|(_, d)| *d == Dataset::RosBag)
        .map(|(f, _)| f.clone())
        .collect();
    let bag_topic = topic.filter(|_| !bags.is_empty() && bags.len() == found.len());
    if let Some(topic) = bag_topic.filter(|_| mode != StreamMode::Never) {
        if let Some((source, notes)) = BagTopicSamples::open(bags, topic)? {
            return Ok(ChosenImu {
                name: file_name_of_topic(topic),
                topic: Some(topic.to_string()),
                source: ImuSource::Bag(source),
                notes,
            });
        }
    }
    // A long flight log, text recording or bag is imported anew each pass: its length costs
    // no memory.
    if let [(file, dataset)] = found.as_slice() {
        if dataset.streams_rows() && in_passes(file) {
            return choose_streamed(input, file, *dataset, topic);
        }
    }
    // A long interchange file is read in passes, not imported: its length costs no memory.
    if let [(file, Dataset::Interchange)] = found.as_slice() {
        let name = crate::import::file_stem(file);
        if in_passes(file) && topic.is_none_or(|t| t == name) {
            return Ok(ChosenImu {
                name,
                topic: None,
                source: ImuSource::File(FileSamples::open(file)?),
                notes: Vec::new(),
            });
        }
    }
    if mode == StreamMode::Always {
        return Err(ChooseError::Choice {
            path: input.display().to_string(),
            message: "--stream always: only one file (a flight log, text recording, ROS bag \
                      or interchange file) can be read in passes; these files are imported \
                      whole (--stream auto)"
                .into(),
        });
    }
    let read_all = |only: Option<&str>| -> Result<_, ChooseError> {
        let (mut sensors, mut notes) = (Vec::new(), Vec::new());
        for (file, dataset) in &found {
            let (s, n) = match (dataset, only) {
                (Dataset::RosBag, Some(topic)) => import_bag_topic(file, topic)?,
                _ => import_file_noted(file, *dataset)?,
            };
            sensors.extend(s);
            notes.extend(n);
        }
        Ok((sensors, notes))
    };
    // A bag's other topics are not decoded when one is asked; read whole only to say what
    // there is when the asked one gives nothing.
    let (mut sensors, mut notes) = read_all(topic)?;
    if topic.is_some() && sensors.is_empty() {
        (sensors, notes) = read_all(None)?;
    }
    let described: Vec<Described> = sensors
        .iter()
        .map(|s| Described {
            name: s.name.clone(),
            is_imu: !axes_of(&s.recording).is_empty(),
            contents: crate::import::contents(&s.recording),
        })
        .collect();
    let index = pick(input, &described, topic, &notes)?;
    let topic = topic
        .map(str::to_string)
        .or_else(|| topic_of(&notes, &sensors[index].name));
    let sensor = sensors.swap_remove(index);
    Ok(ChosenImu {
        name: sensor.name,
        topic,
        source: ImuSource::Recording(Box::new(sensor.recording)),
        notes,
    })
}

/// One sensor an input holds, as [`pick`] chooses among them.
struct Described {
    name: String,
    is_imu: bool,
    /// What it holds ([`crate::import::contents`]).
    contents: Vec<&'static str>,
}

/// The ROS topic a sensor named `name` was made of, where the importer's notes name one.
fn topic_of(notes: &[String], name: &str) -> Option<String> {
    use crate::import::ros_bag::file_name_of_topic;
    notes.iter().find_map(|n| {
        let (t, _) = n.split_once(": frame_id ")?;
        (file_name_of_topic(t) == name).then(|| t.to_string())
    })
}

/// The place among `sensors` of the IMU named by `topic` (a ROS topic or a sensor's name),
/// or of the only IMU; the error says what there is to choose.
fn pick(
    input: &std::path::Path,
    sensors: &[Described],
    topic: Option<&str>,
    notes: &[String],
) -> Result<usize, ChooseError> {
    use crate::import::ros_bag::file_name_of_topic;
    let fail = |message: String| ChooseError::Choice {
        path: input.display().to_string(),
        message,
    };
    let imus: Vec<&str> = sensors
        .iter()
        .filter(|s| s.is_imu)
        .map(|s| s.name.as_str())
        .collect();
    // What a user can pass to --topic: the IMUs' topics where they came from a bag.
    let listed = imus
        .iter()
        .map(|name| topic_of(notes, name).unwrap_or_else(|| name.to_string()))
        .collect::<Vec<_>>()
        .join(", ");
    match topic {
        Some(topic) => {
            let wanted = file_name_of_topic(topic);
            let suffix = format!("-{wanted}");
            let k = sensors
                .iter()
                .position(|s| s.name == topic || s.name == wanted || s.name.ends_with(&suffix));
            let Some(k) = k else {
                let about: Vec<&String> = notes
                    .iter()
                    .filter(|n| n.starts_with(&format!("{topic}: ")))
                    .collect();
                return Err(fail(match about.first() {
                    Some(note) => format!("topic {topic} gives no IMU: {note}"),
                    None => format!("no topic or sensor {topic}; its IMUs: {listed}"),
                }));
            };
            if !sensors[k].is_imu {
                return Err(fail(format!(
                    "topic {topic} holds {}, not IMU data (a reference topic: Odometry or NavSatFix, not sensor_msgs/Imu); its IMUs: {listed}",
                    sensors[k].contents.join(", "),
                )));
            }
            Ok(k)
        }
        None => match imus.as_slice() {
            [one] => Ok(sensors.iter().position(|s| s.name == *one).expect("listed")),
            [] => Err(fail("no IMU in it".into())),
            many => Err(fail(format!(
                "{} IMUs, name one with --topic: {listed}",
                many.len()
            ))),
        },
    }
}

/// The IMU of one long dataset file whose importer streams its rows, read anew each pass
/// ([`DatasetSamples`]): chosen as [`choose_imu`] chooses, after a first pass over the file.
fn choose_streamed(
    input: &std::path::Path,
    file: &std::path::Path,
    dataset: crate::import::Dataset,
    topic: Option<&str>,
) -> Result<ChosenImu, ChooseError> {
    let passes::DatasetSurvey {
        layouts,
        mut steps,
        notes,
    } = DatasetSamples::survey(file, dataset)?;
    let described: Vec<Described> = layouts
        .iter()
        .map(|layout| Described {
            name: layout.name.clone(),
            is_imu: !passes::channels_of(layout).0.is_empty(),
            contents: crate::import::contents_of(&layout.columns),
        })
        .collect();
    let index = pick(input, &described, topic, &notes)?;
    let layout = &layouts[index];
    let samples = DatasetSamples::new(file, dataset, index, layout, steps.swap_remove(index));
    Ok(ChosenImu {
        name: layout.name.clone(),
        topic: topic.map(str::to_string),
        source: ImuSource::Dataset(samples),
        notes,
    })
}

/// The report page's summary: per axis, what goes into `imu.yaml` and what motion adds.
fn summary_lines(report: &NoiseReport) -> Vec<String> {
    let still_s: f64 = report
        .stillness
        .still
        .iter()
        .map(|s| s.to_s - s.from_s)
        .sum();
    let mut lines = vec![format!(
        "{:.1} s at rest in {} stretch(es) of {:.1} s recorded",
        still_s,
        report.stillness.still.len(),
        report.sampling.span_s
    )];
    for a in &report.axes {
        let interval = |c: Option<[f64; 2]>| {
            c.map_or(String::new(), |[lo, hi]| format!(" [{lo:.3e}, {hi:.3e}]"))
        };
        let walk = match a.random_walk {
            Some((k, ci)) => format!("K {k:.3e}{} {}/s/sqrt(Hz)", interval(ci), a.unit),
            None => "no random walk (none fitted)".to_string(),
        };
        let motion = a.motion_inflation.map_or(String::new(), |f| {
            format!("; in motion {f:.2} times the noise at rest")
        });
        lines.push(format!(
            "{} ({}): N {:.3e}{} {}/sqrt(Hz), {walk}{motion}",
            a.channel,
            a.fit.model,
            a.noise_density.0,
            interval(a.noise_density.1),
            a.unit
        ));
    }
    lines
}

/// The model file of a report: each axis' chosen model on its channel, with the fits beside.
pub fn model_of(report: &NoiseReport) -> Result<crate::model::SimModel, serde_json::Error> {
    let fits: Vec<ChannelFit> = report.axes.iter().map(|a| a.fit.clone()).collect();
    let (mut model, _) =
        crate::model::fitted_model(std::path::Path::new(&report.imu), "noise candidates", &fits)?;
    model.comment = Some(format!(
        "fitted by dynacal noise on the still stretches of {} ({:.1} s)",
        report.imu,
        report
            .stillness
            .still
            .iter()
            .map(|s| s.samples.len() as f64 * report.sampling.median_step_s)
            .sum::<f64>()
    ));
    Ok(model)
}

/// One line per axis: the table people expect.
pub fn table(report: &NoiseReport) -> Vec<String> {
    let interval = |ci: Option<[f64; 2]>| {
        ci.map_or("[n/a]".to_string(), |[lo, hi]| {
            format!("[{lo:.3e}, {hi:.3e}]")
        })
    };
    let mut out = vec![format!(
        "{:<4} {:<12} {:>10} {:<24} {:>10} {:<24} {:>10} {:>8} {:>10} {:>9}",
        "axis", "model", "N", "N 95%", "K", "K 95%", "B", "tau_B s", "adev(1s)", "motion x"
    )];
    for a in &report.axes {
        let (k, k_ci) = match &a.random_walk {
            Some((k, ci)) => (format!("{k:.3e}"), interval(*ci)),
            None => ("none".into(), "".into()),
        };
        let (b, tau_b) = a
            .bias_instability
            .map_or(("n/a".into(), "".into()), |(b, t)| {
                (format!("{b:.3e}"), format!("{t:.3}"))
            });
        out.push(format!(
            "{:<4} {:<12} {:>10.3e} {:<24} {:>10} {:<24} {:>10} {:>8} {:>10} {:>9}",
            a.channel,
            a.fit.model,
            a.noise_density.0,
            interval(a.noise_density.1),
            k,
            k_ci,
            b,
            tau_b,
            a.allan_deviation_1s
                .map_or("n/a".into(), |v| format!("{v:.3e}")),
            a.motion_inflation.map_or("-".into(), |v| format!("{v:.2}")),
        ));
    }
    out
}

/// Kalibr's `imu.yaml` of a report (the export of `dynacal export --to kalibr`), with each
/// axis' measured inflation in motion in comments.
pub fn kalibr_yaml(
    report: &NoiseReport,
    rostopic: Option<&str>,
    source: &str,
) -> Result<String, Box<dyn std::error::Error + Send + Sync>> {
    use crate::export::{imu_noise, render, Format};
    if let Some(a) = report.axes.iter().find(|a| a.fit.model == "WN") {
        return Err(format!(
            "{}: the model chosen at rest is white noise alone, so there is no random walk for imu.yaml (see the notes)",
            a.channel
        )
        .into());
    }
    let model = model_of(report)?;
    let mut noise = imu_noise(&model, None, std::path::Path::new(source))?;
    noise.rostopic = rostopic.map(str::to_string);
    let mut text = render(&noise, None, Format::Kalibr, source);
    let inflation: Vec<String> = report
        .axes
        .iter()
        .filter_map(|a| a.motion_inflation.map(|f| format!("{} x{f:.2}", a.channel)))
        .collect();
    if !inflation.is_empty() {
        text.push_str(&format!(
            "# the values are the still stretches'; in motion the finest scale's noise density is {} (vibration and motion at the sample scale): a filter on the moving platform sees that much more\n",
            inflation.join(", ")
        ));
    }
    Ok(text)
}

/// `dynacal noise --report DIR`: each axis' Allan deviation with its interval, the fitted
/// model's, the slope lines of the Kalibr values (white noise N / sqrt(tau), random walk
/// K sqrt(tau / 3)) and, where the recording moves, the white noise measured in motion.
pub fn report_page(
    report: &NoiseReport,
) -> Result<crate::report::HtmlReport, crate::figures::plot::DrawError> {
    use crate::report::charts::{panels_svg, Axes, Panel, Series, Shape, GREY, PALETTE};
    use crate::report::{Cell, HtmlReport, Section, Table};
    let mut panels = Vec::new();
    let mut rows = Vec::new();
    for a in &report.axes {
        let tau = a.wv.allan_tau_s();
        let measured: Vec<(f64, f64, f64, f64)> = (0..a.wv.len())
            .map(|k| {
                let ad = |v: f64| (2.0 * v).sqrt();
                (
                    tau[k],
                    ad(a.wv.variance[k]),
                    ad(a.wv.ci_low[k]),
                    ad(a.wv.ci_high[k]),
                )
            })
            .collect();
        let model: Vec<(f64, f64)> = a
            .fit
            .scales_s
            .iter()
            .zip(&a.fit.model_wv)
            .map(|(s, v)| (s / 2.0, (2.0 * v).sqrt()))
            .collect();
        let line = |f: &dyn Fn(f64) -> f64| -> Vec<(f64, f64)> {
            tau.iter().map(|&t| (t, f(t))).collect()
        };
        let n = a.noise_density.0;
        let mut series = vec![
            Series::new(
                "still: Allan deviation, 95%",
                PALETTE[0],
                Shape::PointsWithBars(measured),
            ),
            Series::new(
                format!("fitted {}", a.fit.model),
                PALETTE[1],
                Shape::Line(model),
            ),
            Series::new(
                "N / sqrt(tau)",
                GREY,
                Shape::Dashed(line(&|t| n / t.sqrt())),
            ),
        ];
        if let Some((k, _)) = a.random_walk {
            series.push(Series::new(
                "K sqrt(tau / 3)",
                PALETTE[2],
                Shape::Dashed(line(&|t| k * (t / 3.0).sqrt())),
            ));
        }
        if let Some(f) = a.motion_inflation {
            series.push(Series::new(
                format!("in motion: {f:.2} N / sqrt(tau)"),
                PALETTE[3],
                Shape::Dashed(line(&|t| f * n / t.sqrt())),
            ));
        }
        panels.push(Panel {
            title: format!(
                "{}: Allan deviation at rest, the fitted {} and the Kalibr values",
                a.channel, a.fit.model
            ),
            x_label: "averaging time tau (s)".into(),
            y_label: format!("Allan deviation ({})", a.unit),
            axes: Axes::LogLog,
            series,
        });
        let ci = |c: Option<[f64; 2]>| {
            c.map_or(Cell::from("-".to_string()), |[lo, hi]| {
                Cell::Interval(lo, hi)
            })
        };
        rows.push(vec![
            Cell::from(a.channel.to_string()),
            Cell::from(a.fit.model.clone()),
            Cell::Number(a.noise_density.0),
            ci(a.noise_density.1),
            a.random_walk
                .map_or(Cell::from("none".to_string()), |r| Cell::Number(r.0)),
            ci(a.random_walk.and_then(|r| r.1)),
            a.bias_instability
                .map_or(Cell::from("-".to_string()), |b| Cell::Number(b.0)),
            a.allan_deviation_1s
                .map_or(Cell::from("-".to_string()), Cell::Number),
            a.motion_inflation
                .map_or(Cell::from("-".to_string()), Cell::Number),
        ]);
    }
    let svg = panels_svg("Allan deviation of each axis", &panels)?;
    let mut section = Section::new("Noise at rest, and in motion")
        .paragraph(format!("{}: {}.", report.imu, report.sampling));
    for note in &report.notes {
        section = section.paragraph(note.clone());
    }
    let section = section
        .table(Table {
            caption: "Per axis: the model the WIC chose on the still stretches, white-noise density N (unit/sqrt(Hz)), bias random walk K (unit/s/sqrt(Hz)) with 95% intervals, bias instability B (the Allan deviation's minimum / 0.664), the Allan deviation at 1 s, and the noise density in motion over at rest".into(),
            header: ["axis", "model", "N", "N 95%", "K", "K 95%", "B", "adev 1 s", "motion x"]
                .map(String::from)
                .to_vec(),
            rows,
        })
        .figure("Allan deviation at rest (points, 95% interval), the fitted model (line), the Kalibr values' slopes and the white noise in motion (dashed)", svg);
    Ok(HtmlReport {
        title: format!("dynacal noise: {}", report.imu),
        summary: summary_lines(report),
        sections: vec![section],
    })
}
