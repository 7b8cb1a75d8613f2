//! The control port and the daemon's life cycle.

use std::net::SocketAddr;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use serde_json::json;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::{broadcast, mpsc};

use super::protocol::{Decoded, LineDecoder, Request, error_reply, parse_request};
use super::worker::{
    Shared, Status, list_scans, prepare_scan, run_reconstruct_job, run_scan_job, scan_dir,
};
use crate::lab::LabConfig;
use crate::lab::devices::LabDevices;
use crate::lab::job::truth_of;
use crate::lab::scan::ScanSetup;
use crate::lab::simlab::SimLab;

/// Why the daemon could not start or stopped.
#[derive(Debug, thiserror::Error)]
pub enum DaemonError {
    #[error("{0}")]
    Setup(String),
    #[error("control.bind = {addr}: {source}")]
    Bind {
        addr: SocketAddr,
        #[source]
        source: std::io::Error,
    },
}

/// Replies and events waiting for one client; a client this far behind is disconnected.
const CLIENT_QUEUE: usize = 1024;
/// A write to a client that takes longer than this disconnects it.
const WRITE_TIMEOUT: Duration = Duration::from_secs(2);
/// How long shutdown waits for a running job to stop before exiting anyway.
const SHUTDOWN_WAIT: Duration = Duration::from_millis(1500);

/// A started daemon: devices up, port bound.
pub struct Daemon {
    shared: Arc<Shared>,
    listener: TcpListener,
    clients: Arc<AtomicUsize>,
}

/// A message for systemd.
enum Notice {
    Ready(String),
    Watchdog(String),
    Stopping,
}

/// Sends notices to systemd from its own thread: a blocked notify socket must not stall the
/// control port. Notices beyond a short queue are dropped (the next watchdog ping follows).
struct Notifier {
    queue: std::sync::mpsc::SyncSender<Notice>,
    /// Closed by the thread once the queue is closed and every notice sent.
    done: std::sync::mpsc::Receiver<()>,
}

impl Notifier {
    /// None outside systemd (no `NOTIFY_SOCKET`) or when the thread cannot start.
    fn start() -> Option<Notifier> {
        std::env::var_os("NOTIFY_SOCKET")?;
        let (queue, rx) = std::sync::mpsc::sync_channel::<Notice>(16);
        let (done_tx, done) = std::sync::mpsc::channel::<()>();
        let spawned = std::thread::Builder::new()
            .name("sd-notify".into())
            .spawn(move || {
                let _done = done_tx;
                let mut warned = false;
                for notice in rx {
                    use sd_notify::NotifyState as N;
                    let sent = match &notice {
                        Notice::Ready(status) => sd_notify::notify(&[N::Ready, N::Status(status)]),
                        Notice::Watchdog(status) => {
                            sd_notify::notify(&[N::Watchdog, N::Status(status)])
                        }
                        Notice::Stopping => sd_notify::notify(&[N::Stopping]),
                    };
                    if let Err(e) = sent
                        && !warned
                    {
                        warned = true;
                        tracing::warn!("sd_notify: {e} (further failures are not logged)");
                    }
                }
            });
        spawned.ok().map(|_| Notifier { queue, done })
    }

    fn send(&self, notice: Notice) {
        self.queue.try_send(notice).ok();
    }

    /// Closes the queue and waits, at most `limit`, for the notices in it to go out.
    fn finish(self, limit: Duration) {
        drop(self.queue);
        // Disconnected (the thread ended) or timed out: either way, stop waiting.
        self.done.recv_timeout(limit).ok();
    }
}

impl Daemon {
    /// Checks the scan config against the profile, starts the simulated lab when the config
    /// says so, connects the devices and binds the control port.
    pub async fn start(lab: LabConfig, quiet: bool) -> Result<Self, DaemonError> {
        let setup = ScanSetup::new(&lab, lab.scan.clone())
            .map_err(|e| DaemonError::Setup(e.to_string()))?;
        let bind = lab.control.bind;
        let listener = TcpListener::bind(bind)
            .await
            .map_err(|source| DaemonError::Bind { addr: bind, source })?;
        let lab_for_devices = lab.clone();
        let (sim, devices) = tokio::task::spawn_blocking(move || {
            let lab = lab_for_devices;
            let sim = if lab.simulate {
                Some(
                    SimLab::start(&lab, &setup, None)
                        .map_err(|e| DaemonError::Setup(format!("the simulated lab: {e}")))?,
                )
            } else {
                None
            };
            let devices = LabDevices::connect(&lab, &setup.profile)
                .map_err(|e| DaemonError::Setup(e.to_string()))?;
            Ok::<_, DaemonError>((sim, devices))
        })
        .await
        .map_err(|e| DaemonError::Setup(e.to_string()))??;
        let truth = sim.as_ref().map(|s| truth_of(&s.truth_mesh));
        let (events, _) = broadcast::channel(4096);
        let shared = Arc::new(Shared {
            status: Mutex::new(Status {
                state: "idle".into(),
                simulated: lab.simulate,
                ..Status::default()
            }),
            lab,
            events,
            abort: Default::default(),
            busy: Default::default(),
            started: Instant::now(),
            quiet,
            devices: Mutex::new(Some(devices)),
            sim,
            truth,
        });
        Ok(Self {
            shared,
            listener,
            clients: Arc::new(AtomicUsize::new(0)),
        })
    }

