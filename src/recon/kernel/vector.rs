//! The vectorised kernel, written once over [`Simd`]: `LANES` voxels per step, in two phases
//! per step.
//!
//! Per step, the TX leg once for the group: its share of the bin position, and its carrier
//! phase less whole turns. Phase 1, arithmetic only, for every member: the RX leg, the
//! fractional bin and the carrier's (sin, cos); the bins go to a small array on the stack.
//! Phase 2, for every member: the profile lookups ([`Simd::lookup`]: one 16-byte load per
//! lane, a bin and its successor, transposed in registers), then the interpolation, the
//! rotation, and the store or the sum.
//!
//! Why two phases: fused, the hottest instructions in a profile were each member's first
//! index loads, waiting on the store of its own bins just before, and that chain held the
//! out-of-order window. Split, the lookups read bins stored a whole phase earlier.

use super::simd::Simd;
use super::{Group, MAX_GROUP, Tile};
use crate::recon::image::{HALF_ANGLE_COS, HALF_ANGLE_SIN};

/// Runs the kernel over the voxels of `tile` that [`Simd::covered`] gives and returns how
/// many: the group's responses summed, then stored, or with `ADD` added to the sums. The TX
/// leg and the sums are computed, loaded and stored once per step for the whole group.
///
/// Always inlined: the caller is the instruction set's `#[target_feature]` function.
#[inline(always)]
pub(super) fn steps<S: Simd, const ADD: bool>(s: S, g: &Group, tile: &mut Tile) -> usize {
    if g.bins < 2 {
        return 0;
    }
    let n = tile.len();
    let covered = S::covered(n);
    let (x, y, z) = (&tile.x[..n], &tile.y[..n], &tile.z[..n]);
    let (re, im) = (&mut tile.re[..n], &mut tile.im[..n]);
    let members = g.members().min(MAX_GROUP);
    // Fixed arrays, not vectors: a tile of a few voxels must not pay for an allocation.
    let mut rx = [[s.splat(0.0); 3]; MAX_GROUP];
    let mut rows = [std::ptr::null::<f32>(); MAX_GROUP];
    for m in 0..members {
        rx[m] = g.rx[m].map(|c| s.splat(c));
        rows[m] = g.row(m).as_ptr().cast();
    }
    let tx_at = g.tx.map(|c| s.splat(c));
    let offset_m = s.splat(g.offset_m);
    // Every lookup reads bins k and k + 1 of a member's row with k ≤ max_bin = bins − 2, so
    // they stay in the row whatever the geometry says.
    let lanes = Lanes {
        bins_per_m: s.splat(g.bins_per_m),
        first: s.splat(g.first),
        last: s.splat(g.last),
        turns_per_m: s.splat(g.turns_per_m),
        max_bin: s.splat_i(g.max_bin() as i32),
    };
    // One step's geometry for every member, kept in memory between the two phases.
    let mut at = [Geometry::zero(s); MAX_GROUP];
    for i in (0..covered).step_by(S::LANES) {
        let remaining = n - i;
        // SAFETY: every slice here holds n elements, and i and `remaining` come from
        // `S::covered(n)`, which is what `load` and `store` ask.
        let load = |values: &[f32]| unsafe { s.load(values.as_ptr().add(i), remaining) };
        let v = [load(x), load(y), load(z)];
        let tx = TxLeg::new(s, &lanes, s.add(distance(s, &tx_at, &v), offset_m));
        // Phase 1, arithmetic only: the members' chains are independent, so they overlap.
        for (geometry, rx) in at.iter_mut().zip(&rx).take(members) {
            *geometry = Geometry::new(s, &lanes, &v, &tx, rx);
        }
        let (mut sum_re, mut sum_im) = if ADD {
            (load(re), load(im))
        } else {
            (s.splat(0.0), s.splat(0.0))
        };
        // Phase 2: the lookups, the interpolation and the rotation. The bins they read were
        // stored a whole phase earlier.
        for (geometry, &row) in at.iter().zip(&rows).take(members) {
            // SAFETY: `row` starts a member's row of g.bins = max_bin + 2 values, and every
            // bin is at most max_bin.
            let (a_re, a_im) = unsafe { geometry.response(s, row) };
            sum_re = s.add(sum_re, a_re);
            sum_im = s.add(sum_im, a_im);
        }
        // SAFETY: as for the loads.
        unsafe {
            s.store(re.as_mut_ptr().add(i), remaining, sum_re);
            s.store(im.as_mut_ptr().add(i), remaining, sum_im);
        }
    }
    covered
}

/// The group's constants, one per lane.
#[derive(Clone, Copy)]
struct Lanes<S: Simd> {
    bins_per_m: S::F,
    first: S::F,
    last: S::F,
    turns_per_m: S::F,
    max_bin: S::I,
}

