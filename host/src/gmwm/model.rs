//! Latent error-process models for the GMWM: white noise, quantization noise, random walk,
//! drift and any number of first-order Gauss-Markov (AR1) processes, their closed-form Haar
//! wavelet variance (WV) with analytic derivatives, their JSON form (the simulator's model
//! file), and a reference simulator used by the parametric bootstrap and the tests.
//!
//! Units. A model carries its signal `unit` (e.g. `rad/s`, `deg/s`, `g`) and its
//! `sample_rate_hz`; every parameter is physical:
//! - white noise `sigma2`: per-sample variance, unit^2 (noise density sqrt(sigma2 dt),
//!   unit/sqrt(Hz));
//! - quantization noise `q2`: unit^2, the process `sqrt(12 q2) (U_t - U_{t-1})`, U ~ U(0,1)
//!   (Haar WV 6 q2 / tau^2);
//! - random walk `sigma2`: per-sample innovation variance, unit^2 (bias random walk
//!   sqrt(sigma2 / dt), unit/s/sqrt(Hz));
//! - drift `slope_per_s`: unit/s (only |slope| is identifiable from a WV);
//! - Gauss-Markov `beta_per_s` (inverse correlation time, 1/s) and `sigma2` (stationary
//!   variance, unit^2): x_t = phi x_{t-1} + w_t, phi = exp(-beta dt),
//!   var(w_t) = sigma2 (1 - phi^2).
//!
//! Fitting works on transformed, unconstrained parameters (`theta`): the natural logarithm
//! of every positive quantity (sigma2, q2, beta_per_s, and slope^2 per sample^2 for drift),
//! so any real theta maps to a valid model and intervals mapped back never go negative.

use rand::Rng;
use rand_distr::{Distribution, StandardNormal};
use serde::{Deserialize, Serialize};

/// Errors in model strings and model objects; each names the offending token or field.
#[derive(Debug, thiserror::Error, PartialEq)]
#[non_exhaustive]
pub enum ModelError {
    #[error("model string is empty (expected e.g. \"WN+GM+GM\")")]
    Empty,
    #[error("model string `{model}`: unknown process `{token}` (known: WN, QN, RW, DR, GM or AR1, optionally with a count as in 2GM or 2*GM)")]
    UnknownProcess { model: String, token: String },
    #[error("model string `{model}`: `{kind}` appears more than once; two such processes are not identifiable from a wavelet variance (their sum is the same process)")]
    Duplicate { model: String, kind: &'static str },
    #[error("model `{model}`: process {index} (`{kind}`): field `{field}` = {value} must be finite and positive")]
    BadValue {
        model: String,
        index: usize,
        kind: &'static str,
        field: &'static str,
        value: f64,
    },
    #[error("model `{model}`: its processes [{found}] do not match the model string")]
    Mismatch { model: String, found: String },
    #[error("model `{model}`: sample_rate_hz = {value} must be finite and positive")]
    BadRate { model: String, value: f64 },
    #[error("model `{model}`: process {index} (`{kind}`): `{a}` = {va} and `{b}` = {vb} disagree (give one, or consistent values)")]
    Inconsistent {
        model: String,
        index: usize,
        kind: &'static str,
        a: &'static str,
        va: f64,
        b: &'static str,
        vb: f64,
    },
}

/// The kind of a latent process, in model strings written WN, QN, RW, DR, GM.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ProcessKind {
    WhiteNoise,
    QuantizationNoise,
    RandomWalk,
    Drift,
    GaussMarkov,
}

impl ProcessKind {
    /// The token used in model strings.
    pub fn token(self) -> &'static str {
        match self {
            ProcessKind::WhiteNoise => "WN",
            ProcessKind::QuantizationNoise => "QN",
            ProcessKind::RandomWalk => "RW",
            ProcessKind::Drift => "DR",
            ProcessKind::GaussMarkov => "GM",
        }
    }
    /// Number of (transformed) parameters.
    pub fn n_params(self) -> usize {
        match self {
            ProcessKind::GaussMarkov => 2,
            _ => 1,
        }
    }
}

/// The structure of a model: which processes, in order. GM processes may repeat; the others
/// appear at most once.
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
pub struct Structure {
    pub kinds: Vec<ProcessKind>,
}

