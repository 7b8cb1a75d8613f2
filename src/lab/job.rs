//! A scan job from request to result, shared by the daemon, `mmnormd demo` and
//! `mmnormd replay`: the scan's folder, its recording, the capture directory, the
//! reconstruction, the score against the truth where there is one, and the events a control
//! client follows.
//!
//! Layout of `recording.data_dir/<name>/`: `scan.mcap` (everything), `capture/` (capture
//! directory v1, with `truth.ply`/`truth_top.npy` in the simulated lab), `recon/` (points.ply,
//! summary.json, PNG previews) and `scan.json` (the job's result).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use super::config::LabConfig;
use super::scan::{
    Devices, RowRecording, RowSummary, ScanError, ScanLog, ScanSetup, align_recording,
    build_capture, row_problem, run_scan,
};
use crate::align::RowAlignment;
use crate::capture::Capture;
use crate::capture::dir::{write_atomically, write_capture_dir};
use crate::dca1000::Frame;
use crate::dca1000::packet::PacketArrival;
use crate::eval::{Metrics, evaluate};
use crate::geometry::{TriMesh, ply};
use crate::radar::RadarProfile;
use crate::recon::{ReconConfig, Reconstruction, image_volume, output, reconstruct_imaged};
use crate::record::replay::{RecordedScan, replayed_output_names};
use crate::record::{McapRecorder, RecorderOptions, messages, unix_now_ns};
use crate::sim::truth::{TOP_GRID_M, top_surface_with_normals};
use crate::ur::motion::ScanSpec;
use crate::ur::rtde::Sample;

/// Why a job failed.
#[derive(Debug, thiserror::Error)]
pub enum JobError {
    #[error(transparent)]
    Scan(#[from] ScanError),
    #[error("recording: {0}")]
    Record(String),
    #[error("{0}")]
    Io(String),
    #[error("reconstruction: {0}")]
    Recon(String),
    #[error("{0}")]
    Request(String),
}

/// What a client may change for one scan.
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ScanRequest {
    /// Folder name under `recording.data_dir` (letters, digits, `-`, `_`, `.`).
    pub name: Option<String>,
    pub width_m: Option<f64>,
    pub height_m: Option<f64>,
    pub speed_m_per_s: Option<f64>,
    /// What was scanned, kept in the recording.
    pub label: Option<String>,
}

impl ScanRequest {
    /// The config's raster with this request's changes.
    pub fn apply(&self, base: &ScanSpec) -> ScanSpec {
        let mut spec = base.clone();
        if let Some(w) = self.width_m {
            spec.width_m = w;
        }
        if let Some(h) = self.height_m {
            spec.height_m = h;
        }
        if let Some(v) = self.speed_m_per_s {
            spec.speed_m_per_s = v;
        }
        spec
    }

    /// The scan's folder name: the request's, checked, or `scan-<unix seconds>`.
    pub fn folder_name(&self, unix_s: u64) -> Result<String, JobError> {
        match &self.name {
            None => Ok(format!("scan-{unix_s}")),
            Some(n)
                if !n.is_empty()
                    && n.len() <= 100
                    && !n.starts_with('.')
                    && n.chars()
                        .all(|c| c.is_ascii_alphanumeric() || "-_.".contains(c)) =>
            {
                Ok(n.clone())
            }
            Some(n) => Err(JobError::Request(format!(
                "name = {n:?}: use 1–100 letters, digits, '-', '_' or '.', not starting with '.'"
            ))),
        }
    }
}

/// The files of one scan.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct ScanPaths {
    pub dir: PathBuf,
    pub mcap: PathBuf,
    pub capture: PathBuf,
    pub recon: PathBuf,
    pub result: PathBuf,
}

impl ScanPaths {
    pub fn new(dir: &Path) -> Self {
        Self {
            dir: dir.to_path_buf(),
            mcap: dir.join("scan.mcap"),
            capture: dir.join("capture"),
            recon: dir.join("recon"),
            result: dir.join("scan.json"),
        }
    }
}

