//! PNG pictures for people: scalar maps drawn with a perceptual colour map.

use std::path::Path;

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

impl ScalarImage {
    /// Writes the image scaled so `lo` maps to the bottom of the colour map and `hi` to the top,
    /// each cell drawn as a `zoom`×`zoom` block.
    pub fn write_png(
        &self,
        path: &Path,
        lo: f32,
        hi: f32,
        zoom: usize,
    ) -> Result<(), PreviewError> {
        let err = |reason: String| PreviewError {
            path: path.display().to_string(),
            reason,
        };
        let zoom = zoom.max(1);
        let (w, h) = (self.width * zoom, self.height * zoom);
        let span = if hi > lo { hi - lo } else { 1.0 };
        let mut rgb = vec![0u8; w * h * 3];
        for y in 0..h {
            for x in 0..w {
                let v = self.values[(y / zoom) * self.width + x / zoom];
                let c = if v.is_nan() {
                    [40, 40, 40]
                } else {
                    viridis((v - lo) / span)
                };
                rgb[(y * w + x) * 3..(y * w + x) * 3 + 3].copy_from_slice(&c);
            }
        }
        let file = std::fs::File::create(path).map_err(|e| err(e.to_string()))?;
        let mut enc = png::Encoder::new(std::io::BufWriter::new(file), w as u32, h as u32);
        enc.set_color(png::ColorType::Rgb);
        enc.set_depth(png::BitDepth::Eight);
        let mut writer = enc.write_header().map_err(|e| err(e.to_string()))?;
        writer
            .write_image_data(&rgb)
            .map_err(|e| err(e.to_string()))?;
        writer.finish().map_err(|e| err(e.to_string()))
    }
}
