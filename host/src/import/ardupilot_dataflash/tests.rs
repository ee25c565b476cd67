//! Unit tests of the DataFlash parser and importer on hand-built logs with the message
//! layouts of ArduCopter 3.3 (the real `log171.bin`'s `FMT` definitions).

use super::*;

const IMU: u8 = 131;
const IMU2: u8 = 135;
const ATT: u8 = 165;
const GPS: u8 = 130;
const IMU_LABELS: &str = "TimeMS,GyrX,GyrY,GyrZ,AccX,AccY,AccZ,ErrG,ErrA,Temp";

/// A `FMT` message defining `type_id`.
fn fmt_msg(type_id: u8, name: &str, format: &str, labels: &str) -> Vec<u8> {
    let length = 3 + format
        .bytes()
        .map(|c| field_size(c).unwrap())
        .sum::<usize>();
    let pad = |s: &str, n: usize| {
        let mut b = s.as_bytes().to_vec();
        b.resize(n, 0);
        b
    };
    let mut m = vec![0xA3, 0x95, FMT_TYPE, type_id, length as u8];
    m.extend(pad(name, 4));
    m.extend(pad(format, 16));
    m.extend(pad(labels, 64));
    assert_eq!(m.len(), FMT_LENGTH);
    m
}

/// A data message: header, type, payload.
fn msg(type_id: u8, payload: &[u8]) -> Vec<u8> {
    let mut m = vec![0xA3, 0x95, type_id];
    m.extend_from_slice(payload);
    m
}

fn imu_msg(type_id: u8, time_ms: u32, gyro: [f32; 3], accel: [f32; 3]) -> Vec<u8> {
    let mut p = time_ms.to_le_bytes().to_vec();
    for v in gyro.iter().chain(&accel) {
        p.extend(v.to_le_bytes());
    }
    p.extend(0u32.to_le_bytes());
    p.extend(0u32.to_le_bytes());
    p.extend(25.0f32.to_le_bytes());
    msg(type_id, &p)
}

/// ATT with roll, pitch, yaw in centidegrees (yaw unsigned).
fn att_msg(time_ms: u32, roll_cd: i16, pitch_cd: i16, yaw_cd: u16) -> Vec<u8> {
    let mut p = time_ms.to_le_bytes().to_vec();
    for v in [0i16, roll_cd, 0, pitch_cd] {
        p.extend(v.to_le_bytes());
    }
    for v in [0u16, yaw_cd, 0, 0] {
        p.extend(v.to_le_bytes());
    }
    msg(ATT, &p)
}

/// GPS as Copter 3.3 logs it: `TimeMS` is GPS time of week, `T` the boot clock in ms.
fn gps_msg(
    status: u8,
    boot_ms: u32,
    lat_1e7: i32,
    speed_cm_s: u32,
    course_cd: i32,
    vz: f32,
) -> Vec<u8> {
    let mut p = vec![status];
    p.extend(400_000_000u32.to_le_bytes()); // GPS time of week, ms: not the boot clock
    p.extend(1871u16.to_le_bytes());
    p.push(9);
    p.extend(150i16.to_le_bytes());
    p.extend(lat_1e7.to_le_bytes());
    p.extend(1_491_647_457i32.to_le_bytes());
    p.extend(1200i32.to_le_bytes()); // RelAlt, cm
    p.extend(59_014i32.to_le_bytes()); // Alt, cm
    p.extend(speed_cm_s.to_le_bytes());
    p.extend(course_cd.to_le_bytes());
    p.extend(vz.to_le_bytes());
    p.extend(boot_ms.to_le_bytes());
    msg(GPS, &p)
}

