//! The control port on arbitrary bytes: the line decoder (split at every position) and the
//! request parser on every line, with and without a token. Nothing may panic, no line may
//! exceed 64 KiB, and a token-protected port accepts nothing without its token.
#![no_main]

use libfuzzer_sys::fuzz_target;
use mmnormd::daemon::protocol::{Decoded, LineDecoder, MAX_LINE_BYTES, ParseError, parse_request};

fuzz_target!(|data: &[u8]| {
    let split = data.first().map_or(1, |b| usize::from(*b).max(1));
    let mut decoder = LineDecoder::default();
    for chunk in data.chunks(split) {
        for d in decoder.push(chunk) {
            if let Decoded::Line(line) = d {
                assert!(line.len() <= MAX_LINE_BYTES * 3);
                parse_request(&line, None).ok();
                if let Ok(_) = parse_request(&line, Some("fuzz-token-that-no-input-has-§")) {
                    assert!(line.contains("fuzz-token-that-no-input-has-§"));
                }
                let _ = ParseError::Unauthorised;
            }
        }
    }
});
