//! The importers on the real datasets in the data folder: sample counts and durations, and
//! physical facts each converted recording must show (gravity, Earth rate, the MEMS gyro
//! tracking the FOG attitude, the ArduPilot and Xsens DOT gyros tracking their own attitude
//! outputs, the PX4 raw IMUs calibrating to the autopilot's own), which would fail on a wrong
//! scale, sign or axis. Malformed copies of real files give errors naming file and line (byte
//! offset for the binary logs). Every test skips with a message when its dataset is absent.

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};

use dynacal::import::{
    adis16405, ardupilot_dataflash, detect, frames, import_to_dir, mpu9250_tetra, mtig,
    psins_fog_mems, psins_lasergyro, px4_ulog, xsens_dot, Dataset,
};
use dynacal::interchange::{open_maybe_gz, FileFormat, ImuRecording};
use nalgebra::{Rotation3, Vector3};

/// WGS-84 Earth rotation rate, rad/s.
const EARTH_RATE_RAD_S: f64 = 7.292115e-5;
const DEG: f64 = std::f64::consts::PI / 180.0;

fn dataset(rel: &str) -> Option<PathBuf> {
    let path = dynacal_tests::data_dir().join(rel);
    if path.exists() {
        Some(path)
    } else {
        eprintln!("SKIP: {} not found (set DYNACAL_DATA)", path.display());
        None
    }
}

fn mean(x: &[f64]) -> f64 {
    x.iter().sum::<f64>() / x.len() as f64
}

/// Mean of the gyro (or accelerometer) triplet over samples `range`, as a vector.
fn mean_vec(t: &[Vec<f64>; 3], range: std::ops::Range<usize>) -> Vector3<f64> {
    Vector3::from_fn(|k, _| mean(&t[k][range.clone()]))
}

fn duration_s(rec: &ImuRecording) -> f64 {
    rec.t_s[rec.len() - 1] - rec.t_s[0]
}

#[test]
fn adis16405_sessions_have_one_million_samples_and_read_gravity() {
    let Some(dir) = dataset("adis16405") else {
        return;
    };
    for s in 1..=6 {
        let path = dir.join(format!("session{s}.csv.gz"));
        assert_eq!(detect(&path).unwrap(), Some(Dataset::Adis16405));
        let rec = adis16405::read(&path).unwrap();
        assert_eq!(rec.len(), 1_000_000);
        assert!((duration_s(&rec) - 9999.99).abs() < 1e-9);
        let accel = rec.accel_m_s2.as_ref().unwrap();
        let f = mean_vec(accel, 0..rec.len());
        println!(
            "session{s}: mean specific force {f:?} m/s^2, |f| = {:.4}",
            f.norm()
        );
        assert!(
            (f.norm() / 9.80665 - 1.0).abs() < 0.02,
            "session{s}: |f| = {}",
            f.norm()
        );
        // The sensor z axis points down: it reads -g.
        assert!(f[2] < -0.99 * f.norm());
    }
}

#[test]
fn mtig_imports_as_a_single_axis_gyro_with_outliers() {
    let Some(path) = dataset("mtig/gyro_x_contaminated.csv.gz") else {
        return;
    };
    let rec = mtig::read(&path).unwrap();
    assert_eq!(rec.len(), 500_000);
    assert!((duration_s(&rec) - 4999.99).abs() < 1e-9);
    assert_eq!(rec.channels(), vec!["gx"]);
    // The README's figure: 132 samples beyond 6 standard deviations from the mean.
    let gx = rec.channel("gx").unwrap();
    let m = mean(gx);
    let sd = (gx.iter().map(|v| (v - m).powi(2)).sum::<f64>() / gx.len() as f64).sqrt();
    let outliers = gx.iter().filter(|v| (*v - m).abs() > 6.0 * sd).count();
    println!("MTi-G gx: mean {m:.3e}, sd {sd:.4e} rad/s, {outliers} samples beyond 6 sd");
    assert_eq!(outliers, 132);
}

#[test]
fn psins_mems_reads_minus_g_on_the_down_axis_and_fog_speed_reaches_16_m_s() {
    let Some(dir) = dataset("psins-fog-mems") else {
        return;
    };
    let mems = psins_fog_mems::read_mems(&dir.join("mems_increments.csv.gz")).unwrap();
    let fog = psins_fog_mems::read_fog(&dir.join("fog_ins_reference.csv.gz")).unwrap();
    assert_eq!((mems.len(), fog.len()), (10_001, 1_000));
    assert!((duration_s(&mems) - 100.0).abs() < 1e-6);
    assert!((duration_s(&fog) - 99.9).abs() < 1e-6);

    // First 10 s: the FOG says the vehicle is nearly level (|roll|, |pitch| < 5 deg).
    let att = fog.attitude_rad.as_ref().unwrap();
    let first_10_s = fog.t_s.iter().take_while(|t| **t <= 10.0).count();
    for angle in &att[..2] {
        assert!(angle[..first_10_s].iter().all(|a| a.abs() < 5.0 * DEG));
    }
    let accel = mems.accel_m_s2.as_ref().unwrap();
    let f = mean_vec(accel, 0..1001);
    println!("PSINS MEMS mean specific force over the first 10 s (FRD): {f:?}");
    assert!((f[2] / -9.8 - 1.0).abs() < 0.015, "{f:?}");
    assert!(f[0].abs() < 0.5 && f[1].abs() < 0.5, "{f:?}");

    let v = fog.velocity_ned_m_s.as_ref().unwrap();
    let speed: Vec<f64> = (0..fog.len())
        .map(|i| (v[0][i].powi(2) + v[1][i].powi(2) + v[2][i].powi(2)).sqrt())
        .collect();
    let max_speed = speed.iter().cloned().fold(0.0, f64::max);
    println!("PSINS FOG max speed {max_speed:.3} m/s");
    assert!((15.5..16.5).contains(&max_speed));
    // Heading about north: the north velocity dominates and is positive.
    assert!(v[0].iter().zip(&v[1]).all(|(n, e)| *n > 5.0 * e.abs()));
}

