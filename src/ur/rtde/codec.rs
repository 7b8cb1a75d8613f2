//! The RTDE wire format (docs/protocols.md C2, C3). Everything is big-endian.
//!
//! Every packet:
//!
//! | offset | size | field |
//! |---|---|---|
//! | 0 | 2 | `u16` size of the whole packet, header included |
//! | 2 | 1 | `u8` type (ASCII) |
//! | 3 | size − 3 | payload |
//!
//! | type | client → robot | robot → client |
//! |---|---|---|
//! | `V` 86 | `u16` protocol version | `u8` accepted |
//! | `v` 118 | — | `u32` major, minor, bugfix, build |
//! | `M` 77 | — | v2: `u8` len, message, `u8` len, source, `u8` level; v1: `u8` level, message |
//! | `O` 79 | v2: `f64` frequency, names joined by `,`; v1: names | v2: `u8` recipe id, types joined by `,`; v1: types |
//! | `I` 73 | names joined by `,` | `u8` recipe id, types (`NOT_FOUND`, `IN_USE`) |
//! | `S` 83 | — | `u8` accepted |
//! | `P` 80 | — | `u8` accepted |
//! | `U` 85 | v2: `u8` recipe id, fields | v2: `u8` recipe id, fields; v1: fields |

/// Packet types.
pub const REQUEST_PROTOCOL_VERSION: u8 = b'V';
pub const GET_URCONTROL_VERSION: u8 = b'v';
pub const TEXT_MESSAGE: u8 = b'M';
pub const CONTROL_PACKAGE_SETUP_OUTPUTS: u8 = b'O';
pub const CONTROL_PACKAGE_SETUP_INPUTS: u8 = b'I';
pub const CONTROL_PACKAGE_START: u8 = b'S';
pub const CONTROL_PACKAGE_PAUSE: u8 = b'P';
pub const DATA_PACKAGE: u8 = b'U';

/// Header bytes of every packet.
pub const HEADER_LEN: usize = 3;
/// Longest names list the controller accepts in a setup request, bytes.
pub const MAX_NAMES_LEN: usize = 2048;

/// Why bytes are not a valid RTDE packet.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CodecError {
    #[error("packet size {size} is smaller than the 3-byte header")]
    BadSize { size: u16 },
    #[error("packet type {ty:?} ({what}) needs {expected} payload bytes, found {actual}")]
    Length {
        ty: char,
        what: &'static str,
        expected: usize,
        actual: usize,
    },
    #[error("unknown packet type 0x{0:02X}")]
    UnknownType(u8),
    #[error("unknown RTDE type name `{0}`")]
    UnknownTypeName(String),
    #[error("data package for recipe {got}, expected recipe {expected}")]
    WrongRecipe { expected: u8, got: u8 },
    #[error("text is not ASCII/UTF-8 in packet {ty:?}")]
    BadText { ty: char },
    #[error("packet of {0} bytes exceeds the 65 535-byte limit")]
    TooLong(usize),
    #[error("names list of {0} bytes exceeds the {MAX_NAMES_LEN}-byte limit")]
    NamesTooLong(usize),
    #[error("value {index} is {got:?}, the recipe says {expected:?}")]
    ValueType {
        index: usize,
        expected: RtdeType,
        got: RtdeType,
    },
}

/// The data types of C3.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize)]
pub enum RtdeType {
    Bool,
    Uint8,
    Uint32,
    Uint64,
    Int32,
    Double,
    Vector3d,
    Vector6d,
    Vector6Int32,
    Vector6Uint32,
}

impl RtdeType {
    const NAMES: [(RtdeType, &'static str, usize); 10] = [
        (RtdeType::Bool, "BOOL", 1),
        (RtdeType::Uint8, "UINT8", 1),
        (RtdeType::Uint32, "UINT32", 4),
        (RtdeType::Uint64, "UINT64", 8),
        (RtdeType::Int32, "INT32", 4),
        (RtdeType::Double, "DOUBLE", 8),
        (RtdeType::Vector3d, "VECTOR3D", 24),
        (RtdeType::Vector6d, "VECTOR6D", 48),
        (RtdeType::Vector6Int32, "VECTOR6INT32", 24),
        (RtdeType::Vector6Uint32, "VECTOR6UINT32", 24),
    ];

    /// The wire name (`DOUBLE`, `VECTOR6D`, …).
    pub fn name(self) -> &'static str {
        Self::NAMES
            .iter()
            .find(|(t, _, _)| *t == self)
            .map_or("", |(_, n, _)| n)
    }

