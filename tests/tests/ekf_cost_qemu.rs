//! Cost of the navigation filter: builds `firmware/src/bin/ekf_cost.rs` for the Cortex-M4F
//! (thumbv7em-none-eabihf, QEMU's netduinoplus2) and holds the `f32` counts under fixed
//! bounds, so a change that makes the filter markedly more expensive fails here; and for a
//! Cortex-M3 without an FPU (thumbv7m-none-eabi, QEMU's netduino2), where the fixed-point
//! filter must cost at most half of software floats. QEMU runs with `-icount shift=0`, so
//! instruction counts are deterministic.
//!
//! Skips with a message when qemu-system-arm is absent, except in CI (`CI` or
//! `DYNACAL_REQUIRE_QEMU` set), where that fails the test.

use std::collections::HashMap;

use dynacal_tests::CostCore;

/// Measured at stop 51 (rustc 1.95, the `firmware` profile the boards run: the filter and
/// nalgebra at opt-level 2, fat LTO): 15 states, one GNSS epoch (linearisation + predict +
/// position and velocity fusion + reset) 37 168 instructions. Bounds leave about 25 % for
/// compiler and model changes.
const MAX_GNSS_EPOCH_15: u64 = 60_000;
/// 27 states, one epoch with GNSS and both extra IMUs' boresight/lever-arm updates
/// (measured 197 332).
const MAX_FULL_EPOCH_27: u64 = 245_000;
/// 27-state block-sparse prediction alone (measured 26 339; a dense Φ P Φᵀ 98 657).
const MAX_PREDICT_27: u64 = 33_000;

/// Parses `ekf-cost scalar=S states=N key=value ...` lines into one map per scalar and
/// state count.
fn parse(stderr: &str) -> HashMap<(String, u64), HashMap<String, u64>> {
    let mut out = HashMap::new();
    for line in stderr.lines().filter(|l| l.starts_with("ekf-cost scalar=")) {
        let mut scalar = String::new();
        let mut fields = HashMap::new();
        for (k, v) in line
            .split_whitespace()
            .skip(1)
            .filter_map(|kv| kv.split_once('='))
        {
            match v.parse() {
                Ok(n) => {
                    fields.insert(k.to_string(), n);
                }
                Err(_) if k == "scalar" => scalar = v.to_string(),
                Err(_) => {}
            }
        }
        if let Some(&n) = fields.get("states") {
            out.insert((scalar, n), fields);
        }
    }
    out
}

/// One stage's instructions of the `scalar` filter with `states` states.
fn stage(
    costs: &HashMap<(String, u64), HashMap<String, u64>>,
    scalar: &str,
    states: u64,
    key: &str,
) -> u64 {
    *costs
        .get(&(scalar.to_string(), states))
        .and_then(|m| m.get(key))
        .unwrap_or_else(|| panic!("no {key} for {scalar} with {states} states in: {costs:?}"))
}

/// A full epoch of the 27-state filter: linearisation, prediction, GNSS position and
/// velocity, both extra IMUs' inter-IMU updates, reset.
fn full_epoch_27(costs: &HashMap<(String, u64), HashMap<String, u64>>, scalar: &str) -> u64 {
    [
        "linearization",
        "predict",
        "gnss_pos_vel",
        "inter_imu_all",
        "reset",
    ]
    .iter()
    .map(|key| stage(costs, scalar, 27, key))
    .sum()
}

#[test]
fn navigation_filter_epoch_cost_on_cortex_m4f_stays_within_bounds() {
    let Some(stderr) = dynacal_tests::run_cost_bench("ekf_cost") else {
        return;
    };
    let costs = parse(&stderr);
    let get = |states: u64, key: &str| -> u64 { stage(&costs, "f32", states, key) };
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
    let full_epoch_27 = full_epoch_27(&costs, "f32");
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
    // Side by side in the same run, the dense N×N Φ P Φᵀ (without even the process noise):
    // at 27 states several times the whole block-sparse prediction; at 15 states, in the
    // boards' profile (level 2, loops not unrolled), about the same (1.02 at stop 51; 1.6
    // at level 3), so there the bound only keeps the block-sparse form from falling behind.
    for (n, least) in [(15, 0.9), (27, 2.5)] {
        let ratio = get(n, "dense_predict") as f64 / get(n, "predict") as f64;
        eprintln!("{n} states: dense/block-sparse prediction = {ratio:.2}");
        assert!(ratio > least, "{n} states: dense/sparse only {ratio}");
    }
}

/// On a core without an FPU (a Cortex-M3: QEMU's netduino2), the same bench in the same run:
/// the 27-state filter's full epoch (two extra IMUs, one GNSS update) in Q32.32 fixed point
/// takes at most half the instructions of `f32`, whose every operation is a library call
/// there; and it is built for that core at all (the flash and RAM of the image are
/// reported).
#[test]
fn fixed_point_takes_half_the_instructions_of_software_floats_without_an_fpu() {
    let Some((stderr, elf)) = dynacal_tests::run_cost_bench_on("ekf_cost", CostCore::M3) else {
        return;
    };
    let costs = parse(&stderr);
    let (soft, fixed) = (full_epoch_27(&costs, "f32"), full_epoch_27(&costs, "fixed"));
    let (flash, statics) = dynacal_tests::flash_and_statics(&elf);
    eprintln!(
        "Cortex-M3, 27-state epoch: software f32 {soft} instructions, fixed point {fixed} \
         ({:.2}x fewer); the bench image: {flash} bytes of flash, {statics} of statics",
        soft as f64 / fixed as f64
    );
    for key in ["predict", "gnss_pos_vel", "inter_imu_all", "reset"] {
        eprintln!(
            "  {key}: f32 {} fixed {}",
            stage(&costs, "f32", 27, key),
            stage(&costs, "fixed", 27, key)
        );
    }
    assert!(stage(&costs, "fixed", 27, "predict") > 1_000, "{costs:?}");
    assert!(
        2 * fixed <= soft,
        "fixed {fixed} against software f32 {soft}"
    );
}
