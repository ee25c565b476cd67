//! ROS bags in: the bags `tests/ros/make.py` wrote with the `rosbags` package (ROS1
//! uncompressed, bz2 and LZ4; ROS2 MCAP and SQLite, with rosbag2's per-message and per-file
//! zstd), bags the `mcap` crate's writer writes here (chunks uncompressed, zstd, LZ4), and
//! the shared real bags against the figures `rosbags` read from them
//! (`tests/ros/real-bags.json`). Every value of the written bags is an exact binary fraction,
//! so the imported files are checked to the bit; damaged bags must fail naming the file and
//! the place.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use dynacal::import::ros_bag;
use dynacal::import::{find_datasets, import_to_dir, Dataset};
use dynacal::interchange::{FileFormat, ImuRecording};

const T0: i128 = 1_700_000_000;
const NS: i128 = 1_000_000_000;

fn fixture(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("ros").join(name)
}

/// The bags `make.py` wrote, each as a user would name it (a ROS2 bag by its folder).
const WRITTEN: [&str; 7] = [
    "ros1-plain.bag",
    "ros1-bz2.bag",
    "ros1-lz4.bag",
    "ros2-mcap",
    "ros2-sqlite3",
    "ros2-mcap-zstd-message",
    "ros2-sqlite3-zstd-file",
];

/// The storage file of a bag path (a ROS2 folder holds one).
fn storage_file(path: &Path) -> PathBuf {
    if path.is_dir() {
        let (found, _) = find_datasets(path).unwrap();
        assert_eq!(found.len(), 1, "{}", path.display());
        assert_eq!(found[0].1, Dataset::RosBag);
        found[0].0.clone()
    } else {
        path.to_path_buf()
    }
}

fn read(path: &Path) -> (BTreeMap<String, ImuRecording>, Vec<String>) {
    let (recordings, report) = ros_bag::read(&storage_file(path)).unwrap();
    (recordings.into_iter().collect(), report.notes)
}

/// The time of `ns` since the Unix epoch as the importer states it.
fn seconds(ns: i128) -> f64 {
    (ns / NS) as f64 + (ns % NS) as f64 * 1e-9
}

fn grid_ns(k: i128, hz: i128) -> i128 {
    T0 * NS + k * NS / hz
}

#[test]
fn every_storage_and_compression_reads_the_written_values_exactly() {
    for bag in WRITTEN {
        let (recordings, notes) = read(&fixture(bag));
        let names: Vec<&str> = recordings.keys().map(String::as_str).collect();
        assert_eq!(names, ["gps-fix", "imu-data", "imu-messy", "odom"], "{bag}");

        let imu = &recordings["imu-data"];
        assert_eq!(imu.len(), 64, "{bag}");
        let gyro = imu.gyro_rad_s.as_ref().unwrap();
        let accel = imu.accel_m_s2.as_ref().unwrap();
        for k in 0..64usize {
            assert_eq!(imu.t_s[k], seconds(grid_ns(k as i128, 128)), "{bag} t {k}");
            let g = |m: usize| ((k * m % 17) as f64 - 8.0) / 1024.0;
            // Forward-left-up -> forward-right-down: y and z negated.
            assert_eq!(
                [gyro[0][k], gyro[1][k], gyro[2][k]],
                [g(3), -g(5), -g(7)],
                "{bag}"
            );
            let a0 = ((k * 11 % 17) as f64 - 8.0) / 256.0;
            assert_eq!([accel[0][k], accel[1][k], accel[2][k]], [a0, -0.0, -9.8125]);
        }

        let fix = &recordings["gps-fix"];
        let kept = [0usize, 1, 2, 4];
        assert_eq!(fix.len(), 4, "{bag}: the fix with status -1 is left out");
        let [lat, lon, h] = fix.position.as_ref().unwrap();
        for (i, &k) in kept.iter().enumerate() {
            assert_eq!(fix.t_s[i], seconds(grid_ns(k as i128, 1)));
            assert_eq!(lat[i], (46.5 + k as f64 / 1024.0).to_radians());
            assert_eq!(lon[i], (6.5 - k as f64 / 2048.0).to_radians());
            assert_eq!(h[i], 400.0 + k as f64);
        }
        assert!(notes
            .iter()
            .any(|n| n == "/gps/fix: 1 messages without a fix (status -1) left out"));
        assert!(notes
            .iter()
            .any(|n| n.starts_with("/odom_imu/imu: skipped, not a sensor")));
        odometry_turned_into_ned(bag, &recordings["odom"]);
        messy_stamps_reported(bag, &recordings["imu-messy"], &notes);
    }
}

