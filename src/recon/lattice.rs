//! Whether a capture's aperture is a raster: its virtual phase centres on one uniform,
//! axis-aligned, horizontal grid, which range-migration imaging ([`super::rma`]) needs.
//!
//! Each antenna's phase centre (TX + RX)/2 is assigned to the nearest node of a lattice
//! `origin + (i·dx, j·dy)` at height z. The spacing along each axis is the median of the gaps
//! between sorted centre coordinates that are not jitter (see `estimate_spacing`), then origin
//! and spacing are refined by least squares over the node indices. The
//! IWR1443BOOST's four RX channels, λ/2 apart, put their phase centres λ/4 apart: with a λ/4 or
//! λ/2 raster they share one lattice, several antennas to a node.
//!
//! A robot never lands exactly on the nodes. Snapping a centre that is δ off its node to it
//! changes the round trip to a scatterer in direction u by 2·δ·u: that is the error resampling
//! adds. The vertical part is corrected exactly for broadside echoes by a phase (see
//! [`super::rma`]); the lateral part is left, and bounded here by
//! `max_offset_fraction`·spacing, a phase error of at most 4π·δ·sin θ/λ (0.26 rad at 55° for
//! 0.1 of a λ/4 spacing). A capture outside that bound is not a raster and is imaged by
//! backprojection.

use serde::Serialize;

use crate::capture::Capture;

/// A raster of phase centres.
#[derive(Debug, Clone, Serialize)]
pub struct Lattice {
    /// Node (0, 0), metres.
    pub origin_m: [f64; 2],
    pub spacing_m: [f64; 2],
    /// Nodes along x and y.
    pub dims: [usize; 2],
    /// Height of the lattice plane (mean of the centres), metres.
    pub z_m: f64,
    /// Node of each antenna, `i + dims[0]·j`.
    #[serde(skip)]
    pub node_of: Vec<usize>,
    /// Each antenna's centre minus its node, metres.
    #[serde(skip)]
    pub offset_m: Vec<[f64; 3]>,
    /// Largest lateral and vertical offsets, metres.
    pub max_lateral_offset_m: f64,
    pub max_vertical_offset_m: f64,
    /// Nodes holding at least one antenna, over all nodes.
    pub occupancy: f64,
}

/// Why an aperture is not a raster.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum NotRaster {
    #[error("the phase centres span fewer than {min} distinct positions along {axis} ({found})")]
    TooFewPositions {
        axis: char,
        found: usize,
        min: usize,
    },
    #[error(
        "a phase centre lies {offset_m:.2e} m from its raster node along {axis}, more than {limit_m:.2e} m ({fraction} of the {spacing_m:.3e} m spacing)"
    )]
    OffGrid {
        axis: char,
        offset_m: f64,
        limit_m: f64,
        fraction: f64,
        spacing_m: f64,
    },
    #[error("the raster has {nodes} nodes, over the limit of {limit}")]
    TooLarge { nodes: usize, limit: usize },
}

/// Fewest distinct positions per axis for a raster.
pub const MIN_POSITIONS: usize = 4;
/// Most lattice nodes accepted (a 2 m × 2 m raster at λ/4).
pub const MAX_NODES: usize = 5_000_000;

