//! Config-port commands and responses (docs/protocols.md A2–A4).
//!
//! Request, all fields little-endian:
//!
//! | offset | size | field |
//! |---|---|---|
//! | 0 | 2 | header `0xA55A` (wire bytes `5A A5`) |
//! | 2 | 2 | command code |
//! | 4 | 2 | data size n (≤ 504) |
//! | 6 | n | data |
//! | 6+n | 2 | footer `0xEEAA` (wire bytes `AA EE`) |
//!
//! Response, always 8 bytes: header, the echoed command code, a `u16` status, footer. Status 0 is
//! success; for `READ_FPGA_VERSION` the status *is* the version, and for the unsolicited
//! `SYSTEM_ERROR` (0x0A) packet it is a bitmask of [`AsyncEvent`]s.

use std::net::Ipv4Addr;

/// Request and response header, as a little-endian `u16`.
pub const HEADER: u16 = 0xA55A;
/// Request and response footer, as a little-endian `u16`.
pub const FOOTER: u16 = 0xEEAA;
/// Largest request data the TI DLL sends, bytes.
pub const MAX_COMMAND_DATA: usize = 504;
/// Size of every response, bytes.
pub const RESPONSE_LEN: usize = 8;

/// Why bytes were not a valid command or response.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum CodecError {
    #[error("packet of {len} bytes is shorter than the {min} bytes of an empty command")]
    TooShort { len: usize, min: usize },
    #[error("bad header 0x{got:04X} (expected 0x{HEADER:04X})")]
    BadHeader { got: u16 },
    #[error("bad footer 0x{got:04X} (expected 0x{FOOTER:04X})")]
    BadFooter { got: u16 },
    #[error("data size {declared} does not match the {actual} bytes present")]
    SizeMismatch { declared: usize, actual: usize },
    #[error("data size {0} exceeds the {MAX_COMMAND_DATA}-byte limit")]
    DataTooLong(usize),
    #[error("unknown command code 0x{0:04X}")]
    UnknownCode(u16),
    #[error("command 0x{code:04X} takes {expected} data bytes, found {actual}")]
    BadDataSize {
        code: u16,
        expected: usize,
        actual: usize,
    },
    #[error("field {field} = {value} is not a valid value")]
    BadField { field: &'static str, value: u16 },
    #[error("response is {len} bytes; responses are exactly {RESPONSE_LEN}")]
    BadResponseLength { len: usize },
}

/// The command codes of A3.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[repr(u16)]
pub enum CommandCode {
    ResetFpga = 0x01,
    ResetArDevice = 0x02,
    ConfigFpgaGen = 0x03,
    ConfigEeprom = 0x04,
    RecordStart = 0x05,
    RecordStop = 0x06,
    PlaybackStart = 0x07,
    PlaybackStop = 0x08,
    SystemConnect = 0x09,
    SystemError = 0x0A,
    ConfigPacketData = 0x0B,
    ConfigDataModeArDev = 0x0C,
    InitFpgaPlayback = 0x0D,
    ReadFpgaVersion = 0x0E,
}

impl CommandCode {
    /// The code for a wire value.
    pub fn from_u16(value: u16) -> Result<Self, CodecError> {
        use CommandCode::*;
        Ok(match value {
            0x01 => ResetFpga,
            0x02 => ResetArDevice,
            0x03 => ConfigFpgaGen,
            0x04 => ConfigEeprom,
            0x05 => RecordStart,
            0x06 => RecordStop,
            0x07 => PlaybackStart,
            0x08 => PlaybackStop,
            0x09 => SystemConnect,
            0x0A => SystemError,
            0x0B => ConfigPacketData,
            0x0C => ConfigDataModeArDev,
            0x0D => InitFpgaPlayback,
            0x0E => ReadFpgaVersion,
            other => return Err(CodecError::UnknownCode(other)),
        })
    }
}

