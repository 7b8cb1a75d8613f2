//! An IWR1443 CLI simulator (docs/protocols.md B6): a sans-IO [`CliSimCore`] and a PTY
//! shell ([`CliSimulator`]) that a client opens like the radar's UART.
//!
//! The core plays the mmWave Studio CLI firmware: it echoes each line, answers `Done` or
//! `Error <n>` and prints the `mmwDemo:/>` prompt, with the reply layout of the pyRadar trace
//! (`echo\n`, lines ending `\n\r`, the prompt without a line end). Its state machine goes
//! INIT → configured → STARTED → STOPPED: argument counts are checked (−51), unknown commands get
//! −50 (or the SDK's "not recognized"), a double `sensorStop` answers `Ignored: Sensor is already
//! stopped` and `Done`, `sensorStart` without a valid profile answers −1, a second `sensorStart`
//! −54, and any other command while started −58. A successful `sensorStart` raises
//! [`SensorEvent::Start`] with the profile's frame count and period, which the lab wiring hands to
//! the DCA1000 simulator.
//!
//! Seeded faults: power-up garbage (bytes on the line and a half-typed line in the input buffer),
//! garbled echoes, dropped replies, a link that stalls (after a read, nothing moves either way for
//! `stall_ms`, as when a busy host's kernel holds a TTY's bytes), and a radar that answers `Done`
//! to `sensorStart` but never streams.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::Duration;

use super::RadarProfile;
use super::cli::grammar::argument_counts;
use crate::signal::Rng;

/// Faults the simulator injects.
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CliFaults {
    pub seed: u64,
    /// Random bytes sent at power-up, and left half-typed in the input buffer.
    pub powerup_garbage_bytes: usize,
    pub garble_echo_probability: f64,
    pub drop_reply_probability: f64,
    /// `sensorStart` answers `Done` but no frames follow.
    pub silent_after_start: bool,
    /// After each read that completes a line, the chance that the link stalls: for `stall_ms`
    /// the PTY shell neither reads nor writes, and the replies to those lines wait.
    pub stall_probability: f64,
    pub stall_ms: u64,
}

/// How the firmware answers a command it does not know.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum UnknownReply {
    /// studio_cli: `Error -50`.
    #[default]
    Error50,
    /// SDK CLI: `'<cmd>' is not recognized as a CLI command`.
    NotRecognized,
}

/// What the radar did that other devices see.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum SensorEvent {
    Start {
        frames: u64,
        frame_period_s: f64,
        /// From a frame's start to the end of its chirps (the profile's `frame_active_s`).
        acquired_s: f64,
    },
    Stop,
}

/// Counters of the simulator.
#[derive(Debug, Clone, Default, PartialEq, Eq, serde::Serialize)]
pub struct CliSimStats {
    pub lines: u64,
    pub done: u64,
    pub errors: u64,
    pub dropped_replies: u64,
    pub garbled_echoes: u64,
    pub sensor_starts: u64,
    pub stalls: u64,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum SensorState {
    Stopped,
    Started,
}

/// The sans-IO simulator: bytes in, bytes out, sensor events.
pub struct CliSimCore {
    prompt: String,
    unknown: UnknownReply,
    faults: CliFaults,
    rng: Rng,
    input: Vec<u8>,
    last_was_cr: bool,
    output: Vec<u8>,
    script: Vec<String>,
    state: SensorState,
    events: Vec<SensorEvent>,
    stall: Option<Duration>,
    stats: CliSimStats,
}

impl CliSimCore {
    pub fn new(unknown: UnknownReply, faults: CliFaults) -> Self {
        let mut rng = Rng::new(faults.seed);
        let garbage: Vec<u8> = (0..faults.powerup_garbage_bytes)
            .map(|_| (rng.next_u64() % 256) as u8)
            .filter(|b| *b != b'\n' && *b != b'\r')
            .collect();
        Self {
            prompt: "mmwDemo:/>".into(),
            unknown,
            rng,
            input: garbage.iter().take(8).copied().collect(),
            last_was_cr: false,
            output: garbage,
            script: Vec::new(),
            state: SensorState::Stopped,
            events: Vec::new(),
            stall: None,
            stats: CliSimStats::default(),
            faults,
        }
    }

    /// Bytes for the host.
    pub fn take_output(&mut self) -> Vec<u8> {
        std::mem::take(&mut self.output)
    }

