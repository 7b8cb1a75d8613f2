//! A sans-IO session that sends a list of CLI commands (docs/protocols.md B1, B4).
//!
//! The caller moves bytes and time: [`CliSession::poll_transmit`] gives bytes to write,
//! [`CliSession::handle_input`] takes bytes read, [`CliSession::poll_timeout`] says when to call
//! [`CliSession::handle_timeout`]. The session:
//! 1. resynchronises: sends a bare `\n` and waits for a prompt, again every `resync_interval`,
//!    up to `resync_attempts` times (power-up garbage is skipped this way, and a partly typed line
//!    in the radar's buffer is flushed);
//! 2. sends one command, then waits for `Done` or `Error <n>` and the prompt after it;
//! 3. retries a command, after a new resync, when no reply came within `command_timeout`, or
//!    when the radar did not recognise text that arrived garbled (a mismatched echo, or the SDK's
//!    "not recognized"); at most `retries` times;
//! 4. fails on `Error <n>` for an intact command, naming the command and the code's meaning.
//!
//! Each command is accounted exactly one `Done`. A retried `sensorStart` that answers
//! `Error -54` (already started) counts as done: the first attempt started the sensor and only its
//! reply was lost.

use std::collections::VecDeque;
use std::time::{Duration, Instant};

use super::reply::{LineKind, PromptKind, ReplyEvent, ReplyParser, classify, error_meaning};

/// Timing and retry limits.
#[derive(Debug, Clone, PartialEq)]
pub struct SessionConfig {
    pub command_timeout: Duration,
    /// Retries per command after the first attempt.
    pub retries: u32,
    pub resync_attempts: u32,
    pub resync_interval: Duration,
}

/// Bare newlines sent before a silent radar is given up: 50 at 200 ms is 10 s. A loaded host can
/// hold a TTY's bytes in the kernel for seconds (its receive path runs on a kernel worker); 4.5 s
/// was measured on a 2-core machine with every core busy, so 2 s was too short.
pub const DEFAULT_RESYNC_ATTEMPTS: u32 = 50;

impl Default for SessionConfig {
    fn default() -> Self {
        Self {
            command_timeout: Duration::from_secs(1),
            retries: 3,
            resync_attempts: DEFAULT_RESYNC_ATTEMPTS,
            resync_interval: Duration::from_millis(200),
        }
    }
}

/// Why a session failed.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum CliError {
    #[error(
        "no prompt from the radar after {attempts} newlines over {waited_ms} ms (is the CLI firmware flashed, the port the CLI one, the board powered?)"
    )]
    NoPrompt { attempts: u32, waited_ms: u64 },
    #[error("`{command}`: no reply after {attempts} attempts of {timeout_ms} ms each")]
    Timeout {
        command: String,
        attempts: u32,
        timeout_ms: u64,
    },
    #[error("`{command}` was refused: Error {code} ({meaning})")]
    Rejected {
        command: String,
        code: i32,
        meaning: &'static str,
    },
    #[error("`{command}` was not recognised after {attempts} attempts (last reply: {reply})")]
    NotRecognized {
        command: String,
        attempts: u32,
        reply: String,
    },
    #[error("serial port: {0}")]
    Io(String),
}

/// How a command was accepted.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub enum Accepted {
    Done,
    /// A retried `sensorStart` answered `Error -54`.
    AlreadyStarted,
}

/// The record of one command.
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize)]
pub struct CommandOutcome {
    pub command: String,
    pub attempts: u32,
    pub accepted: Accepted,
    /// `Debug:`/`Ignored:` lines of the accepted attempt.
    pub info: Vec<String>,
    /// Echoes that did not match the command, over all attempts.
    pub garbled_echoes: u32,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum State {
    /// Waiting for a prompt after a bare newline; `attempts` newlines sent so far.
    Resync {
        attempts: u32,
    },
    /// Waiting for `Done`/`Error` to the current command.
    Reply,
    /// The current command is done; waiting for its prompt.
    Prompt,
    Finished,
    Failed,
}

struct Current {
    command: String,
    attempts: u32,
    echo_ok: bool,
    garbled_echoes: u32,
    info: Vec<String>,
    last_other: Option<String>,
}

/// The session. See the module docs.
pub struct CliSession {
    config: SessionConfig,
    pending: VecDeque<String>,
    current: Option<Current>,
    state: State,
    parser: ReplyParser,
    transmit: VecDeque<Vec<u8>>,
    deadline: Option<Instant>,
    outcomes: Vec<CommandOutcome>,
    error: Option<CliError>,
    prompt: Option<PromptKind>,
    garbage_lines: u64,
}

impl CliSession {
    /// A session that will send `commands`, starting with a resync at `now`.
    pub fn new(commands: Vec<String>, config: SessionConfig, now: Instant) -> Self {
        let mut s = Self {
            config,
            pending: commands.into(),
            current: None,
            state: State::Resync { attempts: 0 },
            parser: ReplyParser::default(),
            transmit: VecDeque::new(),
            deadline: None,
            outcomes: Vec::new(),
            error: None,
            prompt: None,
            garbage_lines: 0,
        };
        s.resync(0, now);
        s
    }

