//! Turning a placed mesh into scatterers: specular surface samples, diffuse samples and edge
//! samples.
//!
//! - **Normals.** Each triangle corner gets the area-weighted mean of the normals of the faces
//!   around that vertex whose normal is within the crease angle of its own face. Smooth parts
//!   (a sphere, a scanned apple) are shaded smoothly; creases (a box edge) stay sharp.
//! - **Specular samples.** Each triangle is split into n² similar sub-triangles; one sample sits at
//!   each sub-triangle's centroid and carries its area and the interpolated normal. Centroids of
//!   two sub-triangles sharing an edge lie two thirds of a median apart, so n is the smallest
//!   integer for which the longest sub-triangle median is ≤ 1.5·spacing: neighbouring samples are
//!   then at most `spacing` apart. With the default spacing of λ/4 that is about one sample per
//!   (λ/4)².
//! - **Diffuse samples.** One sample per `spacing²` of area (λ² by default), placed by systematic
//!   area sampling at a uniformly random point of the triangle where each cell boundary falls.
//!   Diffuse scattering is incoherent, so only its mean power per area matters, not λ/4 phase
//!   sampling.
//! - **Edges.** A mesh edge is sharp when it has one face (a free rim, e.g. a plate), more than
//!   two, or two faces whose normals differ by more than the crease angle. Sharp edges are cut
//!   into pieces no longer than `spacing`.

use std::collections::HashMap;

use nalgebra::Vector3;

use crate::geometry::TriMesh;
use crate::signal::Rng;

/// Samples of one triangle, for culling: bounding sphere and normal cone.
#[derive(Debug, Clone, Copy)]
pub struct Cluster {
    pub centre: [f32; 3],
    pub radius_m: f32,
    pub axis: [f32; 3],
    /// Cosine of the normal cone's half-angle.
    pub cos_half_angle: f32,
    /// Largest curvature across the triangle (normal turn per metre between its corners).
    pub curvature_per_m: f32,
    pub first: u32,
    pub count: u32,
    /// The mesh triangle these samples lie on.
    pub triangle: u32,
}

/// Surface samples in structure-of-arrays form.
#[derive(Debug, Clone, Default)]
pub struct Samples {
    pub position: Vec<[f32; 3]>,
    /// Shading normal (interpolated across smooth parts).
    pub normal: Vec<[f32; 3]>,
    /// Normal of the flat triangle the sample lies on.
    pub face_normal: Vec<[f32; 3]>,
    /// Index of that triangle in its mesh.
    pub triangle: Vec<u32>,
    pub area_m2: Vec<f32>,
}

fn f32v(v: Vector3<f64>) -> [f32; 3] {
    [v.x as f32, v.y as f32, v.z as f32]
}

impl Samples {
    fn push(&mut self, p: Vector3<f64>, n: Vector3<f64>, face: (Vector3<f64>, usize), area: f64) {
        self.position.push(f32v(p));
        self.normal.push(f32v(n));
        self.face_normal.push(f32v(face.0));
        self.triangle.push(face.1 as u32);
        self.area_m2.push(area as f32);
    }

    /// Appends another set.
    pub fn append(&mut self, other: Samples) {
        self.position.extend(other.position);
        self.normal.extend(other.normal);
        self.face_normal.extend(other.face_normal);
        self.triangle.extend(other.triangle);
        self.area_m2.extend(other.area_m2);
    }

    pub fn len(&self) -> usize {
        self.position.len()
    }

    pub fn is_empty(&self) -> bool {
        self.position.is_empty()
    }
}

/// A piece of a sharp edge.
#[derive(Debug, Clone, Copy)]
pub struct EdgeSample {
    pub position: [f32; 3],
    pub length_m: f32,
    /// Normals of the faces meeting at the edge (equal for a free rim).
    pub n1: [f32; 3],
    pub n2: [f32; 3],
    /// Whether the wedge is convex (exterior = seen by either face) or concave (exterior = seen
    /// by both faces). A free rim counts as convex.
    pub convex: bool,
    /// The mesh triangles of `n1` and `n2`.
    pub faces: [u32; 2],
}

