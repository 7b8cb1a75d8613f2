use std::path::Path;

use anyhow::{Context, Result, bail};
use mmnormd::capture::dir::write_atomically;
use mmnormd::capture::read_capture_dir;
use mmnormd::preview::ScalarImage;
use mmnormd::recon::config::{Imaging, Isosurface, Method, VolumeSpec};
use mmnormd::recon::image::VoxelGrid;
use mmnormd::recon::{ReconConfig, Reconstruction, image_volume, reconstruct_imaged};
use serde_json::json;

/// `--method`: one method, or all three from one image.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum MethodChoice {
    Mmnorm,
    Backprojection,
    Interferometric,
    /// All three from one image, into OUT/mmnorm, OUT/backprojection and OUT/interferometric.
    All,
}

/// Command-line choices that override `recon.toml`.
pub struct Overrides {
    pub method: Option<MethodChoice>,
    pub isosurface: Option<Isosurface>,
    pub imaging: Option<Imaging>,
    pub voxel_mm: Option<f64>,
    pub volume: Option<VolumeSpec>,
}

pub fn run(
    capture_dir: &Path,
    out: &Path,
    config_path: Option<&Path>,
    overrides: Overrides,
    force: bool,
    quiet: bool,
) -> Result<()> {
    let mut config = match config_path {
        Some(p) => {
            let text =
                std::fs::read_to_string(p).with_context(|| format!("reading {}", p.display()))?;
            ReconConfig::parse(&text).map_err(|e| anyhow::anyhow!("{}: {e}", p.display()))?
        }
        None => ReconConfig::default(),
    };
    let methods = match overrides.method {
        None => vec![config.method],
        Some(MethodChoice::Mmnorm) => vec![Method::Mmnorm],
        Some(MethodChoice::Backprojection) => vec![Method::Backprojection],
        Some(MethodChoice::Interferometric) => vec![Method::Interferometric],
        Some(MethodChoice::All) => vec![
            Method::Mmnorm,
            Method::Backprojection,
            Method::Interferometric,
        ],
    };
    let nested = methods.len() > 1;
    if let Some(i) = overrides.isosurface {
        config.isosurface = i;
    }
    if let Some(i) = overrides.imaging {
        config.imaging = i;
    }
    if let Some(mm) = overrides.voxel_mm {
        config.voxel_m = mm * 1e-3;
    }
    if let Some(v) = overrides.volume {
        config.volume = v;
    }
    config
        .validate()
        .map_err(|e| anyhow::anyhow!("{e} (--voxel-mm is in millimetres)"))?;
    let dir_of = |m: Method| {
        if nested {
            out.join(method_name(m))
        } else {
            out.to_path_buf()
        }
    };
    if let Some(d) = methods
        .iter()
        .map(|&m| dir_of(m))
        .find(|d| d.join("points.ply").exists())
        && !force
    {
        bail!(
            "{} already holds a reconstruction; pass --force to replace it",
            d.display()
        );
    }
    let capture = read_capture_dir(capture_dir)?;
    // The image is formed for the first method (mmNorm when it is among them: it alone needs
    // the spectral votes).
    config.method = methods[0];
    let imaged = image_volume(&capture, &config, quiet)?;
    for method in methods {
        config.method = method;
        let dir = dir_of(method);
        match reconstruct_imaged(&capture, &config, &imaged, quiet) {
            Ok(recon) => write_outputs(capture_dir, &dir, &config, &recon, &imaged.magnitude)?,
            // With several methods, one failing (say, no component for mmNorm) does not discard
            // the others.
            Err(e) if nested => {
                tracing::error!("{}: {e}", method_name(method));
            }
            Err(e) => return Err(e.into()),
        }
    }
    Ok(())
}

fn method_name(m: Method) -> &'static str {
    match m {
        Method::Mmnorm => "mmnorm",
        Method::Backprojection => "backprojection",
        Method::Interferometric => "interferometric",
    }
}

