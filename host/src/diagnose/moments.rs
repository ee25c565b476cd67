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
use std::ops::Range;

use rayon::prelude::*;

use super::engine::{DiagnoseError, Run};
use super::signals::RunSignals;
use super::terms::Candidate;
pub(super) use super::white_space::WhiteSpace;
use crate::calibration::DesignRows;
use crate::model::{Cause, Channel};
use crate::series_bank::{block_ranges, SeriesBank};

/// What a least-squares fit of per-channel terms jointly with the calibration needs of the
/// calibration: with a reference, the calibration design (weighted least squares over every
/// channel's rows: boresight, lever arm, biases); without one (static data), a mean per
/// channel.
#[derive(Clone, Copy)]
pub(super) enum Absorber<'a> {
    Design(DesignRows<'a>),
    Mean,
}

/// Where a term's regressor comes from: a series held (borrowed, so a term does not copy
/// it), a series of the run's signals (read when asked for: on a long run from their
/// temporary file), or a bias step made when asked for.
#[derive(Clone, Copy)]
pub(super) enum Regressor<'a> {
    #[cfg(test)]
    Series(&'a [f64]),
    /// Series `series` of the run's signals ([`RunSignals::dynamics_index`]).
    Signal {
        signals: &'a RunSignals,
        series: usize,
    },
    /// 0 before epoch `at`, 1 from it on, over `n` epochs.
    Step { at: usize, n: usize },
}

impl<'a> Regressor<'a> {
    /// The regressor's values over the epochs `range`.
    pub fn values_in(&self, range: Range<usize>) -> Result<Cow<'a, [f64]>, DiagnoseError> {
        Ok(match *self {
            #[cfg(test)]
            Regressor::Series(x) => Cow::Borrowed(&x[range]),
            Regressor::Signal { signals, series } => signals.series_in(series, range)?,
            Regressor::Step { at, .. } => {
                Cow::Owned(range.map(|t| if t >= at { 1.0 } else { 0.0 }).collect())
            }
        })
    }

    /// Epochs.
    fn epochs(&self) -> usize {
        match *self {
            #[cfg(test)]
            Regressor::Series(x) => x.len(),
            Regressor::Signal { signals, .. } => signals.epochs(),
            Regressor::Step { n, .. } => n,
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
    /// What the calibration takes from a regressor on `channel` (read a block at a time).
    fn project_blocks(
        &self,
        channel: Channel,
        x: &Regressor<'_>,
    ) -> Result<Projection, DiagnoseError> {
        Ok(match self {
            Absorber::Design(d) => Projection {
                absorbed: d.bread()
                    * d.moments_of_blocks(channel.index(), &mut |range, values| {
                        values.extend_from_slice(&x.values_in(range)?);
                        Ok::<_, DiagnoseError>(())
                    })?,
            },
            Absorber::Mean => {
                let mut sum = 0.0;
                for range in block_ranges(0..x.epochs()) {
                    x.values_in(range)?.iter().for_each(|v| sum += v);
                }
                Projection {
                    absorbed: nalgebra::DVector::from_element(1, sum / x.epochs().max(1) as f64),
                }
            }
        })
    }

    /// [`Absorber::own`] of a regressor over the epochs `range`.
    fn own_in(
        &self,
        channel: Channel,
        x: &Regressor<'_>,
        p: &Projection,
        range: Range<usize>,
    ) -> Result<Vec<f64>, DiagnoseError> {
        let values = x.values_in(range.clone())?;
        Ok(match self {
            Absorber::Design(d) => {
                let mut own = d.fitted_in(channel.index(), &p.absorbed, range)?;
                own.iter_mut()
                    .zip(&values[..])
                    .for_each(|(f, v)| *f = v - *f);
                own
            }
            Absorber::Mean => values.iter().map(|v| v - p.absorbed[0]).collect(),
        })
    }
}

fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

/// The consecutive blocks of a run's epochs the batch-means spread sums scores over
/// ([`MeasuredSpread`]): `count` blocks of `len` epochs from the first (a tail shorter than
/// a block is in none).
#[derive(Debug, Clone, Copy, PartialEq)]
struct SpreadBlocks {
    len: usize,
    count: usize,
}

impl SpreadBlocks {
    fn of(n: usize) -> Self {
        let len = (n / SPREAD_BLOCKS).max(1);
        Self {
            len,
            count: n / len,
        }
    }

    /// The pieces of epochs `range` within blocks: each block's index and the piece's
    /// positions relative to `range.start`.
    fn pieces(&self, range: Range<usize>) -> impl Iterator<Item = (usize, Range<usize>)> + '_ {
        let mut t = range.start;
        std::iter::from_fn(move || {
            let b = t / self.len;
            if t >= range.end || b >= self.count {
                return None;
            }
            let end = ((b + 1) * self.len).min(range.end);
            let piece = t - range.start..end - range.start;
            t = end;
            Some((b, piece))
        })
    }

    /// Adds to `per_block` the products of `x` and `y` (both over epochs `range`) within
    /// each block.
    fn add_products(&self, range: Range<usize>, x: &[f64], y: &[f64], per_block: &mut [f64]) {
        for (b, at) in self.pieces(range) {
            per_block[b] += dot(&x[at.clone()], &y[at]);
        }
    }
}

