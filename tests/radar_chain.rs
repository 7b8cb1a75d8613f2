//! The radar chain through its real transports: the IWR1443 CLI simulator on a PTY opened with
//! serialport, and the DCA1000 simulator on loopback UDP received with the socket2 transport.
//! Each test prints the figure it checks.

use std::path::Path;
use std::sync::{Arc, OnceLock};

use mmnormd::dca1000::board::BoardError;
use mmnormd::dca1000::sim::AdcStream;
use mmnormd::dca1000::udp::UdpBoard;
use mmnormd::lab::LabConfig;
use mmnormd::lab::raw::{RawCapture, RawError, RawReport, capture_raw};
use mmnormd::lab::simchain::{SimChain, load_source};
use mmnormd::radar::cli::{Accepted, CommandOutcome};
use mmnormd::radar::control::open_serial;
use mmnormd::radar::sim::{CliFaults, CliSimStats};
use mmnormd::radar::{CliRadar, RadarControl, RadarProfile};

fn lab() -> LabConfig {
    let mut lab = LabConfig::load(Path::new("config/sim.toml")).unwrap();
    lab.dca1000.host_config_port = 0;
    lab.dca1000.host_data_port = 0;
    lab.dca1000.config_port = 0;
    lab.sim.board_data_port = 0;
    // Scheduling on a loaded 2-core CI machine must not pass for a silent radar; the silent-radar
    // test sets the shipped 40 ms back.
    lab.dca1000.first_frame_margin_ms = 1000;
    lab
}

fn profile(lab: &LabConfig) -> RadarProfile {
    RadarProfile::from_cfg_file(&lab.radar.profile).unwrap()
}

/// The sphere-row scene of config/sim.toml, simulated once for all tests.
fn row_source() -> Arc<AdcStream> {
    static SOURCE: OnceLock<Arc<AdcStream>> = OnceLock::new();
    SOURCE
        .get_or_init(|| {
            let lab = lab();
            Arc::new(load_source(&lab, &profile(&lab), true).unwrap().0)
        })
        .clone()
}

struct Bench {
    lab: LabConfig,
    board: UdpBoard,
    chain: SimChain,
    _dir: tempfile::TempDir,
}

/// Opens the host side first (ephemeral ports), then starts the simulators pointing at it.
fn bench(mut lab: LabConfig) -> Bench {
    let dir = tempfile::tempdir().unwrap();
    let mut board = UdpBoard::open(&lab.dca1000).unwrap();
    lab.dca1000.host_data_port = board.data_addr().port();
    let link = dir.path().join("radar-cli");
    let chain = SimChain::start(&lab, row_source(), Some(&link)).unwrap();
    board.set_board_config_addr(chain.board.config_addr());
    lab.radar.serial_port = link;
    Bench {
        lab,
        board,
        chain,
        _dir: dir,
    }
}

fn capture(b: &mut Bench, frames: u64, out: &Path) -> Result<RawReport, RawError> {
    let profile = profile(&b.lab);
    let port = open_serial(&b.lab.radar).unwrap();
    let mut radar = CliRadar::new(port, b.lab.radar.session_config());
    let job = RawCapture {
        lab: &b.lab,
        profile: &profile,
        frames,
        out_dir: out,
        quiet: true,
    };
    capture_raw(
        &mut b.board,
        Some(&mut radar as &mut dyn RadarControl),
        &job,
    )
}

