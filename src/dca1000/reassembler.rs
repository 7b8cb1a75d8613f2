//! Sans-IO reassembly of the raw data stream into frames (docs/protocols.md A5).
//!
//! Payloads are placed by their byte offset, never by arrival order or by "a frame starts a
//! packet": frames are not packet-aligned (an 8192-byte frame is 5.63 packets). Frame k occupies
//! stream bytes `[k·F, (k+1)·F)`. A frame is handed out as soon as every byte of it has arrived,
//! or, with the bytes that are missing zero-filled and listed in [`Frame::gaps`], once the stream
//! has moved `reorder_window_bytes` past its end (or at [`Reassembler::finish`]). Nothing is
//! zero-filled silently: a frame with a gap is flagged and counted.
//!
//! Counters, all by sequence number except `late`:
//! - `lost`: sequence numbers never received in the span the stream covers;
//! - `duplicates`: a sequence number received again (the copy is dropped);
//! - `reordered`: a packet that arrived after one with a higher sequence number;
//! - `late`: a packet, or the part of one, whose frame had already been handed out.

use std::collections::VecDeque;

use super::packet::{DataPacket, PacketError, RAW_PAYLOAD_LEN};

/// Default distance past a frame's end after which it is handed out incomplete: 64 packets.
pub const DEFAULT_REORDER_WINDOW_BYTES: u64 = 64 * RAW_PAYLOAD_LEN as u64;
/// The sequence window starts this far below the sequence number of stream offset 0.
const SEQUENCE_SLACK: u32 = 4096;
/// Offsets more than this far past the furthest byte seen (24 s of the mmNorm stream) are
/// treated as corrupt: the frames in between would be allocated.
const MAX_OFFSET_JUMP_BYTES: u64 = 64 << 20;
/// In raw mode a packet's sequence number and byte offset advance together (every payload but
/// the last is 1456 bytes). A packet whose sequence number is further than this from the one its
/// offset implies is treated as corrupt; this also bounds the memory of the sequence set.
const MAX_SEQUENCE_SKEW: u32 = 1 << 16;
/// Sequence numbers tracked past the window's base: 2²⁷ packets (195 GB, 20 h of the mmNorm
/// stream) in a 16 MiB bit set.
const MAX_TRACKED_SEQUENCES: u32 = 1 << 27;

/// One frame of the stream.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Frame {
    /// Frame number k from the start of the recording.
    pub index: u64,
    /// F bytes, exactly as the FPGA sent them, with gaps zero-filled.
    pub data: Vec<u8>,
    /// Byte ranges `[start, end)` within the frame that never arrived and were zero-filled.
    pub gaps: Vec<(usize, usize)>,
}

impl Frame {
    /// Whether every byte arrived.
    pub fn is_complete(&self) -> bool {
        self.gaps.is_empty()
    }

    /// Zero-filled bytes in this frame.
    pub fn missing_bytes(&self) -> usize {
        self.gaps.iter().map(|(a, b)| b - a).sum()
    }
}

/// Counters of a stream. `lost` is final only after [`Reassembler::finish`].
#[derive(Debug, Clone, Default, PartialEq, Eq, serde::Serialize)]
pub struct StreamStats {
    /// Datagrams that parsed as data packets.
    pub packets: u64,
    /// Payload bytes placed into frames.
    pub bytes: u64,
    pub lost: u64,
    pub duplicates: u64,
    pub reordered: u64,
    pub late: u64,
    /// Datagrams that were not data packets, or carried an implausible offset.
    pub malformed: u64,
    /// Payload bytes past the expected end of the recording, discarded.
    pub beyond_end_bytes: u64,
    pub frames: u64,
    /// Frames handed out with at least one zero-filled gap.
    pub flagged_frames: u64,
    pub zero_filled_bytes: u64,
}

/// A frame still being filled: its bytes and the sorted, disjoint byte ranges received.
struct Pending {
    data: Vec<u8>,
    filled: Vec<(usize, usize)>,
}

impl Pending {
    fn new(frame_bytes: usize) -> Self {
        Self {
            data: vec![0; frame_bytes],
            filled: Vec::new(),
        }
    }

