//! The radar's chirp profile.
//!
//! This module owns the meaning of a TI mmWave CLI configuration script (`.cfg`): it parses the
//! lines, applies the mmWave SDK's unit conversions (including their truncation to register codes),
//! checks the result against the IWR1443's limits and derives the frequency plan that every later
//! stage uses. It does not talk to a serial port; sending the script to a radar belongs to the
//! device layer.

mod profile;

pub use profile::{ProfileError, RadarProfile, RxLayout, iwr1443boost_rx_offset_m};
