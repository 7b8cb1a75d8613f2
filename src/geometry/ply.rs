//! PLY (Stanford polygon format): a reader for meshes and point clouds, and a binary
//! little-endian writer.
//!
//! The reader accepts `ascii`, `binary_little_endian` and `binary_big_endian`, any scalar
//! property types (`char`…`double` and their `int8`…`float64` aliases) and list properties. It
//! extracts `vertex` x/y/z (and nx/ny/nz when present) and `face` `vertex_indices` (or
//! `vertex_index`); polygons are fanned into triangles. Other elements and properties are read
//! past and ignored.

use std::io::Write;

/// What a PLY file holds that mmnormd uses.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct PlyData {
    pub vertices_m: Vec<[f64; 3]>,
    pub normals: Option<Vec<[f64; 3]>>,
    pub triangles: Vec<[u32; 3]>,
    /// Every scalar vertex property by name, in file order (for extra columns such as
    /// `component`).
    pub vertex_properties: Vec<(String, Vec<f64>)>,
}

#[derive(Debug, Clone, Copy, PartialEq)]
enum Scalar {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
}

impl Scalar {
    fn parse(name: &str) -> Option<Self> {
        Some(match name {
            "char" | "int8" => Self::I8,
            "uchar" | "uint8" => Self::U8,
            "short" | "int16" => Self::I16,
            "ushort" | "uint16" => Self::U16,
            "int" | "int32" => Self::I32,
            "uint" | "uint32" => Self::U32,
            "float" | "float32" => Self::F32,
            "double" | "float64" => Self::F64,
            _ => return None,
        })
    }

    fn size(self) -> usize {
        match self {
            Self::I8 | Self::U8 => 1,
            Self::I16 | Self::U16 => 2,
            Self::I32 | Self::U32 | Self::F32 => 4,
            Self::F64 => 8,
        }
    }
}

#[derive(Debug, Clone)]
enum Property {
    Scalar(String, Scalar),
    List(String, Scalar, Scalar),
}

#[derive(Debug, Clone)]
struct Element {
    name: String,
    count: usize,
    properties: Vec<Property>,
}

#[derive(Debug, Clone, Copy, PartialEq)]
enum Encoding {
    Ascii,
    Little,
    Big,
}

/// Parses a whole PLY file. The error says what is wrong and where.
pub fn parse(bytes: &[u8]) -> Result<PlyData, String> {
    let (encoding, elements, body_start) = parse_header(bytes)?;
    let mut reader: Box<dyn ValueReader + '_> = match encoding {
        Encoding::Ascii => {
            let text = std::str::from_utf8(&bytes[body_start..])
                .map_err(|_| "ASCII body is not text".to_string())?;
            Box::new(AsciiReader {
                words: text.split_ascii_whitespace(),
            })
        }
        Encoding::Little | Encoding::Big => Box::new(BinaryReader {
            bytes: &bytes[body_start..],
            pos: 0,
            big_endian: encoding == Encoding::Big,
        }),
    };
    let mut out = PlyData::default();
    for element in &elements {
        match element.name.as_str() {
            "vertex" => read_vertices(element, reader.as_mut(), &mut out)?,
            "face" => read_faces(element, reader.as_mut(), &mut out)?,
            _ => {
                for _ in 0..element.count {
                    for p in &element.properties {
                        skip_property(p, reader.as_mut())?;
                    }
                }
            }
        }
    }
    let n = out.vertices_m.len() as u32;
    if let Some(t) = out.triangles.iter().find(|t| t.iter().any(|&k| k >= n)) {
        return Err(format!(
            "face {t:?} refers to a vertex beyond the {n} vertices"
        ));
    }
    Ok(out)
}

