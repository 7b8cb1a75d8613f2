//! Lines and prompts out of the radar's UART (docs/protocols.md B1).
//!
//! A reply is the echo of the command, optional info lines, then `Done` or `Error <n>`, then a
//! prompt without a line end. Lines end in `\n`, often followed by a stray `\r`
//! (`sensorStop\nIgnored: Sensor is already stopped\n\rDone\n\rmmwDemo:/>`), so both bytes end a
//! line and empty lines are dropped. A prompt may also start a line when the next echo follows
//! it. Bytes that are not UTF-8 (power-up garbage) are kept as replacement characters.

/// The prompts of the firmwares mmnormd can drive.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PromptKind {
    /// `mmwDemo:/>`: SDK demos and the mmWave Studio CLI firmware.
    MmwDemo,
    /// `LVDS Stream:/>`: the SDK's LVDS-stream test application.
    LvdsStream,
    /// `CLI:/>`: the default SDK CLI.
    Cli,
    /// `CaptureDemo:/>`.
    CaptureDemo,
}

impl PromptKind {
    const ALL: [(PromptKind, &'static str); 4] = [
        (PromptKind::MmwDemo, "mmwDemo:/>"),
        (PromptKind::LvdsStream, "LVDS Stream:/>"),
        (PromptKind::CaptureDemo, "CaptureDemo:/>"),
        (PromptKind::Cli, "CLI:/>"),
    ];

    /// The prompt's text.
    pub fn text(self) -> &'static str {
        Self::ALL
            .iter()
            .find(|(k, _)| *k == self)
            .map_or("", |(_, t)| t)
    }

    /// The prompt that `text` ends with, if any.
    fn ending(text: &str) -> Option<(PromptKind, usize)> {
        Self::ALL
            .iter()
            .find(|(_, t)| text.ends_with(t))
            .map(|(k, t)| (*k, text.len() - t.len()))
    }

    /// The prompt that `text` starts with, if any, and the rest.
    fn leading(text: &str) -> Option<(PromptKind, &str)> {
        Self::ALL
            .iter()
            .find_map(|(k, t)| text.strip_prefix(t).map(|rest| (*k, rest)))
    }
}

/// One unit of radar output.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum ReplyEvent {
    Prompt(PromptKind),
    Line(String),
}

/// Longest line kept before it is cut, characters.
const MAX_LINE: usize = 4096;

/// Splits radar output into [`ReplyEvent`]s.
#[derive(Debug, Default)]
pub struct ReplyParser {
    partial: Vec<u8>,
}

impl ReplyParser {
    /// Feeds bytes and appends the events they complete to `events`.
    pub fn feed(&mut self, bytes: &[u8], events: &mut Vec<ReplyEvent>) {
        for &b in bytes {
            if b == b'\n' || b == b'\r' {
                self.end_line(events);
            } else {
                self.partial.push(b);
                if self.partial.len() >= MAX_LINE {
                    self.end_line(events);
                }
            }
        }
        // A prompt carries no line end: recognise it at the end of what has arrived.
        let text = String::from_utf8_lossy(&self.partial).into_owned();
        if let Some((kind, at)) = PromptKind::ending(&text) {
            let before = text[..at].trim();
            if !before.is_empty() {
                events.push(ReplyEvent::Line(before.to_string()));
            }
            events.push(ReplyEvent::Prompt(kind));
            self.partial.clear();
        }
    }

    fn end_line(&mut self, events: &mut Vec<ReplyEvent>) {
        let text = String::from_utf8_lossy(&self.partial).into_owned();
        self.partial.clear();
        let mut rest = text.as_str();
        while let Some((kind, after)) = PromptKind::leading(rest) {
            events.push(ReplyEvent::Prompt(kind));
            rest = after;
        }
        let line = rest.trim();
        if !line.is_empty() {
            events.push(ReplyEvent::Line(line.to_string()));
        }
    }
}

/// What a line means in reply to `command`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum LineKind {
    /// The command's text, echoed back intact.
    Echo,
    /// `Debug: …`, `Ignored: …` or `Skipped`.
    Info(String),
    Done,
    /// `Error <n>`.
    Error(i32),
    /// `'<text>' is not recognized as a CLI command` (SDK CLI).
    NotRecognized(String),
    /// Anything else: a garbled echo, garbage.
    Other(String),
}

