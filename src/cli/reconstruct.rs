use std::path::Path;

use anyhow::{Context, Result, bail};
use mmnormd::capture::dir::{read_points_npy, truth_files};
use mmnormd::capture::read_capture_dir;
use mmnormd::recon::config::{Imaging, Isosurface, Method, VolumeSpec};
use mmnormd::recon::{ReconConfig, Reconstruction, image_volume, output, reconstruct_imaged};

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
            out.join(m.name())
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
    // Before the long work: every output directory can be made (not a file, not under one).
    for dir in methods.iter().map(|&m| dir_of(m)) {
        if dir.exists() && !dir.is_dir() {
            bail!(
                "--out {}: {} exists and is not a directory",
                out.display(),
                dir.display()
            );
        }
        std::fs::create_dir_all(&dir).with_context(|| {
            format!(
                "--out {}: cannot create the output directory {}",
                out.display(),
                dir.display()
            )
        })?;
    }
    let capture = read_capture_dir(capture_dir)?;
    // The image is formed for the first method (mmNorm when it is among them: it alone needs
    // the spectral votes).
    config.method = methods[0];
    let imaged = image_volume(&capture, &config, quiet)?;
    // A simulated capture carries the surface seen from above; the previews draw it under the
    // points. A truth file that cannot be read only costs the overlay. Read once for all methods.
    let truth = truth_files(capture_dir).top_points.and_then(|path| {
        read_points_npy(&path)
            .map_err(|e| tracing::warn!("{}: {e}; previews without the truth", path.display()))
            .ok()
    });
    for method in methods {
        config.method = method;
        let dir = dir_of(method);
        match reconstruct_imaged(&capture, &config, &imaged, quiet) {
            Ok(recon) => write_outputs(
                capture_dir,
                &dir,
                &config,
                &recon,
                &imaged.magnitude,
                truth.as_deref(),
            )?,
            // With several methods, one failing (say, no component for mmNorm) does not discard
            // the others.
            Err(e) if nested => {
                tracing::error!("{}: {e}", method.name());
            }
            Err(e) => return Err(e.into()),
        }
    }
    Ok(())
}

fn write_outputs(
    capture_dir: &Path,
    out: &Path,
    config: &ReconConfig,
    recon: &Reconstruction,
    magnitude: &[f32],
    truth: Option<&[[f64; 3]]>,
) -> Result<()> {
    output::write_reconstruction(
        &capture_dir.display().to_string(),
        out,
        config,
        recon,
        magnitude,
        truth,
    )?;
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
        config.method.name(),
        s.components.len(),
        stages.join(", ")
    );
    Ok(())
}
