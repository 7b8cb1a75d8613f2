//! `lab.toml`: the lab's devices. Unknown keys are refused; `validate` runs at load time and its
//! errors name the field and the value. Relative paths are relative to the config file.

use std::net::{IpAddr, Ipv4Addr, SocketAddr};
use std::path::{Path, PathBuf};

use crate::align::AlignConfig;
use crate::dca1000::fault::FaultConfig;
use crate::dca1000::udp::Dca1000Config;
use crate::radar::RadarConfig;
use crate::radar::sim::{CliFaults, UnknownReply};
use crate::recon::ReconConfig;
use crate::ur::motion::ScanSpec;

/// The whole config file.
#[derive(Debug, Clone, Default, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct LabConfig {
    /// Start the simulated lab in-process (the UR5e, radar CLI and DCA1000 simulators) and
    /// reach it through the real transports at the addresses below.
    pub simulate: bool,
    pub radar: RadarConfig,
    pub dca1000: Dca1000Config,
    pub robot: RobotConfig,
    /// The default raster; a `scan` request may override parts of it.
    pub scan: ScanSpec,
    pub align: AlignConfig,
    pub recording: RecordingConfig,
    pub reconstruction: ReconConfig,
    pub control: ControlConfig,
    /// The simulated devices; ignored by real hardware.
    pub sim: SimConfig,
}

/// The `[robot]` section: where the UR controller listens.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RobotConfig {
    pub host: IpAddr,
    pub dashboard_port: u16,
    pub script_port: u16,
    pub rtde_port: u16,
    /// 500 on e-Series, 125 on CB3.
    pub rtde_frequency_hz: f64,
    /// Packages missed before the RTDE stream counts as stalled (a gap: the row is rescanned).
    pub rtde_stall_periods: f64,
}

impl Default for RobotConfig {
    fn default() -> Self {
        Self {
            host: IpAddr::V4(Ipv4Addr::new(192, 168, 1, 10)),
            dashboard_port: 29999,
            script_port: 30002,
            rtde_port: 30004,
            rtde_frequency_hz: 500.0,
            rtde_stall_periods: 3.0,
        }
    }
}

impl RobotConfig {
    pub fn validate(&self) -> Result<(), String> {
        if !(self.rtde_frequency_hz.is_finite()
            && self.rtde_frequency_hz > 0.0
            && self.rtde_frequency_hz <= 500.0)
        {
            return Err(format!(
                "robot.rtde_frequency_hz = {} must lie in (0, 500]",
                self.rtde_frequency_hz
            ));
        }
        if !(self.rtde_stall_periods.is_finite() && self.rtde_stall_periods >= 1.0) {
            return Err(format!(
                "robot.rtde_stall_periods = {} must be at least 1",
                self.rtde_stall_periods
            ));
        }
        Ok(())
    }

    pub fn addr(&self, port: u16) -> SocketAddr {
        SocketAddr::new(self.host, port)
    }
}

/// The `[recording]` section: where scans go and when a row is scanned again.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RecordingConfig {
    /// One folder per scan is made here.
    pub data_dir: PathBuf,
    /// A row whose flagged frames exceed this fraction is scanned again.
    pub max_frame_loss: f64,
    /// Rescans of a row before the scan reports it and goes on.
    pub max_row_retries: u32,
    /// A row whose radar or controller clock fit leaves a bin's earliest arrival more than this
    /// off its line is scanned again: the host stamped arrivals late (a busy CPU), so the
    /// frames' poses cannot be trusted. Seconds.
    pub max_clock_residual_s: f64,
    /// MCAP chunks close after this much data time, seconds (crash loss is at most one chunk).
    pub chunk_seconds: f64,
    /// … or this many uncompressed bytes, whichever comes first.
    pub chunk_bytes: u64,
}

impl Default for RecordingConfig {
    fn default() -> Self {
        Self {
            data_dir: PathBuf::from("captures"),
            max_frame_loss: 0.01,
            max_row_retries: 2,
            max_clock_residual_s: 0.002,
            chunk_seconds: 0.25,
            chunk_bytes: 1 << 20,
        }
    }
}