/// Integrates `omega_b` (FRD, rad/s, one per MEMS sample) from the FOG attitude at the FOG's
/// first sample, and returns the largest roll, pitch, yaw differences (rad) from the FOG at
/// each FOG sample. Earth and transport rate are neglected (< 0.5 deg over 100 s).
fn max_attitude_error(
    mems: &ImuRecording,
    fog: &ImuRecording,
    omega_b: &[Vector3<f64>],
) -> [f64; 3] {
    let att = fog.attitude_rad.as_ref().unwrap();
    let c_of = |i: usize| Rotation3::from_euler_angles(att[0][i], att[1][i], att[2][i]);
    let mut c: Rotation3<f64> = c_of(0);
    let mut fog_i = 1;
    let mut worst = [0.0f64; 3];
    for (i, t) in mems.t_s.iter().enumerate() {
        if *t <= fog.t_s[0] + 1e-6 {
            continue;
        }
        c *= Rotation3::new(omega_b[i] * psins_fog_mems::MEMS_DT_S);
        if fog_i < fog.len() && (fog.t_s[fog_i] - t).abs() < 1e-6 {
            let got = frames::euler_zyx_from_c_b_to_n(c.matrix());
            let want = frames::euler_zyx_from_c_b_to_n(c_of(fog_i).matrix());
            for k in 0..3 {
                let d = (got[k] - want[k] + std::f64::consts::PI).rem_euclid(std::f64::consts::TAU)
                    - std::f64::consts::PI;
                worst[k] = worst[k].max(d.abs());
            }
            fog_i += 1;
        }
    }
    assert_eq!(fog_i, fog.len(), "every FOG epoch is compared");
    worst
}

#[test]
fn psins_mems_gyro_integrated_in_frd_tracks_the_fog_attitude_in_ned() {
    let Some(dir) = dataset("psins-fog-mems") else {
        return;
    };
    let mems = psins_fog_mems::read_mems(&dir.join("mems_increments.csv.gz")).unwrap();
    let fog = psins_fog_mems::read_fog(&dir.join("fog_ins_reference.csv.gz")).unwrap();
    let g = mems.gyro_rad_s.as_ref().unwrap();
    let omega: Vec<Vector3<f64>> = (0..mems.len())
        .map(|i| Vector3::new(g[0][i], g[1][i], g[2][i]))
        .collect();
    let att = fog.attitude_rad.as_ref().unwrap();
    let (lo, hi) = att[0]
        .iter()
        .fold((0.0f64, 0.0f64), |(l, h), r| (l.min(*r), h.max(*r)));
    println!("FOG roll spans {:.1} .. {:.1} deg", lo / DEG, hi / DEG);
    assert!(
        hi - lo > 60.0 * DEG,
        "the run rolls enough for the check to mean something"
    );

    let worst = max_attitude_error(&mems, &fog, &omega).map(|e| e / DEG);
    println!("MEMS-integrated vs FOG, max |error| roll, pitch, yaw: {worst:?} deg");
    // Gyro biases of the MEMS unit (about 0.06 deg/s on the pitch axis) and the unknown
    // mounting misalignment leave a few degrees over 100 s.
    assert!(
        worst[0] < 6.0 && worst[1] < 7.0 && worst[2] < 4.0,
        "{worst:?}"
    );

    // Control: with the source's right/forward axes left unswapped (a frame mistake), the
    // same integration is far off, so the check above can fail.
    let unswapped: Vec<Vector3<f64>> = omega
        .iter()
        .map(|w| Vector3::new(w[1], w[0], w[2]))
        .collect();
    let wrong = max_attitude_error(&mems, &fog, &unswapped).map(|e| e / DEG);
    println!("with right/forward unswapped: {wrong:?} deg");
    assert!(wrong[0] > 30.0, "{wrong:?}");
}

#[test]
fn lasergyro_senses_header_gravity_and_earth_rate_and_gyrocompasses_to_header_heading() {
    let Some(path) = dataset("psins-lasergyro/lasergyro.imu.gz") else {
        return;
    };
    assert_eq!(detect(&path).unwrap(), Some(Dataset::PsinsLaserGyro));
    let log = psins_lasergyro::read(&path).unwrap();
    let (h, rec) = (&log.header, &log.recording);
    assert_eq!(rec.len(), 184_718);
    assert!((duration_s(rec) - 1847.17).abs() < 1e-6);
    assert_eq!((h.dt_s, h.g_m_s2), (0.01, 9.780327));

    let f = mean_vec(rec.accel_m_s2.as_ref().unwrap(), 0..rec.len());
    let w = mean_vec(rec.gyro_rad_s.as_ref().unwrap(), 0..rec.len());
    println!(
        "laser gyro mean f {f:?} (|f| {:.5}), mean omega {w:?} (|w| {:.3} deg/h)",
        f.norm(),
        w.norm() / DEG * 3600.0
    );
    assert!((f.norm() / h.g_m_s2 - 1.0).abs() < 0.005);
    assert!(f[2] < -0.999 * f.norm(), "FRD: the down axis reads -g");
    assert!((w.norm() / EARTH_RATE_RAD_S - 1.0).abs() < 0.05);

    // Up component of Earth rate = Omega sin(lat); f points up at rest.
    let up = f.normalize();
    let lat = h.initial_lat_lon_rad_h_m[0];
    let omega_up = w.dot(&up);
    println!(
        "Earth rate up: measured {omega_up:.4e}, expected {:.4e} rad/s",
        EARTH_RATE_RAD_S * lat.sin()
    );
    assert!((omega_up / (EARTH_RATE_RAD_S * lat.sin()) - 1.0).abs() < 0.03);

    // Gyrocompass: the horizontal Earth rate points north; heading of the forward axis.
    let down = -up;
    let north = (w - down * w.dot(&down)).normalize();
    let east = down.cross(&north);
    let forward = Vector3::x();
    let heading = forward.dot(&east).atan2(forward.dot(&north));
    let header_heading = h.initial_attitude_ned_rad()[2];
    println!(
        "gyrocompass heading {:.2} deg, header (NED) {:.2} deg",
        heading / DEG,
        header_heading / DEG
    );
    assert!((heading - header_heading).abs() < 4.0 * DEG);
}

#[test]
fn mpu9250_imports_four_imus_and_imu0_reads_gravity_18_percent_low() {
    let Some(path) = dataset("mpu9250x4-tetra-static/static.csv.gz") else {
        return;
    };
    let recs = mpu9250_tetra::read(&path).unwrap();
    assert_eq!(recs.len(), 4);
    for (k, rec) in recs.iter().enumerate() {
        assert_eq!(rec.len(), 41_671);
        assert!((duration_s(rec) - 967.975).abs() < 1e-9);
        let f = mean_vec(rec.accel_m_s2.as_ref().unwrap(), 0..rec.len());
        let ratio = f.norm() / 9.81;
        println!(
            "imu{k}: |mean f| = {:.3} m/s^2 ({:.1}% of 9.81)",
            f.norm(),
            100.0 * ratio
        );
        if k == 0 {
            assert!((0.80..0.84).contains(&ratio), "imu0 {ratio}");
        } else {
            assert!((ratio - 1.0).abs() < 0.02, "imu{k} {ratio}");
        }
    }
}

