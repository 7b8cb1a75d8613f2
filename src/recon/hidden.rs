//! Surfaces hidden in a brighter surface's range lobe.
//!
//! Li's threshold is one level for the whole image. An open cup seen from above returns its
//! rim 15–24 dB under its floor (under the point-scatterer model; 7 dB under physical optics),
//! and the rim lies 5 cm above the floor, about one range resolution (c/2B, 5 cm for the 3 GHz
//! sweep). There the floor's own range lobe and sidelobes are as bright as the rim, so no
//! threshold takes the rim in without the floor's lobe and sidelobes too
//! (`docs/bench/physics/notes.md`).
//!
//! What sets the rim apart is that it is a different echo. Each antenna's chirp holds a few
//! tones, one per surface it sees, and the brightest is the one that hides the others. So:
//! 1. [`without_strongest_echoes`](super::near_echo::without_strongest_echoes) subtracts from
//!    every chirp its strongest echo inside the range window that the components' box can
//!    reach ([`NearEchoCanceller::without_strongest_in`](super::near_echo::NearEchoCanceller::without_strongest_in)):
//!    one tone, or one tone times a line where the line takes most of what the tone leaves
//!    next to it (an echo spread over less than a bin, such as the two tops of a step). What
//!    remains is every other echo, without the strongest one's lobe and sidelobes.
//! 2. The pipeline images that residual the same way as the capture, and takes Li's mask of
//!    the residual image, where it holds at least `hidden_floor` of the first image's peak
//!    and lies outside the first mask ([`hidden_voxels`]).
//! 3. Those voxels join the mask under a key of their own, so they form components apart from
//!    the first mask's even where they touch them. [`keep_above`] then keeps such a component
//!    only where it shares columns with the first components and its echo lies, over those
//!    columns, at least [`RISE_RANGE_BINS`] range bins above their |S|-weighted depth (both
//!    depths weighted by |S|: the residual's for the hidden component), and where no residual
//!    10 dB brighter than it lies elsewhere in those columns (it would be that echo's
//!    sidelobe).
//!
//! Step 3's rule has three reasons:
//! - A range lobe hides only what lies in its own columns. A component beside the bright one's
//!   columns was not hidden by its lobe, and is what the fit left (below).
//! - The residual holds what the fit leaves of the strongest echo (a surface is not exactly one
//!   tone). That residue lies at the surface's own depth, which its component already covers,
//!   and in a lobe about 0.665 bins on either side of it ([`RISE_RANGE_BINS`]). A flat plate's
//!   residue formed three components 0.4–1.0 cm from the plate; a pitcher's curved top,
//!   components 3.0–3.3 cm above it.
//! - Seen from above, a surface under a brighter one in the same columns is hidden by it, so a
//!   residual there is a sidelobe. A surface above a brighter one is not hidden: the cup's rim
//!   above its floor, a shoulder above a bottle's body.
//!
//! What it does not find: a surface less than 0.8 bins (4 cm) above a brighter one, such as the
//! capped bottle's shoulder 2.8 cm under its cap, which the line takes too or the rise rejects.
//!
//! A kept component leaves the others' antennas alone and draws a share of its own
//! (`subset.rs`); their levels are chosen before its own (`isosurface::staged_descent`).
//! `hidden_surfaces` is on by default (false keeps the paper's components only). The second
//! image costs 6–9 s at a 30×30 cm λ/4 aperture, and it can keep a small component where
//! nothing is (`docs/reconstruction.md`, step 4, has the figures).
//!
//! Neither the paper nor the authors' code does this: §8 names hollow objects as a limit of one
//! level per component.

use rayon::prelude::*;

use super::components::Components;

/// The voxels of the residual's mask (`residual_mask`, Li's on the residual image) where the
/// residual's |S| is at least `floor` and the first mask (`mask`) is not set.
pub fn hidden_voxels(
    residual_mask: &[bool],
    residual_magnitude: &[f32],
    mask: &[bool],
    floor: f32,
) -> Vec<bool> {
    (residual_mask.par_iter().zip(residual_magnitude).zip(mask))
        .map(|((&r, &m), &first)| r && m >= floor && !first)
        .collect()
}

/// A hidden component whose columns hold, outside it, a residual this much brighter than its
/// own peak (dB) is that echo's range sidelobe (13 dB under its main lobe, unwindowed).
pub const SIDELOBE_DB: f32 = 10.0;

