//! The simulated MEMS IMUs as the board would see them: raw integer counts stamped in
//! microseconds of GPS time, written as the firmware's replay input
//! (`dynacal_core::replay`) and as the board's log (`dynacal_core::log` frames), so the
//! firmware and the decoder can be exercised on simulated data with a known truth.
//!
//! Counts: each channel's reported value is divided by the IMU's LSB and rounded to the
//! nearest integer. The LSB is the model's `quantization_step` when all three gyro (or all
//! three accelerometer) channels give the same one, else [`DEFAULT_GYRO_LSB_RAD_S`] /
//! [`DEFAULT_ACCEL_LSB_M_S2`]; these are also the header's scale factors, so a decoder
//! gets counts x LSB back.
//!
//! Time stamps: the board's timer is disciplined to GPS and captures each IMU's data-ready
//! edge, which follows the IMU's oscillator tick; so sample k is stamped with its tick's
//! true time `clock.tick_t_s[k]`, rounded to the microsecond. Sampling jitter and the IMU's
//! time offset (latency) are invisible to the board, as on real hardware: they stay errors
//! for calibration to find. PPS edges are at every whole second from the first sample's
//! second to the last sample, and a PPS edge sorts before a sample with the same stamp.
//! GNSS fixes of the simulated receiver go into the log (not the replay, which carries
//! only IMU samples and PPS).

use std::io::Write;

use dynacal_core::log::{
    encode_frame, Frame, GnssFix, Header, ImuConfig, ImuSampleSet, LogError, PpsEvent,
    MAX_FRAME_LEN, MAX_IMUS, PROTOCOL_VERSION,
};
use dynacal_core::replay::{
    encode_header, encode_record, ReplayError, ReplayHeader, ReplayImu, ReplayRecord,
    MAX_HEADER_LEN, MAX_RECORD_LEN,
};

use super::{SimModel, SimOutput};
use crate::interchange::CHANNELS;

/// Gyro LSB when the model has no common gyro `quantization_step`, rad/s per count
/// (0.2 deg/h: far below any MEMS gyro's noise, and +-2147 rad/s fits an i32).
pub const DEFAULT_GYRO_LSB_RAD_S: f64 = 1e-6;
/// Accelerometer LSB when the model has no common accelerometer `quantization_step`,
/// m/s^2 per count (about 1 ug; +-21474 m/s^2 fits an i32).
pub const DEFAULT_ACCEL_LSB_M_S2: f64 = 1e-5;
/// Board name written in the log header.
pub const BOARD_NAME: &str = "dynacal simulate";