    fn is_full(&self) -> bool {
        self.filled.len() == 1 && self.filled[0] == (0, self.data.len())
    }

    /// Records `[start, end)` as received, merging ranges.
    fn mark(&mut self, start: usize, end: usize) {
        let mut merged = (start, end);
        self.filled.retain(|&(a, b)| {
            if b < merged.0 || a > merged.1 {
                true
            } else {
                merged = (merged.0.min(a), merged.1.max(b));
                false
            }
        });
        let at = self.filled.partition_point(|&(a, _)| a < merged.0);
        self.filled.insert(at, merged);
    }

    fn gaps(&self) -> Vec<(usize, usize)> {
        let mut gaps = Vec::new();
        let mut cursor = 0;
        for &(a, b) in &self.filled {
            if a > cursor {
                gaps.push((cursor, a));
            }
            cursor = b;
        }
        if cursor < self.data.len() {
            gaps.push((cursor, self.data.len()));
        }
        gaps
    }
}

/// A growable set of sequence numbers relative to a base.
struct SequenceSet {
    base: u32,
    bits: Vec<u64>,
}

impl SequenceSet {
    fn new(base: u32) -> Self {
        Self {
            base,
            bits: Vec::new(),
        }
    }

    /// Inserts `seq`; returns whether it was new. `None` if it lies outside the window
    /// (sequence numbers compare modulo 2³²).
    fn insert(&mut self, seq: u32) -> Option<bool> {
        let i = seq.wrapping_sub(self.base);
        if i >= MAX_TRACKED_SEQUENCES {
            return None;
        }
        let i = i as usize;
        let (word, bit) = (i / 64, i % 64);
        if word >= self.bits.len() {
            self.bits.resize(word + 1, 0);
        }
        let fresh = self.bits[word] & (1 << bit) == 0;
        self.bits[word] |= 1 << bit;
        Some(fresh)
    }

    /// How many of `first ..= last` are in the set.
    fn count_in(&self, first: u32, last: u32) -> u64 {
        let lo = u64::from(first.wrapping_sub(self.base));
        let hi = u64::from(last.wrapping_sub(self.base));
        if hi < lo {
            return 0;
        }
        let mut total = 0u64;
        for (w, &word) in self.bits.iter().enumerate() {
            let (start, end) = (w as u64 * 64, w as u64 * 64 + 63);
            if end < lo || start > hi {
                continue;
            }
            let mut mask = u64::MAX;
            if lo > start {
                mask &= u64::MAX << (lo - start);
            }
            if hi < end {
                mask &= u64::MAX >> (end - hi);
            }
            total += u64::from((word & mask).count_ones());
        }
        total
    }
}

/// The reassembler. Feed it datagrams with [`push`](Self::push), take frames with
/// [`pop_frame`](Self::pop_frame), and call [`finish`](Self::finish) when the recording stopped.
pub struct Reassembler {
    frame_bytes: usize,
    reorder_window_bytes: u64,
    expected_frames: Option<u64>,
    next_frame: u64,
    pending: VecDeque<Pending>,
    ready: VecDeque<Frame>,
    stats: StreamStats,
    sequences: Option<SequenceSet>,
    /// Sequence number of stream offset 0, inferred from the first packet (raw mode: every
    /// packet but the last carries 1456 bytes).
    origin_sequence: Option<u32>,
    max_sequence: Option<u32>,
    max_end_offset: u64,
}

impl Reassembler {
    /// A reassembler for frames of `frame_bytes` bytes. With `expected_frames`, bytes past the
    /// end of the recording are discarded and counted, and `finish` hands out every frame up to
    /// it, flagged where nothing arrived.
    pub fn new(frame_bytes: usize, expected_frames: Option<u64>) -> Self {
        Self {
            frame_bytes: frame_bytes.max(1),
            reorder_window_bytes: DEFAULT_REORDER_WINDOW_BYTES,
            expected_frames,
            next_frame: 0,
            pending: VecDeque::new(),
            ready: VecDeque::new(),
            stats: StreamStats::default(),
            sequences: None,
            origin_sequence: None,
            max_sequence: None,
            max_end_offset: 0,
        }
    }

