//! The GNSS receiver on the board: u-blox UBX bytes, as a UART delivers them in pieces of
//! any size, to the log's [`GnssFix`]. The framing, checksum and field decoding are the
//! `ublox` crate's (no_std, a fixed buffer, no allocation; 4.4 KB of flash for the parser
//! with NAV-PVT at opt-level "s"), fuzzed here: arbitrary bytes never panic it. NAV-PVT
//! carries the time of week but not the week; the week comes from its UTC date and time,
//! which are GPS time less the leap seconds, and the time of week must agree with them
//! (a solution whose date or time is not valid, or disagrees, gives no fix: the log's
//! timescale needs the week).
//!
//! In front of the crate's parser sits a framer ([`NavPvtFramer`]) that passes on only whole
//! NAV-PVT frames whose checksum holds: it looks for NAV-PVT's exact six-byte header, and
//! when a frame's checksum fails it searches again from the byte after the false start. A
//! parser that trusts the length after any sync pair would let noise holding `B5 62` and a
//! large length swallow the real frames that follow (the proptest below found one); the
//! framer loses at most the bytes before a real header. The board uses nothing but NAV-PVT.

// Float methods (round, sqrt) without std come from nalgebra's ComplexField.
#[allow(unused_imports)]
use nalgebra::ComplexField;
use ublox::nav_pvt::common::NavPvtValidFlags;
use ublox::proto23::{PacketRef, Proto23};
use ublox::{FixedBuffer, GnssFixType, Parser, UbxPacket};

use crate::log::GnssFix;

/// Bytes the parser holds: a NAV-PVT frame is 100; longer messages are skipped whole.
const PARSER_BYTES: usize = 256;

/// GPS time less UTC since the start of 2017, s (the receiver's NAV-TIMELS says when it
/// changes).
pub const LEAP_SECONDS_2017: u32 = 18;

/// Seconds in a GPS week.
const WEEK_S: u64 = 604_800;

/// What the receiver's bytes gave so far.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ReceiverCounts {
    /// NAV-PVT solutions turned into fixes.
    pub fixes: u32,
    /// NAV-PVT solutions without a valid date and time (or whose time of week disagrees
    /// with them): no fix.
    pub untimed: u32,
    /// Frames the parser refused (bad checksum, bad length, an unknown or malformed
    /// message).
    pub malformed: u32,
}

/// u-blox bytes in, fixes out (see the module's note).
pub struct UbxReceiver {
    framer: NavPvtFramer,
    parser: Parser<FixedBuffer<PARSER_BYTES>, Proto23>,
    leap_seconds: u32,
    counts: ReceiverCounts,
}

impl UbxReceiver {
    /// A receiver whose UTC is GPS time less `leap_seconds`.
    pub fn new(leap_seconds: u32) -> Self {
        Self {
            framer: NavPvtFramer::new(),
            parser: Parser::with_fixed_buffer(),
            leap_seconds,
            counts: ReceiverCounts::default(),
        }
    }

    /// What the bytes gave so far.
    pub fn counts(&self) -> ReceiverCounts {
        self.counts
    }

    /// Feeds `bytes` as read from the UART; `on_fix` gets every NAV-PVT solution with a
    /// valid time, in order.
    pub fn push(&mut self, bytes: &[u8], mut on_fix: impl FnMut(GnssFix)) {
        for &byte in bytes {
            match self.framer.push(byte) {
                Framed::Frame(frame) => self.parse(&frame, &mut on_fix),
                Framed::BadChecksum => self.counts.malformed += 1,
                Framed::Pending => {}
            }
        }
    }

