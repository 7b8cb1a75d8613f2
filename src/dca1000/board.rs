//! The [`CaptureBoard`] trait and the recording half of the capture sequence (B4 steps 4–6).
//!
//! [`record_frames`] starts the board's recording, then starts the radar through a callback (so
//! this module needs nothing from the radar's CLI), reassembles the stream into frames, hands
//! them to a sink in order, and stops the recording. It notices a silent radar within
//! `first_frame_margin` of the moment the first packet was due. It keeps every data packet's
//! byte offset and host arrival time, which time alignment fits the radar's clock to
//! ([`crate::align`]), and it ends early when the caller says the radar has stopped.

use std::time::{Duration, Instant};

use bytes::Bytes;

use super::command::{AsyncEvent, CodecError, Command, FpgaConfig, FpgaVersion, PacketConfig};
use super::packet::{DataPacket, PacketArrival, RAW_PAYLOAD_LEN};
use super::reassembler::{Frame, Reassembler, StreamStats};

/// Why a board operation failed.
#[derive(Debug, thiserror::Error)]
pub enum BoardError {
    #[error(
        "no reply to DCA1000 command {command} within {waited_ms} ms (check the host IP, SW2.5 = SW_CONFIG and the board's power)"
    )]
    Timeout {
        command: &'static str,
        waited_ms: u64,
    },
    #[error("DCA1000 refused command {command} with status {status}")]
    Rejected { command: &'static str, status: u16 },
    #[error("bad reply to DCA1000 command {command}: {source}")]
    BadReply {
        command: &'static str,
        #[source]
        source: CodecError,
    },
    #[error("DCA1000 {what}: {source}")]
    Io {
        what: String,
        #[source]
        source: std::io::Error,
    },
    #[error(
        "the radar is silent: no data {waited_ms} ms after sensorStart; the first packet was due after {expected_ms} ms"
    )]
    RadarSilent { expected_ms: u64, waited_ms: u64 },
    #[error("starting the radar failed: {0}")]
    SensorStart(String),
    #[error("writing frame {frame}: {source}")]
    Sink {
        frame: u64,
        #[source]
        source: std::io::Error,
    },
}

/// One datagram from the data port and when the host received it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Datagram {
    pub bytes: Bytes,
    pub received: Instant,
}

/// Receive-side counters the transport keeps besides the reassembler's.
#[derive(Debug, Clone, Default, PartialEq, Eq, serde::Serialize)]
pub struct ReceiveCounters {
    /// Drops the kernel reports for the data socket (`/proc/net/udp`), where readable.
    pub kernel_drops: Option<u64>,
    /// Datagrams dropped because the bounded queue was full.
    pub queue_drops: u64,
    /// Datagrams from an address other than the board's.
    pub foreign_datagrams: u64,
    /// The receive buffer the kernel granted, bytes.
    pub recv_buffer_bytes: usize,
}

/// A raw-ADC capture board.
pub trait CaptureBoard {
    /// `SYSTEM_CONNECT`, then `READ_FPGA_VERSION`.
    fn connect(&mut self) -> Result<FpgaVersion, BoardError>;
    /// `CONFIG_FPGA_GEN`, then `CONFIG_PACKET_DATA`.
    fn configure(&mut self, fpga: FpgaConfig, packets: PacketConfig) -> Result<(), BoardError>;
    fn start_record(&mut self) -> Result<(), BoardError>;
    fn stop_record(&mut self) -> Result<(), BoardError>;
    /// The next data datagram, or `None` after `timeout`.
    fn recv_datagram(&mut self, timeout: Duration) -> Result<Option<Datagram>, BoardError>;
    /// Async status events received since the last call.
    fn take_events(&mut self) -> Vec<AsyncEvent>;
    fn counters(&self) -> ReceiveCounters;
}