/// The first `lines` lines of a real dataset file, decompressed.
fn head(path: &Path, lines: usize) -> Vec<String> {
    BufReader::new(open_maybe_gz(path).unwrap())
        .lines()
        .take(lines)
        .map(Result::unwrap)
        .collect()
}

#[test]
fn malformed_copies_of_real_files_fail_naming_file_and_line_and_write_nothing() {
    let Some(data) = dataset("") else { return };
    // (source file, copy name, 1-based line to spoil, how, expected message part)
    type Spoil = fn(&str) -> String;
    let cases: [(&str, &str, usize, Spoil, &str); 6] = [
        (
            "adis16405/session1.csv.gz",
            "session1.csv",
            30,
            |l| l.replacen(',', ",1.5", 1),
            "not an integer",
        ),
        (
            "mtig/gyro_x_contaminated.csv.gz",
            "gyro_x.csv",
            12,
            |_| "abc".into(),
            "gx_rad_s",
        ),
        (
            "psins-fog-mems/mems_increments.csv.gz",
            "mems.csv",
            20,
            |l| l.replacen(',', ",x", 1),
            "dtheta_x_rad",
        ),
        (
            "psins-fog-mems/fog_ins_reference.csv.gz",
            "fog.csv",
            9,
            |l| l.rsplit_once(',').unwrap().0.into(),
            "fields",
        ),
        (
            "psins-lasergyro/lasergyro.imu.gz",
            "laser.imu",
            10,
            |l| l.rsplit_once(' ').unwrap().0.into(),
            "5 fields",
        ),
        (
            "mpu9250x4-tetra-static/static.csv.gz",
            "static.csv",
            7,
            |l| {
                let mut fields: Vec<&str> = l.split(',').collect();
                fields[3] = "nan";
                fields.join(",")
            },
            "`imu0_gz_rad_s`: `nan` is not a finite number",
        ),
    ];
    let tmp = tempfile::tempdir().unwrap();
    for (source, name, line, spoil, what) in cases {
        let source = data.join(source);
        if !source.exists() {
            eprintln!("SKIP: {} not found", source.display());
            continue;
        }
        let mut lines = head(&source, 40);
        lines[line - 1] = spoil(&lines[line - 1]);
        let copy = tmp.path().join(name);
        std::fs::write(&copy, lines.join("\n") + "\n").unwrap();
        let out = tmp.path().join(format!("out-{name}"));
        let msg = import_to_dir(&copy, &out, FileFormat::CsvGz)
            .unwrap_err()
            .to_string();
        println!("{msg}");
        assert!(
            msg.contains(name) && msg.contains(&format!("line {line}")) && msg.contains(what),
            "{msg}"
        );
        assert_eq!(
            std::fs::read_dir(&out).map_or(0, |d| d.count()),
            0,
            "nothing written for {name}"
        );
        // The unspoilt copy imports.
        lines = head(&source, 40);
        std::fs::write(&copy, lines.join("\n") + "\n").unwrap();
        assert!(!import_to_dir(&copy, &out, FileFormat::CsvGz)
            .unwrap()
            .written
            .is_empty());
    }
}

const G: f64 = 9.80665;

/// The samples of `rec` whose time lies in [t0 + from_s, t0 + to_s), t0 its first sample.
fn window(rec: &ImuRecording, from_s: f64, to_s: f64) -> std::ops::Range<usize> {
    let t0 = rec.t_s[0];
    let a = rec.t_s.partition_point(|t| *t < t0 + from_s);
    let b = rec.t_s.partition_point(|t| *t < t0 + to_s);
    a..b
}

/// Least-squares slope through the origin and correlation of `y` on `x`.
fn slope_and_correlation(x: &[f64], y: &[f64]) -> (f64, f64) {
    let slope =
        x.iter().zip(y).map(|(a, b)| a * b).sum::<f64>() / x.iter().map(|a| a * a).sum::<f64>();
    let (mx, my) = (mean(x), mean(y));
    let sxy: f64 = x.iter().zip(y).map(|(a, b)| (a - mx) * (b - my)).sum();
    let sxx: f64 = x.iter().map(|a| (a - mx).powi(2)).sum();
    let syy: f64 = y.iter().map(|b| (b - my).powi(2)).sum();
    (slope, sxy / (sxx * syy).sqrt())
}

/// Integral of `rate` (one value per `t_s`) over (a, b], rectangle rule with each sample
/// covering the step that ends at it.
fn integral(t_s: &[f64], rate: &[f64], a: f64, b: f64) -> f64 {
    let i = t_s.partition_point(|t| *t <= a).max(1);
    let j = t_s.partition_point(|t| *t <= b);
    (i..j).map(|k| rate[k] * (t_s[k] - t_s[k - 1])).sum()
}

fn wrap_pi(a: f64) -> f64 {
    (a + std::f64::consts::PI).rem_euclid(std::f64::consts::TAU) - std::f64::consts::PI
}