fn parse_header(bytes: &[u8]) -> Result<(Encoding, Vec<Element>, usize), String> {
    let end_marker = b"end_header";
    let pos = bytes
        .windows(end_marker.len())
        .position(|w| w == end_marker)
        .ok_or("no `end_header` line: not a PLY file or truncated header")?;
    let mut body_start = pos + end_marker.len();
    if bytes.get(body_start) == Some(&b'\r') {
        body_start += 1;
    }
    if bytes.get(body_start) == Some(&b'\n') {
        body_start += 1;
    }
    let header = std::str::from_utf8(&bytes[..pos]).map_err(|_| "header is not text")?;
    let mut lines = header.lines().map(str::trim);
    if lines.next() != Some("ply") {
        return Err("the file does not start with `ply`".into());
    }
    let mut encoding = None;
    let mut elements: Vec<Element> = Vec::new();
    for line in lines {
        let words: Vec<&str> = line.split_whitespace().collect();
        match words.as_slice() {
            [] | ["comment", ..] | ["obj_info", ..] => {}
            ["format", kind, _version] => {
                encoding = Some(match *kind {
                    "ascii" => Encoding::Ascii,
                    "binary_little_endian" => Encoding::Little,
                    "binary_big_endian" => Encoding::Big,
                    other => return Err(format!("unknown format `{other}`")),
                });
            }
            ["element", name, count] => elements.push(Element {
                name: name.to_string(),
                count: count
                    .parse()
                    .map_err(|_| format!("element `{name}` has a bad count `{count}`"))?,
                properties: Vec::new(),
            }),
            ["property", "list", count_ty, item_ty, name] => {
                let element = elements
                    .last_mut()
                    .ok_or("a property comes before any element")?;
                let c = Scalar::parse(count_ty).ok_or(format!("unknown type `{count_ty}`"))?;
                let i = Scalar::parse(item_ty).ok_or(format!("unknown type `{item_ty}`"))?;
                element
                    .properties
                    .push(Property::List(name.to_string(), c, i));
            }
            ["property", ty, name] => {
                let element = elements
                    .last_mut()
                    .ok_or("a property comes before any element")?;
                let s = Scalar::parse(ty).ok_or(format!("unknown type `{ty}`"))?;
                element
                    .properties
                    .push(Property::Scalar(name.to_string(), s));
            }
            _ => return Err(format!("unrecognised header line `{line}`")),
        }
    }
    Ok((encoding.ok_or("no `format` line")?, elements, body_start))
}

trait ValueReader {
    fn next(&mut self, ty: Scalar) -> Result<f64, String>;
}

struct AsciiReader<'a> {
    words: std::str::SplitAsciiWhitespace<'a>,
}

impl ValueReader for AsciiReader<'_> {
    fn next(&mut self, _ty: Scalar) -> Result<f64, String> {
        let w = self
            .words
            .next()
            .ok_or("the body ends early (truncated file)")?;
        w.parse::<f64>()
            .map_err(|_| format!("`{w}` is not a number"))
    }
}

struct BinaryReader<'a> {
    bytes: &'a [u8],
    pos: usize,
    big_endian: bool,
}

impl ValueReader for BinaryReader<'_> {
    fn next(&mut self, ty: Scalar) -> Result<f64, String> {
        let size = ty.size();
        let raw = self
            .bytes
            .get(self.pos..self.pos + size)
            .ok_or("the body ends early (truncated file)")?;
        self.pos += size;
        let mut b = [0u8; 8];
        b[..size].copy_from_slice(raw);
        if self.big_endian {
            b[..size].reverse();
        }
        Ok(match ty {
            Scalar::I8 => f64::from(b[0] as i8),
            Scalar::U8 => f64::from(b[0]),
            Scalar::I16 => f64::from(i16::from_le_bytes([b[0], b[1]])),
            Scalar::U16 => f64::from(u16::from_le_bytes([b[0], b[1]])),
            Scalar::I32 => f64::from(i32::from_le_bytes([b[0], b[1], b[2], b[3]])),
            Scalar::U32 => f64::from(u32::from_le_bytes([b[0], b[1], b[2], b[3]])),
            Scalar::F32 => f64::from(f32::from_le_bytes([b[0], b[1], b[2], b[3]])),
            Scalar::F64 => f64::from_le_bytes(b),
        })
    }
}

