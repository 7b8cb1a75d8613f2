//! Controller time → host time (docs/protocols.md D3 step 1).
//!
//! Each RTDE package carries the controller's `timestamp` and is stamped with the host's
//! monotonic receive time. Their difference is the clock offset plus a latency that is never
//! negative and mostly small: the lower envelope of `host − controller` over controller time is
//! the offset plus the latency floor, and its slope is the clocks' relative drift. The mapper
//! keeps the minimum of `host − controller` in each bin of controller time (0.5 s by default),
//! over a sliding window of bins (32 s), and fits a line to those minima by least squares.
//!
//! The constant latency floor itself is not observable from the stream; it is part of the
//! residual offset that a forward/backward scan of a point target calibrates (D3 step 3).

use std::collections::VecDeque;

/// Settings of the fit.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ClockConfig {
    /// Controller seconds per bin.
    pub bin_s: f64,
    /// Bins in the sliding window.
    pub window_bins: usize,
    /// Bins needed before a fit is offered.
    pub min_bins: usize,
}

impl Default for ClockConfig {
    fn default() -> Self {
        Self {
            bin_s: 0.5,
            window_bins: 64,
            min_bins: 3,
        }
    }
}

/// The current fit: `host = controller + offset_s + drift · (controller − reference_s)`.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct ClockFit {
    pub offset_s: f64,
    /// Relative drift of the host clock against the controller's (s/s; 1e-6 = 1 ppm).
    pub drift: f64,
    pub reference_s: f64,
    /// RMS and largest |residual| of the bin minima about the line, seconds.
    pub residual_rms_s: f64,
    pub residual_max_s: f64,
    pub bins: usize,
}

impl ClockFit {
    /// Host time of a controller time.
    pub fn host_time(&self, controller_s: f64) -> f64 {
        controller_s + self.offset_s + self.drift * (controller_s - self.reference_s)
    }
}

#[derive(Debug, Clone, Copy)]
struct Bin {
    index: i64,
    controller_s: f64,
    min_offset_s: f64,
}

/// The running mapper.
#[derive(Debug, Clone)]
pub struct ClockMapper {
    config: ClockConfig,
    bins: VecDeque<Bin>,
    fit: Option<ClockFit>,
}

impl ClockMapper {
    pub fn new(config: ClockConfig) -> Self {
        Self {
            config,
            bins: VecDeque::new(),
            fit: None,
        }
    }

    /// The fit so far, once `min_bins` bins have closed.
    pub fn fit(&self) -> Option<ClockFit> {
        self.fit
    }

    /// Host time of a controller time under the current fit.
    pub fn host_time(&self, controller_s: f64) -> Option<f64> {
        self.fit.map(|f| f.host_time(controller_s))
    }

    /// Adds one package: its controller `timestamp` and its host receive time, seconds.
    pub fn push(&mut self, controller_s: f64, host_s: f64) {
        if !(controller_s.is_finite() && host_s.is_finite()) {
            return;
        }
        let index = (controller_s / self.config.bin_s).floor() as i64;
        let offset = host_s - controller_s;
        match self.bins.back_mut() {
            Some(last) if last.index == index => {
                if offset < last.min_offset_s {
                    last.min_offset_s = offset;
                    last.controller_s = controller_s;
                }
                return;
            }
            Some(last) if index < last.index => return,
            _ => {}
        }
        // A bin closed: refit on the closed ones.
        self.bins.push_back(Bin {
            index,
            controller_s,
            min_offset_s: offset,
        });
        while self.bins.len() > self.config.window_bins + 1 {
            self.bins.pop_front();
        }
        self.refit();
    }

    fn refit(&mut self) {
        let closed: Vec<Bin> = self
            .bins
            .iter()
            .take(self.bins.len().saturating_sub(1))
            .copied()
            .collect();
        if closed.len() < self.config.min_bins.max(2) {
            return;
        }
        let n = closed.len() as f64;
        let reference = closed.iter().map(|b| b.controller_s).sum::<f64>() / n;
        let mean_d = closed.iter().map(|b| b.min_offset_s).sum::<f64>() / n;
        let (mut sxx, mut sxy) = (0.0, 0.0);
        for b in &closed {
            let x = b.controller_s - reference;
            sxx += x * x;
            sxy += x * (b.min_offset_s - mean_d);
        }
        let drift = if sxx > 0.0 { sxy / sxx } else { 0.0 };
        let residuals: Vec<f64> = closed
            .iter()
            .map(|b| b.min_offset_s - (mean_d + drift * (b.controller_s - reference)))
            .collect();
        self.fit = Some(ClockFit {
            offset_s: mean_d,
            drift,
            reference_s: reference,
            residual_rms_s: (residuals.iter().map(|r| r * r).sum::<f64>() / n).sqrt(),
            residual_max_s: residuals.iter().fold(0.0f64, |m, r| m.max(r.abs())),
            bins: closed.len(),
        });
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::signal::Rng;

    /// A 500 Hz stream whose host clock runs `ppm` fast, with up to `jitter_s` of latency on top
    /// of a 0.2 ms floor: the mapped time of every package stays within 0.3 ms of its true
    /// host time plus the floor.
    fn mapped_error(ppm: f64, jitter_s: f64, seed: u64) -> f64 {
        let mut rng = Rng::new(seed);
        let mut m = ClockMapper::new(ClockConfig::default());
        let offset = 1234.5;
        let floor = 0.0002;
        let mut worst = 0.0f64;
        for k in 0..(60 * 500) {
            let controller = 100.0 + k as f64 * 0.002;
            let true_host = offset + controller * (1.0 + ppm * 1e-6);
            let latency = floor + jitter_s * rng.uniform();
            m.push(controller, true_host + latency);
            if k > 5 * 500
                && let Some(mapped) = m.host_time(controller)
            {
                worst = worst.max((mapped - (true_host + floor)).abs());
            }
        }
        worst
    }

    #[test]
    fn drift_of_50_ppm_and_1_ms_jitter_map_within_0_3_ms() {
        for (ppm, seed) in [(50.0, 1), (-50.0, 2), (0.0, 3)] {
            let e = mapped_error(ppm, 0.001, seed);
            println!(
                "clock mapping: {ppm:+} ppm, 1 ms jitter: worst mapped error {:.3} ms",
                e * 1e3
            );
            assert!(e < 0.3e-3, "{ppm} ppm: {e}");
        }
    }

    #[test]
    fn the_fit_reports_drift_and_residuals() {
        let mut m = ClockMapper::new(ClockConfig::default());
        for k in 0..5000 {
            let c = k as f64 * 0.002;
            m.push(c, 10.0 + c * (1.0 + 20e-6));
        }
        let f = m.fit().unwrap();
        assert!((f.drift - 20e-6).abs() < 1e-9, "{f:?}");
        assert!(f.residual_max_s < 1e-9);
        assert!(f.bins >= 3);
    }
}
