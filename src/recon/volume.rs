//! The imaged volume: an explicit box, or one found from the data.
//!
//! The authors image a fixed box in their radar frame (docs/mmnorm-reference.md §2). mmnormd derives the
//! box from the capture instead, so any aperture height, size or position works:
//! 1. **Range window.** The incoherent sum of |range profile|² over a seeded random subset of
//!    antennas (Hann-windowed), restricted to `range_window_m` (one-way, range offset removed),
//!    keeps the ranges within 20 dB of its peak. Nothing lies nearer than the nearest echo, so
//!    the near-field aliasing of a sparse aperture close to the antennas stays out.
//! 2. **Coarse image.** S(v) on `coarse_voxel_m` voxels over the aperture's x–y extent, grown on
//!    each side by the deepest echo's range times tan(`reach_deg`) (in whole coarse voxels, so
//!    that the footprint's voxels stay where they were), and the heights those ranges allow
//!    below the aperture, from the same antenna subset. A sparse random array has no grating
//!    lobes, unlike a decimated raster. The growth reaches a surface that lies beyond the
//!    aperture's footprint and is tilted towards it, which returns its specular echo to the
//!    antennas near the edge: the rim of an upturned skillet lid 26 cm across under a 16 cm
//!    aperture lies outside a search over the footprint alone, and mmNorm returns the lid's
//!    handle only. A voxel beyond the footprint is seen from one side only, and a raster of
//!    pitch d samples an echo without ambiguity only within λ/(4d) of broadside (about 29° at
//!    λ/2): the antennas that see such a voxel more steeply than that add up an alias of an echo
//!    from the other side. Those voxels are therefore imaged from the antennas that see them
//!    within that angle only (`beyond_footprint_unambiguous`). From every antenna, a plate
//!    beside a sphere under a 24×14 cm raster of 2 mm showed a blob at 0.71 of the peak 6 cm
//!    beyond the footprint, where nothing is, and gained two false components at 10°.
//! 3. **Region.** The box around the 6-connected blobs (of at least 27 voxels) of coarse voxels
//!    with |S| ≥ `power_fraction`·max, padded by `pad_m` (3 cm), on the fine voxel size. Single
//!    voxels of the random array's sidelobe floor do not stretch the box.
//!
//!    Where the subset is a draw from more antennas (`coarse_antennas` of a larger aperture),
//!    a voxel must also be `subset_sigmas` (4) standard errors clear of zero. A specular echo
//!    reaches few antennas, and a random array's sidelobe floor relative to its peak is about
//!    one over the number of antennas that see it: at a 30×30 cm λ/4 aperture (96 721
//!    antennas, 10 000 drawn) the coarse image's 99th percentile lay 9–11 dB under its peak
//!    and blobs of that floor crossed the threshold across the footprint and beyond it, where
//!    the whole aperture's image is empty to −30 dB. The draw is imaged in 8 random groups;
//!    their spread at each voxel gives the standard error of the draw's mean against the whole
//!    aperture's (with the finite-population correction, so a capture with no more antennas
//!    than the draw is imaged and judged as before). If no voxel passes, the draw is too small
//!    to tell and the power threshold alone decides. The fraction is 0.25
//!    (−12 dB). A specular object returns most of its power from one or two highlights, so at
//!    0.5 the box held only those and the pad: under the paper's aperture it cut a 20 cm
//!    screwdriver to 7.6 cm, its handle's end and its shaft's tip outside. On the reduced
//!    accuracy suite (102 cases) the lower fraction raised mmNorm's median F-score from 0.80 to
//!    0.88 and the 25th percentile from 0.54 to 0.69. 0.15 and 0.1 gave the same median but
//!    made more cases worse (the cups rotated; the fork on its side through cardboard).
//! 4. **Core and margin.** That padded box is the volume's [`Core`]. The imaged grid extends
//!    `margin_m` (3 cm) beyond it on the four lateral faces. A surface tilted towards the
//!    aperture returns its specular echo from beyond the region the coarse threshold keeps: the
//!    cracker box on its side has a face 21 cm long under a 12 cm aperture.
//!    Without a margin, its echoing end crossed the box's face and was cut, and mmNorm placed
//!    the cut component 1.3–1.6 cm too low. The margin must not change the mask elsewhere, so
//!    the core keeps the roles the box had (`recon::mask`, `recon::pipeline`):
//!    - Li's threshold and the mask's box guard see the core's voxels only; padding the box
//!      instead lowered the threshold with the empty space it added, and changed the mask of
//!      every case (`docs/bench/history.md`);
//!    - mask components with no voxel in the core are dropped;
//!    - the near echoes removed before imaging are those nearer than the core;
//!    - the baselines threshold the core's image only;
//!    - range migration's gate and kz grid follow the grid's extent, so the core is also imaged
//!      on its own and keeps that image (`recon::pipeline`): imaged with the margin in one
//!      transform, its |S| moved by about 1 %, every case's mask with it, and a range sidelobe
//!      of one of two plates became a component (`tests/recon_scenes.rs`).
//!
//!    An explicit box is its own core, with no margin.
//!
//! The aperture plane is the mean height of the antennas' phase centres; the antennas look down
//! (−z), as in every capture mmnormd writes.

use std::borrow::Cow;

use num_complex::Complex32;
use rustfft::FftPlanner;

use super::components::label_6;
use super::config::{AutoVolume, VolumeSpec};
use super::image::{RangeProfiles, VoxelGrid, backproject};
use crate::SPEED_OF_LIGHT_M_PER_S;
use crate::capture::{Capture, FrequencyPlan};
use crate::signal::{Rng, hann_window};

