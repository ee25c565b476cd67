//! Least squares on inner products, jointly with the calibration: a deterministic term's
//! regressor is seen through what the calibration (boresight, lever arm, biases, or a mean
//! per channel on static data) would absorb of it, on its own channel and on the others the
//! calibration's pull reaches, and a fit of several terms is solved on their inner products
//! with each other, with the error and with every baseline simulation. The inner products
//! are those of generalised least squares: each channel's series filtered by the whitening
//! filter of its baseline noise model ([`super::whiten`]). The spread of a coefficient
//! comes from the same fit on the simulations (so slow noise correlated with slow
//! manoeuvres is in the null distribution) and from batch means of the measured residual;
//! [`eliminate_on_moments`] is the stepwise selection over such terms.

use std::borrow::Cow;
use std::sync::Arc;

use super::terms::Candidate;
pub(super) use super::white_space::WhiteSpace;
use crate::calibration::DesignRows;
use crate::model::{Cause, Channel};

/// What a least-squares fit of per-channel terms jointly with the calibration needs of the
/// calibration: with a reference, the calibration design (weighted least squares over every
/// channel's rows: boresight, lever arm, biases); without one (static data), a mean per
/// channel.
#[derive(Clone, Copy)]
pub(super) enum Absorber<'a> {
    Design(DesignRows<'a>),
    Mean,
}

/// Where a term's regressor comes from: a series of the run (borrowed, so a term does not
/// copy it), or a bias step made when asked for.
#[derive(Clone, Copy)]
pub(super) enum Regressor<'a> {
    Series(&'a [f64]),
    /// 0 before epoch `at`, 1 from it on, over `n` epochs.
    Step {
        at: usize,
        n: usize,
    },
}

impl<'a> Regressor<'a> {
    /// The regressor's values, one per epoch.
    pub fn values(&self) -> Cow<'a, [f64]> {
        match *self {
            Regressor::Series(x) => Cow::Borrowed(x),
            Regressor::Step { at, n } => {
                Cow::Owned((0..n).map(|t| if t >= at { 1.0 } else { 0.0 }).collect())
            }
        }
    }
}

/// A regressor on one channel seen through the calibration: the parameters the calibration
/// would take from it, `absorbed` = (X'WX)^-1 X_c' W_c x.
#[derive(Clone)]
pub(super) struct Projection {
    pub absorbed: nalgebra::DVector<f64>,
}

impl Absorber<'_> {
    pub fn project(&self, channel: Channel, x: &[f64]) -> Projection {
        match self {
            Absorber::Design(d) => Projection {
                absorbed: d.bread() * d.moments(channel.index(), x),
            },
            Absorber::Mean => Projection {
                absorbed: nalgebra::DVector::from_element(
                    1,
                    x.iter().sum::<f64>() / x.len().max(1) as f64,
                ),
            },
        }
    }
    /// `x` on `channel` minus what the calibration takes from it there.
    fn own(&self, channel: Channel, x: &[f64], p: &Projection) -> Vec<f64> {
        match self {
            Absorber::Design(d) => x
                .iter()
                .zip(d.fitted(channel.index(), &p.absorbed))
                .map(|(v, f)| v - f)
                .collect(),
            Absorber::Mean => x.iter().map(|v| v - p.absorbed[0]).collect(),
        }
    }
    /// Every channel's series `y` (gx..az) less what the calibration fitted on all of them
    /// together takes from it: what the engine sees of a series after the calibration.
    pub fn calibrate(&self, y: &[Option<&[f64]>; 6]) -> [Option<Vec<f64>>; 6] {
        let theta = match self {
            Absorber::Design(d) => Some(d.bread() * d.moments_all(y)),
            Absorber::Mean => None,
        };
        std::array::from_fn(|ch| {
            let y = y[ch]?;
            Some(match (self, &theta) {
                (Absorber::Design(d), Some(theta)) if d.has_channel(ch) => y
                    .iter()
                    .zip(d.fitted(ch, theta))
                    .map(|(v, f)| v - f)
                    .collect(),
                (Absorber::Design(_), _) => y.to_vec(),
                (Absorber::Mean, _) => {
                    let m = y.iter().sum::<f64>() / y.len().max(1) as f64;
                    y.iter().map(|v| v - m).collect()
                }
            })
        })
    }
}

fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

/// A deterministic term on one channel: its regressor stripped of what the calibration
/// absorbs from it on its own channel (`own`), filtered by the channel's whitening filter;
/// on the other channels the calibration reaches, its signature is minus the calibration's
/// filtered columns times what it absorbed, kept as moments ([`WhiteSpace`]). With them, its
/// inner products in that metric with the error and with each baseline simulation, and its
/// coefficient with the standard error the simulations give it.
#[derive(Clone)]
pub(super) struct Term<'a> {
    pub channel: Channel,
    pub name: String,
    pub cause: Cause,
    /// The body axis of the regressor (x, y, z = 0, 1, 2).
    pub axis: usize,
    /// The regressor, and what absorbs of it: the term's unfiltered signature on its own
    /// channel ([`Term::own`]) is made from them when asked for rather than held, as a
    /// channel's dozen candidates would hold a dozen series of the drive's length.
    regressor: Regressor<'a>,
    absorber: Absorber<'a>,
    /// Mean and variance of [`Term::own`] (channel unit / regressor unit, squared).
    pub own_mean: f64,
    pub own_variance: f64,
    pub projection: Projection,
    /// `own` filtered by its channel's whitening filter.
    white_own: Arc<[f64]>,
    /// The filtered calibration columns of its own channel times `white_own` (where the
    /// calibration reaches that channel).
    on_own_columns: Option<nalgebra::DVector<f64>>,
    /// Per other channel the calibration reaches, the Gram matrix of its filtered columns
    /// times what this term's regressor gives the calibration.
    pulled: [Option<nalgebra::DVector<f64>>; 6],
    on_error: f64,
    on_sims: Vec<f64>,
    pub coef: f64,
    pub se: f64,
    /// Smallest standard error the term's coefficient may have: the measured-residual
    /// spread of its own channel's fit, kept for the joint fit across channels.
    pub sd_floor: f64,
    /// Some(p-value of its own estimator) when the coefficient (and its standard error)
    /// comes from that estimator, not from the regression: a bias step's local estimate.
    /// The selection neither refits nor drops such a term; it fits the others on what the
    /// term leaves ([`Term::take_out`]).
    pub fixed: Option<f64>,
}

impl<'a> Term<'a> {
    /// One candidate as a term, coefficient not yet set.
    pub fn new(space: &WhiteSpace<'a>, channel: Channel, c: &Candidate<'a>) -> Self {
        Self::batch(space, channel, std::slice::from_ref(c))
            .pop()
            .expect("one term per candidate")
    }

