//! The RTDE client: a dedicated thread that connects, negotiates, and reads continuously (the
//! controller drops clients that stop reading), stamping each package with the host's monotonic
//! receive time.
//!
//! Setup: protocol version 2 (falling back to 1), the controller version, the output recipe at
//! the configured frequency, one input recipe (registers 24 and up: 0–23 may belong to a
//! fieldbus), start. A field the controller refuses (`NOT_FOUND`, `IN_USE`) is an error that
//! names it, and the client stops: retrying cannot help.
//!
//! No package for `stall_periods` periods is a stall (the first package after START gets
//! `first_package_timeout` instead: a controller may take tens of milliseconds to send it): the
//! client marks a gap, drops the connection, and reconnects, re-running the whole setup. Every
//! gap starts a new segment number; consumers must never interpolate poses across segments.
//!
//! Every connection after the first waits the backoff first, which then doubles, up to
//! `backoff_max`. It starts at `backoff_initial` and returns there only after a session
//! streamed for `healthy_after`. A controller that accepts and then fails at once is therefore
//! retried at 0.1, 0.2, 0.4 … 5 s, never in a storm.

use std::io::{Read as _, Write as _};
use std::net::{SocketAddr, TcpStream};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{self, Receiver, Sender};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use crate::netio::{is_would_block, write_all_within};

use super::codec::{
    ClientMessage, CodecError, FieldType, PacketReader, Recipe, RobotMessage, Setup, Value,
};

/// The output fields mmnormd records (C4).
pub const DEFAULT_OUTPUTS: &[&str] = &[
    "timestamp",
    "actual_TCP_pose",
    "target_TCP_pose",
    "actual_TCP_speed",
    "actual_q",
    "robot_mode",
    "safety_mode",
    "safety_status_bits",
    "runtime_state",
    "speed_scaling",
    "output_int_register_24",
];

/// The input fields mmnormd writes: the watchdog counter.
pub const DEFAULT_INPUTS: &[&str] = &["input_int_register_24"];

/// Client settings.
#[derive(Debug, Clone, PartialEq)]
pub struct RtdeConfig {
    pub addr: SocketAddr,
    /// 500 Hz on e-Series, 125 Hz on CB3.
    pub frequency_hz: f64,
    pub outputs: Vec<String>,
    pub inputs: Vec<String>,
    pub connect_timeout: Duration,
    /// Packages missed before a stall is declared.
    pub stall_periods: f64,
    /// How long the first package after START may take.
    pub first_package_timeout: Duration,
    pub backoff_initial: Duration,
    pub backoff_max: Duration,
    /// A session that streamed this long resets the backoff.
    pub healthy_after: Duration,
}

impl RtdeConfig {
    /// The recommended settings for an e-Series controller at `addr`.
    pub fn e_series(addr: SocketAddr) -> Self {
        Self {
            addr,
            frequency_hz: 500.0,
            outputs: DEFAULT_OUTPUTS.iter().map(|s| s.to_string()).collect(),
            inputs: DEFAULT_INPUTS.iter().map(|s| s.to_string()).collect(),
            connect_timeout: Duration::from_secs(2),
            stall_periods: 3.0,
            first_package_timeout: Duration::from_secs(1),
            backoff_initial: Duration::from_millis(100),
            backoff_max: Duration::from_secs(5),
            healthy_after: Duration::from_secs(5),
        }
    }
}

