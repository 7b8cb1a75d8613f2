//! A Fourier sum evaluated on an arbitrary uniform output grid (chirp-z transform, Bluestein).
//!
//! [`Czt`] computes `y_m = Σ_{n<N} x_n·exp(j·(k0 + n·Δk)·(x0 + m·Δx))` for m < M with three FFTs
//! of a length L ≥ N + M − 1. Range-migration imaging uses it to go from wavenumbers to the
//! voxel centres of any grid exactly, where an inverse FFT would land on the aperture's own
//! spacing and need interpolation. With α = Δk·Δx, `n·m = (n² + m² − (m − n)²)/2` turns the sum
//! into a convolution of `x_n·exp(j(Δk·x0·n + α n²/2))` with `exp(−jα p²/2)`; the chirps are
//! formed in f64 and stored in f32.

use std::f64::consts::TAU;
use std::sync::Arc;

use num_complex::{Complex32, Complex64};
use rustfft::{Fft, FftPlanner};

/// A planned chirp-z transform from N wavenumbers to M positions.
pub struct Czt {
    n: usize,
    m: usize,
    forward: Arc<dyn Fft<f32>>,
    inverse: Arc<dyn Fft<f32>>,
    pre: Vec<Complex32>,
    post: Vec<Complex32>,
    kernel: Vec<Complex32>,
}

/// The uniform input wavenumbers and output positions of a [`Czt`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CztAxes {
    /// Input count N, first wavenumber k0 (rad/m) and step Δk.
    pub n: usize,
    pub k0: f64,
    pub dk: f64,
    /// Output count M, first position x0 (m) and step Δx.
    pub m: usize,
    pub x0: f64,
    pub dx: f64,
}

impl Czt {
    pub fn new(axes: CztAxes, planner: &mut FftPlanner<f32>) -> Czt {
        let CztAxes {
            n,
            k0,
            dk,
            m,
            x0,
            dx,
        } = axes;
        let l = fft_friendly((n + m).saturating_sub(1).max(1));
        let alpha = dk * dx;
        // α p²/2 reduced modulo 2π in f64 before the f32 conversion.
        let chirp = |p: f64, sign: f64, extra: f64| {
            let phase = (sign * 0.5 * alpha * p * p + extra).rem_euclid(TAU);
            Complex64::from_polar(1.0, phase)
        };
        let narrow = |z: Complex64| Complex32::new(z.re as f32, z.im as f32);
        let pre = (0..n)
            .map(|i| narrow(chirp(i as f64, 1.0, (dk * x0 * i as f64).rem_euclid(TAU))))
            .collect();
        let scale = 1.0 / l as f64;
        let post = (0..m)
            .map(|i| {
                let extra = (k0 * x0 + k0 * dx * i as f64).rem_euclid(TAU);
                narrow(chirp(i as f64, 1.0, extra) * scale)
            })
            .collect();
        let forward = planner.plan_fft_forward(l);
        let inverse = planner.plan_fft_inverse(l);
        let mut kernel = vec![Complex32::new(0.0, 0.0); l];
        for (p, k) in kernel.iter_mut().enumerate().take(m) {
            *k = narrow(chirp(p as f64, -1.0, 0.0));
        }
        for p in 1..n {
            kernel[l - p] = narrow(chirp(p as f64, -1.0, 0.0));
        }
        forward.process(&mut kernel);
        Czt {
            n,
            m,
            forward,
            inverse,
            pre,
            post,
            kernel,
        }
    }

    /// Input count N.
    pub fn inputs(&self) -> usize {
        self.n
    }

    /// Output count M.
    pub fn outputs(&self) -> usize {
        self.m
    }

    /// Scratch length for [`Czt::apply`].
    pub fn scratch_len(&self) -> usize {
        self.kernel.len()
    }

