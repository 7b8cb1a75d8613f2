use std::path::Path;

use anyhow::{Context, Result, bail};
use mmnormd::capture::dir::read_points_npy;
use mmnormd::capture::truth_files;
use mmnormd::eval::{Metrics, evaluate};
use mmnormd::geometry::{load_mesh, ply};
use mmnormd::sim::truth::{TOP_GRID_M, top_surface_with_normals};

/// Points with optional per-point normals.
type Cloud = (Vec<[f64; 3]>, Option<Vec<[f64; 3]>>);

pub fn run(points: &Path, truth: &Path, tau_m: f64, json: bool) -> Result<()> {
    if !(tau_m.is_finite() && tau_m > 0.0) {
        bail!("--tau-m {tau_m}: must be a positive distance in metres");
    }
    let bytes = std::fs::read(points).with_context(|| format!("reading {}", points.display()))?;
    let cloud =
        ply::parse(&bytes).map_err(|reason| anyhow::anyhow!("{}: {reason}", points.display()))?;
    let (truth_points, truth_normals) = load_truth(truth)?;
    let m = evaluate(
        &cloud.vertices_m,
        cloud.normals.as_deref(),
        &truth_points,
        truth_normals.as_deref(),
        tau_m,
    );
    if json {
        println!("{}", serde_json::to_string(&m)?);
    } else {
        print_table(&m, tau_m);
    }
    Ok(())
}

/// Truth as points (and normals where known): a capture directory's truth, a mesh (scored as
/// seen from above, the paper's depth-camera truth), a PLY point cloud or a (M,3) `.npy`.
fn load_truth(path: &Path) -> Result<Cloud> {
    if path.is_dir() {
        let files = truth_files(path);
        if let Some(mesh) = files.mesh {
            return load_truth(&mesh);
        }
        if let Some(top) = files.top_points {
            return Ok((read_points_npy(&top)?, None));
        }
        bail!(
            "{}: the capture directory holds no truth (truth.ply, truth.stl or truth_top.npy)",
            path.display()
        );
    }
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .unwrap_or("")
        .to_ascii_lowercase();
    match ext.as_str() {
        "npy" => Ok((read_points_npy(path)?, None)),
        "ply" => {
            let bytes =
                std::fs::read(path).with_context(|| format!("reading {}", path.display()))?;
            let data =
                ply::parse(&bytes).map_err(|r| anyhow::anyhow!("{}: {r}", path.display()))?;
            if data.triangles.is_empty() {
                Ok((data.vertices_m, data.normals))
            } else {
                let (p, n) = top_surface_with_normals(&load_mesh(path)?, TOP_GRID_M);
                Ok((p, Some(n)))
            }
        }
        _ => {
            let (p, n) = top_surface_with_normals(&load_mesh(path)?, TOP_GRID_M);
            Ok((p, Some(n)))
        }
    }
}

fn print_table(m: &Metrics, tau_m: f64) {
    let opt = |v: Option<f64>, unit: &str, scale: f64| {
        v.map_or("—".to_string(), |x| format!("{:.4} {unit}", x * scale))
    };
    println!(
        "points {} against {} truth points",
        m.points, m.truth_points
    );
    println!(
        "F-score (τ = {:.1} cm)   {:.4}  (precision {:.4}, recall {:.4}; without the position correction {:.4})",
        tau_m * 100.0,
        m.f_score,
        m.precision,
        m.recall,
        m.f_score_raw
    );
    println!(
        "position error       {}",
        opt(m.position_error_m, "cm", 100.0)
    );
    println!(
        "point error          median {}, p90 {}",
        opt(m.point_error_median_m, "cm", 100.0),
        opt(m.point_error_p90_m, "cm", 100.0)
    );
    println!(
        "relative error < 5 % {}",
        opt(m.rel_error_under_5pct, "", 1.0)
    );
    println!(
        "normal cosine        median {}, p25 {}",
        opt(m.normal_cos_median, "", 1.0),
        opt(m.normal_cos_p25, "", 1.0)
    );
}