/// Why the client failed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum RtdeError {
    #[error("RTDE {addr}: {message}")]
    Io { addr: SocketAddr, message: String },
    #[error("RTDE field `{field}` is not known to this controller (NOT_FOUND)")]
    NotFound { field: String },
    #[error(
        "RTDE field `{field}` is in use by another RTDE client or a fieldbus (IN_USE): stop the other client, or, if a fieldbus holds registers 0–23, use 24–47"
    )]
    InUse { field: String },
    #[error("RTDE: the controller refused {what}")]
    Refused { what: &'static str },
    #[error("RTDE: {0}")]
    Codec(#[from] CodecError),
    #[error("RTDE: unexpected reply to {what}: {reply}")]
    Unexpected { what: &'static str, reply: String },
}

/// One output package.
#[derive(Debug, Clone, PartialEq)]
pub struct Sample {
    /// Host monotonic receive time, seconds since the client's epoch.
    pub host_s: f64,
    /// The controller's `timestamp` field, if in the recipe.
    pub controller_s: Option<f64>,
    /// Segment number: it changes at every gap.
    pub segment: u64,
    pub values: Vec<Value>,
}

/// What the client reports.
#[derive(Debug, Clone, PartialEq)]
pub enum RtdeEvent {
    Connected {
        segment: u64,
        protocol: u16,
        version: (u32, u32, u32, u32),
        at_host_s: f64,
    },
    Sample(Sample),
    /// The stream broke; `segment` is the one that ended.
    Gap {
        segment: u64,
        reason: String,
        at_host_s: f64,
    },
    /// A text message from the controller.
    Text {
        level: u8,
        message: String,
    },
    /// The client gave up (a refused field, or stopped).
    Failed(RtdeError),
}

/// What the caller asks of the client thread.
enum Request {
    Inputs(Vec<Value>),
    Pause,
    Start,
}

/// The running client.
pub struct RtdeClient {
    epoch: Instant,
    events: Receiver<RtdeEvent>,
    inputs: Sender<Request>,
    names: Vec<String>,
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
}

impl RtdeClient {
    /// Starts the client thread. Events arrive on [`events`](Self::events).
    pub fn spawn(config: RtdeConfig) -> Self {
        let epoch = Instant::now();
        let (tx, rx) = mpsc::channel();
        let (in_tx, in_rx) = mpsc::channel();
        let stop = Arc::new(AtomicBool::new(false));
        let names = config.outputs.clone();
        let thread = {
            let stop = stop.clone();
            std::thread::Builder::new()
                .name("rtde-client".into())
                .spawn(move || run(config, epoch, tx, in_rx, stop))
                .ok()
        };
        Self {
            epoch,
            events: rx,
            inputs: in_tx,
            names,
            stop,
            thread,
        }
    }

    /// The client's time origin: `host_s` of samples counts from it.
    pub fn epoch(&self) -> Instant {
        self.epoch
    }

    /// Output field names, in the order of [`Sample::values`].
    pub fn output_names(&self) -> &[String] {
        &self.names
    }

    /// The event stream.
    pub fn events(&self) -> &Receiver<RtdeEvent> {
        &self.events
    }

    /// Queues an input package (values in the order of the input recipe).
    pub fn send_inputs(&self, values: Vec<Value>) {
        self.inputs.send(Request::Inputs(values)).ok();
    }

    /// Pauses the output stream (`P`); no stall is declared while paused.
    pub fn pause(&self) {
        self.inputs.send(Request::Pause).ok();
    }

    /// Resumes the output stream (`S`).
    pub fn resume(&self) {
        self.inputs.send(Request::Start).ok();
    }

    /// Stops the thread.
    pub fn shutdown(mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            t.join().ok();
        }
    }
}

impl Drop for RtdeClient {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            t.join().ok();
        }
    }
}

struct Session {
    stream: TcpStream,
    reader: PacketReader,
    protocol: u16,
    output: Recipe,
    input: Option<Recipe>,
    version: (u32, u32, u32, u32),
}

fn io_error(addr: SocketAddr) -> impl Fn(std::io::Error) -> RtdeError {
    move |e| RtdeError::Io {
        addr,
        message: e.to_string(),
    }
}

impl Session {
    fn send(&mut self, m: &ClientMessage) -> Result<(), RtdeError> {
        let addr = self.stream.peer_addr().map_err(io_error(self.addr()))?;
        let bytes = m.encode(self.protocol)?;
        self.stream.write_all(&bytes).map_err(io_error(addr))
    }

    fn addr(&self) -> SocketAddr {
        self.stream
            .peer_addr()
            .unwrap_or_else(|_| SocketAddr::from(([0, 0, 0, 0], 0)))
    }

