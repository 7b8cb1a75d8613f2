//! The relative signed distance function (RSDF) of one component: a scalar field f whose
//! gradient follows the estimated normal field (paper §3.2, Eq. 8), defined up to a constant.
//!
//! Two integrators:
//! - [`integrate_bfs`], the authors' single-path integral (docs/mmnorm-reference.md §4.3). It starts at
//!   the component voxel nearest the component's mean position and walks a breadth-first
//!   spanning tree in the neighbour order (−x, +y, +x, −y, +z, −z). Each step adds
//!   `voxel · (step · n̂(destination))`. The result depends on the seed, the order and every
//!   normal's noise along its one path.
//! - [`integrate_least_squares`] solves min Σ_edges (f_v − f_u − voxel·(step · (n̂_u + n̂_v)/2))²
//!   over every 6-neighbour edge inside the component. The normal equations are the graph
//!   Laplacian system L f = b, solved by conjugate gradients, with f = 0 at the same seed. It
//!   averages over all paths, so noise in one normal does not propagate along a branch. The
//!   iterations run in parallel over the unknowns (the Laplacian as a gather over each
//!   unknown's neighbours, dot products summed in fixed chunks), and give the same bits on any
//!   number of threads.
//!
//! `tests::least_squares_beats_bfs_on_noisy_sphere_normals` compares the two on a noisy
//! sphere; least squares is the default.
//!
//! Grids are C-ordered (x, y, z): flat index = (x·NY + y)·NZ + z. f increases along the normals
//! (towards the radar for surfaces seen from above). Values outside the component are NaN.

use rayon::prelude::*;

/// The BFS neighbour order of the authors' code, as (dx, dy, dz).
const BFS_ORDER: [[i64; 3]; 6] = [
    [-1, 0, 0],
    [0, 1, 0],
    [1, 0, 0],
    [0, -1, 0],
    [0, 0, 1],
    [0, 0, -1],
];

/// One component of a normal field on a voxel grid.
#[derive(Debug, Clone, Copy)]
pub struct ComponentField<'a> {
    pub dims: [usize; 3],
    pub voxel_m: f64,
    /// Unit normal per voxel.
    pub normals: &'a [[f32; 3]],
    /// Component label per voxel; the component is the voxels equal to `label`.
    pub labels: &'a [u32],
    pub label: u32,
}

impl ComponentField<'_> {
    fn coords(&self, v: usize) -> [i64; 3] {
        let [_, ny, nz] = self.dims;
        [
            (v / (ny * nz)) as i64,
            ((v / nz) % ny) as i64,
            (v % nz) as i64,
        ]
    }

    fn index(&self, c: [i64; 3]) -> Option<usize> {
        let [nx, ny, nz] = self.dims.map(|d| d as i64);
        (c[0] >= 0 && c[0] < nx && c[1] >= 0 && c[1] < ny && c[2] >= 0 && c[2] < nz)
            .then(|| ((c[0] * ny + c[1]) * nz + c[2]) as usize)
    }

    fn member(&self, v: usize) -> bool {
        self.labels[v] == self.label && self.normals[v].iter().all(|c| c.is_finite())
    }

    /// The component's voxels and the one nearest their mean position.
    fn voxels_and_seed(&self) -> Option<(Vec<usize>, usize)> {
        let voxels: Vec<usize> = (0..self.labels.len()).filter(|&v| self.member(v)).collect();
        let n = voxels.len() as f64;
        let mut mean = [0.0f64; 3];
        for &v in &voxels {
            let c = self.coords(v);
            for k in 0..3 {
                mean[k] += c[k] as f64 / n;
            }
        }
        let seed = voxels.iter().copied().min_by(|&a, &b| {
            let d = |v: usize| {
                let c = self.coords(v);
                (0..3).map(|k| (c[k] as f64 - mean[k]).powi(2)).sum::<f64>()
            };
            d(a).total_cmp(&d(b))
        })?;
        Some((voxels, seed))
    }

    /// The 6-neighbours of `v` inside the component, with their step.
    fn neighbours(&self, v: usize) -> impl Iterator<Item = (usize, [i64; 3])> + '_ {
        let c = self.coords(v);
        BFS_ORDER.iter().filter_map(move |s| {
            let w = self.index([c[0] + s[0], c[1] + s[1], c[2] + s[2]])?;
            self.member(w).then_some((w, *s))
        })
    }
}

/// Marks an unused slot of an unknown's neighbour list.
const NO_NEIGHBOUR: usize = usize::MAX;

/// Unknowns per partial sum of [`dot`]: the sums are formed in fixed chunks and added in
/// order, so the result does not depend on how many threads rayon runs.
const DOT_CHUNK: usize = 1 << 14;

/// Σ a·c, in parallel and reproducibly (see [`DOT_CHUNK`]).
fn dot(a: &[f64], c: &[f64]) -> f64 {
    let partial: Vec<f64> = a
        .par_chunks(DOT_CHUNK)
        .zip(c.par_chunks(DOT_CHUNK))
        .map(|(a, c)| a.iter().zip(c).map(|(p, q)| p * q).sum::<f64>())
        .collect();
    partial.iter().sum()
}

