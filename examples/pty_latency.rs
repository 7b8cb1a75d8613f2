//! Round trips through the radar CLI simulator's PTY: a bare newline out, the prompt back.
//!
//! `cargo run --release --example pty_latency -- 90` runs for 90 s and prints the quantiles.
//! It measures the host, not the radar: Linux hands a TTY's received bytes to the reader from a
//! kernel worker, and on a busy host that worker can wait for seconds (README, CLI session).

use std::io::{Read, Write};
use std::time::{Duration, Instant};

use anyhow::Context as _;
use mmnormd::radar::sim::{CliFaults, CliSimCore, CliSimulator, UnknownReply};

fn main() -> anyhow::Result<()> {
    let seconds: u64 = match std::env::args().nth(1) {
        Some(s) => s.parse().with_context(|| format!("seconds = {s:?}"))?,
        None => 60,
    };
    let core = CliSimCore::new(UnknownReply::Error50, CliFaults::default());
    let sim = CliSimulator::spawn(core, None, Box::new(|_| {}))?;
    let mut port = serialport::new(sim.path(), 115_200)
        .timeout(Duration::from_millis(50))
        .open()?;
    let mut round_trips_s = Vec::new();
    let end = Instant::now() + Duration::from_secs(seconds);
    let mut buf = [0u8; 256];
    while Instant::now() < end {
        let sent = Instant::now();
        port.write_all(b"\n")?;
        let mut got = Vec::new();
        while !got.ends_with(b"mmwDemo:/>") {
            match port.read(&mut buf) {
                Ok(n) => got.extend_from_slice(&buf[..n]),
                Err(e) if e.kind() == std::io::ErrorKind::TimedOut => {}
                Err(e) => return Err(e.into()),
            }
        }
        round_trips_s.push(sent.elapsed().as_secs_f64());
        std::thread::sleep(Duration::from_millis(20));
    }
    anyhow::ensure!(!round_trips_s.is_empty(), "no round trip in {seconds} s");
    round_trips_s.sort_by(f64::total_cmp);
    let n = round_trips_s.len();
    let q = |p: f64| round_trips_s[((n - 1) as f64 * p) as usize];
    println!(
        "{n} round trips: p50 {:.1} ms, p99 {:.1} ms, p99.9 {:.1} ms, max {:.1} ms; {} over 1 s, {} over 2 s",
        1e3 * q(0.5),
        1e3 * q(0.99),
        1e3 * q(0.999),
        1e3 * q(1.0),
        round_trips_s.iter().filter(|t| **t > 1.0).count(),
        round_trips_s.iter().filter(|t| **t > 2.0).count(),
    );
    Ok(())
}
