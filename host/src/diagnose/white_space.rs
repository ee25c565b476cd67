//! The run as generalised least squares sees it ([`WhiteSpace`]): per channel the whitening
//! filter of its baseline noise model, the calibrated error filtered, and what every
//! deterministic term's fit needs of the baseline simulations after the same calibration and
//! filter. A term's signature on the channels other than its own is what the calibration's
//! pull leaves there, minus the calibration's columns times what it absorbed, so its inner
//! products there reduce to small moments of the filtered columns (their Gram matrix, their
//! products with the error and with each simulation); only the term's own channel needs a
//! simulation whole. On a long drive the simulations are therefore drawn again, one channel
//! at a time, whenever a batch of terms needs them (same seeds, same series), and memory does
//! not grow with the replicates; on a short one they are held, which is faster.

use std::borrow::Cow;

use nalgebra::{DMatrix, DVector};
use rayon::prelude::*;

use super::engine::DiagnoseError;
use super::moments::Absorber;
use super::whiten::Whitener;
use crate::model::Channel;
use crate::series_bank::SeriesBank;

/// Baseline simulation `r` of channel index `ch` (0..6, gx..az), None where the run has no
/// such channel.
pub(super) type SimOf<'a> = Box<dyn Fn(usize, usize) -> Option<Vec<f64>> + Sync + 'a>;

/// A series per channel (gx..az), None where the run has none.
type PerChannel = [Option<Vec<f64>>; 6];

/// The calibration's columns on one channel, filtered, as moments: their Gram matrix and
/// their inner products with the filtered error and with each filtered simulation.
struct Columns {
    gram: DMatrix<f64>,
    on_error: DVector<f64>,
    on_sims: Vec<DVector<f64>>,
}

/// See the module documentation.
pub(super) struct WhiteSpace<'a> {
    absorber: Absorber<'a>,
    whiteners: [Option<Whitener>; 6],
    /// Epochs of every channel.
    n: usize,
    errors: [Option<WhiteError>; 6],
    replicates: usize,
    sim_of: SimOf<'a>,
    /// Per replicate, the calibration parameters a fit of its simulations on every channel
    /// takes (with a calibration design; None without).
    theta: Vec<Option<DVector<f64>>>,
    /// Per channel the calibration reaches (with a design), its filtered columns' moments.
    columns: [Option<Columns>; 6],
    /// Every replicate's filtered calibrated simulations, when they fit the budget (None:
    /// the run is long, and series a stage needs together are banked in a temporary file,
    /// [`SeriesBank`]).
    held: Option<Vec<PerChannel>>,
}

/// A channel's filtered calibrated error, banked (held on a short run, in a temporary file
/// on a long one), and its sum.
struct WhiteError {
    bank: SeriesBank,
    sum: f64,
}

fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

/// Channel `ch`'s error (0..6, gx..az), None where the run has no such channel: held, or
/// read back from a long run's temporary file.
pub(super) type ErrorOf<'e> = dyn Fn(usize) -> Result<Option<Cow<'e, [f64]>>, DiagnoseError> + 'e;

/// `y` on channel `ch` less what the calibration takes from it: the fit of parameters
/// `theta` with a design, the mean without one.
fn calibrated(
    absorber: Absorber<'_>,
    ch: usize,
    mut y: Vec<f64>,
    theta: Option<&DVector<f64>>,
) -> Result<Vec<f64>, DiagnoseError> {
    match (absorber, theta) {
        (Absorber::Design(d), Some(theta)) if d.has_channel(ch) => {
            d.for_each_fitted(ch, theta, 0..y.len(), &mut |range, fitted| {
                y[range].iter_mut().zip(fitted).for_each(|(v, f)| *v -= f);
            })?;
        }
        (Absorber::Design(_), _) => {}
        (Absorber::Mean, _) => {
            let m = y.iter().sum::<f64>() / y.len().max(1) as f64;
            y.iter_mut().for_each(|v| *v -= m);
        }
    }
    Ok(y)
}