/// Smallest 6-connected blob of strong coarse voxels that counts as an object (3×3×3).
const MIN_BLOB_VOXELS: usize = 27;

/// Random groups the coarse draw is imaged in, to estimate each voxel's standard error.
const SUBSET_GROUPS: usize = 8;

/// Seed of the split of the coarse draw into groups.
const GROUP_SEED: u64 = 0x6772_6f75_7073;

/// The largest fine grid accepted, voxels (about 1.3 GB of image and normals).
pub const MAX_VOXELS: usize = 100_000_000;

/// Why no volume could be set up.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum VolumeError {
    #[error(
        "volume z1 = {z1_m} m is not below the aperture plane at z = {aperture_z_m:.4} m: the radar looks down"
    )]
    AboveAperture { z1_m: f64, aperture_z_m: f64 },
    #[error(
        "volume {bounds:?} at {voxel_m} m voxels has {voxels} voxels, more than the {max} allowed; use a smaller box or larger voxels"
    )]
    TooLarge {
        bounds: [f64; 6],
        voxel_m: f64,
        voxels: usize,
        max: usize,
    },
    #[error(
        "no echo within auto_volume.range_window_m = [{0}, {1}] m below the aperture; widen the window or give --volume"
    )]
    NoEcho(f64, f64),
    #[error("volume {bounds:?} spans less than two {voxel_m} m voxels along {axis}")]
    TooThin {
        bounds: [f64; 6],
        voxel_m: f64,
        axis: char,
    },
}

/// What the automatic search found (recorded in summary.json).
#[derive(Debug, Clone, serde::Serialize)]
pub struct AutoReport {
    pub aperture_z_m: f64,
    pub echo_range_m: [f64; 2],
    pub coarse_grid: VoxelGrid,
    pub coarse_antennas: usize,
    /// Coarse voxels above the power threshold that were not `subset_sigmas` standard errors
    /// clear of zero, and so not counted as strong.
    pub uncertain_voxels: usize,
    pub region_m: [f64; 6],
}

/// `length_m` rounded up to whole voxels of `voxel_m` (a hair's tolerance, so that an exact
/// multiple stays one); 0 for a length of 0 or less.
fn whole_voxels(length_m: f64, voxel_m: f64) -> usize {
    (length_m / voxel_m - 1e-9).ceil().max(0.0) as usize
}

/// Height of the aperture plane: the mean z of the phase centres.
pub fn aperture_z_m(capture: &Capture) -> f64 {
    let centres = capture.centres_m();
    centres.iter().map(|c| c[2]).sum::<f64>() / centres.len().max(1) as f64
}

/// The grid of voxel edge `voxel_m` whose voxel centres cover `bounds` = [x0, x1, y0, y1, z0, z1].
pub fn grid_for(bounds: [f64; 6], voxel_m: f64) -> Result<VoxelGrid, VolumeError> {
    let dims = [0, 1, 2].map(|a| {
        (((bounds[2 * a + 1] - bounds[2 * a]) / voxel_m)
            .floor()
            .max(0.0) as usize)
            .saturating_add(1)
    });
    if let Some(a) = (0..3).find(|&a| dims[a] < 2) {
        return Err(VolumeError::TooThin {
            bounds,
            voxel_m,
            axis: ['x', 'y', 'z'][a],
        });
    }
    within_limit(
        VoxelGrid {
            origin_m: [bounds[0], bounds[2], bounds[4]],
            voxel_m,
            dims,
        },
        bounds,
    )
}

/// `grid` (spanning `bounds`) if it holds at most [`MAX_VOXELS`].
fn within_limit(grid: VoxelGrid, bounds: [f64; 6]) -> Result<VoxelGrid, VolumeError> {
    let voxels = grid
        .dims
        .iter()
        .fold(1usize, |acc, &d| acc.saturating_mul(d));
    if voxels > MAX_VOXELS {
        return Err(VolumeError::TooLarge {
            bounds,
            voxel_m: grid.voxel_m,
            voxels,
            max: MAX_VOXELS,
        });
    }
    Ok(grid)
}

/// The voxels of a grid that hold the echo region: indices `lo[a]..hi[a]` along each axis. With
/// an automatic volume it is the padded high-power region, and the grid extends `margin_m`
/// beyond it; with an explicit box it is the whole grid.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub struct Core {
    pub lo: [usize; 3],
    pub hi: [usize; 3],
}

impl Core {
    /// Every voxel of `grid`.
    pub fn whole(grid: &VoxelGrid) -> Core {
        Core {
            lo: [0; 3],
            hi: grid.dims,
        }
    }

    /// Whether the core is all of `grid` (no margin).
    pub fn is_whole(&self, grid: &VoxelGrid) -> bool {
        *self == Core::whole(grid)
    }

    /// Whether flat index `v` of `grid` lies in the core.
    pub fn contains(&self, grid: &VoxelGrid, v: usize) -> bool {
        let [_, ny, nz] = grid.dims;
        let ijk = [v / (ny * nz), (v / nz) % ny, v % nz];
        (0..3).all(|a| ijk[a] >= self.lo[a] && ijk[a] < self.hi[a])
    }

    /// The core as a grid of its own.
    pub fn grid(&self, grid: &VoxelGrid) -> VoxelGrid {
        VoxelGrid {
            origin_m: grid.centre(self.lo[0], self.lo[1], self.lo[2]),
            voxel_m: grid.voxel_m,
            dims: [0, 1, 2].map(|a| self.hi[a] - self.lo[a]),
        }
    }

