//! Ground truth as a depth camera above the scene would see it: the first hit of vertical rays
//! on a 1 mm grid (the paper's RealSense ground truth, §5).

use rayon::prelude::*;

use super::scene::{ObjectGeometry, Scene};
use crate::geometry::{Bvh, TriMesh};

/// Grid pitch of the top-view truth, metres.
pub const TOP_GRID_M: f64 = 1e-3;

/// Casts rays straight down on a `grid_m` lattice (cell centres at (k + ½)·grid_m) over the
/// mesh's footprint and returns the first hit of each ray that hits.
pub fn top_surface(mesh: &TriMesh, grid_m: f64) -> Vec<[f64; 3]> {
    top_surface_with_normals(mesh, grid_m).0
}

/// Every surface object of `scene` merged into one mesh, in the scene's order: the mesh its
/// truth is taken from (the cardboard sheet is not part of it).
pub fn scene_mesh(scene: &Scene) -> TriMesh {
    let mut mesh = TriMesh::default();
    for o in &scene.objects {
        if let ObjectGeometry::Surface(m) = &o.geometry {
            mesh.append(m);
        }
    }
    mesh
}

/// [`top_surface`] with the unit normal of each hit triangle, turned to face up.
pub fn top_surface_with_normals(mesh: &TriMesh, grid_m: f64) -> (Vec<[f64; 3]>, Vec<[f64; 3]>) {
    top_surface_in(mesh, &Bvh::build(mesh), grid_m)
}

/// [`top_surface_with_normals`] with `mesh`'s hierarchy already built.
pub fn top_surface_in(mesh: &TriMesh, bvh: &Bvh, grid_m: f64) -> (Vec<[f64; 3]>, Vec<[f64; 3]>) {
    let Some((lo, hi)) = mesh.bounds() else {
        return (Vec::new(), Vec::new());
    };
    let kx0 = (lo[0] / grid_m).floor() as i64;
    let kx1 = (hi[0] / grid_m).ceil() as i64;
    let ky0 = (lo[1] / grid_m).floor() as i64;
    let ky1 = (hi[1] / grid_m).ceil() as i64;
    let z_start = hi[2] + 0.01;
    let depth = (hi[2] - lo[2] + 0.02) as f32;
    (ky0..ky1)
        .into_par_iter()
        .flat_map_iter(|ky| {
            (kx0..kx1).filter_map(move |kx| {
                let x = (kx as f64 + 0.5) * grid_m;
                let y = (ky as f64 + 0.5) * grid_m;
                bvh.closest(
                    [x as f32, y as f32, z_start as f32],
                    [0.0, 0.0, -1.0],
                    depth,
                )
                .map(|h| {
                    let [a, b, c] = mesh.corners(h.triangle as usize);
                    let n = (b - a)
                        .cross(&(c - a))
                        .try_normalize(0.0)
                        .unwrap_or_default();
                    let n = if n.z < 0.0 { -n } else { n };
                    ([x, y, z_start - f64::from(h.t)], [n.x, n.y, n.z])
                })
            })
        })
        .unzip()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::{pose_from, sphere_mesh};

    #[test]
    fn sphere_top_view_is_the_upper_hemisphere() {
        let mesh = sphere_mesh(0.02, 0.001).transformed(&pose_from([0.0, 0.0, 0.05], [0.0; 3]));
        let top = top_surface(&mesh, TOP_GRID_M);
        // About π r² / grid² rays hit.
        let expected = std::f64::consts::PI * 0.02f64.powi(2) / 1e-6;
        assert!(
            (top.len() as f64 - expected).abs() / expected < 0.03,
            "{}",
            top.len()
        );
        for p in &top {
            let r = (p[0] * p[0] + p[1] * p[1] + (p[2] - 0.05).powi(2)).sqrt();
            assert!((r - 0.02).abs() < 2e-4 && p[2] >= 0.05 - 1e-6, "{p:?}");
        }
    }
}