    /// Bytes to write now.
    pub fn poll_transmit(&mut self) -> Option<Vec<u8>> {
        self.transmit.pop_front()
    }

    /// When [`handle_timeout`](Self::handle_timeout) is due.
    pub fn poll_timeout(&self) -> Option<Instant> {
        self.deadline
    }

    /// Whether the session has ended, well or not.
    pub fn is_finished(&self) -> bool {
        matches!(self.state, State::Finished | State::Failed)
    }

    /// The outcome: the record of every command, or the failure.
    pub fn result(&self) -> Option<Result<&[CommandOutcome], &CliError>> {
        match self.state {
            State::Finished => Some(Ok(&self.outcomes)),
            State::Failed => self.error.as_ref().map(Err),
            _ => None,
        }
    }

    /// The prompt seen last (which firmware answers).
    pub fn prompt(&self) -> Option<PromptKind> {
        self.prompt
    }

    /// Lines that were neither replies nor echoes (garbage), so far.
    pub fn garbage_lines(&self) -> u64 {
        self.garbage_lines
    }

    fn resync(&mut self, attempts: u32, now: Instant) {
        self.state = State::Resync {
            attempts: attempts + 1,
        };
        self.transmit.push_back(b"\n".to_vec());
        self.deadline = Some(now + self.config.resync_interval);
    }

    fn fail(&mut self, error: CliError) {
        self.error = Some(error);
        self.state = State::Failed;
        self.deadline = None;
        self.transmit.clear();
    }

    fn send_next(&mut self, now: Instant) {
        if self.current.is_none() {
            match self.pending.pop_front() {
                Some(command) => {
                    self.current = Some(Current {
                        command,
                        attempts: 0,
                        echo_ok: false,
                        garbled_echoes: 0,
                        info: Vec::new(),
                        last_other: None,
                    });
                }
                None => {
                    self.state = State::Finished;
                    self.deadline = None;
                    return;
                }
            }
        }
        if let Some(c) = self.current.as_mut() {
            c.attempts += 1;
            c.echo_ok = false;
            c.info.clear();
            let mut line = c.command.clone().into_bytes();
            line.push(b'\n');
            self.transmit.push_back(line);
        }
        self.state = State::Reply;
        self.deadline = Some(now + self.config.command_timeout);
    }

    /// Retries the current command after a resync, or fails when out of attempts.
    fn retry(&mut self, why: impl FnOnce(&Current) -> CliError, now: Instant) {
        let Some(c) = self.current.as_ref() else {
            return;
        };
        if c.attempts > self.config.retries {
            let e = why(c);
            self.fail(e);
            return;
        }
        self.resync(0, now);
    }

    fn accept(&mut self, accepted: Accepted, now: Instant) {
        if let Some(c) = self.current.take() {
            self.outcomes.push(CommandOutcome {
                command: c.command,
                attempts: c.attempts,
                accepted,
                info: c.info,
                garbled_echoes: c.garbled_echoes,
            });
        }
        self.state = State::Prompt;
        self.deadline = Some(now + self.config.command_timeout);
    }

    /// Takes bytes read from the radar.
    pub fn handle_input(&mut self, bytes: &[u8], now: Instant) {
        let mut events = Vec::new();
        self.parser.feed(bytes, &mut events);
        for event in events {
            self.handle_event(event, now);
        }
    }