    /// One whole, checked NAV-PVT frame through the crate's parser.
    fn parse(&mut self, frame: &[u8], on_fix: &mut impl FnMut(GnssFix)) {
        let leap = self.leap_seconds;
        let mut counts = self.counts;
        let mut packets = self.parser.consume_ubx(frame);
        while let Some(packet) = packets.next() {
            match packet {
                Ok(UbxPacket::Proto23(PacketRef::NavPvt(pvt))) => {
                    let valid = pvt.valid();
                    let timed = valid.contains(NavPvtValidFlags::VALID_DATE)
                        && valid.contains(NavPvtValidFlags::VALID_TIME);
                    let t_us = gps_time_us(
                        (pvt.year(), pvt.month(), pvt.day()),
                        (pvt.hour(), pvt.min(), pvt.sec()),
                        pvt.itow(),
                        leap,
                    )
                    .filter(|_| timed);
                    let Some(t_us) = t_us else {
                        counts.untimed += 1;
                        continue;
                    };
                    counts.fixes += 1;
                    on_fix(GnssFix {
                        t_us,
                        lat_rad: pvt.latitude().to_radians(),
                        lon_rad: pvt.longitude().to_radians(),
                        h_m: pvt.height_above_ellipsoid() as f32,
                        vel_ned_m_s: [
                            pvt.vel_north() as f32,
                            pvt.vel_east() as f32,
                            pvt.vel_down() as f32,
                        ],
                        pos_sigma_m: pvt.horizontal_accuracy() as f32,
                        vel_sigma_m_s: pvt.speed_accuracy() as f32,
                        num_sats: pvt.num_satellites(),
                        fix_type: fix_code(pvt.fix_type()),
                    });
                }
                Ok(_) => {}
                Err(_) => counts.malformed += 1,
            }
        }
        self.counts = counts;
    }
}

/// NAV-PVT's header: sync, class 0x01, id 0x07, payload length 92 (little-endian).
const NAV_PVT_HEADER: [u8; 6] = [0xB5, 0x62, 0x01, 0x07, 92, 0];
/// What one byte gave the framer.
enum Framed {
    Pending,
    /// A whole frame whose checksum holds.
    Frame([u8; NAV_PVT_FRAME_LEN]),
    /// A whole frame whose checksum failed: the search started again after its first byte.
    BadChecksum,
}

/// Whole NAV-PVT frames out of a byte stream (see the module's note).
struct NavPvtFramer {
    buf: [u8; NAV_PVT_FRAME_LEN],
    len: usize,
}

impl NavPvtFramer {
    const fn new() -> Self {
        Self {
            buf: [0; NAV_PVT_FRAME_LEN],
            len: 0,
        }
    }

    fn push(&mut self, byte: u8) -> Framed {
        if let Some(slot) = self.buf.get_mut(self.len) {
            *slot = byte;
            self.len += 1;
        }
        if self.len <= NAV_PVT_HEADER.len() {
            if !self.holds_header_start(0) {
                self.resync();
            }
            return Framed::Pending;
        }
        if self.len < NAV_PVT_FRAME_LEN {
            return Framed::Pending;
        }
        if checksum_holds(&self.buf) {
            self.len = 0;
            Framed::Frame(self.buf)
        } else {
            self.resync();
            Framed::BadChecksum
        }
    }

    /// Whether the bytes from `from` on are the start of a header (or all of one).
    fn holds_header_start(&self, from: usize) -> bool {
        let held = self.buf.get(from..self.len).unwrap_or(&[]);
        held.iter()
            .zip(NAV_PVT_HEADER)
            .all(|(&byte, expected)| byte == expected)
    }

    /// Drops the first byte, and the ones after it up to where a header could start.
    fn resync(&mut self) {
        let start = (1..self.len)
            .find(|&from| self.holds_header_start(from))
            .unwrap_or(self.len);
        self.buf.copy_within(start..self.len, 0);
        self.len -= start;
    }
}

/// UBX's 8-bit Fletcher checksum over class, id, length and payload.
fn checksum_holds(frame: &[u8; NAV_PVT_FRAME_LEN]) -> bool {
    let (mut a, mut b) = (0u8, 0u8);
    for &byte in &frame[2..NAV_PVT_FRAME_LEN - 2] {
        a = a.wrapping_add(byte);
        b = b.wrapping_add(a);
    }
    frame[NAV_PVT_FRAME_LEN - 2] == a && frame[NAV_PVT_FRAME_LEN - 1] == b
}