    /// Scalars a value holds: 3 or 6 for the vectors, else 1.
    pub fn scalars(self) -> usize {
        match self {
            RtdeType::Vector3d => 3,
            RtdeType::Vector6d | RtdeType::Vector6Int32 | RtdeType::Vector6Uint32 => 6,
            _ => 1,
        }
    }

    /// Bytes on the wire.
    pub fn size(self) -> usize {
        Self::NAMES
            .iter()
            .find(|(t, _, _)| *t == self)
            .map_or(0, |(_, _, s)| *s)
    }

    /// The type for a wire name.
    pub fn from_name(name: &str) -> Option<Self> {
        Self::NAMES
            .iter()
            .find(|(_, n, _)| *n == name)
            .map(|(t, _, _)| *t)
    }

    /// Scalars in a value of this type (6 for the vectors of six).
    pub fn width(self) -> usize {
        match self {
            RtdeType::Vector3d => 3,
            RtdeType::Vector6d | RtdeType::Vector6Int32 | RtdeType::Vector6Uint32 => 6,
            _ => 1,
        }
    }
}

/// One field's value.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub enum Value {
    Bool(bool),
    Uint8(u8),
    Uint32(u32),
    Uint64(u64),
    Int32(i32),
    Double(f64),
    Vector3d([f64; 3]),
    Vector6d([f64; 6]),
    Vector6Int32([i32; 6]),
    Vector6Uint32([u32; 6]),
}

impl Value {
    /// The value's type.
    pub fn rtde_type(&self) -> RtdeType {
        match self {
            Value::Bool(_) => RtdeType::Bool,
            Value::Uint8(_) => RtdeType::Uint8,
            Value::Uint32(_) => RtdeType::Uint32,
            Value::Uint64(_) => RtdeType::Uint64,
            Value::Int32(_) => RtdeType::Int32,
            Value::Double(_) => RtdeType::Double,
            Value::Vector3d(_) => RtdeType::Vector3d,
            Value::Vector6d(_) => RtdeType::Vector6d,
            Value::Vector6Int32(_) => RtdeType::Vector6Int32,
            Value::Vector6Uint32(_) => RtdeType::Vector6Uint32,
        }
    }

    /// The scalars as f64, in order (for logging and CSV).
    pub fn scalars(&self) -> Vec<f64> {
        match self {
            Value::Bool(b) => vec![f64::from(u8::from(*b))],
            Value::Uint8(v) => vec![f64::from(*v)],
            Value::Uint32(v) => vec![f64::from(*v)],
            Value::Uint64(v) => vec![*v as f64],
            Value::Int32(v) => vec![f64::from(*v)],
            Value::Double(v) => vec![*v],
            Value::Vector3d(v) => v.to_vec(),
            Value::Vector6d(v) => v.to_vec(),
            Value::Vector6Int32(v) => v.iter().map(|x| f64::from(*x)).collect(),
            Value::Vector6Uint32(v) => v.iter().map(|x| f64::from(*x)).collect(),
        }
    }

    fn encode(&self, out: &mut Vec<u8>) {
        match self {
            Value::Bool(b) => out.push(u8::from(*b)),
            Value::Uint8(v) => out.push(*v),
            Value::Uint32(v) => out.extend_from_slice(&v.to_be_bytes()),
            Value::Uint64(v) => out.extend_from_slice(&v.to_be_bytes()),
            Value::Int32(v) => out.extend_from_slice(&v.to_be_bytes()),
            Value::Double(v) => out.extend_from_slice(&v.to_be_bytes()),
            Value::Vector3d(v) => v
                .iter()
                .for_each(|x| out.extend_from_slice(&x.to_be_bytes())),
            Value::Vector6d(v) => v
                .iter()
                .for_each(|x| out.extend_from_slice(&x.to_be_bytes())),
            Value::Vector6Int32(v) => v
                .iter()
                .for_each(|x| out.extend_from_slice(&x.to_be_bytes())),
            Value::Vector6Uint32(v) => v
                .iter()
                .for_each(|x| out.extend_from_slice(&x.to_be_bytes())),
        }
    }

