//! The error model the host refits and the board runs: per IMU and channel the noise its
//! filter needs (white noise, a Gauss-Markov bias, a bias random walk), and each unit's
//! alignment to the first. It travels as `board-model.bin`: the magic `DCBM`, a format
//! version (u16, little-endian), then the model in postcard with a CRC-32 over it (the log's
//! CRC, [`crate::log::LOG_CRC`]). A blob that is damaged, truncated, of another version or
//! of values no filter can run (not finite, negative variances, a correlation time that is
//! not positive) is refused with the reason, and the board keeps its built-in model
//! ([`BoardModel::load_or_built_in`]).

use serde::{Deserialize, Serialize};

use crate::log::{LOG_CRC, MAX_IMUS};
use crate::nav::ekf::EkfConfig;
use crate::Channel;

/// First bytes of every board-model blob.
pub const BOARD_MODEL_MAGIC: [u8; 4] = *b"DCBM";
/// Version of the layout this build writes and reads.
pub const BOARD_MODEL_VERSION: u16 = 1;
/// Bytes before the postcard payload: magic and version.
const PREFIX_LEN: usize = 6;
/// Postcard bytes of one unit: its id, six channels of four f32, two triads of f32.
const UNIT_LEN: usize = 1 + 6 * 4 * 4 + 2 * 3 * 4;
/// Bytes of the largest blob: prefix, unit count, every unit, CRC-32.
pub const MAX_BOARD_MODEL_LEN: usize = PREFIX_LEN + 1 + MAX_IMUS * UNIT_LEN + 4;

/// One channel's noise, in the channel's SI unit (rad/s or m/s^2).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ChannelNoise {
    /// White-noise power spectral density, unit^2 s (the variance per sample times the
    /// sample interval).
    pub white_psd: f32,
    /// Stationary variance of a first-order Gauss-Markov bias, unit^2 (0: none).
    pub gauss_markov_sigma2: f32,
    /// Its correlation time, s.
    pub gauss_markov_tau_s: f32,
    /// Power spectral density of a bias random walk, unit^2 / s (0: none).
    pub random_walk_psd: f32,
}

/// One IMU of the board.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct UnitModel {
    pub imu_id: u8,
    /// Noise per channel, in [`Channel::ALL`] order (gx, gy, gz, ax, ay, az).
    pub channels: [ChannelNoise; 6],
    /// Rotation from the first unit's axes to this unit's (y_k = C y_0), roll, pitch, yaw
    /// (Z-Y-X), rad.
    pub rotation_rpy_rad: [f32; 3],
    /// Lever arm from the first unit to this one, in the first unit's axes, m.
    pub lever_arm_m: [f32; 3],
}

/// The board's error model.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct BoardModel {
    pub units: heapless::Vec<UnitModel, MAX_IMUS>,
}

/// Why a blob was refused.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum BoardModelError {
    /// Ends before its model and CRC do.
    Truncated,
    /// Not a board-model blob.
    BadMagic,
    /// Written in a version this build does not read.
    UnsupportedVersion(u16),
    /// The CRC-32 does not match: the blob is damaged.
    BadCrc,
    /// The CRC matches but the payload is not a model of this layout.
    Malformed,
    /// The output buffer is too small.
    BufferTooSmall,
    /// A value no filter can run, in unit `unit` (its index), channel `channel` (None: the
    /// alignment).
    Invalid { unit: u8, channel: Option<Channel> },
}

impl core::fmt::Display for BoardModelError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::Truncated => write!(f, "truncated: it ends before its model and CRC do"),
            Self::BadMagic => write!(f, "not a board model (bad magic)"),
            Self::UnsupportedVersion(v) => write!(
                f,
                "board model version {v}; this build reads {BOARD_MODEL_VERSION}"
            ),
            Self::BadCrc => write!(f, "damaged: its CRC-32 does not match"),
            Self::Malformed => write!(f, "the payload is not a board model of this layout"),
            Self::BufferTooSmall => write!(f, "output buffer too small"),
            Self::Invalid { unit, channel } => match channel {
                Some(c) => write!(f, "unit {unit} channel {c:?}: a value no filter can run"),
                None => write!(f, "unit {unit} alignment: a value that is not finite"),
            },
        }
    }
}

impl ChannelNoise {
    /// Finite, non-negative values and a positive correlation time where a Gauss-Markov
    /// bias is given. An unused correlation time must be finite too: the fusion averages it
    /// with the other axes' (`fusion::process_noise`), where a NaN would silently drop their
    /// Gauss-Markov bias.
    fn is_valid(&self) -> bool {
        let values = [
            self.white_psd,
            self.gauss_markov_sigma2,
            self.gauss_markov_tau_s,
            self.random_walk_psd,
        ];
        values.iter().all(|v| v.is_finite() && *v >= 0.0)
            && (self.gauss_markov_sigma2 == 0.0 || self.gauss_markov_tau_s > 0.0)
    }
}