/// `CONFIG_FPGA_GEN` data: six mode bytes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FpgaConfig {
    /// 1 raw, 2 multi (data-separated).
    pub log_mode: u8,
    /// 1 four-lane (xWR12/14), 2 two-lane (xWR16/18/68).
    pub lvds_mode: u8,
    /// 1 LVDS capture, 2 DMM playback.
    pub transfer_mode: u8,
    /// 1 SD card (unsupported), 2 Ethernet stream.
    pub capture_mode: u8,
    /// 1 12-bit, 2 14-bit, 3 16-bit.
    pub data_format: u8,
    /// Seconds without LVDS data before the board reports `NO_LVDS_DATA`.
    pub timer_s: u8,
}

impl Default for FpgaConfig {
    /// Raw, 4-lane, capture, Ethernet, 16-bit, 30 s: the settings of A3's byte example.
    fn default() -> Self {
        Self {
            log_mode: 1,
            lvds_mode: 1,
            transfer_mode: 1,
            capture_mode: 2,
            data_format: 3,
            timer_s: 30,
        }
    }
}

impl FpgaConfig {
    fn to_bytes(self) -> [u8; 6] {
        [
            self.log_mode,
            self.lvds_mode,
            self.transfer_mode,
            self.capture_mode,
            self.data_format,
            self.timer_s,
        ]
    }

    /// Checks each mode byte against the values A3 defines.
    pub fn validate(&self) -> Result<(), CodecError> {
        let checks: [(&'static str, u8, &[u8]); 5] = [
            ("log_mode", self.log_mode, &[1, 2]),
            ("lvds_mode", self.lvds_mode, &[1, 2]),
            ("transfer_mode", self.transfer_mode, &[1, 2]),
            ("capture_mode", self.capture_mode, &[1, 2]),
            ("data_format", self.data_format, &[1, 2, 3]),
        ];
        for (field, value, allowed) in checks {
            if !allowed.contains(&value) {
                return Err(CodecError::BadField {
                    field,
                    value: value.into(),
                });
            }
        }
        Ok(())
    }
}

/// `CONFIG_PACKET_DATA` data: packet size and inter-packet delay.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PacketConfig {
    /// Packet size the FPGA is told, bytes (the TI DLL sends 1470; 48..=1472).
    pub packet_size_bytes: u16,
    /// Inter-packet delay in 8 ns FPGA clocks.
    pub delay_clocks: u16,
}

impl PacketConfig {
    /// A packet config from a delay in microseconds: clocks = µs · 1000 / 8, truncated.
    pub fn from_delay_us(packet_size_bytes: u16, delay_us: f64) -> Result<Self, CodecError> {
        let clocks = delay_us * 1000.0 / 8.0;
        if !(clocks.is_finite() && (0.0..=f64::from(u16::MAX)).contains(&clocks)) {
            return Err(CodecError::BadField {
                field: "packet_delay_us",
                value: u16::MAX,
            });
        }
        Ok(Self {
            packet_size_bytes,
            delay_clocks: clocks as u16,
        })
    }

    /// The inter-packet delay, microseconds.
    pub fn delay_us(&self) -> f64 {
        f64::from(self.delay_clocks) * 8.0 / 1000.0
    }
}

/// `CONFIG_EEPROM` data (A3): addresses are stored byte-reversed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct EepromConfig {
    pub host_ip: Ipv4Addr,
    pub fpga_ip: Ipv4Addr,
    pub fpga_mac: [u8; 6],
    pub config_port: u16,
    pub data_port: u16,
}

impl EepromConfig {
    fn to_bytes(self) -> [u8; 18] {
        let mut out = [0u8; 18];
        let mut host = self.host_ip.octets();
        host.reverse();
        let mut fpga = self.fpga_ip.octets();
        fpga.reverse();
        let mut mac = self.fpga_mac;
        mac.reverse();
        out[0..4].copy_from_slice(&host);
        out[4..8].copy_from_slice(&fpga);
        out[8..14].copy_from_slice(&mac);
        out[14..16].copy_from_slice(&self.config_port.to_le_bytes());
        out[16..18].copy_from_slice(&self.data_port.to_le_bytes());
        out
    }