    /// Every candidate on `channel` as a term, coefficients not yet set; the simulations
    /// are visited once for all of them.
    pub fn batch(space: &WhiteSpace<'a>, channel: Channel, cands: &[Candidate<'a>]) -> Vec<Self> {
        use rayon::prelude::*;
        let own_ch = channel.index();
        let absorber = space.absorber();
        let whitener = space.whitener(own_ch).expect("a channel of the run");
        let mut terms: Vec<Term> = cands
            .par_iter()
            .map(|c| {
                let values = c.values.values();
                let projection = absorber.project(channel, &values);
                let own = absorber.own(channel, &values, &projection);
                let own_mean = own.iter().sum::<f64>() / own.len().max(1) as f64;
                let pulled = std::array::from_fn(|ch| {
                    let g = space.column_gram(ch).filter(|_| ch != own_ch)?;
                    Some(g * &projection.absorbed)
                });
                Term {
                    channel,
                    name: c.name.clone(),
                    cause: c.cause,
                    axis: c.axis,
                    white_own: whitener.apply(&own).into(),
                    regressor: c.values,
                    absorber,
                    own_mean,
                    own_variance: super::engine::variance(&own),
                    projection,
                    on_own_columns: None,
                    pulled,
                    on_error: 0.0,
                    on_sims: Vec::new(),
                    coef: 0.0,
                    se: f64::NAN,
                    sd_floor: 0.0,
                    fixed: None,
                }
            })
            .collect();
        if let Some(on_columns) = space.on_white_columns(own_ch, &|column| {
            terms
                .iter()
                .map(|t| dot(column, &t.white_own))
                .collect::<Vec<f64>>()
        }) {
            for (k, t) in terms.iter_mut().enumerate() {
                let m = on_columns.iter().map(|c| c[k]);
                t.on_own_columns = Some(nalgebra::DVector::from_iterator(on_columns.len(), m));
            }
        }
        let white_error = space.error(channel);
        for t in terms.iter_mut() {
            t.on_error =
                dot(&t.white_own, white_error) + t.pulled_moments(|ch| space.columns_on_error(ch));
        }
        let per_replicate: Vec<Vec<f64>> = {
            let terms = &terms;
            let on_own = space.map_white_sims(own_ch, &|sim| {
                terms
                    .iter()
                    .map(|t| dot(&t.white_own, sim))
                    .collect::<Vec<f64>>()
            });
            on_own
                .into_iter()
                .enumerate()
                .map(|(r, own)| {
                    own.iter()
                        .zip(terms)
                        .map(|(o, t)| o + t.pulled_moments(|ch| space.columns_on_sim(ch, r)))
                        .collect()
                })
                .collect()
        };
        for (k, t) in terms.iter_mut().enumerate() {
            t.on_sims = per_replicate.iter().map(|r| r[k]).collect();
        }
        terms
    }

    /// A series' inner product with what the calibration's pull leaves of this term on the
    /// other channels (minus their filtered columns times what it absorbed), from the
    /// columns' moments with the series on each channel (`on`).
    fn pulled_moments<'s>(&self, on: impl Fn(usize) -> Option<&'s nalgebra::DVector<f64>>) -> f64 {
        (0..6)
            .filter(|&ch| ch != self.channel.index())
            .filter_map(|ch| on(ch).map(|m| -m.dot(&self.projection.absorbed)))
            .sum()
    }

    /// The regressor less what the calibration absorbs of it on its own channel, one value
    /// per epoch (made anew at each call).
    pub fn own(&self) -> Vec<f64> {
        let values = self.regressor.values();
        self.absorber.own(self.channel, &values, &self.projection)
    }

    /// The filtered signature on the term's own channel.
    fn white_own(&self) -> &[f64] {
        &self.white_own
    }

    /// A term whose coefficient `coef` (standard error `se`, two-sided p-value `p_value`
    /// against zero) comes from outside the regression; see [`Term::fixed`].
    pub fn fix(&mut self, coef: f64, se: f64, p_value: f64) {
        self.coef = coef;
        self.se = se;
        self.sd_floor = se;
        self.fixed = Some(p_value);
    }

    /// Fits this term on the error less `fixed` (its coefficient times its regressor): the
    /// error's inner product is linear in the error, so it loses the fixed coefficient
    /// times the two terms' inner product.
    pub fn take_out(&mut self, fixed: &Term) {
        let g = gram(self, fixed);
        self.on_error -= fixed.coef * g;
    }

    /// The filtered error of the term's own channel less `coef` times this term there:
    /// what [`MeasuredSpread`] needs when this term is fixed.
    pub fn taken_from(&self, white_error: &[f64]) -> Vec<f64> {
        white_error
            .iter()
            .zip(self.white_own())
            .map(|(v, x)| v - self.coef * x)
            .collect()
    }
}

