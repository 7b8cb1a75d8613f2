use std::path::Path;

use anyhow::{Result, bail};
use mmnormd::capture::space::ensure_room;
use mmnormd::sim::{Scene, simulate, write_simulation};

pub fn run(scene_path: &Path, out: &Path, force: bool, quiet: bool) -> Result<()> {
    let scene = Scene::load(scene_path)?;
    if out.join("capture.json").exists() && !force {
        bail!(
            "{} already holds a capture; pass --force to replace it",
            out.display()
        );
    }
    // Refuse before an hour of simulation, not after it.
    ensure_room(out, scene.channels(), scene.plan.samples_per_chirp)
        .map_err(|e| anyhow::anyhow!("--out {e}"))?;
    tracing::info!(
        "simulating {} ({} object(s)) over a {:.3}×{:.3} m aperture at {:.3} mm spacing",
        scene_path.display(),
        scene.objects.len(),
        scene.aperture.width_m,
        scene.aperture.height_m,
        scene.aperture.spacing_m * 1e3
    );
    let mut result = simulate(&scene, quiet);
    let top = write_simulation(out, &scene, &scene_path.display().to_string(), &mut result)?;
    let s = &result.stats;
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
    println!("truth: truth.ply and truth_top.npy ({top} points)");
    Ok(())
}