/// The TX leg's share of every member's bin position and carrier phase, computed once per
/// step.
struct TxLeg<S: Simd> {
    /// (TX leg + range offset)·bins_per_m − first.
    pos: S::F,
    /// (TX leg + range offset)·turns_per_m less its nearest whole turn: the carrier does not
    /// see whole turns, and the smaller sum keeps more of f32's bits for the RX leg.
    turns: S::F,
}

impl<S: Simd> TxLeg<S> {
    #[inline(always)]
    fn new(s: S, lanes: &Lanes<S>, leg_m: S::F) -> Self {
        let turns = s.mul(leg_m, lanes.turns_per_m);
        Self {
            pos: s.mul_sub(leg_m, lanes.bins_per_m, lanes.first),
            turns: s.sub(turns, s.round(turns)),
        }
    }
}

/// One member's geometry for a step: the lower bins of the interpolation pairs, the
/// fractions, and the carrier's (sin, cos).
#[derive(Clone, Copy)]
struct Geometry<S: Simd> {
    bins: S::Bins,
    frac: S::F,
    sin: S::F,
    cos: S::F,
}

impl<S: Simd> Geometry<S> {
    #[inline(always)]
    fn zero(s: S) -> Self {
        let zero = s.splat(0.0);
        Self {
            bins: S::Bins::default(),
            frac: zero,
            sin: zero,
            cos: zero,
        }
    }

    /// The geometry of the member at `rx`, given the step's TX leg.
    #[inline(always)]
    fn new(s: S, lanes: &Lanes<S>, v: &[S::F; 3], tx: &TxLeg<S>, rx: &[S::F; 3]) -> Self {
        let rx_leg = distance(s, rx, v);
        // max(·, 0) first: it also turns a NaN position into bin 0.
        let pos = s.min(
            s.max(s.mul_add(rx_leg, lanes.bins_per_m, tx.pos), s.splat(0.0)),
            lanes.last,
        );
        let (bins, frac) = s.bins(pos, lanes.max_bin);
        let (sin, cos) = sin_cos_turns(s, s.mul_add(rx_leg, lanes.turns_per_m, tx.turns));
        Self {
            bins,
            frac,
            sin,
            cos,
        }
    }

    /// I(v) for the step's voxels from the member's profile row.
    ///
    /// # Safety
    /// `profile` points at a row of at least `max_bin + 2` complex values, with `max_bin` the
    /// bound [`Geometry::new`] was given.
    #[inline(always)]
    unsafe fn response(&self, s: S, profile: *const f32) -> (S::F, S::F) {
        // SAFETY: the caller's promise, and every bin is at most max_bin.
        let [lo_re, lo_im, hi_re, hi_im] = unsafe { s.lookup(profile, &self.bins) };
        let x_re = s.mul_add(s.sub(hi_re, lo_re), self.frac, lo_re);
        let x_im = s.mul_add(s.sub(hi_im, lo_im), self.frac, lo_im);
        let (sin, cos) = (self.sin, self.cos);
        // x·exp(−j·carrier) = x·(cos − j·sin).
        (
            s.mul_add(x_re, cos, s.mul(x_im, sin)),
            s.mul_sub(x_im, cos, s.mul(x_re, sin)),
        )
    }
}

/// |p − v| for a step's voxels `v`.
#[inline(always)]
fn distance<S: Simd>(s: S, p: &[S::F; 3], v: &[S::F; 3]) -> S::F {
    let d = [0, 1, 2].map(|q| s.sub(p[q], v[q]));
    let squares = s.mul_add(d[2], d[2], s.mul_add(d[1], d[1], s.mul(d[0], d[0])));
    s.sqrt(squares)
}

/// [`crate::recon::image::sin_cos_turns`] a step at a time: the same reduction to the nearest
/// whole turn, the same half-angle polynomials, the same double-angle formulas.
#[inline(always)]
fn sin_cos_turns<S: Simd>(s: S, turns: S::F) -> (S::F, S::F) {
    let u = s.sub(turns, s.round(turns));
    let u2 = s.mul(u, u);
    let horner = |coefficients: &[f32]| {
        coefficients
            .iter()
            .rev()
            .skip(1)
            .fold(s.splat(coefficients[coefficients.len() - 1]), |acc, &k| {
                s.mul_add(acc, u2, s.splat(k))
            })
    };
    let sin_half = s.mul(u, horner(&HALF_ANGLE_SIN));
    let cos_half = horner(&HALF_ANGLE_COS);
    (
        s.mul(sin_half, cos_half),
        s.mul_sub(cos_half, cos_half, s.splat(1.0)),
    )
}
