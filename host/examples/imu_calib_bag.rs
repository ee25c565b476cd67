//! The `imu-calib` pipeline from a ROS2 MCAP bag to Kalibr's four numbers, the peer of
//! `dynacal noise BAG --topic T --kalibr imu.yaml` for speed and memory (host/tests/cli_noise.rs,
//! ignored; BENCHMARKS.md, "Against the peers"): the bag's messages streamed by the `mcap`
//! crate from a mapped file (as dynacal maps it), each Imu decoded and pushed into
//! `imu-calib`'s streaming `AllanEstimator`, its slope fits read at the end.
//!
//! Usage: cargo run --release -p dynacal --example imu_calib_bag -- BAG.mcap TOPIC

use dynacal::import::ros_bag::messages::{imu, Encoding};
use imu_calib::allan::{AllanConfig, AllanEstimator};

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let (path, topic) = (&args[1], &args[2]);
    let file = std::fs::File::open(path)?;
    // SAFETY: a read-only map of a bag nothing writes while it is read.
    let bytes = unsafe { memmap2::Mmap::map(&file)? };
    let mut estimator = AllanEstimator::new(AllanConfig::default());
    let mut since_release = 0usize;
    for message in mcap::MessageStream::new(&bytes)? {
        let message = message?;
        // The bag's pages read so far leave the resident set, as dynacal's reader does, so
        // the peak memory compares the pipelines, not the page cache.
        since_release += message.data.len() + 32;
        if since_release >= 64 << 20 {
            since_release = 0;
            // SAFETY: a read-only map of a file nothing writes: dropped pages read back
            // the same bytes.
            let _ = unsafe { bytes.unchecked_advise(memmap2::UncheckedAdvice::DontNeed) };
        }
        if message.channel.topic != *topic {
            continue;
        }
        let m = imu(&message.data, Encoding::Cdr).map_err(|e| anyhow::anyhow!("{e}"))?;
        let t = m.header.stamp_ns as f64 * 1e-9;
        estimator.push(t, m.linear_acceleration, m.angular_velocity);
    }
    let noise = estimator.finish()?.noise()?;
    println!(
        "accelerometer_noise_density: {:e}\naccelerometer_random_walk: {:e}\ngyroscope_noise_density: {:e}\ngyroscope_random_walk: {:e}",
        noise.accel_noise_density, noise.accel_random_walk, noise.gyro_noise_density, noise.gyro_random_walk
    );
    Ok(())
}
