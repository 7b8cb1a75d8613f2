//! `mmnormd replay`, `mmnormd export`, `mmnormd calibrate` and `mmnormd mcap recover`.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use mmnormd::capture::write_capture_dir;
use mmnormd::lab::LabConfig;
use mmnormd::lab::calibrate::calibrate;
use mmnormd::lab::job::{ScanPaths, reconstruct_and_score, replay_capture, replay_rows};
use mmnormd::record::recover;
use mmnormd::record::replay::{RecordedScan, read_scan, replayed_output_names};

fn read_recording(mcap: &Path) -> Result<RecordedScan> {
    let scan = read_scan(mcap)?;
    if let Some(damage) = &scan.read.damage {
        tracing::warn!(
            "{}: read up to damage ({damage}); `mmnormd mcap recover` salvages such a file",
            mcap.display()
        );
    }
    Ok(scan)
}

fn read(mcap: &Path, config: Option<&Path>) -> Result<(mmnormd::capture::Capture, LabConfig)> {
    let scan = read_recording(mcap)?;
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

/// Calibrates `align.sync_offset_s` and `tcp_from_radar` from a recorded scan of a point
/// reflector measured at `reflector_in_base_m` (docs/hardware.md §6).
pub fn calibrate_scan(
    mcap: &Path,
    reflector_in_base_m: [f64; 3],
    config: Option<&Path>,
) -> Result<()> {
    let scan = read_recording(mcap)?;
    let override_config = config.map(LabConfig::load).transpose()?;
    let (lab, setup, kept) = replay_rows(&scan, override_config.as_ref())?;
    let rows: Vec<_> = kept.into_iter().map(|(rec, _)| rec).collect();
    let c = calibrate(
        &lab,
        &setup,
        &replayed_output_names(),
        &rows,
        reflector_in_base_m,
    )
    .with_context(|| format!("calibrating from {}", mcap.display()))?;
    let mm = |v: [f64; 3]| {
        format!(
            "[{:.2}, {:.2}, {:.2}] mm",
            v[0] * 1e3,
            v[1] * 1e3,
            v[2] * 1e3
        )
    };
    println!(
        "{} rows, {} antennas; the reflector focuses at {} in the base frame, {} from where it was measured",
        rows.len(),
        c.antennas,
        mm(c.found_in_base_m),
        mm(c.error_in_base_m)
    );
    println!(
        "forward rows focus it {:+.3} mm from backward rows with sync_offset_s = {:.4}",
        c.disagreement_m * 1e3,
        c.sync_offset_s
    );
    println!("set in [align]:");
    println!("sync_offset_s = {:.4}", c.suggested_sync_offset_s);
    let t = c.suggested_tcp_from_radar;
    println!(
        "tcp_from_radar = [{:.5}, {:.5}, {:.5}, {}, {}, {}]   # translation corrected; only as good as the reflector's measured position",
        t[0], t[1], t[2], t[3], t[4], t[5]
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

/// Three comma-separated numbers (metres) of the flag `flag`.
pub fn parse_point(text: &str, flag: &str) -> Result<[f64; 3]> {
    let values: Vec<f64> = text
        .split(',')
        .map(|v| v.trim().parse::<f64>())
        .collect::<Result<_, _>>()
        .with_context(|| format!("{flag} {text}: expected X,Y,Z in metres"))?;
    match values.as_slice() {
        [x, y, z] if values.iter().all(|v| v.is_finite()) => Ok([*x, *y, *z]),
        _ => bail!("{flag} {text}: expected three finite numbers X,Y,Z in metres"),
    }
}
