//! The deterministic terms of each channel's error, found in two stages. Per channel: a
//! stepwise selection over the regressors physics says could drive the channel (its own
//! input, the other axes' inputs, specific force on a gyro, angular acceleration, the rate of
//! change of specific force), each fitted jointly with the calibration, then a search for a
//! step of the bias on what the kept terms leave. Across channels: a joint fit of all kept
//! terms with the calibration, so a term one channel shows only because another channel's
//! term moved the calibration drops out. Last, per channel, the kept terms as findings with
//! their coefficients, intervals and shares of the error variance.

use serde_json::json;

use super::engine::{ci, simulated_range, DiagnoseError, Discrepancy, Finding, Run};
use super::moments::{
    eliminate_on_moments, full_fit_residual, gram_matrix, Batch, MeasuredSpread, Regressor, Term,
    WhiteSpace,
};
use super::null::{normal_p_value, scan_p_value};
use super::signals::Dynamics;
use super::stats::{
    drawn_from, local_step_null_sd, local_step_robust_sd, local_step_scan, series_variance,
    step_sharpness, with_bank_series, Series, SeriesSet,
};
use super::white_space::SimReader;
use super::whiten::Whitener;
use crate::calibration::DesignRows;
use crate::model::{Cause, Channel};
use crate::series_bank::{block_ranges, BlockVisit, SeriesBank, BANK_BLOCK_EPOCHS};

/// True when a term's share of the error variance reaches `min`; a NaN share (an error
/// without variance) never does.
fn explains_enough(share: f64, min: f64) -> bool {
    share >= min
}

/// A regressor that may drive a channel's error, and the cause it stands for.
pub(super) struct Candidate<'a> {
    pub name: String,
    pub values: Regressor<'a>,
    pub cause: Cause,
    /// The body axis of the regressor (x, y, z = 0, 1, 2): where its coefficient goes in the
    /// channel's model row.
    pub axis: usize,
}

/// What the per-channel and joint stages found on one channel.
pub(super) struct ChannelTerms<'a> {
    pub terms: Vec<Term<'a>>,
    /// Time of the bias step, s from the start of the sensor recording, when one was found.
    pub step_at_s: Option<f64>,
    pub discrepancies: Vec<Discrepancy>,
    /// What the other channels' terms pushed into this channel through the calibration, to
    /// be taken out of its error: the calibration parameters they moved, whose fit on this
    /// channel's rows is the series (None without a calibration: nothing). Kept as
    /// parameters, so a channel's series is made only when its later stages run.
    pub calibration_spill: Option<nalgebra::DVector<f64>>,
}

/// The deterministic candidates of `channel` by physics. Each is fitted jointly with the
/// calibration (boresight, lever arm, biases) on every channel's rows, so its coefficient is
/// the one of a joint fit: a gyro's omega_z -> gx term is otherwise half absorbed by the
/// boresight, and an accelerometer's jerk term by the time offset. Static data (no
/// dynamics) has none.
fn candidates<'a>(run: &'a Run, channel: Channel) -> Vec<Candidate<'a>> {
    let mut cands = Vec::new();
    if !run.has_dynamics {
        return cands;
    }
    let gyro = channel.is_gyro();
    let signal = |quantity: Dynamics, axis: usize| Regressor::Signal {
        signals: run.signals,
        series: run.signals.dynamics_index(quantity, axis),
    };
    for (j, axis_name) in ["x", "y", "z"].into_iter().enumerate() {
        let (input, input_name) = if gyro {
            (Dynamics::AngularRate, "omega")
        } else {
            (Dynamics::SpecificForce, "f")
        };
        cands.push(Candidate {
            name: format!("{input_name}_{axis_name}"),
            values: signal(input, j),
            cause: if j == channel.axis() {
                Cause::ScaleFactor
            } else {
                Cause::CrossAxis
            },
            axis: j,
        });
        if gyro {
            cands.push(Candidate {
                name: format!("f_{axis_name}"),
                values: signal(Dynamics::SpecificForce, j),
                cause: Cause::GSensitivity,
                axis: j,
            });
        }
        cands.push(Candidate {
            name: format!("omega_dot_{axis_name}"),
            values: signal(Dynamics::AngularAcceleration, j),
            cause: Cause::AngularAcceleration,
            axis: j,
        });
        cands.push(Candidate {
            name: format!("f_dot_{axis_name}"),
            values: signal(Dynamics::SpecificForceRate, j),
            cause: Cause::Jerk,
            axis: j,
        });
    }
    cands
}

