//! Per-triangle lists of the only triangles that can block a ray leaving a triangle's front side
//! towards a known region (the aperture).
//!
//! Two exact filters:
//! 1. A ray that starts on or in front of the plane of triangle S and heads to its front side
//!    (n_S·u > 0) stays strictly in front of that plane, so it can only meet triangles with a
//!    vertex strictly in front of it.
//! 2. A segment from a point within `margin` of S to a point of the view region lies inside the
//!    convex hull of S's `margin`-expanded bounding box and the region. A triangle that lies
//!    wholly outside one face plane of that hull cannot meet the segment.
//!
//! For a convex mesh every list is empty; on a scanned, nearly convex object the lists hold a few
//! neighbours in dents. Long lists are not kept: those triangles fall back to the BVH.

use nalgebra::Vector3;
use rayon::prelude::*;

use super::TriMesh;

/// Where every ray ends: an axis-aligned rectangle in a horizontal plane (the antennas).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ViewRegion {
    pub x_m: [f64; 2],
    pub y_m: [f64; 2],
    pub z_m: f64,
}

#[derive(Debug, Clone, Copy)]
struct Tri {
    v0: [f32; 3],
    e1: [f32; 3],
    e2: [f32; 3],
}

/// Candidate occluders of every triangle of one mesh.
#[derive(Debug, Clone, Default)]
pub struct FrontOccluders {
    /// `lists[start[i]..start[i + 1]]` are triangle i's candidates; `u32::MAX` in `start[i]`
    /// marks a list that was too long.
    start: Vec<u32>,
    lists: Vec<u32>,
    tris: Vec<Tri>,
}

const TOO_MANY: u32 = u32::MAX;

/// Whether a ray leaving triangle `face` may be blocked by its own mesh.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum LocalVisibility {
    Clear,
    Blocked,
    /// The candidate list was too long; ask the BVH.
    Unknown,
}

impl FrontOccluders {
    /// Builds the lists for rays that start within `margin_m` of a triangle and end in `view`,
    /// keeping at most `max_candidates` per triangle.
    pub fn build(
        mesh: &TriMesh,
        view: &ViewRegion,
        margin_m: f64,
        max_candidates: usize,
    ) -> FrontOccluders {
        let Some((lo, hi)) = mesh.bounds() else {
            return FrontOccluders::default();
        };
        let size = (0..3).map(|k| hi[k] - lo[k]).fold(0.0, f64::max).max(1e-3);
        let tolerance = 1e-9 * size;
        let mut around: Vec<Vec<u32>> = vec![Vec::new(); mesh.vertices_m.len()];
        for (f, t) in mesh.triangles.iter().enumerate() {
            for &v in t {
                around[v as usize].push(f as u32);
            }
        }
        let per_triangle: Vec<Option<Vec<u32>>> = (0..mesh.triangles.len())
            .into_par_iter()
            .map(|f| {
                let [a, b, c] = mesh.corners(f);
                let n = (b - a).cross(&(c - a)).try_normalize(0.0)?;
                let d = n.dot(&a);
                let mut list: Vec<u32> = Vec::new();
                for (v, p) in mesh.vertices_m.iter().enumerate() {
                    let h = n.x * p[0] + n.y * p[1] + n.z * p[2] - d;
                    if h > tolerance {
                        list.extend_from_slice(&around[v]);
                    }
                }
                list.sort_unstable();
                list.dedup();
                let planes = hull_planes(&[a, b, c], view, margin_m, tolerance);
                list.retain(|&t| {
                    let corners = mesh.corners(t as usize);
                    !planes
                        .iter()
                        .any(|(n, d)| corners.iter().all(|v| n.dot(v) > d + tolerance))
                });
                (list.len() <= max_candidates).then_some(list)
            })
            .collect();
        let mut start = Vec::with_capacity(per_triangle.len() + 1);
        let mut lists = Vec::new();
        for entry in &per_triangle {
            match entry {
                Some(l) => {
                    start.push(lists.len() as u32);
                    lists.extend_from_slice(l);
                }
                None => start.push(TOO_MANY),
            }
        }
        start.push(lists.len() as u32);
        let tris = (0..mesh.triangles.len())
            .map(|f| {
                let [a, b, c] = mesh
                    .corners(f)
                    .map(|v| [v.x as f32, v.y as f32, v.z as f32]);
                Tri {
                    v0: a,
                    e1: [b[0] - a[0], b[1] - a[1], b[2] - a[2]],
                    e2: [c[0] - a[0], c[1] - a[1], c[2] - a[2]],
                }
            })
            .collect();
        FrontOccluders { start, lists, tris }
    }
}