    /// Decodes one value of `ty` from exactly `ty.size()` bytes.
    fn decode(ty: RtdeType, b: &[u8]) -> Value {
        let f = |i: usize| f64::from_be_bytes(b[8 * i..8 * i + 8].try_into().unwrap_or([0; 8]));
        let i32_at =
            |i: usize| i32::from_be_bytes(b[4 * i..4 * i + 4].try_into().unwrap_or([0; 4]));
        let u32_at =
            |i: usize| u32::from_be_bytes(b[4 * i..4 * i + 4].try_into().unwrap_or([0; 4]));
        match ty {
            RtdeType::Bool => Value::Bool(b[0] != 0),
            RtdeType::Uint8 => Value::Uint8(b[0]),
            RtdeType::Uint32 => Value::Uint32(u32_at(0)),
            RtdeType::Uint64 => {
                Value::Uint64(u64::from_be_bytes(b[..8].try_into().unwrap_or([0; 8])))
            }
            RtdeType::Int32 => Value::Int32(i32_at(0)),
            RtdeType::Double => Value::Double(f(0)),
            RtdeType::Vector3d => Value::Vector3d([f(0), f(1), f(2)]),
            RtdeType::Vector6d => Value::Vector6d([0, 1, 2, 3, 4, 5].map(f)),
            RtdeType::Vector6Int32 => Value::Vector6Int32([0, 1, 2, 3, 4, 5].map(i32_at)),
            RtdeType::Vector6Uint32 => Value::Vector6Uint32([0, 1, 2, 3, 4, 5].map(u32_at)),
        }
    }
}

/// A field of a setup reply: a type, or the controller's refusal of that field.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FieldType {
    Type(RtdeType),
    NotFound,
    InUse,
}

/// A negotiated recipe: field names and types in order.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Recipe {
    /// Recipe id (0 under protocol v1, which has none).
    pub id: u8,
    pub names: Vec<String>,
    pub types: Vec<RtdeType>,
}

impl Recipe {
    /// Payload bytes of one data package of this recipe, id excluded.
    pub fn data_len(&self) -> usize {
        self.types.iter().map(|t| t.size()).sum()
    }

    /// Decodes a data package's fields (after the recipe id).
    pub fn decode_fields(&self, b: &[u8]) -> Result<Vec<Value>, CodecError> {
        if b.len() != self.data_len() {
            return Err(CodecError::Length {
                ty: 'U',
                what: "data package fields",
                expected: self.data_len(),
                actual: b.len(),
            });
        }
        let mut at = 0;
        Ok(self
            .types
            .iter()
            .map(|&t| {
                let v = Value::decode(t, &b[at..at + t.size()]);
                at += t.size();
                v
            })
            .collect())
    }

    /// Encodes fields after checking their types against the recipe.
    pub fn encode_fields(&self, values: &[Value], out: &mut Vec<u8>) -> Result<(), CodecError> {
        if values.len() != self.types.len() {
            return Err(CodecError::Length {
                ty: 'U',
                what: "data package values",
                expected: self.types.len(),
                actual: values.len(),
            });
        }
        for (index, (v, &t)) in values.iter().zip(&self.types).enumerate() {
            if v.rtde_type() != t {
                return Err(CodecError::ValueType {
                    index,
                    expected: t,
                    got: v.rtde_type(),
                });
            }
            v.encode(out);
        }
        Ok(())
    }
}

/// Client-to-robot messages.
#[derive(Debug, Clone, PartialEq)]
pub enum ClientMessage {
    RequestProtocolVersion(u16),
    GetUrcontrolVersion,
    /// `frequency_hz` is sent under protocol v2 only.
    SetupOutputs {
        frequency_hz: f64,
        names: Vec<String>,
    },
    SetupInputs {
        names: Vec<String>,
    },
    Start,
    Pause,
    /// An input data package: recipe id and encoded fields.
    Data {
        recipe_id: u8,
        fields: Vec<u8>,
    },
}

/// Which recipe a setup request or its reply concerns.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Setup {
    /// `O`, CONTROL_PACKAGE_SETUP_OUTPUTS.
    Outputs,
    /// `I`, CONTROL_PACKAGE_SETUP_INPUTS.
    Inputs,
}