fn step_dot(step: [i64; 3], n: [f32; 3]) -> f64 {
    (0..3).map(|k| step[k] as f64 * f64::from(n[k])).sum()
}

/// The authors' breadth-first single-path integral (Eq. 8 along a spanning tree).
pub fn integrate_bfs(field: &ComponentField<'_>) -> Vec<f32> {
    let mut f = vec![f32::NAN; field.labels.len()];
    let Some((_, seed)) = field.voxels_and_seed() else {
        return f;
    };
    let mut value = vec![f64::NAN; field.labels.len()];
    value[seed] = 0.0;
    let mut queue = std::collections::VecDeque::from([seed]);
    while let Some(v) = queue.pop_front() {
        for (w, step) in field.neighbours(v) {
            if value[w].is_nan() {
                value[w] = value[v] + field.voxel_m * step_dot(step, field.normals[w]);
                queue.push_back(w);
            }
        }
    }
    for (o, v) in f.iter_mut().zip(&value) {
        *o = *v as f32;
    }
    f
}

/// Least-squares integration over every edge of the component (conjugate gradients on the
/// graph Laplacian), f = 0 at the seed. Stops at a relative residual of `tolerance` or after
/// `max_iterations`.
pub fn integrate_least_squares(
    field: &ComponentField<'_>,
    tolerance: f64,
    max_iterations: usize,
) -> Vec<f32> {
    let mut out = vec![f32::NAN; field.labels.len()];
    let Some((voxels, seed)) = field.voxels_and_seed() else {
        return out;
    };
    let mut slot = vec![usize::MAX; field.labels.len()];
    for (i, &v) in voxels.iter().enumerate() {
        slot[v] = i;
    }
    // Every edge (i, j) with f_j − f_i meant to equal g adds ±g to b and joins each unknown's
    // neighbours, so that the Laplacian is a gather per unknown, which rayon can share out,
    // instead of a scatter per edge, which it cannot.
    let m = voxels.len();
    let mut b = vec![0.0f64; m];
    let mut neighbours = vec![[NO_NEIGHBOUR; 6]; m];
    let link = |row: &mut [usize; 6], j: usize| {
        if let Some(free) = row.iter_mut().find(|k| **k == NO_NEIGHBOUR) {
            *free = j;
        }
    };
    for (i, &v) in voxels.iter().enumerate() {
        for (w, step) in field.neighbours(v) {
            let j = slot[w];
            if j > i {
                let n = [0, 1, 2].map(|k| 0.5 * (field.normals[v][k] + field.normals[w][k]));
                let g = field.voxel_m * step_dot(step, n);
                b[j] += g;
                b[i] -= g;
                link(&mut neighbours[i], j);
                link(&mut neighbours[j], i);
            }
        }
    }
    let laplacian = |x: &[f64], y: &mut [f64]| {
        y.par_iter_mut()
            .zip(neighbours.par_iter())
            .enumerate()
            .for_each(|(i, (y, row))| {
                *y = row
                    .iter()
                    .take_while(|&&j| j != NO_NEIGHBOUR)
                    .map(|&j| x[i] - x[j])
                    .sum();
            });
    };
    // Conjugate gradients from x = 0; b sums to zero, so the iterates stay orthogonal to the
    // constant null space.
    let mut x = vec![0.0f64; m];
    let mut r = b.clone();
    let mut p = r.clone();
    let mut ap = vec![0.0f64; m];
    let b_norm = dot(&b, &b).sqrt().max(1e-300);
    let mut rr = dot(&r, &r);
    for _ in 0..max_iterations {
        if rr.sqrt() <= tolerance * b_norm {
            break;
        }
        laplacian(&p, &mut ap);
        let alpha = rr / dot(&p, &ap).max(1e-300);
        x.par_iter_mut()
            .zip(r.par_iter_mut())
            .zip(p.par_iter().zip(ap.par_iter()))
            .for_each(|((x, r), (p, ap))| {
                *x += alpha * p;
                *r -= alpha * ap;
            });
        let rr_new = dot(&r, &r);
        let beta = rr_new / rr;
        rr = rr_new;
        p.par_iter_mut()
            .zip(r.par_iter())
            .for_each(|(p, r)| *p = r + beta * *p);
    }
    let origin = x[slot[seed]];
    for (i, &v) in voxels.iter().enumerate() {
        out[v] = (x[i] - origin) as f32;
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::signal::Rng;

    /// A spherical shell of radius 14–17 voxels (z ≥ centre) with radial normals, optionally
    /// perturbed.
    fn shell(noise_rad: f64, seed: u64) -> ([usize; 3], Vec<[f32; 3]>, Vec<u32>, Vec<f64>) {
        let dims = [40, 40, 24];
        let centre = [20.0, 20.0, 2.0];
        let mut rng = Rng::new(seed);
        let mut normals = vec![[f32::NAN; 3]; 40 * 40 * 24];
        let mut labels = vec![0u32; normals.len()];
        let mut exact = vec![f64::NAN; normals.len()];
        for x in 0..40 {
            for y in 0..40 {
                for z in 0..24 {
                    let d = [
                        x as f64 - centre[0],
                        y as f64 - centre[1],
                        z as f64 - centre[2],
                    ];
                    let r = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
                    if (14.0..17.0).contains(&r) && d[2] >= 0.0 {
                        let v = (x * 40 + y) * 24 + z;
                        let (a, b) = rng.normal_pair();
                        let (c, _) = rng.normal_pair();
                        let n = [
                            d[0] / r + noise_rad * a,
                            d[1] / r + noise_rad * b,
                            d[2] / r + noise_rad * c,
                        ];
                        let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
                        normals[v] = n.map(|c| (c / len) as f32);
                        labels[v] = 1;
                        exact[v] = r;
                    }
                }
            }
        }
        (dims, normals, labels, exact)
    }

    /// RMS error after removing the best constant offset, in voxels.
    fn rms_error(f: &[f32], exact: &[f64]) -> f64 {
        let pairs: Vec<(f64, f64)> = f
            .iter()
            .zip(exact)
            .filter(|(a, b)| a.is_finite() && b.is_finite())
            .map(|(a, b)| (f64::from(*a), *b))
            .collect();
        let offset = pairs.iter().map(|(a, b)| b - a).sum::<f64>() / pairs.len() as f64;
        (pairs
            .iter()
            .map(|(a, b)| (a + offset - b).powi(2))
            .sum::<f64>()
            / pairs.len() as f64)
            .sqrt()
    }

    /// RMS errors (voxels) of BFS and least squares on a shell with `noise_rad` normal noise.
    fn errors_of_both(noise_rad: f64, seed: u64) -> (f64, f64) {
        let (dims, normals, labels, exact) = shell(noise_rad, seed);
        let field = ComponentField {
            dims,
            voxel_m: 1.0,
            normals: &normals,
            labels: &labels,
            label: 1,
        };
        (
            rms_error(&integrate_bfs(&field), &exact),
            rms_error(&integrate_least_squares(&field, 1e-10, 5000), &exact),
        )
    }

    #[test]
    fn both_integrators_recover_a_clean_radial_field() {
        let (bfs, ls) = errors_of_both(0.0, 1);
        println!("clean shell: RMS error BFS {bfs:.3} voxels, least squares {ls:.3} voxels");
        assert!(ls < 0.1 && bfs < 0.6, "{ls} {bfs}");
    }

    /// `work` run on a pool of `threads` threads.
    fn on_threads<T: Send>(threads: usize, work: impl FnOnce() -> T + Send) -> T {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(work)
    }

    #[test]
    fn the_integral_is_the_same_on_any_number_of_threads() {
        // A slab of 48×48×12 voxels with noisy upward normals: 27 648 unknowns, so that `dot`
        // sums two chunks and the Laplacian's rows are shared out unevenly.
        let dims = [48, 48, 12];
        let mut rng = Rng::new(7);
        let normals: Vec<[f32; 3]> = (0..48 * 48 * 12)
            .map(|_| {
                let (a, b) = rng.normal_pair();
                let n = [0.2 * a, 0.2 * b, 1.0];
                let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
                n.map(|c| (c / len) as f32)
            })
            .collect();
        let labels = vec![1u32; normals.len()];
        let field = ComponentField {
            dims,
            voxel_m: 0.001,
            normals: &normals,
            labels: &labels,
            label: 1,
        };
        let on = |threads: usize| -> Vec<u32> {
            let f = on_threads(threads, || integrate_least_squares(&field, 1e-8, 2000));
            f.iter().map(|v| v.to_bits()).collect()
        };
        let one = on(1);
        assert!(one.iter().all(|&b| f32::from_bits(b).is_finite()));
        for threads in [2, 3] {
            assert!(on(threads) == one, "{threads} threads differ from one");
        }
    }

    #[test]
    fn dot_adds_its_chunks_in_order() {
        let a: Vec<f64> = (0..3 * DOT_CHUNK + 5)
            .map(|i| (i as f64 * 0.37).sin())
            .collect();
        let c: Vec<f64> = (0..a.len()).map(|i| 1.0 + (i % 7) as f64).collect();
        let reference: f64 = a.iter().zip(&c).map(|(p, q)| p * q).sum();
        let got = dot(&a, &c);
        assert!(
            (got - reference).abs() <= 1e-9 * reference.abs().max(1.0),
            "{got} {reference}"
        );
        let single = on_threads(1, || dot(&a, &c));
        assert_eq!(got.to_bits(), single.to_bits());
    }

    #[test]
    fn least_squares_beats_bfs_on_noisy_sphere_normals() {
        let (mut bfs_total, mut ls_total) = (0.0, 0.0);
        for seed in 1..=3 {
            let (bfs, ls) = errors_of_both(0.3, seed);
            println!(
                "noisy shell (0.3 rad), seed {seed}: RMS error BFS {bfs:.3} voxels, least squares {ls:.3} voxels"
            );
            bfs_total += bfs;
            ls_total += ls;
        }
        assert!(
            ls_total < 0.5 * bfs_total,
            "least squares {ls_total} vs BFS {bfs_total}"
        );
    }
}