/// Yaw k/8 about up from east is heading pi/2 - k/8 from north; the forward-left-up body
/// velocity (k + 1, 0.5, -0.25) turned by it, then east-north-up -> north-east-down.
fn odometry_turned_into_ned(bag: &str, odom: &ImuRecording) {
    assert_eq!(odom.len(), 5);
    let [roll, pitch, yaw] = odom.attitude_rad.as_ref().unwrap();
    let [vn, ve, vd] = odom.velocity_ned_m_s.as_ref().unwrap();
    for k in 0..5 {
        let psi = k as f64 / 8.0;
        assert_eq!(odom.t_s[k], seconds(grid_ns(k as i128, 4)));
        assert!(roll[k].abs() < 1e-12 && pitch[k].abs() < 1e-12, "{bag}");
        assert!(
            (yaw[k] - (std::f64::consts::FRAC_PI_2 - psi)).abs() < 1e-12,
            "{bag} yaw {k}"
        );
        let (fwd, left) = (k as f64 + 1.0, 0.5);
        let east = fwd * psi.cos() - left * psi.sin();
        let north = fwd * psi.sin() + left * psi.cos();
        assert!(
            (vn[k] - north).abs() < 1e-12 && (ve[k] - east).abs() < 1e-12,
            "{bag}"
        );
        assert!((vd[k] - 0.25).abs() < 1e-12, "{bag}");
    }
}

/// Message 10 repeats message 9's stamp, 20 goes back, 30's stamp is zero.
fn messy_stamps_reported(bag: &str, messy: &ImuRecording, notes: &[String]) {
    let kept: Vec<i128> = (0..40).filter(|k| *k != 10 && *k != 20).collect();
    assert_eq!(messy.len(), kept.len(), "{bag}");
    for (i, &k) in kept.iter().enumerate() {
        let ns = match k {
            30 => grid_ns(30, 128) + NS / 1024, // the receive time
            k => grid_ns(k, 128),
        };
        assert_eq!(messy.t_s[i], seconds(ns), "{bag} messy {k}");
        assert_eq!(messy.gyro_rad_s.as_ref().unwrap()[0][i], k as f64 / 512.0);
    }
    for expected in [
        "/imu/messy: 1 header stamps are zero: the bag's receive time is used for them (the first at 1700000000.235351562 s)",
        "/imu/messy: 1 stamps repeat the previous message's (the first at 1700000000.070312500 s)",
        "/imu/messy: 1 stamps go back from the previous message's (the first to 1700000000.144531250 s after 1700000000.148437500 s)",
        "/imu/messy: 2 messages whose stamp is not after every earlier one are left out (an interchange file's time increases strictly)",
        "/imu/messy: angular_velocity_covariance: zero (unknown) on 40 of 40 messages",
    ] {
        assert!(notes.iter().any(|n| n == expected), "{bag}: no `{expected}` in {notes:#?}");
    }
    assert!(notes.iter().any(|n| n.starts_with(
        "/imu/data: angular_velocity_covariance: set on 64 (constant: first diagonal 9.537e-7"
    )));
}

#[test]
fn every_written_bag_imports_to_the_same_files() {
    let mut first: Option<BTreeMap<String, Vec<u8>>> = None;
    for bag in WRITTEN {
        let out = tempfile::tempdir().unwrap();
        let dir = out.path().join("imported");
        let report = import_to_dir(&fixture(bag), &dir, FileFormat::Csv).unwrap();
        assert_eq!(report.written.len(), 4, "{bag}");
        let files: BTreeMap<String, Vec<u8>> = std::fs::read_dir(&dir)
            .unwrap()
            .map(|e| {
                let path = e.unwrap().path();
                let name = path.file_name().unwrap().to_string_lossy().into_owned();
                (name, std::fs::read(&path).unwrap())
            })
            .collect();
        match &first {
            None => first = Some(files),
            Some(first) => assert_eq!(&files, first, "{bag} differs from {}", WRITTEN[0]),
        }
    }
}

