//! Reading a value back from a Kalibr `imu.yaml` (`key: value  # comment`), as the tests of
//! `dynacal export` and `dynacal noise` check what those commands wrote.

/// The number after `key:` in `text`, its comment dropped; panics, showing the file, when
/// the key is absent.
pub fn kalibr_value(text: &str, key: &str) -> f64 {
    text.lines()
        .find_map(|l| l.strip_prefix(&format!("{key}:")))
        .and_then(|v| v.split('#').next())
        .map(|v| v.trim().parse().unwrap())
        .unwrap_or_else(|| panic!("no {key} in\n{text}"))
}