/// How far a hidden component's echo must lie above the brighter surface, in range bins (c/2B).
/// A single tone fitted to an echo spread in range (a curved surface, two surfaces closer than
/// a bin) leaves a lobe on either side of it, the spectrum of τ·e^{j2πνt}: it peaks 0.665 bins
/// from the echo. Imaged, the upper lobe is a surface that is not there. On the reduced suite
/// such components lay 0.55–0.68 bins above the pitcher's and the YCB plate's tops (3 mm voxels,
/// 5 cm bins); the YCB cups' rims under point scatterers lie 0.88–1.09 bins above their floors.
/// Two surfaces much closer than a bin leave lobes further out, 0.85–0.89 bins on the 8 mm step
/// of `tests/recon_scenes.rs`: there the fit takes a line and leaves none
/// ([`NearEchoCanceller::without_strongest_in`](super::near_echo::NearEchoCanceller::without_strongest_in)).
pub const RISE_RANGE_BINS: f64 = 0.8;

/// What [`keep_above`] found.
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize)]
pub struct HiddenSummary {
    /// Voxels the residual's mask added.
    pub voxels: usize,
    /// Components made of them.
    pub components: usize,
    /// Those kept (above the other components, in columns they share).
    pub kept: usize,
}

/// Per component of `labelled`: whether it holds a voxel flagged in `hidden`. Hidden voxels
/// never share a component with the others (they join the mask under a key of their own), so
/// one voxel tells.
pub fn flagged_components(labelled: &Components, hidden: &[bool]) -> Vec<bool> {
    let mut flagged = vec![false; labelled.sizes.len()];
    for (v, &l) in labelled.labels.iter().enumerate() {
        if l != 0 && hidden[v] {
            flagged[l as usize - 1] = true;
        }
    }
    flagged
}

