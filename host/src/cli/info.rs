//! `dynacal info FILE`: what an interchange file holds, a quick check that it reads. A file
//! over 256 MiB is streamed ([`dynacal::interchange::summary`]): a recording of any length
//! in about 20 MiB.

use std::path::PathBuf;

use dynacal::interchange::summary::summarise;

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Interchange CSV, CSV.gz or Parquet.
    pub file: PathBuf,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let summary = summarise(&args.file)?;
    let stated = match summary.stated_rate_hz {
        Some(rate) => format!("stated rate {rate} Hz, "),
        None => String::new(),
    };
    let median_rate_hz = summary
        .median_step_s
        .filter(|step| *step > 0.0)
        .map_or(0.0, |step| 1.0 / step);
    println!(
        "{}: {} samples, {:.3} s, {stated}median rate {median_rate_hz:.3} Hz, channels [{}]",
        args.file.display(),
        summary.samples,
        summary.span_t_s.1 - summary.span_t_s.0,
        summary.channels.join(" ")
    );
    Ok(())
}
