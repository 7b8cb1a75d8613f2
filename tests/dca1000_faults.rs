//! Fault tests of the DCA1000 data path with the seeded injector (lost, reordered, duplicated and corrupted packets): the
//! simulator's sans-IO core streams through the injector into the reassembler on a simulated
//! clock, so the figures are exact. Each test prints the figure it checks.

use std::sync::Arc;
use std::time::{Duration, Instant};

use mmnormd::dca1000::command::{Command, FpgaConfig};
use mmnormd::dca1000::fault::{FaultConfig, InjectedFaults};
use mmnormd::dca1000::packet::RAW_PAYLOAD_LEN;
use mmnormd::dca1000::reassembler::{Frame, Reassembler, StreamStats};
use mmnormd::dca1000::sim::{AdcStream, BoardCore, CoreConfig, Output, StreamPlan};

const FRAME_BYTES: usize = 8192;
const FRAMES: usize = 4000;

fn source() -> Arc<AdcStream> {
    let mut rng = mmnormd::signal::Rng::new(0x2545_F491_4F6C_DD1D);
    let bytes = (0..FRAMES * FRAME_BYTES)
        .map(|_| (rng.next_u64() >> 32) as u8)
        .collect();
    Arc::new(AdcStream {
        frame_bytes: FRAME_BYTES,
        bytes,
    })
}

/// Streams the whole capture through the injector into a reassembler.
fn run(faults: FaultConfig, src: &Arc<AdcStream>) -> (Vec<Frame>, StreamStats, InjectedFaults) {
    let mut core = BoardCore::new(
        CoreConfig {
            faults,
            ..CoreConfig::default()
        },
        src.clone(),
    );
    let t0 = Instant::now();
    core.handle_command(&Command::ConfigFpgaGen(FpgaConfig::default()).encode(), t0);
    core.handle_command(&Command::RecordStart.encode(), t0);
    core.sensor_start(
        StreamPlan {
            frames: FRAMES as u64,
            frame_period_s: 0.003,
            acquired_s: 0.000_07,
        },
        t0,
    );
    let mut r = Reassembler::new(FRAME_BYTES, Some(FRAMES as u64));
    let mut frames = Vec::new();
    let mut now = t0;
    while core.next_deadline().is_some() {
        now += Duration::from_millis(3);
        core.poll(now);
        while let Some(out) = core.pop_output() {
            if let Output::Data(d) = out {
                r.push(&d).unwrap();
            }
        }
        frames.extend(std::iter::from_fn(|| r.pop_frame()));
    }
    let stats = r.finish();
    frames.extend(std::iter::from_fn(|| r.pop_frame()));
    (frames, stats, core.stats().injected)
}

/// Frames touched by the dropped packets.
fn frames_hit(dropped: &[u32]) -> Vec<u64> {
    let mut hit: Vec<u64> = dropped
        .iter()
        .flat_map(|&seq| {
            let start = (seq as usize - 1) * RAW_PAYLOAD_LEN;
            let end = (start + RAW_PAYLOAD_LEN).min(FRAMES * FRAME_BYTES);
            (start / FRAME_BYTES) as u64..=((end - 1) / FRAME_BYTES) as u64
        })
        .collect();
    hit.sort_unstable();
    hit.dedup();
    hit
}

fn check_frames(frames: &[Frame], src: &AdcStream) -> (usize, usize) {
    assert_eq!(frames.len(), FRAMES);
    let (mut exact, mut flagged) = (0, 0);
    for (k, f) in frames.iter().enumerate() {
        assert_eq!(f.index, k as u64, "frames come out in order");
        let truth = &src.bytes[k * FRAME_BYTES..(k + 1) * FRAME_BYTES];
        if f.is_complete() {
            assert_eq!(f.data, truth, "unflagged frame {k} differs from the source");
            exact += 1;
        } else {
            flagged += 1;
            for (a, b) in &f.gaps {
                assert!(f.data[*a..*b].iter().all(|&x| x == 0));
            }
            // Outside its gaps a flagged frame still holds the source's bytes.
            let mut cursor = 0;
            for &(a, b) in &f.gaps {
                assert_eq!(f.data[cursor..a], truth[cursor..a]);
                cursor = b;
            }
            assert_eq!(f.data[cursor..], truth[cursor..]);
        }
    }
    (exact, flagged)
}

#[test]
fn lost_packets_are_counted_exactly_and_only_their_frames_flagged() {
    let src = source();
    for (p, seed) in [(0.001, 11), (0.01, 12), (0.05, 13)] {
        let faults = FaultConfig {
            seed,
            loss_probability: p,
            ..FaultConfig::default()
        };
        let (frames, stats, injected) = run(faults, &src);
        let (exact, flagged) = check_frames(&frames, &src);
        let hit = frames_hit(&injected.dropped_sequences);
        let flagged_idx: Vec<u64> = frames
            .iter()
            .filter(|f| !f.is_complete())
            .map(|f| f.index)
            .collect();
        println!(
            "loss {:.1} %: injected {} lost packets, reported {}; {} frames flagged (expected {}), {} bit-exact of {}",
            p * 100.0,
            injected.dropped,
            stats.lost,
            flagged,
            hit.len(),
            exact,
            FRAMES
        );
        assert!(injected.dropped > 0);
        assert_eq!(stats.lost, injected.dropped);
        assert_eq!(flagged_idx, hit);
        assert_eq!(stats.flagged_frames as usize, flagged);
    }
}

#[test]
fn reordering_within_four_and_duplicates_keep_frames_bit_exact() {
    let src = source();
    let faults = FaultConfig {
        seed: 21,
        reorder_probability: 0.02,
        reorder_depth: 4,
        duplicate_probability: 0.01,
        ..FaultConfig::default()
    };
    let (frames, stats, injected) = run(faults, &src);
    let (exact, flagged) = check_frames(&frames, &src);
    println!(
        "reorder ≤ 4 + duplicates: injected {} reordered / {} duplicated; reported {} / {}; {} of {} frames bit-exact, {} flagged, {} lost",
        injected.reordered,
        injected.duplicated,
        stats.reordered,
        stats.duplicates,
        exact,
        FRAMES,
        flagged,
        stats.lost
    );
    assert!(injected.reordered > 100 && injected.duplicated > 100);
    assert_eq!((exact, flagged, stats.lost), (FRAMES, 0, 0));
    assert_eq!(stats.reordered, injected.reordered);
    assert_eq!(stats.duplicates, injected.duplicated);
}

#[test]
fn a_burst_of_fifty_lost_packets_is_realigned_by_offset() {
    let src = source();
    let faults = FaultConfig {
        seed: 31,
        burst_start: Some(10_000),
        burst_len: 50,
        ..FaultConfig::default()
    };
    let (frames, stats, injected) = run(faults, &src);
    let (exact, flagged) = check_frames(&frames, &src);
    let hit = frames_hit(&injected.dropped_sequences);
    println!(
        "burst of 50: reported {} lost; {} frames flagged ({}..={}), {} bit-exact, 0 misassigned (every unflagged frame equals its source)",
        stats.lost,
        flagged,
        hit.first().copied().unwrap_or(0),
        hit.last().copied().unwrap_or(0),
        exact
    );
    assert_eq!(stats.lost, 50);
    assert_eq!(flagged, hit.len());
    assert_eq!(exact + flagged, FRAMES);
}