/// The run in the metric of generalised least squares: every channel filtered by the
/// whitening filter of its baseline model, the errors and each replicate's baseline
/// simulations after the calibration.
fn white_space<'a>(run: &'a Run) -> Result<WhiteSpace<'a>, DiagnoseError> {
    let mut whiteners: [Option<Whitener>; 6] = std::array::from_fn(|_| None);
    for channel in &run.channels {
        whiteners[channel.index()] = Some(Whitener::new(run.spec(*channel)?, run.n));
    }
    let error_of = |ch: usize, epochs: std::ops::Range<usize>| {
        let channel = Channel::ALL[ch];
        run.signals
            .has_error(channel)
            .then(|| run.signals.error_range(channel, epochs))
            .transpose()
    };
    // A channel's baseline simulation of one replicate (the ones every stage draws).
    let sim_of = move |r: usize, i: usize| -> Option<SimReader> {
        let channel = Channel::ALL[i];
        let slot = run.channels.iter().position(|c| *c == channel)?;
        let mut simulation = run.baseline_simulation(slot, r);
        Some(Box::new(move |epochs, values| {
            simulation.next_block(epochs, values)
        }))
    };
    // Static data has no candidate terms and a step's coefficient is its own estimate, so
    // nothing is fitted against the simulations there: none are filtered.
    let replicates = if run.has_dynamics {
        run.opts.replicates
    } else {
        0
    };
    WhiteSpace::new(
        run.absorber(),
        whiteners,
        (&error_of, run.n),
        replicates,
        Box::new(sim_of),
        run.opts.held_samples,
    )
}

/// The stepwise selection of one channel's terms, with what it needs of the channel: its
/// error and the run in the metric of generalised least squares.
struct Selection<'s, 'a> {
    channel: Channel,
    /// The variance of the channel's error.
    var_e: f64,
    space: &'s WhiteSpace<'a>,
    z_strict: f64,
    min_variance_explained: f64,
}

impl<'a> Selection<'_, 'a> {
    /// Every candidate as a term fitted with the calibration, coefficients not yet set.
    fn terms(&self, cands: &[Candidate<'a>]) -> Result<Batch<'a>, DiagnoseError> {
        Term::batch(self.space, self.channel, cands)
    }

    /// Backward elimination with simulation-calibrated standard errors: the baseline noise
    /// (slow Gauss-Markov wander included) is regressed on the same measured dynamics, so
    /// spurious correlation of slow noise with slow manoeuvres is in the null distribution.
    /// HAC alone under-covers for such persistent noise. With a `fixed` term (a bias step
    /// estimated locally) the candidates are fitted on what it leaves.
    fn select(&self, mut terms: Vec<Term<'a>>, fixed: Option<&Term<'a>>) -> Vec<Term<'a>> {
        if let Some(f) = fixed {
            terms.iter_mut().for_each(|t| t.take_out(f));
        }
        let spread = MeasuredSpread {
            epochs: self.space.epochs(),
            white_error_sum: self.space.error_sum(self.channel),
            fixed,
        };
        let gram = gram_matrix(&terms);
        let var_e = self.var_e;
        let small = |k: usize, b: f64| {
            let explained = b.powi(2) * terms[k].own_variance / var_e;
            !explains_enough(explained, self.min_variance_explained)
        };
        let kept = eliminate_on_moments(&gram, &terms, self.z_strict, &small, Some(spread));
        let mut terms: Vec<Option<Term>> = terms.into_iter().map(Some).collect();
        kept.into_iter()
            .map(|(k, b, sd)| {
                let mut t = terms[k].take().expect("each term once");
                t.coef = b;
                t.se = sd;
                t.sd_floor = sd;
                t
            })
            .collect()
    }
}