    /// The core's values of `values` (C order on `grid`), in C order on [`Core::grid`];
    /// borrowed when the core is the whole grid.
    pub fn crop<'a, T: Copy>(&self, grid: &VoxelGrid, values: &'a [T]) -> Cow<'a, [T]> {
        if self.is_whole(grid) {
            return Cow::Borrowed(values);
        }
        let [_, ny, nz] = grid.dims;
        let mut out = Vec::with_capacity(self.grid(grid).len());
        for i in self.lo[0]..self.hi[0] {
            for j in self.lo[1]..self.hi[1] {
                let row = (i * ny + j) * nz;
                out.extend_from_slice(&values[row + self.lo[2]..row + self.hi[2]]);
            }
        }
        Cow::Owned(out)
    }

    /// Writes `inner` (C order on [`Core::grid`]) over the core's voxels of `values` (C order
    /// on `grid`): the inverse of [`Core::crop`].
    pub fn paste<T: Copy>(&self, grid: &VoxelGrid, values: &mut [T], inner: &[T]) {
        let [_, ny, nz] = grid.dims;
        let run = self.hi[2] - self.lo[2];
        let rows =
            (self.lo[0]..self.hi[0]).flat_map(|i| (self.lo[1]..self.hi[1]).map(move |j| (i, j)));
        for ((i, j), from) in rows.zip(inner.chunks_exact(run)) {
            let row = (i * ny + j) * nz;
            values[row + self.lo[2]..row + self.hi[2]].copy_from_slice(from);
        }
    }

    /// The centres of the core's first and last voxels, as [`VoxelGrid::extent`] gives them for
    /// the grid.
    pub fn extent_m(&self, grid: &VoxelGrid) -> ([f64; 3], [f64; 3]) {
        let last = |a: usize| self.hi[a].saturating_sub(1);
        (
            grid.centre(self.lo[0], self.lo[1], self.lo[2]),
            grid.centre(last(0), last(1), last(2)),
        )
    }
}

/// The fine grid for `spec`, its core, and the automatic search's report where it ran.
pub fn select(
    capture: &Capture,
    spec: VolumeSpec,
    voxel_m: f64,
    pad_factor: usize,
    auto: &AutoVolume,
) -> Result<(VoxelGrid, Core, Option<AutoReport>), VolumeError> {
    let aperture_z = aperture_z_m(capture);
    match spec {
        VolumeSpec::Box(b) => {
            if b[5] >= aperture_z {
                return Err(VolumeError::AboveAperture {
                    z1_m: b[5],
                    aperture_z_m: aperture_z,
                });
            }
            let grid = grid_for(b, voxel_m)?;
            Ok((grid, Core::whole(&grid), None))
        }
        VolumeSpec::Auto => {
            let report = find_region(capture, aperture_z, pad_factor, auto)?;
            let r = report.region_m;
            // Snap outwards to whole voxels so the grid does not depend on float noise.
            let snap = |x: f64, up: bool| {
                let q = x / voxel_m;
                voxel_m * if up { q.ceil() } else { q.floor() }
            };
            let mut b = [0.0; 6];
            for a in 0..3 {
                b[2 * a] = snap(r[2 * a] - auto.pad_m, false);
                b[2 * a + 1] = snap(r[2 * a + 1] + auto.pad_m, true);
            }
            // Never reach up to the aperture itself.
            b[5] = b[5].min(snap(aperture_z - auto.range_window_m[0], false));
            let core_grid = grid_for(b, voxel_m)?;
            // The margin, in whole voxels, on the lateral faces only: a surface tilted towards
            // the aperture can outreach the region the coarse search keeps, but that spans
            // every height that holds an echo (the range window).
            let n = whole_voxels(auto.margin_m, voxel_m);
            let grown_m = n as f64 * voxel_m;
            for a in 0..2 {
                b[2 * a] -= grown_m;
                b[2 * a + 1] += grown_m;
            }
            let grid = within_limit(
                VoxelGrid {
                    origin_m: [b[0], b[2], b[4]],
                    dims: [
                        core_grid.dims[0] + 2 * n,
                        core_grid.dims[1] + 2 * n,
                        core_grid.dims[2],
                    ],
                    ..core_grid
                },
                b,
            )?;
            let core = Core {
                lo: [n, n, 0],
                hi: [
                    n + core_grid.dims[0],
                    n + core_grid.dims[1],
                    core_grid.dims[2],
                ],
            };
            Ok((grid, core, Some(report)))
        }
    }
}

