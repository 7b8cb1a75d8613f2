//! A DCA1000EVM simulator (docs/protocols.md A9): a sans-IO [`BoardCore`] and a UDP shell
//! ([`DcaSimulator`]) that binds loopback addresses only.
//!
//! The core answers every command with the 8-byte echo and status of A2. After `RECORD_START`
//! and a sensor start (from the radar CLI simulator through a [`SensorTrigger`], or at once with
//! `autostart`) it streams the source's frames as raw-mode datagrams: 1456-byte payloads, the
//! sequence number from 1 and the byte offset from 0 at each recording, each packet due when the
//! frame holding its last byte has been captured, at the profile's frame period divided by
//! `time_scale`. A trailing partial payload goes out `flush_delay_s` later, as the FPGA's 2 s
//! idle flush does, and is lost if the recording stops first. It reports `NO_LVDS_DATA` when no
//! sensor start comes within the `CONFIG_FPGA_GEN` timer, `DDR_FULL` at a configured frame
//! (and stops streaming), and `REC_COMPLETED` after `RECORD_STOP`.
//!
//! Choices where A9 is silent: malformed requests get no reply; decodable commands the released
//! FPGA does not support (playback, 0x0C, 0x0D) and `RECORD_START` before `CONFIG_FPGA_GEN` get
//! status 1.

use std::collections::VecDeque;
use std::net::{IpAddr, SocketAddr, UdpSocket};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc;
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use num_complex::Complex;

use super::command::{AsyncEvent, Command, CommandCode, FpgaConfig, FpgaVersion, Response};
use super::fault::{FaultConfig, FaultInjector, InjectedFaults};
use super::packet::{DataPacket, HEADER_LEN, RAW_PAYLOAD_LEN};
use super::samples::{FrameLayout, LayoutError};
use crate::capture::Capture;

/// The raw byte stream a radar would put on the LVDS lanes: whole frames.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct AdcStream {
    pub frame_bytes: usize,
    pub bytes: Vec<u8>,
}

impl AdcStream {
    /// Frames in the stream.
    pub fn frames(&self) -> u64 {
        (self.bytes.len() / self.frame_bytes.max(1)) as u64
    }

    /// Quantises a capture to 16-bit ADC words, one frame per TX position: antennas
    /// `k·R .. (k+1)·R` (R = `layout.rx_count`, the order the simulator writes) make frame k.
    /// The largest |I| or |Q| maps to `full_scale`. Returns the stream and the scale applied
    /// (ADC counts per capture unit).
    pub fn from_capture(
        capture: &Capture,
        layout: &FrameLayout,
        full_scale: i16,
    ) -> Result<(Self, f64), LayoutError> {
        let per_frame = layout.rx_count * layout.chirps_per_frame;
        let n = layout.samples_per_chirp;
        if per_frame == 0 || capture.plan.samples_per_chirp != n {
            return Err(LayoutError::FrameSize {
                expected: layout.frame_bytes(),
                got: capture.plan.samples_per_chirp * 16,
            });
        }
        let peak = capture
            .samples
            .iter()
            .map(|c| c.re.abs().max(c.im.abs()))
            .fold(0.0f32, f32::max);
        let scale = if peak > 0.0 {
            f64::from(full_scale) / f64::from(peak)
        } else {
            1.0
        };
        let frames = capture.antennas() / per_frame;
        let mut bytes = Vec::with_capacity(frames * layout.frame_bytes());
        let quantise = |v: f32| (f64::from(v) * scale).round().clamp(-32768.0, 32767.0) as i16;
        for k in 0..frames {
            let words: Vec<Complex<i16>> = (k * per_frame..(k + 1) * per_frame)
                .flat_map(|a| capture.chirp(a).iter())
                .map(|c| Complex::new(quantise(c.re), quantise(c.im)))
                .collect();
            bytes.extend(layout.encode(&words)?);
        }
        Ok((
            Self {
                frame_bytes: layout.frame_bytes(),
                bytes,
            },
            scale,
        ))
    }
}

