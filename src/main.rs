//! `mmnormd`: the command-line front end. The only place that uses `anyhow`.

mod cli;

use std::path::PathBuf;

use clap::{Parser, Subcommand};
use mmnormd::recon::config::{Imaging, Isosurface, VolumeSpec};
use tracing_subscriber::EnvFilter;

#[derive(Parser)]
#[command(
    name = "mmnormd",
    version,
    about = "mmWave NLOS 3-D reconstruction (mmNorm) and its lab system"
)]
struct Args {
    /// More log output (-v debug, -vv trace). RUST_LOG overrides.
    #[arg(short, long, action = clap::ArgAction::Count, global = true)]
    verbose: u8,
    /// No progress bars or progress log lines.
    #[arg(short, long, global = true)]
    quiet: bool,
    /// Run the daemon with this lab config (when no subcommand is given).
    #[arg(long)]
    config: Option<PathBuf>,
    #[command(subcommand)]
    command: Option<Command>,
}

#[derive(Subcommand)]
enum Command {
    /// Start the simulated lab in-process, scan the demo aperture through the real clients,
    /// reconstruct, score against the scene's truth and print where the files are.
    Demo(cli::demo::DemoArgs),
    /// Talk to a running daemon over its control port.
    Ctl(cli::ctl::CtlArgs),
    /// Rebuild a recorded scan from its raw frames and RTDE samples: align and reconstruct
    /// again into OUT/capture and OUT/recon.
    Replay {
        /// The scan's recording.
        mcap: PathBuf,
        /// Output directory: OUT/capture and OUT/recon.
        #[arg(long)]
        out: PathBuf,
        /// Use this config instead of the one recorded in the file.
        #[arg(long)]
        config: Option<PathBuf>,
    },
    /// Write a recorded scan as a capture directory v1.
    Export {
        /// The scan's recording.
        mcap: PathBuf,
        /// Output capture directory.
        #[arg(long)]
        out: PathBuf,
        /// Use this config instead of the one recorded in the file.
        #[arg(long)]
        config: Option<PathBuf>,
    },
    /// Calibrate align.sync_offset_s and the translation of align.tcp_from_radar from a
    /// recorded scan of a point reflector, rows both ways (docs/hardware.md §6).
    Calibrate {
        /// The scan's recording.
        mcap: PathBuf,
        /// The reflector's apex as measured, X,Y,Z in metres in the robot's base frame (also
        /// where the search starts: within 2 cm of it).
        #[arg(long, value_name = "X,Y,Z", allow_hyphen_values = true)]
        reflector_in_base_m: String,
        /// Use this config instead of the one recorded in the file.
        #[arg(long)]
        config: Option<PathBuf>,
    },
    /// MCAP tools.
    Mcap {
        #[command(subcommand)]
        which: McapCommand,
    },
    /// Simulate a scan of a scene and write a capture directory v1 with its ground truth.
    Simulate {
        /// Scene file (TOML); docs/formats.md describes the format.
        #[arg(long)]
        scene: PathBuf,
        /// Output capture directory.
        #[arg(long)]
        out: PathBuf,
        /// Replace an existing capture in OUT.
        #[arg(long)]
        force: bool,
    },
    /// Check a capture directory and summarise it; optionally draw its aperture power map.
    Inspect {
        /// Capture directory v1.
        capture: PathBuf,
        /// Write the received power of every antenna over the aperture as a PNG.
        #[arg(long)]
        png: Option<PathBuf>,
        /// Draw only echoes whose one-way range (range offset removed) lies in MIN,MAX metres,
        /// e.g. 0.30,0.45 to look past a cardboard sheet.
        #[arg(long, value_name = "MIN,MAX", allow_hyphen_values = true)]
        gate: Option<String>,
    },
    /// Score a point cloud against ground truth with the paper's metrics (§5).
    Eval {
        /// Reconstructed points: PLY with x y z (and nx ny nz for the normal metrics).
        #[arg(long)]
        points: PathBuf,
        /// Ground truth: a mesh (.stl/.obj/.ply, scored as seen from above), a point cloud
        /// (.ply without faces, or an (M,3) .npy), or a capture directory holding truth.
        #[arg(long)]
        truth: PathBuf,
        /// F-score distance threshold, metres.
        #[arg(long, default_value_t = 0.015)]
        tau_m: f64,
        /// Print one JSON object instead of a table.
        #[arg(long)]
        json: bool,
    },
    /// Reconstruct a capture: mmNorm (default) or a baseline; writes points.ply, summary.json
    /// and PNG previews.
    Reconstruct {
        /// Capture directory v1.
        capture: PathBuf,
        /// Output directory.
        #[arg(long)]
        out: PathBuf,
        /// Reconstruction method [default: mmnorm, or recon.toml's]; `all` runs the three from
        /// one image into OUT/mmnorm, OUT/backprojection and OUT/interferometric.
        #[arg(long, value_enum)]
        method: Option<cli::reconstruct::MethodChoice>,
        /// How mmNorm picks each component's isosurface [default: optimized].
        #[arg(long, value_enum)]
        isosurface: Option<Isosurface>,
        /// How S(v) is formed [default: auto, or recon.toml's]: `auto` takes range migration
        /// when the phase centres form a raster and says why in summary.json.
        #[arg(long, value_enum)]
        imaging: Option<Imaging>,
        /// Parameters (TOML); every key is optional; docs/reconstruction.md lists them.
        #[arg(long)]
        config: Option<PathBuf>,
        /// Voxel edge in millimetres [default: 1].
        #[arg(long)]
        voxel_mm: Option<f64>,
        /// `auto`, or the box x0,x1,y0,y1,z0,z1 in metres (capture frame).
        #[arg(long, allow_hyphen_values = true)]
        volume: Option<VolumeSpec>,
        /// Replace an existing reconstruction in OUT.
        #[arg(long)]
        force: bool,
    },
    /// Benchmarks.
    Bench {
        #[command(subcommand)]
        which: BenchCommand,
    },
    /// Parse an IWR1443 CLI profile (.cfg) and print its register codes and derived figures.
    Profile {
        /// The .cfg file.
        cfg: PathBuf,
    },
    /// Record from the devices without the robot.
    Capture {
        #[command(subcommand)]
        which: CaptureCommand,
    },
    /// Check the UR5e before a scan.
    Robot {
        #[command(subcommand)]
        which: RobotCommand,
    },
    /// Run simulated devices on loopback addresses and a PTY.
    Sim {
        #[command(subcommand)]
        which: SimCommand,
    },
}

