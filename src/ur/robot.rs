//! The [`Robot`] trait and [`UrRobot`], its implementation over the Dashboard, the secondary
//! script port (30002, C5 option 1) and RTDE.
//!
//! A row is driven in two moves: a `movel` to the row's start, then a small program that arms
//! the RTDE watchdog on `input_int_register_24` (at least 10 Hz, action "stop") and runs the
//! row's `movel`. While a row runs, the client writes an incrementing counter to that register
//! every [`WATCHDOG_KICK`], so the robot stops by itself if mmnormd dies or stalls for longer
//! than the watchdog's 100 ms. A row is confirmed finished through RTDE: `runtime_state` back to
//! STOPPED after PLAYING, and the pose at the target. A program that ends with the pose short of
//! the target (a watchdog trip, a stop from the pendant) ends the row at that package as
//! [`RowOutcome::StoppedShort`], for the scan to drive it again. A safety stop in the stream
//! (protective stop, safeguard stop, e-stop) ends the row at the first package that shows it,
//! and nothing here ever unlocks it.

use std::io::Write as _;
use std::net::{SocketAddr, TcpStream};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use super::dashboard::{DashboardClient, DashboardError, RobotMode, SafetyStatus};
use super::motion::{Row, ScanSpec, movel_script};
use super::rtde::{RtdeClient, RtdeConfig, RtdeError, RtdeEvent, Sample, Value};