#[test]
fn a_raster_row_is_configured_captured_and_recovered_bit_exactly() {
    let mut b = bench(lab());
    let source = row_source();
    let frames = source.frames();
    let out = tempfile::tempdir().unwrap();
    let report = capture(&mut b, frames, out.path()).unwrap();
    let adc = std::fs::read(out.path().join("adc_data.bin")).unwrap();
    let s = &report.capture.stream;
    println!(
        "raster row: {} frames, {} packets, {} bytes in {:.2} s; lost {}, flagged {}; first packet {:.1} ms after sensorStart; {} radar commands",
        s.frames,
        s.packets,
        s.bytes,
        report.capture.duration_s,
        s.lost,
        report.capture.flagged_frame_indices.len(),
        report.capture.first_packet_ms.unwrap_or(f64::NAN),
        report.radar_commands.len()
    );
    assert_eq!(
        adc, source.bytes,
        "adc_data.bin is the simulated stream, bit-exact"
    );
    assert_eq!((s.lost, s.duplicates, s.reordered), (0, 0, 0));
    assert!(report.capture.flagged_frame_indices.is_empty());
    assert!(report.radar_commands.iter().all(|c| c.attempts == 1));
    // Decoding recovers the quantised simulated samples of every RX.
    let layout = b.lab.dca1000.layout(&profile(&b.lab)).unwrap();
    let first = layout.decode(&adc[..source.frame_bytes]).unwrap();
    assert_eq!(first.len(), 4 * layout.samples_per_chirp);
    assert!(first.iter().any(|c| c.re != 0 || c.im != 0));
    // `capture decode` turns the file into the same samples, shaped frames × chirps × RX ×
    // samples, and draws the range profile.
    let decoded_dir = out.path().join("decoded");
    let run = std::process::Command::new(env!("CARGO_BIN_EXE_mmnormd"))
        .args(["-q", "capture", "decode"])
        .arg(out.path().join("adc_data.bin"))
        .args(["--config", "config/sim.toml", "--out"])
        .arg(&decoded_dir)
        .output()
        .unwrap();
    println!(
        "capture decode: {}",
        String::from_utf8_lossy(&run.stdout).trim()
    );
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    let npy = std::fs::read(decoded_dir.join("samples.npy")).unwrap();
    let array = mmnormd::capture::npy::parse(&npy).unwrap();
    assert_eq!(array.descr, "<c8");
    assert_eq!(
        array.shape,
        vec![
            frames as usize,
            layout.chirps_per_frame,
            4,
            layout.samples_per_chirp
        ]
    );
    let re = f32::from_le_bytes(array.data[8..12].try_into().unwrap());
    assert_eq!(re, f32::from(first[1].re));
    assert!(decoded_dir.join("range_profile.png").exists());
    let json: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.path().join("report.json")).unwrap()).unwrap();
    for key in [
        "packets",
        "bytes",
        "lost",
        "duplicates",
        "reordered",
        "late",
        "flagged_frames",
        "kernel_drops",
    ] {
        assert!(json.get(key).is_some(), "report.json lacks {key}");
    }
    let (board, cli) = b.chain.stats();
    assert_eq!(board.recordings, 1);
    assert_eq!(cli.sensor_starts, 1);
}

/// Configures and starts the simulated radar with `faults` over its PTY: the outcomes, the
/// simulator's counters and the seconds it took.
fn configure_and_start(faults: CliFaults) -> (Vec<CommandOutcome>, CliSimStats, f64) {
    let mut config = lab();
    config.sim.cli_faults = faults;
    let b = bench(config);
    let profile = profile(&b.lab);
    let port = open_serial(&b.lab.radar).unwrap();
    let mut radar = CliRadar::new(port, b.lab.radar.session_config());
    let started = std::time::Instant::now();
    let outcomes = radar.configure(&profile).unwrap();
    radar.start().unwrap();
    let seconds = started.elapsed().as_secs_f64();
    (outcomes, b.chain.radar.stats(), seconds)
}

fn configure_commands_len() -> usize {
    mmnormd::radar::control::configure_commands(&profile(&lab())).len()
}

