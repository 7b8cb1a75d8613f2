//! The kernel in AVX-512F: sixteen voxels per step, the same two phases per step as the AVX2
//! kernel (see `avx2`), with the tile's last `len % 16` voxels done by a masked step.
//!
//! The lookups are sixteen unaligned 16-byte loads (a bin and its successor), four to a
//! register, and the same in-lane transpose as in AVX2, which here yields all sixteen lanes in
//! order. The arithmetic is the AVX2 kernel's, lane for lane.

use std::arch::x86_64::*;

use super::{Group, MAX_GROUP, Output, Tile};
use crate::recon::image::{HALF_ANGLE_COS, HALF_ANGLE_SIN};

/// Lanes per step.
const LANES: usize = 16;

/// Whether this CPU runs the AVX-512 kernel.
pub(super) fn available() -> bool {
    is_x86_feature_detected!("avx512f")
}

/// Runs the kernel over every voxel of `tile` and returns how many it did: all of them, or 0
/// when the CPU lacks AVX-512F or the profiles have fewer than two bins.
pub(super) fn kernel(g: &Group, tile: &mut Tile, output: Output) -> usize {
    if g.bins < 2 || !available() {
        return 0;
    }
    // Every lookup reads bins k and k + 1 of a member's row with k ≤ max_bin = bins − 2.
    let max_bin = g.max_bin();
    // SAFETY: the CPU supports AVX-512F (checked above), all that `steps` requires.
    unsafe {
        match output {
            Output::Store => steps::<false>(g, max_bin, tile),
            Output::Add => steps::<true>(g, max_bin, tile),
        }
    }
    tile.len()
}

/// The group's constants, one per lane.
#[derive(Clone, Copy)]
struct Lanes {
    bins_per_m: __m512,
    first: __m512,
    last: __m512,
    turns_per_m: __m512,
    max_bin: __m512i,
}

/// The TX leg's share of every member's bin position and carrier phase (as in `avx2`).
struct TxLeg {
    pos: __m512,
    turns: __m512,
}

/// `_mm512_roundscale_ps` to the nearest integer, exceptions suppressed.
const NEAREST: i32 = _MM_FROUND_TO_NEAREST_INT | _MM_FROUND_NO_EXC;

impl TxLeg {
    #[inline]
    #[target_feature(enable = "avx512f")]
    fn new(lanes: &Lanes, leg_m: __m512) -> Self {
        let turns = _mm512_mul_ps(leg_m, lanes.turns_per_m);
        let whole = _mm512_roundscale_ps::<NEAREST>(turns);
        Self {
            pos: _mm512_fmsub_ps(leg_m, lanes.bins_per_m, lanes.first),
            turns: _mm512_sub_ps(turns, whole),
        }
    }
}

