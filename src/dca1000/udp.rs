//! The DCA1000 over UDP (docs/protocols.md A1, A8): [`UdpBoard`], a [`CaptureBoard`].
//!
//! The host binds its config port and its data port; the board sends every datagram to the host
//! IP. The data socket asks for a large receive buffer (64 MiB by default) and a warning names
//! the size Linux granted when `net.core.rmem_max` clamps it. A dedicated thread drains the data
//! socket into a bounded queue, so a slow consumer shows up as counted queue drops rather than
//! silent kernel drops; the kernel's own drop count is read from `/proc/net/udp`. The board's
//! source port is not assumed (the real board sends data from port 1024): any datagram from the
//! board's IP is accepted.

use std::net::{Ipv4Addr, SocketAddr, SocketAddrV4, UdpSocket};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::mpsc::{self, Receiver, RecvTimeoutError, SyncSender, TrySendError};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use bytes::Bytes;
use socket2::{Domain, Protocol, Socket, Type};

use super::board::{BoardError, CaptureBoard, Datagram, Exchange, ReceiveCounters};
use super::command::{AsyncEvent, Command, FpgaConfig, FpgaVersion, PacketConfig, Response};
use super::samples::IqOrder;
use crate::netio::is_would_block;

/// The `[dca1000]` section of a lab config. Defaults are the board's factory settings (A1) and
/// the recommended modes (A3).
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Dca1000Config {
    /// The host's address on the board's link; the board sends everything here.
    pub host_ip: Ipv4Addr,
    pub board_ip: Ipv4Addr,
    /// The board's config port.
    pub config_port: u16,
    /// The host's config port (the board replies to it; 0 picks a free one).
    pub host_config_port: u16,
    /// The host's data port (0 picks a free one; the board must then be told, as the
    /// simulator is).
    pub host_data_port: u16,
    /// Receive buffer asked of the kernel for the data socket, bytes.
    pub recv_buffer_bytes: usize,
    /// Datagrams the queue between the receive thread and the reassembler holds.
    pub queue_datagrams: usize,
    pub response_timeout_ms: u64,
    /// `CONFIG_PACKET_DATA`: packet size (48..=1472) and inter-packet delay (5..=500 µs).
    pub packet_size_bytes: u16,
    pub packet_delay_us: f64,
    pub fpga: FpgaConfig,
    /// Which half of each sample instant carries I (A6).
    pub iq_order: IqOrder,
    /// A radar that has sent nothing this long after its first packet was due is reported.
    pub first_frame_margin_ms: u64,
    /// The FPGA's idle flush of a trailing partial payload, waited for when data is missing.
    pub stop_delay_s: f64,
}

impl Default for Dca1000Config {
    fn default() -> Self {
        Self {
            host_ip: Ipv4Addr::new(192, 168, 33, 30),
            board_ip: Ipv4Addr::new(192, 168, 33, 180),
            config_port: 4096,
            host_config_port: 4096,
            host_data_port: 4098,
            recv_buffer_bytes: 64 << 20,
            queue_datagrams: 1 << 16,
            response_timeout_ms: 2000,
            packet_size_bytes: 1470,
            packet_delay_us: 25.0,
            fpga: FpgaConfig::default(),
            iq_order: IqOrder::IFirst,
            first_frame_margin_ms: 40,
            stop_delay_s: 2.0,
        }
    }
}

impl Dca1000Config {
    /// The frame layout `profile` produces on this board: its lanes from `fpga.lvds_mode`, its
    /// I/Q order from `iq_order`, checked against the profile's.
    pub fn layout(
        &self,
        profile: &crate::radar::RadarProfile,
    ) -> Result<super::samples::FrameLayout, super::samples::LayoutError> {
        super::samples::FrameLayout::from_profile(
            profile,
            self.iq_order,
            super::samples::Lanes::from_lvds_mode(self.fpga.lvds_mode)?,
        )
    }

