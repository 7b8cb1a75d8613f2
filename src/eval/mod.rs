//! Scoring a reconstruction against ground truth (paper §5).
//!
//! This module owns the metrics only. It takes plain point sets (and optional normals) and
//! knows nothing of captures, simulation or reconstruction internals. Definitions:
//! - **point error**: distance from each reconstructed point to its nearest truth point;
//!   median and 90th percentile;
//! - **relative point error**: point error / d_G, with d_G the largest distance between two
//!   truth points; the fraction under 5 % is reported;
//! - **position error**: |P80(z_recon) − P80(z_truth)|;
//! - **F-score** at τ (1.5 cm in the paper): precision is the fraction of reconstructed points
//!   within τ of the truth, recall the fraction of truth points within τ of the
//!   reconstruction. It is computed after moving the reconstruction vertically by the signed
//!   position error (`f_score`), and as it stands (`f_score_raw`);
//! - **normal cosine similarity**: |n̂·n| against the normal of the nearest truth point
//!   (sign-agnostic); median and 25th percentile.
//!
//! An empty reconstruction scores F = 0; the truth scored against itself scores F = 1.

mod nearest;
pub mod normals;

pub use nearest::NearestNeighbours;
pub use normals::estimate_normals;

/// The scores of one reconstruction. `None` where a metric is undefined (no points, or no
/// normals on either side).
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Metrics {
    pub f_score: f64,
    pub precision: f64,
    pub recall: f64,
    pub f_score_raw: f64,
    pub position_error_m: Option<f64>,
    pub point_error_median_m: Option<f64>,
    pub point_error_p90_m: Option<f64>,
    pub rel_error_under_5pct: Option<f64>,
    pub normal_cos_median: Option<f64>,
    pub normal_cos_p25: Option<f64>,
    pub points: usize,
    pub truth_points: usize,
}

/// The q-quantile (0…1) of `values` by linear interpolation between order statistics (numpy's
/// default); `None` when empty.
pub fn quantile(values: &[f64], q: f64) -> Option<f64> {
    let mut v: Vec<f64> = values.iter().copied().filter(|x| !x.is_nan()).collect();
    if v.is_empty() {
        return None;
    }
    v.sort_by(f64::total_cmp);
    let pos = q.clamp(0.0, 1.0) * (v.len() - 1) as f64;
    let (lo, hi) = (pos.floor() as usize, pos.ceil() as usize);
    Some(v[lo] + (v[hi] - v[lo]) * (pos - lo as f64))
}

/// The largest distance between two points: the exact maximum over the extreme points of the
/// set along 2 000 directions. That covers the true diameter's end points for any set whose
/// hull is sampled finely enough; the result is never larger than the true diameter.
pub fn diameter(points: &[[f64; 3]]) -> f64 {
    if points.len() < 2 {
        return 0.0;
    }
    let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
    let directions = 2000;
    let mut extremes: Vec<usize> = Vec::new();
    for k in 0..directions {
        // Fibonacci sphere.
        let z = 1.0 - 2.0 * (k as f64 + 0.5) / directions as f64;
        let r = (1.0 - z * z).sqrt();
        let d = [
            r * (golden * k as f64).cos(),
            r * (golden * k as f64).sin(),
            z,
        ];
        let proj = |p: &[f64; 3]| p[0] * d[0] + p[1] * d[1] + p[2] * d[2];
        let best = (0..points.len()).max_by(|&a, &b| proj(&points[a]).total_cmp(&proj(&points[b])));
        extremes.extend(best);
    }
    extremes.sort_unstable();
    extremes.dedup();
    let mut best = 0.0f64;
    for (i, &a) in extremes.iter().enumerate() {
        for &b in &extremes[i + 1..] {
            let d = (0..3)
                .map(|k| (points[a][k] - points[b][k]).powi(2))
                .sum::<f64>();
            best = best.max(d);
        }
    }
    best.sqrt()
}

/// Each reconstructed point's own scores, for distributions pooled over many reconstructions
/// (the paper's Fig. 12c, 13, 14 and 15 pool points, not objects).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct PointScores {
    /// Distance to the nearest truth point, metres.
    pub error_m: Vec<f64>,
    /// `error_m` over the truth's diameter.
    pub relative: Vec<f64>,
    /// |cos| against the nearest truth point's normal; NaN where a point has no normal.
    pub normal_cos: Option<Vec<f64>>,
}

/// Scores `points` (with optional unit normals) against `truth` at F-score threshold `tau_m`.
pub fn evaluate(
    points: &[[f64; 3]],
    normals: Option<&[[f64; 3]]>,
    truth: &[[f64; 3]],
    truth_normals: Option<&[[f64; 3]]>,
    tau_m: f64,
) -> Metrics {
    evaluate_points(points, normals, truth, truth_normals, tau_m).0
}