fn skip_property(p: &Property, r: &mut dyn ValueReader) -> Result<(), String> {
    match p {
        Property::Scalar(_, ty) => {
            r.next(*ty)?;
        }
        Property::List(_, count_ty, item_ty) => {
            let n = r.next(*count_ty)?;
            for _ in 0..list_len(n)? {
                r.next(*item_ty)?;
            }
        }
    }
    Ok(())
}

fn list_len(n: f64) -> Result<usize, String> {
    if n >= 0.0 && n.fract() == 0.0 && n < 1e6 {
        Ok(n as usize)
    } else {
        Err(format!("bad list length {n}"))
    }
}

fn read_vertices(e: &Element, r: &mut dyn ValueReader, out: &mut PlyData) -> Result<(), String> {
    let mut columns: Vec<(String, Vec<f64>)> = Vec::new();
    // The count comes from the file: do not trust it for allocation.
    let capacity = e.count.min(1 << 20);
    for p in &e.properties {
        if let Property::Scalar(name, _) = p {
            columns.push((name.clone(), Vec::with_capacity(capacity)));
        }
    }
    for _ in 0..e.count {
        let mut col = 0;
        for p in &e.properties {
            match p {
                Property::Scalar(_, ty) => {
                    let v = r.next(*ty)?;
                    columns[col].1.push(v);
                    col += 1;
                }
                list => skip_property(list, r)?,
            }
        }
    }
    let find = |n: &str| columns.iter().position(|(name, _)| name == n);
    let (Some(x), Some(y), Some(z)) = (find("x"), find("y"), find("z")) else {
        return Err("the vertex element lacks x, y or z".into());
    };
    out.vertices_m = (0..e.count)
        .map(|i| [columns[x].1[i], columns[y].1[i], columns[z].1[i]])
        .collect();
    if let (Some(nx), Some(ny), Some(nz)) = (find("nx"), find("ny"), find("nz")) {
        out.normals = Some(
            (0..e.count)
                .map(|i| [columns[nx].1[i], columns[ny].1[i], columns[nz].1[i]])
                .collect(),
        );
    }
    out.vertex_properties = columns;
    Ok(())
}

fn read_faces(e: &Element, r: &mut dyn ValueReader, out: &mut PlyData) -> Result<(), String> {
    for _ in 0..e.count {
        for p in &e.properties {
            match p {
                Property::List(name, count_ty, item_ty)
                    if name == "vertex_indices" || name == "vertex_index" =>
                {
                    let n = list_len(r.next(*count_ty)?)?;
                    let mut poly = Vec::with_capacity(n.min(64));
                    for _ in 0..n {
                        let v = r.next(*item_ty)?;
                        if v < 0.0 || v.fract() != 0.0 || v > u32::MAX as f64 {
                            return Err(format!("bad vertex index {v}"));
                        }
                        poly.push(v as u32);
                    }
                    for k in 1..n.saturating_sub(1) {
                        out.triangles.push([poly[0], poly[k], poly[k + 1]]);
                    }
                }
                other => skip_property(other, r)?,
            }
        }
    }
    Ok(())
}

