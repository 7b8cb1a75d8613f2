//! The DCA1000 codecs and the reassembler on arbitrary bytes: command and response decoding
//! (with re-encoding round trips), data-packet parsing, and a stream of datagrams (split by
//! a one-byte length prefix) through the reassembler. Nothing may panic, and every frame handed
//! out must be whole.
#![no_main]

use libfuzzer_sys::fuzz_target;
use mmnormd::dca1000::command::{Command, Response};
use mmnormd::dca1000::packet::DataPacket;
use mmnormd::dca1000::reassembler::Reassembler;

fuzz_target!(|data: &[u8]| {
    if let Ok(command) = Command::decode(data) {
        assert_eq!(Command::decode(&command.encode()), Ok(command));
    }
    if let Ok(response) = Response::decode(data) {
        assert_eq!(&response.encode()[..], data);
    }
    if let Ok(packet) = DataPacket::parse(data) {
        let mut again = Vec::new();
        packet.emit(&mut again);
        assert_eq!(DataPacket::parse(&again), Ok(packet));
    }
    let Some((&frame_selector, mut rest)) = data.split_first() else {
        return;
    };
    let frame_bytes = 16 + usize::from(frame_selector) * 32;
    let mut r = Reassembler::new(frame_bytes, Some(64)).with_reorder_window_bytes(4096);
    while let Some((&len, tail)) = rest.split_first() {
        let n = usize::from(len).min(tail.len());
        let (datagram, next) = tail.split_at(n);
        r.push(datagram).ok();
        while let Some(f) = r.pop_frame() {
            assert_eq!(f.data.len(), frame_bytes);
        }
        rest = next;
    }
    let stats = r.finish();
    let mut frames = 0;
    while let Some(f) = r.pop_frame() {
        assert_eq!(f.data.len(), frame_bytes);
        frames += 1;
    }
    assert!(stats.frames <= 64 && frames <= 64);
});