/// A step of the bias found on a channel.
struct FoundStep {
    /// First epoch after the step.
    index: usize,
    /// Time of the step, s from the start of the sensor recording.
    at_s: f64,
    /// The step's size (difference of the window means either side of it, channel unit)
    /// and its standard error (the null spread of that difference at its window).
    size: f64,
    se: f64,
    /// P-value of the scan's largest |z| ([`scan_p_value`]), one test.
    p_value: f64,
    /// Whether the change is as large at a quarter of its window ([`step_sharpness`]): a
    /// step, not a change of the mean spread over the window (slow wander, a ramp), which
    /// is left to the wavelet-variance tests.
    sharp: bool,
    discrepancy: Discrepancy,
}

/// Largest [`step_sharpness`] of a change of the mean still taken for a step: about three
/// standard deviations, so a true step is refused in about 0.3% of runs.
const MAX_STEP_BLUR: f64 = 3.0;

/// A step of the bias, looked for at short windows (the difference of the means just after
/// and just before each epoch), where slow Gauss-Markov wander barely moves while a step
/// stands whole, on `resid`, what a fit of every candidate term leaves
/// ([`full_fit_residual`]), with the null spread at each window from the baseline
/// simulations. `steps_elsewhere`: what other channels' steps took from this
/// channel through the calibration, given back (a step on ay pulls the boresight about z,
/// which leaves a copy of f_y's turns on ax, and a turn's onset looks like a local step).
fn find_bias_step(
    run: &Run,
    channel: Channel,
    resid: &Series,
    sims: &impl SeriesSet,
) -> Result<Option<FoundStep>, DiagnoseError> {
    let windows: Vec<usize> = (6..20)
        .map(|j| 1usize << j)
        .take_while(|&w| w <= run.n / 8)
        .collect();
    let null_sd = local_step_null_sd(sims, &windows);
    let sim_z: Vec<f64> = sims
        .map_each(&|s| local_step_scan(s, &windows, &null_sd).map(|m| m.z))
        .into_iter()
        .flatten()
        .collect();
    let range = simulated_range(&sim_z);
    // The residual is scaled by its own noise where that is larger than the baseline's (a
    // stronger correlated noise wanders in steps the baseline's would not); the threshold on
    // the largest z still comes from the simulations.
    let own_sd = local_step_robust_sd(resid, &windows);
    let scale_sd: Vec<f64> = null_sd
        .iter()
        .zip(&own_sd)
        .map(|(a, b)| a.max(*b))
        .collect();
    let Some(step) = local_step_scan(resid, &windows, &scale_sd) else {
        return Ok(None);
    };
    // Without a step in any simulation (range -inf) the threshold is z_strict; a NaN z is
    // no step.
    let stands_out = step.z > (1.25 * range[1]).max(run.z_strict);
    if !stands_out {
        return Ok(None);
    }
    let step_time_s = run.signals.time_at_s(step.index)?;
    let blur = step_sharpness(resid, step.index, step.window, sims);
    let sharp = !(blur > MAX_STEP_BLUR);
    Ok(Some(FoundStep {
        index: step.index,
        at_s: step_time_s - run.sensor_start_s,
        size: step.size,
        se: step.sd,
        p_value: scan_p_value(step.z, &sim_z),
        sharp,
        discrepancy: Discrepancy {
            channel,
            statistic: "largest local step of the mean (|z| at its window)".into(),
            measured: step.z,
            simulated_range: range,
            detail: format!(
                "at t = {:.2} s, window {} samples, local size {:.4e}{}",
                step_time_s,
                step.window,
                step.size,
                if sharp {
                    String::new()
                } else {
                    format!(
                        "; spread over the window (a quarter of it sees {blur:.1} sigma less): \
                         slow wander, not a step"
                    )
                }
            ),
        },
    }))
}

