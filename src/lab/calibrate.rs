//! Calibration from a scan of a point reflector (docs/hardware.md §6): `align.sync_offset_s`
//! and the translation of `align.tcp_from_radar`.
//!
//! - **Sync offset.** A timing error δt moves each row's antennas by v·δt along its own
//!   direction, so a point reflector focuses at x + v·δt on forward rows and x − v·δt on backward
//!   ones (docs/protocols.md D3 step 3). The rows are aligned with the config's offset and again
//!   with the offset 1 ms later; the forward-minus-backward disagreement is linear in the
//!   offset, and its zero is the offset to use. Solving it from two alignments needs no sign
//!   convention and no speed.
//! - **Mount.** All rows together focus the reflector at its position as the antennas are
//!   believed to be. A translation error e (TCP frame) of `tcp_from_radar` moves every antenna by
//!   R·e in the base frame (R: the tool's rotation during the raster), and the image with them;
//!   the reflector's measured position in the base frame then gives e = Rᵀ(found − measured).
//!
//! Focusing is a matched filter: |Σ h·exp(−j2πf·path/c)|² over antennas and samples (a capture's
//! echo of a point is exp(+j2πf·path/c)), searched
//! coarse to fine along one axis at a time. The frequency plan is linear, so each antenna's
//! phasors come from one `sin_cos` and a recurrence.

use nalgebra::{Rotation3, Vector3};
use rayon::prelude::*;

use super::LabConfig;
use super::job::AlignedRows;
use super::scan::{RowRecording, ScanSetup, align_recording, build_capture};
use crate::SPEED_OF_LIGHT_M_PER_S;
use crate::capture::Capture;

/// The most antennas a focus sum uses (evenly strided): enough for a sharp peak, bounded time.
const MAX_FOCUS_ANTENNAS: usize = 8000;
/// The change of sync offset used to measure the disagreement's slope, seconds.
const PROBE_S: f64 = 0.001;

/// Why a calibration could not be made.
#[derive(Debug, thiserror::Error)]
pub enum CalibrationError {
    #[error("the scan has no {which} rows; scan with scan.serpentine = true (rows both ways)")]
    MissingDirection { which: &'static str },
    #[error("row {row}: {message}")]
    Align { row: usize, message: String },
    #[error("no antenna reaches the reflector's samples (an empty capture)")]
    Empty,
    #[error(
        "the forward/backward disagreement does not change with the sync offset ({slope_m_per_s:.3e} m/s): is the reflector in the scan?"
    )]
    Flat { slope_m_per_s: f64 },
}

/// What a calibration found.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Calibration {
    /// Where all rows focus the reflector, base frame, metres.
    pub found_in_base_m: [f64; 3],
    /// Found minus measured, base frame, metres.
    pub error_in_base_m: [f64; 3],
    /// Forward rows' focus x minus backward rows' under the config's offset, metres.
    pub disagreement_m: f64,
    /// The config's `align.sync_offset_s`.
    pub sync_offset_s: f64,
    /// The offset at which forward and backward rows agree.
    pub suggested_sync_offset_s: f64,
    /// The config's `align.tcp_from_radar` with its translation corrected.
    pub suggested_tcp_from_radar: [f64; 6],
    /// Antennas in the focus sums (of all rows).
    pub antennas: usize,
}

