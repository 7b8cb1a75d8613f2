//! One scan (issue: scan pipeline): for each raster row, DCA1000 record start, `sensorStart`,
//! the row's `movel` with RTDE streaming, stop and flush, then time alignment
//! ([`crate::align`]). A row whose frame loss exceeds `recording.max_frame_loss`, that had an
//! RTDE gap, whose program ended short of the row's end (the RTDE watchdog tripped), or whose
//! clock fits stray beyond `recording.max_clock_residual_s` ([`row_problem`]) is scanned again
//! up to `recording.max_row_retries` times, then reported and kept for what it holds. Every
//! attempt goes to the [`ScanLog`] (the MCAP recorder) before it is judged, so nothing recorded
//! is lost. The kept frames become the [`Capture`].
//!
//! The devices come in through their traits; this module never opens a socket.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use num_complex::Complex32;

use super::config::LabConfig;
use crate::align::{AlignError, FrameTiming, PoseSample, RowAlignment, RowInput, align_row};
use crate::capture::Capture;
use crate::dca1000::Frame;
use crate::dca1000::board::{
    BoardError, CaptureBoard, CaptureReport, RecordPlan, RecordSink, record_frames,
};
use crate::dca1000::packet::PacketArrival;
use crate::dca1000::samples::{FrameLayout, LayoutError};
use crate::radar::ProfileError;
use crate::radar::{RadarControl, RadarProfile};
use crate::ur::motion::{PlanError, RasterPlan, Row, ScanSpec, plan_raster};
use crate::ur::robot::{Robot, RobotError, RowOutcome};
use crate::ur::rtde::{Sample, Value};

/// Why a scan stopped.
#[derive(Debug, thiserror::Error)]
pub enum ScanError {
    #[error(transparent)]
    Profile(#[from] ProfileError),
    #[error(transparent)]
    Layout(#[from] LayoutError),
    #[error(transparent)]
    Plan(#[from] PlanError),
    #[error("{0}")]
    Setup(String),
    #[error("row {row}: {source}")]
    Board {
        row: usize,
        #[source]
        source: BoardError,
    },
    #[error("row {row}: {source}")]
    Robot {
        row: usize,
        #[source]
        source: RobotError,
    },
    #[error("row {row}: the radar: {message}")]
    Radar { row: usize, message: String },
    #[error("row {row}: {source}")]
    Align {
        row: usize,
        #[source]
        source: AlignError,
    },
    #[error(
        "row {row}: the arm reported a safety stop ({safety}); the scan is paused for a person"
    )]
    SafetyStop { row: usize, safety: String },
    #[error(
        "row {row}: the arm's program ended {:.1} mm short of the row's start, with no safety \
         stop (stopped from the pendant or the Dashboard?)",
        short_of_target_m * 1e3
    )]
    StoppedShort { row: usize, short_of_target_m: f64 },
    #[error("aborted at row {row}")]
    Aborted { row: usize },
    #[error("recording: {0}")]
    Log(String),
}

impl ScanError {
    /// The row the error happened at, if any.
    pub fn row(&self) -> Option<usize> {
        match self {
            ScanError::Board { row, .. }
            | ScanError::Robot { row, .. }
            | ScanError::Radar { row, .. }
            | ScanError::Align { row, .. }
            | ScanError::SafetyStop { row, .. }
            | ScanError::StoppedShort { row, .. }
            | ScanError::Aborted { row } => Some(*row),
            _ => None,
        }
    }
}

/// Everything a scan needs that follows from the config, the profile and the request.
#[derive(Debug, Clone)]
pub struct ScanSetup {
    pub spec: ScanSpec,
    pub profile: RadarProfile,
    pub layout: FrameLayout,
    pub timing: FrameTiming,
    pub plan: RasterPlan,
}