/// The inner products of the one series of `y` (a bank of its own) with every series of
/// `bank`: over all epochs, and within each spread block.
fn products_with(
    bank: &SeriesBank,
    y: &SeriesBank,
    blocks: SpreadBlocks,
) -> Result<Vec<(f64, Vec<f64>)>, DiagnoseError> {
    let mut out = vec![(0.0, vec![0.0; blocks.count]); bank.len()];
    let mut failed = None;
    bank.for_each_block(&mut |range, series| {
        let y = match y.range(0, range.clone()) {
            Ok(y) => y,
            Err(e) => {
                failed.get_or_insert(e);
                return;
            }
        };
        for ((total, per_block), x) in out.iter_mut().zip(series) {
            *total += dot(x, &y);
            blocks.add_products(range.clone(), x, &y, per_block);
        }
    })?;
    match failed {
        Some(e) => Err(e.into()),
        None => Ok(out),
    }
}

/// Where another term's filtered signature on the same channel meets this one's: its
/// inner product with this term's, over all epochs and within each spread block.
#[derive(Clone)]
struct Partner {
    id: u64,
    product: f64,
    block_products: Vec<f64>,
}

/// Gives each term a number no other term of the process has: terms are told apart by it
/// among their partners.
fn next_term_id() -> u64 {
    static NEXT: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);
    NEXT.fetch_add(1, std::sync::atomic::Ordering::Relaxed)
}

/// A deterministic term on one channel: its regressor stripped of what the calibration
/// absorbs from it on its own channel (`own`), filtered by the channel's whitening filter;
/// on the other channels the calibration reaches, its signature is minus the calibration's
/// filtered columns times what it absorbed, kept as moments ([`WhiteSpace`]). With them, its
/// inner products in that metric with the error, with each baseline simulation and with the
/// terms made beside it on its channel, and its coefficient with the standard error the
/// simulations give it. The filtered signature itself is not kept (a channel's dozen
/// candidates would hold a dozen series of the drive's length): every statistic of it a
/// fit needs is summed when it is made.
#[derive(Clone)]
pub(super) struct Term<'a> {
    pub channel: Channel,
    pub name: String,
    pub cause: Cause,
    /// The body axis of the regressor (x, y, z = 0, 1, 2).
    pub axis: usize,
    /// The regressor, and what absorbs of it: the term's unfiltered signature on its own
    /// channel ([`Term::own_in`]) is made from them when asked for rather than held.
    regressor: Regressor<'a>,
    absorber: Absorber<'a>,
    /// Mean and variance of [`Term::own_in`] (channel unit / regressor unit, squared).
    pub own_mean: f64,
    pub own_variance: f64,
    pub projection: Projection,
    id: u64,
    /// The filtered signature's sum over all epochs, and within each spread block its sum
    /// and its inner product with the channel's filtered error.
    white_sum: f64,
    block_sums: Vec<f64>,
    block_on_error: Vec<f64>,
    /// The terms made or joined beside it on its channel, itself included.
    partners: Vec<Partner>,
    /// The filtered calibration columns of its own channel times its filtered signature
    /// (where the calibration reaches that channel).
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