impl RecordingConfig {
    pub fn validate(&self) -> Result<(), String> {
        if !(0.0..=1.0).contains(&self.max_frame_loss) {
            return Err(format!(
                "recording.max_frame_loss = {} must lie in 0..=1",
                self.max_frame_loss
            ));
        }
        if !(self.max_clock_residual_s.is_finite() && self.max_clock_residual_s > 0.0) {
            return Err(format!(
                "recording.max_clock_residual_s = {} must be a finite number above 0",
                self.max_clock_residual_s
            ));
        }
        if !(self.chunk_seconds.is_finite()
            && self.chunk_seconds > 0.0
            && self.chunk_seconds <= 0.5)
        {
            return Err(format!(
                "recording.chunk_seconds = {} must lie in (0, 0.5]",
                self.chunk_seconds
            ));
        }
        if !(4096..=64 << 20).contains(&self.chunk_bytes) {
            return Err(format!(
                "recording.chunk_bytes = {} must lie in 4096..=67108864",
                self.chunk_bytes
            ));
        }
        Ok(())
    }
}

/// The `[control]` section: the TCP control port.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ControlConfig {
    pub bind: SocketAddr,
    /// Required of every client when set; a non-loopback `bind` needs it.
    pub token: Option<String>,
    pub max_clients: usize,
}

impl Default for ControlConfig {
    fn default() -> Self {
        Self {
            bind: SocketAddr::from(([127, 0, 0, 1], 7878)),
            token: None,
            max_clients: 256,
        }
    }
}

impl ControlConfig {
    pub fn validate(&self) -> Result<(), String> {
        if !self.bind.ip().is_loopback() && self.token.as_deref().is_none_or(str::is_empty) {
            return Err(format!(
                "control.bind = {} is not a loopback address; set control.token so that clients must present it",
                self.bind
            ));
        }
        if self.max_clients == 0 {
            return Err("control.max_clients = 0 must be at least 1".into());
        }
        Ok(())
    }
}

/// `[sim.robot]`: the simulated UR5e's clock and stream faults.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SimRobotConfig {
    /// Controller clock against the host's, seconds and ppm.
    pub clock_offset_s: f64,
    pub clock_drift_ppm: f64,
    /// Each RTDE package leaves up to this late (uniform), milliseconds.
    pub jitter_ms: f64,
    pub seed: u64,
    /// The controller loses mmnormd's RTDE inputs during one move, so the row program's
    /// watchdog trips: a host stall, as the robot sees it. Off unless set.
    pub input_loss: Option<InputLoss>,
}

impl Default for SimRobotConfig {
    fn default() -> Self {
        Self {
            clock_offset_s: 12_345.678,
            clock_drift_ppm: 30.0,
            jitter_ms: 0.5,
            seed: 0,
            input_loss: None,
        }
    }
}

/// `[sim.robot.input_loss]`: every RTDE input package is lost from `after_s` into arm move
/// number `move_index` (0-based, counting every `movel` since start-up) until that move ends.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct InputLoss {
    pub move_index: u64,
    pub after_s: f64,
}

/// The `[sim]` section.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SimConfig {
    /// A scene file simulated at start-up; its frames are what the simulated radar streams.
    pub scene: Option<PathBuf>,
    /// Or a capture directory to stream instead.
    pub capture_dir: Option<PathBuf>,
    /// A symlink to the CLI simulator's PTY, for `radar.serial_port`.
    pub radar_link: PathBuf,
    /// The simulated board's data source port (the real board sends from 1024).
    pub board_data_port: u16,
    /// Simulated seconds per wall-clock second.
    pub time_scale: f64,
    /// The FPGA's idle flush of a partial payload, simulated seconds.
    pub flush_delay_s: f64,
    /// ADC counts of the source's largest |I| or |Q|.
    pub full_scale: i16,
    pub unknown_reply: UnknownReply,
    pub ddr_full_at_frame: Option<u64>,
    pub dca1000_faults: FaultConfig,
    pub cli_faults: CliFaults,
    pub robot: SimRobotConfig,
    /// The recorder's disk fails (ENOSPC) after this many bytes: a seeded fault for tests.
    pub record_fail_after_bytes: Option<u64>,
}

