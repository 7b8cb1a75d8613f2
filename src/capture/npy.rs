//! A minimal NumPy `.npy` codec (format versions 1.0, 2.0 and 3.0).
//!
//! Layout (numpy `lib/format.py`):
//!
//! | offset | size | meaning |
//! |---|---|---|
//! | 0 | 6 | magic `\x93NUMPY` |
//! | 6 | 1 | major version (1, 2 or 3) |
//! | 7 | 1 | minor version (0) |
//! | 8 | 2 (v1) or 4 (v2, v3) | header length, little-endian |
//! | 10 or 12 | header length | Python dict literal: `descr`, `fortran_order`, `shape`, space-padded, `\n`-terminated |
//! | after | rest | the array data |
//!
//! The writer reproduces numpy's own header byte for byte (version 1.0, padded so the data starts
//! on a 64-byte boundary), so files written by numpy round-trip bit-exactly through mmnormd.

use num_complex::Complex32;

const MAGIC: &[u8; 6] = b"\x93NUMPY";
const ALIGN: usize = 64;

/// Why a `.npy` payload was refused.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum NpyError {
    #[error("not a .npy file (bad magic)")]
    BadMagic,
    #[error("unsupported .npy format version {major}.{minor}")]
    UnsupportedVersion { major: u8, minor: u8 },
    #[error("truncated .npy: {what}")]
    Truncated { what: String },
    #[error("malformed .npy header: {0}")]
    BadHeader(String),
    #[error("dtype '{found}' but expected '{expected}' ({meaning})")]
    WrongDtype {
        found: String,
        expected: &'static str,
        meaning: &'static str,
    },
    #[error("shape {found:?} but expected {expected}")]
    WrongShape { found: Vec<usize>, expected: String },
    #[error(
        "Fortran-ordered arrays are not accepted; save a C-ordered array (np.ascontiguousarray)"
    )]
    FortranOrder,
    #[error("{actual} data bytes but the header's shape needs {expected}")]
    DataLength { expected: usize, actual: usize },
}

/// A parsed `.npy` file: header fields and the raw data bytes.
#[derive(Debug, Clone, PartialEq)]
pub struct NpyArray<'a> {
    pub descr: String,
    pub fortran_order: bool,
    pub shape: Vec<usize>,
    pub data: &'a [u8],
}

/// Parses the header of `bytes` and returns the array view.
pub fn parse(bytes: &[u8]) -> Result<NpyArray<'_>, NpyError> {
    if bytes.len() < 10 {
        return Err(if bytes.starts_with(&MAGIC[..bytes.len().min(6)]) {
            NpyError::Truncated {
                what: format!("{} bytes, shorter than the preamble", bytes.len()),
            }
        } else {
            NpyError::BadMagic
        });
    }
    if &bytes[..6] != MAGIC {
        return Err(NpyError::BadMagic);
    }
    let (major, minor) = (bytes[6], bytes[7]);
    let (header_len, start) = match (major, minor) {
        (1, 0) => (u16::from_le_bytes([bytes[8], bytes[9]]) as usize, 10),
        (2, 0) | (3, 0) => {
            let Some(len) = bytes.get(8..12) else {
                return Err(NpyError::Truncated {
                    what: "header length".into(),
                });
            };
            (
                u32::from_le_bytes([len[0], len[1], len[2], len[3]]) as usize,
                12,
            )
        }
        _ => return Err(NpyError::UnsupportedVersion { major, minor }),
    };
    let Some(header_bytes) = bytes.get(start..start + header_len) else {
        return Err(NpyError::Truncated {
            what: format!(
                "header says {header_len} bytes, file has {}",
                bytes.len() - start
            ),
        });
    };
    let header = std::str::from_utf8(header_bytes)
        .map_err(|_| NpyError::BadHeader("header is not text".into()))?;
    let (descr, fortran_order, shape) = parse_header_dict(header)?;
    Ok(NpyArray {
        descr,
        fortran_order,
        shape,
        data: &bytes[start + header_len..],
    })
}

/// Builds numpy's version-1.0 header for a C-ordered array.
pub fn header(descr: &str, shape: &[usize]) -> Vec<u8> {
    let shape_text = match shape {
        [one] => format!("({one},)"),
        _ => format!(
            "({})",
            shape
                .iter()
                .map(|d| d.to_string())
                .collect::<Vec<_>>()
                .join(", ")
        ),
    };
    let mut dict =
        format!("{{'descr': '{descr}', 'fortran_order': False, 'shape': {shape_text}, }}");
    let unpadded = MAGIC.len() + 2 + 2 + dict.len() + 1;
    let pad = (ALIGN - unpadded % ALIGN) % ALIGN;
    dict.extend(std::iter::repeat_n(' ', pad));
    dict.push('\n');
    let mut out = Vec::with_capacity(10 + dict.len());
    out.extend_from_slice(MAGIC);
    out.extend_from_slice(&[1, 0]);
    out.extend_from_slice(&(dict.len() as u16).to_le_bytes());
    out.extend_from_slice(dict.as_bytes());
    out
}

