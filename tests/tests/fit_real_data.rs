//! `fit --model auto` on real data: all six ADIS16405 sessions (integer counts at 100 Hz,
//! gyro x 0.05 deg/s, accel x 0.00333 g) and every channel of the SMAC-Group reference WVs.
//! Each fit must converge and report a model with finite positive values and intervals that
//! contain them. Channels run in parallel.

use dynacal::gmwm::fit::{FitInput, FitOptions};
use dynacal::gmwm::inference::{analyze, ChannelFit, ModelChoice};
use dynacal::interchange::{read_table, CHANNELS};
use dynacal::wv::{haar_wv_counts, read_smac_golden, WvOptions};
use rayon::prelude::*;

fn check(fit: &ChannelFit, what: &str) {
    assert!(
        fit.converged,
        "{what}: not converged ({:?})",
        fit.stop_reason
    );
    assert!(!fit.parameters.is_empty(), "{what}: no parameters");
    for p in &fit.parameters {
        assert!(
            p.value.is_finite() && p.value > 0.0,
            "{what}: {} {} = {}",
            p.process,
            p.name,
            p.value
        );
        let [lo, hi] = p
            .ci95
            .unwrap_or_else(|| panic!("{what}: {} {} has no interval", p.process, p.name));
        assert!(
            lo > 0.0 && lo <= p.value && p.value <= hi,
            "{what}: {} {} = {} outside [{lo}, {hi}]",
            p.process,
            p.name,
            p.value
        );
    }
    let cands = fit.candidates.as_ref().expect("auto lists candidates");
    assert!(cands.len() > 10, "{what}: only {} candidates", cands.len());
    assert!(
        cands.iter().any(|c| c.model == fit.model),
        "{what}: chosen model not among candidates"
    );
    println!(
        "{what}: {} objective {:.3e} J-test p {:.2e}",
        fit.model,
        fit.objective,
        fit.j_test.as_ref().map_or(f64::NAN, |j| j.p_value)
    );
}

#[test]
fn auto_fit_converges_on_all_adis16405_sessions() {
    let dir = dynacal::data_dir().join("adis16405");
    if !dir.exists() {
        println!("SKIP: {} not found (set DYNACAL_DATA)", dir.display());
        return;
    }
    let jobs: Vec<(usize, usize)> = (1..=6).flat_map(|s| (0..6).map(move |c| (s, c))).collect();
    let tables: Vec<_> = (1..=6)
        .into_par_iter()
        .map(|s| read_table(&dir.join(format!("session{s}.csv.gz")), Some(&CHANNELS)).unwrap())
        .collect();
    jobs.par_iter().for_each(|&(s, c)| {
        let t = &tables[s - 1];
        let counts: Vec<i32> = t
            .column(CHANNELS[c])
            .unwrap()
            .iter()
            .map(|&v| v as i32)
            .collect();
        let (lsb, unit) = if c < 3 {
            (0.05, "deg/s")
        } else {
            (0.00333, "g")
        };
        let wv = haar_wv_counts(&counts, lsb, 0.01, &WvOptions::default()).unwrap();
        let input = FitInput::from_wv(&wv).unwrap();
        let fit = analyze(
            CHANNELS[c],
            unit,
            &input,
            &ModelChoice::Auto,
            None,
            &FitOptions::default(),
        )
        .unwrap();
        check(&fit, &format!("session{s} {}", CHANNELS[c]));
    });
}

#[test]
fn auto_fit_converges_on_all_reference_wvs() {
    let path = dynacal::data_dir().join("golden/smac_wavelet_variance.json");
    if !path.exists() {
        println!("SKIP: {} not found (set DYNACAL_DATA)", path.display());
        return;
    }
    let channels = read_smac_golden(&path).unwrap();
    assert!(channels.len() >= 27);
    channels.par_iter().for_each(|g| {
        let input = FitInput::from_wv(&g.wv).unwrap();
        let fit = analyze(
            &g.channel,
            "unit",
            &input,
            &ModelChoice::Auto,
            None,
            &FitOptions::default(),
        )
        .unwrap();
        check(&fit, &format!("{} {}", g.sensor_key, g.channel));
    });
}