fn write_outputs(
    capture_dir: &Path,
    out: &Path,
    config: &ReconConfig,
    recon: &Reconstruction,
    magnitude: &[f32],
) -> Result<()> {
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    write_atomically(&out.join("points.ply"), &recon.encode_ply())?;
    let summary = json!({
        "mmnormd_version": env!("CARGO_PKG_VERSION"),
        "capture": capture_dir.display().to_string(),
        "parameters": config,
        "result": recon.summary,
    });
    let mut text = serde_json::to_string_pretty(&summary)?;
    text.push('\n');
    write_atomically(&out.join("summary.json"), text.as_bytes())?;
    write_previews(out, recon, magnitude)?;
    let s = &recon.summary;
    let stages: Vec<String> = s
        .stage_s
        .iter()
        .map(|(n, t)| format!("{n} {t:.1} s"))
        .collect();
    println!(
        "wrote {}: {} points ({}), {} component(s); {}",
        out.display(),
        s.points,
        method_name(config.method),
        s.components.len(),
        stages.join(", ")
    );
    Ok(())
}

/// Top (x–y, colour = height) and side (x–z, colour = point count) views of the points, and
/// max-projections of `magnitude` (|S| on the summary's grid) in dB along z and along y.
fn write_previews(out: &Path, recon: &Reconstruction, magnitude: &[f32]) -> Result<()> {
    let g = &recon.summary.grid;
    let zoom = (400 / g.dims[0].max(g.dims[1]).max(1)).clamp(1, 8);
    let cells = |p: &[f64; 3], u: usize, v: usize| {
        let i = ((p[u] - g.origin_m[u]) / g.voxel_m).round();
        let j = ((p[v] - g.origin_m[v]) / g.voxel_m).round();
        (i >= 0.0 && j >= 0.0 && (i as usize) < g.dims[u] && (j as usize) < g.dims[v])
            .then(|| (i as usize, g.dims[v] - 1 - j as usize))
    };
    // Top view: highest point per (x, y) cell, y up.
    let (w, h) = (g.dims[0], g.dims[1]);
    let mut top = vec![f32::NAN; w * h];
    for p in &recon.points_m {
        if let Some((i, j)) = cells(p, 0, 1) {
            let cell = &mut top[j * w + i];
            if cell.is_nan() || (p[2] as f32) > *cell {
                *cell = p[2] as f32;
            }
        }
    }
    let (lo, hi) = (
        g.origin_m[2] as f32,
        g.centre(0, 0, g.dims[2] - 1)[2] as f32,
    );
    ScalarImage {
        width: w,
        height: h,
        values: top,
    }
    .write_png(&out.join("points_top.png"), lo, hi, zoom)?;
    // Side view: points per (x, z) cell, z up.
    let (w, h) = (g.dims[0], g.dims[2]);
    let mut side = vec![f32::NAN; w * h];
    for p in &recon.points_m {
        if let Some((i, j)) = cells(p, 0, 2) {
            let cell = &mut side[j * w + i];
            *cell = if cell.is_nan() { 1.0 } else { *cell + 1.0 };
        }
    }
    let most = side
        .iter()
        .copied()
        .filter(|x| !x.is_nan())
        .fold(1.0f32, f32::max);
    ScalarImage {
        width: w,
        height: h,
        values: side,
    }
    .write_png(&out.join("points_side.png"), 0.0, most, zoom)?;
    for (name, axis) in [("image_max_z.png", 2usize), ("image_max_y.png", 1)] {
        max_projection(magnitude, g, axis).write_png(&out.join(name), -30.0, 0.0, zoom)?;
    }
    Ok(())
}

/// 20·log10(max over `axis` of |S| / max|S|), with x across and the remaining axis up.
fn max_projection(magnitude: &[f32], g: &VoxelGrid, axis: usize) -> ScalarImage {
    let [nx, ny, nz] = g.dims;
    let (h, up) = if axis == 2 { (ny, 1) } else { (nz, 2) };
    let mut values = vec![0.0f32; nx * h];
    for i in 0..nx {
        for j in 0..ny {
            for k in 0..nz {
                let r = if up == 1 { j } else { k };
                let cell = &mut values[(h - 1 - r) * nx + i];
                *cell = cell.max(magnitude[(i * ny + j) * nz + k]);
            }
        }
    }
    let peak = values
        .iter()
        .copied()
        .fold(0.0f32, f32::max)
        .max(f32::MIN_POSITIVE);
    for v in &mut values {
        *v = 20.0 * (*v / peak).max(1e-6).log10();
    }
    ScalarImage {
        width: nx,
        height: h,
        values,
    }
}