/// What the radar asks the board to stream after `sensorStart`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StreamPlan {
    /// Frames to send (the profile's count; 0 = all the source has).
    pub frames: u64,
    pub frame_period_s: f64,
    /// From a frame's start to the end of its last chirp, when its data is on the LVDS lanes.
    pub acquired_s: f64,
}

/// The bytes a radar puts on the LVDS lanes, frame after frame.
pub trait FrameSource: Send + Sync {
    fn frame_bytes(&self) -> usize;
    /// Frames the source can give (`u64::MAX` for a live one).
    fn frames(&self) -> u64;
    /// The radar starts frames: frame k's first chirp begins at `t0 + k·frame_period_s`.
    fn begin(&self, _t0: Instant, _plan: &StreamPlan) {}
    /// Copies the stream's bytes from `offset` into `buf`; false while a live source is still
    /// producing them.
    fn read(&self, offset: usize, buf: &mut [u8]) -> bool;
}

impl FrameSource for AdcStream {
    fn frame_bytes(&self) -> usize {
        self.frame_bytes
    }

    fn frames(&self) -> u64 {
        AdcStream::frames(self)
    }

    fn read(&self, offset: usize, buf: &mut [u8]) -> bool {
        match self.bytes.get(offset..offset + buf.len()) {
            Some(bytes) => {
                buf.copy_from_slice(bytes);
                true
            }
            None => false,
        }
    }
}

/// The simulator's settings.
#[derive(Debug, Clone, PartialEq)]
pub struct CoreConfig {
    pub version: FpgaVersion,
    /// Simulated seconds per wall-clock second.
    pub time_scale: f64,
    /// Idle time before the FPGA flushes a partial payload, seconds.
    pub flush_delay_s: f64,
    /// Stream at `RECORD_START` without waiting for a sensor start.
    pub autostart: Option<StreamPlan>,
    pub faults: FaultConfig,
    /// Report `DDR_FULL` and stop streaming when this frame is due.
    pub ddr_full_at_frame: Option<u64>,
}

impl Default for CoreConfig {
    fn default() -> Self {
        Self {
            version: FpgaVersion {
                major: 2,
                minor: 9,
                playback: false,
            },
            time_scale: 1.0,
            flush_delay_s: 2.0,
            autostart: None,
            faults: FaultConfig::default(),
            ddr_full_at_frame: None,
        }
    }
}

/// A datagram the core wants sent.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Output {
    /// To the host's config port (a response or an async status).
    Control(Vec<u8>),
    /// To the host's data port.
    Data(Vec<u8>),
}

/// The sans-IO simulator.
pub struct BoardCore {
    config: CoreConfig,
    source: Arc<dyn FrameSource>,
    fpga: Option<FpgaConfig>,
    recording_since: Option<Instant>,
    /// Set once a sensor start came during this recording, or `NO_LVDS_DATA` was reported.
    lvds_seen_or_reported: bool,
    streaming: Option<StreamState>,
    injector: FaultInjector,
    outbox: VecDeque<Output>,
    stats: SimStats,
}

struct StreamState {
    t0: Instant,
    frame_period: Duration,
    acquired: Duration,
    /// Set while the source has not produced the next packet's bytes: poll again then.
    retry_at: Option<Instant>,
    flush_delay: Duration,
    frame_bytes: u64,
    total_bytes: usize,
    next_packet: usize,
}

impl StreamState {
    fn packets(&self) -> usize {
        self.total_bytes.div_ceil(RAW_PAYLOAD_LEN)
    }

    /// When packet `i` is due: once the frame holding its last byte has been acquired, plus
    /// the idle flush for a partial payload.
    fn due(&self, i: usize) -> Instant {
        let end = ((i + 1) * RAW_PAYLOAD_LEN).min(self.total_bytes);
        let last_frame = (end as u64).saturating_sub(1) / self.frame_bytes;
        let at = self.t0 + self.frame_period.mul_f64(last_frame as f64) + self.acquired;
        if end - i * RAW_PAYLOAD_LEN == RAW_PAYLOAD_LEN {
            at
        } else {
            at + self.flush_delay
        }
    }
}

