//! The scan worker: the devices, the running job and the status snapshot.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Instant;

use serde_json::json;
use tokio::sync::broadcast;

use crate::capture::read_capture_dir;
use crate::lab::LabConfig;
use crate::lab::devices::LabDevices;
use crate::lab::job::{
    JobError, JobEvent, LiveJob, ScanPaths, ScanRequest, Truth, reconstruct_and_score, run_live,
    truth_of,
};
use crate::lab::scan::ScanSetup;
use crate::lab::simlab::SimLab;

/// What `status` shows.
#[derive(Debug, Clone, Default, serde::Serialize)]
pub struct Status {
    pub state: String,
    pub scan: Option<String>,
    pub row: Option<usize>,
    pub rows: Option<usize>,
    pub stage: Option<String>,
    pub lost_packets: u64,
    pub scans_finished: u64,
    pub last_result: Option<serde_json::Value>,
    pub last_error: Option<String>,
    pub simulated: bool,
}

/// Everything the worker and the control port share.
pub struct Shared {
    pub lab: LabConfig,
    pub status: Mutex<Status>,
    pub events: broadcast::Sender<String>,
    pub abort: AtomicBool,
    pub busy: AtomicBool,
    pub started: Instant,
    pub quiet: bool,
    pub devices: Mutex<Option<LabDevices>>,
    pub sim: Option<SimLab>,
    pub truth: Option<Truth>,
}

fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|p| p.into_inner())
}

impl Shared {
    pub fn status(&self) -> Status {
        lock(&self.status).clone()
    }

    fn publish(&self, event: &JobEvent) {
        {
            let mut s = lock(&self.status);
            match event {
                JobEvent::State { state, scan } => {
                    s.state = state.clone();
                    s.scan = Some(scan.clone());
                    s.stage = None;
                }
                JobEvent::Row { row: r, .. } => {
                    if r.accepted {
                        s.row = Some(r.row + 1);
                    }
                    s.rows = Some(r.rows);
                    s.lost_packets += r.lost_packets;
                }
                JobEvent::Stage { stage, .. } => {
                    s.state = "reconstructing".into();
                    s.stage = Some(stage.clone());
                }
                JobEvent::Result(r) => {
                    s.last_result = serde_json::to_value(r).ok();
                    s.scans_finished += 1;
                }
                JobEvent::Error { message, .. } => s.last_error = Some(message.clone()),
            }
        }
        if let Ok(text) = serde_json::to_string(event) {
            // No subscriber is not an error.
            self.events.send(text).ok();
        }
    }

    fn set_idle(&self) {
        let mut s = lock(&self.status);
        s.state = "idle".into();
        s.stage = None;
    }

    /// Claims the worker; false when a job already runs.
    pub fn claim(&self) -> bool {
        self.busy
            .compare_exchange(false, true, Ordering::AcqRel, Ordering::Acquire)
            .is_ok()
    }
}

/// Checks a scan request against the config before anything moves.
pub fn prepare_scan(
    shared: &Shared,
    request: &ScanRequest,
) -> Result<(ScanSetup, String), JobError> {
    let name = request.folder_name(crate::record::unix_now_s())?;
    if shared.lab.recording.data_dir.join(&name).exists() {
        return Err(JobError::Request(format!(
            "name = {name:?}: a scan of that name exists"
        )));
    }
    let spec = request.apply(&shared.lab.scan);
    if shared.sim.is_some()
        && (spec.width_m > shared.lab.scan.width_m + 1e-9
            || spec.height_m > shared.lab.scan.height_m + 1e-9)
    {
        // The simulated scene was sampled for views from the configured aperture.
        return Err(JobError::Request(format!(
            "the simulated lab was started for a {:.3} × {:.3} m aperture (scan.width_m, scan.height_m); a {:.3} × {:.3} m scan needs a config that says so",
            shared.lab.scan.width_m, shared.lab.scan.height_m, spec.width_m, spec.height_m
        )));
    }
    let setup = ScanSetup::new(&shared.lab, spec)?;
    Ok((setup, name))
}

