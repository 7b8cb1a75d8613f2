//! The MCAP recorder (docs/protocols.md §E): one file per scan, zstd chunks closed every
//! `chunk_seconds` of wall time (so a crash loses at most one chunk), Foxglove schemas where
//! Foxglove has them, schemas and channels repeated in the summary for indexed readers.
//!
//! Channels: `/radar/adc` (raw frames), `/radar/packets` (every packet's offset and arrival),
//! `/robot/rtde` (every RTDE package), `/scan/rows` (per-row statistics, clock fits and
//! alignment counts), `/tf` (`foxglove.FrameTransform`: base→tcp at up to 50 Hz, tcp→radar),
//! `/robot/tcp_pose` (`foxglove.PoseInFrame`, 50 Hz), `/scan/antennas` (`foxglove.PointCloud`
//! of each row's kept TX positions), `/log` (`foxglove.Log`) and, after reconstruction,
//! `/recon/points` (`foxglove.PointCloud` with normals). Metadata `mmnormd` holds the config,
//! the radar script, the extrinsics, the frame timing, the RTDE recipe and the scan's epoch;
//! `scan_result` is written at the end.
//!
//! A writer that failed stays failed: the first IO error is kept, every later call returns it,
//! and the scan that owns the recorder aborts. [`recover()`] salvages a file whose writer died.
//! It owns the file and nothing else.

pub mod faulty;
pub mod messages;
pub mod recover;
pub mod replay;

use std::collections::BTreeMap;
use std::fs::File;
use std::io::{BufWriter, Seek, Write};
use std::path::{Path, PathBuf};
use std::time::Instant;

use base64::Engine as _;
use mcap::records::{MessageHeader, Metadata};
use mcap::{Compression, WriteOptions, Writer};
use serde_json::json;

use crate::align::RowAlignment;
use crate::dca1000::Frame;
use crate::dca1000::packet::PacketArrival;
use crate::lab::scan::{RowRecording, RowSummary, ScanLog};
use crate::ur::rtde::Sample;
pub use recover::{RecoverReport, recover};

/// The wall clock in Unix nanoseconds (0 before 1970): MCAP log times and scan epochs.
pub fn unix_now_ns() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_nanos() as u64)
}

/// The wall clock in whole Unix seconds (0 before 1970): scan and reconstruction folder names.
pub fn unix_now_s() -> u64 {
    unix_now_ns() / 1_000_000_000
}

/// Why recording failed.
#[derive(Debug, Clone, thiserror::Error)]
pub enum RecordError {
    #[error("cannot create {path}: {message}")]
    Create { path: PathBuf, message: String },
    #[error("the recording failed earlier and accepts nothing more: {first}")]
    Failed { first: String },
    #[error("writing the recording: {0}")]
    Write(String),
}

/// How the recorder chunks.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RecorderOptions {
    pub chunk_seconds: f64,
    pub chunk_bytes: u64,
}

/// Channel ids.
struct Channels {
    adc: u16,
    packets: u16,
    rtde: u16,
    rows: u16,
    tf: u16,
    tcp_pose: u16,
    antennas: u16,
    log: u16,
    points: u16,
}

/// The recorder; see the module docs.
pub struct McapRecorder<W: Write + Seek> {
    writer: Option<Writer<W>>,
    failed: Option<String>,
    failed_at: Option<Instant>,
    channels: Channels,
    sequence: u32,
    epoch_unix_ns: u64,
    options: RecorderOptions,
    chunk_opened: Option<Instant>,
    rtde_names: Vec<String>,
    /// The radar's frame period (from the `mmnormd` metadata's frame timing), for each
    /// frame's nominal time.
    frame_period_s: Option<f64>,
    last_pose_ns: u64,
}

/// Poses go to `/tf` and `/robot/tcp_pose` at most this often, nanoseconds (50 Hz).
const POSE_INTERVAL_NS: u64 = 20_000_000;

fn json_channel<W: Write + Seek>(
    w: &mut Writer<W>,
    (topic, name, schema): (&str, &str, &str),
) -> mcap::McapResult<u16> {
    let schema_id = w.add_schema(name, "jsonschema", schema.as_bytes())?;
    w.add_channel(schema_id, topic, "json", &BTreeMap::new())
}

