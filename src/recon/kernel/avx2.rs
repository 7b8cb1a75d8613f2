//! [`Simd`] in AVX2 and FMA: eight voxels per step; a tile's last `len % 8` voxels are left
//! to the scalar statement.
//!
//! The lookups are eight unaligned 16-byte loads, each of which brings a bin and its
//! successor, transposed in registers into (lo.re, lo.im, hi.re, hi.im). A `vgatherdps` per
//! component would need four gathers instead of eight loads, and loses on Zen.

use std::arch::x86_64::*;

use super::simd::Simd;
use super::{Group, Output, Tile, vector};

/// The AVX2 and FMA instruction set: made only where the CPU runs both.
#[derive(Clone, Copy)]
pub(super) struct Avx2(());

/// Whether this CPU runs the AVX2 kernel.
pub(super) fn available() -> bool {
    is_x86_feature_detected!("avx2") && is_x86_feature_detected!("fma")
}

/// Runs the kernel over the first `tile.len() / 8 * 8` voxels of `tile` and returns how many
/// it did: 0 when the CPU lacks AVX2 or FMA, or the profiles have fewer than two bins.
pub(super) fn kernel(g: &Group, tile: &mut Tile, output: Output) -> usize {
    if !available() {
        return 0;
    }
    let s = Avx2(());
    // SAFETY: the CPU supports AVX2 and FMA (checked above), which is all that `steps`
    // requires.
    unsafe {
        match output {
            Output::Store => steps::<false>(s, g, tile),
            Output::Add => steps::<true>(s, g, tile),
        }
    }
}

/// [`vector::steps`] compiled for AVX2 and FMA.
#[target_feature(enable = "avx2,fma")]
fn steps<const ADD: bool>(s: Avx2, g: &Group, tile: &mut Tile) -> usize {
    vector::steps::<Avx2, ADD>(s, g, tile)
}

// SAFETY (every `unsafe` block below): an `Avx2` exists only where the CPU runs AVX2 and FMA.
impl Simd for Avx2 {
    const LANES: usize = 8;
    type F = __m256;
    type I = __m256i;
    type Bins = [i32; 8];

    #[inline(always)]
    fn splat(self, v: f32) -> __m256 {
        unsafe { _mm256_set1_ps(v) }
    }
    #[inline(always)]
    fn splat_i(self, v: i32) -> __m256i {
        unsafe { _mm256_set1_epi32(v) }
    }
    #[inline(always)]
    fn add(self, a: __m256, b: __m256) -> __m256 {
        unsafe { _mm256_add_ps(a, b) }
    }
    #[inline(always)]
    fn sub(self, a: __m256, b: __m256) -> __m256 {
        unsafe { _mm256_sub_ps(a, b) }
    }
    #[inline(always)]
    fn mul(self, a: __m256, b: __m256) -> __m256 {
        unsafe { _mm256_mul_ps(a, b) }
    }
    #[inline(always)]
    fn mul_add(self, a: __m256, b: __m256, c: __m256) -> __m256 {
        unsafe { _mm256_fmadd_ps(a, b, c) }
    }
    #[inline(always)]
    fn mul_sub(self, a: __m256, b: __m256, c: __m256) -> __m256 {
        unsafe { _mm256_fmsub_ps(a, b, c) }
    }
    #[inline(always)]
    fn sqrt(self, a: __m256) -> __m256 {
        unsafe { _mm256_sqrt_ps(a) }
    }
    #[inline(always)]
    fn min(self, a: __m256, b: __m256) -> __m256 {
        unsafe { _mm256_min_ps(a, b) }
    }
    #[inline(always)]
    fn max(self, a: __m256, b: __m256) -> __m256 {
        unsafe { _mm256_max_ps(a, b) }
    }
    #[inline(always)]
    fn round(self, a: __m256) -> __m256 {
        unsafe { _mm256_round_ps::<{ _MM_FROUND_TO_NEAREST_INT | _MM_FROUND_NO_EXC }>(a) }
    }
    #[inline(always)]
    fn bins(self, pos: __m256, max_bin: __m256i) -> ([i32; 8], __m256) {
        let mut bins = [0i32; 8];
        unsafe {
            let k = _mm256_max_epi32(
                _mm256_min_epi32(_mm256_cvttps_epi32(pos), max_bin),
                _mm256_setzero_si256(),
            );
            // `bins` holds exactly one __m256i.
            _mm256_storeu_si256(bins.as_mut_ptr().cast(), k);
            (bins, _mm256_sub_ps(pos, _mm256_cvtepi32_ps(k)))
        }
    }

    #[inline(always)]
    fn covered(len: usize) -> usize {
        len / 8 * 8
    }
    #[inline(always)]
    unsafe fn load(self, p: *const f32, _remaining: usize) -> __m256 {
        // SAFETY: `covered` leaves at least 8 values at `p` (the caller's promise).
        unsafe { _mm256_loadu_ps(p) }
    }
    #[inline(always)]
    unsafe fn store(self, p: *mut f32, _remaining: usize, v: __m256) {
        // SAFETY: as for `load`.
        unsafe { _mm256_storeu_ps(p, v) }
    }
    #[inline(always)]
    unsafe fn lookup(self, profile: *const f32, bins: &[i32; 8]) -> [__m256; 4] {
        // The eight bins are read as scalars (a volatile read keeps them in memory): eight
        // scalar loads cost less than the lane extractions the compiler emits otherwise.
        // SAFETY: k + 1 is in the row that starts at `profile` (the caller's promise), so the
        // four floats at 2k are its bins k and k + 1.
        let pair = |lane: usize| unsafe {
            _mm_loadu_ps(profile.add(2 * std::ptr::read_volatile(&bins[lane]) as usize))
        };
        // Row j holds the pairs of lanes j and j + 4; the in-lane transpose puts the lanes in
        // order.
        let row = |j: usize| unsafe { _mm256_set_m128(pair(j + 4), pair(j)) };
        unsafe {
            let (r0, r1, r2, r3) = (row(0), row(1), row(2), row(3));
            let t0 = _mm256_unpacklo_ps(r0, r1);
            let t1 = _mm256_unpackhi_ps(r0, r1);
            let t2 = _mm256_unpacklo_ps(r2, r3);
            let t3 = _mm256_unpackhi_ps(r2, r3);
            [
                _mm256_shuffle_ps::<0x44>(t0, t2),
                _mm256_shuffle_ps::<0xEE>(t0, t2),
                _mm256_shuffle_ps::<0x44>(t1, t3),
                _mm256_shuffle_ps::<0xEE>(t1, t3),
            ]
        }
    }
}