/// Per-triangle corner normals with crease handling.
pub fn corner_normals(mesh: &TriMesh, crease_deg: f64) -> Vec<[Vector3<f64>; 3]> {
    let faces: Vec<(Vector3<f64>, f64)> = (0..mesh.triangles.len())
        .map(|i| {
            let [a, b, c] = mesh.corners(i);
            let cr = (b - a).cross(&(c - a));
            let area = 0.5 * cr.norm();
            (cr.try_normalize(0.0).unwrap_or_else(Vector3::z), area)
        })
        .collect();
    let mut around: Vec<Vec<u32>> = vec![Vec::new(); mesh.vertices_m.len()];
    for (f, t) in mesh.triangles.iter().enumerate() {
        for &v in t {
            around[v as usize].push(f as u32);
        }
    }
    let cos_crease = crease_deg.to_radians().cos();
    mesh.triangles
        .iter()
        .enumerate()
        .map(|(f, t)| {
            let nf = faces[f].0;
            t.map(|v| {
                let mut sum = Vector3::zeros();
                for &g in &around[v as usize] {
                    let (ng, area) = faces[g as usize];
                    if ng.dot(&nf) >= cos_crease {
                        sum += ng * area;
                    }
                }
                sum.try_normalize(0.0).unwrap_or(nf)
            })
        })
        .collect()
}

/// Number of subdivisions so that the longest sub-triangle median is ≤ 1.5·spacing.
fn subdivisions(corners: &[Vector3<f64>; 3], spacing_m: f64) -> usize {
    let [a, b, c] = corners;
    let longest_median = [(a, b, c), (b, c, a), (c, a, b)]
        .iter()
        .map(|(p, q, r)| (*p - (*q + *r) / 2.0).norm())
        .fold(0.0, f64::max);
    ((longest_median / (1.5 * spacing_m)).ceil() as usize).max(1)
}

/// Samples every triangle at `spacing_m`; returns the samples and one cluster per triangle.
pub fn sample_surface(
    mesh: &TriMesh,
    normals: &[[Vector3<f64>; 3]],
    spacing_m: f64,
) -> (Samples, Vec<Cluster>) {
    let mut samples = Samples::default();
    let mut clusters = Vec::with_capacity(mesh.triangles.len());
    for (f, corner_n) in normals.iter().enumerate() {
        let corners = mesh.corners(f);
        let [a, b, c] = corners;
        let cr = (b - a).cross(&(c - a));
        let area = 0.5 * cr.norm();
        if area <= 0.0 {
            continue;
        }
        let face_n = cr / (2.0 * area);
        let n = subdivisions(&corners, spacing_m);
        let first = samples.len() as u32;
        let sub_area = area / (n * n) as f64;
        let mut emit = |bu: f64, bv: f64| {
            // (bu, bv) are barycentric coordinates of the centroid along b and c.
            let p = a + (b - a) * bu + (c - a) * bv;
            let nrm = interpolated_normal(corner_n, bu, bv, face_n);
            samples.push(p, nrm, (face_n, f), sub_area);
        };
        let nf = n as f64;
        for i in 0..n {
            for j in 0..n - i {
                // Upward sub-triangle (i,j),(i+1,j),(i,j+1).
                emit((i as f64 + 1.0 / 3.0) / nf, (j as f64 + 1.0 / 3.0) / nf);
                if i + j + 1 < n {
                    // Downward sub-triangle (i+1,j),(i+1,j+1),(i,j+1).
                    emit((i as f64 + 2.0 / 3.0) / nf, (j as f64 + 2.0 / 3.0) / nf);
                }
            }
        }
        let centre = (a + b + c) / 3.0;
        let radius = [a, b, c]
            .iter()
            .map(|p| (p - centre).norm())
            .fold(0.0, f64::max);
        let cos_half = corner_n
            .iter()
            .map(|cn| cn.dot(&face_n))
            .fold(1.0, f64::min)
            .clamp(-1.0, 1.0);
        let corners_p = [a, b, c];
        let curvature = [(0, 1), (1, 2), (2, 0)]
            .iter()
            .map(|&(i, j)| {
                let turn = corner_n[i].dot(&corner_n[j]).clamp(-1.0, 1.0).acos();
                turn / (corners_p[i] - corners_p[j]).norm().max(1e-12)
            })
            .fold(0.0, f64::max);
        clusters.push(Cluster {
            centre: [centre.x as f32, centre.y as f32, centre.z as f32],
            radius_m: radius as f32,
            axis: [face_n.x as f32, face_n.y as f32, face_n.z as f32],
            cos_half_angle: cos_half as f32,
            curvature_per_m: curvature as f32,
            triangle: f as u32,
            first,
            count: samples.len() as u32 - first,
        });
    }
    (samples, clusters)
}