/// Calibrates from `rows` (recordings of a scan over a point reflector at `measured_in_base_m`,
/// which also starts the search) under `lab`'s alignment.
pub fn calibrate(
    lab: &LabConfig,
    setup: &ScanSetup,
    output_names: &[String],
    rows: &[RowRecording],
    measured_in_base_m: [f64; 3],
) -> Result<Calibration, CalibrationError> {
    for (direction, which) in [(1, "forward"), (-1, "backward")] {
        if !rows.iter().any(|r| r.direction == direction) {
            return Err(CalibrationError::MissingDirection { which });
        }
    }
    // Every row aligned once under a config; captures are built from subsets of that.
    let align_all = |lab: &LabConfig| {
        rows.iter()
            .map(|rec| {
                align_recording(lab, setup, output_names, rec)
                    .map(|a| (rec.clone(), a))
                    .map_err(|e| CalibrationError::Align {
                        row: rec.row,
                        message: e.to_string(),
                    })
            })
            .collect::<Result<AlignedRows, _>>()
    };
    let capture_of = |lab: &LabConfig, aligned: &AlignedRows, direction: Option<i8>| {
        let chosen: AlignedRows = aligned
            .iter()
            .filter(|(r, _)| direction.is_none_or(|d| r.direction == d))
            .cloned()
            .collect();
        let capture = build_capture(lab, setup, &chosen);
        if capture.antennas() == 0 {
            return Err(CalibrationError::Empty);
        }
        Ok(capture)
    };
    let aligned = align_all(lab)?;
    let all = capture_of(lab, &aligned, None)?;
    let found = focus_point(&all, measured_in_base_m, 0.02);
    let disagreement = |lab: &LabConfig, aligned: &AlignedRows| -> Result<f64, CalibrationError> {
        let x = |d: i8| -> Result<f64, CalibrationError> {
            let c = capture_of(lab, aligned, Some(d))?;
            Ok(focus_axis(&c, found, 0, 0.005, 41))
        };
        Ok(x(1)? - x(-1)?)
    };
    let d0 = disagreement(lab, &aligned)?;
    let mut probe = lab.clone();
    probe.align.sync_offset_s += PROBE_S;
    let d1 = disagreement(&probe, &align_all(&probe)?)?;
    let slope = (d1 - d0) / PROBE_S;
    // The expected slope is 2v: below a hundredth of that, the rows do not see the reflector.
    let expected = 2.0 * setup.spec.speed_m_per_s;
    if slope.is_nan() || slope.abs() <= 0.01 * expected {
        return Err(CalibrationError::Flat {
            slope_m_per_s: slope,
        });
    }
    let error_in_base_m = [0, 1, 2].map(|k| found[k] - measured_in_base_m[k]);
    let r = setup.spec.tool_rotation_in_base;
    let tool = Rotation3::new(Vector3::new(r[0], r[1], r[2]));
    let e_tcp = tool.inverse() * Vector3::from(error_in_base_m);
    let mut tcp = lab.align.tcp_from_radar;
    for k in 0..3 {
        tcp[k] -= e_tcp[k];
    }
    Ok(Calibration {
        found_in_base_m: found,
        error_in_base_m,
        disagreement_m: d0,
        sync_offset_s: lab.align.sync_offset_s,
        suggested_sync_offset_s: lab.align.sync_offset_s - d0 / slope,
        suggested_tcp_from_radar: tcp,
        antennas: all.antennas(),
    })
}

/// The point where `capture` focuses, searched from `start` within ±`span_m` on each axis: x,
/// y, z in turn, then again in a tenth of the span until no coordinate moves by more than
/// half a micrometre (the peak of an aperture off to one side is tilted, so one pass does not
/// settle it).
pub fn focus_point(capture: &Capture, start: [f64; 3], span_m: f64) -> [f64; 3] {
    let mut p = start;
    for axis in 0..3 {
        p[axis] = focus_axis(capture, p, axis, span_m, 81);
    }
    for _ in 0..12 {
        let before = p;
        for axis in 0..3 {
            p[axis] = focus_axis(capture, p, axis, span_m / 10.0, 21);
        }
        if (0..3).all(|k| (p[k] - before[k]).abs() < 5e-7) {
            break;
        }
    }
    p
}

/// The coordinate along `axis` through `p` where `capture` focuses best, within ±`span_m`:
/// `steps` steps, then 21 around the best at a tenth of the step, then a parabola.
pub fn focus_axis(capture: &Capture, p: [f64; 3], axis: usize, span_m: f64, steps: usize) -> f64 {
    let at = |v: f64| {
        let mut q = p;
        q[axis] = v;
        focus_power(capture, q)
    };
    let search = |centre: f64, half: f64, n: usize| {
        let step = 2.0 * half / (n - 1) as f64;
        let values: Vec<(f64, f64)> = (0..n)
            .map(|i| {
                let v = centre - half + i as f64 * step;
                (v, at(v))
            })
            .collect();
        let best = (0..n)
            .max_by(|&a, &b| values[a].1.total_cmp(&values[b].1))
            .unwrap_or(0);
        (values, best, step)
    };
    let (_, best, step) = search(p[axis], span_m, steps.max(3));
    let centre = p[axis] - span_m + best as f64 * step;
    let (values, i, fine) = search(centre, step, 21);
    if i == 0 || i + 1 == values.len() {
        return values[i].0;
    }
    let (l, m, r) = (values[i - 1].1, values[i].1, values[i + 1].1);
    let denominator = l - 2.0 * m + r;
    let shift = if denominator < 0.0 {
        0.5 * (l - r) / denominator
    } else {
        0.0
    };
    values[i].0 + shift.clamp(-1.0, 1.0) * fine
}