impl Structure {
    /// Parses "WN+GM+GM", "wn + 2GM + RW", "WN+2*GM", "WN+AR1". The order of processes is
    /// kept as written, except that nothing else is implied.
    pub fn parse(model: &str) -> Result<Self, ModelError> {
        let model_trim = model.trim();
        if model_trim.is_empty() {
            return Err(ModelError::Empty);
        }
        let mut kinds = Vec::new();
        for raw in model_trim.split('+') {
            let token = raw.trim();
            let upper = token.to_ascii_uppercase();
            let digits: String = upper.chars().take_while(|c| c.is_ascii_digit()).collect();
            let rest = upper[digits.len()..].trim_start_matches('*').trim();
            let count: usize = if digits.is_empty() {
                1
            } else {
                digits.parse().unwrap_or(0)
            };
            let kind = match rest {
                "WN" => ProcessKind::WhiteNoise,
                "QN" => ProcessKind::QuantizationNoise,
                "RW" => ProcessKind::RandomWalk,
                "DR" => ProcessKind::Drift,
                "GM" | "AR1" => ProcessKind::GaussMarkov,
                _ => {
                    return Err(ModelError::UnknownProcess {
                        model: model.to_string(),
                        token: token.to_string(),
                    })
                }
            };
            if count == 0 {
                return Err(ModelError::UnknownProcess {
                    model: model.to_string(),
                    token: token.to_string(),
                });
            }
            for _ in 0..count {
                kinds.push(kind);
            }
        }
        let s = Structure { kinds };
        s.check_duplicates(model)?;
        Ok(s)
    }

    fn check_duplicates(&self, model: &str) -> Result<(), ModelError> {
        for kind in [
            ProcessKind::WhiteNoise,
            ProcessKind::QuantizationNoise,
            ProcessKind::RandomWalk,
            ProcessKind::Drift,
        ] {
            if self.kinds.iter().filter(|&&k| k == kind).count() > 1 {
                return Err(ModelError::Duplicate {
                    model: model.to_string(),
                    kind: kind.token(),
                });
            }
        }
        Ok(())
    }

    /// Canonical model string, e.g. "WN+GM+GM".
    pub fn name(&self) -> String {
        self.kinds
            .iter()
            .map(|k| k.token())
            .collect::<Vec<_>>()
            .join("+")
    }

    /// Number of transformed parameters.
    pub fn n_params(&self) -> usize {
        self.kinds.iter().map(|k| k.n_params()).sum()
    }

    /// Number of Gauss-Markov processes.
    pub fn n_gm(&self) -> usize {
        self.kinds
            .iter()
            .filter(|&&k| k == ProcessKind::GaussMarkov)
            .count()
    }

    pub fn has(&self, kind: ProcessKind) -> bool {
        self.kinds.contains(&kind)
    }

    /// Haar WV of the model at `theta` (transformed parameters) for the filter widths
    /// `tau_samples` (2^j), written to `nu`; with `jac`, also d nu_j / d theta_k written
    /// row-major (`jac[j * n_params + k]`). `dt_s` is the sampling interval.
    pub fn wv(
        &self,
        theta: &[f64],
        dt_s: f64,
        tau_samples: &[f64],
        nu: &mut [f64],
        mut jac: Option<&mut [f64]>,
    ) {
        let p = self.n_params();
        debug_assert_eq!(theta.len(), p);
        debug_assert_eq!(nu.len(), tau_samples.len());
        nu.iter_mut().for_each(|v| *v = 0.0);
        if let Some(j) = jac.as_deref_mut() {
            debug_assert_eq!(j.len(), p * tau_samples.len());
            j.iter_mut().for_each(|v| *v = 0.0);
        }
        let mut k = 0;
        for &kind in &self.kinds {
            match kind {
                ProcessKind::GaussMarkov => {
                    let beta = theta[k].exp();
                    let sigma2 = theta[k + 1].exp();
                    let a = beta * dt_s;
                    for (j, &tau) in tau_samples.iter().enumerate() {
                        let (g, dg_da) = gm_shape(a, tau / 2.0);
                        let c = 2.0 / (tau * tau);
                        let v = c * sigma2 * g;
                        nu[j] += v;
                        if let Some(jm) = jac.as_deref_mut() {
                            // d/d ln(beta) = a d/da ; d/d ln(sigma2) = the value itself.
                            jm[j * p + k] = c * sigma2 * dg_da * a;
                            jm[j * p + k + 1] = v;
                        }
                    }
                }
                _ => {
                    let x = theta[k].exp();
                    for (j, &tau) in tau_samples.iter().enumerate() {
                        let v = x * unit_wv(kind, tau);
                        nu[j] += v;
                        if let Some(jm) = jac.as_deref_mut() {
                            jm[j * p + k] = v;
                        }
                    }
                }
            }
            k += kind.n_params();
        }
    }
}

/// Haar WV at filter width `tau` (samples) of a process whose single scale parameter is 1:
/// WN variance, QN Q^2, RW innovation variance, drift slope^2 (per sample^2).
fn unit_wv(kind: ProcessKind, tau: f64) -> f64 {
    match kind {
        ProcessKind::WhiteNoise => 1.0 / tau,
        ProcessKind::QuantizationNoise => 6.0 / (tau * tau),
        ProcessKind::RandomWalk => (tau * tau + 2.0) / (12.0 * tau),
        ProcessKind::Drift => tau * tau / 16.0,
        ProcessKind::GaussMarkov => unreachable!("GM has two parameters"),
    }
}

