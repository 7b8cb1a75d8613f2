//! Components that are a brighter surface's range sidelobe.
//!
//! S(v) is formed from unwindowed chirps, as the paper's and the authors' code form it
//! (docs/mmnorm-reference.md §2), so every echo images with range sidelobes: the first 13 dB
//! under its main lobe, 1.43 range bins (c/2B, 5 cm for the 3 GHz sweep) away, the second
//! 18 dB under it at 2.46 bins. A broad surface whose columns all see it at one depth (a
//! closed top, a plate) focuses its sidelobe into a sheet under it. Where Li's threshold lies
//! under that sheet's level, part of it becomes a component of its own where nothing is: under
//! the physics suite's pitcher top, 75 points 6.8 cm down, 8 dB under the top and 4.8 cm
//! (median) from the mesh (`docs/bench/physics/notes.md`).
//!
//! Seen from above, a surface under a brighter one, in the columns they share, is hidden by
//! it (the objects are opaque; a known occluder's sheet is subtracted before imaging). So a
//! component is dropped as a sidelobe when, over the columns it shares with a brighter
//! component:
//! - those columns hold at least [`SHARED_FRACTION`] of its voxels,
//! - its |S|-weighted depth lies [`DEPTH_BINS`] under the brighter one's, where the first two
//!   sidelobes fall, and
//! - its peak is at least [`LEVEL_DB`] under the brighter one's peak in those columns.
//!
//! A surface above a brighter one is kept (the cup's rim above its floor): a sidelobe above a
//! surface exists too, but so do real rims 15–24 dB under their floors, and the two cannot be
//! told apart by level. The surfaces that `recon::hidden` finds are not judged here: it has
//! its own rule against sidelobes, on the residual image.
//!
//! Neither the paper nor the authors' code does this; `drop_sidelobes = false` in the
//! reconstruction config turns it off.

use std::collections::BTreeMap;

use serde::Serialize;

use super::components::Components;

/// The least share of a component's voxels that must lie in columns of the brighter one.
pub const SHARED_FRACTION: f64 = 0.5;

/// How far under the brighter component a sidelobe lies, in range bins: the unwindowed chirp's
/// first two sidelobes peak 1.43 and 2.46 bins from its main lobe. Within 0.8 bins lies the
/// main lobe of a surface itself (its two sides, a curved top's spread); beyond 3 bins the
/// sidelobes are more than 20 dB down.
pub const DEPTH_BINS: [f64; 2] = [0.8, 3.0];

/// How far under the brighter component's peak a sidelobe lies at least, dB. The first
/// sidelobe of one echo is 13 dB under it; imaged from a curved top, whose main lobe spreads
/// over a range of depths while its sidelobes add under it, the sheets that formed components
/// on the two accuracy suites lay 6.9–11.2 dB under their tops, 1.26–1.44 bins down.
pub const LEVEL_DB: f32 = 6.0;

/// What [`drop_sidelobes`] found.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct SidelobeSummary {
    /// Per dropped component (numbered as before the drop): its voxels, the brighter
    /// component it lies under, its depth under it in metres and its peak under it in dB.
    pub dropped: Vec<DroppedComponent>,
}

/// One component taken for a sidelobe.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct DroppedComponent {
    pub component: usize,
    pub voxels: usize,
    pub under: usize,
    pub depth_m: f64,
    pub level_db: f64,
}

/// Sums over the voxels of one component that lie in columns of another.
#[derive(Default, Clone, Copy)]
struct Shared {
    voxels: usize,
    /// Σ |S| and Σ |S|·z of the judged component's voxels in the shared columns.
    weight: f64,
    moment: f64,
    /// Σ |S| and Σ |S|·z of the other component's voxels in those columns, and its peak there.
    other_weight: f64,
    other_moment: f64,
    other_peak: f32,
}

