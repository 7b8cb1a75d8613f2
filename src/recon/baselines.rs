//! The two baselines of paper §5. Neither repository implements them (docs/mmnorm-reference.md §6).
//!
//! - **Backprojection**: the voxel centres where |S| ≥ `fraction`·max|S|. The paper tuned the
//!   fraction for the best median F-score without giving it; mmnormd's default is 0.3
//!   (`ReconConfig::backprojection_fraction`), to be revisited by the accuracy benchmark.
//! - **Interferometric**, after Gao et al. \[21\]:
//!   1. The reference height z_ref is the mean height of the 3-D image's high-power voxels
//!      (|S| ≥ `fraction`·max).
//!   2. The band is split into `subbands` equal sub-bands; each gives a 2-D SAR image focused
//!      on the plane z = z_ref over the volume's x–y grid.
//!   3. Per pixel, the phase step between consecutive sub-band images, averaged coherently over
//!      the pairs, gives the height offset δ = −Δφ·c/(4π·Δf_sub), with Δf_sub the sub-band
//!      spacing (a surface δ above the plane shortens the round trip by 2δ near nadir).
//!   4. A single threshold keeps the pixels whose summed sub-band magnitude is at least
//!      `fraction` of the maximum; the relative heights are offset so their mean is z_ref.
//!
//!   The phase is unambiguous for |δ| < c/(4·Δf_sub), 10 cm for eight sub-bands of 3 GHz.

use num_complex::Complex32;

use super::image::{RangeProfiles, VoxelGrid, backproject};
use crate::SPEED_OF_LIGHT_M_PER_S;
use crate::capture::Capture;
use crate::progress::Progress;

/// Voxel centres (and flat indices) where |S| ≥ `fraction`·max.
pub fn backprojection_points(
    magnitude: &[f32],
    grid: &VoxelGrid,
    fraction: f64,
) -> (Vec<[f64; 3]>, Vec<usize>) {
    let peak = magnitude.iter().copied().fold(0.0f32, f32::max);
    let floor = fraction as f32 * peak;
    let kept: Vec<usize> = (0..magnitude.len())
        .filter(|&v| peak > 0.0 && magnitude[v] >= floor)
        .collect();
    let points = kept.iter().map(|&v| grid.centre_of(v)).collect();
    (points, kept)
}

/// The interferometric baseline's points; also returns z_ref.
pub fn interferometric_points(
    capture: &Capture,
    grid: &VoxelGrid,
    magnitude: &[f32],
    subbands: usize,
    fraction: f64,
    pad_factor: usize,
    quiet: bool,
) -> (Vec<[f64; 3]>, f64) {
    let (high, _) = backprojection_points(magnitude, grid, fraction);
    if high.is_empty() {
        return (Vec::new(), f64::NAN);
    }
    let z_ref = high.iter().map(|p| p[2]).sum::<f64>() / high.len() as f64;
    let plane = VoxelGrid {
        origin_m: [grid.origin_m[0], grid.origin_m[1], z_ref],
        voxel_m: grid.voxel_m,
        dims: [grid.dims[0], grid.dims[1], 1],
    };
    let len = capture.plan.samples_per_chirp / subbands;
    let progress = Progress::new("sub-bands", subbands as u64, quiet);
    let images: Vec<Vec<Complex32>> = (0..subbands)
        .map(|b| {
            let sub = capture.sub_band(b * len, len);
            let profiles = RangeProfiles::new(&sub, &plane, pad_factor);
            let image = backproject(&sub, &plane, &profiles, None);
            progress.inc(1);
            image
        })
        .collect();
    progress.finish();
    let spacing_hz = len as f64 * capture.plan.frequency_step_hz;
    let pixels = plane.len();
    let strength: Vec<f32> = (0..pixels)
        .map(|p| images.iter().map(|im| im[p].norm()).sum())
        .collect();
    let peak = strength.iter().copied().fold(0.0f32, f32::max);
    let ny = plane.dims[1];
    let mut kept: Vec<([f64; 2], f64)> = Vec::new();
    for p in 0..pixels {
        if !(peak > 0.0 && strength[p] >= fraction as f32 * peak) {
            continue;
        }
        let step: Complex32 = images.windows(2).map(|w| w[1][p] * w[0][p].conj()).sum();
        let delta_m = -f64::from(step.arg()) * SPEED_OF_LIGHT_M_PER_S
            / (4.0 * std::f64::consts::PI * spacing_hz);
        let c = plane.centre(p / ny, p % ny, 0);
        kept.push(([c[0], c[1]], delta_m));
    }
    let mean = kept.iter().map(|k| k.1).sum::<f64>() / kept.len().max(1) as f64;
    let points = kept
        .iter()
        .map(|(xy, d)| [xy[0], xy[1], z_ref + d - mean])
        .collect();
    (points, z_ref)
}
