use std::path::Path;

use anyhow::{Context, Result, bail};
use mmnormd::capture::dir::write_atomically;
use mmnormd::capture::{npy, write_capture_dir};
use mmnormd::geometry::ply;
use mmnormd::sim::{Scene, simulate, truth};
use serde_json::json;

pub fn run(scene_path: &Path, out: &Path, force: bool, quiet: bool) -> Result<()> {
    let scene = Scene::load(scene_path)?;
    if out.join("capture.json").exists() && !force {
        bail!(
            "{} already holds a capture; pass --force to replace it",
            out.display()
        );
    }
    tracing::info!(
        "simulating {} ({} object(s)) over a {:.3}×{:.3} m aperture at {:.3} mm spacing",
        scene_path.display(),
        scene.objects.len(),
        scene.aperture.width_m,
        scene.aperture.height_m,
        scene.aperture.spacing_m * 1e3
    );
    let mut result = simulate(&scene, quiet);
    let top = truth::top_surface(&result.truth_mesh, truth::TOP_GRID_M);
    let s = &result.stats;
    result.capture.extra.insert(
        "simulation".into(),
        json!({
            "mmnormd_version": env!("CARGO_PKG_VERSION"),
            "scene": scene_path.display().to_string(),
            "aperture": {
                "columns": result.antennas.columns,
                "rows": result.antennas.rows,
                "per_position": result.antennas.per_position,
                "spacing_m": scene.aperture.spacing_m,
                "z_m": scene.aperture.z_m,
                "layout": format!("{:?}", scene.aperture.layout).to_lowercase(),
                "antenna_pattern": format!("{:?}", scene.aperture.pattern).to_lowercase(),
            },
            "noise": scene.noise.map(|(snr_db, seed)| json!({"snr_db": snr_db, "seed": seed, "sigma": s.noise_sigma})),
            "occluder": scene.occluder.map(|o| json!({"z_m": o.z_m, "thickness_m": o.thickness_m, "refractive_index": o.refractive_index, "loss_db": o.loss_db})),
            "stats": s,
        }),
    );
    write_capture_dir(out, &result.capture)?;
    write_atomically(
        &out.join("truth.ply"),
        &ply::encode_mesh(&result.truth_mesh.vertices_m, &result.truth_mesh.triangles),
    )?;
    write_atomically(&out.join("truth_top.npy"), &npy::encode_f64_rows(&top))
        .context("writing truth_top.npy")?;
    println!(
        "wrote {}: {} antennas × {} samples, {} triangles, {} specular + {} diffuse + {} edge samples, {} contributions, {:.1} s",
        out.display(),
        s.antennas,
        result.capture.plan.samples_per_chirp,
        s.triangles,
        s.specular_samples,
        s.diffuse_samples,
        s.edge_samples,
        s.contributions,
        s.seconds
    );
    println!("truth: truth.ply and truth_top.npy ({} points)", top.len());
    Ok(())
}