/// `labelled` without the components that lie under a brighter one as its range sidelobe
/// (module doc). Components flagged in `skip` are neither judged nor taken as the brighter one.
/// Labels are renumbered 1…m in their old order. Grids are C order with z fastest, z up
/// (towards the aperture); `bin_voxels` is one range bin (c/2B) in voxels.
pub fn drop_sidelobes(
    labelled: Components,
    skip: &[bool],
    magnitude: &[f32],
    dims: [usize; 3],
    voxel_m: f64,
    bin_voxels: f64,
) -> (Components, SidelobeSummary) {
    let nz = dims[2];
    let n = labelled.sizes.len();
    let judged = |l: u32| l != 0 && !skip.get(l as usize - 1).copied().unwrap_or(false);
    let mut peak = vec![0f32; n];
    for (v, &l) in labelled.labels.iter().enumerate() {
        if judged(l) {
            peak[l as usize - 1] = peak[l as usize - 1].max(magnitude[v]);
        }
    }
    // Per column: each judged component's voxel count, Σ|S|, Σ|S|·z and peak.
    let mut pairs: BTreeMap<(usize, usize), Shared> = BTreeMap::new();
    let mut in_column: Vec<(usize, usize, f64, f64, f32)> = Vec::new();
    for column in labelled.labels.chunks(nz).zip(magnitude.chunks(nz)) {
        in_column.clear();
        for (z, (&l, &m)) in column.0.iter().zip(column.1).enumerate() {
            if !judged(l) {
                continue;
            }
            let k = l as usize - 1;
            let (w, zf) = (f64::from(m), z as f64);
            match in_column.iter_mut().find(|e| e.0 == k) {
                Some(e) => {
                    e.1 += 1;
                    e.2 += w;
                    e.3 += w * zf;
                    e.4 = e.4.max(m);
                }
                None => in_column.push((k, 1, w, w * zf, m)),
            }
        }
        for a in &in_column {
            for b in in_column.iter().filter(|b| b.0 != a.0) {
                let s = pairs.entry((a.0, b.0)).or_default();
                s.voxels += a.1;
                s.weight += a.2;
                s.moment += a.3;
                s.other_weight += b.2;
                s.other_moment += b.3;
                s.other_peak = s.other_peak.max(b.4);
            }
        }
    }
    let sidelobe = 10f32.powf(-LEVEL_DB / 20.0);
    let mut dropped: Vec<DroppedComponent> = Vec::new();
    let mut keep = vec![true; n];
    for (&(k, j), s) in &pairs {
        if !keep[k] || s.weight <= 0.0 {
            continue;
        }
        let depth_voxels = s.other_moment / s.other_weight - s.moment / s.weight;
        let share = s.voxels as f64 / labelled.sizes[k] as f64;
        let depth_bins = depth_voxels / bin_voxels;
        if share >= SHARED_FRACTION
            && (DEPTH_BINS[0]..=DEPTH_BINS[1]).contains(&depth_bins)
            && peak[k] <= s.other_peak * sidelobe
        {
            keep[k] = false;
            dropped.push(DroppedComponent {
                component: k + 1,
                voxels: labelled.sizes[k],
                under: j + 1,
                depth_m: depth_voxels * voxel_m,
                level_db: f64::from(20.0 * (peak[k] / s.other_peak).log10()),
            });
        }
    }
    (labelled.retain(&keep), SidelobeSummary { dropped })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::recon::components::label_6;

    const NZ: usize = 80;
    /// One range bin, voxels.
    const BIN: f64 = 10.0;

    /// A 12×1×80 grid with a bright top (|S| 10) over columns 0–7 at z 50–53, and `blocks`
    /// (columns, depths, |S|) beside it. Returns the labelled grid and its |S|.
    fn scene(
        blocks: &[(std::ops::Range<usize>, std::ops::Range<usize>, f32)],
    ) -> (Components, Vec<f32>) {
        let mut mask = vec![false; 12 * NZ];
        let mut magnitude = vec![0f32; 12 * NZ];
        let all = std::iter::once(&(0..8, 50..54, 10.0)).chain(blocks);
        for (xs, zs, m) in all {
            for x in xs.clone() {
                for z in zs.clone() {
                    mask[x * NZ + z] = true;
                    magnitude[x * NZ + z] = *m;
                }
            }
        }
        (label_6(&mask, [12, 1, NZ], 1), magnitude)
    }

    /// [`drop_sidelobes`] on a grid of [`scene`]'s shape, 5 mm voxels and [`BIN`].
    fn run(
        labelled: Components,
        skip: &[bool],
        magnitude: &[f32],
    ) -> (Components, SidelobeSummary) {
        drop_sidelobes(labelled, skip, magnitude, [12, 1, NZ], 0.005, BIN)
    }

    fn dropped(blocks: &[(std::ops::Range<usize>, std::ops::Range<usize>, f32)]) -> Vec<usize> {
        let (labelled, magnitude) = scene(blocks);
        let n = labelled.sizes.len();
        let (kept, summary) = run(labelled, &vec![false; n], &magnitude);
        assert_eq!(kept.sizes.len(), n - summary.dropped.len());
        summary.dropped.iter().map(|d| d.voxels).collect()
    }

    #[test]
    fn a_weak_sheet_a_sidelobe_under_a_bright_top_is_dropped() {
        // 1.4 bins under the top's centre (z 51.5), 10.5 dB under it.
        let (labelled, magnitude) = scene(&[(1..7, 37..39, 3.0)]);
        let (kept, summary) = run(labelled, &[false; 2], &magnitude);
        assert_eq!(kept.sizes, vec![32]);
        let d = &summary.dropped[0];
        assert_eq!((d.component, d.voxels, d.under), (2, 12, 1));
        assert!((d.depth_m - 0.07).abs() < 1e-9, "{}", d.depth_m);
        assert!((d.level_db + 10.46).abs() < 0.01, "{}", d.level_db);
        assert!(kept.labels[37 + NZ] == 0 && kept.labels[50] == 1);
    }

    #[test]
    fn what_a_sidelobe_cannot_be_is_kept() {
        // As bright as 3 dB under the top: brighter than its sidelobes.
        assert!(dropped(&[(1..7, 37..39, 7.0)]).is_empty());
        // Above the top, as a cup's rim above its floor.
        assert!(dropped(&[(1..7, 65..67, 3.0)]).is_empty());
        // 0.5 bins down (its own lobe) and 4 bins down (past the sidelobes).
        assert!(dropped(&[(1..7, 44..46, 3.0)]).is_empty());
        assert!(dropped(&[(1..7, 10..12, 3.0)]).is_empty());
        // Mostly beside the top's columns.
        assert!(dropped(&[(6..12, 37..39, 3.0)]).is_empty());
        // Two of them at once: only the sidelobe goes.
        assert_eq!(
            dropped(&[(1..7, 37..39, 3.0), (9..12, 37..39, 3.0)]),
            vec![12]
        );
    }

    #[test]
    fn skipped_components_are_neither_judged_nor_a_reference() {
        let (labelled, magnitude) = scene(&[(1..7, 37..39, 3.0)]);
        let (kept, summary) = run(labelled.clone(), &[true, false], &magnitude);
        assert!(summary.dropped.is_empty());
        assert_eq!(kept, labelled);
        let (kept, summary) = run(labelled, &[false, true], &magnitude);
        assert!(summary.dropped.is_empty());
        assert_eq!(kept.sizes.len(), 2);
    }
}
