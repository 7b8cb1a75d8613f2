//! Li's minimum cross-entropy threshold (Li & Lee 1993; Li & Tam 1998), used by mmNorm's binary
//! mask (§3.2, docs/mmnorm-reference.md §4.1).
//!
//! The iteration is scikit-image's `threshold_li` for floating-point images, step for step:
//! - NaNs are dropped;
//! - the values are shifted by their minimum;
//! - t starts at the mean;
//! - t ← (μ_b − μ_f)/(ln μ_b − ln μ_f), with μ_f the mean of the values above t and μ_b the mean
//!   of the rest;
//! - iteration stops when the step is at most half the smallest gap between distinct values, or
//!   when μ_b = 0;
//! - the minimum is added back.
//!
//! Arithmetic is f64. `tests/recon_threshold.rs` checks agreement with scikit-image 0.22 on
//! committed fixtures.

/// The threshold and how many updates it took.
use rayon::prelude::*;

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LiThreshold {
    pub threshold: f64,
    pub iterations: usize,
}

/// Why no threshold was found.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum LiError {
    #[error("Li threshold: no values (all NaN or empty)")]
    Empty,
    #[error("Li threshold did not converge within {0} iterations")]
    NotConverged(usize),
}

/// Li's threshold of `values`, giving up after `max_iterations` updates (mmNorm's code gives up
/// after 1000). Equal values return that value; values that are all ±∞ return 0, as in
/// scikit-image.
pub fn li_threshold(values: &[f64], max_iterations: usize) -> Result<LiThreshold, LiError> {
    let not_nan: Vec<f64> = values.par_iter().copied().filter(|v| !v.is_nan()).collect();
    let Some(&first) = not_nan.first() else {
        return Err(LiError::Empty);
    };
    if not_nan.iter().all(|&v| v == first) {
        return Ok(LiThreshold {
            threshold: first,
            iterations: 0,
        });
    }
    let mut image: Vec<f64> = not_nan.into_par_iter().filter(|v| v.is_finite()).collect();
    if image.is_empty() {
        return Ok(LiThreshold {
            threshold: 0.0,
            iterations: 0,
        });
    }
    let min = image.par_iter().copied().reduce(|| f64::INFINITY, f64::min);
    image.par_iter_mut().for_each(|v| *v -= min);
    let tolerance = half_smallest_gap(&image);
    let mean = image.par_iter().sum::<f64>() / image.len() as f64;
    // The values are finite here, so `<=` is the exact complement of `>`.
    let (t, iterations) = iterate(mean, tolerance, max_iterations, |t| split_means(&image, t))?;
    Ok(LiThreshold {
        threshold: t + min,
        iterations,
    })
}

/// Li's update t ← (μ_b − μ_f)/(ln μ_b − ln μ_f) from `start` until the step is at most
/// `tolerance`; `means(t)` gives (μ_f, μ_b) of the shifted values above and at or below t.
/// Returns the last t and the number of updates.
fn iterate(
    start: f64,
    tolerance: f64,
    max_iterations: usize,
    means: impl Fn(f64) -> (f64, f64),
) -> Result<(f64, usize), LiError> {
    let mut t_next = start;
    let mut t_curr = -2.0 * tolerance;
    let mut iterations = 0;
    while (t_next - t_curr).abs() > tolerance {
        if iterations == max_iterations {
            return Err(LiError::NotConverged(max_iterations));
        }
        t_curr = t_next;
        let (mean_fore, mean_back) = means(t_curr);
        if mean_back == 0.0 {
            break;
        }
        t_next = (mean_back - mean_fore) / (mean_back.ln() - mean_fore.ln());
        iterations += 1;
    }
    Ok((t_next, iterations))
}

/// Mean of the values; NaN for none (as numpy's mean of an empty selection).
/// The means of the values above `t` and of those at or below it, in one parallel pass.
fn split_means(values: &[f64], t: f64) -> (f64, f64) {
    let zero = || (0.0f64, 0usize, 0.0f64, 0usize);
    let (fore, n_fore, back, n_back) = values
        .par_iter()
        .fold(zero, |(f, nf, b, nb), &v| {
            if v > t {
                (f + v, nf + 1, b, nb)
            } else {
                (f, nf, b + v, nb + 1)
            }
        })
        .reduce(zero, |x, y| (x.0 + y.0, x.1 + y.1, x.2 + y.2, x.3 + y.3));
    (fore / n_fore as f64, back / n_back as f64)
}

