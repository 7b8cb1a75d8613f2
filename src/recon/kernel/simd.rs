//! The vector operations the kernel is written in (`vector`), one implementation per
//! instruction set: `avx2::Avx2` (eight lanes) and `avx512::Avx512` (sixteen).
//!
//! An implementation is a zero-sized token that exists only where the CPU runs its
//! instructions, so its operations are safe to call. Every operation is `#[inline(always)]`:
//! the kernel is generic over the token and is compiled, inlined whole, inside one
//! `#[target_feature]` function per instruction set, where the intrinsics inline too.

/// An instruction set's f32 and i32 vectors and the operations the kernel needs on them.
pub(super) trait Simd: Copy {
    /// Voxels per step.
    const LANES: usize;
    /// `LANES` f32 values.
    type F: Copy;
    /// `LANES` i32 values.
    type I: Copy;
    /// `LANES` i32 values in memory, where the lookups read them one at a time.
    type Bins: Copy + Default;

    fn splat(self, v: f32) -> Self::F;
    fn splat_i(self, v: i32) -> Self::I;
    fn add(self, a: Self::F, b: Self::F) -> Self::F;
    fn sub(self, a: Self::F, b: Self::F) -> Self::F;
    fn mul(self, a: Self::F, b: Self::F) -> Self::F;
    /// a·b + c, rounded once.
    fn mul_add(self, a: Self::F, b: Self::F, c: Self::F) -> Self::F;
    /// a·b − c, rounded once.
    fn mul_sub(self, a: Self::F, b: Self::F, c: Self::F) -> Self::F;
    fn sqrt(self, a: Self::F) -> Self::F;
    /// The lane-wise minimum; `b` where either is NaN.
    fn min(self, a: Self::F, b: Self::F) -> Self::F;
    /// The lane-wise maximum; `b` where either is NaN.
    fn max(self, a: Self::F, b: Self::F) -> Self::F;
    /// To the nearest integer, ties to even.
    fn round(self, a: Self::F) -> Self::F;
    /// `pos` truncated to i32 and clamped to [0, `max_bin`] by integer operations, as the
    /// bins in memory, and `pos` less that bin.
    fn bins(self, pos: Self::F, max_bin: Self::I) -> (Self::Bins, Self::F);

    /// How many of `len` voxels the steps cover: every one where the last step can be
    /// masked, otherwise the whole steps.
    fn covered(len: usize) -> usize;
    /// The `LANES` values from `p`, or, where `remaining` < `LANES`, the first `remaining`
    /// and zeros.
    ///
    /// # Safety
    /// `p` points at `min(remaining, LANES)` readable f32; `remaining` ≥ `LANES` unless the
    /// position came from [`Simd::covered`] of an implementation that masks.
    unsafe fn load(self, p: *const f32, remaining: usize) -> Self::F;
    /// Stores the first `min(remaining, LANES)` lanes at `p`.
    ///
    /// # Safety
    /// As for [`Simd::load`], for writing.
    unsafe fn store(self, p: *mut f32, remaining: usize, v: Self::F);
    /// For every lane, complex bins k and k + 1 of the row at `profile` (k from `bins`), as
    /// (re_k, im_k, re_{k+1}, im_{k+1}).
    ///
    /// # Safety
    /// Every bin k satisfies k + 1 < the row's length, and the row starts at `profile`.
    unsafe fn lookup(self, profile: *const f32, bins: &Self::Bins) -> [Self::F; 4];
}