/// Every candidate of a batch as terms, and their filtered signatures in a bank (held on a
/// short run, spilled on a long one), against which later terms of the channel are joined.
pub(super) struct Batch<'a> {
    pub terms: Vec<Term<'a>>,
    pub signatures: SeriesBank,
}

/// A term's filtered signature on its own channel, made a block of the filtered error's
/// epochs at a time ([`WhiteSignature::of`]), with what the term needs of it.
struct WhiteSignature {
    /// The signature, in a bank of its own.
    bank: SeriesBank,
    /// The unfiltered signature's sum, the filtered one's, and the filtered one's within
    /// each spread block.
    own_sum: f64,
    white_sum: f64,
    block_sums: Vec<f64>,
    /// Its inner product with the channel's filtered error, over all epochs and within
    /// each spread block.
    on_error: f64,
    block_on_error: Vec<f64>,
}

impl WhiteSignature {
    /// The signature of the unfiltered one `own_in` gives over any epochs. Summed element
    /// by element in order (within the spread blocks too), and multiplied with the error
    /// over the error bank's own blocks: the figures of the signature held whole.
    fn of(
        space: &WhiteSpace<'_>,
        channel: Channel,
        blocks: SpreadBlocks,
        own_in: &dyn Fn(Range<usize>) -> Result<Vec<f64>, DiagnoseError>,
    ) -> Result<Self, DiagnoseError> {
        let whitener = space
            .whitener(channel.index())
            .expect("a channel of the run");
        let mut out = Self {
            bank: SeriesBank::columns(space.epochs(), 1, space.is_long())?,
            own_sum: 0.0,
            white_sum: 0.0,
            block_sums: vec![0.0; blocks.count],
            on_error: 0.0,
            block_on_error: vec![0.0; blocks.count],
        };
        let mut stream = whitener.stream();
        let (mut white, mut failed) = (Vec::new(), None);
        space.error(channel).for_each_block(&mut |range, error| {
            if failed.is_some() {
                return;
            }
            let own = match own_in(range.clone()) {
                Ok(own) => own,
                Err(e) => {
                    failed = Some(e);
                    return;
                }
            };
            own.iter().for_each(|v| out.own_sum += v);
            white.clear();
            stream.apply(&own, &mut white);
            white.iter().for_each(|v| out.white_sum += v);
            for (b, at) in blocks.pieces(range.clone()) {
                white[at].iter().for_each(|v| out.block_sums[b] += v);
            }
            out.on_error += dot(error[0], &white);
            blocks.add_products(range.clone(), error[0], &white, &mut out.block_on_error);
            if let Err(e) = out.bank.write(0, range.start, &white) {
                failed = Some(e.into());
            }
        })?;
        match failed {
            Some(e) => Err(e),
            None => Ok(out),
        }
    }
}

