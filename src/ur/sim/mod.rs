//! A UR5e simulator on loopback TCP (docs/protocols.md C, C8): an RTDE server, a Dashboard
//! server with the replies of C6 (Local-mode refusals included), and a script port that runs
//! `movel` with a trapezoidal velocity profile, so the TCP pose evolves in time and appears in
//! RTDE.
//!
//! It has no kinematics: `actual_q` is a fixed joint vector, and any pose is reachable.
//!
//! Seeded faults ([`Faults`]): jitter on RTDE send times, a stall (socket open, no data),
//! kill and restart of the RTDE server, a protective stop a given time into a given move, a
//! controller clock offset and drift, fieldbus-held input registers (`IN_USE`), a late first
//! package, and a close right after START.

mod dashboard_server;
pub mod rtde_server;
pub mod script;
pub mod state;

use std::io::Read as _;
use std::net::{SocketAddr, TcpListener, TcpStream};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use state::ArmState;

/// Faults the simulator injects; change them while it runs with [`UrSim::set_faults`].
#[derive(Debug, Clone, Default)]
pub struct Faults {
    pub seed: u64,
    /// Each RTDE package is sent up to this late (uniform), seconds.
    pub jitter_s: f64,
    /// RTDE sends nothing until this instant (sockets stay open).
    pub stall_until: Option<Instant>,
    /// Input registers 0–23 answer `IN_USE`.
    pub fieldbus_holds_registers: bool,
    /// Refuse protocol version 2, as a controller older than 3.2 would.
    pub protocol_v1_only: bool,
    /// The first data package after START comes this much late, seconds (Nagle on the
    /// controller's side is enough for 40 ms).
    pub first_package_delay_s: f64,
    /// Close the connection right after accepting START, as a controller that fails just
    /// after setup would.
    pub close_after_start: bool,
}

/// The TCP pose at an instant, where the arm's motion decides it.
pub type PoseOracle = Arc<dyn Fn(Instant) -> Option<[f64; 6]> + Send + Sync>;

/// Where and how the simulator starts.
#[derive(Debug, Clone, PartialEq)]
pub struct UrSimConfig {
    pub rtde: SocketAddr,
    pub dashboard: SocketAddr,
    pub script: SocketAddr,
    pub start_pose: [f64; 6],
    pub remote_control: bool,
    pub clock_offset_s: f64,
    pub clock_drift_ppm: f64,
    /// `(move index, seconds into it)`: a protective stop.
    pub protective_stop: Option<(u64, f64)>,
    /// `(move index, seconds into it)`: from then until the move ends, every RTDE input package
    /// is lost (so a program's watchdog trips).
    pub input_loss: Option<(u64, f64)>,
}

impl Default for UrSimConfig {
    fn default() -> Self {
        let at = |port| SocketAddr::from(([127, 0, 0, 1], port));
        Self {
            rtde: at(30004),
            dashboard: at(29999),
            script: at(30002),
            start_pose: [0.45, -0.20, 0.35, 0.0, std::f64::consts::PI, 0.0],
            remote_control: true,
            clock_offset_s: 0.0,
            clock_drift_ppm: 0.0,
            protective_stop: None,
            input_loss: None,
        }
    }
}

/// Why the simulator could not start.
#[derive(Debug, thiserror::Error)]
pub enum UrSimError {
    #[error("the UR5e simulator binds loopback addresses only; {field} = {addr} is not one")]
    NotLoopback {
        field: &'static str,
        addr: SocketAddr,
    },
    #[error("cannot bind the simulator's {what} port {addr}: {source}")]
    Bind {
        what: &'static str,
        addr: SocketAddr,
        #[source]
        source: std::io::Error,
    },
}

struct Server {
    addr: SocketAddr,
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
}

impl Server {
    fn spawn(
        what: &'static str,
        addr: SocketAddr,
        handler: Arc<dyn Fn(TcpStream, Arc<AtomicBool>) + Send + Sync>,
    ) -> Result<Self, UrSimError> {
        let listener =
            TcpListener::bind(addr).map_err(|source| UrSimError::Bind { what, addr, source })?;
        let addr =
            listener
                .local_addr()
                .map_err(|source| UrSimError::Bind { what, addr, source })?;
        listener.set_nonblocking(true).ok();
        let stop = Arc::new(AtomicBool::new(false));
        let thread = {
            let stop = stop.clone();
            std::thread::Builder::new()
                .name(format!("ur-sim-{what}"))
                .spawn(move || {
                    let mut connections = Vec::new();
                    while !stop.load(Ordering::Relaxed) {
                        match listener.accept() {
                            Ok((stream, _)) => {
                                stream.set_nonblocking(false).ok();
                                let (h, s) = (handler.clone(), stop.clone());
                                connections.push(std::thread::spawn(move || h(stream, s)));
                            }
                            Err(_) => std::thread::sleep(Duration::from_millis(5)),
                        }
                    }
                    for c in connections {
                        c.join().ok();
                    }
                })
                .map_err(|source| UrSimError::Bind { what, addr, source })?
        };
        Ok(Self {
            addr,
            stop,
            thread: Some(thread),
        })
    }

    fn shutdown(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            t.join().ok();
        }
    }
}

impl Drop for Server {
    fn drop(&mut self) {
        self.shutdown();
    }
}

/// The running simulator.
pub struct UrSim {
    arm: Arc<Mutex<ArmState>>,
    faults: Arc<Mutex<Faults>>,
    rtde: Option<Server>,
    rtde_addr: SocketAddr,
    dashboard: Server,
    script: Server,
}

