//! The run as generalised least squares sees it ([`WhiteSpace`]): per channel the whitening
//! filter of its baseline noise model, the calibrated error filtered, and what every
//! deterministic term's fit needs of the baseline simulations after the same calibration and
//! filter. A term's signature on the channels other than its own is what the calibration's
//! pull leaves there, minus the calibration's columns times what it absorbed, so its inner
//! products there reduce to small moments of the filtered columns (their Gram matrix, their
//! products with the error and with each simulation); only the term's own channel needs a
//! simulation, and only its inner products with the terms' signatures. On a long drive the
//! simulations are therefore drawn again a block at a time, one channel at a time, whenever a
//! batch of terms needs them (same seeds, same series), and none is held whole; on a short
//! one they are held, which is faster.

use std::borrow::Cow;
use std::ops::Range;

use nalgebra::{DMatrix, DVector};
use rayon::prelude::*;

use super::draws::DrawnBlockVisit;
use super::engine::DiagnoseError;
use super::moments::Absorber;
use super::whiten::Whitener;
use crate::model::Channel;
use crate::series_bank::{block_ranges, SeriesBank};

/// A simulation read a block at a time, in order: `read(epochs, values)` appends it over
/// the next epochs (the blocks of [`block_ranges`]).
pub(super) type SimReader<'s> =
    Box<dyn FnMut(Range<usize>, &mut Vec<f64>) -> Result<(), DiagnoseError> + 's>;

/// Baseline simulation `r` of channel index `ch` (0..6, gx..az) to read, None where the run
/// has no such channel.
pub(super) type SimOf<'a> = Box<dyn Fn(usize, usize) -> Option<SimReader<'a>> + Sync + 'a>;

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

