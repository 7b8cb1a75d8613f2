//! Charts for people: an RGB canvas with lines, markers and 8×8 bitmap text (ASCII), and the CDF
//! chart of the paper's Fig. 12–15. No font files, no system libraries.

use std::path::Path;

use crate::capture::dir::write_atomically;
use crate::preview::PreviewError;

pub type Rgb = [u8; 3];

pub const BLACK: Rgb = [0, 0, 0];
pub const GREY: Rgb = [150, 150, 150];
pub const LIGHT: Rgb = [225, 225, 225];
pub const WHITE: Rgb = [255, 255, 255];
/// The paper's colours: mmNorm blue, Backprojection green, Interferometric orange, the centre
/// ablation (and NLOS) red, the weighted ablation pink.
pub const BLUE: Rgb = [31, 119, 180];
pub const GREEN: Rgb = [44, 160, 44];
pub const ORANGE: Rgb = [255, 127, 14];
pub const RED: Rgb = [214, 39, 40];
pub const PINK: Rgb = [227, 119, 194];

/// An RGB raster, row 0 at the top.
pub struct Canvas {
    pub width: usize,
    pub height: usize,
    pixels: Vec<Rgb>,
}

impl Canvas {
    pub fn new(width: usize, height: usize, background: Rgb) -> Canvas {
        Canvas {
            width,
            height,
            pixels: vec![background; width * height],
        }
    }

    pub fn set(&mut self, x: i64, y: i64, c: Rgb) {
        if x >= 0 && y >= 0 && (x as usize) < self.width && (y as usize) < self.height {
            self.pixels[y as usize * self.width + x as usize] = c;
        }
    }

    /// The pixel at (x, y), None outside the canvas.
    pub fn get(&self, x: i64, y: i64) -> Option<Rgb> {
        (x >= 0 && y >= 0 && (x as usize) < self.width && (y as usize) < self.height)
            .then(|| self.pixels[y as usize * self.width + x as usize])
    }

    pub fn fill_rect(&mut self, x: i64, y: i64, w: i64, h: i64, c: Rgb) {
        for j in y..y + h {
            for i in x..x + w {
                self.set(i, j, c);
            }
        }
    }

    /// A line `thickness` pixels wide; `dash` > 0 draws dashes of that many pixels.
    pub fn line(&mut self, a: (f64, f64), b: (f64, f64), c: Rgb, thickness: i64, dash: usize) {
        let steps = ((b.0 - a.0).abs().max((b.1 - a.1).abs()).ceil() as usize).max(1);
        let half = thickness / 2;
        for s in 0..=steps {
            if dash > 0 && (s / dash) % 2 == 1 {
                continue;
            }
            let t = s as f64 / steps as f64;
            let x = (a.0 + (b.0 - a.0) * t).round() as i64;
            let y = (a.1 + (b.1 - a.1) * t).round() as i64;
            self.fill_rect(x - half, y - half, thickness, thickness, c);
        }
    }

    /// An × marker of half-size `r`.
    pub fn cross(&mut self, x: f64, y: f64, r: f64, c: Rgb) {
        self.line((x - r, y - r), (x + r, y + r), c, 2, 0);
        self.line((x - r, y + r), (x + r, y - r), c, 2, 0);
    }

    /// Width in pixels of `text` at `scale`.
    pub fn text_width(text: &str, scale: i64) -> i64 {
        text.chars().count() as i64 * 8 * scale
    }

    /// Draws ASCII `text` with its top-left corner at (x, y); other characters show as '?'.
    pub fn text(&mut self, x: i64, y: i64, text: &str, c: Rgb, scale: i64) {
        for (n, ch) in text.chars().enumerate() {
            let code = if ch.is_ascii() {
                ch as usize
            } else {
                '?' as usize
            };
            let glyph = font8x8::legacy::BASIC_LEGACY[code];
            for (row, bits) in glyph.iter().enumerate() {
                for col in 0..8 {
                    if bits & (1 << col) != 0 {
                        let px = x + (n as i64 * 8 + col) * scale;
                        let py = y + row as i64 * scale;
                        self.fill_rect(px, py, scale, scale, c);
                    }
                }
            }
        }
    }

    /// Writes the canvas as an RGB PNG (atomically).
    pub fn write_png(&self, path: &Path) -> Result<(), PreviewError> {
        let err = |reason: String| PreviewError {
            path: path.display().to_string(),
            reason,
        };
        let mut bytes = Vec::new();
        {
            let mut enc = png::Encoder::new(&mut bytes, self.width as u32, self.height as u32);
            enc.set_color(png::ColorType::Rgb);
            enc.set_depth(png::BitDepth::Eight);
            let mut writer = enc.write_header().map_err(|e| err(e.to_string()))?;
            let flat: Vec<u8> = self.pixels.iter().flatten().copied().collect();
            writer
                .write_image_data(&flat)
                .map_err(|e| err(e.to_string()))?;
            writer.finish().map_err(|e| err(e.to_string()))?;
        }
        write_atomically(path, &bytes).map_err(|e| err(e.to_string()))
    }
}

