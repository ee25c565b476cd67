//! Backward elimination over an error-signal file of any length, in memory that does not grow
//! with it (`dynacal regress`). The file is read once (a CSV by the fast block reader, else
//! row by row) into a binary spill file
//! in the temporary folder (`TMPDIR`; 8 bytes a value, the dynamics and error columns only),
//! and the Gram matrix of [1, dynamics, errors] is summed on the way: every least-squares
//! solution of the elimination comes from it. Each round of the elimination then passes over
//! the spill file, all channels at once, on every core: once for the residual sums (and the
//! VAR(1) sums of the scores when prewhitening), once for the Newey-West (1994) bandwidth's
//! lag products when the lag is not given, and once for the Bartlett meat. Memory holds the
//! Gram matrix, one block of rows, and per channel the last `lag + 1` scores (the automatic
//! lag grows as the cube root of the length).
//!
//! The statistics are those of [`super::backward_elimination`] on the loaded file: the same
//! column scaling, score definition, prewhitening, bandwidth rule and Bartlett sums (formed
//! afresh every [`super::MEAT_CHUNK`] windows, as the batch path does), and the same tests
//! ([`super::ScaledSolution::conclude`]). They differ in rounding only: the normal equations
//! come from the Gram matrix rather than from the scaled design, and the meat's chunks are
//! summed in order rather than by a parallel reduction. The residuals are not kept.

use std::fs::File;
use std::io::{BufWriter, Read, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};

use nalgebra::{DMatrix, DVector};
use rayon::prelude::*;

use super::{
    add_outer_upper, add_var1_sums, bandwidth_weights, column_scale, lag_of_bandwidth,
    meat_from_upper, nw94_bandwidth, nw94_prelag, solve_scaled, var1_fit, var1_residual,
    HacEstimate, Inference, RegressError, RegressionOptions, RegressionReport, ScaledSolution,
    DYNAMICS_REGRESSORS, MEAT_CHUNK,
};
use crate::error_signal::{no_error_column, DYNAMICS_COLUMNS, ERROR_COLUMNS};
use crate::interchange::fast::for_each_fast_row;
use crate::interchange::{for_each_row, parquet, TableError, TableRows};

/// Rows handed to the channels at a time.
const BLOCK_ROWS: usize = 8192;

/// Dynamics regressors per row.
const REGRESSORS: usize = DYNAMICS_REGRESSORS.len();

/// Errors of a streamed regression (a channel's own failure is in its outcome).
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum StreamError {
    /// The error-signal file could not be read.
    #[error(transparent)]
    Table(#[from] TableError),
    /// The spill file could not be written or read back.
    #[error(
        "the spill file in {dir}: {source} (set TMPDIR to a folder with room for 8 bytes a value)"
    )]
    Spill {
        dir: PathBuf,
        #[source]
        source: std::io::Error,
    },
}

fn spill_error(source: std::io::Error) -> StreamError {
    StreamError::Spill {
        dir: std::env::temp_dir(),
        source,
    }
}

/// One error channel's outcome: its column name and its report, or why it has none.
pub type ChannelOutcome = (&'static str, Result<RegressionReport, RegressError>);

/// Regresses each error column of the error-signal file at `path` on the 15 dynamics
/// columns with backward elimination, as [`super::backward_elimination`] would on the loaded
/// file, streamed. Channels come in [`ERROR_COLUMNS`] order.
pub fn regress_file(
    path: &Path,
    opts: &RegressionOptions,
) -> Result<Vec<ChannelOutcome>, StreamError> {
    let errors = error_columns_of(path)?;
    crate::progress::stage(|| format!("reading {}", path.display()));
    let (store, gram) = RowStore::read(path, &errors)?;
    let mut fits: Vec<ChannelFit> = errors
        .iter()
        .enumerate()
        .map(|(k, name)| ChannelFit::new(name, REGRESSORS + k, &gram))
        .collect();
    let mut round = 0;
    while fits.iter().any(|f| f.outcome.is_none()) {
        round += 1;
        let mut passes: Vec<RoundPass> = fits
            .iter_mut()
            .enumerate()
            .filter_map(|(k, f)| f.start_round(k, &gram, opts))
            .collect();
        for stage in [Stage::Sums, Stage::Bandwidth, Stage::Meat] {
            if !passes.iter().any(|p| p.wants(stage, opts)) {
                continue;
            }
            crate::progress::stage(|| {
                format!("regressing {}: round {round}, {stage:?}", path.display())
            });
            passes.iter_mut().for_each(|p| p.begin(stage, opts));
            store.pass(|block| {
                passes
                    .par_iter_mut()
                    .for_each(|p| p.feed(block, store.columns))
            })?;
            passes.iter_mut().for_each(|p| p.end(stage, opts));
        }
        for pass in passes {
            let k = pass.channel;
            fits[k].end_round(pass, opts);
        }
    }
    Ok(fits
        .into_iter()
        .map(|f| (f.name, f.outcome.expect("every channel concluded")))
        .collect())
}

/// The error columns the file has, in [`ERROR_COLUMNS`] order; none is an error naming it.
fn error_columns_of(path: &Path) -> Result<Vec<&'static str>, TableError> {
    let headers = if parquet::is_parquet(path) {
        parquet::headers(path)?
    } else {
        TableRows::open(path, None)?.headers().to_vec()
    };
    let errors: Vec<&'static str> = ERROR_COLUMNS
        .into_iter()
        .filter(|c| headers.iter().any(|h| h == c))
        .collect();
    if errors.is_empty() {
        return Err(no_error_column(path));
    }
    Ok(errors)
}

