//! Components split at sharp transitions (paper §8).
//!
//! mmNorm chooses one isosurface level per component. Where a component holds surfaces at
//! different depths that the image blurs together (a step shallower than the 5 cm range
//! resolution, a rim and the floor inside it), the normal field says nothing about the jump:
//! both sides point up, so the integrated RSDF is one plane and any one level misses one side.
//! What does see the jump is the depth at which each column's echo energy sits.
//!
//! Each column (x, y) of a component has a depth, the |S|²-weighted mean z of its voxels, and a
//! slope, −n_x/n_z and −n_y/n_z of its |S|²-weighted mean normal. Over a smooth surface the depth
//! moves as the slopes predict. At a column where the depth `BASELINE_M` to one side and to the
//! other differ by more than `jump_m` beyond the slopes' prediction, the column lies on a
//! transition. The columns off every transition, grouped by face adjacency, form the component's
//! regions. Regions at the same depth (within `jump_m`) form one level; a level whose regions
//! together hold less than the smallest component or [`MIN_REGION_SHARE`] of the component is
//! not one. A level's largest region, and any other holding the share alone, seed it; every
//! other column joins the seed nearest it. Each level becomes a component of its own, whose
//! level the isosurface optimisation chooses jointly with the others' (Eq. 11–13), as before.
//!
//! Where a normal is steeper than [`STEEP_NZ`] (about 73° from vertical) the predicted slope is
//! too uncertain to judge a departure, and no transition is marked across it.
//!
//! Grids are C-ordered (x, y, z): flat index = (x·NY + y)·NZ + z.

use std::collections::VecDeque;

use super::components::{Components, label_6_keyed};

/// Normals with |n_z| below this do not predict a slope (it would exceed 3.2).
pub const STEEP_NZ: f64 = 0.3;

/// The lateral distance, metres, to each side of a column over which its depth departure is
/// judged. The depth of a column mixes its neighbours' echoes over a few times the image's
/// lateral resolution: on an 8 mm step under a 20 cm aperture at 40 cm the depth moved from one
/// top to the other over some 15 mm, so each side spans half of that.
pub const BASELINE_M: f64 = 0.008;

/// A level (the regions at one depth) stands as a component of its own only when its regions
/// hold at least this share of their component's voxels together (and the smallest component's
/// size). Region depths are compared as means, so on a tilted surface a small region near one
/// end differs from the rest by the tilt; and a thin rim over a steep inner wall shows
/// departures along its length, where cutting it into arcs leaves each arc too few antennas for
/// the cost to place it. At a tenth, a 4.5 cm plate tilted 5° lost a fifth of itself to a
/// component of its own (`tests/recon_scenes.rs`). The regions of a level count together: under
/// point scatterers the edges of a box's top radiate to every antenna and frame the top with
/// transitions, cutting it into a strip along each edge and the middle, none of which alone
/// holds a quarter (`a_step_gets_a_level_on_each_side`).
pub const MIN_REGION_SHARE: f64 = 0.25;

/// What the split did.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct SplitSummary {
    pub jump_m: f64,
    pub components_before: usize,
    pub components_after: usize,
}

/// The |S|²-weighted sums of one column of one component.
#[derive(Debug, Clone, Copy, Default)]
struct Column {
    voxels: usize,
    weight: f64,
    weighted_z: f64,
    weighted_normal: [f64; 3],
}

impl Column {
    fn depth(&self) -> f64 {
        self.weighted_z / self.weight
    }

    /// The surface slope along `axis` (dz per column step), if the normal is not too steep.
    fn slope(&self, axis: usize) -> Option<f64> {
        let n = self.weighted_normal;
        let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
        (len > 0.0 && (n[2] / len).abs() >= STEEP_NZ).then(|| -n[axis] / n[2])
    }
}