/// The steps over every voxel of `tile`, the last one masked when `tile.len()` is not a
/// multiple of 16: the group's responses summed, then stored, or with `ADD` added to the
/// sums.
#[target_feature(enable = "avx512f")]
fn steps<const ADD: bool>(g: &Group, max_bin: u32, tile: &mut Tile) {
    let n = tile.len();
    let (x, y, z) = (&tile.x[..n], &tile.y[..n], &tile.z[..n]);
    let (re, im) = (&mut tile.re[..n], &mut tile.im[..n]);
    let members = g.members().min(MAX_GROUP);
    let splat = |v: f32| _mm512_set1_ps(v);
    let mut rx = [[_mm512_setzero_ps(); 3]; MAX_GROUP];
    let mut rows = [std::ptr::null::<f32>(); MAX_GROUP];
    for m in 0..members {
        rx[m] = g.rx[m].map(splat);
        rows[m] = g.row(m).as_ptr().cast();
    }
    let tx_at = g.tx.map(splat);
    let offset_m = splat(g.offset_m);
    let lanes = Lanes {
        bins_per_m: splat(g.bins_per_m),
        first: splat(g.first),
        last: splat(g.last),
        turns_per_m: splat(g.turns_per_m),
        max_bin: _mm512_set1_epi32(max_bin as i32),
    };
    let mut at = [Geometry::default(); MAX_GROUP];
    for i in (0..n).step_by(LANES) {
        // The lanes at or past n are masked off: loaded as 0 (a valid position, whose
        // lookups stay in the row), never stored.
        let mask: __mmask16 = if n - i >= LANES {
            !0
        } else {
            (1u16 << (n - i)) - 1
        };
        // SAFETY: the masked loads and stores touch only elements i..min(i + 16, n), which
        // every slice here holds.
        let load = |s: &[f32]| unsafe { _mm512_maskz_loadu_ps(mask, s.as_ptr().add(i)) };
        let v = [load(x), load(y), load(z)];
        let tx = TxLeg::new(&lanes, _mm512_add_ps(distance(&tx_at, &v), offset_m));
        for (geometry, rx) in at.iter_mut().zip(&rx).take(members) {
            *geometry = Geometry::new(&lanes, &v, &tx, rx);
        }
        let (mut sum_re, mut sum_im) = if ADD {
            (load(re), load(im))
        } else {
            (_mm512_setzero_ps(), _mm512_setzero_ps())
        };
        for (geometry, &row) in at.iter().zip(&rows).take(members) {
            // SAFETY: `row` starts a member's row of g.bins = max_bin + 2 values, and this
            // function requires AVX-512F.
            let (a_re, a_im) = unsafe { geometry.response(row) };
            sum_re = _mm512_add_ps(sum_re, a_re);
            sum_im = _mm512_add_ps(sum_im, a_im);
        }
        // SAFETY: as for the loads.
        unsafe {
            _mm512_mask_storeu_ps(re.as_mut_ptr().add(i), mask, sum_re);
            _mm512_mask_storeu_ps(im.as_mut_ptr().add(i), mask, sum_im);
        }
    }
}

/// One member's geometry for sixteen voxels (as in `avx2`).
#[derive(Clone, Copy)]
struct Geometry {
    bins: [i32; LANES],
    frac: __m512,
    sin: __m512,
    cos: __m512,
}

impl Default for Geometry {
    fn default() -> Self {
        // SAFETY: all-zero bits are a valid __m512.
        let zero = unsafe { std::mem::zeroed::<__m512>() };
        Self {
            bins: [0; LANES],
            frac: zero,
            sin: zero,
            cos: zero,
        }
    }
}

impl Geometry {
    #[inline]
    #[target_feature(enable = "avx512f")]
    fn new(lanes: &Lanes, v: &[__m512; 3], tx: &TxLeg, rx: &[__m512; 3]) -> Self {
        let rx_leg = distance(rx, v);
        // max(·, 0) first: it also turns a NaN position into bin 0.
        let pos = _mm512_min_ps(
            _mm512_max_ps(
                _mm512_fmadd_ps(rx_leg, lanes.bins_per_m, tx.pos),
                _mm512_setzero_ps(),
            ),
            lanes.last,
        );
        // Bounded by integer operations, so that the lookups do not rest on the float
        // arithmetic: k in [0, max_bin].
        let k = _mm512_max_epi32(
            _mm512_min_epi32(_mm512_cvttps_epi32(pos), lanes.max_bin),
            _mm512_setzero_si512(),
        );
        let mut bins = [0i32; LANES];
        // SAFETY: `bins` holds exactly one __m512i.
        unsafe { _mm512_storeu_si512(bins.as_mut_ptr().cast(), k) };
        let (sin, cos) = sin_cos_turns(_mm512_fmadd_ps(rx_leg, lanes.turns_per_m, tx.turns));
        Self {
            bins,
            frac: _mm512_sub_ps(pos, _mm512_cvtepi32_ps(k)),
            sin,
            cos,
        }
    }

