//! The few ROS message types dynacal reads, decoded from their two wire encodings: ROS1's
//! serialisation (little-endian, packed, strings and arrays prefixed by a `u32` length, a
//! header with a `seq` counter and an unsigned time) and ROS2's CDR (a 4-byte encapsulation
//! header naming the byte order, every primitive aligned to its own size from the end of
//! that header, strings counted with their terminating NUL, a header without `seq` and with
//! a signed second count).
//!
//! Written here rather than through a serde crate (`cdr`, `serde_rosmsg`): three fixed
//! layouts, and every failure must name the field and the byte offset inside the message,
//! which those crates do not report. Values are returned as stored: ROS's frames
//! (forward-left-up body, east-north-up world) are turned into the interchange's by the
//! caller.

/// A message's wire encoding.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Encoding {
    /// ROS1 serialisation (`.bag`, or an MCAP channel with encoding `ros1`).
    Ros1,
    /// OMG CDR as ROS2 writes it (`cdr`), either byte order.
    Cdr,
}

/// A `std_msgs/Header`: the stamp and the frame the data are expressed in.
#[derive(Debug, Clone, PartialEq)]
pub struct Header {
    /// The stamp, ns since the Unix epoch (ROS1 and ROS2 both count from it); 0 when the
    /// publisher left it unset.
    pub stamp_ns: i128,
    pub frame_id: String,
}

/// A `sensor_msgs/Imu`, as stored (ROS's forward-left-up axes for a REP 103 body frame).
#[derive(Debug, Clone, PartialEq)]
pub struct Imu {
    pub header: Header,
    /// Orientation quaternion x, y, z, w.
    pub orientation: [f64; 4],
    /// Row-major 3x3; element 0 = -1 means "no orientation" (REP 145).
    pub orientation_covariance: [f64; 9],
    /// rad/s.
    pub angular_velocity: [f64; 3],
    pub angular_velocity_covariance: [f64; 9],
    /// m/s^2, including the reaction to gravity (+g up at rest on a level sensor).
    pub linear_acceleration: [f64; 3],
    pub linear_acceleration_covariance: [f64; 9],
}

/// A `sensor_msgs/NavSatFix`.
#[derive(Debug, Clone, PartialEq)]
pub struct NavSatFix {
    pub header: Header,
    /// `NavSatStatus.status`: -1 no fix, 0 fix, 1 SBAS, 2 GBAS.
    pub status: i8,
    /// deg, deg, m above the WGS 84 ellipsoid.
    pub latitude_deg: f64,
    pub longitude_deg: f64,
    pub altitude_m: f64,
    /// Row-major 3x3, m^2, east-north-up.
    pub position_covariance: [f64; 9],
    pub position_covariance_type: u8,
}

/// A `nav_msgs/Odometry`: the pose of `child_frame_id` in `header.frame_id`, and its twist
/// in `child_frame_id`.
#[derive(Debug, Clone, PartialEq)]
pub struct Odometry {
    pub header: Header,
    pub child_frame_id: String,
    /// m, in the world frame.
    pub position: [f64; 3],
    /// x, y, z, w: the child (body) frame's orientation in the world frame.
    pub orientation: [f64; 4],
    /// m/s and rad/s, in the child (body) frame.
    pub linear_velocity: [f64; 3],
    pub angular_velocity: [f64; 3],
}

/// A decoding failure: the field being read and the byte offset inside the message.
#[derive(Debug, Clone, PartialEq)]
pub struct DecodeError {
    pub field: &'static str,
    pub offset: usize,
    pub message: String,
}

impl std::fmt::Display for DecodeError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "field `{}` at byte {} of the message: {}",
            self.field, self.offset, self.message
        )
    }
}

/// Reads primitives in order, aligning them as CDR does.
struct Reader<'a> {
    bytes: &'a [u8],
    pos: usize,
    /// CDR aligns from the end of the encapsulation header; ROS1 does not align.
    align_origin: Option<usize>,
    big_endian: bool,
}