#[test]
fn ardupilot_log_has_three_imus_on_one_clock_reading_gravity_and_the_crash() {
    let Some(path) = dataset("ardupilot-3imu-copter/log171.bin") else {
        return;
    };
    assert_eq!(detect(&path).unwrap(), Some(Dataset::ArduPilotDataFlash));
    let recs = ardupilot_dataflash::read(&path).unwrap();
    let names: Vec<&str> = recs.iter().map(|r| r.0.as_str()).collect();
    assert_eq!(names, ["imu0", "imu1", "imu2", "reference"]);
    let imus: Vec<&ImuRecording> = recs[..3].iter().map(|r| &r.1).collect();
    for (k, rec) in imus.iter().enumerate() {
        assert_eq!(rec.len(), 11_916, "imu{k}");
        assert_eq!(
            rec.t_s, imus[0].t_s,
            "imu{k}: the IMUs are sampled together"
        );
        assert!(
            (rec.rate_hz() - 50.0).abs() < 1e-9,
            "imu{k}: {}",
            rec.rate_hz()
        );
    }
    // The log's own clock: the first sample 11.46 s after boot.
    assert_eq!((imus[0].t_s[0], imus[0].t_s[11_915]), (11.46, 254.061));

    for (k, rec) in imus.iter().enumerate() {
        let accel = rec.accel_m_s2.as_ref().unwrap();
        let gyro = rec.gyro_rad_s.as_ref().unwrap();
        let rest = window(rec, 18.0, 66.0);
        let f_rest = mean_vec(accel, rest.clone());
        let w_rest = mean_vec(gyro, rest.clone());
        // Upside down on the ground after the crash.
        let f_flipped = mean_vec(accel, window(rec, 234.0, 243.0));
        let g_from_flip = (f_flipped[2] - f_rest[2]) / 2.0;
        let (i_max, w_max) = (0..rec.len())
            .map(|i| {
                (
                    i,
                    (gyro[0][i].powi(2) + gyro[1][i].powi(2) + gyro[2][i].powi(2)).sqrt(),
                )
            })
            .fold((0, 0.0), |a, b| if b.1 > a.1 { b } else { a });
        let t_max = rec.t_s[i_max] - rec.t_s[0];
        println!(
            "imu{k}: at rest ({} samples) |f| = {:.3} m/s^2 ({:+.1}% of g), f = {f_rest:.3?}, |omega| = {:.2e} rad/s; \
             upside down after the crash f_z = {:.3}: g from the flip {g_from_flip:.4}, z bias {:.3}; \
             max |omega| {w_max:.2} rad/s at {t_max:.2} s",
            rest.len(),
            f_rest.norm(),
            100.0 * (f_rest.norm() / G - 1.0),
            w_rest.norm(),
            f_flipped[2],
            (f_flipped[2] + f_rest[2]) / 2.0,
        );
        assert_eq!(rest.len(), 2275);
        // Level at rest: the down axis reads about -g (each unit's accelerometer z bias
        // lowers it by 2-7%; the flip below shows the scale is right).
        assert!((0.92..1.01).contains(&(f_rest.norm() / G)), "imu{k}");
        assert!(f_rest[2] < -0.99 * f_rest.norm(), "imu{k}: FRD, z down");
        assert!(
            (g_from_flip / G - 1.0).abs() < 0.015,
            "imu{k}: {g_from_flip}"
        );
        // rad/s as logged: still at rest, the crash's spin at 35 to 42 rad/s.
        assert!(w_rest.norm() < 0.01, "imu{k}");
        assert!(
            (34.0..42.0).contains(&w_max) && (226.0..229.0).contains(&t_max),
            "imu{k}"
        );
        if k == 0 {
            // The README's figure for the first IMU: 35.6 rad/s.
            assert!((35.5..35.7).contains(&w_max), "{w_max}");
        }
    }
}

#[test]
fn ardupilot_reference_agrees_with_itself_and_with_the_gyros() {
    let Some(path) = dataset("ardupilot-3imu-copter/log171.bin") else {
        return;
    };
    let mut recs = ardupilot_dataflash::read(&path).unwrap();
    let (name, reference) = recs.pop().unwrap();
    assert_eq!(name, "reference");
    let imu0 = &recs[0].1;
    println!(
        "reference: {} GPS fixes with attitude, {:.3} s to {:.3} s, median step {:.3} s",
        reference.len(),
        reference.t_s[0],
        reference.t_s[reference.len() - 1],
        reference.median_dt_s()
    );
    assert_eq!(reference.len(), 1034);
    assert!((reference.median_dt_s() - 0.201).abs() < 1e-9);
    let v = reference.velocity_ned_m_s.as_ref().unwrap();
    let p = reference.position.as_ref().unwrap();
    let att = reference.attitude_rad.as_ref().unwrap();
    let max_speed = (0..reference.len())
        .map(|i| v[0][i].hypot(v[1][i]))
        .fold(0.0, f64::max);
    println!("max ground speed {max_speed:.2} m/s");
    assert!((12.0..12.5).contains(&max_speed));

    // Position differences over 1 s agree with the NED velocity: north, east and down
    // (VZ is down-positive, the height goes up when it is negative).
    let r_earth = 6_378_137.0;
    let (mut pos_rate, mut vel) = (Vec::new(), Vec::new());
    for i in 0..reference.len() - 5 {
        let dt = reference.t_s[i + 5] - reference.t_s[i];
        if dt > 1.2 {
            continue;
        }
        let d = [
            (p[0][i + 5] - p[0][i]) * r_earth,
            (p[1][i + 5] - p[1][i]) * r_earth * p[0][i].cos(),
            -(p[2][i + 5] - p[2][i]),
        ];
        for k in 0..3 {
            pos_rate.push(d[k] / dt);
            vel.push((i + 1..=i + 5).map(|j| v[k][j]).sum::<f64>() / 5.0);
        }
    }
    let (slope, corr) = slope_and_correlation(&vel, &pos_rate);
    println!("position rate on velocity: slope {slope:.3}, correlation {corr:.3}");
    assert!((slope - 1.0).abs() < 0.1 && corr > 0.95, "{slope} {corr}");

    // In flight, the IMU's roll and pitch rates integrated over about 1 s follow the change of
    // the reference's roll and pitch (small angles; the crash after 220 s left out).
    let gyro = imu0.gyro_rad_s.as_ref().unwrap();
    let t_first = imu0.t_s[0];
    for axis in 0..2 {
        let (mut integrated, mut change) = (Vec::new(), Vec::new());
        for i in 0..reference.len() - 5 {
            let (a, b) = (reference.t_s[i], reference.t_s[i + 5]);
            if b - a > 1.2 || a < t_first + 70.0 || b > t_first + 220.0 {
                continue;
            }
            integrated.push(integral(&imu0.t_s, &gyro[axis], a, b));
            change.push(wrap_pi(att[axis][i + 5] - att[axis][i]));
        }
        let (slope, corr) = slope_and_correlation(&integrated, &change);
        println!(
            "axis {axis}: {} windows, ATT change on integrated gyro: slope {slope:.3}, correlation {corr:.3}",
            change.len()
        );
        assert!(change.len() > 500);
        assert!(
            (0.75..1.15).contains(&slope) && corr > 0.9,
            "{slope} {corr}"
        );
    }
}