impl<'a> Term<'a> {
    /// Every candidate on `channel` as a term, coefficients not yet set; the simulations
    /// are visited once for all of them.
    pub fn batch(
        space: &WhiteSpace<'a>,
        channel: Channel,
        cands: &[Candidate<'a>],
    ) -> Result<Batch<'a>, DiagnoseError> {
        let own_ch = channel.index();
        let blocks = SpreadBlocks::of(space.epochs());
        let mut signatures = SeriesBank::new(space.epochs(), space.is_long())?;
        let mut terms: Vec<Term> = Vec::with_capacity(cands.len());
        // A core's worth at a time, each signature banked as soon as it is made.
        for chunk in cands.chunks(rayon::current_num_threads().max(1)) {
            let made: Vec<(Term, SeriesBank)> = chunk
                .par_iter()
                .map(|c| Self::made(space, channel, c, blocks))
                .collect::<Result<_, _>>()?;
            for (term, white_own) in made {
                signatures.append(white_own)?;
                terms.push(term);
            }
        }
        // Each pair's products, over all epochs and per spread block, in one pass.
        let k = terms.len();
        let mut pairs = vec![vec![(0.0, vec![0.0; blocks.count]); k]; k];
        signatures.for_each_block(&mut |range, series| {
            for a in 0..k {
                for b in a..k {
                    let (total, per_block) = &mut pairs[a][b];
                    *total += dot(series[a], series[b]);
                    blocks.add_products(range.clone(), series[a], series[b], per_block);
                }
            }
        })?;
        for a in 0..k {
            for b in a..k {
                let (product, block_products) = pairs[a][b].clone();
                let id = terms[b].id;
                terms[a].partners.push(Partner {
                    id,
                    product,
                    block_products: block_products.clone(),
                });
                if a != b {
                    let id = terms[a].id;
                    terms[b].partners.push(Partner {
                        id,
                        product,
                        block_products,
                    });
                }
            }
        }
        let dots_with = |column: &SeriesBank| Ok(signatures.dots_with(column)?);
        if let Some(on_columns) = space.on_white_columns(own_ch, &dots_with)? {
            for (k, t) in terms.iter_mut().enumerate() {
                let m = on_columns.iter().map(|c| c[k]);
                t.on_own_columns = Some(nalgebra::DVector::from_iterator(on_columns.len(), m));
            }
        }
        let on_own = space.white_sim_dots(own_ch, &signatures)?;
        for (k, t) in terms.iter_mut().enumerate() {
            t.on_sims = on_own
                .iter()
                .enumerate()
                .map(|(r, own)| own[k] + t.pulled_moments(|ch| space.columns_on_sim(ch, r)))
                .collect();
        }
        Ok(Batch { terms, signatures })
    }

    /// A candidate as a term with what its filtered signature gives alone (its sums and its
    /// products with the error), and the signature (in a bank of its own). Made a block of
    /// epochs at a time, in three passes over the regressor (what the calibration takes
    /// from it, the filtered signature with its sums, the unfiltered one's spread), so a
    /// long run's candidate is never held whole.
    fn made(
        space: &WhiteSpace<'a>,
        channel: Channel,
        c: &Candidate<'a>,
        blocks: SpreadBlocks,
    ) -> Result<(Self, SeriesBank), DiagnoseError> {
        let own_ch = channel.index();
        let n = space.epochs();
        let absorber = space.absorber();
        let projection = absorber.project_blocks(channel, &c.values)?;
        let own_in = |range| absorber.own_in(channel, &c.values, &projection, range);
        let signature = WhiteSignature::of(space, channel, blocks, &own_in)?;
        let own_mean = signature.own_sum / n.max(1) as f64;
        let mut squares = 0.0;
        for range in block_ranges(0..n) {
            own_in(range)?
                .iter()
                .for_each(|v| squares += (v - own_mean).powi(2));
        }
        let pulled = std::array::from_fn(|ch| {
            let g = space.column_gram(ch).filter(|_| ch != own_ch)?;
            Some(g * &projection.absorbed)
        });
        let mut term = Term {
            channel,
            name: c.name.clone(),
            cause: c.cause,
            axis: c.axis,
            regressor: c.values,
            absorber,
            own_mean,
            own_variance: squares / (n as f64 - 1.0).max(1.0),
            projection,
            id: next_term_id(),
            white_sum: signature.white_sum,
            block_sums: signature.block_sums,
            block_on_error: signature.block_on_error,
            partners: Vec::new(),
            on_own_columns: None,
            pulled,
            on_error: 0.0,
            on_sims: Vec::new(),
            coef: 0.0,
            se: f64::NAN,
            sd_floor: 0.0,
            fixed: None,
        };
        term.on_error = signature.on_error + term.pulled_moments(|ch| space.columns_on_error(ch));
        Ok((term, signature.bank))
    }