    /// Reads until one non-data, non-text reply arrives.
    fn reply(&mut self, what: &'static str, timeout: Duration) -> Result<RobotMessage, RtdeError> {
        let addr = self.addr();
        let start = Instant::now();
        let mut buf = [0u8; 4096];
        loop {
            while let Some((ty, payload)) = self.reader.next_packet()? {
                match RobotMessage::decode(ty, &payload, self.protocol)? {
                    RobotMessage::Text { .. } | RobotMessage::Data { .. } => {}
                    other => return Ok(other),
                }
            }
            let left = timeout.saturating_sub(start.elapsed());
            if left.is_zero() {
                return Err(RtdeError::Io {
                    addr,
                    message: format!("no reply to {what} within {} ms", timeout.as_millis()),
                });
            }
            self.stream
                .set_read_timeout(Some(left))
                .map_err(io_error(addr))?;
            match self.stream.read(&mut buf) {
                Ok(0) => {
                    return Err(RtdeError::Io {
                        addr,
                        message: format!("closed while waiting for the reply to {what}"),
                    });
                }
                Ok(n) => self.reader.feed(&buf[..n]),
                Err(e) if is_would_block(&e) => {}
                Err(e) => return Err(io_error(addr)(e)),
            }
        }
    }
}

/// The recipe a setup reply grants. The reply must be typed as the request (`O` for
/// outputs, `I` for inputs), as a controller's is.
fn recipe_from(
    names: &[String],
    reply: RobotMessage,
    expected: Setup,
    what: &'static str,
) -> Result<Recipe, RtdeError> {
    let RobotMessage::SetupReply {
        setup,
        recipe_id,
        types,
    } = reply
    else {
        return Err(RtdeError::Unexpected {
            what,
            reply: format!("{reply:?}"),
        });
    };
    if setup != expected {
        return Err(RtdeError::Unexpected {
            what,
            reply: format!(
                "a setup reply of packet type '{}'",
                char::from(setup.packet_type())
            ),
        });
    }
    if types.len() != names.len() {
        return Err(RtdeError::Unexpected {
            what,
            reply: format!("{} types for {} fields", types.len(), names.len()),
        });
    }
    let mut out = Vec::with_capacity(types.len());
    for (name, t) in names.iter().zip(types) {
        match t {
            FieldType::Type(t) => out.push(t),
            FieldType::NotFound => {
                return Err(RtdeError::NotFound {
                    field: name.clone(),
                });
            }
            FieldType::InUse => {
                return Err(RtdeError::InUse {
                    field: name.clone(),
                });
            }
        }
    }
    Ok(Recipe {
        id: recipe_id,
        names: names.to_vec(),
        types: out,
    })
}

/// Connects and runs the whole setup.
fn setup(config: &RtdeConfig) -> Result<Session, RtdeError> {
    let stream = TcpStream::connect_timeout(&config.addr, config.connect_timeout)
        .map_err(io_error(config.addr))?;
    stream.set_nodelay(true).ok();
    let mut s = Session {
        stream,
        reader: PacketReader::default(),
        protocol: 2,
        output: Recipe {
            id: 0,
            names: Vec::new(),
            types: Vec::new(),
        },
        input: None,
        version: (0, 0, 0, 0),
    };
    let timeout = config.connect_timeout;
    s.send(&ClientMessage::RequestProtocolVersion(2))?;
    if s.reply("protocol version 2", timeout)? != RobotMessage::ProtocolVersionAccepted(true) {
        s.protocol = 1;
        s.send(&ClientMessage::RequestProtocolVersion(1))?;
        if s.reply("protocol version 1", timeout)? != RobotMessage::ProtocolVersionAccepted(true) {
            return Err(RtdeError::Refused {
                what: "protocol versions 2 and 1",
            });
        }
    }
    s.send(&ClientMessage::GetUrcontrolVersion)?;
    if let RobotMessage::UrcontrolVersion {
        major,
        minor,
        bugfix,
        build,
    } = s.reply("controller version", timeout)?
    {
        s.version = (major, minor, bugfix, build);
    }
    s.send(&ClientMessage::SetupOutputs {
        frequency_hz: config.frequency_hz,
        names: config.outputs.clone(),
    })?;
    s.output = recipe_from(
        &config.outputs,
        s.reply("output setup", timeout)?,
        Setup::Outputs,
        "output setup",
    )?;
    if !config.inputs.is_empty() {
        s.send(&ClientMessage::SetupInputs {
            names: config.inputs.clone(),
        })?;
        s.input = Some(recipe_from(
            &config.inputs,
            s.reply("input setup", timeout)?,
            Setup::Inputs,
            "input setup",
        )?);
    }
    s.send(&ClientMessage::Start)?;
    if s.reply("start", timeout)? != RobotMessage::StartAccepted(true) {
        return Err(RtdeError::Refused { what: "start" });
    }
    Ok(s)
}

