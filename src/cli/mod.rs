//! Subcommand implementations of the `mmnormd` binary. They parse nothing (clap does), call the
//! library and report; errors become `anyhow` with context.

pub mod bench;
pub mod capture;
pub mod ctl;
pub mod daemon;
pub mod demo;
pub mod eval;
pub mod inspect;
pub mod profile;
pub mod reconstruct;
pub mod replay;
pub mod robot;
pub mod simulate;