/// Inner product of two terms' signatures in the whitened metric, over every channel: on a
/// channel that is neither's own, the pulls' product through the columns' Gram matrix; on
/// one term's own channel, its filtered regressor against the other's pull there.
pub(super) fn gram(a: &Term, b: &Term) -> f64 {
    let (ca, cb) = (a.channel.index(), b.channel.index());
    let mut g = if ca == cb {
        dot(&a.white_own, &b.white_own)
    } else {
        let own_a = a.on_own_columns.as_ref();
        let own_b = b.on_own_columns.as_ref();
        -own_a.map_or(0.0, |m| m.dot(&b.projection.absorbed))
            - own_b.map_or(0.0, |m| m.dot(&a.projection.absorbed))
    };
    for ch in (0..6).filter(|&ch| ch != ca && ch != cb) {
        if let Some(p) = &a.pulled[ch] {
            g += p.dot(&b.projection.absorbed);
        }
    }
    g
}

/// The Gram matrix of `terms`.
pub(super) fn gram_matrix(terms: &[Term]) -> nalgebra::DMatrix<f64> {
    nalgebra::DMatrix::from_fn(terms.len(), terms.len(), |a, b| gram(&terms[a], &terms[b]))
}

/// The error left after a least-squares fit of every one of `terms` (named or not, jointly
/// with the calibration; exactly collinear directions get no coefficient): what no
/// candidate can explain, however weakly. Why: a term too weak to be named at the run's
/// family-wise level still leaves its pattern in the error, and a bias step looked for on
/// that pattern finds a turn's onset.
pub(super) fn full_fit_residual(e: &[f64], terms: &[Term]) -> Vec<f64> {
    let k = terms.len();
    let beta = if k == 0 {
        nalgebra::DVector::zeros(0)
    } else {
        let gram = gram_matrix(terms);
        let rhs = nalgebra::DVector::from_iterator(k, terms.iter().map(|t| t.on_error));
        let scale = gram.diagonal().amax().max(f64::MIN_POSITIVE);
        gram.svd(true, true)
            .solve(&rhs, 1e-10 * scale)
            .unwrap_or_else(|_| nalgebra::DVector::zeros(k))
    };
    let mut r = e.to_vec();
    for (t, b) in terms.iter().zip(beta.iter()) {
        r.iter_mut().zip(t.own()).for_each(|(v, x)| *v -= b * x);
    }
    let m = r.iter().sum::<f64>() / r.len().max(1) as f64;
    r.iter_mut().for_each(|v| *v -= m);
    r
}

/// Coefficients, null standard deviations and |z| of a least-squares fit on moments.
struct MomentFit {
    beta: Vec<f64>,
    sd: Vec<f64>,
    z: Vec<f64>,
}

/// The error a fit of terms on one channel leaves, for a spread of its coefficients that
/// does not lean on the baseline model: the channel's filtered error
/// ([`WhiteSpace::error`]).
#[derive(Clone, Copy)]
pub(super) struct MeasuredSpread<'a> {
    pub white_error: &'a [f64],
}

/// Blocks of the batch-means spread: long enough (45 s of a 900 s drive) to hold most of the
/// correlation of a Gauss-Markov wander of 20 s, many enough for a spread within ~16%.
const SPREAD_BLOCKS: usize = 20;