#[test]
fn damaged_copies_of_the_real_log_fail_naming_the_byte_offset_and_write_nothing() {
    let Some(path) = dataset("ardupilot-3imu-copter/log171.bin") else {
        return;
    };
    let bytes = std::fs::read(&path).unwrap();
    let log = ardupilot_dataflash::DataFlashLog::parse(&path, bytes.clone()).unwrap();
    assert_eq!(log.messages().len(), 91_530);
    let tmp = tempfile::tempdir().unwrap();
    let copy = tmp.path().join("log171-damaged.bin");
    let out = tmp.path().join("out");

    // Cut inside a message: the error names the message that starts before the cut.
    let cut = 1_000_000;
    let m = log.messages()[log.messages().partition_point(|m| m.offset <= cut) - 1];
    std::fs::write(&copy, &bytes[..cut]).unwrap();
    let msg = import_to_dir(&copy, &out, FileFormat::CsvGz)
        .unwrap_err()
        .to_string();
    println!("{msg}");
    assert!(
        msg.contains("log171-damaged.bin")
            && msg.contains(&format!("byte offset {}: message {}", m.offset, m.index))
            && msg.contains("is truncated"),
        "{msg}"
    );

    // One byte of a header changed.
    let m = log.messages()[50_000];
    let mut damaged = bytes.clone();
    damaged[m.offset + 1] = 0x00;
    std::fs::write(&copy, &damaged).unwrap();
    let msg = import_to_dir(&copy, &out, FileFormat::CsvGz)
        .unwrap_err()
        .to_string();
    println!("{msg}");
    assert!(
        msg.contains(&format!("byte offset {}: message 50000", m.offset))
            && msg.contains("found A3 00"),
        "{msg}"
    );
    assert_eq!(
        std::fs::read_dir(&out).map_or(0, |d| d.count()),
        0,
        "nothing written"
    );
}

/// `Euler_Y` (deg) of a DOT export by its `SampleTimeFine` stamp, rows with a finite value.
fn dot_pitch_deg(path: &Path) -> std::collections::HashMap<u64, f64> {
    let mut lines = BufReader::new(open_maybe_gz(path).unwrap()).lines();
    let header: Vec<String> = lines
        .next()
        .unwrap()
        .unwrap()
        .split(',')
        .map(|s| s.trim().to_string())
        .collect();
    let col = |name: &str| header.iter().position(|h| h == name).unwrap();
    let (t, y) = (col("SampleTimeFine"), col("Euler_Y"));
    lines
        .map(Result::unwrap)
        .map(|l| {
            let f: Vec<&str> = l.split(',').map(str::trim).collect();
            (f[t].parse().unwrap(), f[y].parse().unwrap())
        })
        .collect()
}

#[test]
fn xsens_dots_import_at_120_hz_on_one_clock_with_gyros_in_rad_s() {
    let Some(dir) = dataset("xsens-dot4-quadrotor") else {
        return;
    };
    let units = [
        ("dot1", 22_902, vec![2]),
        ("dot2", 22_863, vec![2]),
        ("dot4", 22_859, vec![2]),
        ("dot7", 22_867, vec![2, 3908, 3909]),
    ];
    let mut stamps = Vec::new();
    for (unit, samples, dropped) in units {
        let path = dir.join(format!("{unit}.csv.gz"));
        assert_eq!(detect(&path).unwrap(), Some(Dataset::XsensDot));
        let dot = xsens_dot::read(&path).unwrap();
        let rec = &dot.recording;
        assert_eq!(
            (rec.len(), &dot.dropped_lines),
            (samples, &dropped),
            "{unit}"
        );
        assert_eq!(rec.sample_rate_hz, Some(120.0));
        assert!((rec.median_dt_s() - 0.008333).abs() < 1e-12);
        let us: Vec<u64> = rec.t_s.iter().map(|t| (t * 1e6).round() as u64).collect();

        let accel = rec.accel_m_s2.as_ref().unwrap();
        let f = mean_vec(accel, 0..rec.len());
        let gyro = rec.gyro_rad_s.as_ref().unwrap();
        let w_max = (0..rec.len())
            .map(|i| (gyro[0][i].powi(2) + gyro[1][i].powi(2) + gyro[2][i].powi(2)).sqrt())
            .fold(0.0, f64::max);

        // The gyro about the unit's y axis, integrated over 1 s windows, follows the DOT's own
        // pitch change (deg/s -> rad/s: a missing conversion would be a factor 57).
        let pitch = dot_pitch_deg(&path);
        let (mut integrated, mut change) = (Vec::new(), Vec::new());
        for i in (0..rec.len() - 120).step_by(120) {
            let (a, b) = (rec.t_s[i], rec.t_s[i + 120]);
            integrated.push(integral(&rec.t_s, &gyro[1], a, b));
            change.push((pitch[&us[i + 120]] - pitch[&us[i]]).to_radians());
        }
        let (slope, corr) = slope_and_correlation(&integrated, &change);
        println!(
            "{unit}: {} samples, {:.3} s to {:.3} s, dropped lines {dropped:?}; mean f {f:.3?} \
             (|mean f| {:.3} m/s^2); max |omega| {w_max:.2} rad/s; pitch change on integrated gy: \
             slope {slope:.4}, correlation {corr:.4}",
            rec.len(),
            rec.t_s[0],
            rec.t_s[rec.len() - 1],
            f.norm()
        );
        // Airborne the whole time: the mean specific force balances gravity, along the unit's
        // z axis, which points about up.
        assert!((f.norm() / G - 1.0).abs() < 0.06, "{unit}");
        assert!(f[2] > 0.97 * f.norm(), "{unit}: z up");
        assert!(
            (0.97..1.03).contains(&slope) && corr > 0.995,
            "{unit}: {slope} {corr}"
        );
        stamps.push((unit, us));
    }
    // One clock: over the span all four cover, every unit has the same stamps, except the two
    // samples dot7 lacks (one the unit skipped, one dropped with its lost twin).
    let lo = stamps.iter().map(|s| s.1[0]).max().unwrap();
    let hi = stamps.iter().map(|s| *s.1.last().unwrap()).min().unwrap();
    let inside = |s: &[u64]| -> Vec<u64> {
        s.iter()
            .copied()
            .filter(|t| (lo..=hi).contains(t))
            .collect()
    };
    let dot1 = inside(&stamps[0].1);
    println!("common span {lo} us to {hi} us: {} stamps", dot1.len());
    assert_eq!(dot1.len(), 22_854);
    for (unit, s) in &stamps[1..3] {
        assert_eq!(inside(s), dot1, "{unit}");
    }
    let mut dot7_expected = dot1.clone();
    dot7_expected.retain(|t| *t != 710_081_700 && *t != 710_090_033);
    assert_eq!(inside(&stamps[3].1), dot7_expected);
}