/// How soon to ask a live source again for bytes it has not produced yet.
const SOURCE_RETRY: Duration = Duration::from_micros(200);

/// What the simulator did.
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize)]
pub struct SimStats {
    pub commands: u64,
    pub malformed_commands: u64,
    pub recordings: u64,
    pub packets_sent: u64,
    /// Packets the injector dropped in recordings before the current one.
    pub dropped_in_earlier_recordings: u64,
    /// Packets sent more than 1 ms after they were due because the source was late.
    pub packets_late: u64,
    /// The latest of them, milliseconds after due.
    pub worst_late_ms: f64,
    pub injected: InjectedFaults,
}

impl BoardCore {
    pub fn new(config: CoreConfig, source: Arc<dyn FrameSource>) -> Self {
        Self {
            injector: FaultInjector::new(config.faults.clone()),
            config,
            source,
            fpga: None,
            recording_since: None,
            lvds_seen_or_reported: false,
            streaming: None,
            outbox: VecDeque::new(),
            stats: SimStats::default(),
        }
    }

    /// Counters so far.
    pub fn stats(&self) -> SimStats {
        let mut s = self.stats.clone();
        s.injected = self.injector.truth().clone();
        s
    }

    /// Whether the board is recording.
    pub fn is_recording(&self) -> bool {
        self.recording_since.is_some()
    }

    /// The next datagram to send.
    pub fn pop_output(&mut self) -> Option<Output> {
        self.outbox.pop_front()
    }

    /// Handles one request datagram from the host.
    pub fn handle_command(&mut self, bytes: &[u8], now: Instant) {
        let Ok(command) = Command::decode(bytes) else {
            self.stats.malformed_commands += 1;
            return;
        };
        self.stats.commands += 1;
        let code = command.code() as u16;
        let status = match command {
            Command::SystemConnect | Command::ResetFpga | Command::ResetArDevice => 0,
            Command::ReadFpgaVersion => self.config.version.to_status(),
            Command::ConfigFpgaGen(c) => match c.validate() {
                Ok(()) => {
                    self.fpga = Some(c);
                    0
                }
                Err(_) => 1,
            },
            Command::ConfigPacketData(_) | Command::ConfigEeprom(_) => 0,
            Command::RecordStart if self.fpga.is_some() => {
                self.recording_since = Some(now);
                self.lvds_seen_or_reported = false;
                self.streaming = None;
                // Each recording draws its own faults: the seed advances with the count.
                self.stats.dropped_in_earlier_recordings += self.injector.truth().dropped;
                self.injector = FaultInjector::new(FaultConfig {
                    seed: self.config.faults.seed.wrapping_add(self.stats.recordings),
                    ..self.config.faults.clone()
                });
                self.stats.recordings += 1;
                if let Some(plan) = self.config.autostart {
                    self.sensor_start(plan, now);
                }
                0
            }
            Command::RecordStop => {
                self.stop_stream();
                let was_recording = self.recording_since.take().is_some();
                self.outbox.push_back(Output::Control(
                    Response { code, status: 0 }.encode().to_vec(),
                ));
                if was_recording {
                    self.push_status(&[AsyncEvent::RecordCompleted]);
                }
                return;
            }
            _ => 1,
        };
        self.outbox
            .push_back(Output::Control(Response { code, status }.encode().to_vec()));
    }

    /// The radar started its frames. Ignored unless recording (the FPGA drops LVDS data then).
    pub fn sensor_start(&mut self, plan: StreamPlan, now: Instant) {
        if self.recording_since.is_none() {
            return;
        }
        let frame_bytes = self.source.frame_bytes().max(1);
        let available = self.source.frames();
        let frames = if plan.frames == 0 {
            available
        } else {
            plan.frames.min(available)
        };
        let scale = self.config.time_scale.max(1e-6);
        self.lvds_seen_or_reported = true;
        self.source.begin(now, &plan);
        self.streaming = Some(StreamState {
            t0: now,
            frame_period: Duration::from_secs_f64(plan.frame_period_s.max(0.0) / scale),
            acquired: Duration::from_secs_f64(plan.acquired_s.max(0.0) / scale),
            retry_at: None,
            flush_delay: Duration::from_secs_f64(self.config.flush_delay_s.max(0.0) / scale),
            frame_bytes: frame_bytes as u64,
            total_bytes: frames as usize * frame_bytes,
            next_packet: 0,
        });
    }

