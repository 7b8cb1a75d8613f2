//! `mmnormd robot status`, `mmnormd robot log` and `mmnormd sim robot`.

use std::io::Write as _;
use std::net::{SocketAddr, ToSocketAddrs as _};
use std::path::PathBuf;
use std::time::{Duration, Instant};

use anyhow::{Context as _, Result, bail};
use mmnormd::ur::dashboard::DashboardClient;
use mmnormd::ur::rtde::client::DEFAULT_OUTPUTS;
use mmnormd::ur::rtde::{RtdeClient, RtdeConfig, RtdeEvent, RtdeType, Value, fields};
use mmnormd::ur::sim::{Faults, UrSim, UrSimConfig};

fn resolve(host: &str, port: u16) -> Result<SocketAddr> {
    (host, port)
        .to_socket_addrs()
        .with_context(|| format!("resolving {host}:{port}"))?
        .next()
        .with_context(|| format!("{host}:{port} resolves to no address"))
}

#[derive(clap::Args)]
pub struct StatusArgs {
    /// The robot's address (a host name or an IP address).
    #[arg(long)]
    host: String,
    /// The Dashboard server's TCP port.
    #[arg(long, default_value_t = 29999)]
    dashboard_port: u16,
    /// The RTDE server's TCP port.
    #[arg(long, default_value_t = 30004)]
    rtde_port: u16,
}

pub fn status(a: StatusArgs) -> Result<()> {
    let timeout = Duration::from_secs(3);
    let mut dashboard = DashboardClient::connect(resolve(&a.host, a.dashboard_port)?, timeout)?;
    let mode = dashboard.robot_mode()?;
    let safety = dashboard.safety_status()?;
    let remote = match dashboard.is_in_remote_control() {
        Ok(r) => r.to_string(),
        Err(e) => format!("unknown ({e})"),
    };
    let mut config = RtdeConfig::e_series(resolve(&a.host, a.rtde_port)?);
    config.frequency_hz = 10.0;
    config.outputs = vec!["timestamp".into(), "actual_TCP_pose".into()];
    config.inputs.clear();
    config.stall_periods = 20.0;
    let rtde = RtdeClient::spawn(config);
    let deadline = Instant::now() + timeout;
    let mut pose = None;
    while pose.is_none() && Instant::now() < deadline {
        match rtde
            .events()
            .recv_timeout(deadline.saturating_duration_since(Instant::now()))
        {
            Ok(RtdeEvent::Sample(s)) => pose = s.values.get(1).copied(),
            Ok(RtdeEvent::Failed(e)) => bail!(e),
            Ok(_) => {}
            Err(_) => break,
        }
    }
    println!("{}", dashboard.greeting);
    println!("robot mode:     {}", mode.name());
    println!("safety status:  {}", safety.name());
    println!("remote control: {remote}");
    match pose {
        Some(Value::Vector6d(p)) => println!(
            "TCP pose:       x {:.4} y {:.4} z {:.4} m, rotation vector {:.4} {:.4} {:.4} rad",
            p[0], p[1], p[2], p[3], p[4], p[5]
        ),
        _ => println!(
            "TCP pose:       no RTDE package within {} s",
            timeout.as_secs()
        ),
    }
    Ok(())
}

#[derive(clap::Args)]
pub struct LogArgs {
    /// The robot's address (a host name or an IP address).
    #[arg(long)]
    host: String,
    /// The RTDE server's TCP port.
    #[arg(long, default_value_t = 30004)]
    rtde_port: u16,
    /// Output rate in Hz: at most 500 on e-Series, 125 on CB3.
    #[arg(long, default_value_t = 500.0)]
    frequency: f64,
    /// How long to record, seconds.
    #[arg(long)]
    seconds: f64,
    /// The CSV file.
    #[arg(long)]
    out: PathBuf,
}

