//! Raw data packets of the data port (docs/protocols.md A5).
//!
//! | offset | size | field |
//! |---|---|---|
//! | 0 | 4 | `u32` LE sequence number, per data port |
//! | 4 | 6 | `u48` LE byte offset: payload bytes sent on this port before this packet |
//! | 10 | ≤ 1456 | payload (always 1456 in raw mode except the final flush) |

/// Bytes before the payload.
pub const HEADER_LEN: usize = 10;
/// The payload of every raw-mode packet but the last, bytes.
pub const RAW_PAYLOAD_LEN: usize = 1456;
/// Largest payload accepted: a 1472-byte packet (the largest `CONFIG_PACKET_DATA` size) less
/// the header.
pub const MAX_PAYLOAD_LEN: usize = 1472 - HEADER_LEN;
/// Largest byte offset a `u48` holds.
pub const MAX_OFFSET: u64 = (1 << 48) - 1;

/// Why a datagram is not a data packet.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum PacketError {
    #[error("datagram of {len} bytes has no payload after the {HEADER_LEN}-byte header")]
    TooShort { len: usize },
    #[error("payload of {len} bytes exceeds the {MAX_PAYLOAD_LEN}-byte maximum")]
    TooLong { len: usize },
}

/// Where a received data packet sat in the stream and when it arrived.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct PacketArrival {
    pub byte_offset: u64,
    pub payload_len: u32,
    /// Host monotonic time, seconds since the recording's epoch.
    pub host_s: f64,
}

/// A checked view of one data packet.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct DataPacket<'a> {
    pub sequence: u32,
    pub byte_offset: u64,
    pub payload: &'a [u8],
}

impl<'a> DataPacket<'a> {
    /// Parses a datagram: a header and 1..=1462 payload bytes.
    pub fn parse(datagram: &'a [u8]) -> Result<Self, PacketError> {
        if datagram.len() <= HEADER_LEN {
            return Err(PacketError::TooShort {
                len: datagram.len(),
            });
        }
        let payload = &datagram[HEADER_LEN..];
        if payload.len() > MAX_PAYLOAD_LEN {
            return Err(PacketError::TooLong { len: payload.len() });
        }
        let sequence = u32::from_le_bytes([datagram[0], datagram[1], datagram[2], datagram[3]]);
        let mut offset = [0u8; 8];
        offset[..6].copy_from_slice(&datagram[4..10]);
        Ok(Self {
            sequence,
            byte_offset: u64::from_le_bytes(offset),
            payload,
        })
    }

    /// Appends the datagram bytes to `out`. The offset is truncated to 48 bits.
    pub fn emit(&self, out: &mut Vec<u8>) {
        out.extend_from_slice(&self.sequence.to_le_bytes());
        out.extend_from_slice(&(self.byte_offset & MAX_OFFSET).to_le_bytes()[..6]);
        out.extend_from_slice(self.payload);
    }

    /// Stream offset just past this payload.
    pub fn end_offset(&self) -> u64 {
        self.byte_offset + self.payload.len() as u64
    }
}

/// Cuts a byte stream into raw-mode datagrams: 1456-byte payloads, sequence numbers from
/// `first_sequence`, and one shorter final packet when the stream does not divide evenly.
pub fn packetize(stream: &[u8], first_sequence: u32) -> Vec<Vec<u8>> {
    stream
        .chunks(RAW_PAYLOAD_LEN)
        .enumerate()
        .map(|(i, chunk)| {
            let mut out = Vec::with_capacity(HEADER_LEN + chunk.len());
            DataPacket {
                sequence: first_sequence.wrapping_add(i as u32),
                byte_offset: (i * RAW_PAYLOAD_LEN) as u64,
                payload: chunk,
            }
            .emit(&mut out);
            out
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn header_fields_are_little_endian() {
        let mut d = vec![0x01, 0x00, 0x00, 0x00, 0xB0, 0x05, 0x00, 0x00, 0x00, 0x01];
        d.extend_from_slice(&[7u8; 1456]);
        let p = DataPacket::parse(&d).unwrap();
        assert_eq!(p.sequence, 1);
        assert_eq!(p.byte_offset, 0x0100_0000_05B0);
        assert_eq!(p.payload.len(), 1456);
        let mut again = Vec::new();
        p.emit(&mut again);
        assert_eq!(again, d);
    }

    #[test]
    fn short_and_long_datagrams_are_refused() {
        assert_eq!(
            DataPacket::parse(&[0u8; 10]),
            Err(PacketError::TooShort { len: 10 })
        );
        assert_eq!(
            DataPacket::parse(&[0u8; 1473]),
            Err(PacketError::TooLong { len: 1463 })
        );
    }

    #[test]
    fn packetize_cuts_full_payloads_and_one_partial_tail() {
        // The 4000-frame capture of docs/protocols.md §0.5: 22 505 full packets and one of 720 bytes.
        let stream = vec![0u8; 4000 * 8192];
        let packets = packetize(&stream, 1);
        assert_eq!(packets.len(), 22_506);
        let last = DataPacket::parse(&packets[22_505]).unwrap();
        assert_eq!(last.payload.len(), 720);
        assert_eq!(last.sequence, 22_506);
        assert_eq!(last.byte_offset, 22_505 * 1456);
        assert_eq!(last.end_offset(), 4000 * 8192);
    }
}