/// Sum of z z' (upper triangle, row-major) over the rows z = [1, dynamics, errors], and
/// which dynamics columns vary.
struct Gram {
    dim: usize,
    upper: Vec<f64>,
    rows: usize,
    first: [f64; REGRESSORS],
    varies: [bool; REGRESSORS],
}

impl Gram {
    fn new(errors: usize) -> Self {
        let dim = 1 + REGRESSORS + errors;
        Self {
            dim,
            upper: vec![0.0; dim * dim],
            rows: 0,
            first: [0.0; REGRESSORS],
            varies: [false; REGRESSORS],
        }
    }

    /// Adds a stored row (dynamics, then errors); `z` is room for the row with its 1.
    fn add(&mut self, row: &[f64], z: &mut [f64]) {
        if self.rows == 0 {
            self.first.copy_from_slice(&row[..REGRESSORS]);
        }
        for (k, varies) in self.varies.iter_mut().enumerate() {
            *varies |= row[k] != self.first[k];
        }
        z[0] = 1.0;
        z[1..].copy_from_slice(row);
        add_outer_upper(&mut self.upper, z);
        self.rows += 1;
    }

    /// Sum over rows of z_a z_b.
    fn sum(&self, a: usize, b: usize) -> f64 {
        let (a, b) = if a <= b { (a, b) } else { (b, a) };
        self.upper[a * self.dim + b]
    }
}

/// The rows of an error-signal file (dynamics, then the error columns) spilled to a
/// temporary binary file, passed over block by block.
struct RowStore {
    file: File,
    columns: usize,
    rows: usize,
}

impl RowStore {
    /// Reads the file at `path` (its `t_s`, dynamics and `errors` columns, checked row by
    /// row) into a spill file, summing the Gram matrix on the way: a CSV by the fast block
    /// reader where it can, else (and any file it gives up on, read again from its start)
    /// row by row, whose errors name the line or row.
    fn read(path: &Path, errors: &[&'static str]) -> Result<(Self, Gram), StreamError> {
        let mut wanted: Vec<&str> = vec!["t_s"];
        wanted.extend(DYNAMICS_COLUMNS);
        wanted.extend(errors);
        if !parquet::is_parquet(path) {
            if let Some(read) = Self::read_fast(path, &wanted, errors.len())? {
                return Ok(read);
            }
        }
        let mut spill = Spill::new(errors.len())?;
        for_each_row(path, &wanted, |_, values| spill.push(&values[1..]))?;
        spill.finish()
    }

    /// [`Self::read`] by the fast block reader; `None` where it gives up (a row out of time
    /// order too: the row reader names it).
    fn read_fast(
        path: &Path,
        wanted: &[&str],
        errors: usize,
    ) -> Result<Option<(Self, Gram)>, StreamError> {
        let mut spill = Spill::new(errors)?;
        let read = for_each_fast_row(path, wanted, |row| {
            spill.push(&row[1..])?;
            Ok::<_, StreamError>(true)
        })?;
        if !read {
            return Ok(None);
        }
        spill.finish().map(Some)
    }

    /// Calls `block` with the stored rows, [`BLOCK_ROWS`] at a time, in order.
    fn pass(&self, mut block: impl FnMut(&[f64])) -> Result<(), StreamError> {
        let mut file = &self.file;
        file.seek(SeekFrom::Start(0)).map_err(spill_error)?;
        let mut bytes = vec![0u8; BLOCK_ROWS * self.columns * 8];
        let mut values = vec![0.0; BLOCK_ROWS * self.columns];
        let mut left = self.rows;
        while left > 0 {
            let rows = left.min(BLOCK_ROWS);
            let n = rows * self.columns;
            file.read_exact(&mut bytes[..n * 8]).map_err(spill_error)?;
            for (v, b) in values[..n].iter_mut().zip(bytes.chunks_exact(8)) {
                *v = f64::from_le_bytes(b.try_into().expect("8 bytes"));
            }
            block(&values[..n]);
            left -= rows;
        }
        Ok(())
    }
}

/// Rows on their way into a [`RowStore`], with their Gram matrix.
struct Spill {
    out: BufWriter<File>,
    gram: Gram,
    z: Vec<f64>,
    bytes: Vec<u8>,
}

impl Spill {
    fn new(errors: usize) -> Result<Self, StreamError> {
        let gram = Gram::new(errors);
        let file = tempfile::tempfile().map_err(spill_error)?;
        Ok(Self {
            out: BufWriter::with_capacity(1 << 20, file),
            z: vec![0.0; gram.dim],
            bytes: Vec::with_capacity(gram.dim * 8),
            gram,
        })
    }