/// The messages of the rosbags-written MCAP bag, written again by the `mcap` crate with
/// each chunk compression (and without chunks' compression), read back identically.
#[test]
fn mcap_chunks_uncompressed_zstd_and_lz4_read_back_exactly() {
    let source = storage_file(&fixture("ros2-mcap"));
    let bytes = std::fs::read(&source).unwrap();
    let (reference, _) = read(&fixture("ros2-mcap"));
    for compression in [
        None,
        Some(mcap::Compression::Zstd),
        Some(mcap::Compression::Lz4),
    ] {
        let out = tempfile::tempdir().unwrap();
        let path = out.path().join("rewritten.mcap");
        let file = std::io::BufWriter::new(std::fs::File::create(&path).unwrap());
        let mut writer = mcap::WriteOptions::new()
            .compression(compression)
            .chunk_size(Some(4096))
            .profile("ros2")
            .create(file)
            .unwrap();
        let mut channels = BTreeMap::new();
        for (sequence, message) in mcap::MessageStream::new(&bytes).unwrap().enumerate() {
            let message = message.unwrap();
            let channel = &message.channel;
            let id = *channels.entry(channel.id).or_insert_with(|| {
                let schema = channel.schema.as_ref().unwrap();
                let schema_id = writer
                    .add_schema(&schema.name, &schema.encoding, &schema.data)
                    .unwrap();
                writer
                    .add_channel(schema_id, &channel.topic, "cdr", &BTreeMap::new())
                    .unwrap()
            });
            let header = mcap::records::MessageHeader {
                channel_id: id,
                sequence: sequence as u32,
                log_time: message.log_time,
                publish_time: message.publish_time,
            };
            writer
                .write_to_known_channel(&header, &message.data)
                .unwrap();
        }
        writer.finish().unwrap();
        drop(writer);
        let (recordings, _) = read(&path);
        assert_eq!(recordings, reference, "{compression:?}");
    }
}

fn real_bag(name: &str) -> Option<PathBuf> {
    let path = dynacal_tests::data_dir().join("ros-bags").join(name);
    if path.exists() {
        Some(path)
    } else {
        eprintln!("SKIP: {} not found (set DYNACAL_DATA)", path.display());
        None
    }
}

fn mean_std(x: &[f64]) -> (f64, f64) {
    let n = x.len() as f64;
    let mean = x.iter().sum::<f64>() / n;
    let var = x.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1.0);
    (mean, var.sqrt())
}

/// The shared bags against what the `rosbags` package read from them: topics, counts,
/// stamps, frames, and each Imu axis' mean and standard deviation (ROS axes there, ours
/// here: y and z negated); the ROS1 bag and its MCAP conversion give identical files.
#[test]
fn shared_real_bags_match_the_rosbags_package() {
    let figures: serde_json::Value =
        serde_json::from_slice(&std::fs::read(fixture("real-bags.json")).unwrap()).unwrap();
    let mut imported = Vec::new();
    for name in ["xsens-test1.bag", "xsens-test1-mcap"] {
        let Some(path) = real_bag(name) else { return };
        let (recordings, notes) = read(&path);
        let topics = figures[name].as_object().unwrap();
        for (topic, fig) in topics {
            let count = fig["count"].as_u64().unwrap() as usize;
            let file = topic.trim_start_matches('/').replace('/', "-");
            match (fig["type"].as_str().unwrap(), recordings.get(&file)) {
                ("sensor_msgs/msg/Imu", Some(rec)) => {
                    imu_matches(name, topic, fig, rec);
                    let frames: Vec<&str> = fig["frames"]
                        .as_array()
                        .unwrap()
                        .iter()
                        .map(|f| f.as_str().unwrap())
                        .collect();
                    let expected = format!("{topic}: frame_id {}:", frames.join(", "));
                    assert!(
                        notes.iter().any(|n| n.starts_with(&expected)),
                        "{name}: {expected}"
                    );
                }
                ("sensor_msgs/msg/Imu", None) => {
                    // The odometry-derived topic: skipped, its stamps reported as rosbags counts them.
                    let repeated = fig["repeated"].as_u64().unwrap();
                    let back = fig["back"].as_u64().unwrap();
                    for expected in [
                        format!("{topic}: skipped, not a sensor"),
                        format!("{topic}: {repeated} stamps repeat the previous message's"),
                        format!("{topic}: {back} stamps go back from the previous message's"),
                    ] {
                        assert!(
                            notes.iter().any(|n| n.starts_with(&expected)),
                            "{name}: {expected}"
                        );
                    }
                }
                ("nav_msgs/msg/Odometry", Some(rec)) => {
                    assert_eq!(rec.len(), count, "{name} {topic}")
                }
                (other, rec) => panic!("{name} {topic}: {other} imported as {rec:?}"),
            }
        }
        imported.push(recordings);
    }
    assert_eq!(
        imported[0], imported[1],
        "the ROS1 bag and its MCAP conversion differ"
    );
}