/// The request–reply exchange of the config port; every board's command sequences are built on
/// it.
pub trait Exchange {
    /// Sends `command` and returns the status of its reply.
    fn exchange(&mut self, command: Command, name: &'static str) -> Result<u16, BoardError>;

    /// Sends `command` and requires status 0.
    fn expect_ok(&mut self, command: Command, name: &'static str) -> Result<(), BoardError> {
        match self.exchange(command, name)? {
            0 => Ok(()),
            status => Err(BoardError::Rejected {
                command: name,
                status,
            }),
        }
    }

    /// `SYSTEM_CONNECT`, then `READ_FPGA_VERSION`.
    fn connect_sequence(&mut self) -> Result<FpgaVersion, BoardError> {
        self.expect_ok(Command::SystemConnect, "SYSTEM_CONNECT")?;
        let status = self.exchange(Command::ReadFpgaVersion, "READ_FPGA_VERSION")?;
        Ok(FpgaVersion::from_status(status))
    }

    /// `CONFIG_FPGA_GEN`, then `CONFIG_PACKET_DATA`.
    fn configure_sequence(
        &mut self,
        fpga: FpgaConfig,
        packets: PacketConfig,
    ) -> Result<(), BoardError> {
        self.expect_ok(Command::ConfigFpgaGen(fpga), "CONFIG_FPGA_GEN")?;
        self.expect_ok(Command::ConfigPacketData(packets), "CONFIG_PACKET_DATA")
    }
}

/// Timing of one recording.
#[derive(Debug, Clone, PartialEq)]
pub struct RecordPlan {
    pub frames: u64,
    pub frame_bytes: usize,
    pub frame_period_s: f64,
    /// How long past the first packet's due time a silent radar is tolerated (the shipped
    /// 40 ms when mmnormd starts the radar; the FPGA's `NO_LVDS_DATA` timer when it does not).
    pub first_frame_margin: Duration,
    /// The FPGA's idle flush of a partial payload (2 s), waited for when data is missing.
    pub stop_delay: Duration,
    /// Arrival times are seconds since this instant.
    pub epoch: Instant,
}

/// What a recording produced besides its frames.
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize)]
pub struct CaptureReport {
    pub frames_expected: u64,
    #[serde(flatten)]
    pub stream: StreamStats,
    #[serde(flatten)]
    pub receive: ReceiveCounters,
    /// Frames with a zero-filled gap.
    pub flagged_frame_indices: Vec<u64>,
    pub events: Vec<AsyncEvent>,
    /// From the end of `sensorStart` to the first data packet, milliseconds.
    pub first_packet_ms: Option<f64>,
    pub duration_s: f64,
    /// Every data packet that parsed, in arrival order (not in `report.json`).
    #[serde(skip)]
    pub arrivals: Vec<PacketArrival>,
}

/// Where a recording's data goes as it arrives, and how it starts and ends.
pub trait RecordSink {
    /// Starts the radar (`sensorStart`), right after `RECORD_START`.
    fn start_sensor(&mut self) -> Result<(), String>;
    /// Asked between datagrams: true once the radar has stopped before the planned count.
    fn finished(&mut self) -> bool {
        false
    }
    /// Every data packet that parsed, as it arrives.
    fn packet(&mut self, _arrival: &PacketArrival) -> std::io::Result<()> {
        Ok(())
    }
    /// Every frame in order, complete or flagged.
    fn frame(&mut self, frame: &Frame) -> std::io::Result<()>;
}