impl Setup {
    /// The packet type.
    pub fn packet_type(self) -> u8 {
        match self {
            Setup::Outputs => CONTROL_PACKAGE_SETUP_OUTPUTS,
            Setup::Inputs => CONTROL_PACKAGE_SETUP_INPUTS,
        }
    }
}

/// Robot-to-client messages.
#[derive(Debug, Clone, PartialEq)]
pub enum RobotMessage {
    ProtocolVersionAccepted(bool),
    UrcontrolVersion {
        major: u32,
        minor: u32,
        bugfix: u32,
        build: u32,
    },
    Text {
        level: u8,
        message: String,
        source: String,
    },
    /// A setup reply, typed as the request it answers (`O` or `I`): the recipe id (0 for
    /// outputs under v1) and each field's type or refusal.
    SetupReply {
        setup: Setup,
        recipe_id: u8,
        types: Vec<FieldType>,
    },
    StartAccepted(bool),
    PauseAccepted(bool),
    /// An output data package: recipe id (0 under v1) and the raw fields.
    Data {
        recipe_id: u8,
        fields: Vec<u8>,
    },
}

fn frame(ty: u8, payload: &[u8]) -> Result<Vec<u8>, CodecError> {
    let size = HEADER_LEN + payload.len();
    let size16 = u16::try_from(size).map_err(|_| CodecError::TooLong(size))?;
    let mut out = Vec::with_capacity(size);
    out.extend_from_slice(&size16.to_be_bytes());
    out.push(ty);
    out.extend_from_slice(payload);
    Ok(out)
}

fn names_payload(names: &[String]) -> Result<Vec<u8>, CodecError> {
    let joined = names.join(",");
    if joined.len() > MAX_NAMES_LEN {
        return Err(CodecError::NamesTooLong(joined.len()));
    }
    Ok(joined.into_bytes())
}

fn text(ty: u8, b: &[u8]) -> Result<String, CodecError> {
    String::from_utf8(b.to_vec()).map_err(|_| CodecError::BadText { ty: char::from(ty) })
}

fn need(ty: u8, what: &'static str, b: &[u8], expected: usize) -> Result<(), CodecError> {
    if b.len() == expected {
        Ok(())
    } else {
        Err(CodecError::Length {
            ty: char::from(ty),
            what,
            expected,
            actual: b.len(),
        })
    }
}

/// Splits off a leading byte (a recipe id or a level), or reports it missing.
fn leading_byte<'a>(ty: u8, what: &'static str, b: &'a [u8]) -> Result<(u8, &'a [u8]), CodecError> {
    b.split_first()
        .map(|(&first, rest)| (first, rest))
        .ok_or(CodecError::Length {
            ty: char::from(ty),
            what,
            expected: 1,
            actual: 0,
        })
}

/// A data package: the recipe id (when given) and the fields.
fn data_frame(recipe_id: Option<u8>, fields: &[u8]) -> Result<Vec<u8>, CodecError> {
    let mut p = Vec::with_capacity(1 + fields.len());
    p.extend(recipe_id);
    p.extend_from_slice(fields);
    frame(DATA_PACKAGE, &p)
}

/// The names of a comma-separated list, as the controller splits it: empty names (a trailing
/// comma, as ur_rtde sends, or `a,,b`) are dropped.
fn split_names(s: &str) -> Vec<String> {
    s.split(',')
        .filter(|n| !n.is_empty())
        .map(str::to_string)
        .collect()
}

impl ClientMessage {
    /// The framed bytes under `protocol` (1 or 2).
    pub fn encode(&self, protocol: u16) -> Result<Vec<u8>, CodecError> {
        match self {
            ClientMessage::RequestProtocolVersion(v) => {
                frame(REQUEST_PROTOCOL_VERSION, &v.to_be_bytes())
            }
            ClientMessage::GetUrcontrolVersion => frame(GET_URCONTROL_VERSION, &[]),
            ClientMessage::SetupOutputs {
                frequency_hz,
                names,
            } => {
                let mut p = Vec::new();
                if protocol >= 2 {
                    p.extend_from_slice(&frequency_hz.to_be_bytes());
                }
                p.extend(names_payload(names)?);
                frame(CONTROL_PACKAGE_SETUP_OUTPUTS, &p)
            }
            ClientMessage::SetupInputs { names } => {
                frame(CONTROL_PACKAGE_SETUP_INPUTS, &names_payload(names)?)
            }
            ClientMessage::Start => frame(CONTROL_PACKAGE_START, &[]),
            ClientMessage::Pause => frame(CONTROL_PACKAGE_PAUSE, &[]),
            ClientMessage::Data { recipe_id, fields } => data_frame(Some(*recipe_id), fields),
        }
    }