/// Encodes an (N,3) float64 array.
pub fn encode_f64_rows(rows: &[[f64; 3]]) -> Vec<u8> {
    let mut out = header("<f8", &[rows.len(), 3]);
    out.reserve(rows.len() * 24);
    for v in rows.iter().flatten() {
        out.extend_from_slice(&v.to_le_bytes());
    }
    out
}

/// Encodes an (N,T) complex64 array.
pub fn encode_c64(samples: &[Complex32], rows: usize, cols: usize) -> Vec<u8> {
    let mut out = header("<c8", &[rows, cols]);
    out.reserve(samples.len() * 8);
    for s in samples {
        out.extend_from_slice(&s.re.to_le_bytes());
        out.extend_from_slice(&s.im.to_le_bytes());
    }
    out
}

/// Decodes an (N,3) float64 array.
pub fn decode_f64_rows(bytes: &[u8]) -> Result<Vec<[f64; 3]>, NpyError> {
    let a = parse(bytes)?;
    a.expect_dtype("<f8", "float64, little-endian")?;
    let n = match a.shape.as_slice() {
        [n, 3] => *n,
        _ => {
            return Err(NpyError::WrongShape {
                found: a.shape.clone(),
                expected: "(N, 3)".into(),
            });
        }
    };
    a.expect_len(n.checked_mul(24))?;
    Ok(a.data
        .chunks_exact(24)
        .map(|row| {
            let f = |i: usize| {
                let mut b = [0u8; 8];
                b.copy_from_slice(&row[i * 8..i * 8 + 8]);
                f64::from_le_bytes(b)
            };
            [f(0), f(1), f(2)]
        })
        .collect())
}

/// Decodes an (N,T) complex64 array; returns the samples and (N, T).
pub fn decode_c64(bytes: &[u8]) -> Result<(Vec<Complex32>, usize, usize), NpyError> {
    let a = parse(bytes)?;
    a.expect_dtype("<c8", "complex64, little-endian")?;
    let (n, t) = match a.shape.as_slice() {
        [n, t] => (*n, *t),
        _ => {
            return Err(NpyError::WrongShape {
                found: a.shape.clone(),
                expected: "(N, T)".into(),
            });
        }
    };
    a.expect_len(n.checked_mul(t).and_then(|x| x.checked_mul(8)))?;
    let samples = a
        .data
        .chunks_exact(8)
        .map(|c| {
            Complex32::new(
                f32::from_le_bytes([c[0], c[1], c[2], c[3]]),
                f32::from_le_bytes([c[4], c[5], c[6], c[7]]),
            )
        })
        .collect();
    Ok((samples, n, t))
}

impl NpyArray<'_> {
    fn expect_dtype(&self, expected: &'static str, meaning: &'static str) -> Result<(), NpyError> {
        if self.descr != expected {
            return Err(NpyError::WrongDtype {
                found: self.descr.clone(),
                expected,
                meaning,
            });
        }
        if self.fortran_order {
            return Err(NpyError::FortranOrder);
        }
        Ok(())
    }

    /// `expected` is `None` when the header's shape overflows.
    fn expect_len(&self, expected: Option<usize>) -> Result<(), NpyError> {
        let expected =
            expected.ok_or_else(|| NpyError::BadHeader("the shape is too large".into()))?;
        if self.data.len() != expected {
            return Err(NpyError::DataLength {
                expected,
                actual: self.data.len(),
            });
        }
        Ok(())
    }
}

/// Parses `{'descr': '<f8', 'fortran_order': False, 'shape': (3, 3), }`.
fn parse_header_dict(text: &str) -> Result<(String, bool, Vec<usize>), NpyError> {
    let bad = |m: &str| NpyError::BadHeader(format!("{m} in {:?}", text.trim_end()));
    let body = text
        .trim()
        .strip_prefix('{')
        .and_then(|t| t.strip_suffix('}'))
        .ok_or_else(|| bad("not a dict"))?;
    let mut descr = None;
    let mut fortran = None;
    let mut shape = None;
    let mut rest = body.trim_start();
    while !rest.is_empty() {
        let (key, after_key) = take_string(rest).ok_or_else(|| bad("expected a quoted key"))?;
        let after_colon = after_key
            .trim_start()
            .strip_prefix(':')
            .ok_or_else(|| bad("expected ':'"))?
            .trim_start();
        let after_value = match key.as_str() {
            "descr" => {
                let (v, r) =
                    take_string(after_colon).ok_or_else(|| bad("descr is not a string"))?;
                descr = Some(v);
                r
            }
            "fortran_order" => {
                if let Some(r) = after_colon.strip_prefix("True") {
                    fortran = Some(true);
                    r
                } else if let Some(r) = after_colon.strip_prefix("False") {
                    fortran = Some(false);
                    r
                } else {
                    return Err(bad("fortran_order is not True/False"));
                }
            }
            "shape" => {
                let inner_start = after_colon
                    .strip_prefix('(')
                    .ok_or_else(|| bad("shape is not a tuple"))?;
                let close = inner_start.find(')').ok_or_else(|| bad("unclosed shape"))?;
                let dims = inner_start[..close]
                    .split(',')
                    .map(str::trim)
                    .filter(|s| !s.is_empty())
                    .map(|s| s.trim_end_matches('L').parse::<usize>())
                    .collect::<Result<Vec<_>, _>>()
                    .map_err(|_| bad("shape has a non-integer dimension"))?;
                shape = Some(dims);
                &inner_start[close + 1..]
            }
            other => return Err(bad(&format!("unknown key '{other}'"))),
        };
        rest = after_value.trim_start();
        rest = rest.strip_prefix(',').unwrap_or(rest).trim_start();
    }
    match (descr, fortran, shape) {
        (Some(d), Some(f), Some(s)) => Ok((d, f, s)),
        _ => Err(bad("missing descr, fortran_order or shape")),
    }
}

