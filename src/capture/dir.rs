//! Capture directory v1: `capture.json`, `tx.npy`, `rx.npy`, `samples.npy`, optional truth.
//!
//! | file | content |
//! |---|---|
//! | `capture.json` | `{"format": "mmnorm-capture", "version": 1, "start_frequency_hz", "frequency_step_hz", "samples_per_chirp", "range_offset_m", "antennas", "description"}`; other keys are kept |
//! | `tx.npy` | float64 (N,3), TX phase centres, metres |
//! | `rx.npy` | float64 (N,3), RX positions, metres |
//! | `samples.npy` | complex64 (N,T), C order |
//! | `truth.stl` / `truth.ply` | optional ground-truth mesh, same frame |
//! | `truth_top.npy` | optional float64 (M,3), the surface seen from above |
//!
//! Writing puts every file in place through a temporary name and a rename, and writes
//! `capture.json` last: a directory without `capture.json` is never a capture.

use std::io::Write;
use std::path::{Path, PathBuf};

use serde_json::{Map, Value};

use super::npy::{self, NpyError};
use super::{Capture, FrequencyPlan};

pub const FORMAT_NAME: &str = "mmnorm-capture";
pub const FORMAT_VERSION: u64 = 1;

/// Why a capture directory could not be read or written. Each variant names the file.
#[derive(Debug, thiserror::Error)]
pub enum CaptureDirError {
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{path}: {source}")]
    Npy {
        path: PathBuf,
        #[source]
        source: NpyError,
    },
    #[error("{path}: {reason}")]
    Invalid { path: PathBuf, reason: String },
}

/// Ground-truth files present in a capture directory.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct TruthFiles {
    pub mesh: Option<PathBuf>,
    pub top_points: Option<PathBuf>,
}

fn io_err(path: &Path) -> impl FnOnce(std::io::Error) -> CaptureDirError + '_ {
    move |source| CaptureDirError::Io {
        path: path.to_path_buf(),
        source,
    }
}

fn invalid(path: &Path, reason: impl Into<String>) -> CaptureDirError {
    CaptureDirError::Invalid {
        path: path.to_path_buf(),
        reason: reason.into(),
    }
}

/// Reads and validates a capture directory. Nothing partial is ever returned.
pub fn read_capture_dir(dir: &Path) -> Result<Capture, CaptureDirError> {
    if !dir.is_dir() {
        return Err(invalid(
            dir,
            "not a directory (expected a capture directory v1)",
        ));
    }
    let json_path = dir.join("capture.json");
    let text = std::fs::read_to_string(&json_path).map_err(io_err(&json_path))?;
    let mut map: Map<String, Value> = serde_json::from_str(&text)
        .map_err(|e| invalid(&json_path, format!("not a JSON object: {e}")))?;
    let meta = Meta::take(&mut map, &json_path)?;

    let read = |name: &str| -> Result<(PathBuf, Vec<u8>), CaptureDirError> {
        let path = dir.join(name);
        let bytes = std::fs::read(&path).map_err(io_err(&path))?;
        Ok((path, bytes))
    };
    let (tx_path, tx_bytes) = read("tx.npy")?;
    let tx_m = npy::decode_f64_rows(&tx_bytes).map_err(|source| CaptureDirError::Npy {
        path: tx_path.clone(),
        source,
    })?;
    let (rx_path, rx_bytes) = read("rx.npy")?;
    let rx_m = npy::decode_f64_rows(&rx_bytes).map_err(|source| CaptureDirError::Npy {
        path: rx_path.clone(),
        source,
    })?;
    let (s_path, s_bytes) = read("samples.npy")?;
    let (samples, n, t) = npy::decode_c64(&s_bytes).map_err(|source| CaptureDirError::Npy {
        path: s_path.clone(),
        source,
    })?;

    for (path, count) in [(&tx_path, tx_m.len()), (&rx_path, rx_m.len()), (&s_path, n)] {
        if count as u64 != meta.antennas {
            return Err(invalid(
                path,
                format!(
                    "holds {count} antennas but capture.json says antennas = {}",
                    meta.antennas
                ),
            ));
        }
    }
    if t as u64 != meta.samples_per_chirp {
        return Err(invalid(
            &s_path,
            format!(
                "holds {t} samples per chirp but capture.json says samples_per_chirp = {}",
                meta.samples_per_chirp
            ),
        ));
    }
    for (path, rows) in [(&tx_path, &tx_m), (&rx_path, &rx_m)] {
        if let Some(i) = rows.iter().position(|p| p.iter().any(|v| !v.is_finite())) {
            return Err(invalid(
                path,
                format!("row {i} is not finite: {:?}", rows[i]),
            ));
        }
    }
    if let Some(k) = samples
        .iter()
        .position(|s| !(s.re.is_finite() && s.im.is_finite()))
    {
        return Err(invalid(
            &s_path,
            format!("sample [{}, {}] is not finite", k / t.max(1), k % t.max(1)),
        ));
    }
    let capture = Capture {
        plan: FrequencyPlan {
            start_frequency_hz: meta.start_frequency_hz,
            frequency_step_hz: meta.frequency_step_hz,
            samples_per_chirp: t,
        },
        range_offset_m: meta.range_offset_m,
        tx_m,
        rx_m,
        samples: samples.into(),
        description: meta.description,
        extra: map,
    };
    capture.validate().map_err(|e| invalid(&json_path, e.0))?;
    Ok(capture)
}