fn foxglove_channel<W: Write + Seek, T: foxglove::Encode>(
    w: &mut Writer<W>,
    topic: &str,
) -> mcap::McapResult<u16> {
    let schema_id = match messages::schema_of::<T>() {
        Some((name, encoding, data)) => w.add_schema(&name, &encoding, &data)?,
        None => 0,
    };
    w.add_channel(
        schema_id,
        topic,
        &T::get_message_encoding(),
        &BTreeMap::new(),
    )
}

/// A file the recorder can write.
pub trait WriteSeek: Write + Seek + Send {}
impl<T: Write + Seek + Send> WriteSeek for T {}

impl McapRecorder<Box<dyn WriteSeek>> {
    /// Creates `path` (refusing to replace a file) and writes the header and channels. With
    /// `fail_after_bytes`, the file fails as a full disk would once that much is written
    /// ([`faulty::FailingWriter`]).
    pub fn create(
        path: &Path,
        options: RecorderOptions,
        epoch_unix_ns: u64,
        fail_after_bytes: Option<u64>,
    ) -> Result<Self, RecordError> {
        let file = File::options()
            .write(true)
            .create_new(true)
            .open(path)
            .map_err(|e| RecordError::Create {
                path: path.to_path_buf(),
                message: e.to_string(),
            })?;
        let buffered = BufWriter::with_capacity(1 << 20, file);
        let w: Box<dyn WriteSeek> = match fail_after_bytes {
            Some(budget) => Box::new(faulty::FailingWriter::new(buffered, budget)),
            None => Box::new(buffered),
        };
        Self::new(w, options, epoch_unix_ns)
    }
}

impl<W: Write + Seek> McapRecorder<W> {
    /// A recorder writing to `w`.
    pub fn new(w: W, options: RecorderOptions, epoch_unix_ns: u64) -> Result<Self, RecordError> {
        let write_error = |e: mcap::McapError| RecordError::Write(e.to_string());
        let mut writer = WriteOptions::new()
            .compression(Some(Compression::Zstd))
            .chunk_size(Some(options.chunk_bytes))
            .profile("")
            .library(concat!("mmnormd ", env!("CARGO_PKG_VERSION")))
            .create(w)
            .map_err(write_error)?;
        let channels = (|| -> mcap::McapResult<Channels> {
            use foxglove::messages::{FrameTransform, Log, PointCloud, PoseInFrame};
            Ok(Channels {
                adc: json_channel(&mut writer, messages::ADC)?,
                packets: json_channel(&mut writer, messages::PACKETS)?,
                rtde: json_channel(&mut writer, messages::RTDE)?,
                rows: json_channel(&mut writer, messages::ROWS)?,
                tf: foxglove_channel::<_, FrameTransform>(&mut writer, messages::TF)?,
                tcp_pose: foxglove_channel::<_, PoseInFrame>(&mut writer, messages::TCP_POSE)?,
                antennas: foxglove_channel::<_, PointCloud>(&mut writer, messages::ANTENNAS)?,
                log: foxglove_channel::<_, Log>(&mut writer, messages::LOG)?,
                points: foxglove_channel::<_, PointCloud>(&mut writer, messages::POINTS)?,
            })
        })()
        .map_err(write_error)?;
        Ok(Self {
            writer: Some(writer),
            failed: None,
            failed_at: None,
            channels,
            sequence: 0,
            epoch_unix_ns,
            options,
            chunk_opened: None,
            rtde_names: Vec::new(),
            frame_period_s: None,
            last_pose_ns: 0,
        })
    }

    /// Unix nanoseconds of a host time (seconds from the scan's epoch).
    pub fn unix_ns(&self, host_s: f64) -> u64 {
        let offset_ns = (host_s * 1e9).round();
        if offset_ns >= 0.0 {
            self.epoch_unix_ns.saturating_add(offset_ns as u64)
        } else {
            self.epoch_unix_ns.saturating_sub((-offset_ns) as u64)
        }
    }

    /// The first failure, if any.
    pub fn failure(&self) -> Option<&str> {
        self.failed.as_deref()
    }

    /// When the first write failed.
    pub fn failed_at(&self) -> Option<Instant> {
        self.failed_at
    }

    /// Runs `f` on the writer unless the recorder has failed; a failure sticks.
    fn with_writer(
        &mut self,
        f: impl FnOnce(&mut Writer<W>) -> mcap::McapResult<()>,
    ) -> Result<(), RecordError> {
        if let Some(first) = &self.failed {
            return Err(RecordError::Failed {
                first: first.clone(),
            });
        }
        let Some(writer) = self.writer.as_mut() else {
            return Err(RecordError::Failed {
                first: "the recording is already finished".into(),
            });
        };
        f(writer).map_err(|e| {
            let mut message = e.to_string();
            let mut source = std::error::Error::source(&e);
            while let Some(s) = source {
                message = format!("{message}: {s}");
                source = s.source();
            }
            self.failed = Some(message.clone());
            self.failed_at = Some(Instant::now());
            RecordError::Write(message)
        })
    }

