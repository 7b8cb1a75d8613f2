//! The raster planner (docs/protocols.md C5): a scan spec becomes rows of constant-speed
//! `movel`s in the robot's base frame.
//!
//! Rows run along x and step along y. Each row is lengthened at both ends by the distance the
//! trapezoidal profile needs to reach its speed, v²/2a, so that the constant-velocity middle
//! covers the aperture's whole width; the planner reports that usable middle. The speed must not
//! exceed λ/4 per frame period (0.32 m/s at 77.5 GHz and 3 ms), or consecutive frames would be
//! more than λ/4 apart; such a spec is refused before any motion.
//!
//! URScript goes to the secondary interface (port 30002, C5 option 1): each row is one
//! `movel(p[...], a=..., v=...)` statement, which the controller runs as a one-line program.

/// What to scan, in the robot's base frame.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ScanSpec {
    /// Aperture centre in base, metres (z is the scan height).
    pub centre_in_base_m: [f64; 3],
    /// Aperture extent along x (the rows) and y, metres.
    pub width_m: f64,
    pub height_m: f64,
    /// Distance between rows, metres (λ/4 = 0.97 mm for the paper's aperture).
    pub row_spacing_m: f64,
    /// TCP speed along a row, m/s.
    pub speed_m_per_s: f64,
    /// TCP acceleration of the `movel`s, m/s².
    pub accel_m_per_s2: f64,
    /// Tool orientation as a rotation vector in base, radians (held through the scan).
    pub tool_rotation_in_base: [f64; 3],
    /// Alternate the direction of successive rows.
    pub serpentine: bool,
}

impl Default for ScanSpec {
    fn default() -> Self {
        Self {
            centre_in_base_m: [0.45, -0.20, 0.35],
            width_m: 0.60,
            height_m: 0.45,
            row_spacing_m: 0.000_967,
            speed_m_per_s: 0.25,
            accel_m_per_s2: 1.0,
            tool_rotation_in_base: [0.0, std::f64::consts::PI, 0.0],
            serpentine: true,
        }
    }
}

/// Why a scan spec was refused.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum PlanError {
    #[error("scan.{field} = {value} must be a positive number")]
    NotPositive { field: &'static str, value: f64 },
    #[error(
        "scan.speed_m_per_s = {speed} exceeds λ/4 per frame ({limit:.4} m/s = {quarter_wave_mm:.3} mm per {period_ms} ms frame)"
    )]
    TooFast {
        speed: f64,
        limit: f64,
        quarter_wave_mm: f64,
        period_ms: f64,
    },
    #[error("scan.{field} = {value} is not finite")]
    NotFinite { field: &'static str, value: f64 },
}

/// One row of the raster.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Row {
    pub index: usize,
    /// Where the `movel` starts and ends: `p[x, y, z, rx, ry, rz]` in base.
    pub start_pose: [f64; 6],
    pub end_pose: [f64; 6],
    /// The constant-velocity stretch along x, metres in base (low, high): the aperture's width.
    pub usable_x_m: (f64, f64),
    /// +1 when the row runs towards +x.
    pub direction: i8,
    /// Time the `movel` takes, including its ramps, seconds.
    pub duration_s: f64,
}

/// A `movel` statement to `pose` in base, with its line end.
pub fn movel_script(pose: &[f64; 6], speed_m_per_s: f64, accel_m_per_s2: f64) -> String {
    let p = pose;
    format!(
        "movel(p[{:.6},{:.6},{:.6},{:.6},{:.6},{:.6}], a={accel_m_per_s2:.4}, v={speed_m_per_s:.4})\n",
        p[0], p[1], p[2], p[3], p[4], p[5]
    )
}

impl Row {
    /// The URScript statement that drives this row.
    pub fn urscript(&self, speed_m_per_s: f64, accel_m_per_s2: f64) -> String {
        movel_script(&self.end_pose, speed_m_per_s, accel_m_per_s2)
    }
}

/// The planned raster.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct RasterPlan {
    pub rows: Vec<Row>,
    /// Run-up added at each end of a row, v²/2a, metres.
    pub ramp_m: f64,
    /// Driving time of all rows (not the moves between them), seconds.
    pub total_row_time_s: f64,
}