    fn from_bytes(b: &[u8; 18]) -> Self {
        let ip = |s: &[u8]| Ipv4Addr::new(s[3], s[2], s[1], s[0]);
        let mut mac = [0u8; 6];
        mac.copy_from_slice(&b[8..14]);
        mac.reverse();
        Self {
            host_ip: ip(&b[0..4]),
            fpga_ip: ip(&b[4..8]),
            fpga_mac: mac,
            config_port: u16::from_le_bytes([b[14], b[15]]),
            data_port: u16::from_le_bytes([b[16], b[17]]),
        }
    }
}

/// A host-to-board command with its typed data.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Command {
    ResetFpga,
    ResetArDevice,
    ConfigFpgaGen(FpgaConfig),
    ConfigEeprom(EepromConfig),
    RecordStart,
    RecordStop,
    PlaybackStart,
    PlaybackStop,
    SystemConnect,
    ConfigPacketData(PacketConfig),
    ConfigDataModeArDev,
    InitFpgaPlayback,
    ReadFpgaVersion,
}

impl Command {
    /// The command's code.
    pub fn code(&self) -> CommandCode {
        match self {
            Command::ResetFpga => CommandCode::ResetFpga,
            Command::ResetArDevice => CommandCode::ResetArDevice,
            Command::ConfigFpgaGen(_) => CommandCode::ConfigFpgaGen,
            Command::ConfigEeprom(_) => CommandCode::ConfigEeprom,
            Command::RecordStart => CommandCode::RecordStart,
            Command::RecordStop => CommandCode::RecordStop,
            Command::PlaybackStart => CommandCode::PlaybackStart,
            Command::PlaybackStop => CommandCode::PlaybackStop,
            Command::SystemConnect => CommandCode::SystemConnect,
            Command::ConfigPacketData(_) => CommandCode::ConfigPacketData,
            Command::ConfigDataModeArDev => CommandCode::ConfigDataModeArDev,
            Command::InitFpgaPlayback => CommandCode::InitFpgaPlayback,
            Command::ReadFpgaVersion => CommandCode::ReadFpgaVersion,
        }
    }

    /// The request bytes, framed.
    pub fn encode(&self) -> Vec<u8> {
        let data: Vec<u8> = match self {
            Command::ConfigFpgaGen(c) => c.to_bytes().to_vec(),
            Command::ConfigEeprom(c) => c.to_bytes().to_vec(),
            Command::ConfigPacketData(c) => [
                c.packet_size_bytes.to_le_bytes(),
                c.delay_clocks.to_le_bytes(),
                [0, 0],
            ]
            .concat(),
            _ => Vec::new(),
        };
        let mut out = Vec::with_capacity(8 + data.len());
        out.extend_from_slice(&HEADER.to_le_bytes());
        out.extend_from_slice(&(self.code() as u16).to_le_bytes());
        out.extend_from_slice(&(data.len() as u16).to_le_bytes());
        out.extend_from_slice(&data);
        out.extend_from_slice(&FOOTER.to_le_bytes());
        out
    }

