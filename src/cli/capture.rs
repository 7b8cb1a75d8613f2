//! `mmnormd capture raw` and `mmnormd sim radar`.

use std::path::PathBuf;
use std::sync::Arc;

use anyhow::{Context as _, Result};
use mmnormd::dca1000::udp::UdpBoard;
use mmnormd::lab::LabConfig;
use mmnormd::lab::raw::{RawCapture, capture_raw};
use mmnormd::lab::simchain::{SimChain, load_source};
use mmnormd::radar::control::open_serial;
use mmnormd::radar::{CliRadar, RadarControl, RadarProfile};

#[derive(clap::Args)]
pub struct RawArgs {
    /// Lab config (the [radar] and [dca1000] sections are used).
    #[arg(long)]
    config: PathBuf,
    /// Frames to record.
    #[arg(long)]
    frames: u64,
    /// Output directory (adc_data.bin, report.json).
    #[arg(long)]
    out: PathBuf,
    /// Leave the radar alone and drive the DCA1000 only.
    #[arg(long)]
    no_radar: bool,
}

pub fn raw(args: RawArgs, quiet: bool) -> Result<()> {
    let lab = LabConfig::load(&args.config)?;
    let profile = RadarProfile::from_cfg_file(&lab.radar.profile)?;
    anyhow::ensure!(args.frames > 0, "--frames 0: record at least one frame");
    let mut board = UdpBoard::open(&lab.dca1000)?;
    let mut radar = if args.no_radar {
        None
    } else {
        let port = open_serial(&lab.radar)?;
        Some(CliRadar::new(port, lab.radar.session_config()))
    };
    let job = RawCapture {
        lab: &lab,
        profile: &profile,
        frames: args.frames,
        out_dir: &args.out,
        quiet,
    };
    let report = capture_raw(
        &mut board,
        radar.as_mut().map(|r| r as &mut dyn RadarControl),
        &job,
    )
    .with_context(|| {
        format!(
            "capture failed; see {}",
            args.out.join("report.json").display()
        )
    })?;
    let s = &report.capture.stream;
    println!(
        "{} frames of {} B in {:.2} s: {} packets, {} bytes, {} lost, {} duplicates, {} reordered, {} late, {} flagged frames, kernel drops {}",
        s.frames,
        report.frame_bytes,
        report.capture.duration_s,
        s.packets,
        s.bytes,
        s.lost,
        s.duplicates,
        s.reordered,
        s.late,
        report.capture.flagged_frame_indices.len(),
        report
            .capture
            .receive
            .kernel_drops
            .map_or("n/a".to_string(), |d| d.to_string())
    );
    println!("wrote {}/adc_data.bin and report.json", args.out.display());
    Ok(())
}

#[derive(clap::Args)]
pub struct DecodeArgs {
    /// The raw file (adc_data.bin).
    file: PathBuf,
    /// Lab config: its [radar] profile, [dca1000] iq_order and [dca1000.fpga] lvds_mode.
    #[arg(long)]
    config: PathBuf,
    /// Output directory (samples.npy, range_profile.png).
    #[arg(long)]
    out: PathBuf,
    /// Replace samples.npy and range_profile.png if they exist.
    #[arg(long)]
    force: bool,
}

pub fn decode(args: DecodeArgs) -> Result<()> {
    let lab = LabConfig::load(&args.config)?;
    let profile = RadarProfile::from_cfg_file(&lab.radar.profile)?;
    let layout = lab.dca1000.layout(&profile).with_context(|| {
        format!(
            "{} and {}",
            args.config.display(),
            lab.radar.profile.display()
        )
    })?;
    let (npy_path, png_path) = (
        args.out.join("samples.npy"),
        args.out.join("range_profile.png"),
    );
    for p in [&npy_path, &png_path] {
        anyhow::ensure!(
            args.force || !p.exists(),
            "{} exists; pass --force to replace it",
            p.display()
        );
    }
    let bytes =
        std::fs::read(&args.file).with_context(|| format!("reading {}", args.file.display()))?;
    let decoded = mmnormd::lab::decode::decode(&bytes, &layout, &args.file.display().to_string())?;
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("creating {}", args.out.display()))?;
    mmnormd::capture::dir::write_atomically(&npy_path, &decoded.npy())?;
    let range_bin_m = profile.frequency_plan().range_bin_m();
    let profiles = decoded.range_profiles_db();
    let title = format!(
        "Range profile, {} frames x {} chirps",
        decoded.frames, decoded.chirps
    );
    mmnormd::lab::decode::write_range_profile_png(&profiles, range_bin_m, &title, &png_path)?;
    println!(
        "{} frames x {} chirps x {} RX x {} samples ({:?} lanes, {}) -> {} and {}",
        decoded.frames,
        decoded.chirps,
        decoded.rx,
        decoded.samples,
        layout.lanes,
        layout.iq_order.name(),
        npy_path.display(),
        png_path.display()
    );
    Ok(())
}

#[derive(clap::Args)]
pub struct SimRadarArgs {
    /// Lab config: [dca1000] addresses (loopback only) and the [sim] section.
    #[arg(long)]
    config: PathBuf,
}

pub fn sim_radar(args: SimRadarArgs, quiet: bool) -> Result<()> {
    let lab = LabConfig::load(&args.config)?;
    let profile = RadarProfile::from_cfg_file(&lab.radar.profile)?;
    let (source, scale) = load_source(&lab, &profile, quiet)?;
    let frames = source.frames();
    let chain = SimChain::start(&lab, Arc::new(source), None)?;
    println!(
        "radar CLI on {} (linked from {}); DCA1000 on {} sending to {}:{}; {} frames ready ({:.1} ADC counts per unit); Ctrl-C stops",
        chain.radar.path(),
        lab.sim.radar_link.display(),
        chain.board.config_addr(),
        lab.dca1000.host_ip,
        lab.dca1000.host_data_port,
        frames,
        scale
    );
    wait_for_stop_signal()?;
    let (board, cli) = chain.stats();
    println!(
        "stopped: {} commands, {} recordings, {} packets sent; radar {} lines, {} sensorStart",
        board.commands, board.recordings, board.packets_sent, cli.lines, cli.sensor_starts
    );
    Ok(())
}

/// Blocks until SIGINT or SIGTERM.
pub fn wait_for_stop_signal() -> Result<()> {
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .context("starting the signal runtime")?;
    runtime.block_on(async {
        let mut term = tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate())
            .context("installing the SIGTERM handler")?;
        tokio::select! {
            r = tokio::signal::ctrl_c() => r.context("waiting for Ctrl-C"),
            _ = term.recv() => Ok(()),
        }
    })
}
