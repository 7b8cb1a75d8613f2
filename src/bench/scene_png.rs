//! One picture per case in the style of the paper's Fig. 10: truth, mmNorm and the
//! backprojection baseline, from the top (colour = height) and from the side (colour = y), all
//! panels on the same axes so their sizes and positions compare directly.
//!
//! A reconstruction's points sit on its voxel lattice. Each is drawn as a square at least one
//! voxel wide, so that a surface covered at the voxel pitch shows as a solid patch; squares of a
//! fixed size alias against the pixel grid into stripes that look like structure.

use std::path::Path;

use crate::plot::{BLACK, Canvas, WHITE};
use crate::preview::{PanelRect, PreviewError, draw_axes_cm, draw_colour_bar, viridis};

const PANEL: i64 = 240;
/// Between panels: room for the next panel's tick labels.
const GAP: i64 = 44;
const BAR_WIDTH: i64 = 14;
/// Right of the panels: a colour bar per row and its labels.
const BAR_MARGIN: i64 = 80;
const HEAD: i64 = 44;
const LABEL: i64 = 48;

/// Smallest square drawn for a point, pixels.
const MIN_DOT_PX: i64 = 2;

/// Draws the six panels into `path`; points outside the truth's box plus 3 cm are left out.
/// `voxel_m` is the reconstructions' lattice pitch.
pub fn write_scene_png(
    path: &Path,
    title: &str,
    truth: &[[f64; 3]],
    mmnorm: &[[f64; 3]],
    backprojection: &[[f64; 3]],
    voxel_m: f64,
) -> Result<(), PreviewError> {
    draw_scene(title, truth, mmnorm, backprojection, voxel_m).write_png(path)
}