    /// `output[m] = Σ_n input[n]·exp(j(k0 + nΔk)(x0 + mΔx))`. `scratch` is resized as needed.
    pub fn apply(
        &self,
        input: &[Complex32],
        output: &mut [Complex32],
        scratch: &mut Vec<Complex32>,
    ) {
        let l = self.kernel.len();
        scratch.clear();
        scratch.resize(l, Complex32::new(0.0, 0.0));
        for ((s, x), p) in scratch.iter_mut().zip(input).zip(&self.pre) {
            *s = x * p;
        }
        self.forward.process(scratch);
        for (s, k) in scratch.iter_mut().zip(&self.kernel) {
            *s *= k;
        }
        self.inverse.process(scratch);
        for ((o, s), p) in output.iter_mut().zip(scratch.iter()).zip(&self.post) {
            *o = s * p;
        }
    }
}

/// Windows of consecutive bins of a zero-padded DFT, without the padded FFT.
///
/// Bin k of the `fft_len`-point DFT (negative exponent, as [`rustfft`]'s forward transform) of
/// an N-sample signal zero-padded is `Σ_n x_n·exp(−j2π·k·n/fft_len)`. For bins `first + m`,
/// m < M, that is a chirp-z transform with k0 = 0, Δk = −2π/fft_len, x0 = 0 and Δx = 1 of the
/// signal modulated by `exp(−j2π·first·n/fft_len)` ([`Self::shift`]): one planned [`Czt`]
/// serves every window of up to `max_len` bins, wherever it starts. Its FFTs have the length
/// [`fft_friendly`]`(N + M − 1)` instead of `fft_len`; for the isosurface cost (N = 512, 16×
/// padding, windows of about 150 bins) that is 720 points instead of 8192.
pub struct PaddedDftWindows {
    czt: Czt,
    fft_len: usize,
}

impl PaddedDftWindows {
    pub fn new(
        samples: usize,
        fft_len: usize,
        max_len: usize,
        planner: &mut FftPlanner<f32>,
    ) -> PaddedDftWindows {
        let axes = CztAxes {
            n: samples,
            k0: 0.0,
            dk: -TAU / fft_len.max(1) as f64,
            m: max_len,
            x0: 0.0,
            dx: 1.0,
        };
        PaddedDftWindows {
            czt: Czt::new(axes, planner),
            fft_len: fft_len.max(1),
        }
    }

    /// Most bins per window.
    pub fn max_len(&self) -> usize {
        self.czt.outputs()
    }

    /// The modulation `exp(−j2π·first·n/fft_len)` for windows that start at bin `first` (any
    /// integer: the DFT is periodic), formed in f64.
    pub fn shift(&self, first: i64) -> Vec<Complex32> {
        let l = self.fft_len as i64;
        (0..self.czt.inputs() as i64)
            .map(|n| {
                // first·n reduced modulo fft_len in integers, so the phase stays exact.
                let turns = (first.rem_euclid(l) * n).rem_euclid(l) as f64 / l as f64;
                let z = Complex64::from_polar(1.0, -TAU * turns);
                Complex32::new(z.re as f32, z.im as f32)
            })
            .collect()
    }

    /// Bins `first..first + len` of the padded DFT of `signal` (its first N samples; missing
    /// ones are zeros), with `shift` = [`Self::shift`]`(first)`. `len` is capped at
    /// [`Self::max_len`]; `buffers` holds scratch between calls.
    pub fn window(
        &self,
        signal: &[Complex32],
        shift: &[Complex32],
        len: usize,
        buffers: &mut (Vec<Complex32>, Vec<Complex32>),
    ) -> Vec<Complex32> {
        let (modulated, scratch) = buffers;
        modulated.clear();
        modulated.extend(signal.iter().zip(shift).map(|(x, s)| x * s));
        modulated.resize(self.czt.inputs(), Complex32::new(0.0, 0.0));
        let mut out = vec![Complex32::new(0.0, 0.0); self.czt.outputs()];
        self.czt.apply(modulated, &mut out, scratch);
        out.truncate(len);
        out
    }
}

