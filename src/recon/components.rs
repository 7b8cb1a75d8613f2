//! Connected components of a voxel mask with 6-connectivity (face neighbours), as mmNorm labels
//! its high-power regions before integrating one RSDF per component (§3.2; docs/mmnorm-reference.md §4.2
//! uses `cc3d` with connectivity 6).
//!
//! Grids are C-ordered (x, y, z): flat index = (x·NY + y)·NZ + z.

/// Labelled components: `labels[v]` is 0 for background or a dropped component, else 1…n in
/// order of each component's first voxel in flat order; `sizes[k - 1]` is component k's voxel
/// count.
#[derive(Debug, Clone, PartialEq)]
pub struct Components {
    pub labels: Vec<u32>,
    pub sizes: Vec<usize>,
}

/// Labels the 6-connected components of `mask` (shape `dims` = [NX, NY, NZ]) and keeps those
/// with at least `min_voxels` voxels; smaller ones become background.
///
/// # Panics
/// If `mask.len()` is not NX·NY·NZ (a caller's bug, not an input error).
pub fn label_6(mask: &[bool], dims: [usize; 3], min_voxels: usize) -> Components {
    let keys: Vec<u32> = mask.iter().map(|&m| u32::from(m)).collect();
    label_6_keyed(&keys, dims, min_voxels)
}

/// [`label_6`] over keyed voxels: voxels with key 0 are background, and two face neighbours
/// join only when their keys are equal (so regions already drawn inside a component stay apart).
///
/// # Panics
/// If `keys.len()` is not NX·NY·NZ (a caller's bug, not an input error).
pub fn label_6_keyed(keys: &[u32], dims: [usize; 3], min_voxels: usize) -> Components {
    let [nx, ny, nz] = dims;
    assert_eq!(
        keys.len(),
        nx * ny * nz,
        "keys do not match their dimensions"
    );
    let mut labels = vec![0u32; keys.len()];
    let mut sizes = Vec::new();
    let mut stack = Vec::new();
    let mut members = Vec::new();
    for seed in 0..keys.len() {
        if keys[seed] == 0 || labels[seed] != 0 {
            continue;
        }
        let key = keys[seed];
        let label = sizes.len() as u32 + 1;
        labels[seed] = label;
        stack.push(seed);
        members.clear();
        while let Some(v) = stack.pop() {
            members.push(v);
            let (x, y, z) = (v / (ny * nz), (v / nz) % ny, v % nz);
            let mut visit = |w: usize| {
                if keys[w] == key && labels[w] == 0 {
                    labels[w] = label;
                    stack.push(w);
                }
            };
            if x > 0 {
                visit(v - ny * nz);
            }
            if x + 1 < nx {
                visit(v + ny * nz);
            }
            if y > 0 {
                visit(v - nz);
            }
            if y + 1 < ny {
                visit(v + nz);
            }
            if z > 0 {
                visit(v - 1);
            }
            if z + 1 < nz {
                visit(v + 1);
            }
        }
        if members.len() >= min_voxels {
            sizes.push(members.len());
        } else {
            // Too small: clear it; `u32::MAX` keeps it from being revisited as a new seed.
            for &v in &members {
                labels[v] = u32::MAX;
            }
        }
    }
    for l in &mut labels {
        if *l == u32::MAX {
            *l = 0;
        }
    }
    Components { labels, sizes }
}

/// `components` without those that have no voxel where `reaches(flat index)` holds, relabelled
/// 1…m in their old order (still the order of each one's first voxel).
pub fn retain_reaching(components: Components, reaches: impl Fn(usize) -> bool) -> Components {
    let mut kept = vec![false; components.sizes.len()];
    for (v, &l) in components.labels.iter().enumerate() {
        if l != 0 && !kept[l as usize - 1] && reaches(v) {
            kept[l as usize - 1] = true;
        }
    }
    components.retain(&kept)
}