    /// Checks every field; the error names the field and its value.
    pub fn validate(&self) -> Result<(), String> {
        if self.config_port == 0 {
            return Err("dca1000.config_port = 0 is not a port".into());
        }
        if !(48..=1472).contains(&self.packet_size_bytes) {
            return Err(format!(
                "dca1000.packet_size_bytes = {} is outside 48..=1472",
                self.packet_size_bytes
            ));
        }
        if !(5.0..=500.0).contains(&self.packet_delay_us) {
            return Err(format!(
                "dca1000.packet_delay_us = {} is outside 5..=500",
                self.packet_delay_us
            ));
        }
        if self.recv_buffer_bytes < 1 << 20 {
            return Err(format!(
                "dca1000.recv_buffer_bytes = {} is below 1 MiB",
                self.recv_buffer_bytes
            ));
        }
        if self.queue_datagrams < 1024 {
            return Err(format!(
                "dca1000.queue_datagrams = {} is below 1024",
                self.queue_datagrams
            ));
        }
        if self.response_timeout_ms == 0 {
            return Err("dca1000.response_timeout_ms = 0 must be positive".into());
        }
        if !(self.stop_delay_s.is_finite() && self.stop_delay_s >= 0.0) {
            return Err(format!(
                "dca1000.stop_delay_s = {} must be a non-negative number",
                self.stop_delay_s
            ));
        }
        self.fpga
            .validate()
            .map_err(|e| format!("dca1000.fpga: {e}"))?;
        Ok(())
    }

    /// The packet config this section asks for.
    pub fn packet_config(&self) -> Result<PacketConfig, String> {
        PacketConfig::from_delay_us(self.packet_size_bytes, self.packet_delay_us)
            .map_err(|e| format!("dca1000.packet_delay_us = {}: {e}", self.packet_delay_us))
    }
}

/// The board over UDP.
pub struct UdpBoard {
    control: UdpSocket,
    board_control: SocketAddr,
    response_timeout: Duration,
    data: Receiver<Datagram>,
    data_addr: SocketAddr,
    events: Vec<AsyncEvent>,
    counters: Arc<SharedCounters>,
    recv_buffer_bytes: usize,
    data_inode: Option<u64>,
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
}

#[derive(Default)]
struct SharedCounters {
    queue_drops: AtomicU64,
    foreign: AtomicU64,
}

fn io_err(what: impl Into<String>) -> impl FnOnce(std::io::Error) -> BoardError {
    let what = what.into();
    move |source| BoardError::Io { what, source }
}

impl UdpBoard {
    /// Binds both host ports and starts the receive thread.
    pub fn open(config: &Dca1000Config) -> Result<Self, BoardError> {
        let control_addr =
            SocketAddr::V4(SocketAddrV4::new(config.host_ip, config.host_config_port));
        let control = UdpSocket::bind(control_addr)
            .map_err(io_err(format!("binding the config port {control_addr}")))?;
        let data_addr = SocketAddr::V4(SocketAddrV4::new(config.host_ip, config.host_data_port));
        let socket = Socket::new(Domain::IPV4, Type::DGRAM, Some(Protocol::UDP))
            .map_err(io_err("creating the data socket"))?;
        socket
            .set_recv_buffer_size(config.recv_buffer_bytes)
            .map_err(io_err("setting SO_RCVBUF"))?;
        let granted = socket.recv_buffer_size().unwrap_or(0);
        if granted < config.recv_buffer_bytes {
            tracing::warn!(
                asked = config.recv_buffer_bytes,
                granted,
                "the kernel clamped the DCA1000 data socket's receive buffer; raise net.core.rmem_max (sysctl -w net.core.rmem_max={})",
                config.recv_buffer_bytes
            );
        }
        socket
            .bind(&data_addr.into())
            .map_err(io_err(format!("binding the data port {data_addr}")))?;
        let data_socket: UdpSocket = socket.into();
        let data_addr = data_socket
            .local_addr()
            .map_err(io_err("reading the data port"))?;
        data_socket
            .set_read_timeout(Some(Duration::from_millis(50)))
            .map_err(io_err("setting the data socket timeout"))?;
        let data_inode = socket_inode(&data_socket);
        let (tx, rx) = mpsc::sync_channel(config.queue_datagrams);
        let stop = Arc::new(AtomicBool::new(false));
        let counters = Arc::new(SharedCounters::default());
        let thread = {
            let (stop, counters, board_ip) = (stop.clone(), counters.clone(), config.board_ip);
            std::thread::Builder::new()
                .name("dca1000-rx".into())
                .spawn(move || receive(data_socket, board_ip, tx, stop, counters))
                .map_err(io_err("starting the receive thread"))?
        };
        Ok(Self {
            control,
            board_control: SocketAddr::V4(SocketAddrV4::new(config.board_ip, config.config_port)),
            response_timeout: Duration::from_millis(config.response_timeout_ms),
            data: rx,
            data_addr,
            events: Vec::new(),
            counters,
            recv_buffer_bytes: granted,
            data_inode,
            stop,
            thread: Some(thread),
        })
    }