#[test]
fn serial_garbage_garbled_echoes_and_dropped_replies_are_survived() {
    let (outcomes, cli, seconds) = configure_and_start(CliFaults {
        seed: 7,
        powerup_garbage_bytes: 64,
        garble_echo_probability: 0.2,
        drop_reply_probability: 0.2,
        ..CliFaults::default()
    });
    let retries: u32 = outcomes.iter().map(|o| o.attempts - 1).sum();
    let garbled: u32 = outcomes.iter().map(|o| o.garbled_echoes).sum();
    println!(
        "CLI faults: 64 B power-up garbage, {} dropped replies, {} garbled echoes (client saw {}); {} commands done with {} retries (max {} attempts) in {:.1} s",
        cli.dropped_replies,
        cli.garbled_echoes,
        garbled,
        outcomes.len(),
        retries,
        outcomes.iter().map(|o| o.attempts).max().unwrap_or(0),
        seconds
    );
    assert!(
        cli.dropped_replies >= 1 && cli.garbled_echoes >= 1,
        "the faults fired"
    );
    assert_eq!(outcomes.len(), configure_commands_len());
    assert!(
        outcomes
            .iter()
            .all(|o| o.attempts <= 4 && o.accepted == Accepted::Done)
    );
    assert_eq!(cli.sensor_starts, 1);
}

#[test]
fn a_link_that_stalls_for_4_5_s_is_waited_out() {
    let (outcomes, cli, seconds) = configure_and_start(CliFaults {
        seed: 1,
        stall_probability: 0.1,
        stall_ms: 4500,
        ..CliFaults::default()
    });
    println!(
        "CLI link stalls: {} of 4.5 s over {} lines; {} commands done, {} retries, in {:.1} s",
        cli.stalls,
        cli.lines,
        outcomes.len(),
        outcomes.iter().map(|o| o.attempts - 1).sum::<u32>(),
        seconds
    );
    assert!(cli.stalls >= 1, "the fault fired");
    assert_eq!(outcomes.len(), configure_commands_len());
    assert!(outcomes.iter().all(|o| o.accepted == Accepted::Done));
    assert_eq!(cli.sensor_starts, 1);
}

#[test]
fn a_radar_silent_after_sensor_start_is_detected_within_50_ms() {
    let mut config = lab();
    config.sim.cli_faults.silent_after_start = true;
    config.dca1000.first_frame_margin_ms =
        mmnormd::dca1000::udp::Dca1000Config::default().first_frame_margin_ms;
    let mut b = bench(config);
    let out = tempfile::tempdir().unwrap();
    let err = capture(&mut b, 100, out.path()).unwrap_err();
    let RawError::Board(BoardError::RadarSilent {
        expected_ms,
        waited_ms,
    }) = err
    else {
        panic!("expected RadarSilent, got {err}");
    };
    println!(
        "silent radar: first packet due {expected_ms} ms after sensorStart, reported after {waited_ms} ms ({} ms late)",
        waited_ms - expected_ms
    );
    assert!(waited_ms - expected_ms < 50);
    let report: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.path().join("report.json")).unwrap()).unwrap();
    assert!(report["error"].as_str().unwrap().contains("silent"));
    assert!(!out.path().join("adc_data.bin").exists());
}

#[test]
fn udp_loss_on_the_wire_is_counted_and_flagged() {
    let mut config = lab();
    config.sim.dca1000_faults.seed = 9;
    config.sim.dca1000_faults.loss_probability = 0.01;
    let mut b = bench(config);
    let source = row_source();
    let out = tempfile::tempdir().unwrap();
    let report = capture(&mut b, source.frames(), out.path()).unwrap();
    let injected = b.chain.board.stats().injected;
    let r = &report.capture;
    let drops = r.receive.kernel_drops.unwrap_or(0) + r.receive.queue_drops;
    println!(
        "1 % loss over UDP: injected {}, reported lost {}, kernel + queue drops {}; {} frames flagged",
        injected.dropped,
        r.stream.lost,
        drops,
        r.flagged_frame_indices.len()
    );
    assert!(injected.dropped > 0);
    assert_eq!(r.stream.lost, injected.dropped + drops);
    let adc = std::fs::read(out.path().join("adc_data.bin")).unwrap();
    for k in 0..source.frames() as usize {
        let fb = source.frame_bytes;
        let range = k * fb..(k + 1) * fb;
        if !r.flagged_frame_indices.contains(&(k as u64)) {
            assert_eq!(adc[range.clone()], source.bytes[range], "frame {k}");
        }
    }
}
