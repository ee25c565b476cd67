//! TDK InvenSense ICM-42688-P over SPI (embedded-hal 1.0 `SpiDevice`): set-up for
//! data-ready on INT1 and a burst read of one sample set in raw counts.
//!
//! Hand-written because the crates.io drivers for this part either lack what the board
//! needs (raw counts, not scaled floats; data-ready pulses for timer capture) or pin an
//! older embedded-hal. Register addresses and fields are from the data sheet (DS-000347),
//! user bank 0.

use embedded_hal::delay::DelayNs;
use embedded_hal::spi::{Operation, SpiDevice};

const DEVICE_CONFIG: u8 = 0x11;
const INT_CONFIG: u8 = 0x14;
const TEMP_DATA1: u8 = 0x1D;
const PWR_MGMT0: u8 = 0x4E;
const GYRO_CONFIG0: u8 = 0x4F;
const ACCEL_CONFIG0: u8 = 0x50;
const INT_CONFIG1: u8 = 0x64;
const INT_SOURCE0: u8 = 0x65;
const WHO_AM_I: u8 = 0x75;
const REG_BANK_SEL: u8 = 0x76;

const WHO_AM_I_VALUE: u8 = 0x47;
const SPI_READ: u8 = 0x80;

/// DEVICE_CONFIG: SOFT_RESET_CONFIG.
const SOFT_RESET: u8 = 0x01;
/// INT_CONFIG: INT1 pulsed, push-pull, active high.
const INT1_PULSED_PUSH_PULL_ACTIVE_HIGH: u8 = 0b0000_0011;
/// INT_CONFIG1: 100 us pulses, de-assert enabled, INT_ASYNC_RESET cleared (the data sheet
/// requires it cleared for INT1 to work).
const INT_CONFIG1_VALUE: u8 = 0x00;
/// INT_SOURCE0: UI_DRDY_INT1_EN.
const DRDY_ON_INT1: u8 = 0b0000_1000;
/// GYRO_CONFIG0: FS_SEL 000 (+-2000 deg/s), ODR 0111 (200 Hz).
const GYRO_2000DPS_200HZ: u8 = 0b0000_0111;
/// ACCEL_CONFIG0: FS_SEL 000 (+-16 g), ODR 0111 (200 Hz).
const ACCEL_16G_200HZ: u8 = 0b0000_0111;
/// PWR_MGMT0: gyro and accelerometer in low-noise mode, temperature sensor on.
const GYRO_ACCEL_LOW_NOISE: u8 = 0b0000_1111;

/// Output data rate configured by [`Icm42688::init`], Hz.
pub const SAMPLE_RATE_HZ: f32 = 200.0;
/// Gyro scale at +-2000 deg/s full scale: 1/16.4 deg/s per count, in rad/s per count.
pub const GYRO_SCALE_RAD_S_PER_COUNT: f64 = core::f64::consts::PI / 180.0 / 16.4;
/// Accelerometer scale at +-16 g full scale: 1/2048 g per count (g = 9.80665 m/s^2).
pub const ACCEL_SCALE_M_S2_PER_COUNT: f64 = 9.80665 / 2048.0;
/// Model name written in the log header.
pub const MODEL: &str = "ICM-42688-P";

/// Why the IMU could not be set up.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum InitError<E> {
    Spi(E),
    /// WHO_AM_I read something else: wrong part, or no part on this chip select.
    WrongDevice(u8),
}

/// One sample set in raw counts, sensor axes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RawSample {
    pub temperature_counts: i16,
    pub accel_counts: [i16; 3],
    pub gyro_counts: [i16; 3],
}

impl RawSample {
    /// Die temperature, degrees Celsius (data sheet: counts / 132.48 + 25).
    pub fn temperature_deg_c(&self) -> f32 {
        self.temperature_counts as f32 / 132.48 + 25.0
    }
}

pub struct Icm42688<SPI> {
    spi: SPI,
}

impl<SPI: SpiDevice> Icm42688<SPI> {
    pub fn new(spi: SPI) -> Self {
        Icm42688 { spi }
    }

    /// Resets the part and configures 200 Hz, +-2000 deg/s, +-16 g, low-noise mode, with a
    /// data-ready pulse on INT1 for each sample set.
    pub fn init(&mut self, delay: &mut impl DelayNs) -> Result<(), InitError<SPI::Error>> {
        self.write(REG_BANK_SEL, 0).map_err(InitError::Spi)?;
        self.write(DEVICE_CONFIG, SOFT_RESET)
            .map_err(InitError::Spi)?;
        // The data sheet asks for 1 ms after a soft reset before any register access.
        delay.delay_ms(2);
        let id = self.read(WHO_AM_I).map_err(InitError::Spi)?;
        if id != WHO_AM_I_VALUE {
            return Err(InitError::WrongDevice(id));
        }
        for (register, value) in [
            (INT_CONFIG, INT1_PULSED_PUSH_PULL_ACTIVE_HIGH),
            (INT_CONFIG1, INT_CONFIG1_VALUE),
            (INT_SOURCE0, DRDY_ON_INT1),
            (GYRO_CONFIG0, GYRO_2000DPS_200HZ),
            (ACCEL_CONFIG0, ACCEL_16G_200HZ),
            (PWR_MGMT0, GYRO_ACCEL_LOW_NOISE),
        ] {
            self.write(register, value).map_err(InitError::Spi)?;
        }
        // Sensors need 200 us after leaving off mode before the next register write; the
        // gyro's first sample follows about 45 ms later.
        delay.delay_ms(50);
        Ok(())
    }

    /// Reads temperature, accelerometer and gyro in one burst (registers 0x1D..=0x2A,
    /// big-endian pairs), so all belong to the same sample set.
    pub fn read_sample(&mut self) -> Result<RawSample, SPI::Error> {
        let mut raw = [0u8; 14];
        self.spi.transaction(&mut [
            Operation::Write(&[TEMP_DATA1 | SPI_READ]),
            Operation::Read(&mut raw),
        ])?;
        let word = |k: usize| i16::from_be_bytes([raw[2 * k], raw[2 * k + 1]]);
        Ok(RawSample {
            temperature_counts: word(0),
            accel_counts: [word(1), word(2), word(3)],
            gyro_counts: [word(4), word(5), word(6)],
        })
    }

    fn write(&mut self, register: u8, value: u8) -> Result<(), SPI::Error> {
        self.spi.write(&[register & !SPI_READ, value])
    }

    fn read(&mut self, register: u8) -> Result<u8, SPI::Error> {
        let mut value = [0u8];
        self.spi.transaction(&mut [
            Operation::Write(&[register | SPI_READ]),
            Operation::Read(&mut value),
        ])?;
        Ok(value[0])
    }
}