const PX4_LOG: &str = "px4-ulog/sample_log_small.ulg";

/// Median of the steps of `t` (any unit).
fn median_step(t: &[f64]) -> f64 {
    let mut d: Vec<f64> = t.windows(2).map(|w| w[1] - w[0]).collect();
    d.sort_by(f64::total_cmp);
    d[d.len() / 2]
}

#[test]
fn px4_log_holds_its_topics_instances_and_rates() {
    let Some(path) = dataset(PX4_LOG) else {
        return;
    };
    assert_eq!(detect(&path).unwrap(), Some(Dataset::Px4ULog));
    let log = px4_ulog::ULog::read(&path).unwrap();
    assert_eq!((log.version, log.start_time_us), (1, 20_309_082));
    assert_eq!(log.message_count(), 15_900);
    assert_eq!(log.topics().len(), 72, "one per subscription");
    let samples: usize = log.topics().iter().map(|t| t.len()).sum();
    assert_eq!(samples, 14_604, "every data message in a topic");
    assert_eq!(log.parameter_count(), 980);
    assert_eq!(
        log.info()["ver_hw"],
        px4_ulog::InfoValue::Text("CUBEPILOT_CUBEORANGE".into())
    );
    let texts: Vec<&str> = log
        .logged_strings()
        .iter()
        .map(|l| l.text.as_str())
        .collect();
    assert_eq!(
        texts,
        [
            "[commander] Takeoff detected",
            "[commander] Landing detected",
            "[commander] Disarmed by landing"
        ]
    );
    assert_eq!(log.dropouts().len(), 1);
    assert_eq!(log.dropouts()[0].duration_ms, 30);

    // Three instances of each raw sensor and of vehicle_imu; vehicle_imu k integrates the
    // chip of sensor_gyro k and sensor_accel k (the device ids say so).
    for (name, len) in [("sensor_gyro", 6), ("sensor_accel", 6), ("vehicle_imu", 12)] {
        let instances: Vec<_> = log.instances(name).collect();
        assert_eq!(instances.len(), 3, "{name}");
        for (k, t) in instances.iter().enumerate() {
            assert_eq!((t.multi_id as usize, t.len()), (k, len), "{name}");
        }
    }
    for k in 0..3 {
        let id = |name: &str, field: &str| log.topic(name, k).unwrap().value(0, field).unwrap();
        let gyro = id("sensor_gyro", "device_id");
        assert_eq!(gyro, id("sensor_accel", "device_id"), "instance {k}");
        assert_eq!(gyro, id("vehicle_imu", "gyro_device_id"), "instance {k}");
        assert_eq!(gyro, id("vehicle_imu", "accel_device_id"), "instance {k}");
    }

    // Rates from the file's own stamps against what it declares: sensor_combined steps by
    // its integration interval (`gyro_integral_dt`), about 1 / IMU_INTEG_RATE.
    let step_us = |name: &str, k: u8| {
        let t = log.topic(name, k).unwrap().timestamps_us().unwrap();
        median_step(&t.iter().map(|&t| t as f64).collect::<Vec<_>>())
    };
    let combined = log.topic("sensor_combined", 0).unwrap();
    assert_eq!(combined.len(), 1298);
    let integ_rate_hz = log.parameter("IMU_INTEG_RATE").unwrap();
    let combined_step_us = step_us("sensor_combined", 0);
    let integral_dt_us = median_of(&combined.column("gyro_integral_dt").unwrap());
    println!(
        "sensor_combined: median step {combined_step_us} µs ({:.2} Hz), median gyro_integral_dt \
         {integral_dt_us} µs, IMU_INTEG_RATE {integ_rate_hz} Hz",
        1e6 / combined_step_us
    );
    assert_eq!(integ_rate_hz, 200.0);
    assert!((combined_step_us - integral_dt_us).abs() <= 5.0);
    assert!((1e6 / combined_step_us / integ_rate_hz - 1.0).abs() < 0.03);
    assert_eq!(log.topic("vehicle_attitude", 0).unwrap().len(), 1298);
    // The logger keeps one raw sample a second, one vehicle_imu integral every 0.5 s, GPS at
    // 5 Hz.
    for k in 0..3 {
        assert!((step_us("sensor_gyro", k) / 1e6 - 1.0).abs() < 0.01);
        assert!((step_us("vehicle_imu", k) / 0.5e6 - 1.0).abs() < 0.01);
        let dt = log
            .topic("vehicle_imu", k)
            .unwrap()
            .column("delta_angle_dt")
            .unwrap();
        assert!(
            (median_of(&dt) * integ_rate_hz / 1e6 - 1.0).abs() < 0.03,
            "{dt:?}"
        );
    }
    assert_eq!(log.topic("vehicle_gps_position", 0).unwrap().len(), 32);
    assert!((step_us("vehicle_gps_position", 0) / 0.2e6 - 1.0).abs() < 0.01);

    // Nested formats decode: position_setpoint_triplet's `current` setpoint (no position yet:
    // NaN) and telemetry_status's array of heartbeats.
    let triplet = log.topic("position_setpoint_triplet", 0).unwrap();
    assert_eq!(triplet.value(0, "current.timestamp"), Some(1_425_100.0));
    assert_eq!(triplet.value(0, "current.type"), Some(5.0));
    assert!(triplet.value(0, "current.lat").unwrap().is_nan());
    let telemetry = log.topic("telemetry_status", 1).unwrap();
    assert!(telemetry.has("heartbeats[3].system_id"));
}

fn median_of(x: &[f64]) -> f64 {
    let mut x = x.to_vec();
    x.sort_by(f64::total_cmp);
    x[x.len() / 2]
}

/// Roll and pitch (rad) of a body whose accelerometer reads the mean specific force `f` at
/// rest (FRD: f = -g down in the body frame).
fn tilt_from_gravity(f: Vector3<f64>) -> (f64, f64) {
    ((-f[1]).atan2(-f[2]), f[0].atan2(f[1].hypot(f[2])))
}