    /// The radar stopped at `now`: no frame starts after it; frames that started before it
    /// finish acquiring and drain on schedule.
    pub fn sensor_stop(&mut self, now: Instant) {
        if let Some(s) = self.streaming.as_mut() {
            let elapsed = now.saturating_duration_since(s.t0).as_secs_f64();
            let period = s.frame_period.as_secs_f64();
            let started = if period > 0.0 {
                (elapsed / period).floor() as u64 + 1
            } else {
                u64::MAX
            };
            let cap = started.saturating_mul(s.frame_bytes);
            s.total_bytes = s
                .total_bytes
                .min(usize::try_from(cap).unwrap_or(usize::MAX));
        }
    }

    fn stop_stream(&mut self) {
        if self.streaming.take().is_some() {
            let mut out = Vec::new();
            self.injector.flush(&mut out);
            self.queue_data(out);
        }
    }

    fn push_status(&mut self, events: &[AsyncEvent]) {
        let status = AsyncEvent::encode(events);
        self.outbox.push_back(Output::Control(
            Response {
                code: CommandCode::SystemError as u16,
                status,
            }
            .encode()
            .to_vec(),
        ));
    }

    fn queue_data(&mut self, datagrams: Vec<Vec<u8>>) {
        self.stats.packets_sent += datagrams.len() as u64;
        self.outbox.extend(datagrams.into_iter().map(Output::Data));
    }

    /// Produces everything due by `now`.
    pub fn poll(&mut self, now: Instant) {
        if let (Some(since), Some(fpga)) = (self.recording_since, self.fpga)
            && self.streaming.is_none()
            && !self.lvds_seen_or_reported
        {
            let timer =
                Duration::from_secs_f64(f64::from(fpga.timer_s) / self.config.time_scale.max(1e-6));
            if now >= since + timer {
                self.lvds_seen_or_reported = true;
                self.push_status(&[AsyncEvent::NoLvdsData]);
            }
        }
        let Some(stream) = self.streaming.as_mut() else {
            return;
        };
        let mut out = Vec::new();
        let mut ddr_full = false;
        stream.retry_at = None;
        let mut payload = [0u8; RAW_PAYLOAD_LEN];
        while stream.next_packet < stream.packets() && stream.due(stream.next_packet) <= now {
            let i = stream.next_packet;
            let start = i * RAW_PAYLOAD_LEN;
            let end = (start + RAW_PAYLOAD_LEN).min(stream.total_bytes);
            if let Some(k) = self.config.ddr_full_at_frame
                && (end as u64).div_ceil(stream.frame_bytes) > k
            {
                ddr_full = true;
                break;
            }
            let bytes = &mut payload[..end - start];
            if !self.source.read(start, bytes) {
                stream.retry_at = Some(now + SOURCE_RETRY);
                break;
            }
            let late_ms = now.saturating_duration_since(stream.due(i)).as_secs_f64() * 1e3;
            if late_ms > 1.0 {
                self.stats.packets_late += 1;
                self.stats.worst_late_ms = self.stats.worst_late_ms.max(late_ms);
            }
            let mut datagram = Vec::with_capacity(HEADER_LEN + bytes.len());
            DataPacket {
                sequence: i as u32 + 1,
                byte_offset: start as u64,
                payload: bytes,
            }
            .emit(&mut datagram);
            self.injector.push(datagram, &mut out);
            stream.next_packet += 1;
        }
        let finished = stream.next_packet >= stream.packets();
        if finished || ddr_full {
            self.injector.flush(&mut out);
            self.streaming = None;
        }
        self.queue_data(out);
        if ddr_full {
            self.push_status(&[AsyncEvent::DdrFull]);
        }
    }