/// Why the robot could not do what was asked.
#[derive(Debug, thiserror::Error)]
pub enum RobotError {
    #[error(transparent)]
    Dashboard(#[from] DashboardError),
    #[error(transparent)]
    Rtde(#[from] RtdeError),
    #[error("script port {addr}: {source}")]
    Script {
        addr: SocketAddr,
        #[source]
        source: std::io::Error,
    },
    #[error("{what} did not finish within {waited_s:.1} s")]
    Timeout { what: String, waited_s: f64 },
    #[error("the RTDE output recipe lacks `{0}`, which driving rows needs")]
    MissingField(&'static str),
    #[error("the robot is not ready: robot mode {mode}, safety {safety}")]
    NotReady { mode: String, safety: String },
}

/// What `mmnormd robot status` shows.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct RobotStatus {
    pub robot_mode: RobotMode,
    pub safety: SafetyStatus,
    pub remote_control: bool,
    pub tcp_pose: Option<[f64; 6]>,
}

/// How a row ended.
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub enum RowOutcome {
    /// The default, for recordings made before the outcome was written.
    #[default]
    Completed,
    /// A safety stop appeared in the stream; the scan must pause. It is never unlocked here.
    SafetyStop {
        safety: SafetyStatus,
        /// Controller time of the first package that showed it.
        at_controller_s: Option<f64>,
        /// From that package's arrival to the decision to pause, milliseconds.
        decided_after_ms: f64,
    },
    /// Stopped on request (`abort`) with `stopl` before the move ended.
    Aborted,
    /// The program ended (`runtime_state` STOPPED after PLAYING) with the TCP short of the
    /// target and no safety stop: the RTDE watchdog tripped, or someone stopped the program.
    StoppedShort {
        /// From the TCP where the program ended to the target, metres.
        short_of_target_m: f64,
    },
}

/// One driven row: its RTDE samples and how it ended.
#[derive(Debug, Clone, PartialEq)]
pub struct RowRecord {
    pub index: usize,
    pub samples: Vec<Sample>,
    pub outcome: RowOutcome,
    /// The constant-velocity stretch along x (from the plan).
    pub usable_x_m: (f64, f64),
    /// RTDE gaps (stalls, reconnects) during the row.
    pub gaps: usize,
}

/// An arm that drives raster rows.
pub trait Robot {
    fn status(&mut self) -> Result<RobotStatus, RobotError>;
    /// Moves to `pose` at the spec's speed (nothing when already there). Setting `abort`
    /// stops the arm at once and ends the move as [`RowOutcome::Aborted`].
    fn move_to(
        &mut self,
        pose: &[f64; 6],
        spec: &ScanSpec,
        abort: &AtomicBool,
    ) -> Result<RowOutcome, RobotError>;
    /// Drives one row: to its start, then along it at the spec's speed; `abort` as for
    /// [`move_to`](Self::move_to). Each of the row's RTDE samples also goes to `on_sample` as
    /// it arrives.
    fn drive_row(
        &mut self,
        row: &Row,
        spec: &ScanSpec,
        abort: &AtomicBool,
        on_sample: &mut dyn FnMut(&Sample),
    ) -> Result<RowRecord, RobotError>;
    /// Stops motion now.
    fn stop(&mut self) -> Result<(), RobotError>;
    /// The instant that samples' `host_s` count from.
    fn epoch(&self) -> Instant;
    /// RTDE output names, in the order of each sample's values.
    fn output_names(&self) -> Vec<String>;
}

/// Addresses of a UR controller.
#[derive(Debug, Clone, PartialEq)]
pub struct UrAddresses {
    pub dashboard: SocketAddr,
    pub script: SocketAddr,
    pub rtde: RtdeConfig,
}

/// The real arm (or the simulator) over TCP.
pub struct UrRobot {
    dashboard: DashboardClient,
    script: TcpStream,
    script_addr: SocketAddr,
    rtde: RtdeClient,
    latest: Option<Sample>,
    gaps: usize,
    watchdog_counter: i32,
    at: FieldIndex,
}

struct FieldIndex {
    timestamp: usize,
    pose: usize,
    runtime: usize,
    safety: usize,
    /// `actual_TCP_speed`, when in the recipe.
    speed: Option<usize>,
}

/// Pose within this distance of a target counts as at the target, metres.
const AT_TARGET_M: f64 = 0.0005;

/// How often a running move writes the watchdog register. The programs ask for at least 10 Hz,
/// so one kick may be late by up to 80 ms (a busy host) before the robot stops.
pub const WATCHDOG_KICK: Duration = Duration::from_millis(20);

/// `runtime_state` codes (docs/protocols.md C4).
const RUNTIME_STOPPED: i64 = 1;
const RUNTIME_PLAYING: i64 = 2;

fn pose_of(s: &Sample, i: usize) -> Option<[f64; 6]> {
    match s.values.get(i) {
        Some(Value::Vector6d(p)) => Some(*p),
        _ => None,
    }
}

fn int_of(s: &Sample, i: usize) -> Option<i64> {
    match s.values.get(i) {
        Some(Value::Int32(v)) => Some(i64::from(*v)),
        Some(Value::Uint32(v)) => Some(i64::from(*v)),
        _ => None,
    }
}

fn distance_m(a: &[f64; 6], b: &[f64; 6]) -> f64 {
    (0..3).map(|i| (a[i] - b[i]).powi(2)).sum::<f64>().sqrt()
}

impl UrRobot {
    /// Connects the Dashboard, the script port and RTDE, and waits for the first package.
    pub fn connect(addresses: &UrAddresses) -> Result<Self, RobotError> {
        let timeout = addresses.rtde.connect_timeout;
        let dashboard = DashboardClient::connect(addresses.dashboard, timeout)?;
        let script = TcpStream::connect_timeout(&addresses.script, timeout).map_err(|source| {
            RobotError::Script {
                addr: addresses.script,
                source,
            }
        })?;
        let find = |name: &'static str| {
            addresses
                .rtde
                .outputs
                .iter()
                .position(|n| n == name)
                .ok_or(RobotError::MissingField(name))
        };
        let at = FieldIndex {
            timestamp: find("timestamp")?,
            pose: find("actual_TCP_pose")?,
            runtime: find("runtime_state")?,
            safety: find("safety_mode")?,
            speed: find("actual_TCP_speed").ok(),
        };
        let rtde = RtdeClient::spawn(addresses.rtde.clone());
        let mut robot = Self {
            dashboard,
            script,
            script_addr: addresses.script,
            rtde,
            latest: None,
            gaps: 0,
            watchdog_counter: 0,
            at,
        };
        let start = Instant::now();
        while robot.latest.is_none() {
            robot.pump(Duration::from_millis(50), &mut Vec::new())?;
            if start.elapsed() > timeout * 2 {
                return Err(RobotError::Timeout {
                    what: "the first RTDE package".into(),
                    waited_s: start.elapsed().as_secs_f64(),
                });
            }
        }
        Ok(robot)
    }

    /// The RTDE client (for its epoch and field names).
    pub fn rtde(&self) -> &RtdeClient {
        &self.rtde
    }

    /// Waits up to `wait` for the next event, then takes every event already queued, appending
    /// samples to `into`. Returns as soon as something arrived, so callers see each package
    /// within microseconds of its arrival.
    fn pump(&mut self, wait: Duration, into: &mut Vec<Sample>) -> Result<(), RobotError> {
        let mut first = true;
        loop {
            let event = if first {
                first = false;
                self.rtde.events().recv_timeout(wait).ok()
            } else {
                self.rtde.events().try_recv().ok()
            };
            let Some(event) = event else {
                return Ok(());
            };
            match event {
                RtdeEvent::Sample(s) => {
                    into.push(s.clone());
                    self.latest = Some(s);
                }
                RtdeEvent::Gap { reason, .. } => {
                    tracing::warn!("RTDE gap: {reason}");
                    self.gaps += 1;
                }
                RtdeEvent::Failed(e) => return Err(e.into()),
                RtdeEvent::Connected { .. } | RtdeEvent::Text { .. } => {}
            }
        }
    }

    fn send_script(&mut self, text: &str) -> Result<(), RobotError> {
        self.script
            .write_all(text.as_bytes())
            .map_err(|source| RobotError::Script {
                addr: self.script_addr,
                source,
            })
    }

    fn kick_watchdog(&mut self) {
        self.watchdog_counter = self.watchdog_counter.wrapping_add(1);
        self.rtde
            .send_inputs(vec![Value::Int32(self.watchdog_counter)]);
    }

    /// Sends `script`, then follows RTDE until the move reaches `target` and stops, a safety stop
    /// shows, or `timeout` passes.
    fn run_move(
        &mut self,
        script: &str,
        target: &[f64; 6],
        timeout: Duration,
        samples: &mut Vec<Sample>,
        abort: &AtomicBool,
        on_sample: &mut dyn FnMut(&Sample),
    ) -> Result<RowOutcome, RobotError> {
        let first = samples.len();
        self.kick_watchdog();
        self.send_script(script)?;
        let start = Instant::now();
        let mut last_kick = Instant::now();
        let mut seen_playing = false;
        let mut checked = first;
        loop {
            self.pump(Duration::from_millis(10), samples)?;
            samples.iter().skip(checked).for_each(&mut *on_sample);
            if abort.load(Ordering::Relaxed) {
                self.send_script("stopl(2.0)\n")?;
                self.await_standstill(samples, on_sample)?;
                return Ok(RowOutcome::Aborted);
            }
            if last_kick.elapsed() >= WATCHDOG_KICK {
                self.kick_watchdog();
                last_kick = Instant::now();
            }
            for (k, s) in samples.iter().enumerate().skip(checked) {
                let safety = int_of(s, self.at.safety)
                    .and_then(|c| SafetyStatus::from_code(c as i32))
                    .unwrap_or(SafetyStatus::Undefined);
                if safety.is_stop() {
                    let decided_s = self.rtde.epoch().elapsed().as_secs_f64();
                    let outcome = RowOutcome::SafetyStop {
                        safety,
                        at_controller_s: s.controller_s,
                        decided_after_ms: (decided_s - s.host_s) * 1e3,
                    };
                    // The row's data ends at the package that showed the stop.
                    samples.truncate(k + 1);
                    return Ok(outcome);
                }
                let runtime = int_of(s, self.at.runtime).unwrap_or(0);
                let ended = seen_playing && runtime == RUNTIME_STOPPED;
                seen_playing |= runtime == RUNTIME_PLAYING;
                let to_target_m = pose_of(s, self.at.pose).map(|p| distance_m(&p, target));
                let at_target = to_target_m.is_some_and(|d| d < AT_TARGET_M);
                // PLAYING can only be missed by a move shorter than a period; allow for it after
                // 200 ms.
                let settled = seen_playing || start.elapsed() > Duration::from_millis(200);
                if at_target && runtime == RUNTIME_STOPPED && settled {
                    return Ok(RowOutcome::Completed);
                }
                if ended && let Some(short_of_target_m) = to_target_m {
                    // The row's data ends at the package that showed the program ended.
                    samples.truncate(k + 1);
                    return Ok(RowOutcome::StoppedShort { short_of_target_m });
                }
            }
            checked = samples.len();
            if start.elapsed() > timeout {
                return Err(RobotError::Timeout {
                    what: format!("the move to {target:?}"),
                    waited_s: start.elapsed().as_secs_f64(),
                });
            }
        }
    }
}

impl Robot for UrRobot {
    fn status(&mut self) -> Result<RobotStatus, RobotError> {
        self.pump(Duration::from_millis(20), &mut Vec::new())?;
        Ok(RobotStatus {
            robot_mode: self.dashboard.robot_mode()?,
            safety: self.dashboard.safety_status()?,
            remote_control: self.dashboard.is_in_remote_control()?,
            tcp_pose: self.latest.as_ref().and_then(|s| pose_of(s, self.at.pose)),
        })
    }