fn run(
    config: RtdeConfig,
    epoch: Instant,
    events: Sender<RtdeEvent>,
    inputs: Receiver<Request>,
    stop: Arc<AtomicBool>,
) {
    let period = Duration::from_secs_f64(1.0 / config.frequency_hz.max(1e-3));
    let stall = period.mul_f64(config.stall_periods);
    let host_s = || epoch.elapsed().as_secs_f64();
    let timestamp_at = config.outputs.iter().position(|n| n == "timestamp");
    let mut segment = 0u64;
    let mut backoff = config.backoff_initial;
    let mut first_attempt = true;
    while !stop.load(Ordering::Relaxed) {
        if !first_attempt {
            if !sleep_unless_stopped(backoff, &stop) {
                return;
            }
            backoff = (backoff * 2).min(config.backoff_max);
        }
        first_attempt = false;
        let mut session = match setup(&config) {
            Ok(s) => s,
            Err(e @ (RtdeError::NotFound { .. } | RtdeError::InUse { .. })) => {
                events.send(RtdeEvent::Failed(e)).ok();
                return;
            }
            Err(_) => continue,
        };
        segment += 1;
        events
            .send(RtdeEvent::Connected {
                segment,
                protocol: session.protocol,
                version: session.version,
                at_host_s: host_s(),
            })
            .ok();
        let ended = read_loop(
            &mut session,
            ReadContext {
                config: &config,
                stall,
                segment,
                timestamp_at,
                events: &events,
                inputs: &inputs,
                stop: &stop,
                epoch,
            },
        );
        if ended.streamed >= config.healthy_after {
            backoff = config.backoff_initial;
        }
        events
            .send(RtdeEvent::Gap {
                segment,
                reason: ended.reason,
                at_host_s: host_s(),
            })
            .ok();
    }
}

/// Sleeps `d` in short steps; false when `stop` was set meanwhile.
fn sleep_unless_stopped(d: Duration, stop: &AtomicBool) -> bool {
    let until = Instant::now() + d;
    while Instant::now() < until {
        if stop.load(Ordering::Relaxed) {
            return false;
        }
        std::thread::sleep((until - Instant::now()).min(Duration::from_millis(20)));
    }
    !stop.load(Ordering::Relaxed)
}

/// How a session ended: why, and for how long data flowed (first to last package).
struct Ended {
    reason: String,
    streamed: Duration,
}

/// What the read loop of one session needs besides the session.
#[derive(Clone, Copy)]
struct ReadContext<'a> {
    config: &'a RtdeConfig,
    stall: Duration,
    segment: u64,
    timestamp_at: Option<usize>,
    events: &'a Sender<RtdeEvent>,
    inputs: &'a Receiver<Request>,
    stop: &'a AtomicBool,
    epoch: Instant,
}

/// Reads one session until it ends: why, and for how long data flowed.
fn read_loop(s: &mut Session, ctx: ReadContext<'_>) -> Ended {
    let mut first_package: Option<Instant> = None;
    let mut last_package = Instant::now();
    let reason = read_packages(s, ctx, &mut first_package, &mut last_package);
    Ended {
        reason,
        streamed: first_package.map_or(Duration::ZERO, |t| {
            last_package.saturating_duration_since(t)
        }),
    }
}