impl ScanSetup {
    /// Reads the profile and plans the raster; refuses what cannot work before any device is
    /// touched (over-speed, a profile too short for a row, extrinsics for another RX count).
    pub fn new(lab: &LabConfig, spec: ScanSpec) -> Result<Self, ScanError> {
        let profile = RadarProfile::from_cfg_file(&lab.radar.profile)?;
        Self::with_profile(lab, spec, profile)
    }

    /// [`new`](Self::new) with the profile already read (a replay takes it from the recording).
    pub fn with_profile(
        lab: &LabConfig,
        spec: ScanSpec,
        profile: RadarProfile,
    ) -> Result<Self, ScanError> {
        let layout = lab.dca1000.layout(&profile)?;
        if layout.chirps_per_frame != 1 {
            return Err(ScanError::Setup(format!(
                "radar.profile {} has {} chirps per frame; a scan takes one chirp per frame (one TX position each)",
                lab.radar.profile.display(),
                layout.chirps_per_frame
            )));
        }
        if lab.align.rx_in_radar_m.len() != profile.rx_count() {
            return Err(ScanError::Setup(format!(
                "align.rx_in_radar_m lists {} receivers but the profile enables {}",
                lab.align.rx_in_radar_m.len(),
                profile.rx_count()
            )));
        }
        let period_s = profile.frame_period_s();
        let wavelength_m = profile.first_sample_wavelength_m();
        let plan = plan_raster(&spec, wavelength_m, period_s)?;
        let row_s = plan.rows.first().map_or(0.0, |r| r.duration_s);
        let recorded_s = f64::from(profile.frames) * period_s;
        if profile.frames != 0 && recorded_s < row_s + 1.0 {
            return Err(ScanError::Setup(format!(
                "radar.profile records {} frames × {:.1} ms = {recorded_s:.2} s per row, but a row at scan.speed_m_per_s = {} takes {row_s:.2} s (+1 s margin); raise frameCfg's frame count",
                profile.frames,
                period_s * 1e3,
                spec.speed_m_per_s
            )));
        }
        Ok(Self {
            timing: FrameTiming {
                frame_period_s: period_s,
                frame_bytes: layout.frame_bytes(),
                centre_s: profile.first_chirp_centre_s(),
                acquired_s: profile.frame_active_s(),
                wavelength_m,
            },
            spec,
            profile,
            layout,
            plan,
        })
    }
}

/// The devices a scan drives.
pub struct Devices<'a> {
    pub radar: &'a mut dyn RadarControl,
    pub board: &'a mut dyn CaptureBoard,
    pub robot: &'a mut (dyn Robot + Send),
}

/// What one attempt at a row recorded.
#[derive(Debug, Clone)]
pub struct RowRecording {
    pub row: usize,
    pub attempt: u32,
    pub direction: i8,
    pub usable_x_m: (f64, f64),
    /// Every frame in order, zero-filled where data was lost.
    pub frames: Vec<Vec<u8>>,
    pub complete: Vec<bool>,
    pub arrivals: Vec<PacketArrival>,
    /// RTDE samples, `host_s` counted from the scan's epoch.
    pub rtde: Vec<Sample>,
    pub report: CaptureReport,
    pub outcome: RowOutcome,
    pub rtde_gaps: usize,
}

impl RowRecording {
    /// Flagged frames before the last one (the last frame's tail waits in the FPGA for its
    /// idle flush when the radar stops early), as a fraction of those frames.
    pub fn frame_loss(&self) -> f64 {
        let n = self.complete.len().saturating_sub(1);
        if n == 0 {
            return 1.0;
        }
        self.complete[..n].iter().filter(|c| !**c).count() as f64 / n as f64
    }
}

/// The RTDE samples of a row as alignment wants them.
pub fn pose_samples(output_names: &[String], samples: &[Sample]) -> Vec<PoseSample> {
    let pose_at = output_names.iter().position(|n| n == "actual_TCP_pose");
    samples
        .iter()
        .filter_map(|s| {
            let tcp_pose = match s.values.get(pose_at?) {
                Some(Value::Vector6d(p)) => *p,
                _ => return None,
            };
            Some(PoseSample {
                host_s: s.host_s,
                controller_s: s.controller_s?,
                segment: s.segment,
                tcp_pose,
            })
        })
        .collect()
}