pub fn log(a: LogArgs, quiet: bool) -> Result<()> {
    anyhow::ensure!(
        a.frequency > 0.0 && a.frequency <= 500.0,
        "--frequency {} must lie in (0, 500]",
        a.frequency
    );
    anyhow::ensure!(a.seconds > 0.0, "--seconds {} must be positive", a.seconds);
    let mut config = RtdeConfig::e_series(resolve(&a.host, a.rtde_port)?);
    config.frequency_hz = a.frequency;
    config.inputs.clear();
    let names: Vec<String> = DEFAULT_OUTPUTS.iter().map(|s| s.to_string()).collect();
    let rtde = RtdeClient::spawn(config);
    let file =
        std::fs::File::create(&a.out).with_context(|| format!("creating {}", a.out.display()))?;
    let mut csv = std::io::BufWriter::new(file);
    // The header comes from the controller's field table, so even a log that received nothing
    // says what it would have held.
    let mut cols = vec!["host_time_s".to_string(), "segment".to_string()];
    for name in &names {
        let width = fields::output_type(name).map_or(1, RtdeType::scalars);
        if width == 1 {
            cols.push(name.clone());
        } else {
            cols.extend((0..width).map(|i| format!("{name}_{i}")));
        }
    }
    writeln!(csv, "{}", cols.join(","))
        .and_then(|()| csv.flush())
        .with_context(|| format!("writing {}", a.out.display()))?;
    let (mut packets, mut gaps, mut missing) = (0u64, 0u64, 0u64);
    let mut last: Option<(u64, f64)> = None;
    let period = 1.0 / a.frequency;
    let progress = mmnormd::progress::Progress::new("rtde log", a.seconds.ceil() as u64, quiet);
    let start = Instant::now();
    let mut shown = 0;
    while start.elapsed().as_secs_f64() < a.seconds {
        let event = match rtde.events().recv_timeout(Duration::from_millis(100)) {
            Ok(e) => e,
            Err(_) => continue,
        };
        match event {
            RtdeEvent::Sample(s) => {
                let mut row = vec![format!("{:.6}", s.host_s), s.segment.to_string()];
                row.extend(
                    s.values
                        .iter()
                        .flat_map(|v| v.scalars())
                        .map(|x| x.to_string()),
                );
                writeln!(csv, "{}", row.join(","))?;
                if let (Some((segment, t0)), Some(t1)) = (last, s.controller_s)
                    && segment == s.segment
                {
                    missing += (((t1 - t0) / period).round() as u64).saturating_sub(1);
                }
                last = s.controller_s.map(|t| (s.segment, t));
                packets += 1;
            }
            RtdeEvent::Gap { reason, .. } => {
                gaps += 1;
                tracing::warn!("RTDE gap: {reason}");
            }
            RtdeEvent::Failed(e) => {
                csv.flush().ok();
                bail!(e)
            }
            RtdeEvent::Connected {
                protocol, version, ..
            } => tracing::info!(
                "RTDE connected: protocol {protocol}, controller {}.{}.{}.{}",
                version.0,
                version.1,
                version.2,
                version.3
            ),
            RtdeEvent::Text { level, message } => {
                tracing::info!("controller message (level {level}): {message}")
            }
        }
        let whole = start.elapsed().as_secs();
        if whole > shown {
            progress.inc(whole - shown);
            shown = whole;
        }
    }
    progress.finish();
    csv.flush()
        .with_context(|| format!("writing {}", a.out.display()))?;
    if packets == 0 {
        bail!(
            "no RTDE package from {}:{} in {} s ({gaps} sessions ended without data); {} holds the header only",
            a.host,
            a.rtde_port,
            a.seconds,
            a.out.display()
        );
    }
    println!(
        "{packets} packages in {:.1} s ({:.1} Hz), {gaps} gaps, {missing} missing by controller timestamp; wrote {}",
        a.seconds,
        packets as f64 / a.seconds,
        a.out.display()
    );
    Ok(())
}

