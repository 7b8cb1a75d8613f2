//! Captures: what a scan produced, in memory and on disk.
//!
//! A [`Capture`] is the frequency plan, the range offset, N virtual antennas (a TX and an RX
//! position each, metres) and an N×T array of complex baseband samples. It is the single hand-off
//! between acquisition (simulator or real devices) and reconstruction. This module owns the
//! *capture directory v1* format ([`dir`]) and the `.npy` codec it is built on ([`npy`]); it knows
//! nothing about how samples were produced or how they will be imaged.
//!
//! Sample convention: `h[t] = Σ a·exp(+j·2π·f_t·(d + range_offset_m)/c)` with
//! `f_t = start + t·step`, `d = |TX − p| + |p − RX|` for a reflector at `p`, and
//! `c = 299 792 458 m/s`. The antennas look along −z.

pub mod dir;
pub mod npy;
pub mod space;

use std::sync::Arc;

use num_complex::Complex32;

use crate::SPEED_OF_LIGHT_M_PER_S;

pub use dir::{TruthFiles, read_capture_dir, truth_files, write_capture_dir};

/// The sampled frequencies of one chirp: `f_t = start_frequency_hz + t·frequency_step_hz`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FrequencyPlan {
    pub start_frequency_hz: f64,
    pub frequency_step_hz: f64,
    pub samples_per_chirp: usize,
}

impl FrequencyPlan {
    /// Frequency of sample `t`, Hz.
    pub fn frequency_hz(&self, t: usize) -> f64 {
        self.start_frequency_hz + t as f64 * self.frequency_step_hz
    }

    /// Wavelength of sample 0, metres.
    pub fn first_wavelength_m(&self) -> f64 {
        SPEED_OF_LIGHT_M_PER_S / self.start_frequency_hz
    }

    /// Frequency at the middle of the sweep, Hz.
    pub fn centre_frequency_hz(&self) -> f64 {
        self.start_frequency_hz
            + 0.5 * (self.samples_per_chirp.saturating_sub(1)) as f64 * self.frequency_step_hz
    }

    /// Bandwidth covered by the samples, |step|·T, Hz.
    pub fn bandwidth_hz(&self) -> f64 {
        self.frequency_step_hz.abs() * self.samples_per_chirp as f64
    }

    /// One-way range per bin of a T-point FFT, c/(2·|step|·T), metres.
    pub fn range_bin_m(&self) -> f64 {
        SPEED_OF_LIGHT_M_PER_S / (2.0 * self.bandwidth_hz())
    }

    /// Checks that the plan describes a real sweep.
    pub fn validate(&self) -> Result<(), String> {
        if !(self.start_frequency_hz.is_finite() && self.start_frequency_hz > 0.0) {
            return Err(format!(
                "start_frequency_hz must be positive and finite, found {}",
                self.start_frequency_hz
            ));
        }
        if !(self.frequency_step_hz.is_finite() && self.frequency_step_hz != 0.0) {
            return Err(format!(
                "frequency_step_hz must be finite and non-zero, found {}",
                self.frequency_step_hz
            ));
        }
        if self.samples_per_chirp == 0 {
            return Err("samples_per_chirp must be at least 1, found 0".into());
        }
        let last = self.frequency_hz(self.samples_per_chirp - 1);
        if !(last.is_finite() && last > 0.0) {
            return Err(format!(
                "the last sample's frequency {last} Hz is not positive"
            ));
        }
        Ok(())
    }
}

/// One capture: N virtual antennas with T complex samples each.
#[derive(Debug, Clone, PartialEq)]
pub struct Capture {
    pub plan: FrequencyPlan,
    /// Constant added to every round-trip distance by the radar, metres.
    pub range_offset_m: f64,
    /// TX phase-centre position of each virtual antenna, metres.
    pub tx_m: Vec<[f64; 3]>,
    /// RX position of each virtual antenna, metres.
    pub rx_m: Vec<[f64; 3]>,
    /// N×T samples, antenna-major (C order). Shared: a clone of the capture (to look at it
    /// with another range offset, say) does not copy them; `Arc::make_mut` copies on write.
    pub samples: Arc<Vec<Complex32>>,
    pub description: String,
    /// Keys of `capture.json` that this version does not interpret, kept in order.
    pub extra: serde_json::Map<String, serde_json::Value>,
}

