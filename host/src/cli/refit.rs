//! `dynacal refit LOG --out DIR`: the board log's units refitted (`dynacal::refit`): their
//! own error models and alignment, written as `model.json` (the typed model, loadable by
//! `dynacal simulate`), `board-model.bin` (what the board runs: `dynacal board --model`, or
//! flashed into the board's model sector) and `refit.json` (the check of the board's
//! wavelet variances, each fit with its intervals, the alignments, notes). All three are
//! written whole or none, `refit.json` last as the set's completion marker.

use std::path::PathBuf;

use anyhow::Context;
use dynacal::decode::decode_file;
use dynacal::gmwm::inference::BootstrapOptions;
use dynacal::input::stream::StreamMode;
use dynacal::output::{write_atomic, write_json_atomic, FileSet};
use dynacal::refit::{refit, refit_file, typed_model, RefitOptions};
use dynacal_core::board_model::MAX_BOARD_MODEL_LEN;

use super::fit::model_choice;

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Board log (three IMUs or more, as the board writes it).
    pub log: PathBuf,
    /// Output folder (created if absent).
    #[arg(long)]
    pub out: PathBuf,
    /// Model of each channel's error, e.g. "WN+GM", or "auto" (chosen by WIC).
    #[arg(long, default_value = "auto")]
    pub model: String,
    /// Replicates of the intervals' parametric bootstrap of the units' N-cornered hat
    /// (0: the delta method, whose intervals are too narrow for a hat's variances: 86% of
    /// the truth inside the 95% intervals against 96% with the bootstrap, BENCHMARKS.md).
    #[arg(long, default_value_t = 200)]
    pub bootstrap: usize,
    /// Seed of the bootstrap.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Decode the log into spill files and read the units stretch by stretch instead of
    /// holding its samples (memory that does not grow with the log): `auto` for logs over
    /// 64 MiB (about 40 minutes of three 1 kHz IMUs, which held take about 1 GB).
    #[arg(long, value_enum, default_value_t = StreamMode::Auto)]
    pub stream: StreamMode,
    /// Shared times a stretch holds when streamed (tests cut a short log into several).
    #[arg(long, hide = true, default_value_t = dynacal::redundancy::STRETCH_EPOCHS)]
    pub stretch_epochs: usize,
}

/// Size of a log above which `--stream auto` streams it.
const STREAM_LOG_BYTES: u64 = 64 << 20;

pub fn run(args: Args) -> anyhow::Result<()> {
    let streamed = match args.stream {
        StreamMode::Always => true,
        StreamMode::Never => false,
        StreamMode::Auto => std::fs::metadata(&args.log).is_ok_and(|m| m.len() > STREAM_LOG_BYTES),
    };
    let options = RefitOptions {
        choice: model_choice(&args.model)?,
        bootstrap: (args.bootstrap > 0).then_some(BootstrapOptions {
            replicates: args.bootstrap,
            seed: args.seed,
        }),
    };
    let result = if streamed {
        super::map_long_series_alone();
        let bar = super::working(&format!(
            "refitting {} stretch by stretch",
            args.log.display()
        ));
        let result = refit_file(&args.log, &options, args.stretch_epochs.max(1024));
        bar.finish_and_clear();
        result.with_context(|| format!("{}", args.log.display()))
    } else {
        let log = decode_file(&args.log)?;
        log.validate(&args.log)?;
        let bar = super::working(&format!("refitting {}", args.log.display()));
        let result = refit(&log, &options).with_context(|| format!("{}", args.log.display()));
        bar.finish_and_clear();
        result
    };
    let result = result?;
    let mut blob = [0u8; MAX_BOARD_MODEL_LEN];
    let len = result
        .board_model
        .encode(&mut blob)
        .map_err(|e| anyhow::anyhow!("the refitted board model does not encode: {e}"))?;

    // refit.json last: the completion marker of the folder's set (`dynacal::output::FileSet`).
    let mut set = FileSet::create(&args.out, Some("refit.json"))
        .with_context(|| format!("{}: cannot create output folder", args.out.display()))?;
    let cannot = |name: &str| format!("{}: cannot write", args.out.join(name).display());
    write_json_atomic(&set.path("model.json"), &typed_model(&result))
        .with_context(|| cannot("model.json"))?;
    write_atomic(&set.path("board-model.bin"), &blob[..len])
        .with_context(|| cannot("board-model.bin"))?;
    write_json_atomic(&set.path("refit.json"), &result).with_context(|| cannot("refit.json"))?;
    set.commit().context("moving the outputs into place")?;

    let checked = result.agreement.len();
    println!(
        "{}: {} units refitted; board wavelet variances checked on {checked} channels{}",
        args.log.display(),
        result.units.len(),
        if checked > 0 { ", all agree" } else { "" }
    );
    for (unit, model) in result.units.iter().zip(&result.board_model.units) {
        let a = &unit.alignment;
        println!(
            "  {}: rotation {} deg, lever arm {} m",
            unit.name,
            a.rotation_rpy_deg
                .map_or("not determined".into(), |r| format!(
                    "{:.3} {:.3} {:.3}",
                    r[0], r[1], r[2]
                )),
            a.lever_arm_m.map_or("not determined".into(), |r| format!(
                "{:.4} {:.4} {:.4}",
                r[0], r[1], r[2]
            ))
        );
        for (fit, noise) in unit.fits.iter().zip(&model.channels) {
            println!(
                "    {:<9} {:<10} white {:.3e} unit^2 s, Gauss-Markov {:.3e} unit^2 tau {:.0} s, walk {:.3e} unit^2/s",
                fit.channel, fit.model, noise.white_psd, noise.gauss_markov_sigma2, noise.gauss_markov_tau_s, noise.random_walk_psd
            );
        }
    }
    for note in &result.notes {
        println!("  note: {note}");
    }
    println!(
        "wrote model.json, board-model.bin ({len} bytes), refit.json to {}",
        args.out.display()
    );
    Ok(())
}