impl WhiteError {
    /// Channel `ch`'s error of `n` epochs (`error_of`, present) less what the calibration
    /// (`absorber` with parameters `theta`) takes from it, filtered by `whitener`, a block
    /// at a time into a bank (spilled when `spill`).
    fn new(
        (error_of, n): (&ErrorOf<'_>, usize),
        ch: usize,
        (absorber, theta): (Absorber<'_>, Option<&DVector<f64>>),
        whitener: &Whitener,
        spill: bool,
    ) -> Result<Self, DiagnoseError> {
        let read = |epochs: Range<usize>| -> Result<Vec<f64>, DiagnoseError> {
            Ok(error_of(ch, epochs)?.unwrap_or_default().into_owned())
        };
        // Only what is taken without a design needs the mean.
        let mean = match absorber {
            Absorber::Mean => {
                let mut sum = 0.0;
                for epochs in block_ranges(0..n) {
                    read(epochs)?.iter().for_each(|v| sum += v);
                }
                sum / n.max(1) as f64
            }
            Absorber::Design(_) => 0.0,
        };
        let mut bank = SeriesBank::columns(n, 1, spill)?;
        let (mut stream, mut sum) = (whitener.stream(), 0.0);
        for epochs in block_ranges(0..n) {
            let mut y = read(epochs.clone())?;
            subtract_calibration(absorber, ch, epochs.clone(), &mut y, theta, mean)?;
            stream.apply_in_place(&mut y);
            y.iter().for_each(|v| sum += v);
            bank.write(0, epochs.start, &y)?;
        }
        Ok(Self { bank, sum })
    }
}

fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

/// Channel `ch`'s error (0..6, gx..az) over a range of epochs, None where the run has no
/// such channel: held, or read back from a long run's temporary file.
pub(super) type ErrorOf<'e> =
    dyn Fn(usize, Range<usize>) -> Result<Option<Cow<'e, [f64]>>, DiagnoseError> + 'e;

/// `y` on channel `ch` less what the calibration takes from it: the fit of parameters
/// `theta` with a design, the mean without one.
fn calibrated(
    absorber: Absorber<'_>,
    ch: usize,
    mut y: Vec<f64>,
    theta: Option<&DVector<f64>>,
) -> Result<Vec<f64>, DiagnoseError> {
    // Only what is taken without a design needs the mean.
    let mean = match absorber {
        Absorber::Mean => y.iter().sum::<f64>() / y.len().max(1) as f64,
        Absorber::Design(_) => 0.0,
    };
    subtract_calibration(absorber, ch, 0..y.len(), &mut y, theta, mean)?;
    Ok(y)
}

/// [`calibrated`] over the epochs `epochs` of a series `y` given over them, whose mean (what
/// is taken without a design) is `mean`.
fn subtract_calibration(
    absorber: Absorber<'_>,
    ch: usize,
    epochs: Range<usize>,
    y: &mut [f64],
    theta: Option<&DVector<f64>>,
    mean: f64,
) -> Result<(), DiagnoseError> {
    match (absorber, theta) {
        (Absorber::Design(d), Some(theta)) if d.has_channel(ch) => {
            d.add_fitted(ch, theta, -1.0, epochs, y)?;
        }
        (Absorber::Design(_), _) => {}
        (Absorber::Mean, _) => y.iter_mut().for_each(|v| *v -= mean),
    }
    Ok(())
}

impl<'a> WhiteSpace<'a> {
    /// `error_of(ch, epochs)`: every channel's error of `n` epochs (None where absent), read
    /// a block at a time; `sim_of(r, ch)`: channel `ch`'s baseline simulation of replicate r, for r in
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
        // channels), then each channel's error calibrated, filtered and banked, a block at
        // a time: a long drive holds none.
        let theta = match absorber {
            Absorber::Design(d) => {
                let mut moments = DVector::<f64>::zeros(d.parameters());
                // An empty read tells whether the channel is there.
                for ch in (0..6).filter(|&ch| d.has_channel(ch)) {
                    if error_of(ch, 0..0)?.is_some() {
                        moments += d.moments_of_blocks(ch, &mut |epochs, values| {
                            values.extend_from_slice(&error_of(ch, epochs)?.unwrap_or_default());
                            Ok::<_, DiagnoseError>(())
                        })?;
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
            if error_of(ch, 0..0)?.is_none() {
                continue;
            }
            *white = Some(WhiteError::new(
                (error_of, n),
                ch,
                (absorber, theta.as_ref()),
                w,
                !hold,
            )?);
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
                if !hold {
                    // Only the calibration's take is kept: read a block at a time.
                    let mut moments = DVector::<f64>::zeros(design.parameters());
                    for ch in (0..6).filter(|&ch| design.has_channel(ch)) {
                        if let Some(mut read) = self.read_sim(r, ch) {
                            moments += design.moments_of_blocks(ch, &mut *read)?;
                        }
                    }
                    return Ok((design.bread() * moments, None));
                }
                let mut sims: [Option<Vec<f64>>; 6] = Default::default();
                for (ch, sim) in sims.iter_mut().enumerate() {
                    *sim = self.sim_whole(r, ch)?;
                }
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

    /// Replicate `r`'s simulation of channel `ch` to read, where the channel is filtered.
    fn read_sim(&self, r: usize, ch: usize) -> Option<SimReader<'a>> {
        self.whiteners[ch]
            .as_ref()
            .and_then(|_| (self.sim_of)(r, ch))
    }

    /// Replicate `r`'s simulation of channel `ch` whole, where the channel is filtered.
    fn sim_whole(&self, r: usize, ch: usize) -> Result<Option<Vec<f64>>, DiagnoseError> {
        let Some(mut read) = self.read_sim(r, ch) else {
            return Ok(None);
        };
        let mut y = Vec::with_capacity(self.n);
        for epochs in block_ranges(0..self.n) {
            read(epochs, &mut y)?;
        }
        Ok(Some(y))
    }

    /// Replicate `r`'s filtered calibrated simulation of channel `ch`, whole.
    fn white_sim(&self, r: usize, ch: usize) -> Result<Option<Vec<f64>>, DiagnoseError> {
        match self.sim_whole(r, ch)? {
            Some(y) => self.filter(ch, y, self.theta[r].as_ref()).map(Some),
            None => Ok(None),
        }
    }

    /// `visit(epochs, values)` with each block of replicate `r`'s filtered calibrated
    /// simulation of channel `ch`, drawn again and never held whole (false where the
    /// channel has none).
    fn for_each_white_sim_block(
        &self,
        r: usize,
        ch: usize,
        visit: &mut DrawnBlockVisit<'_>,
    ) -> Result<bool, DiagnoseError> {
        let (Some(mut read), Some(w)) = (self.read_sim(r, ch), self.whiteners[ch].as_ref()) else {
            return Ok(false);
        };
        let mut mean = 0.0;
        if let (Absorber::Mean, Some(mut first_pass)) = (self.absorber, self.read_sim(r, ch)) {
            let (mut sum, mut y) = (0.0, Vec::new());
            for epochs in block_ranges(0..self.n) {
                y.clear();
                first_pass(epochs, &mut y)?;
                y.iter().for_each(|v| sum += v);
            }
            mean = sum / self.n.max(1) as f64;
        }
        let (mut stream, mut y) = (w.stream(), Vec::new());
        for epochs in block_ranges(0..self.n) {
            y.clear();
            read(epochs.clone(), &mut y)?;
            let theta = self.theta[r].as_ref();
            subtract_calibration(self.absorber, ch, epochs.clone(), &mut y, theta, mean)?;
            stream.apply_in_place(&mut y);
            visit(epochs, &mut y)?;
        }
        Ok(true)
    }

    /// For every replicate (in order), the inner products of each series of `bank` with its
    /// filtered simulation of channel `ch`: from the simulation held, or drawn again a
    /// block at a time.
    pub fn white_sim_dots(
        &self,
        ch: usize,
        bank: &SeriesBank,
    ) -> Result<Vec<Vec<f64>>, DiagnoseError> {
        (0..self.replicates)
            .into_par_iter()
            .map(|r| {
                if let Some(held) = &self.held {
                    let sim = held[r][ch]
                        .as_deref()
                        .expect("a channel of the run has its simulations");
                    return Ok(bank.dots(sim)?);
                }
                let mut sums = vec![0.0; bank.len()];
                let drawn = self.for_each_white_sim_block(r, ch, &mut |epochs, y| {
                    Ok(bank.add_dots_in(epochs, y, &mut sums)?)
                })?;
                assert!(drawn, "a channel of the run has its simulations");
                Ok(sums)
            })
            .collect()
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
        let on_sims = self
            .white_sim_dots(ch, &bank)?
            .into_iter()
            .map(DVector::from_vec)
            .collect();
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
}
