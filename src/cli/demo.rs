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
    /// Lab config with `simulate = true`.
    #[arg(long, default_value = "config/sim.toml")]
    pub config: PathBuf,
    /// Where scans go [default: the config's recording.data_dir].
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// The scan's folder name [default: scan-<unix seconds>].
    #[arg(long)]
    pub name: Option<String>,
}

pub fn run(args: &DemoArgs, quiet: bool) -> Result<()> {
    let started = std::time::Instant::now();
    let mut lab = LabConfig::load(&args.config)?;
    if !lab.simulate {
        bail!(
            "{}: simulate = false; the demo runs the simulated lab (config/sim.toml)",
            args.config.display()
        );
    }
    if let Some(out) = &args.out {
        lab.recording.data_dir = out.clone();
    }
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
    let events = |e: JobEvent| match e {
        JobEvent::Row { row: r, .. } if r.accepted => progress.inc(1),
        JobEvent::Row { row: r, .. } => progress.set_message(&format!(
            "row {} again: {}",
            r.row + 1,
            r.problem.unwrap_or_default()
        )),
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
