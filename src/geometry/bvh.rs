//! A bounding-volume hierarchy over triangles for shadow rays and first-hit queries.
//!
//! Built with a binned surface-area heuristic (12 bins) into a flat node array; traversal uses
//! a fixed stack and single-precision slab and Möller–Trumbore tests. Single precision is enough
//! for visibility: scenes are under a few metres, where f32 resolves 0.1 µm.

use super::TriMesh;
use super::vec3::{cross, dot, sub};

const BINS: usize = 12;
const MAX_LEAF: usize = 4;
const STACK: usize = 64;
/// Deepest interior level; below it nodes become (larger) leaves, so traversal never needs
/// more than `STACK` entries.
const MAX_DEPTH: usize = STACK - 2;

#[derive(Debug, Clone, Copy)]
struct Node {
    lo: [f32; 3],
    hi: [f32; 3],
    /// Leaf: first triangle. Interior: index of the left child (the right one follows it).
    start: u32,
    /// Leaf: triangle count (> 0). Interior: 0.
    count: u32,
}

#[derive(Debug, Clone, Copy)]
struct Tri {
    v0: [f32; 3],
    e1: [f32; 3],
    e2: [f32; 3],
}

/// A ray hit: distance along the (unit) direction and the mesh triangle index.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Hit {
    pub t: f32,
    pub triangle: u32,
}

/// The hierarchy; triangle indices in hits refer to the mesh it was built from.
#[derive(Debug, Clone)]
pub struct Bvh {
    nodes: Vec<Node>,
    tris: Vec<Tri>,
    tri_ids: Vec<u32>,
}

#[derive(Clone, Copy)]
struct Aabb {
    lo: [f32; 3],
    hi: [f32; 3],
}

impl Aabb {
    const EMPTY: Aabb = Aabb {
        lo: [f32::INFINITY; 3],
        hi: [f32::NEG_INFINITY; 3],
    };
    fn grow(&mut self, p: [f32; 3]) {
        for ((lo, hi), v) in self.lo.iter_mut().zip(&mut self.hi).zip(p) {
            *lo = lo.min(v);
            *hi = hi.max(v);
        }
    }
    fn merge(&mut self, o: &Aabb) {
        self.grow(o.lo);
        self.grow(o.hi);
    }
    fn area(&self) -> f32 {
        let d = sub(self.hi, self.lo);
        if d[0] < 0.0 {
            return 0.0;
        }
        2.0 * (d[0] * d[1] + d[1] * d[2] + d[2] * d[0])
    }
}

struct Prim {
    bounds: Aabb,
    centre: [f32; 3],
    id: u32,
}

impl Bvh {
    /// Builds the hierarchy over every triangle of `mesh`.
    pub fn build(mesh: &TriMesh) -> Bvh {
        let mut prims: Vec<Prim> = (0..mesh.triangles.len())
            .map(|i| {
                let mut b = Aabb::EMPTY;
                for k in mesh.triangles[i] {
                    b.grow(mesh.vertices_m[k as usize].map(|c| c as f32));
                }
                let centre = [0, 1, 2].map(|k| 0.5 * (b.lo[k] + b.hi[k]));
                Prim {
                    bounds: b,
                    centre,
                    id: i as u32,
                }
            })
            .collect();
        let mut nodes = vec![Node {
            lo: [0.0; 3],
            hi: [0.0; 3],
            start: 0,
            count: 0,
        }];
        if !prims.is_empty() {
            let n = prims.len();
            build_node(&mut nodes, 0, &mut prims, 0, n, 0);
        }
        let tri_ids: Vec<u32> = prims.iter().map(|p| p.id).collect();
        let tris = tri_ids
            .iter()
            .map(|&i| {
                let [a, b, c] = mesh.triangles[i as usize]
                    .map(|k| mesh.vertices_m[k as usize].map(|x| x as f32));
                Tri {
                    v0: a,
                    e1: sub(b, a),
                    e2: sub(c, a),
                }
            })
            .collect();
        Bvh {
            nodes,
            tris,
            tri_ids,
        }
    }

    /// Whether any triangle lies on the segment `origin + t·dir`, 0 < t < `t_max`
    /// (`dir` need not be unit; `t_max` is in its units).
    pub fn occluded(&self, origin: [f32; 3], dir: [f32; 3], t_max: f32) -> bool {
        self.traverse(origin, dir, t_max, true).is_some()
    }

