//! Time alignment (docs/protocols.md D3): a recorded row's radar frames, packet arrival
//! times and RTDE samples in; the kept frames, each with its host time and the TX and RX
//! positions in the robot base frame, out.
//!
//! Pure functions of recorded data and the `[align]` config, so a replay reproduces a live run
//! bit for bit. Nothing here touches a device or a clock. Three clocks meet:
//! - **radar → host.** Frame k's chirp is sampled `k·T + centre` after the first frame starts
//!   (radar clock). A raw-mode packet leaves once the frame holding its last byte has been
//!   acquired (`k·T + acquired`). The lower envelope of `arrival − due` over the row, fitted by
//!   [`ClockMapper`], maps radar time to host time; `pipeline_latency_s` (the floor that no
//!   stream can observe) is subtracted and the calibrated `sync_offset_s` added.
//! - **controller → host.** The same lower-envelope fit over the RTDE `timestamp`s.
//! - **pose at a frame.** Linear in position and slerp in rotation between the two RTDE
//!   samples around the frame's host time ([`pose`]), then `base_from_tcp · tcp_from_radar`
//!   places the TX and every RX.
//!
//! A frame is dropped when it was flagged (zero-filled by the reassembler), when no RTDE sample
//! pair of one segment within `max_pose_gap_s` brackets it, when the TCP lies outside the row's
//! constant-velocity stretch, or when its TX lies closer than `min_spacing_wavelengths`·λ0
//! (3/16, docs/mmnorm-reference.md §1) to the row's last kept TX.

pub mod pose;

use nalgebra::Isometry3;

pub use crate::dca1000::packet::PacketArrival;
use crate::ur::clock::{ClockConfig, ClockFit, ClockMapper};

/// The `[align]` section of `lab.toml`.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct AlignConfig {
    /// The radar board's pose on the tool flange (UR convention: metres, rotation vector).
    pub tcp_from_radar: [f64; 6],
    /// TX1's phase centre in the radar frame, metres.
    pub tx_in_radar_m: [f64; 3],
    /// Each enabled RX's phase centre in the radar frame, metres, in channel order.
    pub rx_in_radar_m: Vec<[f64; 3]>,
    /// Latency from a frame's acquisition to its packets' arrival that the stream cannot show
    /// (LVDS, FPGA, network), seconds.
    pub pipeline_latency_s: f64,
    /// Residual offset from the forward/backward calibration (D3 step 3), added to every
    /// frame's host time, seconds.
    pub sync_offset_s: f64,
    /// Frames closer than this many wavelengths to the row's last kept TX are dropped.
    pub min_spacing_wavelengths: f64,
    /// Longest RTDE interval a frame may be interpolated across, seconds.
    pub max_pose_gap_s: f64,
    /// Bin of the lower-envelope fits, seconds.
    pub fit_bin_s: f64,
    /// The radar's internal round-trip range offset written into the capture, metres (TI: 0.15).
    pub range_offset_m: f64,
}

impl Default for AlignConfig {
    fn default() -> Self {
        Self {
            tcp_from_radar: [0.0; 6],
            tx_in_radar_m: [0.0; 3],
            // IWR1443BOOST, RX along the radar's y axis: −(5 mm + (3 − k)·λ0/2) at 77.2 GHz.
            rx_in_radar_m: (0..4)
                .map(|k| [0.0, -(0.005 + f64::from(3 - k) * 0.003_883_3 / 2.0), 0.0])
                .collect(),
            pipeline_latency_s: 0.0,
            sync_offset_s: 0.0,
            min_spacing_wavelengths: 3.0 / 16.0,
            max_pose_gap_s: 0.010,
            fit_bin_s: 0.2,
            range_offset_m: 0.15,
        }
    }
}

