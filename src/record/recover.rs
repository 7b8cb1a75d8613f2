//! Reading a recording record by record, and salvaging one whose writer died (`kill -9`, a full
//! disk): every whole record and every whole chunk up to the damage is copied into a new,
//! finished file with its summary. What was lost is at most the chunk that was being written.

use std::collections::BTreeMap;
use std::fs::File;
use std::io::{BufWriter, Read};
use std::path::{Path, PathBuf};

use mcap::records::{MessageHeader, Metadata, Record};
use mcap::sans_io::linear_reader::{LinearReadEvent, LinearReader, LinearReaderOptions};
use mcap::{Compression, WriteOptions};

/// Why a recording could not be read or rewritten.
#[derive(Debug, thiserror::Error)]
pub enum ReadError {
    #[error("{path}: {message}")]
    Io { path: PathBuf, message: String },
    #[error("{path}: not an MCAP file (no magic)")]
    NotMcap { path: PathBuf },
}

/// How far a read went.
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize)]
pub struct ReadStop {
    /// Bytes of the file.
    pub file_bytes: u64,
    /// Why reading stopped before the footer, if it did (a truncated or corrupt record).
    pub damage: Option<String>,
}

/// One record in file order, with chunks already opened.
pub enum Item<'a> {
    Schema {
        id: u16,
        name: &'a str,
        encoding: &'a str,
        data: &'a [u8],
    },
    Channel(&'a mcap::records::Channel),
    Message {
        header: &'a MessageHeader,
        data: &'a [u8],
    },
    Metadata(&'a Metadata),
}

/// Calls `on_item` for every schema, channel, message and metadata record of `path` in file
/// order. A damaged tail ends the walk and is reported, not raised.
pub fn for_each_record(
    path: &Path,
    mut on_item: impl FnMut(Item<'_>) -> Result<(), String>,
) -> Result<ReadStop, ReadError> {
    let io = |message: String| ReadError::Io {
        path: path.to_path_buf(),
        message,
    };
    let mut file = File::open(path).map_err(|e| io(e.to_string()))?;
    let file_bytes = file.metadata().map(|m| m.len()).unwrap_or(0);
    let mut magic = [0u8; 8];
    if file.read_exact(&mut magic).is_err() || magic[..] != *mcap::MAGIC {
        return Err(ReadError::NotMcap {
            path: path.to_path_buf(),
        });
    }
    let mut reader = LinearReader::new_with_options(
        LinearReaderOptions::default()
            .with_skip_start_magic(true)
            .with_skip_end_magic(true)
            .with_validate_chunk_crcs(true),
    );
    let mut stop = ReadStop {
        file_bytes,
        damage: None,
    };
    while let Some(event) = reader.next_event() {
        match event {
            Ok(LinearReadEvent::ReadRequest(n)) => {
                let buf = reader.insert(n);
                let read = file.read(buf).map_err(|e| io(e.to_string()))?;
                reader.notify_read(read);
            }
            Ok(LinearReadEvent::Record { data, opcode }) => {
                let record = match mcap::parse_record(opcode, data) {
                    Ok(r) => r,
                    Err(e) => {
                        stop.damage = Some(e.to_string());
                        break;
                    }
                };
                let item = match &record {
                    Record::Schema { header, data } => Item::Schema {
                        id: header.id,
                        name: &header.name,
                        encoding: &header.encoding,
                        data,
                    },
                    Record::Channel(c) => Item::Channel(c),
                    Record::Message { header, data } => Item::Message { header, data },
                    Record::Metadata(m) => Item::Metadata(m),
                    // The footer ends a finished file; the summary repeats what came before.
                    Record::Footer(_) | Record::DataEnd(_) => break,
                    _ => continue,
                };
                on_item(item).map_err(io)?;
            }
            Err(e) => {
                stop.damage = Some(e.to_string());
                break;
            }
        }
    }
    Ok(stop)
}

/// What a recovery did.
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize)]
pub struct RecoverReport {
    pub schemas: u64,
    pub channels: u64,
    pub messages: u64,
    pub metadata: u64,
    /// Log time of the last recovered message, Unix nanoseconds.
    pub last_log_time_ns: Option<u64>,
    pub read: ReadStop,
}