    /// Sensor events since the last call.
    pub fn take_events(&mut self) -> Vec<SensorEvent> {
        std::mem::take(&mut self.events)
    }

    pub fn stats(&self) -> &CliSimStats {
        &self.stats
    }

    /// A stall the link owes since the last call (the `stall_*` faults): the shell holds every
    /// byte, both ways, for that long.
    pub fn take_stall(&mut self) -> Option<Duration> {
        self.stall.take()
    }

    /// Bytes from the host (one read of the link).
    pub fn feed(&mut self, bytes: &[u8]) {
        if self.feed_lines(bytes) > 0 && self.roll(self.faults.stall_probability) {
            self.stats.stalls += 1;
            self.stall = Some(Duration::from_millis(self.faults.stall_ms));
        }
    }

    /// Feeds bytes; returns how many lines they completed.
    fn feed_lines(&mut self, bytes: &[u8]) -> usize {
        let mut lines = 0;
        for &b in bytes {
            let cr = b == b'\r';
            if b == b'\n' && self.last_was_cr {
                self.last_was_cr = false;
                continue;
            }
            self.last_was_cr = cr;
            if b == b'\n' || cr {
                let line = String::from_utf8_lossy(&std::mem::take(&mut self.input)).into_owned();
                self.line(&line);
                lines += 1;
            } else if self.input.len() < 1024 {
                self.input.push(b);
            }
        }
        lines
    }

    fn roll(&mut self, p: f64) -> bool {
        p > 0.0 && self.rng.uniform() < p
    }

    fn line(&mut self, line: &str) {
        self.stats.lines += 1;
        let text = line.trim();
        if text.is_empty() {
            self.output.extend_from_slice(b"\n");
            self.output.extend_from_slice(self.prompt.as_bytes());
            return;
        }
        let (info, result) = self.execute(text);
        if self.roll(self.faults.drop_reply_probability) {
            self.stats.dropped_replies += 1;
            return;
        }
        let echo = if self.roll(self.faults.garble_echo_probability) {
            self.stats.garbled_echoes += 1;
            garble(text, &mut self.rng)
        } else {
            text.to_string()
        };
        let mut reply = format!("{echo}\n");
        for i in info {
            reply.push_str(&i);
            reply.push_str("\n\r");
        }
        match result {
            Ok(()) => {
                self.stats.done += 1;
                reply.push_str("Done\n\r");
            }
            Err(Reply::Code(code)) => {
                self.stats.errors += 1;
                reply.push_str(&format!("Error {code}\n\r"));
            }
            Err(Reply::NotRecognized) => {
                self.stats.errors += 1;
                let word = text.split_whitespace().next().unwrap_or("");
                reply.push_str(&format!("'{word}' is not recognized as a CLI command\n\r"));
            }
        }
        reply.push_str(&self.prompt);
        self.output.extend_from_slice(reply.as_bytes());
    }