    /// Adds a row (dynamics, then errors).
    fn push(&mut self, row: &[f64]) -> Result<(), StreamError> {
        self.gram.add(row, &mut self.z);
        self.bytes.clear();
        row.iter().for_each(|v| self.bytes.extend(v.to_le_bytes()));
        self.out.write_all(&self.bytes).map_err(spill_error)
    }

    fn finish(self) -> Result<(RowStore, Gram), StreamError> {
        let file = self
            .out
            .into_inner()
            .map_err(|e| spill_error(e.into_error()))?;
        let store = RowStore {
            file,
            columns: self.gram.dim - 1,
            rows: self.gram.rows,
        };
        Ok((store, self.gram))
    }
}

/// One error channel's backward elimination across rounds.
struct ChannelFit {
    name: &'static str,
    /// The error's column among the stored ones.
    column: usize,
    /// Active dynamics regressors (indices into [`DYNAMICS_REGRESSORS`]).
    active: Vec<usize>,
    eliminated: Vec<String>,
    /// Mean of the error.
    mean: f64,
    /// Total sum of squares, once the first round measured it.
    sst: Option<f64>,
    outcome: Option<Result<RegressionReport, RegressError>>,
}

impl ChannelFit {
    fn new(name: &'static str, column: usize, gram: &Gram) -> Self {
        let active = super::varying_regressors(gram.varies.iter().copied());
        let eliminated = (0..REGRESSORS)
            .filter(|k| !active.contains(k))
            .map(|k| DYNAMICS_REGRESSORS[k].to_string())
            .collect();
        Self {
            name,
            column,
            active,
            eliminated,
            mean: gram.sum(0, 1 + column) / gram.rows as f64,
            sst: None,
            outcome: None,
        }
    }

