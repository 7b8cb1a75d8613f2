//! The binary image of §3.2 (Eq. 9–10): the voxels that hold the object's surface.
//!
//! As in the authors' code (docs/mmnorm-reference.md §4.1), Li's threshold is computed on |S|^e for
//! e = 2, 2.5, 3.5, 4 in turn. An attempt fails when Li does not converge within the iteration
//! limit. A successful attempt is accepted when the oriented bounding box of its voxels is at most
//! `max_box_m3` (0.03 m³). The mask is (|S| > floor·max|S|) ∧ (|S|^e ≥ t_Li).
//!
//! Two departures, both deliberate:
//! - The oriented box is the principal-axes box of the voxel centres (plus one voxel), not
//!   open3d's minimal box. It is never smaller than the minimal one, so the guard is at most
//!   slightly stricter.
//! - When no attempt passes the guard, the authors use the last exponent's mask if that attempt
//!   converged and exit otherwise, even if an earlier one converged. mmnormd uses the converged
//!   attempt with the smallest box, and fails only when none converged.
//!
//! |S| is divided by its maximum over the core before the exponent; Li's iteration is
//! scale-equivariant, so this changes nothing but the floating-point range.
//!
//! Li's threshold is computed over every voxel of the volume's core (`recon::volume::Core`) by
//! default, as the authors compute it over their box. Their box is fixed; mmnormd's core is
//! found from the data and padded, and the voxels of empty space that the padding adds pull the
//! threshold down, so the mask depends on the core:
//! from the −6 dB box to the −12 dB one the threshold fell by 10–30 % on four cases of the
//! accuracy suite, and the components grew, merged or split (`docs/bench/history.md`).
//! That is why the imaged margin around the core is left out of the threshold: the threshold
//! is the core's, and applies over the margin too.
//! [`LiVoxels::AboveFloor`] computes it over the core's voxels above the floor only, which empty
//! space does not reach. It is not the default: on 11 cases of the suite taken by rule it
//! lowered the F-score on 6 and raised it on 1 (per-case median 0.87 → 0.78), because the higher
//! threshold drops the weaker parts of objects such as the pitcher and the cups.

use nalgebra::{Matrix3, SymmetricEigen, Vector3};
use rayon::prelude::*;
use serde::Serialize;

use super::config::LiVoxels;
use super::image::VoxelGrid;
use super::threshold::li_threshold_sorted;
use super::volume::Core;

/// One exponent's attempt.
#[derive(Debug, Clone, Serialize)]
pub struct MaskAttempt {
    pub exponent: f64,
    /// Li's threshold on (|S|/max)^e; None when it did not converge.
    pub threshold: Option<f64>,
    pub iterations: Option<usize>,
    pub voxels: usize,
    pub box_m3: Option<f64>,
    pub accepted: bool,
}

/// The chosen mask and every attempt.
#[derive(Debug, Clone)]
pub struct Mask {
    pub mask: Vec<bool>,
    pub attempts: Vec<MaskAttempt>,
    /// The exponent whose threshold made the mask.
    pub exponent: f64,
    /// max |S| over the core, which the floor and the threshold are relative to.
    pub peak: f32,
}

/// Why no mask was made.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum MaskError {
    #[error("the image is zero everywhere: nothing above the noise in the volume")]
    EmptyImage,
    #[error("Li's threshold did not converge for any exponent in {0:?}")]
    NoThreshold(Vec<f64>),
}

/// r^e for r ≥ 0, by multiplications and one square root when 2e is a small integer (the
/// default exponents 2, 2.5, 3.5 and 4 are): `powf` costs tens of nanoseconds, and the mask
/// raises 10⁸ voxels to each exponent.
#[derive(Clone, Copy)]
struct Power {
    exponent: f64,
    half_steps: Option<i32>,
}

impl Power {
    fn new(exponent: f64) -> Power {
        let twice = 2.0 * exponent;
        let half_steps =
            (twice.fract() == 0.0 && (0.0..=32.0).contains(&twice)).then_some(twice as i32);
        Power {
            exponent,
            half_steps,
        }
    }

