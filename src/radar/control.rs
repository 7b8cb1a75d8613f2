//! Driving the radar: the [`RadarControl`] trait and its implementation over a serial line.
//!
//! [`CliRadar`] runs [`CliSession`]s over any [`SerialLink`]: a real port opened with
//! [`open_serial`] (115200 8N1, no flow control; serialport is built without libudev) or the
//! simulator's PTY. `configure` sends `sensorStop` and `flushCfg` (unless the profile starts with
//! them) and every profile line but `sensorStart`; `start` sends `sensorStart`; `stop` sends
//! `sensorStop`.

use std::io::{Read as _, Write as _};
use std::path::PathBuf;
use std::time::{Duration, Instant};

use super::RadarProfile;
use super::cli::{
    CliError, CliSession, CommandOutcome, DEFAULT_RESYNC_ATTEMPTS, PromptKind, SessionConfig,
};

/// The `[radar]` section of a lab config.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RadarConfig {
    /// The chirp profile (`.cfg`), relative to the config file.
    pub profile: PathBuf,
    /// The CLI UART (use `/dev/serial/by-id/...`; on IWR1443BOOST the XDS110's first port).
    pub serial_port: PathBuf,
    pub baud_rate: u32,
    pub command_timeout_ms: u64,
    /// Retries per command after the first attempt.
    pub retries: u32,
    pub resync_attempts: u32,
    pub resync_interval_ms: u64,
}

impl Default for RadarConfig {
    fn default() -> Self {
        Self {
            profile: PathBuf::from("firmware_cfg/iwr1443_mmnorm.cfg"),
            // The name systemd/99-mmnormd-radar.rules gives the CLI UART.
            serial_port: PathBuf::from("/dev/mmnormd-radar"),
            baud_rate: 115_200,
            command_timeout_ms: 1000,
            retries: 3,
            resync_attempts: DEFAULT_RESYNC_ATTEMPTS,
            resync_interval_ms: 200,
        }
    }
}

impl RadarConfig {
    /// Checks every field; the error names the field and its value.
    pub fn validate(&self) -> Result<(), String> {
        if self.baud_rate == 0 {
            return Err("radar.baud_rate = 0 must be positive".into());
        }
        if !(10..=60_000).contains(&self.command_timeout_ms) {
            return Err(format!(
                "radar.command_timeout_ms = {} is outside 10..=60000",
                self.command_timeout_ms
            ));
        }
        if self.retries > 20 {
            return Err(format!("radar.retries = {} is above 20", self.retries));
        }
        if self.resync_attempts == 0 {
            return Err("radar.resync_attempts = 0 must be at least 1".into());
        }
        if self.resync_interval_ms == 0 {
            return Err("radar.resync_interval_ms = 0 must be positive".into());
        }
        Ok(())
    }

    /// The session limits of this section.
    pub fn session_config(&self) -> SessionConfig {
        SessionConfig {
            command_timeout: Duration::from_millis(self.command_timeout_ms),
            retries: self.retries,
            resync_attempts: self.resync_attempts,
            resync_interval: Duration::from_millis(self.resync_interval_ms),
        }
    }
}

/// A radar front end that can be configured, started and stopped.
pub trait RadarControl {
    /// Sends the profile (all but `sensorStart`). Returns the record of every command.
    fn configure(&mut self, profile: &RadarProfile) -> Result<Vec<CommandOutcome>, CliError>;
    /// `sensorStart`: frames begin.
    fn start(&mut self) -> Result<(), CliError>;
    /// `sensorStop`.
    fn stop(&mut self) -> Result<(), CliError>;
}

/// A byte pipe with read timeouts.
pub trait SerialLink {
    fn write_bytes(&mut self, bytes: &[u8]) -> std::io::Result<()>;
    /// Reads what is there, waiting at most `timeout`; `Ok(0)` on timeout.
    fn read_bytes(&mut self, buf: &mut [u8], timeout: Duration) -> std::io::Result<usize>;
}

impl SerialLink for Box<dyn serialport::SerialPort> {
    fn write_bytes(&mut self, bytes: &[u8]) -> std::io::Result<()> {
        self.write_all(bytes)?;
        self.flush()
    }

    fn read_bytes(&mut self, buf: &mut [u8], timeout: Duration) -> std::io::Result<usize> {
        self.set_timeout(timeout.max(Duration::from_millis(1)))?;
        match self.read(buf) {
            Ok(n) => Ok(n),
            Err(e) if e.kind() == std::io::ErrorKind::TimedOut => Ok(0),
            Err(e) => Err(e),
        }
    }
}

