//! PNG pictures for people: scalar maps drawn with a perceptual colour map, as figures with a
//! title, axes in centimetres, a colour bar, and the truth under the data where it is known.

use std::path::Path;

use crate::plot::{BLACK, Canvas, GREY, LIGHT, WHITE, linear_ticks};

/// A scalar image, row-major, row 0 at the top.
pub struct ScalarImage {
    pub width: usize,
    pub height: usize,
    /// Values; NaN cells are drawn in dark grey.
    pub values: Vec<f32>,
}

/// Why a picture could not be written.
#[derive(Debug, thiserror::Error)]
#[error("cannot write picture {path}: {reason}")]
pub struct PreviewError {
    pub path: String,
    pub reason: String,
}

/// Anchor colours of the viridis map at 0, 0.25, 0.5, 0.75 and 1.
const VIRIDIS: [[f32; 3]; 5] = [
    [68.0, 1.0, 84.0],
    [59.0, 82.0, 139.0],
    [33.0, 145.0, 140.0],
    [94.0, 201.0, 98.0],
    [253.0, 231.0, 37.0],
];

/// The viridis colour of `x` in 0…1 (clamped).
pub fn viridis(x: f32) -> [u8; 3] {
    let x = x.clamp(0.0, 1.0) * 4.0;
    let i = (x.floor() as usize).min(3);
    let f = x - i as f32;
    [0, 1, 2].map(|k| (VIRIDIS[i][k] * (1.0 - f) + VIRIDIS[i + 1][k] * f).round() as u8)
}

/// A map drawn as a figure: `image` spans `x_m` (left edge to right edge) across and `y_m`
/// (bottom edge to top edge) up, in metres; the axes are labelled in centimetres.
pub struct MapFigure<'a> {
    pub title: &'a str,
    pub image: &'a ScalarImage,
    pub x_m: (f64, f64),
    pub y_m: (f64, f64),
    /// Axis names without the unit, e.g. "x" and "y" (the figure adds "(cm)").
    pub x_name: &'a str,
    pub y_name: &'a str,
    pub colour: ColourBar,
    /// Points (metres, on the figure's two axes) drawn in grey under the data, with their
    /// legend text: where the data are missing, the truth shows.
    pub truth: Option<(&'a [[f64; 2]], &'a str)>,
    /// Pixels per cell, at least 1.
    pub zoom: usize,
}

/// The colour scale: `lo` maps to the bottom of viridis and `hi` to the top; the bar's labels
/// print `value × label_scale` (100 to print metres as centimetres, 1 for dB).
pub struct ColourBar {
    pub lo: f32,
    pub hi: f32,
    pub label: String,
    pub label_scale: f64,
}

/// Background of cells without data.
const EMPTY: [u8; 3] = [250, 250, 250];
/// The truth under the data.
const TRUTH: [u8; 3] = [175, 175, 175];
const MARGIN_LEFT: i64 = 64;
const MARGIN_TOP: i64 = 52;
const MARGIN_BOTTOM: i64 = 54;
const MARGIN_RIGHT: i64 = 120;
const BAR_WIDTH: i64 = 16;

/// A rectangle of pixels on a canvas.
pub struct PanelRect {
    pub x: i64,
    pub y: i64,
    pub width: i64,
    pub height: i64,
}

/// A frame around `rect` with ticks and labels in centimetres: `x_m` spans the rectangle from
/// its left edge to its right edge and `y_m` from its bottom edge to its top edge (metres).
pub fn draw_axes_cm(c: &mut Canvas, rect: &PanelRect, x_m: (f64, f64), y_m: (f64, f64)) {
    let (x0, y0, w, h) = (
        rect.x as f64,
        rect.y as f64,
        rect.width as f64,
        rect.height as f64,
    );
    let span = |(a, b): (f64, f64)| if b > a { b - a } else { 1.0 };
    c.line((x0 - 1.0, y0 - 1.0), (x0 + w, y0 - 1.0), GREY, 1, 0);
    c.line((x0 + w, y0 - 1.0), (x0 + w, y0 + h), GREY, 1, 0);
    c.line((x0 - 1.0, y0 + h), (x0 + w, y0 + h), BLACK, 1, 0);
    c.line((x0 - 1.0, y0 - 1.0), (x0 - 1.0, y0 + h), BLACK, 1, 0);
    let count = |pixels: f64| (pixels / 70.0).clamp(2.0, 6.0);
    for (x_cm, label) in linear_ticks(x_m.0 * 100.0, x_m.1 * 100.0, count(w)) {
        let px = (x0 + (x_cm / 100.0 - x_m.0) / span(x_m) * w).round();
        c.line((px, y0 + h), (px, y0 + h + 4.0), BLACK, 1, 0);
        let tw = Canvas::text_width(&label, 1);
        c.text(
            px as i64 - tw / 2,
            rect.y + rect.height + 8,
            &label,
            BLACK,
            1,
        );
    }
    for (y_cm, label) in linear_ticks(y_m.0 * 100.0, y_m.1 * 100.0, count(h)) {
        let py = (y0 + h - (y_cm / 100.0 - y_m.0) / span(y_m) * h).round();
        c.line((x0 - 5.0, py), (x0 - 1.0, py), BLACK, 1, 0);
        let tw = Canvas::text_width(&label, 1);
        c.text(rect.x - 8 - tw, py as i64 - 4, &label, BLACK, 1);
    }
}