    fn handle_event(&mut self, event: ReplyEvent, now: Instant) {
        match (self.state, event) {
            (State::Finished | State::Failed, _) => {}
            (_, ReplyEvent::Prompt(kind)) => {
                self.prompt = Some(kind);
                if matches!(self.state, State::Resync { .. } | State::Prompt) {
                    self.send_next(now);
                }
            }
            (State::Reply, ReplyEvent::Line(line)) => self.handle_reply_line(&line, now),
            (_, ReplyEvent::Line(_)) => self.garbage_lines += 1,
        }
    }

    fn handle_reply_line(&mut self, line: &str, now: Instant) {
        let Some(c) = self.current.as_mut() else {
            return;
        };
        match classify(line, &c.command) {
            LineKind::Echo => c.echo_ok = true,
            LineKind::Info(text) => c.info.push(text),
            LineKind::Done => self.accept(Accepted::Done, now),
            LineKind::Error(-54) if c.attempts > 1 && is_sensor_start(&c.command) => {
                self.accept(Accepted::AlreadyStarted, now)
            }
            LineKind::Error(-50) if !c.echo_ok => {
                let reply = format!("Error -50 after echo {:?}", c.last_other);
                self.retry_garbled(reply, now);
            }
            LineKind::Error(code) => {
                let command = c.command.clone();
                self.fail(CliError::Rejected {
                    command,
                    code,
                    meaning: error_meaning(code),
                });
            }
            LineKind::NotRecognized(text) => {
                self.retry_garbled(format!("'{text}' is not recognized"), now);
            }
            LineKind::Other(text) => {
                if c.echo_ok {
                    self.garbage_lines += 1;
                } else {
                    c.garbled_echoes += 1;
                }
                c.last_other = Some(text);
            }
        }
    }

    /// Retries a command the radar did not recognise because it arrived garbled.
    fn retry_garbled(&mut self, reply: String, now: Instant) {
        self.retry(
            |c| CliError::NotRecognized {
                command: c.command.clone(),
                attempts: c.attempts,
                reply,
            },
            now,
        );
    }

    /// Call when [`poll_timeout`](Self::poll_timeout) has passed.
    pub fn handle_timeout(&mut self, now: Instant) {
        if self.deadline.is_none_or(|d| now < d) {
            return;
        }
        match self.state {
            State::Resync { attempts } => {
                if attempts >= self.config.resync_attempts {
                    let waited_ms =
                        self.config.resync_interval.as_millis() as u64 * u64::from(attempts);
                    self.fail(CliError::NoPrompt {
                        attempts,
                        waited_ms,
                    });
                } else {
                    self.resync(attempts, now);
                }
            }
            State::Reply => {
                let timeout_ms = self.config.command_timeout.as_millis() as u64;
                self.retry(
                    |c| CliError::Timeout {
                        command: c.command.clone(),
                        attempts: c.attempts,
                        timeout_ms,
                    },
                    now,
                );
            }
            // Done arrived but its prompt did not: find the prompt again before going on.
            State::Prompt => self.resync(0, now),
            State::Finished | State::Failed => {}
        }
    }
}

fn is_sensor_start(command: &str) -> bool {
    command.split_whitespace().next() == Some("sensorStart")
}

#[cfg(test)]
mod tests {
    use super::*;

    fn start(commands: &[&str]) -> (CliSession, Instant) {
        let now = Instant::now();
        let s = CliSession::new(
            commands.iter().map(|c| c.to_string()).collect(),
            SessionConfig::default(),
            now,
        );
        (s, now)
    }

    fn sent(s: &mut CliSession) -> Vec<String> {
        std::iter::from_fn(|| s.poll_transmit())
            .map(|b| String::from_utf8(b).unwrap())
            .collect()
    }

    #[test]
    fn a_clean_exchange_sends_each_command_after_its_prompt() {
        let (mut s, t) = start(&["sensorStop", "flushCfg"]);
        assert_eq!(sent(&mut s), ["\n"]);
        s.handle_input(b"\n\rmmwDemo:/>", t);
        assert_eq!(sent(&mut s), ["sensorStop\n"]);
        s.handle_input(
            b"sensorStop\nIgnored: Sensor is already stopped\n\rDone\n\rmmwDemo:/>",
            t,
        );
        assert_eq!(sent(&mut s), ["flushCfg\n"]);
        s.handle_input(b"flushCfg\nDone\n\rmmwDemo:/>", t);
        let outcomes = s.result().unwrap().unwrap();
        assert_eq!(outcomes.len(), 2);
        assert_eq!(outcomes[0].info, ["Ignored: Sensor is already stopped"]);
        assert_eq!(s.prompt(), Some(PromptKind::MmwDemo));
    }