/// Splits each component of `components` at its transitions (see the module doc). `magnitude`
/// and `normals` are per voxel of the same grid; pieces under `min_voxels` are dropped, as the
/// labelling drops small components.
pub fn split_at_transitions(
    components: &Components,
    magnitude: &[f32],
    normals: &[[f32; 3]],
    dims: [usize; 3],
    voxel_m: f64,
    jump_m: f64,
    min_voxels: usize,
) -> (Components, SplitSummary) {
    let [nx, ny, nz] = dims;
    let count = components.sizes.len();
    let plane = nx * ny;
    let mut columns: Vec<Option<Column>> = vec![None; count * plane];
    for (v, &l) in components.labels.iter().enumerate() {
        if l == 0 {
            continue;
        }
        let c = columns[(l as usize - 1) * plane + v / nz].get_or_insert_with(Column::default);
        let w = f64::from(magnitude[v]).powi(2);
        c.voxels += 1;
        c.weight += w;
        c.weighted_z += w * (v % nz) as f64;
        for (sum, &n) in c.weighted_normal.iter_mut().zip(&normals[v]) {
            if n.is_finite() {
                *sum += w * f64::from(n);
            }
        }
    }
    let half = (BASELINE_M / voxel_m).round().max(1.0) as usize;
    let jump_voxels = jump_m / voxel_m;
    let mut region_of_column = vec![0u32; count * plane];
    let mut next_region = 1u32;
    for label in 0..count {
        let cols = &columns[label * plane..(label + 1) * plane];
        let regions = regions(cols, [nx, ny], half, jump_voxels, min_voxels);
        for (col, r) in regions.iter().enumerate() {
            if let Some(r) = r {
                region_of_column[label * plane + col] = next_region + r;
            }
        }
        next_region += regions.iter().flatten().max().map_or(0, |m| m + 1);
    }
    let keys: Vec<u32> = components
        .labels
        .iter()
        .enumerate()
        .map(|(v, &l)| match l {
            0 => 0,
            l => region_of_column[(l as usize - 1) * plane + v / nz],
        })
        .collect();
    let split = label_6_keyed(&keys, dims, min_voxels);
    let summary = SplitSummary {
        jump_m,
        components_before: count,
        components_after: split.sizes.len(),
    };
    (split, summary)
}

/// The regions of one component at one depth.
struct Level {
    /// The |S|²-weighted depth of its largest region, voxels.
    depth: f64,
    /// Its regions' voxels.
    voxels: usize,
    /// Its largest region.
    largest: usize,
}