impl Default for SimConfig {
    fn default() -> Self {
        Self {
            scene: None,
            capture_dir: None,
            radar_link: PathBuf::from("/tmp/mmnormd-sim/radar-cli"),
            board_data_port: 1024,
            time_scale: 1.0,
            flush_delay_s: 2.0,
            full_scale: 8191,
            unknown_reply: UnknownReply::Error50,
            ddr_full_at_frame: None,
            dca1000_faults: FaultConfig::default(),
            cli_faults: CliFaults::default(),
            robot: SimRobotConfig::default(),
            record_fail_after_bytes: None,
        }
    }
}

impl SimConfig {
    /// Checks every field; the error names the field and its value.
    pub fn validate(&self) -> Result<(), String> {
        if !(self.time_scale.is_finite() && self.time_scale > 0.0 && self.time_scale <= 1000.0) {
            return Err(format!(
                "sim.time_scale = {} must lie in (0, 1000]",
                self.time_scale
            ));
        }
        if !(self.flush_delay_s.is_finite() && self.flush_delay_s >= 0.0) {
            return Err(format!(
                "sim.flush_delay_s = {} must be a non-negative number",
                self.flush_delay_s
            ));
        }
        if self.full_scale <= 0 {
            return Err(format!(
                "sim.full_scale = {} must be positive",
                self.full_scale
            ));
        }
        if self.scene.is_some() && self.capture_dir.is_some() {
            return Err("sim.scene and sim.capture_dir are both set; choose one".into());
        }
        self.dca1000_faults
            .validate()
            .map_err(|e| format!("sim.dca1000_{e}"))?;
        for (name, p) in [
            (
                "garble_echo_probability",
                self.cli_faults.garble_echo_probability,
            ),
            (
                "drop_reply_probability",
                self.cli_faults.drop_reply_probability,
            ),
            ("stall_probability", self.cli_faults.stall_probability),
        ] {
            if !(0.0..=1.0).contains(&p) {
                return Err(format!("sim.cli_faults.{name} = {p} must lie in 0..=1"));
            }
        }
        if self.cli_faults.stall_ms > 60_000 {
            return Err(format!(
                "sim.cli_faults.stall_ms = {} is above 60000",
                self.cli_faults.stall_ms
            ));
        }
        let r = &self.robot;
        for (name, v) in [
            ("clock_offset_s", r.clock_offset_s),
            ("clock_drift_ppm", r.clock_drift_ppm),
            ("jitter_ms", r.jitter_ms),
        ] {
            if !v.is_finite() {
                return Err(format!("sim.robot.{name} = {v} is not a finite number"));
            }
        }
        if !(0.0..=100.0).contains(&r.jitter_ms) {
            return Err(format!(
                "sim.robot.jitter_ms = {} must lie in 0..=100",
                r.jitter_ms
            ));
        }
        if let Some(loss) = r.input_loss
            && !(loss.after_s.is_finite() && loss.after_s >= 0.0)
        {
            return Err(format!(
                "sim.robot.input_loss.after_s = {} must be a finite number ≥ 0",
                loss.after_s
            ));
        }
        Ok(())
    }
}

/// Why a config file was refused.
#[derive(Debug, thiserror::Error)]
pub enum LabConfigError {
    #[error("cannot read config {path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("config {path}: {message}")]
    Parse { path: PathBuf, message: String },
    #[error("config {path}: {message}")]
    Invalid { path: PathBuf, message: String },
}