/// The Gauss-Markov WV shape g(a, h) and dg/da, where a = beta dt, h = tau/2 and
/// nu = 2 sigma2 g / tau^2:
/// g = B / (1-phi)^2, B = h (1 - phi^2) - 3 phi + 4 phi^(h+1) - phi^(2h+1), phi = e^-a
/// (the AR1 formula of gmwm.md rewritten with the stationary variance sigma2).
///
/// Why not the textbook formula as is: for slow processes (a h small, e.g. beta = 0.00155/s at
/// 100 Hz) its terms cancel to O((a h)^3) and lose all precision, so there B is summed as its
/// Taylor series in a (the a^0..a^2 coefficients vanish exactly); elsewhere it is rewritten
/// with expm1 so that no difference of nearly equal exponentials remains.
pub(crate) fn gm_shape(a: f64, h: f64) -> (f64, f64) {
    let u = -(-a).exp_m1(); // 1 - phi, accurate for small a
    let phi = (-a).exp();
    let (b, db) = if 2.0 * a * (h + 1.0) <= 0.5 {
        // B = sum_{n>=3} (-1)^n / n! [ -h (2a)^n - 3 a^n + 4 ((h+1)a)^n - ((2h+1)a)^n ].
        let (x1, x2, x3, x4) = (2.0 * a, a, (h + 1.0) * a, (2.0 * h + 1.0) * a);
        let (mut p1, mut p2, mut p3, mut p4) = (x1 * x1, x2 * x2, x3 * x3, x4 * x4);
        let mut fact = 2.0;
        let mut b = 0.0;
        let mut db = 0.0;
        for n in 3..60 {
            p1 *= x1;
            p2 *= x2;
            p3 *= x3;
            p4 *= x4;
            fact *= n as f64;
            let sign = if n % 2 == 0 { 1.0 } else { -1.0 };
            let term = sign / fact * (-h * p1 - 3.0 * p2 + 4.0 * p3 - p4);
            b += term;
            // d/da of c_n a^n is n c_n a^(n-1) = n term / a.
            db += n as f64 * term / a;
            if n > 4 && term.abs() <= 1e-18 * b.abs() {
                break;
            }
        }
        (b, db)
    } else {
        let big_u = -(-a * h).exp_m1(); // 1 - phi^h
        let phi_h = 1.0 - big_u;
        let b = h * (-(-2.0 * a).exp_m1()) - phi * big_u * (2.0 + big_u);
        let db = 2.0 * h * phi * phi
            + phi * (3.0 - 4.0 * (h + 1.0) * phi_h + (2.0 * h + 1.0) * phi_h * phi_h);
        (b, db)
    };
    let g = b / (u * u);
    let dg = db / (u * u) - 2.0 * b * phi / (u * u * u);
    (g, dg)
}

/// One latent process with physical parameters (see the module doc for units).
#[derive(Debug, Clone, PartialEq)]
pub enum Process {
    WhiteNoise { sigma2: f64 },
    QuantizationNoise { q2: f64 },
    RandomWalk { sigma2: f64 },
    Drift { slope_per_s: f64 },
    GaussMarkov { beta_per_s: f64, sigma2: f64 },
}

impl Process {
    pub fn kind(&self) -> ProcessKind {
        match self {
            Process::WhiteNoise { .. } => ProcessKind::WhiteNoise,
            Process::QuantizationNoise { .. } => ProcessKind::QuantizationNoise,
            Process::RandomWalk { .. } => ProcessKind::RandomWalk,
            Process::Drift { .. } => ProcessKind::Drift,
            Process::GaussMarkov { .. } => ProcessKind::GaussMarkov,
        }
    }
}

/// The JSON form of a process. White noise and random walk also carry (and accept instead of
/// sigma2) the Allan-variance style densities that Kalibr / VIO configurations use.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
enum ProcessJson {
    WhiteNoise {
        #[serde(default, skip_serializing_if = "Option::is_none")]
        sigma2: Option<f64>,
        /// sqrt(sigma2 dt), unit/sqrt(Hz).
        #[serde(default, skip_serializing_if = "Option::is_none")]
        noise_density: Option<f64>,
    },
    QuantizationNoise {
        q2: f64,
    },
    RandomWalk {
        #[serde(default, skip_serializing_if = "Option::is_none")]
        sigma2: Option<f64>,
        /// sqrt(sigma2 / dt), unit/s/sqrt(Hz).
        #[serde(default, skip_serializing_if = "Option::is_none")]
        bias_random_walk: Option<f64>,
    },
    Drift {
        slope_per_s: f64,
    },
    GaussMarkov {
        beta_per_s: f64,
        sigma2: f64,
    },
}

#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct ModelSpecJson {
    model: String,
    unit: String,
    sample_rate_hz: f64,
    processes: Vec<ProcessJson>,
}

