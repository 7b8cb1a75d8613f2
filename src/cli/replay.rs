//! `mmnormd replay`, `mmnormd export` and `mmnormd mcap recover`.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use mmnormd::capture::write_capture_dir;
use mmnormd::lab::LabConfig;
use mmnormd::lab::job::{ScanPaths, reconstruct_and_score, replay_capture};
use mmnormd::record::recover;
use mmnormd::record::replay::read_scan;

fn read(mcap: &Path, config: Option<&Path>) -> Result<(mmnormd::capture::Capture, LabConfig)> {
    let scan = read_scan(mcap)?;
    if let Some(damage) = &scan.read.damage {
        tracing::warn!(
            "{}: read up to damage ({damage}); `mmnormd mcap recover` salvages such a file",
            mcap.display()
        );
    }
    let override_config = config.map(LabConfig::load).transpose()?;
    let (lab, _setup, capture) = replay_capture(&scan, override_config.as_ref())?;
    if capture.antennas() == 0 {
        bail!("{}: no finished row to rebuild", mcap.display());
    }
    Ok((capture, lab))
}

/// Rebuilds the capture from the raw frames and RTDE samples, aligns and reconstructs again.
pub fn replay(mcap: &Path, out: &Path, config: Option<&Path>, quiet: bool) -> Result<()> {
    let (capture, lab) = read(mcap, config)?;
    let paths = ScanPaths::new(out);
    if paths.capture.exists() || paths.recon.exists() {
        bail!(
            "{} already holds a replay; choose another --out",
            out.display()
        );
    }
    write_capture_dir(&paths.capture, &capture)?;
    let (recon, _) =
        reconstruct_and_score(&lab.reconstruction, &capture, &paths, None, quiet, &|_| {})?;
    println!(
        "replayed {}: {} antennas, {} points into {}",
        mcap.display(),
        capture.antennas(),
        recon.points_m.len(),
        paths.recon.join("points.ply").display()
    );
    Ok(())
}

/// Writes the capture directory v1 of a recording.
pub fn export(mcap: &Path, out: &Path, config: Option<&Path>) -> Result<()> {
    let (capture, _) = read(mcap, config)?;
    if out.join("capture.json").exists() {
        bail!("{} already holds a capture", out.display());
    }
    write_capture_dir(out, &capture)?;
    println!(
        "exported {} antennas × {} samples to {}",
        capture.antennas(),
        capture.plan.samples_per_chirp,
        out.display()
    );
    Ok(())
}

/// Salvages a recording whose writer died.
pub fn recover_file(damaged: &Path, out: Option<PathBuf>) -> Result<()> {
    let out = out.unwrap_or_else(|| damaged.with_extension("recovered.mcap"));
    let report =
        recover(damaged, &out).with_context(|| format!("recovering {}", damaged.display()))?;
    println!(
        "recovered {} messages, {} channels, {} metadata records into {}{}",
        report.messages,
        report.channels,
        report.metadata,
        out.display(),
        report
            .read
            .damage
            .map(|d| format!(" (the original stops with: {d})"))
            .unwrap_or_default()
    );
    Ok(())
}