/// Stage 1 on one channel (`slot` in the run's channels): the stepwise selection over the
/// physics candidates, then a bias step. A step found takes its size and interval from its
/// local estimate (the window means either side of it), and the selection runs again on
/// what it leaves, so terms that were standing in for it (a scale factor, when the input's
/// level changes during the run) drop out. Why local: a step regressor over the whole run
/// (0 before, 1 after) is confounded with slow wander, whose spread over a fitted
/// baseline's drawn models is wide, while a step stands whole at a window of seconds, where
/// the wander barely moves.
fn channel_terms<'a>(
    run: &'a Run,
    space: &WhiteSpace<'a>,
    slot: usize,
    channel: Channel,
    steps_elsewhere: Option<&SeriesBank>,
) -> Result<ChannelTerms<'a>, DiagnoseError> {
    let cands = candidates(run, channel);
    // Baseline simulations: the null distribution of the step scan.
    let sims = run.baseline_sims(slot);
    let selection = Selection {
        channel,
        var_e: run.signals.with_error(channel, series_variance)?,
        space,
        z_strict: run.z_strict,
        min_variance_explained: run.opts.min_variance_explained,
    };
    let mut batch = selection.terms(&cands)?;
    let mut terms = selection.select(batch.terms.clone(), None);
    let mut discrepancies = Vec::new();
    let mut step_at_s = None;
    let unexplained = full_fit_residual(run, channel, &batch.terms, steps_elsewhere)?;
    let found = with_bank_series(&unexplained, 0, |resid| {
        find_bias_step(run, channel, resid, &sims)
    })??;
    if let Some(found) = found {
        let FoundStep {
            index,
            at_s,
            size,
            se,
            p_value,
            sharp,
            discrepancy,
        } = found;
        discrepancies.push(discrepancy);
        if sharp {
            let candidate = Candidate {
                name: format!("step_at_{at_s:.2}_s"),
                values: Regressor::Step {
                    at: index,
                    n: run.n,
                },
                cause: Cause::BiasShift,
                axis: 0,
            };
            let mut step_term = Term::join(space, channel, &candidate, &mut batch)?;
            step_term.fix(size, se, p_value);
            step_at_s = Some(at_s);
            terms = selection.select(batch.terms, Some(&step_term));
            terms.push(step_term);
        }
    }
    Ok(ChannelTerms {
        terms,
        step_at_s,
        discrepancies,
        calibration_spill: None,
    })
}

