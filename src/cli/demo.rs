//! `mmnormd demo`: the simulated lab end to end (see the README).

use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicBool;

use anyhow::{Context, Result, bail};
use mmnormd::lab::LabConfig;
use mmnormd::lab::devices::LabDevices;
use mmnormd::lab::job::{JobEvent, LiveJob, ScanRequest, run_live, truth_of};
use mmnormd::lab::scan::ScanSetup;
use mmnormd::lab::simlab::SimLab;
use mmnormd::progress::Progress;

#[derive(clap::Args)]
pub struct DemoArgs {
    /// Lab config with `simulate = true` [default: the simulated lab built into the binary,
    /// config/sim.toml with its scene and radar profile, written under --out/demo-config].
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Where scans go [default: the config's recording.data_dir; with the built-in config,
    /// captures/lab under the current directory].
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// The scan's folder name [default: scan-<unix seconds>].
    #[arg(long)]
    pub name: Option<String>,
}

/// The simulated lab's files, built into the binary so that the demo runs in any directory:
/// (path relative to the bundle's root, contents). The config names the other two by relative
/// path, so they keep the repository's layout.
const BUILT_IN_LAB: [(&str, &str); 3] = [
    ("config/sim.toml", include_str!("../../config/sim.toml")),
    (
        "tools/scenes/lab_sphere.toml",
        include_str!("../../tools/scenes/lab_sphere.toml"),
    ),
    (
        "firmware_cfg/iwr1443_demo.cfg",
        include_str!("../../firmware_cfg/iwr1443_demo.cfg"),
    ),
];

/// Writes [`BUILT_IN_LAB`] under `root` and returns the config's path.
fn write_built_in_lab(root: &Path) -> Result<PathBuf> {
    for (relative, text) in BUILT_IN_LAB {
        let path = root.join(relative);
        if let Some(dir) = path.parent() {
            std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
        }
        std::fs::write(&path, text).with_context(|| format!("writing {}", path.display()))?;
    }
    Ok(root.join(BUILT_IN_LAB[0].0))
}

pub fn run(args: &DemoArgs, quiet: bool) -> Result<()> {
    let started = std::time::Instant::now();
    let (config_path, out) = match &args.config {
        Some(path) => (path.clone(), args.out.clone()),
        None => {
            let out = args
                .out
                .clone()
                .unwrap_or_else(|| PathBuf::from("captures").join("lab"));
            let config = write_built_in_lab(&out.join("demo-config"))?;
            (config, Some(out))
        }
    };
    let mut lab = LabConfig::load(&config_path)?;
    if !lab.simulate {
        bail!(
            "{}: simulate = false; the demo runs the simulated lab (config/sim.toml)",
            config_path.display()
        );
    }
    if let Some(out) = out {
        lab.recording.data_dir = out;
    }
    println!(
        "config: {}; scans go to {}",
        config_path.display(),
        lab.recording.data_dir.display()
    );
    let request = ScanRequest {
        name: args.name.clone(),
        ..ScanRequest::default()
    };
    let setup = ScanSetup::new(&lab, request.apply(&lab.scan))?;
    let name = request.folder_name(mmnormd::record::unix_now_s())?;
    println!(
        "simulated lab: {} rows of {:.0} cm at {:.0} mm/s ({:.1} s of rows), radar {} frames every {:.0} ms",
        setup.plan.rows.len(),
        setup.spec.width_m * 100.0,
        setup.spec.speed_m_per_s * 1e3,
        setup.plan.total_row_time_s,
        setup.profile.frames,
        setup.timing.frame_period_s * 1e3
    );
    let sim = SimLab::start(&lab, &setup, None).context("starting the simulated lab")?;
    let mut devices =
        LabDevices::connect(&lab, &setup.profile).context("connecting to the simulated lab")?;
    let truth = truth_of(&sim.truth_mesh);
    let progress = Progress::new("scan rows", setup.plan.rows.len() as u64, quiet);
    let problems = std::sync::Mutex::new(Vec::<String>::new());
    let events = |e: JobEvent| match e {
        JobEvent::Row { row: r, .. } if r.accepted => progress.inc(1),
        JobEvent::Row { row: r, .. } => {
            let problem = r.problem.unwrap_or_default();
            progress.set_message(&format!("row {} again: {problem}", r.row + 1));
            if let Ok(mut p) = problems.lock() {
                p.push(problem);
            }
        }
        JobEvent::Stage { stage, .. } => progress.set_message(&stage),
        _ => {}
    };
    let job = LiveJob {
        lab: &lab,
        setup: &setup,
        request: &request,
        name: &name,
        truth: Some(&truth),
        truth_mesh: Some(&sim.truth_mesh),
        quiet,
    };
    let result = run_live(
        &job,
        &mut devices.devices(),
        &AtomicBool::new(false),
        &events,
    )?;
    progress.finish();
    let stats = sim.frames.stats();
    let board = sim.chain.board.stats();
    println!(
        "scan: {} rows ({} rescanned), {} frames, {} kept, {} packets lost, {:.1} s; the simulated radar rendered {} frames, {} packets late (worst {:.1} ms)",
        result.rows,
        result.rescanned_rows,
        result.frames,
        result.kept_frames,
        result.lost_packets,
        result.scan_s,
        stats.frames_rendered,
        board.packets_late,
        board.worst_late_ms
    );
    let problems = problems.into_inner().unwrap_or_default();
    for line in explain_scan(
        result.rescanned_rows,
        &problems,
        board.packets_late,
        result.lost_packets,
    ) {
        println!("  {line}");
    }
    if let Some(m) = &result.metrics {
        println!(
            "reconstruction: {} points from {} antennas in {:.1} s; F-score {:.3} (precision {:.3}, recall {:.3}) at τ = 1.5 cm, median point error {:.1} mm, normal cos median {:.3}",
            result.points,
            result.antennas,
            result.recon_s,
            m.f_score,
            m.precision,
            m.recall,
            m.point_error_median_m.unwrap_or(f64::NAN) * 1e3,
            m.normal_cos_median.unwrap_or(f64::NAN)
        );
        println!(
            "  precision: the share of rebuilt points within 1.5 cm of the true surface (1.000: \
             none is false)."
        );
        println!(
            "  recall: the share of the object's top surface (as a camera above sees it) that was \
             rebuilt. A radar sees a surface only where its echo comes back into the aperture, \
             and a {:.0}×{:.0} cm aperture sees the part of a rounded object that faces it, not \
             its flanks: recall, and with it the F-score, is capped by the aperture (the paper's \
             60×45 cm one sees more). points_top.png shows the truth in grey under the points.",
            setup.spec.width_m * 100.0,
            setup.spec.height_m * 100.0
        );
        println!(
            "  median point error: how far the rebuilt points lie from the true surface, against \
             this reconstruction's {:.0} mm voxels.",
            lab.reconstruction.voxel_m * 1e3
        );
    }
    let p = &result.paths;
    println!("recording  {}", p.mcap.display());
    println!("capture    {}", p.capture.display());
    println!(
        "points     {}",
        Path::new(&p.recon).join("points.ply").display()
    );
    println!(
        "pictures   {} and {}",
        p.recon.join("points_top.png").display(),
        p.recon.join("image_max_z.png").display()
    );
    println!("result     {}", p.result.display());
    println!("demo finished in {:.1} s", started.elapsed().as_secs_f64());
    Ok(())
}

/// One line each on what a loaded machine does to the simulated scan: rows scanned again (by
/// cause), packets the simulated board sent late, packets lost.
fn explain_scan(
    rescanned_rows: usize,
    problems: &[String],
    packets_late: u64,
    lost_packets: u64,
) -> Vec<String> {
    let mut lines = Vec::new();
    let count = |needle: &str| problems.iter().filter(|p| p.contains(needle)).count();
    let gaps = count("RTDE gap");
    if gaps > 0 {
        lines.push(format!(
            "{gaps} row(s) had an RTDE gap: the 500 Hz pose stream paused (the simulated controller \
             shares the CPU with the radar's rendering), so the row was scanned again rather than \
             interpolating poses across the hole."
        ));
    }
    let short = count("short of the row's end");
    if short > 0 {
        lines.push(format!(
            "{short} row(s) stopped short: the arm's RTDE watchdog tripped because a keep-alive \
             came late on a busy host; the row was scanned again."
        ));
    }
    let clock = count("clock fit strays");
    if clock > 0 {
        lines.push(format!(
            "{clock} row(s) had a clock fit off its line: the host stamped arrivals late, which \
             would misplace antennas by millimetres, so the row was scanned again."
        ));
    }
    let loss = count("frame loss");
    if loss > 0 {
        lines.push(format!(
            "{loss} row(s) lost too many frames (UDP packets dropped on a loaded host); the row was \
             scanned again."
        ));
    }
    if rescanned_rows > 0 && gaps + short + clock + loss == 0 {
        lines.push(format!(
            "{rescanned_rows} row(s) were scanned again; the daemon's log names each cause."
        ));
    }
    if packets_late > 0 {
        lines.push(format!(
            "{packets_late} packets late: the simulated radar renders each frame on this same CPU \
             and sometimes finishes after the frame was due. Nothing is lost: the data arrive \
             whole, and the time alignment fits the earliest arrivals, so late ones do not move \
             the antennas."
        ));
    }
    if lost_packets > 0 {
        lines.push(format!(
            "{lost_packets} packets lost: their samples are zero-filled and the frames flagged; \
             rows over recording.max_frame_loss are scanned again."
        ));
    }
    if lines.is_empty() {
        lines.push("no row needed scanning again and no packet was late or lost.".into());
    }
    lines
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_built_in_lab_loads_from_any_directory() {
        let dir = tempfile::tempdir().unwrap();
        let config = write_built_in_lab(&dir.path().join("demo-config")).unwrap();
        let lab = LabConfig::load(&config).unwrap();
        assert!(lab.simulate);
        // The scene and the radar profile it names resolve inside the written bundle.
        let scene = lab.sim.scene.clone().unwrap();
        assert!(scene.starts_with(dir.path()), "{}", scene.display());
        mmnormd::sim::Scene::load(&scene).unwrap();
        let setup = ScanSetup::new(&lab, ScanRequest::default().apply(&lab.scan)).unwrap();
        assert_eq!(setup.plan.rows.len(), 26);
    }

    #[test]
    fn each_cause_of_a_rescan_gets_its_own_line_and_a_clean_scan_says_so() {
        let problems = vec![
            "2 RTDE gap(s) during the row".to_string(),
            "the radar clock fit strays 3.1 ms from its line".to_string(),
        ];
        let lines = explain_scan(2, &problems, 5, 0);
        assert_eq!(lines.len(), 3, "{lines:?}");
        assert!(
            lines[0].starts_with("1 row(s) had an RTDE gap"),
            "{lines:?}"
        );
        assert!(
            lines[1].starts_with("1 row(s) had a clock fit"),
            "{lines:?}"
        );
        assert!(lines[2].starts_with("5 packets late"), "{lines:?}");
        let clean = explain_scan(0, &[], 0, 0);
        assert_eq!(clean.len(), 1);
        assert!(clean[0].starts_with("no row needed"), "{clean:?}");
    }
}
