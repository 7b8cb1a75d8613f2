//! Rigid transforms in the UR pose convention and their interpolation.
//!
//! A UR pose `[x, y, z, rx, ry, rz]` is a translation in metres and a rotation vector (axis ×
//! angle, radians) (docs/protocols.md C7). `base_from_tcp` maps TCP coordinates into the
//! base frame. Between two RTDE samples the pose is interpolated linearly in position and by
//! slerp in rotation.

use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};

/// The transform of a UR pose: `frame_from_child` for a pose of `child` given in `frame`.
pub fn isometry_of_pose(pose: &[f64; 6]) -> Isometry3<f64> {
    Isometry3::from_parts(
        Translation3::new(pose[0], pose[1], pose[2]),
        UnitQuaternion::from_scaled_axis(Vector3::new(pose[3], pose[4], pose[5])),
    )
}

/// The UR pose of a transform (rotation vector with angle in [0, π]).
pub fn pose_of_isometry(iso: &Isometry3<f64>) -> [f64; 6] {
    let t = iso.translation.vector;
    let r = iso.rotation.scaled_axis();
    [t.x, t.y, t.z, r.x, r.y, r.z]
}

/// The pose a fraction `f` (0..=1) of the way from `a` to `b`: linear in position, slerp in
/// rotation (the shorter arc).
pub fn interpolate(a: &Isometry3<f64>, b: &Isometry3<f64>, f: f64) -> Isometry3<f64> {
    let translation = a.translation.vector.lerp(&b.translation.vector, f);
    // `slerp` is undefined for antipodal quaternions; `try_slerp` declines them and nothing
    // between two RTDE samples 2 ms apart turns by 180°, so fall back to the nearer end.
    let rotation = a
        .rotation
        .try_slerp(&b.rotation, f, 1e-12)
        .unwrap_or(if f < 0.5 { a.rotation } else { b.rotation });
    Isometry3::from_parts(Translation3::from(translation), rotation)
}

/// A point given in the child frame, expressed in the parent frame.
pub fn apply(parent_from_child: &Isometry3<f64>, point: &[f64; 3]) -> [f64; 3] {
    let p = parent_from_child.transform_point(&Point3::new(point[0], point[1], point[2]));
    [p.x, p.y, p.z]
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::FRAC_PI_2;

    #[test]
    fn a_pose_round_trips_through_its_transform() {
        let pose = [0.4, -0.2, 0.3, 0.1, -2.9, 0.2];
        let back = pose_of_isometry(&isometry_of_pose(&pose));
        for (a, b) in pose.iter().zip(back) {
            assert!((a - b).abs() < 1e-12, "{pose:?} → {back:?}");
        }
    }

    #[test]
    fn a_point_follows_translation_then_rotation() {
        // 90° about z, then 1 m along x: (1, 0, 0) in the child lands at (1, 1, 0).
        let iso = isometry_of_pose(&[1.0, 0.0, 0.0, 0.0, 0.0, FRAC_PI_2]);
        let p = apply(&iso, &[1.0, 0.0, 0.0]);
        assert!((p[0] - 1.0).abs() < 1e-12 && (p[1] - 1.0).abs() < 1e-12 && p[2].abs() < 1e-12);
    }

    #[test]
    fn halfway_is_linear_in_position_and_half_the_angle() {
        let a = isometry_of_pose(&[0.0, 0.0, 0.0, 0.0, 0.0, 0.0]);
        let b = isometry_of_pose(&[0.2, -0.1, 0.4, 0.0, 0.0, 1.0]);
        let mid = pose_of_isometry(&interpolate(&a, &b, 0.25));
        assert!((mid[0] - 0.05).abs() < 1e-12 && (mid[1] + 0.025).abs() < 1e-12);
        assert!((mid[2] - 0.1).abs() < 1e-12, "{mid:?}");
        assert!(
            (mid[5] - 0.25).abs() < 1e-12,
            "slerp keeps the axis and splits the angle: {mid:?}"
        );
    }
}