/// Aligns a recorded row with the config's extrinsics.
pub fn align_recording(
    lab: &LabConfig,
    setup: &ScanSetup,
    output_names: &[String],
    rec: &RowRecording,
) -> Result<RowAlignment, AlignError> {
    let poses = pose_samples(output_names, &rec.rtde);
    align_row(
        &lab.align,
        &setup.timing,
        &RowInput {
            frame_complete: &rec.complete,
            packets: &rec.arrivals,
            poses: &poses,
            usable_x_m: rec.usable_x_m,
        },
    )
}

/// A row's result as the scan reports it.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct RowSummary {
    pub row: usize,
    pub rows: usize,
    pub attempt: u32,
    pub direction: i8,
    pub frames: usize,
    pub kept: usize,
    pub frame_loss: f64,
    pub lost_packets: u64,
    pub rtde_gaps: usize,
    pub accepted: bool,
    /// Why the row is scanned again or reported, if it is.
    pub problem: Option<String>,
}

impl RowSummary {
    /// The summary of a recorded attempt.
    fn of(
        rec: &RowRecording,
        rows: usize,
        kept: usize,
        problem: Option<String>,
        accepted: bool,
    ) -> Self {
        Self {
            row: rec.row,
            rows,
            attempt: rec.attempt,
            direction: rec.direction,
            frames: rec.complete.len(),
            kept,
            frame_loss: rec.frame_loss(),
            lost_packets: rec.report.stream.lost,
            rtde_gaps: rec.rtde_gaps,
            accepted,
            problem,
        }
    }
}

/// Where a scan records and reports as it goes. Data arrive as they are received, so a
/// recorder loses at most what it has not yet written when the process dies.
pub trait ScanLog {
    /// A frame of row `row`'s attempt `attempt`, complete or flagged.
    fn frame(&mut self, row: usize, attempt: u32, frame: &Frame) -> Result<(), String>;
    /// A data packet's place and arrival.
    fn packet(&mut self, row: usize, attempt: u32, arrival: &PacketArrival) -> Result<(), String>;
    /// An RTDE sample (`host_s` from the scan's epoch).
    fn rtde(&mut self, row: usize, attempt: u32, sample: &Sample) -> Result<(), String>;
    /// The attempt's end: its report and alignment, before it is judged.
    fn row(&mut self, rec: &RowRecording, aligned: &RowAlignment) -> Result<(), String>;
    /// A row's verdict.
    fn progress(&mut self, summary: &RowSummary);
    /// Called every few milliseconds while a row records (a recorder closes chunks on time).
    fn tick(&mut self) -> Result<(), String> {
        Ok(())
    }
}

/// The scan's result: the capture from every accepted row and what happened.
#[derive(Debug, Clone)]
pub struct ScanResult {
    pub capture: Capture,
    pub rows: Vec<RowSummary>,
    /// Rows that failed every attempt (kept for what they hold).
    pub reported_rows: Vec<usize>,
    pub elapsed_s: f64,
}