    /// Sets how far past a frame's end the stream must move before the frame is handed out
    /// incomplete.
    pub fn with_reorder_window_bytes(mut self, bytes: u64) -> Self {
        self.reorder_window_bytes = bytes;
        self
    }

    /// The counters so far.
    pub fn stats(&self) -> &StreamStats {
        &self.stats
    }

    /// Stream bytes per frame.
    pub fn frame_bytes(&self) -> usize {
        self.frame_bytes
    }

    /// The furthest stream offset received.
    pub fn max_end_offset(&self) -> u64 {
        self.max_end_offset
    }

    /// The next frame ready to hand out, in order.
    pub fn pop_frame(&mut self) -> Option<Frame> {
        self.ready.pop_front()
    }

    /// Takes one datagram from the data port.
    pub fn push(&mut self, datagram: &[u8]) -> Result<(), PacketError> {
        let packet = match DataPacket::parse(datagram) {
            Ok(p) => p,
            Err(e) => {
                self.stats.malformed += 1;
                return Err(e);
            }
        };
        if packet.end_offset() > self.max_end_offset.saturating_add(MAX_OFFSET_JUMP_BYTES) {
            self.stats.malformed += 1;
            return Ok(());
        }
        if !self.is_plausible(&packet) {
            self.stats.malformed += 1;
            return Ok(());
        }
        self.stats.packets += 1;
        if !self.note_sequence(&packet) {
            self.stats.duplicates += 1;
            return Ok(());
        }
        self.place(&packet);
        self.release(false);
        Ok(())
    }

    /// Whether the sequence number agrees with the offset, given the first packet's.
    fn is_plausible(&self, packet: &DataPacket<'_>) -> bool {
        let Some(origin) = self.origin_sequence else {
            return true;
        };
        let implied = origin.wrapping_add((packet.byte_offset / RAW_PAYLOAD_LEN as u64) as u32);
        (packet.sequence.wrapping_sub(implied) as i32).unsigned_abs() <= MAX_SEQUENCE_SKEW
    }

    /// Records the sequence number; false for a duplicate.
    fn note_sequence(&mut self, packet: &DataPacket<'_>) -> bool {
        let seq = packet.sequence;
        let origin = *self.origin_sequence.get_or_insert_with(|| {
            seq.wrapping_sub((packet.byte_offset / RAW_PAYLOAD_LEN as u64) as u32)
        });
        let set = self
            .sequences
            .get_or_insert_with(|| SequenceSet::new(origin.wrapping_sub(SEQUENCE_SLACK)));
        match set.insert(seq) {
            Some(false) => return false,
            Some(true) => {}
            None => self.stats.late += 1,
        }
        match self.max_sequence {
            Some(max) if (seq.wrapping_sub(max) as i32) < 0 => self.stats.reordered += 1,
            _ => self.max_sequence = Some(seq),
        }
        true
    }

    fn place(&mut self, packet: &DataPacket<'_>) {
        let f = self.frame_bytes as u64;
        let mut start = packet.byte_offset;
        let mut end = packet.end_offset();
        if let Some(n) = self.expected_frames {
            let limit = n * f;
            if end > limit {
                self.stats.beyond_end_bytes += end - start.max(limit);
                end = limit;
            }
        }
        let released_end = self.next_frame * f;
        if start < released_end {
            if end > start {
                self.stats.late += 1;
            }
            start = released_end;
        }
        if start >= end {
            return;
        }
        self.max_end_offset = self.max_end_offset.max(end);
        let payload_origin = packet.byte_offset;
        let mut cursor = start;
        while cursor < end {
            let k = cursor / f;
            let frame_start = k * f;
            let piece_end = end.min(frame_start + f);
            let slot = (k - self.next_frame) as usize;
            while self.pending.len() <= slot {
                self.pending.push_back(Pending::new(self.frame_bytes));
            }
            let a = (cursor - frame_start) as usize;
            let b = (piece_end - frame_start) as usize;
            let src = &packet.payload
                [(cursor - payload_origin) as usize..(piece_end - payload_origin) as usize];
            let frame = &mut self.pending[slot];
            frame.data[a..b].copy_from_slice(src);
            frame.mark(a, b);
            self.stats.bytes += (b - a) as u64;
            cursor = piece_end;
        }
    }