    /// Serves until SIGTERM or SIGINT, then stops cleanly.
    pub async fn serve(self) -> Result<(), DaemonError> {
        let systemd = Notifier::start();
        let notify = |n: Notice| {
            if let Some(s) = &systemd {
                s.send(n);
            }
        };
        notify(Notice::Ready("idle".into()));
        tracing::info!(
            "mmnormd ready on {} ({})",
            self.shared.lab.control.bind,
            if self.shared.lab.simulate {
                "simulated lab"
            } else {
                "lab devices"
            }
        );
        let watchdog = sd_notify::watchdog_enabled().map(|d| d / 2);
        let mut ping = tokio::time::interval(watchdog.unwrap_or(Duration::from_secs(3600)));
        let mut term = signal(tokio::signal::unix::SignalKind::terminate())?;
        let mut int = signal(tokio::signal::unix::SignalKind::interrupt())?;
        let mut idle = tokio::time::interval(IDLE_DRAIN);
        loop {
            tokio::select! {
                _ = idle.tick() => {
                    // Between jobs, keep reading the RTDE stream the robot sends.
                    let shared = self.shared.clone();
                    tokio::task::spawn_blocking(move || drain_idle(&shared));
                }
                _ = term.recv() => break,
                _ = int.recv() => break,
                _ = ping.tick(), if watchdog.is_some() => {
                    let s = self.shared.status();
                    notify(Notice::Watchdog(format!("{} {}", s.state, s.scan.unwrap_or_default())));
                }
                accepted = self.listener.accept() => {
                    let Ok((stream, _)) = accepted else { continue };
                    let shared = self.shared.clone();
                    let clients = self.clients.clone();
                    if clients.fetch_add(1, Ordering::AcqRel) >= shared.lab.control.max_clients {
                        clients.fetch_sub(1, Ordering::AcqRel);
                        tokio::spawn(refuse(stream));
                        continue;
                    }
                    tokio::spawn(async move {
                        client(stream, shared).await;
                        clients.fetch_sub(1, Ordering::AcqRel);
                    });
                }
            }
        }
        notify(Notice::Stopping);
        self.shutdown().await;
        if let Some(s) = systemd {
            // STOPPING=1 goes out before the process ends, unless the socket is stuck.
            tokio::task::spawn_blocking(move || s.finish(Duration::from_millis(200)))
                .await
                .ok();
        }
        Ok(())
    }

    /// Aborts a running job (the arm stops first), waits for the recording to be finished,
    /// and stops an idle arm too.
    async fn shutdown(&self) {
        let started = Instant::now();
        self.shared
            .abort
            .store(true, std::sync::atomic::Ordering::Relaxed);
        {
            let mut s = self.shared.status.lock().unwrap_or_else(|p| p.into_inner());
            s.state = "stopping".into();
        }
        if !self.shared.busy.load(Ordering::Acquire)
            && let Ok(mut d) = self.shared.devices.try_lock()
            && let Some(devices) = d.as_mut()
        {
            use crate::ur::robot::Robot as _;
            devices.robot.stop().ok();
        }
        while self.shared.busy.load(Ordering::Acquire) && started.elapsed() < SHUTDOWN_WAIT {
            tokio::time::sleep(Duration::from_millis(5)).await;
        }
        let waited = started.elapsed().as_secs_f64();
        if self.shared.busy.load(Ordering::Acquire) {
            tracing::error!("the running job did not stop within {waited:.2} s; exiting anyway");
        } else {
            tracing::info!("stopped in {waited:.3} s");
        }
    }
}

/// How often the RTDE queue is drained between jobs.
const IDLE_DRAIN: Duration = Duration::from_millis(200);

fn drain_idle(shared: &Shared) {
    if shared.busy.load(Ordering::Acquire) {
        return;
    }
    if let Ok(mut d) = shared.devices.try_lock()
        && let Some(devices) = d.as_mut()
        && let Err(e) = devices.robot.drain_events()
    {
        tracing::warn!("robot: {e}");
    }
}

fn signal(
    kind: tokio::signal::unix::SignalKind,
) -> Result<tokio::signal::unix::Signal, DaemonError> {
    tokio::signal::unix::signal(kind)
        .map_err(|e| DaemonError::Setup(format!("installing a signal handler: {e}")))
}

async fn refuse(mut stream: TcpStream) {
    let line = error_reply("too many clients; try again later") + "\n";
    tokio::time::timeout(WRITE_TIMEOUT, stream.write_all(line.as_bytes()))
        .await
        .ok();
}