fn definitions() -> Vec<u8> {
    let mut b = fmt_msg(FMT_TYPE, "FMT", "BBnNZ", "Type,Length,Name,Format,Columns");
    b.extend(fmt_msg(IMU, "IMU", "IffffffIIf", IMU_LABELS));
    b.extend(fmt_msg(IMU2, "IMU2", "IffffffIIf", IMU_LABELS));
    b.extend(fmt_msg(
        ATT,
        "ATT",
        "IccccCCCC",
        "TimeMS,DesRoll,Roll,DesPitch,Pitch,DesYaw,Yaw,ErrRP,ErrYaw",
    ));
    b.extend(fmt_msg(
        GPS,
        "GPS",
        "BIHBcLLeeEefI",
        "Status,TimeMS,Week,NSats,HDop,Lat,Lng,RelAlt,Alt,Spd,GCrs,VZ,T",
    ));
    b
}

/// Two IMUs sampled together at 50 Hz from 11.46 s, ATT at 10 Hz, GPS fixes.
fn sample_log() -> Vec<u8> {
    let mut b = definitions();
    for i in 0..3u32 {
        let t = 11_460 + 20 * i;
        b.extend(imu_msg(IMU, t, [0.01, -0.02, 0.5], [0.2, -0.4, -9.6]));
        b.extend(imu_msg(
            IMU2,
            t,
            [0.0, 0.0, 0.25 * i as f32],
            [0.0, 0.0, -9.4],
        ));
    }
    b.extend(att_msg(11_400, 1000, -500, 1000)); // 10, -5, 10 deg
    b.extend(att_msg(11_500, 1000, -500, 2000)); // yaw 20 deg
    b.extend(gps_msg(1, 11_420, 0, 0, 0, 0.0)); // no fix: left out
    b.extend(gps_msg(3, 11_450, -353_640_332, 500, 9000, -0.25)); // 5 m/s east, climbing
    b.extend(gps_msg(3, 11_600, -353_640_332, 0, 0, 0.0)); // after the last ATT: left out
    b
}

fn parse(bytes: Vec<u8>) -> Result<DataFlashLog, ImportError> {
    DataFlashLog::parse(Path::new("test.bin"), bytes)
}

#[test]
fn letters_decode_to_their_units() {
    assert_eq!(decode_number(b'c', &(-4500i16).to_le_bytes()), Some(-45.0));
    assert_eq!(decode_number(b'C', &35_999u16.to_le_bytes()), Some(359.99));
    assert_eq!(decode_number(b'e', &59_014i32.to_le_bytes()), Some(590.14));
    assert_eq!(decode_number(b'E', &1220u32.to_le_bytes()), Some(12.2));
    assert_eq!(
        decode_number(b'L', &(-353_640_332i32).to_le_bytes()),
        Some(-353_640_332.0 * 1e-7)
    );
    assert_eq!(decode_number(b'f', &0.5f32.to_le_bytes()), Some(0.5));
    assert_eq!(
        decode_number(b'Q', &11_460_000u64.to_le_bytes()),
        Some(11_460_000.0)
    );
    assert_eq!(decode_number(b'b', &[0xFF]), Some(-1.0));
    assert_eq!(decode_number(b'Z', &[0; 64]), None);
    assert_eq!(decode_number(b'h', &[1]), None, "wrong slice length");
}

#[test]
fn parses_formats_and_fields_of_a_copter_log() {
    let log = parse(sample_log()).unwrap();
    assert_eq!(log.formats().len(), 6, "FMT's own and five defined");
    assert_eq!(log.messages().len(), 5 + 6 + 2 + 3);
    let gps = log.named("GPS").nth(1).unwrap();
    assert_eq!(log.value(gps, "Spd"), Some(5.0));
    assert_eq!(log.value(gps, "GCrs"), Some(90.0));
    assert_eq!(log.value(gps, "Alt"), Some(590.14));
    assert_eq!(log.value(gps, "T"), Some(11_450.0));
    assert_eq!(log.value(gps, "Nope"), None);
    // Message offsets: five FMTs, then 43-byte IMU messages.
    let imu2 = log.named("IMU2").next().unwrap();
    assert_eq!((imu2.index, imu2.offset), (6, 5 * 89 + 43));
}