#[test]
fn px4_imus_read_gravity_and_agree_with_the_attitude() {
    let Some(path) = dataset(PX4_LOG) else {
        return;
    };
    let recs = px4_ulog::read(&path).unwrap();
    let names: Vec<&str> = recs.iter().map(|r| r.0.as_str()).collect();
    assert_eq!(
        names,
        [
            "sensor_combined",
            "imu0",
            "imu1",
            "imu2",
            "vehicle_imu0",
            "vehicle_imu1",
            "vehicle_imu2",
            "reference"
        ]
    );
    let rec = |name: &str| &recs.iter().find(|r| r.0 == name).unwrap().1;

    // The vehicle stands still throughout (the "takeoff" it logs moves no sensor).
    let combined = rec("sensor_combined");
    assert_eq!(combined.len(), 1298);
    assert_eq!(combined.t_s[0], 20.326716);
    assert!((duration_s(combined) - 6.496152).abs() < 1e-9);
    let f = mean_vec(combined.accel_m_s2.as_ref().unwrap(), 0..combined.len());
    let gyro = combined.gyro_rad_s.as_ref().unwrap();
    let w = mean_vec(gyro, 0..combined.len());
    let w_max = (0..combined.len())
        .map(|i| Vector3::new(gyro[0][i], gyro[1][i], gyro[2][i]).norm())
        .fold(0.0, f64::max);
    println!(
        "sensor_combined: mean f {f:.4?} m/s^2, |f| {:.4} ({:+.2}% of g); mean |omega| {:.2e}, max |omega| {w_max:.4} rad/s",
        f.norm(),
        100.0 * (f.norm() / G - 1.0),
        w.norm()
    );
    assert!((f.norm() / G - 1.0).abs() < 0.03, "{}", f.norm());
    assert!(f[2] < -0.99 * f.norm(), "FRD, z down");
    assert!(w.norm() < 0.01 && w_max < 0.05);

    // The estimator's attitude (the reference) against the tilt gravity gives.
    let reference = rec("reference");
    let att = reference.attitude_rad.as_ref().unwrap();
    let (roll, pitch) = tilt_from_gravity(f);
    let (ref_roll, ref_pitch) = (mean(&att[0]), mean(&att[1]));
    println!(
        "tilt from gravity roll {:.3} pitch {:.3} deg; reference roll {:.3} pitch {:.3} deg",
        roll / DEG,
        pitch / DEG,
        ref_roll / DEG,
        ref_pitch / DEG
    );
    assert!(roll > 0.5 * DEG, "a measurable roll: {}", roll / DEG);
    assert!((roll - ref_roll).abs() < 0.2 * DEG && (pitch - ref_pitch).abs() < 0.2 * DEG);

    // vehicle_imu: calibrated, body frame, the same gravity to 0.5 % and 1 deg (instance 1
    // leans 0.7 deg from the others); sensor_combined is instance 0's (CAL_ACC_PRIME).
    for k in 0..3 {
        let v = rec(&format!("vehicle_imu{k}"));
        assert_eq!(v.len(), 12);
        let f_k = mean_vec(v.accel_m_s2.as_ref().unwrap(), 0..v.len());
        let w_k = mean_vec(v.gyro_rad_s.as_ref().unwrap(), 0..v.len());
        println!(
            "vehicle_imu{k}: mean f {f_k:.4?}, |f| {:.4}, |omega| {:.2e}",
            f_k.norm(),
            w_k.norm()
        );
        assert!(
            (f_k.norm() / f.norm() - 1.0).abs() < 0.005,
            "vehicle_imu{k}"
        );
        assert!(f_k.angle(&f) < DEG, "vehicle_imu{k}: {f_k:?}");
        if k == 0 {
            assert!((f_k - f).norm() < 0.02, "the primary IMU");
        }
        assert!(w_k.norm() < 0.01);
    }
}

#[test]
fn px4_raw_imus_turn_into_the_body_frame_and_calibrate_to_vehicle_imu() {
    let Some(path) = dataset(PX4_LOG) else {
        return;
    };
    let log = px4_ulog::ULog::read(&path).unwrap();
    let imus = px4_ulog::read_sensor_imus(&log).unwrap();
    let vehicle = px4_ulog::read_vehicle_imus(&log).unwrap();
    let names: Vec<&str> = imus.iter().map(|(n, _)| n.as_str()).collect();
    assert_eq!(
        names,
        ["imu0", "imu1", "imu2"],
        "in the body frame: no `_board`"
    );
    // Sampled together: the instances' stamps agree to 2 ms (as `dynacal redundancy` needs).
    for (name, rec) in &imus {
        assert_eq!(rec.len(), 6);
        for (t, t0) in rec.t_s.iter().zip(&imus[0].1.t_s) {
            assert!((t - t0).abs() < 2e-3, "{name}: {t} vs {t0}");
        }
    }
    // PX4 1.11: corrected = board rotation (SENS_BOARD_ROT 4 = yaw 180 deg, then the
    // SENS_BOARD_{X,Y,Z}_OFF trims in degrees) * ((raw - offset) .* scale), with the
    // calibration slot whose CAL_ACCn_ID is the chip's device id. The importer applies the
    // rotation, built here on its own.
    let p = |name: &str| log.parameter(name).unwrap_or_else(|| panic!("no {name}"));
    assert_eq!(p("SENS_BOARD_ROT"), 4.0);
    let board = Rotation3::from_euler_angles(
        p("SENS_BOARD_X_OFF") * DEG,
        p("SENS_BOARD_Y_OFF") * DEG,
        p("SENS_BOARD_Z_OFF") * DEG,
    ) * Rotation3::from_axis_angle(&Vector3::z_axis(), std::f64::consts::PI);
    println!(
        "SENS_BOARD_ROT 4, trims {:.3} {:.3} {:.3} deg",
        p("SENS_BOARD_X_OFF"),
        p("SENS_BOARD_Y_OFF"),
        p("SENS_BOARD_Z_OFF")
    );
    for (k, (name, rec)) in imus.iter().enumerate() {
        let topic = |t: &str| log.topic(t, k as u8).unwrap();
        let device = topic("sensor_accel").value(0, "device_id").unwrap();
        let to_body =
            px4_ulog::sensor_to_body(&log, px4_ulog::SensorKind::Accel, Some(device)).unwrap();
        let to_body = to_body.unwrap();
        assert!(
            (to_body.r_b_s.matrix() - board.matrix()).norm() < 1e-12,
            "{name}"
        );
        let slot = (0..4)
            .find(|c| log.parameter(&format!("CAL_ACC{c}_ID")) == Some(device))
            .unwrap();
        let cal = |kind: &str, what: &str| {
            Vector3::from_fn(|a, _| p(&format!("CAL_{kind}{slot}_{}{what}", ["X", "Y", "Z"][a])))
        };
        // The topics' own means, in the sensor's axes.
        let raw_mean = |t: &str| {
            let t = topic(t);
            Vector3::from_fn(|a, _| mean(&t.column(["x", "y", "z"][a]).unwrap()))
        };
        let (f_raw, w_raw) = (raw_mean("sensor_accel"), raw_mean("sensor_gyro"));
        let f = mean_vec(rec.accel_m_s2.as_ref().unwrap(), 0..rec.len());
        let w = mean_vec(rec.gyro_rad_s.as_ref().unwrap(), 0..rec.len());
        assert!((f - board * f_raw).norm() < 1e-9 && (w - board * w_raw).norm() < 1e-9);
        let f_corrected = board * (f_raw - cal("ACC", "OFF")).component_mul(&cal("ACC", "SCALE"));
        let v = &vehicle[k].1;
        let f_vehicle = mean_vec(v.accel_m_s2.as_ref().unwrap(), 0..v.len());
        println!(
            "{name}: raw f {f_raw:.3?} (|f| {:.3}), imported {f:.3?}, calibrated {f_corrected:.3?}, vehicle_imu{k} {f_vehicle:.3?}; raw omega {w_raw:.4?} vs CAL_GYRO{slot} offsets {:.4?}",
            f_raw.norm(),
            cal("GYRO", "OFF")
        );
        assert!((f_raw.norm() / G - 1.0).abs() < 0.03);
        // Imported (rotated, uncalibrated): gravity along the body's axes as vehicle_imu has
        // it, to the calibration (offsets to 0.16 m/s^2 across, scales to 3 % along z);
        // unrotated it leans 4.6 deg away.
        let across = |v: Vector3<f64>| v.xy().norm();
        assert!(
            across(f - f_vehicle) < 0.2,
            "{name}: {f:?} vs {f_vehicle:?}"
        );
        assert!(f.angle(&f_vehicle) < 1.5 * DEG, "{name}");
        assert!(f_raw.angle(&f_vehicle) > 3.0 * DEG, "{name}");
        assert!((f_corrected - f_vehicle).norm() < 0.05, "{name}");
        // Unrotated, the raw values are far from the body frame's (x and y flipped).
        assert!((f_raw - f_vehicle).norm() > 0.3, "{name}");
        // At rest a raw gyro reads its calibration offset (to 4.5e-3 rad/s here).
        assert!((w_raw - cal("GYRO", "OFF")).norm() < 0.006, "{name}");
    }
}

