//! Unit tests of the ULog parser and importer on byte streams built here, with the formats
//! of PX4 v1.11 (the real `sample_log_small.ulg`'s definitions) where the importer reads them.

use super::*;

/// A ULog byte stream under construction; `push` returns each message's byte offset.
struct Log {
    bytes: Vec<u8>,
}

const GYRO_FORMAT: &str = "sensor_gyro:uint64_t timestamp;uint64_t timestamp_sample;\
uint32_t device_id;float x;float y;float z;float temperature;uint32_t error_count;";
const ACCEL_FORMAT: &str = "sensor_accel:uint64_t timestamp;uint64_t timestamp_sample;\
uint32_t device_id;float x;float y;float z;float temperature;uint32_t error_count;\
uint8_t[3] clip_counter;uint8_t[5] _padding0;";
const COMBINED_FORMAT: &str = "sensor_combined:uint64_t timestamp;float[3] gyro_rad;\
uint32_t gyro_integral_dt;int32_t accelerometer_timestamp_relative;\
float[3] accelerometer_m_s2;uint32_t accelerometer_integral_dt;\
uint8_t accelerometer_clipping;uint8_t[3] _padding0;";
const VEHICLE_IMU_FORMAT: &str = "vehicle_imu:uint64_t timestamp;uint64_t timestamp_sample;\
uint32_t accel_device_id;uint32_t gyro_device_id;float[3] delta_angle;\
float[3] delta_velocity;uint16_t delta_angle_dt;uint16_t delta_velocity_dt;\
uint8_t delta_velocity_clipping;uint8_t[3] _padding0;";
const GPS_FORMAT: &str = "vehicle_gps_position:uint64_t timestamp;int32_t lat;int32_t lon;\
int32_t alt;int32_t alt_ellipsoid;float vel_n_m_s;float vel_e_m_s;float vel_d_m_s;\
uint8_t fix_type;bool vel_ned_valid;uint8_t[6] _padding0;";
const ATTITUDE_FORMAT: &str = "vehicle_attitude:uint64_t timestamp;float[4] q;\
float[4] delta_q_reset;uint8_t quat_reset_counter;uint8_t[7] _padding0;";

/// Little-endian bytes of a list of values.
macro_rules! le {
    ($($v:expr),* $(,)?) => {{
        let mut b: Vec<u8> = Vec::new();
        $(b.extend_from_slice(&($v).to_le_bytes());)*
        b
    }};
}

impl Log {
    /// Header (version 1, start 1 s) and the flag bits.
    fn new() -> Self {
        let mut bytes = MAGIC.to_vec();
        bytes.push(1);
        bytes.extend(1_000_000u64.to_le_bytes());
        let mut log = Log { bytes };
        log.push(b'B', &[0; FLAG_BITS_LEN]);
        log
    }
    fn push(&mut self, kind: u8, payload: &[u8]) -> usize {
        let at = self.bytes.len();
        self.bytes.extend((payload.len() as u16).to_le_bytes());
        self.bytes.push(kind);
        self.bytes.extend_from_slice(payload);
        at
    }
    fn format(&mut self, text: &str) -> usize {
        self.push(b'F', text.as_bytes())
    }
    fn key(kind: u8, prefix: &[u8], key: &str, value: &[u8]) -> (u8, Vec<u8>) {
        let mut p = prefix.to_vec();
        p.push(key.len() as u8);
        p.extend(key.as_bytes());
        p.extend(value);
        (kind, p)
    }
    fn info(&mut self, key: &str, value: &[u8]) -> usize {
        let (k, p) = Self::key(b'I', &[], key, value);
        self.push(k, &p)
    }
    fn param_i32(&mut self, name: &str, value: i32) -> usize {
        let (k, p) = Self::key(b'P', &[], &format!("int32_t {name}"), &value.to_le_bytes());
        self.push(k, &p)
    }
    fn param_f32(&mut self, name: &str, value: f32) -> usize {
        let (k, p) = Self::key(b'P', &[], &format!("float {name}"), &value.to_le_bytes());
        self.push(k, &p)
    }
    fn add(&mut self, multi_id: u8, msg_id: u16, name: &str) -> usize {
        let mut p = vec![multi_id];
        p.extend(msg_id.to_le_bytes());
        p.extend(name.as_bytes());
        self.push(b'A', &p)
    }
    fn data(&mut self, msg_id: u16, payload: &[u8]) -> usize {
        let mut p = msg_id.to_le_bytes().to_vec();
        p.extend_from_slice(payload);
        self.push(b'D', &p)
    }
}

fn parse(bytes: &[u8]) -> Result<ULog, ImportError> {
    ULog::parse(Path::new("test.ulg"), bytes)
}

/// A `sensor_gyro` / `sensor_accel` payload (the accelerometer's trailing padding left out, as
/// PX4 logs it).
fn raw_sample(accel: bool, t_us: u64, device_id: u32, v: [f32; 3]) -> Vec<u8> {
    let mut p = le!(t_us + 400, t_us, device_id, v[0], v[1], v[2], 45.5f32, 0u32);
    if accel {
        p.extend([0, 0, 0]);
    }
    p
}

fn combined_sample(t_us: u64, gyro: [f32; 3], accel: [f32; 3], relative: i32) -> Vec<u8> {
    le!(t_us, gyro[0], gyro[1], gyro[2], 4888u32, relative, accel[0], accel[1], accel[2], 4888u32)
        .into_iter()
        .chain([0u8])
        .collect()
}

fn vehicle_imu_sample(t_us: u64, d_angle: [f32; 3], d_vel: [f32; 3], dt_us: u16) -> Vec<u8> {
    let mut p = le!(t_us + 100, t_us, 7u32, 7u32);
    for v in d_angle.iter().chain(&d_vel) {
        p.extend(v.to_le_bytes());
    }
    p.extend(le!(dt_us, dt_us));
    p.push(0);
    p
}

fn gps_sample(t_us: u64, fix_type: u8, lat_1e7: i32, vel_ned: [f32; 3]) -> Vec<u8> {
    let mut p = le!(t_us, lat_1e7, 104_082_151i32, 66_814i32, 106_766i32);
    for v in vel_ned {
        p.extend(v.to_le_bytes());
    }
    p.extend([fix_type, 1]);
    p
}

