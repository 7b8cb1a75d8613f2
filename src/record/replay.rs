//! Reading a scan back from its recording: the metadata and, per row attempt, the raw frames,
//! packet arrivals, RTDE poses and the row's plan, exactly as the live run saw them. Alignment
//! and capture assembly then run the same code as live ([`crate::lab::scan`]), so the same
//! config gives bit-identical antennas and samples.

use std::collections::BTreeMap;
use std::path::Path;

use base64::Engine as _;
use serde::Deserialize;

use super::messages;
use super::recover::{Item, ReadError, ReadStop, for_each_record};
use crate::dca1000::packet::PacketArrival;
use crate::ur::robot::RowOutcome;
use crate::ur::rtde::{Sample, Value};

/// One row attempt as recorded.
#[derive(Debug, Clone, Default)]
pub struct RecordedRow {
    pub row: usize,
    pub attempt: u32,
    pub direction: i8,
    pub usable_x_m: (f64, f64),
    pub rtde_gaps: usize,
    /// How the arm's move ended.
    pub outcome: RowOutcome,
    pub frames: Vec<Vec<u8>>,
    pub complete: Vec<bool>,
    pub arrivals: Vec<PacketArrival>,
    /// RTDE samples reduced to `actual_TCP_pose` (the one value alignment reads).
    pub rtde: Vec<Sample>,
    /// Whether `/scan/rows` closed this attempt (an attempt cut by a crash has no result).
    pub finished: bool,
}

/// A recording read back.
#[derive(Debug, Clone, Default)]
pub struct RecordedScan {
    pub metadata: BTreeMap<String, BTreeMap<String, String>>,
    /// Attempts in the order they started.
    pub rows: Vec<RecordedRow>,
    pub read: ReadStop,
}

#[derive(Deserialize)]
struct AdcMessage {
    row: usize,
    attempt: u32,
    frame: u64,
    complete: bool,
    data: String,
}

#[derive(Deserialize)]
struct PacketMessage {
    row: usize,
    attempt: u32,
    byte_offset: u64,
    payload_len: u32,
    host_s: f64,
}

#[derive(Deserialize)]
struct RtdeMessage {
    row: usize,
    attempt: u32,
    host_s: f64,
    controller_s: Option<f64>,
    segment: u64,
    fields: BTreeMap<String, serde_json::Value>,
}

#[derive(Deserialize)]
struct RowMessage {
    row: usize,
    attempt: u32,
    direction: i8,
    usable_x_m: (f64, f64),
    rtde_gaps: usize,
    /// Absent from recordings made before a row could end short; they kept only completed rows.
    #[serde(default)]
    outcome: RowOutcome,
}

/// The attempt `(row, attempt)`, created in start order when first seen.
fn row_of<'a>(
    rows: &'a mut Vec<RecordedRow>,
    index: &mut BTreeMap<(usize, u32), usize>,
    row: usize,
    attempt: u32,
) -> &'a mut RecordedRow {
    let at = *index.entry((row, attempt)).or_insert_with(|| {
        rows.push(RecordedRow {
            row,
            attempt,
            ..RecordedRow::default()
        });
        rows.len() - 1
    });
    &mut rows[at]
}

/// Reads `path` (finished or recovered; a damaged tail ends the read and is reported).
pub fn read_scan(path: &Path) -> Result<RecordedScan, ReadError> {
    let mut scan = RecordedScan::default();
    let mut topics: BTreeMap<u16, String> = BTreeMap::new();
    let mut index: BTreeMap<(usize, u32), usize> = BTreeMap::new();
    let read = for_each_record(path, |item| {
        match item {
            Item::Channel(c) => {
                topics.insert(c.id, c.topic.clone());
            }
            Item::Metadata(m) => {
                scan.metadata.insert(m.name.clone(), m.metadata.clone());
            }
            Item::Message { header, data } => {
                let Some(topic) = topics.get(&header.channel_id) else {
                    return Ok(());
                };
                let bad = |e: serde_json::Error| format!("{topic}: {e}");
                match topic.as_str() {
                    t if t == messages::ADC.0 => {
                        let m: AdcMessage = serde_json::from_slice(data).map_err(bad)?;
                        let bytes = base64::engine::general_purpose::STANDARD
                            .decode(&m.data)
                            .map_err(|e| format!("{topic}: {e}"))?;
                        let r = row_of(&mut scan.rows, &mut index, m.row, m.attempt);
                        if m.frame != r.frames.len() as u64 {
                            return Err(format!(
                                "{topic}: row {} attempt {} frame {} follows {} frames",
                                m.row,
                                m.attempt,
                                m.frame,
                                r.frames.len()
                            ));
                        }
                        r.frames.push(bytes);
                        r.complete.push(m.complete);
                    }
                    t if t == messages::PACKETS.0 => {
                        let m: PacketMessage = serde_json::from_slice(data).map_err(bad)?;
                        row_of(&mut scan.rows, &mut index, m.row, m.attempt)
                            .arrivals
                            .push(PacketArrival {
                                byte_offset: m.byte_offset,
                                payload_len: m.payload_len,
                                host_s: m.host_s,
                            });
                    }
                    t if t == messages::RTDE.0 => {
                        let m: RtdeMessage = serde_json::from_slice(data).map_err(bad)?;
                        let pose = m
                            .fields
                            .get("actual_TCP_pose")
                            .and_then(|v| serde_json::from_value::<[f64; 6]>(v.clone()).ok());
                        row_of(&mut scan.rows, &mut index, m.row, m.attempt)
                            .rtde
                            .push(Sample {
                                host_s: m.host_s,
                                controller_s: m.controller_s,
                                segment: m.segment,
                                values: pose.map(Value::Vector6d).into_iter().collect(),
                            });
                    }
                    t if t == messages::ROWS.0 => {
                        let m: RowMessage = serde_json::from_slice(data).map_err(bad)?;
                        let r = row_of(&mut scan.rows, &mut index, m.row, m.attempt);
                        r.direction = m.direction;
                        r.usable_x_m = m.usable_x_m;
                        r.rtde_gaps = m.rtde_gaps;
                        r.outcome = m.outcome;
                        r.finished = true;
                    }
                    _ => {}
                }
            }
            Item::Schema { .. } => {}
        }
        Ok(())
    })?;
    scan.read = read;
    Ok(scan)
}

/// The output names replayed samples carry (see [`RecordedRow::rtde`]).
pub fn replayed_output_names() -> Vec<String> {
    vec!["actual_TCP_pose".into()]
}