    /// The passes of this round for channel `k` (this one), or `None` once it has its
    /// outcome.
    fn start_round(
        &mut self,
        k: usize,
        gram: &Gram,
        opts: &RegressionOptions,
    ) -> Option<RoundPass> {
        if self.outcome.is_some() {
            return None;
        }
        let intercept = opts.intercept;
        let p = self.active.len() + usize::from(intercept);
        if gram.rows <= p + 1 {
            self.outcome = Some(Err(RegressError::TooFewObservations { n: gram.rows, p }));
            return None;
        }
        // z indices of the parameters: 0 is the constant, 1 + k dynamics column k.
        let z_of: Vec<usize> = (0..p)
            .map(|j| match (intercept, j) {
                (true, 0) => 0,
                (true, j) => 1 + self.active[j - 1],
                (false, j) => 1 + self.active[j],
            })
            .collect();
        let scale: Vec<f64> = z_of
            .iter()
            .map(|&a| column_scale(gram.sum(a, a).sqrt()))
            .collect();
        let xtx = DMatrix::from_fn(p, p, |i, j| {
            gram.sum(z_of[i], z_of[j]) * (1.0 / scale[i]) * (1.0 / scale[j])
        });
        let y_z = 1 + self.column;
        let xty = DVector::from_fn(p, |i, _| gram.sum(z_of[i], y_z) * (1.0 / scale[i]));
        let (xtx_inv, beta_s) = solve_scaled(&xtx, &xty);
        Some(RoundPass {
            channel: k,
            scores: Scores {
                y: self.column,
                x: z_of.iter().map(|&a| a.checked_sub(1)).collect(),
                inv_scale: scale.iter().map(|s| 1.0 / s).collect(),
                beta_s: beta_s.iter().copied().collect(),
                xs: vec![0.0; p],
                u: vec![0.0; p],
            },
            solution: ScaledSolution {
                n: gram.rows,
                scale,
                xtx_inv,
                beta_s,
                sse: 0.0,
                sst: 0.0,
            },
            mean: self
                .sst
                .is_none()
                .then_some(if intercept { self.mean } else { 0.0 }),
            sums: None,
            prewhitening: None,
            bandwidth: None,
            meat: None,
            hac: None,
            weights: bandwidth_weights(p, intercept),
        })
    }

    /// Concludes the round: the tests, then the next elimination or the report.
    fn end_round(&mut self, pass: RoundPass, opts: &RegressionOptions) {
        let RoundPass {
            mut solution,
            sums,
            hac,
            ..
        } = pass;
        let sums = sums.expect("the residual sums are always measured");
        solution.sse = sums.sse;
        if let Some(sst) = sums.sst {
            self.sst = Some(sst);
        }
        solution.sst = self.sst.unwrap_or(0.0);
        let fit = solution.conclude(self.active.len(), hac, Vec::new(), opts);
        match fit.least_significant(opts) {
            Some(i) => {
                self.eliminated
                    .push(DYNAMICS_REGRESSORS[self.active[i]].to_string());
                self.active.remove(i);
            }
            None => {
                let eliminated = std::mem::take(&mut self.eliminated);
                self.outcome = Some(Ok(fit.into_report(
                    &DYNAMICS_REGRESSORS,
                    &self.active,
                    opts,
                    eliminated,
                )));
            }
        }
    }
}

/// The passes of a round.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Stage {
    /// Residual and total sums of squares, and the VAR(1) sums of the scores.
    Sums,
    /// The lag products of the weighted (prewhitened) scores for the NW94 bandwidth.
    Bandwidth,
    /// The Bartlett moving sums of the (prewhitened) scores.
    Meat,
}

/// A channel's scores u_t = xs_t e_t under its current fit, from stored rows.
struct Scores {
    /// The error's column among the stored ones.
    y: usize,
    /// Per parameter: `None` for the constant, else its stored column.
    x: Vec<Option<usize>>,
    inv_scale: Vec<f64>,
    beta_s: Vec<f64>,
    xs: Vec<f64>,
    u: Vec<f64>,
}

impl Scores {
    /// The residual of `row`, with its scores left in `self.u`.
    fn residual(&mut self, row: &[f64]) -> f64 {
        for ((xs, x), inv) in self.xs.iter_mut().zip(&self.x).zip(&self.inv_scale) {
            *xs = x.map_or(1.0, |c| row[c]) * inv;
        }
        let fitted: f64 = self
            .xs
            .iter()
            .zip(&self.beta_s)
            .fold(0.0, |acc, (x, b)| acc + x * b);
        let e = row[self.y] - fitted;
        for (u, xs) in self.u.iter_mut().zip(&self.xs) {
            *u = xs * e;
        }
        e
    }
}

/// Sums of the first pass.
struct ResidualSums {
    sse: f64,
    /// Total sum of squares, when this round measures it.
    sst: Option<f64>,
    /// VAR(1) normal-equation sums, when prewhitening.
    var1: Option<Var1Sums>,
}

/// Sxx = sum u_{t-1} u_{t-1}', Syx = sum u_t u_{t-1}', and the previous scores.
struct Var1Sums {
    sxx: DMatrix<f64>,
    syx: DMatrix<f64>,
    previous: Option<Vec<f64>>,
}

/// Turns scores u_t into prewhitened ones e_t = u_t - A u_{t-1} (t >= 1), or u_t without A.
pub(crate) struct Whitener {
    a: Option<DMatrix<f64>>,
    previous: Vec<f64>,
    started: bool,
    e: Vec<f64>,
}