/// Runs the scan. After an abort the radar may still be sending: the caller stops it once it
/// has finished what it records, so that a slow `sensorStop` cannot hold up the file.
pub fn run_scan(
    lab: &LabConfig,
    setup: &ScanSetup,
    devices: &mut Devices<'_>,
    epoch: Instant,
    log: &mut dyn ScanLog,
    abort: &AtomicBool,
) -> Result<ScanResult, ScanError> {
    let started = Instant::now();
    let names = devices.robot.output_names();
    let mut kept: Vec<(RowRecording, RowAlignment)> = Vec::new();
    let mut summaries = Vec::new();
    let mut reported = Vec::new();
    let rows = setup.plan.rows.len();
    for row in &setup.plan.rows {
        for attempt in 0..=lab.recording.max_row_retries {
            if abort.load(Ordering::Relaxed) {
                return Err(ScanError::Aborted { row: row.index });
            }
            let rec = record_row(lab, setup, devices, log, row, attempt, epoch, abort)?;
            let last_attempt = attempt == lab.recording.max_row_retries;
            let aligned = match align_recording(lab, setup, &names, &rec) {
                Ok(a) => a,
                // A row that cannot be aligned (too short a stream to fit a clock) is scanned
                // again; its raw data stay in the recording, without a row result.
                Err(source) if last_attempt => {
                    return Err(ScanError::Align {
                        row: row.index,
                        source,
                    });
                }
                Err(source) => {
                    let problem = Some(format!("alignment: {source}"));
                    let summary = RowSummary::of(&rec, rows, 0, problem, false);
                    log.progress(&summary);
                    summaries.push(summary);
                    continue;
                }
            };
            log.row(&rec, &aligned).map_err(ScanError::Log)?;
            let problem = row_problem(lab, &rec, &aligned);
            let accepted = problem.is_none() || last_attempt;
            let summary =
                RowSummary::of(&rec, rows, aligned.frames.len(), problem.clone(), accepted);
            log.progress(&summary);
            summaries.push(summary);
            if problem.is_none() || last_attempt {
                if problem.is_some() {
                    reported.push(row.index);
                }
                kept.push((rec, aligned));
                break;
            }
        }
    }
    Ok(ScanResult {
        capture: build_capture(lab, setup, &kept),
        rows: summaries,
        reported_rows: reported,
        elapsed_s: started.elapsed().as_secs_f64(),
    })
}

/// The recording side of one row attempt: frames and packets into the log and the buffers,
/// RTDE samples drained from the robot thread, the radar stopped once the arm is done.
struct RowSink<'a, 'r> {
    radar: &'a mut (dyn RadarControl + 'r),
    log: &'a mut dyn ScanLog,
    row: usize,
    attempt: u32,
    go: Option<mpsc::Sender<()>>,
    samples: mpsc::Receiver<Sample>,
    robot_done: &'a AtomicBool,
    row_abort: &'a AtomicBool,
    abort: &'a AtomicBool,
    radar_stop: Option<Result<(), String>>,
    log_error: Option<String>,
    frames: Vec<Vec<u8>>,
    complete: Vec<bool>,
    rtde: Vec<Sample>,
}

impl RowSink<'_, '_> {
    fn drain_samples(&mut self) {
        while let Ok(sample) = self.samples.try_recv() {
            if self.log_error.is_none()
                && let Err(e) = self.log.rtde(self.row, self.attempt, &sample)
            {
                self.log_error = Some(e);
            }
            self.rtde.push(sample);
        }
        if self.log_error.is_none()
            && let Err(e) = self.log.tick()
        {
            self.log_error = Some(e);
        }
    }

    fn failed(&self) -> std::io::Result<()> {
        match &self.log_error {
            Some(e) => Err(std::io::Error::other(e.clone())),
            None => Ok(()),
        }
    }
}

impl RecordSink for RowSink<'_, '_> {
    fn start_sensor(&mut self) -> Result<(), String> {
        self.radar.start().map_err(|e| e.to_string())?;
        if let Some(go) = self.go.take() {
            go.send(()).ok();
        }
        Ok(())
    }

    fn finished(&mut self) -> bool {
        self.drain_samples();
        if self.abort.load(Ordering::Relaxed) {
            // The scan is over: the arm stops, and the radar is stopped by the caller once it
            // has finished the recording (`sensorStop` may wait seconds on a stalled link).
            self.row_abort.store(true, Ordering::Relaxed);
            return true;
        }
        if self.log_error.is_some() {
            self.row_abort.store(true, Ordering::Relaxed);
        }
        if self.radar_stop.is_none()
            && (self.robot_done.load(Ordering::Acquire) || self.row_abort.load(Ordering::Relaxed))
        {
            self.radar_stop = Some(self.radar.stop().map_err(|e| e.to_string()));
        }
        self.radar_stop.is_some()
    }