#[derive(Subcommand)]
enum CaptureCommand {
    /// Configure the radar and the DCA1000, record N frames, and write adc_data.bin (TI's
    /// layout, bit-exact) and report.json (packets, loss, reordering, flagged frames).
    Raw(cli::capture::RawArgs),
    /// Decode an adc_data.bin under a lab config's profile, lvds_mode and iq_order: writes
    /// samples.npy (complex64, frames × chirps × RX × samples) and range_profile.png.
    Decode(cli::capture::DecodeArgs),
}

#[derive(Subcommand)]
enum SimCommand {
    /// The IWR1443 CLI simulator on a PTY and the DCA1000 simulator on loopback UDP, streaming
    /// the frames of the config's [sim] scene or capture directory, until Ctrl-C.
    Radar(cli::capture::SimRadarArgs),
    /// A UR5e simulator: RTDE, Dashboard and script ports on 127.0.0.1, until Ctrl-C.
    Robot(cli::robot::SimRobotArgs),
}

#[derive(Subcommand)]
enum McapCommand {
    /// Salvage a recording whose writer died (kill -9, full disk): every whole chunk is
    /// copied into a new finished file [default: FILE with extension .recovered.mcap].
    Recover {
        /// The damaged recording (it is only read).
        file: PathBuf,
        /// The recovered file; an existing file is never replaced [default: FILE with
        /// extension .recovered.mcap].
        #[arg(long)]
        out: Option<PathBuf>,
    },
}

#[derive(Subcommand)]
enum RobotCommand {
    /// Robot mode, safety status, remote control and TCP pose.
    Status(cli::robot::StatusArgs),
    /// Record the RTDE outputs to CSV: one row per package, host receive time first.
    Log(cli::robot::LogArgs),
}

