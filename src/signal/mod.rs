//! FMCW signal synthesis and seeded randomness shared by every forward model.
//!
//! [`ToneAccumulator`] adds reflections `a·exp(+j·2π·f_t·(d + offset)/c)` to a chirp, the capture
//! convention of [`crate::capture`]. [`Rng`] is the project's seeded generator: its output is fixed
//! by this code, not by a dependency's version, so a seed means the same files forever.

mod rng;
mod tones;

pub use rng::Rng;
pub use tones::ToneAccumulator;
