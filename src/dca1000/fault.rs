//! A seeded fault injector for the data stream, in the manner of smoltcp's `FaultInjector`.
//!
//! It sits between the simulator's packetiser and its socket. Each datagram may be dropped,
//! held back and released after up to `reorder_depth` later datagrams, or followed by a copy.
//! A burst drops a run of consecutive datagrams. The injector keeps its own ground truth of what
//! it did, measured on the stream it emits, so tests can compare the receiver's counters with it.

use crate::signal::Rng;

/// What to inject. Probabilities are per datagram.
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct FaultConfig {
    pub seed: u64,
    pub loss_probability: f64,
    pub reorder_probability: f64,
    /// A reordered datagram is released after 1..=depth later ones.
    pub reorder_depth: usize,
    pub duplicate_probability: f64,
    /// Drop `burst_len` consecutive datagrams starting at datagram index `burst_start`.
    pub burst_start: Option<u64>,
    pub burst_len: u64,
}

impl FaultConfig {
    /// Whether any fault is configured.
    pub fn is_active(&self) -> bool {
        self.loss_probability > 0.0
            || self.reorder_probability > 0.0
            || self.duplicate_probability > 0.0
            || (self.burst_start.is_some() && self.burst_len > 0)
    }

    /// Checks that probabilities are probabilities.
    pub fn validate(&self) -> Result<(), String> {
        for (name, p) in [
            ("loss_probability", self.loss_probability),
            ("reorder_probability", self.reorder_probability),
            ("duplicate_probability", self.duplicate_probability),
        ] {
            if !(0.0..=1.0).contains(&p) {
                return Err(format!("faults.{name} = {p} must lie in 0..=1"));
            }
        }
        if self.reorder_probability > 0.0 && self.reorder_depth == 0 {
            return Err("faults.reorder_depth = 0 must be at least 1 when reordering".into());
        }
        Ok(())
    }
}

/// The sequence number of a data datagram (its first four bytes, little-endian).
fn sequence_of(datagram: &[u8]) -> Option<u32> {
    datagram
        .get(..4)
        .map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
}

/// What the injector did, counted on its output.
#[derive(Debug, Clone, Default, PartialEq, Eq, serde::Serialize)]
pub struct InjectedFaults {
    pub dropped: u64,
    /// Sequence numbers of the dropped datagrams, in stream order.
    pub dropped_sequences: Vec<u32>,
    pub duplicated: u64,
    /// Datagrams emitted after one with a higher sequence number.
    pub reordered: u64,
    pub emitted: u64,
}

/// The injector. Feed datagrams in stream order; send what it returns, in order.
pub struct FaultInjector {
    config: FaultConfig,
    rng: Rng,
    index: u64,
    held: Vec<(u64, Vec<u8>, bool)>,
    max_sequence: Option<u32>,
    truth: InjectedFaults,
}

impl FaultInjector {
    pub fn new(config: FaultConfig) -> Self {
        Self {
            rng: Rng::new(config.seed),
            config,
            index: 0,
            held: Vec::new(),
            max_sequence: None,
            truth: InjectedFaults::default(),
        }
    }

    /// The ground truth so far.
    pub fn truth(&self) -> &InjectedFaults {
        &self.truth
    }

    /// Takes the next datagram and appends what to send now to `out`.
    pub fn push(&mut self, datagram: Vec<u8>, out: &mut Vec<Vec<u8>>) {
        let index = self.index;
        self.index += 1;
        let in_burst = self
            .config
            .burst_start
            .is_some_and(|s| index >= s && index < s + self.config.burst_len);
        let lose = in_burst || self.roll(self.config.loss_probability);
        let duplicate = self.roll(self.config.duplicate_probability);
        let hold = self.held.is_empty() && self.roll(self.config.reorder_probability);
        if lose {
            self.truth.dropped += 1;
            if let Some(seq) = sequence_of(&datagram) {
                self.truth.dropped_sequences.push(seq);
            }
        } else if hold {
            let depth = 1 + (self.rng.next_u64() % self.config.reorder_depth.max(1) as u64);
            self.held.push((index + depth, datagram, duplicate));
        } else {
            self.emit(datagram, duplicate, out);
        }
        self.release(index, out);
    }

    /// Releases everything still held.
    pub fn flush(&mut self, out: &mut Vec<Vec<u8>>) {
        self.release(u64::MAX, out);
    }

    fn roll(&mut self, p: f64) -> bool {
        p > 0.0 && self.rng.uniform() < p
    }

    fn release(&mut self, index: u64, out: &mut Vec<Vec<u8>>) {
        let mut i = 0;
        while i < self.held.len() {
            if self.held[i].0 <= index {
                let (_, d, dup) = self.held.remove(i);
                self.emit(d, dup, out);
            } else {
                i += 1;
            }
        }
    }

    fn emit(&mut self, datagram: Vec<u8>, duplicate: bool, out: &mut Vec<Vec<u8>>) {
        if let Some(seq) = sequence_of(&datagram) {
            match self.max_sequence {
                Some(max) if seq < max => self.truth.reordered += 1,
                _ => self.max_sequence = Some(seq),
            }
        }
        if duplicate {
            self.truth.duplicated += 1;
            self.truth.emitted += 1;
            out.push(datagram.clone());
        }
        self.truth.emitted += 1;
        out.push(datagram);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_same_seed_injects_the_same_faults() {
        let config = FaultConfig {
            seed: 7,
            loss_probability: 0.05,
            reorder_probability: 0.05,
            reorder_depth: 4,
            duplicate_probability: 0.02,
            ..FaultConfig::default()
        };
        let run = || {
            let mut f = FaultInjector::new(config.clone());
            let mut out = Vec::new();
            for seq in 0u32..2000 {
                f.push(seq.to_le_bytes().to_vec(), &mut out);
            }
            f.flush(&mut out);
            (out, f.truth().clone())
        };
        let (a, ta) = run();
        let (b, tb) = run();
        assert_eq!(a, b);
        assert_eq!(ta, tb);
        assert!(
            ta.dropped > 50 && ta.reordered > 20 && ta.duplicated > 10,
            "{ta:?}"
        );
        assert_eq!(ta.emitted, 2000 - ta.dropped + ta.duplicated);
    }
}