    /// The nearest triangle on the ray within `t_max`.
    pub fn closest(&self, origin: [f32; 3], dir: [f32; 3], t_max: f32) -> Option<Hit> {
        self.traverse(origin, dir, t_max, false)
    }

    fn traverse(&self, o: [f32; 3], d: [f32; 3], t_max: f32, any: bool) -> Option<Hit> {
        if self.tris.is_empty() {
            return None;
        }
        // A zero component would give 0·∞ = NaN in the slab test; a tiny one keeps it finite.
        let inv = d.map(|c| {
            1.0 / if c.abs() < 1e-30 {
                1e-30f32.copysign(c)
            } else {
                c
            }
        });
        let mut best: Option<Hit> = None;
        let mut t_best = t_max;
        let mut stack = [0u32; STACK];
        let mut sp = 1usize;
        while sp > 0 {
            sp -= 1;
            let node = &self.nodes[stack[sp] as usize];
            if !slab(node, o, inv, t_best) {
                continue;
            }
            if node.count > 0 {
                let first = node.start as usize;
                for (k, tri) in self.tris[first..first + node.count as usize]
                    .iter()
                    .enumerate()
                {
                    if let Some(t) = intersect(tri, o, d, t_best) {
                        t_best = t;
                        best = Some(Hit {
                            t,
                            triangle: self.tri_ids[first + k],
                        });
                        if any {
                            return best;
                        }
                    }
                }
            } else {
                // Depth ≤ MAX_DEPTH keeps sp + 2 ≤ STACK: each level leaves one sibling.
                stack[sp] = node.start;
                stack[sp + 1] = node.start + 1;
                sp += 2;
            }
        }
        best
    }
}

#[inline]
fn slab(n: &Node, o: [f32; 3], inv: [f32; 3], t_max: f32) -> bool {
    let mut t0 = 0.0f32;
    let mut t1 = t_max;
    for k in 0..3 {
        let a = (n.lo[k] - o[k]) * inv[k];
        let b = (n.hi[k] - o[k]) * inv[k];
        t0 = t0.max(a.min(b));
        t1 = t1.min(a.max(b));
    }
    t0 <= t1
}

#[inline]
fn intersect(tri: &Tri, o: [f32; 3], d: [f32; 3], t_max: f32) -> Option<f32> {
    ray_triangle(tri.v0, tri.e1, tri.e2, o, d, t_max)
}

/// Barycentric slack of [`ray_triangle`]: in f32 a ray through the edge two triangles share
/// can fall just outside both; the slack closes that crack (a mesh stays watertight to rays).
const EDGE_SLACK: f32 = 1e-6;

/// Möller–Trumbore: the distance 0 < t < `t_max` at which `o + t·d` meets the triangle
/// `v0 + u·e1 + v·e2` (edges included, with [`EDGE_SLACK`]).
#[inline]
pub(crate) fn ray_triangle(
    v0: [f32; 3],
    e1: [f32; 3],
    e2: [f32; 3],
    o: [f32; 3],
    d: [f32; 3],
    t_max: f32,
) -> Option<f32> {
    let p = cross(d, e2);
    let det = dot(e1, p);
    if det.abs() < 1e-20 {
        return None;
    }
    let inv = 1.0 / det;
    let s = sub(o, v0);
    let u = dot(s, p) * inv;
    if !(-EDGE_SLACK..=1.0 + EDGE_SLACK).contains(&u) {
        return None;
    }
    let q = cross(s, e1);
    let v = dot(d, q) * inv;
    if v < -EDGE_SLACK || u + v > 1.0 + EDGE_SLACK {
        return None;
    }
    let t = dot(e2, q) * inv;
    (t > 0.0 && t < t_max).then_some(t)
}

