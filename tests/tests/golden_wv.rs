//! The batch Haar wavelet variance reproduces the reference implementation's published values
//! (SMAC-Group `wv`, `golden/smac_wavelet_variance.json` key `adis`) on the real ADIS16405
//! session 1, through both the integer-count and the floating-point paths.

use dynacal::interchange::{read_table, CHANNELS};
use dynacal::wv::{haar_wv, haar_wv_counts, read_smac_golden, WaveletVariance, WvOptions};

/// deg/s per count (gyro) and g per count (accelerometer), from the data README.
const LSB: [f64; 6] = [0.05, 0.05, 0.05, 0.00333, 0.00333, 0.00333];

fn max_rel(a: &[f64], b: &[f64]) -> f64 {
    assert_eq!(a.len(), b.len());
    a.iter()
        .zip(b)
        .map(|(x, y)| ((x - y) / y).abs())
        .fold(0.0, f64::max)
}

fn assert_matches(ours: &WaveletVariance, golden: &WaveletVariance, what: &str, tol: f64) {
    assert_eq!(ours.levels, golden.levels, "{what}: levels");
    let checks = [
        ("scales", max_rel(&ours.scales_s, &golden.scales_s)),
        ("variance", max_rel(&ours.variance, &golden.variance)),
        ("ci_low", max_rel(&ours.ci_low, &golden.ci_low)),
        ("ci_high", max_rel(&ours.ci_high, &golden.ci_high)),
    ];
    for (name, err) in checks {
        println!("{what} {name}: max relative difference {err:.2e}");
        assert!(
            err <= tol,
            "{what} {name}: relative difference {err:e} > {tol:e}"
        );
    }
}

#[test]
fn adis_session1_matches_reference_wv() {
    let data = dynacal::data_dir();
    let session = data.join("adis16405/session1.csv.gz");
    let golden_path = data.join("golden/smac_wavelet_variance.json");
    if !session.exists() || !golden_path.exists() {
        println!(
            "SKIP: {} or {} absent",
            session.display(),
            golden_path.display()
        );
        return;
    }
    let golden = read_smac_golden(&golden_path).unwrap();
    let adis: Vec<_> = golden.iter().filter(|g| g.sensor_key == "adis").collect();
    assert_eq!(adis.len(), 6);
    let table = read_table(&session, Some(&CHANNELS)).unwrap();
    for (c, name) in CHANNELS.iter().enumerate() {
        let reference = adis
            .iter()
            .find(|g| g.channel_key() == Some(name))
            .unwrap_or_else(|| panic!("no golden channel for {name}"));
        let column = table.column(name).unwrap();
        assert_eq!(column.len(), reference.wv.n);
        let counts: Vec<i32> = column.iter().map(|&v| v as i32).collect();
        assert!(column.iter().zip(&counts).all(|(&v, &c)| v == c as f64));

        let exact = haar_wv_counts(&counts, LSB[c], 0.01, &WvOptions::default()).unwrap();
        assert_matches(&exact, &reference.wv, &format!("{name} counts"), 1e-9);

        let physical: Vec<f64> = counts.iter().map(|&k| k as f64 * LSB[c]).collect();
        let float = haar_wv(&physical, 0.01, &WvOptions::default()).unwrap();
        assert_matches(&float, &reference.wv, &format!("{name} f64"), 1e-9);

        // Overlapping Allan variance is twice the WV, at half the scale.
        for i in 0..exact.len() {
            assert_eq!(exact.allan_variance[i], 2.0 * exact.variance[i]);
            assert_eq!(exact.allan_tau_s()[i] * 2.0, exact.scales_s[i]);
            assert_eq!(exact.n_coefficients[i], counts.len() + 1 - (1 << (i + 1)));
        }
    }
}