/// What a job reports as it runs (the control port's `subscribe` stream).
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
#[serde(tag = "event", rename_all = "snake_case")]
pub enum JobEvent {
    State {
        state: String,
        scan: String,
    },
    Row {
        scan: String,
        #[serde(flatten)]
        row: RowSummary,
    },
    Stage {
        stage: String,
        scan: String,
    },
    Result(Box<JobResult>),
    Error {
        scan: String,
        message: String,
    },
}

/// The job's result (`scan.json`).
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct JobResult {
    pub scan: String,
    pub paths: ScanPaths,
    pub rows: usize,
    pub rescanned_rows: usize,
    pub reported_rows: Vec<usize>,
    pub frames: usize,
    pub kept_frames: usize,
    pub lost_packets: u64,
    pub antennas: usize,
    pub points: usize,
    pub metrics: Option<Metrics>,
    pub scan_s: f64,
    pub recon_s: f64,
    pub stage_s: Vec<(String, f64)>,
}

/// The truth as scored: top surface points and normals on a 1 mm grid.
pub type Truth = (Vec<[f64; 3]>, Vec<[f64; 3]>);

/// The truth of a mesh seen from above (the paper's depth-camera truth).
pub fn truth_of(mesh: &TriMesh) -> Truth {
    top_surface_with_normals(mesh, TOP_GRID_M)
}

/// Metadata `mmnormd`: what a replay needs to redo the run.
pub fn recording_metadata(
    lab: &LabConfig,
    setup: &ScanSetup,
    request: &ScanRequest,
    epoch_unix_ns: u64,
    rtde_outputs: &[String],
) -> BTreeMap<String, String> {
    let json = |v: serde_json::Value| v.to_string();
    BTreeMap::from([
        ("version".into(), env!("CARGO_PKG_VERSION").into()),
        (
            "config_toml".into(),
            toml::to_string(lab).unwrap_or_default(),
        ),
        ("radar_script".into(), setup.profile.script.join("\n")),
        ("scan_spec".into(), json(serde_json::json!(setup.spec))),
        ("request".into(), json(serde_json::json!(request))),
        (
            "extrinsics".into(),
            json(serde_json::json!({
                "tcp_from_radar": lab.align.tcp_from_radar,
                "tx_in_radar_m": lab.align.tx_in_radar_m,
                "rx_in_radar_m": lab.align.rx_in_radar_m,
                "pipeline_latency_s": lab.align.pipeline_latency_s,
                "sync_offset_s": lab.align.sync_offset_s,
            })),
        ),
        ("frame_timing".into(), json(serde_json::json!(setup.timing))),
        ("epoch_unix_ns".into(), epoch_unix_ns.to_string()),
        ("rtde_outputs".into(), json(serde_json::json!(rtde_outputs))),
    ])
}

/// Forwards the scan's log to the recorder and its verdicts to the events.
struct Tee<'a, W: std::io::Write + std::io::Seek> {
    scan: &'a str,
    recorder: &'a mut McapRecorder<W>,
    /// Each row attempt's clock fits, for the `clock_fits` metadata.
    fits: Vec<serde_json::Value>,
    events: &'a (dyn Fn(JobEvent) + Sync),
}

impl<W: std::io::Write + std::io::Seek> ScanLog for Tee<'_, W> {
    fn frame(&mut self, row: usize, attempt: u32, frame: &Frame) -> Result<(), String> {
        self.recorder.frame(row, attempt, frame)
    }
    fn packet(&mut self, row: usize, attempt: u32, a: &PacketArrival) -> Result<(), String> {
        self.recorder.packet(row, attempt, a)
    }
    fn rtde(&mut self, row: usize, attempt: u32, s: &Sample) -> Result<(), String> {
        self.recorder.rtde(row, attempt, s)
    }
    fn row(&mut self, rec: &RowRecording, aligned: &RowAlignment) -> Result<(), String> {
        self.fits.push(serde_json::json!({
            "row": rec.row,
            "attempt": rec.attempt,
            "radar": aligned.radar_fit,
            "controller": aligned.controller_fit,
        }));
        self.recorder.row(rec, aligned)
    }
    fn progress(&mut self, summary: &RowSummary) {
        self.recorder.progress(summary);
        (self.events)(JobEvent::Row {
            scan: self.scan.into(),
            row: summary.clone(),
        });
    }
    fn tick(&mut self) -> Result<(), String> {
        ScanLog::tick(self.recorder)
    }
}