    /// Points commands at another board address than the config's (a simulator bound to an
    /// ephemeral port).
    pub fn set_board_config_addr(&mut self, addr: SocketAddr) {
        self.board_control = addr;
    }

    /// The bound data address (where the board must send).
    pub fn data_addr(&self) -> SocketAddr {
        self.data_addr
    }
}

/// Sends a command and waits for its reply; async status packets met on the way are kept.
impl Exchange for UdpBoard {
    fn exchange(&mut self, command: Command, name: &'static str) -> Result<u16, BoardError> {
        self.control
            .send_to(&command.encode(), self.board_control)
            .map_err(io_err(format!("sending {name} to {}", self.board_control)))?;
        let start = Instant::now();
        let mut buf = [0u8; 64];
        loop {
            let left = self.response_timeout.saturating_sub(start.elapsed());
            if left.is_zero() {
                return Err(BoardError::Timeout {
                    command: name,
                    waited_ms: self.response_timeout.as_millis() as u64,
                });
            }
            self.control
                .set_read_timeout(Some(left))
                .map_err(io_err("setting the config socket timeout"))?;
            let n = match self.control.recv_from(&mut buf) {
                Ok((n, _)) => n,
                Err(e) if is_would_block(&e) => continue,
                Err(e) => return Err(io_err(format!("waiting for the reply to {name}"))(e)),
            };
            let reply = Response::decode(&buf[..n]).map_err(|source| BoardError::BadReply {
                command: name,
                source,
            })?;
            if reply.is_async_status() {
                self.events.extend(AsyncEvent::decode(reply.status));
            } else if reply.code == command.code() as u16 {
                return Ok(reply.status);
            }
        }
    }
}

impl CaptureBoard for UdpBoard {
    fn connect(&mut self) -> Result<FpgaVersion, BoardError> {
        self.connect_sequence()
    }

    fn configure(&mut self, fpga: FpgaConfig, packets: PacketConfig) -> Result<(), BoardError> {
        self.configure_sequence(fpga, packets)
    }

    fn start_record(&mut self) -> Result<(), BoardError> {
        while self.data.try_recv().is_ok() {}
        self.expect_ok(Command::RecordStart, "RECORD_START")
    }

    fn stop_record(&mut self) -> Result<(), BoardError> {
        self.expect_ok(Command::RecordStop, "RECORD_STOP")
    }

    fn recv_datagram(&mut self, timeout: Duration) -> Result<Option<Datagram>, BoardError> {
        match self.data.recv_timeout(timeout) {
            Ok(d) => Ok(Some(d)),
            Err(RecvTimeoutError::Timeout) => Ok(None),
            Err(RecvTimeoutError::Disconnected) => Err(BoardError::Io {
                what: "the receive thread ended".into(),
                source: std::io::Error::other("receive thread stopped"),
            }),
        }
    }

    fn take_events(&mut self) -> Vec<AsyncEvent> {
        let mut buf = [0u8; 64];
        if self.control.set_nonblocking(true).is_ok() {
            while let Ok((n, _)) = self.control.recv_from(&mut buf) {
                if let Ok(r) = Response::decode(&buf[..n])
                    && r.is_async_status()
                {
                    self.events.extend(AsyncEvent::decode(r.status));
                }
            }
            self.control.set_nonblocking(false).ok();
        }
        std::mem::take(&mut self.events)
    }