/// [`evaluate`], with the per-point scores behind the metrics.
pub fn evaluate_points(
    points: &[[f64; 3]],
    normals: Option<&[[f64; 3]]>,
    truth: &[[f64; 3]],
    truth_normals: Option<&[[f64; 3]]>,
    tau_m: f64,
) -> (Metrics, PointScores) {
    let empty = Metrics {
        f_score: 0.0,
        precision: 0.0,
        recall: 0.0,
        f_score_raw: 0.0,
        position_error_m: None,
        point_error_median_m: None,
        point_error_p90_m: None,
        rel_error_under_5pct: None,
        normal_cos_median: None,
        normal_cos_p25: None,
        points: points.len(),
        truth_points: truth.len(),
    };
    if points.is_empty() || truth.is_empty() {
        return (empty, PointScores::default());
    }
    let truth_index = NearestNeighbours::new(truth, tau_m);
    let nearest: Vec<(usize, f64)> = points.iter().map(|p| truth_index.nearest(p)).collect();
    let errors: Vec<f64> = nearest.iter().map(|&(_, d)| d).collect();
    let d_g = diameter(truth);
    let under = errors
        .iter()
        .filter(|&&e| d_g > 0.0 && e / d_g < 0.05)
        .count();

    let z80 = |s: &[[f64; 3]]| quantile(&s.iter().map(|p| p[2]).collect::<Vec<_>>(), 0.8);
    let shift = z80(truth)
        .zip(z80(points))
        .map(|(t, r)| t - r)
        .unwrap_or(0.0);
    let f = |shift_m: f64| {
        let moved: Vec<[f64; 3]> = points
            .iter()
            .map(|p| [p[0], p[1], p[2] + shift_m])
            .collect();
        let recon_index = NearestNeighbours::new(&moved, tau_m);
        let precision = moved
            .iter()
            .filter(|p| truth_index.within(p, tau_m))
            .count() as f64
            / moved.len() as f64;
        let recall = truth
            .iter()
            .filter(|p| recon_index.within(p, tau_m))
            .count() as f64
            / truth.len() as f64;
        let f = if precision + recall > 0.0 {
            2.0 * precision * recall / (precision + recall)
        } else {
            0.0
        };
        (f, precision, recall)
    };
    let (f_score, precision, recall) = f(shift);
    let (f_score_raw, _, _) = f(0.0);

    let cosines: Option<Vec<f64>> = normals.zip(truth_normals).map(|(n, tn)| {
        nearest
            .iter()
            .zip(n)
            .map(|(&(j, _), a)| {
                let b = tn[j];
                (a[0] * b[0] + a[1] * b[1] + a[2] * b[2]).abs()
            })
            .collect()
    });
    let metrics = Metrics {
        f_score,
        precision,
        recall,
        f_score_raw,
        position_error_m: Some(shift.abs()),
        point_error_median_m: quantile(&errors, 0.5),
        point_error_p90_m: quantile(&errors, 0.9),
        rel_error_under_5pct: Some(under as f64 / points.len() as f64),
        normal_cos_median: cosines.as_ref().and_then(|c| quantile(c, 0.5)),
        normal_cos_p25: cosines.as_ref().and_then(|c| quantile(c, 0.25)),
        ..empty
    };
    let relative = errors
        .iter()
        .map(|e| if d_g > 0.0 { e / d_g } else { f64::NAN })
        .collect();
    let scores = PointScores {
        error_m: errors,
        relative,
        normal_cos: cosines,
    };
    (metrics, scores)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn patch(z: f64, step: f64) -> Vec<[f64; 3]> {
        let mut v = Vec::new();
        for i in 0..40 {
            for j in 0..30 {
                v.push([i as f64 * step, j as f64 * step, z]);
            }
        }
        v
    }

    #[test]
    fn truth_against_itself_scores_one_and_empty_scores_zero() {
        let t = patch(0.0, 0.002);
        let n = vec![[0.0, 0.0, 1.0]; t.len()];
        let m = evaluate(&t, Some(&n), &t, Some(&n), 0.015);
        assert_eq!(
            (m.f_score, m.precision, m.recall, m.f_score_raw),
            (1.0, 1.0, 1.0, 1.0)
        );
        assert_eq!(m.point_error_median_m, Some(0.0));
        assert_eq!(m.normal_cos_median, Some(1.0));
        assert_eq!(m.rel_error_under_5pct, Some(1.0));
        let e = evaluate(&[], None, &t, None, 0.015);
        assert_eq!((e.f_score, e.points, e.truth_points), (0.0, 0, 1200));
        assert_eq!(e.normal_cos_median, None);
    }

    #[test]
    fn a_vertical_offset_is_position_error_not_shape_error() {
        let t = patch(0.0, 0.002);
        let r = patch(0.03, 0.002);
        let m = evaluate(&r, None, &t, None, 0.015);
        assert!((m.position_error_m.unwrap() - 0.03).abs() < 1e-12);
        assert_eq!(m.f_score, 1.0);
        assert_eq!(m.f_score_raw, 0.0);
        assert!((m.point_error_median_m.unwrap() - 0.03).abs() < 1e-12);
    }

    #[test]
    fn partial_coverage_lowers_recall_and_tilted_normals_lower_cosine() {
        let t = patch(0.0, 0.002);
        let half: Vec<[f64; 3]> = t.iter().copied().filter(|p| p[0] < 0.039).collect();
        let tilt = [0.6, 0.0, 0.8];
        let m = evaluate(
            &half,
            Some(&vec![tilt; half.len()]),
            &t,
            Some(&vec![[0.0, 0.0, 1.0]; t.len()]),
            0.005,
        );
        assert_eq!(m.precision, 1.0);
        // Truth columns within 5 mm of the kept half are still covered.
        let covered = t.iter().filter(|p| p[0] < 0.039 + 0.005).count() as f64 / t.len() as f64;
        assert!(
            (m.recall - covered).abs() < 1e-12,
            "{} vs {covered}",
            m.recall
        );
        assert!((m.normal_cos_median.unwrap() - 0.8).abs() < 1e-12);
    }

    #[test]
    fn diameter_and_quantiles_match_closed_forms() {
        let t = patch(0.0, 0.002);
        let want = (0.078f64.powi(2) + 0.058f64.powi(2)).sqrt();
        assert!((diameter(&t) - want).abs() < 1e-12);
        assert_eq!(quantile(&[1.0, 2.0, 3.0, 4.0], 0.5), Some(2.5));
        assert_eq!(quantile(&[5.0], 0.8), Some(5.0));
        assert_eq!(quantile(&[], 0.5), None);
    }
}
