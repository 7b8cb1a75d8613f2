use super::*;
use crate::signal::Rng;

const T: f64 = 0.003;
const FRAME_BYTES: usize = 8192;
const SPEED_M_PER_S: f64 = 0.1;
/// Host time of the first frame's start.
const T0_HOST_S: f64 = 5.0;
/// The RTDE latency floor: no stream shows it; `sync_offset_s` calibrates it.
const RTDE_FLOOR_S: f64 = 0.0002;
/// Controller clock = host clock − 100 s, running 40 ppm slow.
fn controller_of_host(host_s: f64) -> f64 {
    (host_s - 100.0) * (1.0 - 40e-6)
}

fn timing() -> FrameTiming {
    FrameTiming {
        frame_period_s: T,
        frame_bytes: FRAME_BYTES,
        centre_s: 0.000_04,
        acquired_s: 0.000_07,
        wavelength_m: 0.003_883,
    }
}

/// TCP x along the row (true host time): from −0.15 m at t0 at constant speed.
fn tcp_pose_at(host_s: f64) -> [f64; 6] {
    let x = -0.15 + SPEED_M_PER_S * (host_s - T0_HOST_S);
    [x, 0.2, 0.4, std::f64::consts::PI, 0.0, 0.0]
}

struct Row {
    complete: Vec<bool>,
    packets: Vec<PacketArrival>,
    poses: Vec<PoseSample>,
}

/// `frames` frames; packets arrive 0.3 ms after their frame is acquired plus exponential
/// jitter (mean `jitter_s`); RTDE samples every 2 ms (controller clock) with the same jitter.
fn row(frames: usize, jitter_s: f64, radar_ppm: f64, seed: u64) -> Row {
    let mut rng = Rng::for_stream(seed, 0, 0);
    let mut exp = |mean: f64| -mean * (1.0 - rng.uniform()).ln();
    let total = frames * FRAME_BYTES;
    let mut packets = Vec::new();
    let mut offset = 0usize;
    while offset + 1456 <= total {
        let frame = (offset + 1455) / FRAME_BYTES;
        let radar_s = frame as f64 * T + timing().acquired_s;
        packets.push(PacketArrival {
            byte_offset: offset as u64,
            payload_len: 1456,
            host_s: T0_HOST_S + radar_s * (1.0 + radar_ppm * 1e-6) + 0.0003 + exp(jitter_s),
        });
        offset += 1456;
    }
    let mut poses = Vec::new();
    let start_c = controller_of_host(T0_HOST_S - 0.2);
    let end_c = controller_of_host(T0_HOST_S + frames as f64 * T + 0.2);
    let mut c = (start_c / 0.002).ceil() * 0.002;
    while c < end_c {
        let host = 100.0 + c / (1.0 - 40e-6);
        poses.push(PoseSample {
            host_s: host + RTDE_FLOOR_S + exp(jitter_s),
            controller_s: c,
            segment: 0,
            tcp_pose: tcp_pose_at(host),
        });
        c += 0.002;
    }
    Row {
        complete: vec![true; frames],
        packets,
        poses,
    }
}

fn config() -> AlignConfig {
    AlignConfig {
        tcp_from_radar: [0.01, 0.02, 0.05, 0.0, 0.0, 0.3],
        pipeline_latency_s: 0.0003,
        sync_offset_s: RTDE_FLOOR_S,
        ..AlignConfig::default()
    }
}

fn input(r: &Row) -> RowInput<'_> {
    RowInput {
        frame_complete: &r.complete,
        packets: &r.packets,
        poses: &r.poses,
        usable_x_m: (0.1, -0.1),
    }
}

/// Largest distance between each kept TX and where it truly was at its frame's chirp.
fn worst_tx_error_m(config: &AlignConfig, aligned: &RowAlignment, radar_ppm: f64) -> f64 {
    let tcp_from_radar = pose::isometry_of_pose(&config.tcp_from_radar);
    aligned
        .frames
        .iter()
        .map(|f| {
            let true_host =
                T0_HOST_S + (f.frame as f64 * T + timing().centre_s) * (1.0 + radar_ppm * 1e-6);
            let base_from_radar = pose::isometry_of_pose(&tcp_pose_at(true_host)) * tcp_from_radar;
            distance_m(
                &pose::apply(&base_from_radar, &config.tx_in_radar_m),
                &f.tx_in_base_m,
            )
        })
        .fold(0.0, f64::max)
}