impl BoardModel {
    /// The model the board starts with: every unit has the automotive filter's noise
    /// ([`EkfConfig::automotive_mems`]: white noise and bias random walks, no Gauss-Markov
    /// bias), in the first unit's axes at its place.
    pub fn built_in(imu_ids: &[u8]) -> Self {
        let filter = EkfConfig::<f32>::automotive_mems();
        let noise = |white_psd: f32, random_walk_psd: f32| ChannelNoise {
            white_psd,
            gauss_markov_sigma2: 0.0,
            gauss_markov_tau_s: 0.0,
            random_walk_psd,
        };
        let gyro = noise(filter.gyro_noise_psd.value(), filter.gyro_bias_psd.value());
        let accel = noise(
            filter.accel_noise_psd.value(),
            filter.accel_bias_psd.value(),
        );
        let mut units = heapless::Vec::new();
        for &imu_id in imu_ids.iter().take(MAX_IMUS) {
            let _ = units.push(UnitModel {
                imu_id,
                channels: [gyro, gyro, gyro, accel, accel, accel],
                rotation_rpy_rad: [0.0; 3],
                lever_arm_m: [0.0; 3],
            });
        }
        Self { units }
    }

    /// The first value no filter can run, if any.
    pub fn validate(&self) -> Result<(), BoardModelError> {
        for (k, unit) in self.units.iter().enumerate() {
            let index = k as u8;
            for (noise, channel) in unit.channels.iter().zip(Channel::ALL) {
                if !noise.is_valid() {
                    return Err(BoardModelError::Invalid {
                        unit: index,
                        channel: Some(channel),
                    });
                }
            }
            let alignment = unit.rotation_rpy_rad.iter().chain(&unit.lever_arm_m);
            if !alignment.clone().all(|v| v.is_finite()) {
                return Err(BoardModelError::Invalid {
                    unit: index,
                    channel: None,
                });
            }
        }
        Ok(())
    }

    /// Writes the blob into `out`; returns its length.
    pub fn encode(&self, out: &mut [u8]) -> Result<usize, BoardModelError> {
        self.validate()?;
        if out.len() < PREFIX_LEN {
            return Err(BoardModelError::BufferTooSmall);
        }
        out[..4].copy_from_slice(&BOARD_MODEL_MAGIC);
        out[4..6].copy_from_slice(&BOARD_MODEL_VERSION.to_le_bytes());
        let written = postcard::to_slice_crc32(self, &mut out[PREFIX_LEN..], LOG_CRC.digest())
            .map_err(|_| BoardModelError::BufferTooSmall)?;
        Ok(PREFIX_LEN + written.len())
    }

    /// Reads a blob, checked whole: magic, version, CRC, layout, values.
    pub fn decode(bytes: &[u8]) -> Result<Self, BoardModelError> {
        if bytes.len() < PREFIX_LEN {
            return Err(BoardModelError::Truncated);
        }
        if bytes[..4] != BOARD_MODEL_MAGIC {
            return Err(BoardModelError::BadMagic);
        }
        let version = u16::from_le_bytes([bytes[4], bytes[5]]);
        if version != BOARD_MODEL_VERSION {
            return Err(BoardModelError::UnsupportedVersion(version));
        }
        let model: Self = postcard::from_bytes_crc32(&bytes[PREFIX_LEN..], LOG_CRC.digest())
            .map_err(|e| match e {
                postcard::Error::DeserializeBadCrc => BoardModelError::BadCrc,
                postcard::Error::DeserializeUnexpectedEnd => BoardModelError::Truncated,
                _ => BoardModelError::Malformed,
            })?;
        model.validate()?;
        Ok(model)
    }

