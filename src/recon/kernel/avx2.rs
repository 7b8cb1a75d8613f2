//! The kernel in AVX2 and FMA: eight voxels per step, with no intermediate arrays.
//!
//! Per step: both distances, the fractional bin and the carrier's (cos, sin) in registers;
//! then the eight lookups as eight unaligned 16-byte loads, each of which brings a bin and its
//! successor, transposed in registers into (lo.re, lo.im, hi.re, hi.im); then the
//! interpolation, the rotation, and the store or the sum. A `vgatherdps` per component would
//! need four gathers instead of eight loads, and loses on Zen.

use std::arch::x86_64::*;
use std::f32::consts::TAU;

use super::{Group, MAX_GROUP, Output, Tile};

/// Lanes per step.
const LANES: usize = 8;

/// Whether this CPU runs the AVX2 kernel.
pub(super) fn available() -> bool {
    is_x86_feature_detected!("avx2") && is_x86_feature_detected!("fma")
}

/// Runs the kernel over the first `tile.len() / 8 * 8` voxels of `tile` and returns how many
/// it did: 0 when the CPU lacks AVX2 or FMA, or the profiles have fewer than two bins.
pub(super) fn kernel(g: &Group, tile: &mut Tile, output: Output) -> usize {
    if g.bins < 2 || !available() {
        return 0;
    }
    let n = tile.len() / LANES * LANES;
    // Every lookup reads bins k and k + 1 of a member's row with k ≤ max_bin = bins − 2, so
    // they stay in the row whatever the geometry says.
    let max_bin = g.max_bin();
    // SAFETY: the CPU supports AVX2 and FMA (checked above), which is all that the
    // `target_feature` functions require.
    unsafe {
        match output {
            Output::Store => steps::<false>(g, max_bin, tile, n),
            Output::Add => steps::<true>(g, max_bin, tile, n),
        }
    }
    n
}

/// The group's constants, one per lane.
#[derive(Clone, Copy)]
struct Lanes {
    bins_per_m: __m256,
    first: __m256,
    last: __m256,
    turns_per_m: __m256,
    max_bin: __m256i,
}

/// The steps over voxels `0..n` (`n` a multiple of 8, at most `tile.len()`): the group's
/// responses summed, then stored, or with `ADD` added to the sums. The TX leg and the sums
/// are computed, loaded and stored once per step for the whole group.
#[target_feature(enable = "avx2,fma")]
fn steps<const ADD: bool>(g: &Group, max_bin: u32, tile: &mut Tile, n: usize) {
    let (x, y, z) = (&tile.x[..n], &tile.y[..n], &tile.z[..n]);
    let (re, im) = (&mut tile.re[..n], &mut tile.im[..n]);
    let members = g.members().min(MAX_GROUP);
    let splat = |v: f32| _mm256_set1_ps(v);
    // Fixed arrays, not vectors: a tile of a few voxels must not pay for an allocation.
    let mut rx = [[_mm256_setzero_ps(); 3]; MAX_GROUP];
    let mut rows = [std::ptr::null::<f32>(); MAX_GROUP];
    for m in 0..members {
        rx[m] = g.rx[m].map(splat);
        rows[m] = g.row(m).as_ptr().cast();
    }
    let tx = g.tx.map(splat);
    let offset_m = splat(g.offset_m);
    let lanes = Lanes {
        bins_per_m: splat(g.bins_per_m),
        first: splat(g.first),
        last: splat(g.last),
        turns_per_m: splat(g.turns_per_m),
        max_bin: _mm256_set1_epi32(max_bin as i32),
    };
    let zero = _mm256_setzero_ps();
    let mut bins = [0i32; LANES];
    for i in (0..n).step_by(LANES) {
        // SAFETY: i + 8 ≤ n, and every slice here holds n elements.
        let v = unsafe {
            [
                _mm256_loadu_ps(x.as_ptr().add(i)),
                _mm256_loadu_ps(y.as_ptr().add(i)),
                _mm256_loadu_ps(z.as_ptr().add(i)),
            ]
        };
        let tx_leg = _mm256_add_ps(distance(&tx, &v), offset_m);
        let (mut sum_re, mut sum_im) = if ADD {
            // SAFETY: as above.
            unsafe {
                (
                    _mm256_loadu_ps(re.as_ptr().add(i)),
                    _mm256_loadu_ps(im.as_ptr().add(i)),
                )
            }
        } else {
            (zero, zero)
        };
        for m in 0..members {
            // SAFETY: rows[m] starts member m's row of g.bins = max_bin + 2 values, and this
            // function requires AVX2 and FMA.
            let (a_re, a_im) = unsafe { response(&lanes, &v, tx_leg, &rx[m], rows[m], &mut bins) };
            sum_re = _mm256_add_ps(sum_re, a_re);
            sum_im = _mm256_add_ps(sum_im, a_im);
        }
        // SAFETY: i + 8 ≤ n = re.len() = im.len().
        unsafe {
            _mm256_storeu_ps(re.as_mut_ptr().add(i), sum_re);
            _mm256_storeu_ps(im.as_mut_ptr().add(i), sum_im);
        }
    }
}