    /// Parses a framed request (the simulator's side). Checks header, footer, the declared size
    /// and each command's data length.
    pub fn decode(bytes: &[u8]) -> Result<Self, CodecError> {
        if bytes.len() < 8 {
            return Err(CodecError::TooShort {
                len: bytes.len(),
                min: 8,
            });
        }
        let word = |i: usize| u16::from_le_bytes([bytes[i], bytes[i + 1]]);
        if word(0) != HEADER {
            return Err(CodecError::BadHeader { got: word(0) });
        }
        let declared = usize::from(word(4));
        if declared > MAX_COMMAND_DATA {
            return Err(CodecError::DataTooLong(declared));
        }
        if bytes.len() != 8 + declared {
            return Err(CodecError::SizeMismatch {
                declared,
                actual: bytes.len() - 8,
            });
        }
        let footer = word(6 + declared);
        if footer != FOOTER {
            return Err(CodecError::BadFooter { got: footer });
        }
        let raw_code = word(2);
        let code = CommandCode::from_u16(raw_code)?;
        let data = &bytes[6..6 + declared];
        let expect = |n: usize| {
            if data.len() == n {
                Ok(())
            } else {
                Err(CodecError::BadDataSize {
                    code: raw_code,
                    expected: n,
                    actual: data.len(),
                })
            }
        };
        Ok(match code {
            CommandCode::ConfigFpgaGen => {
                expect(6)?;
                let c = FpgaConfig {
                    log_mode: data[0],
                    lvds_mode: data[1],
                    transfer_mode: data[2],
                    capture_mode: data[3],
                    data_format: data[4],
                    timer_s: data[5],
                };
                Command::ConfigFpgaGen(c)
            }
            CommandCode::ConfigEeprom => {
                expect(18)?;
                let mut b = [0u8; 18];
                b.copy_from_slice(data);
                Command::ConfigEeprom(EepromConfig::from_bytes(&b))
            }
            CommandCode::ConfigPacketData => {
                expect(6)?;
                Command::ConfigPacketData(PacketConfig {
                    packet_size_bytes: u16::from_le_bytes([data[0], data[1]]),
                    delay_clocks: u16::from_le_bytes([data[2], data[3]]),
                })
            }
            CommandCode::SystemError => return Err(CodecError::UnknownCode(raw_code)),
            other => {
                expect(0)?;
                match other {
                    CommandCode::ResetFpga => Command::ResetFpga,
                    CommandCode::ResetArDevice => Command::ResetArDevice,
                    CommandCode::RecordStart => Command::RecordStart,
                    CommandCode::RecordStop => Command::RecordStop,
                    CommandCode::PlaybackStart => Command::PlaybackStart,
                    CommandCode::PlaybackStop => Command::PlaybackStop,
                    CommandCode::SystemConnect => Command::SystemConnect,
                    CommandCode::ConfigDataModeArDev => Command::ConfigDataModeArDev,
                    CommandCode::InitFpgaPlayback => Command::InitFpgaPlayback,
                    _ => Command::ReadFpgaVersion,
                }
            }
        })
    }
}

/// An 8-byte response or an unsolicited status packet.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Response {
    /// The echoed command code (0x0A for an async status packet).
    pub code: u16,
    pub status: u16,
}

impl Response {
    /// Parses 8 response bytes, checking header, footer and length.
    pub fn decode(bytes: &[u8]) -> Result<Self, CodecError> {
        if bytes.len() != RESPONSE_LEN {
            return Err(CodecError::BadResponseLength { len: bytes.len() });
        }
        let word = |i: usize| u16::from_le_bytes([bytes[i], bytes[i + 1]]);
        if word(0) != HEADER {
            return Err(CodecError::BadHeader { got: word(0) });
        }
        if word(6) != FOOTER {
            return Err(CodecError::BadFooter { got: word(6) });
        }
        Ok(Self {
            code: word(2),
            status: word(4),
        })
    }

    /// The 8 response bytes.
    pub fn encode(&self) -> [u8; RESPONSE_LEN] {
        let mut out = [0u8; RESPONSE_LEN];
        out[0..2].copy_from_slice(&HEADER.to_le_bytes());
        out[2..4].copy_from_slice(&self.code.to_le_bytes());
        out[4..6].copy_from_slice(&self.status.to_le_bytes());
        out[6..8].copy_from_slice(&FOOTER.to_le_bytes());
        out
    }

    /// Whether this is an unsolicited status packet (code 0x0A).
    pub fn is_async_status(&self) -> bool {
        self.code == CommandCode::SystemError as u16
    }
}

