//! The IWR1443's UART command line (docs/protocols.md §B), sans-IO.
//!
//! - [`reply`] splits the radar's output into lines and prompts and classifies each line: the
//!   echo, info lines (`Debug:`, `Ignored:`, `Skipped`), `Done`, `Error <n>` with its studio_cli
//!   meaning, and the SDK's "not recognized" reply. Stray `\r` and power-up garbage are tolerated.
//! - [`session`] runs a list of commands: it resynchronises with bare newlines until a prompt
//!   appears, sends one command at a time, accepts exactly one `Done` per command, and retries a
//!   command whose reply timed out or whose text arrived garbled, at most N times.
//! - [`grammar`] lists the commands the firmware accepts and their argument counts.
//!
//! Nothing here owns a serial port; [`crate::radar::control`] drives a session over one, and
//! [`crate::radar::sim`] answers one.

pub mod grammar;
pub mod reply;
pub mod session;

pub use reply::{LineKind, PromptKind, ReplyEvent, ReplyParser, error_meaning};
pub use session::{
    Accepted, CliError, CliSession, CommandOutcome, DEFAULT_RESYNC_ATTEMPTS, SessionConfig,
};