fn attitude_sample(t_us: u64, q: UnitQuaternion<f64>) -> Vec<u8> {
    let mut p = t_us.to_le_bytes().to_vec();
    for v in [q.w, q.i, q.j, q.k] {
        p.extend((v as f32).to_le_bytes());
    }
    p.extend([0u8; 16]);
    p.push(0);
    p
}

/// Definitions of the topics the importer reads, subscribed as msg_ids 0-7: sensor_gyro and
/// sensor_accel instances 0 and 1, sensor_combined, vehicle_imu, GPS, attitude.
fn definitions() -> Log {
    let mut log = Log::new();
    for f in [
        GYRO_FORMAT,
        ACCEL_FORMAT,
        COMBINED_FORMAT,
        VEHICLE_IMU_FORMAT,
        GPS_FORMAT,
        ATTITUDE_FORMAT,
    ] {
        log.format(f);
    }
    log.info("char[3] sys_name", b"PX4");
    log.param_i32("SENS_BOARD_ROT", 4);
    log.add(0, 0, "sensor_gyro");
    log.add(1, 1, "sensor_gyro");
    log.add(0, 2, "sensor_accel");
    log.add(1, 3, "sensor_accel");
    log.add(0, 4, "sensor_combined");
    log.add(0, 5, "vehicle_imu");
    log.add(0, 6, "vehicle_gps_position");
    log.add(0, 7, "vehicle_attitude");
    log
}

/// Two IMU instances at 1 Hz (instance 1's gyro and accelerometer on different chips),
/// sensor_combined at 200 Hz, vehicle_imu, GPS fixes and attitude.
fn sample_log() -> Vec<u8> {
    let mut log = definitions();
    for s in 0..3u64 {
        let t = 21_000_000 + 1_000_000 * s;
        let f = s as f32;
        log.data(0, &raw_sample(false, t, 0x25000a, [0.01 * f, -0.02, 0.03]));
        log.data(1, &raw_sample(false, t + 7, 0x380022, [0.5, 0.0, f]));
        log.data(2, &raw_sample(true, t, 0x25000a, [0.68, 0.24, -9.7 + f]));
        log.data(3, &raw_sample(true, t + 7, 0x280022, [0.35, 0.3, -9.9]));
    }
    for s in 0..4u64 {
        let f = s as f32;
        log.data(
            4,
            &combined_sample(
                20_000_000 + 5_000 * s,
                [0.1 * f, 0.0, -0.1],
                [0.0, -0.17, -9.62],
                0,
            ),
        );
    }
    log.data(
        5,
        &vehicle_imu_sample(
            20_500_000,
            [0.0005, 0.0, -0.001],
            [0.0, -0.001, -0.048],
            5000,
        ),
    );
    log.data(
        5,
        &vehicle_imu_sample(21_000_000, [0.0, 0.0, 0.0], [0.0, 0.0, -0.0485], 4850),
    );
    let yaw = |deg: f64| UnitQuaternion::from_euler_angles(0.02, -0.01, deg.to_radians());
    log.data(7, &attitude_sample(20_400_000, yaw(10.0)));
    log.data(7, &attitude_sample(20_500_000, yaw(20.0)));
    log.data(6, &gps_sample(20_350_000, 3, 634_170_622, [0.0; 3])); // before the attitude
    log.data(6, &gps_sample(20_420_000, 2, 634_170_622, [0.0; 3])); // 2D fix: left out
    log.data(
        6,
        &gps_sample(20_450_000, 3, 634_170_612, [0.05, -0.13, 0.24]),
    );
    log.push(b'S', &SYNC_MAGIC);
    log.push(
        b'L',
        &[b'6']
            .into_iter()
            .chain(le!(20_460_000u64))
            .chain(*b"[commander] Takeoff detected")
            .collect::<Vec<u8>>(),
    );
    log.push(b'O', &30u16.to_le_bytes());
    log.bytes
}

#[test]
fn basic_types_decode_little_endian() {
    assert_eq!(BasicType::Int8.decode(&[0xFF]), Some(-1.0));
    assert_eq!(BasicType::UInt16.decode(&[0x34, 0x12]), Some(4660.0));
    assert_eq!(BasicType::Int32.decode(&(-7i32).to_le_bytes()), Some(-7.0));
    assert_eq!(
        BasicType::UInt64.decode(&26_822_868u64.to_le_bytes()),
        Some(26_822_868.0)
    );
    assert_eq!(BasicType::Float.decode(&0.5f32.to_le_bytes()), Some(0.5));
    assert_eq!(
        BasicType::Double.decode(&(-2.25f64).to_le_bytes()),
        Some(-2.25)
    );
    assert_eq!(BasicType::Bool.decode(&[2]), Some(1.0));
    assert_eq!(BasicType::Char.decode(b"A"), Some(65.0));
    assert_eq!(BasicType::Int16.decode(&[1]), None, "wrong slice length");
    assert_eq!(BasicType::from_name("uint64_t"), Some(BasicType::UInt64));
    assert_eq!(BasicType::from_name("float32"), None);
}

#[test]
fn arrays_and_nested_formats_flatten_and_decode() {
    let mut log = Log::new();
    // The nested format is defined after the one using it, as the spec allows.
    log.format(
        "status:uint64_t timestamp;vec3[2] v;hb[2] beats;int16_t[2] t;uint8_t[3] _padding0;",
    );
    log.format("vec3:float x;float y;float z;");
    log.format("hb:uint8_t kind;bool ok;");
    log.add(2, 9, "status");
    let payload = le!(
        5u64, 1.0f32, 2.0f32, 3.0f32, -1.0f32, -2.0f32, -3.0f32, 7u8, 1u8, 8u8, 0u8, -300i16,
        301i16
    );
    let at = log.data(9, &payload);
    let ulog = parse(&log.bytes).unwrap();
    let t = ulog.topic("status", 2).unwrap();
    let layout = t.layout();
    assert_eq!(
        (layout.size, layout.trailing_padding),
        (8 + 24 + 4 + 4 + 3, 3)
    );
    let names: Vec<&str> = layout.fields.iter().map(|f| f.name.as_str()).collect();
    assert_eq!(
        names,
        [
            "timestamp",
            "v[0].x",
            "v[0].y",
            "v[0].z",
            "v[1].x",
            "v[1].y",
            "v[1].z",
            "beats[0].kind",
            "beats[0].ok",
            "beats[1].kind",
            "beats[1].ok",
            "t[0]",
            "t[1]"
        ]
    );
    assert_eq!(layout.field("beats[1].kind").unwrap().offset, 8 + 24 + 2);
    assert_eq!(t.len(), 1);
    assert_eq!(t.offset(0), at as u64);
    assert_eq!(t.value(0, "v[1].y"), Some(-2.0));
    assert_eq!(t.value(0, "beats[1].kind"), Some(8.0));
    assert_eq!(t.value(0, "beats[1].ok"), Some(0.0));
    assert_eq!(t.value(0, "t[0]"), Some(-300.0));
    assert_eq!(t.value(0, "_padding0[0]"), None);
    assert_eq!(t.timestamps_us(), Some(vec![5]));
}

