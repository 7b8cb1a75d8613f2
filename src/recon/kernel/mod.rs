//! The exact per-antenna kernel I_j(v) over a tile of voxels, the hot loop of backprojection
//! and of exact normal votes.
//!
//! For one antenna and a tile of voxel centres held as separate x, y, z arrays it computes, in
//! one pass per voxel:
//! - both distances, the fractional range bin, and the carrier's (cos, sin) from the phase
//!   reduced in turns (the branch-free polynomial of [`super::image::sin_cos_turns`]);
//! - the two neighbouring bins of the cropped range profile, linearly interpolated and rotated
//!   by the carrier;
//!
//! and either stores I_a(v) in the tile ([`MatchedFilter::tile_responses`], for the votes) or
//! adds it to the tile's sums ([`MatchedFilter::accumulate_group`], for the image). The image
//! takes antennas in groups that share a TX position (the four RX channels of one position):
//! the TX leg is computed once per voxel for the group, and the sums are loaded and stored
//! once per group.
//!
//! On x86-64 the pass is hand-vectorised, in the widest instruction set the CPU has, chosen at
//! run time ([`KernelIsa`]; the environment variable `MMNORMD_KERNEL` can ask for a narrower
//! one). The kernel is written once, in `vector`, over the operations of the `simd::Simd`
//! trait, and compiled inside one `#[target_feature]` function per instruction set:
//! - `avx512` (AVX-512F): sixteen voxels per step, the tile's last `len % 16` in one masked
//!   step;
//! - `avx2` (AVX2 and FMA): eight voxels per step.
//!
//! Each step does the geometry of every member first and then the profile lookups per
//! member, done as one 16-byte load per voxel (a bin and its successor) and a register
//! transpose, because gathers lose to that on Zen (AVX-512 gathers measured 0.59× on Zen 5).
//! The vector kernel groups the arithmetic differently from the scalar code (the TX leg's
//! share of the bin and its whole turns taken once per step, FMA where the scalar code rounds
//! twice), so the paths agree to rounding, not bit for bit. Elsewhere, and for the last
//! `len % 8` voxels of a tile in AVX2, the scalar `voxel_response` runs; it is the plain
//! statement of the kernel.
//!
//! The tile's arrays stay in L1; the caller keeps the antenna loop outside the tile so that one
//! profile row serves the whole tile. `tests::tile_kernel_matches_an_f64_reference` checks every
//! instruction set the CPU runs, one antenna at a time and in groups, against the kernel's
//! statement in f64, and `image::tests::fast_image_matches_brute_force_eq4` the image against
//! Eq. 4 in f64.

#[cfg(target_arch = "x86_64")]
mod avx2;
#[cfg(target_arch = "x86_64")]
mod avx512;
mod isa;
#[cfg(target_arch = "x86_64")]
mod simd;
#[cfg(target_arch = "x86_64")]
mod vector;

pub use isa::{KERNEL_ENV, KernelIsa, KernelIsaError};

use super::image::{MatchedFilter, sin_cos_turns};
use num_complex::Complex32;

/// Voxel centres of a tile (structure of arrays) and I_a(v) or its running sum.
#[derive(Debug, Default, Clone)]
pub struct Tile {
    pub x: Vec<f32>,
    pub y: Vec<f32>,
    pub z: Vec<f32>,
    /// I_a(v) of the last [`MatchedFilter::tile_responses`] call, or the sum of the
    /// [`MatchedFilter::accumulate_group`] calls since [`Tile::clear_sums`].
    pub re: Vec<f32>,
    pub im: Vec<f32>,
}

impl Tile {
    /// Loads voxel centres and zeroes the sums.
    pub fn load(&mut self, centres: impl IntoIterator<Item = [f32; 3]>) {
        self.x.clear();
        self.y.clear();
        self.z.clear();
        for c in centres {
            self.x.push(c[0]);
            self.y.push(c[1]);
            self.z.push(c[2]);
        }
        let n = self.x.len();
        self.re.resize(n, 0.0);
        self.im.resize(n, 0.0);
        self.clear_sums();
    }

    /// Zeroes `re` and `im`.
    pub fn clear_sums(&mut self) {
        self.re.fill(0.0);
        self.im.fill(0.0);
    }

    pub fn len(&self) -> usize {
        self.x.len()
    }

    pub fn is_empty(&self) -> bool {
        self.x.is_empty()
    }
}

/// Most antennas in one [`MatchedFilter::tx_groups`] group.
pub const MAX_GROUP: usize = 8;

