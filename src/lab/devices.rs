//! The lab's devices over their real transports: the IWR1443 CLI on a serial port, the DCA1000
//! over UDP and the UR5e over Dashboard, script port and RTDE. Connecting configures the board
//! and sends the radar its profile; nothing moves until a scan asks.

use std::time::Duration;

use super::config::LabConfig;
use super::scan::Devices;
use crate::dca1000::board::{BoardError, CaptureBoard};
use crate::dca1000::command::FpgaVersion;
use crate::dca1000::udp::UdpBoard;
use crate::radar::cli::CliError;
use crate::radar::control::open_serial;
use crate::radar::{CliRadar, RadarControl, RadarProfile};
use crate::ur::robot::{RobotError, UrAddresses, UrRobot};
use crate::ur::rtde::RtdeConfig;

/// Why the devices could not be brought up.
#[derive(Debug, thiserror::Error)]
pub enum ConnectError {
    #[error(transparent)]
    Board(#[from] BoardError),
    #[error("radar: {0}")]
    Radar(#[from] CliError),
    #[error("robot: {0}")]
    Robot(#[from] RobotError),
    #[error("{0}")]
    Config(String),
}

/// The connected devices.
pub struct LabDevices {
    pub radar: CliRadar<Box<dyn serialport::SerialPort>>,
    pub board: UdpBoard,
    pub robot: UrRobot,
    pub fpga_version: FpgaVersion,
}

impl LabDevices {
    /// Opens and configures everything: the board first (so that it records what the radar
    /// sends), then the radar's profile, then the robot.
    pub fn connect(lab: &LabConfig, profile: &RadarProfile) -> Result<Self, ConnectError> {
        let d = &lab.dca1000;
        let mut board = UdpBoard::open(d)?;
        let fpga_version = board.connect()?;
        let packets = d.packet_config().map_err(ConnectError::Config)?;
        board.configure(d.fpga, packets)?;
        let port = open_serial(&lab.radar)?;
        let mut radar = CliRadar::new(port, lab.radar.session_config());
        radar.configure(profile)?;
        let r = &lab.robot;
        let mut rtde = RtdeConfig::e_series(r.addr(r.rtde_port));
        rtde.frequency_hz = r.rtde_frequency_hz;
        rtde.stall_periods = r.rtde_stall_periods;
        rtde.connect_timeout = Duration::from_secs(3);
        let robot = UrRobot::connect(&UrAddresses {
            dashboard: r.addr(r.dashboard_port),
            script: r.addr(r.script_port),
            rtde,
        })?;
        Ok(Self {
            radar,
            board,
            robot,
            fpga_version,
        })
    }

    /// The devices as a scan drives them.
    pub fn devices(&mut self) -> Devices<'_> {
        Devices {
            radar: &mut self.radar,
            board: &mut self.board,
            robot: &mut self.robot,
        }
    }
}