/// Runs a claimed scan on this thread; the worker is released at the end.
pub fn run_scan_job(shared: &Arc<Shared>, request: ScanRequest, setup: ScanSetup, name: String) {
    shared.abort.store(false, Ordering::Relaxed);
    {
        let mut s = lock(&shared.status);
        s.row = Some(0);
        s.rows = Some(setup.plan.rows.len());
        s.lost_packets = 0;
    }
    // The job's last event (its result) goes out after the worker is released, so a client
    // that starts the next scan as soon as it sees the result is not told the worker is busy.
    let last = Mutex::new(None);
    let publish = |e: JobEvent| match e {
        JobEvent::Result(_) => *lock(&last) = Some(e),
        e => shared.publish(&e),
    };
    let result = {
        let mut guard = lock(&shared.devices);
        match guard.as_mut() {
            None => Err(JobError::Request("the devices are not connected".into())),
            Some(devices) => {
                let job = LiveJob {
                    lab: &shared.lab,
                    setup: &setup,
                    request: &request,
                    name: &name,
                    truth: shared.truth.as_ref(),
                    truth_mesh: shared.sim.as_ref().map(|s| &s.truth_mesh),
                    quiet: shared.quiet,
                };
                run_live(&job, &mut devices.devices(), &shared.abort, &publish)
            }
        }
    };
    if let Err(e) = result {
        tracing::error!("scan {name}: {e}");
        *lock(&last) = Some(JobEvent::Error {
            scan: name,
            message: e.to_string(),
        });
    }
    release_then_publish(shared, last.into_inner().unwrap_or_else(|p| p.into_inner()));
}

/// Marks the worker idle and free, then publishes the job's last event.
fn release_then_publish(shared: &Shared, last: Option<JobEvent>) {
    shared.set_idle();
    shared.busy.store(false, Ordering::Release);
    if let Some(event) = last {
        shared.publish(&event);
    }
}

/// Re-runs the reconstruction of a stored scan into `recon-<unix seconds>/`.
pub fn run_reconstruct_job(shared: &Arc<Shared>, scan: String) {
    let result = (|| -> Result<serde_json::Value, JobError> {
        let dir = scan_dir(&shared.lab.recording.data_dir, &scan)?;
        let capture_dir = dir.join("capture");
        let capture = read_capture_dir(&capture_dir)
            .map_err(|e| JobError::Request(format!("scan {scan:?}: {e}")))?;
        let mut paths = ScanPaths::new(&dir);
        paths.recon = dir.join(format!("recon-{}", crate::record::unix_now_s()));
        let truth = crate::capture::truth_files(&capture_dir)
            .mesh
            .and_then(|m| crate::geometry::load_mesh(&m).ok())
            .map(|m| truth_of(&m));
        shared.publish(&JobEvent::State {
            state: "reconstructing".into(),
            scan: scan.clone(),
        });
        let publish = |stage: &str| {
            shared.publish(&JobEvent::Stage {
                stage: stage.into(),
                scan: scan.clone(),
            })
        };
        let (recon, metrics) = reconstruct_and_score(
            &shared.lab.reconstruction,
            &capture,
            &paths,
            truth.as_ref(),
            shared.quiet,
            &publish,
        )?;
        Ok(
            json!({"event": "reconstructed", "scan": scan, "dir": paths.recon,
            "points": recon.points_m.len(), "metrics": metrics}),
        )
    })();
    match result {
        Ok(summary) => {
            release_then_publish(shared, None);
            // No subscriber is not an error.
            shared.events.send(summary.to_string()).ok();
        }
        Err(e) => release_then_publish(
            shared,
            Some(JobEvent::Error {
                scan,
                message: e.to_string(),
            }),
        ),
    }
}

/// The folder of a stored scan, refusing names that leave the data directory.
pub fn scan_dir(data_dir: &Path, scan: &str) -> Result<PathBuf, JobError> {
    ScanRequest {
        name: Some(scan.into()),
        ..ScanRequest::default()
    }
    .folder_name(0)?;
    let dir = data_dir.join(scan);
    if !dir.is_dir() {
        return Err(JobError::Request(format!("scan {scan:?}: no such scan")));
    }
    Ok(dir)
}

/// Stored scans and their reconstructions.
pub fn list_scans(data_dir: &Path) -> Vec<serde_json::Value> {
    let Ok(entries) = std::fs::read_dir(data_dir) else {
        return Vec::new();
    };
    let mut names: Vec<PathBuf> = entries
        .filter_map(Result::ok)
        .map(|e| e.path())
        .filter(|p| p.join("scan.mcap").exists())
        .collect();
    names.sort();
    names
        .iter()
        .map(|dir| {
            let result = std::fs::read_to_string(dir.join("scan.json"))
                .ok()
                .and_then(|t| serde_json::from_str::<serde_json::Value>(&t).ok());
            let mut recons: Vec<String> = std::fs::read_dir(dir)
                .into_iter()
                .flatten()
                .filter_map(Result::ok)
                .filter(|e| e.path().join("points.ply").exists())
                .map(|e| e.file_name().to_string_lossy().into_owned())
                .collect();
            recons.sort();
            json!({
                "scan": dir.file_name().map(|n| n.to_string_lossy().into_owned()),
                "mcap": dir.join("scan.mcap"),
                "capture": dir.join("capture").is_dir(),
                "reconstructions": recons,
                "points": result.as_ref().and_then(|r| r.get("points").cloned()),
                "f_score": result.as_ref().and_then(|r| r.pointer("/metrics/f_score").cloned()),
            })
        })
        .collect()
}