/// A complete model in physical units: the simulator's model file and the `model` object of
/// each fitted channel.
///
/// ```json
/// {"model": "WN+GM+GM", "unit": "rad/s", "sample_rate_hz": 100,
///  "processes": [{"kind": "white_noise", "sigma2": 1e-6, "noise_density": 1e-4},
///                {"kind": "gauss_markov", "beta_per_s": 0.01, "sigma2": 1e-8}, ...]}
/// ```
/// Written, white noise and random walk show both the variance and the density
/// (`noise_density`, unit/sqrt(Hz); `bias_random_walk`, unit/s/sqrt(Hz)); read, either may
/// be given, and when both are they must agree (to 1e-6 relative).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(try_from = "ModelSpecJson", into = "ModelSpecJson")]
pub struct ModelSpec {
    pub model: String,
    pub unit: String,
    pub sample_rate_hz: f64,
    pub processes: Vec<Process>,
}

impl From<ModelSpec> for ModelSpecJson {
    fn from(m: ModelSpec) -> Self {
        let dt = m.dt_s();
        let processes = m
            .processes
            .iter()
            .map(|p| match *p {
                Process::WhiteNoise { sigma2 } => ProcessJson::WhiteNoise {
                    sigma2: Some(sigma2),
                    noise_density: Some((sigma2 * dt).sqrt()),
                },
                Process::QuantizationNoise { q2 } => ProcessJson::QuantizationNoise { q2 },
                Process::RandomWalk { sigma2 } => ProcessJson::RandomWalk {
                    sigma2: Some(sigma2),
                    bias_random_walk: Some((sigma2 / dt).sqrt()),
                },
                Process::Drift { slope_per_s } => ProcessJson::Drift { slope_per_s },
                Process::GaussMarkov { beta_per_s, sigma2 } => {
                    ProcessJson::GaussMarkov { beta_per_s, sigma2 }
                }
            })
            .collect();
        ModelSpecJson {
            model: m.model,
            unit: m.unit,
            sample_rate_hz: m.sample_rate_hz,
            processes,
        }
    }
}

impl TryFrom<ModelSpecJson> for ModelSpec {
    type Error = ModelError;
    fn try_from(j: ModelSpecJson) -> Result<Self, ModelError> {
        let model = j.model.clone();
        if !(j.sample_rate_hz.is_finite() && j.sample_rate_hz > 0.0) {
            return Err(ModelError::BadRate {
                model,
                value: j.sample_rate_hz,
            });
        }
        let dt = 1.0 / j.sample_rate_hz;
        // sigma2 from a variance and/or a density (density^2 * factor = sigma2).
        let resolve = |index: usize,
                       kind: &'static str,
                       sigma2: Option<f64>,
                       density_name: &'static str,
                       density: Option<f64>,
                       factor: f64|
         -> Result<f64, ModelError> {
            for (field, value) in [("sigma2", sigma2), (density_name, density)] {
                if let Some(value) = value.filter(|v| !(v.is_finite() && *v > 0.0)) {
                    return Err(ModelError::BadValue {
                        model: model.clone(),
                        index,
                        kind,
                        field,
                        value,
                    });
                }
            }
            match (sigma2, density) {
                (Some(s), None) => Ok(s),
                (None, Some(d)) => Ok(d * d * factor),
                (Some(s), Some(d)) => {
                    let from_d = d * d * factor;
                    if (s - from_d).abs() <= 1e-6 * s.abs().max(from_d.abs()) {
                        Ok(s)
                    } else {
                        Err(ModelError::Inconsistent {
                            model: model.clone(),
                            index,
                            kind,
                            a: "sigma2",
                            va: s,
                            b: density_name,
                            vb: d,
                        })
                    }
                }
                (None, None) => Err(ModelError::BadValue {
                    model: model.clone(),
                    index,
                    kind,
                    field: "sigma2",
                    value: f64::NAN,
                }),
            }
        };
        let mut processes = Vec::with_capacity(j.processes.len());
        for (index, p) in j.processes.into_iter().enumerate() {
            processes.push(match p {
                ProcessJson::WhiteNoise {
                    sigma2,
                    noise_density,
                } => Process::WhiteNoise {
                    sigma2: resolve(
                        index,
                        "WN",
                        sigma2,
                        "noise_density",
                        noise_density,
                        1.0 / dt,
                    )?,
                },
                ProcessJson::QuantizationNoise { q2 } => Process::QuantizationNoise { q2 },
                ProcessJson::RandomWalk {
                    sigma2,
                    bias_random_walk,
                } => Process::RandomWalk {
                    sigma2: resolve(
                        index,
                        "RW",
                        sigma2,
                        "bias_random_walk",
                        bias_random_walk,
                        dt,
                    )?,
                },
                ProcessJson::Drift { slope_per_s } => Process::Drift { slope_per_s },
                ProcessJson::GaussMarkov { beta_per_s, sigma2 } => {
                    Process::GaussMarkov { beta_per_s, sigma2 }
                }
            });
        }
        let spec = ModelSpec {
            model: j.model,
            unit: j.unit,
            sample_rate_hz: j.sample_rate_hz,
            processes,
        };
        spec.validate()?;
        Ok(spec)
    }
}

