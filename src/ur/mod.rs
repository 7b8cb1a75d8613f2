//! The UR5e arm (docs/protocols.md §C): its RTDE pose stream, the controller-clock mapping,
//! the Dashboard, the raster planner, rows driven through the [`robot::Robot`] trait, and a
//! simulator of the arm.
//!
//! - [`rtde`]: the sans-IO RTDE codec (every packet type of C2 and data type of C3, big-endian,
//!   length-checked) and the client thread around it.
//! - [`dashboard`]: the Dashboard line protocol with typed replies.
//! - [`robot`]: the `Robot` trait and `UrRobot` (Dashboard + script port + RTDE).
//! - [`sim`]: the UR5e simulator (RTDE, Dashboard and script servers on loopback).
//! - [`clock`]: the controller `timestamp` → host monotonic time mapping by a running fit of the
//!   lower envelope of the latencies (D3).
//! - [`motion`]: the raster planner: rows of constant-speed `movel`, the λ/4-per-frame speed
//!   check, the usable constant-velocity middle of each row.
//!
//! The codec, the clock mapping and the planner open no socket; the client, `UrRobot` and the
//! simulator are the IO shells.

pub mod clock;
pub mod dashboard;
pub mod motion;
pub mod robot;
pub mod rtde;
pub mod sim;