/// The constants of the kernel for a group of antennas that share their TX position.
#[derive(Clone, Copy)]
struct Group<'a> {
    tx: [f32; 3],
    /// One RX position per member.
    rx: &'a [[f32; 3]],
    /// The members' cropped range profiles, `bins` each, member-major.
    rows: &'a [Complex32],
    bins: usize,
    offset_m: f32,
    bins_per_m: f32,
    first: f32,
    /// Highest fractional bin, `bins − 1`.
    last: f32,
    turns_per_m: f32,
}

impl Group<'_> {
    /// Highest lower bin of an interpolation pair, `bins − 2`.
    fn max_bin(&self) -> u32 {
        self.bins.saturating_sub(2) as u32
    }

    fn members(&self) -> usize {
        self.rx.len().min(self.rows.len() / self.bins.max(1))
    }

    fn row(&self, member: usize) -> &[Complex32] {
        &self.rows[member * self.bins..(member + 1) * self.bins]
    }
}

/// Whether the kernel stores I_a(v) or adds it to the tile's sums.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Output {
    Store,
    Add,
}

impl MatchedFilter<'_> {
    /// The antennas in runs of consecutive indices that share one TX position (exactly, in
    /// f32), at most [`MAX_GROUP`] long: the four virtual channels of one IWR1443BOOST TX
    /// position form one. [`Self::accumulate_group`] computes the TX leg once per run.
    pub fn tx_groups(&self) -> Vec<std::ops::Range<usize>> {
        let mut groups: Vec<std::ops::Range<usize>> = Vec::new();
        for a in 0..self.antennas() {
            match groups.last_mut() {
                Some(g) if g.len() < MAX_GROUP && self.tx[g.start] == self.tx[a] => g.end = a + 1,
                _ => groups.push(a..a + 1),
            }
        }
        groups
    }

    /// I_a(v) for every voxel of `tile`, into `tile.re` and `tile.im`.
    pub fn tile_responses(&self, a: usize, tile: &mut Tile) {
        self.run_kernel(a..a + 1, tile, Output::Store);
    }

    /// Adds Σ_a I_a(v) over `antennas`, one of [`Self::tx_groups`], for every voxel of
    /// `tile` to `tile.re` and `tile.im`. Antennas that do not share the first one's TX are
    /// accumulated one at a time.
    pub fn accumulate_group(&self, antennas: std::ops::Range<usize>, tile: &mut Tile) {
        if antennas.is_empty() {
            return;
        }
        let shared = antennas
            .clone()
            .take(MAX_GROUP)
            .take_while(|&a| self.tx[a] == self.tx[antennas.start])
            .count();
        if shared == antennas.len() {
            self.run_kernel(antennas, tile, Output::Add);
        } else {
            for a in antennas {
                self.run_kernel(a..a + 1, tile, Output::Add);
            }
        }
    }

    /// The kernel for `antennas`, which share one TX position, in [`KernelIsa::active`].
    fn run_kernel(&self, antennas: std::ops::Range<usize>, tile: &mut Tile, output: Output) {
        run_group(KernelIsa::active(), &self.group(antennas), tile, output);
    }

    /// The kernel's constants for `antennas`, which share one TX position.
    fn group(&self, antennas: std::ops::Range<usize>) -> Group<'_> {
        let bins = self.profiles.bins;
        Group {
            tx: self.tx[antennas.start],
            rx: &self.rx[antennas.clone()],
            rows: &self.profiles.data[antennas.start * bins..antennas.end * bins],
            bins,
            offset_m: self.offset_m,
            bins_per_m: self.bins_per_m,
            first: self.first,
            last: self.last,
            turns_per_m: self.turns_per_m,
        }
    }
}

/// The kernel for one group over the whole tile in `isa`: the vector kernel over what it
/// covers, then the scalar statement over the rest. An `isa` this CPU lacks runs as scalar.
fn run_group(isa: KernelIsa, g: &Group, tile: &mut Tile, output: Output) {
    let done = match isa {
        #[cfg(target_arch = "x86_64")]
        KernelIsa::Avx512 => avx512::kernel(g, tile, output),
        #[cfg(target_arch = "x86_64")]
        KernelIsa::Avx2 => avx2::kernel(g, tile, output),
        _ => 0,
    };
    scalar_span(g, tile, done, output);
}