    fn counters(&self) -> ReceiveCounters {
        ReceiveCounters {
            kernel_drops: self.data_inode.and_then(|inode| {
                let text = std::fs::read_to_string("/proc/net/udp").ok()?;
                udp_drops_for_inode(&text, inode)
            }),
            queue_drops: self.counters.queue_drops.load(Ordering::Relaxed),
            foreign_datagrams: self.counters.foreign.load(Ordering::Relaxed),
            recv_buffer_bytes: self.recv_buffer_bytes,
        }
    }
}

impl Drop for UdpBoard {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            t.join().ok();
        }
    }
}

fn receive(
    socket: UdpSocket,
    board_ip: Ipv4Addr,
    queue: SyncSender<Datagram>,
    stop: Arc<AtomicBool>,
    counters: Arc<SharedCounters>,
) {
    let mut buf = vec![0u8; 65536];
    while !stop.load(Ordering::Relaxed) {
        let (n, from) = match socket.recv_from(&mut buf) {
            Ok(r) => r,
            Err(e) if is_would_block(&e) => continue,
            Err(_) => break,
        };
        if from.ip() != board_ip {
            counters.foreign.fetch_add(1, Ordering::Relaxed);
            continue;
        }
        let datagram = Datagram {
            bytes: Bytes::copy_from_slice(&buf[..n]),
            received: Instant::now(),
        };
        match queue.try_send(datagram) {
            Ok(()) => {}
            Err(TrySendError::Full(_)) => {
                counters.queue_drops.fetch_add(1, Ordering::Relaxed);
            }
            Err(TrySendError::Disconnected(_)) => break,
        }
    }
}

/// The inode of a socket, from `/proc/self/fd` (Linux).
fn socket_inode(socket: &UdpSocket) -> Option<u64> {
    use std::os::fd::AsRawFd as _;
    let link = std::fs::read_link(format!("/proc/self/fd/{}", socket.as_raw_fd())).ok()?;
    let text = link.to_str()?;
    text.strip_prefix("socket:[")?
        .strip_suffix(']')?
        .parse()
        .ok()
}

/// The `drops` column of the `/proc/net/udp` row whose `inode` column is `inode`.
pub fn udp_drops_for_inode(proc_net_udp: &str, inode: u64) -> Option<u64> {
    // The header names "tx_queue rx_queue" and "tr tm->when" as separate words although each
    // pair is one column in the rows, so columns are located from the end of each row instead.
    for line in proc_net_udp.lines().skip(1) {
        let cols: Vec<&str> = line.split_whitespace().collect();
        // Rows end: ... uid timeout inode ref pointer drops
        if cols.len() < 6 {
            continue;
        }
        let n = cols.len();
        if cols[n - 4].parse::<u64>().ok() == Some(inode) {
            return cols[n - 1].parse().ok();
        }
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn proc_net_udp_drops_are_read_by_inode() {
        let text = "   sl  local_address rem_address   st tx_queue rx_queue tr tm->when retrnsmt   uid  timeout inode ref pointer drops
  123: 0100007F:1002 00000000:0000 07 00000000:00000000 00:00000000 00000000     0        0 48213 2 0000000000000000 17
  456: 00000000:0044 00000000:0000 07 00000000:00000000 00:00000000 00000000     0        0 1111 2 0000000000000000 0
";
        assert_eq!(udp_drops_for_inode(text, 48213), Some(17));
        assert_eq!(udp_drops_for_inode(text, 1111), Some(0));
        assert_eq!(udp_drops_for_inode(text, 9), None);
    }

    #[test]
    fn config_errors_name_the_field_and_value() {
        let mut c = Dca1000Config {
            packet_delay_us: 1.0,
            ..Dca1000Config::default()
        };
        assert_eq!(
            c.validate().unwrap_err(),
            "dca1000.packet_delay_us = 1 is outside 5..=500"
        );
        c.packet_delay_us = 25.0;
        c.fpga.lvds_mode = 9;
        assert!(c.validate().unwrap_err().contains("lvds_mode = 9"));
        assert!(Dca1000Config::default().validate().is_ok());
    }
}