impl<'a> WhiteSpace<'a> {
    /// `error_of(ch)`: every channel's error of `n` epochs (None where absent), read one at
    /// a time; `sim_of(r, ch)`: channel `ch`'s baseline simulation of replicate r, for r in
    /// 0..replicates. The filtered simulations are held when replicates times epochs is at
    /// most `held_samples`.
    pub fn new(
        absorber: Absorber<'a>,
        whiteners: [Option<Whitener>; 6],
        (error_of, n): (&ErrorOf<'_>, usize),
        replicates: usize,
        sim_of: SimOf<'a>,
        held_samples: usize,
    ) -> Result<Self, DiagnoseError> {
        let hold = replicates.saturating_mul(n) <= held_samples;
        // The calibration of every channel's error together (its moments add over the
        // channels), then each channel's error calibrated, filtered and banked, one at a
        // time: a long drive holds none.
        let theta = match absorber {
            Absorber::Design(d) => {
                let mut moments = DVector::<f64>::zeros(d.parameters());
                for ch in (0..6).filter(|&ch| d.has_channel(ch)) {
                    if let Some(e) = error_of(ch)? {
                        moments += d.moments(ch, &e)?;
                    }
                }
                Some(d.bread() * moments)
            }
            Absorber::Mean => None,
        };
        let mut white_errors: [Option<WhiteError>; 6] = std::array::from_fn(|_| None);
        for (ch, white) in white_errors.iter_mut().enumerate() {
            let Some(w) = whiteners[ch].as_ref() else {
                continue;
            };
            let Some(e) = error_of(ch)? else {
                continue;
            };
            let mut filtered = calibrated(absorber, ch, e.into_owned(), theta.as_ref())?;
            w.stream().apply_in_place(&mut filtered);
            let sum = filtered.iter().sum();
            let mut bank = SeriesBank::new(n, !hold)?;
            bank.push(filtered)?;
            *white = Some(WhiteError { bank, sum });
        }
        let mut space = WhiteSpace {
            absorber,
            whiteners,
            n,
            errors: white_errors,
            replicates,
            sim_of,
            theta: vec![None; replicates],
            columns: std::array::from_fn(|_| None),
            held: None,
        };
        space.draw_replicates(hold)?;
        for ch in 0..6 {
            space.columns[ch] = space.columns_of(ch)?;
        }
        Ok(space)
    }

    /// One pass over the replicates: each one's calibration parameters, and its filtered
    /// calibrated simulations when `hold`.
    fn draw_replicates(&mut self, hold: bool) -> Result<(), DiagnoseError> {
        let Absorber::Design(design) = self.absorber else {
            if hold {
                let held = (0..self.replicates)
                    .into_par_iter()
                    .map(|r| {
                        let mut sims: PerChannel = Default::default();
                        for (ch, sim) in sims.iter_mut().enumerate() {
                            *sim = self.white_sim(r, ch)?;
                        }
                        Ok(sims)
                    })
                    .collect::<Result<_, DiagnoseError>>()?;
                self.held = Some(held);
            }
            return Ok(());
        };
        let drawn: Vec<(DVector<f64>, Option<PerChannel>)> = (0..self.replicates)
            .into_par_iter()
            .map(|r| {
                let sim = |ch: usize| self.whiteners[ch].as_ref().and((self.sim_of)(r, ch));
                if !hold {
                    // Only the calibration's take is kept: one channel's simulation at a
                    // time, not six.
                    let mut moments = DVector::<f64>::zeros(design.parameters());
                    for ch in (0..6).filter(|&ch| design.has_channel(ch)) {
                        if let Some(y) = sim(ch) {
                            moments += design.moments(ch, &y)?;
                        }
                    }
                    return Ok((design.bread() * moments, None));
                }
                let mut sims: [Option<Vec<f64>>; 6] = std::array::from_fn(sim);
                let theta = design.bread()
                    * design.moments_all(&std::array::from_fn(|ch| sims[ch].as_deref()))?;
                let mut white: PerChannel = Default::default();
                for (ch, out) in white.iter_mut().enumerate() {
                    if let Some(y) = sims[ch].take() {
                        *out = Some(self.filter(ch, y, Some(&theta))?);
                    }
                }
                Ok((theta, Some(white)))
            })
            .collect::<Result<_, DiagnoseError>>()?;
        let (theta, held): (Vec<_>, Vec<_>) = drawn.into_iter().unzip();
        self.theta = theta.into_iter().map(Some).collect();
        self.held = held.into_iter().collect();
        Ok(())
    }

    /// `y` on channel `ch` after the calibration (parameters `theta` with a design, the
    /// mean without one), filtered.
    fn filter(
        &self,
        ch: usize,
        y: Vec<f64>,
        theta: Option<&DVector<f64>>,
    ) -> Result<Vec<f64>, DiagnoseError> {
        let mut y = calibrated(self.absorber, ch, y, theta)?;
        self.whiteners[ch]
            .as_ref()
            .expect("a filtered channel has its whitener")
            .stream()
            .apply_in_place(&mut y);
        Ok(y)
    }

    /// Replicate `r`'s filtered calibrated simulation of channel `ch`, drawn again unless
    /// held.
    fn white_sim(&self, r: usize, ch: usize) -> Result<Option<Vec<f64>>, DiagnoseError> {
        if let Some(held) = &self.held {
            return Ok(held[r][ch].clone());
        }
        if self.whiteners[ch].is_none() {
            return Ok(None);
        }
        let Some(y) = (self.sim_of)(r, ch) else {
            return Ok(None);
        };
        self.filter(ch, y, self.theta[r].as_ref()).map(Some)
    }

    /// `f` of replicate `r`'s filtered simulation of channel `ch` (None where absent).
    fn with_white_sim<T>(
        &self,
        r: usize,
        ch: usize,
        f: impl FnOnce(&[f64]) -> Result<T, DiagnoseError>,
    ) -> Result<Option<T>, DiagnoseError> {
        match &self.held {
            Some(held) => held[r][ch].as_deref().map(f).transpose(),
            None => self.white_sim(r, ch)?.map(|s| f(&s)).transpose(),
        }
    }

    /// `f` of each of the calibration's filtered columns on channel `ch`, in order (None
    /// without a design reaching the channel, or without the channel), each made a block at
    /// a time into a bank of its own (a temporary file on a long run).
    pub fn on_white_columns<T: Send>(
        &self,
        ch: usize,
        f: &(dyn Fn(&SeriesBank) -> Result<T, DiagnoseError> + Sync),
    ) -> Result<Option<Vec<T>>, DiagnoseError> {
        let Absorber::Design(d) = self.absorber else {
            return Ok(None);
        };
        let Some(w) = self.whiteners[ch].as_ref().filter(|_| d.has_channel(ch)) else {
            return Ok(None);
        };
        (0..d.parameters())
            .into_par_iter()
            .map(|k| f(&self.white_column(d, w, ch, k)?))
            .collect::<Result<Vec<T>, DiagnoseError>>()
            .map(Some)
    }

    /// The calibration's column `k` on channel `ch` (the fit of a unit parameter), filtered
    /// by `w`, made a block at a time into a bank of its own.
    fn white_column(
        &self,
        d: crate::calibration::DesignRows<'_>,
        w: &Whitener,
        ch: usize,
        k: usize,
    ) -> Result<SeriesBank, DiagnoseError> {
        let p = d.parameters();
        let unit = DVector::from_fn(p, |a, _| f64::from(a == k));
        let mut column = SeriesBank::columns(self.n, 1, self.is_long())?;
        let mut stream = w.stream();
        let (mut white, mut failed) = (Vec::new(), None);
        d.for_each_fitted(ch, &unit, 0..self.n, &mut |range, fitted| {
            white.clear();
            stream.apply(fitted, &mut white);
            if let Err(e) = column.write(0, range.start, &white) {
                failed.get_or_insert(e);
            }
        })?;
        match failed {
            Some(e) => Err(e.into()),
            None => Ok(column),
        }
    }

    /// The moments of channel `ch`'s filtered calibration columns (None without a design
    /// reaching the channel, or without the channel). The columns are banked as they are
    /// made, a core's worth at a time.
    fn columns_of(&self, ch: usize) -> Result<Option<Columns>, DiagnoseError> {
        let Absorber::Design(d) = self.absorber else {
            return Ok(None);
        };
        let (Some(w), Some(error)) = (self.whiteners[ch].as_ref(), self.errors[ch].as_ref()) else {
            return Ok(None);
        };
        if !d.has_channel(ch) {
            return Ok(None);
        }
        let p = d.parameters();
        let mut bank = SeriesBank::new(self.n, self.is_long())?;
        let mut on_error = DVector::<f64>::zeros(p);
        let indices: Vec<usize> = (0..p).collect();
        for chunk in indices.chunks(rayon::current_num_threads().max(1)) {
            let made: Vec<SeriesBank> = chunk
                .par_iter()
                .map(|&k| self.white_column(d, w, ch, k))
                .collect::<Result<_, DiagnoseError>>()?;
            for (&k, column) in chunk.iter().zip(made) {
                on_error[k] = error.bank.dots_with(&column)?[0];
                bank.append(column)?;
            }
        }
        let mut gram = DMatrix::<f64>::zeros(p, p);
        bank.for_each_block(&mut |_, x| {
            for a in 0..p {
                for b in 0..p {
                    gram[(a, b)] += dot(x[a], x[b]);
                }
            }
        })?;
        let moments = |y: &[f64]| Ok(DVector::from_vec(bank.dots(y)?));
        let on_sims = (0..self.replicates)
            .into_par_iter()
            .map(|r| {
                Ok(self
                    .with_white_sim(r, ch, moments)?
                    .expect("a channel of the run has its simulations"))
            })
            .collect::<Result<Vec<_>, DiagnoseError>>()?;
        Ok(Some(Columns {
            gram,
            on_error,
            on_sims,
        }))
    }

    /// Whether the run is long: series a stage needs together are then banked in a
    /// temporary file rather than held.
    pub fn is_long(&self) -> bool {
        self.held.is_none()
    }

    /// Epochs of the run.
    pub fn epochs(&self) -> usize {
        self.n
    }

    /// The filtered calibrated error of `channel`, banked (one series).
    pub fn error(&self, channel: Channel) -> &SeriesBank {
        &self.white_error(channel).bank
    }

    /// The sum of [`WhiteSpace::error`] over the run.
    pub fn error_sum(&self, channel: Channel) -> f64 {
        self.white_error(channel).sum
    }

    fn white_error(&self, channel: Channel) -> &WhiteError {
        self.errors[channel.index()]
            .as_ref()
            .expect("a channel of the run")
    }

    /// The whitening filter of channel index `ch`.
    pub fn whitener(&self, ch: usize) -> Option<&Whitener> {
        self.whiteners[ch].as_ref()
    }

    pub fn absorber(&self) -> Absorber<'a> {
        self.absorber
    }

    /// The Gram matrix of channel `ch`'s filtered calibration columns.
    pub fn column_gram(&self, ch: usize) -> Option<&DMatrix<f64>> {
        self.columns[ch].as_ref().map(|c| &c.gram)
    }

    /// Channel `ch`'s filtered calibration columns' inner products with its filtered error.
    pub fn columns_on_error(&self, ch: usize) -> Option<&DVector<f64>> {
        self.columns[ch].as_ref().map(|c| &c.on_error)
    }

    /// The same with replicate `r`'s filtered simulation.
    pub fn columns_on_sim(&self, ch: usize, r: usize) -> Option<&DVector<f64>> {
        self.columns[ch].as_ref().map(|c| &c.on_sims[r])
    }

    /// For every replicate (in order), `f` of its filtered simulation of channel `ch`.
    pub fn map_white_sims<T: Send>(
        &self,
        ch: usize,
        f: &(dyn Fn(&[f64]) -> Result<T, DiagnoseError> + Sync),
    ) -> Result<Vec<T>, DiagnoseError> {
        (0..self.replicates)
            .into_par_iter()
            .map(|r| {
                Ok(self
                    .with_white_sim(r, ch, f)?
                    .expect("a channel of the run has its simulations"))
            })
            .collect()
    }
}