/// The deterministic terms of every channel of the run (in the run's channel order): stage 1
/// per channel, then, with a calibration, stage 2 across channels: the terms kept per channel
/// are fitted jointly with the calibration and each other, so a term one channel shows only
/// because another channel's term pulled the boresight or lever arm drops out.
pub(super) fn find_terms<'a>(run: &'a Run) -> Result<Vec<ChannelTerms<'a>>, DiagnoseError> {
    let mut error_variance = [f64::NAN; 6];
    for channel in &run.channels {
        error_variance[channel.index()] = run.signals.with_error(*channel, series_variance)?;
    }
    let space = white_space(run)?;
    let stage1 = |slot: usize, channel: Channel, steps_elsewhere: Option<&SeriesBank>| {
        channel_terms(run, &space, slot, channel, steps_elsewhere)
    };
    let first: Vec<Result<ChannelTerms, DiagnoseError>> = run
        .per_channel(vec![(); run.channels.len()], |slot, channel, ()| {
            stage1(slot, channel, None)
        });
    let mut per_channel: Vec<ChannelTerms> = first.into_iter().collect::<Result<_, _>>()?;
    // Steps found, their pull on the calibration given back to the other channels, and
    // the scan run again there.
    if let Some(design) = run.design {
        crate::progress::stage(|| "testing terms again beside the steps found".into());
        run.work.expect(run.channels.len() as u64);
        let steps: Vec<&Term> = per_channel
            .iter()
            .flat_map(|c| c.terms.iter().filter(|t| t.fixed.is_some()))
            .collect();
        let again: Vec<Result<Option<ChannelTerms>, DiagnoseError>> = run.per_channel(
            vec![(); run.channels.len()],
            |slot, channel, ()| match step_spill(design, run, &steps, channel)? {
                Some(s) => stage1(slot, channel, Some(&s)).map(Some),
                None => Ok(None),
            },
        );
        for (slot, redone) in again.into_iter().enumerate() {
            if let Some(r) = redone? {
                per_channel[slot] = r;
            }
        }
    }
    let Some(design) = run.design else {
        return Ok(per_channel);
    };
    let all: Vec<Term> = per_channel
        .iter_mut()
        .flat_map(|c| std::mem::take(&mut c.terms))
        .collect();
    let joint = joint_terms(design, all, run.z_strict, &|t: &Term, b: f64| {
        let explained = b.powi(2) * t.own_variance / error_variance[t.channel.index()];
        !explains_enough(explained, run.opts.min_variance_explained)
    });
    let mut joint_spill = joint.spill;
    for t in joint.terms {
        per_channel[run.slot(t.channel)].terms.push(t);
    }
    for (found, channel) in per_channel.iter_mut().zip(&run.channels) {
        found.calibration_spill = joint_spill[channel.index()].take();
    }
    Ok(per_channel)
}

/// What the bias steps found on the other channels (`steps`: every channel's) took from
/// `channel` through the calibration (None where no other channel has a step): each step's
/// coefficient times the calibration's fit of what it absorbed of the step, on this
/// channel's rows. Made when the channel's scan runs again, a block at a time into a bank
/// of one series (spilled on a long run).
fn step_spill(
    design: DesignRows<'_>,
    run: &Run,
    steps: &[&Term],
    channel: Channel,
) -> Result<Option<SeriesBank>, DiagnoseError> {
    let elsewhere: Vec<&&Term> = steps.iter().filter(|t| t.channel != channel).collect();
    if elsewhere.is_empty() {
        return Ok(None);
    }
    let mut bank = SeriesBank::columns(run.n, 1, run.is_long())?;
    let mut spill = Vec::with_capacity(BANK_BLOCK_EPOCHS);
    for epochs in block_ranges(0..run.n) {
        spill.clear();
        spill.resize(epochs.len(), 0.0);
        for t in &elsewhere {
            design.add_fitted(
                channel.index(),
                &t.projection.absorbed,
                t.coef,
                epochs.clone(),
                &mut spill,
            )?;
        }
        bank.write(0, epochs.start, &spill)?;
    }
    Ok(Some(bank))
}

/// The terms the joint fit keeps and, per channel, what the other channels' kept terms
/// had pushed into it through the calibration (to be taken out of its error): the
/// calibration parameters they moved.
struct JointTerms<'a> {
    terms: Vec<Term<'a>>,
    spill: [Option<nalgebra::DVector<f64>>; 6],
}