/// Standard deviations of the coefficients from the measured residual itself (batch means:
/// the coefficients' scores summed over SPREAD_BLOCKS consecutive blocks, in a sandwich with
/// the inverse Gram matrix). Why: the simulated spread assumes the baseline's noise; when the
/// channel's correlated noise is stronger than the baseline's (a noise change), that spread
/// is too small and slow wander correlated with slow manoeuvres is named as terms.
fn measured_spread(
    spread: MeasuredSpread,
    terms: &[Term],
    active: &[usize],
    beta: &[f64],
    gram_inv: &nalgebra::DMatrix<f64>,
) -> Vec<f64> {
    let n = spread.white_error.len();
    let mut u = spread.white_error.to_vec();
    for (a, &k) in active.iter().enumerate() {
        u.iter_mut()
            .zip(terms[k].white_own())
            .for_each(|(v, x)| *v -= beta[a] * x);
    }
    let mean = u.iter().sum::<f64>() / n.max(1) as f64;
    let block = (n / SPREAD_BLOCKS).max(1);
    let scores: Vec<nalgebra::DVector<f64>> = (0..n / block)
        .map(|b| {
            let range = b * block..(b + 1) * block;
            nalgebra::DVector::from_iterator(
                active.len(),
                active.iter().map(|&k| {
                    terms[k].white_own()[range.clone()]
                        .iter()
                        .zip(&u[range.clone()])
                        .map(|(x, v)| x * (v - mean))
                        .sum::<f64>()
                }),
            )
        })
        .collect();
    let blocks = scores.len() as f64;
    let centre = scores
        .iter()
        .fold(nalgebra::DVector::zeros(active.len()), |acc, s| acc + s)
        / blocks;
    let meat = scores.iter().fold(
        nalgebra::DMatrix::zeros(active.len(), active.len()),
        |acc, s| {
            let d = s - &centre;
            acc + &d * d.transpose()
        },
    ) * (blocks / (blocks - 1.0).max(1.0));
    let cov = gram_inv * meat * gram_inv;
    (0..active.len())
        .map(|a| cov[(a, a)].max(0.0).sqrt())
        .collect()
}

/// Fits the `active` terms on their moments (None when they are exactly collinear). The
/// spread of each coefficient is that of the same fit on every baseline simulation, or,
/// when `spread` is given and it is larger, the batch-means spread of the measured
/// residual.
fn fit_on_moments(
    gram: &nalgebra::DMatrix<f64>,
    terms: &[Term],
    active: &[usize],
    spread: Option<MeasuredSpread>,
) -> Option<MomentFit> {
    let g = nalgebra::DMatrix::from_fn(active.len(), active.len(), |a, b| {
        gram[(active[a], active[b])]
    });
    let chol = g.cholesky()?;
    let solve = |rhs: &dyn Fn(usize) -> f64| {
        chol.solve(&nalgebra::DVector::from_iterator(
            active.len(),
            active.iter().map(|&k| rhs(k)),
        ))
    };
    let beta: Vec<f64> = solve(&|k| terms[k].on_error).iter().copied().collect();
    let replicates = terms[active[0]].on_sims.len();
    let null: Vec<nalgebra::DVector<f64>> = (0..replicates)
        .map(|r| solve(&|k| terms[k].on_sims[r]))
        .collect();
    let reps = null.len() as f64;
    let mut sd: Vec<f64> = (0..active.len())
        .map(|a| {
            let m = null.iter().map(|x| x[a]).sum::<f64>() / reps;
            (null.iter().map(|x| (x[a] - m).powi(2)).sum::<f64>() / (reps - 1.0).max(1.0)).sqrt()
        })
        .collect();
    if let Some(spread) = spread {
        let measured = measured_spread(spread, terms, active, &beta, &chol.inverse());
        sd.iter_mut().zip(measured).for_each(|(s, m)| *s = s.max(m));
    }
    for (s, &k) in sd.iter_mut().zip(active) {
        *s = s.max(terms[k].sd_floor);
    }
    let z = (0..active.len())
        .map(|a| {
            if sd[a] > 0.0 {
                (beta[a] / sd[a]).abs()
            } else {
                0.0
            }
        })
        .collect();
    Some(MomentFit { beta, sd, z })
}