    fn execute(&mut self, text: &str) -> (Vec<String>, Result<(), Reply>) {
        let mut words = text.split_whitespace();
        let command = words.next().unwrap_or("");
        let argc = words.count();
        let Some(counts) = argument_counts(command) else {
            return match self.unknown {
                UnknownReply::Error50 => (vec![], Err(Reply::Code(-50))),
                UnknownReply::NotRecognized => (vec![], Err(Reply::NotRecognized)),
            };
        };
        if !counts.is_empty() && !counts.contains(&argc) {
            return (vec![], Err(Reply::Code(-51)));
        }
        match (command, self.state) {
            ("sensorStop", SensorState::Stopped) => {
                (vec!["Ignored: Sensor is already stopped".into()], Ok(()))
            }
            ("sensorStop", SensorState::Started) => {
                self.state = SensorState::Stopped;
                self.events.push(SensorEvent::Stop);
                (vec![], Ok(()))
            }
            ("sensorStart", SensorState::Started) => (vec![], Err(Reply::Code(-54))),
            ("sensorStart", SensorState::Stopped) => {
                let script = self.script.join("\n");
                match RadarProfile::from_cfg_str(&script) {
                    Ok(profile) => {
                        self.state = SensorState::Started;
                        self.stats.sensor_starts += 1;
                        if !self.faults.silent_after_start {
                            self.events.push(SensorEvent::Start {
                                frames: u64::from(profile.frames),
                                frame_period_s: profile.frame_period_s(),
                                acquired_s: profile.frame_active_s(),
                            });
                        }
                        (vec![], Ok(()))
                    }
                    Err(e) => (vec![format!("Debug: {e}")], Err(Reply::Code(-1))),
                }
            }
            (_, SensorState::Started) => (vec![], Err(Reply::Code(-58))),
            ("flushCfg", _) => {
                self.script.clear();
                (vec![], Ok(()))
            }
            ("channelCfg", _) => {
                self.script.push(text.to_string());
                (
                    vec!["Debug: Init Calibration Status = 0x1ffe".into()],
                    Ok(()),
                )
            }
            _ => {
                self.script.push(text.to_string());
                (vec![], Ok(()))
            }
        }
    }
}

enum Reply {
    Code(i32),
    NotRecognized,
}

fn garble(text: &str, rng: &mut Rng) -> String {
    let mut chars: Vec<char> = text.chars().collect();
    let n = chars.len().max(1);
    for _ in 0..2 {
        let i = (rng.next_u64() % n as u64) as usize;
        if let Some(c) = chars.get_mut(i) {
            *c = '?';
        }
    }
    let g: String = chars.into_iter().collect();
    if g == text { format!("{text}?") } else { g }
}

/// Why the PTY simulator could not start.
#[derive(Debug, thiserror::Error)]
pub enum CliSimError {
    #[error("cannot open a PTY pair: {0}")]
    Pty(String),
    #[error("cannot link {link} to the PTY {pty}: {source}")]
    Link {
        link: PathBuf,
        pty: String,
        #[source]
        source: std::io::Error,
    },
}

/// The simulator on a PTY pair, on its own thread. Clients open [`path`](Self::path) (or the
/// symlink given to [`spawn`](Self::spawn)) as they would `/dev/ttyACM0`.
pub struct CliSimulator {
    path: String,
    link: Option<PathBuf>,
    stop: Arc<AtomicBool>,
    stats: Arc<Mutex<CliSimStats>>,
    thread: Option<JoinHandle<()>>,
    _slave: serialport::TTYPort,
}

impl CliSimulator {
    /// Opens a PTY, optionally symlinks `link` to its slave, and serves `core` on it. Sensor
    /// events go to `on_event`.
    pub fn spawn(
        core: CliSimCore,
        link: Option<&Path>,
        mut on_event: Box<dyn FnMut(SensorEvent) + Send>,
    ) -> Result<Self, CliSimError> {
        let (mut master, slave) =
            serialport::TTYPort::pair().map_err(|e| CliSimError::Pty(e.to_string()))?;
        let path = serialport::SerialPort::name(&slave)
            .ok_or_else(|| CliSimError::Pty("the PTY slave has no name".into()))?;
        if let Some(link) = link {
            if let Some(parent) = link.parent() {
                std::fs::create_dir_all(parent).ok();
            }
            std::fs::remove_file(link).ok();
            std::os::unix::fs::symlink(&path, link).map_err(|source| CliSimError::Link {
                link: link.to_path_buf(),
                pty: path.clone(),
                source,
            })?;
        }
        serialport::SerialPort::set_timeout(&mut master, Duration::from_millis(20))
            .map_err(|e| CliSimError::Pty(e.to_string()))?;
        let stop = Arc::new(AtomicBool::new(false));
        let stats = Arc::new(Mutex::new(CliSimStats::default()));
        let thread = {
            let (stop, stats) = (stop.clone(), stats.clone());
            std::thread::Builder::new()
                .name("iwr1443-sim".into())
                .spawn(move || {
                    use std::io::{Read as _, Write as _};
                    let mut core = core;
                    let mut buf = [0u8; 512];
                    while !stop.load(Ordering::Relaxed) {
                        let out = core.take_output();
                        if !out.is_empty() && master.write_all(&out).is_err() {
                            std::thread::sleep(Duration::from_millis(5));
                        }
                        match master.read(&mut buf) {
                            Ok(n) if n > 0 => core.feed(&buf[..n]),
                            Ok(_) => {}
                            // EIO while no client holds the slave open; keep waiting.
                            Err(_) => std::thread::sleep(Duration::from_millis(5)),
                        }
                        for e in core.take_events() {
                            on_event(e);
                        }
                        if let Some(stall) = core.take_stall() {
                            let until = std::time::Instant::now() + stall;
                            while std::time::Instant::now() < until && !stop.load(Ordering::Relaxed)
                            {
                                std::thread::sleep(Duration::from_millis(10));
                            }
                        }
                        if let Ok(mut s) = stats.lock() {
                            *s = core.stats().clone();
                        }
                    }
                })
                .map_err(|e| CliSimError::Pty(e.to_string()))?
        };
        Ok(Self {
            path,
            link: link.map(Path::to_path_buf),
            stop,
            stats,
            thread: Some(thread),
            _slave: slave,
        })
    }

