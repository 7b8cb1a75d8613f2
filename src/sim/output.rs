//! Writing a simulation: the capture directory v1, its provenance under `extra.simulation`, and
//! the ground truth (`truth.ply`, the placed mesh; `truth_top.npy`, its top view).

use std::path::Path;

use serde_json::json;

use super::forward::SimOutput;
use super::scene::Scene;
use super::truth;
use crate::capture::dir::{CaptureDirError, write_atomically};
use crate::capture::{npy, write_capture_dir};
use crate::geometry::ply;

/// Records the scene's provenance in the capture and writes `out`. `scene_label` names the
/// scene file (or suite case) in the provenance. Returns the number of top-view truth points.
pub fn write_simulation(
    out: &Path,
    scene: &Scene,
    scene_label: &str,
    result: &mut SimOutput,
) -> Result<usize, CaptureDirError> {
    let top = truth::top_surface(&result.truth_mesh, truth::TOP_GRID_M);
    let s = &result.stats;
    result.capture.extra.insert(
        "simulation".into(),
        json!({
            "mmnormd_version": env!("CARGO_PKG_VERSION"),
            "scene": scene_label,
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
    write_atomically(&out.join("truth_top.npy"), &npy::encode_f64_rows(&top))?;
    Ok(top.len())
}
