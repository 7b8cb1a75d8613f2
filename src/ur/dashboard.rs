//! The Dashboard server (port 29999; docs/protocols.md C6): one `\n`-terminated line each
//! way, typed replies, and a blocking client.
//!
//! The Local-mode refusal ("Command is not allowed due to safety reasons, please switch robot to
//! Remote Control mode...") becomes [`DashboardError::LocalMode`]. The client never unlocks a
//! protective stop: it has no such command.

use std::io::{BufRead as _, BufReader, Write as _};
use std::net::{SocketAddr, TcpStream};
use std::time::{Duration, Instant};

/// `robotmode` values (C4).
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub enum RobotMode {
    NoController,
    Disconnected,
    ConfirmSafety,
    Booting,
    PowerOff,
    PowerOn,
    Idle,
    Backdrive,
    Running,
    UpdatingFirmware,
}

impl RobotMode {
    const ALL: [(RobotMode, &'static str, i32); 10] = [
        (RobotMode::NoController, "NO_CONTROLLER", -1),
        (RobotMode::Disconnected, "DISCONNECTED", 0),
        (RobotMode::ConfirmSafety, "CONFIRM_SAFETY", 1),
        (RobotMode::Booting, "BOOTING", 2),
        (RobotMode::PowerOff, "POWER_OFF", 3),
        (RobotMode::PowerOn, "POWER_ON", 4),
        (RobotMode::Idle, "IDLE", 5),
        (RobotMode::Backdrive, "BACKDRIVE", 6),
        (RobotMode::Running, "RUNNING", 7),
        (RobotMode::UpdatingFirmware, "UPDATING_FIRMWARE", 8),
    ];

    pub fn name(self) -> &'static str {
        Self::ALL.iter().find(|m| m.0 == self).map_or("", |m| m.1)
    }

    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL.iter().find(|m| m.1 == name).map(|m| m.0)
    }

    /// The RTDE `robot_mode` code.
    pub fn code(self) -> i32 {
        Self::ALL.iter().find(|m| m.0 == self).map_or(-1, |m| m.2)
    }

    pub fn from_code(code: i32) -> Option<Self> {
        Self::ALL.iter().find(|m| m.2 == code).map(|m| m.0)
    }
}

/// `safetystatus` / `safety_mode` values (C4).
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum SafetyStatus {
    Normal,
    Reduced,
    ProtectiveStop,
    Recovery,
    SafeguardStop,
    SystemEmergencyStop,
    RobotEmergencyStop,
    Violation,
    Fault,
    ValidateJointId,
    Undefined,
    AutomaticModeSafeguardStop,
    SystemThreePositionEnablingStop,
}

impl SafetyStatus {
    const ALL: [(SafetyStatus, &'static str, i32); 13] = [
        (SafetyStatus::Normal, "NORMAL", 1),
        (SafetyStatus::Reduced, "REDUCED", 2),
        (SafetyStatus::ProtectiveStop, "PROTECTIVE_STOP", 3),
        (SafetyStatus::Recovery, "RECOVERY", 4),
        (SafetyStatus::SafeguardStop, "SAFEGUARD_STOP", 5),
        (
            SafetyStatus::SystemEmergencyStop,
            "SYSTEM_EMERGENCY_STOP",
            6,
        ),
        (SafetyStatus::RobotEmergencyStop, "ROBOT_EMERGENCY_STOP", 7),
        (SafetyStatus::Violation, "VIOLATION", 8),
        (SafetyStatus::Fault, "FAULT", 9),
        (SafetyStatus::ValidateJointId, "VALIDATE_JOINT_ID", 10),
        (SafetyStatus::Undefined, "UNDEFINED_SAFETY_MODE", 11),
        (
            SafetyStatus::AutomaticModeSafeguardStop,
            "AUTOMATIC_MODE_SAFEGUARD_STOP",
            12,
        ),
        (
            SafetyStatus::SystemThreePositionEnablingStop,
            "SYSTEM_THREE_POSITION_ENABLING_STOP",
            13,
        ),
    ];

    pub fn name(self) -> &'static str {
        Self::ALL.iter().find(|m| m.0 == self).map_or("", |m| m.1)
    }

    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL.iter().find(|m| m.1 == name).map(|m| m.0)
    }

    pub fn code(self) -> i32 {
        Self::ALL.iter().find(|m| m.0 == self).map_or(11, |m| m.2)
    }

    pub fn from_code(code: i32) -> Option<Self> {
        Self::ALL.iter().find(|m| m.2 == code).map(|m| m.0)
    }

    /// Whether motion is stopped by safety (a scan must pause).
    pub fn is_stop(self) -> bool {
        !matches!(self, SafetyStatus::Normal | SafetyStatus::Reduced)
    }
}