/// Errors turning a simulation into board data.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum BoardError {
    #[error("the model has no MEMS IMU; a replay needs at least one")]
    NoImu,
    #[error("the model has {0} MEMS IMUs; the board logs at most {MAX_IMUS}")]
    TooManyImus(usize),
    #[error("IMU `{0}`: the name must be ASCII of at most 16 characters to be a board model name")]
    BadName(String),
    #[error(
        "IMU `{imu}`: the {kind} channels have different quantization_step values; \
         one LSB per sensor is needed for raw counts"
    )]
    MixedSteps { imu: String, kind: &'static str },
    #[error("IMU `{imu}`, sample {sample}, channel {channel}: {value} does not fit an i32 count of LSB {lsb}")]
    CountOverflow {
        imu: String,
        sample: usize,
        channel: &'static str,
        value: f64,
        lsb: f64,
    },
    #[error("IMU `{imu}`, sample {sample}: stamp {t_us} us does not follow {previous_t_us} us")]
    TimeNotIncreasing {
        imu: String,
        sample: usize,
        t_us: u64,
        previous_t_us: u64,
    },
    #[error("replay encoding: {0}")]
    Replay(ReplayError),
    #[error("log encoding: {0}")]
    Log(LogError),
    #[error("{0}")]
    Io(#[from] std::io::Error),
}

/// One MEMS IMU as raw counts.
#[derive(Debug, Clone, PartialEq)]
pub struct BoardImu {
    /// Id, model name, rate and scale factors (the LSBs).
    pub config: ReplayImu,
    /// Board stamps, GPS time, microseconds; strictly increasing.
    pub t_us: Vec<u64>,
    pub gyro_counts: Vec<[i32; 3]>,
    pub accel_counts: Vec<[i32; 3]>,
}

/// Everything the board would record in a simulated run.
#[derive(Debug, Clone, PartialEq)]
pub struct BoardRecording {
    /// The MEMS IMUs in model order; `imu_id` is the index.
    pub imus: Vec<BoardImu>,
    /// PPS edges, microseconds of GPS time.
    pub pps_t_us: Vec<u64>,
    /// GNSS fixes of the simulated receiver.
    pub gnss: Vec<GnssFix>,
}

/// The LSB of channels `first..first + 3`: their common `quantization_step`, else `default`.
fn lsb_of(model: &crate::model::ImuModel, first: usize, default: f64) -> Result<f64, BoardError> {
    let steps: Vec<Option<f64>> = (first..first + 3)
        .map(|i| model.channel(i).quantization_step)
        .collect();
    match steps[0] {
        Some(q) if steps.iter().all(|s| *s == Some(q)) => Ok(q),
        None if steps.iter().all(Option::is_none) => Ok(default),
        _ => Err(BoardError::MixedSteps {
            imu: model.name.clone(),
            kind: if first == 0 { "gyro" } else { "accelerometer" },
        }),
    }
}

/// Seconds to microseconds, rounded to the nearest (times here are non-negative and far
/// below 2^53 us).
fn to_us(t_s: f64) -> u64 {
    (t_s * 1e6).round().max(0.0) as u64
}

/// The board's view of `out` (simulated from `model`).
pub fn board_recording(out: &SimOutput, model: &SimModel) -> Result<BoardRecording, BoardError> {
    if out.imus.is_empty() {
        return Err(BoardError::NoImu);
    }
    if out.imus.len() > MAX_IMUS {
        return Err(BoardError::TooManyImus(out.imus.len()));
    }
    let mut imus = Vec::with_capacity(out.imus.len());
    for (id, (run, m)) in out.imus.iter().zip(&model.imus).enumerate() {
        let name = ReplayImu::model_field(&run.name)
            .ok_or_else(|| BoardError::BadName(run.name.clone()))?;
        let lsb = [
            lsb_of(m, 0, DEFAULT_GYRO_LSB_RAD_S)?,
            lsb_of(m, 3, DEFAULT_ACCEL_LSB_M_S2)?,
        ];
        let config = ReplayImu {
            imu_id: id as u8,
            model: name,
            sample_rate_hz: m.rate_hz as f32,
            gyro_scale_rad_s_per_count: lsb[0],
            accel_scale_m_s2_per_count: lsb[1],
        };
        let rec = &run.recording;
        let (Some(gyro), Some(accel)) = (&rec.gyro_rad_s, &rec.accel_m_s2) else {
            unreachable!("simulated IMUs always have all six channels")
        };
        let n = rec.t_s.len();
        let count = |values: &[f64], k: usize, channel: usize| -> Result<i32, BoardError> {
            let l = lsb[channel / 3];
            let c = (values[k] / l).round();
            if c.abs() <= i32::MAX as f64 {
                Ok(c as i32)
            } else {
                Err(BoardError::CountOverflow {
                    imu: run.name.clone(),
                    sample: k,
                    channel: CHANNELS[channel],
                    value: values[k],
                    lsb: l,
                })
            }
        };
        let mut imu = BoardImu {
            config,
            t_us: Vec::with_capacity(n),
            gyro_counts: Vec::with_capacity(n),
            accel_counts: Vec::with_capacity(n),
        };
        for k in 0..n {
            let t_us = to_us(run.clock.tick_t_s[k]);
            if let Some(&previous_t_us) = imu.t_us.last() {
                if t_us <= previous_t_us {
                    return Err(BoardError::TimeNotIncreasing {
                        imu: run.name.clone(),
                        sample: k,
                        t_us,
                        previous_t_us,
                    });
                }
            }
            imu.t_us.push(t_us);
            imu.gyro_counts.push([
                count(&gyro[0], k, 0)?,
                count(&gyro[1], k, 1)?,
                count(&gyro[2], k, 2)?,
            ]);
            imu.accel_counts.push([
                count(&accel[0], k, 3)?,
                count(&accel[1], k, 4)?,
                count(&accel[2], k, 5)?,
            ]);
        }
        imus.push(imu);
    }
    let first_us = imus.iter().filter_map(|i| i.t_us.first()).min().copied();
    let last_us = imus.iter().filter_map(|i| i.t_us.last()).max().copied();
    let pps_t_us = match (first_us, last_us) {
        (Some(first), Some(last)) => (first.div_ceil(1_000_000)..=last / 1_000_000)
            .map(|s| s * 1_000_000)
            .collect(),
        _ => Vec::new(),
    };
    let gnss = out.gnss.as_ref().map_or_else(Vec::new, gnss_fixes);
    Ok(BoardRecording {
        imus,
        pps_t_us,
        gnss,
    })
}

/// The simulated receiver's fixes as the board's GNSS frames: the stated horizontal sigma
/// is the root sum of squares of the north and east ones, the speed sigma that of the three
/// velocity axes (NAV-PVT reports one number for each).
pub fn gnss_fixes(g: &super::gnss::GnssFixes) -> Vec<GnssFix> {
    let horizontal_sigma_m = g.sigma_ned_m[0].hypot(g.sigma_ned_m[1]);
    let v = g.sigma_v_ned_m_s;
    let speed_sigma_m_s = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    (0..g.t_s.len())
        .map(|k| GnssFix {
            t_us: to_us(g.t_s[k]),
            lat_rad: g.position[0][k],
            lon_rad: g.position[1][k],
            h_m: g.position[2][k] as f32,
            vel_ned_m_s: [0, 1, 2].map(|a| g.velocity_ned_m_s[a][k] as f32),
            pos_sigma_m: horizontal_sigma_m as f32,
            vel_sigma_m_s: speed_sigma_m_s as f32,
            // The simulator has no constellation: satellites are not reported.
            num_sats: 0,
            fix_type: 3,
        })
        .collect()
}

/// One event of the merged, time-ordered stream.
enum Event {
    Pps(usize),
    Gnss(usize),
    Imu { imu: usize, sample: usize },
}

impl BoardRecording {
    /// All events in time order; on equal stamps PPS first, then GNSS, then IMUs in id order.
    fn events(&self) -> impl Iterator<Item = Event> + '_ {
        let mut next_pps = 0usize;
        let mut next_gnss = 0usize;
        let mut next_imu = vec![0usize; self.imus.len()];
        std::iter::from_fn(move || {
            let mut best: Option<(u64, Event)> = None;
            let mut consider = |t: u64, e: Event| {
                if best.as_ref().is_none_or(|(b, _)| t < *b) {
                    best = Some((t, e));
                }
            };
            if let Some(&t) = self.pps_t_us.get(next_pps) {
                consider(t, Event::Pps(next_pps));
            }
            if let Some(g) = self.gnss.get(next_gnss) {
                consider(g.t_us, Event::Gnss(next_gnss));
            }
            for (i, imu) in self.imus.iter().enumerate() {
                if let Some(&t) = imu.t_us.get(next_imu[i]) {
                    consider(
                        t,
                        Event::Imu {
                            imu: i,
                            sample: next_imu[i],
                        },
                    );
                }
            }
            let (_, e) = best?;
            match e {
                Event::Pps(_) => next_pps += 1,
                Event::Gnss(_) => next_gnss += 1,
                Event::Imu { imu, .. } => next_imu[imu] += 1,
            }
            Some(e)
        })
    }

    fn imu_sample(&self, imu: usize, sample: usize) -> ImuSampleSet {
        let i = &self.imus[imu];
        ImuSampleSet {
            t_us: i.t_us[sample],
            imu_id: i.config.imu_id,
            gyro_counts: i.gyro_counts[sample],
            accel_counts: i.accel_counts[sample],
        }
    }

    /// The GNSS record of fix `k`: the NAV-PVT frame a u-blox receiver sends for it, as
    /// received at its time of validity.
    fn gnss_record(&self, k: usize) -> Result<ReplayRecord, BoardError> {
        let fix = &self.gnss[k];
        let frame = dynacal_core::gnss::encode_nav_pvt(fix, dynacal_core::gnss::LEAP_SECONDS_2017);
        ReplayRecord::gnss(fix.t_us, &frame).map_err(BoardError::Replay)
    }

    /// Writes the firmware replay input: header, IMU, PPS and GNSS records in time order,
    /// end record.
    pub fn write_replay(&self, w: &mut dyn Write) -> Result<(), BoardError> {
        let configs: Vec<ReplayImu> = self.imus.iter().map(|i| i.config).collect();
        let header = ReplayHeader::new(&configs).map_err(BoardError::Replay)?;
        let mut buf = [0u8; MAX_HEADER_LEN];
        let n = encode_header(&header, &mut buf).map_err(BoardError::Replay)?;
        w.write_all(&buf[..n])?;
        let mut rec = [0u8; MAX_RECORD_LEN];
        let (mut samples, mut edges) = (0u64, 0u64);
        for e in self.events() {
            let record = match e {
                Event::Pps(k) => {
                    edges += 1;
                    ReplayRecord::Pps {
                        t_us: self.pps_t_us[k],
                    }
                }
                Event::Imu { imu, sample } => {
                    samples += 1;
                    let s = self.imu_sample(imu, sample);
                    ReplayRecord::Imu {
                        t_us: s.t_us,
                        imu_id: s.imu_id,
                        gyro_counts: s.gyro_counts,
                        accel_counts: s.accel_counts,
                    }
                }
                Event::Gnss(k) => self.gnss_record(k)?,
            };
            let n = encode_record(&record, &mut rec).map_err(BoardError::Replay)?;
            w.write_all(&rec[..n])?;
        }
        let end = ReplayRecord::End {
            imu_sample_sets: samples,
            pps_edges: edges,
        };
        let n = encode_record(&end, &mut rec).map_err(BoardError::Replay)?;
        w.write_all(&rec[..n])?;
        Ok(())
    }

    /// The log header: protocol version, board name, each IMU's id, model and scales.
    pub fn log_header(&self) -> Header {
        // At most MAX_IMUS IMUs with names of at most 16 ASCII bytes (checked in
        // `board_recording`), so the header's fixed capacities hold them.
        let imus = self
            .imus
            .iter()
            .map(|i| ImuConfig {
                imu_id: i.config.imu_id,
                model: i.config.model_str().try_into().unwrap_or_default(),
                sample_rate_hz: i.config.sample_rate_hz,
                gyro_scale_rad_s_per_count: i.config.gyro_scale_rad_s_per_count,
                accel_scale_m_s2_per_count: i.config.accel_scale_m_s2_per_count,
            })
            .take(MAX_IMUS)
            .collect();
        Header {
            protocol_version: PROTOCOL_VERSION,
            board: BOARD_NAME.try_into().unwrap_or_default(),
            imus,
        }
    }

    /// Writes the board log: the header, then IMU sample sets, PPS edges (sequence counting
    /// from 1) and GNSS fixes in time order.
    pub fn write_log(&self, w: &mut dyn Write) -> Result<(), BoardError> {
        let mut buf = [0u8; MAX_FRAME_LEN];
        let mut put = |frame: &Frame, w: &mut dyn Write| -> Result<(), BoardError> {
            let n = encode_frame(frame, &mut buf).map_err(BoardError::Log)?;
            w.write_all(&buf[..n])?;
            Ok(())
        };
        put(&Frame::Header(self.log_header()), w)?;
        for e in self.events() {
            let frame = match e {
                Event::Pps(k) => Frame::Pps(PpsEvent {
                    t_us: self.pps_t_us[k],
                    sequence: k as u32 + 1,
                }),
                Event::Gnss(k) => Frame::Gnss(self.gnss[k]),
                Event::Imu { imu, sample } => Frame::Imu(self.imu_sample(imu, sample)),
            };
            put(&frame, w)?;
        }
        Ok(())
    }

    /// The replay input as [`crate::replay::ReplayInput`] (records held in memory: for short
    /// runs and checks; [`BoardRecording::write_replay`] streams the same bytes).
    pub fn to_replay_input(&self) -> Result<crate::replay::ReplayInput, BoardError> {
        let configs: Vec<ReplayImu> = self.imus.iter().map(|i| i.config).collect();
        let header = ReplayHeader::new(&configs).map_err(BoardError::Replay)?;
        let records = self
            .events()
            .map(|e| match e {
                Event::Pps(k) => Ok(ReplayRecord::Pps {
                    t_us: self.pps_t_us[k],
                }),
                Event::Imu { imu, sample } => {
                    let s = self.imu_sample(imu, sample);
                    Ok(ReplayRecord::Imu {
                        t_us: s.t_us,
                        imu_id: s.imu_id,
                        gyro_counts: s.gyro_counts,
                        accel_counts: s.accel_counts,
                    })
                }
                Event::Gnss(k) => self.gnss_record(k),
            })
            .collect::<Result<_, _>>()?;
        Ok(crate::replay::ReplayInput { header, records })
    }

    /// The replay input's bytes.
    pub fn replay_bytes(&self) -> Result<Vec<u8>, BoardError> {
        let mut v = Vec::new();
        self.write_replay(&mut v)?;
        Ok(v)
    }

    /// The board log's bytes.
    pub fn log_bytes(&self) -> Result<Vec<u8>, BoardError> {
        let mut v = Vec::new();
        self.write_log(&mut v)?;
        Ok(v)
    }
}
