//! RTDE, the UR controller's real-time data exchange (research/protocols.md C2–C4), sans-IO.

pub mod codec;

pub use codec::{ClientMessage, CodecError, PacketReader, Recipe, RobotMessage, RtdeType, Value};