    /// Parses a client packet's payload (the simulator's side).
    pub fn decode(ty: u8, b: &[u8], protocol: u16) -> Result<Self, CodecError> {
        Ok(match ty {
            REQUEST_PROTOCOL_VERSION => {
                need(ty, "protocol version", b, 2)?;
                ClientMessage::RequestProtocolVersion(u16::from_be_bytes([b[0], b[1]]))
            }
            GET_URCONTROL_VERSION => {
                need(ty, "no payload", b, 0)?;
                ClientMessage::GetUrcontrolVersion
            }
            CONTROL_PACKAGE_SETUP_OUTPUTS => {
                let (frequency_hz, rest) = if protocol >= 2 {
                    if b.len() < 8 {
                        return Err(CodecError::Length {
                            ty: 'O',
                            what: "frequency",
                            expected: 8,
                            actual: b.len(),
                        });
                    }
                    let f = f64::from_be_bytes(b[..8].try_into().unwrap_or([0; 8]));
                    (f, &b[8..])
                } else {
                    (0.0, b)
                };
                ClientMessage::SetupOutputs {
                    frequency_hz,
                    names: split_names(&text(ty, rest)?),
                }
            }
            CONTROL_PACKAGE_SETUP_INPUTS => ClientMessage::SetupInputs {
                names: split_names(&text(ty, b)?),
            },
            CONTROL_PACKAGE_START => {
                need(ty, "no payload", b, 0)?;
                ClientMessage::Start
            }
            CONTROL_PACKAGE_PAUSE => {
                need(ty, "no payload", b, 0)?;
                ClientMessage::Pause
            }
            DATA_PACKAGE => {
                let (recipe_id, fields) = leading_byte(ty, "recipe id", b)?;
                ClientMessage::Data {
                    recipe_id,
                    fields: fields.to_vec(),
                }
            }
            other => return Err(CodecError::UnknownType(other)),
        })
    }
}

impl RobotMessage {
    /// The framed bytes under `protocol` (the simulator's side).
    pub fn encode(&self, protocol: u16) -> Result<Vec<u8>, CodecError> {
        match self {
            RobotMessage::ProtocolVersionAccepted(a) => {
                frame(REQUEST_PROTOCOL_VERSION, &[u8::from(*a)])
            }
            RobotMessage::UrcontrolVersion {
                major,
                minor,
                bugfix,
                build,
            } => {
                let p: Vec<u8> = [major, minor, bugfix, build]
                    .iter()
                    .flat_map(|v| v.to_be_bytes())
                    .collect();
                frame(GET_URCONTROL_VERSION, &p)
            }
            RobotMessage::Text {
                level,
                message,
                source,
            } => {
                let mut p = Vec::new();
                if protocol >= 2 {
                    let m = &message.as_bytes()[..message.len().min(255)];
                    let s = &source.as_bytes()[..source.len().min(255)];
                    p.push(m.len() as u8);
                    p.extend_from_slice(m);
                    p.push(s.len() as u8);
                    p.extend_from_slice(s);
                    p.push(*level);
                } else {
                    p.push(*level);
                    p.extend_from_slice(message.as_bytes());
                }
                frame(TEXT_MESSAGE, &p)
            }
            RobotMessage::SetupReply {
                setup,
                recipe_id,
                types,
            } => {
                let names: Vec<&str> = types
                    .iter()
                    .map(|t| match t {
                        FieldType::Type(t) => t.name(),
                        FieldType::NotFound => "NOT_FOUND",
                        FieldType::InUse => "IN_USE",
                    })
                    .collect();
                let mut p = Vec::new();
                if protocol >= 2 || *setup == Setup::Inputs {
                    p.push(*recipe_id);
                }
                p.extend_from_slice(names.join(",").as_bytes());
                frame(setup.packet_type(), &p)
            }
            RobotMessage::StartAccepted(a) => frame(CONTROL_PACKAGE_START, &[u8::from(*a)]),
            RobotMessage::PauseAccepted(a) => frame(CONTROL_PACKAGE_PAUSE, &[u8::from(*a)]),
            RobotMessage::Data { recipe_id, fields } => {
                data_frame((protocol >= 2).then_some(*recipe_id), fields)
            }
        }
    }