    /// The model of `blob` where there is one and it reads, else the built-in model for
    /// `imu_ids` with the reason the blob was refused (the board logs it).
    pub fn load_or_built_in(
        blob: Option<&[u8]>,
        imu_ids: &[u8],
    ) -> (Self, Option<BoardModelError>) {
        match blob.map(Self::decode) {
            Some(Ok(model)) => (model, None),
            Some(Err(reason)) => (Self::built_in(imu_ids), Some(reason)),
            None => (Self::built_in(imu_ids), None),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn refitted() -> BoardModel {
        let mut model = BoardModel::built_in(&[0, 1, 2]);
        model.units[1].channels[4] = ChannelNoise {
            white_psd: 3.2e-4,
            gauss_markov_sigma2: 1e-6,
            gauss_markov_tau_s: 120.0,
            random_walk_psd: 2e-9,
        };
        model.units[2].rotation_rpy_rad = [0.01, -0.005, 0.02];
        model.units[2].lever_arm_m = [-0.04, 0.05, 0.03];
        model
    }

    fn blob(model: &BoardModel) -> std::vec::Vec<u8> {
        let mut buf = [0u8; MAX_BOARD_MODEL_LEN];
        let n = model.encode(&mut buf).unwrap();
        buf[..n].to_vec()
    }

    /// A refitted model comes back as it was, and three units fill the largest blob.
    #[test]
    fn a_model_comes_back_whole() {
        let model = refitted();
        let bytes = blob(&model);
        assert_eq!(bytes.len(), MAX_BOARD_MODEL_LEN);
        assert_eq!(BoardModel::decode(&bytes), Ok(model.clone()));
        assert_eq!(
            BoardModel::load_or_built_in(Some(&bytes), &[0, 1, 2]),
            (model, None)
        );
    }

    /// In flash a blob is followed by erased bytes (0xFF), and a blob of fewer units is
    /// shorter than the span the board reads: the model still reads.
    #[test]
    fn a_model_followed_by_erased_flash_reads() {
        let mut model = refitted();
        model.units.truncate(2);
        let mut bytes = blob(&model);
        assert!(bytes.len() < MAX_BOARD_MODEL_LEN);
        bytes.resize(MAX_BOARD_MODEL_LEN + 64, 0xFF);
        assert_eq!(BoardModel::decode(&bytes), Ok(model));
    }

    /// Every kind of bad blob is refused with its reason and the built-in model is kept.
    #[test]
    fn bad_blobs_are_refused_with_the_reason() {
        let good = blob(&refitted());
        let built_in = BoardModel::built_in(&[0, 1, 2]);
        let mut damaged = good.clone();
        damaged[40] ^= 0x10;
        let mut newer = good.clone();
        newer[4] = 2;
        let mut foreign = good.clone();
        foreign[0] = b'X';
        let cases: [(&[u8], BoardModelError); 5] = [
            (&damaged, BoardModelError::BadCrc),
            (&newer, BoardModelError::UnsupportedVersion(2)),
            (&foreign, BoardModelError::BadMagic),
            (&good[..3], BoardModelError::Truncated),
            (&good[..good.len() - 1], BoardModelError::Truncated),
        ];
        for (bytes, reason) in cases {
            let (model, why) = BoardModel::load_or_built_in(Some(bytes), &[0, 1, 2]);
            assert_eq!((model, why), (built_in.clone(), Some(reason)));
        }
    }

    /// A model no filter can run is neither written nor read.
    #[test]
    fn values_no_filter_can_run_are_named() {
        let mut model = refitted();
        model.units[1].channels[2].gauss_markov_tau_s = 0.0;
        model.units[1].channels[2].gauss_markov_sigma2 = 1e-6;
        let mut buf = [0u8; MAX_BOARD_MODEL_LEN];
        let want = BoardModelError::Invalid {
            unit: 1,
            channel: Some(Channel::Gz),
        };
        assert_eq!(model.encode(&mut buf), Err(want));
        model.units[1].channels[2].gauss_markov_tau_s = 30.0;
        model.units[0].lever_arm_m[1] = f32::NAN;
        assert_eq!(
            model.encode(&mut buf),
            Err(BoardModelError::Invalid {
                unit: 0,
                channel: None
            })
        );
    }

    /// Regression (review while fuzzing): a correlation time of NaN beside a zero
    /// Gauss-Markov variance passed `validate()`, and the fusion's axis average then lost
    /// the other axes' Gauss-Markov bias without a word.
    #[test]
    fn an_unused_correlation_time_that_is_not_finite_is_refused() {
        for tau in [f32::NAN, f32::INFINITY, -1.0] {
            let mut model = refitted();
            model.units[2].channels[1].gauss_markov_sigma2 = 0.0;
            model.units[2].channels[1].gauss_markov_tau_s = tau;
            assert_eq!(
                model.validate(),
                Err(BoardModelError::Invalid {
                    unit: 2,
                    channel: Some(Channel::Gy)
                }),
                "tau {tau}"
            );
        }
    }

    /// Every single byte of a good blob changed to every other value: the blob is refused,
    /// or (never, with a CRC-32 over the payload, but the property is what the board needs)
    /// it reads as a model that passes `validate()`. A refusal of a changed prefix names it.
    #[test]
    fn every_single_byte_change_is_refused_or_reads_a_runnable_model() {
        let good = blob(&refitted());
        let mut refused = 0usize;
        for at in 0..good.len() {
            for value in 0..=255u8 {
                if value == good[at] {
                    continue;
                }
                let mut bytes = good.clone();
                bytes[at] = value;
                match BoardModel::decode(&bytes) {
                    Ok(model) => assert_eq!(model.validate(), Ok(()), "byte {at} = {value}"),
                    Err(reason) => {
                        refused += 1;
                        let want = match at {
                            0..4 => Some(BoardModelError::BadMagic),
                            4..6 => {
                                Some(BoardModelError::UnsupportedVersion(u16::from_le_bytes([
                                    bytes[4], bytes[5],
                                ])))
                            }
                            _ => None,
                        };
                        if let Some(want) = want {
                            assert_eq!(reason, want, "byte {at} = {value}");
                        }
                    }
                }
            }
        }
        assert_eq!(refused, good.len() * 255);
    }

    /// Finite, non-negative noise values, and sometimes exactly zero (a term the model does
    /// not have).
    fn arb_noise() -> impl proptest::strategy::Strategy<Value = ChannelNoise> {
        use proptest::strategy::Strategy;
        let value =
            || proptest::prop_oneof![1 => proptest::strategy::Just(0.0f32), 4 => 0.0f32..1e3];
        (value(), value(), 1e-3f32..1e5, value()).prop_map(|(w, s2, tau, rw)| ChannelNoise {
            white_psd: w,
            gauss_markov_sigma2: s2,
            gauss_markov_tau_s: tau,
            random_walk_psd: rw,
        })
    }

    fn arb_model() -> impl proptest::strategy::Strategy<Value = BoardModel> {
        use proptest::strategy::Strategy;
        let unit = (
            proptest::num::u8::ANY,
            proptest::array::uniform6(arb_noise()),
            proptest::array::uniform3(-4.0f32..4.0),
            proptest::array::uniform3(-2.0f32..2.0),
        )
            .prop_map(
                |(imu_id, channels, rotation_rpy_rad, lever_arm_m)| UnitModel {
                    imu_id,
                    channels,
                    rotation_rpy_rad,
                    lever_arm_m,
                },
            );
        proptest::collection::vec(unit, 0..=MAX_IMUS).prop_map(|units| BoardModel {
            units: units.into_iter().collect(),
        })
    }

    proptest::proptest! {


        // Seeded: every failure reproduces (the project's rule for random generators).


        #![proptest_config(proptest::test_runner::Config {


            rng_seed: proptest::test_runner::RngSeed::Fixed(0x5eed0b02),


            failure_persistence: Some(std::boxed::Box::new(


                proptest::test_runner::FileFailurePersistence::Off


            )),


            ..proptest::test_runner::Config::default()


        })]
        /// Any runnable model comes back as it was, whatever bytes follow the blob (flash
        /// beyond it holds anything); every shorter prefix of its blob is refused as
        /// truncated, never read as a smaller model.
        #[test]
        fn any_model_round_trips_and_every_prefix_is_refused(
            model in arb_model(),
            tail in proptest::collection::vec(proptest::num::u8::ANY, 0..64),
        ) {
            let bytes = blob(&model);
            proptest::prop_assert_eq!(BoardModel::decode(&bytes), Ok(model.clone()));
            let mut followed = bytes.clone();
            followed.extend_from_slice(&tail);
            proptest::prop_assert_eq!(BoardModel::decode(&followed), Ok(model));
            for len in 0..bytes.len() {
                proptest::prop_assert_eq!(
                    BoardModel::decode(&bytes[..len]),
                    Err(BoardModelError::Truncated),
                    "prefix of {} bytes", len
                );
            }
        }
    }

    proptest::proptest! {


        // Seeded: every failure reproduces (the project's rule for random generators).


        #![proptest_config(proptest::test_runner::Config {


            rng_seed: proptest::test_runner::RngSeed::Fixed(0x5eed0b01),


            failure_persistence: Some(std::boxed::Box::new(


                proptest::test_runner::FileFailurePersistence::Off


            )),


            ..proptest::test_runner::Config::default()


        })]
        /// Arbitrary bytes, and a good blob with bytes changed, never panic the reader, and
        /// a changed blob is never read as a different model.
        #[test]
        fn arbitrary_bytes_never_panic(
            noise in proptest::collection::vec(proptest::num::u8::ANY, 0..600),
            damage in proptest::collection::vec((0usize..MAX_BOARD_MODEL_LEN, 1u8..=255), 1..4),
        ) {
            let _ = BoardModel::decode(&noise);
            let good = refitted();
            let mut bytes = blob(&good);
            for (at, flip) in damage {
                let at = at % bytes.len();
                bytes[at] ^= flip;
            }
            if let Ok(read) = BoardModel::decode(&bytes) {
                proptest::prop_assert_eq!(read, good);
            }
        }
    }
}