/// Opens a CLI UART: 8 data bits, no parity, 1 stop bit, no flow control.
pub fn open_serial(config: &RadarConfig) -> Result<Box<dyn serialport::SerialPort>, CliError> {
    let path = config.serial_port.display().to_string();
    serialport::new(&path, config.baud_rate)
        .data_bits(serialport::DataBits::Eight)
        .parity(serialport::Parity::None)
        .stop_bits(serialport::StopBits::One)
        .flow_control(serialport::FlowControl::None)
        .timeout(Duration::from_millis(10))
        .open()
        .map_err(|e| CliError::Io(format!("opening radar.serial_port = {path}: {e}")))
}

/// Runs a session to its end over a link.
pub fn run_session(
    link: &mut dyn SerialLink,
    mut session: CliSession,
) -> Result<(Vec<CommandOutcome>, Option<PromptKind>), CliError> {
    let mut buf = [0u8; 1024];
    loop {
        while let Some(bytes) = session.poll_transmit() {
            link.write_bytes(&bytes)
                .map_err(|e| CliError::Io(format!("writing: {e}")))?;
        }
        match session.result() {
            Some(Ok(outcomes)) => return Ok((outcomes.to_vec(), session.prompt())),
            Some(Err(e)) => return Err(e.clone()),
            None => {}
        }
        let now = Instant::now();
        let wait = session
            .poll_timeout()
            .map_or(Duration::from_millis(50), |d| {
                d.saturating_duration_since(now)
            });
        let n = link
            .read_bytes(&mut buf, wait.min(Duration::from_millis(50)))
            .map_err(|e| CliError::Io(format!("reading: {e}")))?;
        let now = Instant::now();
        if n > 0 {
            session.handle_input(&buf[..n], now);
        }
        session.handle_timeout(now);
    }
}

/// A radar driven over its CLI.
pub struct CliRadar<L: SerialLink> {
    link: L,
    config: SessionConfig,
    prompt: Option<PromptKind>,
}

impl<L: SerialLink> CliRadar<L> {
    pub fn new(link: L, config: SessionConfig) -> Self {
        Self {
            link,
            config,
            prompt: None,
        }
    }

    /// The firmware's prompt, once seen.
    pub fn prompt(&self) -> Option<PromptKind> {
        self.prompt
    }

    /// Sends commands in one session.
    pub fn send(&mut self, commands: Vec<String>) -> Result<Vec<CommandOutcome>, CliError> {
        let session = CliSession::new(commands, self.config.clone(), Instant::now());
        let (outcomes, prompt) = run_session(&mut self.link, session)?;
        self.prompt = prompt.or(self.prompt);
        Ok(outcomes)
    }
}

/// The commands `configure` sends for a profile.
pub fn configure_commands(profile: &RadarProfile) -> Vec<String> {
    let first = |name: &str| {
        profile
            .script
            .iter()
            .any(|l| l.split_whitespace().next() == Some(name))
    };
    let mut commands = Vec::new();
    if !first("sensorStop") {
        commands.push("sensorStop".to_string());
    }
    if !first("flushCfg") {
        commands.push("flushCfg".to_string());
    }
    commands.extend(
        profile
            .script
            .iter()
            .filter(|l| l.split_whitespace().next() != Some("sensorStart"))
            .cloned(),
    );
    commands
}

impl<L: SerialLink> RadarControl for CliRadar<L> {
    fn configure(&mut self, profile: &RadarProfile) -> Result<Vec<CommandOutcome>, CliError> {
        self.send(configure_commands(profile))
    }

    fn start(&mut self) -> Result<(), CliError> {
        self.send(vec!["sensorStart".into()]).map(|_| ())
    }

    fn stop(&mut self) -> Result<(), CliError> {
        self.send(vec!["sensorStop".into()]).map(|_| ())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn configure_sends_the_profile_without_sensor_start() {
        let text = std::fs::read_to_string("firmware_cfg/iwr1443_mmnorm.cfg").unwrap();
        let profile = RadarProfile::from_cfg_str(&text).unwrap();
        let commands = configure_commands(&profile);
        assert_eq!(commands[0], "sensorStop");
        assert_eq!(commands[1], "flushCfg");
        assert_eq!(commands.last().unwrap(), "lvdsStreamCfg -1 0 1 0");
        assert!(!commands.iter().any(|c| c.starts_with("sensorStart")));
    }

    #[test]
    fn config_errors_name_the_field() {
        let c = RadarConfig {
            command_timeout_ms: 0,
            ..RadarConfig::default()
        };
        assert_eq!(
            c.validate().unwrap_err(),
            "radar.command_timeout_ms = 0 is outside 10..=60000"
        );
    }
}
