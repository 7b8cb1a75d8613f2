//! Capture directory v1: interop with numpy, bit-exact round trips and clear refusals.

use std::fs;
use std::path::{Path, PathBuf};

use mmnormd::capture::npy;
use mmnormd::capture::{Capture, FrequencyPlan, read_capture_dir, write_capture_dir};
use num_complex::Complex32;

fn fixture() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/numpy_capture")
}

fn small_capture() -> Capture {
    let n = 3;
    let t = 4;
    Capture {
        plan: FrequencyPlan {
            start_frequency_hz: 77.5e9,
            frequency_step_hz: 5.86e6,
            samples_per_chirp: t,
        },
        range_offset_m: 0.15,
        tx_m: vec![[0.0, 0.0, 0.4], [0.001, 0.0, 0.4], [0.002, 1e-17, 0.4]],
        rx_m: vec![[-0.005, 0.0, 0.4], [-0.004, 0.0, 0.4], [-0.003, 0.0, 0.4]],
        samples: std::sync::Arc::new(
            (0..n * t)
                .map(|k| Complex32::new(k as f32 * 0.1 + 1e-30, -(k as f32).sqrt()))
                .collect(),
        ),
        description: "unit test".into(),
        extra: serde_json::Map::new(),
    }
}

#[test]
fn numpy_written_capture_is_read_and_written_back_byte_identically() {
    let capture = read_capture_dir(&fixture()).unwrap();
    assert_eq!(capture.antennas(), 25);
    assert_eq!(capture.plan.samples_per_chirp, 64);
    assert!(capture.extra.contains_key("made_by"));
    assert!(capture.extra.contains_key("point_target"));
    let dir = tempfile::tempdir().unwrap();
    write_capture_dir(dir.path(), &capture).unwrap();
    for name in ["tx.npy", "rx.npy", "samples.npy"] {
        assert_eq!(
            fs::read(fixture().join(name)).unwrap(),
            fs::read(dir.path().join(name)).unwrap(),
            "{name} differs from numpy's bytes"
        );
    }
    let again = read_capture_dir(dir.path()).unwrap();
    assert_eq!(again, capture);
    // Unknown keys keep their order and values.
    let keys: Vec<_> = again.extra.keys().cloned().collect();
    assert_eq!(keys, ["made_by", "point_target"]);
}

#[test]
fn round_trip_is_bit_exact_including_subnormals_and_extra_keys() {
    let mut c = small_capture();
    c.extra.insert(
        "operator".into(),
        serde_json::json!({"name": "lab", "run": 7}),
    );
    c.extra
        .insert("z_first".into(), serde_json::json!(0.1 + 0.2));
    let dir = tempfile::tempdir().unwrap();
    write_capture_dir(dir.path(), &c).unwrap();
    let back = read_capture_dir(dir.path()).unwrap();
    assert_eq!(back, c);
    for (a, b) in back.samples.iter().zip(c.samples.iter()) {
        assert_eq!(a.re.to_bits(), b.re.to_bits());
        assert_eq!(a.im.to_bits(), b.im.to_bits());
    }
    let first = fs::read(dir.path().join("capture.json")).unwrap();
    write_capture_dir(dir.path(), &back).unwrap();
    assert_eq!(first, fs::read(dir.path().join("capture.json")).unwrap());
}

/// Writes a valid capture, lets `spoil` damage it, and returns the error text.
fn refusal(spoil: impl FnOnce(&Path)) -> String {
    let dir = tempfile::tempdir().unwrap();
    write_capture_dir(dir.path(), &small_capture()).unwrap();
    spoil(dir.path());
    let err = read_capture_dir(dir.path()).expect_err("the damaged capture was accepted");
    err.to_string()
}

/// Refusal of a capture whose `capture.json` has `from` replaced by `to`.
fn json_refusal(from: &str, to: &str) -> String {
    refusal(|d| {
        let text = fs::read_to_string(d.join("capture.json")).unwrap();
        assert!(text.contains(from), "{from} not in capture.json");
        fs::write(d.join("capture.json"), text.replace(from, to)).unwrap();
    })
}

#[test]
fn damaged_captures_are_refused_naming_file_and_problem() {
    let e = refusal(|d| fs::remove_file(d.join("rx.npy")).unwrap());
    assert!(e.contains("rx.npy"), "{e}");

    let e = refusal(|d| {
        let bytes = fs::read(d.join("samples.npy")).unwrap();
        fs::write(d.join("samples.npy"), &bytes[..bytes.len() - 3]).unwrap();
    });
    assert!(
        e.contains("samples.npy") && e.contains("93 data bytes"),
        "{e}"
    );

    let e = refusal(|d| {
        let f32_rows: Vec<u8> = {
            let mut b = npy::header("<f4", &[3, 3]);
            b.extend_from_slice(&[0u8; 36]);
            b
        };
        fs::write(d.join("tx.npy"), f32_rows).unwrap();
    });
    assert!(
        e.contains("tx.npy") && e.contains("'<f4'") && e.contains("float64"),
        "{e}"
    );

    let e = refusal(|d| {
        fs::write(d.join("tx.npy"), npy::encode_f64_rows(&[[0.0; 3]; 2])).unwrap();
    });
    assert!(
        e.contains("tx.npy") && e.contains("2 antennas") && e.contains("antennas = 3"),
        "{e}"
    );

    let e = refusal(|d| {
        let mut rows = vec![[0.0, 0.0, 0.4]; 3];
        rows[1][2] = f64::NAN;
        fs::write(d.join("rx.npy"), npy::encode_f64_rows(&rows)).unwrap();
    });
    assert!(e.contains("rx.npy") && e.contains("row 1"), "{e}");

    let e = refusal(|d| {
        let mut b = npy::header("<c8", &[3, 2, 2]);
        b.extend_from_slice(&[0u8; 96]);
        fs::write(d.join("samples.npy"), b).unwrap();
    });
    assert!(e.contains("samples.npy") && e.contains("(N, T)"), "{e}");

    let e = json_refusal("\"samples_per_chirp\": 4", "\"samples_per_chirp\": 5");
    assert!(
        e.contains("samples.npy") && e.contains("samples_per_chirp = 5"),
        "{e}"
    );

    let e = json_refusal("\"version\": 1", "\"version\": 2");
    assert!(e.contains("capture.json") && e.contains("version"), "{e}");

    let e = json_refusal("\"range_offset_m\": 0.15", "\"range_offset_m\": \"far\"");
    assert!(e.contains("range_offset_m"), "{e}");
}

#[test]
fn non_finite_samples_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let mut c = small_capture();
    std::sync::Arc::make_mut(&mut c.samples)[5].im = f32::INFINITY;
    assert!(write_capture_dir(dir.path(), &c).is_err());
    let good = small_capture();
    write_capture_dir(dir.path(), &good).unwrap();
    let mut bad = good.samples.to_vec();
    bad[6].re = f32::NAN;
    fs::write(dir.path().join("samples.npy"), npy::encode_c64(&bad, 3, 4)).unwrap();
    let e = read_capture_dir(dir.path()).unwrap_err().to_string();
    assert!(e.contains("samples.npy") && e.contains("[1, 2]"), "{e}");
}