#[derive(Subcommand)]
enum BenchCommand {
    /// The paper's evaluation (§6.2–§6.3) over a suite of simulated scenes: results.csv,
    /// report.md, CDF plots and one picture per case.
    Accuracy(cli::bench::AccuracyArgs),
    /// The pipeline on the paper's full-scale workload (60×45 cm at λ/4, 4 RX, 8.3·10⁷ voxels),
    /// stage by stage, against the exact reference on a sub-volume in the same run.
    Perf(cli::bench::PerfArgs),
    /// The exact per-antenna kernel alone (backprojection and normal votes on a voxel cube),
    /// in updates/s and as a fraction of the CPU's arithmetic peak; medians of repeats.
    Kernel(cli::bench::KernelArgs),
    /// The DCA1000 receive path (reassembly and 4-lane decoding) on one core, in MB/s against
    /// the real stream rate of 2.73 MB/s.
    Stream(cli::bench::StreamArgs),
    /// Chirp synthesis (the simulator's inner sum): one chirp of R reflections swept directly
    /// and gridded, and the R from which gridding wins; medians of repeats on one thread.
    Tones(cli::bench::TonesArgs),
    /// How much of each case's truth a specular method can see under each suite's aperture,
    /// from the geometry alone: the F-score of the seen truth points (no simulation).
    Coverage(cli::bench::CoverageArgs),
}

fn main() -> std::process::ExitCode {
    let args = Args::parse();
    let default = match args.verbose {
        0 => "info",
        1 => "debug",
        _ => "trace",
    };
    let filter = EnvFilter::try_from_default_env().unwrap_or_else(|_| EnvFilter::new(default));
    let colour = colour_logs(
        std::io::IsTerminal::is_terminal(&std::io::stderr()),
        std::env::var_os("NO_COLOR"),
    );
    tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        .with_ansi(colour)
        .with_target(false)
        .init();
    // A bad MMNORMD_KERNEL stops the program here, named, before any work.
    if let Err(e) = mmnormd::recon::kernel::KernelIsa::from_env() {
        return report(Err(e.into()));
    }
    let Some(command) = args.command else {
        return match args.config {
            Some(config) => report(cli::daemon::run(&config, args.quiet)),
            None => {
                eprintln!(
                    "error: give a subcommand, or --config LAB.toml to run the daemon (see --help)"
                );
                std::process::ExitCode::FAILURE
            }
        };
    };
    if !matches!(
        command,
        Command::Demo(_) | Command::Sim { .. } | Command::Capture { .. }
    ) {
        end_quietly_on_closed_stdout();
    }
    let result = match command {
        Command::Simulate { scene, out, force } => {
            cli::simulate::run(&scene, &out, force, args.quiet)
        }
        Command::Inspect { capture, png, gate } => gate
            .as_deref()
            .map(cli::inspect::parse_gate)
            .transpose()
            .and_then(|gate| cli::inspect::run(&capture, png.as_deref(), gate)),
        Command::Eval {
            points,
            truth,
            tau_m,
            json,
        } => cli::eval::run(&points, &truth, tau_m, json),
        Command::Reconstruct {
            capture,
            out,
            method,
            isosurface,
            imaging,
            config,
            voxel_mm,
            volume,
            force,
        } => cli::reconstruct::run(
            &capture,
            &out,
            config.as_deref(),
            cli::reconstruct::Overrides {
                method,
                isosurface,
                imaging,
                voxel_mm,
                volume,
            },
            force,
            args.quiet,
        ),
        Command::Bench {
            which: BenchCommand::Accuracy(a),
        } => cli::bench::accuracy(a, args.quiet),
        Command::Bench {
            which: BenchCommand::Perf(a),
        } => cli::bench::perf(a, args.quiet),
        Command::Bench {
            which: BenchCommand::Kernel(a),
        } => cli::bench::kernel(a, args.quiet),
        Command::Bench {
            which: BenchCommand::Stream(a),
        } => cli::bench::stream(a),
        Command::Bench {
            which: BenchCommand::Tones(a),
        } => cli::bench::tones(a),
        Command::Bench {
            which: BenchCommand::Coverage(a),
        } => cli::bench::coverage(a, args.quiet),
        Command::Profile { cfg } => cli::profile::run(&cfg),
        Command::Demo(a) => cli::demo::run(&a, args.quiet),
        Command::Ctl(a) => cli::ctl::run(&a, args.quiet),
        Command::Replay { mcap, out, config } => {
            cli::replay::replay(&mcap, &out, config.as_deref(), args.quiet)
        }
        Command::Export { mcap, out, config } => {
            cli::replay::export(&mcap, &out, config.as_deref())
        }
        Command::Calibrate {
            mcap,
            reflector_in_base_m,
            config,
        } => cli::replay::parse_point(&reflector_in_base_m, "--reflector-in-base-m")
            .and_then(|p| cli::replay::calibrate_scan(&mcap, p, config.as_deref())),
        Command::Mcap {
            which: McapCommand::Recover { file, out },
        } => cli::replay::recover_file(&file, out),
        Command::Capture {
            which: CaptureCommand::Raw(a),
        } => cli::capture::raw(a, args.quiet),
        Command::Capture {
            which: CaptureCommand::Decode(a),
        } => cli::capture::decode(a),
        Command::Sim {
            which: SimCommand::Radar(a),
        } => cli::capture::sim_radar(a, args.quiet),
        Command::Sim {
            which: SimCommand::Robot(a),
        } => cli::robot::sim_robot(a),
        Command::Robot {
            which: RobotCommand::Status(a),
        } => cli::robot::status(a),
        Command::Robot {
            which: RobotCommand::Log(a),
        } => cli::robot::log(a, args.quiet),
    };
    report(result)
}