#[test]
fn imus_become_recordings_on_the_log_clock() {
    let log = parse(sample_log()).unwrap();
    let imus = read_imus(&log).unwrap();
    assert_eq!(imus.keys().copied().collect::<Vec<_>>(), vec![0, 1]);
    for rec in imus.values() {
        assert_eq!(rec.t_s, vec![11.46, 11.48, 11.5]);
    }
    let imu0 = &imus[&0];
    assert_eq!(imu0.channel("gz").unwrap()[0], 0.5);
    assert_eq!(imu0.channel("gx").unwrap()[0], f64::from(0.01f32));
    assert_eq!(imu0.channel("az").unwrap()[2], f64::from(-9.6f32));
    assert_eq!(imus[&1].channel("gz").unwrap(), &[0.0, 0.25, 0.5]);
}

#[test]
fn reference_has_fixes_with_ned_velocity_and_interpolated_attitude() {
    let log = parse(sample_log()).unwrap();
    let rec = read_reference(&log).unwrap().unwrap();
    // Only the 3D fix inside the ATT span: the no-fix and the late one are left out.
    assert_eq!(rec.t_s, vec![11.45]);
    let close = |a: f64, b: f64| assert!((a - b).abs() < 1e-9, "{a} vs {b}");
    let att = rec.attitude_rad.as_ref().unwrap();
    close(att[0][0], 10f64.to_radians());
    close(att[1][0], -5f64.to_radians());
    // Half-way between yaw 10 and 20 deg (same roll and pitch): 15 deg.
    close(att[2][0], 15f64.to_radians());
    let v = rec.velocity_ned_m_s.as_ref().unwrap();
    close(v[0][0], 0.0);
    close(v[1][0], 5.0);
    assert_eq!(v[2][0], -0.25, "VZ is down-positive as logged");
    let p = rec.position.as_ref().unwrap();
    close(p[0][0], (-35.3640332f64).to_radians());
    close(p[1][0], 149.1647457f64.to_radians());
    assert_eq!(p[2][0], 590.14);
}

#[test]
fn yaw_interpolates_across_north() {
    let q = |yaw_deg: f64| UnitQuaternion::from_euler_angles(0.0, 0.0, yaw_deg.to_radians());
    let att = [(1.0, q(350.0)), (1.1, q(10.0)), (2.0, q(20.0))];
    let (_, _, yaw) = crate::import::frames::attitude_at(&att, 1.05, MAX_ATT_GAP_S)
        .unwrap()
        .euler_angles();
    assert!(yaw.to_degrees().abs() < 1e-9, "{}", yaw.to_degrees());
    assert!(
        crate::import::frames::attitude_at(&att, 1.5, MAX_ATT_GAP_S).is_none(),
        "ATT samples 0.9 s apart"
    );
    assert!(
        crate::import::frames::attitude_at(&att, 0.5, MAX_ATT_GAP_S).is_none()
            && crate::import::frames::attitude_at(&att, 2.5, MAX_ATT_GAP_S).is_none()
    );
}

#[test]
fn detects_the_header_bytes() {
    assert!(is_dataflash(&sample_log()[..3]));
    assert!(!is_dataflash(&[0xA3, 0x95, IMU]));
    assert!(!is_dataflash(b"t_s,gx"));
}

/// The message of a parse or import error of `bytes`.
fn error_of(bytes: Vec<u8>) -> String {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("bad.bin");
    std::fs::write(&path, bytes).unwrap();
    let msg = read(&path).unwrap_err().to_string();
    assert!(msg.contains("bad.bin"), "{msg}");
    msg
}