/// One member's I(v) for eight voxels `v`, given the TX leg plus the range offset.
///
/// # Safety
/// The CPU supports AVX2 and FMA; `profile` points at a row of at least `max_bin + 2`
/// complex values.
#[inline]
#[target_feature(enable = "avx2,fma")]
unsafe fn response(
    lanes: &Lanes,
    v: &[__m256; 3],
    tx_leg: __m256,
    rx: &[__m256; 3],
    profile: *const f32,
    bins: &mut [i32; LANES],
) -> (__m256, __m256) {
    let round_trip = _mm256_add_ps(tx_leg, distance(rx, v));
    // max(·, 0) first: it also turns a NaN position into bin 0.
    let pos = _mm256_min_ps(
        _mm256_max_ps(
            _mm256_sub_ps(_mm256_mul_ps(round_trip, lanes.bins_per_m), lanes.first),
            _mm256_setzero_ps(),
        ),
        lanes.last,
    );
    // Bounded by integer operations, so that the loads below do not rest on the float
    // arithmetic: k in [0, max_bin].
    let k = _mm256_max_epi32(
        _mm256_min_epi32(_mm256_cvttps_epi32(pos), lanes.max_bin),
        _mm256_setzero_si256(),
    );
    let frac = _mm256_sub_ps(pos, _mm256_cvtepi32_ps(k));
    // The eight bins go through memory (a volatile read keeps them there): eight scalar loads
    // cost less than the lane extractions the compiler emits otherwise.
    // SAFETY: `bins` holds exactly one __m256i.
    unsafe { _mm256_storeu_si256(bins.as_mut_ptr().cast(), k) };
    // SAFETY: 0 ≤ k ≤ max_bin and the row holds max_bin + 2 values from `profile` (the
    // caller's promise), so the four floats at 2k are its bins k and k + 1.
    let pair = |lane: usize| unsafe {
        _mm_loadu_ps(profile.add(2 * std::ptr::read_volatile(&bins[lane]) as usize))
    };
    let [lo_re, lo_im, hi_re, hi_im] = transpose([
        _mm256_set_m128(pair(4), pair(0)),
        _mm256_set_m128(pair(5), pair(1)),
        _mm256_set_m128(pair(6), pair(2)),
        _mm256_set_m128(pair(7), pair(3)),
    ]);
    let x_re = _mm256_fmadd_ps(_mm256_sub_ps(hi_re, lo_re), frac, lo_re);
    let x_im = _mm256_fmadd_ps(_mm256_sub_ps(hi_im, lo_im), frac, lo_im);
    let (s, c) = sin_cos_turns(_mm256_mul_ps(round_trip, lanes.turns_per_m));
    // x·exp(−j·carrier) = x·(cos − j·sin).
    (
        _mm256_fmadd_ps(x_re, c, _mm256_mul_ps(x_im, s)),
        _mm256_fmsub_ps(x_im, c, _mm256_mul_ps(x_re, s)),
    )
}