/// Fits the terms of all channels jointly with the calibration and with each other, and
/// eliminates, one at a time, those no longer significant or too small to matter (`small`
/// at their coefficient).
///
/// Why: a term on one channel moves the calibration (a gyro's omega_z -> gx term pulls the
/// boresight about y), and the moved calibration leaves a copy of the term's pattern on the
/// other channels (f_x on az). Each channel's own fit sees that copy as a term of its own;
/// in the joint fit the copy is explained by the term that caused it. Fixed terms (a bias
/// step's local estimate) keep their coefficients; the others are fitted on what they leave.
fn joint_terms<'a>(
    design: DesignRows<'_>,
    terms: Vec<Term<'a>>,
    z_strict: f64,
    small: &dyn Fn(&Term, f64) -> bool,
) -> JointTerms<'a> {
    let (fixed, mut terms): (Vec<Term>, Vec<Term>) =
        terms.into_iter().partition(|t| t.fixed.is_some());
    for t in terms.iter_mut() {
        fixed.iter().for_each(|f| t.take_out(f));
    }
    let k = terms.len();
    let gram = gram_matrix(&terms);
    let mut kept = eliminate_on_moments(&gram, &terms, z_strict, &|i, b| small(&terms[i], b), None);
    let fixed_kept: Vec<(usize, f64, f64)> = fixed
        .iter()
        .enumerate()
        .map(|(i, f)| (k + i, f.coef, f.se))
        .collect();
    kept.extend(fixed_kept);
    terms.extend(fixed);
    let mut spill: [Option<nalgebra::DVector<f64>>; 6] = std::array::from_fn(|ch| {
        design
            .has_channel(ch)
            .then(|| nalgebra::DVector::zeros(design.parameters()))
    });
    let mut terms: Vec<Option<Term>> = terms.into_iter().map(Some).collect();
    let mut out = Vec::new();
    for (i, coef, se) in kept {
        let mut t = terms[i].take().expect("each term once");
        // What the calibration took from this term shows on the other channels as
        // -coef * X_ch absorbed.
        for (ch, s) in spill.iter_mut().enumerate() {
            if let Some(s) = s.as_mut().filter(|_| ch != t.channel.index()) {
                s.axpy(-coef, &t.projection.absorbed, 1.0);
            }
        }
        t.coef = coef;
        t.se = se;
        out.push(t);
    }
    JointTerms { terms: out, spill }
}

/// A kept term's coefficient as the extended model carries it.
#[derive(Debug, Clone, Copy)]
pub(super) struct Coefficient {
    pub value: f64,
    pub ci95: [f64; 2],
    /// Share of the channel's error variance the term accounts for.
    pub variance_explained: f64,
    /// Two-sided p-value of the coefficient against zero, from its final interval.
    pub p_value: f64,
}

impl Coefficient {
    /// The coefficient of a term left out of a model: zero, exactly.
    pub const ZERO: Coefficient = Coefficient {
        value: 0.0,
        ci95: [0.0, 0.0],
        variance_explained: 0.0,
        p_value: 1.0,
    };
}

/// A channel's deterministic terms after both stages: each term with its coefficient
/// (`coefficients[k]` belongs to `terms[k]`) and the bias left beside them.
pub(super) struct FittedTerms<'a> {
    pub terms: Vec<Term<'a>>,
    /// Each term's [`Term::own_in`], made once (the gain's simulations read them over and
    /// over): held on a short run, in a temporary file on a long one.
    own: SeriesBank,
    pub coefficients: Vec<Coefficient>,
    /// Mean error the terms leave, channel unit.
    pub intercept: f64,
    /// The channel error's variance, channel unit squared.
    pub var_e: f64,
    /// Time of the bias step, s from the start of the sensor recording, if one was kept.
    pub step_at_s: Option<f64>,
}

/// Causes of per-channel terms, in the order their findings are reported.
const TERM_CAUSES: [Cause; 6] = [
    Cause::ScaleFactor,
    Cause::CrossAxis,
    Cause::GSensitivity,
    Cause::AngularAcceleration,
    Cause::Jerk,
    Cause::BiasShift,
];

