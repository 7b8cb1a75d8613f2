//! The TI DCA1000EVM raw-ADC capture board.
//!
//! This module owns everything that crosses the board's Ethernet link (docs/protocols.md §A):
//! - [`command`]: the command and response codec of the config port (A2–A4), byte-exact;
//! - [`packet`]: the data-packet codec of the data port (A5);
//! - [`reassembler`]: the sans-IO reassembler that places payloads by byte offset, counts lost,
//!   reordered, duplicate and late packets and slices frames, flagging every zero-filled gap;
//! - [`samples`]: the 4-lane complex sample layout of the IWR1443 (A6);
//! - [`board`]: the [`board::CaptureBoard`] trait and the capture sequence of B4;
//! - [`udp`]: the socket2 transport with its receive thread and kernel-drop reading;
//! - [`sim`]: a DCA1000 simulator that answers every command and streams a capture's frames;
//! - [`loopback`]: that simulator behind the [`board::CaptureBoard`] trait, in-process;
//! - [`fault`]: the seeded fault injector (loss, reordering, duplicates) the simulator applies.
//!
//! The codecs and the reassembler never touch a socket; the transport and the simulator are thin
//! IO shells around them. Nothing here knows about the radar's serial CLI or the robot.

pub mod board;
pub mod command;
pub mod fault;
pub mod loopback;
pub mod packet;
pub mod reassembler;
pub mod samples;
pub mod sim;
pub mod udp;

pub use board::{
    BoardError, CaptureBoard, CaptureReport, ReceiveCounters, RecordPlan, RecordSink, record_frames,
};
pub use command::{AsyncEvent, Command, CommandCode, FpgaConfig, PacketConfig, Response};
pub use packet::DataPacket;
pub use reassembler::{Frame, Reassembler, StreamStats};
pub use samples::{FrameLayout, IqOrder, Lanes};
