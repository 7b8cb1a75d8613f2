//! The daemon (`mmnormd --config lab.toml`): the devices (or the simulated lab), the control
//! port, the scan worker and systemd integration.
//!
//! Tokio runs the control port: one task per client, replies and events through a bounded
//! queue per client, so a client that stops reading is disconnected instead of slowing anyone
//! down. Scans and reconstructions run on their own thread with the devices; one at a time,
//! a second `scan` gets "busy". `status` reads a snapshot under a short lock and answers while
//! a reconstruction keeps both cores busy. SIGTERM/SIGINT abort a running scan (the arm gets
//! `stopl` within one RTDE poll), the recording is finished, and the process exits within 2 s.
//! With `NOTIFY_SOCKET` set, readiness, status lines and watchdog pings go to systemd.

pub mod protocol;
mod server;
mod worker;

pub use server::{Daemon, DaemonError};