    /// When [`poll`](Self::poll) next has something to do.
    pub fn next_deadline(&self) -> Option<Instant> {
        if let Some(s) = &self.streaming {
            return (s.next_packet < s.packets())
                .then(|| s.retry_at.unwrap_or_else(|| s.due(s.next_packet)));
        }
        match (self.recording_since, self.fpga) {
            (Some(since), Some(fpga)) if !self.lvds_seen_or_reported => Some(
                since
                    + Duration::from_secs_f64(
                        f64::from(fpga.timer_s) / self.config.time_scale.max(1e-6),
                    ),
            ),
            _ => None,
        }
    }
}

/// Why the simulator could not start.
#[derive(Debug, thiserror::Error)]
pub enum SimError {
    #[error("the DCA1000 simulator binds loopback addresses only; {field} = {addr} is not one")]
    NotLoopback { field: &'static str, addr: IpAddr },
    #[error("cannot bind the simulator's {what} socket on {addr}: {source}")]
    Bind {
        what: &'static str,
        addr: SocketAddr,
        #[source]
        source: std::io::Error,
    },
}

/// Where the UDP simulator listens and sends.
#[derive(Debug, Clone, PartialEq)]
pub struct SimAddresses {
    /// The board's config port (commands in, replies out).
    pub board_config: SocketAddr,
    /// The board's data source address (the real board sends from port 1024).
    pub board_data: SocketAddr,
    /// The host's data port, where datagrams go.
    pub host_data: SocketAddr,
}

pub(crate) enum TriggerMsg {
    Start(StreamPlan),
    Stop,
}

/// A handle the radar simulator uses to start and stop the board's stream.
#[derive(Clone)]
pub struct SensorTrigger(mpsc::Sender<TriggerMsg>);

impl SensorTrigger {
    pub(crate) fn new(tx: mpsc::Sender<TriggerMsg>) -> Self {
        Self(tx)
    }

    pub fn start(&self, plan: StreamPlan) {
        self.0.send(TriggerMsg::Start(plan)).ok();
    }

    /// The radar stopped (`sensorStop`): frames it already acquired still drain.
    pub fn stop(&self) {
        self.0.send(TriggerMsg::Stop).ok();
    }
}

/// The UDP shell around [`BoardCore`], on its own thread.
pub struct DcaSimulator {
    config_addr: SocketAddr,
    trigger: SensorTrigger,
    stop: Arc<AtomicBool>,
    core: Arc<Mutex<BoardCore>>,
    thread: Option<JoinHandle<()>>,
}

impl DcaSimulator {
    /// Binds the sockets and starts the thread.
    pub fn spawn(
        addresses: &SimAddresses,
        config: CoreConfig,
        source: Arc<dyn FrameSource>,
    ) -> Result<Self, SimError> {
        for (field, addr) in [
            ("board_config", addresses.board_config),
            ("board_data", addresses.board_data),
            ("host_data", addresses.host_data),
        ] {
            if !addr.ip().is_loopback() {
                return Err(SimError::NotLoopback {
                    field,
                    addr: addr.ip(),
                });
            }
        }
        let bind = |what, addr| {
            UdpSocket::bind(addr).map_err(|source| SimError::Bind { what, addr, source })
        };
        let control = bind("config", addresses.board_config)?;
        let data = bind("data", addresses.board_data)?;
        let config_addr = control.local_addr().map_err(|source| SimError::Bind {
            what: "config",
            addr: addresses.board_config,
            source,
        })?;
        let (tx, rx) = mpsc::channel();
        let stop = Arc::new(AtomicBool::new(false));
        let host_data = addresses.host_data;
        let core = Arc::new(Mutex::new(BoardCore::new(config, source)));
        let thread = {
            let (stop, core) = (stop.clone(), core.clone());
            std::thread::Builder::new()
                .name("dca1000-sim".into())
                .spawn(move || run(&core, control, data, host_data, rx, stop))
                .ok()
        };
        Ok(Self {
            config_addr,
            trigger: SensorTrigger(tx),
            stop,
            core,
            thread,
        })
    }