impl Whitener {
    /// No prewhitening: each score as it is, for `p` parameters.
    pub(crate) fn none(p: usize) -> Self {
        Self {
            a: None,
            previous: vec![0.0; p],
            started: false,
            e: vec![0.0; p],
        }
    }

    /// The prewhitened score of `u`, if there is one (none for the first with A).
    fn next(&mut self, u: &[f64]) -> Option<&[f64]> {
        let Some(a) = &self.a else {
            self.e.copy_from_slice(u);
            return Some(&self.e);
        };
        let started = std::mem::replace(&mut self.started, true);
        if started {
            var1_residual(a, &self.previous, u, &mut self.e);
        }
        self.previous.copy_from_slice(u);
        started.then_some(&self.e[..])
    }
}

/// Lag products sum_t h_t h_{t-j}, j = 0 ..= m, of the weighted prewhitened scores h.
struct BandwidthSums {
    whitener: Whitener,
    /// The last m + 1 values of h, h_t at t % (m + 1).
    ring: Vec<f64>,
    sums: Vec<f64>,
    count: usize,
}

/// The Bartlett moving sums v_t of `lag + 1` consecutive prewhitened scores and sum v v':
/// [`super::newey_west_meat_from_scores`] of scores that arrive one at a time.
pub(crate) struct BartlettSums {
    whitener: Whitener,
    lag: usize,
    /// Prewhitened scores in the run.
    n: usize,
    /// The last `lag + 1` scores, score s at slot s % (lag + 1).
    ring: Vec<f64>,
    v: Vec<f64>,
    /// The score leaving the window.
    oldest: Vec<f64>,
    chunk: Vec<f64>,
    total: Vec<f64>,
    count: usize,
}

impl BartlettSums {
    /// Sums for `n` scores (after prewhitening) of `p` parameters and a Bartlett lag `lag`.
    pub(crate) fn new(whitener: Whitener, p: usize, lag: usize, n: usize) -> Self {
        Self {
            whitener,
            lag,
            n,
            ring: vec![0.0; (lag + 1) * p],
            v: vec![0.0; p],
            oldest: vec![0.0; p],
            chunk: vec![0.0; p * p],
            total: vec![0.0; p * p],
            count: 0,
        }
    }

    /// Window `t` (the one ending at score t, t < n + lag); score t, if any, is already in
    /// the ring and score t - lag - 1, if any, in `oldest`.
    fn window(&mut self, t: usize) {
        let p = self.v.len();
        let slots = self.lag + 1;
        if t.is_multiple_of(MEAT_CHUNK) {
            self.v.iter_mut().for_each(|v| *v = 0.0);
            for s in t.saturating_sub(self.lag)..=t.min(self.n - 1) {
                let e = &self.ring[(s % slots) * p..(s % slots + 1) * p];
                self.v.iter_mut().zip(e).for_each(|(v, e)| *v += e);
            }
        } else {
            if t < self.n {
                let e = &self.ring[(t % slots) * p..(t % slots + 1) * p];
                self.v.iter_mut().zip(e).for_each(|(v, e)| *v += e);
            }
            if t > self.lag {
                self.v
                    .iter_mut()
                    .zip(&self.oldest)
                    .for_each(|(v, e)| *v -= e);
            }
        }
        add_outer_upper(&mut self.chunk, &self.v);
        if (t + 1).is_multiple_of(MEAT_CHUNK) {
            self.fold_chunk();
        }
    }

    fn fold_chunk(&mut self) {
        for (t, c) in self.total.iter_mut().zip(&mut self.chunk) {
            *t += *c;
            *c = 0.0;
        }
    }

    /// Takes the next score u (before prewhitening).
    pub(crate) fn push(&mut self, u: &[f64]) {
        let Some(e) = self.whitener.next(u) else {
            return;
        };
        let p = e.len();
        let t = self.count;
        let slot = t % (self.lag + 1);
        // Score t - lag - 1 leaves the window as score t enters it, in the same slot.
        self.oldest
            .copy_from_slice(&self.ring[slot * p..(slot + 1) * p]);
        self.ring[slot * p..(slot + 1) * p].copy_from_slice(e);
        self.window(t);
        self.count += 1;
    }