/// The log's fix-type code of a NAV-PVT fix type.
fn fix_code(fix: GnssFixType) -> u8 {
    match fix {
        GnssFixType::NoFix => 0,
        GnssFixType::DeadReckoningOnly => 1,
        GnssFixType::Fix2D => 2,
        GnssFixType::Fix3D => 3,
        GnssFixType::GPSPlusDeadReckoning => 4,
        GnssFixType::TimeOnlyFix => 5,
        // Codes the protocol reserves: a solution of no known kind is none.
        _ => 0,
    }
}

/// Days from 1970-01-01 to a civil (proleptic Gregorian) date; None for a date that is not
/// one (Howard Hinnant's days_from_civil).
fn days_since_1970(year: u16, month: u8, day: u8) -> Option<i64> {
    if !(1..=12).contains(&month) || !(1..=31).contains(&day) {
        return None;
    }
    let y = i64::from(year) - i64::from(month <= 2);
    let era = y.div_euclid(400);
    let year_of_era = y - era * 400;
    let m = i64::from(month);
    let day_of_year = (153 * (m + if m > 2 { -3 } else { 9 }) + 2) / 5 + i64::from(day) - 1;
    let day_of_era = year_of_era * 365 + year_of_era / 4 - year_of_era / 100 + day_of_year;
    Some(era * 146_097 + day_of_era - 719_468)
}

/// GPS time in microseconds since 1980-01-06 of a NAV-PVT solution: the week from its UTC
/// date and time plus the leap seconds, the time within the week from its time of week
/// (`itow_ms`, to the millisecond); None for an invalid date or a time of week more than
/// a second from the date's.
fn gps_time_us(
    (year, month, day): (u16, u8, u8),
    (hour, minute, second): (u8, u8, u8),
    itow_ms: u32,
    leap_seconds: u32,
) -> Option<u64> {
    // UTC may lie up to the leap seconds before GPS time's start (the day before).
    let days = days_since_1970(year, month, day)? - GPS_EPOCH_DAYS_SINCE_1970;
    if hour > 23 || minute > 59 || second > 60 {
        return None;
    }
    let utc_s = days * 86_400 + i64::from(hour) * 3600 + i64::from(minute) * 60 + i64::from(second);
    let gps_s = u64::try_from(utc_s + i64::from(leap_seconds)).ok()?;
    let tow_s = u64::from(itow_ms) / 1000;
    if tow_s >= WEEK_S {
        return None;
    }
    // The week whose time of week lies nearest the date's (a solution near midnight on
    // Saturday may round either side of the week's start).
    let week = (gps_s + WEEK_S / 2 - tow_s) / WEEK_S;
    let from_tow_ms = week * WEEK_S * 1000 + u64::from(itow_ms);
    let apart_ms = from_tow_ms.abs_diff(gps_s * 1000);
    (apart_ms <= 1000).then_some(from_tow_ms * 1000)
}

/// Bytes of a NAV-PVT frame: sync, class, id, length, the 92-byte payload, checksum.
pub const NAV_PVT_FRAME_LEN: usize = 100;

/// Days from 1970-01-01 to 1980-01-06, the start of GPS time.
const GPS_EPOCH_DAYS_SINCE_1970: i64 = 3657;

/// The civil date of a day count from 1970-01-01 (Howard Hinnant's civil_from_days).
fn civil_from_days(days: i64) -> (u16, u8, u8) {
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let day_of_era = z - era * 146_097;
    let year_of_era =
        (day_of_era - day_of_era / 1460 + day_of_era / 36_524 - day_of_era / 146_096) / 365;
    let day_of_year = day_of_era - (365 * year_of_era + year_of_era / 4 - year_of_era / 100);
    let mp = (5 * day_of_year + 2) / 153;
    let day = day_of_year - (153 * mp + 2) / 5 + 1;
    let month = if mp < 10 { mp + 3 } else { mp - 9 };
    let year = year_of_era + era * 400 + i64::from(month <= 2);
    (year as u16, month as u8, day as u8)
}

