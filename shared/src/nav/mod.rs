//! Navigation: strapdown INS/GNSS error-state filtering with inter-IMU calibration.

pub mod ekf;