#[test]
fn two_multi_id_instances_are_kept_apart() {
    let ulog = parse(&sample_log()).unwrap();
    let gyros: Vec<&Topic> = ulog.instances("sensor_gyro").collect();
    assert_eq!(gyros.len(), 2);
    assert_eq!((gyros[0].multi_id, gyros[1].multi_id), (0, 1));
    assert_eq!(
        gyros[0].column("x").unwrap(),
        [0.0, f64::from(0.01f32), f64::from(0.02f32)]
    );
    assert_eq!(gyros[1].column("z").unwrap(), [0.0, 1.0, 2.0]);
    assert_eq!(
        gyros[1].column("device_id").unwrap(),
        [f64::from(0x380022); 3]
    );
    assert_eq!(
        gyros[1].timestamps_us().unwrap(),
        [21_000_407, 22_000_407, 23_000_407]
    );
    // The accelerometer's data leave out its 5-byte trailing padding.
    let accel = ulog.topic("sensor_accel", 0).unwrap();
    assert_eq!((accel.layout().size, accel.len()), (48, 3));
    assert_eq!(accel.value(2, "z"), Some(f64::from(-7.7f32)));
    // Definitions and the other messages.
    assert_eq!(ulog.version, 1);
    assert_eq!(ulog.start_time_us, 1_000_000);
    assert_eq!(ulog.info()["sys_name"], InfoValue::Text("PX4".into()));
    assert_eq!(ulog.parameter("SENS_BOARD_ROT"), Some(4.0));
    assert_eq!(ulog.sync_count(), 1);
    assert_eq!(ulog.dropouts()[0].duration_ms, 30);
    let l = &ulog.logged_strings()[0];
    assert_eq!((l.level, l.timestamp_us), (b'6', 20_460_000));
    assert_eq!(l.text, "[commander] Takeoff detected");
}

#[test]
fn a_subscription_removed_and_added_again_continues_its_instance() {
    let mut log = Log::new();
    log.format("t:uint64_t timestamp;");
    log.add(0, 3, "t");
    log.data(3, &le!(1u64));
    log.push(b'R', &3u16.to_le_bytes());
    log.add(0, 4, "t");
    log.data(4, &le!(2u64));
    let ulog = parse(&log.bytes).unwrap();
    assert_eq!(ulog.topics().len(), 1);
    assert_eq!(
        ulog.topic("t", 0).unwrap().timestamps_us(),
        Some(vec![1, 2])
    );
    // The removed msg_id carries no more data.
    log.data(3, &le!(3u64));
    let msg = parse(&log.bytes).unwrap_err().to_string();
    assert!(
        msg.contains("data for msg_id 3, which no subscription"),
        "{msg}"
    );
}

/// The message of a parse error of `bytes`, checked to name the file and `offset`.
fn error_at(bytes: &[u8], offset: usize) -> String {
    let msg = parse(bytes).unwrap_err().to_string();
    assert!(
        msg.starts_with(&format!("test.ulg: byte offset {offset}: ")),
        "{msg}"
    );
    msg
}

#[test]
fn damaged_headers_and_messages_name_their_byte_offset() {
    let good = sample_log();
    let mut b = good.clone();
    b[3] = b'X';
    assert!(error_at(&b, 0).contains("magic 55 4C 6F 58 01 12 35"));
    assert!(error_at(&good[..12], 0).contains("ends 12 byte(s) into the 16-byte ULog header"));
    let mut b = good.clone();
    b[7] = 2;
    assert!(error_at(&b, 7).contains("ULog version 2"));

    // The last message (the dropout, 5 bytes) cut short, or its header cut short.
    let last = good.len() - 5;
    let msg = error_at(&good[..good.len() - 1], last);
    assert!(
        msg.contains("('O'): truncated: a payload of 2 bytes, but the file ends after 1"),
        "{msg}"
    );
    assert!(error_at(&good[..last + 2], last).contains("ends 2 byte(s) into a message header"));
    // A size overrunning the file.
    let mut b = good.clone();
    b[last] = 0xFF;
    assert!(error_at(&b, last).contains("payload of 255 bytes"));
    // An unknown message type, a bad sync marker, a bad dropout.
    let mut b = good.clone();
    b[last + 2] = b'Z';
    assert!(error_at(&b, last).contains("unknown message type 0x5A"));
    let mut log = definitions();
    let at = log.push(b'S', &[0x2F, 0x73, 0x13, 0x20, 0x25, 0x0C, 0xBB, 0x13]);
    assert!(error_at(&log.bytes, at).contains("sync marker 2F 73 13 20 25 0C BB 13"));
}

#[test]
fn data_that_does_not_fit_its_subscription_names_its_offset() {
    let mut log = definitions();
    let at = log.data(42, &[0; 40]);
    let msg = error_at(&log.bytes, at);
    assert!(
        msg.contains("('D'): data for msg_id 42, which no subscription"),
        "{msg}"
    );

    // sensor_accel: 48 bytes, of which the trailing 5 may be left out.
    let mut log = definitions();
    let at = log.data(2, &[0; 42]);
    assert!(error_at(&log.bytes, at)
        .contains("`sensor_accel` instance 0 data of 42 bytes, its format needs 43 to 48"));
    let mut log = definitions();
    let at = log.data(0, &[0; 41]);
    assert!(error_at(&log.bytes, at)
        .contains("`sensor_gyro` instance 0 data of 41 bytes, its format needs 40"));
    let mut log = definitions();
    let at = log.push(b'D', &[0]);
    assert!(error_at(&log.bytes, at).contains("needs at least 2"));
}

