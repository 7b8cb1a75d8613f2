//! The complex mmWave image S(v) (paper Eq. 4–5) by range-FFT backprojection.
//!
//! For antenna j and voxel v the matched filter of Eq. 4 is
//! `I_j(v) = Σ_t h_j[t]·exp(−j·2π·f_t·D/c)` with `D = |TX_j − v| + |v − RX_j| + range_offset`.
//! The exponent's sign matches the capture convention `exp(+j…)`, as the authors' code does
//! (the paper prints the opposite sign). Writing `f_t = f_0 + t·Δf` splits it into the phasor
//! `exp(−j·2π·f_0·D/c)` and the DFT of h_j at ν = Δf·D/c cycles per sample. That DFT is read
//! from a zero-padded FFT (`pad_factor`·T points) by linear interpolation between the two
//! neighbouring bins. The authors take the floor bin with no interpolation; interpolating
//! removes their up-to-0.39 rad sub-bin phase error.
//!
//! Only the bins that the volume can reach are kept, so memory is N × (reachable bins), not
//! N × pad·T. S(v) is the mean of I_j(v) over the N antennas. The authors' per-group
//! normalisation quirk (docs/mmnorm-reference.md §2.5) is not replicated.
//!
//! The hot loop is f32 and parallel over x-slabs of the grid. `tests::fast_image_matches_brute_force_eq4`
//! checks it against Eq. 4 evaluated directly in f64.

use num_complex::{Complex32, Complex64};
use rayon::prelude::*;
use rustfft::FftPlanner;

use super::kernel::Tile;
use crate::SPEED_OF_LIGHT_M_PER_S;
use crate::capture::Capture;
use crate::progress::Progress;

/// A C-ordered (x, y, z) voxel grid; voxel (i, j, k) has its centre at
/// `origin_m + voxel_m·(i, j, k)`.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct VoxelGrid {
    pub origin_m: [f64; 3],
    pub voxel_m: f64,
    pub dims: [usize; 3],
}