    /// Parses a robot packet's payload under `protocol`. Setup replies to `I` and `O` share a
    /// layout; the caller knows which it asked.
    pub fn decode(ty: u8, b: &[u8], protocol: u16) -> Result<Self, CodecError> {
        Ok(match ty {
            REQUEST_PROTOCOL_VERSION => {
                need(ty, "accepted flag", b, 1)?;
                RobotMessage::ProtocolVersionAccepted(b[0] != 0)
            }
            GET_URCONTROL_VERSION => {
                need(ty, "four u32", b, 16)?;
                let u =
                    |i: usize| u32::from_be_bytes(b[4 * i..4 * i + 4].try_into().unwrap_or([0; 4]));
                RobotMessage::UrcontrolVersion {
                    major: u(0),
                    minor: u(1),
                    bugfix: u(2),
                    build: u(3),
                }
            }
            TEXT_MESSAGE => {
                if protocol >= 2 {
                    let short = |expected| CodecError::Length {
                        ty: 'M',
                        what: "text message",
                        expected,
                        actual: b.len(),
                    };
                    let m_len = usize::from(*b.first().ok_or_else(|| short(1))?);
                    let s_at = 1 + m_len;
                    let s_len = usize::from(*b.get(s_at).ok_or_else(|| short(s_at + 1))?);
                    let level_at = s_at + 1 + s_len;
                    need(ty, "text message", b, level_at + 1)?;
                    RobotMessage::Text {
                        message: text(ty, &b[1..s_at])?,
                        source: text(ty, &b[s_at + 1..level_at])?,
                        level: b[level_at],
                    }
                } else {
                    let (level, msg) = leading_byte(ty, "level", b)?;
                    RobotMessage::Text {
                        level,
                        message: text(ty, msg)?,
                        source: String::new(),
                    }
                }
            }
            CONTROL_PACKAGE_SETUP_OUTPUTS | CONTROL_PACKAGE_SETUP_INPUTS => {
                let (recipe_id, rest) = if protocol >= 2 || ty == CONTROL_PACKAGE_SETUP_INPUTS {
                    leading_byte(ty, "recipe id", b)?
                } else {
                    (0, b)
                };
                let types = split_names(&text(ty, rest)?)
                    .into_iter()
                    .map(|n| match n.as_str() {
                        "NOT_FOUND" => Ok(FieldType::NotFound),
                        "IN_USE" => Ok(FieldType::InUse),
                        other => RtdeType::from_name(other)
                            .map(FieldType::Type)
                            .ok_or(CodecError::UnknownTypeName(n)),
                    })
                    .collect::<Result<_, _>>()?;
                let setup = if ty == CONTROL_PACKAGE_SETUP_INPUTS {
                    Setup::Inputs
                } else {
                    Setup::Outputs
                };
                RobotMessage::SetupReply {
                    setup,
                    recipe_id,
                    types,
                }
            }
            CONTROL_PACKAGE_START => {
                need(ty, "accepted flag", b, 1)?;
                RobotMessage::StartAccepted(b[0] != 0)
            }
            CONTROL_PACKAGE_PAUSE => {
                need(ty, "accepted flag", b, 1)?;
                RobotMessage::PauseAccepted(b[0] != 0)
            }
            DATA_PACKAGE => {
                if protocol >= 2 {
                    let (recipe_id, fields) = leading_byte(ty, "recipe id", b)?;
                    RobotMessage::Data {
                        recipe_id,
                        fields: fields.to_vec(),
                    }
                } else {
                    RobotMessage::Data {
                        recipe_id: 0,
                        fields: b.to_vec(),
                    }
                }
            }
            other => return Err(CodecError::UnknownType(other)),
        })
    }
}

