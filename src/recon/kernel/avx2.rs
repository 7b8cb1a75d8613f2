//! The kernel in AVX2 and FMA: eight voxels per step, in two phases per step.
//!
//! Per step, the TX leg once for the group: its share of the bin position, and its carrier
//! phase less whole turns. Phase 1, arithmetic only, for every member: the RX leg, the
//! fractional bin and the carrier's (sin, cos); the bins go to a small array on the stack.
//! Phase 2, for every member: the eight lookups as eight unaligned 16-byte loads, each of
//! which brings a bin and its successor, transposed in registers into (lo.re, lo.im, hi.re,
//! hi.im); then the interpolation, the rotation, and the store or the sum.
//!
//! Why two phases: fused, the hottest instructions in a profile were each member's first
//! index loads, waiting on the store of its own bins just before, and that chain held the
//! out-of-order window. Split, the lookups read bins stored a whole phase earlier.
//!
//! A `vgatherdps` per component would need four gathers instead of eight loads, and loses on
//! Zen.

use std::arch::x86_64::*;

use super::{Group, MAX_GROUP, Output, Tile};
use crate::recon::image::{HALF_ANGLE_COS, HALF_ANGLE_SIN};

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

/// The TX leg's share of every member's bin position and carrier phase, computed once per
/// step.
struct TxLeg {
    /// (TX leg + range offset)·bins_per_m − first.
    pos: __m256,
    /// (TX leg + range offset)·turns_per_m less its nearest whole turn: the carrier does not
    /// see whole turns, and the smaller sum keeps more of f32's bits for the RX leg.
    turns: __m256,
}