    /// The windows after the last score, then the meat.
    pub(crate) fn finish(mut self) -> DMatrix<f64> {
        let p = self.v.len();
        for t in self.n..self.n + self.lag {
            if t > self.lag {
                let s = (t - self.lag - 1) % (self.lag + 1);
                self.oldest.copy_from_slice(&self.ring[s * p..(s + 1) * p]);
            }
            self.window(t);
        }
        self.fold_chunk();
        meat_from_upper(&self.total, p, self.lag)
    }
}

/// One channel's work in one round of passes.
struct RoundPass {
    channel: usize,
    scores: Scores,
    solution: ScaledSolution,
    /// The error's mean, when this round measures the total sum of squares.
    mean: Option<f64>,
    sums: Option<ResidualSums>,
    /// The round's VAR(1) prewhitening, A and (I - A)^-1, when asked for and fitted (else
    /// the scores are used as they are).
    prewhitening: Option<(DMatrix<f64>, DMatrix<f64>)>,
    bandwidth: Option<BandwidthSums>,
    meat: Option<BartlettSums>,
    /// The long-run covariance, once measured (its lag and bandwidth once chosen).
    hac: Option<HacEstimate>,
    weights: Vec<f64>,
}

impl RoundPass {
    fn p(&self) -> usize {
        self.scores.u.len()
    }

    /// Whether this channel needs the pass `stage`.
    fn wants(&self, stage: Stage, opts: &RegressionOptions) -> bool {
        match (stage, opts.inference) {
            (Stage::Sums, _) => true,
            (_, Inference::Classical) => false,
            (Stage::Bandwidth, Inference::NeweyWest { lag, .. }) => lag.is_none(),
            (Stage::Meat, Inference::NeweyWest { .. }) => true,
        }
    }

    fn whitener(&self) -> Whitener {
        Whitener {
            a: self.prewhitening.as_ref().map(|(a, _)| a.clone()),
            previous: vec![0.0; self.p()],
            started: false,
            e: vec![0.0; self.p()],
        }
    }

    /// Scores after prewhitening: one fewer when A was fitted.
    fn whitened_count(&self) -> usize {
        self.solution.n - usize::from(self.prewhitening.is_some())
    }

    fn begin(&mut self, stage: Stage, opts: &RegressionOptions) {
        if !self.wants(stage, opts) {
            return;
        }
        let p = self.p();
        let prewhite = matches!(opts.inference, Inference::NeweyWest { prewhite: true, .. });
        match stage {
            Stage::Sums => {
                self.sums = Some(ResidualSums {
                    sse: 0.0,
                    sst: self.mean.map(|_| 0.0),
                    var1: prewhite.then(|| Var1Sums {
                        sxx: DMatrix::zeros(p, p),
                        syx: DMatrix::zeros(p, p),
                        previous: None,
                    }),
                });
            }
            Stage::Bandwidth => {
                let m = nw94_prelag(self.whitened_count(), prewhite);
                self.bandwidth = Some(BandwidthSums {
                    whitener: self.whitener(),
                    ring: vec![0.0; m + 1],
                    sums: vec![0.0; m + 1],
                    count: 0,
                });
            }
            Stage::Meat => {
                let n_e = self.whitened_count();
                let lag = match (opts.inference, &self.hac) {
                    (Inference::NeweyWest { lag: Some(l), .. }, _) => l.min(n_e - 1),
                    (_, Some(hac)) => hac.lag,
                    _ => 0,
                };
                self.meat = Some(BartlettSums::new(self.whitener(), p, lag, n_e));
            }
        }
    }

    /// Takes a block of stored rows of `columns` values each.
    fn feed(&mut self, block: &[f64], columns: usize) {
        let intercept_only = self.weights.iter().all(|w| *w == 0.0);
        for row in block.chunks_exact(columns) {
            let e = self.scores.residual(row);
            let u = &self.scores.u;
            if let Some(s) = &mut self.sums {
                s.sse += e * e;
                if let (Some(sst), Some(mean)) = (&mut s.sst, self.mean) {
                    *sst += (row[self.scores.y] - mean).powi(2);
                }
                if let Some(v) = &mut s.var1 {
                    match &mut v.previous {
                        Some(prev) => {
                            add_var1_sums(&mut v.sxx, &mut v.syx, prev, u);
                            prev.copy_from_slice(u);
                        }
                        None => v.previous = Some(u.clone()),
                    }
                }
            }
            if let Some(b) = &mut self.bandwidth {
                if let Some(e) = b.whitener.next(u) {
                    let h: f64 = if intercept_only {
                        e.iter().sum()
                    } else {
                        e.iter().zip(&self.weights).map(|(e, w)| e * w).sum()
                    };
                    let slots = b.ring.len();
                    b.ring[b.count % slots] = h;
                    for j in 0..slots.min(b.count + 1) {
                        b.sums[j] += b.ring[(b.count - j) % slots] * h;
                    }
                    b.count += 1;
                }
            }
            if let Some(m) = &mut self.meat {
                m.push(u);
            }
        }
    }