fn build_node(
    nodes: &mut Vec<Node>,
    index: usize,
    prims: &mut [Prim],
    start: usize,
    end: usize,
    depth: usize,
) {
    let mut bounds = Aabb::EMPTY;
    let mut cbounds = Aabb::EMPTY;
    for p in &prims[start..end] {
        bounds.merge(&p.bounds);
        cbounds.grow(p.centre);
    }
    let count = end - start;
    let leaf = Node {
        lo: bounds.lo,
        hi: bounds.hi,
        start: start as u32,
        count: count as u32,
    };
    if count <= MAX_LEAF || depth >= MAX_DEPTH {
        nodes[index] = leaf;
        return;
    }
    // Binned SAH over the widest centroid axis.
    let extent = sub(cbounds.hi, cbounds.lo);
    let axis = (0..3)
        .max_by(|&a, &b| extent[a].total_cmp(&extent[b]))
        .unwrap_or(0);
    if extent[axis] <= 0.0 {
        nodes[index] = leaf;
        return;
    }
    let bin_of =
        |c: f32| (((c - cbounds.lo[axis]) / extent[axis] * BINS as f32) as usize).min(BINS - 1);
    let mut bin_bounds = [Aabb::EMPTY; BINS];
    let mut bin_count = [0usize; BINS];
    for p in &prims[start..end] {
        let b = bin_of(p.centre[axis]);
        bin_bounds[b].merge(&p.bounds);
        bin_count[b] += 1;
    }
    let mut best = (f32::INFINITY, 0usize);
    for split in 1..BINS {
        let (mut left, mut right) = (Aabb::EMPTY, Aabb::EMPTY);
        let (mut nl, mut nr) = (0usize, 0usize);
        for b in 0..split {
            left.merge(&bin_bounds[b]);
            nl += bin_count[b];
        }
        for b in split..BINS {
            right.merge(&bin_bounds[b]);
            nr += bin_count[b];
        }
        if nl == 0 || nr == 0 {
            continue;
        }
        let cost = left.area() * nl as f32 + right.area() * nr as f32;
        if cost < best.0 {
            best = (cost, split);
        }
    }
    let leaf_cost = bounds.area() * count as f32;
    if best.0 >= leaf_cost && count <= 2 * MAX_LEAF {
        nodes[index] = leaf;
        return;
    }
    let mid = if best.0.is_finite() {
        let split = best.1;
        let slice = &mut prims[start..end];
        let mut i = 0;
        for j in 0..slice.len() {
            if bin_of(slice[j].centre[axis]) < split {
                slice.swap(i, j);
                i += 1;
            }
        }
        start + i
    } else {
        start + count / 2
    };
    let left = nodes.len();
    nodes.push(leaf);
    nodes.push(leaf);
    nodes[index] = Node {
        lo: bounds.lo,
        hi: bounds.hi,
        start: left as u32,
        count: 0,
    };
    build_node(nodes, left, prims, start, mid, depth + 1);
    build_node(nodes, left + 1, prims, mid, end, depth + 1);
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::{box_mesh, sphere_mesh};

    #[test]
    fn rays_hit_a_sphere_where_geometry_says() {
        let mesh = sphere_mesh(0.1, 0.005);
        let bvh = Bvh::build(&mesh);
        let hit = bvh
            .closest([0.001, 0.0, 1.0], [0.0, 0.0, -1.0], 10.0)
            .unwrap();
        assert!((hit.t - 0.9).abs() < 1e-4, "{hit:?}");
        assert!(bvh.occluded([0.001, 0.0, 1.0], [0.0, 0.0, -1.0], 10.0));
        assert!(!bvh.occluded([0.001, 0.0, 1.0], [0.0, 0.0, -1.0], 0.85));
        assert!(!bvh.occluded([0.2, 0.0, 1.0], [0.0, 0.0, -1.0], 10.0));
    }

    #[test]
    fn brute_force_agrees_on_random_rays() {
        let mut mesh = box_mesh([0.1, 0.2, 0.05], 0.01);
        mesh.append(
            &sphere_mesh(0.04, 0.004)
                .transformed(&crate::geometry::pose_from([0.05, 0.0, 0.08], [0.0; 3])),
        );
        let bvh = Bvh::build(&mesh);
        let mut state = 12345u64;
        let mut rnd = || {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((state >> 40) as f32 / (1u64 << 24) as f32) * 2.0 - 1.0
        };
        for _ in 0..500 {
            let o = [rnd() * 0.3, rnd() * 0.3, rnd() * 0.3];
            let d = [rnd(), rnd(), rnd()];
            let mut brute: Option<f32> = None;
            for (i, t) in mesh.triangles.iter().enumerate() {
                let _ = i;
                let [a, b, c] = t.map(|k| mesh.vertices_m[k as usize].map(|x| x as f32));
                let tri = Tri {
                    v0: a,
                    e1: sub(b, a),
                    e2: sub(c, a),
                };
                if let Some(th) = intersect(&tri, o, d, brute.unwrap_or(100.0)) {
                    brute = Some(th);
                }
            }
            let got = bvh.closest(o, d, 100.0).map(|h| h.t);
            assert_eq!(got.is_some(), brute.is_some());
            if let (Some(g), Some(b)) = (got, brute) {
                assert!((g - b).abs() < 1e-5);
            }
        }
    }
}
