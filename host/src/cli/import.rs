//! `dynacal import PATH --out DIR [--format csv|csv-gz|parquet]`: convert a measured dataset (file or folder) into
//! interchange files, one per sensor, written all together or not at all.

use std::path::PathBuf;

use dynacal::import::import_to_dir;
use dynacal::interchange::FileFormat;

#[derive(Debug, clap::Args)]
pub struct Args {
    /// A dataset file, or a folder searched (with its subfolders) for dataset files.
    pub path: PathBuf,
    /// Folder for the interchange files (`<sensor>.csv.gz`, or the `--format`'s ending);
    /// created if needed.
    #[arg(long)]
    pub out: PathBuf,
    /// The files' form: CSV text, gzip-compressed CSV, or Parquet (binary columns, about ten
    /// times faster to read).
    #[arg(long, value_enum, default_value_t = FileFormat::CsvGz)]
    pub format: FileFormat,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let report = import_to_dir(&args.path, &args.out, args.format)?;
    for w in &report.written {
        let left_out = match w.left_out.as_slice() {
            [] => String::new(),
            columns => format!("; not carried: {}", columns.join(", ")),
        };
        println!(
            "{}: {} samples, {:.3} s, [{}] <- {} ({}{left_out})",
            w.path.display(),
            w.samples,
            w.duration_s,
            w.contents.join(" "),
            w.source.display(),
            w.dataset.describe()
        );
    }
    for (source, note) in &report.notes {
        println!("{}: {note}", source.display());
    }
    for s in &report.skipped {
        println!("skipped {} (not a dataset)", s.display());
    }
    println!(
        "wrote {} interchange files to {}",
        report.written.len(),
        args.out.display()
    );
    Ok(())
}