fn find_region(
    capture: &Capture,
    aperture_z: f64,
    pad_factor: usize,
    auto: &AutoVolume,
) -> Result<AutoReport, VolumeError> {
    let n = capture.antennas();
    let mut chosen: Vec<usize> = (0..n).collect();
    if n > auto.coarse_antennas {
        Rng::new(0x766f_6c75_6d65).partial_shuffle(&mut chosen, auto.coarse_antennas);
        chosen.truncate(auto.coarse_antennas);
        chosen.sort_unstable();
    }
    let sub = capture.subset(&chosen);
    let [r_min, r_max] = auto.range_window_m;
    let (lo, hi) = echo_ranges(&sub, [r_min, r_max]).ok_or(VolumeError::NoEcho(r_min, r_max))?;
    let centres = sub.centres_m();
    let extent = |k: usize| {
        centres
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), c| {
                (a.min(c[k]), b.max(c[k]))
            })
    };
    let (x, y) = (extent(0), extent(1));
    // Whole coarse voxels, so that the footprint's voxels stay where they were without it: a
    // capture with nothing beyond the footprint keeps its region.
    let reach_m = auto.coarse_voxel_m
        * whole_voxels(hi * auto.reach_deg.to_radians().tan(), auto.coarse_voxel_m) as f64;
    let bounds = [
        x.0 - reach_m,
        x.1 + reach_m,
        y.0 - reach_m,
        y.1 + reach_m,
        aperture_z - hi,
        aperture_z - lo,
    ];
    let coarse = grid_for(bounds, auto.coarse_voxel_m)?;
    let pad_factor = pad_factor.min(8);
    let (mut image, standard_error) = coarse_image(&sub, &coarse, pad_factor, n);
    if reach_m > 0.0 {
        let footprint = [x.0, x.1, y.0, y.1];
        beyond_footprint_unambiguous(&sub, &coarse, pad_factor, footprint, &mut image);
    }
    let peak = image.iter().map(|s| s.norm()).fold(0.0f32, f32::max);
    let floor = auto.power_fraction as f32 * peak;
    let sigmas = auto.subset_sigmas as f32;
    let above = |s: &Complex32| peak > 0.0 && s.norm() >= floor;
    let mut uncertain_voxels = 0;
    let mut strong: Vec<bool> = image
        .iter()
        .enumerate()
        .map(|(v, s)| {
            let above = above(s);
            let certain = standard_error
                .as_ref()
                .is_none_or(|se| s.norm() >= sigmas * se[v]);
            uncertain_voxels += usize::from(above && !certain);
            above && certain
        })
        .collect();
    if !strong.contains(&true) && uncertain_voxels > 0 {
        // Too few of the draw see anything for the test to tell: keep the power threshold.
        tracing::warn!(
            "no coarse voxel is auto_volume.subset_sigmas = {} standard errors clear of zero with \
             auto_volume.coarse_antennas = {}; the power threshold alone bounds the volume",
            auto.subset_sigmas,
            chosen.len()
        );
        strong = image.iter().map(above).collect();
        uncertain_voxels = 0;
    }
    // A sparse random array leaves a noise-like sidelobe floor whose highest voxels can cross
    // the threshold one by one; objects are blobs. Keep the 6-connected blobs of at least
    // MIN_BLOB_VOXELS, or the largest one if none is that big.
    let blobs = label_6(&strong, coarse.dims, 1);
    let largest = blobs.sizes.iter().copied().max().unwrap_or(0);
    let min_size = MIN_BLOB_VOXELS.min(largest);
    let kept = |label: u32| label != 0 && blobs.sizes[label as usize - 1] >= min_size;
    let half = 0.5 * auto.coarse_voxel_m;
    let mut region = [
        f64::INFINITY,
        f64::NEG_INFINITY,
        f64::INFINITY,
        f64::NEG_INFINITY,
        f64::INFINITY,
        f64::NEG_INFINITY,
    ];
    for (v, &label) in blobs.labels.iter().enumerate() {
        if kept(label) {
            let c = coarse.centre_of(v);
            for a in 0..3 {
                region[2 * a] = region[2 * a].min(c[a] - half);
                region[2 * a + 1] = region[2 * a + 1].max(c[a] + half);
            }
        }
    }
    if !region[0].is_finite() {
        return Err(VolumeError::NoEcho(r_min, r_max));
    }
    Ok(AutoReport {
        aperture_z_m: aperture_z,
        echo_range_m: [lo, hi],
        coarse_grid: coarse,
        coarse_antennas: chosen.len(),
        uncertain_voxels,
        region_m: region,
    })
}

/// The coarse image from `sub`, a random draw of the capture's `total` antennas, and, when
/// some antennas were left out, each voxel's standard error as an estimate of the image the
/// whole aperture would give. The draw is imaged in [`SUBSET_GROUPS`] random groups (the same
/// work as imaging it at once); the spread of the groups' images about their weighted mean
/// gives the per-antenna variance at each voxel, and the standard error of a mean over
/// `sub.antennas()` of `total` antennas drawn without replacement follows.
fn coarse_image(
    sub: &Capture,
    coarse: &VoxelGrid,
    pad_factor: usize,
    total: usize,
) -> (Vec<Complex32>, Option<Vec<f32>>) {
    let image_of = |c: &Capture| image_on(c, coarse, pad_factor);
    let drawn = sub.antennas();
    if drawn >= total || drawn < 2 * SUBSET_GROUPS {
        return (image_of(sub), None);
    }
    let mut order: Vec<usize> = (0..drawn).collect();
    Rng::new(GROUP_SEED).partial_shuffle(&mut order, drawn);
    let groups: Vec<(f32, Vec<Complex32>)> = order
        .chunks(drawn.div_ceil(SUBSET_GROUPS))
        .map(|chunk| {
            let mut indices = chunk.to_vec();
            indices.sort_unstable();
            let share = indices.len() as f32 / drawn as f32;
            (share, image_of(&sub.subset(&indices)))
        })
        .collect();
    let mut image = vec![Complex32::new(0.0, 0.0); coarse.len()];
    for (share, group) in &groups {
        for (s, g) in image.iter_mut().zip(group) {
            *s += g * *share;
        }
    }
    // Var(one antenna's term) ≈ Σ n_g·|S_g − S|² / (G − 1); the mean of `drawn` of `total`
    // has that over `drawn`, times the finite-population correction 1 − drawn/total.
    let unsampled = 1.0 - drawn as f64 / total as f64;
    let scale = unsampled / (groups.len() - 1) as f64;
    let standard_error = image
        .iter()
        .enumerate()
        .map(|(v, s)| {
            let spread: f64 = groups
                .iter()
                .map(|(share, g)| f64::from(*share) * f64::from((g[v] - s).norm_sqr()))
                .sum();
            (spread * scale).sqrt() as f32
        })
        .collect();
    (image, Some(standard_error))
}