#[test]
fn bad_definitions_and_subscriptions_name_their_byte_offset() {
    let mut log = Log::new();
    let at = log.format("t:uint64_t timestamp;float32 x;");
    log.add(0, 0, "t");
    let msg = error_at(&log.bytes, at);
    assert!(
        msg.contains("field `x` has the unknown type `float32`"),
        "{msg}"
    );
    // Also when no subscription uses the format.
    let mut log = Log::new();
    let at = log.format("t:uint64_t timestamp;nope[2] x;");
    assert!(error_at(&log.bytes, at).contains("unknown type `nope`"));

    let mut log = Log::new();
    let at = log.format("a:uint64_t timestamp;b inner;");
    log.format("b:a back;");
    assert!(error_at(&log.bytes, at).contains("format `a` contains itself (a -> b -> a)"));

    for (text, expected) in [
        ("t uint64_t timestamp;", "has no `name:`"),
        ("t:uint64_t;", "is not `type name`"),
        ("t:float[x] x;", "`float[x]` has no array length"),
        ("t:float x;;float y;", "empty field 1"),
        ("t:float x;float x;", "field `x` twice"),
    ] {
        let mut log = Log::new();
        let at = log.format(text);
        let msg = error_at(&log.bytes, at);
        assert!(msg.contains(expected), "{text}: {msg}");
    }

    let mut log = Log::new();
    let at = log.add(0, 1, "ghost");
    assert!(error_at(&log.bytes, at).contains("subscribes to `ghost`, which no format defines"));
    let mut log = definitions();
    let at = log.add(2, 0, "sensor_gyro");
    assert!(error_at(&log.bytes, at)
        .contains("msg_id 0 is already subscribed to `sensor_gyro` instance 0"));
    let mut log = definitions();
    let at = log.push(b'R', &99u16.to_le_bytes());
    assert!(error_at(&log.bytes, at).contains("removes msg_id 99"));

    let mut log = Log::new();
    let at = log.info("char[4] sys_name", b"PX4");
    assert!(error_at(&log.bytes, at).contains("value of 3 bytes, its type needs 4"));
    let mut log = Log::new();
    let at = log.push(b'I', &[40, b'c']);
    assert!(error_at(&log.bytes, at).contains("key of 40 bytes overruns"));
}

#[test]
fn flag_bits_are_checked() {
    let mut log = Log::new();
    let at = log.push(b'B', &[0; FLAG_BITS_LEN]);
    assert!(error_at(&log.bytes, at).contains("flag bits after the first message"));

    let mut b = Log::new().bytes;
    b[HEADER_LEN + 3 + 8] = 0b10; // an incompatible flag this reader does not know
    assert!(error_at(&b, HEADER_LEN).contains("unknown incompatible flags (byte 0 = 0x02)"));

    // Appended data must start at a message.
    let mut log = Log::new();
    log.format("t:uint64_t timestamp;");
    let end = log.bytes.len() as u64;
    log.bytes[HEADER_LEN + 3 + 8] = INCOMPAT_DATA_APPENDED;
    log.bytes[HEADER_LEN + 3 + 16..HEADER_LEN + 3 + 24].copy_from_slice(&(end - 1).to_le_bytes());
    error_at(&log.bytes, end as usize - 1);
    log.bytes[HEADER_LEN + 3 + 16..HEADER_LEN + 3 + 24].copy_from_slice(&end.to_le_bytes());
    assert_eq!(
        parse(&log.bytes).unwrap().incompat_flags[0],
        INCOMPAT_DATA_APPENDED
    );
}

#[test]
fn imu_instances_pair_gyro_and_accel_of_one_chip() {
    let ulog = parse(&sample_log()).unwrap();
    let imus = read_sensor_imus(&ulog).unwrap();
    let names: Vec<&str> = imus.iter().map(|(n, _)| n.as_str()).collect();
    // Instance 1's gyro and accelerometer report different chips: written apart.
    assert_eq!(names, ["imu0", "gyro1", "accel1"]);
    let imu0 = &imus[0].1;
    assert_eq!(
        imu0.t_s,
        [21.0, 22.0, 23.0],
        "timestamp_sample, not timestamp"
    );
    // SENS_BOARD_ROT 4 (yaw 180 deg): x and y change sign, z stays (to the 1e-16 of
    // sin(pi) in the matrix).
    let close = |a: f64, b: f32| assert!((a - f64::from(b)).abs() < 1e-15, "{a} vs {b}");
    close(imu0.channel("gx").unwrap()[2], -0.02);
    close(imu0.channel("gy").unwrap()[2], 0.02);
    close(imu0.channel("ax").unwrap()[0], -0.68);
    close(imu0.channel("az").unwrap()[1], -8.7);
    assert_eq!(imus[1].1.channels(), ["gx", "gy", "gz"]);
    assert_eq!(imus[2].1.channels(), ["ax", "ay", "az"]);
    assert_eq!(imus[2].1.t_s, [21.000007, 22.000007, 23.000007]);
}

#[test]
fn sensor_combined_and_vehicle_imu_convert_to_rates() {
    let ulog = parse(&sample_log()).unwrap();
    let combined = read_sensor_combined(&ulog).unwrap();
    assert_eq!(combined.len(), 1);
    let (name, rec) = &combined[0];
    assert_eq!(name, "sensor_combined");
    assert_eq!(rec.t_s, [20.0, 20.005, 20.01, 20.015]);
    assert_eq!(rec.channel("gx").unwrap()[3], f64::from(0.3f32));
    assert_eq!(rec.channel("az").unwrap()[0], f64::from(-9.62f32));

    let vimu = read_vehicle_imus(&ulog).unwrap();
    let (name, rec) = &vimu[0];
    assert_eq!(name, "vehicle_imu0");
    assert_eq!(rec.t_s, [20.5, 21.0]);
    let close = |a: f64, b: f64| assert!((a - b).abs() < 1e-6, "{a} vs {b}");
    close(rec.channel("gx").unwrap()[0], 0.1); // 0.0005 rad over 5 ms
    close(rec.channel("gz").unwrap()[0], -0.2);
    close(rec.channel("az").unwrap()[0], -9.6);
    close(rec.channel("az").unwrap()[1], -10.0); // 0.0485 m/s over 4.85 ms
}