impl UrSim {
    /// Binds the three ports (loopback only) and starts serving.
    pub fn spawn(config: &UrSimConfig, faults: Faults) -> Result<Self, UrSimError> {
        for (field, addr) in [
            ("rtde", config.rtde),
            ("dashboard", config.dashboard),
            ("script", config.script),
        ] {
            if !addr.ip().is_loopback() {
                return Err(UrSimError::NotLoopback { field, addr });
            }
        }
        let mut arm = ArmState::new(config.start_pose);
        arm.remote_control = config.remote_control;
        arm.clock_offset_s = config.clock_offset_s;
        arm.clock_drift_ppm = config.clock_drift_ppm;
        arm.protective_stop = config.protective_stop;
        arm.input_loss = config.input_loss;
        let arm = Arc::new(Mutex::new(arm));
        let faults = Arc::new(Mutex::new(faults));
        let rtde = Self::rtde_server(config.rtde, &arm, &faults)?;
        let rtde_addr = rtde.addr;
        let dashboard = {
            let arm = arm.clone();
            Server::spawn(
                "dashboard",
                config.dashboard,
                Arc::new(move |s, stop| dashboard_server::serve(s, arm.clone(), stop)),
            )?
        };
        let script = {
            let arm = arm.clone();
            Server::spawn(
                "script",
                config.script,
                Arc::new(move |s, stop| serve_script(s, arm.clone(), stop)),
            )?
        };
        Ok(Self {
            arm,
            faults,
            rtde: Some(rtde),
            rtde_addr,
            dashboard,
            script,
        })
    }

    fn rtde_server(
        addr: SocketAddr,
        arm: &Arc<Mutex<ArmState>>,
        faults: &Arc<Mutex<Faults>>,
    ) -> Result<Server, UrSimError> {
        let (arm, faults) = (arm.clone(), faults.clone());
        Server::spawn(
            "rtde",
            addr,
            Arc::new(move |s, stop| rtde_server::serve(s, arm.clone(), faults.clone(), stop)),
        )
    }

    pub fn rtde_addr(&self) -> SocketAddr {
        self.rtde_addr
    }

    pub fn dashboard_addr(&self) -> SocketAddr {
        self.dashboard.addr
    }

    pub fn script_addr(&self) -> SocketAddr {
        self.script.addr
    }

    /// The arm's state now (pose, modes, moves started, registers). The state evolves in
    /// time whether or not anyone watches: reading it advances it to the present.
    pub fn arm(&self) -> ArmState {
        let mut a = self.arm.lock().unwrap_or_else(|p| p.into_inner());
        let now_s = a.host_s(Instant::now());
        a.advance(now_s);
        a.clone()
    }

    /// A function giving the TCP pose at any instant the arm's motion already decides
    /// ([`ArmState::pose_at`]): what a simulated radar riding on the flange sees from.
    pub fn pose_oracle(&self) -> PoseOracle {
        let arm = self.arm.clone();
        Arc::new(move |at: Instant| {
            let mut a = arm.lock().unwrap_or_else(|p| p.into_inner());
            let now_s = a.host_s(Instant::now());
            a.advance(now_s);
            // Instants before boot are clamped to it by `host_s`; measure them signed.
            let t_s = crate::netio::signed_seconds(at, a.boot);
            a.pose_at(t_s, now_s)
        })
    }

    /// Changes the faults in flight.
    pub fn set_faults(&self, change: impl FnOnce(&mut Faults)) {
        if let Ok(mut f) = self.faults.lock() {
            change(&mut f);
        }
    }

    /// Kills the RTDE server: its listener and every client connection close.
    pub fn kill_rtde(&mut self) {
        if let Some(mut s) = self.rtde.take() {
            s.shutdown();
        }
    }

    /// Restarts the RTDE server on the same port.
    pub fn restart_rtde(&mut self) -> Result<(), UrSimError> {
        self.kill_rtde();
        self.rtde = Some(Self::rtde_server(self.rtde_addr, &self.arm, &self.faults)?);
        Ok(())
    }

    /// Switches Remote/Local control, as the teach pendant does.
    pub fn set_remote_control(&self, remote: bool) {
        if let Ok(mut a) = self.arm.lock() {
            a.remote_control = remote;
        }
    }
}

/// The script port: statements run as they arrive; ignored in Local mode (C, fact 9).
fn serve_script(mut stream: TcpStream, arm: Arc<Mutex<ArmState>>, stop: Arc<AtomicBool>) {
    stream
        .set_read_timeout(Some(Duration::from_millis(50)))
        .ok();
    let mut pending = String::new();
    let mut buf = [0u8; 4096];
    while !stop.load(Ordering::Relaxed) {
        match stream.read(&mut buf) {
            Ok(0) => return,
            Ok(n) => pending.push_str(&String::from_utf8_lossy(&buf[..n])),
            Err(e) if crate::netio::is_would_block(&e) => continue,
            Err(_) => return,
        }
        while let Some(end) = pending.find('\n') {
            let line: String = pending.drain(..=end).collect();
            let Ok(mut a) = arm.lock() else {
                return;
            };
            if !a.remote_control {
                continue;
            }
            let now = Instant::now();
            match script::parse_line(&line) {
                Some(script::Statement::Movel {
                    pose,
                    accel_m_per_s2,
                    speed_m_per_s,
                }) => {
                    a.start_move(pose, speed_m_per_s, accel_m_per_s2, now);
                }
                Some(script::Statement::Stopl) => a.stop(now),
                Some(script::Statement::Watchdog {
                    variable,
                    min_frequency_hz,
                }) => a.set_watchdog(variable, min_frequency_hz, now),
                None => {}
            }
        }
    }
}
