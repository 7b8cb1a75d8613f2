//! [`LoopbackBoard`]: the simulator's sans-IO core behind the [`CaptureBoard`] trait, with no
//! sockets, in the manner of smoltcp's `Loopback` device. Commands go straight to the core and
//! its datagrams come back on the host side at the core's schedule, through its fault injector.
//! The radar's `sensorStart` reaches it through a [`SensorTrigger`].

use std::collections::VecDeque;
use std::sync::Arc;
use std::sync::mpsc;
use std::time::{Duration, Instant};

use bytes::Bytes;

use super::board::{BoardError, CaptureBoard, Datagram, Exchange, ReceiveCounters};
use super::command::{AsyncEvent, Command, FpgaConfig, FpgaVersion, PacketConfig, Response};
use super::sim::{AdcStream, BoardCore, CoreConfig, Output, SensorTrigger, SimStats, TriggerMsg};

/// The simulated board in-process.
pub struct LoopbackBoard {
    core: BoardCore,
    triggers: mpsc::Receiver<TriggerMsg>,
    trigger: SensorTrigger,
    data: VecDeque<Vec<u8>>,
    control: VecDeque<Response>,
    events: Vec<AsyncEvent>,
}

impl LoopbackBoard {
    pub fn new(config: CoreConfig, source: Arc<AdcStream>) -> Self {
        let (tx, rx) = mpsc::channel();
        Self {
            core: BoardCore::new(config, source),
            triggers: rx,
            trigger: SensorTrigger::new(tx),
            data: VecDeque::new(),
            control: VecDeque::new(),
            events: Vec::new(),
        }
    }

    /// The handle a radar (real or simulated) starts the stream with.
    pub fn trigger(&self) -> SensorTrigger {
        self.trigger.clone()
    }

    /// The simulator's counters, with its injected faults.
    pub fn stats(&self) -> SimStats {
        self.core.stats()
    }

    fn pump(&mut self) {
        while let Ok(msg) = self.triggers.try_recv() {
            match msg {
                TriggerMsg::Start(plan) => self.core.sensor_start(plan, Instant::now()),
                TriggerMsg::Stop => self.core.sensor_stop(Instant::now()),
            }
        }
        self.core.poll(Instant::now());
        while let Some(out) = self.core.pop_output() {
            match out {
                Output::Data(d) => self.data.push_back(d),
                Output::Control(c) => match Response::decode(&c) {
                    Ok(r) if r.is_async_status() => {
                        self.events.extend(AsyncEvent::decode(r.status));
                    }
                    Ok(r) => self.control.push_back(r),
                    Err(_) => {}
                },
            }
        }
    }
}

impl Exchange for LoopbackBoard {
    fn exchange(&mut self, command: Command, name: &'static str) -> Result<u16, BoardError> {
        self.core.handle_command(&command.encode(), Instant::now());
        self.pump();
        while let Some(reply) = self.control.pop_front() {
            if reply.code == command.code() as u16 {
                return Ok(reply.status);
            }
        }
        Err(BoardError::Timeout {
            command: name,
            waited_ms: 0,
        })
    }
}

impl CaptureBoard for LoopbackBoard {
    fn connect(&mut self) -> Result<FpgaVersion, BoardError> {
        self.connect_sequence()
    }

    fn configure(&mut self, fpga: FpgaConfig, packets: PacketConfig) -> Result<(), BoardError> {
        self.configure_sequence(fpga, packets)
    }

    fn start_record(&mut self) -> Result<(), BoardError> {
        self.data.clear();
        self.expect_ok(Command::RecordStart, "RECORD_START")
    }

    fn stop_record(&mut self) -> Result<(), BoardError> {
        self.expect_ok(Command::RecordStop, "RECORD_STOP")
    }

    fn recv_datagram(&mut self, timeout: Duration) -> Result<Option<Datagram>, BoardError> {
        let until = Instant::now() + timeout;
        loop {
            self.pump();
            if let Some(d) = self.data.pop_front() {
                return Ok(Some(Datagram {
                    bytes: Bytes::from(d),
                    received: Instant::now(),
                }));
            }
            let now = Instant::now();
            if now >= until {
                return Ok(None);
            }
            let next = self.core.next_deadline().unwrap_or(until).min(until);
            std::thread::sleep(
                next.saturating_duration_since(now)
                    .clamp(Duration::from_micros(100), Duration::from_millis(2)),
            );
        }
    }

    fn take_events(&mut self) -> Vec<AsyncEvent> {
        self.pump();
        std::mem::take(&mut self.events)
    }

    fn counters(&self) -> ReceiveCounters {
        ReceiveCounters::default()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dca1000::board::{RecordPlan, record_frames};
    use crate::dca1000::fault::FaultConfig;
    use crate::dca1000::sim::StreamPlan;

    #[test]
    fn records_through_the_trait_without_sockets() {
        let source = Arc::new(AdcStream {
            frame_bytes: 8192,
            bytes: (0..200 * 8192).map(|i| (i % 253) as u8).collect(),
        });
        let config = CoreConfig {
            time_scale: 20.0,
            faults: FaultConfig {
                seed: 4,
                loss_probability: 0.01,
                ..FaultConfig::default()
            },
            ..CoreConfig::default()
        };
        let mut board = LoopbackBoard::new(config, source.clone());
        board.connect().unwrap();
        board
            .configure(
                FpgaConfig::default(),
                PacketConfig::from_delay_us(1470, 25.0).unwrap(),
            )
            .unwrap();
        let trigger = board.trigger();
        let plan = RecordPlan {
            frames: 200,
            frame_bytes: 8192,
            frame_period_s: 0.003,
            first_frame_margin: Duration::from_millis(500),
            stop_delay: Duration::from_secs(2),
            epoch: Instant::now(),
        };
        let mut stream = Vec::new();
        struct Sink<'a> {
            trigger: SensorTrigger,
            stream: &'a mut Vec<u8>,
        }
        impl crate::dca1000::board::RecordSink for Sink<'_> {
            fn start_sensor(&mut self) -> Result<(), String> {
                self.trigger.start(StreamPlan {
                    frames: 200,
                    frame_period_s: 0.003,
                    acquired_s: 0.000_07,
                });
                Ok(())
            }
            fn frame(&mut self, f: &crate::dca1000::Frame) -> std::io::Result<()> {
                self.stream.extend_from_slice(&f.data);
                Ok(())
            }
        }
        let report = record_frames(
            &mut board,
            &plan,
            &mut Sink {
                trigger,
                stream: &mut stream,
            },
        )
        .unwrap();
        let injected = board.stats().injected;
        assert_eq!(report.stream.lost, injected.dropped);
        assert!(report.events.contains(&AsyncEvent::RecordCompleted));
        for k in 0..200 {
            let r = k * 8192..(k + 1) * 8192;
            if !report.flagged_frame_indices.contains(&(k as u64)) {
                assert_eq!(stream[r.clone()], source.bytes[r]);
            }
        }
    }
}