#[test]
fn kept_frames_sit_where_the_antenna_was_at_their_chirp() {
    let r = row(4000, 0.0005, 30.0, 1);
    let config = config();
    let aligned = align_row(&config, &timing(), &input(&r)).unwrap();
    let error_m = worst_tx_error_m(&config, &aligned, 30.0);
    println!(
        "{} of 4000 frames kept, worst TX error {:.1} µm (0.5 ms mean jitter, radar 30 ppm, controller −40 ppm); dropped {:?}",
        aligned.frames.len(),
        error_m * 1e6,
        aligned.dropped
    );
    // 10 µm = 0.1 ms at 0.1 m/s.
    assert!(error_m < 10e-6, "{error_m}");
    assert!(
        (aligned.radar_fit.drift - 30e-6).abs() < 5e-6,
        "{:?}",
        aligned.radar_fit
    );
}

#[test]
fn an_uncalibrated_latency_floor_shifts_the_row_by_speed_times_floor() {
    let r = row(4000, 0.0, 0.0, 5);
    let config = AlignConfig {
        sync_offset_s: 0.0,
        ..config()
    };
    let aligned = align_row(&config, &timing(), &input(&r)).unwrap();
    let error_m = worst_tx_error_m(&config, &aligned, 0.0);
    assert!(
        (error_m - SPEED_M_PER_S * RTDE_FLOOR_S).abs() < 1e-6,
        "{error_m}"
    );
}

#[test]
fn kept_frames_are_spaced_by_at_least_three_sixteenths_of_a_wavelength() {
    let r = row(4000, 0.0, 0.0, 2);
    let aligned = align_row(&config(), &timing(), &input(&r)).unwrap();
    let min_m = 3.0 / 16.0 * timing().wavelength_m;
    let gaps: Vec<f64> = aligned
        .frames
        .windows(2)
        .map(|w| distance_m(&w[0].tx_in_base_m, &w[1].tx_in_base_m))
        .collect();
    assert!(
        gaps.iter()
            .all(|g| *g >= min_m && *g < min_m + SPEED_M_PER_S * T + 1e-9)
    );
    // 0.3 mm per frame: every third frame is kept over the 0.2 m usable stretch.
    let usable_frames = (0.2 / (SPEED_M_PER_S * T)) as u64;
    assert_eq!(
        aligned.dropped.too_close + aligned.frames.len() as u64,
        usable_frames + 1
    );
    assert!(aligned.dropped.outside_usable > 0);
}

#[test]
fn flagged_frames_and_rtde_gaps_are_dropped_and_counted() {
    let mut r = row(4000, 0.0, 0.0, 3);
    for k in [1500, 1501, 2600] {
        r.complete[k] = false;
    }
    // A 50 ms hole in the RTDE stream in the middle of the usable stretch.
    let hole = (T0_HOST_S + 6.0, T0_HOST_S + 6.05);
    r.poses.retain(|s| !(hole.0..hole.1).contains(&s.host_s));
    let config = AlignConfig {
        min_spacing_wavelengths: 0.0,
        ..config()
    };
    let aligned = align_row(&config, &timing(), &input(&r)).unwrap();
    assert_eq!(aligned.dropped.flagged, 3);
    // 16 or 17 frames fall into the hole, depending on where the samples sit.
    assert!(
        (15..=18).contains(&aligned.dropped.no_pose),
        "{:?}",
        aligned.dropped
    );
    assert!(
        aligned
            .frames
            .iter()
            .all(|f| ![1500, 1501, 2600].contains(&f.frame))
    );
}

#[test]
fn a_row_too_short_to_fit_is_refused_with_the_count() {
    let r = row(20, 0.0, 0.0, 4);
    let err = align_row(&config(), &timing(), &input(&r)).unwrap_err();
    assert!(
        matches!(err, AlignError::RadarFit { packets: 112, .. }),
        "{err}"
    );
}

#[test]
fn config_errors_name_the_field_and_value() {
    let bad = AlignConfig {
        max_pose_gap_s: f64::NAN,
        ..AlignConfig::default()
    };
    assert!(
        bad.validate()
            .unwrap_err()
            .contains("align.max_pose_gap_s = NaN")
    );
    let bad = AlignConfig {
        pipeline_latency_s: -0.001,
        ..AlignConfig::default()
    };
    assert!(
        bad.validate()
            .unwrap_err()
            .contains("align.pipeline_latency_s = -0.001")
    );
    assert!(AlignConfig::default().validate().is_ok());
}