impl VoxelGrid {
    pub fn len(&self) -> usize {
        self.dims.iter().product()
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Centre of voxel `(i, j, k)`.
    pub fn centre(&self, i: usize, j: usize, k: usize) -> [f64; 3] {
        [
            self.origin_m[0] + self.voxel_m * i as f64,
            self.origin_m[1] + self.voxel_m * j as f64,
            self.origin_m[2] + self.voxel_m * k as f64,
        ]
    }

    /// Centre of the voxel at flat (C-order) index `v`.
    pub fn centre_of(&self, v: usize) -> [f64; 3] {
        let [_, ny, nz] = self.dims;
        self.centre(v / (ny * nz), (v / nz) % ny, v % nz)
    }

    /// Evaluates `f(flat index, voxel centre)` for every voxel in parallel (x-slabs), in C order,
    /// counting finished x-slabs on `progress`.
    pub fn par_map<T: Send + Clone>(
        &self,
        fill: T,
        progress: Option<&Progress>,
        f: impl Fn(usize, [f32; 3]) -> T + Sync,
    ) -> Vec<T> {
        let plane = self.dims[1] * self.dims[2];
        self.par_slabs(fill, progress, |i, centres, slab| {
            for (k, (o, v)) in slab.iter_mut().zip(centres).enumerate() {
                *o = f(i * plane + k, *v);
            }
        })
    }

    /// Fills the grid one x-slab at a time in parallel: `f(i, centres, slab)` gets slab i's voxel
    /// centres and values (y-major, z fastest). Counts finished slabs on `progress`.
    pub fn par_slabs<T: Send + Clone>(
        &self,
        fill: T,
        progress: Option<&Progress>,
        f: impl Fn(usize, &[[f32; 3]], &mut [T]) + Sync,
    ) -> Vec<T> {
        let [_, ny, nz] = self.dims;
        let mut out = vec![fill; self.len()];
        out.par_chunks_mut((ny * nz).max(1))
            .enumerate()
            .for_each(|(i, slab)| {
                let mut centres = Vec::with_capacity(ny * nz);
                for j in 0..ny {
                    for k in 0..nz {
                        centres.push(self.centre(i, j, k).map(|c| c as f32));
                    }
                }
                f(i, &centres, slab);
                if let Some(p) = progress {
                    p.inc(1);
                }
            });
        out
    }

    /// The grid's corner voxel centres (min, max).
    pub fn extent(&self) -> ([f64; 3], [f64; 3]) {
        let [nx, ny, nz] = self.dims;
        (
            self.origin_m,
            self.centre(
                nx.saturating_sub(1),
                ny.saturating_sub(1),
                nz.saturating_sub(1),
            ),
        )
    }
}

/// Range profiles cropped to the bins a volume can reach.
#[derive(Debug, Clone)]
pub struct RangeProfiles {
    /// Padded FFT length.
    pub fft_len: usize,
    /// First kept bin (may be negative for a negative frequency step) and the kept count.
    pub first_bin: i64,
    pub bins: usize,
    /// N × `bins` values, antenna-major.
    pub data: Vec<Complex32>,
}

/// Shortest and longest round trip TX → point → RX over the points of the box [lo, hi], metres
/// (range offset not included): the nearest and the farthest point of the box for each leg.
pub fn box_round_trip_m(tx: &[f64; 3], rx: &[f64; 3], lo: [f64; 3], hi: [f64; 3]) -> (f64, f64) {
    let near = |p: &[f64; 3]| {
        (0..3)
            .map(|k| (p[k].clamp(lo[k], hi[k]) - p[k]).powi(2))
            .sum::<f64>()
            .sqrt()
    };
    let far = |p: &[f64; 3]| {
        (0..3)
            .map(|k| (p[k] - lo[k]).abs().max((p[k] - hi[k]).abs()).powi(2))
            .sum::<f64>()
            .sqrt()
    };
    (near(tx) + near(rx), far(tx) + far(rx))
}

/// Smallest and largest round trip from any antenna to any point of `grid`, metres
/// (range offset not included).
pub(crate) fn round_trip_bounds(capture: &Capture, grid: &VoxelGrid) -> (f64, f64) {
    let (lo, hi) = grid.extent();
    let mut bounds = (f64::INFINITY, 0.0f64);
    for (tx, rx) in capture.tx_m.iter().zip(&capture.rx_m) {
        let (near, far) = box_round_trip_m(tx, rx, lo, hi);
        bounds.0 = bounds.0.min(near);
        bounds.1 = bounds.1.max(far);
    }
    bounds
}

impl RangeProfiles {
    /// Zero-padded FFT (`pad_factor`·T points, negative exponent) of every chirp, keeping the
    /// bins that round trips into `grid` can reach, plus one on each side for interpolation.
    pub fn new(capture: &Capture, grid: &VoxelGrid, pad_factor: usize) -> RangeProfiles {
        let t = capture.plan.samples_per_chirp;
        let fft_len = t * pad_factor.max(1);
        let (near, far) = round_trip_bounds(capture, grid);
        let bin_of = |d: f64| {
            (d + capture.range_offset_m) * capture.plan.frequency_step_hz * fft_len as f64
                / SPEED_OF_LIGHT_M_PER_S
        };
        let (a, b) = (bin_of(near), bin_of(far));
        let first_bin = a.min(b).floor() as i64 - 1;
        let bins = ((a.max(b).ceil() as i64 + 2 - first_bin).max(1) as usize).min(fft_len);
        let fft = FftPlanner::<f32>::new().plan_fft_forward(fft_len);
        let mut data = vec![Complex32::new(0.0, 0.0); capture.antennas() * bins];
        data.par_chunks_mut(bins).enumerate().for_each_init(
            || vec![Complex32::new(0.0, 0.0); fft_len],
            |buf, (i, out)| {
                buf.fill(Complex32::new(0.0, 0.0));
                buf[..t].copy_from_slice(capture.chirp(i));
                fft.process(buf);
                for (k, o) in out.iter_mut().enumerate() {
                    *o = buf[(first_bin + k as i64).rem_euclid(fft_len as i64) as usize];
                }
            },
        );
        RangeProfiles {
            fft_len,
            first_bin,
            bins,
            data,
        }
    }
}

/// The per-antenna matched filter I_j(v) of Eq. 4 in f32, from cropped range profiles.
pub struct MatchedFilter<'a> {
    pub(super) profiles: &'a RangeProfiles,
    pub(super) tx: Vec<[f32; 3]>,
    pub(super) rx: Vec<[f32; 3]>,
    pub(super) turns_per_m: f32,
    pub(super) bins_per_m: f32,
    pub(super) offset_m: f32,
    pub(super) first: f32,
    pub(super) last: f32,
}