/// The region (0…) of each column of one component (None where the component has no column).
fn regions(
    cols: &[Option<Column>],
    [nx, ny]: [usize; 2],
    half: usize,
    jump_voxels: f64,
    min_voxels: usize,
) -> Vec<Option<u32>> {
    let step = [ny, 1];
    let position = |c: usize| [c / ny, c % ny];
    let extent = [nx, ny];
    // The column `k` steps from `c` along `axis` (k may be negative), if it is the component's.
    let along = |c: usize, axis: usize, k: isize| -> Option<usize> {
        let p = position(c)[axis] as isize + k;
        (p >= 0 && (p as usize) < extent[axis])
            .then(|| (c as isize + k * step[axis] as isize) as usize)
            .filter(|&d| cols[d].is_some())
    };
    let transition = |c: usize| {
        (0..2).any(|axis| {
            let h = half as isize;
            let mut predicted = 0.0;
            for k in -h..h {
                let (Some(a), Some(b)) = (along(c, axis, k), along(c, axis, k + 1)) else {
                    return false;
                };
                let (Some(sa), Some(sb)) = (
                    cols[a].and_then(|x| x.slope(axis)),
                    cols[b].and_then(|x| x.slope(axis)),
                ) else {
                    return false;
                };
                predicted += (sa + sb) / 2.0;
            }
            let (Some(a), Some(b)) = (along(c, axis, -h), along(c, axis, h)) else {
                return false;
            };
            let moved = cols[b].map_or(0.0, |x| x.depth()) - cols[a].map_or(0.0, |x| x.depth());
            (moved - predicted).abs() > jump_voxels
        })
    };
    let on_transition: Vec<bool> = (0..cols.len())
        .map(|c| cols[c].is_some() && transition(c))
        .collect();
    // Regions of the columns off every transition.
    let mut region: Vec<Option<u32>> = vec![None; cols.len()];
    let mut sizes = Vec::new();
    let mut queue = VecDeque::new();
    for seed in 0..cols.len() {
        if cols[seed].is_none() || on_transition[seed] || region[seed].is_some() {
            continue;
        }
        let id = sizes.len() as u32;
        region[seed] = Some(id);
        queue.push_back(seed);
        let mut voxels = 0;
        while let Some(c) = queue.pop_front() {
            voxels += cols[c].map_or(0, |x| x.voxels);
            for axis in 0..2 {
                for k in [-1, 1] {
                    if let Some(d) = along(c, axis, k)
                        && !on_transition[d]
                        && region[d].is_none()
                    {
                        region[d] = Some(id);
                        queue.push_back(d);
                    }
                }
            }
        }
        sizes.push(voxels);
    }
    // Each region's depth: the |S|²-weighted mean over its columns.
    let mut sums = vec![(0.0f64, 0.0f64); sizes.len()];
    for (c, r) in cols.iter().zip(&region) {
        if let (Some(c), Some(r)) = (c, r) {
            sums[*r as usize].0 += c.weighted_z;
            sums[*r as usize].1 += c.weight;
        }
    }
    let depth: Vec<f64> = sums.iter().map(|&(z, w)| z / w).collect();
    // Regions at the same depth (within the jump) form one level, the largest region setting
    // it: a surface that spurious transitions cut into pieces is not split. A level stands when
    // its regions together hold the share ([`MIN_REGION_SHARE`]). Its largest region, and any
    // other holding the share alone, seed it; the rest join the nearest seed with the
    // transition columns. A wall between two tops is a small region whose depth lies between
    // theirs: counted into the nearer top's level as a seed, it pulled that top's level 6 mm
    // (`two_plates_joined_by_a_wall_get_a_level_each`).
    let total: usize = cols.iter().flatten().map(|c| c.voxels).sum();
    let floor = min_voxels.max((MIN_REGION_SHARE * total as f64).ceil() as usize);
    let mut by_size: Vec<usize> = (0..sizes.len()).filter(|&k| depth[k].is_finite()).collect();
    by_size.sort_by_key(|&k| std::cmp::Reverse(sizes[k]));
    let mut levels: Vec<Level> = Vec::new();
    let mut level_of: Vec<Option<usize>> = vec![None; sizes.len()];
    for &k in &by_size {
        let same = levels
            .iter()
            .position(|l| (l.depth - depth[k]).abs() <= jump_voxels);
        let i = same.unwrap_or_else(|| {
            levels.push(Level {
                depth: depth[k],
                voxels: 0,
                largest: k,
            });
            levels.len() - 1
        });
        levels[i].voxels += sizes[k];
        level_of[k] = Some(i);
    }
    let mut kept_id: Vec<Option<u32>> = vec![None; levels.len()];
    let mut kept = 0u32;
    for (i, level) in levels.iter().enumerate() {
        if level.voxels >= floor {
            kept_id[i] = Some(kept);
            kept += 1;
        }
    }
    let renumber: Vec<Option<u32>> = (0..sizes.len())
        .map(|k| {
            let i = level_of[k]?;
            let seeds = sizes[k] >= floor || levels[i].largest == k;
            kept_id[i].filter(|_| seeds)
        })
        .collect();
    if kept < 2 {
        return cols.iter().map(|c| c.map(|_| 0)).collect();
    }
    for r in &mut region {
        *r = r.and_then(|k| renumber[k as usize]);
    }
    queue.extend((0..cols.len()).filter(|&c| region[c].is_some()));
    while let Some(c) = queue.pop_front() {
        for axis in 0..2 {
            for k in [-1, 1] {
                if let Some(d) = along(c, axis, k)
                    && region[d].is_none()
                {
                    region[d] = region[c];
                    queue.push_back(d);
                }
            }
        }
    }
    // Columns that no region reaches keep to the first; the labelling parts them if they lie
    // apart.
    cols.iter()
        .zip(&region)
        .map(|(c, r)| c.map(|_| r.unwrap_or(0)))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    const DIMS: [usize; 3] = [60, 20, 40];

    /// One component filling the grid, whose magnitude in column (x, y) peaks at
    /// `surface(x)` (a Gaussian 6 voxels wide in z, as a blurred echo) and whose normals follow
    /// `normal(x)`.
    fn scene(
        surface: impl Fn(usize) -> f64,
        normal: impl Fn(usize) -> [f32; 3],
    ) -> (Components, Vec<f32>, Vec<[f32; 3]>) {
        let [nx, ny, nz] = DIMS;
        let n = nx * ny * nz;
        let mut magnitude = vec![0.0f32; n];
        let mut normals = vec![[0.0f32; 3]; n];
        for v in 0..n {
            let (x, z) = (v / (ny * nz), v % nz);
            let d = (z as f64 - surface(x)) / 6.0;
            magnitude[v] = (-d * d).exp() as f32;
            normals[v] = normal(x);
        }
        let components = Components {
            labels: vec![1; n],
            sizes: vec![n],
        };
        (components, magnitude, normals)
    }

    fn split(c: &Components, m: &[f32], n: &[[f32; 3]]) -> Components {
        split_at_transitions(c, m, n, DIMS, 0.001, 0.004, 100).0
    }

    #[test]
    fn a_step_the_normals_do_not_explain_is_split_where_it_lies() {
        let up = |_| [0.0, 0.0, 1.0];
        let (c, m, n) = scene(|x| if x < 30 { 15.0 } else { 23.0 }, up);
        let s = split(&c, &m, &n);
        assert_eq!(s.sizes.len(), 2, "{:?}", s.sizes);
        let [_, ny, nz] = DIMS;
        let label_at = |x: usize| s.labels[(x * ny + 10) * nz + 20];
        assert!((0..28).all(|x| label_at(x) == label_at(0)));
        assert!((32..60).all(|x| label_at(x) == label_at(59)));
        assert_ne!(label_at(0), label_at(59));
    }

    #[test]
    fn a_slope_the_normals_predict_is_not_split() {
        // z = 10 + 0.5·x: normal ∝ (−0.5, 0, 1).
        let len = (1.25f32).sqrt();
        let (c, m, n) = scene(|x| 10.0 + 0.5 * x as f64, |_| [-0.5 / len, 0.0, 1.0 / len]);
        assert_eq!(split(&c, &m, &n).sizes.len(), 1);
    }

    #[test]
    fn a_region_under_a_quarter_of_its_component_is_not_split_off() {
        // A 10-column ledge 8 voxels above the rest: 2 of its columns lie off the transition
        // (8 columns to each side of the step), 3 % of the component.
        let (c, m, n) = scene(|x| if x < 50 { 15.0 } else { 23.0 }, |_| [0.0, 0.0, 1.0]);
        assert_eq!(split(&c, &m, &n).sizes.len(), 1);
        // A 24-column ledge, 16 columns (27 %) off the transition, is.
        let (c, m, n) = scene(|x| if x < 36 { 15.0 } else { 23.0 }, |_| [0.0, 0.0, 1.0]);
        assert_eq!(split(&c, &m, &n).sizes.len(), 2);
    }

    #[test]
    fn pieces_at_one_depth_count_together_towards_the_share() {
        // A two-column rib 8 voxels high at x = 18..19 marks transitions 8 columns to each side
        // of it, so the low top falls into two pieces off the transitions (x < 10 and
        // 12..22), each under a quarter of the component and together over it.
        let surface = |x: usize| match x {
            18 | 19 => 23.0,
            x if x < 30 => 15.0,
            _ => 23.0,
        };
        let (c, m, n) = scene(surface, |_| [0.0, 0.0, 1.0]);
        let s = split(&c, &m, &n);
        assert_eq!(s.sizes.len(), 2, "{:?}", s.sizes);
        let [_, ny, nz] = DIMS;
        let label_at = |x: usize| s.labels[(x * ny + 10) * nz + 15];
        assert_eq!(
            label_at(5),
            label_at(15),
            "the low top's pieces are one level"
        );
        assert_ne!(label_at(5), s.labels[(59 * ny + 10) * nz + 23]);
    }
}