impl<'a> Reader<'a> {
    fn new(bytes: &'a [u8], encoding: Encoding) -> Result<Self, DecodeError> {
        match encoding {
            Encoding::Ros1 => Ok(Self {
                bytes,
                pos: 0,
                align_origin: None,
                big_endian: false,
            }),
            Encoding::Cdr => {
                let err = |message: String| DecodeError {
                    field: "encapsulation",
                    offset: 0,
                    message,
                };
                let Some(head) = bytes.get(..4) else {
                    return Err(err(format!(
                        "{} bytes, shorter than CDR's header",
                        bytes.len()
                    )));
                };
                let big_endian = match (head[0], head[1]) {
                    (0, 0) => true,
                    (0, 1) => false,
                    _ => {
                        return Err(err(format!(
                            "encapsulation {:02x} {:02x} is neither CDR_BE nor CDR_LE",
                            head[0], head[1]
                        )))
                    }
                };
                Ok(Self {
                    bytes,
                    pos: 4,
                    align_origin: Some(4),
                    big_endian,
                })
            }
        }
    }

    fn take<const N: usize>(&mut self, field: &'static str) -> Result<[u8; N], DecodeError> {
        if let Some(origin) = self.align_origin {
            let misaligned = (self.pos - origin) % N;
            if misaligned != 0 {
                self.pos += N - misaligned;
            }
        }
        let Some(slice) = self.bytes.get(self.pos..self.pos + N) else {
            return Err(DecodeError {
                field,
                offset: self.pos,
                message: format!("the message ends at byte {}", self.bytes.len()),
            });
        };
        self.pos += N;
        let mut out = [0; N];
        out.copy_from_slice(slice);
        if self.big_endian {
            out.reverse();
        }
        Ok(out)
    }

    fn u8(&mut self, field: &'static str) -> Result<u8, DecodeError> {
        Ok(self.take::<1>(field)?[0])
    }
    fn u16(&mut self, field: &'static str) -> Result<u16, DecodeError> {
        Ok(u16::from_le_bytes(self.take(field)?))
    }
    fn u32(&mut self, field: &'static str) -> Result<u32, DecodeError> {
        Ok(u32::from_le_bytes(self.take(field)?))
    }
    fn f64(&mut self, field: &'static str) -> Result<f64, DecodeError> {
        Ok(f64::from_le_bytes(self.take(field)?))
    }
    fn f64s<const N: usize>(&mut self, field: &'static str) -> Result<[f64; N], DecodeError> {
        let mut out = [0.0; N];
        for x in &mut out {
            *x = self.f64(field)?;
        }
        Ok(out)
    }

    fn string(&mut self, field: &'static str) -> Result<String, DecodeError> {
        let start = self.pos;
        let len = self.u32(field)? as usize;
        let Some(bytes) = self.bytes.get(self.pos..self.pos.saturating_add(len)) else {
            return Err(DecodeError {
                field,
                offset: start,
                message: format!("a string of {len} bytes runs past the message's end"),
            });
        };
        self.pos += len;
        // CDR counts the terminating NUL; ROS1 has none.
        let text = match (self.align_origin, bytes.split_last()) {
            (Some(_), Some((0, text))) => text,
            (Some(_), _) => {
                return Err(DecodeError {
                    field,
                    offset: start,
                    message: "a CDR string without its terminating NUL".into(),
                })
            }
            (None, _) => bytes,
        };
        String::from_utf8(text.to_vec()).map_err(|_| DecodeError {
            field,
            offset: start,
            message: "not UTF-8 text".into(),
        })
    }