/// A live scan's inputs.
pub struct LiveJob<'a> {
    pub lab: &'a LabConfig,
    pub setup: &'a ScanSetup,
    pub request: &'a ScanRequest,
    pub name: &'a str,
    /// The scene's truth in the simulated lab.
    pub truth: Option<&'a Truth>,
    pub truth_mesh: Option<&'a TriMesh>,
    pub quiet: bool,
}

/// Finishes the recording of a scan that ended in `e`, or says why it could not be written.
fn end_recording<W: std::io::Write + std::io::Seek>(
    recorder: &mut McapRecorder<W>,
    epoch: Instant,
    e: ScanError,
) -> JobError {
    if let Some(at) = recorder.failed_at() {
        // The scan stopped because the recording failed: say why and how fast.
        return JobError::Record(format!(
            "{}{}; the scan stopped {:.1} ms after the first failed write",
            recorder.failure().unwrap_or("write failed"),
            e.row().map(|r| format!(" (row {r})")).unwrap_or_default(),
            at.elapsed().as_secs_f64() * 1e3
        ));
    }
    // Keep what was recorded: say why it ended and finish the file.
    let host_s = epoch.elapsed().as_secs_f64();
    if recorder.log(host_s, 4, &format!("scan ended: {e}")).is_ok() {
        recorder.finish().ok();
    }
    e.into()
}

/// Scans, records, reconstructs and scores. The recording is finished on every path it can
/// be; a recorder that failed aborts the scan.
pub fn run_live(
    job: &LiveJob<'_>,
    devices: &mut Devices<'_>,
    abort: &AtomicBool,
    events: &(dyn Fn(JobEvent) + Sync),
) -> Result<JobResult, JobError> {
    let lab = job.lab;
    let paths = ScanPaths::new(&lab.recording.data_dir.join(job.name));
    if paths.dir.exists() {
        return Err(JobError::Request(format!(
            "name = {:?}: {} already exists",
            job.name,
            paths.dir.display()
        )));
    }
    std::fs::create_dir_all(&paths.dir)
        .map_err(|e| JobError::Io(format!("creating {}: {e}", paths.dir.display())))?;
    let epoch = Instant::now();
    let epoch_unix_ns = unix_now_ns();
    let fail_after = lab
        .simulate
        .then_some(lab.sim.record_fail_after_bytes)
        .flatten();
    let mut recorder = McapRecorder::create(
        &paths.mcap,
        RecorderOptions {
            chunk_seconds: lab.recording.chunk_seconds,
            chunk_bytes: lab.recording.chunk_bytes,
        },
        epoch_unix_ns,
        fail_after,
    )
    .map_err(|e| JobError::Record(e.to_string()))?;
    let started = (|| {
        let names = devices.robot.output_names();
        recorder.metadata(
            "mmnormd",
            recording_metadata(lab, job.setup, job.request, epoch_unix_ns, &names),
        )?;
        recorder.static_transform(
            0.0,
            messages::TCP_FRAME,
            messages::RADAR_FRAME,
            &lab.align.tcp_from_radar,
        )?;
        recorder.log(0.0, 2, &format!("scan {} started", job.name))
    })();
    if let Err(e) = started {
        return Err(JobError::Record(e.to_string()));
    }
    events(JobEvent::State {
        state: "scanning".into(),
        scan: job.name.into(),
    });
    let mut tee = Tee {
        scan: job.name,
        recorder: &mut recorder,
        fits: Vec::new(),
        events,
    };
    let scanned = run_scan(lab, job.setup, devices, epoch, &mut tee, abort);
    let fits = serde_json::Value::Array(std::mem::take(&mut tee.fits)).to_string();
    // The clock fits of every row attempt, whatever happens next.
    recorder
        .metadata("clock_fits", BTreeMap::from([("json".into(), fits)]))
        .ok();
    let scan = match scanned {
        Ok(s) => s,
        Err(e) => {
            let error = end_recording(&mut recorder, epoch, e);
            if abort.load(Ordering::Relaxed)
                && let Err(e) = devices.radar.stop()
            {
                tracing::warn!("radar: sensorStop after the abort: {e}");
            }
            return Err(error);
        }
    };
    let scan_s = scan.elapsed_s;
    let mut capture = scan.capture;
    capture.description = format!(
        "{}{}",
        job.name,
        job.request
            .label
            .as_deref()
            .map(|l| format!(": {l}"))
            .unwrap_or_default()
    );
    events(JobEvent::Stage {
        stage: "capture".into(),
        scan: job.name.into(),
    });
    write_capture(&paths, &capture, job.truth_mesh)?;
    let recon_started = Instant::now();
    let (recon, metrics) = reconstruct_and_score(
        &lab.reconstruction,
        &capture,
        &paths,
        job.truth,
        job.quiet,
        &|stage| {
            events(JobEvent::Stage {
                stage: stage.into(),
                scan: job.name.into(),
            })
        },
    )?;
    let recon_s = recon_started.elapsed().as_secs_f64();
    let host_s = epoch.elapsed().as_secs_f64();
    let result = JobResult {
        scan: job.name.into(),
        paths: paths.clone(),
        rows: setup_rows(job.setup),
        rescanned_rows: scan.rows.iter().filter(|r| r.attempt > 0).count(),
        reported_rows: scan.reported_rows,
        frames: scan
            .rows
            .iter()
            .filter(|r| r.accepted)
            .map(|r| r.frames)
            .sum(),
        kept_frames: scan
            .rows
            .iter()
            .filter(|r| r.accepted)
            .map(|r| r.kept)
            .sum(),
        lost_packets: scan.rows.iter().map(|r| r.lost_packets).sum(),
        antennas: capture.antennas(),
        points: recon.points_m.len(),
        metrics,
        scan_s,
        recon_s,
        stage_s: recon.summary.stage_s.clone(),
    };
    let finished = (|| {
        recorder.points(host_s, &recon.points_m, recon.normals.as_deref())?;
        let text = serde_json::to_string(&result).unwrap_or_default();
        recorder.metadata("scan_result", BTreeMap::from([("json".into(), text)]))?;
        recorder.finish().map(|_| ())
    })();
    finished.map_err(|e| JobError::Record(e.to_string()))?;
    write_result(&paths, &result)?;
    events(JobEvent::Result(Box::new(result.clone())));
    Ok(result)
}