/// The NAV-PVT frame a u-blox receiver sends for `fix` (what the simulator's replay input
/// carries, so the board reads the receiver's own bytes): its time of week to the
/// millisecond, its UTC date and time (GPS time less `leap_seconds`, the fraction in the
/// nanosecond field), position to 1e-7 deg and 1 mm, velocity and accuracies to 1 mm and
/// 1 mm/s, date and time flagged valid.
pub fn encode_nav_pvt(fix: &GnssFix, leap_seconds: u32) -> [u8; NAV_PVT_FRAME_LEN] {
    let mut frame = [0u8; NAV_PVT_FRAME_LEN];
    frame[..6].copy_from_slice(&[0xB5, 0x62, 0x01, 0x07, 92, 0]);
    let p = &mut frame[6..98];
    let mut put = |at: usize, bytes: &[u8]| p[at..at + bytes.len()].copy_from_slice(bytes);
    let itow_ms = (fix.t_us / 1000) % (WEEK_S * 1000);
    put(0, &(itow_ms as u32).to_le_bytes());
    // UTC since GPS time's start, which is negative for the first leap seconds of it.
    let utc_us = fix.t_us as i64 - i64::from(leap_seconds) * 1_000_000;
    let utc_s = utc_us.div_euclid(1_000_000);
    let (year, month, day) = civil_from_days(utc_s.div_euclid(86_400) + GPS_EPOCH_DAYS_SINCE_1970);
    put(4, &year.to_le_bytes());
    let of_day = utc_s.rem_euclid(86_400);
    put(
        6,
        &[
            month,
            day,
            (of_day / 3600) as u8,
            (of_day / 60 % 60) as u8,
            (of_day % 60) as u8,
        ],
    );
    put(11, &[0x07]);
    put(
        16,
        &((utc_us.rem_euclid(1_000_000) * 1000) as i32).to_le_bytes(),
    );
    put(20, &[fix.fix_type, 0x01, 0, fix.num_sats]);
    let e7 = |rad: f64| (rad.to_degrees() * 1e7).round() as i32;
    let milli = |x: f32| (f64::from(x) * 1e3).round() as i32;
    put(24, &e7(fix.lon_rad).to_le_bytes());
    put(28, &e7(fix.lat_rad).to_le_bytes());
    put(32, &milli(fix.h_m).to_le_bytes());
    put(36, &milli(fix.h_m).to_le_bytes());
    put(40, &(milli(fix.pos_sigma_m).max(0) as u32).to_le_bytes());
    put(44, &(milli(fix.pos_sigma_m).max(0) as u32).to_le_bytes());
    for (k, v) in fix.vel_ned_m_s.iter().enumerate() {
        put(48 + 4 * k, &milli(*v).to_le_bytes());
    }
    let ground =
        (fix.vel_ned_m_s[0] * fix.vel_ned_m_s[0] + fix.vel_ned_m_s[1] * fix.vel_ned_m_s[1]).sqrt();
    put(60, &milli(ground).to_le_bytes());
    put(68, &(milli(fix.vel_sigma_m_s).max(0) as u32).to_le_bytes());
    let (mut a, mut b) = (0u8, 0u8);
    for byte in &frame[2..98] {
        a = a.wrapping_add(*byte);
        b = b.wrapping_add(a);
    }
    frame[98] = a;
    frame[99] = b;
    frame
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A NAV-PVT frame (UBX protocol 23 layout, 92-byte payload) with its checksum.
    fn nav_pvt_frame(fields: &Pvt) -> Vec<u8> {
        let mut p = vec![0u8; 92];
        let put = |p: &mut Vec<u8>, at: usize, bytes: &[u8]| {
            p[at..at + bytes.len()].copy_from_slice(bytes)
        };
        put(&mut p, 0, &fields.itow_ms.to_le_bytes());
        put(&mut p, 4, &fields.date.0.to_le_bytes());
        p[6] = fields.date.1;
        p[7] = fields.date.2;
        p[8] = fields.time.0;
        p[9] = fields.time.1;
        p[10] = fields.time.2;
        p[11] = fields.valid;
        p[20] = 3;
        p[23] = 14;
        put(&mut p, 24, &fields.lon_e7.to_le_bytes());
        put(&mut p, 28, &fields.lat_e7.to_le_bytes());
        put(&mut p, 32, &fields.height_mm.to_le_bytes());
        put(&mut p, 40, &1500u32.to_le_bytes());
        put(&mut p, 48, &1234i32.to_le_bytes());
        put(&mut p, 52, &(-567i32).to_le_bytes());
        put(&mut p, 56, &89i32.to_le_bytes());
        put(&mut p, 68, &120u32.to_le_bytes());
        let mut frame = vec![0xB5, 0x62, 0x01, 0x07, 92, 0];
        frame.extend_from_slice(&p);
        let (mut a, mut b) = (0u8, 0u8);
        for byte in &frame[2..] {
            a = a.wrapping_add(*byte);
            b = b.wrapping_add(a);
        }
        frame.extend_from_slice(&[a, b]);
        frame
    }

    struct Pvt {
        itow_ms: u32,
        date: (u16, u8, u8),
        time: (u8, u8, u8),
        valid: u8,
        lat_e7: i32,
        lon_e7: i32,
        height_mm: i32,
    }

    /// 2026-11-25 12:34:56 UTC: GPS week 2446, Wednesday, 12:35:14 GPS.
    fn example() -> Pvt {
        Pvt {
            itow_ms: (3 * 86_400 + 12 * 3600 + 35 * 60 + 14) * 1000 + 200,
            date: (2026, 11, 25),
            time: (12, 34, 56),
            valid: 0x03,
            lat_e7: 465_191_234,
            lon_e7: 66_323_456,
            height_mm: 412_345,
        }
    }

    fn fixes(receiver: &mut UbxReceiver, bytes: &[u8], chunk: usize) -> Vec<GnssFix> {
        let mut out = Vec::new();
        for piece in bytes.chunks(chunk.max(1)) {
            receiver.push(piece, |f| out.push(f));
        }
        out
    }

    /// A solution read in pieces of any size gives the fix its fields say, at the GPS time
    /// of its week and time of week.
    #[test]
    fn a_nav_pvt_solution_becomes_a_fix_at_its_gps_time() {
        let frame = nav_pvt_frame(&example());
        for chunk in [1, 3, 7, 100, 1000] {
            let mut receiver = UbxReceiver::new(LEAP_SECONDS_2017);
            let got = fixes(&mut receiver, &frame, chunk);
            assert_eq!(got.len(), 1, "chunk {chunk}");
            let fix = got[0];
            let week = 2446u64;
            let tow_ms = u64::from(example().itow_ms);
            assert_eq!(fix.t_us, (week * WEEK_S * 1000 + tow_ms) * 1000);
            assert!((fix.lat_rad - 46.519_123_4f64.to_radians()).abs() < 1e-12);
            assert!((fix.lon_rad - 6.632_345_6f64.to_radians()).abs() < 1e-12);
            assert!((fix.h_m - 412.345).abs() < 1e-3);
            assert_eq!(fix.vel_ned_m_s, [1.234, -0.567, 0.089]);
            assert_eq!((fix.pos_sigma_m, fix.vel_sigma_m_s), (1.5, 0.12));
            assert_eq!((fix.num_sats, fix.fix_type), (14, 3));
        }
    }

    /// A damaged checksum gives no fix and is counted; a solution without a valid date, or
    /// whose time of week disagrees with its date, gives none either.
    #[test]
    fn damaged_or_untimed_solutions_give_no_fix() {
        let mut receiver = UbxReceiver::new(LEAP_SECONDS_2017);
        let mut frame = nav_pvt_frame(&example());
        let last = frame.len() - 1;
        frame[last] ^= 0xFF;
        assert!(fixes(&mut receiver, &frame, 16).is_empty());
        assert_eq!(receiver.counts().malformed, 1);
        let undated = nav_pvt_frame(&Pvt {
            valid: 0x02,
            ..example()
        });
        let disagreeing = nav_pvt_frame(&Pvt {
            itow_ms: 1000,
            ..example()
        });
        let mut bytes = undated;
        bytes.extend(disagreeing);
        assert!(fixes(&mut receiver, &bytes, 50).is_empty());
        assert_eq!(receiver.counts().untimed, 2);
    }

    /// A fix encoded as a receiver would send it comes back from the receiver as it was,
    /// to the frame's resolution (1e-7 deg, 1 mm, 1 mm/s, 1 ms), across a week's start,
    /// a year's end and GPS time's first seconds.
    #[test]
    fn an_encoded_fix_comes_back_as_it_was() {
        let start_of_2027 =
            ((days_since_1970(2027, 1, 1).unwrap() - 3657) as u64 * 86_400 + 18) * 1_000_000;
        for t_us in [
            1_479_645_314_200_000u64,
            start_of_2027 - 100_000,
            start_of_2027 + 300_000,
        ] {
            let fix = GnssFix {
                t_us,
                lat_rad: 0.811_911_46,
                lon_rad: -0.114_612_28,
                h_m: 400.123,
                vel_ned_m_s: [12.345, -3.21, 0.05],
                pos_sigma_m: 0.3,
                vel_sigma_m_s: 0.05,
                num_sats: 11,
                fix_type: 3,
            };
            let mut receiver = UbxReceiver::new(LEAP_SECONDS_2017);
            let got = fixes(&mut receiver, &encode_nav_pvt(&fix, LEAP_SECONDS_2017), 13);
            assert_eq!(got.len(), 1, "{t_us}");
            let back = got[0];
            assert_eq!(back.t_us, t_us);
            assert!(
                (back.lat_rad - fix.lat_rad).abs() < 1e-9
                    && (back.lon_rad - fix.lon_rad).abs() < 1e-9
            );
            assert!((back.h_m - fix.h_m).abs() < 1e-3);
            for k in 0..3 {
                assert!((back.vel_ned_m_s[k] - fix.vel_ned_m_s[k]).abs() < 1e-3);
            }
            assert_eq!(
                (
                    back.pos_sigma_m,
                    back.vel_sigma_m_s,
                    back.num_sats,
                    back.fix_type
                ),
                (0.3, 0.05, 11, 3)
            );
        }
    }

    /// Noise that holds NAV-PVT's whole header, 50 bytes before a real frame: the false
    /// frame's checksum fails, and the search resumes inside it, where the real frames are.
    #[test]
    fn a_false_frame_start_does_not_hide_the_frames_that_follow() {
        let mut bytes = std::vec![0xB5, 0x62, 0x01, 0x07, 92, 0];
        bytes.extend((0..44u8).map(|k| k.wrapping_mul(37)));
        let frame = nav_pvt_frame(&example());
        bytes.extend_from_slice(&frame);
        bytes.extend_from_slice(&frame);
        for chunk in [1, 7, 100, 400] {
            let mut receiver = UbxReceiver::new(LEAP_SECONDS_2017);
            assert_eq!(
                fixes(&mut receiver, &bytes, chunk).len(),
                2,
                "pieces of {chunk}"
            );
            assert_eq!(receiver.counts().malformed, 1);
        }
    }

    proptest::proptest! {


        // Seeded: every failure reproduces (the project's rule for random generators).


        #![proptest_config(proptest::test_runner::Config {


            rng_seed: proptest::test_runner::RngSeed::Fixed(0x5eed0901),


            failure_persistence: Some(std::boxed::Box::new(


                proptest::test_runner::FileFailurePersistence::Off


            )),


            ..proptest::test_runner::Config::default()


        })]
        /// Arbitrary bytes, in arbitrary pieces, never panic the receiver; a solution that
        /// follows them whole is still found.
        #[test]
        fn arbitrary_bytes_never_panic_and_do_not_hide_a_following_fix(
            noise in proptest::collection::vec(proptest::num::u8::ANY, 0..2000),
            chunk in 1usize..300,
        ) {
            let mut receiver = UbxReceiver::new(LEAP_SECONDS_2017);
            let mut bytes = noise;
            let frame = nav_pvt_frame(&example());
            bytes.extend_from_slice(&frame);
            bytes.extend_from_slice(&frame);
            let got = fixes(&mut receiver, &bytes, chunk);
            proptest::prop_assert!(!got.is_empty());
        }

        /// Solutions with arbitrary bytes before, between and after them, read in arbitrary
        /// pieces, all come out, in order, and nothing else does: the noise may hold partial
        /// or whole false headers, which cost the framer only bytes that are not frames.
        #[test]
        fn solutions_interleaved_with_noise_are_all_recovered(
            gaps in proptest::collection::vec(
                proptest::collection::vec(proptest::num::u8::ANY, 0..300),
                1..8,
            ),
            header_in_noise in proptest::collection::vec(0usize..8, 0..8),
            chunk in 1usize..250,
        ) {
            let mut bytes = std::vec::Vec::new();
            let mut sent = std::vec::Vec::new();
            for (k, gap) in gaps.iter().enumerate() {
                bytes.extend_from_slice(gap);
                // Some gaps end with the first bytes of a header (or all of one), the case
                // where a framer that trusts a sync pair loses the real frame behind it.
                if let Some(&n) = header_in_noise.get(k) {
                    bytes.extend_from_slice(&NAV_PVT_HEADER[..n.min(NAV_PVT_HEADER.len())]);
                }
                let fix = GnssFix {
                    t_us: 1_479_645_314_200_000 + k as u64 * 200_000,
                    lat_rad: 0.811_911_46,
                    lon_rad: -0.114_612_28,
                    h_m: 400.0 + k as f32,
                    vel_ned_m_s: [1.0, -2.0, 0.5],
                    pos_sigma_m: 0.3,
                    vel_sigma_m_s: 0.05,
                    num_sats: 11,
                    fix_type: 3,
                };
                bytes.extend_from_slice(&encode_nav_pvt(&fix, LEAP_SECONDS_2017));
                sent.push(fix.t_us);
            }
            bytes.extend_from_slice(&gaps[0]);
            let mut receiver = UbxReceiver::new(LEAP_SECONDS_2017);
            let got: std::vec::Vec<u64> =
                fixes(&mut receiver, &bytes, chunk).iter().map(|f| f.t_us).collect();
            proptest::prop_assert_eq!(&got, &sent);
            proptest::prop_assert_eq!(receiver.counts().fixes as usize, sent.len());
        }

        /// Frames damaged anywhere (a byte changed, as line noise does) never panic the
        /// receiver, whatever the damage makes of a length or a class.
        #[test]
        fn damaged_frames_never_panic(
            damage in proptest::collection::vec((0usize..500, proptest::num::u8::ANY), 1..20),
            chunk in 1usize..120,
        ) {
            let mut receiver = UbxReceiver::new(LEAP_SECONDS_2017);
            let mut bytes: Vec<u8> = (0..5).flat_map(|_| nav_pvt_frame(&example())).collect();
            for (at, value) in damage {
                let at = at % bytes.len();
                bytes[at] = value;
            }
            let got = fixes(&mut receiver, &bytes, chunk);
            let counts = receiver.counts();
            proptest::prop_assert_eq!(got.len() as u32, counts.fixes);
        }
    }
}