    fn packet(&mut self, arrival: &PacketArrival) -> std::io::Result<()> {
        self.failed()?;
        self.log
            .packet(self.row, self.attempt, arrival)
            .map_err(std::io::Error::other)
    }

    fn frame(&mut self, frame: &Frame) -> std::io::Result<()> {
        self.failed()?;
        self.log
            .frame(self.row, self.attempt, frame)
            .map_err(std::io::Error::other)?;
        self.complete.push(frame.is_complete());
        self.frames.push(frame.data.to_vec());
        Ok(())
    }
}

/// Why a row attempt must be scanned again, if it must: a program that ended short of the
/// row's end, frame loss above `recording.max_frame_loss`, an RTDE gap, or a clock fit whose
/// largest residual exceeds `recording.max_clock_residual_s`.
pub fn row_problem(lab: &LabConfig, rec: &RowRecording, aligned: &RowAlignment) -> Option<String> {
    let frame_loss = rec.frame_loss();
    let limit_s = lab.recording.max_clock_residual_s;
    let strayed = [
        ("radar", &aligned.radar_fit),
        ("controller", &aligned.controller_fit),
    ]
    .into_iter()
    // A NaN residual (a fit that could not be judged) strays too.
    .find(|(_, fit)| fit.residual_max_s.is_nan() || fit.residual_max_s > limit_s);
    if let RowOutcome::StoppedShort { short_of_target_m } = rec.outcome {
        Some(format!(
            "the arm stopped {:.1} mm short of the row's end (the RTDE watchdog tripped, or the \
             program was stopped)",
            short_of_target_m * 1e3
        ))
    } else if frame_loss > lab.recording.max_frame_loss {
        Some(format!(
            "frame loss {:.2} % above recording.max_frame_loss = {:.2} %",
            frame_loss * 100.0,
            lab.recording.max_frame_loss * 100.0
        ))
    } else if rec.rtde_gaps > 0 {
        Some(format!("{} RTDE gap(s) during the row", rec.rtde_gaps))
    } else if let Some((clock, fit)) = strayed {
        Some(format!(
            "the {clock} clock fit strays {:.1} ms from its line, above \
             recording.max_clock_residual_s = {:.1} ms (the host stamped arrivals late)",
            fit.residual_max_s * 1e3,
            limit_s * 1e3
        ))
    } else {
        None
    }
}

/// The error for an arm move that did not complete; a row that stopped short is judged by
/// [`row_problem`] instead.
fn completed(row: usize, outcome: &RowOutcome) -> Result<(), ScanError> {
    match outcome {
        RowOutcome::Completed => Ok(()),
        RowOutcome::Aborted => Err(ScanError::Aborted { row }),
        RowOutcome::SafetyStop { safety, .. } => Err(ScanError::SafetyStop {
            row,
            safety: safety.name().into(),
        }),
        RowOutcome::StoppedShort { short_of_target_m } => Err(ScanError::StoppedShort {
            row,
            short_of_target_m: *short_of_target_m,
        }),
    }
}