impl Components {
    /// The components whose `keep` is true, relabelled 1…m in their old order.
    pub fn retain(self, keep: &[bool]) -> Components {
        let Components { mut labels, sizes } = self;
        if keep.iter().all(|&k| k) {
            return Components { labels, sizes };
        }
        let mut new_label = vec![0u32; sizes.len()];
        let mut new_sizes = Vec::new();
        for (k, &size) in sizes.iter().enumerate() {
            if keep[k] {
                new_sizes.push(size);
                new_label[k] = new_sizes.len() as u32;
            }
        }
        for l in &mut labels {
            if *l != 0 {
                *l = new_label[*l as usize - 1];
            }
        }
        Components {
            labels,
            sizes: new_sizes,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn grid(dims: [usize; 3], on: &[[usize; 3]]) -> Vec<bool> {
        let mut m = vec![false; dims[0] * dims[1] * dims[2]];
        for p in on {
            m[(p[0] * dims[1] + p[1]) * dims[2] + p[2]] = true;
        }
        m
    }

    #[test]
    fn faces_connect_edges_and_corners_do_not() {
        let dims = [3, 3, 3];
        // A face pair, an edge-diagonal voxel and a corner-diagonal voxel.
        let m = grid(dims, &[[0, 0, 0], [0, 0, 1], [1, 1, 1], [2, 2, 2]]);
        let c = label_6(&m, dims, 1);
        assert_eq!(c.sizes, vec![2, 1, 1]);
        assert_eq!(c.labels[0], 1);
        assert_eq!(c.labels[1], 1);
        assert_eq!(c.labels[(3 + 1) * 3 + 1], 2);
        assert_eq!(c.labels[26], 3);
    }

    #[test]
    fn small_components_are_dropped_and_labels_stay_dense() {
        let dims = [4, 4, 1];
        let mut on = vec![[0, 0, 0]];
        on.extend([[2, 0, 0], [2, 1, 0], [2, 2, 0], [3, 2, 0]]);
        on.extend([[0, 3, 0], [1, 3, 0]]);
        let c = label_6(&grid(dims, &on), dims, 2);
        assert_eq!(c.sizes, vec![2, 4]);
        assert_eq!(c.labels[0], 0, "the single voxel is dropped");
        assert_eq!(c.labels[3], 1);
        assert_eq!(c.labels[8], 2, "voxel (2, 0, 0)");
        assert_eq!(c.labels.iter().filter(|&&l| l != 0).count(), 6);
    }

    #[test]
    fn components_that_never_reach_the_region_are_dropped_and_the_rest_relabelled() {
        // Three components along x in a 7×1×1 row; the region is x ≥ 3, which the first misses
        // and the second (x = 2..3) crosses into.
        let dims = [7, 1, 1];
        let on = [[0, 0, 0], [2, 0, 0], [3, 0, 0], [5, 0, 0], [6, 0, 0]];
        let c = retain_reaching(label_6(&grid(dims, &on), dims, 1), |v| v >= 3);
        assert_eq!(c.sizes, vec![2, 2]);
        assert_eq!(c.labels, vec![0, 0, 1, 1, 0, 2, 2]);
        let all = label_6(&grid(dims, &on), dims, 1);
        assert_eq!(retain_reaching(all.clone(), |_| true), all);
    }

    #[test]
    fn keyed_neighbours_join_only_with_their_own_key() {
        // A 6×1×1 row keyed 1 1 2 2 1 0: three components (the last 1 is apart from the first).
        let c = label_6_keyed(&[1, 1, 2, 2, 1, 0], [6, 1, 1], 1);
        assert_eq!(c.sizes, vec![2, 2, 1]);
        assert_eq!(c.labels, vec![1, 1, 2, 2, 3, 0]);
    }

    #[test]
    fn a_solid_box_is_one_component() {
        let dims = [5, 6, 7];
        let c = label_6(&vec![true; 210], dims, 10);
        assert_eq!(c.sizes, vec![210]);
        assert!(c.labels.iter().all(|&l| l == 1));
    }
}