    #[inline]
    fn of(self, r: f64) -> f64 {
        match self.half_steps {
            Some(h) if h % 2 == 0 => r.powi(h / 2),
            Some(h) => r.powi(h / 2) * r.sqrt(),
            None => r.powf(self.exponent),
        }
    }
}

/// Builds the mask from |S| (`magnitude`, C order on `grid`), with Li's threshold computed over
/// the `li_voxels` of `core` and the box guard applied to the mask's voxels in `core`; the
/// threshold then applies over the whole grid.
#[allow(clippy::too_many_arguments)]
pub fn li_mask(
    magnitude: &[f32],
    grid: &VoxelGrid,
    core: &Core,
    floor_fraction: f64,
    li_voxels: LiVoxels,
    exponents: &[f64],
    max_iterations: usize,
    max_box_m3: f64,
) -> Result<Mask, MaskError> {
    let whole = core.is_whole(grid);
    let in_core = |v: usize| whole || core.contains(grid, v);
    // The core's peak: the floor, like the threshold, is the core's.
    let peak = (magnitude.par_iter().enumerate())
        .filter(|&(v, _)| in_core(v))
        .map(|(_, &m)| m)
        .reduce(|| 0.0f32, f32::max);
    if peak.is_nan() || peak <= 0.0 {
        return Err(MaskError::EmptyImage);
    }
    let relative: Vec<f64> = magnitude
        .par_iter()
        .map(|&m| f64::from(m) / f64::from(peak))
        .collect();
    // r ↦ r^e keeps the order of the values, so one sort serves every exponent.
    let counted = |r: f64| match li_voxels {
        LiVoxels::All => true,
        LiVoxels::AboveFloor => r > floor_fraction,
    };
    let mut sorted: Vec<f64> = relative
        .par_iter()
        .enumerate()
        .filter(|&(v, &r)| r.is_finite() && counted(r) && in_core(v))
        .map(|(_, &r)| r)
        .collect();
    sorted.par_sort_unstable_by(f64::total_cmp);
    let mut attempts = Vec::new();
    let mut best: Option<(f64, Vec<bool>, f64)> = None; // (box, mask, exponent)
    for &e in exponents {
        let power = Power::new(e);
        let powered_sorted: Vec<f64> = sorted.par_iter().map(|&r| power.of(r)).collect();
        let li = li_threshold_sorted(&powered_sorted, max_iterations);
        drop(powered_sorted);
        let Ok(li) = li else {
            attempts.push(MaskAttempt {
                exponent: e,
                threshold: None,
                iterations: None,
                voxels: 0,
                box_m3: None,
                accepted: false,
            });
            continue;
        };
        let mask: Vec<bool> = relative
            .par_iter()
            .map(|&r| r > floor_fraction && power.of(r) >= li.threshold)
            .collect();
        let box_m3 = if whole {
            oriented_box_m3(&mask, grid)
        } else {
            let in_core: Vec<bool> = (mask.par_iter().enumerate())
                .map(|(v, &m)| m && core.contains(grid, v))
                .collect();
            oriented_box_m3(&in_core, grid)
        };
        let accepted = box_m3 <= max_box_m3;
        attempts.push(MaskAttempt {
            exponent: e,
            threshold: Some(li.threshold),
            iterations: Some(li.iterations),
            voxels: mask.iter().filter(|&&m| m).count(),
            box_m3: Some(box_m3),
            accepted,
        });
        if accepted {
            return Ok(Mask {
                mask,
                attempts,
                exponent: e,
                peak,
            });
        }
        if best.as_ref().is_none_or(|b| box_m3 < b.0) {
            best = Some((box_m3, mask, e));
        }
    }
    match best {
        Some((_, mask, exponent)) => Ok(Mask {
            mask,
            attempts,
            exponent,
            peak,
        }),
        None => Err(MaskError::NoThreshold(exponents.to_vec())),
    }
}