/// A vertex column to write: name and values (one per vertex), stored as the given PLY type.
pub enum Column<'a> {
    F64(&'a str, Vec<f64>),
    F32(&'a str, Vec<f32>),
    I32(&'a str, Vec<i32>),
}

impl Column<'_> {
    fn header(&self) -> String {
        match self {
            Column::F64(n, _) => format!("property double {n}"),
            Column::F32(n, _) => format!("property float {n}"),
            Column::I32(n, _) => format!("property int {n}"),
        }
    }

    fn len(&self) -> usize {
        match self {
            Column::F64(_, v) => v.len(),
            Column::F32(_, v) => v.len(),
            Column::I32(_, v) => v.len(),
        }
    }

    fn write(&self, i: usize, out: &mut Vec<u8>) {
        match self {
            Column::F64(_, v) => out.extend_from_slice(&v[i].to_le_bytes()),
            Column::F32(_, v) => out.extend_from_slice(&v[i].to_le_bytes()),
            Column::I32(_, v) => out.extend_from_slice(&v[i].to_le_bytes()),
        }
    }
}

/// Encodes a binary little-endian PLY with the given vertex columns and triangles.
/// Panics if the columns differ in length (a programming error, not an input error).
pub fn encode(columns: &[Column<'_>], triangles: &[[u32; 3]]) -> Vec<u8> {
    let n = columns.first().map_or(0, Column::len);
    assert!(
        columns.iter().all(|c| c.len() == n),
        "PLY columns differ in length"
    );
    let mut out = Vec::new();
    let mut header = format!(
        "ply\nformat binary_little_endian 1.0\ncomment written by mmnormd {}\nelement vertex {n}\n",
        env!("CARGO_PKG_VERSION")
    );
    for c in columns {
        header.push_str(&c.header());
        header.push('\n');
    }
    if !triangles.is_empty() {
        header.push_str(&format!(
            "element face {}\nproperty list uchar uint vertex_indices\n",
            triangles.len()
        ));
    }
    header.push_str("end_header\n");
    out.write_all(header.as_bytes()).ok();
    for i in 0..n {
        for c in columns {
            c.write(i, &mut out);
        }
    }
    for t in triangles {
        out.push(3);
        for k in t {
            out.extend_from_slice(&k.to_le_bytes());
        }
    }
    out
}

/// Encodes a mesh with double-precision vertices.
pub fn encode_mesh(vertices_m: &[[f64; 3]], triangles: &[[u32; 3]]) -> Vec<u8> {
    let col = |k: usize| vertices_m.iter().map(|v| v[k]).collect::<Vec<_>>();
    encode(
        &[
            Column::F64("x", col(0)),
            Column::F64("y", col(1)),
            Column::F64("z", col(2)),
        ],
        triangles,
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn binary_mesh_round_trips() {
        let v = vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.5]];
        let t = vec![[0, 1, 2]];
        let parsed = parse(&encode_mesh(&v, &t)).unwrap();
        assert_eq!(parsed.vertices_m, v);
        assert_eq!(parsed.triangles, t);
        assert!(parsed.normals.is_none());
    }

    #[test]
    fn ascii_with_quads_normals_and_extra_elements() {
        let text = "ply\nformat ascii 1.0\ncomment hi\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\nproperty float nx\nproperty float ny\nproperty float nz\nproperty uchar red\nelement face 1\nproperty list uchar int vertex_index\nelement edge 1\nproperty int vertex1\nproperty int vertex2\nend_header\n0 0 0 0 0 1 255\n1 0 0 0 0 1 0\n1 1 0 0 0 1 0\n0 1 0 0 0 1 9\n4 0 1 2 3\n0 1\n";
        let p = parse(text.as_bytes()).unwrap();
        assert_eq!(p.vertices_m.len(), 4);
        assert_eq!(p.triangles, vec![[0, 1, 2], [0, 2, 3]]);
        assert_eq!(p.normals.unwrap()[3], [0.0, 0.0, 1.0]);
        assert_eq!(p.vertex_properties[6].1[3], 9.0);
    }

    #[test]
    fn absurd_counts_fail_cleanly() {
        let text = "ply\nformat binary_little_endian 1.0\nelement vertex 999999999999\nproperty float x\nproperty float y\nproperty float z\nend_header\n";
        assert!(parse(text.as_bytes()).unwrap_err().contains("truncated"));
    }

    #[test]
    fn big_endian_and_truncation() {
        let mut bytes = b"ply\nformat binary_big_endian 1.0\nelement vertex 1\nproperty double x\nproperty double y\nproperty double z\nend_header\n".to_vec();
        for v in [1.5f64, -2.0, 3.25] {
            bytes.extend_from_slice(&v.to_be_bytes());
        }
        assert_eq!(parse(&bytes).unwrap().vertices_m, vec![[1.5, -2.0, 3.25]]);
        let err = parse(&bytes[..bytes.len() - 3]).unwrap_err();
        assert!(err.contains("truncated"), "{err}");
        assert!(parse(b"solid cube\nfacet").is_err());
    }
}
