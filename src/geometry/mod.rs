//! Triangle meshes and the queries the simulator and the evaluation need.
//!
//! This module owns geometry only: loading meshes (STL, OBJ, PLY), building primitives, placing
//! them with a pose, and answering ray queries through a bounding-volume hierarchy. It knows
//! nothing about radio waves; the simulator turns geometry into scattering.

mod bvh;
mod io;
mod occluders;
pub mod ply;
mod primitives;
pub mod vec3;

pub use bvh::{Bvh, Hit};
pub use io::{MeshError, load_mesh};
pub use occluders::{FrontOccluders, LocalVisibility, ViewRegion};
pub use primitives::{
    bottle_mesh, bowl_mesh, box_mesh, cup_mesh, cylinder_mesh, plate_mesh, sphere_mesh,
};

use nalgebra::{Isometry3, Point3, Rotation3, Translation3, UnitQuaternion, Vector3};

/// An indexed triangle mesh in metres. Triangles wind counter-clockwise seen from outside.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct TriMesh {
    pub vertices_m: Vec<[f64; 3]>,
    pub triangles: Vec<[u32; 3]>,
}

/// A rigid placement: rotation about the fixed x, then y, then z axes, then a translation.
pub fn pose_from(position_m: [f64; 3], rotation_deg: [f64; 3]) -> Isometry3<f64> {
    let [rx, ry, rz] = rotation_deg.map(f64::to_radians);
    let rotation = Rotation3::from_euler_angles(rx, ry, rz);
    Isometry3::from_parts(
        Translation3::new(position_m[0], position_m[1], position_m[2]),
        UnitQuaternion::from_rotation_matrix(&rotation),
    )
}

impl TriMesh {
    /// Axis-aligned bounds (min, max); `None` for a mesh without vertices.
    pub fn bounds(&self) -> Option<([f64; 3], [f64; 3])> {
        let first = *self.vertices_m.first()?;
        Some(self.vertices_m.iter().fold((first, first), |(lo, hi), v| {
            (
                [lo[0].min(v[0]), lo[1].min(v[1]), lo[2].min(v[2])],
                [hi[0].max(v[0]), hi[1].max(v[1]), hi[2].max(v[2])],
            )
        }))
    }

    /// Corner positions of triangle `i`.
    pub fn corners(&self, i: usize) -> [Vector3<f64>; 3] {
        self.triangles[i].map(|k| Vector3::from(self.vertices_m[k as usize]))
    }

    /// Total surface area, m².
    pub fn area_m2(&self) -> f64 {
        (0..self.triangles.len())
            .map(|i| {
                let [a, b, c] = self.corners(i);
                0.5 * (b - a).cross(&(c - a)).norm()
            })
            .sum()
    }

    /// Signed volume (positive for a closed, outward-wound mesh), m³.
    pub fn signed_volume_m3(&self) -> f64 {
        (0..self.triangles.len())
            .map(|i| {
                let [a, b, c] = self.corners(i);
                a.dot(&b.cross(&c)) / 6.0
            })
            .sum()
    }

    /// The mesh moved by `pose`.
    pub fn transformed(&self, pose: &Isometry3<f64>) -> TriMesh {
        TriMesh {
            vertices_m: self
                .vertices_m
                .iter()
                .map(|v| {
                    let p = pose * Point3::from(*v);
                    [p.x, p.y, p.z]
                })
                .collect(),
            triangles: self.triangles.clone(),
        }
    }

    /// The mesh scaled about the origin.
    pub fn scaled(&self, factor: f64) -> TriMesh {
        TriMesh {
            vertices_m: self
                .vertices_m
                .iter()
                .map(|v| v.map(|c| c * factor))
                .collect(),
            triangles: self.triangles.clone(),
        }
    }

    /// The mesh translated so that its bounding-box centre is at the origin.
    pub fn centred(&self) -> TriMesh {
        let Some((lo, hi)) = self.bounds() else {
            return self.clone();
        };
        let c = [0, 1, 2].map(|k| 0.5 * (lo[k] + hi[k]));
        TriMesh {
            vertices_m: self
                .vertices_m
                .iter()
                .map(|v| [v[0] - c[0], v[1] - c[1], v[2] - c[2]])
                .collect(),
            triangles: self.triangles.clone(),
        }
    }

    /// Appends another mesh.
    pub fn append(&mut self, other: &TriMesh) {
        let base = self.vertices_m.len() as u32;
        self.vertices_m.extend_from_slice(&other.vertices_m);
        self.triangles
            .extend(other.triangles.iter().map(|t| t.map(|k| k + base)));
    }

    /// Merges vertices closer than `tolerance_m` (STL files repeat each corner per triangle) and
    /// drops triangles that become degenerate.
    pub fn welded(&self, tolerance_m: f64) -> TriMesh {
        use std::collections::HashMap;
        let key = |v: &[f64; 3]| v.map(|c| (c / tolerance_m).round() as i64);
        let mut index: HashMap<[i64; 3], u32> = HashMap::new();
        let mut vertices_m = Vec::new();
        let remap: Vec<u32> = self
            .vertices_m
            .iter()
            .map(|v| {
                *index.entry(key(v)).or_insert_with(|| {
                    vertices_m.push(*v);
                    (vertices_m.len() - 1) as u32
                })
            })
            .collect();
        let triangles = self
            .triangles
            .iter()
            .map(|t| t.map(|k| remap[k as usize]))
            .filter(|t| t[0] != t[1] && t[1] != t[2] && t[0] != t[2])
            .collect();
        TriMesh {
            vertices_m,
            triangles,
        }
    }

    /// Checks indices and coordinates; the message names the first bad element.
    pub fn validate(&self) -> Result<(), String> {
        if let Some(i) = self
            .vertices_m
            .iter()
            .position(|v| v.iter().any(|c| !c.is_finite()))
        {
            return Err(format!(
                "vertex {i} is not finite: {:?}",
                self.vertices_m[i]
            ));
        }
        let n = self.vertices_m.len() as u32;
        if let Some(i) = self
            .triangles
            .iter()
            .position(|t| t.iter().any(|&k| k >= n))
        {
            return Err(format!(
                "triangle {i} refers to vertex {:?}, but there are {n} vertices",
                self.triangles[i]
            ));
        }
        if self.triangles.is_empty() {
            return Err("the mesh has no triangles".into());
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pose_rotates_about_x_then_y_then_z() {
        let pose = pose_from([1.0, 2.0, 3.0], [90.0, 0.0, 90.0]);
        // x-rotation takes +y to +z; z-rotation then leaves +z alone.
        let p = pose * Point3::new(0.0, 1.0, 0.0);
        assert!((p - Point3::new(1.0, 2.0, 4.0)).norm() < 1e-12, "{p}");
        // +x: unchanged by x-rotation, z-rotation takes it to +y.
        let q = pose * Point3::new(1.0, 0.0, 0.0);
        assert!((q - Point3::new(1.0, 3.0, 3.0)).norm() < 1e-12, "{q}");
    }
}