#[derive(clap::Args)]
pub struct SimRobotArgs {
    /// The loopback address every port binds (127.0.0.1 … 127.255.255.254): a second
    /// simulator, or one beside a client with fixed ports such as ur_rtde, takes its own.
    #[arg(long, default_value = "127.0.0.1")]
    address: std::net::Ipv4Addr,
    /// The RTDE server's TCP port.
    #[arg(long, default_value_t = 30004)]
    rtde_port: u16,
    /// The Dashboard server's TCP port.
    #[arg(long, default_value_t = 29999)]
    dashboard_port: u16,
    /// The URScript (secondary interface) TCP port.
    #[arg(long, default_value_t = 30002)]
    script_port: u16,
    /// Start in Local mode: Dashboard actions are refused and scripts ignored.
    #[arg(long)]
    local: bool,
    /// Controller clock offset against this machine's clock, seconds.
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true)]
    clock_offset_s: f64,
    /// Controller clock drift against this machine's clock, parts per million.
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true)]
    clock_drift_ppm: f64,
    /// Up to this much lateness on each RTDE package, milliseconds.
    #[arg(long, default_value_t = 0.0)]
    jitter_ms: f64,
    /// A protective stop SECONDS into move number MOVE (0-based): `MOVE:SECONDS`.
    #[arg(long)]
    protective_stop: Option<String>,
    /// Every RTDE input package lost from SECONDS into move number MOVE until it ends, so a
    /// program's watchdog trips: `MOVE:SECONDS`.
    #[arg(long)]
    input_loss: Option<String>,
    /// Input registers 0–23 answer IN_USE, as with a fieldbus enabled.
    #[arg(long)]
    fieldbus: bool,
    /// Seed of the RTDE jitter's random draws (the same seed, the same jitter).
    #[arg(long, default_value_t = 0)]
    seed: u64,
}

/// `MOVE:SECONDS` of the fault flag `flag`.
fn move_and_seconds(flag: &str, text: Option<&str>) -> Result<Option<(u64, f64)>> {
    let Some(text) = text else {
        return Ok(None);
    };
    let (m, s) = text
        .split_once(':')
        .with_context(|| format!("{flag} {text}: expected MOVE:SECONDS"))?;
    Ok(Some((
        m.parse().with_context(|| format!("{flag} move `{m}`"))?,
        s.parse().with_context(|| format!("{flag} seconds `{s}`"))?,
    )))
}

pub fn sim_robot(a: SimRobotArgs) -> Result<()> {
    let protective_stop = move_and_seconds("--protective-stop", a.protective_stop.as_deref())?;
    let input_loss = move_and_seconds("--input-loss", a.input_loss.as_deref())?;
    let at = |port| SocketAddr::from((a.address, port));
    let config = UrSimConfig {
        rtde: at(a.rtde_port),
        dashboard: at(a.dashboard_port),
        script: at(a.script_port),
        remote_control: !a.local,
        clock_offset_s: a.clock_offset_s,
        clock_drift_ppm: a.clock_drift_ppm,
        protective_stop,
        input_loss,
        ..UrSimConfig::default()
    };
    let faults = Faults {
        seed: a.seed,
        jitter_s: a.jitter_ms * 1e-3,
        fieldbus_holds_registers: a.fieldbus,
        ..Faults::default()
    };
    let sim = UrSim::spawn(&config, faults)?;
    println!(
        "UR5e simulator: RTDE {}, Dashboard {}, script {}; Ctrl-C stops",
        sim.rtde_addr(),
        sim.dashboard_addr(),
        sim.script_addr()
    );
    super::capture::wait_for_stop_signal()?;
    let arm = sim.arm();
    println!(
        "stopped: {} moves, watchdog trips {}, safety {}",
        arm.moves_started,
        arm.watchdog_trips,
        arm.safety.name()
    );
    Ok(())
}