    fn write(&mut self, channel_id: u16, unix_ns: u64, data: &[u8]) -> Result<(), RecordError> {
        let header = MessageHeader {
            channel_id,
            sequence: self.sequence,
            log_time: unix_ns,
            publish_time: unix_ns,
        };
        self.with_writer(|w| w.write_to_known_channel(&header, data))?;
        self.sequence = self.sequence.wrapping_add(1);
        self.chunk_opened.get_or_insert_with(Instant::now);
        self.tick()
    }

    fn write_json(
        &mut self,
        channel_id: u16,
        unix_ns: u64,
        value: &serde_json::Value,
    ) -> Result<(), RecordError> {
        let data = serde_json::to_vec(value).map_err(|e| RecordError::Write(e.to_string()))?;
        self.write(channel_id, unix_ns, &data)
    }

    /// Closes the open chunk once it is `chunk_seconds` old, and flushes it to the file.
    pub fn tick(&mut self) -> Result<(), RecordError> {
        if let Some(opened) = self.chunk_opened
            && opened.elapsed().as_secs_f64() >= self.options.chunk_seconds
        {
            self.chunk_opened = None;
            self.with_writer(|w| w.flush())?;
        }
        Ok(())
    }

    /// Writes a metadata record (closing the open chunk first).
    pub fn metadata(
        &mut self,
        name: &str,
        entries: BTreeMap<String, String>,
    ) -> Result<(), RecordError> {
        if name == "mmnormd" {
            if let Some(names) = entries.get("rtde_outputs") {
                self.rtde_names = serde_json::from_str(names).unwrap_or_default();
            }
            self.frame_period_s = entries
                .get("frame_timing")
                .and_then(|t| serde_json::from_str::<serde_json::Value>(t).ok())
                .and_then(|t| t["frame_period_s"].as_f64());
        }
        let record = Metadata {
            name: name.into(),
            metadata: entries,
        };
        self.chunk_opened = None;
        self.with_writer(|w| w.write_metadata(&record))
    }

    /// A line on `/log` (level 1 DEBUG … 5 FATAL).
    pub fn log(&mut self, host_s: f64, level: i32, text: &str) -> Result<(), RecordError> {
        let ns = self.unix_ns(host_s);
        let data = messages::encode(&messages::log_line(ns, level, text));
        self.write(self.channels.log, ns, &data)
    }

    /// A static transform (`tcp → radar`) on `/tf`.
    pub fn static_transform(
        &mut self,
        host_s: f64,
        parent: &str,
        child: &str,
        pose: &[f64; 6],
    ) -> Result<(), RecordError> {
        let ns = self.unix_ns(host_s);
        let data = messages::encode(&messages::frame_transform(ns, parent, child, pose));
        self.write(self.channels.tf, ns, &data)
    }

    /// The reconstruction on `/recon/points`.
    pub fn points(
        &mut self,
        host_s: f64,
        points: &[[f64; 3]],
        normals: Option<&[[f64; 3]]>,
    ) -> Result<(), RecordError> {
        let ns = self.unix_ns(host_s);
        let cloud = messages::point_cloud(ns, messages::BASE_FRAME, points, normals);
        self.write(self.channels.points, ns, &messages::encode(&cloud))
    }

    /// Writes the summary and the footer. Call it: a file without it holds no index (but
    /// [`recover()`] still reads it).
    pub fn finish(&mut self) -> Result<mcap::Summary, RecordError> {
        let mut summary = None;
        self.with_writer(|w| {
            summary = Some(w.finish()?);
            Ok(())
        })?;
        self.writer = None;
        summary.ok_or_else(|| RecordError::Write("no summary".into()))
    }

    fn record_frame(&mut self, row: usize, attempt: u32, frame: &Frame) -> Result<(), RecordError> {
        // The frame's nominal time is not known until alignment; log it at arrival.
        let ns = unix_now_ns();
        let value = json!({
            "row": row,
            "attempt": attempt,
            "frame": frame.index,
            // Seconds after the first frame's start on the radar's clock; `/scan/rows` holds
            // the row's fit of that clock to host time.
            "nominal_radar_s": self.frame_period_s.map(|t| frame.index as f64 * t),
            "complete": frame.is_complete(),
            "data": base64::engine::general_purpose::STANDARD.encode(&frame.data),
        });
        self.write_json(self.channels.adc, ns, &value)
    }

