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
use super::vec3::{cross, dot, sub};

/// Where every ray ends: an axis-aligned rectangle in a horizontal plane (the antennas).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ViewRegion {
    pub x_m: [f64; 2],
    pub y_m: [f64; 2],
    pub z_m: f64,
}

/// Lanes of a [`Block`].
const LANES: usize = 8;

/// Eight candidate triangles, component-major, so that one ray meets all eight in a few vector
/// operations. Unused lanes hold a degenerate triangle, which no ray meets.
#[derive(Debug, Clone, Copy, Default)]
struct Block {
    /// First vertex, then the edges to the second and third: `[component][lane]`.
    v0: [[f32; LANES]; 3],
    e1: [[f32; LANES]; 3],
    e2: [[f32; LANES]; 3],
}

/// Candidate occluders of every triangle of one mesh.
#[derive(Debug, Clone, Default)]
pub struct FrontOccluders {
    /// `blocks[start[i]..start[i + 1]]` hold triangle i's candidates; `u32::MAX` in `start[i]`
    /// marks a list that was too long.
    start: Vec<u32>,
    blocks: Vec<Block>,
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
        let corners_f32 = |f: usize| {
            mesh.corners(f)
                .map(|v| [v.x as f32, v.y as f32, v.z as f32])
        };
        let mut start = Vec::with_capacity(per_triangle.len() + 1);
        let mut blocks = Vec::new();
        for entry in &per_triangle {
            let Some(list) = entry else {
                start.push(TOO_MANY);
                continue;
            };
            start.push(blocks.len() as u32);
            for chunk in list.chunks(LANES) {
                let mut b = Block::default();
                for (lane, &t) in chunk.iter().enumerate() {
                    let [a, p, q] = corners_f32(t as usize);
                    for k in 0..3 {
                        b.v0[k][lane] = a[k];
                        b.e1[k][lane] = p[k] - a[k];
                        b.e2[k][lane] = q[k] - a[k];
                    }
                }
                blocks.push(b);
            }
        }
        start.push(blocks.len() as u32);
        FrontOccluders { start, blocks }
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
                .unwrap_or(self.blocks.len() as u32)
        } else {
            e
        };
        let Some(blocks) = self.blocks.get(s as usize..end as usize) else {
            return LocalVisibility::Unknown;
        };
        if any_hit(blocks, origin, dir, t_max) {
            LocalVisibility::Blocked
        } else {
            LocalVisibility::Clear
        }
    }
}

/// Whether the ray meets any triangle of `blocks`.
fn any_hit(blocks: &[Block], origin: [f32; 3], dir: [f32; 3], t_max: f32) -> bool {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU supports AVX2 (checked just above).
        return unsafe { any_hit_avx2(blocks, origin, dir, t_max) };
    }
    blocks.iter().any(|b| block_hit(b, origin, dir, t_max))
}

/// [`any_hit`] compiled for AVX2.
///
/// # Safety
/// The CPU must support AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn any_hit_avx2(blocks: &[Block], origin: [f32; 3], dir: [f32; 3], t_max: f32) -> bool {
    blocks.iter().any(|b| block_hit(b, origin, dir, t_max))
}

/// Möller–Trumbore on eight triangles at once: the same arithmetic, in the same order, and the
/// same acceptance tests as [`super::bvh::ray_triangle`], lane by lane and without branches.
// The tests are joined with `&`, not `&&` or ranges, so that every lane runs the same code.
#[allow(clippy::manual_range_contains)]
#[inline(always)]
fn block_hit(b: &Block, o: [f32; 3], d: [f32; 3], t_max: f32) -> bool {
    let mut hit = [false; LANES];
    for (lane, h) in hit.iter_mut().enumerate() {
        let v0 = [b.v0[0][lane], b.v0[1][lane], b.v0[2][lane]];
        let e1 = [b.e1[0][lane], b.e1[1][lane], b.e1[2][lane]];
        let e2 = [b.e2[0][lane], b.e2[1][lane], b.e2[2][lane]];
        let p = cross(d, e2);
        let det = dot(e1, p);
        let inv = 1.0 / det;
        let s = sub(o, v0);
        let u = dot(s, p) * inv;
        let q = cross(s, e1);
        let v = dot(d, q) * inv;
        let t = dot(e2, q) * inv;
        *h = (det.abs() >= 1e-20)
            & (u >= 0.0)
            & (u <= 1.0)
            & (v >= 0.0)
            & (u + v <= 1.0)
            & (t > 0.0)
            & (t < t_max);
    }
    hit.iter().fold(false, |a, &h| a | h)
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
        assert!(occ.blocks.is_empty() && occ.overflowing() == 0);

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