/// The smallest length ≥ `n` whose only prime factors are 2, 3 and 5.
pub fn fft_friendly(n: usize) -> usize {
    let mut candidate = n.max(1);
    loop {
        let mut r = candidate;
        for p in [2, 3, 5] {
            while r.is_multiple_of(p) {
                r /= p;
            }
        }
        if r == 1 {
            return candidate;
        }
        candidate += 1;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::signal::Rng;

    #[test]
    fn matches_the_direct_sum_in_f64() {
        let mut rng = Rng::new(3);
        let mut planner = FftPlanner::new();
        for (n, m) in [(17usize, 9usize), (64, 100), (250, 37)] {
            let axes = CztAxes {
                n,
                k0: -812.3,
                dk: 6.7,
                m,
                x0: 0.0123,
                dx: 0.00097,
            };
            let czt = Czt::new(axes, &mut planner);
            let input: Vec<Complex32> = (0..n)
                .map(|_| {
                    let (a, b) = rng.normal_pair();
                    Complex32::new(a as f32, b as f32)
                })
                .collect();
            let mut output = vec![Complex32::new(0.0, 0.0); m];
            let mut scratch = Vec::new();
            czt.apply(&input, &mut output, &mut scratch);
            let (mut err, mut sig) = (0.0f64, 0.0f64);
            for (j, o) in output.iter().enumerate() {
                let x = axes.x0 + axes.dx * j as f64;
                let exact: Complex64 = input
                    .iter()
                    .enumerate()
                    .map(|(i, v)| {
                        let k = axes.k0 + axes.dk * i as f64;
                        Complex64::new(f64::from(v.re), f64::from(v.im))
                            * Complex64::from_polar(1.0, k * x)
                    })
                    .sum();
                err += (Complex64::new(f64::from(o.re), f64::from(o.im)) - exact).norm_sqr();
                sig += exact.norm_sqr();
            }
            let ser_db = 10.0 * (sig / err).log10();
            assert!(ser_db > 100.0, "{n}→{m}: {ser_db} dB");
        }
    }

    /// Windows anywhere on the padded axis (before 0, across the wrap, past the end) equal the
    /// bins of the padded FFT.
    #[test]
    fn padded_dft_windows_match_the_padded_fft() {
        let (n, pad) = (96usize, 8usize);
        let l = n * pad;
        let mut rng = Rng::new(11);
        let signal: Vec<Complex32> = (0..n)
            .map(|_| {
                let (a, b) = rng.normal_pair();
                Complex32::new(a as f32, b as f32)
            })
            .collect();
        let mut planner = FftPlanner::new();
        let mut spectrum = signal.clone();
        spectrum.resize(l, Complex32::new(0.0, 0.0));
        planner.plan_fft_forward(l).process(&mut spectrum);
        let peak = spectrum.iter().map(|z| z.norm()).fold(0.0f32, f32::max);
        let windows = PaddedDftWindows::new(n, l, 50, &mut planner);
        let mut buffers = Default::default();
        for (first, len) in [
            (0i64, 50usize),
            (-20, 40),
            (l as i64 - 10, 30),
            (3 * l as i64 + 7, 1),
            (400, 50),
        ] {
            let shift = windows.shift(first);
            let got = windows.window(&signal, &shift, len, &mut buffers);
            assert_eq!(got.len(), len);
            for (m, g) in got.iter().enumerate() {
                let e = spectrum[(first + m as i64).rem_euclid(l as i64) as usize];
                assert!(
                    (g - e).norm() <= 1e-5 * peak,
                    "first {first} bin {m}: {g} vs {e}"
                );
            }
        }
    }

    #[test]
    fn friendly_lengths() {
        assert_eq!(fft_friendly(1), 1);
        assert_eq!(fft_friendly(7), 8);
        assert_eq!(fft_friendly(1191), 1200);
        assert_eq!(fft_friendly(1025), 1080);
    }
}