/// Copies every readable record of `damaged` into a new finished file `out`.
///
/// The file is written beside `out` under a temporary name and renamed to `out` only once it is
/// finished: a failure (the damaged file is no MCAP at all, a disk error) leaves nothing at `out`
/// and removes the partial file. An existing `out` is never replaced.
pub fn recover(damaged: &Path, out: &Path) -> Result<RecoverReport, ReadError> {
    let io = |path: &Path, message: String| ReadError::Io {
        path: path.to_path_buf(),
        message,
    };
    if out.exists() {
        return Err(io(out, "exists; refusing to replace it".into()));
    }
    let mut partial = out.as_os_str().to_owned();
    partial.push(".partial.tmp");
    let partial = PathBuf::from(partial);
    // A partial file of an earlier recovery that was killed is this function's own leftover.
    let _ = std::fs::remove_file(&partial);
    match recover_into(damaged, &partial) {
        Ok(report) => {
            std::fs::rename(&partial, out).map_err(|e| {
                let _ = std::fs::remove_file(&partial);
                io(out, e.to_string())
            })?;
            Ok(report)
        }
        Err(e) => {
            let _ = std::fs::remove_file(&partial);
            Err(e)
        }
    }
}

/// [`recover`]'s work, into `out` (created new).
fn recover_into(damaged: &Path, out: &Path) -> Result<RecoverReport, ReadError> {
    let io = |path: &Path, message: String| ReadError::Io {
        path: path.to_path_buf(),
        message,
    };
    let file = File::options()
        .write(true)
        .create_new(true)
        .open(out)
        .map_err(|e| io(out, e.to_string()))?;
    let mut writer = WriteOptions::new()
        .compression(Some(Compression::Zstd))
        .library(concat!("mmnormd ", env!("CARGO_PKG_VERSION"), " recover"))
        .create(BufWriter::new(file))
        .map_err(|e| io(out, e.to_string()))?;
    let mut report = RecoverReport::default();
    let mut known_channels = BTreeMap::new();
    let read = for_each_record(damaged, |item| {
        let r = match item {
            Item::Schema {
                id,
                name,
                encoding,
                data,
            } => {
                report.schemas += 1;
                writer
                    .add_schema_with_id(id, name, encoding, data)
                    .map(|_| ())
            }
            Item::Channel(c) => {
                report.channels += 1;
                known_channels.insert(c.id, ());
                writer
                    .add_channel_with_id(
                        c.id,
                        c.schema_id,
                        &c.topic,
                        &c.message_encoding,
                        &c.metadata,
                    )
                    .map(|_| ())
            }
            Item::Message { header, data } => {
                if !known_channels.contains_key(&header.channel_id) {
                    return Ok(());
                }
                report.messages += 1;
                report.last_log_time_ns = Some(header.log_time);
                writer.write_to_known_channel(header, data)
            }
            Item::Metadata(m) => {
                report.metadata += 1;
                writer.write_metadata(m)
            }
        };
        r.map_err(|e| e.to_string())
    })?;
    report.read = read;
    writer.finish().map_err(|e| io(out, e.to_string()))?;
    Ok(report)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_file_that_is_no_mcap_is_refused_and_leaves_no_output() {
        let dir = tempfile::tempdir().unwrap();
        let bad = dir.path().join("bad.mcap");
        std::fs::write(&bad, b"this is not a recording").unwrap();
        let out = dir.path().join("x.mcap");
        let err = recover(&bad, &out).unwrap_err();
        assert!(matches!(err, ReadError::NotMcap { .. }), "{err}");
        let left: Vec<_> = std::fs::read_dir(dir.path())
            .unwrap()
            .filter_map(Result::ok)
            .map(|e| e.file_name())
            .collect();
        assert_eq!(left, vec![std::ffi::OsString::from("bad.mcap")], "{left:?}");
    }

    #[test]
    fn an_existing_output_is_never_replaced() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("x.mcap");
        std::fs::write(&out, b"keep me").unwrap();
        let err = recover(&dir.path().join("missing.mcap"), &out).unwrap_err();
        assert!(err.to_string().contains("refusing to replace"), "{err}");
        assert_eq!(std::fs::read(&out).unwrap(), b"keep me");
    }
}