    fn drive_row(
        &mut self,
        row: &Row,
        spec: &ScanSpec,
        abort: &AtomicBool,
        on_sample: &mut dyn FnMut(&Sample),
    ) -> Result<RowRecord, RobotError> {
        self.check_ready()?;
        let gaps_before = self.gaps;
        let approach = self.approach(&row.start_pose, spec, abort)?;
        if approach != RowOutcome::Completed {
            let outcome = approach;
            return Ok(RowRecord {
                index: row.index,
                samples: Vec::new(),
                outcome,
                usable_x_m: row.usable_x_m,
                gaps: self.gaps - gaps_before,
            });
        }
        let program = format!(
            "def mmnorm_row_{}():\n  rtde_set_watchdog(\"input_int_register_24\", 10, \"stop\")\n  {}end\n",
            row.index,
            row.urscript(spec.speed_m_per_s, spec.accel_m_per_s2)
        );
        let mut samples = Vec::new();
        let timeout = Duration::from_secs_f64(row.duration_s * 1.5 + 5.0);
        let outcome = self.run_move(
            &program,
            &row.end_pose,
            timeout,
            &mut samples,
            abort,
            on_sample,
        )?;
        Ok(RowRecord {
            index: row.index,
            samples,
            outcome,
            usable_x_m: row.usable_x_m,
            gaps: self.gaps - gaps_before,
        })
    }