/// Stepwise selection on moments. `gram` holds the terms' inner products after the
/// calibration; each term carries its moment with the error and with every baseline
/// simulation. Backward: the least significant term goes while one is below `z_strict` or
/// `small` (too little variance explained at its coefficient). Forward: of the terms left
/// out, the most significant when added to the survivors comes back if it passes, and the
/// backward pass runs again. The forward pass matters when two terms are nearly collinear
/// (omega_z and f_y ~ speed * omega_z on a car): backward elimination drops whichever is
/// slightly weaker in the crowded full model, and the proxy left alone may fall short where
/// the true term alone would not. Each term comes back at most once, so this ends. Returns
/// (term, coefficient, null sd) of the survivors.
pub(super) fn eliminate_on_moments(
    gram: &nalgebra::DMatrix<f64>,
    terms: &[Term],
    z_strict: f64,
    small: &dyn Fn(usize, f64) -> bool,
    spread: Option<MeasuredSpread>,
) -> Vec<(usize, f64, f64)> {
    let mut active: Vec<usize> = (0..terms.len()).collect();
    let mut brought_back: Vec<usize> = Vec::new();
    loop {
        let fit = loop {
            if active.is_empty() {
                break None;
            }
            let Some(fit) = fit_on_moments(gram, terms, &active, spread) else {
                // Exactly collinear: the term with the weakest marginal fit goes.
                let marginal = |a: usize| {
                    let k = active[a];
                    terms[k].on_error.abs() / gram[(k, k)].max(1e-300).sqrt()
                };
                let weakest = (0..active.len())
                    .min_by(|&a, &b| marginal(a).total_cmp(&marginal(b)))
                    .expect("active is not empty");
                active.remove(weakest);
                continue;
            };
            let failing =
                (0..active.len()).filter(|&a| fit.z[a] < z_strict || small(active[a], fit.beta[a]));
            match failing.min_by(|&a, &b| fit.z[a].total_cmp(&fit.z[b])) {
                Some(a) => {
                    active.remove(a);
                }
                None => break Some(fit),
            }
        };
        let best = (0..terms.len())
            .filter(|k| !active.contains(k) && !brought_back.contains(k))
            .filter_map(|k| {
                let with: Vec<usize> = active.iter().copied().chain([k]).collect();
                let f = fit_on_moments(gram, terms, &with, spread)?;
                let (z, b) = (f.z[with.len() - 1], f.beta[with.len() - 1]);
                (z >= z_strict && !small(k, b)).then_some((k, z))
            })
            .max_by(|a, b| a.1.total_cmp(&b.1));
        match best {
            Some((k, _)) => {
                brought_back.push(k);
                active.push(k);
            }
            None => {
                return fit.map_or_else(Vec::new, |f| {
                    active
                        .iter()
                        .enumerate()
                        .map(|(a, &k)| (k, f.beta[a], f.sd[a]))
                        .collect()
                });
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;
    use rand_distr::{Distribution, StandardNormal};

    /// Candidates on one channel without a calibration design, fitted with a white-noise
    /// baseline of sd 0.05 (so generalised least squares is ordinary least squares): the
    /// columns' terms, their Gram matrix and the channel's filtered error.
    fn moment_terms<'a>(
        e: &[f64],
        sims: &'a [Vec<f64>],
        columns: &'a [(&str, Vec<f64>)],
    ) -> (nalgebra::DMatrix<f64>, Vec<Term<'a>>, Vec<f64>) {
        let absorber = Absorber::Mean;
        let spec = crate::gmwm::model::ModelSpec {
            model: "WN".into(),
            unit: "rad/s".into(),
            sample_rate_hz: 100.0,
            processes: vec![crate::gmwm::model::Process::WhiteNoise { sigma2: 0.0025 }],
        };
        let mut whiteners: [Option<super::super::whiten::Whitener>; 6] =
            std::array::from_fn(|_| None);
        whiteners[0] = Some(super::super::whiten::Whitener::new(&spec, e.len()));
        let mut errors: [Option<&[f64]>; 6] = [None; 6];
        errors[0] = Some(e);
        let sim_of = move |r: usize, ch: usize| (ch == 0).then(|| sims[r].clone());
        let space = WhiteSpace::new(
            absorber,
            whiteners,
            errors,
            sims.len(),
            Box::new(sim_of),
            usize::MAX,
        );
        let terms: Vec<Term> = columns
            .iter()
            .map(|(name, values)| {
                let c = Candidate {
                    name: (*name).into(),
                    values: Regressor::Series(values),
                    cause: Cause::ScaleFactor,
                    axis: 0,
                };
                Term::new(&space, Channel::Gx, &c)
            })
            .collect();
        let white_error = space.error(Channel::Gx).to_vec();
        (gram_matrix(&terms), terms, white_error)
    }

    fn white_series(rng: &mut ChaCha8Rng, n: usize, sigma: f64) -> Vec<f64> {
        (0..n)
            .map(|_| sigma * Distribution::<f64>::sample(&StandardNormal, rng))
            .collect()
    }

    #[test]
    fn stepwise_selection_keeps_the_true_term_over_its_proxy_and_names_nothing_in_noise() {
        let mut rng = ChaCha8Rng::seed_from_u64(31);
        let n = 20_000;
        let t: Vec<f64> = (0..n).map(|k| k as f64 * 0.01).collect();
        let truth: Vec<f64> = t
            .iter()
            .map(|t| (0.31 * t).sin() + 0.5 * (1.7 * t).sin())
            .collect();
        let proxy: Vec<f64> = truth
            .iter()
            .zip(&t)
            .map(|(x, t)| x * (1.0 + 0.4 * (0.05 * t).sin()))
            .collect();
        let unrelated: Vec<f64> = t.iter().map(|t| (0.9 * t).cos()).collect();
        let sims: Vec<Vec<f64>> = (0..30).map(|_| white_series(&mut rng, n, 0.05)).collect();
        let noise = white_series(&mut rng, n, 0.05);
        let columns = [
            ("truth", truth.clone()),
            ("proxy", proxy),
            ("unrelated", unrelated),
        ];
        let never_small = |_: usize, _: f64| false;

        let e: Vec<f64> = truth
            .iter()
            .zip(&noise)
            .map(|(x, w)| 0.02 * x + w)
            .collect();
        let (gram, terms, white_error) = moment_terms(&e, &sims, &columns);
        let kept = eliminate_on_moments(
            &gram,
            &terms,
            4.0,
            &never_small,
            Some(MeasuredSpread {
                white_error: &white_error,
            }),
        );
        assert_eq!(kept.len(), 1, "{kept:?}");
        let (k, b, sd) = kept[0];
        assert_eq!(terms[k].name, "truth");
        assert!((b - 0.02).abs() < 3.0 * sd, "{b} +- {sd}");

        let (gram, terms, white_error) = moment_terms(&noise, &sims, &columns);
        let kept = eliminate_on_moments(
            &gram,
            &terms,
            4.0,
            &never_small,
            Some(MeasuredSpread {
                white_error: &white_error,
            }),
        );
        assert!(kept.is_empty(), "{kept:?}");
    }

    #[test]
    fn the_measured_spread_guards_against_a_noise_stronger_than_the_baseline() {
        // The baseline simulations are white; the measured error is a slow random walk that
        // wanders with a slow regressor. Against the simulations alone the slope is
        // "significant"; with the measured residual's batch-means spread it is not.
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let n = 20_000;
        let slow: Vec<f64> = (0..n).map(|k| (k as f64 * 2e-4).sin()).collect();
        let sims: Vec<Vec<f64>> = (0..30).map(|_| white_series(&mut rng, n, 0.05)).collect();
        let mut walk = 0.0;
        let e: Vec<f64> = (0..n)
            .map(|_| {
                walk += 0.01 * Distribution::<f64>::sample(&StandardNormal, &mut rng);
                walk + 0.05 * Distribution::<f64>::sample(&StandardNormal, &mut rng)
            })
            .collect();
        let columns = [("slow", slow)];
        let (gram, terms, white_error) = moment_terms(&e, &sims, &columns);
        let never_small = |_: usize, _: f64| false;
        assert_eq!(
            eliminate_on_moments(&gram, &terms, 4.0, &never_small, None).len(),
            1
        );
        assert!(eliminate_on_moments(
            &gram,
            &terms,
            4.0,
            &never_small,
            Some(MeasuredSpread {
                white_error: &white_error
            })
        )
        .is_empty());
    }
}