/// `labelled` without the components of `hidden` voxels that share no column with the other
/// components, or lie, over the columns they share, less than `rise_voxels` above those
/// components' |S|-weighted depth. A hidden component's rise is the mean over its voxels in
/// such columns, weighted by the residual's |S| (`residual_magnitude`): where its echo is, not
/// where its mask happens to reach. A component is dropped too when its columns hold, outside
/// it, a residual [`SIDELOBE_DB`] brighter than its own peak: it is that echo's sidelobe. Labels
/// are renumbered 1…m in their old order. Grids are C order with z fastest.
pub fn keep_above(
    labelled: Components,
    hidden: &[bool],
    magnitude: &[f32],
    residual_magnitude: &[f32],
    dims: [usize; 3],
    rise_voxels: f64,
) -> (Components, HiddenSummary) {
    let nz = dims[2];
    let n = labelled.sizes.len();
    // |S|-weighted depth of the other components in each column.
    let columns = dims[0] * dims[1];
    let mut weight = vec![0f64; columns];
    let mut moment = vec![0f64; columns];
    for (v, &l) in labelled.labels.iter().enumerate() {
        if l != 0 && !hidden[v] {
            let m = f64::from(magnitude[v]);
            weight[v / nz] += m;
            moment[v / nz] += m * (v % nz) as f64;
        }
    }
    let mut is_hidden = vec![false; n];
    // Per component: Σ w·rise and Σ w over its voxels in shared columns, w = residual |S|.
    let mut rise_sums = vec![(0f64, 0f64); n];
    for (v, &l) in labelled.labels.iter().enumerate() {
        if l == 0 || !hidden[v] {
            continue;
        }
        let k = l as usize - 1;
        is_hidden[k] = true;
        let c = v / nz;
        if weight[c] > 0.0 {
            let w = f64::from(residual_magnitude[v]);
            rise_sums[k].0 += w * ((v % nz) as f64 - moment[c] / weight[c]);
            rise_sums[k].1 += w;
        }
    }
    // Per component: its residual peak, and the residual's peak elsewhere in its columns.
    let mut own_peak = vec![0f32; n];
    let mut beside_peak = vec![0f32; n];
    let mut in_column: Vec<u32> = Vec::new();
    for c in 0..columns {
        let voxels = c * nz..(c + 1) * nz;
        in_column.clear();
        for v in voxels.clone() {
            let l = labelled.labels[v];
            if l != 0 && hidden[v] {
                own_peak[l as usize - 1] = own_peak[l as usize - 1].max(residual_magnitude[v]);
                if !in_column.contains(&l) {
                    in_column.push(l);
                }
            }
        }
        for &l in &in_column {
            let beside = (voxels.clone())
                .filter(|&v| labelled.labels[v] != l)
                .map(|v| residual_magnitude[v])
                .fold(0.0f32, f32::max);
            beside_peak[l as usize - 1] = beside_peak[l as usize - 1].max(beside);
        }
    }
    let sidelobe = 10f32.powf(SIDELOBE_DB / 20.0);
    let keep: Vec<bool> = (0..n)
        .map(|k| {
            let (sum, w) = rise_sums[k];
            if is_hidden[k] {
                tracing::debug!(
                    "hidden component {}: {} voxels, rise {:.1} voxels, beside {:.1} dB",
                    k + 1,
                    labelled.sizes[k],
                    if w > 0.0 { sum / w } else { f64::NAN },
                    20.0 * (beside_peak[k] / own_peak[k]).log10()
                );
            }
            !is_hidden[k]
                || (w > 0.0 && sum / w >= rise_voxels && beside_peak[k] < own_peak[k] * sidelobe)
        })
        .collect();
    let summary = HiddenSummary {
        voxels: hidden.iter().filter(|&&h| h).count(),
        components: is_hidden.iter().filter(|&&h| h).count(),
        kept: (0..n).filter(|&k| is_hidden[k] && keep[k]).count(),
    };
    (labelled.retain(&keep), summary)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::recon::components::label_6_keyed;

    /// A 6×1×40 grid: a bright "floor" over columns 0–3 at z 5–9, and four hidden blocks: one
    /// 20 voxels above the floor in columns 2–3 (a rim), one at the floor's depth in columns
    /// 2–3 but apart from it (residue), one under it in columns 0–1 (a sidelobe), one in
    /// column 5 alone (beside the floor). With a rise of 10 voxels only the rim stays.
    #[test]
    fn only_hidden_components_above_the_bright_ones_stay() {
        let dims = [6, 1, 40];
        let at = |x: usize, z: usize| x * 40 + z;
        let mut keys = vec![0u32; 240];
        let mut magnitude = vec![0f32; 240];
        let mut hidden = vec![false; 240];
        for x in 0..4 {
            for z in 5..10 {
                keys[at(x, z)] = 1;
                magnitude[at(x, z)] = 10.0;
            }
        }
        let mut block = |xs: std::ops::Range<usize>, zs: std::ops::Range<usize>| {
            for x in xs {
                for z in zs.clone() {
                    keys[at(x, z)] = 2;
                    hidden[at(x, z)] = true;
                    magnitude[at(x, z)] = 1.0;
                }
            }
        };
        block(2..4, 26..31); // rim: 21 voxels above the floor's centre (z 7)
        block(2..4, 11..13); // residue: 5 above
        block(0..2, 0..3); // under the floor
        block(5..6, 26..31); // beside the floor's columns
        let labelled = label_6_keyed(&keys, dims, 1);
        assert_eq!(labelled.sizes.len(), 5);
        // The residual holds the hidden blocks only: the floor's echo was removed.
        let residual: Vec<f32> = (0..240)
            .map(|v| if hidden[v] { magnitude[v] } else { 0.0 })
            .collect();
        let (kept, summary) = keep_above(labelled, &hidden, &magnitude, &residual, dims, 10.0);
        assert_eq!(
            summary,
            HiddenSummary {
                voxels: 10 + 4 + 6 + 5,
                components: 4,
                kept: 1,
            }
        );
        assert_eq!(kept.sizes, vec![20, 10]);
        assert_eq!(kept.labels[at(0, 5)], 1, "the floor");
        assert_eq!(kept.labels[at(2, 28)], 2, "the rim");
        for v in [at(2, 11), at(0, 1), at(5, 28)] {
            assert_eq!(kept.labels[v], 0);
        }
    }

    #[test]
    fn hidden_voxels_lie_in_the_residual_mask_above_the_floor_and_outside_the_first_mask() {
        let residual_mask = [true, true, true, false];
        let magnitude = [2.0, 0.5, 2.0, 2.0];
        let mask = [false, false, true, false];
        assert_eq!(
            hidden_voxels(&residual_mask, &magnitude, &mask, 1.0),
            vec![true, false, false, false]
        );
    }
}