/// One attempt at one row (see the module docs).
#[allow(clippy::too_many_arguments)]
fn record_row(
    lab: &LabConfig,
    setup: &ScanSetup,
    devices: &mut Devices<'_>,
    log: &mut dyn ScanLog,
    row: &Row,
    attempt: u32,
    epoch: Instant,
    abort: &AtomicBool,
) -> Result<RowRecording, ScanError> {
    let index = row.index;
    let robot_error = |source| ScanError::Robot { row: index, source };
    completed(
        index,
        &devices
            .robot
            .move_to(&row.start_pose, &setup.spec, abort)
            .map_err(robot_error)?,
    )?;
    let d = &lab.dca1000;
    let plan = RecordPlan {
        frames: if setup.profile.frames == 0 {
            u64::MAX
        } else {
            u64::from(setup.profile.frames)
        },
        frame_bytes: setup.layout.frame_bytes(),
        frame_period_s: setup.timing.frame_period_s,
        first_frame_margin: Duration::from_millis(d.first_frame_margin_ms),
        stop_delay: Duration::from_secs_f64(d.stop_delay_s),
        epoch,
    };
    let shift_s = crate::netio::signed_seconds(devices.robot.epoch(), epoch);
    let board = &mut *devices.board;
    let robot = &mut *devices.robot;
    let row_abort = AtomicBool::new(false);
    let robot_done = AtomicBool::new(false);
    let (go_tx, go_rx) = mpsc::channel::<()>();
    let (sample_tx, sample_rx) = mpsc::channel::<Sample>();
    let mut sink = RowSink {
        radar: &mut *devices.radar,
        log,
        row: index,
        attempt,
        go: Some(go_tx),
        samples: sample_rx,
        robot_done: &robot_done,
        row_abort: &row_abort,
        abort,
        radar_stop: None,
        log_error: None,
        frames: Vec::new(),
        complete: Vec::new(),
        rtde: Vec::new(),
    };
    let (recorded, driven) = std::thread::scope(|s| {
        let (row_abort, robot_done) = (&row_abort, &robot_done);
        let driver = s.spawn(move || {
            go_rx.recv().ok()?;
            let mut forward = |sample: &Sample| {
                let mut sample = sample.clone();
                sample.host_s += shift_s;
                sample_tx.send(sample).ok();
            };
            let r = robot.drive_row(row, &setup.spec, row_abort, &mut forward);
            robot_done.store(true, Ordering::Release);
            Some(r)
        });
        let recorded = record_frames(board, &plan, &mut sink);
        sink.go = None;
        // Whatever ended the recording, the arm must not go on alone.
        if recorded.is_err() {
            row_abort.store(true, Ordering::Relaxed);
        }
        let driven = driver.join();
        (recorded, driven)
    });
    sink.drain_samples();
    if let Some(e) = sink.log_error.take() {
        if sink.radar_stop.is_none() {
            sink.radar.stop().ok();
        }
        return Err(ScanError::Log(e));
    }
    if abort.load(Ordering::Relaxed) {
        // Left running for the caller to stop after the recording is finished.
        return Err(ScanError::Aborted { row: index });
    }
    if sink.radar_stop.is_none() {
        // The recording ended without the row finishing: make sure the radar is stopped.
        sink.radar_stop = Some(sink.radar.stop().map_err(|e| e.to_string()));
    }
    let mut report = recorded.map_err(|source| ScanError::Board { row: index, source })?;
    let record = match driven {
        Ok(Some(r)) => r.map_err(robot_error)?,
        Ok(None) => {
            return Err(ScanError::Radar {
                row: index,
                message: "sensorStart failed".into(),
            });
        }
        Err(_) => {
            return Err(ScanError::Setup(format!(
                "row {index}: the robot thread panicked"
            )));
        }
    };
    if let Some(Err(message)) = sink.radar_stop.take() {
        return Err(ScanError::Radar {
            row: index,
            message,
        });
    }
    // A row that stopped short is judged by `row_problem`, like a lossy one.
    if !matches!(record.outcome, RowOutcome::StoppedShort { .. }) {
        completed(index, &record.outcome)?;
    }
    Ok(RowRecording {
        row: index,
        attempt,
        direction: row.direction,
        usable_x_m: row.usable_x_m,
        frames: sink.frames,
        complete: sink.complete,
        arrivals: std::mem::take(&mut report.arrivals),
        rtde: sink.rtde,
        report,
        outcome: record.outcome,
        rtde_gaps: record.gaps,
    })
}

