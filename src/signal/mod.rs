//! FMCW signal synthesis and seeded randomness shared by every forward model.
//!
//! [`ToneAccumulator`] adds reflections `a·exp(+j·2π·f_t·(d + offset)/c)` to a chirp, the capture
//! convention of [`crate::capture`]. [`Rng`] is the project's seeded generator: its output is fixed
//! by this code, not by a dependency's version, so a seed means the same files forever.

pub mod czt;
mod rng;
mod spread;
mod tones;

pub use czt::{Czt, CztAxes, PaddedDftWindows, fft_friendly};
pub use rng::Rng;
pub use tones::{GRID_AFTER, ToneAccumulator};

/// The periodic Hann window of length `t`, `½ − ½·cos(2πk/t)`: range sidelobes at −31 dB instead
/// of a rectangular window's −13 dB, coherent gain ½.
pub fn hann_window(t: usize) -> Vec<f32> {
    (0..t)
        .map(|k| (0.5 - 0.5 * (std::f64::consts::TAU * k as f64 / t as f64).cos()) as f32)
        .collect()
}
