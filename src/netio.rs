//! Socket helpers for loops with sub-millisecond deadlines.
//!
//! Linux rounds `SO_RCVTIMEO`/`SO_SNDTIMEO` to the kernel tick (4 ms at HZ = 250), so a loop
//! that must wake every 2 ms cannot wait in a blocking read. Such loops use nonblocking sockets,
//! drain what is there, and sleep (hrtimer-precise) until their next deadline. Host receive
//! instants become seconds from an epoch with [`signed_seconds`].

use std::io::{ErrorKind, Write};
use std::time::{Duration, Instant};

/// `at − epoch` in seconds, negative when `at` is earlier.
pub fn signed_seconds(at: Instant, epoch: Instant) -> f64 {
    if at >= epoch {
        at.duration_since(epoch).as_secs_f64()
    } else {
        -epoch.duration_since(at).as_secs_f64()
    }
}

/// Whether an IO error only means "nothing now".
pub fn is_would_block(e: &std::io::Error) -> bool {
    matches!(e.kind(), ErrorKind::WouldBlock | ErrorKind::TimedOut)
}

/// Writes all of `bytes` to a nonblocking writer, retrying while it would block, for at most
/// `limit`. A peer that reads nothing for that long gets `TimedOut`.
pub fn write_all_within(
    w: &mut impl Write,
    mut bytes: &[u8],
    limit: Duration,
) -> std::io::Result<()> {
    let start = Instant::now();
    while !bytes.is_empty() {
        match w.write(bytes) {
            Ok(0) => return Err(ErrorKind::WriteZero.into()),
            Ok(n) => bytes = &bytes[n..],
            Err(e) if is_would_block(&e) || e.kind() == ErrorKind::Interrupted => {
                if start.elapsed() > limit {
                    return Err(std::io::Error::new(
                        ErrorKind::TimedOut,
                        format!("the peer read nothing for {:.1} s", limit.as_secs_f64()),
                    ));
                }
                std::thread::sleep(Duration::from_micros(200));
            }
            Err(e) => return Err(e),
        }
    }
    Ok(())
}

/// Sleeps until `deadline`, but at most `cap`.
pub fn sleep_until(deadline: Option<Instant>, cap: Duration) {
    let now = Instant::now();
    let wait = deadline.map_or(cap, |d| d.saturating_duration_since(now).min(cap));
    if !wait.is_zero() {
        std::thread::sleep(wait);
    }
}