impl AlignConfig {
    /// Checks every field; the error names the field and its value.
    pub fn validate(&self) -> Result<(), String> {
        let finite = |name: &str, values: &[f64]| -> Result<(), String> {
            match values.iter().find(|v| !v.is_finite()) {
                Some(v) => Err(format!(
                    "align.{name} holds {v}, which is not a finite number"
                )),
                None => Ok(()),
            }
        };
        finite("tcp_from_radar", &self.tcp_from_radar)?;
        finite("tx_in_radar_m", &self.tx_in_radar_m)?;
        for rx in &self.rx_in_radar_m {
            finite("rx_in_radar_m", rx)?;
        }
        if self.rx_in_radar_m.is_empty() {
            return Err("align.rx_in_radar_m is empty; list one position per enabled RX".into());
        }
        finite("pipeline_latency_s", &[self.pipeline_latency_s])?;
        finite("sync_offset_s", &[self.sync_offset_s])?;
        finite("range_offset_m", &[self.range_offset_m])?;
        if !(self.pipeline_latency_s >= 0.0 && self.pipeline_latency_s < 1.0) {
            return Err(format!(
                "align.pipeline_latency_s = {} must lie in [0, 1)",
                self.pipeline_latency_s
            ));
        }
        if !(self.min_spacing_wavelengths.is_finite() && self.min_spacing_wavelengths >= 0.0) {
            return Err(format!(
                "align.min_spacing_wavelengths = {} must be a non-negative number",
                self.min_spacing_wavelengths
            ));
        }
        if !(self.max_pose_gap_s.is_finite() && self.max_pose_gap_s > 0.0) {
            return Err(format!(
                "align.max_pose_gap_s = {} must be positive",
                self.max_pose_gap_s
            ));
        }
        if !(self.fit_bin_s.is_finite() && self.fit_bin_s > 0.0) {
            return Err(format!(
                "align.fit_bin_s = {} must be positive",
                self.fit_bin_s
            ));
        }
        Ok(())
    }
}

/// The radar's frame timing (from the profile).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct FrameTiming {
    pub frame_period_s: f64,
    pub frame_bytes: usize,
    /// From a frame's start to the middle of its sampled chirps, seconds.
    pub centre_s: f64,
    /// From a frame's start to the end of its last chirp, when its data leaves, seconds.
    pub acquired_s: f64,
    /// λ0 of the first ADC sample, metres.
    pub wavelength_m: f64,
}

/// One RTDE sample, reduced to what alignment needs.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct PoseSample {
    pub host_s: f64,
    pub controller_s: f64,
    pub segment: u64,
    /// `actual_TCP_pose`: `base_from_tcp` in the UR convention.
    pub tcp_pose: [f64; 6],
}

/// What one recorded row holds.
#[derive(Debug, Clone, Copy)]
pub struct RowInput<'a> {
    /// Whether each frame, in order from 0, arrived whole.
    pub frame_complete: &'a [bool],
    pub packets: &'a [PacketArrival],
    pub poses: &'a [PoseSample],
    /// The row's constant-velocity stretch of TCP x in base, metres.
    pub usable_x_m: (f64, f64),
}

/// A kept frame.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct AlignedFrame {
    pub frame: u64,
    pub host_s: f64,
    pub tx_in_base_m: [f64; 3],
    pub rx_in_base_m: Vec<[f64; 3]>,
}

/// How many frames each rule dropped.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize)]
pub struct DropCounts {
    pub flagged: u64,
    pub no_pose: u64,
    pub outside_usable: u64,
    pub too_close: u64,
}

/// The result for one row.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct RowAlignment {
    pub frames: Vec<AlignedFrame>,
    pub dropped: DropCounts,
    /// Radar time (s after the first frame's start) → host time.
    pub radar_fit: ClockFit,
    /// Controller time → host time.
    pub controller_fit: ClockFit,
}

/// Why a row could not be aligned.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum AlignError {
    #[error(
        "the row's {packets} full data packets span too little time to fit the radar clock (need two {bin_s} s bins)"
    )]
    RadarFit { packets: usize, bin_s: f64 },
    #[error(
        "the row's {samples} RTDE samples span too little time to fit the controller clock (need two {bin_s} s bins)"
    )]
    ControllerFit { samples: usize, bin_s: f64 },
}

/// Payload of a full raw-mode packet; a shorter one was flushed late and carries no timing.
const FULL_PAYLOAD: u32 = crate::dca1000::packet::RAW_PAYLOAD_LEN as u32;

fn mapper(bin_s: f64) -> ClockMapper {
    ClockMapper::new(ClockConfig {
        bin_s,
        window_bins: usize::MAX / 2,
        min_bins: 2,
    })
}

/// The radar → host fit from the full packets' arrivals.
pub fn fit_radar_clock(
    timing: &FrameTiming,
    packets: &[PacketArrival],
    bin_s: f64,
) -> Result<ClockFit, AlignError> {
    let mut fit = mapper(bin_s);
    let frame_bytes = timing.frame_bytes.max(1) as u64;
    let mut full = 0;
    for p in packets.iter().filter(|p| p.payload_len == FULL_PAYLOAD) {
        let last_byte = p.byte_offset + u64::from(p.payload_len) - 1;
        let frame = last_byte / frame_bytes;
        fit.push(
            frame as f64 * timing.frame_period_s + timing.acquired_s,
            p.host_s,
        );
        full += 1;
    }
    // Close the last bin: `push` fits on closed bins only.
    if let Some(last) = packets.iter().map(|p| p.host_s).reduce(f64::max) {
        fit.push(f64::MAX / 4.0, last);
    }
    fit.fit().ok_or(AlignError::RadarFit {
        packets: full,
        bin_s,
    })
}

