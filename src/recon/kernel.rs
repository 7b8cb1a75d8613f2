//! The exact per-antenna kernel I_j(v) over a tile of voxels, the hot loop of backprojection
//! and of exact normal votes.
//!
//! For one antenna and a tile of voxel centres held as separate x, y, z arrays it runs two
//! passes, as torchbp's CPU backprojection does:
//! 1. **Geometry** (vectorised): both distances, the fractional range bin, and the carrier's
//!    (cos, sin) from the phase reduced in turns, by the branch-free polynomial of
//!    [`super::image::sin_cos_turns`]. On x86-64 with
//!    AVX2 and FMA this pass is compiled for them and chosen at run time; eight voxels go
//!    through each instruction.
//! 2. **Lookup** (scalar): the two neighbouring bins of the cropped range profile, linearly
//!    interpolated and rotated by the carrier. A gather instruction loses to scalar loads here.
//!
//! The tile's arrays stay in L1; the caller keeps the antenna loop outside the tile so that one
//! profile row serves the whole tile. `tests::tile_kernel_matches_the_scalar_response` checks it
//! against [`MatchedFilter::response`].

use super::image::{MatchedFilter, sin_cos_turns};

/// Voxel centres of a tile (structure of arrays) and the kernel's per-voxel scratch.
#[derive(Debug, Default, Clone)]
pub struct Tile {
    pub x: Vec<f32>,
    pub y: Vec<f32>,
    pub z: Vec<f32>,
    bin: Vec<u32>,
    frac: Vec<f32>,
    cos: Vec<f32>,
    sin: Vec<f32>,
    /// I_a(v) of the last [`MatchedFilter::tile_responses`] call.
    pub re: Vec<f32>,
    pub im: Vec<f32>,
}

impl Tile {
    /// Loads voxel centres.
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
        for v in [
            &mut self.frac,
            &mut self.cos,
            &mut self.sin,
            &mut self.re,
            &mut self.im,
        ] {
            v.resize(n, 0.0);
        }
        self.bin.resize(n, 0);
    }

    pub fn len(&self) -> usize {
        self.x.len()
    }

    pub fn is_empty(&self) -> bool {
        self.x.is_empty()
    }
}

/// The constants of the geometry pass for one antenna.
#[derive(Clone, Copy)]
struct Geometry {
    tx: [f32; 3],
    rx: [f32; 3],
    offset_m: f32,
    bins_per_m: f32,
    first: f32,
    last: f32,
    max_bin: u32,
    turns_per_m: f32,
}

impl MatchedFilter<'_> {
    /// I_a(v) for every voxel of `tile`, into `tile.re` and `tile.im`.
    pub fn tile_responses(&self, a: usize, tile: &mut Tile) {
        let g = Geometry {
            tx: self.tx[a],
            rx: self.rx[a],
            offset_m: self.offset_m,
            bins_per_m: self.bins_per_m,
            first: self.first,
            last: self.last,
            max_bin: self.profiles.bins.saturating_sub(2) as u32,
            turns_per_m: self.turns_per_m,
        };
        geometry_pass(&g, tile);
        let bins = self.profiles.bins;
        let row = &self.profiles.data[a * bins..(a + 1) * bins];
        let n = tile.len();
        let (bin, frac, cos, sin) = (
            &tile.bin[..n],
            &tile.frac[..n],
            &tile.cos[..n],
            &tile.sin[..n],
        );
        let (re, im) = (&mut tile.re[..n], &mut tile.im[..n]);
        for i in 0..n {
            let k = (bin[i] as usize).min(bins.saturating_sub(2));
            let pair = &row[k..k + 2];
            let (lo, hi) = (pair[0], pair[1]);
            let x = lo + (hi - lo) * frac[i];
            // x·exp(−j·carrier) = x·(cos − j·sin).
            re[i] = x.re * cos[i] + x.im * sin[i];
            im[i] = x.im * cos[i] - x.re * sin[i];
        }
    }
}

fn geometry_pass(g: &Geometry, tile: &mut Tile) {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma") {
        // SAFETY: the CPU has just been found to support AVX2 and FMA, which is all that the
        // `target_feature` function requires.
        unsafe { geometry_pass_avx2(g, tile) };
        return;
    }
    geometry_pass_body(g, tile);
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
fn geometry_pass_avx2(g: &Geometry, tile: &mut Tile) {
    geometry_pass_body(g, tile);
}

#[inline(always)]
fn geometry_pass_body(g: &Geometry, tile: &mut Tile) {
    let n = tile.x.len();
    let (x, y, z) = (&tile.x[..n], &tile.y[..n], &tile.z[..n]);
    let (bin, frac) = (&mut tile.bin[..n], &mut tile.frac[..n]);
    let (cos, sin) = (&mut tile.cos[..n], &mut tile.sin[..n]);
    for i in 0..n {
        let dist = |p: [f32; 3]| {
            let d = [p[0] - x[i], p[1] - y[i], p[2] - z[i]];
            (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt()
        };
        let round_trip = dist(g.tx) + dist(g.rx) + g.offset_m;
        let pos = (round_trip * g.bins_per_m - g.first).max(0.0).min(g.last);
        let k = (pos as u32).min(g.max_bin);
        bin[i] = k;
        frac[i] = pos - k as f32;
        let (s, c) = sin_cos_turns(round_trip * g.turns_per_m);
        sin[i] = s;
        cos[i] = c;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::recon::image::{RangeProfiles, VoxelGrid};
    use crate::sim::{Scene, simulate};
    use num_complex::Complex32;

    #[test]
    fn tile_kernel_matches_the_scalar_response() {
        let text = "[radar]\nstart_frequency_hz = 77.5e9\nfrequency_step_hz = 5.859375e6\nsamples_per_chirp = 256\n\
            [aperture]\nwidth_m = 0.02\nheight_m = 0.02\nspacing_m = 0.004\nz_m = 0.3\nlayout = \"iwr1443boost\"\n\
            [[object]]\nshape = \"point\"\nposition_m = [0.003, -0.002, 0.0]\nrcs_m2 = 0.01\n";
        let scene = Scene::parse(text, std::path::Path::new("inline.toml")).unwrap();
        let capture = simulate(&scene, true).capture;
        let grid = VoxelGrid {
            origin_m: [-0.01, -0.01, -0.01],
            voxel_m: 0.0013,
            dims: [9, 8, 7],
        };
        let profiles = RangeProfiles::new(&capture, &grid, 16);
        let filter = MatchedFilter::new(&capture, &profiles);
        let centres: Vec<[f32; 3]> = (0..9)
            .flat_map(|i| (0..8).flat_map(move |j| (0..7).map(move |k| (i, j, k))))
            .map(|(i, j, k)| grid.centre(i, j, k).map(|c| c as f32))
            .collect();
        let mut tile = Tile::default();
        tile.load(centres.iter().copied());
        for a in 0..filter.antennas() {
            filter.tile_responses(a, &mut tile);
            for (i, v) in centres.iter().enumerate() {
                let r = filter.response(a, *v);
                let t = Complex32::new(tile.re[i], tile.im[i]);
                assert!(
                    (r - t).norm() <= 1e-5 * r.norm().max(1e-3),
                    "antenna {a} voxel {i}: {r} vs {t}"
                );
            }
        }
    }
}
