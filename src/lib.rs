//! # mmnormd
//!
//! mmWave non-line-of-sight 3-D reconstruction (mmNorm) and the lab system around it.
//!
//! Data flows one way: the devices (real or simulated) produce a scan, recorded to MCAP and
//! aligned into a [`capture::Capture`] (a scene can also be simulated straight into one); the capture goes to the reconstruction; the reconstruction writes a point
//! cloud; the evaluation scores it. Each stage reads the previous stage's plain data types and never
//! reaches back into an earlier one.
//!
//! Layout:
//! - [`radar`]: the IWR1443: its chirp profile (`.cfg`), its UART CLI session and a PTY
//!   simulator of that CLI.
//! - [`dca1000`]: the DCA1000EVM: command and packet codecs, the reassembler, the sample layout,
//!   the UDP transport, a simulator and a fault injector.
//! - [`ur`]: the UR5e: RTDE codec and client, Dashboard, clock mapping, raster planner, and a
//!   simulator.
//! - [`align`]: time alignment of radar frames with robot poses (pure functions of recorded data).
//! - [`record`]: the MCAP recorder, recovery and the replay reader.
//! - [`daemon`]: the control port's protocol and server, the scan worker, systemd integration.
//! - [`lab`]: `lab.toml`, the scan pipeline and jobs, device bring-up, the simulated lab and
//!   the radar-only capture sequence.
//! - [`netio`]: nonblocking socket waits below the kernel tick.
//! - [`capture`]: the in-memory capture and the on-disk *capture directory v1* (`.npy` + JSON).
//! - [`geometry`]: triangle meshes, their file formats (STL, OBJ, PLY), primitives and a BVH.
//! - [`signal`]: the FMCW tone synthesis and the seeded noise generator shared by every model.
//! - [`sim`]: scenes and the physical-optics forward simulator that turns a scene into a capture.
//! - [`recon`]: the mmNorm reconstruction (volume, image, normals, mask, RSDF, isosurface) and the
//!   backprojection and interferometric baselines.
//! - [`eval`]: the paper's metrics (F-score, point, position and normal errors).
//! - [`preview`] and [`plot`]: PNG pictures and charts for people.
//! - [`bench`](mod@bench): the accuracy benchmark (the paper's evaluation over a suite of simulated scenes).
//! - [`progress`]: progress bars on a terminal, periodic log lines elsewhere.
//!
//! The command-line front end lives in the binary (`src/main.rs` and `src/cli/`); it is the only
//! place that uses `anyhow`. Library modules return their own `thiserror` enums.

pub mod align;
pub mod bench;
pub mod capture;
pub mod daemon;
pub mod dca1000;
pub mod eval;
pub mod geometry;
pub mod lab;
pub mod netio;
pub mod plot;
pub mod preview;
pub mod progress;
pub mod radar;
pub mod recon;
pub mod record;
pub mod signal;
pub mod sim;
pub mod ur;

/// Speed of light in vacuum, m/s (exact, SI). The authors' code mixes this with 3e8 in places;
/// mmnormd uses this constant everywhere.
pub const SPEED_OF_LIGHT_M_PER_S: f64 = 299_792_458.0;