    fn record_rtde(&mut self, row: usize, attempt: u32, s: &Sample) -> Result<(), RecordError> {
        let ns = self.unix_ns(s.host_s);
        let fields = messages::rtde_fields(&self.rtde_names, &s.values);
        let pose = fields
            .get("actual_TCP_pose")
            .and_then(|v| serde_json::from_value::<[f64; 6]>(v.clone()).ok());
        let value = json!({
            "row": row,
            "attempt": attempt,
            "host_s": s.host_s,
            "controller_s": s.controller_s,
            "segment": s.segment,
            "fields": fields,
        });
        self.write_json(self.channels.rtde, ns, &value)?;
        if let Some(p) = pose
            && ns >= self.last_pose_ns + POSE_INTERVAL_NS
        {
            self.last_pose_ns = ns;
            let tf = messages::frame_transform(ns, messages::BASE_FRAME, messages::TCP_FRAME, &p);
            self.write(self.channels.tf, ns, &messages::encode(&tf))?;
            let pose = messages::encode(&messages::pose_in_frame(ns, &p));
            self.write(self.channels.tcp_pose, ns, &pose)?;
        }
        Ok(())
    }

    fn record_row(
        &mut self,
        rec: &RowRecording,
        aligned: &RowAlignment,
    ) -> Result<(), RecordError> {
        let ns = unix_now_ns();
        let value = json!({
            "row": rec.row,
            "attempt": rec.attempt,
            "direction": rec.direction,
            "usable_x_m": [rec.usable_x_m.0, rec.usable_x_m.1],
            "frames": rec.complete.len(),
            "kept": aligned.frames.len(),
            "frame_loss": rec.frame_loss(),
            "rtde_gaps": rec.rtde_gaps,
            "outcome": rec.outcome,
            "packets": rec.report,
            "dropped": aligned.dropped,
            "radar_fit": aligned.radar_fit,
            "controller_fit": aligned.controller_fit,
        });
        self.write_json(self.channels.rows, ns, &value)?;
        let tx: Vec<[f64; 3]> = aligned.frames.iter().map(|f| f.tx_in_base_m).collect();
        let cloud = messages::point_cloud(ns, messages::BASE_FRAME, &tx, None);
        self.write(self.channels.antennas, ns, &messages::encode(&cloud))
    }
}

impl<W: Write + Seek> ScanLog for McapRecorder<W> {
    fn frame(&mut self, row: usize, attempt: u32, frame: &Frame) -> Result<(), String> {
        self.record_frame(row, attempt, frame)
            .map_err(|e| e.to_string())
    }

    fn packet(&mut self, row: usize, attempt: u32, a: &PacketArrival) -> Result<(), String> {
        let ns = self.unix_ns(a.host_s);
        let value = json!({
            "row": row,
            "attempt": attempt,
            "byte_offset": a.byte_offset,
            "payload_len": a.payload_len,
            "host_s": a.host_s,
        });
        self.write_json(self.channels.packets, ns, &value)
            .map_err(|e| e.to_string())
    }

    fn rtde(&mut self, row: usize, attempt: u32, sample: &Sample) -> Result<(), String> {
        self.record_rtde(row, attempt, sample)
            .map_err(|e| e.to_string())
    }

    fn row(&mut self, rec: &RowRecording, aligned: &RowAlignment) -> Result<(), String> {
        self.record_row(rec, aligned).map_err(|e| e.to_string())
    }

    fn progress(&mut self, summary: &RowSummary) {
        let level = if summary.problem.is_some() { 3 } else { 2 };
        let text = match &summary.problem {
            Some(p) => format!(
                "row {}/{} attempt {}: {p}",
                summary.row + 1,
                summary.rows,
                summary.attempt
            ),
            None => format!(
                "row {}/{}: {} frames, {} kept",
                summary.row + 1,
                summary.rows,
                summary.frames,
                summary.kept
            ),
        };
        let ns = unix_now_ns();
        let data = messages::encode(&messages::log_line(ns, level, &text));
        // A failed writer is reported by the next data call, which aborts the scan.
        self.write(self.channels.log, ns, &data).ok();
    }

    fn tick(&mut self) -> Result<(), String> {
        McapRecorder::tick(self).map_err(|e| e.to_string())
    }
}