    /// I(v) for the sixteen voxels from the member's profile row.
    ///
    /// # Safety
    /// The CPU supports AVX-512F; `profile` points at a row of at least `max_bin + 2` complex
    /// values, with `max_bin` the bound [`Geometry::new`] was given.
    #[inline]
    #[target_feature(enable = "avx512f")]
    unsafe fn response(&self, profile: *const f32) -> (__m512, __m512) {
        // SAFETY: 0 ≤ k ≤ max_bin and the row holds max_bin + 2 values from `profile` (the
        // caller's promise), so the four floats at 2k are its bins k and k + 1.
        let pair = |lane: usize| unsafe {
            _mm_loadu_ps(profile.add(2 * std::ptr::read_volatile(&self.bins[lane]) as usize))
        };
        // Row j holds the pairs of lanes j, j + 4, j + 8 and j + 12.
        let row = |j: usize| {
            let r = _mm512_castps128_ps512(pair(j));
            let r = _mm512_insertf32x4::<1>(r, pair(j + 4));
            let r = _mm512_insertf32x4::<2>(r, pair(j + 8));
            _mm512_insertf32x4::<3>(r, pair(j + 12))
        };
        let [lo_re, lo_im, hi_re, hi_im] = transpose([row(0), row(1), row(2), row(3)]);
        let x_re = _mm512_fmadd_ps(_mm512_sub_ps(hi_re, lo_re), self.frac, lo_re);
        let x_im = _mm512_fmadd_ps(_mm512_sub_ps(hi_im, lo_im), self.frac, lo_im);
        let (s, c) = (self.sin, self.cos);
        // x·exp(−j·carrier) = x·(cos − j·sin).
        (
            _mm512_fmadd_ps(x_re, c, _mm512_mul_ps(x_im, s)),
            _mm512_fmsub_ps(x_im, c, _mm512_mul_ps(x_re, s)),
        )
    }
}

/// |p − v| for sixteen voxels `v`.
#[inline]
#[target_feature(enable = "avx512f")]
fn distance(p: &[__m512; 3], v: &[__m512; 3]) -> __m512 {
    let d = [0, 1, 2].map(|q| _mm512_sub_ps(p[q], v[q]));
    let squares = _mm512_fmadd_ps(
        d[2],
        d[2],
        _mm512_fmadd_ps(d[1], d[1], _mm512_mul_ps(d[0], d[0])),
    );
    _mm512_sqrt_ps(squares)
}

/// The 4×4 transpose within each 128-bit lane: rows of (re_k, im_k, re_{k+1}, im_{k+1})
/// pairs into the four component vectors.
#[inline]
#[target_feature(enable = "avx512f")]
fn transpose(r: [__m512; 4]) -> [__m512; 4] {
    let t0 = _mm512_unpacklo_ps(r[0], r[1]);
    let t1 = _mm512_unpackhi_ps(r[0], r[1]);
    let t2 = _mm512_unpacklo_ps(r[2], r[3]);
    let t3 = _mm512_unpackhi_ps(r[2], r[3]);
    [
        _mm512_shuffle_ps::<0x44>(t0, t2),
        _mm512_shuffle_ps::<0xEE>(t0, t2),
        _mm512_shuffle_ps::<0x44>(t1, t3),
        _mm512_shuffle_ps::<0xEE>(t1, t3),
    ]
}

/// The half-angle sine and cosine of `avx2`, sixteen lanes at a time.
#[inline]
#[target_feature(enable = "avx512f")]
fn sin_cos_turns(turns: __m512) -> (__m512, __m512) {
    let whole = _mm512_roundscale_ps::<NEAREST>(turns);
    let u = _mm512_sub_ps(turns, whole);
    let u2 = _mm512_mul_ps(u, u);
    let horner = |coefficients: &[f32]| {
        coefficients.iter().rev().skip(1).fold(
            _mm512_set1_ps(coefficients[coefficients.len() - 1]),
            |acc, &k| _mm512_fmadd_ps(acc, u2, _mm512_set1_ps(k)),
        )
    };
    let s = _mm512_mul_ps(u, horner(&HALF_ANGLE_SIN));
    let c = horner(&HALF_ANGLE_COS);
    (
        _mm512_mul_ps(s, c),
        _mm512_fmsub_ps(c, c, _mm512_set1_ps(1.0)),
    )
}