/// The scalar kernel over the voxels `from..` of `tile`.
fn scalar_span(g: &Group, tile: &mut Tile, from: usize, output: Output) {
    for i in from..tile.len() {
        let v = [tile.x[i], tile.y[i], tile.z[i]];
        let sum: Complex32 = (0..g.members()).map(|m| voxel_response(g, m, v)).sum();
        match output {
            Output::Store => {
                tile.re[i] = sum.re;
                tile.im[i] = sum.im;
            }
            Output::Add => {
                tile.re[i] += sum.re;
                tile.im[i] += sum.im;
            }
        }
    }
}

/// I_a(v) of the group's `member` for one voxel: the scalar statement of the kernel.
#[inline(always)]
fn voxel_response(g: &Group, member: usize, v: [f32; 3]) -> Complex32 {
    let dist = |p: [f32; 3]| {
        let d = [p[0] - v[0], p[1] - v[1], p[2] - v[2]];
        (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt()
    };
    let round_trip = dist(g.tx) + dist(g.rx[member]) + g.offset_m;
    let pos = (round_trip * g.bins_per_m - g.first).max(0.0).min(g.last);
    let k = (pos as u32).min(g.max_bin()) as usize;
    let frac = pos - k as f32;
    let row = g.row(member);
    let Some(&lo) = row.get(k) else {
        return Complex32::new(0.0, 0.0);
    };
    let hi = row.get(k + 1).copied().unwrap_or(lo);
    let x = lo + (hi - lo) * frac;
    let (s, c) = sin_cos_turns(round_trip * g.turns_per_m);
    // x·exp(−j·carrier) = x·(cos − j·sin).
    Complex32::new(x.re * c + x.im * s, x.im * c - x.re * s)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::recon::image::{RangeProfiles, VoxelGrid};
    use crate::sim::{Scene, simulate};
    use num_complex::Complex64;

    /// I_a(v) in f64 from the same cropped profile: the round trip, the bin, the interpolation
    /// and the carrier's exp(−j2π f_0 D/c) all in double precision.
    fn reference(filter: &MatchedFilter, a: usize, v: [f32; 3]) -> Complex64 {
        let dist = |p: [f32; 3]| {
            (0..3)
                .map(|q| (f64::from(p[q]) - f64::from(v[q])).powi(2))
                .sum::<f64>()
                .sqrt()
        };
        let round_trip = dist(filter.tx[a]) + dist(filter.rx[a]) + f64::from(filter.offset_m);
        let bins = filter.profiles.bins;
        let pos = (round_trip * f64::from(filter.bins_per_m) - f64::from(filter.first))
            .clamp(0.0, (bins - 1) as f64);
        let k = (pos as usize).min(bins - 2);
        let frac = pos - k as f64;
        let at = |b: usize| {
            let z = filter.profiles.data[a * bins + b];
            Complex64::new(f64::from(z.re), f64::from(z.im))
        };
        let x = at(k) + (at(k + 1) - at(k)) * frac;
        let phase = std::f64::consts::TAU * f64::from(filter.turns_per_m) * round_trip;
        x * Complex64::from_polar(1.0, -phase)
    }

    /// Relative to the profile's scale: a wrong bin or a swapped component errs by tenths.
    const TOLERANCE: f64 = 3e-4;

    fn close(a: Complex64, b: Complex32, scale: f64) -> bool {
        (a - Complex64::new(f64::from(b.re), f64::from(b.im))).norm() <= TOLERANCE * scale
    }

    /// The kernel in every instruction set this CPU runs, on every antenna, one at a time and
    /// in TX groups, against [`reference`], on a tile of 315 voxels: 3 past a multiple of 8
    /// (the AVX2 steps and the scalar tail both run) and 11 past one of 16 (AVX-512's masked
    /// last step).
    #[test]
    fn tile_kernel_matches_an_f64_reference() {
        let text = "[radar]\nstart_frequency_hz = 77.5e9\nfrequency_step_hz = 5.859375e6\nsamples_per_chirp = 256\n\
            [aperture]\nwidth_m = 0.02\nheight_m = 0.02\nspacing_m = 0.004\nz_m = 0.3\nlayout = \"iwr1443boost\"\n\
            [[object]]\nshape = \"point\"\nposition_m = [0.003, -0.002, 0.0]\nrcs_m2 = 0.01\n";
        let scene = Scene::parse(text, std::path::Path::new("inline.toml")).unwrap();
        let capture = simulate(&scene, true).capture;
        let dims = [9, 7, 5];
        let grid = VoxelGrid {
            origin_m: [-0.01, -0.01, -0.01],
            voxel_m: 0.0013,
            dims,
        };
        let profiles = RangeProfiles::new(&capture, &grid, 16);
        let filter = MatchedFilter::new(&capture, &profiles);
        let scale = profiles
            .data
            .iter()
            .map(|z| z.norm())
            .fold(0.0f32, f32::max) as f64;
        let centres: Vec<[f32; 3]> = (0..dims[0])
            .flat_map(|i| (0..dims[1]).flat_map(move |j| (0..dims[2]).map(move |k| (i, j, k))))
            .map(|(i, j, k)| grid.centre(i, j, k).map(|c| c as f32))
            .collect();
        assert_eq!((centres.len() % 8, centres.len() % 16), (3, 11));
        let mut tile = Tile::default();
        tile.load(centres.iter().copied());
        let responses: Vec<Vec<Complex64>> = (0..filter.antennas())
            .map(|a| centres.iter().map(|&v| reference(&filter, a, v)).collect())
            .collect();
        let groups = filter.tx_groups();
        assert_eq!(groups.len() * 4, filter.antennas());
        assert!(groups.iter().all(|g| g.len() == 4));
        for isa in KernelIsa::available() {
            for (a, expected) in responses.iter().enumerate() {
                run_group(isa, &filter.group(a..a + 1), &mut tile, Output::Store);
                for (i, &e) in expected.iter().enumerate() {
                    let got = Complex32::new(tile.re[i], tile.im[i]);
                    assert!(
                        close(e, got, scale),
                        "{isa}, antenna {a} voxel {i}: {e} vs {got}"
                    );
                }
            }
            // Groups: the four RX channels of each TX position, added twice.
            for group in &groups {
                tile.clear_sums();
                for _ in 0..2 {
                    run_group(isa, &filter.group(group.clone()), &mut tile, Output::Add);
                }
                for (i, got) in tile.re.iter().zip(&tile.im).enumerate() {
                    let e: Complex64 =
                        group.clone().map(|a| responses[a][i]).sum::<Complex64>() * 2.0;
                    let got = Complex32::new(*got.0, *got.1);
                    assert!(
                        close(e, got, 8.0 * scale),
                        "{isa}, group {group:?} voxel {i}: {e} vs {got}"
                    );
                }
            }
        }
        // The public entry points run the active instruction set.
        let a = filter.antennas() - 1;
        filter.tile_responses(a, &mut tile);
        for (i, &e) in responses[a].iter().enumerate() {
            assert!(close(e, Complex32::new(tile.re[i], tile.im[i]), scale));
        }
    }

    /// Antennas that do not share a TX position are never grouped, and a group given to
    /// `accumulate_group` that mixes two is summed one antenna at a time.
    #[test]
    fn groups_hold_one_tx_position() {
        let text = "[radar]\nstart_frequency_hz = 77.5e9\nfrequency_step_hz = 5.859375e6\nsamples_per_chirp = 64\n\
            [aperture]\nwidth_m = 0.008\nheight_m = 0.004\nspacing_m = 0.004\nz_m = 0.3\n\
            [[object]]\nshape = \"point\"\nposition_m = [0.0, 0.0, 0.0]\nrcs_m2 = 0.01\n";
        let scene = Scene::parse(text, std::path::Path::new("inline.toml")).unwrap();
        let capture = simulate(&scene, true).capture;
        let grid = VoxelGrid {
            origin_m: [-0.004, -0.004, -0.004],
            voxel_m: 0.002,
            dims: [4, 4, 4],
        };
        let profiles = RangeProfiles::new(&capture, &grid, 4);
        let filter = MatchedFilter::new(&capture, &profiles);
        let groups = filter.tx_groups();
        assert_eq!(
            groups.len(),
            filter.antennas(),
            "monostatic: one antenna per position"
        );
        let centres: Vec<[f32; 3]> = (0..grid.len())
            .map(|p| grid.centre(p / 16, p / 4 % 4, p % 4).map(|c| c as f32))
            .collect();
        let mut mixed = Tile::default();
        mixed.load(centres.iter().copied());
        filter.accumulate_group(0..filter.antennas(), &mut mixed);
        let mut single = Tile::default();
        single.load(centres.iter().copied());
        for group in groups {
            filter.accumulate_group(group, &mut single);
        }
        assert_eq!(mixed.re, single.re);
        assert_eq!(mixed.im, single.im);
    }
}