/// |Σ h·exp(−j2πf·path/c)|² at `p` over at most 8 000 antennas (evenly strided).
pub fn focus_power(capture: &Capture, p: [f64; 3]) -> f64 {
    let n = capture.antennas();
    let stride = n.div_ceil(MAX_FOCUS_ANTENNAS).max(1);
    let f0 = capture.plan.start_frequency_hz;
    let df = capture.plan.frequency_step_hz;
    let distance = |q: [f64; 3]| {
        ((q[0] - p[0]).powi(2) + (q[1] - p[1]).powi(2) + (q[2] - p[2]).powi(2)).sqrt()
    };
    let (re, im) = (0..n)
        .into_par_iter()
        .step_by(stride)
        .map(|a| {
            let path =
                distance(capture.tx_m[a]) + distance(capture.rx_m[a]) + capture.range_offset_m;
            // Phase in turns, reduced before the trigonometry.
            let turns = |f: f64| (f * path / SPEED_OF_LIGHT_M_PER_S).fract();
            let (s0, c0) = (std::f64::consts::TAU * turns(f0)).sin_cos();
            let (sd, cd) = (std::f64::consts::TAU * turns(df)).sin_cos();
            // w = exp(−j2πf·path/c), stepped by exp(−j2π·df·path/c).
            let (mut wr, mut wi) = (c0, -s0);
            let sd = -sd;
            let (mut re, mut im) = (0.0f64, 0.0f64);
            for h in capture.chirp(a) {
                let (hr, hi) = (f64::from(h.re), f64::from(h.im));
                re += hr * wr - hi * wi;
                im += hr * wi + hi * wr;
                (wr, wi) = (wr * cd - wi * sd, wr * sd + wi * cd);
            }
            (re, im)
        })
        .reduce(|| (0.0, 0.0), |a, b| (a.0 + b.0, a.1 + b.1));
    re * re + im * im
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::capture::FrequencyPlan;
    use num_complex::Complex32;
    use std::sync::Arc;

    /// A monostatic row of antennas along x at z = 0.3 m over a point at `target`, the echoes
    /// exact: h = exp(+j2πf·path/c), the convention of the simulator and the capture format.
    fn point_capture(target: [f64; 3]) -> Capture {
        let plan = FrequencyPlan {
            start_frequency_hz: 77e9,
            frequency_step_hz: 4e9 / 256.0,
            samples_per_chirp: 256,
        };
        let antennas: Vec<[f64; 3]> = (-40..=40)
            .flat_map(|i| (-2..=2).map(move |j| [i as f64 * 1e-3, j as f64 * 2e-3, 0.3]))
            .collect();
        let mut samples = Vec::new();
        for a in &antennas {
            let d = ((a[0] - target[0]).powi(2)
                + (a[1] - target[1]).powi(2)
                + (a[2] - target[2]).powi(2))
            .sqrt();
            for k in 0..plan.samples_per_chirp {
                let phase = std::f64::consts::TAU
                    * (plan.frequency_hz(k) * 2.0 * d / SPEED_OF_LIGHT_M_PER_S).fract();
                samples.push(Complex32::new(phase.cos() as f32, phase.sin() as f32));
            }
        }
        Capture {
            plan,
            range_offset_m: 0.0,
            tx_m: antennas.clone(),
            rx_m: antennas,
            samples: Arc::new(samples),
            description: String::new(),
            extra: serde_json::Map::new(),
        }
    }

    #[test]
    fn a_point_target_is_found_to_a_few_micrometres_from_a_centimetre_off() {
        let target = [0.0123, -0.0031, 0.0501];
        let capture = point_capture(target);
        let found = focus_point(&capture, [0.0, 0.0, 0.06], 0.02);
        let error: Vec<f64> = (0..3).map(|k| (found[k] - target[k]) * 1e6).collect();
        println!("found {found:?}, error {error:?} µm");
        assert!((found[0] - target[0]).abs() < 5e-6, "{error:?}");
        assert!((found[2] - target[2]).abs() < 5e-6, "{error:?}");
        // The aperture is 8 mm in y: y is found, less sharply.
        assert!((found[1] - target[1]).abs() < 5e-5, "{error:?}");
    }
}
