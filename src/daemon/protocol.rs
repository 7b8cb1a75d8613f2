//! The control port's protocol, sans-IO: newline-delimited JSON, one request per line, one
//! reply per request, and events on subscribed connections.
//!
//! Requests: `{"cmd": "scan", "name"?, "width_m"?, "height_m"?, "speed_m_per_s"?, "label"?}`,
//! `{"cmd": "status"}`, `{"cmd": "abort"}`, `{"cmd": "list"}`,
//! `{"cmd": "reconstruct", "scan": NAME}`, `{"cmd": "subscribe"}`; each may carry `"token"`.
//! Replies: `{"ok": true, ...}` or `{"ok": false, "error": "..."}`. Events: `{"event": ...}`.

use serde::Deserialize;

use crate::lab::job::ScanRequest;

/// The longest request line accepted, bytes (without the newline).
pub const MAX_LINE_BYTES: usize = 64 * 1024;

/// What the decoder found in the bytes.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Decoded {
    Line(String),
    /// A line longer than [`MAX_LINE_BYTES`]; the connection cannot be resynchronised.
    TooLong,
}

/// Splits a byte stream into lines of at most [`MAX_LINE_BYTES`].
#[derive(Debug, Default)]
pub struct LineDecoder {
    buf: Vec<u8>,
    overflowed: bool,
}

impl LineDecoder {
    /// Takes received bytes; returns every complete line (or the overflow) in order.
    pub fn push(&mut self, bytes: &[u8]) -> Vec<Decoded> {
        let mut out = Vec::new();
        if self.overflowed {
            return out;
        }
        for &b in bytes {
            if b == b'\n' {
                let line = std::mem::take(&mut self.buf);
                let text = String::from_utf8_lossy(&line);
                out.push(Decoded::Line(text.trim_end_matches('\r').to_string()));
            } else {
                self.buf.push(b);
                if self.buf.len() > MAX_LINE_BYTES {
                    self.overflowed = true;
                    self.buf = Vec::new();
                    out.push(Decoded::TooLong);
                    return out;
                }
            }
        }
        out
    }
}

/// A parsed request.
#[derive(Debug, Clone, PartialEq)]
pub enum Request {
    Scan(ScanRequest),
    Status,
    Abort,
    List,
    Reconstruct { scan: String },
    Subscribe,
}

#[derive(Deserialize)]
#[serde(tag = "cmd", rename_all = "snake_case", deny_unknown_fields)]
enum Wire {
    Scan {
        #[serde(default)]
        token: Option<String>,
        name: Option<String>,
        width_m: Option<f64>,
        height_m: Option<f64>,
        speed_m_per_s: Option<f64>,
        label: Option<String>,
    },
    Status {
        #[serde(default)]
        token: Option<String>,
    },
    Abort {
        #[serde(default)]
        token: Option<String>,
    },
    List {
        #[serde(default)]
        token: Option<String>,
    },
    Reconstruct {
        #[serde(default)]
        token: Option<String>,
        scan: String,
    },
    Subscribe {
        #[serde(default)]
        token: Option<String>,
    },
}

/// Why a line is not a request.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ParseError {
    #[error("not a request: {0}")]
    Malformed(String),
    #[error("this port requires a token; the request's is missing or wrong")]
    Unauthorised,
}

/// Parses one line, checking the token when the port requires one.
pub fn parse_request(line: &str, token: Option<&str>) -> Result<Request, ParseError> {
    let wire: Wire = serde_json::from_str(line).map_err(|e| {
        let text = e.to_string();
        ParseError::Malformed(if text.contains("unknown variant") {
            format!("{text}; commands: scan, status, abort, list, reconstruct, subscribe")
        } else {
            text
        })
    })?;
    let (given, request) = match wire {
        Wire::Scan {
            token,
            name,
            width_m,
            height_m,
            speed_m_per_s,
            label,
        } => (
            token,
            Request::Scan(ScanRequest {
                name,
                width_m,
                height_m,
                speed_m_per_s,
                label,
            }),
        ),
        Wire::Status { token } => (token, Request::Status),
        Wire::Abort { token } => (token, Request::Abort),
        Wire::List { token } => (token, Request::List),
        Wire::Reconstruct { token, scan } => (token, Request::Reconstruct { scan }),
        Wire::Subscribe { token } => (token, Request::Subscribe),
    };
    if let Some(required) = token
        && given.as_deref() != Some(required)
    {
        return Err(ParseError::Unauthorised);
    }
    Ok(request)
}

/// `{"ok": false, "error": message}`.
pub fn error_reply(message: &str) -> String {
    serde_json::json!({"ok": false, "error": message}).to_string()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lines_split_across_reads_and_overflow_once() {
        let mut d = LineDecoder::default();
        assert!(d.push(b"{\"cmd\":").is_empty());
        assert_eq!(
            d.push(b"\"status\"}\r\n{\"cmd\":\"list\"}\n"),
            vec![
                Decoded::Line("{\"cmd\":\"status\"}".into()),
                Decoded::Line("{\"cmd\":\"list\"}".into())
            ]
        );
        let long = vec![b'x'; MAX_LINE_BYTES + 1];
        assert_eq!(d.push(&long), vec![Decoded::TooLong]);
        assert!(
            d.push(b"\n{\"cmd\":\"status\"}\n").is_empty(),
            "no resync after overflow"
        );
        let mut d = LineDecoder::default();
        let exact = [vec![b' '; MAX_LINE_BYTES], b"\n".to_vec()].concat();
        assert_eq!(d.push(&exact).len(), 1, "exactly 64 KiB is accepted");
    }

    #[test]
    fn requests_parse_and_bad_ones_say_why() {
        assert_eq!(
            parse_request(r#"{"cmd":"scan","name":"a","width_m":0.2}"#, None),
            Ok(Request::Scan(ScanRequest {
                name: Some("a".into()),
                width_m: Some(0.2),
                ..ScanRequest::default()
            }))
        );
        assert_eq!(
            parse_request(r#"{"cmd":"reconstruct","scan":"a"}"#, None),
            Ok(Request::Reconstruct { scan: "a".into() })
        );
        let e = parse_request(r#"{"cmd":"fly"}"#, None).unwrap_err();
        assert!(e.to_string().contains("commands: scan, status"), "{e}");
        let e = parse_request("{not json", None).unwrap_err();
        assert!(matches!(e, ParseError::Malformed(_)));
        let e = parse_request(r#"{"cmd":"scan","widht_m":1}"#, None).unwrap_err();
        assert!(e.to_string().contains("widht_m"), "{e}");
        assert_eq!(
            parse_request(r#"{"cmd":"status"}"#, Some("s3cret")),
            Err(ParseError::Unauthorised)
        );
        assert_eq!(
            parse_request(r#"{"cmd":"status","token":"s3cret"}"#, Some("s3cret")),
            Ok(Request::Status)
        );
    }
}
