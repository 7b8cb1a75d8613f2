//! The IWR1443 CLI on arbitrary bytes: the reply parser, a session fed the bytes as radar output
//! (with timeouts interleaved), and the CLI simulator fed them as host input. Nothing may panic.
#![no_main]

use std::time::{Duration, Instant};

use libfuzzer_sys::fuzz_target;
use mmnormd::radar::cli::{CliSession, ReplyParser, SessionConfig};
use mmnormd::radar::sim::{CliFaults, CliSimCore, UnknownReply};

fuzz_target!(|data: &[u8]| {
    let mut parser = ReplyParser::default();
    let mut events = Vec::new();
    for chunk in data.chunks(7) {
        parser.feed(chunk, &mut events);
    }

    let t0 = Instant::now();
    let commands = vec!["sensorStop".to_string(), "flushCfg".to_string(), "sensorStart".to_string()];
    let mut session = CliSession::new(commands, SessionConfig::default(), t0);
    let mut now = t0;
    for chunk in data.split(|&b| b == 0xFF) {
        session.handle_input(chunk, now);
        while session.poll_transmit().is_some() {}
        now += Duration::from_millis(250);
        session.handle_timeout(now);
    }
    if let Some(Ok(outcomes)) = session.result() {
        assert!(outcomes.len() <= 3);
    }

    let faults = CliFaults {
        seed: data.len() as u64,
        garble_echo_probability: 0.1,
        drop_reply_probability: 0.1,
        ..CliFaults::default()
    };
    let mut sim = CliSimCore::new(UnknownReply::Error50, faults);
    sim.feed(data);
    sim.take_output();
    sim.take_events();
});