/// The picture of [`write_scene_png`].
fn draw_scene(
    title: &str,
    truth: &[[f64; 3]],
    mmnorm: &[[f64; 3]],
    backprojection: &[[f64; 3]],
    voxel_m: f64,
) -> Canvas {
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for p in truth {
        for k in 0..3 {
            lo[k] = lo[k].min(p[k] - 0.03);
            hi[k] = hi[k].max(p[k] + 0.03);
        }
    }
    if !lo[0].is_finite() {
        lo = [-0.1; 3];
        hi = [0.1; 3];
    }
    let columns = [
        ("truth", truth),
        ("mmNorm", mmnorm),
        ("backprojection", backprojection),
    ];
    let width = LABEL + 3 * PANEL + 4 * GAP + BAR_MARGIN;
    let height = HEAD + 2 * (PANEL + GAP + 14);
    let mut c = Canvas::new(width as usize, height as usize, WHITE);
    c.text(GAP, 10, title, BLACK, 2);
    // One metres-per-pixel for every panel: the largest extent fills a panel.
    let span = (0..3)
        .map(|k| hi[k] - lo[k])
        .fold(0.0f64, f64::max)
        .max(1e-3);
    let scale = (PANEL - 8) as f64 / span;
    // The truth is a dense sample of the mesh; the reconstructions lie on the voxel lattice.
    let lattice_px = if voxel_m.is_finite() && voxel_m > 0.0 {
        ((voxel_m * scale).ceil() as i64).clamp(MIN_DOT_PX, PANEL / 8)
    } else {
        MIN_DOT_PX
    };
    for (row, (name, u, v, colour_axis)) in [("top", 0usize, 1usize, 2usize), ("side", 0, 2, 1)]
        .into_iter()
        .enumerate()
    {
        let y0 = HEAD + row as i64 * (PANEL + GAP + 14) + 14;
        c.text(4, y0 + PANEL / 2 - 4, name, BLACK, 1);
        for (col, (label, points)) in columns.iter().enumerate() {
            let dot = if col == 0 { MIN_DOT_PX } else { lattice_px };
            let x0 = LABEL + GAP + col as i64 * (PANEL + GAP);
            c.fill_rect(x0, y0, PANEL, PANEL, [245, 245, 245]);
            // The panel spans PANEL / scale metres about the box's centre on both axes.
            let half_m = PANEL as f64 / 2.0 / scale;
            let (cu, cv) = ((lo[u] + hi[u]) / 2.0, (lo[v] + hi[v]) / 2.0);
            draw_axes_cm(
                &mut c,
                &PanelRect {
                    x: x0,
                    y: y0,
                    width: PANEL,
                    height: PANEL,
                },
                (cu - half_m, cu + half_m),
                (cv - half_m, cv + half_m),
            );
            if row == 0 {
                let text = format!("{label} ({})", points.len());
                c.text(x0, y0 - 14, &text, BLACK, 1);
            }
            // Centre the box in the panel; draw far points first so near ones stay on top.
            let mut order: Vec<&[f64; 3]> = points
                .iter()
                .filter(|p| (0..3).all(|k| p[k] >= lo[k] && p[k] <= hi[k]))
                .collect();
            order.sort_by(|a, b| a[colour_axis].total_cmp(&b[colour_axis]));
            if colour_axis == 1 {
                order.reverse();
            }
            for p in order {
                let x = x0 + PANEL / 2 + ((p[u] - cu) * scale).round() as i64;
                let y = y0 + PANEL / 2 - ((p[v] - cv) * scale).round() as i64;
                let t = (p[colour_axis] - lo[colour_axis]) / (hi[colour_axis] - lo[colour_axis]);
                let half = (dot - 1) / 2;
                c.fill_rect(x - half, y - half, dot, dot, viridis(t as f32));
            }
        }
        let bx = LABEL + 3 * (PANEL + GAP) + GAP;
        c.text(bx - 8, y0 - 14, ["z (cm)", "y (cm)"][row], BLACK, 1);
        draw_colour_bar(
            &mut c,
            &PanelRect {
                x: bx,
                y: y0,
                width: BAR_WIDTH,
                height: PANEL,
            },
            lo[colour_axis] * 100.0,
            hi[colour_axis] * 100.0,
        );
    }
    let bar = format!(
        "axes in cm, panels {:.0} cm across; top: x-y, colour = height z; side: x-z, colour = y",
        span * 100.0
    );
    c.text(GAP, height - 12, &bar, BLACK, 1);
    c
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Pixels of the top-row panel `col` that still show the panel's background, within the
    /// square of `half_px` around its centre.
    fn background_pixels(c: &Canvas, col: i64, half_px: i64) -> usize {
        let x0 = LABEL + GAP + col * (PANEL + GAP);
        let y0 = HEAD + 14;
        let (cx, cy) = (x0 + PANEL / 2, y0 + PANEL / 2);
        let mut n = 0;
        for y in cy - half_px..=cy + half_px {
            for x in cx - half_px..=cx + half_px {
                if c.get(x, y) == Some([245, 245, 245]) {
                    n += 1;
                }
            }
        }
        n
    }

    #[test]
    fn a_surface_covered_at_the_voxel_pitch_is_drawn_without_gaps() {
        // A flat 20 cm square sampled on a 3 mm lattice, in a 26 cm panel: 2.7 pixels a voxel,
        // where 2-pixel dots leave a blank column every few voxels.
        let voxel_m = 0.003;
        let lattice: Vec<[f64; 3]> = (-33..=33)
            .flat_map(|i| (-33..=33).map(move |j| [i as f64 * voxel_m, j as f64 * voxel_m, 0.1]))
            .collect();
        let c = draw_scene("t", &lattice, &lattice, &lattice, voxel_m);
        assert_eq!(background_pixels(&c, 1, 60), 0, "mmNorm panel");
        assert_eq!(background_pixels(&c, 2, 60), 0, "backprojection panel");
        let fixed = draw_scene("t", &lattice, &lattice, &lattice, 0.0);
        assert!(
            background_pixels(&fixed, 1, 60) > 100,
            "fixed 2-pixel dots leave stripes, so the check above can fail"
        );
    }
}
