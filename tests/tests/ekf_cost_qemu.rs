//! Cost of the navigation filter on the Cortex-M4F: builds `firmware/src/bin/ekf_cost.rs`
//! for thumbv7em-none-eabihf, runs it in QEMU's netduinoplus2 with `-icount shift=0` (so
//! instruction counts are deterministic) and holds the counts under fixed bounds, so a
//! change that makes the filter markedly more expensive fails here.
//!
//! Skips with a message when qemu-system-arm is absent, except in CI (`CI` or
//! `DYNACAL_REQUIRE_QEMU` set), where that fails the test.

use std::collections::HashMap;

/// Measured at this commit (rustc 1.95, release profile): 15 states, one GNSS epoch
/// (linearisation + predict + position and velocity fusion + reset) 48 176 instructions.
/// Bounds leave about 25 % for compiler and model changes.
const MAX_GNSS_EPOCH_15: u64 = 60_000;
/// 27 states, one epoch with GNSS and both extra IMUs' boresight/lever-arm updates
/// (measured 196 505).
const MAX_FULL_EPOCH_27: u64 = 245_000;
/// 27-state block-sparse prediction alone (measured 17 709; a dense Φ P Φᵀ costs several
/// times more).
const MAX_PREDICT_27: u64 = 22_000;

/// Parses `ekf-cost states=N key=value ...` lines into one map per state count.
fn parse(stderr: &str) -> HashMap<u64, HashMap<String, u64>> {
    let mut out = HashMap::new();
    for line in stderr.lines().filter(|l| l.starts_with("ekf-cost states=")) {
        let fields: HashMap<String, u64> = line
            .split_whitespace()
            .skip(1)
            .filter_map(|kv| {
                let (k, v) = kv.split_once('=')?;
                Some((k.to_string(), v.parse().ok()?))
            })
            .collect();
        if let Some(&n) = fields.get("states") {
            out.insert(n, fields);
        }
    }
    out
}

#[test]
fn navigation_filter_epoch_cost_on_cortex_m4f_stays_within_bounds() {
    let Some(stderr) = dynacal_tests::run_cost_bench("ekf_cost") else {
        return;
    };
    let costs = parse(&stderr);
    let get = |states: u64, key: &str| -> u64 {
        *costs
            .get(&states)
            .and_then(|m| m.get(key))
            .unwrap_or_else(|| panic!("no {key} for {states} states in: {stderr}"))
    };
    // The calibration must be sane (about 5.95 instructions per SysTick tick), or every
    // count below would be meaningless.
    let calibration: HashMap<String, u64> = stderr
        .lines()
        .find(|l| l.starts_with("ekf-cost calibration_instructions="))
        .map(|l| {
            l.split_whitespace()
                .skip(1)
                .filter_map(|kv| {
                    let (k, v) = kv.split_once('=')?;
                    Some((k.to_string(), v.parse().ok()?))
                })
                .collect()
        })
        .expect("calibration line");
    let per_tick =
        calibration["calibration_instructions"] as f64 / calibration["calibration_ticks"] as f64;
    assert!(
        (5.0..7.0).contains(&per_tick),
        "{per_tick} instructions per tick"
    );

    let gnss_epoch_15 =
        get(15, "linearization") + get(15, "predict") + get(15, "gnss_pos_vel") + get(15, "reset");
    let full_epoch_27 = get(27, "linearization")
        + get(27, "predict")
        + get(27, "gnss_pos_vel")
        + get(27, "inter_imu_all")
        + get(27, "reset");
    eprintln!(
        "15-state GNSS epoch {gnss_epoch_15} instructions; 27-state full epoch {full_epoch_27}"
    );
    // Real work was measured (a broken clock would report zeros).
    assert!(get(15, "predict") > 1_000 && get(27, "inter_imu_all") > 10_000);
    assert!(
        gnss_epoch_15 < MAX_GNSS_EPOCH_15,
        "15-state GNSS epoch {gnss_epoch_15}"
    );
    assert!(
        full_epoch_27 < MAX_FULL_EPOCH_27,
        "27-state epoch {full_epoch_27}"
    );
    assert!(
        get(27, "predict") < MAX_PREDICT_27,
        "27-state predict {}",
        get(27, "predict")
    );
    // The prediction exploits the block structure: 12 more (constant) states cost far less
    // than the (27/15)³ ≈ 5.8× of a dense N³ product.
    assert!(get(27, "predict") * 2 < get(15, "predict") * 4);
    // Side by side in the same run, the dense N×N Φ P Φᵀ (without even the process noise)
    // costs more than the whole block-sparse prediction.
    for n in [15, 27] {
        let ratio = get(n, "dense_predict") as f64 / get(n, "predict") as f64;
        eprintln!("{n} states: dense/block-sparse prediction = {ratio:.2}");
        assert!(ratio > 1.5, "{n} states: dense/sparse only {ratio}");
    }
}
