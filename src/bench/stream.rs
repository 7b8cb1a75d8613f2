//! `mmnormd bench stream`: the DCA1000 receive path's throughput on one core, against the real
//! stream rate (8192 B every 3 ms = 2.73 MB/s).
//!
//! A recording of `frames` frames is cut into raw-mode datagrams, optionally through the seeded
//! fault injector (reordering and duplicates, no loss), then timed `repeats` times:
//! - reassembly: every datagram through [`Reassembler::push`] and every frame out;
//! - decoding: every frame through [`FrameLayout::decode`] into per-RX complex samples.
//!
//! Figures are medians over the repeats, in MB/s of stream bytes (10⁶ B/s).

use std::time::Instant;

use crate::dca1000::fault::{FaultConfig, FaultInjector};
use crate::dca1000::packet::packetize;
use crate::dca1000::reassembler::Reassembler;
use crate::dca1000::samples::{FrameLayout, IqOrder, Lanes};
use crate::signal::Rng;

/// The real stream rate of the mmNorm profile, bytes per second.
pub const REAL_RATE_BYTES_PER_S: f64 = 8192.0 / 0.003;

/// One benchmark's figures.
#[derive(Debug, Clone, serde::Serialize)]
pub struct StreamBench {
    pub frames: usize,
    pub frame_bytes: usize,
    pub repeats: usize,
    pub reorder_and_duplicates: bool,
    pub reassemble_mb_per_s: f64,
    pub decode_mb_per_s: f64,
    /// Reassembly then decoding of the same bytes, one after the other.
    pub combined_mb_per_s: f64,
    pub real_rate_mb_per_s: f64,
    /// Combined rate over the real rate.
    pub headroom: f64,
}

/// Runs the benchmark on the calling thread.
pub fn run_stream_bench(frames: usize, repeats: usize, faults: bool) -> StreamBench {
    let layout = FrameLayout {
        chirps_per_frame: 1,
        samples_per_chirp: 512,
        rx_count: 4,
        iq_order: IqOrder::IFirst,
        lanes: Lanes::Four,
    };
    let frame_bytes = layout.frame_bytes();
    let mut rng = Rng::new(0x9E37_79B9_7F4A_7C15);
    let stream: Vec<u8> = (0..frames * frame_bytes)
        .map(|_| rng.next_u64() as u8)
        .collect();
    let mut datagrams = packetize(&stream, 1);
    if faults {
        let mut injector = FaultInjector::new(FaultConfig {
            seed: 1,
            reorder_probability: 0.02,
            reorder_depth: 4,
            duplicate_probability: 0.01,
            ..FaultConfig::default()
        });
        let mut out = Vec::with_capacity(datagrams.len() + datagrams.len() / 50);
        for d in datagrams {
            injector.push(d, &mut out);
        }
        injector.flush(&mut out);
        datagrams = out;
    }
    let bytes = stream.len() as f64;
    // Reassembly is timed as a capture runs it: each frame is dropped once handed out, so the
    // allocator reuses its memory. Decoding is timed over frames reassembled beforehand.
    let reassemble_pass = || {
        let t = Instant::now();
        let mut r = Reassembler::new(frame_bytes, Some(frames as u64));
        let mut handed_out = 0usize;
        for d in &datagrams {
            r.push(d).ok();
            while let Some(f) = r.pop_frame() {
                handed_out += std::hint::black_box(f).data.len();
            }
        }
        r.finish();
        while let Some(f) = r.pop_frame() {
            handed_out += f.data.len();
        }
        std::hint::black_box(handed_out);
        t.elapsed().as_secs_f64()
    };
    let frames_in: Vec<&[u8]> = stream.chunks_exact(frame_bytes).collect();
    let decode_pass = || {
        let t = Instant::now();
        let mut checksum = 0i64;
        for f in &frames_in {
            if let Ok(s) = layout.decode(f) {
                checksum += i64::from(s[0].re);
            }
        }
        std::hint::black_box(checksum);
        t.elapsed().as_secs_f64()
    };
    let (mut reassemble, mut decode, mut combined) = (Vec::new(), Vec::new(), Vec::new());
    // One untimed pass of each first.
    reassemble_pass();
    decode_pass();
    for _ in 0..repeats.max(1) {
        let t_reassemble = reassemble_pass();
        let t_decode = decode_pass();
        reassemble.push(bytes / t_reassemble / 1e6);
        decode.push(bytes / t_decode / 1e6);
        combined.push(bytes / (t_reassemble + t_decode) / 1e6);
    }
    let combined_mb_per_s = super::median(combined);
    StreamBench {
        frames,
        frame_bytes,
        repeats: repeats.max(1),
        reorder_and_duplicates: faults,
        reassemble_mb_per_s: super::median(reassemble),
        decode_mb_per_s: super::median(decode),
        combined_mb_per_s,
        real_rate_mb_per_s: REAL_RATE_BYTES_PER_S / 1e6,
        headroom: combined_mb_per_s * 1e6 / REAL_RATE_BYTES_PER_S,
    }
}