/// Volume of the principal-axes bounding box of the masked voxel centres, each axis grown by
/// one voxel, m³.
pub fn oriented_box_m3(mask: &[bool], grid: &VoxelGrid) -> f64 {
    let [_, ny, nz] = grid.dims;
    let points: Vec<Vector3<f64>> = mask
        .iter()
        .enumerate()
        .filter(|(_, m)| **m)
        .map(|(v, _)| Vector3::from(grid.centre(v / (ny * nz), (v / nz) % ny, v % nz)))
        .collect();
    if points.is_empty() {
        return 0.0;
    }
    let n = points.len() as f64;
    let mean = points.iter().sum::<Vector3<f64>>() / n;
    let cov = points
        .iter()
        .map(|p| (p - mean) * (p - mean).transpose())
        .sum::<Matrix3<f64>>()
        / n;
    let axes = SymmetricEigen::new(cov).eigenvectors;
    (0..3)
        .map(|k| {
            let axis = axes.column(k);
            let (lo, hi) = points
                .iter()
                .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), p| {
                    let s = axis.dot(&(p - mean));
                    (a.min(s), b.max(s))
                });
            hi - lo + grid.voxel_m
        })
        .product()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// [`li_mask`] over the whole grid, with the 5 % floor and 1000 iterations.
    fn whole_mask(
        magnitude: &[f32],
        g: &VoxelGrid,
        li_voxels: LiVoxels,
        exponents: &[f64],
        max_box_m3: f64,
    ) -> Result<Mask, MaskError> {
        li_mask(
            magnitude,
            g,
            &Core::whole(g),
            0.05,
            li_voxels,
            exponents,
            1000,
            max_box_m3,
        )
    }

    #[test]
    fn power_matches_powf() {
        for e in [2.0, 2.5, 3.5, 4.0, 1.7] {
            let p = Power::new(e);
            for i in 0..1000 {
                let r = i as f64 / 999.0;
                let (fast, exact) = (p.of(r), r.powf(e));
                assert!(
                    (fast - exact).abs() <= 1e-14 * exact.max(1e-300),
                    "{r}^{e}: {fast} vs {exact}"
                );
            }
        }
    }

    fn grid(dims: [usize; 3]) -> VoxelGrid {
        VoxelGrid {
            origin_m: [0.0; 3],
            voxel_m: 0.01,
            dims,
        }
    }

    #[test]
    fn a_bright_blob_on_a_dim_floor_is_masked() {
        let g = grid([20, 20, 20]);
        let mut magnitude = vec![0.01f32; g.len()];
        for i in 5..10 {
            for j in 6..12 {
                for k in 8..11 {
                    magnitude[(i * 20 + j) * 20 + k] = 1.0;
                }
            }
        }
        let m = whole_mask(&magnitude, &g, LiVoxels::All, &[2.0], 1.0).unwrap();
        assert_eq!(m.mask.iter().filter(|&&x| x).count(), 5 * 6 * 3);
        assert!(m.attempts[0].accepted);
        // 5 × 6 × 3 voxels of 1 cm: the box is 0.05 × 0.06 × 0.03 m.
        let b = m.attempts[0].box_m3.unwrap();
        assert!((b - 9e-5).abs() < 1e-9, "{b}");
    }

    /// An object's image (a bright core fading over a shell of sidelobes) in a box with `empty`
    /// voxels of space around it, at a thousandth of the peak.
    fn object_in_space(empty: usize) -> (Vec<f32>, VoxelGrid) {
        let object: Vec<f32> = (0..2000)
            .map(|v| match v % 10 {
                0..=2 => 1.0 - 0.01 * (v % 7) as f32,
                3..=5 => 0.3 - 0.01 * (v % 5) as f32,
                _ => 0.06 + 0.01 * (v % 3) as f32,
            })
            .collect();
        let mut magnitude = object;
        magnitude.resize(2000 + empty, 1e-3);
        let g = grid([magnitude.len() / 100, 10, 10]);
        (magnitude, g)
    }

    #[test]
    fn the_threshold_above_the_floor_does_not_depend_on_empty_space() {
        let threshold = |empty: usize, voxels: LiVoxels| {
            let (magnitude, g) = object_in_space(empty);
            let m = whole_mask(&magnitude, &g, voxels, &[2.0], 1.0).unwrap();
            let t = m.attempts[0].threshold.unwrap();
            println!(
                "{voxels:?}, {empty} empty voxels: threshold {t:.5}, mask {}",
                m.attempts[0].voxels
            );
            (t, m.attempts[0].voxels)
        };
        // Over every voxel, three times the empty space lowers the threshold and takes in the
        // sidelobe shell; over the voxels above the floor it changes nothing.
        let (small, large) = (
            threshold(8000, LiVoxels::All),
            threshold(38000, LiVoxels::All),
        );
        assert!(
            large.0 < 0.8 * small.0 && large.1 > small.1,
            "{small:?} {large:?}"
        );
        let (small, large) = (
            threshold(8000, LiVoxels::AboveFloor),
            threshold(38000, LiVoxels::AboveFloor),
        );
        assert_eq!(small, large);
    }

    #[test]
    fn the_threshold_over_a_core_ignores_the_margin_and_applies_beyond_it() {
        // object_in_space(8000) is 100 x-slabs of 10×10; a margin of 300 more slabs of empty
        // space, with one bright voxel in it, is added after it.
        let (small, g_small) = object_in_space(8000);
        let mut big = small.clone();
        big.resize(small.len() + 30_000, 1e-3);
        big[small.len() + 12_345] = 1.0;
        let g_big = grid([g_small.dims[0] + 300, 10, 10]);
        let core = Core {
            lo: [0; 3],
            hi: g_small.dims,
        };
        let mask_of = |m: &[f32], g: &VoxelGrid, c: &Core| {
            li_mask(m, g, c, 0.05, LiVoxels::All, &[2.0], 1000, 1.0).unwrap()
        };
        let alone = mask_of(&small, &g_small, &Core::whole(&g_small));
        let cored = mask_of(&big, &g_big, &core);
        let uncored = mask_of(&big, &g_big, &Core::whole(&g_big));
        let t = |m: &Mask| m.attempts[0].threshold.unwrap();
        assert_eq!(t(&alone), t(&cored));
        assert!(
            t(&uncored) < 0.8 * t(&alone),
            "{} {}",
            t(&uncored),
            t(&alone)
        );
        assert_eq!(alone.mask[..], cored.mask[..small.len()]);
        assert!(cored.mask[small.len() + 12_345]);
        assert_eq!(alone.attempts[0].box_m3, cored.attempts[0].box_m3);
        assert!(core.contains(&g_big, small.len() - 1) && !core.contains(&g_big, small.len()));
    }

    #[test]
    fn a_rotated_slab_has_a_thin_oriented_box() {
        // A one-voxel-thick diagonal sheet x = y: the axis-aligned box is 20 × 20 × 5 voxels, the
        // oriented one about 28 × 1.4 × 5.
        let g = grid([20, 20, 5]);
        let mut mask = vec![false; g.len()];
        for i in 0..20 {
            for k in 0..5 {
                mask[(i * 20 + i) * 5 + k] = true;
            }
        }
        let b = oriented_box_m3(&mask, &g);
        let aligned = 0.2 * 0.2 * 0.05;
        assert!(b < 0.3 * aligned, "{b} vs {aligned}");
    }

    #[test]
    fn a_box_over_the_limit_falls_back_to_the_smallest() {
        let g = grid([10, 10, 10]);
        let mut magnitude = vec![0.0f32; g.len()];
        for (v, m) in magnitude.iter_mut().enumerate() {
            *m = 0.5 + 0.5 * ((v * 7919) % 101) as f32 / 101.0;
        }
        let m = whole_mask(&magnitude, &g, LiVoxels::All, &[2.0, 4.0], 1e-9).unwrap();
        assert!(m.attempts.iter().all(|a| !a.accepted));
        let smallest = m
            .attempts
            .iter()
            .filter_map(|a| a.box_m3)
            .fold(f64::INFINITY, f64::min);
        let used = m
            .attempts
            .iter()
            .find(|a| a.exponent == m.exponent)
            .and_then(|a| a.box_m3)
            .unwrap();
        assert_eq!(used, smallest);
        assert_eq!(
            whole_mask(&[0.0; 8], &grid([2, 2, 2]), LiVoxels::All, &[2.0], 1.0).unwrap_err(),
            MaskError::EmptyImage
        );
    }
}