/// One client: lines in, replies and (after `subscribe`) events out through a bounded queue.
async fn client(stream: TcpStream, shared: Arc<Shared>) {
    stream.set_nodelay(true).ok();
    let (mut rd, mut wr) = stream.into_split();
    let (tx, mut rx) = mpsc::channel::<String>(CLIENT_QUEUE);
    let writer = tokio::spawn(async move {
        while let Some(mut line) = rx.recv().await {
            line.push('\n');
            match tokio::time::timeout(WRITE_TIMEOUT, wr.write_all(line.as_bytes())).await {
                Ok(Ok(())) => {}
                _ => break,
            }
        }
    });
    let mut decoder = LineDecoder::default();
    let mut buf = vec![0u8; 8192];
    let mut subscription: Option<tokio::task::JoinHandle<()>> = None;
    'read: loop {
        let n = match rd.read(&mut buf).await {
            Ok(0) | Err(_) => break,
            Ok(n) => n,
        };
        for decoded in decoder.push(&buf[..n]) {
            let reply = match decoded {
                Decoded::TooLong => {
                    tx.try_send(error_reply("line longer than 64 KiB; closing"))
                        .ok();
                    break 'read;
                }
                Decoded::Line(line) if line.trim().is_empty() => continue,
                Decoded::Line(line) => {
                    match parse_request(&line, shared.lab.control.token.as_deref()) {
                        Err(e) => error_reply(&e.to_string()),
                        Ok(Request::Subscribe) => {
                            if subscription.is_none() {
                                subscription = Some(forward_events(&shared, tx.clone()));
                            }
                            json!({"ok": true, "subscribed": true}).to_string()
                        }
                        Ok(request) => handle(&shared, request).await,
                    }
                }
            };
            // A client that lets its queue fill is not reading: drop it.
            if tx.try_send(reply).is_err() {
                break 'read;
            }
        }
    }
    if let Some(s) = subscription {
        s.abort();
    }
    drop(tx);
    writer.await.ok();
}

/// Copies daemon events into a client's queue until it falls behind.
fn forward_events(shared: &Arc<Shared>, tx: mpsc::Sender<String>) -> tokio::task::JoinHandle<()> {
    let mut events = shared.events.subscribe();
    tokio::spawn(async move {
        loop {
            match events.recv().await {
                Ok(line) => {
                    if tx.try_send(line).is_err() {
                        break;
                    }
                }
                Err(broadcast::error::RecvError::Lagged(n)) => {
                    tx.try_send(error_reply(&format!(
                        "{n} events were dropped: this client reads too slowly; closing"
                    )))
                    .ok();
                    break;
                }
                Err(broadcast::error::RecvError::Closed) => break,
            }
        }
    })
}

async fn handle(shared: &Arc<Shared>, request: Request) -> String {
    match request {
        Request::Status => {
            let status = shared.status();
            // In the simulated lab, the simulators' own counters (what was injected).
            let sim = shared.sim.as_ref().map(|s| {
                let (board, radar) = s.chain.stats();
                json!({"dca1000": board, "radar_cli": radar, "render": s.frames.stats()})
            });
            json!({"ok": true, "status": status, "sim": sim,
                "uptime_s": shared.started.elapsed().as_secs_f64()})
            .to_string()
        }
        Request::Abort => {
            let running = shared.busy.load(Ordering::Acquire);
            if running {
                shared
                    .abort
                    .store(true, std::sync::atomic::Ordering::Relaxed);
            }
            json!({"ok": true, "aborting": running}).to_string()
        }
        Request::List => {
            let dir = shared.lab.recording.data_dir.clone();
            let scans = tokio::task::spawn_blocking(move || list_scans(&dir))
                .await
                .unwrap_or_default();
            json!({"ok": true, "scans": scans}).to_string()
        }
        Request::Scan(request) => {
            if !shared.claim() {
                return error_reply(&busy_message(&shared.status()));
            }
            let prepared = {
                let shared = shared.clone();
                let request = request.clone();
                tokio::task::spawn_blocking(move || prepare_scan(&shared, &request)).await
            };
            match prepared {
                Ok(Ok((setup, name))) => {
                    let rows = setup.plan.rows.len();
                    let reply = json!({"ok": true, "scan": name, "rows": rows}).to_string();
                    let shared = shared.clone();
                    std::thread::spawn(move || run_scan_job(&shared, request, setup, name));
                    reply
                }
                Ok(Err(e)) => {
                    shared.busy.store(false, Ordering::Release);
                    error_reply(&e.to_string())
                }
                Err(e) => {
                    shared.busy.store(false, Ordering::Release);
                    error_reply(&e.to_string())
                }
            }
        }
        Request::Reconstruct { scan } => {
            if let Err(e) = scan_dir(&shared.lab.recording.data_dir, &scan) {
                return error_reply(&e.to_string());
            }
            if !shared.claim() {
                return error_reply(&busy_message(&shared.status()));
            }
            let reply = json!({"ok": true, "reconstructing": scan}).to_string();
            let shared = shared.clone();
            std::thread::spawn(move || run_reconstruct_job(&shared, scan));
            reply
        }
        Request::Subscribe => json!({"ok": true}).to_string(),
    }
}

fn busy_message(s: &Status) -> String {
    format!(
        "busy: {} {}; one job runs at a time",
        s.state,
        s.scan.as_deref().unwrap_or("")
    )
}