/// Half the smallest gap between distinct values (at least two distinct values exist).
/// [`li_threshold`] of finite values given in ascending order, in O(log n) per iteration: the
/// means above and below t come from prefix sums (compensated) and a binary search, instead of
/// a pass over the values. mmNorm's mask runs Li on 10⁸ voxels, where a pass costs 50 ms and
/// the iteration may take hundreds.
pub fn li_threshold_sorted(sorted: &[f64], max_iterations: usize) -> Result<LiThreshold, LiError> {
    let (Some(&first), Some(&last)) = (sorted.first(), sorted.last()) else {
        return Err(LiError::Empty);
    };
    if first == last {
        return Ok(LiThreshold {
            threshold: first,
            iterations: 0,
        });
    }
    let n = sorted.len();
    // prefix[i] = Σ_{j<i} (v_j − min), Neumaier-compensated.
    let mut prefix = Vec::with_capacity(n + 1);
    let (mut sum, mut carry) = (0.0f64, 0.0f64);
    prefix.push(0.0);
    for &v in sorted {
        let x = v - first;
        let t = sum + x;
        carry += if sum.abs() >= x.abs() {
            (sum - t) + x
        } else {
            (x - t) + sum
        };
        sum = t;
        prefix.push(sum + carry);
    }
    let tolerance = half_smallest_sorted_gap(sorted);
    let total = prefix[n];
    let (t, iterations) = iterate(total / n as f64, tolerance, max_iterations, |t| {
        let split = sorted.partition_point(|&v| v - first <= t);
        (
            (total - prefix[split]) / (n - split) as f64,
            prefix[split] / split as f64,
        )
    })?;
    Ok(LiThreshold {
        threshold: t + first,
        iterations,
    })
}

/// Half the smallest positive difference between consecutive values of an ascending slice.
pub fn half_smallest_sorted_gap(sorted: &[f64]) -> f64 {
    sorted
        .windows(2)
        .map(|w| w[1] - w[0])
        .filter(|g| *g > 0.0)
        .fold(f64::INFINITY, f64::min)
        / 2.0
}

fn half_smallest_gap(values: &[f64]) -> f64 {
    let mut sorted = values.to_vec();
    sorted.par_sort_unstable_by(f64::total_cmp);
    sorted.dedup();
    sorted
        .windows(2)
        .map(|w| w[1] - w[0])
        .fold(f64::INFINITY, f64::min)
        / 2.0
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The sorted, prefix-sum iteration reaches the pass-per-iteration threshold.
    #[test]
    fn sorted_iteration_matches_the_reference() {
        let mut rng = crate::signal::Rng::new(4);
        for power in [1, 3, 6] {
            let values: Vec<f64> = (0..20_000).map(|_| rng.uniform().powi(power)).collect();
            let mut sorted = values.clone();
            sorted.sort_by(f64::total_cmp);
            let fast = li_threshold_sorted(&sorted, 1000).unwrap();
            let reference = li_threshold(&values, 1000).unwrap();
            assert!(
                (fast.threshold - reference.threshold).abs() <= 1e-9 * reference.threshold.abs(),
                "{fast:?} vs {reference:?}"
            );
        }
    }

    #[test]
    fn degenerate_inputs_follow_scikit_image() {
        assert_eq!(li_threshold(&[], 10), Err(LiError::Empty));
        assert_eq!(li_threshold(&[f64::NAN], 10), Err(LiError::Empty));
        assert_eq!(
            li_threshold(&[3.0, 3.0, f64::NAN], 10).unwrap().threshold,
            3.0
        );
        assert_eq!(
            li_threshold(&[f64::INFINITY, f64::NEG_INFINITY], 10)
                .unwrap()
                .threshold,
            0.0
        );
    }

    #[test]
    fn separates_two_clusters_and_honours_the_iteration_limit() {
        let mut v: Vec<f64> = (0..100).map(|k| 1.0 + 0.001 * k as f64).collect();
        v.extend((0..100).map(|k| 10.0 + 0.001 * k as f64));
        let t = li_threshold(&v, 1000).unwrap();
        assert!(t.threshold > 1.1 && t.threshold < 10.0, "{t:?}");
        assert!(t.iterations >= 1);
        assert_eq!(li_threshold(&v, 0), Err(LiError::NotConverged(0)));
    }
}
