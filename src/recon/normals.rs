//! The surface-normal field (paper §2.2, Eq. 1–3 with the weights of Eq. 6).
//!
//! For a voxel v with image value S(v), antenna j votes along its candidate vector u_j with the
//! weight `w_j = Re(I_j(v)·conj(S(v)))/|S(v)|`, the projection of its contribution onto the
//! sum. The normal is the normalised vote sum. Candidates are unit vectors from v towards the
//! antenna's virtual phase centre (TX + RX)/2, as in the paper (Eq. 1).
//! [`Candidates::Displacement`] keeps the authors' variant instead (docs/mmnorm-reference.md §3): the
//! un-normalised displacement, which weights far antennas more. Only the selected voxels get a
//! normal (the authors select |S| above 5 % of max|S|; [`above_fraction`] makes that selection);
//! the others are NaN. Each voxel's normal depends on that voxel alone, so the selection changes
//! which values are computed, never their values.

use num_complex::Complex32;

use super::image::{MatchedFilter, RangeProfiles, TILE, VoxelGrid};
use super::kernel::Tile;
use crate::capture::Capture;
use crate::progress::Progress;

/// How a vote's direction is formed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Candidates {
    /// Unit vectors (paper Eq. 1). The default.
    Unit,
    /// Un-normalised voxel-to-antenna displacements (the authors' code).
    Displacement,
}

/// The voxels whose |S| exceeds `fraction`·max|S|.
pub fn above_fraction(image: &[Complex32], fraction: f32) -> Vec<bool> {
    let peak = image.iter().map(|s| s.norm()).fold(0.0f32, f32::max);
    image.iter().map(|s| s.norm() > fraction * peak).collect()
}

