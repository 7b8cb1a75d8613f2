//! [`Simd`] in AVX-512F: sixteen voxels per step, with a tile's last `len % 16` voxels done by
//! one masked step.
//!
//! The lookups are sixteen unaligned 16-byte loads (a bin and its successor), four to a
//! register, and the same in-lane transpose as in AVX2, which here yields all sixteen lanes
//! in order. AVX-512 gathers of the (re, im) pairs measured 0.59× these loads on Zen 5.

use std::arch::x86_64::*;

use super::simd::Simd;
use super::{Group, Output, Tile, vector};

/// The AVX-512F instruction set: made only where the CPU runs it.
#[derive(Clone, Copy)]
pub(super) struct Avx512(());

/// Whether this CPU runs the AVX-512 kernel.
pub(super) fn available() -> bool {
    is_x86_feature_detected!("avx512f")
}

/// Runs the kernel over every voxel of `tile` and returns how many it did: all of them, or 0
/// when the CPU lacks AVX-512F or the profiles have fewer than two bins.
pub(super) fn kernel(g: &Group, tile: &mut Tile, output: Output) -> usize {
    if !available() {
        return 0;
    }
    let s = Avx512(());
    // SAFETY: the CPU supports AVX-512F (checked above), all that `steps` requires.
    unsafe {
        match output {
            Output::Store => steps::<false>(s, g, tile),
            Output::Add => steps::<true>(s, g, tile),
        }
    }
}

/// [`vector::steps`] compiled for AVX-512F.
#[target_feature(enable = "avx512f")]
fn steps<const ADD: bool>(s: Avx512, g: &Group, tile: &mut Tile) -> usize {
    vector::steps::<Avx512, ADD>(s, g, tile)
}

/// The lanes below `remaining`.
#[inline(always)]
fn mask(remaining: usize) -> __mmask16 {
    if remaining >= 16 {
        !0
    } else {
        (1u16 << remaining) - 1
    }
}

// SAFETY (every `unsafe` block below): an `Avx512` exists only where the CPU runs AVX-512F.
impl Simd for Avx512 {
    const LANES: usize = 16;
    type F = __m512;
    type I = __m512i;
    type Bins = [i32; 16];

    #[inline(always)]
    fn splat(self, v: f32) -> __m512 {
        unsafe { _mm512_set1_ps(v) }
    }
    #[inline(always)]
    fn splat_i(self, v: i32) -> __m512i {
        unsafe { _mm512_set1_epi32(v) }
    }
    #[inline(always)]
    fn add(self, a: __m512, b: __m512) -> __m512 {
        unsafe { _mm512_add_ps(a, b) }
    }
    #[inline(always)]
    fn sub(self, a: __m512, b: __m512) -> __m512 {
        unsafe { _mm512_sub_ps(a, b) }
    }
    #[inline(always)]
    fn mul(self, a: __m512, b: __m512) -> __m512 {
        unsafe { _mm512_mul_ps(a, b) }
    }
    #[inline(always)]
    fn mul_add(self, a: __m512, b: __m512, c: __m512) -> __m512 {
        unsafe { _mm512_fmadd_ps(a, b, c) }
    }
    #[inline(always)]
    fn mul_sub(self, a: __m512, b: __m512, c: __m512) -> __m512 {
        unsafe { _mm512_fmsub_ps(a, b, c) }
    }
    #[inline(always)]
    fn sqrt(self, a: __m512) -> __m512 {
        unsafe { _mm512_sqrt_ps(a) }
    }
    #[inline(always)]
    fn min(self, a: __m512, b: __m512) -> __m512 {
        unsafe { _mm512_min_ps(a, b) }
    }
    #[inline(always)]
    fn max(self, a: __m512, b: __m512) -> __m512 {
        unsafe { _mm512_max_ps(a, b) }
    }
    #[inline(always)]
    fn round(self, a: __m512) -> __m512 {
        unsafe { _mm512_roundscale_ps::<{ _MM_FROUND_TO_NEAREST_INT | _MM_FROUND_NO_EXC }>(a) }
    }
    #[inline(always)]
    fn bins(self, pos: __m512, max_bin: __m512i) -> ([i32; 16], __m512) {
        let mut bins = [0i32; 16];
        unsafe {
            let k = _mm512_max_epi32(
                _mm512_min_epi32(_mm512_cvttps_epi32(pos), max_bin),
                _mm512_setzero_si512(),
            );
            // `bins` holds exactly one __m512i.
            _mm512_storeu_si512(bins.as_mut_ptr().cast(), k);
            (bins, _mm512_sub_ps(pos, _mm512_cvtepi32_ps(k)))
        }
    }

    #[inline(always)]
    fn covered(len: usize) -> usize {
        len
    }
    #[inline(always)]
    unsafe fn load(self, p: *const f32, remaining: usize) -> __m512 {
        // SAFETY: the masked load reads only the min(remaining, 16) values at `p` (the
        // caller's promise); the masked-off lanes are 0, a valid position whose lookups stay
        // in the row, and are never stored.
        unsafe { _mm512_maskz_loadu_ps(mask(remaining), p) }
    }
    #[inline(always)]
    unsafe fn store(self, p: *mut f32, remaining: usize, v: __m512) {
        // SAFETY: as for `load`.
        unsafe { _mm512_mask_storeu_ps(p, mask(remaining), v) }
    }
    #[inline(always)]
    unsafe fn lookup(self, profile: *const f32, bins: &[i32; 16]) -> [__m512; 4] {
        // SAFETY: k + 1 is in the row that starts at `profile` (the caller's promise), so the
        // four floats at 2k are its bins k and k + 1. The volatile read keeps the bins in
        // memory, as in AVX2.
        let pair = |lane: usize| unsafe {
            _mm_loadu_ps(profile.add(2 * std::ptr::read_volatile(&bins[lane]) as usize))
        };
        // Row j holds the pairs of lanes j, j + 4, j + 8 and j + 12; the in-lane transpose
        // puts the lanes in order.
        let row = |j: usize| unsafe {
            let r = _mm512_castps128_ps512(pair(j));
            let r = _mm512_insertf32x4::<1>(r, pair(j + 4));
            let r = _mm512_insertf32x4::<2>(r, pair(j + 8));
            _mm512_insertf32x4::<3>(r, pair(j + 12))
        };
        unsafe {
            let (r0, r1, r2, r3) = (row(0), row(1), row(2), row(3));
            let t0 = _mm512_unpacklo_ps(r0, r1);
            let t1 = _mm512_unpackhi_ps(r0, r1);
            let t2 = _mm512_unpacklo_ps(r2, r3);
            let t3 = _mm512_unpackhi_ps(r2, r3);
            [
                _mm512_shuffle_ps::<0x44>(t0, t2),
                _mm512_shuffle_ps::<0xEE>(t0, t2),
                _mm512_shuffle_ps::<0x44>(t1, t3),
                _mm512_shuffle_ps::<0xEE>(t1, t3),
            ]
        }
    }
}