/// A report printed into a pipe that the reader has closed (`mmnormd eval … | head -3`) ends
/// the program quietly, as it ends other Unix tools, instead of panicking in `println!`. The
/// Rust runtime ignores SIGPIPE; this restores the default for the one-shot commands. The
/// daemon, the demo, the device simulators and `capture` keep it ignored: they serve sockets or
/// record from devices, and neither a peer that hangs up nor a closed log pipe may stop them.
fn end_quietly_on_closed_stdout() {
    #[cfg(unix)]
    // SAFETY: sets a signal disposition to its default before any thread of ours has started;
    // no handler runs.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
}

/// Whether log lines carry ANSI colour: only on a terminal, and never when `NO_COLOR` is set to
/// anything but the empty string (no-color.org). The journal of a systemd unit, a pipe and a file
/// get plain text.
fn colour_logs(stderr_is_terminal: bool, no_color: Option<std::ffi::OsString>) -> bool {
    stderr_is_terminal && no_color.is_none_or(|v| v.is_empty())
}

fn report(result: anyhow::Result<()>) -> std::process::ExitCode {
    match result {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {}", error_chain(&e));
            std::process::ExitCode::FAILURE
        }
    }
}

/// The error and its causes joined by ": ", leaving out a cause whose text the message before it
/// already ends with (the library's errors name their source in their own message).
fn error_chain(e: &anyhow::Error) -> String {
    let mut out = String::new();
    for cause in e.chain() {
        let text = cause.to_string();
        if out.ends_with(&text) {
            continue;
        }
        if !out.is_empty() {
            out.push_str(": ");
        }
        out.push_str(&text);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn logs_are_coloured_only_on_a_terminal_without_no_color() {
        assert!(colour_logs(true, None));
        assert!(colour_logs(true, Some("".into())));
        assert!(!colour_logs(true, Some("1".into())));
        assert!(!colour_logs(false, None));
    }

    /// Every argument of every subcommand says what it is (and, for a quantity, its unit), so
    /// that `--help` is the reference.
    #[test]
    fn every_option_and_argument_has_help_text() {
        use clap::CommandFactory;
        fn walk(cmd: &clap::Command, path: &str, missing: &mut Vec<String>) {
            for arg in cmd.get_arguments() {
                let id = arg.get_id().as_str();
                if id == "help" || id == "version" {
                    continue;
                }
                if arg.get_help().is_none() && arg.get_long_help().is_none() {
                    missing.push(format!("{path} {id}"));
                }
            }
            for sub in cmd.get_subcommands() {
                if sub.get_about().is_none() && sub.get_long_about().is_none() {
                    missing.push(format!("{path} {} (the subcommand)", sub.get_name()));
                }
                walk(sub, &format!("{path} {}", sub.get_name()), missing);
            }
        }
        let mut missing = Vec::new();
        walk(&Args::command(), "mmnormd", &mut missing);
        assert!(missing.is_empty(), "no help text: {missing:#?}");
    }

    #[test]
    fn an_error_names_its_source_once() {
        let io = std::io::Error::new(std::io::ErrorKind::NotFound, "no such file");
        let e = anyhow::Error::new(mmnormd::bench::BenchError::Io {
            path: "out/results.csv".into(),
            source: io,
        })
        .context("bench accuracy");
        assert_eq!(
            error_chain(&e),
            "bench accuracy: out/results.csv: no such file"
        );
    }
}