impl TxLeg {
    #[inline]
    #[target_feature(enable = "avx2,fma")]
    fn new(lanes: &Lanes, leg_m: __m256) -> Self {
        let turns = _mm256_mul_ps(leg_m, lanes.turns_per_m);
        let whole = _mm256_round_ps::<{ _MM_FROUND_TO_NEAREST_INT | _MM_FROUND_NO_EXC }>(turns);
        Self {
            pos: _mm256_fmsub_ps(leg_m, lanes.bins_per_m, lanes.first),
            turns: _mm256_sub_ps(turns, whole),
        }
    }
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
    let tx_at = g.tx.map(splat);
    let offset_m = splat(g.offset_m);
    let lanes = Lanes {
        bins_per_m: splat(g.bins_per_m),
        first: splat(g.first),
        last: splat(g.last),
        turns_per_m: splat(g.turns_per_m),
        max_bin: _mm256_set1_epi32(max_bin as i32),
    };
    let zero = _mm256_setzero_ps();
    // One step's geometry for every member, kept in memory between the two phases.
    let mut at = [Geometry::default(); MAX_GROUP];
    for i in (0..n).step_by(LANES) {
        // SAFETY: i + 8 ≤ n, and every slice here holds n elements.
        let v = unsafe {
            [
                _mm256_loadu_ps(x.as_ptr().add(i)),
                _mm256_loadu_ps(y.as_ptr().add(i)),
                _mm256_loadu_ps(z.as_ptr().add(i)),
            ]
        };
        let tx = TxLeg::new(&lanes, _mm256_add_ps(distance(&tx_at, &v), offset_m));
        // Phase 1, arithmetic only: the members' chains are independent, so they overlap.
        for (geometry, rx) in at.iter_mut().zip(&rx).take(members) {
            *geometry = Geometry::new(&lanes, &v, &tx, rx);
        }
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
        // Phase 2: the lookups, the interpolation and the rotation. The bins they read were
        // stored a whole phase earlier.
        for (geometry, &row) in at.iter().zip(&rows).take(members) {
            // SAFETY: `row` starts a member's row of g.bins = max_bin + 2 values, and this
            // function requires AVX2 and FMA.
            let (a_re, a_im) = unsafe { geometry.response(row) };
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

/// One member's geometry for eight voxels: the lower bins of the interpolation pairs, the
/// fractions, and the carrier's (sin, cos).
#[derive(Clone, Copy)]
struct Geometry {
    bins: [i32; LANES],
    frac: __m256,
    sin: __m256,
    cos: __m256,
}

impl Default for Geometry {
    fn default() -> Self {
        // SAFETY: all-zero bits are a valid __m256.
        let zero = unsafe { std::mem::zeroed::<__m256>() };
        Self {
            bins: [0; LANES],
            frac: zero,
            sin: zero,
            cos: zero,
        }
    }
}

impl Geometry {
    /// The geometry of the member at `rx`, given the step's TX leg.
    #[inline]
    #[target_feature(enable = "avx2,fma")]
    fn new(lanes: &Lanes, v: &[__m256; 3], tx: &TxLeg, rx: &[__m256; 3]) -> Self {
        let rx_leg = distance(rx, v);
        // max(·, 0) first: it also turns a NaN position into bin 0.
        let pos = _mm256_min_ps(
            _mm256_max_ps(
                _mm256_fmadd_ps(rx_leg, lanes.bins_per_m, tx.pos),
                _mm256_setzero_ps(),
            ),
            lanes.last,
        );
        // Bounded by integer operations, so that the lookups do not rest on the float
        // arithmetic: k in [0, max_bin].
        let k = _mm256_max_epi32(
            _mm256_min_epi32(_mm256_cvttps_epi32(pos), lanes.max_bin),
            _mm256_setzero_si256(),
        );
        let mut bins = [0i32; LANES];
        // SAFETY: `bins` holds exactly one __m256i.
        unsafe { _mm256_storeu_si256(bins.as_mut_ptr().cast(), k) };
        let (sin, cos) = sin_cos_turns(_mm256_fmadd_ps(rx_leg, lanes.turns_per_m, tx.turns));
        Self {
            bins,
            frac: _mm256_sub_ps(pos, _mm256_cvtepi32_ps(k)),
            sin,
            cos,
        }
    }

    /// I(v) for the eight voxels from the member's profile row.
    ///
    /// # Safety
    /// The CPU supports AVX2 and FMA; `profile` points at a row of at least `max_bin + 2`
    /// complex values, with `max_bin` the bound [`Geometry::new`] was given.
    #[inline]
    #[target_feature(enable = "avx2,fma")]
    unsafe fn response(&self, profile: *const f32) -> (__m256, __m256) {
        // The eight bins are read as scalars (a volatile read keeps them in memory): eight
        // scalar loads cost less than the lane extractions the compiler emits otherwise.
        // SAFETY: 0 ≤ k ≤ max_bin and the row holds max_bin + 2 values from `profile` (the
        // caller's promise), so the four floats at 2k are its bins k and k + 1.
        let pair = |lane: usize| unsafe {
            _mm_loadu_ps(profile.add(2 * std::ptr::read_volatile(&self.bins[lane]) as usize))
        };
        let [lo_re, lo_im, hi_re, hi_im] = transpose([
            _mm256_set_m128(pair(4), pair(0)),
            _mm256_set_m128(pair(5), pair(1)),
            _mm256_set_m128(pair(6), pair(2)),
            _mm256_set_m128(pair(7), pair(3)),
        ]);
        let x_re = _mm256_fmadd_ps(_mm256_sub_ps(hi_re, lo_re), self.frac, lo_re);
        let x_im = _mm256_fmadd_ps(_mm256_sub_ps(hi_im, lo_im), self.frac, lo_im);
        let (s, c) = (self.sin, self.cos);
        // x·exp(−j·carrier) = x·(cos − j·sin).
        (
            _mm256_fmadd_ps(x_re, c, _mm256_mul_ps(x_im, s)),
            _mm256_fmsub_ps(x_im, c, _mm256_mul_ps(x_re, s)),
        )
    }
}

/// |p − v| for eight voxels `v`.
#[inline]
#[target_feature(enable = "avx2,fma")]
fn distance(p: &[__m256; 3], v: &[__m256; 3]) -> __m256 {
    let d = [0, 1, 2].map(|q| _mm256_sub_ps(p[q], v[q]));
    let squares = _mm256_fmadd_ps(
        d[2],
        d[2],
        _mm256_fmadd_ps(d[1], d[1], _mm256_mul_ps(d[0], d[0])),
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

/// [`super::sin_cos_turns`] for eight lanes: the same reduction to the nearest whole turn,
/// the same half-angle polynomials, the same double-angle formulas.
#[inline]
#[target_feature(enable = "avx2,fma")]
fn sin_cos_turns(turns: __m256) -> (__m256, __m256) {
    let whole = _mm256_round_ps::<{ _MM_FROUND_TO_NEAREST_INT | _MM_FROUND_NO_EXC }>(turns);
    let u = _mm256_sub_ps(turns, whole);
    let u2 = _mm256_mul_ps(u, u);
    let horner = |coefficients: &[f32]| {
        coefficients.iter().rev().skip(1).fold(
            _mm256_set1_ps(coefficients[coefficients.len() - 1]),
            |acc, &k| _mm256_fmadd_ps(acc, u2, _mm256_set1_ps(k)),
        )
    };
    let s = _mm256_mul_ps(u, horner(&HALF_ANGLE_SIN));
    let c = horner(&HALF_ANGLE_COS);
    (
        _mm256_mul_ps(s, c),
        _mm256_fmsub_ps(c, c, _mm256_set1_ps(1.0)),
    )
}
