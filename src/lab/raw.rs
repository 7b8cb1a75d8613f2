//! A radar-only capture (docs/protocols.md B4), for bench checks of the radar chain and for
//! interop with TI's tools: `mmnormd capture raw`.
//!
//! Sequence: DCA `SYSTEM_CONNECT`, `READ_FPGA_VERSION`, `CONFIG_FPGA_GEN`, `CONFIG_PACKET_DATA`;
//! radar `sensorStop`, `flushCfg` and the profile (unless the radar is left alone); DCA
//! `RECORD_START`; radar `sensorStart`; N frames; DCA `RECORD_STOP`; radar `sensorStop`.
//!
//! Output directory:
//! - `adc_data.bin`: the reassembled byte stream, N × F bytes in stream order (TI's layout), with
//!   lost bytes zero-filled and every affected frame listed in the report. It is written as
//!   `adc_data.bin.partial` and renamed only when the capture completed; a failed capture
//!   leaves the partial file with what had arrived.
//! - `report.json`: the counters (packets, bytes, lost, duplicates, reordered, late, flagged
//!   frames, kernel drops), the async events, the radar's command record, and the error if any.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::Duration;

use super::config::LabConfig;
use crate::capture::dir::write_atomically;
use crate::dca1000::board::{
    BoardError, CaptureBoard, CaptureReport, RecordPlan, RecordSink, record_frames,
};
use crate::dca1000::command::FpgaVersion;
use crate::dca1000::samples::FrameLayout;
use crate::progress::Progress;
use crate::radar::cli::{CliError, CommandOutcome};
use crate::radar::{RadarControl, RadarProfile};

/// Why a raw capture failed.
#[derive(Debug, thiserror::Error)]
pub enum RawError {
    #[error(transparent)]
    Board(#[from] BoardError),
    #[error("radar: {0}")]
    Radar(#[from] CliError),
    #[error("{0}")]
    Setup(String),
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
}

/// What `report.json` holds.
#[derive(Debug, Clone, serde::Serialize)]
pub struct RawReport {
    pub frames_requested: u64,
    pub frame_bytes: usize,
    pub fpga_version: Option<FpgaVersion>,
    /// The radar's command record; empty with `--no-radar`.
    pub radar_commands: Vec<CommandOutcome>,
    #[serde(flatten)]
    pub capture: CaptureReport,
    pub error: Option<String>,
}

/// One raw capture's request.
pub struct RawCapture<'a> {
    pub lab: &'a LabConfig,
    pub profile: &'a RadarProfile,
    pub frames: u64,
    pub out_dir: &'a Path,
    pub quiet: bool,
}

/// Runs the capture and writes `adc_data.bin` and `report.json`. The report is written on
/// failure too, with the error.
pub fn capture_raw(
    board: &mut dyn CaptureBoard,
    radar: Option<&mut dyn RadarControl>,
    job: &RawCapture<'_>,
) -> Result<RawReport, RawError> {
    let layout = job
        .lab
        .dca1000
        .layout(job.profile)
        .map_err(|e| RawError::Setup(e.to_string()))?;
    std::fs::create_dir_all(job.out_dir).map_err(|source| RawError::Io {
        path: job.out_dir.to_path_buf(),
        source,
    })?;
    let mut report = RawReport {
        frames_requested: job.frames,
        frame_bytes: layout.frame_bytes(),
        fpga_version: None,
        radar_commands: Vec::new(),
        capture: CaptureReport::default(),
        error: None,
    };
    let result = run(board, radar, job, &layout, &mut report);
    if let Err(e) = &result {
        report.error = Some(e.to_string());
    }
    let json = serde_json::to_vec_pretty(&report).unwrap_or_default();
    let report_path = job.out_dir.join("report.json");
    write_atomically(&report_path, &json).map_err(|e| RawError::Io {
        path: report_path,
        source: std::io::Error::other(e.to_string()),
    })?;
    result.map(|()| report)
}

/// Frames to `adc_data.bin.partial`, in order.
struct FileSink<'a, 'r, W: Write> {
    radar: Option<&'a mut (dyn RadarControl + 'r)>,
    writer: &'a mut W,
    progress: &'a Progress,
}

impl<W: Write> RecordSink for FileSink<'_, '_, W> {
    fn start_sensor(&mut self) -> Result<(), String> {
        match self.radar.as_deref_mut() {
            Some(r) => r.start().map_err(|e| e.to_string()),
            None => Ok(()),
        }
    }

    fn frame(&mut self, frame: &crate::dca1000::Frame) -> std::io::Result<()> {
        self.progress.inc(1);
        self.writer.write_all(&frame.data)
    }
}

fn run(
    board: &mut dyn CaptureBoard,
    mut radar: Option<&mut dyn RadarControl>,
    job: &RawCapture<'_>,
    layout: &FrameLayout,
    report: &mut RawReport,
) -> Result<(), RawError> {
    let d = &job.lab.dca1000;
    report.fpga_version = Some(board.connect()?);
    let packets = d.packet_config().map_err(RawError::Setup)?;
    board.configure(d.fpga, packets)?;
    if let Some(r) = radar.as_deref_mut() {
        report.radar_commands = r.configure(job.profile)?;
    }
    let partial = job.out_dir.join("adc_data.bin.partial");
    let io = |path: &Path| {
        let path = path.to_path_buf();
        move |source| RawError::Io { path, source }
    };
    let file = std::fs::File::create(&partial).map_err(io(&partial))?;
    let mut writer = std::io::BufWriter::with_capacity(1 << 20, file);
    let plan = RecordPlan {
        frames: job.frames,
        frame_bytes: layout.frame_bytes(),
        frame_period_s: job.profile.frame_period_s(),
        first_frame_margin: if radar.is_some() {
            Duration::from_millis(d.first_frame_margin_ms)
        } else {
            Duration::from_secs(u64::from(d.fpga.timer_s))
        },
        stop_delay: Duration::from_secs_f64(d.stop_delay_s),
        epoch: std::time::Instant::now(),
    };
    let progress = Progress::new("capture", job.frames, job.quiet);
    let mut sink = FileSink {
        radar: radar.as_deref_mut(),
        writer: &mut writer,
        progress: &progress,
    };
    let recorded = record_frames(board, &plan, &mut sink);
    let flushed = writer.flush().and_then(|()| writer.get_ref().sync_all());
    progress.finish();
    report.capture = recorded?;
    flushed.map_err(io(&partial))?;
    if let Some(r) = radar
        && let Err(e) = r.stop()
    {
        tracing::warn!("sensorStop after the capture failed: {e}");
    }
    let done = job.out_dir.join("adc_data.bin");
    std::fs::rename(&partial, &done).map_err(io(&done))?;
    Ok(())
}