/// One line of a CDF chart.
pub struct Series {
    pub label: String,
    pub colour: Rgb,
    pub values: Vec<f64>,
}

/// A reference point drawn as ×: the paper's value of a percentile.
pub struct Marker {
    pub x: f64,
    pub y: f64,
    pub colour: Rgb,
}

/// Round tick values (1, 2, 2.5 or 5 times a power of ten apart, about `count` of them) over
/// `a..=b`, with labels that carry as many decimals as the step needs.
pub fn linear_ticks(a: f64, b: f64, count: f64) -> Vec<(f64, String)> {
    if !(a.is_finite() && b.is_finite() && b > a && count > 0.0) {
        return Vec::new();
    }
    let raw = (b - a) / count;
    let mag = 10f64.powf(raw.log10().floor());
    let step = [1.0, 2.0, 2.5, 5.0, 10.0]
        .iter()
        .map(|m| m * mag)
        .find(|s| *s >= raw)
        .unwrap_or(raw);
    let digits = if step >= 1.0 {
        0
    } else {
        // 2.5·10^k needs one more decimal than 10^k.
        let d = (-step.log10().floor()) as usize;
        if ((step / 10f64.powi(-(d as i32))) - 2.5).abs() < 1e-9 {
            d + 1
        } else {
            d
        }
    };
    let mut out = Vec::new();
    let mut k = (a / step).ceil();
    while k * step <= b + step * 1e-9 {
        let x = k * step;
        // Avoid "-0".
        let x = if x.abs() < step * 1e-9 { 0.0 } else { x };
        out.push((x, format!("{x:.digits$}")));
        k += 1.0;
    }
    out
}

/// An empirical CDF chart in the style of the paper's Fig. 12–15.
pub struct CdfChart {
    pub title: String,
    pub x_label: String,
    pub log_x: bool,
    pub x_range: (f64, f64),
    pub series: Vec<Series>,
    /// Dashed horizontal lines at these CDF levels (the percentiles the paper quotes).
    pub levels: Vec<f64>,
    /// Dashed vertical lines at these x values.
    pub verticals: Vec<f64>,
    pub markers: Vec<Marker>,
}

const W: usize = 760;
const H: usize = 500;
const LEFT: f64 = 70.0;
const RIGHT: f64 = 20.0;
const TOP: f64 = 40.0;
const BOTTOM: f64 = 60.0;

impl CdfChart {
    fn x_to_px(&self, x: f64) -> f64 {
        let (a, b) = self.x_range;
        let t = if self.log_x {
            (x.max(a).ln() - a.ln()) / (b.ln() - a.ln())
        } else {
            (x - a) / (b - a)
        };
        LEFT + t.clamp(0.0, 1.0) * (W as f64 - LEFT - RIGHT)
    }

    fn px_to_x(&self, px: f64) -> f64 {
        let (a, b) = self.x_range;
        let t = (px - LEFT) / (W as f64 - LEFT - RIGHT);
        if self.log_x {
            (a.ln() + t * (b.ln() - a.ln())).exp()
        } else {
            a + t * (b - a)
        }
    }

    fn y_to_px(y: f64) -> f64 {
        H as f64 - BOTTOM - y.clamp(0.0, 1.0) * (H as f64 - TOP - BOTTOM)
    }

    /// The x positions of the axis ticks and their labels.
    fn ticks(&self) -> Vec<(f64, String)> {
        let (a, b) = self.x_range;
        if self.log_x {
            let mut out = Vec::new();
            let mut e = a.log10().ceil() as i32;
            while 10f64.powi(e) <= b * (1.0 + 1e-9) {
                out.push((10f64.powi(e), format!("1e{e}")));
                e += 1;
            }
            return out;
        }
        linear_ticks(a, b, 5.0)
    }