#[test]
fn px4_reference_is_a_parked_vehicle_in_trondheim() {
    let Some(path) = dataset(PX4_LOG) else {
        return;
    };
    let log = px4_ulog::ULog::read(&path).unwrap();
    let reference = px4_ulog::read_reference(&log).unwrap().unwrap();
    // Every one of the 32 fixes is 3D and inside the attitude's span.
    assert_eq!(reference.len(), 32);
    assert_eq!(reference.t_s[0], 20.471648);
    let pos = reference.position.as_ref().unwrap();
    let vel = reference.velocity_ned_m_s.as_ref().unwrap();
    let lat0 = pos[0][0];
    for i in 0..reference.len() {
        let north_m = (pos[0][i] - lat0) * 6.371e6;
        let east_m = (pos[1][i] - pos[1][0]) * 6.371e6 * lat0.cos();
        assert!(
            north_m.hypot(east_m) < 5.0,
            "fix {i}: {north_m} m N, {east_m} m E"
        );
        assert!(
            (102.0..108.0).contains(&pos[2][i]),
            "ellipsoidal height {}",
            pos[2][i]
        );
        let speed = Vector3::new(vel[0][i], vel[1][i], vel[2][i]).norm();
        assert!(speed < 0.5, "fix {i}: {speed} m/s");
    }
    assert!((lat0 / DEG - 63.4170622).abs() < 1e-9);
    assert!((pos[1][0] / DEG - 10.4082151).abs() < 1e-9);
    // The height is the ellipsoidal one: `alt` (above mean sea level) is the geoid height
    // (about 40 m here) lower.
    let gps = log.topic("vehicle_gps_position", 0).unwrap();
    let undulation_m =
        (gps.value(0, "alt_ellipsoid").unwrap() - gps.value(0, "alt").unwrap()) / 1e3;
    assert!((39.0..41.0).contains(&undulation_m), "{undulation_m}");
}

#[test]
fn damaged_copies_of_the_px4_log_fail_naming_the_byte_offset() {
    let Some(path) = dataset(PX4_LOG) else {
        return;
    };
    let bytes = std::fs::read(&path).unwrap();
    let log = px4_ulog::ULog::parse(&path, &bytes).unwrap();
    let sample = log.topic("sensor_combined", 0).unwrap().offset(700) as usize;
    let tmp = tempfile::tempdir().unwrap();
    let copy = tmp.path().join("log-damaged.ulg");
    let out = tmp.path().join("out");

    // Cut inside a message.
    std::fs::write(&copy, &bytes[..sample + 20]).unwrap();
    let msg = import_to_dir(&copy, &out, FileFormat::CsvGz)
        .unwrap_err()
        .to_string();
    println!("{msg}");
    assert!(
        msg.contains("log-damaged.ulg")
            && msg.contains(&format!("byte offset {sample}: message "))
            && msg.contains("('D'): truncated: a payload of 47 bytes, but the file ends after 17"),
        "{msg}"
    );
    // A msg_id changed to one never subscribed.
    let mut damaged = bytes.clone();
    damaged[sample + 3..sample + 5].copy_from_slice(&999u16.to_le_bytes());
    std::fs::write(&copy, &damaged).unwrap();
    let msg = import_to_dir(&copy, &out, FileFormat::CsvGz)
        .unwrap_err()
        .to_string();
    assert!(
        msg.contains(&format!("byte offset {sample}: "))
            && msg.contains("data for msg_id 999, which no subscription ('A') announced"),
        "{msg}"
    );
    // A payload size one short.
    let mut damaged = bytes;
    damaged[sample] -= 1;
    std::fs::write(&copy, &damaged).unwrap();
    let msg = import_to_dir(&copy, &out, FileFormat::CsvGz)
        .unwrap_err()
        .to_string();
    assert!(
        msg.contains(&format!("byte offset {sample}: "))
            && msg.contains(
                "`sensor_combined` instance 0 data of 44 bytes, its format needs 45 to 48"
            ),
        "{msg}"
    );
    assert_eq!(
        std::fs::read_dir(&out).map_or(0, |d| d.count()),
        0,
        "nothing written"
    );
}