#[test]
fn corrupt_bytes_are_errors_naming_offset_and_message() {
    let good = sample_log();
    let imu2_first = 5 * 89 + 43;

    let mut b = good.clone();
    b[imu2_first] = 0x00; // a damaged header
    let msg = error_of(b);
    assert!(
        msg.contains(&format!("byte offset {imu2_first}"))
            && msg.contains("message 6")
            && msg.contains("A3 95, found 00 95"),
        "{msg}"
    );

    let mut b = good.clone();
    b[imu2_first + 2] = 0x99; // a type no FMT defined
    let msg = error_of(b);
    assert!(msg.contains("type 153 (0x99) has no FMT"), "{msg}");

    let mut b = good.clone();
    b.truncate(good.len() - 5); // the last GPS message cut short
    let msg = error_of(b);
    let last = good.len() - 45;
    assert!(
        msg.contains(&format!("byte offset {last}"))
            && msg.contains("(GPS, 45 bytes) is truncated"),
        "{msg}"
    );

    let mut b = good.clone();
    b.extend([0xA3, 0x95]); // a header cut short
    assert!(error_of(b).contains("ends 2 byte(s) into a message header"));

    let mut b = good;
    b.push(0xFF); // trailing garbage
    assert!(error_of(b).contains("found FF"));
}

#[test]
fn bad_definitions_are_errors() {
    let mut b = definitions();
    let mut bad = fmt_msg(140, "EKF1", "Iff", "TimeMS,A,B");
    bad[4] = 20; // length disagrees with the format (needs 15)
    b.extend(bad);
    assert!(error_of(b).contains("EKF1: length 20 bytes, but its format `Iff` needs 15"));

    let mut b = definitions();
    b.extend(fmt_msg(140, "EKF1", "If", "TimeMS"));
    assert!(error_of(b).contains("1 labels for the 2 letters"));

    let mut b = definitions();
    let mut bad = fmt_msg(140, "EKF1", "If", "TimeMS,A");
    bad[9 + 1] = b'X'; // unknown letter
    b.extend(bad);
    assert!(error_of(b).contains("unknown letter `X`"));
}

#[test]
fn duplicated_or_backward_time_stamps_are_errors() {
    let mut b = definitions();
    b.extend(imu_msg(IMU, 1000, [0.0; 3], [0.0; 3]));
    b.extend(imu_msg(IMU, 1000, [0.0; 3], [0.0; 3]));
    let msg = error_of(b);
    assert!(
        msg.contains(&format!("byte offset {}", 5 * 89 + 43))
            && msg.contains("message 6 (IMU)")
            && msg.contains("time 1 s is a duplicate of the previous IMU 0 sample's 1 s"),
        "{msg}"
    );

    let mut b = definitions();
    b.extend(imu_msg(IMU2, 1000, [0.0; 3], [0.0; 3]));
    b.extend(imu_msg(IMU2, 980, [0.0; 3], [0.0; 3]));
    assert!(error_of(b).contains("time 0.98 s is before the previous IMU 1 sample's 1 s"));

    let mut b = definitions();
    b.extend(imu_msg(IMU, 1000, [f32::NAN, 0.0, 0.0], [0.0; 3]));
    assert!(error_of(b).contains("`GyrX` is NaN"));

    let mut b = definitions();
    b.extend(att_msg(1000, 0, 0, 0));
    assert!(error_of(b).contains("no IMU messages"));
}

#[test]
fn four_x_layout_with_instance_field_and_float_degrees() {
    // ArduPilot 4.x: one IMU message with an instance field, TimeUS, ATT in float degrees.
    let mut b = fmt_msg(FMT_TYPE, "FMT", "BBnNZ", "Type,Length,Name,Format,Columns");
    b.extend(fmt_msg(
        200,
        "IMU",
        "QBffffff",
        "TimeUS,I,GyrX,GyrY,GyrZ,AccX,AccY,AccZ",
    ));
    b.extend(fmt_msg(201, "ATT", "Qfff", "TimeUS,Roll,Pitch,Yaw"));
    let mut p = 2_001_000u64.to_le_bytes().to_vec();
    for v in [30.0f32, -10.0, 270.0] {
        p.extend(v.to_le_bytes());
    }
    b.extend(msg(201, &p));
    let imu = |t_us: u64, i: u8| {
        let mut p = t_us.to_le_bytes().to_vec();
        p.push(i);
        for v in [0.1f32, 0.0, 0.0, 0.0, 0.0, -9.8] {
            p.extend(v.to_le_bytes());
        }
        msg(200, &p)
    };
    for t in [2_000_000u64, 2_002_500] {
        b.extend(imu(t, 0));
        b.extend(imu(t, 1));
        b.extend(imu(t, 2));
    }
    let log = parse(b).unwrap();
    let imus = read_imus(&log).unwrap();
    assert_eq!(imus.len(), 3);
    assert_eq!(imus[&2].t_s, vec![2.0, 2.0025]);
    assert_eq!(imus[&1].channel("az").unwrap()[1], f64::from(-9.8f32));
    let att = attitude(&log.record(log.named("ATT").next().unwrap()), None).unwrap();
    assert_eq!(att.0, 2.001);
    let (roll, pitch, yaw) = att.1.euler_angles();
    let close = |a: f64, b: f64| assert!((a - b).abs() < 1e-9, "{a} vs {b}");
    close(roll.to_degrees(), 30.0);
    close(pitch.to_degrees(), -10.0);
    close(yaw.to_degrees(), -90.0); // 270 deg wrapped into (-180, 180]
}