/// The FPGA version carried in `READ_FPGA_VERSION`'s status field.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub struct FpgaVersion {
    pub major: u8,
    pub minor: u8,
    /// True for the playback bitfile, false for the record bitfile.
    pub playback: bool,
}

impl FpgaVersion {
    /// Decodes bits 0–6 (major), 7–13 (minor) and 14 (playback).
    pub fn from_status(status: u16) -> Self {
        Self {
            major: (status & 0x7F) as u8,
            minor: ((status >> 7) & 0x7F) as u8,
            playback: status & (1 << 14) != 0,
        }
    }

    /// The inverse of [`FpgaVersion::from_status`].
    pub fn to_status(self) -> u16 {
        u16::from(self.major & 0x7F)
            | (u16::from(self.minor & 0x7F) << 7)
            | (u16::from(self.playback) << 14)
    }
}

/// One event of the async status bitmask (A4).
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub enum AsyncEvent {
    NoLvdsData,
    NoHeader,
    EepromFailure,
    SdCardDetected,
    SdCardRemoved,
    SdCardFull,
    ModeConfigFailure,
    DdrFull,
    RecordCompleted,
    LvdsBufferFull,
    PlaybackCompleted,
    PlaybackOutOfSequence,
    /// A bit that A4 does not name.
    Unknown(u8),
}

impl AsyncEvent {
    const NAMED: [AsyncEvent; 12] = [
        AsyncEvent::NoLvdsData,
        AsyncEvent::NoHeader,
        AsyncEvent::EepromFailure,
        AsyncEvent::SdCardDetected,
        AsyncEvent::SdCardRemoved,
        AsyncEvent::SdCardFull,
        AsyncEvent::ModeConfigFailure,
        AsyncEvent::DdrFull,
        AsyncEvent::RecordCompleted,
        AsyncEvent::LvdsBufferFull,
        AsyncEvent::PlaybackCompleted,
        AsyncEvent::PlaybackOutOfSequence,
    ];

    /// The bit of this event in the mask.
    pub fn bit(self) -> u8 {
        match self {
            AsyncEvent::Unknown(bit) => bit,
            named => Self::NAMED.iter().position(|&e| e == named).unwrap_or(0) as u8,
        }
    }

    /// Every event set in `mask`, lowest bit first.
    pub fn decode(mask: u16) -> Vec<AsyncEvent> {
        (0..16u8)
            .filter(|bit| mask & (1 << bit) != 0)
            .map(|bit| {
                Self::NAMED
                    .get(usize::from(bit))
                    .copied()
                    .unwrap_or(AsyncEvent::Unknown(bit))
            })
            .collect()
    }

    /// The mask with exactly these events set.
    pub fn encode(events: &[AsyncEvent]) -> u16 {
        events
            .iter()
            .fold(0u16, |m, e| m | (1u16 << (e.bit() & 15)))
    }