/// A vertical viridis bar in `rect`, `lo` at the bottom and `hi` at the top, with both ends and
/// the middle labelled to its right (as printed: the caller scales to the unit it names).
pub fn draw_colour_bar(c: &mut Canvas, rect: &PanelRect, lo: f64, hi: f64) {
    let (bx, y0, bw, h) = (rect.x, rect.y, rect.width, rect.height);
    for k in 0..h {
        let t = 1.0 - k as f32 / (h - 1).max(1) as f32;
        c.fill_rect(bx, y0 + k, bw, 1, viridis(t));
    }
    for e in 0..bw {
        c.set(bx + e, y0 - 1, LIGHT);
        c.set(bx + e, y0 + h, LIGHT);
    }
    let digits = if (hi - lo).abs() >= 10.0 { 0 } else { 1 };
    for t in [0.0, 0.5, 1.0] {
        let py = y0 + ((1.0 - t) * (h - 1) as f64).round() as i64;
        // The tick sits on the bar's left, so that it cannot read as a minus sign.
        c.line(
            ((bx - 4) as f64, py as f64),
            ((bx - 1) as f64, py as f64),
            BLACK,
            1,
            0,
        );
        let value = lo + t * (hi - lo);
        c.text(bx + bw + 4, py - 4, &format!("{value:.digits$}"), BLACK, 1);
    }
}