fn interpolated_normal(
    corner_n: &[Vector3<f64>; 3],
    bu: f64,
    bv: f64,
    face: Vector3<f64>,
) -> Vector3<f64> {
    (corner_n[0] * (1.0 - bu - bv) + corner_n[1] * bu + corner_n[2] * bv)
        .try_normalize(0.0)
        .unwrap_or(face)
}

/// One sample per `spacing_m²` of area, by systematic area sampling over the triangles; each
/// sample carries an equal share of the total area.
pub fn sample_by_area(
    mesh: &TriMesh,
    normals: &[[Vector3<f64>; 3]],
    spacing_m: f64,
    rng: &mut Rng,
) -> Samples {
    let cell = spacing_m * spacing_m;
    let mut samples = Samples::default();
    let mut next = rng.uniform() * cell;
    let mut walked = 0.0;
    for (f, corner_n) in normals.iter().enumerate() {
        let [a, b, c] = mesh.corners(f);
        let cr = (b - a).cross(&(c - a));
        let area = 0.5 * cr.norm();
        if area <= 0.0 {
            continue;
        }
        let face = cr / (2.0 * area);
        walked += area;
        while next < walked {
            next += cell;
            // A uniform point of the triangle.
            let (r1, r2) = (rng.uniform().sqrt(), rng.uniform());
            let (bu, bv) = (r1 * (1.0 - r2), r1 * r2);
            let p = a + (b - a) * bu + (c - a) * bv;
            samples.push(
                p,
                interpolated_normal(corner_n, bu, bv, face),
                (face, f),
                cell,
            );
        }
    }
    let share = (walked / samples.len().max(1) as f64) as f32;
    samples.area_m2.fill(share);
    samples
}