/// Writes a capture directory, creating `dir` if needed. Files go through a temporary name and a
/// rename; `capture.json` is written last.
pub fn write_capture_dir(dir: &Path, capture: &Capture) -> Result<(), CaptureDirError> {
    capture.validate().map_err(|e| invalid(dir, e.0))?;
    std::fs::create_dir_all(dir).map_err(io_err(dir))?;
    let n = capture.antennas();
    let t = capture.plan.samples_per_chirp;
    write_atomically(&dir.join("tx.npy"), &npy::encode_f64_rows(&capture.tx_m))?;
    write_atomically(&dir.join("rx.npy"), &npy::encode_f64_rows(&capture.rx_m))?;
    write_atomically(
        &dir.join("samples.npy"),
        &npy::encode_c64(&capture.samples, n, t),
    )?;
    let mut map = Map::new();
    map.insert("format".into(), FORMAT_NAME.into());
    map.insert("version".into(), FORMAT_VERSION.into());
    map.insert(
        "start_frequency_hz".into(),
        capture.plan.start_frequency_hz.into(),
    );
    map.insert(
        "frequency_step_hz".into(),
        capture.plan.frequency_step_hz.into(),
    );
    map.insert("samples_per_chirp".into(), (t as u64).into());
    map.insert("range_offset_m".into(), capture.range_offset_m.into());
    map.insert("antennas".into(), (n as u64).into());
    map.insert("description".into(), capture.description.clone().into());
    for (k, v) in &capture.extra {
        map.insert(k.clone(), v.clone());
    }
    let json_path = dir.join("capture.json");
    let mut text = serde_json::to_string_pretty(&Value::Object(map))
        .map_err(|e| invalid(&json_path, e.to_string()))?;
    text.push('\n');
    write_atomically(&json_path, text.as_bytes())
}

/// Writes `bytes` to `path` through `path.tmp` and a rename, syncing before the rename.
pub fn write_atomically(path: &Path, bytes: &[u8]) -> Result<(), CaptureDirError> {
    let mut tmp = path.as_os_str().to_owned();
    tmp.push(".tmp");
    let tmp = PathBuf::from(tmp);
    let mut file = std::fs::File::create(&tmp).map_err(io_err(&tmp))?;
    file.write_all(bytes).map_err(io_err(&tmp))?;
    file.sync_all().map_err(io_err(&tmp))?;
    drop(file);
    std::fs::rename(&tmp, path).map_err(io_err(path))
}

/// Lists the ground-truth files of a capture directory.
pub fn truth_files(dir: &Path) -> TruthFiles {
    let mesh = ["truth.ply", "truth.stl"]
        .iter()
        .map(|n| dir.join(n))
        .find(|p| p.is_file());
    let top = dir.join("truth_top.npy");
    TruthFiles {
        mesh,
        top_points: top.is_file().then_some(top),
    }
}

/// Reads `truth_top.npy`: float64 (M,3).
pub fn read_points_npy(path: &Path) -> Result<Vec<[f64; 3]>, CaptureDirError> {
    let bytes = std::fs::read(path).map_err(io_err(path))?;
    npy::decode_f64_rows(&bytes).map_err(|source| CaptureDirError::Npy {
        path: path.to_path_buf(),
        source,
    })
}

/// The interpreted keys of `capture.json`.
struct Meta {
    start_frequency_hz: f64,
    frequency_step_hz: f64,
    samples_per_chirp: u64,
    range_offset_m: f64,
    antennas: u64,
    description: String,
}

impl Meta {
    /// Removes the known keys from `map`, checking each; what stays in `map` is kept as extra.
    fn take(map: &mut Map<String, Value>, path: &Path) -> Result<Self, CaptureDirError> {
        let mut take = |key: &str| {
            map.shift_remove(key)
                .ok_or_else(|| invalid(path, format!("missing key `{key}`")))
        };
        let format = take("format")?;
        if format.as_str() != Some(FORMAT_NAME) {
            return Err(invalid(
                path,
                format!("`format` is {format}, expected \"{FORMAT_NAME}\""),
            ));
        }
        let version = take("version")?;
        if version.as_u64() != Some(FORMAT_VERSION) {
            return Err(invalid(
                path,
                format!("`version` is {version}; this mmnormd reads version {FORMAT_VERSION}"),
            ));
        }
        let float = |key: &str, v: Value| {
            v.as_f64()
                .filter(|f| f.is_finite())
                .ok_or_else(|| invalid(path, format!("`{key}` must be a finite number, found {v}")))
        };
        let count = |key: &str, v: Value| {
            v.as_u64().filter(|c| *c > 0).ok_or_else(|| {
                invalid(
                    path,
                    format!("`{key}` must be a positive integer, found {v}"),
                )
            })
        };
        let start_frequency_hz = float("start_frequency_hz", take("start_frequency_hz")?)?;
        let frequency_step_hz = float("frequency_step_hz", take("frequency_step_hz")?)?;
        let samples_per_chirp = count("samples_per_chirp", take("samples_per_chirp")?)?;
        let range_offset_m = float("range_offset_m", take("range_offset_m")?)?;
        let antennas = count("antennas", take("antennas")?)?;
        let description = match take("description")? {
            Value::String(s) => s,
            other => {
                return Err(invalid(
                    path,
                    format!("`description` must be a string, found {other}"),
                ));
            }
        };
        Ok(Self {
            start_frequency_hz,
            frequency_step_hz,
            samples_per_chirp,
            range_offset_m,
            antennas,
            description,
        })
    }
}
