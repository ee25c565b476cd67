//! The simulator: car or static trajectories with exact kinematics, a navigation-grade
//! reference IMU, up to three MEMS IMUs with their own mounting, clocks and error effects,
//! a GNSS receiver and a PPS, written in the interchange format with a truth file.

pub mod jet;
pub mod trajectory;