    /// `c` as a term beside a batch already made on `channel`: its products with each of
    /// the batch's terms are given to both.
    pub fn join(
        space: &WhiteSpace<'a>,
        channel: Channel,
        c: &Candidate<'a>,
        batch: &mut Batch<'a>,
    ) -> Result<Self, DiagnoseError> {
        let blocks = SpreadBlocks::of(space.epochs());
        let joined = Self::batch(space, channel, std::slice::from_ref(c))?;
        let mut term = joined
            .terms
            .into_iter()
            .next()
            .expect("one term per candidate");
        let products = products_with(&batch.signatures, &joined.signatures, blocks)?;
        for (other, (product, block_products)) in batch.terms.iter_mut().zip(products) {
            other.partners.push(Partner {
                id: term.id,
                product,
                block_products: block_products.clone(),
            });
            term.partners.push(Partner {
                id: other.id,
                product,
                block_products,
            });
        }
        Ok(term)
    }

    /// This term's meeting with `other`, a term made or joined beside it on its channel.
    fn partner(&self, other: &Term) -> &Partner {
        self.partners
            .iter()
            .find(|p| p.id == other.id)
            .expect("terms of one channel meet only when made or joined together")
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
    /// per epoch of `epochs` (made anew at each call).
    pub fn own_in(&self, epochs: Range<usize>) -> Result<Vec<f64>, DiagnoseError> {
        self.absorber
            .own_in(self.channel, &self.regressor, &self.projection, epochs)
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
}

/// Inner product of two terms' signatures in the whitened metric, over every channel: on a
/// channel that is neither's own, the pulls' product through the columns' Gram matrix; on
/// one term's own channel, its filtered regressor against the other's pull there.
pub(super) fn gram(a: &Term, b: &Term) -> f64 {
    let (ca, cb) = (a.channel.index(), b.channel.index());
    let mut g = if ca == cb {
        a.partner(b).product
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

/// The error of `channel` left after a least-squares fit of every one of `terms` (named or
/// not, jointly with the calibration; exactly collinear directions get no coefficient),
/// centred: what no candidate can explain, however weakly. Why: a term too weak to be named
/// at the run's family-wise level still leaves its pattern in the error, and a bias step
/// looked for on that pattern finds a turn's onset. `steps_elsewhere` (what other channels'
/// steps took from it through the calibration) is given back. Made a block at a time into a
/// bank of its own (spilled on a long run), then centred there.
pub(super) fn full_fit_residual(
    run: &Run,
    channel: Channel,
    terms: &[Term],
    steps_elsewhere: Option<&SeriesBank>,
) -> Result<SeriesBank, DiagnoseError> {
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
    let mut bank = SeriesBank::columns(run.n, 1, run.is_long())?;
    let mut sum = 0.0;
    for epochs in block_ranges(0..run.n) {
        let mut r = run
            .signals
            .error_range(channel, epochs.clone())?
            .into_owned();
        for (t, b) in terms.iter().zip(beta.iter()) {
            r.iter_mut()
                .zip(t.own_in(epochs.clone())?)
                .for_each(|(v, x)| *v -= b * x);
        }
        r.iter().for_each(|v| sum += v);
        bank.write(0, epochs.start, &r)?;
    }
    let m = sum / run.n.max(1) as f64;
    let mut failed = None;
    bank.update(0, &mut |epochs, r| {
        r.iter_mut().for_each(|v| *v -= m);
        if let Some(spill) = steps_elsewhere {
            match spill.range(0, epochs) {
                Ok(spill) => r.iter_mut().zip(spill.iter()).for_each(|(v, s)| *v += s),
                Err(e) => {
                    failed.get_or_insert(e);
                }
            }
        }
    })?;
    failed.map_or(Ok(bank), |e| Err(e.into()))
}

/// Coefficients, null standard deviations and |z| of a least-squares fit on moments.
struct MomentFit {
    beta: Vec<f64>,
    sd: Vec<f64>,
    z: Vec<f64>,
}

/// What the batch-means spread of a fit of terms on one channel needs beyond the terms'
/// own moments: the channel's filtered error ([`WhiteSpace::error`]) summed over its
/// epochs, and a term fixed outside the fit (a bias step), whose coefficient times its
/// signature is taken out of that error first.
#[derive(Clone, Copy)]
pub(super) struct MeasuredSpread<'a, 't> {
    /// Epochs of the channel, and its filtered error's sum over them.
    pub epochs: usize,
    pub white_error_sum: f64,
    pub fixed: Option<&'t Term<'a>>,
}

/// Blocks of the batch-means spread: long enough (45 s of a 900 s drive) to hold most of the
/// correlation of a Gauss-Markov wander of 20 s, many enough for a spread within ~16%.
const SPREAD_BLOCKS: usize = 20;

/// Standard deviations of the coefficients from the measured residual itself (batch means:
/// the coefficients' scores summed over SPREAD_BLOCKS consecutive blocks, in a sandwich with
/// the inverse Gram matrix). Why: the simulated spread assumes the baseline's noise; when the
/// channel's correlated noise is stronger than the baseline's (a noise change), that spread
/// is too small and slow wander correlated with slow manoeuvres is named as terms.
///
/// A term's score over a block is its signature's product with the residual's deviation
/// from its mean there, which the moments each term carries give without its series: the
/// product with the error, less the fitted terms' products with it, less the mean times
/// its sum.
fn measured_spread(
    spread: MeasuredSpread,
    terms: &[Term],
    active: &[usize],
    beta: &[f64],
    gram_inv: &nalgebra::DMatrix<f64>,
) -> Vec<f64> {
    let blocks = terms[active[0]].block_sums.len();
    let fixed = spread.fixed.map(|f| (f.coef, f));
    let error_sum = spread.white_error_sum - fixed.map_or(0.0, |(coef, f)| coef * f.white_sum);
    let residual_sum = error_sum
        - active
            .iter()
            .zip(beta)
            .map(|(&k, b)| b * terms[k].white_sum)
            .sum::<f64>();
    let mean = residual_sum / spread.epochs.max(1) as f64;
    let scores: Vec<nalgebra::DVector<f64>> = (0..blocks)
        .map(|blk| {
            nalgebra::DVector::from_iterator(
                active.len(),
                active.iter().map(|&k| {
                    let t = &terms[k];
                    let on_error = t.block_on_error[blk]
                        - fixed.map_or(0.0, |(coef, f)| coef * t.partner(f).block_products[blk]);
                    let fitted: f64 = active
                        .iter()
                        .zip(beta)
                        .map(|(&a, b)| b * t.partner(&terms[a]).block_products[blk])
                        .sum();
                    on_error - fitted - mean * t.block_sums[blk]
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
    /// The white space of one channel (gx) with error `e`, simulations `sims` and a
    /// white-noise baseline of sd 0.05, without a calibration design; `held_samples` as
    /// [`WhiteSpace::new`] takes it (0 banks series in a temporary file).
    fn one_channel_space<'a>(
        e: &[f64],
        sims: &'a [Vec<f64>],
        held_samples: usize,
    ) -> WhiteSpace<'a> {
        let spec = crate::gmwm::model::ModelSpec {
            model: "WN".into(),
            unit: "rad/s".into(),
            sample_rate_hz: 100.0,
            processes: vec![crate::gmwm::model::Process::WhiteNoise { sigma2: 0.0025 }],
        };
        let mut whiteners: [Option<super::super::whiten::Whitener>; 6] =
            std::array::from_fn(|_| None);
        whiteners[0] = Some(super::super::whiten::Whitener::new(&spec, e.len()));
        let error_of = |ch: usize, epochs: std::ops::Range<usize>| {
            Ok((ch == 0).then(|| Cow::Borrowed(&e[epochs])))
        };
        let sim_of = move |r: usize, ch: usize| {
            (ch == 0).then(|| -> super::super::white_space::SimReader<'a> {
                Box::new(move |epochs, values| {
                    values.extend_from_slice(&sims[r][epochs]);
                    Ok(())
                })
            })
        };
        WhiteSpace::new(
            Absorber::Mean,
            whiteners,
            (&error_of, e.len()),
            sims.len(),
            Box::new(sim_of),
            held_samples,
        )
        .unwrap()
    }

    /// `held_samples` as [`WhiteSpace::new`] takes it: 0 banks the terms' signatures in a
    /// temporary file.
    fn moment_terms<'a>(
        e: &[f64],
        sims: &'a [Vec<f64>],
        columns: &'a [(&str, Vec<f64>)],
        held_samples: usize,
    ) -> (nalgebra::DMatrix<f64>, Vec<Term<'a>>, (usize, f64)) {
        let space = one_channel_space(e, sims, held_samples);
        let cands: Vec<Candidate> = columns
            .iter()
            .map(|(name, values)| Candidate {
                name: (*name).into(),
                values: Regressor::Series(values),
                cause: Cause::ScaleFactor,
                axis: 0,
            })
            .collect();
        let terms = Term::batch(&space, Channel::Gx, &cands).unwrap().terms;
        let spread = (space.epochs(), space.error_sum(Channel::Gx));
        (gram_matrix(&terms), terms, spread)
    }

    /// The measured spread of a fit on one channel of `epochs` whose filtered error sums to
    /// `sum`, nothing fixed.
    fn measured<'a, 't>((epochs, sum): (usize, f64)) -> Option<MeasuredSpread<'a, 't>> {
        Some(MeasuredSpread {
            epochs,
            white_error_sum: sum,
            fixed: None,
        })
    }

    #[test]
    fn the_spread_from_moments_is_the_batch_means_spread_of_the_residual_series() {
        // A slow and a fast regressor, a step joined after them and fixed, on a wandering
        // error: the spread each term's moments give is the one its filtered series give,
        // held or banked in a temporary file.
        let mut rng = ChaCha8Rng::seed_from_u64(8);
        let n = 9_001;
        let slow: Vec<f64> = (0..n).map(|k| (k as f64 * 3e-4).sin()).collect();
        let fast: Vec<f64> = (0..n).map(|k| (k as f64 * 0.02).cos()).collect();
        let sims: Vec<Vec<f64>> = (0..10).map(|_| white_series(&mut rng, n, 0.05)).collect();
        let mut walk = 0.0;
        let e: Vec<f64> = (0..n)
            .map(|k| {
                walk += 0.005 * Distribution::<f64>::sample(&StandardNormal, &mut rng);
                walk + 0.1 * slow[k] + f64::from(k >= 4_000) * 0.03
            })
            .collect();
        for held_samples in [usize::MAX, 0] {
            let space = one_channel_space(&e, &sims, held_samples);
            fn candidate<'c>(name: &str, values: Regressor<'c>) -> Candidate<'c> {
                Candidate {
                    name: name.into(),
                    values,
                    cause: Cause::ScaleFactor,
                    axis: 0,
                }
            }
            let cands = [
                candidate("slow", Regressor::Series(&slow)),
                candidate("fast", Regressor::Series(&fast)),
            ];
            let mut batch = Term::batch(&space, Channel::Gx, &cands).unwrap();
            let step = Regressor::Step { at: 4_000, n };
            let mut step =
                Term::join(&space, Channel::Gx, &candidate("step", step), &mut batch).unwrap();
            step.fix(0.03, 0.001, 1e-9);
            let whitener = space.whitener(0).unwrap();
            let white = |t: &Term| whitener.apply(&t.own_in(0..n).unwrap());
            let mut white_error = Vec::new();
            space
                .error(Channel::Gx)
                .for_each_block(&mut |_, e| white_error.extend_from_slice(e[0]))
                .unwrap();
            let spread_e: Vec<f64> = white_error
                .iter()
                .zip(white(&step))
                .map(|(v, x)| v - step.coef * x)
                .collect();
            let active = [0, 1];
            let beta = [0.08, -0.01];
            let gram_inv = nalgebra::DMatrix::from_fn(2, 2, |a, b| 1.0 + (a + 2 * b) as f64);
            // The spread as the residual's series give it.
            let x: Vec<Vec<f64>> = batch.terms.iter().map(white).collect();
            let mut u = spread_e.clone();
            for (a, b) in beta.iter().enumerate() {
                u.iter_mut().zip(&x[a]).for_each(|(v, x)| *v -= b * x);
            }
            let mean = u.iter().sum::<f64>() / n as f64;
            let blocks = SpreadBlocks::of(n);
            let scores: Vec<nalgebra::DVector<f64>> = (0..blocks.count)
                .map(|b| {
                    let r = b * blocks.len..(b + 1) * blocks.len;
                    nalgebra::DVector::from_iterator(
                        2,
                        x.iter().map(|x| {
                            x[r.clone()]
                                .iter()
                                .zip(&u[r.clone()])
                                .map(|(x, v)| x * (v - mean))
                                .sum::<f64>()
                        }),
                    )
                })
                .collect();
            let count = scores.len() as f64;
            let centre = scores
                .iter()
                .fold(nalgebra::DVector::zeros(2), |a, s| a + s)
                / count;
            let meat = scores
                .iter()
                .fold(nalgebra::DMatrix::zeros(2, 2), |acc, s| {
                    let d = s - &centre;
                    acc + &d * d.transpose()
                })
                * (count / (count - 1.0));
            let cov = &gram_inv * meat * &gram_inv;
            let spread = MeasuredSpread {
                epochs: n,
                white_error_sum: white_error.iter().sum(),
                fixed: Some(&step),
            };
            let from_moments = measured_spread(spread, &batch.terms, &active, &beta, &gram_inv);
            for (a, m) in from_moments.iter().enumerate() {
                let series = cov[(a, a)].sqrt();
                assert!((m - series).abs() <= 1e-8 * series, "{m} against {series}");
            }
            // The step's products with the batch, both ways, are its series'.
            for (t, x) in batch.terms.iter().zip(&x) {
                let g = dot(x, &white(&step));
                assert!((gram(t, &step) - g).abs() <= 1e-9 * g.abs());
                assert!((gram(&step, t) - g).abs() <= 1e-9 * g.abs());
            }
        }
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
        // Held and banked in a temporary file alike.
        for held_samples in [usize::MAX, 0] {
            let (gram, terms, spread) = moment_terms(&e, &sims, &columns, held_samples);
            let kept = eliminate_on_moments(&gram, &terms, 4.0, &never_small, measured(spread));
            assert_eq!(kept.len(), 1, "{kept:?}");
            let (k, b, sd) = kept[0];
            assert_eq!(terms[k].name, "truth");
            assert!((b - 0.02).abs() < 3.0 * sd, "{b} +- {sd}");

            let (gram, terms, spread) = moment_terms(&noise, &sims, &columns, held_samples);
            let kept = eliminate_on_moments(&gram, &terms, 4.0, &never_small, measured(spread));
            assert!(kept.is_empty(), "{kept:?}");
        }
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
        let (gram, terms, spread) = moment_terms(&e, &sims, &columns, usize::MAX);
        let never_small = |_: usize, _: f64| false;
        assert_eq!(
            eliminate_on_moments(&gram, &terms, 4.0, &never_small, None).len(),
            1
        );
        assert!(
            eliminate_on_moments(&gram, &terms, 4.0, &never_small, measured(spread)).is_empty()
        );
    }
}