fn take_string(s: &str) -> Option<(String, &str)> {
    let quote = s.chars().next().filter(|c| *c == '\'' || *c == '"')?;
    let body = &s[1..];
    let end = body.find(quote)?;
    Some((body[..end].to_string(), &body[end + 1..]))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn header_matches_numpy_layout() {
        let h = header("<f8", &[3, 3]);
        assert_eq!(h.len() % 64, 0);
        let text = std::str::from_utf8(&h[10..]).unwrap();
        assert!(text.starts_with("{'descr': '<f8', 'fortran_order': False, 'shape': (3, 3), }"));
        assert!(text.ends_with(" \n"));
        let one_d = header("<c8", &[5]);
        assert!(
            std::str::from_utf8(&one_d[10..])
                .unwrap()
                .contains("'shape': (5,), }")
        );
    }

    /// Bytes that numpy 1.26 wrote for `np.save(f, np.arange(6, dtype='<f8').reshape(2, 3))`.
    #[test]
    fn reads_a_numpy_written_file_and_writes_it_back_identically() {
        let mut file = b"\x93NUMPY\x01\x00v\x00".to_vec();
        let mut dict = "{'descr': '<f8', 'fortran_order': False, 'shape': (2, 3), }".to_string();
        while !(10 + dict.len() + 1).is_multiple_of(64) {
            dict.push(' ');
        }
        dict.push('\n');
        assert_eq!(dict.len(), 0x76);
        file.extend_from_slice(dict.as_bytes());
        for v in 0..6 {
            file.extend_from_slice(&(v as f64).to_le_bytes());
        }
        let rows = decode_f64_rows(&file).unwrap();
        assert_eq!(rows, vec![[0.0, 1.0, 2.0], [3.0, 4.0, 5.0]]);
        assert_eq!(encode_f64_rows(&rows), file);
    }

    #[test]
    fn refuses_wrong_dtype_shape_order_and_truncation() {
        let mut f4 = header("<f4", &[2, 3]);
        f4.extend_from_slice(&[0u8; 24]);
        assert!(matches!(
            decode_f64_rows(&f4),
            Err(NpyError::WrongDtype { .. })
        ));
        let mut shape = header("<f8", &[2, 2]);
        shape.extend_from_slice(&[0u8; 32]);
        assert!(matches!(
            decode_f64_rows(&shape),
            Err(NpyError::WrongShape { .. })
        ));
        let mut fortran = header("<f8", &[1, 3]);
        let at = fortran.windows(5).position(|w| w == b"False").unwrap();
        fortran[at..at + 5].copy_from_slice(b"True ");
        fortran.extend_from_slice(&[0u8; 24]);
        assert_eq!(decode_f64_rows(&fortran), Err(NpyError::FortranOrder));
        let full = encode_c64(&[Complex32::new(1.0, 2.0); 6], 2, 3);
        let cut = &full[..full.len() - 5];
        assert!(matches!(
            decode_c64(cut),
            Err(NpyError::DataLength {
                expected: 48,
                actual: 43
            })
        ));
        assert!(matches!(
            parse(&full[..20]),
            Err(NpyError::Truncated { .. })
        ));
        assert_eq!(
            parse(b"PK\x03\x04 not numpy at all"),
            Err(NpyError::BadMagic)
        );
    }

    #[test]
    fn overflowing_shapes_are_refused() {
        let mut b = header("<c8", &[usize::MAX / 4, 16]);
        b.extend_from_slice(&[0u8; 8]);
        assert!(matches!(decode_c64(&b), Err(NpyError::BadHeader(_))));
    }

    #[test]
    fn version_two_headers_are_read() {
        let v1 = encode_c64(&[Complex32::new(0.5, -0.25)], 1, 1);
        let header_len = u16::from_le_bytes([v1[8], v1[9]]) as usize;
        let mut v2 = b"\x93NUMPY\x02\x00".to_vec();
        v2.extend_from_slice(&(header_len as u32).to_le_bytes());
        v2.extend_from_slice(&v1[10..]);
        let (s, n, t) = decode_c64(&v2).unwrap();
        assert_eq!((n, t), (1, 1));
        assert_eq!(s[0], Complex32::new(0.5, -0.25));
    }
}