fn setup_rows(setup: &ScanSetup) -> usize {
    setup.plan.rows.len()
}

/// Writes the capture directory, with the truth mesh and its top surface when known.
pub fn write_capture(
    paths: &ScanPaths,
    capture: &Capture,
    truth_mesh: Option<&TriMesh>,
) -> Result<(), JobError> {
    let io = |e: String| JobError::Io(format!("{}: {e}", paths.capture.display()));
    write_capture_dir(&paths.capture, capture).map_err(|e| io(e.to_string()))?;
    if let Some(mesh) = truth_mesh {
        write_atomically(
            &paths.capture.join("truth.ply"),
            &ply::encode_mesh(&mesh.vertices_m, &mesh.triangles),
        )
        .map_err(|e| io(e.to_string()))?;
    }
    Ok(())
}

/// Writes `scan.json`.
pub fn write_result(paths: &ScanPaths, result: &JobResult) -> Result<(), JobError> {
    let mut text = serde_json::to_string_pretty(result).unwrap_or_default();
    text.push('\n');
    write_atomically(&paths.result, text.as_bytes())
        .map_err(|e| JobError::Io(format!("{}: {e}", paths.result.display())))
}

/// Images, reconstructs, writes `recon/` and scores against `truth` (τ = 1.5 cm).
pub fn reconstruct_and_score(
    config: &ReconConfig,
    capture: &Capture,
    paths: &ScanPaths,
    truth: Option<&Truth>,
    quiet: bool,
    stage: &dyn Fn(&str),
) -> Result<(Reconstruction, Option<Metrics>), JobError> {
    let recon_error = |e: crate::recon::pipeline::ReconError| JobError::Recon(e.to_string());
    stage("imaging");
    let imaged = image_volume(capture, config, quiet).map_err(recon_error)?;
    stage("reconstructing");
    let recon = reconstruct_imaged(capture, config, &imaged, quiet).map_err(recon_error)?;
    output::write_reconstruction(
        &paths.capture.display().to_string(),
        &paths.recon,
        config,
        &recon,
        &imaged.magnitude,
        truth.map(|(points, _)| points.as_slice()),
    )
    .map_err(|e| JobError::Io(e.to_string()))?;
    let metrics = truth.map(|(points, normals)| {
        stage("scoring");
        evaluate(
            &recon.points_m,
            recon.normals.as_deref(),
            points,
            Some(normals),
            0.015,
        )
    });
    Ok((recon, metrics))
}