/// Cuts the sharp edges of `mesh` into pieces no longer than `spacing_m`.
pub fn sample_edges(mesh: &TriMesh, crease_deg: f64, spacing_m: f64) -> Vec<EdgeSample> {
    let mut edges: HashMap<(u32, u32), Vec<u32>> = HashMap::new();
    for (f, t) in mesh.triangles.iter().enumerate() {
        for k in 0..3 {
            let (a, b) = (t[k], t[(k + 1) % 3]);
            edges
                .entry((a.min(b), a.max(b)))
                .or_default()
                .push(f as u32);
        }
    }
    let face_normal = |f: u32| {
        let [a, b, c] = mesh.corners(f as usize);
        (b - a)
            .cross(&(c - a))
            .try_normalize(0.0)
            .unwrap_or_else(Vector3::z)
    };
    let face_centre = |f: u32| {
        let [a, b, c] = mesh.corners(f as usize);
        (a + b + c) / 3.0
    };
    let cos_crease = crease_deg.to_radians().cos();
    let mut keys: Vec<_> = edges.keys().copied().collect();
    keys.sort_unstable();
    let mut out = Vec::new();
    for key in keys {
        let faces = &edges[&key];
        let (n1, n2, convex, pair) = match faces.as_slice() {
            [f] => {
                let n = face_normal(*f);
                (n, n, true, [*f, *f])
            }
            [f, g] => {
                let (n1, n2) = (face_normal(*f), face_normal(*g));
                if n1.dot(&n2) >= cos_crease {
                    continue;
                }
                let p = Vector3::from(mesh.vertices_m[key.0 as usize]);
                let convex = (face_centre(*g) - p).dot(&n1) <= 0.0;
                (n1, n2, convex, [*f, *g])
            }
            many => {
                let n = face_normal(many[0]);
                (n, n, true, [many[0], many[0]])
            }
        };
        let a = Vector3::from(mesh.vertices_m[key.0 as usize]);
        let b = Vector3::from(mesh.vertices_m[key.1 as usize]);
        let len = (b - a).norm();
        let pieces = ((len / spacing_m).ceil() as usize).max(1);
        for i in 0..pieces {
            let p = a + (b - a) * ((i as f64 + 0.5) / pieces as f64);
            let f32v = |v: Vector3<f64>| [v.x as f32, v.y as f32, v.z as f32];
            out.push(EdgeSample {
                position: f32v(p),
                length_m: (len / pieces as f64) as f32,
                n1: f32v(n1),
                n2: f32v(n2),
                convex,
                faces: pair,
            });
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::{box_mesh, plate_mesh, sphere_mesh};

    #[test]
    fn samples_cover_the_area_at_the_requested_spacing() {
        let plate = plate_mesh([0.05, 0.04], 0.004);
        let normals = corner_normals(&plate, 30.0);
        let spacing = 0.001;
        let (s, clusters) = sample_surface(&plate, &normals, spacing);
        let total: f64 = s.area_m2.iter().map(|&a| f64::from(a)).sum();
        assert!((total - 0.002).abs() < 1e-9);
        assert_eq!(clusters.len(), plate.triangles.len());
        let per_sq = s.len() as f64 * spacing * spacing / 0.002;
        println!("samples per spacing² = {per_sq:.2}");
        assert!((0.8..1.6).contains(&per_sq), "{per_sq}");
        // Every sample's nearest neighbour is within the spacing.
        let step = 37;
        for i in (0..s.len()).step_by(step) {
            let p = s.position[i];
            let nearest = (0..s.len())
                .filter(|&j| j != i)
                .map(|j| {
                    let q = s.position[j];
                    ((p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2) + (p[2] - q[2]).powi(2)).sqrt()
                })
                .fold(f32::INFINITY, f32::min);
            assert!(nearest <= spacing as f32 * 1.0001, "{nearest}");
        }
        assert!(s.normal.iter().all(|n| (n[2] - 1.0).abs() < 1e-6));
    }

    #[test]
    fn area_sampling_keeps_the_area() {
        let sphere = sphere_mesh(0.05, 0.003);
        let normals = corner_normals(&sphere, 30.0);
        let s = sample_by_area(&sphere, &normals, 0.004, &mut Rng::new(3));
        let total: f64 = s.area_m2.iter().map(|&a| f64::from(a)).sum();
        assert!((total - sphere.area_m2()).abs() / total < 1e-5);
        let expected = sphere.area_m2() / 0.004f64.powi(2);
        assert!(
            (s.len() as f64 - expected).abs() <= 1.0,
            "{} vs {expected}",
            s.len()
        );
    }

    #[test]
    fn sphere_normals_are_radial_and_box_edges_are_sharp() {
        let sphere = sphere_mesh(0.05, 0.003);
        let (s, _) = sample_surface(&sphere, &corner_normals(&sphere, 30.0), 0.002);
        let worst = s
            .position
            .iter()
            .zip(&s.normal)
            .map(|(p, n)| {
                let r = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
                (p[0] * n[0] + p[1] * n[1] + p[2] * n[2]) / r
            })
            .fold(1.0f32, f32::min);
        assert!(worst > 0.9995, "{worst}");
        assert!(sample_edges(&sphere, 30.0, 0.001).is_empty());

        let cube = box_mesh([0.02, 0.02, 0.02], 0.005);
        let edges = sample_edges(&cube, 30.0, 0.001);
        let total: f32 = edges.iter().map(|e| e.length_m).sum();
        assert!((total - 12.0 * 0.02).abs() < 1e-5, "{total}");
        assert!(edges.iter().all(|e| e.convex));
        let plate = plate_mesh([0.02, 0.01], 0.005);
        let rim: f32 = sample_edges(&plate, 30.0, 0.001)
            .iter()
            .map(|e| e.length_m)
            .sum();
        assert!((rim - 0.06).abs() < 1e-5, "{rim}");
    }
}
