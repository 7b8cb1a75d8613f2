//! The recording's message types: mmnormd's own channels as JSON with a JSON Schema each, and
//! Foxglove's well-known types (protobuf, from the `foxglove` crate) where Foxglove has one.

use std::collections::BTreeMap;

use foxglove::messages::{
    FrameTransform, PackedElementField, Pose, PoseInFrame, Quaternion, Timestamp, Vector3,
    packed_element_field::NumericType,
};
use nalgebra::UnitQuaternion;

use crate::align::pose::isometry_of_pose;
use crate::ur::rtde::Value;

/// Topic, schema name and JSON Schema of each mmnormd channel.
pub const ADC: (&str, &str, &str) = (
    "/radar/adc",
    "mmnormd.RadarFrame",
    r#"{"type":"object","title":"mmnormd.RadarFrame","description":"One raw radar frame as the DCA1000 delivered it: 16-bit I/Q words in TI's 4-lane layout, zero-filled where packets were lost (complete = false).","properties":{"row":{"type":"integer"},"attempt":{"type":"integer"},"frame":{"type":"integer","description":"index from sensorStart"},"nominal_radar_s":{"type":["number","null"],"description":"frame index × frame period: the frame's start on the radar clock"},"complete":{"type":"boolean"},"data":{"type":"string","contentEncoding":"base64"}},"required":["row","attempt","frame","complete","data"]}"#,
);
pub const PACKETS: (&str, &str, &str) = (
    "/radar/packets",
    "mmnormd.PacketArrival",
    r#"{"type":"object","title":"mmnormd.PacketArrival","description":"One DCA1000 data packet: its byte offset in the stream and its host arrival time (seconds from the scan's epoch).","properties":{"row":{"type":"integer"},"attempt":{"type":"integer"},"byte_offset":{"type":"integer"},"payload_len":{"type":"integer"},"host_s":{"type":"number"}},"required":["row","attempt","byte_offset","payload_len","host_s"]}"#,
);
pub const RTDE: (&str, &str, &str) = (
    "/robot/rtde",
    "mmnormd.RtdeSample",
    r#"{"type":"object","title":"mmnormd.RtdeSample","description":"One RTDE output package: host receive time (seconds from the scan's epoch), controller timestamp, stream segment and every recipe field by name.","properties":{"row":{"type":"integer"},"attempt":{"type":"integer"},"host_s":{"type":"number"},"controller_s":{"type":["number","null"]},"segment":{"type":"integer"},"fields":{"type":"object"}},"required":["row","attempt","host_s","segment","fields"]}"#,
);
pub const ROWS: (&str, &str, &str) = (
    "/scan/rows",
    "mmnormd.RowResult",
    r#"{"type":"object","title":"mmnormd.RowResult","description":"One row attempt: its plan, packet statistics, clock fits, alignment counts and verdict.","properties":{"row":{"type":"integer"},"attempt":{"type":"integer"},"direction":{"type":"integer"},"usable_x_m":{"type":"array"},"frames":{"type":"integer"},"kept":{"type":"integer"},"frame_loss":{"type":"number"},"rtde_gaps":{"type":"integer"},"outcome":{"type":["string","object"],"description":"How the arm's move ended: \"Completed\", or {\"StoppedShort\":{\"short_of_target_m\":…}} for a row scanned again"},"packets":{"type":"object"},"dropped":{"type":"object"},"radar_fit":{"type":"object"},"controller_fit":{"type":"object"}},"required":["row","attempt"]}"#,
);

/// Foxglove topics.
pub const TF: &str = "/tf";
pub const TCP_POSE: &str = "/robot/tcp_pose";
pub const LOG: &str = "/log";
pub const ANTENNAS: &str = "/scan/antennas";
pub const POINTS: &str = "/recon/points";
/// The frame names on `/tf`.
pub const BASE_FRAME: &str = "base";
pub const TCP_FRAME: &str = "tcp";
pub const RADAR_FRAME: &str = "radar";

/// Foxglove's timestamp of Unix nanoseconds.
pub fn timestamp(unix_ns: u64) -> Timestamp {
    Timestamp::new(
        (unix_ns / 1_000_000_000).min(u64::from(u32::MAX)) as u32,
        (unix_ns % 1_000_000_000) as u32,
    )
}

fn rotation(pose: &[f64; 6]) -> Quaternion {
    let q: UnitQuaternion<f64> = isometry_of_pose(pose).rotation;
    Quaternion {
        x: q.i,
        y: q.j,
        z: q.k,
        w: q.w,
    }
}

