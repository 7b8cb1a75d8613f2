//! The simulated lab in-process: the UR5e simulator on loopback TCP, the IWR1443 CLI simulator
//! on a PTY and the DCA1000 simulator on loopback UDP, at the addresses of `lab.toml`. The
//! radar's frames are rendered live from where the simulated arm carries it
//! ([`super::scene_frames`]), so a scan through the real clients sees what a real lab would.

use std::net::SocketAddr;
use std::path::Path;
use std::sync::Arc;

use super::config::LabConfig;
use super::scan::ScanSetup;
use super::scene_frames::{SceneFrames, SceneFramesConfig};
use super::simchain::{SimChain, SimChainError};
use crate::geometry::{TriMesh, ViewRegion};
use crate::sim::{ForwardModel, Scene};
use crate::ur::sim::{Faults, UrSim, UrSimConfig, UrSimError};

/// Why the simulated lab could not start.
#[derive(Debug, thiserror::Error)]
pub enum SimLabError {
    #[error("sim.scene: {0}")]
    Scene(String),
    #[error(transparent)]
    Robot(#[from] UrSimError),
    #[error(transparent)]
    Chain(#[from] SimChainError),
    #[error("the simulated radar's render thread: {0}")]
    Thread(#[from] std::io::Error),
}

/// The running simulators.
pub struct SimLab {
    pub robot: UrSim,
    pub chain: SimChain,
    pub frames: Arc<SceneFrames>,
    /// The scene's surfaces in the base frame: the truth a reconstruction is scored against.
    pub truth_mesh: TriMesh,
}

/// Margin around the configured aperture inside which the scene is sampled for viewing.
const VIEW_MARGIN_M: f64 = 0.15;

impl SimLab {
    /// Starts every simulator. `link` overrides `sim.radar_link` (tests use a private one).
    pub fn start(
        lab: &LabConfig,
        setup: &ScanSetup,
        link: Option<&Path>,
    ) -> Result<Self, SimLabError> {
        let scene_path = lab
            .sim
            .scene
            .as_deref()
            .ok_or_else(|| SimLabError::Scene("the simulated lab needs sim.scene".into()))?;
        let scene = Scene::load(scene_path).map_err(|e| SimLabError::Scene(e.to_string()))?;
        if scene.plan.samples_per_chirp != setup.layout.samples_per_chirp {
            return Err(SimLabError::Scene(format!(
                "{} is simulated with {} samples per chirp but radar.profile has {}; give the scene the same profile",
                scene_path.display(),
                scene.plan.samples_per_chirp,
                setup.layout.samples_per_chirp
            )));
        }
        let spec = &setup.spec;
        let [cx, cy, z] = spec.centre_in_base_m;
        let half_w = spec.width_m / 2.0 + setup.plan.ramp_m + VIEW_MARGIN_M;
        let half_h = spec.height_m / 2.0 + VIEW_MARGIN_M;
        let view = ViewRegion {
            x_m: [cx - half_w, cx + half_w],
            y_m: [cy - half_h, cy + half_h],
            z_m: z,
        };
        let model = Arc::new(ForwardModel::new(&scene, &view));
        let truth_mesh = model.truth_mesh.clone();
        let r = &lab.robot;
        let at = |port| SocketAddr::new(r.host, port);
        let [rx, ry, rz] = spec.tool_rotation_in_base;
        let robot = UrSim::spawn(
            &UrSimConfig {
                rtde: at(r.rtde_port),
                dashboard: at(r.dashboard_port),
                script: at(r.script_port),
                start_pose: [cx, cy, z + 0.05, rx, ry, rz],
                remote_control: true,
                clock_offset_s: lab.sim.robot.clock_offset_s,
                clock_drift_ppm: lab.sim.robot.clock_drift_ppm,
                protective_stop: None,
                input_loss: lab.sim.robot.input_loss.map(|l| (l.move_index, l.after_s)),
            },
            Faults {
                seed: lab.sim.robot.seed,
                jitter_s: lab.sim.robot.jitter_ms * 1e-3,
                ..Faults::default()
            },
        )?;
        let frames = Arc::new(SceneFrames::start(
            model,
            robot.pose_oracle(),
            SceneFramesConfig {
                layout: setup.layout.clone(),
                chirp_centre_s: setup.timing.centre_s,
                geometry: lab.align.clone(),
                reference_pose: [cx, cy, z, rx, ry, rz],
                full_scale: lab.sim.full_scale,
                noise: scene.noise,
            },
        )?);
        let chain = SimChain::start(lab, frames.clone(), link)?;
        Ok(Self {
            robot,
            chain,
            frames,
            truth_mesh,
        })
    }
}
