//! The point-scatterer model ([`Physics::PointScatterer`]), an independent second physics.
//!
//! Written from the description of the kind of simulator the mmNorm authors used, not from the
//! physical-optics model beside it, so that the reconstruction can be scored under physics it
//! was not tuned to:
//!
//! - **Surface samples** at `surface_spacing_m`, each on one face with that face's normal. A
//!   sample reflects from TX to RX only when the bisector of its two legs lies within
//!   `specular_cone_deg` of the normal; inside the cone it reflects fully, outside not at all.
//! - **Edge samples** at `edge_spacing_m` on every edge whose dihedral angle exceeds
//!   `edge_dihedral_deg` and on free rims. They radiate to every antenna they see.
//! - Every sample's amplitude is w/d, with d its round trip; no antenna pattern, no obliquity
//!   factor, no diffuse term. Visibility is a BVH shadow ray per sample and leg, as in the other
//!   model. The sheet, the point targets and the noise are shared with the other model.
//!
//! **Scale.** A surface sample of area A weighs `w = ρ·A·2/λ0` (per metre of reference range).
//! Summed over a mirror, `Σ w·e^{jk·2r}/(2r)` has the stationary-phase value `1/2` at every
//! range: a plate returns what image theory gives for a mirror 1 m away, and the 1/d law keeps
//! it there at any distance. An edge sample weighs `edge_strength` surface samples of area
//! `surface_spacing_m²`, scaled by its share of `edge_spacing_m`: all points are equal.

use num_complex::Complex32;

use super::{Ctx, Leg};
use crate::geometry::TriMesh;
use crate::geometry::vec3::{add, dot};
use crate::signal::ToneAccumulator;
use crate::sim::scene::PointScatterer;
use crate::sim::surface::{self, Cluster, EdgeSample, Samples};

/// The point-scatterer model's scatterers.
#[derive(Default)]
pub(super) struct PointScatterers {
    pub samples: Samples,
    /// w per surface sample.
    pub weight: Vec<f32>,
    pub clusters: Vec<Cluster>,
    pub cluster_object: Vec<u16>,
    /// Cosine of the specular cone's half-angle.
    pub cos_cone: f32,
    /// Cosine and sine of the cone's half-angle, for culling whole clusters.
    pub cluster_limit: (f32, f32),
    pub edges: Vec<EdgeSample>,
    pub edge_weight: Vec<f32>,
    pub edge_object: Vec<u16>,
}

impl PointScatterers {
    pub fn new(model: &PointScatterer) -> Self {
        let cone = model.specular_cone_deg.to_radians();
        PointScatterers {
            cos_cone: cone.cos() as f32,
            cluster_limit: (cone.cos() as f32, cone.sin() as f32),
            ..Default::default()
        }
    }

    /// Samples one object's mesh; `reflectivity` and `edge` are its material's scales.
    pub fn add_object(
        &mut self,
        model: &PointScatterer,
        mesh: &TriMesh,
        id: u16,
        lambda0_m: f64,
        (reflectivity, edge): (f64, f64),
    ) {
        let face_normals: Vec<[nalgebra::Vector3<f64>; 3]> = (0..mesh.triangles.len())
            .map(|f| {
                let [a, b, c] = mesh.corners(f);
                let n = (b - a)
                    .cross(&(c - a))
                    .try_normalize(0.0)
                    .unwrap_or_else(nalgebra::Vector3::z);
                [n; 3]
            })
            .collect();
        let per_area = 2.0 / lambda0_m;
        let base = self.samples.len() as u32;
        let (samples, clusters) =
            surface::sample_surface(mesh, &face_normals, model.surface_spacing_m);
        self.weight.extend(
            samples
                .area_m2
                .iter()
                .map(|&a| (reflectivity * f64::from(a) * per_area) as f32),
        );
        self.samples.append(samples);
        for mut c in clusters {
            c.first += base;
            self.clusters.push(c);
            self.cluster_object.push(id);
        }
        if edge > 0.0 && model.edge_strength > 0.0 {
            let edges = surface::sample_edges(mesh, model.edge_dihedral_deg, model.edge_spacing_m);
            let point = model.edge_strength * edge * model.surface_spacing_m.powi(2) * per_area;
            self.edge_weight.extend(
                edges
                    .iter()
                    .map(|e| (point * f64::from(e.length_m) / model.edge_spacing_m) as f32),
            );
            self.edge_object
                .extend(std::iter::repeat_n(id, edges.len()));
            self.edges.extend(edges);
        }
    }

    pub fn surface_samples(&self) -> usize {
        self.samples.len()
    }
}

impl Ctx<'_> {
    /// Sums the point scatterers' returns for one raster position into `out` (see
    /// [`Ctx::position`] for the arguments); returns the number of contributions.
    pub(super) fn point_scatterers(
        &self,
        ps: &PointScatterers,
        tx: [f32; 3],
        rxs: &[[f32; 3]],
        (centre, spread): ([f32; 3], f32),
        out: &mut [ToneAccumulator],
    ) -> u64 {
        let mut count = 0u64;
        let rx_leg = |p: [f32; 3], rx: [f32; 3], tx_leg: &Leg| {
            if rx == tx { *tx_leg } else { self.leg(p, rx) }
        };
        for (c, &own) in ps.clusters.iter().zip(&ps.cluster_object) {
            if !super::cluster_in_view(c, ps.cluster_limit, centre, spread) {
                continue;
            }
            let faces = [(own, c.triangle, c.axis)];
            for i in c.first as usize..(c.first + c.count) as usize {
                let p = ps.samples.position[i];
                let n = ps.samples.normal[i];
                let t = self.leg(p, tx);
                if dot(n, t.u) <= 0.0 {
                    continue;
                }
                let mut tx_clear: Option<bool> = None;
                for (k, &rx) in rxs.iter().enumerate() {
                    let r = rx_leg(p, rx, &t);
                    let h = add(t.u, r.u);
                    let hh = dot(h, h);
                    let nh = dot(n, h);
                    // cos θ_b ≥ cos cone, without the square root or the division.
                    if nh <= 0.0 || nh * nh < ps.cos_cone * ps.cos_cone * hh {
                        continue;
                    }
                    let amp = ps.weight[i] * t.factor * r.factor / (t.d + r.d);
                    match self.admit(amp, p, n, (&t, &r, rx == tx), &faces, &mut tx_clear) {
                        None => break,
                        Some(false) => continue,
                        Some(true) => {}
                    }
                    out[k].add(Complex32::new(amp, 0.0), super::path_m(&t, &r));
                    count += 1;
                }
            }
        }

        for ((e, &weight), &own) in ps.edges.iter().zip(&ps.edge_weight).zip(&ps.edge_object) {
            let p = e.position;
            let t = self.leg(p, tx);
            let offset_dir = super::edge_offset_dir(e, t.u);
            let faces = [(own, e.faces[0], e.n1), (own, e.faces[1], e.n2)];
            let mut tx_clear: Option<bool> = None;
            for (k, &rx) in rxs.iter().enumerate() {
                let r = rx_leg(p, rx, &t);
                let amp = weight * t.factor * r.factor / (t.d + r.d);
                match self.admit(
                    amp,
                    p,
                    offset_dir,
                    (&t, &r, rx == tx),
                    &faces,
                    &mut tx_clear,
                ) {
                    None => break,
                    Some(false) => continue,
                    Some(true) => {}
                }
                out[k].add(Complex32::new(amp, 0.0), super::path_m(&t, &r));
                count += 1;
            }
        }
        count
    }
}