/// `programState` replies.
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize)]
pub struct ProgramState {
    pub state: String,
    pub program: String,
}

/// Why a Dashboard exchange failed.
#[derive(Debug, thiserror::Error)]
pub enum DashboardError {
    #[error(
        "the robot is in Local mode: switch the robot to Remote Control (then mmnormd reconnects to port 29999)"
    )]
    LocalMode,
    #[error("Dashboard {addr}: {source}")]
    Io {
        addr: SocketAddr,
        #[source]
        source: std::io::Error,
    },
    #[error(
        "Dashboard {addr}: timed out, no answer within {waited_s:.1} s (is the robot powered, on \
         this network, and is this its address?)"
    )]
    TimedOut { addr: SocketAddr, waited_s: f64 },
    #[error("Dashboard reply to `{command}` was not understood: {reply:?}")]
    Unexpected { command: String, reply: String },
    #[error("`{command}`: the robot did not reach {want} within {waited_s:.0} s (last: {last})")]
    NotReached {
        command: &'static str,
        want: &'static str,
        waited_s: f64,
        last: String,
    },
}

/// The Local-mode refusal's text, as the controller sends it.
pub const LOCAL_MODE_REFUSAL: &str = "Command is not allowed due to safety reasons, please switch robot to Remote Control mode and reconnect to port 29999";

/// Parses `Robotmode: RUNNING`.
pub fn parse_robot_mode(reply: &str) -> Option<RobotMode> {
    RobotMode::from_name(reply.strip_prefix("Robotmode:")?.trim())
}

/// Parses `Safetystatus: NORMAL` (or `Safetymode: NORMAL`).
pub fn parse_safety_status(reply: &str) -> Option<SafetyStatus> {
    let rest = reply
        .strip_prefix("Safetystatus:")
        .or_else(|| reply.strip_prefix("Safetymode:"))?;
    SafetyStatus::from_name(rest.trim())
}

/// Parses `PLAYING prog.urp`.
pub fn parse_program_state(reply: &str) -> Option<ProgramState> {
    let mut words = reply.trim().splitn(2, ' ');
    let state = words.next()?;
    matches!(state, "STOPPED" | "PLAYING" | "PAUSED").then(|| ProgramState {
        state: state.to_string(),
        program: words.next().unwrap_or("").trim().to_string(),
    })
}

/// The error for an IO failure on `addr`: a socket timeout (which Linux reports on a read as
/// "Resource temporarily unavailable") is named as one.
fn io_failure(addr: SocketAddr, timeout: Duration, source: std::io::Error) -> DashboardError {
    match source.kind() {
        std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut => DashboardError::TimedOut {
            addr,
            waited_s: timeout.as_secs_f64(),
        },
        _ => DashboardError::Io { addr, source },
    }
}

/// A connected Dashboard client.
pub struct DashboardClient {
    addr: SocketAddr,
    timeout: Duration,
    reader: BufReader<TcpStream>,
    writer: TcpStream,
    /// The greeting line.
    pub greeting: String,
}

impl DashboardClient {
    /// Connects and reads the greeting.
    pub fn connect(addr: SocketAddr, timeout: Duration) -> Result<Self, DashboardError> {
        let io = |source| io_failure(addr, timeout, source);
        let stream = TcpStream::connect_timeout(&addr, timeout).map_err(io)?;
        stream.set_read_timeout(Some(timeout)).map_err(io)?;
        stream.set_nodelay(true).map_err(io)?;
        let writer = stream.try_clone().map_err(io)?;
        let mut client = Self {
            addr,
            timeout,
            reader: BufReader::new(stream),
            writer,
            greeting: String::new(),
        };
        client.greeting = client.read_line()?;
        Ok(client)
    }

    fn read_line(&mut self) -> Result<String, DashboardError> {
        let mut line = String::new();
        let n = self
            .reader
            .read_line(&mut line)
            .map_err(|source| io_failure(self.addr, self.timeout, source))?;
        if n == 0 {
            return Err(DashboardError::Io {
                addr: self.addr,
                source: std::io::Error::new(std::io::ErrorKind::UnexpectedEof, "connection closed"),
            });
        }
        Ok(line.trim_end_matches(['\r', '\n']).to_string())
    }