/// Classifies a line of the reply to `command`.
pub fn classify(line: &str, command: &str) -> LineKind {
    if line == command.trim() {
        return LineKind::Echo;
    }
    if line == "Done" {
        return LineKind::Done;
    }
    if let Some(code) = line.strip_prefix("Error") {
        let code = code.trim();
        return match code.parse::<i32>() {
            Ok(n) => LineKind::Error(n),
            Err(_) if code.is_empty() => LineKind::Error(0),
            Err(_) => LineKind::Other(line.to_string()),
        };
    }
    if line.starts_with("Debug:") || line.starts_with("Ignored:") || line.starts_with("Skipped") {
        return LineKind::Info(line.to_string());
    }
    if let Some(text) = line.strip_suffix("is not recognized as a CLI command") {
        return LineKind::NotRecognized(text.trim().trim_matches('\'').to_string());
    }
    LineKind::Other(line.to_string())
}

/// The studio_cli meaning of an error code (B1).
pub fn error_meaning(code: i32) -> &'static str {
    match code {
        -50 => "invalid command",
        -51 => "invalid usage (wrong number of arguments)",
        -52 => "invalid parameter",
        -53 => "reconfiguration on `sensorStart 1`",
        -54 => "sensor already started or stopped",
        -55 => "LVDS header or software session not supported",
        -56 => "timeout",
        -57 => "data path configuration failed",
        -58 => "command not allowed after sensorStart",
        _ => "mmWaveLink or SDK error",
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn events(chunks: &[&[u8]]) -> Vec<ReplyEvent> {
        let mut p = ReplyParser::default();
        let mut out = Vec::new();
        for c in chunks {
            p.feed(c, &mut out);
        }
        out
    }

    fn line(s: &str) -> ReplyEvent {
        ReplyEvent::Line(s.into())
    }

    #[test]
    fn the_pyradar_trace_parses_with_its_stray_carriage_returns() {
        let e = events(&[b"sensorStop\nIgnored: Sensor is already stopped\n\rDone\n\rmmwDemo:/>"]);
        assert_eq!(
            e,
            vec![
                line("sensorStop"),
                line("Ignored: Sensor is already stopped"),
                line("Done"),
                ReplyEvent::Prompt(PromptKind::MmwDemo)
            ]
        );
        assert_eq!(classify("sensorStop", "sensorStop"), LineKind::Echo);
        assert!(matches!(
            classify("Ignored: Sensor is already stopped", "sensorStop"),
            LineKind::Info(_)
        ));
    }

    #[test]
    fn prompts_are_found_across_chunks_and_before_an_echo() {
        let e = events(&[b"Do", b"ne\r\nLVDS Str", b"eam:/>", b"flushCfg\n"]);
        assert_eq!(
            e,
            vec![
                line("Done"),
                ReplyEvent::Prompt(PromptKind::LvdsStream),
                line("flushCfg")
            ]
        );
        let e = events(&[b"CLI:/>version\n"]);
        assert_eq!(
            e,
            vec![ReplyEvent::Prompt(PromptKind::Cli), line("version")]
        );
    }

    #[test]
    fn errors_and_unrecognised_commands_are_classified() {
        assert_eq!(classify("Error -58", "chirpCfg 0"), LineKind::Error(-58));
        assert_eq!(error_meaning(-58), "command not allowed after sensorStart");
        assert_eq!(
            classify("'?`???' is not recognized as a CLI command", "flushCfg"),
            LineKind::NotRecognized("?`???".into())
        );
        assert_eq!(
            classify("flushCgf", "flushCfg"),
            LineKind::Other("flushCgf".into())
        );
    }

    #[test]
    fn garbage_before_a_prompt_becomes_a_line_of_its_own() {
        let e = events(&[&[0xFF, 0x00, b'x', 0x80], b"mmwDemo:/>"]);
        assert_eq!(e.len(), 2);
        assert!(matches!(&e[0], ReplyEvent::Line(_)));
        assert_eq!(e[1], ReplyEvent::Prompt(PromptKind::MmwDemo));
    }
}
