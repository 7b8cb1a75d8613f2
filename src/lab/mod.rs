//! The lab: a config file that names the devices, the wiring of the simulated devices, and the
//! acquisition sequences that drive more than one device.
//!
//! - [`config`]: `lab.toml`, typed and validated before any device is touched.
//! - [`simchain`]: the simulated radar chain (the IWR1443 CLI simulator on a PTY, the DCA1000
//!   simulator on loopback UDP, wired so that `sensorStart` starts the stream).
//! - [`raw`]: the radar-only capture of research/protocols.md B4 (`mmnormd capture raw`).
//!
//! Each device's protocol lives in its own module ([`crate::radar`], [`crate::dca1000`]); this
//! module only sequences them.

pub mod config;
pub mod devices;
pub mod job;
pub mod raw;
pub mod scan;
pub mod scene_frames;
pub mod simchain;
pub mod simlab;

pub use config::{LabConfig, LabConfigError, SimConfig};
