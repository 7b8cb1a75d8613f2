//! RTDE, the UR controller's real-time data exchange (docs/protocols.md C2–C4): the
//! sans-IO codec and the client thread around it.

pub mod client;
pub mod codec;
pub mod fields;

pub use client::{RtdeClient, RtdeConfig, RtdeError, RtdeEvent, Sample};
pub use codec::{ClientMessage, CodecError, PacketReader, Recipe, RobotMessage, RtdeType, Value};
