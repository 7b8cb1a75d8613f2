//! The lab: a config file that names the devices, the wiring of the simulated devices, and the
//! acquisition sequences that drive more than one device.
//!
//! - [`config`]: `lab.toml`, typed and validated before any device is touched.
//! - [`devices`]: the devices over their real transports, configured.
//! - [`scan`]: one scan's rows (record, `sensorStart`, `movel`, stop, align, rescan) and the
//!   capture they make.
//! - [`job`]: a scan job from request to result (recording, capture directory, reconstruction,
//!   score, events), and replay.
//! - [`simlab`]: the simulated lab in-process; [`scene_frames`]: its radar, rendering each frame
//!   from where the simulated arm carries it; [`simchain`]: the simulated radar chain alone.
//! - [`calibrate`]: `align.sync_offset_s` and `tcp_from_radar` from a scan of a point reflector.
//! - [`raw`]: the radar-only capture of docs/protocols.md B4 (`mmnormd capture raw`);
//!   [`decode`]: its `adc_data.bin` as samples and a range profile (`mmnormd capture decode`).
//!
//! Each device's protocol lives in its own module ([`crate::radar`], [`crate::dca1000`],
//! [`crate::ur`]); this module only sequences them. It never opens a control port
//! ([`crate::daemon`] does).

pub mod calibrate;
pub mod config;
pub mod decode;
pub mod devices;
pub mod job;
pub mod raw;
pub mod scan;
pub mod scene_frames;
pub mod simchain;
pub mod simlab;

pub use config::{LabConfig, LabConfigError, SimConfig};