#[test]
fn reference_has_3d_fixes_with_interpolated_attitude() {
    let ulog = parse(&sample_log()).unwrap();
    let rec = read_reference(&ulog).unwrap().unwrap();
    // The fix before the first attitude sample and the 2D fix are left out.
    assert_eq!(rec.t_s, [20.45]);
    let close = |a: f64, b: f64| assert!((a - b).abs() < 1e-6, "{a} vs {b}");
    let att = rec.attitude_rad.as_ref().unwrap();
    close(att[0][0], 0.02);
    close(att[1][0], -0.01);
    close(att[2][0], 15f64.to_radians());
    let p = rec.position.as_ref().unwrap();
    close(p[0][0], 63.4170612f64.to_radians());
    close(p[1][0], 10.4082151f64.to_radians());
    close(p[2][0], 106.766);
    let v = rec.velocity_ned_m_s.as_ref().unwrap();
    assert_eq!(
        [v[0][0], v[1][0], v[2][0]],
        [0.05f32, -0.13, 0.24].map(f64::from)
    );
}

/// The error of importing `bytes` as a file.
fn import_error(bytes: &[u8]) -> String {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("bad.ulg");
    std::fs::write(&path, bytes).unwrap();
    let msg = read(&path).unwrap_err().to_string();
    assert!(msg.contains("bad.ulg"), "{msg}");
    msg
}

#[test]
fn bad_values_and_times_are_errors_naming_the_sample() {
    let mut log = definitions();
    log.data(0, &raw_sample(false, 1_000, 1, [0.0; 3]));
    let at = log.data(0, &raw_sample(false, 1_000, 1, [0.0; 3]));
    let msg = import_error(&log.bytes);
    assert!(
        msg.contains(&format!("byte offset {at}: sensor_gyro instance 0 sample 1: `timestamp_sample` 0.001 s is a duplicate")),
        "{msg}"
    );

    let mut log = definitions();
    log.data(5, &vehicle_imu_sample(1_000, [0.0; 3], [0.0; 3], 0));
    assert!(import_error(&log.bytes).contains("`delta_angle_dt` is 0 µs"));

    let mut log = definitions();
    log.data(
        4,
        &combined_sample(1_000, [f32::NAN, 0.0, 0.0], [0.0; 3], 0),
    );
    assert!(import_error(&log.bytes).contains("`gyro_rad[0]` is NaN"));
    let mut log = definitions();
    log.data(4, &combined_sample(1_000, [0.0; 3], [0.0; 3], i32::MAX));
    assert!(import_error(&log.bytes).contains("sample 0: the sample has no accelerometer value"));

    let mut log = definitions();
    log.data(4, &combined_sample(1_000, [0.0; 3], [0.0; 3], 0));
    let twice = UnitQuaternion::new_unchecked(Quaternion::new(2.0, 0.0, 0.0, 0.0));
    log.data(7, &attitude_sample(1_000, twice));
    assert!(import_error(&log.bytes).contains("quaternion `q` has the norm"));

    let log = definitions();
    assert!(import_error(&log.bytes).contains("no samples of sensor_combined"));
}

#[test]
fn detects_the_magic() {
    assert!(is_ulog(&sample_log()[..7]));
    assert!(!is_ulog(b"ULog\x01\x12"));
    assert!(!is_ulog(&[0xA3, 0x95, 0x80]));
}

/// Asserts two matrices agree to `tol` in every entry.
fn assert_matrix(actual: &nalgebra::Matrix3<f64>, expected: [[f64; 3]; 3], tol: f64) {
    for (r, row) in expected.iter().enumerate() {
        for (c, e) in row.iter().enumerate() {
            assert!(
                (actual[(r, c)] - e).abs() < tol,
                "({r}, {c}): {} vs {e}\n{actual}",
                actual[(r, c)]
            );
        }
    }
}