/// |p − v| for eight voxels `v`, summed as the scalar kernel sums (no contraction), so that
/// both paths see the same round trip.
#[inline]
#[target_feature(enable = "avx2,fma")]
fn distance(p: &[__m256; 3], v: &[__m256; 3]) -> __m256 {
    let d = [0, 1, 2].map(|q| _mm256_sub_ps(p[q], v[q]));
    let squares = _mm256_add_ps(
        _mm256_add_ps(_mm256_mul_ps(d[0], d[0]), _mm256_mul_ps(d[1], d[1])),
        _mm256_mul_ps(d[2], d[2]),
    );
    _mm256_sqrt_ps(squares)
}

/// Rows r_j = [p_j | p_{j+4}] of (re_k, im_k, re_{k+1}, im_{k+1}) pairs, for lanes 0..8, into
/// the four component vectors, lanes in order.
#[inline]
#[target_feature(enable = "avx2,fma")]
fn transpose(r: [__m256; 4]) -> [__m256; 4] {
    let t0 = _mm256_unpacklo_ps(r[0], r[1]);
    let t1 = _mm256_unpackhi_ps(r[0], r[1]);
    let t2 = _mm256_unpacklo_ps(r[2], r[3]);
    let t3 = _mm256_unpackhi_ps(r[2], r[3]);
    [
        _mm256_shuffle_ps::<0x44>(t0, t2),
        _mm256_shuffle_ps::<0xEE>(t0, t2),
        _mm256_shuffle_ps::<0x44>(t1, t3),
        _mm256_shuffle_ps::<0xEE>(t1, t3),
    ]
}

/// [`super::sin_cos_turns`] for eight lanes: reduction to the nearest quarter turn, the same
/// polynomials, and the quadrant by blends and sign flips.
#[inline]
#[target_feature(enable = "avx2,fma")]
fn sin_cos_turns(turns: __m256) -> (__m256, __m256) {
    let splat = |v: f32| _mm256_set1_ps(v);
    let quarter = _mm256_round_ps::<{ _MM_FROUND_TO_NEAREST_INT | _MM_FROUND_NO_EXC }>(
        _mm256_mul_ps(turns, splat(4.0)),
    );
    let y = _mm256_mul_ps(splat(TAU), _mm256_fnmadd_ps(quarter, splat(0.25), turns));
    let y2 = _mm256_mul_ps(y, y);
    let poly = |coefficients: &[f32]| {
        coefficients
            .iter()
            .rev()
            .skip(1)
            .fold(splat(coefficients[coefficients.len() - 1]), |acc, &k| {
                _mm256_fmadd_ps(acc, y2, splat(k))
            })
    };
    let s = _mm256_mul_ps(y, poly(&[1.0, -1.0 / 6.0, 1.0 / 120.0, -1.0 / 5040.0]));
    let c = poly(&[1.0, -0.5, 1.0 / 24.0, -1.0 / 720.0, 1.0 / 40320.0]);
    // Quadrant q: (sin, cos) = (s, c), (c, −s), (−s, −c), (−c, s).
    let q = _mm256_cvtps_epi32(quarter);
    let one = _mm256_set1_epi32(1);
    let swap = _mm256_castsi256_ps(_mm256_cmpeq_epi32(_mm256_and_si256(q, one), one));
    let negate = _mm256_castsi256_ps(_mm256_slli_epi32::<30>(_mm256_and_si256(
        q,
        _mm256_set1_epi32(2),
    )));
    let minus_s = _mm256_xor_ps(s, splat(-0.0));
    let sin = _mm256_blendv_ps(s, c, swap);
    let cos = _mm256_blendv_ps(c, minus_s, swap);
    (_mm256_xor_ps(sin, negate), _mm256_xor_ps(cos, negate))
}
