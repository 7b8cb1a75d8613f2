use std::path::Path;

use anyhow::{Result, bail};
use mmnormd::capture::{read_capture_dir, truth_files};
use mmnormd::preview::{ColourBar, MapFigure, ScalarImage};
use num_complex::Complex32;
use rayon::prelude::*;
use rustfft::FftPlanner;

/// Largest side of the aperture picture, pixels.
const MAX_SIDE: usize = 320;

/// Parses `--gate MIN,MAX` (one-way range in metres).
pub fn parse_gate(text: &str) -> Result<(f64, f64)> {
    let parts: Vec<&str> = text.split(',').map(str::trim).collect();
    let parsed: Vec<f64> = parts.iter().filter_map(|p| p.parse().ok()).collect();
    match parsed.as_slice() {
        [lo, hi]
            if parts.len() == 2 && lo.is_finite() && hi.is_finite() && *lo >= 0.0 && lo < hi =>
        {
            Ok((*lo, *hi))
        }
        _ => bail!("--gate {text:?}: expected MIN,MAX in metres with 0 ≤ MIN < MAX"),
    }
}

pub fn run(dir: &Path, png: Option<&Path>, gate: Option<(f64, f64)>) -> Result<()> {
    let c = read_capture_dir(dir)?;
    let n = c.antennas();
    let t = c.plan.samples_per_chirp;
    let centres: Vec<[f64; 3]> = c
        .tx_m
        .iter()
        .zip(&c.rx_m)
        .map(|(a, b)| [0, 1, 2].map(|k| 0.5 * (a[k] + b[k])))
        .collect();
    let (lo, hi) = centres.iter().fold(
        ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]),
        |(lo, hi), p| {
            (
                [0, 1, 2].map(|k| lo[k].min(p[k])),
                [0, 1, 2].map(|k| hi[k].max(p[k])),
            )
        },
    );
    // Range-FFT bins (4× zero padding) that fall inside the gate, by one-way range.
    let pad = 4 * t;
    let round_trip_of_bin = |k: usize| {
        k as f64 / pad as f64 * mmnormd::SPEED_OF_LIGHT_M_PER_S / c.plan.frequency_step_hz.abs()
    };
    let gate_bins: Option<Vec<usize>> = gate.map(|(lo, hi)| {
        (0..pad / 2)
            .filter(|&k| {
                let one_way = (round_trip_of_bin(k) - c.range_offset_m) / 2.0;
                (lo..=hi).contains(&one_way)
            })
            .collect()
    });
    if let (Some(bins), Some((lo, hi))) = (&gate_bins, gate)
        && bins.is_empty()
    {
        bail!("--gate {lo},{hi}: no range bin of this capture falls between {lo} m and {hi} m");
    }
    let hann = mmnormd::signal::hann_window(t);
    let power_db: Vec<f32> = (0..n)
        .into_par_iter()
        .map_init(
            || {
                let fft = FftPlanner::<f32>::new().plan_fft_forward(pad);
                (fft, vec![Complex32::new(0.0, 0.0); pad])
            },
            |(fft, buf), i| match &gate_bins {
                // Mean power per sample.
                None => {
                    let p: f32 = c.chirp(i).iter().map(Complex32::norm_sqr).sum::<f32>() / t as f32;
                    10.0 * p.max(1e-30).log10()
                }
                // Strongest echo amplitude inside the gate (per-sample units). A Hann window
                // keeps strong echoes outside the gate (a cardboard sheet) from leaking in
                // through range sidelobes; its coherent gain of ½ is divided out.
                Some(bins) => {
                    buf.fill(Complex32::new(0.0, 0.0));
                    for (k, (b, s)) in buf.iter_mut().zip(c.chirp(i)).enumerate() {
                        *b = s * hann[k];
                    }
                    fft.process(buf);
                    let a = bins.iter().map(|&k| buf[k].norm()).fold(0.0f32, f32::max)
                        / (0.5 * t as f32);
                    20.0 * a.max(1e-15).log10()
                }
            },
        )
        .collect();
    let peak_db = power_db.iter().copied().fold(f32::NEG_INFINITY, f32::max);
    let mut sorted = power_db.clone();
    sorted.sort_by(f32::total_cmp);
    let median_db = sorted[sorted.len() / 2];

    // Mean range profile: |FFT| of each chirp, 4× zero-padded, averaged.
    let fft = FftPlanner::<f32>::new().plan_fft_forward(pad);
    let mut profile = vec![0f32; pad];
    let mut buf = vec![Complex32::new(0.0, 0.0); pad];
    let stride = (n / 2000).max(1);
    for i in (0..n).step_by(stride) {
        buf.fill(Complex32::new(0.0, 0.0));
        buf[..t].copy_from_slice(c.chirp(i));
        fft.process(&mut buf);
        for (p, v) in profile.iter_mut().zip(&buf) {
            *p += v.norm();
        }
    }
    let half = pad / 2;
    let (peak_bin, _) =
        profile[..half]
            .iter()
            .enumerate()
            .fold(
                (0, f32::NEG_INFINITY),
                |b, (k, &v)| if v > b.1 { (k, v) } else { b },
            );
    // With h ∝ exp(+j2π·f_t·d/c) the FFT peaks at bin d·step·T/c (one-way range d/2).
    let round_trip_m = round_trip_of_bin(peak_bin);
    println!("capture {}", dir.display());
    println!("  description    {}", c.description);
    println!("  antennas       {n} × {t} samples");
    println!(
        "  frequencies    {:.6} GHz + k·{:.3} kHz ({:.4} GHz swept, range bin {:.2} cm)",
        c.plan.start_frequency_hz / 1e9,
        c.plan.frequency_step_hz / 1e3,
        c.plan.bandwidth_hz() / 1e9,
        c.plan.range_bin_m() * 100.0
    );
    println!("  range offset   {} m", c.range_offset_m);
    println!(
        "  aperture       x {:.4}…{:.4} m, y {:.4}…{:.4} m, z {:.4}…{:.4} m (virtual centres)",
        lo[0], hi[0], lo[1], hi[1], lo[2], hi[2]
    );
    let measure = if gate.is_some() {
        "gated echo"
    } else {
        "power"
    };
    println!("  {measure:<14} peak {peak_db:.1} dB, median {median_db:.1} dB (per sample)");
    println!(
        "  strongest echo round trip {:.3} m incl. offset → one-way {:.3} m without it",
        round_trip_m,
        (round_trip_m - c.range_offset_m) / 2.0
    );
    let truth = truth_files(dir);
    println!(
        "  truth          mesh {}, top view {}",
        truth
            .mesh
            .as_ref()
            .map_or("none".into(), |p| p.display().to_string()),
        truth
            .top_points
            .as_ref()
            .map_or("none".into(), |p| p.display().to_string())
    );
    if let Some(path) = png {
        let (image, cell_m) = aperture_image(&centres, &power_db, lo, hi);
        let what = match gate {
            None => "received power".to_string(),
            Some((lo, hi)) => format!("strongest echo between {lo} m and {hi} m one way"),
        };
        let edges =
            |k: usize, cells: usize| (lo[k] - cell_m / 2.0, lo[k] + cell_m * (cells as f64 - 0.5));
        MapFigure {
            title: &format!("{what} at each antenna"),
            image: &image,
            x_m: edges(0, image.width),
            y_m: edges(1, image.height),
            x_name: "x",
            y_name: "y",
            colour: ColourBar {
                lo: peak_db - 40.0,
                hi: peak_db,
                label: "power (dB)".into(),
                label_scale: 1.0,
            },
            truth: None,
            zoom: 2,
        }
        .write_png(path)?;
        println!(
            "  wrote {} ({}×{} cells, colour = {what}, top 40 dB; +x right, +y up)",
            path.display(),
            image.width,
            image.height
        );
    }
    Ok(())
}