/// Unit normals per voxel (C order) where `selected` is true (and |S| > 0); NaN elsewhere.
pub fn normal_field(
    capture: &Capture,
    grid: &VoxelGrid,
    profiles: &RangeProfiles,
    image: &[Complex32],
    selected: &[bool],
    candidates: Candidates,
    progress: Option<&Progress>,
) -> Vec<[f32; 3]> {
    let filter = MatchedFilter::new(capture, profiles);
    let centres: Vec<[f32; 3]> = (0..filter.antennas()).map(|a| filter.centre(a)).collect();
    let plane = grid.dims[1] * grid.dims[2];
    grid.par_slabs([f32::NAN; 3], progress, |i, voxel_centres, slab| {
        // The voxels above the floor, with S and |S|.
        let active: Vec<(usize, Complex32, f32)> = (0..slab.len())
            .filter_map(|k| {
                let s = image[i * plane + k];
                let magnitude = s.norm();
                (selected[i * plane + k] && magnitude > 0.0).then_some((k, s, magnitude))
            })
            .collect();
        // Antenna-outer over tiles, as in the image (`recon::kernel`).
        let mut tile = Tile::default();
        for chunk in active.chunks(TILE) {
            tile.load(chunk.iter().map(|&(k, _, _)| voxel_centres[k]));
            let m = chunk.len();
            // S/|S|, so that Eq. 6's projection is a dot product.
            let unit_re: Vec<f32> = chunk.iter().map(|&(_, s, mag)| s.re / mag).collect();
            let unit_im: Vec<f32> = chunk.iter().map(|&(_, s, mag)| s.im / mag).collect();
            let mut sums = [vec![0.0f32; m], vec![0.0f32; m], vec![0.0f32; m]];
            for (a, c) in centres.iter().enumerate() {
                filter.tile_responses(a, &mut tile);
                let [sx, sy, sz] = &mut sums;
                for i in 0..m {
                    // Eq. 6: projection of I_j onto S.
                    let w = tile.re[i] * unit_re[i] + tile.im[i] * unit_im[i];
                    let d = [c[0] - tile.x[i], c[1] - tile.y[i], c[2] - tile.z[i]];
                    let scale = match candidates {
                        Candidates::Unit => w / (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt(),
                        Candidates::Displacement => w,
                    };
                    sx[i] += scale * d[0];
                    sy[i] += scale * d[1];
                    sz[i] += scale * d[2];
                }
            }
            for (i, &(k, _, _)) in chunk.iter().enumerate() {
                let sum = [sums[0][i], sums[1][i], sums[2][i]];
                let len = (sum[0] * sum[0] + sum[1] * sum[1] + sum[2] * sum[2]).sqrt();
                if len > 0.0 {
                    slab[k] = sum.map(|c| c / len);
                }
            }
        }
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::recon::image::backproject;
    use crate::sim::{Scene, simulate};

    fn capture(object: &str) -> Capture {
        let text = format!(
            "[radar]\nstart_frequency_hz = 77.5e9\nfrequency_step_hz = 5.859375e6\nsamples_per_chirp = 256\n\
             [aperture]\nwidth_m = 0.24\nheight_m = 0.24\nspacing_m = 0.006\nz_m = 0.3\n{object}"
        );
        let scene = Scene::parse(&text, std::path::Path::new("inline.toml")).unwrap();
        simulate(&scene, true).capture
    }

    /// Median cosine between the estimated normals on the strongest voxels and `truth(v)`.
    fn median_cosine(
        object: &str,
        grid: VoxelGrid,
        min_fraction: f32,
        truth: impl Fn([f64; 3]) -> Option<[f64; 3]>,
    ) -> f64 {
        let c = capture(object);
        let profiles = RangeProfiles::new(&c, &grid, 32);
        let image = backproject(&c, &grid, &profiles, None);
        let normals = normal_field(
            &c,
            &grid,
            &profiles,
            &image,
            &above_fraction(&image, min_fraction),
            Candidates::Unit,
            None,
        );
        let [_, ny, nz] = grid.dims;
        let mut cosines: Vec<f64> = Vec::new();
        for (v, n) in normals.iter().enumerate() {
            if n[0].is_nan() {
                continue;
            }
            let p = grid.centre(v / (ny * nz), (v / nz) % ny, v % nz);
            let Some(t) = truth(p) else { continue };
            cosines.push((0..3).map(|k| f64::from(n[k]) * t[k]).sum::<f64>().abs());
        }
        cosines.sort_by(f64::total_cmp);
        assert!(
            cosines.len() >= 20,
            "only {} voxels with normals",
            cosines.len()
        );
        println!(
            "{} voxels with normals, cosine p10 {:.6}",
            cosines.len(),
            cosines[cosines.len() / 10]
        );
        cosines[cosines.len() / 2]
    }

    #[test]
    fn tilted_plate_normals_follow_the_tilt() {
        let grid = VoxelGrid {
            origin_m: [-0.03, -0.03, -0.01],
            voxel_m: 0.003,
            dims: [21, 21, 7],
        };
        let tilt = 10f64.to_radians();
        let cos = median_cosine(
            "[[object]]\nshape = \"plate\"\nsize_m = [0.08, 0.08]\nrotation_deg = [0.0, 10.0, 0.0]\ndiffuse = 0.0\n",
            grid,
            0.5,
            |_| Some([tilt.sin(), 0.0, tilt.cos()]),
        );
        println!("tilted plate: median cosine to the true normal {cos:.6}");
        assert!(cos > 0.99);
        // The untilted normal is measurably wrong: the check can fail.
        let flat = median_cosine(
            "[[object]]\nshape = \"plate\"\nsize_m = [0.08, 0.08]\nrotation_deg = [0.0, 10.0, 0.0]\ndiffuse = 0.0\n",
            grid,
            0.5,
            |_| Some([0.0, 0.0, 1.0]),
        );
        assert!(flat < 0.99, "{flat}");
    }

    #[test]
    fn sphere_normals_are_radial() {
        let grid = VoxelGrid {
            origin_m: [-0.03, -0.03, 0.0],
            voxel_m: 0.003,
            dims: [21, 21, 14],
        };
        let cos = median_cosine(
            "[[object]]\nshape = \"sphere\"\nradius_m = 0.03\nposition_m = [0.0, 0.0, 0.0]\ndiffuse = 0.0\n",
            grid,
            0.2,
            // The radial direction from the centre (undefined at the centre itself).
            |p| {
                let r = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
                (r > 0.01).then(|| p.map(|c| c / r))
            },
        );
        println!("sphere: median cosine to the radial normal {cos:.6}");
        assert!(cos > 0.98);
    }
}
