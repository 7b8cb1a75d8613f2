//! The simulated radar chain: the IWR1443 CLI simulator on a PTY and the DCA1000 simulator on
//! loopback UDP, wired so that a successful `sensorStart` starts the board's stream. Both run
//! through their real transports; clients cannot tell them from hardware except by address.

use std::net::{SocketAddr, SocketAddrV4};
use std::path::Path;
use std::sync::Arc;

use super::config::LabConfig;
use crate::capture::read_capture_dir;
use crate::dca1000::sim::{
    AdcStream, CoreConfig, DcaSimulator, FrameSource, SimAddresses, SimStats, StreamPlan,
};
use crate::radar::RadarProfile;
use crate::radar::sim::{CliSimCore, CliSimStats, CliSimulator, SensorEvent};
use crate::sim::{Scene, simulate};

/// Why the simulated chain could not start.
#[derive(Debug, thiserror::Error)]
pub enum SimChainError {
    #[error("sim: {0}")]
    Source(String),
    #[error(transparent)]
    Board(#[from] crate::dca1000::sim::SimError),
    #[error(transparent)]
    Cli(#[from] crate::radar::sim::CliSimError),
}

/// The frames the simulated radar streams: the config's scene (simulated now) or capture
/// directory, quantised to the profile's layout.
pub fn load_source(
    lab: &LabConfig,
    profile: &RadarProfile,
    quiet: bool,
) -> Result<(AdcStream, f64), SimChainError> {
    let capture = match (&lab.sim.scene, &lab.sim.capture_dir) {
        (Some(scene), None) => {
            let scene = Scene::load(scene).map_err(|e| SimChainError::Source(e.to_string()))?;
            simulate(&scene, quiet).capture
        }
        (None, Some(dir)) => {
            read_capture_dir(dir).map_err(|e| SimChainError::Source(e.to_string()))?
        }
        _ => {
            return Err(SimChainError::Source(
                "set sim.scene or sim.capture_dir to say what the radar sees".into(),
            ));
        }
    };
    let layout = lab
        .dca1000
        .layout(profile)
        .map_err(|e| SimChainError::Source(e.to_string()))?;
    AdcStream::from_capture(&capture, &layout, lab.sim.full_scale)
        .map_err(|e| SimChainError::Source(format!("the capture does not fit the profile: {e}")))
}

/// The running simulators.
pub struct SimChain {
    pub board: DcaSimulator,
    pub radar: CliSimulator,
}

impl SimChain {
    /// Starts both simulators at the config's addresses (the board at `dca1000.board_ip`,
    /// sending to `dca1000.host_ip:host_data_port`), the CLI on a PTY linked from
    /// `link` (or `sim.radar_link`).
    pub fn start(
        lab: &LabConfig,
        source: Arc<dyn FrameSource>,
        link: Option<&Path>,
    ) -> Result<Self, SimChainError> {
        let d = &lab.dca1000;
        let addresses = SimAddresses {
            board_config: SocketAddr::V4(SocketAddrV4::new(d.board_ip, d.config_port)),
            board_data: SocketAddr::V4(SocketAddrV4::new(d.board_ip, lab.sim.board_data_port)),
            host_data: SocketAddr::V4(SocketAddrV4::new(d.host_ip, d.host_data_port)),
        };
        let core = CoreConfig {
            time_scale: lab.sim.time_scale,
            flush_delay_s: lab.sim.flush_delay_s,
            faults: lab.sim.dca1000_faults.clone(),
            ddr_full_at_frame: lab.sim.ddr_full_at_frame,
            ..CoreConfig::default()
        };
        let board = DcaSimulator::spawn(&addresses, core, source)?;
        let trigger = board.trigger();
        let on_event = Box::new(move |event| match event {
            SensorEvent::Start {
                frames,
                frame_period_s,
                acquired_s,
            } => trigger.start(StreamPlan {
                frames,
                frame_period_s,
                acquired_s,
            }),
            SensorEvent::Stop => trigger.stop(),
        });
        let cli = CliSimCore::new(lab.sim.unknown_reply, lab.sim.cli_faults.clone());
        let radar =
            CliSimulator::spawn(cli, link.or(Some(lab.sim.radar_link.as_path())), on_event)?;
        Ok(Self { board, radar })
    }

    /// The counters of both simulators.
    pub fn stats(&self) -> (SimStats, CliSimStats) {
        (self.board.stats(), self.radar.stats())
    }
}