/// Backprojection of `capture` on `grid`.
fn image_on(capture: &Capture, grid: &VoxelGrid, pad_factor: usize) -> Vec<Complex32> {
    let profiles = RangeProfiles::new(capture, grid, pad_factor);
    backproject(capture, grid, &profiles, None)
}

/// Lateral size of the cells of antennas the voxels beyond the footprint are imaged from, metres.
const CELL_M: f64 = 0.01;

/// Re-images the coarse voxels beyond the aperture's `footprint` ([x0, x1, y0, y1]) from the
/// antennas that see each within the raster's unambiguous angles ([`unambiguous_sines`]); the
/// footprint's voxels keep `image`. A raster of pitch d samples an echo arriving at direction
/// cosine u without ambiguity only for |u| < λ/(4d): an echo at u aliases to u − λ/(2d). A voxel
/// over the footprint is seen from every side, but one beyond it only from one side, and the
/// antennas that see it at steep angles add up an alias of an echo from the other side where
/// nothing is. The antennas are grouped in cells of [`CELL_M`], each imaged on its own and added
/// to a voxel, weighted by its share of the antennas, where the cell's centroid sees it within
/// the angles on both axes. Nothing changes where every antenna sees every such voxel within
/// them, as under a raster of λ/4 or finer. Where the coarse image is a draw (step 3), a voxel
/// out there is held to the standard error of the draw's unrestricted image.
fn beyond_footprint_unambiguous(
    sub: &Capture,
    coarse: &VoxelGrid,
    pad_factor: usize,
    footprint: [f64; 4],
    image: &mut [Complex32],
) {
    let centres = sub.centres_m();
    let sines = unambiguous_sines(&sub.plan, &centres);
    // The voxels beyond the footprint, with their centres.
    let beyond: Vec<(usize, [f64; 3])> = (0..coarse.len())
        .map(|v| (v, coarse.centre_of(v)))
        .filter(|(_, c)| {
            c[0] < footprint[0] || c[0] > footprint[1] || c[1] < footprint[2] || c[1] > footprint[3]
        })
        .collect();
    // The steepest view of a voxel along an axis is from the aperture's far side there.
    let plane_z_m = aperture_z_m(sub);
    let seen_steeply = |p: &[f64; 3]| {
        let depth_m = plane_z_m - p[2];
        [
            (0, footprint[0], footprint[1]),
            (1, footprint[2], footprint[3]),
        ]
        .iter()
        .any(|&(k, lo, hi)| {
            let lateral_m = (p[k] - lo).abs().max((p[k] - hi).abs());
            lateral_m > sines[k] * lateral_m.hypot(depth_m)
        })
    };
    if !beyond.iter().any(|(_, p)| seen_steeply(p)) {
        return;
    }
    let mut cells: std::collections::BTreeMap<(i64, i64), Vec<usize>> = Default::default();
    for (a, c) in centres.iter().enumerate() {
        let key = (
            (c[0] / CELL_M).floor() as i64,
            (c[1] / CELL_M).floor() as i64,
        );
        cells.entry(key).or_default().push(a);
    }
    for &(v, _) in &beyond {
        image[v] = Complex32::new(0.0, 0.0);
    }
    let total = sub.antennas() as f64;
    for antennas in cells.values() {
        let mut centroid = [0.0; 3];
        for &a in antennas {
            for k in 0..3 {
                centroid[k] += centres[a][k] / antennas.len() as f64;
            }
        }
        let cell_image = image_on(&sub.subset(antennas), coarse, pad_factor);
        let share = (antennas.len() as f64 / total) as f32;
        for &(v, p) in &beyond {
            let offset_m = [0, 1, 2].map(|k| p[k] - centroid[k]);
            let range_m = offset_m.iter().map(|o| o * o).sum::<f64>().sqrt();
            if (0..2).all(|k| offset_m[k].abs() <= sines[k] * range_m) {
                image[v] += cell_image[v] * share;
            }
        }
    }
}

/// Sines of the steepest angles off broadside, along x and along y, at which the phase
/// centres sample an echo without ambiguity: λ/(4·pitch) at the sweep's shortest wavelength,
/// where the pitch is the median step between successive distinct coordinates (1 for a
/// random or λ/4 aperture, whose steps are finer).
fn unambiguous_sines(plan: &FrequencyPlan, centres: &[[f64; 3]]) -> [f64; 2] {
    let highest_hz = plan
        .frequency_hz(0)
        .max(plan.frequency_hz(plan.samples_per_chirp.saturating_sub(1)));
    let wavelength_m = SPEED_OF_LIGHT_M_PER_S / highest_hz;
    [0, 1].map(|k| {
        let mut coords: Vec<f64> = centres.iter().map(|c| c[k]).collect();
        coords.sort_unstable_by(f64::total_cmp);
        let mut steps: Vec<f64> = coords
            .windows(2)
            .map(|w| w[1] - w[0])
            .filter(|&step| step > DISTINCT_M)
            .collect();
        if steps.is_empty() {
            return 1.0;
        }
        steps.sort_unstable_by(f64::total_cmp);
        let pitch_m = steps[steps.len() / 2];
        (wavelength_m / (4.0 * pitch_m)).min(1.0)
    })
}

