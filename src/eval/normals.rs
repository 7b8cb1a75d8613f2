//! Normals for point clouds that have none (the baselines), as the paper does for them in §6.3.1:
//! the standard local-plane estimate, the direction of least variance of each point's nearest
//! neighbours (principal component analysis).

use nalgebra::{Matrix3, SymmetricEigen, Vector3};
use rayon::prelude::*;

use super::NearestNeighbours;

/// Unit normals by PCA over each point's `k` nearest neighbours within `radius_m` (itself
/// included). Points with fewer than three such neighbours get NaN normals, which the metrics
/// skip. The sign is arbitrary; the cosine metric is sign-agnostic.
pub fn estimate_normals(points: &[[f64; 3]], k: usize, radius_m: f64) -> Vec<[f64; 3]> {
    if points.is_empty() {
        return Vec::new();
    }
    let index = NearestNeighbours::new(points, radius_m);
    points
        .par_iter()
        .map(|q| {
            let near = index.neighbours_within(q, radius_m);
            let near = &near[..near.len().min(k)];
            if near.len() < 3 {
                return [f64::NAN; 3];
            }
            let n = near.len() as f64;
            let mean = near
                .iter()
                .fold(Vector3::zeros(), |s, &(i, _)| s + Vector3::from(points[i]))
                / n;
            let cov = near.iter().fold(Matrix3::zeros(), |s, &(i, _)| {
                let d = Vector3::from(points[i]) - mean;
                s + d * d.transpose()
            }) / n;
            let eig = SymmetricEigen::new(cov);
            let (smallest, _) = eig
                .eigenvalues
                .iter()
                .enumerate()
                .min_by(|a, b| a.1.total_cmp(b.1))
                .unwrap_or((0, &0.0));
            let v = eig.eigenvectors.column(smallest);
            [v[0], v[1], v[2]]
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn points_on_a_tilted_plane_get_its_normal_and_a_sphere_gets_radial_normals() {
        // Plane z = 0.5·x, normal ∝ (−0.5, 0, 1).
        let mut plane = Vec::new();
        for i in 0..30 {
            for j in 0..30 {
                let (x, y) = (i as f64 * 0.002, j as f64 * 0.002);
                plane.push([x, y, 0.5 * x]);
            }
        }
        let want = Vector3::new(-0.5, 0.0, 1.0).normalize();
        for n in estimate_normals(&plane, 20, 0.01) {
            assert!(Vector3::from(n).dot(&want).abs() > 0.999, "{n:?}");
        }
        // Sphere of 5 cm: the local plane's normal is radial to within the patch's curvature.
        let mut sphere = Vec::new();
        for i in 0..60 {
            for j in 0..120 {
                let (t, p) = (
                    std::f64::consts::PI * (i as f64 + 0.5) / 60.0,
                    std::f64::consts::TAU * j as f64 / 120.0,
                );
                sphere.push([
                    0.05 * t.sin() * p.cos(),
                    0.05 * t.sin() * p.sin(),
                    0.05 * t.cos(),
                ]);
            }
        }
        let normals = estimate_normals(&sphere, 16, 0.01);
        let worst = sphere
            .iter()
            .zip(&normals)
            .map(|(p, n)| Vector3::from(*p).normalize().dot(&Vector3::from(*n)).abs())
            .fold(1.0f64, f64::min);
        assert!(worst > 0.99, "{worst}");
        // Isolated points have none.
        let lone = estimate_normals(&[[0.0; 3], [1.0, 0.0, 0.0]], 10, 0.01);
        assert!(lone.iter().all(|n| n[0].is_nan()));
    }
}
