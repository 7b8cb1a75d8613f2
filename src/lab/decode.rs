//! `mmnormd capture decode`: a raw `adc_data.bin` (TI's layout, as `capture raw` and mmWave
//! Studio write it) turned into samples a person can look at: a `.npy` of complex64 shaped
//! frames × chirps × RX × samples, and a range-profile picture.

use std::path::Path;

use num_complex::Complex32;
use rustfft::FftPlanner;

use crate::capture::npy;
use crate::dca1000::samples::{FrameLayout, LayoutError};
use crate::plot::{self, Canvas};
use crate::preview::PreviewError;
use crate::signal::hann_window;

/// Why a file could not be decoded.
#[derive(Debug, thiserror::Error)]
pub enum DecodeError {
    #[error(
        "{path} holds {bytes} bytes, not a whole number of the profile's {frame_bytes}-byte frames ({frames} whole, {rest} bytes left over): check the profile, lvds_mode and the capture"
    )]
    PartialFrame {
        path: String,
        bytes: usize,
        frame_bytes: usize,
        frames: usize,
        rest: usize,
    },
    #[error("{path} holds no frame")]
    Empty { path: String },
    #[error(transparent)]
    Layout(#[from] LayoutError),
    #[error("writing the range profile: {0}")]
    Picture(#[from] PreviewError),
}

/// Decoded samples: `[frame][chirp][rx][sample]`, flattened.
#[derive(Debug)]
pub struct Decoded {
    pub frames: usize,
    pub chirps: usize,
    pub rx: usize,
    pub samples: usize,
    pub data: Vec<Complex32>,
}

/// Decodes every frame of `bytes` (named `path` in errors) under `layout`.
pub fn decode(bytes: &[u8], layout: &FrameLayout, path: &str) -> Result<Decoded, DecodeError> {
    let frame_bytes = layout.frame_bytes();
    let (frames, rest) = (bytes.len() / frame_bytes, bytes.len() % frame_bytes);
    if rest != 0 {
        return Err(DecodeError::PartialFrame {
            path: path.into(),
            bytes: bytes.len(),
            frame_bytes,
            frames,
            rest,
        });
    }
    if frames == 0 {
        return Err(DecodeError::Empty { path: path.into() });
    }
    let mut data = Vec::with_capacity(bytes.len() / 4);
    for frame in bytes.chunks_exact(frame_bytes) {
        data.extend(
            layout
                .decode(frame)?
                .into_iter()
                .map(|z| Complex32::new(f32::from(z.re), f32::from(z.im))),
        );
    }
    Ok(Decoded {
        frames,
        chirps: layout.chirps_per_frame,
        rx: layout.rx_count,
        samples: layout.samples_per_chirp,
        data,
    })
}

impl Decoded {
    /// The `.npy` bytes: complex64, shape (frames, chirps, RX, samples).
    pub fn npy(&self) -> Vec<u8> {
        let mut out = npy::header("<c8", &[self.frames, self.chirps, self.rx, self.samples]);
        out.reserve(self.data.len() * 8);
        for z in &self.data {
            out.extend_from_slice(&z.re.to_le_bytes());
            out.extend_from_slice(&z.im.to_le_bytes());
        }
        out
    }

    /// Each receiver's range profile: the mean over every chirp of |FFT| (Hann window), in dB
    /// full scale (an i16 sine of full amplitude is 0 dB), one value per range bin.
    pub fn range_profiles_db(&self) -> Vec<Vec<f64>> {
        let n = self.samples;
        let fft = FftPlanner::<f32>::new().plan_fft_forward(n);
        let window = hann_window(n);
        let gain: f32 = window.iter().sum::<f32>() * 32768.0;
        let mut sums = vec![vec![0.0f64; n]; self.rx];
        let mut buf = vec![Complex32::new(0.0, 0.0); n];
        for (k, chirp) in self.data.chunks_exact(n).enumerate() {
            let rx = k % self.rx;
            for ((b, z), w) in buf.iter_mut().zip(chirp).zip(&window) {
                *b = z * w;
            }
            fft.process(&mut buf);
            for (s, b) in sums[rx].iter_mut().zip(&buf) {
                *s += f64::from(b.norm() / gain);
            }
        }
        let count = (self.frames * self.chirps).max(1) as f64;
        sums.into_iter()
            .map(|row| {
                row.into_iter()
                    .map(|s| 20.0 * (s / count).max(1e-12).log10())
                    .collect()
            })
            .collect()
    }
}

/// Colours of up to four receivers.
const RX_COLOURS: [plot::Rgb; 4] = [plot::BLUE, plot::GREEN, plot::ORANGE, plot::RED];

/// Draws the range profiles (`range_bin_m` metres per bin; a complex chirp's bins are all
/// positive ranges) with a title, axes in metres and dBFS, and a legend per receiver.
pub fn write_range_profile_png(
    profiles_db: &[Vec<f64>],
    range_bin_m: f64,
    title: &str,
    path: &Path,
) -> Result<(), PreviewError> {
    let (w, h) = (760usize, 460usize);
    let (left, right, top, bottom) = (70.0, 20.0, 56.0, 60.0);
    let bins = profiles_db.first().map_or(0, Vec::len);
    let x_max = range_bin_m * bins as f64;
    let finite = profiles_db
        .iter()
        .flatten()
        .copied()
        .filter(|v| v.is_finite());
    let (lo, hi) = finite.fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| {
        (a.min(v), b.max(v))
    });
    let (y_lo, y_hi) = if lo < hi {
        ((lo / 10.0).floor() * 10.0, (hi / 10.0).ceil() * 10.0)
    } else {
        (-120.0, 0.0)
    };
    let x_px = |x: f64| left + (x / x_max.max(1e-9)) * (w as f64 - left - right);
    let y_px = |y: f64| h as f64 - bottom - (y - y_lo) / (y_hi - y_lo) * (h as f64 - top - bottom);
    let mut c = Canvas::new(w, h, plot::WHITE);
    for (x, label) in plot::linear_ticks(0.0, x_max, 6.0) {
        let px = x_px(x);
        c.line((px, y_px(y_lo)), (px, y_px(y_hi)), plot::LIGHT, 1, 0);
        c.text(
            (px - Canvas::text_width(&label, 1) as f64 / 2.0) as i64,
            (h as f64 - bottom) as i64 + 8,
            &label,
            plot::BLACK,
            1,
        );
    }
    for (y, label) in plot::linear_ticks(y_lo, y_hi, 6.0) {
        let py = y_px(y);
        c.line((left, py), (w as f64 - right, py), plot::LIGHT, 1, 0);
        c.text(
            left as i64 - 8 - Canvas::text_width(&label, 1),
            py as i64 - 4,
            &label,
            plot::BLACK,
            1,
        );
    }
    c.line(
        (left, y_px(y_lo)),
        (w as f64 - right, y_px(y_lo)),
        plot::BLACK,
        1,
        0,
    );
    c.line((left, y_px(y_lo)), (left, y_px(y_hi)), plot::BLACK, 1, 0);
    for (rx, profile) in profiles_db.iter().enumerate() {
        let colour = RX_COLOURS[rx % RX_COLOURS.len()];
        for (k, pair) in profile.windows(2).enumerate() {
            let a = (
                x_px(k as f64 * range_bin_m),
                y_px(pair[0].clamp(y_lo, y_hi)),
            );
            let b = (
                x_px((k + 1) as f64 * range_bin_m),
                y_px(pair[1].clamp(y_lo, y_hi)),
            );
            c.line(a, b, colour, 1, 0);
        }
        let ly = top as i64 + 8 + 14 * rx as i64;
        let lx = w as i64 - right as i64 - 70;
        c.fill_rect(lx, ly, 14, 3, colour);
        c.text(lx + 20, ly - 3, &format!("RX {rx}"), plot::BLACK, 1);
    }
    c.text(
        ((w as i64) - Canvas::text_width(title, 2)) / 2,
        16,
        title,
        plot::BLACK,
        2,
    );
    let x_label = "range (m, from the radar, before any offset)";
    c.text(
        ((w as i64) - Canvas::text_width(x_label, 1)) / 2,
        h as i64 - 24,
        x_label,
        plot::BLACK,
        1,
    );
    c.text(8, top as i64 - 14, "dBFS", plot::BLACK, 1);
    c.write_png(path)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dca1000::samples::{IqOrder, Lanes};
    use num_complex::Complex;

    /// A tone in bin 10 of RX 1, encoded in the 2-lane layout, decodes back and peaks in
    /// bin 10 of RX 1's profile, at about −6 dBFS for a half-scale tone; a truncated file is
    /// refused with its sizes.
    #[test]
    fn a_tone_decodes_to_its_range_bin() {
        let layout = FrameLayout {
            chirps_per_frame: 2,
            samples_per_chirp: 64,
            rx_count: 2,
            iq_order: IqOrder::QFirst,
            lanes: Lanes::Two,
        };
        let mut frame = Vec::new();
        for _chirp in 0..2 {
            for rx in 0..2 {
                for s in 0..64 {
                    let phase = 2.0 * std::f64::consts::PI * 10.0 * s as f64 / 64.0;
                    let a = if rx == 1 { 16384.0 } else { 0.0 };
                    frame.push(Complex::new(
                        (a * phase.cos()).round() as i16,
                        (a * phase.sin()).round() as i16,
                    ));
                }
            }
        }
        let bytes = layout.encode(&frame).unwrap();
        let two: Vec<u8> = [bytes.clone(), bytes].concat();
        let d = decode(&two, &layout, "x.bin").unwrap();
        assert_eq!((d.frames, d.chirps, d.rx, d.samples), (2, 2, 2, 64));
        assert_eq!(
            d.data[64 + 3],
            Complex32::new(frame[64 + 3].re.into(), frame[64 + 3].im.into())
        );
        let profiles = d.range_profiles_db();
        let peak = (0..64)
            .max_by(|&a, &b| profiles[1][a].total_cmp(&profiles[1][b]))
            .unwrap();
        assert_eq!(peak, 10);
        assert!((profiles[1][10] + 6.0).abs() < 0.1, "{}", profiles[1][10]);
        assert!(profiles[0][10] < -100.0);
        let e = decode(&two[..two.len() - 5], &layout, "x.bin")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("1 whole") && e.contains("bytes left over"),
            "{e}"
        );
        let npy = d.npy();
        assert!(String::from_utf8_lossy(&npy[..80]).contains("'shape': (2, 2, 2, 64)"));
        assert_eq!(npy.len() % 64, (2 * 2 * 2 * 64 * 8) % 64);
    }
}