/// Coordinates closer than this are one raster position, metres.
const DISTINCT_M: f64 = 1e-5;

/// One-way ranges (metres, range offset removed) whose summed echo power lies within 20 dB of
/// the strongest inside `window_m`. The Hann window's main lobe (±1.5 range resolutions at
/// −20 dB) is the margin.
fn echo_ranges(capture: &Capture, window_m: [f64; 2]) -> Option<(f64, f64)> {
    let t = capture.plan.samples_per_chirp;
    let fft_len = 2 * t;
    let fft = FftPlanner::<f32>::new().plan_fft_forward(fft_len);
    let mut power = vec![0.0f64; fft_len];
    let mut buf = vec![Complex32::new(0.0, 0.0); fft_len];
    // A Hann window: its sidelobes (−31 dB) stay below the 20 dB cut, where a rectangular
    // window's (−13 dB) would stretch the window by several range resolutions.
    let hann = hann_window(t);
    for a in 0..capture.antennas() {
        buf.fill(Complex32::new(0.0, 0.0));
        for ((b, h), w) in buf.iter_mut().zip(capture.chirp(a)).zip(&hann) {
            *b = h * w;
        }
        fft.process(&mut buf);
        for (p, b) in power.iter_mut().zip(&buf) {
            *p += f64::from(b.norm_sqr());
        }
    }
    // Bin k holds round trip k·c/(Δf·L); a negative step mirrors the spectrum.
    let step = capture.plan.frequency_step_hz;
    let range_of = |k: usize| {
        let signed = if step > 0.0 {
            k as f64
        } else {
            -(k as f64) + fft_len as f64
        };
        0.5 * (signed * SPEED_OF_LIGHT_M_PER_S / (step.abs() * fft_len as f64)
            - capture.range_offset_m)
    };
    let inside: Vec<(f64, f64)> = (0..fft_len)
        .map(|k| (range_of(k), power[k]))
        .filter(|(r, _)| *r >= window_m[0] && *r <= window_m[1])
        .collect();
    let peak = inside.iter().map(|x| x.1).fold(0.0f64, f64::max);
    if peak <= 0.0 {
        return None;
    }
    let strong = inside.iter().filter(|x| x.1 >= 0.01 * peak);
    let (lo, hi) = strong.fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), x| {
        (a.min(x.0), b.max(x.0))
    });
    Some((lo, hi))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sim::{Scene, simulate};
    use std::path::Path;

    /// Two 4×1.2 cm patches of point targets 3 mm apart, 8 cm apart, under a 12×12 cm λ/2
    /// raster, the second patch's amplitude `weak` of the first's: a long object whose highlight
    /// outshines the rest of it.
    fn two_parts(weak: f64) -> Capture {
        let mut text = String::from(
            "[radar]\nstart_frequency_hz = 77.5e9\nfrequency_step_hz = 5.859375e6\n\
             samples_per_chirp = 512\nrange_offset_m = 0.15\n\
             [aperture]\nwidth_m = 0.12\nheight_m = 0.12\nspacing_m = 0.004\nz_m = 0.3\n",
        );
        for k in 0..14 {
            let x = 0.04 + 0.003 * f64::from(k);
            for j in -2..=2 {
                let y = 0.003 * f64::from(j);
                for (sign, rcs) in [(-1.0, 1e-4), (1.0, 1e-4 * weak * weak)] {
                    text += &format!(
                        "[[object]]\nshape = \"point\"\nposition_m = [{}, {y}, 0.0]\nrcs_m2 = {rcs}\n",
                        sign * x
                    );
                }
            }
        }
        simulated(&text)
    }

    /// The capture of the scene `text` (scene TOML, paths relative to `tests/`).
    fn simulated(text: &str) -> Capture {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/inline.toml");
        let scene = Scene::parse(text, &path).unwrap_or_else(|e| panic!("{e}"));
        simulate(&scene, true).capture
    }

    /// The capture of a 4 cm plate at the origin (and `more` objects) under `aperture` (the
    /// `[aperture]` table's keys), `samples` per chirp.
    fn plate_under(aperture: &str, samples: usize, more: &str) -> Capture {
        simulated(&format!(
            "[radar]\nstart_frequency_hz = 77.5e9\nfrequency_step_hz = 5.859375e6\n\
             samples_per_chirp = {samples}\nrange_offset_m = 0.15\n[aperture]\n{aperture}\n\
             [[object]]\nshape = \"plate\"\nsize_m = [0.04, 0.04]\nposition_m = [0.0, 0.0, 0.0]\n\
             {more}"
        ))
    }

    fn contains(grid: &VoxelGrid, p: [f64; 3]) -> bool {
        (0..3).all(|a| {
            let lo = grid.origin_m[a];
            let hi = lo + grid.dims[a] as f64 * grid.voxel_m;
            p[a] > lo && p[a] < hi
        })
    }

    #[test]
    fn the_margin_surrounds_the_unmargined_box_laterally_and_its_core_is_that_box() {
        let capture = two_parts(0.4);
        let select_with = |margin_m: f64| {
            let auto = AutoVolume {
                margin_m,
                ..AutoVolume::default()
            };
            select(&capture, VolumeSpec::Auto, 0.002, 4, &auto).expect("a volume")
        };
        let (plain, plain_core, _) = select_with(0.0);
        assert_eq!(plain_core, Core::whole(&plain));
        let (wide, core, _) = select_with(0.03);
        // 0.03 m is 15 voxels of 2 mm on each lateral side; heights are not extended.
        assert_eq!(core.lo, [15, 15, 0]);
        assert_eq!(
            core.hi,
            [plain.dims[0] + 15, plain.dims[1] + 15, plain.dims[2]]
        );
        assert_eq!(
            wide.dims,
            [plain.dims[0] + 30, plain.dims[1] + 30, plain.dims[2]]
        );
        let inner = core.grid(&wide);
        assert_eq!(inner.dims, plain.dims);
        for a in 0..3 {
            assert!(
                (inner.origin_m[a] - plain.origin_m[a]).abs() < 1e-12,
                "{inner:?} {plain:?}"
            );
        }
        let values: Vec<usize> = (0..wide.len()).collect();
        let cropped = core.crop(&wide, &values);
        assert_eq!(cropped.len(), plain.len());
        assert!(cropped.iter().all(|&v| core.contains(&wide, v)));
        let mut pasted = vec![usize::MAX; wide.len()];
        core.paste(&wide, &mut pasted, &cropped);
        for (v, &p) in pasted.iter().enumerate() {
            assert_eq!(
                p,
                if core.contains(&wide, v) {
                    v
                } else {
                    usize::MAX
                }
            );
        }
        assert_eq!(core.extent_m(&wide).0, inner.extent().0);
    }

    #[test]
    fn the_box_holds_a_part_8_db_weaker_than_the_highlight() {
        // 0.4 in amplitude is −8 dB: inside the default −12 dB, outside the old −6 dB.
        let capture = two_parts(0.4);
        let select_with = |fraction: f64| {
            let auto = AutoVolume {
                power_fraction: fraction,
                ..AutoVolume::default()
            };
            select(&capture, VolumeSpec::Auto, 0.002, 4, &auto)
                .expect("a volume")
                .0
        };
        let (strong, weak) = ([-0.079, 0.0, 0.0], [0.079, 0.0, 0.0]);
        let grid = select_with(AutoVolume::default().power_fraction);
        assert!(contains(&grid, strong) && contains(&grid, weak), "{grid:?}");
        let old = select_with(0.5);
        assert!(contains(&old, strong) && !contains(&old, weak), "{old:?}");
    }

    #[test]
    fn the_search_reaches_a_plate_beyond_the_aperture_tilted_towards_it() {
        // A 4 cm plate under the centre of a 12×12 cm aperture, and another whose centre lies
        // 4 cm beyond the aperture's edge, tilted 10° towards it: its specular echo returns to
        // the antennas near that edge.
        let capture = plate_under(
            "width_m = 0.12\nheight_m = 0.12\nspacing_m = 0.004\nz_m = 0.3",
            512,
            "[[object]]\nshape = \"plate\"\nsize_m = [0.04, 0.04]\nposition_m = [0.10, 0.0, 0.0]\n\
             rotation_deg = [0.0, -10.0, 0.0]\n",
        );
        let select_with = |reach_deg: f64| {
            let auto = AutoVolume {
                reach_deg,
                ..AutoVolume::default()
            };
            select(&capture, VolumeSpec::Auto, 0.002, 4, &auto).expect("a volume")
        };
        let (centre, beyond) = ([0.0, 0.0, 0.0], [0.115, 0.0, 0.0]);
        let (grid, core, report) = select_with(10.0);
        let report = report.expect("the search ran");
        assert!(
            contains(&grid, centre) && contains(&grid, beyond),
            "{grid:?}"
        );
        assert!(contains(&core.grid(&grid), beyond), "{report:?}");
        // Searched over the aperture's footprint alone, the box holds the centre plate only.
        let (footprint, _, _) = select_with(0.0);
        assert!(
            contains(&footprint, centre) && !contains(&footprint, beyond),
            "{footprint:?}"
        );
    }

    #[test]
    fn beyond_the_footprint_a_lambda_half_raster_images_no_alias() {
        // A sphere returns echoes to every antenna, those far from it at steep angles: a λ/2
        // raster aliases the steepest of them beyond the aperture's far edge, where nothing is.
        let text = "[radar]\nstart_frequency_hz = 77.5e9\nfrequency_step_hz = 5.859375e6\n\
             samples_per_chirp = 512\nrange_offset_m = 0.15\n\
             [aperture]\nwidth_m = 0.24\nheight_m = 0.14\nspacing_m = 0.002\nz_m = 0.22\n\
             [[object]]\nshape = \"plate\"\nsize_m = [0.04, 0.04]\nposition_m = [-0.07, 0.0, 0.02]\n\
             [[object]]\nshape = \"sphere\"\nradius_m = 0.05\nposition_m = [0.07, 0.0, -0.03]\n";
        let capture = simulated(text);
        let sines = unambiguous_sines(&capture.plan, &capture.centres_m());
        // 2 mm steps at the sweep's top, 80.5 GHz (λ 3.72 mm): 0.466, about 28°.
        for s in sines {
            assert!((s - 0.4656).abs() < 0.001, "{sines:?}");
        }
        let centres = capture.centres_m();
        let (x0, x1) = (-0.12, 0.12);
        let (y0, y1) = (-0.07, 0.07);
        assert!(
            centres
                .iter()
                .all(|c| c[0] >= x0 - 1e-9 && c[0] <= x1 + 1e-9)
        );
        let reach_m = 0.054;
        let coarse = grid_for(
            [
                x0 - reach_m,
                x1 + reach_m,
                y0 - reach_m,
                y1 + reach_m,
                -0.08,
                0.1,
            ],
            0.006,
        )
        .expect("a grid");
        let (mut image, _) = coarse_image(&capture, &coarse, 4, capture.antennas());
        let beyond = |v: usize| {
            let c = coarse.centre_of(v);
            c[0] < x0 || c[0] > x1 || c[1] < y0 || c[1] > y1
        };
        // The strongest voxel beyond the footprint, relative to the image's peak.
        let strongest_beyond = |image: &[Complex32]| {
            let peak = image.iter().map(|s| s.norm()).fold(0.0f32, f32::max);
            let beyond_peak = (0..image.len())
                .filter(|&v| beyond(v))
                .map(|v| image[v].norm())
                .fold(0.0f32, f32::max);
            beyond_peak / peak
        };
        // From every antenna, a blob 6 cm beyond the plate's edge of the footprint reaches
        // 0.71 of the peak; imaged from the antennas that see it unambiguously, 0.21, under the
        // power threshold (0.25).
        let everyone = strongest_beyond(&image);
        assert!(everyone > 0.5, "{everyone}");
        let inside: Vec<Complex32> = (0..image.len())
            .filter(|&v| !beyond(v))
            .map(|v| image[v])
            .collect();
        beyond_footprint_unambiguous(&capture, &coarse, 4, [x0, x1, y0, y1], &mut image);
        let unambiguous = strongest_beyond(&image);
        assert!(
            unambiguous < AutoVolume::default().power_fraction as f32,
            "{everyone} -> {unambiguous}"
        );
        // The footprint's voxels are left as they were.
        let kept: Vec<Complex32> = (0..image.len())
            .filter(|&v| !beyond(v))
            .map(|v| image[v])
            .collect();
        assert_eq!(kept, inside);
    }

    #[test]
    fn a_quarter_wavelength_raster_is_not_reimaged_beyond_its_footprint() {
        // λ0/4 steps: unambiguous to 79° at this sweep's top (79 GHz), steeper than any
        // antenna sees a voxel 3 cm beyond this 8×8 cm aperture's edge from 30 cm above it.
        let aperture = "width_m = 0.08\nheight_m = 0.08\nspacing_m = 0.000967\nz_m = 0.3";
        let capture = plate_under(aperture, 256, "");
        let sines = unambiguous_sines(&capture.plan, &capture.centres_m());
        for s in sines {
            assert!(s > 0.95 && s < 1.0, "{sines:?}");
        }
        // Voxels whose value the re-imaging changes, on a 6 mm grid between heights z0 and z1.
        let changed = |z0: f64, z1: f64| {
            let grid = grid_for([-0.07, 0.07, -0.07, 0.07, z0, z1], 0.006).expect("a grid");
            let (image, _) = coarse_image(&capture, &grid, 4, capture.antennas());
            let mut after = image.clone();
            let footprint = [-0.04, 0.04, -0.04, 0.04];
            beyond_footprint_unambiguous(&capture, &grid, 4, footprint, &mut after);
            after.iter().zip(&image).filter(|(a, b)| a != b).count()
        };
        assert_eq!(changed(-0.03, 0.03), 0);
        // The same voxels 1–2 cm under the aperture are seen beyond the angle, and re-imaged.
        assert!(changed(0.28, 0.29) > 0);
    }

    #[test]
    fn a_small_draw_keeps_the_plate_and_not_its_sidelobes() {
        // A 4 cm plate under a 12×12 cm aperture of 961 antennas returns its specular echo to
        // the antennas above it only. Imaged from a draw of 500 of them, the few that see it
        // leave a sidelobe floor that crosses the power threshold across the footprint.
        let aperture = "width_m = 0.12\nheight_m = 0.12\nspacing_m = 0.004\nz_m = 0.3";
        let capture = plate_under(aperture, 512, "");
        let region_with = |coarse_antennas: usize, subset_sigmas: f64| {
            let auto = AutoVolume {
                coarse_antennas,
                subset_sigmas,
                ..AutoVolume::default()
            };
            let (_, _, report) = select(&capture, VolumeSpec::Auto, 0.002, 4, &auto)
                .unwrap_or_else(|e| panic!("{e}"));
            report.expect("the search ran")
        };
        // The widest lateral reach of the region from the plate's centre, metres.
        let reach = |r: &AutoReport| (0..4).map(|i| r.region_m[i].abs()).fold(0.0, f64::max);
        let untested = region_with(500, 0.0);
        assert!(reach(&untested) > 0.045, "{untested:?}");
        let tested = region_with(500, 4.0);
        assert!(tested.uncertain_voxels > 0, "{tested:?}");
        // The plate (±2 cm) within a coarse voxel, and no more.
        assert!(reach(&tested) < 0.03, "{tested:?}");
        let r = tested.region_m;
        assert!(r[0] < -0.018 && r[1] > 0.018, "{tested:?}");
        assert!(r[2] < -0.018 && r[3] > 0.018, "{tested:?}");
        // From 200, too few see the plate for any voxel to pass: the threshold alone decides.
        let unsure = region_with(200, 4.0);
        assert_eq!(unsure.uncertain_voxels, 0, "{unsure:?}");
        assert!(reach(&unsure) > 0.014, "{unsure:?}");
    }
}