/// Plans a raster for frames of `frame_period_s` at wavelength `wavelength_m`.
pub fn plan_raster(
    spec: &ScanSpec,
    wavelength_m: f64,
    frame_period_s: f64,
) -> Result<RasterPlan, PlanError> {
    for (field, value) in [
        ("width_m", spec.width_m),
        ("row_spacing_m", spec.row_spacing_m),
        ("speed_m_per_s", spec.speed_m_per_s),
        ("accel_m_per_s2", spec.accel_m_per_s2),
    ] {
        if !(value.is_finite() && value > 0.0) {
            return Err(PlanError::NotPositive { field, value });
        }
    }
    if !(spec.height_m.is_finite() && spec.height_m >= 0.0) {
        return Err(PlanError::NotPositive {
            field: "height_m",
            value: spec.height_m,
        });
    }
    for (i, v) in spec
        .centre_in_base_m
        .iter()
        .chain(&spec.tool_rotation_in_base)
        .enumerate()
    {
        if !v.is_finite() {
            let field = if i < 3 {
                "centre_in_base_m"
            } else {
                "tool_rotation_in_base"
            };
            return Err(PlanError::NotFinite { field, value: *v });
        }
    }
    let quarter_wave = wavelength_m / 4.0;
    let limit = quarter_wave / frame_period_s;
    if spec.speed_m_per_s > limit {
        return Err(PlanError::TooFast {
            speed: spec.speed_m_per_s,
            limit,
            quarter_wave_mm: quarter_wave * 1e3,
            period_ms: frame_period_s * 1e3,
        });
    }
    let v = spec.speed_m_per_s;
    let a = spec.accel_m_per_s2;
    let ramp = v * v / (2.0 * a);
    let [cx, cy, z] = spec.centre_in_base_m;
    let (x0, x1) = (cx - spec.width_m / 2.0, cx + spec.width_m / 2.0);
    let rows_n = (spec.height_m / spec.row_spacing_m + 1e-9).floor() as usize + 1;
    let y0 = cy - (rows_n - 1) as f64 * spec.row_spacing_m / 2.0;
    let length = spec.width_m + 2.0 * ramp;
    let duration = length / v + v / a;
    let [rx, ry, rz] = spec.tool_rotation_in_base;
    let rows = (0..rows_n)
        .map(|k| {
            let y = y0 + k as f64 * spec.row_spacing_m;
            let forward = !spec.serpentine || k % 2 == 0;
            let (from, to) = if forward {
                (x0 - ramp, x1 + ramp)
            } else {
                (x1 + ramp, x0 - ramp)
            };
            Row {
                index: k,
                start_pose: [from, y, z, rx, ry, rz],
                end_pose: [to, y, z, rx, ry, rz],
                usable_x_m: (x0, x1),
                direction: if forward { 1 } else { -1 },
                duration_s: duration,
            }
        })
        .collect::<Vec<_>>();
    Ok(RasterPlan {
        total_row_time_s: duration * rows.len() as f64,
        rows,
        ramp_m: ramp,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    const LAMBDA_M: f64 = 0.003_868;

    #[test]
    fn the_default_raster_covers_the_aperture_with_constant_speed() {
        let spec = ScanSpec::default();
        let plan = plan_raster(&spec, LAMBDA_M, 0.003).unwrap();
        assert_eq!(plan.rows.len(), 466);
        let r0 = &plan.rows[0];
        let r1 = &plan.rows[1];
        assert!((plan.ramp_m - 0.25f64.powi(2) / 2.0).abs() < 1e-12);
        assert!((r0.usable_x_m.0 - 0.15).abs() < 1e-12 && (r0.usable_x_m.1 - 0.75).abs() < 1e-12);
        assert_eq!((r0.direction, r1.direction), (1, -1));
        assert!((r0.start_pose[0] - (0.15 - plan.ramp_m)).abs() < 1e-12);
        assert!((r1.start_pose[0] - (0.75 + plan.ramp_m)).abs() < 1e-12);
        assert!((r1.start_pose[1] - r0.start_pose[1] - spec.row_spacing_m).abs() < 1e-12);
        assert!(r0.urscript(0.25, 1.0).starts_with("movel(p[0.781250,"));
    }

    #[test]
    fn an_over_speed_spec_is_refused_with_the_limit() {
        let spec = ScanSpec {
            speed_m_per_s: 0.4,
            ..ScanSpec::default()
        };
        let e = plan_raster(&spec, LAMBDA_M, 0.003).unwrap_err();
        assert_eq!(
            e.to_string(),
            "scan.speed_m_per_s = 0.4 exceeds λ/4 per frame (0.3223 m/s = 0.967 mm per 3 ms frame)"
        );
        let spec = ScanSpec {
            accel_m_per_s2: 0.0,
            ..ScanSpec::default()
        };
        assert!(matches!(
            plan_raster(&spec, LAMBDA_M, 0.003),
            Err(PlanError::NotPositive {
                field: "accel_m_per_s2",
                ..
            })
        ));
    }
}
