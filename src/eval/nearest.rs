//! Exact nearest-neighbour queries on a uniform grid of buckets.

use std::collections::HashMap;

/// Points bucketed by a cubic cell; queries search rings of cells outward until no closer point
/// can exist.
pub struct NearestNeighbours<'a> {
    points: &'a [[f64; 3]],
    cell_m: f64,
    buckets: HashMap<[i64; 3], Vec<u32>>,
    /// Cell-index bounds of all points, which limit the ring search.
    lo: [i64; 3],
    hi: [i64; 3],
}

impl<'a> NearestNeighbours<'a> {
    /// Buckets `points` (not empty) into cells of `cell_m`.
    pub fn new(points: &'a [[f64; 3]], cell_m: f64) -> NearestNeighbours<'a> {
        let cell_m = if cell_m.is_finite() && cell_m > 0.0 {
            cell_m
        } else {
            1.0
        };
        let mut buckets: HashMap<[i64; 3], Vec<u32>> = HashMap::new();
        let mut lo = [i64::MAX; 3];
        let mut hi = [i64::MIN; 3];
        for (i, p) in points.iter().enumerate() {
            let c = p.map(|x| (x / cell_m).floor() as i64);
            for k in 0..3 {
                lo[k] = lo[k].min(c[k]);
                hi[k] = hi[k].max(c[k]);
            }
            buckets.entry(c).or_default().push(i as u32);
        }
        NearestNeighbours {
            points,
            cell_m,
            buckets,
            lo,
            hi,
        }
    }

    fn distance(&self, i: u32, q: &[f64; 3]) -> f64 {
        let p = self.points[i as usize];
        ((p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2) + (p[2] - q[2]).powi(2)).sqrt()
    }

    /// The nearest point's index and distance (`(0, ∞)` for an empty set).
    pub fn nearest(&self, q: &[f64; 3]) -> (usize, f64) {
        let c = q.map(|x| (x / self.cell_m).floor() as i64);
        // Rings beyond this cover every bucket.
        let max_ring = (0..3)
            .map(|k| (c[k] - self.lo[k]).abs().max((self.hi[k] - c[k]).abs()))
            .max()
            .unwrap_or(0);
        let mut best = (0usize, f64::INFINITY);
        for ring in 0..=max_ring {
            // Any point in ring r is at least (r − 1)·cell away.
            if best.1 < (ring - 1).max(0) as f64 * self.cell_m {
                break;
            }
            for dx in -ring..=ring {
                for dy in -ring..=ring {
                    for dz in -ring..=ring {
                        if dx.abs().max(dy.abs()).max(dz.abs()) != ring {
                            continue;
                        }
                        if let Some(bucket) = self.buckets.get(&[c[0] + dx, c[1] + dy, c[2] + dz]) {
                            for &i in bucket {
                                let d = self.distance(i, q);
                                if d < best.1 {
                                    best = (i as usize, d);
                                }
                            }
                        }
                    }
                }
            }
        }
        best
    }

    /// Whether some point lies strictly closer than `radius_m` (≤ one cell) to `q`.
    pub fn within(&self, q: &[f64; 3], radius_m: f64) -> bool {
        let c = q.map(|x| (x / self.cell_m).floor() as i64);
        let reach = (radius_m / self.cell_m).ceil() as i64;
        for dx in -reach..=reach {
            for dy in -reach..=reach {
                for dz in -reach..=reach {
                    if let Some(bucket) = self.buckets.get(&[c[0] + dx, c[1] + dy, c[2] + dz])
                        && bucket.iter().any(|&i| self.distance(i, q) < radius_m)
                    {
                        return true;
                    }
                }
            }
        }
        false
    }

    /// The indices and distances of every point closer than `radius_m` to `q`, nearest first.
    pub fn neighbours_within(&self, q: &[f64; 3], radius_m: f64) -> Vec<(usize, f64)> {
        let c = q.map(|x| (x / self.cell_m).floor() as i64);
        let reach = (radius_m / self.cell_m).ceil() as i64;
        let mut found = Vec::new();
        for dx in -reach..=reach {
            for dy in -reach..=reach {
                for dz in -reach..=reach {
                    if let Some(bucket) = self.buckets.get(&[c[0] + dx, c[1] + dy, c[2] + dz]) {
                        found.extend(
                            bucket
                                .iter()
                                .map(|&i| (i as usize, self.distance(i, q)))
                                .filter(|&(_, d)| d < radius_m),
                        );
                    }
                }
            }
        }
        found.sort_by(|a, b| a.1.total_cmp(&b.1).then(a.0.cmp(&b.0)));
        found
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::signal::Rng;

    #[test]
    fn radius_search_agrees_with_brute_force() {
        let mut rng = Rng::new(4);
        let pts: Vec<[f64; 3]> = (0..400)
            .map(|_| {
                [
                    rng.uniform() * 0.1,
                    rng.uniform() * 0.1,
                    rng.uniform() * 0.02,
                ]
            })
            .collect();
        let nn = NearestNeighbours::new(&pts, 0.004);
        for q in pts.iter().take(50) {
            let got = nn.neighbours_within(q, 0.011);
            let mut want: Vec<(usize, f64)> = pts
                .iter()
                .enumerate()
                .map(|(i, p)| {
                    (
                        i,
                        ((p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2) + (p[2] - q[2]).powi(2))
                            .sqrt(),
                    )
                })
                .filter(|&(_, d)| d < 0.011)
                .collect();
            want.sort_by(|a, b| a.1.total_cmp(&b.1).then(a.0.cmp(&b.0)));
            assert_eq!(got, want);
        }
    }

    #[test]
    fn grid_search_agrees_with_brute_force() {
        let mut rng = Rng::new(9);
        let pts: Vec<[f64; 3]> = (0..500)
            .map(|_| [rng.uniform(), rng.uniform() * 0.5, rng.uniform() * 0.1])
            .collect();
        let nn = NearestNeighbours::new(&pts, 0.03);
        for _ in 0..300 {
            let q = [
                rng.uniform() * 1.4 - 0.2,
                rng.uniform(),
                rng.uniform() * 0.5 - 0.2,
            ];
            let brute = pts
                .iter()
                .map(|p| {
                    ((p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2) + (p[2] - q[2]).powi(2)).sqrt()
                })
                .fold(f64::INFINITY, f64::min);
            let (_, d) = nn.nearest(&q);
            assert!((d - brute).abs() < 1e-12, "{d} vs {brute}");
            assert_eq!(nn.within(&q, 0.03), brute < 0.03);
        }
    }
}