    fn header(&mut self) -> Result<Header, DecodeError> {
        let stamp_ns = match self.align_origin {
            None => {
                let _seq = self.u32("header.seq")?;
                let sec = self.u32("header.stamp.secs")?;
                let nsec = self.u32("header.stamp.nsecs")?;
                i128::from(sec) * 1_000_000_000 + i128::from(nsec)
            }
            Some(_) => {
                let sec = self.u32("header.stamp.sec")? as i32;
                let nsec = self.u32("header.stamp.nanosec")?;
                i128::from(sec) * 1_000_000_000 + i128::from(nsec)
            }
        };
        let frame_id = self.string("header.frame_id")?;
        Ok(Header { stamp_ns, frame_id })
    }

    /// The whole message must be read: trailing bytes mean another layout.
    fn finish(self, message: &'static str) -> Result<(), DecodeError> {
        // CDR may pad the end to a multiple of 4.
        let slack = if self.align_origin.is_some() { 3 } else { 0 };
        if self.bytes.len() > self.pos + slack {
            return Err(DecodeError {
                field: message,
                offset: self.pos,
                message: format!(
                    "{} bytes left after the last field: not a {message}",
                    self.bytes.len() - self.pos
                ),
            });
        }
        Ok(())
    }
}

/// Decodes a `sensor_msgs/Imu`.
pub fn imu(bytes: &[u8], encoding: Encoding) -> Result<Imu, DecodeError> {
    let mut r = Reader::new(bytes, encoding)?;
    let msg = Imu {
        header: r.header()?,
        orientation: r.f64s("orientation")?,
        orientation_covariance: r.f64s("orientation_covariance")?,
        angular_velocity: r.f64s("angular_velocity")?,
        angular_velocity_covariance: r.f64s("angular_velocity_covariance")?,
        linear_acceleration: r.f64s("linear_acceleration")?,
        linear_acceleration_covariance: r.f64s("linear_acceleration_covariance")?,
    };
    r.finish("sensor_msgs/Imu")?;
    Ok(msg)
}

/// Decodes a `sensor_msgs/NavSatFix`.
pub fn nav_sat_fix(bytes: &[u8], encoding: Encoding) -> Result<NavSatFix, DecodeError> {
    let mut r = Reader::new(bytes, encoding)?;
    let header = r.header()?;
    let status = r.u8("status.status")? as i8;
    let _service = r.u16("status.service")?;
    let msg = NavSatFix {
        header,
        status,
        latitude_deg: r.f64("latitude")?,
        longitude_deg: r.f64("longitude")?,
        altitude_m: r.f64("altitude")?,
        position_covariance: r.f64s("position_covariance")?,
        position_covariance_type: r.u8("position_covariance_type")?,
    };
    r.finish("sensor_msgs/NavSatFix")?;
    Ok(msg)
}

/// Decodes a `nav_msgs/Odometry` (its covariances are read past, not kept).
pub fn odometry(bytes: &[u8], encoding: Encoding) -> Result<Odometry, DecodeError> {
    let mut r = Reader::new(bytes, encoding)?;
    let header = r.header()?;
    let child_frame_id = r.string("child_frame_id")?;
    let position = r.f64s("pose.pose.position")?;
    let orientation = r.f64s("pose.pose.orientation")?;
    let _: [f64; 36] = r.f64s("pose.covariance")?;
    let linear_velocity = r.f64s("twist.twist.linear")?;
    let angular_velocity = r.f64s("twist.twist.angular")?;
    let _: [f64; 36] = r.f64s("twist.covariance")?;
    r.finish("nav_msgs/Odometry")?;
    Ok(Odometry {
        header,
        child_frame_id,
        position,
        orientation,
        linear_velocity,
        angular_velocity,
    })
}

/// Writes CDR little-endian (what ROS2 publishes on the common platforms): the
/// encapsulation header, then each primitive aligned to its size from the header's end.
struct CdrWriter {
    bytes: Vec<u8>,
}