    /// The PTY device a client opens.
    pub fn path(&self) -> &str {
        &self.path
    }

    pub fn stats(&self) -> CliSimStats {
        self.stats.lock().map(|s| s.clone()).unwrap_or_default()
    }
}

impl Drop for CliSimulator {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            t.join().ok();
        }
        if let Some(link) = &self.link {
            std::fs::remove_file(link).ok();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn reply(core: &mut CliSimCore, line: &str) -> String {
        core.feed(format!("{line}\n").as_bytes());
        String::from_utf8(core.take_output()).unwrap()
    }

    #[test]
    fn a_stall_is_owed_after_the_lines_it_rolled_for_and_counted() {
        let faults = CliFaults {
            seed: 11,
            stall_probability: 0.5,
            stall_ms: 300,
            ..CliFaults::default()
        };
        let mut core = CliSimCore::new(UnknownReply::Error50, faults);
        let mut owed = 0;
        for _ in 0..40 {
            reply(&mut core, "");
            if let Some(stall) = core.take_stall() {
                assert_eq!(stall, Duration::from_millis(300));
                owed += 1;
            }
        }
        assert_eq!(owed, core.stats().stalls);
        assert!((10..=30).contains(&owed), "{owed} of 40 at p = 0.5");
        assert_eq!(core.take_stall(), None);
        // The reply is still whole: the shell holds it, the core does not change it.
        assert_eq!(reply(&mut core, ""), "\nmmwDemo:/>");
    }

    #[test]
    fn replies_follow_the_firmware_layout_and_state_machine() {
        let mut core = CliSimCore::new(UnknownReply::Error50, CliFaults::default());
        assert_eq!(
            reply(&mut core, "sensorStop"),
            "sensorStop\nIgnored: Sensor is already stopped\n\rDone\n\rmmwDemo:/>"
        );
        assert_eq!(
            reply(&mut core, "frobnicate 1"),
            "frobnicate 1\nError -50\n\rmmwDemo:/>"
        );
        assert_eq!(
            reply(&mut core, "adcCfg 2"),
            "adcCfg 2\nError -51\n\rmmwDemo:/>"
        );
        assert!(reply(&mut core, "sensorStart").contains("Error -1"));
        let text = std::fs::read_to_string("firmware_cfg/iwr1443_mmnorm.cfg").unwrap();
        for line in text
            .lines()
            .filter(|l| !l.starts_with('%') && !l.is_empty())
        {
            assert!(reply(&mut core, line).contains("Done"), "{line}");
        }
        match core.take_events()[..] {
            [
                SensorEvent::Start {
                    frames: 4000,
                    frame_period_s,
                    acquired_s,
                },
            ] => {
                // frameCfg 3 ms; profileCfg idle 10 µs + ramp end 60 µs, one chirp.
                assert!((frame_period_s - 0.003).abs() < 1e-12);
                assert!((acquired_s - 70e-6).abs() < 1e-12);
            }
            ref other => panic!("{other:?}"),
        }
        assert!(reply(&mut core, "chirpCfg 0 0 0 0 0 0 0 1").contains("Error -58"));
        assert!(reply(&mut core, "sensorStart").contains("Error -54"));
        assert!(reply(&mut core, "sensorStop").contains("Done"));
        assert_eq!(core.take_events(), vec![SensorEvent::Stop]);
    }

    #[test]
    fn power_up_garbage_spoils_the_first_line_until_a_newline() {
        let faults = CliFaults {
            seed: 3,
            powerup_garbage_bytes: 40,
            ..CliFaults::default()
        };
        let mut core = CliSimCore::new(UnknownReply::NotRecognized, faults);
        assert!(!core.take_output().is_empty());
        assert!(reply(&mut core, "flushCfg").contains("is not recognized"));
        assert!(reply(&mut core, "flushCfg").contains("Done"));
    }
}