mod fuzz {
    //! Damaged hand-built logs through `import::detect` and `import::import_file`
    //! (`crate::import::fuzz` says what a clean answer is).

    use super::sample_log;
    use crate::import::fuzz::{arb_mutation, check_damaged, check_tail, config};
    use crate::import::Dataset;
    use proptest::prelude::*;

    proptest! {
        #![proptest_config(config(256, 0xF0220101))]

        #[test]
        fn damaged_logs_are_read_or_refused_cleanly(
            mutations in proptest::collection::vec(arb_mutation(), 1..6),
        ) {
            check_damaged(Dataset::ArduPilotDataFlash, &sample_log(), &mutations)?;
        }

        /// Bytes after the last message keep every sample, or are refused where they are.
        #[test]
        fn a_damaged_tail_keeps_the_samples_before_it(
            tail in proptest::collection::vec(any::<u8>(), 1..200),
            header in any::<bool>(),
        ) {
            // Half the tails start as a message would, so the parser reads into them.
            let tail = if header { [&[0xA3, 0x95][..], &tail].concat() } else { tail };
            check_tail(Dataset::ArduPilotDataFlash, &sample_log(), &tail)?;
        }
    }
}

#[test]
fn a_log_walked_twice_gives_what_the_log_held_whole_gives() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("log.bin");
    std::fs::write(&path, sample_log()).unwrap();
    let held = parse(sample_log()).unwrap();
    let imus = read_imus(&held).unwrap();
    let reference = read_reference(&held).unwrap().unwrap();
    let streamed = read(&path).unwrap();
    let names: Vec<&str> = streamed.iter().map(|(n, _)| n.as_str()).collect();
    assert_eq!(names, ["imu0", "imu1", "reference"]);
    for (k, rec) in &imus {
        let got = &streamed[*k].1;
        assert_eq!(got.t_s, rec.t_s);
        assert_eq!(got.gyro_rad_s, rec.gyro_rad_s);
        assert_eq!(got.accel_m_s2, rec.accel_m_s2);
    }
    let got = &streamed[2].1;
    assert_eq!(got.t_s, reference.t_s);
    assert_eq!(got.attitude_rad, reference.attitude_rad);
    assert_eq!(got.position, reference.position);
    assert_eq!(got.velocity_ned_m_s, reference.velocity_ned_m_s);

    // The survey's walk holds the reference's messages alone, and counts every message.
    let survey = DataFlashLog::walk(&path, &|f| f.name == "ATT" || f.name == "GPS", &mut |_| {
        Ok(())
    })
    .unwrap();
    assert_eq!(survey.message_count(), held.messages().len());
    assert_eq!(survey.messages().len(), 2 + 3, "two ATT, three GPS");
    let gps = survey.named("GPS").nth(1).unwrap();
    assert_eq!(survey.value(gps, "Spd"), Some(5.0));
    assert_eq!(gps.offset, held.named("GPS").nth(1).unwrap().offset);
}
