//! Li's threshold against scikit-image 0.22 on committed fixtures
//! (`tests/data/li_threshold.json`, written by `tools/make_li_fixtures.py`).

use std::path::Path;

use mmnormd::recon::threshold::li_threshold;

#[test]
fn li_threshold_matches_scikit_image() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/li_threshold.json");
    let fixture: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap();
    let cases = fixture["cases"].as_array().unwrap();
    assert!(cases.len() >= 7);
    for case in cases {
        let name = case["name"].as_str().unwrap();
        let values: Vec<f64> = case["values"]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_f64().unwrap_or(f64::NAN))
            .collect();
        let want = case["threshold"].as_f64().unwrap();
        let got = li_threshold(&values, 1000).unwrap();
        let rel = (got.threshold - want).abs() / want.abs().max(1e-12);
        println!(
            "{name}: {:.12} vs scikit-image {want:.12} (rel {rel:.1e}, {} iterations)",
            got.threshold, got.iterations
        );
        assert!(rel < 1e-9, "{name}: {} vs {want}", got.threshold);
    }
}