    fn end(&mut self, stage: Stage, opts: &RegressionOptions) {
        match stage {
            Stage::Sums => {
                let Some(sums) = &mut self.sums else { return };
                self.prewhitening = sums.var1.take().and_then(|v| var1_fit(&v.sxx, &v.syx));
            }
            Stage::Bandwidth => {
                let Some(b) = self.bandwidth.take() else {
                    return;
                };
                let n_e = b.count;
                let bandwidth = nw94_bandwidth(&b.sums, n_e, self.solution.n - n_e);
                self.hac = Some(HacEstimate {
                    meat: DMatrix::zeros(0, 0),
                    lag: lag_of_bandwidth(bandwidth, n_e),
                    bandwidth: Some(bandwidth),
                });
            }
            Stage::Meat => {
                let Some(m) = self.meat.take() else { return };
                let lag = m.lag;
                let s = m.finish();
                let meat = match self.prewhitening.as_ref().map(|(_, d)| d) {
                    Some(d) => d * s * d.transpose(),
                    None => s,
                };
                let bandwidth = match opts.inference {
                    Inference::NeweyWest { lag: None, .. } => {
                        self.hac.as_ref().and_then(|h| h.bandwidth)
                    }
                    _ => None,
                };
                self.hac = Some(HacEstimate {
                    meat,
                    lag,
                    bandwidth,
                });
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::super::tests::ar1;
    use super::*;
    use crate::error_signal::ErrorSignals;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;
    use rand_distr::StandardNormal;

    /// Error signals of `n` rows at 100 Hz: slow dynamics of several magnitudes (one column
    /// constant), and four error channels each with two true terms, a bias and AR(1) plus
    /// white noise; the accelerometer x and y channels are absent.
    fn signals(seed: u64, n: usize) -> ErrorSignals {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let dynamics: [Vec<f64>; 15] = std::array::from_fn(|k| {
            if k == 7 {
                vec![0.25; n]
            } else {
                let scale = [1.0, 0.1, 30.0][k % 3];
                ar1(&mut rng, n, 0.995, scale * 0.1)
            }
        });
        let errors: [Option<Vec<f64>>; 6] = std::array::from_fn(|c| {
            (c != 3 && c != 4).then(|| {
                let slow = ar1(&mut rng, n, 0.99, 1e-4);
                (0..n)
                    .map(|t| {
                        1e-3 * (c as f64 + 1.0)
                            + 2e-3 * dynamics[c][t]
                            + 1e-5 * dynamics[9 + c % 3][t]
                            + slow[t]
                            + 1e-3 * rng.sample::<f64, _>(StandardNormal)
                    })
                    .collect()
            })
        });
        ErrorSignals {
            t_s: (0..n).map(|t| t as f64 * 0.01).collect(),
            errors,
            dynamics,
            specific_force_b_m_s2: None,
        }
    }

    fn close(a: f64, b: f64, tol: f64) -> bool {
        (a - b).abs() <= tol * a.abs().max(b.abs()).max(1e-300)
    }

    /// The streamed reports equal the batch ones on the same rows: the same terms kept and
    /// eliminated in the same order, the same lag, estimates and standard errors to 1e-9.
    fn assert_streamed_equals_batch(sig: &ErrorSignals, opts: &RegressionOptions, file: &str) {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join(file);
        sig.write(&path).unwrap();
        let streamed = regress_file(&path, opts).unwrap();
        let regs = sig.regressors();
        let present: Vec<&str> = ERROR_COLUMNS
            .iter()
            .zip(&sig.errors)
            .filter_map(|(name, e)| e.as_ref().map(|_| *name))
            .collect();
        assert_eq!(
            streamed.iter().map(|(n, _)| *n).collect::<Vec<_>>(),
            present
        );
        for ((name, outcome), y) in streamed.iter().zip(sig.errors.iter().flatten()) {
            let batch = super::super::backward_elimination(y, &regs, opts).unwrap();
            let stream = outcome.as_ref().unwrap();
            assert_eq!(stream.eliminated, batch.eliminated, "{name}");
            assert_eq!(stream.hac_lag, batch.hac_lag, "{name}");
            assert_eq!(stream.n, batch.n);
            for (s, b) in stream.coefficients.iter().zip(&batch.coefficients) {
                assert_eq!(s.name, b.name, "{name}");
                assert!(close(s.estimate, b.estimate, 1e-9), "{name} {s:?} {b:?}");
                assert!(close(s.std_error, b.std_error, 1e-9), "{name} {s:?} {b:?}");
            }
            assert_eq!(stream.coefficients.len(), batch.coefficients.len());
            assert!(close(stream.r2, batch.r2, 1e-9), "{name}");
            assert!(close(stream.wald_f_statistic, batch.wald_f_statistic, 1e-8));
            match (stream.hac_bandwidth, batch.hac_bandwidth) {
                (Some(s), Some(b)) => assert!(close(s, b, 1e-9), "{name} {s} {b}"),
                (s, b) => assert_eq!(s, b),
            }
            assert!(!stream.eliminated.is_empty() && stream.coefficients.len() > 2);
        }
    }

    #[test]
    fn streamed_equals_batch_under_default_inference() {
        let sig = signals(11, 20_000);
        assert_streamed_equals_batch(&sig, &RegressionOptions::default(), "e.csv");
    }

    #[test]
    fn streamed_equals_batch_under_every_inference_and_format() {
        let sig = signals(12, 9_000);
        let options = [
            Inference::Classical,
            Inference::NeweyWest {
                lag: Some(5_000),
                prewhite: false,
            },
            Inference::NeweyWest {
                lag: None,
                prewhite: false,
            },
            Inference::NeweyWest {
                lag: Some(3),
                prewhite: true,
            },
        ];
        for (k, inference) in options.into_iter().enumerate() {
            let opts = RegressionOptions {
                inference,
                intercept: k != 2,
                ..RegressionOptions::default()
            };
            let file = ["e.csv", "e.csv.gz", "e.parquet", "e.csv"][k];
            assert_streamed_equals_batch(&sig, &opts, file);
        }
    }

    #[test]
    fn short_blank_lined_disordered_and_foreign_files_are_read_or_refused_as_rows_are() {
        let sig = signals(13, 12);
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("short.csv");
        sig.write(&path).unwrap();
        let outcomes = regress_file(&path, &RegressionOptions::default()).unwrap();
        for (_, outcome) in outcomes {
            let e = outcome.unwrap_err();
            assert!(
                matches!(e, RegressError::TooFewObservations { n: 12, p: 15 }),
                "{e}"
            );
        }
        // Rows the fast reader gives up on (a blank line), and a row out of time order,
        // which the row reader names.
        let long = signals(14, 3_000);
        let path = dir.path().join("long.csv");
        long.write(&path).unwrap();
        let text = std::fs::read_to_string(&path).unwrap();
        let blank = text.replacen("\n0.5,", "\n\n0.5,", 1);
        assert_ne!(blank, text);
        std::fs::write(&path, &blank).unwrap();
        let fast = dir.path().join("fast.csv");
        std::fs::write(&fast, &text).unwrap();
        let opts = RegressionOptions::default();
        let (slow, quick) = (
            regress_file(&path, &opts).unwrap(),
            regress_file(&fast, &opts).unwrap(),
        );
        for ((_, a), (_, b)) in slow.iter().zip(&quick) {
            assert_eq!(a.as_ref().unwrap(), b.as_ref().unwrap());
        }
        let lines: Vec<&str> = text.lines().collect();
        let mut swapped = lines.clone();
        swapped.swap(100, 101);
        std::fs::write(&path, swapped.join("\n")).unwrap();
        let e = regress_file(&path, &opts).unwrap_err().to_string();
        assert!(e.contains("long.csv") && e.contains("line 102"), "{e}");
        let rec = dir.path().join("rec.csv");
        std::fs::write(&rec, "t_s,gx_rad_s\n0,1\n0.01,2\n").unwrap();
        let e = regress_file(&rec, &RegressionOptions::default()).unwrap_err();
        assert!(e.to_string().contains("no error column"), "{e}");
        assert!(e.to_string().contains("rec.csv"), "{e}");
    }
}