/// A recording's config, setup and capture, rebuilt exactly as the live run built them:
/// the same alignment and the same row verdicts on the same recorded data.
pub fn replay_capture(
    scan: &RecordedScan,
    config_override: Option<&LabConfig>,
) -> Result<(LabConfig, ScanSetup, Capture), JobError> {
    let (lab, setup, kept) = replay_rows(scan, config_override)?;
    let capture = build_capture(&lab, &setup, &kept);
    Ok((lab, setup, capture))
}

/// Rows with their alignment, in row order.
pub type AlignedRows = Vec<(RowRecording, RowAlignment)>;

/// A recording's config, setup and kept rows (each row's attempt that the live run kept,
/// aligned again), in row order.
pub fn replay_rows(
    scan: &RecordedScan,
    config_override: Option<&LabConfig>,
) -> Result<(LabConfig, ScanSetup, AlignedRows), JobError> {
    let bad = |what: &str| JobError::Request(format!("the recording's metadata lacks {what}"));
    let meta = scan
        .metadata
        .get("mmnormd")
        .ok_or_else(|| bad("`mmnormd`"))?;
    let lab: LabConfig = match config_override {
        Some(c) => c.clone(),
        None => toml::from_str(meta.get("config_toml").ok_or_else(|| bad("config_toml"))?)
            .map_err(|e| JobError::Request(format!("the recorded config: {e}")))?,
    };
    let profile = RadarProfile::from_cfg_str(
        meta.get("radar_script")
            .ok_or_else(|| bad("radar_script"))?,
    )
    .map_err(|e| JobError::Request(format!("the recorded radar script: {e}")))?;
    let spec: ScanSpec =
        serde_json::from_str(meta.get("scan_spec").ok_or_else(|| bad("scan_spec"))?)
            .map_err(|e| JobError::Request(format!("the recorded scan spec: {e}")))?;
    let setup = ScanSetup::with_profile(&lab, spec, profile)?;
    let names = replayed_output_names();
    // Per row, in row order: the first attempt without a problem, else the last one recorded.
    // That is the attempt the live run kept (it stops at the first clean attempt, and keeps its
    // last one otherwise), also for a recording judged by older, laxer rules.
    let mut kept: BTreeMap<usize, (RowRecording, RowAlignment, bool)> = BTreeMap::new();
    for rec in scan.rows.iter().filter(|r| r.finished) {
        let recording = RowRecording {
            row: rec.row,
            attempt: rec.attempt,
            direction: rec.direction,
            usable_x_m: rec.usable_x_m,
            frames: rec.frames.clone(),
            complete: rec.complete.clone(),
            arrivals: rec.arrivals.clone(),
            rtde: rec.rtde.clone(),
            report: Default::default(),
            outcome: rec.outcome.clone(),
            rtde_gaps: rec.rtde_gaps,
        };
        let aligned = align_recording(&lab, &setup, &names, &recording).map_err(|source| {
            ScanError::Align {
                row: rec.row,
                source,
            }
        })?;
        let clean = row_problem(&lab, &recording, &aligned).is_none();
        if !kept.get(&rec.row).is_some_and(|k| k.2) {
            kept.insert(rec.row, (recording, aligned, clean));
        }
    }
    let kept: AlignedRows = kept.into_values().map(|(r, a, _)| (r, a)).collect();
    Ok((lab, setup, kept))
}