    fn move_to(
        &mut self,
        pose: &[f64; 6],
        spec: &ScanSpec,
        abort: &AtomicBool,
    ) -> Result<RowOutcome, RobotError> {
        self.check_ready()?;
        self.approach(pose, spec, abort)
    }

    fn stop(&mut self) -> Result<(), RobotError> {
        self.send_script("stopl(2.0)\n")?;
        Ok(())
    }

    fn epoch(&self) -> Instant {
        self.rtde.epoch()
    }

    fn output_names(&self) -> Vec<String> {
        self.rtde.output_names().to_vec()
    }
}

impl UrRobot {
    /// Refuses motion in Local mode (script would be silently ignored, docs/protocols.md §0
    /// fact 9) and outside Running or under a safety stop.
    fn check_ready(&mut self) -> Result<(), RobotError> {
        let status = self.status()?;
        if !status.remote_control {
            return Err(DashboardError::LocalMode.into());
        }
        if status.robot_mode != RobotMode::Running || status.safety.is_stop() {
            return Err(RobotError::NotReady {
                mode: status.robot_mode.name().into(),
                safety: status.safety.name().into(),
            });
        }
        Ok(())
    }

    /// A plain `movel` to `p` unless the TCP is already within 0.5 mm of it.
    fn approach(
        &mut self,
        p: &[f64; 6],
        spec: &ScanSpec,
        abort: &AtomicBool,
    ) -> Result<RowOutcome, RobotError> {
        let here = self
            .latest
            .as_ref()
            .and_then(|s| pose_of(s, self.at.pose))
            .unwrap_or(*p);
        if distance_m(&here, p) < AT_TARGET_M {
            return Ok(RowOutcome::Completed);
        }
        let t = Duration::from_secs_f64(
            distance_m(&here, p) / spec.speed_m_per_s
                + spec.speed_m_per_s / spec.accel_m_per_s2
                + 5.0,
        );
        let script = movel_script(p, spec.speed_m_per_s, spec.accel_m_per_s2);
        self.run_move(&script, p, t, &mut Vec::new(), abort, &mut |_| {})
    }

    /// After a `stopl`, follows RTDE until the TCP speed is below 1 mm/s (at most 500 ms), so
    /// that the recording shows the arm at rest.
    fn await_standstill(
        &mut self,
        samples: &mut Vec<Sample>,
        on_sample: &mut dyn FnMut(&Sample),
    ) -> Result<(), RobotError> {
        let speed_at = self.at.speed;
        let started = Instant::now();
        while started.elapsed() < Duration::from_millis(500) {
            let before = samples.len();
            self.pump(Duration::from_millis(10), samples)?;
            samples.iter().skip(before).for_each(&mut *on_sample);
            let resting =
                samples
                    .iter()
                    .skip(before)
                    .any(|s| match speed_at.and_then(|i| s.values.get(i)) {
                        Some(Value::Vector6d(v)) => {
                            (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt() < 0.001
                        }
                        _ => false,
                    });
            if resting {
                break;
            }
        }
        Ok(())
    }

    /// Takes every RTDE event queued since the last call (between scans nothing else reads
    /// them; the stream must be read continuously, docs/protocols.md §0 fact 7).
    pub fn drain_events(&mut self) -> Result<(), RobotError> {
        self.pump(Duration::ZERO, &mut Vec::new())
    }

    /// The index of the `timestamp` field in samples.
    pub fn timestamp_index(&self) -> usize {
        self.at.timestamp
    }

    /// The index of `actual_TCP_pose` in samples.
    pub fn pose_index(&self) -> usize {
        self.at.pose
    }
}