    /// Draws the chart.
    pub fn draw(&self) -> Canvas {
        let mut c = Canvas::new(W, H, WHITE);
        let (x0, x1) = (LEFT, W as f64 - RIGHT);
        let (y0, y1) = (Self::y_to_px(0.0), Self::y_to_px(1.0));
        for (x, label) in self.ticks() {
            let px = self.x_to_px(x);
            c.line((px, y0), (px, y1), LIGHT, 1, 0);
            c.text(
                (px - Canvas::text_width(&label, 1) as f64 / 2.0) as i64,
                y0 as i64 + 8,
                &label,
                BLACK,
                1,
            );
        }
        for k in 0..=5 {
            let y = k as f64 / 5.0;
            let py = Self::y_to_px(y);
            c.line((x0, py), (x1, py), LIGHT, 1, 0);
            c.text(x0 as i64 - 34, py as i64 - 4, &format!("{y:.1}"), BLACK, 1);
        }
        for &l in &self.levels {
            let py = Self::y_to_px(l);
            c.line((x0, py), (x1, py), GREY, 1, 6);
        }
        for &v in &self.verticals {
            let px = self.x_to_px(v);
            c.line((px, y0), (px, y1), GREY, 1, 6);
        }
        c.line((x0, y0), (x1, y0), BLACK, 1, 0);
        c.line((x0, y0), (x0, y1), BLACK, 1, 0);
        for s in &self.series {
            let mut v: Vec<f64> = s.values.iter().copied().filter(|x| !x.is_nan()).collect();
            if v.is_empty() {
                continue;
            }
            v.sort_by(f64::total_cmp);
            let n = v.len() as f64;
            let mut last: Option<(f64, f64)> = None;
            let mut px = x0;
            while px <= x1 {
                let x = self.px_to_x(px);
                let below = v.partition_point(|&e| e <= x) as f64 / n;
                let p = (px, Self::y_to_px(below));
                if let Some(q) = last {
                    // A vertical step, then along: the CDF's staircase at pixel resolution.
                    c.line(q, (p.0, q.1), s.colour, 2, 0);
                    c.line((p.0, q.1), p, s.colour, 2, 0);
                }
                last = Some(p);
                px += 1.0;
            }
        }
        for m in &self.markers {
            c.cross(self.x_to_px(m.x), Self::y_to_px(m.y), 5.0, m.colour);
        }
        c.text(
            (W as i64 - Canvas::text_width(&self.title, 2)) / 2,
            10,
            &self.title,
            BLACK,
            2,
        );
        c.text(
            (W as i64 - Canvas::text_width(&self.x_label, 1)) / 2,
            H as i64 - 26,
            &self.x_label,
            BLACK,
            1,
        );
        c.text(8, TOP as i64 - 14, "CDF", BLACK, 1);
        // Legend, top left inside the axes.
        let (lx, mut ly) = (x0 as i64 + 12, y1 as i64 + 10);
        for s in &self.series {
            c.fill_rect(lx, ly + 3, 22, 3, s.colour);
            c.text(lx + 28, ly, &s.label, BLACK, 1);
            ly += 14;
        }
        if !self.markers.is_empty() {
            c.cross(lx as f64 + 11.0, ly as f64 + 4.0, 4.0, GREY);
            c.text(lx + 28, ly, "paper's percentile", BLACK, 1);
        }
        c
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_cdf_of_uniform_values_crosses_its_median_at_the_middle() {
        let chart = CdfChart {
            title: "t".into(),
            x_label: "x".into(),
            log_x: false,
            x_range: (0.0, 1.0),
            series: vec![Series {
                label: "u".into(),
                colour: RED,
                values: (0..1000).map(|i| (i as f64 + 0.5) / 1000.0).collect(),
            }],
            levels: vec![0.5],
            verticals: vec![],
            markers: vec![],
        };
        let c = chart.draw();
        // The red line passes through the centre of the axes: (x = 0.5, F = 0.5).
        let (px, py) = (
            chart.x_to_px(0.5).round() as i64,
            CdfChart::y_to_px(0.5).round() as i64,
        );
        let near_red = (-2..=2).any(|d: i64| {
            (-2..=2)
                .any(|e: i64| c.pixels[((py + e) as usize) * c.width + (px + d) as usize] == RED)
        });
        assert!(near_red);
        // And not through (x = 0.5, F = 0.9).
        let py9 = CdfChart::y_to_px(0.9).round() as i64;
        assert_ne!(c.pixels[py9 as usize * c.width + px as usize], RED);
        assert!((chart.px_to_x(chart.x_to_px(0.3)) - 0.3).abs() < 1e-12);
    }

    #[test]
    fn text_draws_pixels_and_png_round_trips_its_size() {
        let mut c = Canvas::new(40, 12, WHITE);
        c.text(0, 0, "F1", BLACK, 1);
        assert!(c.pixels.contains(&BLACK));
        let dir = std::env::temp_dir().join(format!("mmnormd-plot-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("t.png");
        c.write_png(&path).unwrap();
        let decoder =
            png::Decoder::new(std::io::BufReader::new(std::fs::File::open(&path).unwrap()));
        let reader = decoder.read_info().unwrap();
        assert_eq!((reader.info().width, reader.info().height), (40, 12));
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