impl ModelSpec {
    /// Reads a model JSON text (the simulator's input), validated.
    pub fn from_json(text: &str) -> Result<Self, serde_json::Error> {
        serde_json::from_str(text)
    }

    /// Sampling interval in seconds.
    pub fn dt_s(&self) -> f64 {
        1.0 / self.sample_rate_hz
    }

    /// The structure implied by the processes (in their order).
    pub fn structure(&self) -> Structure {
        Structure {
            kinds: self.processes.iter().map(|p| p.kind()).collect(),
        }
    }

    /// Checks the model string matches the processes, and every value is finite and
    /// positive (drift slope: finite).
    pub fn validate(&self) -> Result<(), ModelError> {
        if !(self.sample_rate_hz.is_finite() && self.sample_rate_hz > 0.0) {
            return Err(ModelError::BadRate {
                model: self.model.clone(),
                value: self.sample_rate_hz,
            });
        }
        let declared = Structure::parse(&self.model)?;
        let found = self.structure();
        let mut a = declared.kinds.clone();
        let mut b = found.kinds.clone();
        a.sort();
        b.sort();
        if a != b {
            return Err(ModelError::Mismatch {
                model: self.model.clone(),
                found: found.name(),
            });
        }
        for (index, p) in self.processes.iter().enumerate() {
            let kind = p.kind().token();
            let fields: Vec<(&'static str, f64, bool)> = match *p {
                Process::WhiteNoise { sigma2 } => vec![("sigma2", sigma2, true)],
                Process::QuantizationNoise { q2 } => vec![("q2", q2, true)],
                Process::RandomWalk { sigma2 } => vec![("sigma2", sigma2, true)],
                Process::Drift { slope_per_s } => vec![("slope_per_s", slope_per_s, false)],
                Process::GaussMarkov { beta_per_s, sigma2 } => {
                    vec![("beta_per_s", beta_per_s, true), ("sigma2", sigma2, true)]
                }
            };
            for (field, value, positive) in fields {
                if !value.is_finite() || (positive && value <= 0.0) {
                    return Err(ModelError::BadValue {
                        model: self.model.clone(),
                        index,
                        kind,
                        field,
                        value,
                    });
                }
            }
        }
        Ok(())
    }

    /// Transformed parameters (see the module doc), in process order.
    pub fn theta(&self) -> Vec<f64> {
        let dt = self.dt_s();
        let mut t = Vec::new();
        for p in &self.processes {
            match *p {
                Process::WhiteNoise { sigma2 } => t.push(sigma2.ln()),
                Process::QuantizationNoise { q2 } => t.push(q2.ln()),
                Process::RandomWalk { sigma2 } => t.push(sigma2.ln()),
                Process::Drift { slope_per_s } => t.push((slope_per_s * dt).powi(2).ln()),
                Process::GaussMarkov { beta_per_s, sigma2 } => {
                    t.push(beta_per_s.ln());
                    t.push(sigma2.ln());
                }
            }
        }
        t
    }

    /// The model with structure `s` at transformed parameters `theta`.
    pub fn from_theta(s: &Structure, theta: &[f64], unit: &str, sample_rate_hz: f64) -> Self {
        let dt = 1.0 / sample_rate_hz;
        let mut k = 0;
        let mut processes = Vec::with_capacity(s.kinds.len());
        for &kind in &s.kinds {
            processes.push(match kind {
                ProcessKind::WhiteNoise => Process::WhiteNoise {
                    sigma2: theta[k].exp(),
                },
                ProcessKind::QuantizationNoise => Process::QuantizationNoise { q2: theta[k].exp() },
                ProcessKind::RandomWalk => Process::RandomWalk {
                    sigma2: theta[k].exp(),
                },
                ProcessKind::Drift => Process::Drift {
                    slope_per_s: (0.5 * theta[k]).exp() / dt,
                },
                ProcessKind::GaussMarkov => Process::GaussMarkov {
                    beta_per_s: theta[k].exp(),
                    sigma2: theta[k + 1].exp(),
                },
            });
            k += kind.n_params();
        }
        ModelSpec {
            model: s.name(),
            unit: unit.to_string(),
            sample_rate_hz,
            processes,
        }
    }

    /// Theoretical Haar WV (unit^2) at levels j (filter width 2^j samples).
    pub fn wv_at_levels(&self, levels: &[u32]) -> Vec<f64> {
        let taus: Vec<f64> = levels.iter().map(|&j| (j as f64).exp2()).collect();
        let mut nu = vec![0.0; taus.len()];
        self.structure()
            .wv(&self.theta(), self.dt_s(), &taus, &mut nu, None);
        nu
    }

    /// Simulates `n` samples of the model (sum of independent processes). GM processes start
    /// in their stationary distribution; RW and drift start at one step from zero.
    pub fn simulate<R: Rng + ?Sized>(&self, n: usize, rng: &mut R) -> Vec<f64> {
        ModelSimulation::new(self).next_block(n, rng)
    }
}

