//! Times reading an interchange file whole (`ImuRecording::read`, the fast path first) and
//! with the `csv` crate alone (`read_table_by_rows`; `null` for a Parquet file), for `bench/ingest_bench.py`. Prints one
//! JSON line: the minimum over the repeats of each, s. With `BENCH_READ_FAST_ONLY` set it
//! times `read_table` alone (for a profiler).
//!
//! `cargo run --release --example bench_read -- FILE [REPEATS]`

use std::time::Instant;

use dynacal::interchange::{read_table_by_rows, ImuRecording};

fn main() {
    let mut args = std::env::args().skip(1);
    let path = std::path::PathBuf::from(args.next().expect("usage: bench_read FILE [REPEATS]"));
    let repeats: usize = args.next().map_or(3, |r| r.parse().expect("REPEATS"));
    let best = |f: &dyn Fn() -> usize| {
        (0..repeats)
            .map(|_| {
                let start = Instant::now();
                let rows = f();
                (start.elapsed().as_secs_f64(), rows)
            })
            .fold((f64::INFINITY, 0), |a, b| if b.0 < a.0 { b } else { a })
    };
    if std::env::var_os("BENCH_READ_FAST_ONLY").is_some() {
        let (s, _) = best(&|| {
            dynacal::interchange::read_table(&path, None)
                .expect("read")
                .rows()
        });
        eprintln!("read_table alone: {s} s");
        return;
    }
    let (read_s, rows) = best(&|| ImuRecording::read(&path).expect("read").len());
    // The `csv` crate has no Parquet to read.
    let by_rows_s = (!dynacal::interchange::parquet::is_parquet(&path))
        .then(|| best(&|| read_table_by_rows(&path, None).expect("read").rows()).0);
    let (table_s, _) = best(&|| {
        dynacal::interchange::read_table(&path, None)
            .expect("read")
            .rows()
    });
    eprintln!("read_table alone: {table_s} s");
    println!(
        "{{\"rows\": {rows}, \"read_s\": {read_s}, \"csv_crate_s\": {}, \"threads\": {}}}",
        by_rows_s.map_or("null".to_string(), |s| s.to_string()),
        rayon::current_num_threads()
    );
}