impl<'a> MatchedFilter<'a> {
    pub fn new(capture: &Capture, profiles: &'a RangeProfiles) -> MatchedFilter<'a> {
        let plan = capture.plan;
        MatchedFilter {
            profiles,
            tx: capture.tx_m.iter().map(|p| p.map(|c| c as f32)).collect(),
            rx: capture.rx_m.iter().map(|p| p.map(|c| c as f32)).collect(),
            turns_per_m: (plan.start_frequency_hz / SPEED_OF_LIGHT_M_PER_S) as f32,
            bins_per_m: (plan.frequency_step_hz * profiles.fft_len as f64 / SPEED_OF_LIGHT_M_PER_S)
                as f32,
            offset_m: capture.range_offset_m as f32,
            first: profiles.first_bin as f32,
            last: (profiles.bins - 1) as f32,
        }
    }

    /// Number of antennas.
    pub fn antennas(&self) -> usize {
        self.tx.len()
    }

    /// Virtual phase centre (TX + RX)/2 of antenna `a`.
    pub fn centre(&self, a: usize) -> [f32; 3] {
        [0, 1, 2].map(|k| 0.5 * (self.tx[a][k] + self.rx[a][k]))
    }
}

/// (sin, cos) of 2π·`turns` in f32, much faster than `f32::sin_cos`: reduction to the
/// nearest whole turn, u = turns − n in [−½, ½]; Taylor polynomials of the half angle πu,
/// which lies in [−π/2, π/2], scaled by √2 ([`HALF_ANGLE_SIN`], [`HALF_ANGLE_COS`]); then the
/// double-angle formulas sin 2a = 2 sin a cos a and cos 2a = 2 cos² a − 1, which the √2 makes
/// one product each. Errors are below 4e-7. There are no branches, so loops around it
/// vectorise, and `recon::kernel`'s AVX2 and AVX-512 paths compute the same polynomials eight
/// or sixteen at a time.
#[inline(always)]
pub fn sin_cos_turns(turns: f32) -> (f32, f32) {
    // Round to the nearest turn without `f32::round` (a libm call on baseline x86-64).
    let x = turns + 0.5;
    let t = x as i32;
    let n = t - i32::from((t as f32) > x);
    let u = turns - n as f32;
    let u2 = u * u;
    let horner = |coefficients: &[f32]| {
        let (&last, rest) = coefficients.split_last().unwrap_or((&0.0, &[]));
        rest.iter().rev().fold(last, |acc, &k| acc * u2 + k)
    };
    let s = u * horner(&HALF_ANGLE_SIN);
    let c = horner(&HALF_ANGLE_COS);
    (s * c, c * c - 1.0)
}

/// √2·sin(πu) = u·Σ_i `HALF_ANGLE_SIN[i]`·u²ⁱ: the Taylor series of sin to x¹¹.
pub const HALF_ANGLE_SIN: [f32; 6] = half_angle_taylor(1);

/// √2·cos(πu) = Σ_i `HALF_ANGLE_COS[i]`·u²ⁱ: the Taylor series of cos to x¹².
pub const HALF_ANGLE_COS: [f32; 7] = half_angle_taylor(0);

/// √2·(−1)ⁱ·π^(2i+p)/(2i+p)!, the coefficient of u²ⁱ (times u when p = 1) in the Taylor
/// series of √2·sin(πu) (p = 1) or √2·cos(πu) (p = 0).
const fn half_angle_taylor<const N: usize>(p: u32) -> [f32; N] {
    let mut out = [0.0f32; N];
    let mut term = std::f64::consts::SQRT_2;
    let mut power = 0;
    while power < p {
        power += 1;
        term *= std::f64::consts::PI / power as f64;
    }
    let mut i = 0;
    while i < N {
        out[i] = term as f32;
        term *= -std::f64::consts::PI * std::f64::consts::PI
            / ((power + 1) as f64 * (power + 2) as f64);
        power += 2;
        i += 1;
    }
    out
}

/// Voxels per cache tile of the antenna-outer loops (8 KB of complex sums).
pub const TILE: usize = 1024;

/// S(v) for every voxel of `grid` (C order), by interpolated backprojection (f32). Counts
/// x-slabs on `progress`.
pub fn backproject(
    capture: &Capture,
    grid: &VoxelGrid,
    profiles: &RangeProfiles,
    progress: Option<&Progress>,
) -> Vec<Complex32> {
    let filter = MatchedFilter::new(capture, profiles);
    let n = filter.antennas();
    let scale = 1.0 / n.max(1) as f32;
    let groups = filter.tx_groups();
    grid.par_slabs(Complex32::new(0.0, 0.0), progress, |_, centres, slab| {
        // Antenna-outer over L1-sized tiles of voxels: the tile's sums stay in L1 and one
        // antenna's profile row stays in cache across the tile (`recon::kernel`).
        let mut tile = Tile::default();
        for (out, tile_centres) in slab.chunks_mut(TILE).zip(centres.chunks(TILE)) {
            tile.load(tile_centres.iter().copied());
            for group in &groups {
                filter.accumulate_group(group.clone(), &mut tile);
            }
            for (i, o) in out.iter_mut().enumerate() {
                *o = Complex32::new(tile.re[i], tile.im[i]) * scale;
            }
        }
    })
}

/// Eq. 4–5 evaluated directly in f64: S(v) = mean_j Σ_t h_j\[t\]·exp(−j2π f_t D_j(v)/c).
/// O(voxels × antennas × T): for tests on small cases.
pub fn backproject_exact_f64(capture: &Capture, grid: &VoxelGrid) -> Vec<Complex64> {
    let [nx, ny, nz] = grid.dims;
    let n = capture.antennas();
    let plan = capture.plan;
    let mut out = Vec::with_capacity(grid.len());
    for i in 0..nx {
        for j in 0..ny {
            for k in 0..nz {
                let v = grid.centre(i, j, k);
                let mut acc = Complex64::new(0.0, 0.0);
                for a in 0..n {
                    let d = |p: &[f64; 3]| {
                        ((p[0] - v[0]).powi(2) + (p[1] - v[1]).powi(2) + (p[2] - v[2]).powi(2))
                            .sqrt()
                    };
                    let round_trip =
                        d(&capture.tx_m[a]) + d(&capture.rx_m[a]) + capture.range_offset_m;
                    for (t, h) in capture.chirp(a).iter().enumerate() {
                        let phase = -std::f64::consts::TAU * plan.frequency_hz(t) * round_trip
                            / SPEED_OF_LIGHT_M_PER_S;
                        acc += Complex64::new(f64::from(h.re), f64::from(h.im))
                            * Complex64::from_polar(1.0, phase);
                    }
                }
                out.push(acc / n as f64);
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sim::{Scene, simulate};

    fn point_capture() -> Capture {
        let text = "[radar]\nstart_frequency_hz = 77.5e9\nfrequency_step_hz = 5.859375e6\nsamples_per_chirp = 256\n\
            [aperture]\nwidth_m = 0.04\nheight_m = 0.04\nspacing_m = 0.004\nz_m = 0.3\nlayout = \"iwr1443boost\"\nantenna_pattern = \"isotropic\"\n\
            [[object]]\nshape = \"point\"\nposition_m = [0.003, -0.002, 0.0]\nrcs_m2 = 0.01\n\
            [[object]]\nshape = \"sphere\"\nradius_m = 0.01\nposition_m = [-0.02, 0.01, 0.005]\n";
        let scene = Scene::parse(text, std::path::Path::new("inline.toml")).unwrap();
        simulate(&scene, true).capture
    }

    #[test]
    fn fast_sin_cos_matches_f64() {
        let mut worst = 0.0f64;
        for i in -20_000..20_000 {
            let turns = i as f32 * 0.00731 + 0.1234;
            let (s, c) = sin_cos_turns(turns);
            let (es, ec) = (std::f64::consts::TAU * f64::from(turns)).sin_cos();
            worst = worst
                .max((f64::from(s) - es).abs())
                .max((f64::from(c) - ec).abs());
        }
        assert!(worst < 4e-7, "{worst}");
    }

    #[test]
    fn fast_image_matches_brute_force_eq4() {
        let capture = point_capture();
        let grid = VoxelGrid {
            origin_m: [-0.01, -0.01, -0.01],
            voxel_m: 0.0013,
            dims: [14, 13, 12],
        };
        let exact = backproject_exact_f64(&capture, &grid);
        for (pad, floor_db) in [(8usize, 30.0f64), (64, 60.0)] {
            let profiles = RangeProfiles::new(&capture, &grid, pad);
            let fast = backproject(&capture, &grid, &profiles, None);
            let signal: f64 = exact.iter().map(|s| s.norm_sqr()).sum();
            let error: f64 = fast
                .iter()
                .zip(&exact)
                .map(|(f, e)| (Complex64::new(f64::from(f.re), f64::from(f.im)) - e).norm_sqr())
                .sum();
            let ser_db = 10.0 * (signal / error).log10();
            println!(
                "pad ×{pad}: {} of {} bins kept, signal-to-error {ser_db:.1} dB",
                profiles.bins, profiles.fft_len
            );
            assert!(ser_db >= floor_db, "pad {pad}: {ser_db} dB");
        }
        // The image peaks at the point target.
        let profiles = RangeProfiles::new(&capture, &grid, 64);
        let fast = backproject(&capture, &grid, &profiles, None);
        let peak = (0..fast.len())
            .max_by(|&a, &b| fast[a].norm().total_cmp(&fast[b].norm()))
            .unwrap();
        let (i, j, k) = (peak / (13 * 12), (peak / 12) % 13, peak % 12);
        let p = grid.centre(i, j, k);
        let err = ((p[0] - 0.003).powi(2) + (p[1] + 0.002).powi(2) + p[2].powi(2)).sqrt();
        assert!(err < 0.0013, "peak at {p:?}");
    }
}
