//! What a reconstruction leaves on disk: `points.ply`, `summary.json` and PNG previews (top
//! and side views of the points, max-projections of |S|). Every file is written atomically.

use std::path::{Path, PathBuf};

use serde_json::json;

use super::image::VoxelGrid;
use super::{ReconConfig, Reconstruction};
use crate::capture::dir::write_atomically;
use crate::preview::{ColourBar, MapFigure, ScalarImage};

/// Why the outputs could not be written.
#[derive(Debug, thiserror::Error)]
pub enum OutputError {
    #[error("writing {path}: {message}")]
    Write { path: PathBuf, message: String },
}

fn write_err(path: &Path) -> impl Fn(String) -> OutputError + '_ {
    move |message| OutputError::Write {
        path: path.to_path_buf(),
        message,
    }
}

/// Writes `points.ply`, `summary.json` (version, capture, parameters, result) and the
/// previews into `out`. `truth` (the surface seen from above, in the reconstruction's frame),
/// where known, is drawn in grey under the point views.
pub fn write_reconstruction(
    capture_label: &str,
    out: &Path,
    config: &ReconConfig,
    recon: &Reconstruction,
    magnitude: &[f32],
    truth: Option<&[[f64; 3]]>,
) -> Result<(), OutputError> {
    std::fs::create_dir_all(out).map_err(|e| write_err(out)(e.to_string()))?;
    let ply = out.join("points.ply");
    write_atomically(&ply, &recon.encode_ply()).map_err(|e| write_err(&ply)(e.to_string()))?;
    write_summary(&out.join("summary.json"), capture_label, config, recon)?;
    write_previews(out, recon, magnitude, truth)
}

/// Writes `path` as `summary.json` is written: the version, the capture, the parameters and
/// the reconstruction's summary, as pretty JSON.
pub fn write_summary(
    path: &Path,
    capture_label: &str,
    config: &ReconConfig,
    recon: &Reconstruction,
) -> Result<(), OutputError> {
    let summary = json!({
        "mmnormd_version": env!("CARGO_PKG_VERSION"),
        "capture": capture_label,
        "parameters": config,
        "result": recon.summary,
    });
    let mut text =
        serde_json::to_string_pretty(&summary).map_err(|e| write_err(path)(e.to_string()))?;
    text.push('\n');
    write_atomically(path, text.as_bytes()).map_err(|e| write_err(path)(e.to_string()))
}

/// Top (x–y, colour = height) and side (x–z, colour = point count) views of the points over
/// the truth, and max-projections of `magnitude` (|S| on the summary's grid) in dB along z and
/// along y.
fn write_previews(
    out: &Path,
    recon: &Reconstruction,
    magnitude: &[f32],
    truth: Option<&[[f64; 3]]>,
) -> Result<(), OutputError> {
    let g = &recon.summary.grid;
    let zoom = (400 / g.dims[0].max(g.dims[1]).max(1)).clamp(1, 8);
    // Cell edges along each axis, metres.
    let edges = |k: usize| {
        (
            g.origin_m[k] - g.voxel_m / 2.0,
            g.origin_m[k] + g.voxel_m * (g.dims[k] as f64 - 0.5),
        )
    };
    let cells = |p: &[f64; 3], u: usize, v: usize| {
        let i = ((p[u] - g.origin_m[u]) / g.voxel_m).round();
        let j = ((p[v] - g.origin_m[v]) / g.voxel_m).round();
        (i >= 0.0 && j >= 0.0 && (i as usize) < g.dims[u] && (j as usize) < g.dims[v])
            .then(|| (i as usize, g.dims[v] - 1 - j as usize))
    };
    let method = recon.summary.method.title();
    let points = recon.points_m.len();
    let truth_on = |u: usize, v: usize| -> Vec<[f64; 2]> {
        truth
            .unwrap_or_default()
            .iter()
            .map(|p| [p[u], p[v]])
            .collect()
    };
    let write = |name: &str, figure: MapFigure<'_>| {
        let path = out.join(name);
        figure
            .write_png(&path)
            .map_err(|e| write_err(&path)(e.to_string()))
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
    let (z_lo, z_hi) = (
        g.origin_m[2] as f32,
        g.centre(0, 0, g.dims[2] - 1)[2] as f32,
    );
    let truth_xy = truth_on(0, 1);
    let truth_xz = truth_on(0, 2);
    let legend = "truth: the surface seen from above";
    write(
        "points_top.png",
        MapFigure {
            title: &format!("{method}: {points} points, from above"),
            image: &ScalarImage {
                width: w,
                height: h,
                values: top,
            },
            x_m: edges(0),
            y_m: edges(1),
            x_name: "x",
            y_name: "y",
            colour: ColourBar {
                lo: z_lo,
                hi: z_hi,
                label: "height z (cm)".into(),
                label_scale: 100.0,
            },
            truth: truth.map(|_| (truth_xy.as_slice(), legend)),
            zoom,
        },
    )?;
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
    write(
        "points_side.png",
        MapFigure {
            title: &format!("{method}: {points} points from the side, looking along +y"),
            image: &ScalarImage {
                width: w,
                height: h,
                values: side,
            },
            x_m: edges(0),
            y_m: edges(2),
            x_name: "x",
            y_name: "z",
            colour: ColourBar {
                lo: 0.0,
                hi: most,
                label: "points per cell".into(),
                label_scale: 1.0,
            },
            truth: truth.map(|_| (truth_xz.as_slice(), legend)),
            zoom,
        },
    )?;
    for (name, axis, view, (u, v)) in [
        (
            "image_max_z.png",
            2usize,
            "from above (max over z)",
            ("x", "y"),
        ),
        (
            "image_max_y.png",
            1,
            "from the side (max over y)",
            ("x", "z"),
        ),
    ] {
        write(
            name,
            MapFigure {
                title: &format!("image |S| {view}"),
                image: &max_projection(magnitude, g, axis),
                x_m: edges(0),
                y_m: edges(if axis == 2 { 1 } else { 2 }),
                x_name: u,
                y_name: v,
                colour: ColourBar {
                    lo: -30.0,
                    hi: 0.0,
                    label: "|S| (dB of peak)".into(),
                    label_scale: 1.0,
                },
                truth: None,
                zoom,
            },
        )?;
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