impl MapFigure<'_> {
    /// The figure as a canvas.
    pub fn draw(&self) -> Canvas {
        let zoom = self.zoom.max(1) as i64;
        let (mw, mh) = (
            self.image.width as i64 * zoom,
            self.image.height as i64 * zoom,
        );
        let title_scale =
            if Canvas::text_width(self.title, 2) + 16 <= MARGIN_LEFT + mw + MARGIN_RIGHT {
                2
            } else {
                1
            };
        let width = (MARGIN_LEFT + mw + MARGIN_RIGHT).max(Canvas::text_width(self.title, 1) + 16);
        let height = MARGIN_TOP + mh + MARGIN_BOTTOM;
        let mut c = Canvas::new(width as usize, height as usize, WHITE);
        c.text(8, 8, self.title, BLACK, title_scale);
        let (x0, y0) = (MARGIN_LEFT, MARGIN_TOP);
        c.fill_rect(x0, y0, mw, mh, EMPTY);
        // Metres to pixels inside the map.
        let (xa, xb) = self.x_m;
        let (ya, yb) = self.y_m;
        let span = |a: f64, b: f64| if b > a { b - a } else { 1.0 };
        let px_x = |x: f64| x0 as f64 + (x - xa) / span(xa, xb) * mw as f64;
        let px_y = |y: f64| y0 as f64 + mh as f64 - (y - ya) / span(ya, yb) * mh as f64;
        if let Some((points, legend)) = self.truth {
            for p in points {
                let (x, y) = (px_x(p[0]).floor() as i64, px_y(p[1]).floor() as i64);
                if x >= x0 && x < x0 + mw && y >= y0 && y < y0 + mh {
                    c.fill_rect(x, y, 2.min(x0 + mw - x), 2.min(y0 + mh - y), TRUTH);
                }
            }
            c.fill_rect(8, y0 + mh + 38, 10, 10, TRUTH);
            c.text(22, y0 + mh + 39, legend, BLACK, 1);
        }
        let bar = &self.colour;
        let span_c = if bar.hi > bar.lo {
            bar.hi - bar.lo
        } else {
            1.0
        };
        for j in 0..self.image.height {
            for i in 0..self.image.width {
                let v = self.image.values[j * self.image.width + i];
                if !v.is_nan() {
                    let colour = viridis((v - bar.lo) / span_c);
                    c.fill_rect(
                        x0 + i as i64 * zoom,
                        y0 + j as i64 * zoom,
                        zoom,
                        zoom,
                        colour,
                    );
                }
            }
        }
        let rect = PanelRect {
            x: x0,
            y: y0,
            width: mw,
            height: mh,
        };
        draw_axes_cm(&mut c, &rect, self.x_m, self.y_m);
        let x_label = format!("{} (cm)", self.x_name);
        let w = Canvas::text_width(&x_label, 1);
        c.text(x0 + mw / 2 - w / 2, y0 + mh + 24, &x_label, BLACK, 1);
        c.text(4, y0 - 12, &format!("{} (cm)", self.y_name), BLACK, 1);
        draw_colour_bar(
            &mut c,
            &PanelRect {
                x: x0 + mw + 16,
                y: y0,
                width: BAR_WIDTH,
                height: mh,
            },
            bar.lo as f64 * bar.label_scale,
            bar.hi as f64 * bar.label_scale,
        );
        c.text(
            width - 4 - Canvas::text_width(&bar.label, 1),
            y0 - 22,
            &bar.label,
            BLACK,
            1,
        );
        c
    }

    /// Writes the figure as a PNG (atomically).
    pub fn write_png(&self, path: &Path) -> Result<(), PreviewError> {
        self.draw().write_png(path)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 10×10 map of 1 cm cells over x 0…10 cm, y 0…10 cm: the left half holds data (height
    /// 5 cm), the right half is empty; the truth covers the whole square.
    fn figure_canvas(with_truth: bool) -> Canvas {
        let values = (0..100)
            .map(|k| if k % 10 < 5 { 0.05 } else { f32::NAN })
            .collect();
        let image = ScalarImage {
            width: 10,
            height: 10,
            values,
        };
        let truth: Vec<[f64; 2]> = (0..100)
            .flat_map(|i| (0..100).map(move |j| [i as f64 * 1e-3, j as f64 * 1e-3]))
            .collect();
        MapFigure {
            title: "test",
            image: &image,
            x_m: (0.0, 0.1),
            y_m: (0.0, 0.1),
            x_name: "x",
            y_name: "y",
            colour: ColourBar {
                lo: 0.0,
                hi: 0.1,
                label: "height z (cm)".into(),
                label_scale: 100.0,
            },
            truth: with_truth.then_some((truth.as_slice(), "truth")),
            zoom: 20,
        }
        .draw()
    }

    #[test]
    fn the_truth_shows_where_the_data_are_missing_and_the_bar_spans_the_colour_map() {
        let c = figure_canvas(true);
        let (x0, y0) = (MARGIN_LEFT, MARGIN_TOP);
        // A data cell (left half) in the map's colour for 5 of 10 cm, a missing one in grey.
        assert_eq!(c.get(x0 + 30, y0 + 100), Some(viridis(0.5)));
        assert_eq!(c.get(x0 + 150, y0 + 101), Some(TRUTH));
        // Without the truth the missing cell is background.
        assert_eq!(figure_canvas(false).get(x0 + 150, y0 + 101), Some(EMPTY));
        // The bar: top is the map's top colour, bottom its bottom colour.
        let bx = x0 + 200 + 16 + 2;
        assert_eq!(c.get(bx, y0), Some(viridis(1.0)));
        assert_eq!(c.get(bx, y0 + 199), Some(viridis(0.0)));
        // Title, tick labels and bar labels draw black pixels in their margins.
        let black_in = |x: std::ops::Range<i64>, y: std::ops::Range<i64>| {
            x.flat_map(|i| y.clone().map(move |j| (i, j)))
                .filter(|&(i, j)| c.get(i, j) == Some(BLACK))
                .count()
        };
        assert!(black_in(0..200, 0..30) > 50, "title");
        assert!(
            black_in(x0..x0 + 200, y0 + 206..y0 + 218) > 20,
            "x tick labels"
        );
        assert!(black_in(0..x0 - 6, y0..y0 + 200) > 20, "y tick labels");
        assert!(black_in(bx + 16..bx + 60, y0..y0 + 200) > 20, "bar labels");
    }

    #[test]
    fn ticks_fall_on_round_centimetres() {
        let t = linear_ticks(-3.0, 13.8, 5.0);
        let values: Vec<f64> = t.iter().map(|(v, _)| *v).collect();
        assert_eq!(values, vec![0.0, 5.0, 10.0]);
        let labels: Vec<&str> = t.iter().map(|(_, l)| l.as_str()).collect();
        assert_eq!(labels, vec!["0", "5", "10"]);
        let quarter = linear_ticks(0.0, 1.0, 4.0);
        assert_eq!(quarter[1].1, "0.25");
    }
}
