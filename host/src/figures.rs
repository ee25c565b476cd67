//! Figures of the paper reproduced on simulated data. [`fig1`] is Fig. 1 of Stebler,
//! Guerrier, Skaloud (IEEE TIM 2015): a low-grade and a tactical-grade MEMS IMU ride a
//! simulated car with a navigation-grade reference IMU and a 10 Hz GNSS receiver; the
//! reference-IMU/GNSS error-state filter with two extra IMUs (27 states) estimates both
//! inter-IMU boresights and lever arms with the joint update of eqs. (8)-(12), starting from
//! zero with 20 deg and 20 cm one-sigma. The run is traced, smoothed (RTS, variance-weighted
//! mean of Section V-B), summarised in a JSON report and drawn as an SVG.

pub mod fig1;
pub mod plot;