/// Median gap between distinct coordinates along axis `k` (the raster pitch), if any.
fn pitch(centres: &[[f64; 3]], k: usize) -> Option<f64> {
    let mut v: Vec<f64> = centres.iter().map(|p| (p[k] * 1e7).round() / 1e7).collect();
    v.sort_by(f64::total_cmp);
    v.dedup();
    let mut gaps: Vec<f64> = v.windows(2).map(|w| w[1] - w[0]).collect();
    gaps.sort_by(f64::total_cmp);
    gaps.get(gaps.len() / 2).copied()
}

/// Places each antenna's power in a cell of an image spanning the aperture (max per cell), and
/// returns it with the cell's width in metres (cell (0, bottom) centred on `lo`). Cells are one
/// raster pitch wide when the picture fits in `MAX_SIDE`, else coarser.
fn aperture_image(
    centres: &[[f64; 3]],
    power_db: &[f32],
    lo: [f64; 3],
    hi: [f64; 3],
) -> (ScalarImage, f64) {
    let (wx, wy) = ((hi[0] - lo[0]).max(1e-9), (hi[1] - lo[1]).max(1e-9));
    let raster = pitch(centres, 0)
        .into_iter()
        .chain(pitch(centres, 1))
        .fold(0.0, f64::max);
    let cell = (wx.max(wy) / MAX_SIDE as f64).max(raster * 0.999);
    let width = ((wx / cell).round() as usize + 1).min(MAX_SIDE + 1);
    let height = ((wy / cell).round() as usize + 1).min(MAX_SIDE + 1);
    let mut values = vec![f32::NAN; width * height];
    for (p, &v) in centres.iter().zip(power_db) {
        let x = (((p[0] - lo[0]) / cell).round() as usize).min(width - 1);
        let y = height - 1 - (((p[1] - lo[1]) / cell).round() as usize).min(height - 1);
        let cell_v = &mut values[y * width + x];
        if cell_v.is_nan() || v > *cell_v {
            *cell_v = v;
        }
    }
    (
        ScalarImage {
            width,
            height,
            values,
        },
        cell,
    )
}