#[test]
fn board_rotations_match_hand_computed_matrices() {
    let m = |rot: i64| *board::rotation_matrix(rot).unwrap().matrix();
    let h = std::f64::consts::FRAC_1_SQRT_2;
    assert_matrix(
        &m(0),
        [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
        1e-15,
    );
    // YAW_45: x_body = (x - y) / sqrt 2, y_body = (x + y) / sqrt 2.
    assert_matrix(&m(1), [[h, -h, 0.0], [h, h, 0.0], [0.0, 0.0, 1.0]], 1e-15);
    assert_matrix(
        &m(4),
        [[-1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, 1.0]],
        1e-15,
    );
    assert_matrix(
        &m(8),
        [[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]],
        1e-15,
    );
    // ROLL_90: (x, y, z) -> (x, -z, y); ROLL_90_YAW_90: -> (z, x, y).
    assert_matrix(
        &m(16),
        [[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]],
        1e-15,
    );
    assert_matrix(
        &m(18),
        [[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]],
        1e-15,
    );
    // PITCH_90: (x, y, z) -> (z, y, -x); ROLL_90_PITCH_180_YAW_90: -> (z, -x, -y).
    assert_matrix(
        &m(24),
        [[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]],
        1e-15,
    );
    assert_matrix(
        &m(36),
        [[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]],
        1e-15,
    );
    // ROLL_90_PITCH_68_YAW_293 and ROLL_90_PITCH_315 against the matrices PX4's
    // `rotate_3f` writes out (6 digits; the second's 0.707107 is 1 / sqrt 2).
    assert_matrix(
        &m(38),
        [
            [0.146371, 0.362280, -0.920505],
            [-0.344827, -0.853477, -0.390731],
            [-0.927184, 0.374607, 0.0],
        ],
        2e-6,
    );
    assert_matrix(&m(40), [[h, -h, 0.0], [0.0, 0.0, -1.0], [h, h, 0.0]], 1e-15);
    // Every value PX4 defines is a proper rotation; nothing past ROTATION_MAX or below 0.
    for rot in 0..48 {
        let r = m(rot);
        assert!((r.determinant() - 1.0).abs() < 1e-12, "{rot}");
        assert_matrix(
            &(r.transpose() * r),
            [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
            1e-12,
        );
    }
    assert!(board::rotation_matrix(48).is_none());
    assert!(board::rotation_matrix(-1).is_none());
    // The level trim comes after the board rotation: a yaw trim adds to YAW_180.
    let trimmed = board::level_adjustment([0.0, 0.0, 30.0]) * board::rotation_matrix(4).unwrap();
    let c = 210f64.to_radians().cos();
    let s = 210f64.to_radians().sin();
    assert_matrix(
        trimmed.matrix(),
        [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]],
        1e-12,
    );
}

/// A log with one gyro and one accelerometer (same chip, device id 0x25000a) reading
/// (1, 2, 3) and (4, 5, 6), and the parameters `params` (int32 and float) before the data.
fn board_log(ints: &[(&str, i32)], floats: &[(&str, f32)]) -> Vec<u8> {
    let mut log = Log::new();
    log.format(GYRO_FORMAT);
    log.format(ACCEL_FORMAT);
    for (name, v) in ints {
        log.param_i32(name, *v);
    }
    for (name, v) in floats {
        log.param_f32(name, *v);
    }
    log.add(0, 0, "sensor_gyro");
    log.add(0, 1, "sensor_accel");
    log.data(0, &raw_sample(false, 1_000, 0x25000a, [1.0, 2.0, 3.0]));
    log.data(1, &raw_sample(true, 1_000, 0x25000a, [4.0, 5.0, 6.0]));
    log.bytes
}

/// The single row of gyro and accelerometer of the one raw IMU of `bytes`, and its name.
fn board_imu(bytes: &[u8]) -> (String, [f64; 3], [f64; 3]) {
    let mut imus = read_sensor_imus(&parse(bytes).unwrap()).unwrap();
    assert_eq!(imus.len(), 1);
    let (name, rec) = imus.remove(0);
    let g = ["gx", "gy", "gz"].map(|c| rec.channel(c).unwrap()[0]);
    let a = ["ax", "ay", "az"].map(|c| rec.channel(c).unwrap()[0]);
    (name, g, a)
}

#[test]
fn raw_imus_turn_into_the_body_frame_with_board_rotation_trims_and_external_rotation() {
    let close = |a: [f64; 3], b: [f64; 3]| {
        assert!((0..3).all(|i| (a[i] - b[i]).abs() < 1e-6), "{a:?} vs {b:?}")
    };
    // GIVEN ROLL_90_YAW_90 ((x, y, z) -> (z, x, y)) and a 2 deg roll trim
    // WHEN the raw IMU is read THEN it is (z, x cos 2 - y sin 2, x sin 2 + y cos 2).
    let bytes = board_log(&[("SENS_BOARD_ROT", 18)], &[("SENS_BOARD_X_OFF", 2.0)]);
    let (name, g, a) = board_imu(&bytes);
    assert_eq!(name, "imu0");
    let (c, s) = (2f64.to_radians().cos(), 2f64.to_radians().sin());
    close(g, [3.0, c - 2.0 * s, s + 2.0 * c]);
    close(a, [6.0, 4.0 * c - 5.0 * s, 4.0 * s + 5.0 * c]);
    let to_body = sensor_to_body(
        &parse(&bytes).unwrap(),
        SensorKind::Gyro,
        Some(0x25000a as f64),
    )
    .unwrap()
    .unwrap();
    assert_eq!(
        (to_body.rotation, to_body.rotation_parameter.as_str()),
        (18, "SENS_BOARD_ROT")
    );
    assert_eq!(to_body.level_offsets_deg, [2.0, 0.0, 0.0]);

    // GIVEN the accelerometer's calibration slot marks it external with YAW_90
    // (CAL_ACC1_ROT 2; internal sensors have -1) THEN it uses that, the gyro the board's.
    let bytes = board_log(
        &[
            ("SENS_BOARD_ROT", 4),
            ("CAL_ACC0_ID", 0x111),
            ("CAL_ACC0_ROT", -1),
            ("CAL_ACC1_ID", 0x25000a),
            ("CAL_ACC1_ROT", 2),
            ("CAL_GYRO0_ID", 0x25000a),
            ("CAL_GYRO0_ROT", -1),
        ],
        &[],
    );
    let (_, g, a) = board_imu(&bytes);
    close(g, [-1.0, -2.0, 3.0]);
    close(a, [-5.0, 4.0, 6.0]);

    // GIVEN no SENS_BOARD_ROT THEN the data stay in the sensor's axes, and the name says so.
    let (name, g, a) = board_imu(&board_log(&[], &[("SENS_BOARD_Z_OFF", 5.0)]));
    assert_eq!(name, format!("imu0{BOARD_FRAME_SUFFIX}"));
    assert_eq!((g, a), ([1.0, 2.0, 3.0], [4.0, 5.0, 6.0]));
}

#[test]
fn an_unknown_or_changing_board_rotation_is_an_error_naming_its_parameter() {
    let mut log = Log::new();
    log.format(GYRO_FORMAT);
    let at = log.param_i32("SENS_BOARD_ROT", 48);
    log.add(0, 0, "sensor_gyro");
    log.data(0, &raw_sample(false, 1_000, 7, [0.0; 3]));
    let msg = read_sensor_imus(&parse(&log.bytes).unwrap())
        .unwrap_err()
        .to_string();
    assert!(
        msg.contains(&format!("byte offset {at}: parameter SENS_BOARD_ROT is 48, not a rotation PX4 defines (0 to 47)")),
        "{msg}"
    );

    let mut log = Log::new();
    log.format(GYRO_FORMAT);
    log.param_i32("SENS_BOARD_ROT", 4);
    log.add(0, 0, "sensor_gyro");
    log.data(0, &raw_sample(false, 1_000, 7, [0.0; 3]));
    let at = log.param_i32("SENS_BOARD_ROT", 0);
    let msg = read_sensor_imus(&parse(&log.bytes).unwrap())
        .unwrap_err()
        .to_string();
    assert!(
        msg.contains(&format!(
            "byte offset {at}: parameter SENS_BOARD_ROT changes from 4 to 0 during the log"
        )),
        "{msg}"
    );
}

/// The GPS format of PX4 v1.14 (`msg/SensorGps.msg`, fields in the logger's order by size)
/// under topic name `name`: doubles for position, metres for heights.
fn gps_v114_format(name: &str) -> String {
    format!(
        "{name}:uint64_t timestamp;uint64_t timestamp_sample;double latitude_deg;\
         double longitude_deg;double altitude_msl_m;double altitude_ellipsoid_m;\
         float s_variance_m_s;float c_variance_rad;float eph;float epv;float hdop;float vdop;\
         int32_t noise_per_ms;int32_t jamming_indicator;float vel_m_s;float vel_n_m_s;\
         float vel_e_m_s;float vel_d_m_s;float cog_rad;int32_t timestamp_time_relative;\
         float heading;float heading_offset;float heading_accuracy;uint32_t device_id;\
         uint16_t automatic_gain_control;uint8_t fix_type;uint8_t jamming_state;\
         bool vel_ned_valid;uint8_t satellites_used;uint8_t[2] _padding0;"
    )
}

/// A v1.14 GPS payload (trailing padding left out).
fn gps_v114_sample(
    t_us: u64,
    fix_type: u8,
    lat_lon_deg: [f64; 2],
    h_m: f64,
    vel: [f32; 3],
) -> Vec<u8> {
    let mut p = le!(
        t_us,
        t_us - 80_000,
        lat_lon_deg[0],
        lat_lon_deg[1],
        h_m - 40.1,
        h_m
    );
    p.extend(le!(
        0.3f32, 0.1f32, 0.9f32, 1.4f32, 0.8f32, 1.1f32, 90i32, 40i32
    ));
    p.extend(le!(
        0.28f32,
        vel[0],
        vel[1],
        vel[2],
        1.2f32,
        0i32,
        f32::NAN,
        f32::NAN,
        0.0f32
    ));
    p.extend(le!(0x0a0001u32, 1200u16));
    p.extend([fix_type, 1, 1, 17]);
    p
}

/// One GPS fix: time µs, `fix_type`, latitude and longitude deg, ellipsoidal height m, NED
/// velocity m/s.
type GpsFix = (u64, u8, [f64; 2], f64, [f32; 3]);

/// A log with `vehicle_attitude` around t = 20.4-20.5 s and the given GPS topics: each name
/// with its fixes (t_us, fix_type, lat/lon deg, ellipsoidal height m, NED velocity).
fn gps_v114_log(topics: &[(&str, &[GpsFix])]) -> Vec<u8> {
    let mut log = Log::new();
    log.format(ATTITUDE_FORMAT);
    log.add(0, 0, "vehicle_attitude");
    for (k, (name, _)) in topics.iter().enumerate() {
        log.format(&gps_v114_format(name));
        log.add(0, 1 + k as u16, name);
    }
    let q = UnitQuaternion::from_euler_angles(0.02, -0.01, 0.3);
    log.data(0, &attitude_sample(20_400_000, q));
    log.data(0, &attitude_sample(20_500_000, q));
    for (k, (_, fixes)) in topics.iter().enumerate() {
        for &(t_us, fix, ll, h, v) in fixes.iter() {
            log.data(1 + k as u16, &gps_v114_sample(t_us, fix, ll, h, v));
        }
    }
    log.bytes
}

#[test]
fn reference_reads_px4_v1_14_sensor_gps_in_float_degrees_and_metres() {
    // GIVEN only `sensor_gps` (v1.14 names, double degrees), a 3D fix, an extrapolated one
    // (fix_type 8) and an RTK fixed one (6).
    let lat_deg = 63.417_062_212_345_67;
    let lon_deg = -10.408_215_198_765_43;
    let fixes = [
        (
            20_420_000,
            3,
            [lat_deg, lon_deg],
            106.766,
            [0.05f32, -0.13, 0.24],
        ),
        (20_440_000, 8, [lat_deg + 1e-4, lon_deg], 107.0, [0.0; 3]),
        (
            20_460_000,
            6,
            [lat_deg, lon_deg + 2e-7],
            106.5,
            [1.5, 0.0, -0.25],
        ),
    ];
    let bytes = gps_v114_log(&[("sensor_gps", &fixes)]);
    let ulog = parse(&bytes).unwrap();
    assert_eq!(gps_topic(&ulog).unwrap().name, "sensor_gps");
    // WHEN the reference is read THEN it holds the measured fixes, in rad, m and m/s.
    let rec = read_reference(&ulog).unwrap().unwrap();
    assert_eq!(rec.t_s, [20.42, 20.46]);
    let p = rec.position.as_ref().unwrap();
    // 63.41706221234567 deg = 1.106836... rad, to the last bits of the double.
    assert!((p[0][0] - lat_deg * std::f64::consts::PI / 180.0).abs() < 1e-15);
    assert!((p[1][0] - (-0.181657_f64)).abs() < 1e-6, "{}", p[1][0]);
    assert!((p[1][1] - (lon_deg + 2e-7).to_radians()).abs() < 1e-15);
    assert_eq!([p[2][0], p[2][1]], [106.766, 106.5], "ellipsoidal, not MSL");
    let v = rec.velocity_ned_m_s.as_ref().unwrap();
    assert_eq!(
        [v[0][0], v[1][0], v[2][0]],
        [0.05f32, -0.13, 0.24].map(f64::from)
    );
    assert_eq!([v[0][1], v[1][1], v[2][1]], [1.5, 0.0, -0.25]);
    let att = rec.attitude_rad.as_ref().unwrap();
    assert!((att[2][1] - 0.3).abs() < 1e-6);
}

#[test]
fn reference_prefers_vehicle_gps_position_over_sensor_gps() {
    let fix = |lat: f64| [(20_450_000u64, 3u8, [lat, 10.0], 100.0, [0.0f32; 3])];
    // Both logged: the vehicle topic (the receiver PX4 selects) wins.
    let vehicle = fix(45.0);
    let sensor = fix(46.0);
    let bytes = gps_v114_log(&[("sensor_gps", &sensor), ("vehicle_gps_position", &vehicle)]);
    let rec = read_reference(&parse(&bytes).unwrap()).unwrap().unwrap();
    assert_eq!(rec.position.as_ref().unwrap()[0], [45f64.to_radians()]);
    // Subscribed but never logged: sensor_gps instead.
    let bytes = gps_v114_log(&[("vehicle_gps_position", &[]), ("sensor_gps", &sensor)]);
    let rec = read_reference(&parse(&bytes).unwrap()).unwrap().unwrap();
    assert_eq!(rec.position.as_ref().unwrap()[0], [46f64.to_radians()]);
}

/// Regression (an array length in a format replaced by a large number, as the fuzzing
/// harness's field mutation does): the
/// format's field list was built one entry per element before any check, so
/// `float[2147483648]` exhausted memory and a length near `usize::MAX` overflowed the size.
/// A message holds at most 65,535 bytes, so a longer format is refused naming its offset.
#[test]
fn a_format_longer_than_any_message_is_an_error_naming_its_offset() {
    for len in ["16384", "2147483648", "9223372036854775807"] {
        let mut log = definitions();
        let at = log.format(&format!("huge:uint64_t timestamp;float[{len}] x;"));
        log.add(0, 8, "huge");
        let msg = parse(&log.bytes).unwrap_err().to_string();
        assert!(
            msg.contains(&format!("byte offset {at}:")) && msg.contains("65535"),
            "{len}: {msg}"
        );
    }
    // Nested: 300 copies of a 300-byte format.
    let mut log = definitions();
    log.format("block:uint8_t[300] b;");
    let at = log.format("nest:uint64_t timestamp;block[300] blocks;");
    log.add(0, 8, "nest");
    let msg = parse(&log.bytes).unwrap_err().to_string();
    assert!(msg.contains(&format!("byte offset {at}:")), "{msg}");
}

mod fuzz {
    //! Damaged hand-built logs through `import::detect` and `import::import_file`
    //! (`crate::import::fuzz` says what a clean answer is).

    use super::sample_log;
    use crate::import::fuzz::{arb_mutation, check_damaged, check_tail, config};
    use crate::import::Dataset;
    use proptest::prelude::*;

    proptest! {
        #![proptest_config(config(256, 0xF0220201))]

        #[test]
        fn damaged_logs_are_read_or_refused_cleanly(
            mutations in proptest::collection::vec(arb_mutation(), 1..6),
        ) {
            check_damaged(Dataset::Px4ULog, &sample_log(), &mutations)?;
        }

        /// Bytes after the last message keep every sample, or are refused where they are.
        #[test]
        fn a_damaged_tail_keeps_the_samples_before_it(
            tail in proptest::collection::vec(any::<u8>(), 1..200),
            kind in proptest::sample::select(&b"DFALOSIPQRBC"[..]),
            size in 0u16..300,
        ) {
            // Most tails start with a message header of a real type, so the parser reads
            // into them.
            let tail = [&size.to_le_bytes()[..], &[kind], &tail].concat();
            check_tail(Dataset::Px4ULog, &sample_log(), &tail)?;
        }
    }
}

/// Writes `bytes` as `name` in a fresh folder.
fn log_file(bytes: &[u8], name: &str) -> (tempfile::TempDir, std::path::PathBuf) {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join(name);
    std::fs::write(&path, bytes).unwrap();
    (dir, path)
}

#[test]
fn a_log_walked_twice_gives_what_the_log_held_whole_gives() {
    let (_dir, path) = log_file(&sample_log(), "sample.ulg");
    let held = parse(&sample_log()).unwrap();
    let mut expected = read_sensor_combined(&held).unwrap();
    expected.extend(read_sensor_imus(&held).unwrap());
    expected.extend(read_vehicle_imus(&held).unwrap());
    expected.push(("reference".into(), read_reference(&held).unwrap().unwrap()));
    let streamed = read(&path).unwrap();
    let names = |r: &[NamedRecording]| r.iter().map(|(n, _)| n.clone()).collect::<Vec<_>>();
    assert_eq!(
        names(&streamed),
        [
            "sensor_combined",
            "imu0",
            "gyro1",
            "accel1",
            "vehicle_imu0",
            "reference"
        ]
    );
    assert_eq!(names(&streamed), names(&expected));
    for ((name, got), (_, want)) in streamed.iter().zip(&expected) {
        assert_eq!(got.t_s, want.t_s, "{name}");
        assert_eq!(got.named_columns(), want.named_columns(), "{name}");
    }

    // The first walk holds the reference's topics alone, and counts every sample.
    let survey = ULog::walk(&path, &reference_topic, &mut |_| Ok(())).unwrap();
    for topic in survey.topics() {
        let whole = held.topic(&topic.name, topic.multi_id).unwrap();
        assert_eq!(topic.len(), whole.len(), "{}", topic.name);
        assert_eq!(
            topic.is_held(),
            reference_topic(&topic.name),
            "{}",
            topic.name
        );
    }
    assert_eq!(survey.topic("sensor_gyro", 0).unwrap().value(0, "x"), None);
    assert_eq!(survey.parameter("SENS_BOARD_ROT"), Some(4.0));
    assert_eq!(survey.message_count(), held.message_count());
}

#[test]
fn one_chips_gyro_and_accel_logged_out_of_step_still_share_a_recording() {
    // GIVEN instance 0's accelerometer samples logged three ahead of its gyro's
    let mut log = definitions();
    let t = |s: u64| 30_000_000 + 1_000 * s;
    for s in 0..3 {
        log.data(2, &raw_sample(true, t(s), 9, [0.0, 0.0, -9.8 + s as f32]));
    }
    for s in 0..5 {
        log.data(0, &raw_sample(false, t(s), 9, [s as f32, 0.0, 0.0]));
        if s + 3 < 5 {
            log.data(
                2,
                &raw_sample(true, t(s + 3), 9, [0.0, 0.0, -6.8 + s as f32]),
            );
        }
    }
    let (_dir, path) = log_file(&log.bytes, "skew.ulg");
    // WHEN it is imported THEN gyro and accelerometer samples pair by their times.
    let imus = read(&path).unwrap();
    assert_eq!(imus.len(), 1);
    let (name, rec) = &imus[0];
    assert_eq!(name, "imu0");
    assert_eq!(rec.t_s, [30.0, 30.001, 30.002, 30.003, 30.004]);
    let close = |a: &[f64], b: [f64; 5]| {
        assert!(a.iter().zip(b).all(|(x, y)| (x - y).abs() < 1e-5), "{a:?}")
    };
    // SENS_BOARD_ROT 4: x changes sign, z stays.
    close(rec.channel("gx").unwrap(), [0.0, -1.0, -2.0, -3.0, -4.0]);
    close(rec.channel("az").unwrap(), [-9.8, -8.8, -7.8, -6.8, -5.8]);

    // GIVEN one accelerometer time differing from its gyro's THEN they are written apart.
    let mut log = definitions();
    for s in 0..3 {
        log.data(0, &raw_sample(false, t(s), 9, [0.0; 3]));
        let late = if s == 1 { 1 } else { 0 };
        log.data(2, &raw_sample(true, t(s) + late, 9, [0.0, 0.0, -9.8]));
    }
    let (_dir, path) = log_file(&log.bytes, "apart.ulg");
    let names: Vec<String> = read(&path).unwrap().into_iter().map(|r| r.0).collect();
    assert_eq!(names, ["gyro0", "accel0"]);
}