/// The controller → host fit over the row's RTDE samples.
pub fn fit_controller_clock(poses: &[PoseSample], bin_s: f64) -> Result<ClockFit, AlignError> {
    let mut fit = mapper(bin_s);
    for s in poses {
        fit.push(s.controller_s, s.host_s);
    }
    if let Some(last) = poses.last() {
        fit.push(f64::MAX / 4.0, last.host_s);
    }
    fit.fit().ok_or(AlignError::ControllerFit {
        samples: poses.len(),
        bin_s,
    })
}

/// Aligns one row (see the module docs).
pub fn align_row(
    config: &AlignConfig,
    timing: &FrameTiming,
    row: &RowInput<'_>,
) -> Result<RowAlignment, AlignError> {
    let radar_fit = fit_radar_clock(timing, row.packets, config.fit_bin_s)?;
    let controller_fit = fit_controller_clock(row.poses, config.fit_bin_s)?;
    // Sample times on the host clock, in controller order (RTDE samples arrive in order).
    let mapped: Vec<(f64, u64, Isometry3<f64>)> = row
        .poses
        .iter()
        .map(|s| {
            (
                controller_fit.host_time(s.controller_s),
                s.segment,
                pose::isometry_of_pose(&s.tcp_pose),
            )
        })
        .collect();
    let tcp_from_radar = pose::isometry_of_pose(&config.tcp_from_radar);
    let (x_lo, x_hi) = (
        row.usable_x_m.0.min(row.usable_x_m.1),
        row.usable_x_m.0.max(row.usable_x_m.1),
    );
    let min_spacing_m = config.min_spacing_wavelengths * timing.wavelength_m;
    let mut out = RowAlignment {
        frames: Vec::new(),
        dropped: DropCounts::default(),
        radar_fit,
        controller_fit,
    };
    let mut last_kept: Option<[f64; 3]> = None;
    for (k, &complete) in row.frame_complete.iter().enumerate() {
        if !complete {
            out.dropped.flagged += 1;
            continue;
        }
        let radar_s = k as f64 * timing.frame_period_s + timing.centre_s;
        let host_s =
            radar_fit.host_time(radar_s) - config.pipeline_latency_s + config.sync_offset_s;
        let Some(base_from_tcp) = pose_at(&mapped, host_s, config.max_pose_gap_s) else {
            out.dropped.no_pose += 1;
            continue;
        };
        let tcp_x = base_from_tcp.translation.vector.x;
        if !(x_lo..=x_hi).contains(&tcp_x) {
            out.dropped.outside_usable += 1;
            continue;
        }
        let base_from_radar = base_from_tcp * tcp_from_radar;
        let tx = pose::apply(&base_from_radar, &config.tx_in_radar_m);
        if let Some(prev) = last_kept
            && distance_m(&prev, &tx) < min_spacing_m
        {
            out.dropped.too_close += 1;
            continue;
        }
        last_kept = Some(tx);
        out.frames.push(AlignedFrame {
            frame: k as u64,
            host_s,
            tx_in_base_m: tx,
            rx_in_base_m: config
                .rx_in_radar_m
                .iter()
                .map(|rx| pose::apply(&base_from_radar, rx))
                .collect(),
        });
    }
    Ok(out)
}

fn distance_m(a: &[f64; 3], b: &[f64; 3]) -> f64 {
    (0..3).map(|i| (a[i] - b[i]).powi(2)).sum::<f64>().sqrt()
}

/// The TCP pose at `host_s`, between the two samples around it when they belong to one
/// segment and lie at most `max_gap_s` apart.
fn pose_at(
    samples: &[(f64, u64, Isometry3<f64>)],
    host_s: f64,
    max_gap_s: f64,
) -> Option<Isometry3<f64>> {
    let after = samples.partition_point(|s| s.0 <= host_s);
    let (a, b) = (samples.get(after.checked_sub(1)?)?, samples.get(after)?);
    let gap = b.0 - a.0;
    if a.1 != b.1 || gap > max_gap_s || gap <= 0.0 {
        return None;
    }
    Some(pose::interpolate(&a.2, &b.2, (host_s - a.0) / gap))
}

#[cfg(test)]
mod tests;