    #[test]
    fn a_lost_reply_is_retried_after_a_resync_and_counted_once() {
        let (mut s, t) = start(&["channelCfg 15 1 0"]);
        sent(&mut s);
        s.handle_input(b"mmwDemo:/>", t);
        sent(&mut s);
        let t1 = t + Duration::from_millis(1001);
        s.handle_timeout(t1);
        assert_eq!(sent(&mut s), ["\n"]);
        // The late reply of the first attempt ends in a prompt: it is consumed by the resync.
        s.handle_input(b"channelCfg 15 1 0\nDone\n\rmmwDemo:/>", t1);
        assert_eq!(sent(&mut s), ["channelCfg 15 1 0\n"]);
        s.handle_input(b"channelCfg 15 1 0\nDone\n\rmmwDemo:/>", t1);
        let outcomes = s.result().unwrap().unwrap();
        assert_eq!((outcomes.len(), outcomes[0].attempts), (1, 2));
    }

    #[test]
    fn a_refusal_fails_with_the_code_and_its_meaning() {
        let (mut s, t) = start(&["chirpCfg 0 0 0 0 0 0 0 1"]);
        sent(&mut s);
        s.handle_input(
            b"mmwDemo:/>chirpCfg 0 0 0 0 0 0 0 1\nError -58\n\rmmwDemo:/>",
            t,
        );
        let err = s.result().unwrap().unwrap_err().clone();
        assert_eq!(
            err.to_string(),
            "`chirpCfg 0 0 0 0 0 0 0 1` was refused: Error -58 (command not allowed after sensorStart)"
        );
    }

    #[test]
    fn garbled_text_is_retried_and_gives_up_after_the_limit() {
        let (mut s, t) = start(&["flushCfg"]);
        sent(&mut s);
        s.handle_input(b"mmwDemo:/>", t);
        for _ in 0..4 {
            assert_eq!(sent(&mut s), ["flushCfg\n"]);
            s.handle_input(b"fl?shCfg\nError -50\n\r", t);
            if s.is_finished() {
                break;
            }
            assert_eq!(sent(&mut s), ["\n"]);
            s.handle_input(b"mmwDemo:/>", t);
        }
        assert!(matches!(
            s.result().unwrap(),
            Err(CliError::NotRecognized { attempts: 4, .. })
        ));
    }

    #[test]
    fn no_prompt_at_all_fails_after_the_resync_attempts() {
        let (mut s, mut t) = start(&["flushCfg"]);
        for _ in 0..60 {
            t += Duration::from_millis(201);
            s.handle_timeout(t);
        }
        assert_eq!(
            s.result().unwrap().unwrap_err(),
            &CliError::NoPrompt {
                attempts: 50,
                waited_ms: 10_000
            }
        );
    }

    #[test]
    fn a_prompt_held_up_for_4_5_s_by_the_host_is_waited_for() {
        let (mut s, mut t) = start(&["flushCfg"]);
        for _ in 0..22 {
            t += Duration::from_millis(205);
            s.handle_timeout(t);
        }
        assert!(!s.is_finished(), "still resynchronising after 4.5 s");
        // The stall ends: every newline's prompt arrives at once, then the command's reply.
        s.handle_input("\nmmwDemo:/>".repeat(23).as_bytes(), t);
        assert_eq!(sent(&mut s).last().map(String::as_str), Some("flushCfg\n"));
        s.handle_input(b"flushCfg\nDone\n\rmmwDemo:/>", t);
        let outcomes = s.result().unwrap().unwrap();
        assert_eq!((outcomes.len(), outcomes[0].attempts), (1, 1));
    }

    #[test]
    fn a_retried_sensor_start_that_is_already_started_counts_as_done() {
        let (mut s, t) = start(&["sensorStart"]);
        sent(&mut s);
        s.handle_input(b"mmwDemo:/>", t);
        sent(&mut s);
        let t1 = t + Duration::from_millis(1001);
        s.handle_timeout(t1);
        s.handle_input(b"mmwDemo:/>", t1);
        assert_eq!(sent(&mut s), ["\n", "sensorStart\n"]);
        s.handle_input(b"sensorStart\nError -54\n\rmmwDemo:/>", t1);
        let outcomes = s.result().unwrap().unwrap();
        assert_eq!(outcomes[0].accepted, Accepted::AlreadyStarted);
    }
}