/// A model simulated a block at a time, each process's state carried from one block to the
/// next, so a long series need not be held ([`ModelSpec::simulate`] is its one block). The
/// draws of a block come process after process, so a run cut into blocks is another draw
/// of the same model than the run in one block.
pub struct ModelSimulation<'a> {
    spec: &'a ModelSpec,
    /// Per process: its state (quantization noise: the last uniform draw; random walk:
    /// its level; Gauss-Markov: its value), None before its first sample.
    states: Vec<Option<f64>>,
    /// Samples simulated so far.
    t: usize,
}

impl<'a> ModelSimulation<'a> {
    pub fn new(spec: &'a ModelSpec) -> Self {
        Self {
            spec,
            states: vec![None; spec.processes.len()],
            t: 0,
        }
    }

    /// The next `n` samples.
    pub fn next_block<R: Rng + ?Sized>(&mut self, n: usize, rng: &mut R) -> Vec<f64> {
        let mut x = vec![0.0; n];
        self.add_next(&mut x, rng);
        x
    }

    /// Adds the next `x.len()` samples to `x`: [`Self::next_block`] into a buffer reused.
    pub fn add_next<R: Rng + ?Sized>(&mut self, x: &mut [f64], rng: &mut R) {
        let dt = self.spec.dt_s();
        let n = x.len();
        for (p, state) in self.spec.processes.iter().zip(self.states.iter_mut()) {
            match *p {
                Process::WhiteNoise { sigma2 } => {
                    let s = sigma2.sqrt();
                    for v in x.iter_mut() {
                        let z: f64 = StandardNormal.sample(rng);
                        *v += s * z;
                    }
                }
                Process::QuantizationNoise { q2 } => {
                    let s = (12.0 * q2).sqrt();
                    let mut prev: f64 = state.unwrap_or_else(|| rng.random());
                    for v in x.iter_mut() {
                        let u: f64 = rng.random();
                        *v += s * (u - prev);
                        prev = u;
                    }
                    *state = Some(prev);
                }
                Process::RandomWalk { sigma2 } => {
                    let s = sigma2.sqrt();
                    let mut level = state.unwrap_or(0.0);
                    for v in x.iter_mut() {
                        let z: f64 = StandardNormal.sample(rng);
                        level += s * z;
                        *v += level;
                    }
                    *state = Some(level);
                }
                Process::Drift { slope_per_s } => {
                    let w = slope_per_s * dt;
                    for (t, v) in (self.t..).zip(x.iter_mut()) {
                        *v += w * (t + 1) as f64;
                    }
                }
                Process::GaussMarkov { beta_per_s, sigma2 } => {
                    let phi = (-beta_per_s * dt).exp();
                    let innov = (sigma2 * -(-2.0 * beta_per_s * dt).exp_m1()).sqrt();
                    let mut value = state.unwrap_or_else(|| {
                        let z0: f64 = StandardNormal.sample(rng);
                        sigma2.sqrt() * z0
                    });
                    for v in x.iter_mut() {
                        let z: f64 = StandardNormal.sample(rng);
                        value = phi * value + innov * z;
                        *v += value;
                    }
                    *state = Some(value);
                }
            }
        }
        self.t += n;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// Oracle: nu = sigma2 / tau^2 * sum_k R(k) phi^|k| with R the autocorrelation of the
    /// unnormalised Haar filter (+1 h times, -1 h times), written as
    /// -sigma2/tau^2 sum_k R(k) (1 - phi^|k|) (sum R = 0) to stay accurate for phi -> 1.
    fn gm_wv_bruteforce(a: f64, sigma2: f64, h: usize) -> f64 {
        let tau = 2.0 * h as f64;
        let mut s = 0.0;
        for k in 1..2 * h {
            let r = if k <= h {
                2.0 * h as f64 - 3.0 * k as f64
            } else {
                -(2.0 * h as f64 - k as f64)
            };
            s += 2.0 * r * (-(-a * k as f64).exp_m1());
        }
        -sigma2 * s / (tau * tau)
    }

    #[test]
    fn gm_closed_form_matches_bruteforce_sum_in_both_regimes() {
        for &a in &[1e-7, 1.55e-5, 1e-3, 0.05, 0.7, 1.13, 5.0, 40.0] {
            for j in 1..=12 {
                let h = 1usize << (j - 1);
                let (g, _) = gm_shape(a, h as f64);
                let tau = 2.0 * h as f64;
                let closed = 2.0 * 0.3 * g / (tau * tau);
                let brute = gm_wv_bruteforce(a, 0.3, h);
                let rel = (closed - brute).abs() / brute.abs();
                assert!(
                    rel < 1e-9,
                    "a={a} j={j}: closed {closed} brute {brute} rel {rel}"
                );
            }
        }
    }

    #[test]
    fn gm_limits_are_white_noise_and_random_walk() {
        // Fast GM (a large): WN of variance sigma2.
        let (g, _) = gm_shape(50.0, 8.0);
        assert!((2.0 * g / 256.0 - 1.0 / 16.0).abs() < 1e-12);
        // Slow GM: RW with innovation 2 a sigma2.
        let a = 1e-9;
        let tau = 64.0;
        let (g, _) = gm_shape(a, tau / 2.0);
        let rw = 2.0 * a * (tau * tau + 2.0) / (12.0 * tau);
        assert!(((2.0 * g / (tau * tau)) / rw - 1.0).abs() < 1e-6);
    }

    #[test]
    fn parses_model_strings_and_rejects_bad_ones() {
        let s = Structure::parse("wn + 2GM + rw").unwrap();
        assert_eq!(s.name(), "WN+GM+GM+RW");
        assert_eq!(s.n_params(), 6);
        assert_eq!(Structure::parse("WN+2*AR1").unwrap().name(), "WN+GM+GM");
        assert!(matches!(
            Structure::parse("WN+XX"),
            Err(ModelError::UnknownProcess { token, .. }) if token == "XX"
        ));
        assert!(matches!(
            Structure::parse("WN+WN"),
            Err(ModelError::Duplicate { kind: "WN", .. })
        ));
        assert_eq!(Structure::parse("  "), Err(ModelError::Empty));
        assert!(Structure::parse("WN+0GM").is_err());
    }

    #[test]
    fn model_json_round_trips_and_accepts_densities() {
        let text = r#"{"model": "WN+RW+GM", "unit": "rad/s", "sample_rate_hz": 100,
            "processes": [{"kind": "white_noise", "noise_density": 0.001},
                          {"kind": "random_walk", "bias_random_walk": 0.0001},
                          {"kind": "gauss_markov", "beta_per_s": 0.5, "sigma2": 1e-6}]}"#;
        let m = ModelSpec::from_json(text).unwrap();
        match m.processes[0] {
            Process::WhiteNoise { sigma2 } => assert!((sigma2 - 1e-6 / 0.01).abs() < 1e-18),
            _ => panic!(),
        }
        match m.processes[1] {
            Process::RandomWalk { sigma2 } => assert!((sigma2 - 1e-8 * 0.01).abs() < 1e-22),
            _ => panic!(),
        }
        let v = serde_json::to_value(&m).unwrap();
        assert!((v["processes"][0]["noise_density"].as_f64().unwrap() - 0.001).abs() < 1e-15);
        let back = ModelSpec::from_json(&v.to_string()).unwrap();
        // serde_json's default float parser may be one ulp off: compare to 1e-12 relative.
        assert_eq!(back.structure(), m.structure());
        for (a, b) in back.theta().iter().zip(m.theta()) {
            assert!((a - b).abs() < 1e-12, "{a} vs {b}");
        }
        let clash = text.replace(
            r#""noise_density": 0.001"#,
            r#""noise_density": 0.001, "sigma2": 1"#,
        );
        let e = ModelSpec::from_json(&clash).unwrap_err().to_string();
        assert!(e.contains("disagree"), "{e}");
        let bad = r#"{"model": "WN+GM", "unit": "g", "sample_rate_hz": 100,
            "processes": [{"kind": "white_noise", "sigma2": 1}]}"#;
        let e = ModelSpec::from_json(bad).unwrap_err().to_string();
        assert!(e.contains("do not match"), "{e}");
        let neg = r#"{"model": "GM", "unit": "g", "sample_rate_hz": 100,
            "processes": [{"kind": "gauss_markov", "beta_per_s": -1, "sigma2": 1}]}"#;
        let e = ModelSpec::from_json(neg).unwrap_err().to_string();
        assert!(e.contains("beta_per_s"), "{e}");
    }

    #[test]
    fn theta_round_trip_keeps_physical_values() {
        let m = ModelSpec {
            model: "WN+QN+RW+DR+GM".into(),
            unit: "deg/s".into(),
            sample_rate_hz: 100.0,
            processes: vec![
                Process::WhiteNoise { sigma2: 0.65 },
                Process::QuantizationNoise { q2: 1e-4 },
                Process::RandomWalk { sigma2: 1e-9 },
                Process::Drift { slope_per_s: 1e-5 },
                Process::GaussMarkov {
                    beta_per_s: 1.68,
                    sigma2: 0.00168,
                },
            ],
        };
        let back = ModelSpec::from_theta(&m.structure(), &m.theta(), "deg/s", 100.0);
        let (x, y) = (
            serde_json::to_value(&m).unwrap(),
            serde_json::to_value(&back).unwrap(),
        );
        for (a, b) in x["processes"]
            .as_array()
            .unwrap()
            .iter()
            .zip(y["processes"].as_array().unwrap())
        {
            for key in ["sigma2", "q2", "slope_per_s", "beta_per_s"] {
                if let (Some(p), Some(q)) = (a.get(key), b.get(key)) {
                    let (p, q) = (p.as_f64().unwrap(), q.as_f64().unwrap());
                    assert!((p - q).abs() <= 1e-12 * p.abs(), "{key}: {p} vs {q}");
                }
            }
        }
    }

    #[test]
    fn simulated_wv_matches_theory() {
        use rand::SeedableRng;
        let m = ModelSpec {
            model: "WN+QN+GM".into(),
            unit: "rad/s".into(),
            sample_rate_hz: 100.0,
            processes: vec![
                Process::WhiteNoise { sigma2: 1.0 },
                Process::QuantizationNoise { q2: 0.5 },
                Process::GaussMarkov {
                    beta_per_s: 2.0,
                    sigma2: 0.5,
                },
            ],
        };
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        let n = 1 << 18;
        let x = m.simulate(n, &mut rng);
        let mut s = vec![0.0; n + 1];
        for t in 0..n {
            s[t + 1] = s[t] + x[t];
        }
        for j in 1..=6u32 {
            let h = 1usize << (j - 1);
            let tau = 2 * h;
            let mut acc = 0.0;
            for t in tau..=n {
                let w = ((s[t] - s[t - h]) - (s[t - h] - s[t - tau])) / tau as f64;
                acc += w * w;
            }
            let est = acc / (n - tau + 1) as f64;
            let theory = m.wv_at_levels(&[j])[0];
            assert!(
                (est / theory - 1.0).abs() < 0.05,
                "j={j}: {est} vs {theory}"
            );
        }
    }

    /// A model simulated a block at a time carries every process's state over the blocks:
    /// the step from one block's last sample to the next's first is drawn as any other (a
    /// random walk's level or a Gauss-Markov value started anew would jump there by its
    /// whole spread, a hundred times the step's variance here). Over 2 000 block edges
    /// the mean squared step is within 15% of the steps' inside the blocks.
    #[test]
    fn a_simulation_in_blocks_carries_its_state_across_them() {
        use rand::SeedableRng;
        let m = ModelSpec {
            model: "RW+GM+QN".into(),
            unit: "rad/s".into(),
            sample_rate_hz: 100.0,
            processes: vec![
                Process::RandomWalk { sigma2: 1.0 },
                Process::GaussMarkov {
                    beta_per_s: 0.1,
                    sigma2: 100.0,
                },
                Process::QuantizationNoise { q2: 0.01 },
            ],
        };
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let mut simulation = ModelSimulation::new(&m);
        let (mut edge, mut inside) = ((0.0, 0usize), (0.0, 0usize));
        let mut last: Option<f64> = None;
        for _ in 0..2001 {
            let block = simulation.next_block(100, &mut rng);
            if let Some(previous) = last {
                edge.0 += (block[0] - previous).powi(2);
                edge.1 += 1;
            }
            for w in block.windows(2) {
                inside.0 += (w[1] - w[0]).powi(2);
                inside.1 += 1;
            }
            last = block.last().copied();
        }
        let ratio = (edge.0 / edge.1 as f64) / (inside.0 / inside.1 as f64);
        assert!((ratio - 1.0).abs() < 0.15, "{ratio}");
    }

    proptest! {
        #[test]
        fn jacobian_matches_finite_differences(
            ln_wn in -8.0f64..2.0, ln_q in -10.0f64..0.0, ln_rw in -20.0f64..-5.0,
            ln_dr in -30.0f64..-10.0, ln_beta in -8.0f64..5.0, ln_s2 in -8.0f64..1.0,
            ln_beta2 in -8.0f64..5.0,
        ) {
            let s = Structure::parse("WN+QN+RW+DR+GM+GM").unwrap();
            let theta = [ln_wn, ln_q, ln_rw, ln_dr, ln_beta, ln_s2, ln_beta2, ln_s2 - 1.0];
            let taus: Vec<f64> = (1..=16).map(|j| (j as f64).exp2()).collect();
            let p = theta.len();
            let mut nu = vec![0.0; taus.len()];
            let mut jac = vec![0.0; taus.len() * p];
            s.wv(&theta, 0.01, &taus, &mut nu, Some(&mut jac));
            for k in 0..p {
                let step = 1e-6;
                let mut tp = theta;
                tp[k] += step;
                let mut tm = theta;
                tm[k] -= step;
                let mut np = vec![0.0; taus.len()];
                let mut nm = vec![0.0; taus.len()];
                s.wv(&tp, 0.01, &taus, &mut np, None);
                s.wv(&tm, 0.01, &taus, &mut nm, None);
                for j in 0..taus.len() {
                    let fd = (np[j] - nm[j]) / (2.0 * step);
                    let an = jac[j * p + k];
                    // Relative to the WV itself: the derivative of a log-parameterised term
                    // is bounded by that term, so this scale is the natural one.
                    prop_assert!((fd - an).abs() <= 1e-6 * nu[j].abs() + 1e-300,
                        "j={} k={}: fd {} analytic {} nu {}", j, k, fd, an, nu[j]);
                }
            }
        }
    }
}