/// Records `plan.frames` frames: `RECORD_START`, `sink.start_sensor`, receive, `RECORD_STOP`.
/// Once `sink.finished` says the radar has stopped, packets still in flight are awaited for
/// [`LINGER`] (or three frame periods, if longer) and the recording ends there.
pub fn record_frames(
    board: &mut dyn CaptureBoard,
    plan: &RecordPlan,
    sink: &mut dyn RecordSink,
) -> Result<CaptureReport, BoardError> {
    let started = Instant::now();
    let mut reassembler = Reassembler::new(plan.frame_bytes, Some(plan.frames));
    let mut report = CaptureReport {
        frames_expected: plan.frames,
        ..CaptureReport::default()
    };
    board.start_record()?;
    if let Err(e) = sink.start_sensor() {
        board.stop_record().ok();
        return Err(BoardError::SensorStart(e));
    }
    let sensor_at = Instant::now();
    let period = Duration::from_secs_f64(plan.frame_period_s.max(0.0));
    let total_bytes = plan.frames * plan.frame_bytes as u64;
    let frames_for_first_packet = (RAW_PAYLOAD_LEN as u64)
        .min(total_bytes)
        .div_ceil(plan.frame_bytes.max(1) as u64);
    let first_due = period.mul_f64(frames_for_first_packet as f64);
    let first_deadline = sensor_at + first_due + plan.first_frame_margin;
    // The end is reckoned from the first packet: a radar started by hand (`--no-radar`) may
    // begin long after the recording.
    let run_time =
        period.mul_f64(plan.frames as f64) + plan.stop_delay + Duration::from_millis(500);
    let mut end_deadline = sensor_at + first_due + plan.first_frame_margin + run_time;
    let mut emitted = 0u64;
    let mut stopped = false;
    while emitted < plan.frames {
        if !stopped && sink.finished() {
            stopped = true;
            reassembler.end_early();
            let linger = LINGER.max(period.mul_f64(3.0));
            end_deadline = end_deadline.min(Instant::now() + linger);
        }
        let now = Instant::now();
        let deadline = if report.first_packet_ms.is_none() {
            first_deadline.min(end_deadline)
        } else {
            end_deadline
        };
        if now >= deadline {
            if report.first_packet_ms.is_none() {
                board.stop_record().ok();
                return Err(BoardError::RadarSilent {
                    expected_ms: first_due.as_millis() as u64,
                    waited_ms: now.duration_since(sensor_at).as_millis() as u64,
                });
            }
            break;
        }
        let wait = (deadline - now).min(Duration::from_millis(20));
        if let Some(datagram) = board.recv_datagram(wait)? {
            if report.first_packet_ms.is_none() {
                report.first_packet_ms = Some(sensor_at.elapsed().as_secs_f64() * 1e3);
                if !stopped {
                    end_deadline = Instant::now() + run_time;
                }
            }
            if let Ok(p) = DataPacket::parse(&datagram.bytes) {
                let arrival = PacketArrival {
                    byte_offset: p.byte_offset,
                    payload_len: p.payload.len() as u32,
                    host_s: crate::netio::signed_seconds(datagram.received, plan.epoch),
                };
                sink.packet(&arrival).map_err(|source| BoardError::Sink {
                    frame: p.byte_offset / plan.frame_bytes.max(1) as u64,
                    source,
                })?;
                report.arrivals.push(arrival);
            }
            // A malformed datagram is counted by the reassembler and otherwise ignored.
            reassembler.push(&datagram.bytes).ok();
            emitted += hand_out(&mut reassembler, &mut report, sink)?;
        }
        report.events.extend(board.take_events());
    }
    board.stop_record()?;
    report.stream = reassembler.finish();
    hand_out(&mut reassembler, &mut report, sink)?;
    report.events.extend(board.take_events());
    report.receive = board.counters();
    report.duration_s = started.elapsed().as_secs_f64();
    Ok(report)
}

/// How long packets in flight are awaited after the radar stopped.
pub const LINGER: Duration = Duration::from_millis(100);

/// Passes every ready frame to the sink; returns how many.
fn hand_out(
    reassembler: &mut Reassembler,
    report: &mut CaptureReport,
    sink: &mut dyn RecordSink,
) -> Result<u64, BoardError> {
    let mut count = 0;
    while let Some(frame) = reassembler.pop_frame() {
        if !frame.is_complete() {
            report.flagged_frame_indices.push(frame.index);
        }
        sink.frame(&frame).map_err(|source| BoardError::Sink {
            frame: frame.index,
            source,
        })?;
        count += 1;
    }
    Ok(count)
}