impl CdrWriter {
    fn new() -> Self {
        Self {
            bytes: vec![0, 1, 0, 0],
        }
    }
    fn align(&mut self, size: usize) {
        while !(self.bytes.len() - 4).is_multiple_of(size) {
            self.bytes.push(0);
        }
    }
    fn u8(&mut self, v: u8) {
        self.bytes.push(v);
    }
    fn u16(&mut self, v: u16) {
        self.align(2);
        self.bytes.extend(v.to_le_bytes());
    }
    fn u32(&mut self, v: u32) {
        self.align(4);
        self.bytes.extend(v.to_le_bytes());
    }
    fn f64s(&mut self, values: &[f64]) {
        for v in values {
            self.align(8);
            self.bytes.extend(v.to_le_bytes());
        }
    }
    fn string(&mut self, text: &str) {
        self.u32(text.len() as u32 + 1);
        self.bytes.extend(text.as_bytes());
        self.bytes.push(0);
    }
    /// A ROS2 header; the stamp must fit `builtin_interfaces/Time` (i32 seconds).
    fn header(&mut self, header: &Header) {
        let sec = header.stamp_ns.div_euclid(1_000_000_000);
        let nanosec = header.stamp_ns.rem_euclid(1_000_000_000);
        self.u32(i32::try_from(sec).expect("a stamp within i32 seconds") as u32);
        self.u32(nanosec as u32);
        self.string(&header.frame_id);
    }
}

/// A `sensor_msgs/Imu` in CDR.
pub fn encode_imu_cdr(msg: &Imu) -> Vec<u8> {
    let mut w = CdrWriter::new();
    w.header(&msg.header);
    w.f64s(&msg.orientation);
    w.f64s(&msg.orientation_covariance);
    w.f64s(&msg.angular_velocity);
    w.f64s(&msg.angular_velocity_covariance);
    w.f64s(&msg.linear_acceleration);
    w.f64s(&msg.linear_acceleration_covariance);
    w.bytes
}

/// A `sensor_msgs/NavSatFix` in CDR (service: GPS).
pub fn encode_nav_sat_fix_cdr(msg: &NavSatFix) -> Vec<u8> {
    let mut w = CdrWriter::new();
    w.header(&msg.header);
    w.u8(msg.status as u8);
    w.u16(1);
    w.f64s(&[msg.latitude_deg, msg.longitude_deg, msg.altitude_m]);
    w.f64s(&msg.position_covariance);
    w.u8(msg.position_covariance_type);
    w.bytes
}

/// A `nav_msgs/Odometry` in CDR, its covariances zero (unknown).
pub fn encode_odometry_cdr(msg: &Odometry) -> Vec<u8> {
    let mut w = CdrWriter::new();
    w.header(&msg.header);
    w.string(&msg.child_frame_id);
    w.f64s(&msg.position);
    w.f64s(&msg.orientation);
    w.f64s(&[0.0; 36]);
    w.f64s(&msg.linear_velocity);
    w.f64s(&msg.angular_velocity);
    w.f64s(&[0.0; 36]);
    w.bytes
}