    /// Hands out complete frames at the front, and incomplete ones the stream has left behind
    /// (all of them when `all`).
    fn release(&mut self, all: bool) {
        let f = self.frame_bytes as u64;
        while let Some(front) = self.pending.front() {
            let frame_end = (self.next_frame + 1) * f;
            let left_behind = frame_end + self.reorder_window_bytes <= self.max_end_offset;
            if !(front.is_full() || left_behind || all) {
                break;
            }
            let Some(done) = self.pending.pop_front() else {
                break;
            };
            self.emit(done);
        }
    }

    fn emit(&mut self, done: Pending) {
        let gaps = done.gaps();
        let frame = Frame {
            index: self.next_frame,
            data: done.data,
            gaps,
        };
        self.next_frame += 1;
        self.stats.frames += 1;
        if !frame.is_complete() {
            self.stats.flagged_frames += 1;
            self.stats.zero_filled_bytes += frame.missing_bytes() as u64;
        }
        self.ready.push_back(frame);
    }

    /// The radar stopped before the expected count: the recording ends with the data that
    /// arrives, and [`finish`](Self::finish) neither pads nor counts the frames never made.
    pub fn end_early(&mut self) {
        self.expected_frames = None;
    }

    /// Ends the recording: hands out every pending frame (and, with `expected_frames`, every
    /// frame up to it) and computes the final lost count over the span of sequence numbers the
    /// recording covers. Returns the final counters; frames remain available to
    /// [`pop_frame`](Self::pop_frame).
    pub fn finish(&mut self) -> StreamStats {
        self.release(true);
        if let Some(n) = self.expected_frames {
            while self.next_frame < n {
                self.emit(Pending::new(self.frame_bytes));
            }
        }
        self.stats.lost = self.lost_packets();
        self.stats.clone()
    }

    /// Sequence numbers missing from `origin ..= last`, where `last` is the highest sequence
    /// seen or, with `expected_frames`, the sequence of the recording's final raw packet.
    fn lost_packets(&self) -> u64 {
        let (Some(origin), Some(set)) = (self.origin_sequence, &self.sequences) else {
            return self.expected_frames.map_or(0, |n| {
                (n * self.frame_bytes as u64).div_ceil(RAW_PAYLOAD_LEN as u64)
            });
        };
        let mut last = self.max_sequence.unwrap_or(origin);
        if let Some(n) = self.expected_frames {
            let total = (n * self.frame_bytes as u64).div_ceil(RAW_PAYLOAD_LEN as u64);
            if total > 0 {
                last = origin.wrapping_add(u32::try_from(total - 1).unwrap_or(u32::MAX));
            }
        }
        let span = u64::from(last.wrapping_sub(origin)) + 1;
        if span > u64::from(MAX_TRACKED_SEQUENCES) {
            return 0;
        }
        span - set.count_in(origin, last).min(span)
    }
}

#[cfg(test)]
mod tests {
    use super::super::packet::packetize;
    use super::*;

    fn stream(frames: usize, frame_bytes: usize) -> Vec<u8> {
        (0..frames * frame_bytes)
            .map(|i| (i.wrapping_mul(2_654_435_761) >> 13) as u8)
            .collect()
    }

    fn drain(r: &mut Reassembler) -> Vec<Frame> {
        std::iter::from_fn(|| r.pop_frame()).collect()
    }

    #[test]
    fn in_order_stream_gives_every_frame_bit_exact() {
        let s = stream(10, 8192);
        let mut r = Reassembler::new(8192, Some(10));
        for p in packetize(&s, 1) {
            r.push(&p).unwrap();
        }
        let stats = r.finish();
        let frames = drain(&mut r);
        assert_eq!(frames.len(), 10);
        for f in &frames {
            assert!(f.is_complete());
            let k = f.index as usize;
            assert_eq!(f.data, s[k * 8192..(k + 1) * 8192]);
        }
        assert_eq!(
            (stats.lost, stats.duplicates, stats.reordered, stats.late),
            (0, 0, 0, 0)
        );
        assert_eq!(stats.bytes, s.len() as u64);
    }