    /// Sends one command and returns its reply line; the Local-mode refusal is an error.
    pub fn command(&mut self, command: &str) -> Result<String, DashboardError> {
        self.writer
            .write_all(format!("{command}\n").as_bytes())
            .map_err(|source| io_failure(self.addr, self.timeout, source))?;
        let reply = self.read_line()?;
        if reply.starts_with("Command is not allowed due to safety reasons") {
            return Err(DashboardError::LocalMode);
        }
        Ok(reply)
    }

    fn typed<T>(
        &mut self,
        command: &str,
        parse: fn(&str) -> Option<T>,
    ) -> Result<T, DashboardError> {
        let reply = self.command(command)?;
        parse(&reply).ok_or(DashboardError::Unexpected {
            command: command.to_string(),
            reply,
        })
    }

    pub fn robot_mode(&mut self) -> Result<RobotMode, DashboardError> {
        self.typed("robotmode", parse_robot_mode)
    }

    pub fn safety_status(&mut self) -> Result<SafetyStatus, DashboardError> {
        self.typed("safetystatus", parse_safety_status)
    }

    pub fn program_state(&mut self) -> Result<ProgramState, DashboardError> {
        self.typed("programState", parse_program_state)
    }

    pub fn is_in_remote_control(&mut self) -> Result<bool, DashboardError> {
        self.typed("is in remote control", |r| match r.trim() {
            "true" => Some(true),
            "false" => Some(false),
            _ => None,
        })
    }

    /// `stop`: stops the running program.
    pub fn stop(&mut self) -> Result<(), DashboardError> {
        let reply = self.command("stop")?;
        if reply.starts_with("Stopped") {
            Ok(())
        } else {
            Err(DashboardError::Unexpected {
                command: "stop".into(),
                reply,
            })
        }
    }

    /// `power on`, then `brake release`, polling `robotmode` until IDLE and then RUNNING.
    pub fn power_on_and_release_brakes(&mut self, wait: Duration) -> Result<(), DashboardError> {
        self.command("power on")?;
        self.wait_for("power on", RobotMode::Idle, wait)?;
        self.command("brake release")?;
        self.wait_for("brake release", RobotMode::Running, wait)
    }

    fn wait_for(
        &mut self,
        command: &'static str,
        want: RobotMode,
        wait: Duration,
    ) -> Result<(), DashboardError> {
        let start = Instant::now();
        loop {
            let mode = self.robot_mode()?;
            if mode == want || (want == RobotMode::Idle && mode == RobotMode::Running) {
                return Ok(());
            }
            if start.elapsed() > wait {
                return Err(DashboardError::NotReached {
                    command,
                    want: want.name(),
                    waited_s: wait.as_secs_f64(),
                    last: mode.name().to_string(),
                });
            }
            std::thread::sleep(Duration::from_millis(100));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_server_that_never_greets_is_reported_as_a_timeout_naming_the_wait() {
        // Accepts the connection (the kernel does, from the backlog) but never writes.
        let listener = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
        let addr = listener.local_addr().unwrap();
        let started = std::time::Instant::now();
        let err = DashboardClient::connect(addr, Duration::from_millis(200))
            .err()
            .expect("no greeting");
        let text = err.to_string();
        println!("{text} after {:.2} s", started.elapsed().as_secs_f64());
        assert!(matches!(err, DashboardError::TimedOut { .. }), "{err:?}");
        assert!(
            text.contains("timed out") && text.contains("0.2 s"),
            "{text}"
        );
        assert!(!text.contains("os error"), "{text}");
        drop(listener);
    }

    #[test]
    fn replies_parse_into_their_types() {
        assert_eq!(
            parse_robot_mode("Robotmode: RUNNING"),
            Some(RobotMode::Running)
        );
        assert_eq!(parse_robot_mode("Robotmode: FLYING"), None);
        assert_eq!(
            parse_safety_status("Safetystatus: PROTECTIVE_STOP"),
            Some(SafetyStatus::ProtectiveStop)
        );
        assert_eq!(
            parse_safety_status("Safetymode: NORMAL"),
            Some(SafetyStatus::Normal)
        );
        assert_eq!(
            parse_program_state("PLAYING scan.urp"),
            Some(ProgramState {
                state: "PLAYING".into(),
                program: "scan.urp".into()
            })
        );
        assert!(SafetyStatus::ProtectiveStop.is_stop());
        assert!(!SafetyStatus::Reduced.is_stop());
        for m in RobotMode::ALL {
            assert_eq!(RobotMode::from_code(m.0.code()), Some(m.0));
        }
        for s in SafetyStatus::ALL {
            assert_eq!(SafetyStatus::from_code(s.0.code()), Some(s.0));
        }
    }
}