/// Outward face planes (n, d: n·x ≤ d inside) of the convex hull of the triangle's bounding box
/// grown by `margin` and the view rectangle.
fn hull_planes(
    tri: &[Vector3<f64>; 3],
    view: &ViewRegion,
    margin: f64,
    tolerance: f64,
) -> Vec<(Vector3<f64>, f64)> {
    let lo = tri
        .iter()
        .fold(Vector3::repeat(f64::INFINITY), |m, v| m.inf(v));
    let hi = tri
        .iter()
        .fold(Vector3::repeat(f64::NEG_INFINITY), |m, v| m.sup(v));
    let mut points = Vec::with_capacity(12);
    for i in 0..8 {
        let pick = |k: usize, a: f64, b: f64| {
            if i >> k & 1 == 0 {
                a - margin
            } else {
                b + margin
            }
        };
        points.push(Vector3::new(
            pick(0, lo.x, hi.x),
            pick(1, lo.y, hi.y),
            pick(2, lo.z, hi.z),
        ));
    }
    for (x, y) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
        points.push(Vector3::new(view.x_m[x], view.y_m[y], view.z_m));
    }
    let mut planes = Vec::new();
    let n = points.len();
    for i in 0..n {
        for j in i + 1..n {
            for k in j + 1..n {
                let Some(normal) = (points[j] - points[i])
                    .cross(&(points[k] - points[i]))
                    .try_normalize(1e-12)
                else {
                    continue;
                };
                let d = normal.dot(&points[i]);
                let side = |s: f64| points.iter().all(|p| s * (normal.dot(p) - d) <= tolerance);
                if side(1.0) {
                    planes.push((normal, d));
                } else if side(-1.0) {
                    planes.push((-normal, -d));
                }
            }
        }
    }
    planes
}

impl FrontOccluders {
    /// Number of triangles whose list was too long.
    pub fn overflowing(&self) -> usize {
        self.start.iter().filter(|&&s| s == TOO_MANY).count()
    }

    /// Tests the ray `origin + t·dir`, 0 < t < `t_max`, which must leave triangle `face` on its
    /// front side, against `face`'s candidates.
    pub fn test(&self, face: u32, origin: [f32; 3], dir: [f32; 3], t_max: f32) -> LocalVisibility {
        let f = face as usize;
        let (Some(&s), Some(&e)) = (self.start.get(f), self.start.get(f + 1)) else {
            return LocalVisibility::Unknown;
        };
        if s == TOO_MANY {
            return LocalVisibility::Unknown;
        }
        // The next entry may itself be a TOO_MANY marker; find the real end.
        let end = if e == TOO_MANY {
            self.start[f + 1..]
                .iter()
                .copied()
                .find(|&x| x != TOO_MANY)
                .unwrap_or(self.lists.len() as u32)
        } else {
            e
        };
        for &k in &self.lists[s as usize..end as usize] {
            if super::bvh::ray_triangle(
                self.tris[k as usize].v0,
                self.tris[k as usize].e1,
                self.tris[k as usize].e2,
                origin,
                dir,
                t_max,
            )
            .is_some()
            {
                return LocalVisibility::Blocked;
            }
        }
        LocalVisibility::Clear
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::{Bvh, box_mesh, pose_from, sphere_mesh};
    use nalgebra::Vector3;

    #[test]
    fn convex_meshes_have_empty_lists_and_concave_ones_agree_with_the_bvh() {
        let sphere = sphere_mesh(0.05, 0.01);
        let view = ViewRegion {
            x_m: [-0.2, 0.2],
            y_m: [-0.2, 0.2],
            z_m: 0.5,
        };
        let occ = FrontOccluders::build(&sphere, &view, 1e-4, 32);
        assert!(occ.lists.is_empty() && occ.overflowing() == 0);

        // An L of two boxes: the inner corner shadows itself.
        let mut l = box_mesh([0.1, 0.02, 0.02], 0.01);
        l.append(
            &box_mesh([0.02, 0.02, 0.08], 0.01)
                .transformed(&pose_from([0.04, 0.0, 0.05], [0.0; 3])),
        );
        let occ = FrontOccluders::build(&l, &view, 2e-4, 10_000);
        let bvh = Bvh::build(&l);
        let mut checked = 0;
        for f in 0..l.triangles.len() {
            let [a, b, c] = l.corners(f);
            let n = (b - a).cross(&(c - a)).normalize();
            let p = (a + b + c) / 3.0 + n * 1e-4;
            // Rays to points of the view region.
            for target in [
                [-0.2f64, -0.2],
                [0.2, 0.1],
                [0.0, 0.0],
                [0.15, -0.05],
                [-0.1, 0.2],
            ] {
                let t = Vector3::new(target[0], target[1], 0.5);
                let v = t - p;
                let len = v.norm();
                let u = (v / len).map(|x| x as f32);
                if (n.x as f32) * u[0] + (n.y as f32) * u[1] + (n.z as f32) * u[2] <= 0.0 {
                    continue;
                }
                let o = [p.x as f32, p.y as f32, p.z as f32];
                let local = occ.test(f as u32, o, [u[0], u[1], u[2]], len as f32);
                assert_ne!(local, LocalVisibility::Unknown);
                let want = bvh.occluded(o, [u[0], u[1], u[2]], len as f32);
                assert_eq!(local == LocalVisibility::Blocked, want, "face {f}");
                checked += 1;
            }
        }
        assert!(checked > 100);
    }
}