/// An inconsistency inside an in-memory capture.
#[derive(Debug, thiserror::Error)]
#[error("invalid capture: {0}")]
pub struct InvalidCapture(pub String);

impl Capture {
    /// Number of virtual antennas N.
    pub fn antennas(&self) -> usize {
        self.tx_m.len()
    }

    /// The T samples of antenna `i`.
    pub fn chirp(&self, i: usize) -> &[Complex32] {
        let t = self.plan.samples_per_chirp;
        &self.samples[i * t..(i + 1) * t]
    }

    /// The capture restricted to the antennas at `indices` (in that order).
    pub fn subset(&self, indices: &[usize]) -> Capture {
        Capture {
            plan: self.plan,
            range_offset_m: self.range_offset_m,
            tx_m: indices.iter().map(|&i| self.tx_m[i]).collect(),
            rx_m: indices.iter().map(|&i| self.rx_m[i]).collect(),
            samples: Arc::new(
                indices
                    .iter()
                    .flat_map(|&i| self.chirp(i).iter().copied())
                    .collect(),
            ),
            description: self.description.clone(),
            extra: serde_json::Map::new(),
        }
    }

    /// The capture restricted to samples `first..first + len` of every chirp: a sub-band that
    /// starts at `f_first` with the same step.
    pub fn sub_band(&self, first: usize, len: usize) -> Capture {
        let mut plan = self.plan;
        plan.start_frequency_hz = self.plan.frequency_hz(first);
        plan.samples_per_chirp = len;
        Capture {
            plan,
            range_offset_m: self.range_offset_m,
            tx_m: self.tx_m.clone(),
            rx_m: self.rx_m.clone(),
            samples: Arc::new(
                (0..self.antennas())
                    .flat_map(|a| self.chirp(a)[first..first + len].iter().copied())
                    .collect(),
            ),
            description: self.description.clone(),
            extra: serde_json::Map::new(),
        }
    }

    /// Virtual phase centre (TX + RX)/2 of every antenna.
    pub fn centres_m(&self) -> Vec<[f64; 3]> {
        (0..self.tx_m.len()).map(|a| self.centre_m(a)).collect()
    }

    /// Virtual phase centre (TX + RX)/2 of antenna `a`.
    pub fn centre_m(&self, a: usize) -> [f64; 3] {
        let (t, r) = (&self.tx_m[a], &self.rx_m[a]);
        [0, 1, 2].map(|k| 0.5 * (t[k] + r[k]))
    }

    /// Checks shapes and finiteness; the first problem found is reported with its index.
    pub fn validate(&self) -> Result<(), InvalidCapture> {
        self.plan.validate().map_err(InvalidCapture)?;
        if !self.range_offset_m.is_finite() {
            return Err(InvalidCapture(format!(
                "range_offset_m must be finite, found {}",
                self.range_offset_m
            )));
        }
        let n = self.tx_m.len();
        if n == 0 {
            return Err(InvalidCapture(
                "a capture needs at least one antenna".into(),
            ));
        }
        if self.rx_m.len() != n {
            return Err(InvalidCapture(format!(
                "{} TX positions but {} RX positions",
                n,
                self.rx_m.len()
            )));
        }
        let t = self.plan.samples_per_chirp;
        if self.samples.len() != n * t {
            return Err(InvalidCapture(format!(
                "{} samples, expected N×T = {n}×{t} = {}",
                self.samples.len(),
                n * t
            )));
        }
        for (name, positions) in [("TX", &self.tx_m), ("RX", &self.rx_m)] {
            if let Some(i) = positions
                .iter()
                .position(|p| p.iter().any(|v| !v.is_finite()))
            {
                return Err(InvalidCapture(format!(
                    "{name} position of antenna {i} is not finite: {:?}",
                    positions[i]
                )));
            }
        }
        if let Some(k) = self
            .samples
            .iter()
            .position(|s| !(s.re.is_finite() && s.im.is_finite()))
        {
            return Err(InvalidCapture(format!(
                "sample {} of antenna {} is not finite",
                k % t,
                k / t
            )));
        }
        Ok(())
    }
}