    /// Whether the TI record tool stops recording on this event (bits 0, 1 and 8).
    pub fn stops_recording(self) -> bool {
        matches!(
            self,
            AsyncEvent::NoLvdsData | AsyncEvent::NoHeader | AsyncEvent::RecordCompleted
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn hex(s: &str) -> Vec<u8> {
        s.split_whitespace()
            .map(|b| u8::from_str_radix(b, 16).unwrap())
            .collect()
    }

    #[test]
    fn commands_match_the_byte_examples_of_a3() {
        let cases = [
            (Command::SystemConnect, "5A A5 09 00 00 00 AA EE"),
            (Command::ReadFpgaVersion, "5A A5 0E 00 00 00 AA EE"),
            (
                Command::ConfigFpgaGen(FpgaConfig::default()),
                "5A A5 03 00 06 00 01 01 01 02 03 1E AA EE",
            ),
            (
                Command::ConfigPacketData(PacketConfig::from_delay_us(1470, 25.0).unwrap()),
                "5A A5 0B 00 06 00 BE 05 35 0C 00 00 AA EE",
            ),
            (Command::RecordStart, "5A A5 05 00 00 00 AA EE"),
            (Command::RecordStop, "5A A5 06 00 00 00 AA EE"),
            (Command::ResetFpga, "5A A5 01 00 00 00 AA EE"),
            (Command::ResetArDevice, "5A A5 02 00 00 00 AA EE"),
        ];
        for (command, bytes) in cases {
            assert_eq!(command.encode(), hex(bytes), "{command:?}");
            assert_eq!(Command::decode(&hex(bytes)).unwrap(), command);
        }
    }

    #[test]
    fn eeprom_addresses_are_reversed_on_the_wire() {
        let c = EepromConfig {
            host_ip: Ipv4Addr::new(192, 168, 33, 30),
            fpga_ip: Ipv4Addr::new(192, 168, 33, 180),
            fpga_mac: [0x12, 0x34, 0x56, 0x78, 0x90, 0x12],
            config_port: 4096,
            data_port: 4098,
        };
        let bytes = Command::ConfigEeprom(c).encode();
        assert_eq!(
            &bytes[6..24],
            &hex("1E 21 A8 C0 B4 21 A8 C0 12 90 78 56 34 12 00 10 02 10")[..]
        );
        assert_eq!(Command::decode(&bytes).unwrap(), Command::ConfigEeprom(c));
    }

    #[test]
    fn malformed_requests_are_refused_with_the_offending_value() {
        let mut bad_footer = Command::SystemConnect.encode();
        bad_footer[7] = 0xEF;
        assert_eq!(
            Command::decode(&bad_footer),
            Err(CodecError::BadFooter { got: 0xEFAA })
        );
        assert_eq!(
            Command::decode(&hex("5A A5 03 00 02 00 01 01 AA EE")),
            Err(CodecError::BadDataSize {
                code: 3,
                expected: 6,
                actual: 2
            })
        );
        assert_eq!(
            Command::decode(&hex("5A A5 99 00 00 00 AA EE")),
            Err(CodecError::UnknownCode(0x99))
        );
        assert!(matches!(
            Command::decode(&hex("5A A5 09 00 04 00 AA EE")),
            Err(CodecError::SizeMismatch { .. })
        ));
        let fpga = FpgaConfig {
            data_format: 7,
            ..FpgaConfig::default()
        };
        assert_eq!(
            fpga.validate(),
            Err(CodecError::BadField {
                field: "data_format",
                value: 7
            })
        );
    }

    #[test]
    fn responses_round_trip_and_are_validated() {
        let r = Response::decode(&hex("5A A5 09 00 00 00 AA EE")).unwrap();
        assert_eq!(r, Response { code: 9, status: 0 });
        assert_eq!(r.encode().to_vec(), hex("5A A5 09 00 00 00 AA EE"));
        assert_eq!(
            Response::decode(&hex("5A A5 09 00 00 00 AA")),
            Err(CodecError::BadResponseLength { len: 7 })
        );
        assert_eq!(
            Response::decode(&hex("5B A5 09 00 00 00 AA EE")),
            Err(CodecError::BadHeader { got: 0xA55B })
        );
    }

    #[test]
    fn fpga_version_and_async_status_decode() {
        let v = FpgaVersion {
            major: 2,
            minor: 9,
            playback: false,
        };
        assert_eq!(v.to_status(), 2 | (9 << 7));
        assert_eq!(FpgaVersion::from_status(v.to_status()), v);
        let events = AsyncEvent::decode(0b1_1000_0001 | (1 << 14));
        assert_eq!(
            events,
            vec![
                AsyncEvent::NoLvdsData,
                AsyncEvent::DdrFull,
                AsyncEvent::RecordCompleted,
                AsyncEvent::Unknown(14)
            ]
        );
        assert_eq!(AsyncEvent::encode(&events), 0b1_1000_0001 | (1 << 14));
        assert!(AsyncEvent::RecordCompleted.stops_recording());
        assert!(!AsyncEvent::DdrFull.stops_recording());
    }
}