/// The capture from the kept frames of the accepted rows: one virtual antenna per (frame, RX),
/// RX-minor, samples as ADC counts.
pub fn build_capture(
    lab: &LabConfig,
    setup: &ScanSetup,
    rows: &[(RowRecording, RowAlignment)],
) -> Capture {
    let t = setup.layout.samples_per_chirp;
    let rx = setup.layout.rx_count;
    let mut capture = Capture {
        plan: setup.profile.frequency_plan(),
        range_offset_m: lab.align.range_offset_m,
        tx_m: Vec::new(),
        rx_m: Vec::new(),
        samples: Default::default(),
        description: String::new(),
        extra: serde_json::Map::new(),
    };
    let samples = std::sync::Arc::make_mut(&mut capture.samples);
    for (rec, aligned) in rows {
        for f in &aligned.frames {
            let Some(bytes) = rec.frames.get(f.frame as usize) else {
                continue;
            };
            let Ok(words) = setup.layout.decode(bytes) else {
                continue;
            };
            for (k, rx_m) in f.rx_in_base_m.iter().enumerate().take(rx) {
                capture.tx_m.push(f.tx_in_base_m);
                capture.rx_m.push(*rx_m);
                samples.extend(
                    words[k * t..(k + 1) * t]
                        .iter()
                        .map(|w| Complex32::new(f32::from(w.re), f32::from(w.im))),
                );
            }
        }
    }
    capture
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ur::clock::ClockFit;

    fn fit(residual_max_s: f64) -> ClockFit {
        ClockFit {
            offset_s: 0.0,
            drift: 0.0,
            reference_s: 0.0,
            residual_rms_s: residual_max_s / 2.0,
            residual_max_s,
            bins: 8,
        }
    }

    /// A row attempt of 100 complete frames that ended as `outcome`, and its alignment.
    fn attempt(
        outcome: RowOutcome,
        radar_s: f64,
        controller_s: f64,
    ) -> (RowRecording, RowAlignment) {
        let rec = RowRecording {
            row: 3,
            attempt: 0,
            direction: 1,
            usable_x_m: (0.0, 0.1),
            frames: Vec::new(),
            complete: vec![true; 100],
            arrivals: Vec::new(),
            rtde: Vec::new(),
            report: Default::default(),
            outcome,
            rtde_gaps: 0,
        };
        let aligned = RowAlignment {
            frames: Vec::new(),
            dropped: Default::default(),
            radar_fit: fit(radar_s),
            controller_fit: fit(controller_s),
        };
        (rec, aligned)
    }

    #[test]
    fn a_row_is_judged_by_its_outcome_its_losses_and_its_clock_fits() {
        let lab = LabConfig::default();
        let problem = |(rec, aligned): (RowRecording, RowAlignment)| {
            row_problem(&lab, &rec, &aligned).unwrap_or_default()
        };
        assert_eq!(problem(attempt(RowOutcome::Completed, 1e-4, 1e-3)), "");
        let short = RowOutcome::StoppedShort {
            short_of_target_m: 0.0474,
        };
        assert!(problem(attempt(short, 1e-4, 1e-3)).starts_with("the arm stopped 47.4 mm short"));
        assert_eq!(
            problem(attempt(RowOutcome::Completed, 1e-4, 0.0116)),
            "the controller clock fit strays 11.6 ms from its line, above \
             recording.max_clock_residual_s = 2.0 ms (the host stamped arrivals late)"
        );
        assert!(
            problem(attempt(RowOutcome::Completed, 0.003, 1e-3)).starts_with("the radar clock")
        );
        assert!(
            problem(attempt(RowOutcome::Completed, f64::NAN, 1e-3)).starts_with("the radar clock")
        );
        let (mut lossy, aligned) = attempt(RowOutcome::Completed, 1e-4, 1e-3);
        lossy.complete[10] = false;
        lossy.complete[20] = false;
        assert_eq!(
            row_problem(&lab, &lossy, &aligned).unwrap_or_default(),
            "frame loss 2.02 % above recording.max_frame_loss = 1.00 %"
        );
    }
}
