//! The UR5e arm (research/protocols.md §C): its RTDE pose stream, the controller-clock mapping,
//! and the raster planner.
//!
//! - [`rtde`]: the sans-IO RTDE codec (every packet type of C2 and data type of C3, big-endian,
//!   length-checked).
//! - [`clock`]: the controller `timestamp` → host monotonic time mapping by a running fit of the
//!   lower envelope of the latencies (D3).
//! - [`motion`]: the raster planner: rows of constant-speed `movel`, the λ/4-per-frame speed
//!   check, the usable constant-velocity middle of each row.
//!
//! Nothing here opens a socket.

pub mod clock;
pub mod dashboard;
pub mod motion;
pub mod robot;
pub mod rtde;
pub mod sim;