/// Finds the lattice of `capture`'s phase centres, with every centre within
/// `max_offset_fraction` of the spacing from its node along each axis (and vertically, of the
/// larger spacing).
pub fn detect(capture: &Capture, max_offset_fraction: f64) -> Result<Lattice, NotRaster> {
    let centres = capture.centres_m();
    let mut axes = [(0.0, 0.0, 0usize); 2];
    let mut index = vec![[0usize; 2]; centres.len()];
    for (a, name) in [(0usize, 'x'), (1, 'y')] {
        let values: Vec<f64> = centres.iter().map(|c| c[a]).collect();
        let spacing = estimate_spacing(&values).ok_or(NotRaster::TooFewPositions {
            axis: name,
            found: distinct(&values),
            min: MIN_POSITIONS,
        })?;
        let (origin, spacing, count) = fit_axis(&values, spacing, &mut index, a);
        if count < MIN_POSITIONS {
            return Err(NotRaster::TooFewPositions {
                axis: name,
                found: count,
                min: MIN_POSITIONS,
            });
        }
        axes[a] = (origin, spacing, count);
    }
    let dims = [axes[0].2, axes[1].2];
    let nodes = dims[0].saturating_mul(dims[1]);
    if nodes > MAX_NODES {
        return Err(NotRaster::TooLarge {
            nodes,
            limit: MAX_NODES,
        });
    }
    let z_m = centres.iter().map(|c| c[2]).sum::<f64>() / centres.len().max(1) as f64;
    let mut offset_m = Vec::with_capacity(centres.len());
    let mut node_of = Vec::with_capacity(centres.len());
    let (mut lateral, mut vertical) = (0.0f64, 0.0f64);
    for (c, ij) in centres.iter().zip(&index) {
        let o = [
            c[0] - (axes[0].0 + axes[0].1 * ij[0] as f64),
            c[1] - (axes[1].0 + axes[1].1 * ij[1] as f64),
            c[2] - z_m,
        ];
        for (a, name) in [(0usize, 'x'), (1, 'y')] {
            let limit_m = max_offset_fraction * axes[a].1;
            if o[a].abs() > limit_m {
                return Err(NotRaster::OffGrid {
                    axis: name,
                    offset_m: o[a].abs(),
                    limit_m,
                    fraction: max_offset_fraction,
                    spacing_m: axes[a].1,
                });
            }
        }
        let limit_z = max_offset_fraction * axes[0].1.max(axes[1].1);
        if o[2].abs() > limit_z {
            return Err(NotRaster::OffGrid {
                axis: 'z',
                offset_m: o[2].abs(),
                limit_m: limit_z,
                fraction: max_offset_fraction,
                spacing_m: axes[0].1.max(axes[1].1),
            });
        }
        lateral = lateral.max(o[0].hypot(o[1]));
        vertical = vertical.max(o[2].abs());
        offset_m.push(o);
        node_of.push(ij[0] + dims[0] * ij[1]);
    }
    let mut occupied = vec![false; nodes];
    for &n in &node_of {
        occupied[n] = true;
    }
    let occupancy = occupied.iter().filter(|&&o| o).count() as f64 / nodes.max(1) as f64;
    Ok(Lattice {
        origin_m: [axes[0].0, axes[1].0],
        spacing_m: [axes[0].1, axes[1].1],
        dims,
        z_m,
        node_of,
        offset_m,
        max_lateral_offset_m: lateral,
        max_vertical_offset_m: vertical,
        occupancy,
    })
}

/// Coordinates closer than this are one position.
const SAME_POSITION_M: f64 = 1e-6;

fn distinct(values: &[f64]) -> usize {
    let mut v = values.to_vec();
    v.sort_by(f64::total_cmp);
    v.windows(2)
        .filter(|w| w[1] - w[0] > SAME_POSITION_M)
        .count()
        + usize::from(!v.is_empty())
}

/// The spacing of sorted coordinates: the median of the gaps over a quarter of the largest,
/// then the median of the gaps over half of that (so a few missing rows do not skew it); None
/// when the values hold fewer than [`MIN_POSITIONS`] distinct positions.
fn estimate_spacing(values: &[f64]) -> Option<f64> {
    let mut v = values.to_vec();
    v.sort_by(f64::total_cmp);
    let gaps: Vec<f64> = v
        .windows(2)
        .map(|w| w[1] - w[0])
        .filter(|g| *g > SAME_POSITION_M)
        .collect();
    if gaps.len() + 1 < MIN_POSITIONS {
        return None;
    }
    let median_above = |threshold: f64| {
        let mut large: Vec<f64> = gaps.iter().copied().filter(|g| *g > threshold).collect();
        large.sort_by(f64::total_cmp);
        large.get(large.len() / 2).copied()
    };
    let largest = gaps.iter().copied().fold(0.0, f64::max);
    let rough = median_above(0.25 * largest)?;
    let spacing = median_above(0.5 * rough)?;
    (spacing.is_finite() && spacing > 0.0).then_some(spacing)
}