    /// The bound config address (the one to put in the host's config).
    pub fn config_addr(&self) -> SocketAddr {
        self.config_addr
    }

    /// The handle the radar simulator starts the stream with.
    pub fn trigger(&self) -> SensorTrigger {
        self.trigger.clone()
    }

    /// Counters so far.
    pub fn stats(&self) -> SimStats {
        self.core.lock().map(|c| c.stats()).unwrap_or_default()
    }

    /// Stops the thread and returns the final counters.
    pub fn shutdown(mut self) -> SimStats {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            t.join().ok();
        }
        self.stats()
    }
}

impl Drop for DcaSimulator {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            t.join().ok();
        }
    }
}

fn run(
    shared: &Mutex<BoardCore>,
    control: UdpSocket,
    data: UdpSocket,
    host_data: SocketAddr,
    triggers: mpsc::Receiver<TriggerMsg>,
    stop: Arc<AtomicBool>,
) {
    let mut host_control: Option<SocketAddr> = None;
    let mut buf = vec![0u8; 2048];
    // Nonblocking with sleeps: a socket timeout would round to the kernel tick (netio).
    control.set_nonblocking(true).ok();
    while !stop.load(Ordering::Relaxed) {
        let Ok(mut core) = shared.lock() else {
            return;
        };
        let mut idle = true;
        while let Ok((n, from)) = control.recv_from(&mut buf) {
            host_control = Some(from);
            core.handle_command(&buf[..n], Instant::now());
            idle = false;
        }
        while let Ok(msg) = triggers.try_recv() {
            match msg {
                TriggerMsg::Start(plan) => core.sensor_start(plan, Instant::now()),
                TriggerMsg::Stop => core.sensor_stop(Instant::now()),
            }
        }
        core.poll(Instant::now());
        while let Some(out) = core.pop_output() {
            match out {
                Output::Control(bytes) => {
                    if let Some(to) = host_control {
                        control.send_to(&bytes, to).ok();
                    }
                }
                Output::Data(bytes) => {
                    data.send_to(&bytes, host_data).ok();
                }
            }
        }
        let next = core.next_deadline();
        drop(core);
        if idle {
            crate::netio::sleep_until(next, Duration::from_millis(1));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dca1000::Reassembler;

    fn source(frames: usize) -> Arc<AdcStream> {
        Arc::new(AdcStream {
            frame_bytes: 8192,
            bytes: (0..frames * 8192).map(|i| (i % 251) as u8).collect(),
        })
    }

    fn drain(core: &mut BoardCore) -> (Vec<Vec<u8>>, Vec<Response>) {
        let (mut data, mut control) = (Vec::new(), Vec::new());
        while let Some(o) = core.pop_output() {
            match o {
                Output::Data(d) => data.push(d),
                Output::Control(c) => control.push(Response::decode(&c).unwrap()),
            }
        }
        (data, control)
    }

    #[test]
    fn streams_on_schedule_and_holds_the_partial_tail_for_the_flush_delay() {
        let mut core = BoardCore::new(CoreConfig::default(), source(3));
        let t0 = Instant::now();
        core.handle_command(&Command::ConfigFpgaGen(FpgaConfig::default()).encode(), t0);
        core.handle_command(&Command::RecordStart.encode(), t0);
        let (_, replies) = drain(&mut core);
        assert_eq!(replies.iter().map(|r| r.status).collect::<Vec<_>>(), [0, 0]);
        core.sensor_start(
            StreamPlan {
                frames: 3,
                frame_period_s: 0.003,
                acquired_s: 0.000_07,
            },
            t0,
        );
        // 3 × 8192 = 24 576 B = 16 full packets + 1 of 1280 B.
        core.poll(t0 + Duration::from_micros(100));
        let (first, _) = drain(&mut core);
        assert_eq!(first.len(), 5, "packets wholly inside frame 0");
        core.poll(t0 + Duration::from_millis(10));
        assert_eq!(drain(&mut core).0.len(), 11);
        core.poll(t0 + Duration::from_millis(1900));
        assert!(
            drain(&mut core).0.is_empty(),
            "the tail waits for the flush"
        );
        core.poll(t0 + Duration::from_millis(2010));
        let (tail, _) = drain(&mut core);
        assert_eq!(DataPacket::parse(&tail[0]).unwrap().payload.len(), 1280);
        core.handle_command(&Command::RecordStop.encode(), t0 + Duration::from_secs(3));
        let (_, replies) = drain(&mut core);
        assert_eq!(
            replies[1].status,
            AsyncEvent::encode(&[AsyncEvent::RecordCompleted])
        );
    }

    #[test]
    fn a_sensor_stop_ends_the_stream_after_the_frames_already_started() {
        let mut core = BoardCore::new(CoreConfig::default(), source(10));
        let t0 = Instant::now();
        core.handle_command(&Command::ConfigFpgaGen(FpgaConfig::default()).encode(), t0);
        core.handle_command(&Command::RecordStart.encode(), t0);
        drain(&mut core);
        let plan = StreamPlan {
            frames: 10,
            frame_period_s: 0.003,
            acquired_s: 0.000_07,
        };
        core.sensor_start(plan, t0);
        // Stopped 10.5 ms in: frames 0..=3 started, 4 × 8192 B = 22 full packets + 736 B.
        core.sensor_stop(t0 + Duration::from_micros(10_500));
        core.poll(t0 + Duration::from_secs(5));
        let (data, _) = drain(&mut core);
        let bytes: usize = data
            .iter()
            .map(|d| DataPacket::parse(d).unwrap().payload.len())
            .sum();
        assert_eq!((data.len(), bytes), (23, 4 * 8192));
    }

    #[test]
    fn no_sensor_start_reports_no_lvds_data_after_the_timer() {
        let mut core = BoardCore::new(CoreConfig::default(), source(1));
        let t0 = Instant::now();
        let fpga = FpgaConfig {
            timer_s: 1,
            ..FpgaConfig::default()
        };
        core.handle_command(&Command::ConfigFpgaGen(fpga).encode(), t0);
        core.handle_command(&Command::RecordStart.encode(), t0);
        drain(&mut core);
        core.poll(t0 + Duration::from_millis(999));
        assert!(drain(&mut core).1.is_empty());
        core.poll(t0 + Duration::from_millis(1001));
        let status = drain(&mut core).1[0];
        assert!(status.is_async_status());
        assert_eq!(
            AsyncEvent::decode(status.status),
            vec![AsyncEvent::NoLvdsData]
        );
    }

    #[test]
    fn ddr_full_stops_the_stream_and_is_reported() {
        let config = CoreConfig {
            ddr_full_at_frame: Some(2),
            ..CoreConfig::default()
        };
        let mut core = BoardCore::new(config, source(5));
        let t0 = Instant::now();
        core.handle_command(&Command::ConfigFpgaGen(FpgaConfig::default()).encode(), t0);
        core.handle_command(&Command::RecordStart.encode(), t0);
        core.sensor_start(
            StreamPlan {
                frames: 5,
                frame_period_s: 0.003,
                acquired_s: 0.000_07,
            },
            t0,
        );
        core.poll(t0 + Duration::from_secs(5));
        let (data, control) = drain(&mut core);
        let mut r = Reassembler::new(8192, None);
        for d in &data {
            r.push(d).unwrap();
        }
        assert!(r.max_end_offset() <= 2 * 8192);
        assert_eq!(
            AsyncEvent::decode(control.last().unwrap().status),
            vec![AsyncEvent::DdrFull]
        );
    }

    #[test]
    fn record_start_before_fpga_config_fails_and_garbage_gets_no_reply() {
        let mut core = BoardCore::new(CoreConfig::default(), source(1));
        let t0 = Instant::now();
        core.handle_command(&Command::RecordStart.encode(), t0);
        core.handle_command(&[0x5A, 0xA5, 0x09], t0);
        let (_, replies) = drain(&mut core);
        assert_eq!(replies, vec![Response { code: 5, status: 1 }]);
        assert_eq!(core.stats().malformed_commands, 1);
    }
}