impl<'a> FittedTerms<'a> {
    /// The terms `found` on `channel`, whose error (as the joint calibration leaves it) is
    /// the one series of the bank `e`. A term whose final interval (widened by the time offset's uncertainty where it
    /// rides on the channel's own derivative) no longer excludes zero at the run's per-test
    /// level is dropped: a finding means its effect is there.
    pub fn new(
        run: &Run,
        channel: Channel,
        found: ChannelTerms<'a>,
        e: &SeriesBank,
    ) -> Result<Self, DiagnoseError> {
        let n = run.n;
        let (var_e, e_sum) = with_bank_series(e, 0, |e| (series_variance(e), e.sum()))?;
        let offset_sigma_s = run
            .calibration
            .and_then(|c| c.time_offset_s)
            .map(|o| o.sigma);
        let (terms, coefficients): (Vec<Term>, Vec<Coefficient>) = found
            .terms
            .into_iter()
            .map(|t| {
                // A term on the channel's own derivative is measured on data shifted by the
                // common time offset, so that offset's uncertainty is part of the term's.
                let own_derivative = t.axis == channel.axis()
                    && match t.cause {
                        Cause::AngularAcceleration => channel.is_gyro(),
                        Cause::Jerk => !channel.is_gyro(),
                        _ => false,
                    };
                let se = match offset_sigma_s {
                    Some(sigma) if own_derivative => t.se.hypot(sigma),
                    _ => t.se,
                };
                let c = Coefficient {
                    value: t.coef,
                    ci95: ci(t.coef, se),
                    variance_explained: t.coef.powi(2) * t.own_variance / var_e,
                    p_value: t.fixed.unwrap_or_else(|| normal_p_value(t.coef / se)),
                };
                (t, c)
            })
            .filter(|(_, c)| c.p_value < run.alpha_test)
            .unzip();
        let intercept = e_sum / n as f64 - terms.iter().map(|t| t.coef * t.own_mean).sum::<f64>();
        let step_kept = terms.iter().any(|t| t.cause == Cause::BiasShift);
        let mut own = SeriesBank::columns(n, terms.len(), run.is_long())?;
        for epochs in block_ranges(0..n) {
            for (k, t) in terms.iter().enumerate() {
                own.write(k, epochs.start, &t.own_in(epochs.clone())?)?;
            }
        }
        Ok(Self {
            own,
            terms,
            coefficients,
            intercept,
            var_e,
            step_at_s: found.step_at_s.filter(|_| step_kept),
        })
    }

    /// `visit(epochs, owns)` for each block of `range` in order, `owns` being each kept
    /// term's regressor less what the calibration absorbs of it on the channel
    /// ([`Term::own_in`]) over the block, in [`FittedTerms::terms`] order.
    pub fn for_each_own_block(
        &self,
        range: std::ops::Range<usize>,
        visit: &mut BlockVisit<'_>,
    ) -> Result<(), DiagnoseError> {
        let all: Vec<usize> = (0..self.own.len()).collect();
        Ok(self.own.for_each_block_in(&all, range, visit)?)
    }

    /// The residual of the error `e` (the one series of a bank) over the run: less the
    /// terms' deterministic part and the intercept, made a block at a time into a bank of
    /// its own (spilled when `spill`).
    pub fn residual(&self, e: &SeriesBank, spill: bool) -> Result<SeriesBank, DiagnoseError> {
        let n = e.epochs();
        let mut resid = SeriesBank::columns(n, 1, spill)?;
        let mut r = Vec::with_capacity(BANK_BLOCK_EPOCHS);
        for epochs in block_ranges(0..n) {
            r.clear();
            r.resize(epochs.len(), 0.0);
            self.add_deterministic(&self.coefficients, epochs.clone(), 0.0, &mut r)?;
            let e = e.range(0, epochs.clone())?;
            r.iter_mut()
                .zip(e.iter())
                .for_each(|(r, e)| *r = e - self.intercept - *r);
            resid.write(0, epochs.start, &r)?;
        }
        Ok(resid)
    }