/// Node indices along axis `a`, then origin and spacing refitted by least squares; returns
/// (origin, spacing, node count). Sorted coordinates start a new node where they jump by more
/// than half a spacing, and the index advances by the jump in spacings, rounded: each step is
/// local, so an error in `spacing` does not build up across a long raster.
fn fit_axis(values: &[f64], spacing: f64, index: &mut [[usize; 2]], a: usize) -> (f64, f64, usize) {
    let mut order: Vec<usize> = (0..values.len()).collect();
    order.sort_by(|&p, &q| values[p].total_cmp(&values[q]));
    let mut ids = vec![0.0f64; values.len()];
    let mut current = 0usize;
    for w in 0..order.len() {
        if w > 0 {
            let gap = values[order[w]] - values[order[w - 1]];
            if gap > 0.5 * spacing {
                current += (gap / spacing).round().max(1.0) as usize;
            }
        }
        ids[order[w]] = current as f64;
    }
    let n = values.len() as f64;
    let (mean_i, mean_v) = (ids.iter().sum::<f64>() / n, values.iter().sum::<f64>() / n);
    let (mut sxy, mut sxx) = (0.0, 0.0);
    for (i, v) in ids.iter().zip(values) {
        sxy += (i - mean_i) * (v - mean_v);
        sxx += (i - mean_i) * (i - mean_i);
    }
    let fitted = if sxx > 0.0 { sxy / sxx } else { spacing };
    let origin = mean_v - fitted * mean_i;
    for (slot, i) in index.iter_mut().zip(&ids) {
        slot[a] = *i as usize;
    }
    (origin, fitted, current + 1)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::capture::FrequencyPlan;
    use crate::signal::Rng;

    fn capture(tx: Vec<[f64; 3]>, rx: Vec<[f64; 3]>) -> Capture {
        let n = tx.len();
        Capture {
            plan: FrequencyPlan {
                start_frequency_hz: 77e9,
                frequency_step_hz: 1e7,
                samples_per_chirp: 4,
            },
            range_offset_m: 0.0,
            tx_m: tx,
            rx_m: rx,
            samples: vec![num_complex::Complex32::new(0.0, 0.0); 4 * n].into(),
            description: String::new(),
            extra: Default::default(),
        }
    }

    /// Four RX channels λ/2 apart on a λ/4 raster, with robot jitter: one lattice at λ/4, the
    /// jitter reported, every antenna on the node it came from.
    #[test]
    fn finds_the_shared_lattice_of_four_channels() {
        let q = 0.000_97;
        let mut rng = Rng::new(9);
        let (mut tx, mut rx, mut truth) = (vec![], vec![], vec![]);
        for r in 0..20 {
            for c in 0..30 {
                let jitter = [
                    0.05 * q * (rng.uniform() - 0.5),
                    0.05 * q * (rng.uniform() - 0.5),
                ];
                let t = [
                    0.1 + c as f64 * q + jitter[0],
                    -0.05 + r as f64 * q + jitter[1],
                    0.4,
                ];
                for k in 0..4 {
                    let o = -0.011 + 2.0 * q * k as f64;
                    tx.push(t);
                    rx.push([t[0] + o, t[1], t[2]]);
                    // Centre = t + o/2 = node c + k − 5.67 (in units of q): node index below.
                    truth.push((c as f64 + (o / 2.0) / q, r));
                }
            }
        }
        let lattice = detect(&capture(tx, rx), 0.1).unwrap();
        assert!(
            (lattice.spacing_m[0] - q).abs() < 1e-3 * q,
            "{:?}",
            lattice.spacing_m
        );
        assert!((lattice.spacing_m[1] - q).abs() < 1e-3 * q);
        assert_eq!(lattice.dims, [33, 20]);
        assert!(lattice.max_lateral_offset_m < 0.05 * q);
        let first_x = truth.iter().map(|t| t.0).fold(f64::INFINITY, f64::min);
        for (a, (x, r)) in truth.iter().enumerate() {
            let i = (x - first_x).round() as usize;
            assert_eq!(lattice.node_of[a], i + 33 * r, "antenna {a}");
        }
        assert!(lattice.occupancy > 0.9);
    }

    #[test]
    fn refuses_a_line_and_an_irregular_cloud() {
        let line: Vec<[f64; 3]> = (0..50).map(|i| [i as f64 * 0.002, 0.0, 0.3]).collect();
        assert!(matches!(
            detect(&capture(line.clone(), line), 0.1),
            Err(NotRaster::TooFewPositions { axis: 'y', .. })
        ));
        let mut rng = Rng::new(1);
        let cloud: Vec<[f64; 3]> = (0..400)
            .map(|_| [0.1 * rng.uniform(), 0.1 * rng.uniform(), 0.3])
            .collect();
        let err = detect(&capture(cloud.clone(), cloud), 0.1).unwrap_err();
        assert!(matches!(err, NotRaster::OffGrid { .. }), "{err}");
    }
}