/// The ROS2 interface definitions (`ros2msg`, dependencies after `MSG:` lines) of the types
/// dynacal writes, for a bag's schemas: (type, definition).
pub fn ros2_definitions() -> [(&'static str, String); 3] {
    let rule = "================================================================================\n";
    let header = "MSG: std_msgs/Header\nbuiltin_interfaces/Time stamp\nstring frame_id\n";
    let time = "MSG: builtin_interfaces/Time\nint32 sec\nuint32 nanosec\n";
    let quaternion =
        "MSG: geometry_msgs/Quaternion\nfloat64 x 0\nfloat64 y 0\nfloat64 z 0\nfloat64 w 1\n";
    let vector3 = "MSG: geometry_msgs/Vector3\nfloat64 x\nfloat64 y\nfloat64 z\n";
    let point = "MSG: geometry_msgs/Point\nfloat64 x\nfloat64 y\nfloat64 z\n";
    let join = |parts: &[&str]| parts.join(rule);
    [
        (
            "sensor_msgs/msg/Imu",
            join(&[
                "std_msgs/Header header\ngeometry_msgs/Quaternion orientation\nfloat64[9] orientation_covariance\ngeometry_msgs/Vector3 angular_velocity\nfloat64[9] angular_velocity_covariance\ngeometry_msgs/Vector3 linear_acceleration\nfloat64[9] linear_acceleration_covariance\n",
                header, time, quaternion, vector3,
            ]),
        ),
        (
            "sensor_msgs/msg/NavSatFix",
            join(&[
                "uint8 COVARIANCE_TYPE_UNKNOWN=0\nuint8 COVARIANCE_TYPE_APPROXIMATED=1\nuint8 COVARIANCE_TYPE_DIAGONAL_KNOWN=2\nuint8 COVARIANCE_TYPE_KNOWN=3\nstd_msgs/Header header\nsensor_msgs/NavSatStatus status\nfloat64 latitude\nfloat64 longitude\nfloat64 altitude\nfloat64[9] position_covariance\nuint8 position_covariance_type\n",
                header, time,
                "MSG: sensor_msgs/NavSatStatus\nint8 STATUS_NO_FIX=-1\nint8 STATUS_FIX=0\nint8 STATUS_SBAS_FIX=1\nint8 STATUS_GBAS_FIX=2\nuint16 SERVICE_GPS=1\nuint16 SERVICE_GLONASS=2\nuint16 SERVICE_COMPASS=4\nuint16 SERVICE_GALILEO=8\nint8 status\nuint16 service\n",
            ]),
        ),
        (
            "nav_msgs/msg/Odometry",
            join(&[
                "std_msgs/Header header\nstring child_frame_id\ngeometry_msgs/PoseWithCovariance pose\ngeometry_msgs/TwistWithCovariance twist\n",
                header, time,
                "MSG: geometry_msgs/PoseWithCovariance\ngeometry_msgs/Pose pose\nfloat64[36] covariance\n",
                "MSG: geometry_msgs/Pose\ngeometry_msgs/Point position\ngeometry_msgs/Quaternion orientation\n",
                point, quaternion,
                "MSG: geometry_msgs/TwistWithCovariance\ngeometry_msgs/Twist twist\nfloat64[36] covariance\n",
                "MSG: geometry_msgs/Twist\ngeometry_msgs/Vector3 linear\ngeometry_msgs/Vector3 angular\n",
                vector3,
            ]),
        ),
    ]
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A CDR little-endian Imu written field by field with the alignment CDR asks.
    fn cdr_imu(sec: i32, nsec: u32, frame: &str, gyro: [f64; 3]) -> Vec<u8> {
        let mut b = vec![0, 1, 0, 0];
        b.extend(sec.to_le_bytes());
        b.extend(nsec.to_le_bytes());
        b.extend((frame.len() as u32 + 1).to_le_bytes());
        b.extend(frame.as_bytes());
        b.push(0);
        while (b.len() - 4) % 8 != 0 {
            b.push(0);
        }
        let mut values = vec![0.0; 4 + 9];
        values.extend(gyro);
        values.extend([0.0; 9 + 3 + 9]);
        for v in values {
            b.extend(v.to_le_bytes());
        }
        b
    }

    #[test]
    fn cdr_imu_reads_after_the_frame_ids_padding() {
        let bytes = cdr_imu(7, 250_000_000, "imu", [0.5, -0.25, 2.0]);
        let msg = imu(&bytes, Encoding::Cdr).unwrap();
        assert_eq!(msg.header.stamp_ns, 7_250_000_000);
        assert_eq!(msg.header.frame_id, "imu");
        assert_eq!(msg.angular_velocity, [0.5, -0.25, 2.0]);
    }

    #[test]
    fn big_endian_cdr_reads_the_same_values() {
        let le = cdr_imu(3, 5, "ab", [1.5, 0.0, -3.0]);
        // Turn every field around: the stamp's two u32, the string length, the f64s.
        let mut be = vec![0, 0, 0, 0];
        be.extend(3u32.to_be_bytes());
        be.extend(5u32.to_be_bytes());
        be.extend(3u32.to_be_bytes());
        be.extend(b"ab\0");
        while (be.len() - 4) % 8 != 0 {
            be.push(0);
        }
        for chunk in le[be.len()..].chunks(8) {
            let v = f64::from_le_bytes(chunk.try_into().unwrap());
            be.extend(v.to_be_bytes());
        }
        assert_eq!(
            imu(&be, Encoding::Cdr).unwrap(),
            imu(&le, Encoding::Cdr).unwrap()
        );
    }

    #[test]
    fn a_short_message_names_the_field_and_offset() {
        let bytes = cdr_imu(1, 0, "imu", [0.0; 3]);
        let err = imu(&bytes[..100], Encoding::Cdr).unwrap_err();
        assert_eq!(err.field, "orientation_covariance");
        assert_eq!(err.offset, 100);
        let err = imu(&bytes[..2], Encoding::Cdr).unwrap_err();
        assert_eq!(err.field, "encapsulation");
    }

    #[test]
    fn an_imu_is_not_read_as_a_fix_nor_the_other_way() {
        let bytes = cdr_imu(1, 0, "imu", [0.0; 3]);
        let err = nav_sat_fix(&bytes, Encoding::Cdr).unwrap_err();
        assert!(err.message.contains("not a sensor_msgs/NavSatFix"), "{err}");
    }

    #[test]
    fn encoded_messages_decode_to_themselves() {
        let header = |frame: &str| Header {
            stamp_ns: 1_700_000_000_123_456_789,
            frame_id: frame.into(),
        };
        let imu_msg = Imu {
            header: header("imu"),
            orientation: [0.0, 0.0, 0.0, 1.0],
            orientation_covariance: [-1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
            angular_velocity: [0.1, -0.2, 0.3],
            angular_velocity_covariance: [1e-6; 9],
            linear_acceleration: [0.5, 0.25, 9.81],
            linear_acceleration_covariance: [1e-3; 9],
        };
        assert_eq!(
            imu(&encode_imu_cdr(&imu_msg), Encoding::Cdr).unwrap(),
            imu_msg
        );
        let fix = NavSatFix {
            header: header("gnss"),
            status: -1,
            latitude_deg: 46.5,
            longitude_deg: 6.6,
            altitude_m: 410.0,
            position_covariance: [2.0; 9],
            position_covariance_type: 2,
        };
        assert_eq!(
            nav_sat_fix(&encode_nav_sat_fix_cdr(&fix), Encoding::Cdr).unwrap(),
            fix
        );
        let odom = Odometry {
            header: header("map"),
            child_frame_id: "base_link".into(),
            position: [1.0, 2.0, 3.0],
            orientation: [0.0, 0.0, 0.6, 0.8],
            linear_velocity: [4.0, 0.5, -0.25],
            angular_velocity: [0.0, 0.0, 0.125],
        };
        assert_eq!(
            odometry(&encode_odometry_cdr(&odom), Encoding::Cdr).unwrap(),
            odom
        );
    }

    #[test]
    fn ros1_header_has_seq_and_unterminated_strings() {
        let mut b = Vec::new();
        b.extend(42u32.to_le_bytes());
        b.extend(9u32.to_le_bytes());
        b.extend(1u32.to_le_bytes());
        b.extend(2u32.to_le_bytes());
        b.extend(b"gp");
        b.push(0xff); // status -1
        b.extend(1u16.to_le_bytes());
        for v in [46.5, 6.5, 400.0] {
            b.extend(f64::to_le_bytes(v));
        }
        for _ in 0..9 {
            b.extend(0f64.to_le_bytes());
        }
        b.push(2);
        let fix = nav_sat_fix(&b, Encoding::Ros1).unwrap();
        assert_eq!(fix.header.stamp_ns, 9_000_000_001);
        assert_eq!(fix.header.frame_id, "gp");
        assert_eq!(fix.status, -1);
        assert_eq!(fix.latitude_deg, 46.5);
        assert_eq!(fix.position_covariance_type, 2);
    }
}