fn imu_matches(name: &str, topic: &str, fig: &serde_json::Value, rec: &ImuRecording) {
    assert_eq!(
        rec.len(),
        fig["count"].as_u64().unwrap() as usize,
        "{name} {topic}"
    );
    let stamp = |key: &str| seconds(fig[key].as_u64().unwrap() as i128);
    assert_eq!(rec.t_s[0], stamp("first_stamp_ns"), "{name} {topic}");
    assert_eq!(
        *rec.t_s.last().unwrap(),
        stamp("last_stamp_ns"),
        "{name} {topic}"
    );
    for (triplet, key) in [(&rec.gyro_rad_s, "gyro"), (&rec.accel_m_s2, "accel")] {
        let triplet = triplet.as_ref().unwrap();
        for axis in 0..3 {
            let sign = if axis == 0 { 1.0 } else { -1.0 };
            let (mean, std) = mean_std(&triplet[axis]);
            let want_mean = sign * fig[format!("{key}_mean")][axis].as_f64().unwrap();
            let want_std = fig[format!("{key}_std")][axis].as_f64().unwrap();
            assert!(
                (mean - want_mean).abs() <= 1e-12 * want_mean.abs().max(1.0),
                "{name} {topic} {key} {axis}: {mean} vs {want_mean}"
            );
            assert!(
                (std - want_std).abs() <= 1e-9 * want_std,
                "{name} {topic} {key} {axis}: {std} vs {want_std}"
            );
        }
    }
    // Gravity on -z of the forward-right-down axes: the Xsens sits level, z up in ROS.
    let (az, _) = mean_std(&rec.accel_m_s2.as_ref().unwrap()[2]);
    assert!((az + 9.81).abs() < 0.05, "{name} {topic}: mean az {az}");
}

/// Asking one topic decodes it alone: the others are counted and named, not kept.
#[test]
fn one_topic_asked_is_the_only_one_decoded() {
    let path = storage_file(&fixture("ros2-mcap"));
    let (all, _) = ros_bag::read(&path).unwrap();
    for asked in ["/imu/data", "imu-data"] {
        let (recordings, report) = ros_bag::read_only(&path, Some(asked)).unwrap();
        assert_eq!(recordings.len(), 1, "{asked}");
        assert_eq!(
            recordings[0],
            all.iter().find(|r| r.0 == "imu-data").unwrap().clone()
        );
        assert!(report.notes.iter().any(|n| {
            n == "/gps/fix: 5 messages of sensor_msgs/NavSatFix, not read (only imu-data was asked)"
        }));
    }
}

/// A bag is read in two passes, its time lines summarised as they come: every recording's
/// sampling note (median, spread, gaps) is the one its whole time line gives
/// (`Sampling::of`), on the written bags and the shared real ones (whose stamps jitter and
/// pause).
#[test]
fn a_bag_read_in_two_passes_describes_each_time_line_as_held_whole() {
    let mut bags: Vec<PathBuf> = WRITTEN.iter().map(|b| fixture(b)).collect();
    for real in ["ros-bags/xsens-test1.bag", "ros-bags/xsens-test1-mcap"] {
        let path = dynacal::data_dir().join(real);
        match path.exists() {
            true => bags.push(path),
            false => eprintln!("SKIP: {} not found (set DYNACAL_DATA)", path.display()),
        }
    }
    let mut gaps = 0;
    for bag in bags {
        let (recordings, notes) = read(&bag);
        assert!(!recordings.is_empty(), "{}", bag.display());
        for (name, rec) in &recordings {
            let sampling = dynacal::interchange::Sampling::of(&rec.t_s).unwrap();
            gaps += sampling.gaps.len();
            let whole = format!(": {sampling}");
            assert!(
                notes.iter().any(|n| n.ends_with(&whole)
                    && ros_bag::file_name_of_topic(n.split(": ").next().unwrap()) == *name),
                "{}: {name}: no `{whole}` in {notes:#?}",
                bag.display()
            );
        }
    }
    assert!(gaps > 0, "no bag has a gap: the gaps were not tried");
}