    #[test]
    fn a_lost_packet_is_counted_and_its_frames_flagged() {
        let s = stream(10, 8192);
        let mut r = Reassembler::new(8192, Some(10));
        let packets = packetize(&s, 1);
        for (i, p) in packets.iter().enumerate() {
            if i != 11 {
                r.push(p).unwrap();
            }
        }
        let stats = r.finish();
        let frames = drain(&mut r);
        assert_eq!(stats.lost, 1);
        // Packet 11 holds bytes 16016..17472: frames 1 (to 16384) and 2.
        let flagged: Vec<u64> = frames
            .iter()
            .filter(|f| !f.is_complete())
            .map(|f| f.index)
            .collect();
        assert_eq!(flagged, vec![1, 2]);
        assert_eq!(frames[1].gaps, vec![(16016 - 8192, 8192)]);
        assert_eq!(frames[2].gaps, vec![(0, 17472 - 16384)]);
        assert_eq!(stats.zero_filled_bytes, 1456);
        assert!(frames[2].data[..1088].iter().all(|&b| b == 0));
    }

    #[test]
    fn reordered_and_duplicated_packets_still_give_exact_frames() {
        let s = stream(6, 8192);
        let mut packets = packetize(&s, 1);
        packets.swap(3, 5);
        let dup = packets[8].clone();
        packets.insert(9, dup);
        let mut r = Reassembler::new(8192, Some(6));
        for p in &packets {
            r.push(p).unwrap();
        }
        let stats = r.finish();
        let frames = drain(&mut r);
        assert!(frames.iter().all(Frame::is_complete));
        assert_eq!(frames.concat_data(), s);
        // Sequence 4 arrived after 6, and 5 after 6: two reordered arrivals.
        assert_eq!((stats.reordered, stats.duplicates, stats.lost), (2, 1, 0));
    }

    #[test]
    fn losing_the_tail_flags_the_last_frame_and_counts_the_packet() {
        let s = stream(3, 8192);
        let packets = packetize(&s, 1);
        let mut r = Reassembler::new(8192, Some(3));
        for p in &packets[..packets.len() - 1] {
            r.push(p).unwrap();
        }
        let stats = r.finish();
        assert_eq!(stats.lost, 1);
        assert_eq!(stats.flagged_frames, 1);
    }

    #[test]
    fn a_late_packet_past_the_window_is_counted_late_not_placed() {
        let s = stream(40, 8192);
        let packets = packetize(&s, 1);
        let mut r = Reassembler::new(8192, Some(40)).with_reorder_window_bytes(8 * 1456);
        for (i, p) in packets.iter().enumerate() {
            if i != 2 {
                r.push(p).unwrap();
            }
        }
        r.push(&packets[2]).unwrap();
        let stats = r.finish();
        assert_eq!((stats.late, stats.lost, stats.flagged_frames), (1, 0, 1));
    }

    #[test]
    fn garbage_is_counted_and_does_not_disturb_the_stream() {
        let mut r = Reassembler::new(8192, None);
        assert!(r.push(&[1, 2, 3]).is_err());
        let mut far = Vec::new();
        DataPacket {
            sequence: 9,
            byte_offset: 1 << 40,
            payload: &[1; 16],
        }
        .emit(&mut far);
        r.push(&far).unwrap();
        assert_eq!(r.stats().malformed, 2);
        assert_eq!(r.stats().bytes, 0);
        // A sequence number that disagrees with its offset is corrupt, not a reason to track
        // four billion sequence numbers.
        let s = stream(2, 8192);
        let packets = packetize(&s, 1);
        r.push(&packets[0]).unwrap();
        let mut wild = packets[1].clone();
        wild[..4].copy_from_slice(&4_000_000_000u32.to_le_bytes());
        r.push(&wild).unwrap();
        assert_eq!(r.stats().malformed, 3);
        assert_eq!(r.stats().packets, 1);
    }

    trait Concat {
        fn concat_data(&self) -> Vec<u8>;
    }

    impl Concat for Vec<Frame> {
        fn concat_data(&self) -> Vec<u8> {
            self.iter().flat_map(|f| f.data.iter().copied()).collect()
        }
    }
}
