//! The IWR1443 radar: its chirp profile, its UART command line, and a simulator of that line.
//!
//! - `profile` ([`RadarProfile`]): the meaning of a TI mmWave CLI configuration script (`.cfg`): it parses the
//!   lines, applies the mmWave SDK's unit conversions (including their truncation to register
//!   codes), checks the result against the IWR1443's limits and derives the frequency plan that
//!   every later stage uses.
//! - [`cli`]: the sans-IO CLI session (reply parsing, resync, retries, timeouts).
//! - [`control`]: the [`control::RadarControl`] trait and its implementation over a serial port.
//! - [`sim`]: the CLI simulator on a PTY, with seeded faults.
//!
//! Raw ADC samples do not pass through here: they leave the radar over LVDS to the DCA1000
//! ([`crate::dca1000`]).

pub mod cli;
pub mod control;
mod profile;
pub mod sim;

pub use control::{CliRadar, RadarConfig, RadarControl};
pub use profile::{ProfileError, RadarProfile, RxLayout, iwr1443boost_rx_offset_m};