    /// `f` of the error `e` (the one series of a bank) less the deterministic part of
    /// `coefficients` over the epochs of `ranges`, joined in order, a block at a time at
    /// each reading: a training set's residual, or a test set's, without holding it.
    pub fn with_residual<T>(
        &self,
        coefficients: &[Coefficient],
        e: &SeriesBank,
        ranges: &[std::ops::Range<usize>],
        f: impl FnOnce(&Series) -> T,
    ) -> Result<T, DiagnoseError> {
        let draw = |visit: &mut dyn FnMut(&[f64])| -> Result<(), DiagnoseError> {
            // One block's buffer for every block: this runs per fold and per trial.
            let mut left = Vec::with_capacity(BANK_BLOCK_EPOCHS);
            for range in ranges {
                for epochs in block_ranges(range.clone()) {
                    left.clear();
                    left.resize(epochs.len(), 0.0);
                    self.add_deterministic(coefficients, epochs.clone(), 0.0, &mut left)?;
                    let e = e.range(0, epochs)?;
                    left.iter_mut().zip(e.iter()).for_each(|(d, a)| *d = a - *d);
                    visit(&left);
                }
            }
            Ok(())
        };
        let len = ranges.iter().map(|r| r.len()).sum();
        drawn_from(len, &draw, f)
    }

    /// Adds the deterministic part of the error over `range` with these `coefficients` (one
    /// per term, or none: the sum of each term's regressor times its coefficient) and
    /// `intercept` to `x`, a series over `range`, a block at a time.
    pub fn add_deterministic(
        &self,
        coefficients: &[Coefficient],
        range: std::ops::Range<usize>,
        intercept: f64,
        x: &mut [f64],
    ) -> Result<(), DiagnoseError> {
        self.each_deterministic(coefficients, range, &mut |k, d| x[k] += d + intercept)
    }

    /// `visit(k, d)` with the deterministic part `d` at each epoch of `range`, `k` counted
    /// from its start.
    fn each_deterministic(
        &self,
        coefficients: &[Coefficient],
        range: std::ops::Range<usize>,
        visit: &mut dyn FnMut(usize, f64),
    ) -> Result<(), DiagnoseError> {
        let first = range.start;
        self.for_each_own_block(range, &mut |block, own| {
            for t in 0..block.len() {
                let d = coefficients
                    .iter()
                    .zip(own)
                    .map(|(c, own)| c.value * own[t])
                    .sum::<f64>();
                visit(block.start - first + t, d);
            }
        })
    }

    /// One finding per cause with kept terms on `channel`, its p-value the largest of its
    /// terms' (each named term is significant), family-wise.
    pub fn findings(&self, run: &Run, channel: Channel) -> Vec<Finding> {
        let mut findings = Vec::new();
        for cause in TERM_CAUSES {
            let kept: Vec<(&Coefficient, &Term)> = self
                .coefficients
                .iter()
                .zip(&self.terms)
                .filter(|(_, t)| t.cause == cause)
                .collect();
            if kept.is_empty() {
                continue;
            }
            let single = kept.len() == 1;
            findings.push(Finding {
                channel,
                cause,
                regressors: kept.iter().map(|(_, t)| t.name.clone()).collect(),
                estimate: if single {
                    json!(kept[0].0.value)
                } else {
                    json!(kept.iter().map(|(c, _)| c.value).collect::<Vec<_>>())
                },
                ci95: if single {
                    json!(kept[0].0.ci95)
                } else {
                    json!(kept.iter().map(|(c, _)| c.ci95).collect::<Vec<_>>())
                },
                variance_explained: kept.iter().map(|(c, _)| c.variance_explained).sum(),
                p_value: Some(
                    run.family_p(kept.iter().map(|(c, _)| c.p_value).fold(0.0, f64::max)),
                ),
            });
        }
        findings
    }

    /// What the calibration took from these terms, to correct its estimates.
    pub fn absorbed_by(&self, design: DesignRows<'_>) -> nalgebra::DVector<f64> {
        let mut total = nalgebra::DVector::<f64>::zeros(design.parameters());
        for (c, t) in self.coefficients.iter().zip(&self.terms) {
            total += &t.projection.absorbed * c.value;
        }
        total
    }
}
