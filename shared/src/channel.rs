//! The six channels of an IMU (gyro x, y, z and accelerometer x, y, z, body frame
//! forward-right-down), named once for the board and the host: the log's wavelet-variance
//! frames, the interchange files, the error model and the diagnosis all index channels by
//! this type, never by a string or a bare number.

use core::fmt;
use core::str::FromStr;

use serde::{Deserialize, Serialize};

/// One IMU channel. Gyro channels are in rad/s, accelerometer channels in m/s^2; axes are
/// the sensor's body axes (x forward, y right, z down).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Channel {
    Gx,
    Gy,
    Gz,
    Ax,
    Ay,
    Az,
}

/// The kind of sensor behind a channel.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum SensorKind {
    /// Angular rate, rad/s.
    Gyro,
    /// Specific force, m/s^2.
    Accelerometer,
}

impl Channel {
    /// Every channel, in the order dynacal reports them (its [`Channel::index`] order).
    pub const ALL: [Channel; 6] = [
        Channel::Gx,
        Channel::Gy,
        Channel::Gz,
        Channel::Ax,
        Channel::Ay,
        Channel::Az,
    ];
    /// The gyro channels, x, y, z.
    pub const GYROS: [Channel; 3] = [Channel::Gx, Channel::Gy, Channel::Gz];
    /// The accelerometer channels, x, y, z.
    pub const ACCELEROMETERS: [Channel; 3] = [Channel::Ax, Channel::Ay, Channel::Az];

    /// Position in [`Channel::ALL`]: 0..3 gyro x, y, z; 3..6 accelerometer x, y, z.
    pub const fn index(self) -> usize {
        self as usize
    }

    /// The channel at `index` of [`Channel::ALL`], if there is one.
    pub const fn from_index(index: usize) -> Option<Channel> {
        if index < 6 {
            Some(Self::ALL[index])
        } else {
            None
        }
    }

    /// The channel of `kind` on body axis `axis` (0 = x, 1 = y, 2 = z).
    pub const fn of(kind: SensorKind, axis: usize) -> Channel {
        match kind {
            SensorKind::Gyro => Self::GYROS[axis % 3],
            SensorKind::Accelerometer => Self::ACCELEROMETERS[axis % 3],
        }
    }

    /// Short name: `gx` ... `az`.
    pub const fn name(self) -> &'static str {
        match self {
            Channel::Gx => "gx",
            Channel::Gy => "gy",
            Channel::Gz => "gz",
            Channel::Ax => "ax",
            Channel::Ay => "ay",
            Channel::Az => "az",
        }
    }

    /// The interchange column holding this channel (`gx_rad_s` ... `az_m_s2`).
    pub const fn column(self) -> &'static str {
        match self {
            Channel::Gx => "gx_rad_s",
            Channel::Gy => "gy_rad_s",
            Channel::Gz => "gz_rad_s",
            Channel::Ax => "ax_m_s2",
            Channel::Ay => "ay_m_s2",
            Channel::Az => "az_m_s2",
        }
    }

    /// Gyro or accelerometer.
    pub const fn kind(self) -> SensorKind {
        if self.index() < 3 {
            SensorKind::Gyro
        } else {
            SensorKind::Accelerometer
        }
    }

    /// True for gx, gy, gz.
    pub const fn is_gyro(self) -> bool {
        matches!(self.kind(), SensorKind::Gyro)
    }

    /// Body axis: 0 = x (forward), 1 = y (right), 2 = z (down).
    pub const fn axis(self) -> usize {
        self.index() % 3
    }

    /// SI unit of the channel's values.
    pub const fn si_unit(self) -> &'static str {
        match self.kind() {
            SensorKind::Gyro => "rad/s",
            SensorKind::Accelerometer => "m/s^2",
        }
    }
}

impl fmt::Display for Channel {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// A name that is not one of `gx` ... `az`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct UnknownChannel;

impl fmt::Display for UnknownChannel {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str("not an IMU channel (expected gx, gy, gz, ax, ay or az)")
    }
}

impl FromStr for Channel {
    type Err = UnknownChannel;
    /// Accepts the short name (`gx`) or the interchange column (`gx_rad_s`).
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Self::ALL
            .into_iter()
            .find(|c| c.name() == s || c.column() == s)
            .ok_or(UnknownChannel)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn index_name_and_column_round_trip() {
        for (i, c) in Channel::ALL.into_iter().enumerate() {
            assert_eq!(c.index(), i);
            assert_eq!(Channel::from_index(i), Some(c));
            assert_eq!(c.name().parse::<Channel>(), Ok(c));
            assert_eq!(c.column().parse::<Channel>(), Ok(c));
            assert_eq!(Channel::of(c.kind(), c.axis()), c);
        }
        assert_eq!(Channel::from_index(6), None);
        assert_eq!("gyro".parse::<Channel>(), Err(UnknownChannel));
        assert!(Channel::Gz.is_gyro() && !Channel::Ax.is_gyro());
        assert_eq!(Channel::Ay.axis(), 1);
    }

    #[test]
    fn serialises_as_the_short_name() {
        let mut buf = [0u8; 16];
        let bytes = postcard::to_slice(&Channel::Az, &mut buf).unwrap();
        assert_eq!(
            postcard::from_bytes::<Channel>(bytes).unwrap(),
            Channel::Az,
            "postcard keeps the variant"
        );
    }
}