impl LabConfig {
    /// Reads, resolves and validates a config file.
    pub fn load(path: &Path) -> Result<Self, LabConfigError> {
        let text = std::fs::read_to_string(path).map_err(|source| LabConfigError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        Self::parse(&text, path)
    }

    /// Parses config text; relative paths resolve against `path`'s directory.
    pub fn parse(text: &str, path: &Path) -> Result<Self, LabConfigError> {
        let mut config: LabConfig = toml::from_str(text).map_err(|e| LabConfigError::Parse {
            path: path.to_path_buf(),
            message: e.to_string(),
        })?;
        let base = path.parent().unwrap_or(Path::new("."));
        let resolve = |p: &mut PathBuf| {
            if p.is_relative() {
                *p = base.join(&*p);
            }
        };
        resolve(&mut config.radar.profile);
        if let Some(s) = config.sim.scene.as_mut() {
            resolve(s);
        }
        if let Some(c) = config.sim.capture_dir.as_mut() {
            resolve(c);
        }
        resolve(&mut config.recording.data_dir);
        config
            .validate()
            .map_err(|message| LabConfigError::Invalid {
                path: path.to_path_buf(),
                message,
            })?;
        Ok(config)
    }

    /// Checks every section (the scan's speed against the radar profile is checked where the
    /// profile is read, [`crate::lab::scan::ScanSetup::new`]).
    pub fn validate(&self) -> Result<(), String> {
        self.radar.validate()?;
        self.dca1000.validate()?;
        self.robot.validate()?;
        self.align.validate()?;
        self.recording.validate()?;
        self.reconstruction
            .validate()
            .map_err(|e| format!("reconstruction.{e}"))?;
        self.control.validate()?;
        self.sim.validate()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn unknown_keys_and_bad_values_are_refused_with_their_names() {
        let p = Path::new("config/x.toml");
        let e = LabConfig::parse("[dca1000]\nboard_iq = \"1.2.3.4\"\n", p).unwrap_err();
        assert!(e.to_string().contains("board_iq"), "{e}");
        let e = LabConfig::parse("[dca1000]\npacket_size_bytes = 9000\n", p).unwrap_err();
        assert!(
            e.to_string()
                .contains("dca1000.packet_size_bytes = 9000 is outside 48..=1472"),
            "{e}"
        );
        let e = LabConfig::parse("[sim.dca1000_faults]\nloss_probability = 2.0\n", p).unwrap_err();
        assert!(e.to_string().contains("loss_probability = 2"), "{e}");
        let e = LabConfig::parse("[dca1000]\nhost_ip = \"192.168.33\"\n", p).unwrap_err();
        assert!(e.to_string().contains("host_ip"), "{e}");
        let e = LabConfig::parse("[sim.cli_faults]\nstall_probability = -0.1\n", p).unwrap_err();
        assert!(
            e.to_string()
                .contains("sim.cli_faults.stall_probability = -0.1 must lie in 0..=1"),
            "{e}"
        );
        let e = LabConfig::parse("[sim.cli_faults]\nstall_ms = 90000\n", p).unwrap_err();
        assert!(
            e.to_string()
                .contains("sim.cli_faults.stall_ms = 90000 is above 60000"),
            "{e}"
        );
        let e = LabConfig::parse(
            "[sim.robot.input_loss]\nmove_index = 3\nafter_s = -0.5\n",
            p,
        )
        .unwrap_err();
        assert!(
            e.to_string()
                .contains("sim.robot.input_loss.after_s = -0.5 must be a finite number ≥ 0"),
            "{e}"
        );
        let e = LabConfig::parse("[recording]\nmax_clock_residual_s = 0.0\n", p).unwrap_err();
        assert!(
            e.to_string()
                .contains("recording.max_clock_residual_s = 0 must be a finite number above 0"),
            "{e}"
        );
        let e = LabConfig::parse("[sim.robot.input_loss]\nafter_s = 0.3\n", p).unwrap_err();
        assert!(e.to_string().contains("move_index"), "{e}");
    }

    #[test]
    fn a_control_port_off_loopback_needs_a_token() {
        let p = Path::new("config/x.toml");
        let e = LabConfig::parse("[control]\nbind = \"0.0.0.0:7878\"\n", p).unwrap_err();
        assert!(
            e.to_string()
                .contains("control.bind = 0.0.0.0:7878 is not a loopback address"),
            "{e}"
        );
        let ok = LabConfig::parse("[control]\nbind = \"0.0.0.0:7878\"\ntoken = \"k3y\"\n", p);
        assert!(ok.is_ok());
    }

    #[test]
    fn relative_paths_resolve_against_the_config_file() {
        let c = LabConfig::parse(
            "[radar]\nprofile = \"../firmware_cfg/a.cfg\"\n",
            Path::new("config/lab.toml"),
        )
        .unwrap();
        assert_eq!(c.radar.profile, Path::new("config/../firmware_cfg/a.cfg"));
    }
}
