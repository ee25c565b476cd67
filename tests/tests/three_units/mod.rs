//! The three MEMS units the board's fusion is tested on (`examples/models/three-units-200hz.json`,
//! `dynacal navsim`'s default drive): white noise plus a slow Gauss-Markov bias per channel
//! at 200 Hz, unit 0 the body frame, units 1 and 2 turned and offset from it, and a 10 Hz
//! GNSS receiver; and the board model that describes them to the fusion.
// Each test file that includes this module uses a part of it.
#![allow(dead_code)]

use dynacal::model::SimModel;
use dynacal::navsim::drive::board_model as board_model_of;
use dynacal_core::board_model::BoardModel;

/// Sample rate of every unit, Hz.
pub const RATE_HZ: f64 = 200.0;

/// The simulator's model of the three units and the receiver (antenna at the body origin,
/// white errors only) without fixes over `outages` (start, end s).
pub fn sim_model(outages: &[[f64; 2]]) -> SimModel {
    let mut model = dynacal::navsim::three_unit_model();
    if let Some(gnss) = model.gnss.as_mut() {
        gnss.outages = outages.to_vec();
    }
    model
}

/// The board model of the simulated mounts: the model's noise (`true_noise`), or the
/// board's built-in noise.
pub fn board_model(true_noise: bool) -> BoardModel {
    board_model_of(&sim_model(&[]), true_noise)
}
