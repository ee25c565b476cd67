//! `dynacal info FILE`: what an interchange file holds, a quick check that it reads.

use std::path::PathBuf;

use dynacal::interchange::ImuRecording;

#[derive(Debug, clap::Args)]
pub struct Args {
    /// Interchange CSV or CSV.gz.
    pub file: PathBuf,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let rec = ImuRecording::read(&args.file)?;
    let dt = rec.median_dt_s();
    let stated = match rec.sample_rate_hz {
        Some(rate) => format!("stated rate {rate} Hz, "),
        None => String::new(),
    };
    println!(
        "{}: {} samples, {:.3} s, {stated}median rate {:.3} Hz, channels [{}]",
        args.file.display(),
        rec.len(),
        rec.t_s[rec.len() - 1] - rec.t_s[0],
        if dt > 0.0 { 1.0 / dt } else { 0.0 },
        rec.channels().join(" ")
    );
    Ok(())
}