/// Splits a TCP byte stream into packets: `feed` bytes, then take `(type, payload)` pairs.
#[derive(Debug, Default)]
pub struct PacketReader {
    buf: Vec<u8>,
}

impl PacketReader {
    pub fn feed(&mut self, bytes: &[u8]) {
        self.buf.extend_from_slice(bytes);
    }

    /// The next whole packet, `Ok(None)` when more bytes are needed. A size below the header is
    /// an error: the stream has lost its framing.
    pub fn next_packet(&mut self) -> Result<Option<(u8, Vec<u8>)>, CodecError> {
        if self.buf.len() < HEADER_LEN {
            return Ok(None);
        }
        let size = u16::from_be_bytes([self.buf[0], self.buf[1]]);
        if usize::from(size) < HEADER_LEN {
            return Err(CodecError::BadSize { size });
        }
        let size = usize::from(size);
        if self.buf.len() < size {
            return Ok(None);
        }
        let ty = self.buf[2];
        let payload = self.buf[HEADER_LEN..size].to_vec();
        self.buf.drain(..size);
        Ok(Some((ty, payload)))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn roundtrip_robot(m: RobotMessage, protocol: u16) -> RobotMessage {
        let bytes = m.encode(protocol).unwrap();
        let mut r = PacketReader::default();
        r.feed(&bytes);
        let (ty, p) = r.next_packet().unwrap().unwrap();
        RobotMessage::decode(ty, &p, protocol).unwrap()
    }

    #[test]
    fn protocol_version_request_is_big_endian_with_its_size() {
        let b = ClientMessage::RequestProtocolVersion(2).encode(2).unwrap();
        assert_eq!(b, vec![0x00, 0x05, b'V', 0x00, 0x02]);
        let b = ClientMessage::SetupOutputs {
            frequency_hz: 500.0,
            names: vec!["timestamp".into(), "actual_q".into()],
        }
        .encode(2)
        .unwrap();
        assert_eq!(&b[..3], &[0x00, (3 + 8 + 18) as u8, b'O']);
        assert_eq!(&b[3..11], &500.0f64.to_be_bytes());
        assert_eq!(&b[11..], b"timestamp,actual_q");
        let v1 = ClientMessage::SetupOutputs {
            frequency_hz: 500.0,
            names: vec!["timestamp".into()],
        }
        .encode(1)
        .unwrap();
        assert_eq!(&v1[3..], b"timestamp");
    }

    #[test]
    fn every_robot_message_round_trips_under_both_protocols() {
        for protocol in [1, 2] {
            let messages = [
                RobotMessage::ProtocolVersionAccepted(true),
                RobotMessage::UrcontrolVersion {
                    major: 5,
                    minor: 11,
                    bugfix: 1,
                    build: 108_318,
                },
                RobotMessage::Text {
                    level: 2,
                    message: "hello".into(),
                    source: if protocol == 2 {
                        "rtde".into()
                    } else {
                        String::new()
                    },
                },
                RobotMessage::SetupReply {
                    setup: Setup::Outputs,
                    recipe_id: if protocol == 2 { 1 } else { 0 },
                    types: vec![
                        FieldType::Type(RtdeType::Double),
                        FieldType::NotFound,
                        FieldType::Type(RtdeType::Vector6d),
                    ],
                },
                // An input reply carries its recipe id under both versions.
                RobotMessage::SetupReply {
                    setup: Setup::Inputs,
                    recipe_id: 2,
                    types: vec![FieldType::Type(RtdeType::Int32), FieldType::InUse],
                },
                RobotMessage::StartAccepted(true),
                RobotMessage::PauseAccepted(false),
                RobotMessage::Data {
                    recipe_id: if protocol == 2 { 1 } else { 0 },
                    fields: vec![1, 2, 3],
                },
            ];
            for m in messages {
                assert_eq!(roundtrip_robot(m.clone(), protocol), m, "v{protocol}");
            }
        }
    }

    #[test]
    fn data_fields_decode_by_recipe_with_checked_length() {
        let recipe = Recipe {
            id: 1,
            names: vec![
                "timestamp".into(),
                "actual_TCP_pose".into(),
                "robot_mode".into(),
                "runtime_state".into(),
            ],
            types: vec![
                RtdeType::Double,
                RtdeType::Vector6d,
                RtdeType::Int32,
                RtdeType::Uint32,
            ],
        };
        let values = vec![
            Value::Double(12.5),
            Value::Vector6d([0.4, -0.2, 0.3, 0.0, 3.0, 0.0]),
            Value::Int32(7),
            Value::Uint32(2),
        ];
        let mut b = Vec::new();
        recipe.encode_fields(&values, &mut b).unwrap();
        assert_eq!(b.len(), 8 + 48 + 4 + 4);
        assert_eq!(&b[..8], &12.5f64.to_be_bytes());
        assert_eq!(recipe.decode_fields(&b).unwrap(), values);
        assert_eq!(
            recipe.decode_fields(&b[1..]),
            Err(CodecError::Length {
                ty: 'U',
                what: "data package fields",
                expected: 64,
                actual: 63
            })
        );
        assert!(matches!(
            recipe.encode_fields(
                &[Value::Int32(1), values[1], values[2], values[3]],
                &mut Vec::new()
            ),
            Err(CodecError::ValueType { index: 0, .. })
        ));
        for (t, size) in [
            (RtdeType::Bool, 1),
            (RtdeType::Uint8, 1),
            (RtdeType::Uint32, 4),
            (RtdeType::Uint64, 8),
            (RtdeType::Int32, 4),
            (RtdeType::Double, 8),
            (RtdeType::Vector3d, 24),
            (RtdeType::Vector6d, 48),
            (RtdeType::Vector6Int32, 24),
            (RtdeType::Vector6Uint32, 24),
        ] {
            assert_eq!(t.size(), size);
            assert_eq!(RtdeType::from_name(t.name()), Some(t));
        }
    }

    #[test]
    fn the_reader_waits_for_whole_packets_and_refuses_a_broken_size() {
        let a = RobotMessage::StartAccepted(true).encode(2).unwrap();
        let b = RobotMessage::PauseAccepted(true).encode(2).unwrap();
        let stream = [a, b].concat();
        let mut r = PacketReader::default();
        r.feed(&stream[..5]);
        assert_eq!(r.next_packet().unwrap(), Some((b'S', vec![1])));
        assert_eq!(r.next_packet().unwrap(), None);
        r.feed(&stream[5..]);
        assert_eq!(r.next_packet().unwrap(), Some((b'P', vec![1])));
        r.feed(&[0x00, 0x01, b'U']);
        assert_eq!(r.next_packet(), Err(CodecError::BadSize { size: 1 }));
    }

    /// ur_rtde ends its names with a comma; the controller ignores the empty name.
    #[test]
    fn empty_names_are_dropped_as_the_controller_does() {
        let m = ClientMessage::decode(
            b'O',
            b"\x40\x7f\x40\x00\x00\x00\x00\x00timestamp,actual_q,",
            2,
        )
        .unwrap();
        assert_eq!(
            m,
            ClientMessage::SetupOutputs {
                frequency_hz: 500.0,
                names: vec!["timestamp".into(), "actual_q".into()],
            }
        );
        let m = ClientMessage::decode(b'I', b"input_int_register_24,,", 2).unwrap();
        assert_eq!(
            m,
            ClientMessage::SetupInputs {
                names: vec!["input_int_register_24".into()],
            }
        );
    }

    #[test]
    fn in_use_and_not_found_are_decoded_as_refusals() {
        let m = RobotMessage::decode(b'I', b"\x00INT32,IN_USE", 2).unwrap();
        assert_eq!(
            m,
            RobotMessage::SetupReply {
                setup: Setup::Inputs,
                recipe_id: 0,
                types: vec![FieldType::Type(RtdeType::Int32), FieldType::InUse]
            }
        );
        // The reply's packet type follows the request it answers.
        let input_reply = RobotMessage::SetupReply {
            setup: Setup::Inputs,
            recipe_id: 1,
            types: vec![FieldType::Type(RtdeType::Int32)],
        };
        assert_eq!(input_reply.encode(2).unwrap()[2], b'I');
        assert_eq!(
            RobotMessage::decode(b'O', b"\x01FLOAT", 2),
            Err(CodecError::UnknownTypeName("FLOAT".into()))
        );
    }
}