/// The body of [`read_loop`]: reads until the session ends and says why; `first_package` and
/// `last_package` record when data came.
fn read_packages(
    s: &mut Session,
    ctx: ReadContext<'_>,
    first_package: &mut Option<Instant>,
    last_package: &mut Instant,
) -> String {
    let ReadContext {
        config,
        stall,
        segment,
        timestamp_at,
        events,
        inputs,
        stop,
        epoch,
    } = ctx;
    let mut buf = [0u8; 16384];
    let mut paused = false;
    let poll = (stall / 12).clamp(Duration::from_micros(200), Duration::from_millis(2));
    if s.stream.set_nonblocking(true).is_err() {
        return "cannot make the socket nonblocking".into();
    }
    loop {
        if stop.load(Ordering::Relaxed) {
            return "client stopped".into();
        }
        while let Ok(request) = inputs.try_recv() {
            let message = match request {
                Request::Inputs(values) => s.input.as_ref().and_then(|recipe| {
                    let mut fields = Vec::new();
                    recipe
                        .encode_fields(&values, &mut fields)
                        .ok()
                        .map(|()| ClientMessage::Data {
                            recipe_id: recipe.id,
                            fields,
                        })
                }),
                Request::Pause => {
                    paused = true;
                    Some(ClientMessage::Pause)
                }
                Request::Start => {
                    paused = false;
                    *last_package = Instant::now();
                    Some(ClientMessage::Start)
                }
            };
            if let Some(m) = message {
                let sent = m
                    .encode(s.protocol)
                    .map_err(|e| std::io::Error::other(e.to_string()))
                    .and_then(|b| write_all_within(&mut s.stream, &b, Duration::from_secs(1)));
                if let Err(e) = sent {
                    return format!("write failed: {e}");
                }
            }
        }
        match s.stream.read(&mut buf) {
            Ok(0) => return "the controller closed the connection".into(),
            Ok(n) => {
                let received = Instant::now();
                s.reader.feed(&buf[..n]);
                loop {
                    let packet = match s.reader.next_packet() {
                        Ok(Some(p)) => p,
                        Ok(None) => break,
                        Err(e) => return format!("framing lost: {e}"),
                    };
                    match RobotMessage::decode(packet.0, &packet.1, s.protocol) {
                        Ok(RobotMessage::Data { fields, .. }) => {
                            let Ok(values) = s.output.decode_fields(&fields) else {
                                return "a data package did not match the recipe".into();
                            };
                            *last_package = received;
                            first_package.get_or_insert(received);
                            let controller_s = timestamp_at.and_then(|i| match values.get(i) {
                                Some(Value::Double(t)) => Some(*t),
                                _ => None,
                            });
                            events
                                .send(RtdeEvent::Sample(Sample {
                                    host_s: received.duration_since(epoch).as_secs_f64(),
                                    controller_s,
                                    segment,
                                    values,
                                }))
                                .ok();
                        }
                        Ok(RobotMessage::Text { level, message, .. }) => {
                            events.send(RtdeEvent::Text { level, message }).ok();
                        }
                        Ok(_) => {}
                        Err(e) => return format!("bad package: {e}"),
                    }
                }
            }
            Err(e) if is_would_block(&e) => std::thread::sleep(poll),
            Err(e) => return format!("read failed: {e}"),
        }
        if paused {
            continue;
        }
        if first_package.is_none() {
            if last_package.elapsed() > config.first_package_timeout {
                return format!(
                    "no first package within {} ms of START",
                    config.first_package_timeout.as_millis()
                );
            }
        } else if last_package.elapsed() > stall {
            return format!(
                "stall: no package for {:.1} ms ({} periods at {} Hz)",
                last_package.elapsed().as_secs_f64() * 1e3,
                config.stall_periods,
                config.frequency_hz
            );
        }
    }
}
