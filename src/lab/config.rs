//! `lab.toml`: the lab's devices. Unknown keys are refused; `validate` runs at load time and its
//! errors name the field and the value. Relative paths are relative to the config file.

use std::path::{Path, PathBuf};

use crate::dca1000::fault::FaultConfig;
use crate::dca1000::udp::Dca1000Config;
use crate::radar::RadarConfig;
use crate::radar::sim::{CliFaults, UnknownReply};

/// The whole config file.
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct LabConfig {
    pub radar: RadarConfig,
    pub dca1000: Dca1000Config,
    /// The simulated devices (`mmnormd sim radar`); ignored by real hardware.
    pub sim: SimConfig,
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
        ] {
            if !(0.0..=1.0).contains(&p) {
                return Err(format!("sim.cli_faults.{name} = {p} must lie in 0..=1"));
            }
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
        config
            .validate()
            .map_err(|message| LabConfigError::Invalid {
                path: path.to_path_buf(),
                message,
            })?;
        Ok(config)
    }

    /// Checks every section.
    pub fn validate(&self) -> Result<(), String> {
        self.radar.validate()?;
        self.dca1000.validate()?;
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