/// `parent_from_child` as a `foxglove.FrameTransform`.
pub fn frame_transform(unix_ns: u64, parent: &str, child: &str, pose: &[f64; 6]) -> FrameTransform {
    FrameTransform {
        timestamp: Some(timestamp(unix_ns)),
        parent_frame_id: parent.into(),
        child_frame_id: child.into(),
        translation: Some(Vector3 {
            x: pose[0],
            y: pose[1],
            z: pose[2],
        }),
        rotation: Some(rotation(pose)),
    }
}

/// The TCP pose in base as a `foxglove.PoseInFrame`.
pub fn pose_in_frame(unix_ns: u64, pose: &[f64; 6]) -> PoseInFrame {
    PoseInFrame {
        timestamp: Some(timestamp(unix_ns)),
        frame_id: BASE_FRAME.into(),
        pose: Some(Pose {
            position: Some(Vector3 {
                x: pose[0],
                y: pose[1],
                z: pose[2],
            }),
            orientation: Some(rotation(pose)),
        }),
    }
}

/// A `foxglove.PointCloud` of float32 x, y, z (and nx, ny, nz when normals are given) in
/// `frame_id`.
pub fn point_cloud(
    unix_ns: u64,
    frame_id: &str,
    points: &[[f64; 3]],
    normals: Option<&[[f64; 3]]>,
) -> foxglove::messages::PointCloud {
    let names: &[&str] = if normals.is_some() {
        &["x", "y", "z", "nx", "ny", "nz"]
    } else {
        &["x", "y", "z"]
    };
    let fields = names
        .iter()
        .enumerate()
        .map(|(i, name)| PackedElementField {
            name: (*name).into(),
            offset: 4 * i as u32,
            r#type: NumericType::Float32 as i32,
        })
        .collect();
    let mut data = Vec::with_capacity(points.len() * names.len() * 4);
    for (i, p) in points.iter().enumerate() {
        let n = normals.and_then(|n| n.get(i));
        for v in p.iter().chain(n.into_iter().flatten()) {
            data.extend_from_slice(&(*v as f32).to_le_bytes());
        }
    }
    foxglove::messages::PointCloud {
        timestamp: Some(timestamp(unix_ns)),
        frame_id: frame_id.into(),
        pose: Some(Pose {
            position: Some(Vector3::default()),
            orientation: Some(Quaternion {
                w: 1.0,
                ..Quaternion::default()
            }),
        }),
        point_stride: 4 * names.len() as u32,
        fields,
        data: data.into(),
    }
}

/// A `foxglove.Log` line (level 1 DEBUG … 5 FATAL).
pub fn log_line(unix_ns: u64, level: i32, message: &str) -> foxglove::messages::Log {
    foxglove::messages::Log {
        timestamp: Some(timestamp(unix_ns)),
        level,
        message: message.into(),
        name: "mmnormd".into(),
        file: String::new(),
        line: 0,
    }
}

/// Encodes a Foxglove message as protobuf bytes.
pub fn encode<T: foxglove::Encode>(message: &T) -> Vec<u8> {
    let mut buf = Vec::with_capacity(message.encoded_len().unwrap_or(256));
    // Encoding into a growable Vec cannot run out of room.
    message.encode(&mut buf).ok();
    buf
}

/// Schema name, encoding and data of a Foxglove type.
pub fn schema_of<T: foxglove::Encode>() -> Option<(String, String, Vec<u8>)> {
    T::get_schema().map(|s| (s.name, s.encoding, s.data.into_owned()))
}

/// RTDE values as JSON, by field name.
pub fn rtde_fields(names: &[String], values: &[Value]) -> BTreeMap<String, serde_json::Value> {
    names
        .iter()
        .zip(values)
        .map(|(name, v)| {
            let json = match v {
                Value::Bool(b) => serde_json::json!(b),
                Value::Uint8(x) => serde_json::json!(x),
                Value::Uint32(x) => serde_json::json!(x),
                Value::Uint64(x) => serde_json::json!(x),
                Value::Int32(x) => serde_json::json!(x),
                Value::Double(x) => serde_json::json!(x),
                Value::Vector3d(x) => serde_json::json!(x),
                Value::Vector6d(x) => serde_json::json!(x),
                Value::Vector6Int32(x) => serde_json::json!(x),
                Value::Vector6Uint32(x) => serde_json::json!(x),
            };
            (name.clone(), json)
        })
        .collect()
}
