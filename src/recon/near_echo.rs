//! Echoes nearer than the objects, found in measured chirps and kept out of the isosurface cost.
//!
//! The cost (Eq. 12) compares measured and simulated range spectra over the bins the objects'
//! box can reach. An echo nearer than that window leaks into it through its main lobe and its
//! range sidelobes (−13 dB for the unwindowed FFT; one raw bin is c/B of round trip, 10 cm at
//! 3 GHz). Through cardboard (NLOS) that echo is the sheet: specular and broad, it returns
//! 15–25 dB more than a small object 10 cm behind it, so the measured window holds more sheet
//! than object and no candidate surface can match it. The simulated chirps hold the components
//! only, so the measured ones must too.
//!
//! [`NearEchoCanceller::clean`] removes the strongest echo that peaks before the window, one at
//! a time (as CLEAN does), while it is at least `ratio` of the window's own peak and at most
//! `tones` times. Sidelobes of echoes inside the window stay below 0.22 of them, so with the
//! default ratio 0.3 they are never taken for near echoes. A line-of-sight capture is left
//! untouched unless part of the scene lies nearer than the components' box (the upper rim of a
//! lid standing on edge, outside every component). Each echo's frequency is refined by
//! golden-section search on the DTFT magnitude; its model is that tone times a quadratic in
//! time, fitted by least squares to the spectrum before the window only, so that the objects
//! pull on the fit through their sidelobes alone (a fit to the whole chirp absorbs a fifth of
//! an object 2.4 bins behind the sheet). The quadratic holds what a single tone cannot: a
//! reflection coefficient that changes over the band, as a slab's Fabry–Pérot Γ(f) does, and
//! the delay spread of echoes closer than a range bin, such as a sheet's two faces 2·n·t apart
//! (1.3 cm of round trip for 4 mm at n = 1.6: an eighth of a bin). A single tone leaves a third
//! of such a pair.
//!
//! Measured on the accuracy suite's banana-on-its-side capture through cardboard against the
//! same scene without it (300 antennas, the L1 distance of L2-normalised window magnitudes that
//! the cost uses): 1.80 median uncleaned, 0.19 after single tones, 0.086 (p90 0.15) after the
//! quadratic fitted before the window.
//!
//! That fit sees the echo's near flank only. When the echo lies less than a raw bin before the
//! window, what it leaves in the window is enough to move the cost's minimum. On the clutter
//! scene flat through cardboard, the sheet peaks 2 padded bins before the window; there the
//! cleaned windows were further from the same capture with the sheet's echo subtracted exactly
//! (median L1 0.55 over the 50 antennas used) than the uncleaned ones (0.43), and mmNorm's
//! level was one candidate high: points 2.6 mm above the surface. So the cost does not compare
//! cleaned windows. [`NearEchoSubspace`] holds the span of the basis spectra of the echoes the
//! canceller found, and the cost projects it out of the measured and the simulated spectrum
//! alike, over every bin up to the window's end. The measured spectrum is echoes plus objects,
//! so its projection is the objects' projection whatever the echoes' amplitudes. With it the
//! clutter scene's points lie 0.06 mm below the surface (median signed offset), as with the
//! sheet's echo subtracted exactly.
//!
//! Neither the paper nor the authors' code does this: their scenes keep the box well behind the
//! cardboard's echo. It is documented in `isosurface.rs` with the cost.

use std::sync::Arc;

use nalgebra::{Matrix3, Vector3};
use num_complex::{Complex32, Complex64};
use rayon::prelude::*;
use rustfft::{Fft, FftPlanner};

use super::config::Optimisation;
use super::image::box_round_trip_m;
use crate::SPEED_OF_LIGHT_M_PER_S;
use crate::capture::Capture;

/// Antenna `a`'s range window over the box `lo..hi`: the first padded bin and the length of the
/// bins its round trips can reach, widened by `pad_bins` on each side, in a padded spectrum of
/// `fft_len` bins.
pub fn box_window(
    capture: &Capture,
    a: usize,
    lo: [f64; 3],
    hi: [f64; 3],
    fft_len: usize,
    pad_bins: i64,
) -> (i64, usize) {
    let bins_per_m = capture.plan.frequency_step_hz * fft_len as f64 / SPEED_OF_LIGHT_M_PER_S;
    let (near, far) = box_round_trip_m(&capture.tx_m[a], &capture.rx_m[a], lo, hi);
    let b0 = (near + capture.range_offset_m) * bins_per_m;
    let b1 = (far + capture.range_offset_m) * bins_per_m;
    let first = b0.min(b1).floor() as i64 - pad_bins;
    let last = b0.max(b1).ceil() as i64 + pad_bins;
    (first, (last - first + 1) as usize)
}

/// `capture` with every chirp's echoes that peak nearer than the box `lo..hi` (its
/// [`box_window`], `pad_bins` wide margins) subtracted by [`NearEchoCanceller::clean_chirp`],
/// and how many antennas had any.
pub fn without_near_echoes(
    capture: &Capture,
    lo: [f64; 3],
    hi: [f64; 3],
    canceller: &NearEchoCanceller,
    pad_bins: i64,
) -> (Capture, usize) {
    each_chirp_in_box(capture, lo, hi, canceller, pad_bins, |chirp, first, len| {
        let (chirp, removed) = canceller.clean_chirp(chirp, first, len);
        (chirp, removed > 0)
    })
}

/// `capture` with each chirp's strongest echo inside the round trips of the box `lo..hi` (its
/// [`box_window`], `pad_bins` padded bins wider on each side) subtracted by
/// [`NearEchoCanceller::without_strongest_in`].
pub fn without_strongest_echoes(
    capture: &Capture,
    lo: [f64; 3],
    hi: [f64; 3],
    canceller: &NearEchoCanceller,
    pad_bins: i64,
) -> Capture {
    each_chirp_in_box(capture, lo, hi, canceller, pad_bins, |chirp, first, len| {
        (canceller.without_strongest_in(chirp, first, len), true)
    })
    .0
}

/// `capture` with every chirp replaced by `f(chirp, first, len)` of its box window, and how
/// many of them `f` said it changed.
fn each_chirp_in_box(
    capture: &Capture,
    lo: [f64; 3],
    hi: [f64; 3],
    canceller: &NearEchoCanceller,
    pad_bins: i64,
    f: impl Fn(&[Complex32], i64, usize) -> (Vec<Complex32>, bool) + Sync,
) -> (Capture, usize) {
    let t = capture.plan.samples_per_chirp;
    let mut samples = vec![Complex32::new(0.0, 0.0); capture.samples.len()];
    let changed: usize = samples
        .par_chunks_mut(t)
        .enumerate()
        .map(|(a, out)| {
            let (first, len) = box_window(capture, a, lo, hi, canceller.fft_len(), pad_bins);
            let (chirp, changed) = f(capture.chirp(a), first, len);
            out[..chirp.len()].copy_from_slice(&chirp);
            usize::from(changed)
        })
        .sum();
    let mut clean = capture.clone();
    clean.samples = Arc::new(samples);
    (clean, changed)
}

/// The near echoes of one chirp (see [`NearEchoCanceller::near_echoes`]).
pub struct NearEchoes {
    /// The chirp's padded spectrum, bins `0..first + len`.
    pub measured: Vec<Complex32>,
    /// Three basis spectra per echo removed, over the same bins: the echo's tone times 1, τ
    /// and τ².
    pub basis: Vec<Vec<Complex32>>,
    /// The window `first..first + len` after the echoes' least-squares fit was subtracted.
    pub cleaned: Vec<Complex32>,
}

impl NearEchoes {
    /// Echoes removed.
    pub fn echoes(&self) -> usize {
        self.basis.len() / 3
    }
}

/// The span of the near echoes of one chirp (each echo's tone times 1, τ and τ², over bins
/// `0..first + len`), to be projected out of the measured and the simulated spectra alike (see
/// the module docs). The measured spectrum is echoes plus objects, so its projection is the
/// objects' projection whatever the echoes' amplitudes. A candidate whose echo lies in the span
/// (on top of the sheet) projects to almost nothing and matches nothing.
pub struct NearEchoSubspace {
    first: usize,
    /// Orthonormal basis of the echoes' span over bins `0..span`, in f64.
    basis: Vec<Vec<Complex64>>,
}

fn wide(z: Complex32) -> Complex64 {
    Complex64::new(f64::from(z.re), f64::from(z.im))
}

/// Σ conj(a)·b.
fn inner(a: &[Complex64], b: &[Complex64]) -> Complex64 {
    a.iter().zip(b).map(|(x, y)| x.conj() * y).sum()
}

/// A basis vector whose norm falls below this fraction of its own in Gram–Schmidt adds
/// nothing to the span and is dropped.
const DEPENDENT_FRACTION: f64 = 1e-6;

impl NearEchoSubspace {
    /// The subspace of the echoes of `echoes`, found before the window that starts at bin
    /// `first`; None when none was removed.
    pub fn new(echoes: &NearEchoes, first: i64) -> Option<NearEchoSubspace> {
        if echoes.echoes() == 0 || first < 0 {
            return None;
        }
        // Modified Gram–Schmidt, run twice over each vector for stability.
        let mut basis: Vec<Vec<Complex64>> = Vec::new();
        for b in &echoes.basis {
            let mut v: Vec<Complex64> = b.iter().map(|z| wide(*z)).collect();
            let norm0 = inner(&v, &v).re.sqrt();
            for _ in 0..2 {
                for q in &basis {
                    let c = inner(q, &v);
                    v.iter_mut().zip(q).for_each(|(x, y)| *x -= c * y);
                }
            }
            let norm = inner(&v, &v).re.sqrt();
            if norm > DEPENDENT_FRACTION * norm0 && norm > 0.0 {
                v.iter_mut().for_each(|x| *x /= norm);
                basis.push(v);
            }
        }
        Some(NearEchoSubspace {
            first: (first as usize).min(echoes.measured.len()),
            basis,
        })
    }

    /// Bins a simulated spectrum must cover: `0..span()`.
    pub fn span(&self) -> usize {
        self.basis.first().map_or(self.first, Vec::len)
    }

    /// The window's first bin.
    pub fn first(&self) -> usize {
        self.first
    }

    /// The window bins of `spectrum` (bins `0..span()`) with its part in the echoes' span
    /// removed.
    pub fn project(&self, spectrum: &[Complex32]) -> Vec<Complex32> {
        let x: Vec<Complex64> = spectrum.iter().map(|z| wide(*z)).collect();
        let coefficients: Vec<Complex64> = self.basis.iter().map(|q| inner(q, &x)).collect();
        (self.first..self.span().min(x.len()))
            .map(|i| {
                let inside: Complex64 = self
                    .basis
                    .iter()
                    .zip(&coefficients)
                    .map(|(q, c)| c * q[i])
                    .sum();
                let z = x[i] - inside;
                Complex32::new(z.re as f32, z.im as f32)
            })
            .collect()
    }
}

/// Golden-section iterations per tone: the bracket of two padded bins shrinks by 0.618 each,
/// to about 1e-4 of a raw bin after 24.
const GOLDEN_ITERATIONS: usize = 24;

/// [`NearEchoCanceller::without_strongest_in`] subtracts the strongest echo's tone times a line
/// only where the line takes all but this share of the energy the tone alone leaves near the
/// echo ([`SPREAD_OFFSETS`]): the leftover was then that echo spread over less than a range
/// bin.
pub const SPREAD_SHARE: f64 = 0.25;

/// Where [`SPREAD_SHARE`] is judged: every quarter of a raw range bin within 1.5 of the
/// strongest echo. A single tone fitted to an echo spread over less than a bin leaves its lobes
/// there, about 0.7 bins on either side.
pub const SPREAD_OFFSETS: [f64; 13] = [
    -1.5, -1.25, -1.0, -0.75, -0.5, -0.25, 0.0, 0.25, 0.5, 0.75, 1.0, 1.25, 1.5,
];

/// G(d) = Σ_t τ_t·e^{−j2πdt/N} ([`centred_time`]) at each of [`SPREAD_OFFSETS`]: the DTFT of the
/// line term e^{j2πνt}·τ at ν + d/N, for any ν.
fn line_kernel(n: usize) -> Vec<Complex64> {
    let tau: Vec<Complex32> = (0..n)
        .map(|t| Complex32::new(centred_time(t, n) as f32, 0.0))
        .collect();
    SPREAD_OFFSETS
        .iter()
        .map(|d| dtft(&tau, d / n as f64))
        .collect()
}

/// τ_t = (t − (N−1)/2)/N: time across an N-sample chirp, centred so that Σ τ = 0.
fn centred_time(t: usize, n: usize) -> f64 {
    (t as f64 - 0.5 * (n as f64 - 1.0)) / n as f64
}

/// Zero-padded range spectra of chirps, with the removal of near echoes.
pub struct NearEchoCanceller {
    fft: Arc<dyn Fft<f32>>,
    samples: usize,
    fft_len: usize,
    tones: usize,
    ratio: f32,
    /// [`line_kernel`] of `samples`.
    line_kernel: Vec<Complex64>,
}

impl NearEchoCanceller {
    /// Spectra of `samples`-long chirps zero-padded to `samples·pad_factor`; `tones` echoes at
    /// most are removed per chirp (0: none), each while it is at least `ratio` of the window's
    /// peak.
    /// The canceller of the isosurface cost's settings (`cost_pad_factor`, `near_echo_tones`,
    /// `near_echo_ratio`), for `samples`-long chirps: the one the cost and the imaging share.
    pub fn of_cost(samples: usize, opts: &Optimisation) -> NearEchoCanceller {
        NearEchoCanceller::new(
            samples,
            opts.cost_pad_factor,
            opts.near_echo_tones,
            opts.near_echo_ratio,
        )
    }

    pub fn new(samples: usize, pad_factor: usize, tones: usize, ratio: f64) -> NearEchoCanceller {
        let fft_len = samples * pad_factor.max(1);
        NearEchoCanceller {
            fft: FftPlanner::<f32>::new().plan_fft_forward(fft_len),
            samples,
            fft_len,
            tones,
            ratio: ratio as f32,
            line_kernel: line_kernel(samples),
        }
    }

    /// Padded FFT length.
    pub fn fft_len(&self) -> usize {
        self.fft_len
    }

    /// The padded spectrum of `chirp`.
    pub fn spectrum(&self, chirp: &[Complex32]) -> Vec<Complex32> {
        let mut buf = vec![Complex32::new(0.0, 0.0); self.fft_len];
        let n = chirp.len().min(self.samples);
        buf[..n].copy_from_slice(&chirp[..n]);
        self.fft.process(&mut buf);
        buf
    }

    /// Bins `first..first + len` of a padded spectrum (indices wrap, as the FFT does).
    pub fn window(&self, spectrum: &[Complex32], first: i64, len: usize) -> Vec<Complex32> {
        let l = self.fft_len as i64;
        (0..len)
            .map(|k| spectrum[(first + k as i64).rem_euclid(l) as usize])
            .collect()
    }

    /// The window `first..first + len` of `chirp`'s padded spectrum after removing the echoes
    /// that peak before `first`, and how many were removed.
    pub fn clean(&self, chirp: &[Complex32], first: i64, len: usize) -> (Vec<Complex32>, usize) {
        let found = self.near_echoes(chirp, first, len);
        let removed = found.echoes();
        (found.cleaned, removed)
    }

    /// `chirp` with the echoes that peak before bin `first` of its padded spectrum subtracted
    /// (their least-squares models, fitted as for [`Self::clean`]), and how many were removed.
    pub fn clean_chirp(
        &self,
        chirp: &[Complex32],
        first: i64,
        len: usize,
    ) -> (Vec<Complex32>, usize) {
        let (found, residual) = self.remove(chirp, first, len);
        (residual, found.echoes())
    }

    /// What [`Self::clean`] removes, in the form [`NearEchoSubspace`] needs: the chirp's padded
    /// spectrum over bins `0..first + len`, the basis spectra of every echo removed over the
    /// same bins, and the cleaned window.
    pub fn near_echoes(&self, chirp: &[Complex32], first: i64, len: usize) -> NearEchoes {
        self.remove(chirp, first, len).0
    }

    /// [`Self::near_echoes`] and the chirp with the echoes' models subtracted.
    fn remove(&self, chirp: &[Complex32], first: i64, len: usize) -> (NearEchoes, Vec<Complex32>) {
        let mut spectrum = self.spectrum(chirp);
        let before = first.clamp(0, self.fft_len as i64) as usize;
        let span = (first + len as i64).clamp(0, self.fft_len as i64) as usize;
        let measured = spectrum[..span].to_vec();
        let mut basis = Vec::new();
        let mut residual: Vec<Complex32> = chirp[..chirp.len().min(self.samples)].to_vec();
        if self.tones == 0 || before < 2 {
            let found = NearEchoes {
                measured,
                basis,
                cleaned: self.window(&spectrum, first, len),
            };
            return (found, residual);
        }
        let mut removed = 0;
        while removed < self.tones {
            let inside = self
                .window(&spectrum, first, len)
                .iter()
                .map(|z| z.norm())
                .fold(0.0f32, f32::max);
            let Some((peak_bin, peak)) = spectrum[..before]
                .iter()
                .map(|z| z.norm())
                .enumerate()
                .max_by(|a, b| a.1.total_cmp(&b.1))
            else {
                break;
            };
            if peak.is_nan() || peak < self.ratio * inside || peak <= 0.0 {
                break;
            }
            let nu = self.refine(&residual, peak_bin);
            let Some(spectra) =
                self.subtract_modulated_tone(&mut residual, &mut spectrum, nu, before)
            else {
                break;
            };
            basis.extend(spectra.map(|mut b| {
                b.truncate(span);
                b
            }));
            removed += 1;
        }
        let found = NearEchoes {
            measured,
            basis,
            cleaned: self.window(&spectrum, first, len),
        };
        (found, residual)
    }

    /// `chirp` with its strongest echo inside the window `first..first + len` of its padded
    /// spectrum subtracted: the frequency refined by golden-section search on the DTFT
    /// magnitude, the model that tone times a line in time, e^{j2πνt}·(a0 + a1·τ), fitted by
    /// least squares over the whole chirp.
    ///
    /// The line is there for echoes closer than a range bin, such as the two tops of a step 8 mm
    /// apart (0.16 raw bins of round trip at 3 GHz): one tone leaves 28 % of the second top as a
    /// lobe on either side of the pair, which images as a surface 0.85–0.89 bins above the step;
    /// tone times a line leaves 2–4 %. But the line also takes 17 % of an echo one bin away (3 %
    /// at 1.33 bins; a quadratic would take 52 % and 22 %), and a cup's rim can lie that close
    /// to its floor. So the line is subtracted only where it takes all but [`SPREAD_SHARE`] of
    /// what the tone alone leaves near the echo ([`SPREAD_OFFSETS`]): there the leftover is
    /// the same echo spread, not another one. What else the chirp holds pulls on the fit by its
    /// overlap with the model: a tone 1.3 raw bins away by a fifth of itself, one 45 bins away
    /// by 1 %.
    pub fn without_strongest_in(
        &self,
        chirp: &[Complex32],
        first: i64,
        len: usize,
    ) -> Vec<Complex32> {
        let mut residual: Vec<Complex32> = chirp[..chirp.len().min(self.samples)].to_vec();
        let window = self.window(&self.spectrum(&residual), first, len);
        let Some((offset, peak)) =
            (window.iter().map(|z| z.norm()).enumerate()).max_by(|a, b| a.1.total_cmp(&b.1))
        else {
            return residual;
        };
        if peak.is_nan() || peak <= 0.0 {
            return residual;
        }
        let bin = (first + offset as i64).rem_euclid(self.fft_len as i64) as usize;
        let nu = self.refine(&residual, bin);
        // Least squares of e^{j2πνt}·(a0 + a1·τ): Σ τ = 0, so the two basis functions are
        // orthogonal and each amplitude is its own projection.
        let n = residual.len();
        let tau = |t: usize| centred_time(t, n);
        // e^{j2πνt}, once per sample for the fit and both subtractions.
        let carrier: Vec<Complex64> = (0..n)
            .map(|t| Complex64::from_polar(1.0, std::f64::consts::TAU * nu * t as f64))
            .collect();
        let (mut p0, mut p1, mut g1) = (Complex64::default(), Complex64::default(), 0f64);
        for (t, z) in residual.iter().enumerate() {
            let w = wide(*z) * carrier[t].conj();
            p0 += w;
            p1 += w * tau(t);
            g1 += tau(t) * tau(t);
        }
        let (a0, a1) = (
            p0 / n as f64,
            if g1 > 0.0 {
                p1 / g1
            } else {
                Complex64::default()
            },
        );
        let subtract = |x: &mut [Complex32], model: &dyn Fn(usize) -> Complex64| {
            for (t, z) in x.iter_mut().enumerate() {
                let w = model(t);
                *z -= Complex32::new(w.re as f32, w.im as f32);
            }
        };
        subtract(&mut residual, &|t| a0 * carrier[t]);
        // The residual's DTFT at SPREAD_OFFSETS raw bins from the echo, where a spread echo
        // leaves its lobes and a separate echo farther away cannot dilute the comparison. The
        // line's own DTFT there is a1·G(d), G(d) = Σ τ·e^{−j2πdt/N}, whatever ν.
        let computed;
        let kernel = if n == self.samples {
            &self.line_kernel
        } else {
            computed = line_kernel(n);
            &computed
        };
        let (mut tone_left, mut line_left) = (0f64, 0f64);
        for (d, g) in SPREAD_OFFSETS.iter().zip(kernel) {
            let z = dtft(&residual, nu + d / n as f64);
            tone_left += z.norm_sqr();
            line_left += (z - a1 * g).norm_sqr();
        }
        if line_left < SPREAD_SHARE * tone_left {
            subtract(&mut residual, &|t| a1 * tau(t) * carrier[t]);
        }
        residual
    }

    /// Fits e^{+j2πνt}·(a0 + a1·τ + a2·τ²), τ = t/N − ½, to the spectrum's bins below
    /// `before` by least squares and subtracts it from the chirp `x` and its `spectrum`. The
    /// fit ignores the window and everything past it, so the objects' own echoes pull on it
    /// only through their sidelobes. Returns the padded spectra of the three basis functions,
    /// or None when the fit is singular (nothing is changed).
    fn subtract_modulated_tone(
        &self,
        x: &mut [Complex32],
        spectrum: &mut [Complex32],
        nu: f64,
        before: usize,
    ) -> Option<[Vec<Complex32>; 3]> {
        let n = x.len();
        let carrier = |t: usize| Complex64::from_polar(1.0, std::f64::consts::TAU * nu * t as f64);
        let tau = |t: usize| t as f64 / n as f64 - 0.5;
        let basis: [Vec<Complex64>; 3] =
            std::array::from_fn(|p| (0..n).map(|t| carrier(t) * tau(t).powi(p as i32)).collect());
        let spectra: [Vec<Complex32>; 3] = std::array::from_fn(|p| {
            let b: Vec<Complex32> = basis[p]
                .iter()
                .map(|z| Complex32::new(z.re as f32, z.im as f32))
                .collect();
            self.spectrum(&b)
        });
        let mut gram = Matrix3::<Complex64>::zeros();
        let mut rhs = Vector3::<Complex64>::zeros();
        for k in 0..before {
            let column = [0, 1, 2].map(|p| wide(spectra[p][k]));
            for p in 0..3 {
                for q in 0..3 {
                    gram[(p, q)] += column[p].conj() * column[q];
                }
                rhs[p] += column[p].conj() * wide(spectrum[k]);
            }
        }
        let a = gram.lu().solve(&rhs)?;
        if a.iter().any(|z| !(z.re.is_finite() && z.im.is_finite())) {
            return None;
        }
        for (t, z) in x.iter_mut().enumerate() {
            let w: Complex64 = (0..3).map(|p| a[p] * basis[p][t]).sum();
            *z -= Complex32::new(w.re as f32, w.im as f32);
        }
        let a32 = a.map(|z| Complex32::new(z.re as f32, z.im as f32));
        for (k, z) in spectrum.iter_mut().enumerate() {
            *z -= a32[0] * spectra[0][k] + a32[1] * spectra[1][k] + a32[2] * spectra[2][k];
        }
        Some(spectra)
    }

    /// The frequency (cycles per sample) of the DTFT magnitude's maximum within one padded bin
    /// of `bin`.
    fn refine(&self, x: &[Complex32], bin: usize) -> f64 {
        let l = self.fft_len as f64;
        let (mut lo, mut hi) = ((bin as f64 - 1.0) / l, (bin as f64 + 1.0) / l);
        let g = 0.5 * (5f64.sqrt() - 1.0);
        let mut a = hi - g * (hi - lo);
        let mut b = lo + g * (hi - lo);
        let (mut fa, mut fb) = (dtft(x, a).norm(), dtft(x, b).norm());
        for _ in 0..GOLDEN_ITERATIONS {
            if fa > fb {
                hi = b;
                b = a;
                fb = fa;
                a = hi - g * (hi - lo);
                fa = dtft(x, a).norm();
            } else {
                lo = a;
                a = b;
                fa = fb;
                b = lo + g * (hi - lo);
                fb = dtft(x, b).norm();
            }
        }
        0.5 * (lo + hi)
    }
}

/// Σ_t x_t·exp(−j2πνt), in f64.
fn dtft(x: &[Complex32], nu: f64) -> Complex64 {
    let step = Complex64::from_polar(1.0, -std::f64::consts::TAU * nu);
    let mut phasor = Complex64::new(1.0, 0.0);
    let mut sum = Complex64::new(0.0, 0.0);
    for (t, z) in x.iter().enumerate() {
        if t % 64 == 0 {
            // Re-seed the recurrence so its rounding does not build up.
            phasor = Complex64::from_polar(1.0, -std::f64::consts::TAU * nu * t as f64);
        }
        sum += Complex64::new(f64::from(z.re), f64::from(z.im)) * phasor;
        phasor *= step;
    }
    sum
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::signal::Rng;

    fn tone(n: usize, amplitude: Complex64, nu: f64) -> Vec<Complex32> {
        (0..n)
            .map(|t| {
                let w =
                    amplitude * Complex64::from_polar(1.0, std::f64::consts::TAU * nu * t as f64);
                Complex32::new(w.re as f32, w.im as f32)
            })
            .collect()
    }

    fn norm(x: &[Complex32]) -> f64 {
        x.iter()
            .map(|z| f64::from(z.norm_sqr()))
            .sum::<f64>()
            .sqrt()
    }

    fn add(a: &mut [Complex32], b: &[Complex32]) {
        for (x, y) in a.iter_mut().zip(b) {
            *x += y;
        }
    }

    /// A floor's echo and a rim's 18 dB under it and 1.33 raw bins nearer, as an open cup
    /// returns them, with a stronger echo 45 raw bins away, outside the window: the floor goes,
    /// what is left of it stays under a quarter of the rim (the two tones' overlap pulls on the
    /// fit, see [`NearEchoCanceller::without_strongest_in`]), and the echo outside stays.
    #[test]
    fn the_strongest_echo_in_the_window_goes_and_a_weaker_one_beside_it_stays() {
        let (n, pad) = (512usize, 4usize);
        let canceller = NearEchoCanceller::new(n, pad, 4, 0.3);
        let l = (n * pad) as f64;
        let floor_bin = 301.37; // padded bins
        let rim_bin = floor_bin - 1.33 * pad as f64;
        let outside_bin = 120.6;
        let floor = tone(n, Complex64::from_polar(8.0, 0.3), floor_bin / l);
        let rim = tone(n, Complex64::from_polar(1.0, -1.1), rim_bin / l);
        let outside = tone(n, Complex64::from_polar(30.0, 2.0), outside_bin / l);
        let mut measured = floor.clone();
        add(&mut measured, &rim);
        add(&mut measured, &outside);
        let first = (rim_bin - 2.0 * pad as f64).floor() as i64;
        let len = (floor_bin - rim_bin) as usize + 4 * pad;
        let residual = canceller.without_strongest_in(&measured, first, len);
        let mut expected = rim.clone();
        add(&mut expected, &outside);
        let error: f64 = residual
            .iter()
            .zip(&expected)
            .map(|(a, b)| f64::from((a - b).norm_sqr()))
            .sum::<f64>()
            .sqrt();
        println!(
            "residue {:.4} of the floor, {:.4} of the rim",
            error / norm(&floor),
            error / norm(&rim)
        );
        assert!(error < 0.25 * norm(&rim), "{error}");
    }

    /// Two tops of a step 0.16 raw bins apart (8 mm at 3 GHz), the second 0.7 of the first: both
    /// go, leaving under 5 % of the second (1.9 %; one tone alone leaves 28 %, as a pair of
    /// lobes about a raw bin on either side).
    #[test]
    fn two_echoes_closer_than_a_bin_go_together() {
        let (n, pad) = (512usize, 4usize);
        let canceller = NearEchoCanceller::new(n, pad, 4, 0.3);
        let l = (n * pad) as f64;
        let low_bin = 301.37;
        let low = tone(n, Complex64::from_polar(1.0, 0.3), low_bin / l);
        let high = tone(
            n,
            Complex64::from_polar(0.7, 2.1),
            (low_bin - 0.16 * pad as f64) / l,
        );
        let mut measured = low.clone();
        add(&mut measured, &high);
        let first = low_bin as i64 - 3 * pad as i64;
        let residual = canceller.without_strongest_in(&measured, first, 6 * pad);
        let left = norm(&residual) / norm(&high);
        println!("residue {left:.4} of the second top");
        assert!(left < 0.05, "{left}");
    }

    /// A strong off-grid "sheet" tone 2.4 raw bins before a weak "object" tone: its leakage
    /// dominates the object's window (error over 50 % of the object's peak) until it is
    /// removed, after which the window matches the object's own spectrum within 10 % (6.5 %).
    #[test]
    fn removes_a_strong_near_echo_and_keeps_the_object() {
        let (n, pad) = (512usize, 4usize);
        let canceller = NearEchoCanceller::new(n, pad, 4, 0.3);
        let l = (n * pad) as f64;
        let sheet_bin = 81.37; // padded bins
        let object_bin = sheet_bin + 2.4 * pad as f64;
        let object = tone(n, Complex64::new(0.0, 10.0), object_bin / l);
        let mut measured = tone(n, Complex64::from_polar(200.0, 0.7), sheet_bin / l);
        add(&mut measured, &object);
        let mut rng = Rng::new(5);
        for z in &mut measured {
            let (re, im) = rng.normal_pair();
            *z += Complex32::new(0.05 * re as f32, 0.05 * im as f32);
        }
        let first = object_bin.floor() as i64 - pad as i64 - 2;
        let len = 3 * pad;
        let truth: Vec<f32> = canceller
            .window(&canceller.spectrum(&object), first, len)
            .iter()
            .map(|z| z.norm())
            .collect();
        let error = |w: &[Complex32]| {
            w.iter()
                .zip(&truth)
                .map(|(z, t)| (z.norm() - t).abs())
                .fold(0.0f32, f32::max)
                / truth.iter().copied().fold(0.0f32, f32::max)
        };
        let raw = canceller.window(&canceller.spectrum(&measured), first, len);
        assert!(
            error(&raw) > 0.5,
            "the sheet should dominate: {}",
            error(&raw)
        );
        let (clean, removed) = canceller.clean(&measured, first, len);
        assert!(removed >= 1, "{removed}");
        assert!(error(&clean) < 0.1, "{}", error(&clean));
    }

    /// A strong "sheet" tone 2.6 padded bins before the window and a weak "object" tone one raw
    /// bin after the sheet, under candidate models a quarter of a raw bin apart. Fitted to the
    /// bins before the window alone, the sheet leaves a residual in the window that moves the
    /// cost's minimum one candidate too far (costs 1.18 at the truth, 0.28 there). With the
    /// echoes' subspace projected out of both spectra, the minimum is the truth, at 0.00.
    #[test]
    fn projecting_the_near_echo_out_finds_the_object_next_to_the_sheet() {
        let (n, pad) = (512usize, 4usize);
        let canceller = NearEchoCanceller::new(n, pad, 4, 0.3);
        let l = (n * pad) as f64;
        let sheet_bin = 81.37;
        let object_bin = sheet_bin + pad as f64;
        let mut measured = tone(n, Complex64::from_polar(200.0, 0.7), sheet_bin / l);
        add(
            &mut measured,
            &tone(n, Complex64::new(0.0, 10.0), object_bin / l),
        );
        let mut rng = Rng::new(9);
        for z in &mut measured {
            let (re, im) = rng.normal_pair();
            *z += Complex32::new(0.05 * re as f32, 0.05 * im as f32);
        }
        let first = sheet_bin.ceil() as i64 + pad as i64 / 2;
        let len = 4 * pad;
        let span = first as usize + len;
        let normalised = |w: &[Complex32]| {
            let m: Vec<f32> = w.iter().map(|z| z.norm()).collect();
            let s = m.iter().map(|x| x * x).sum::<f32>().sqrt();
            m.into_iter().map(|x| x / s).collect::<Vec<f32>>()
        };
        let l1 = |a: &[f32], b: &[f32]| a.iter().zip(b).map(|(x, y)| (x - y).abs()).sum::<f32>();
        // Candidate object models a quarter of a raw bin apart; the true one is offset 0.
        let offsets: Vec<f64> = (-4..=4).map(|i| f64::from(i) * 0.25 * pad as f64).collect();
        let models: Vec<Vec<Complex32>> = offsets
            .iter()
            .map(|d| canceller.spectrum(&tone(n, Complex64::new(1.0, 0.0), (object_bin + d) / l)))
            .collect();
        let argmin = |costs: &[f32]| {
            (0..costs.len())
                .min_by(|&a, &b| costs[a].total_cmp(&costs[b]))
                .unwrap_or(0)
        };
        let echoes = canceller.near_echoes(&measured, first, len);
        assert_eq!(echoes.echoes(), 1);
        let clean = normalised(&echoes.cleaned);
        let clean_costs: Vec<f32> = models
            .iter()
            .map(|m| l1(&normalised(&m[first as usize..span]), &clean))
            .collect();
        let subspace = NearEchoSubspace::new(&echoes, first).expect("one echo");
        assert_eq!(subspace.span(), span);
        let measured_window = normalised(&subspace.project(&echoes.measured));
        let projected_costs: Vec<f32> = models
            .iter()
            .map(|m| l1(&normalised(&subspace.project(&m[..span])), &measured_window))
            .collect();
        assert_ne!(argmin(&clean_costs), 4, "{clean_costs:?}");
        assert_eq!(argmin(&projected_costs), 4, "{projected_costs:?}");
        assert!(projected_costs[4] < 0.02, "{projected_costs:?}");
    }

    /// The projected measured window is the object's own projection: the sheet, however
    /// strong, lies in the subspace (to 0.1 % of the object's peak here).
    #[test]
    fn the_projection_removes_the_sheet_and_keeps_the_object() {
        let (n, pad) = (512usize, 4usize);
        let canceller = NearEchoCanceller::new(n, pad, 4, 0.3);
        let l = (n * pad) as f64;
        let object = tone(n, Complex64::new(2.0, 0.0), 70.1 / l);
        let mut measured = tone(n, Complex64::from_polar(100.0, 0.1), 60.3 / l);
        add(&mut measured, &object);
        let (first, len) = (64i64, 16usize);
        let echoes = canceller.near_echoes(&measured, first, len);
        assert_eq!(echoes.echoes(), 1);
        let subspace = NearEchoSubspace::new(&echoes, first).expect("one echo");
        let expected = subspace.project(&canceller.spectrum(&object)[..subspace.span()]);
        let peak = expected.iter().map(|z| z.norm()).fold(0.0f32, f32::max);
        let error = subspace
            .project(&echoes.measured)
            .iter()
            .zip(&expected)
            .map(|(a, b)| (a - b).norm())
            .fold(0.0f32, f32::max);
        assert!(peak > 0.5 * 2.0 * n as f32, "the object survives: {peak}");
        assert!(error < 1e-3 * peak, "{error} vs {peak}");
    }

    /// An echo inside the window and its sidelobes before it: nothing is removed.
    #[test]
    fn leaves_a_line_of_sight_window_alone() {
        let (n, pad) = (512usize, 4usize);
        let canceller = NearEchoCanceller::new(n, pad, 4, 0.3);
        let object_bin = 200.6;
        let object = tone(n, Complex64::new(3.0, -2.0), object_bin / (n * pad) as f64);
        let first = object_bin as i64 - pad as i64;
        let (clean, removed) = canceller.clean(&object, first, 4 * pad);
        assert_eq!(removed, 0);
        assert_eq!(
            clean,
            canceller.window(&canceller.spectrum(&object), first, 4 * pad)
        );
    }

    /// A sheet seen as two faces of opposite sign an eighth of a raw bin apart (4 mm at
    /// n = 1.6): what leaks into the window after removal is a few percent of before.
    #[test]
    fn two_unresolved_faces_are_removed_too() {
        let (n, pad) = (512usize, 4usize);
        let canceller = NearEchoCanceller::new(n, pad, 4, 0.3);
        let l = (n * pad) as f64;
        let mut measured = tone(n, Complex64::from_polar(100.0, 0.2), 60.3 / l);
        add(
            &mut measured,
            &tone(n, Complex64::from_polar(-60.0, 0.2), 60.8 / l),
        );
        let first = 60 + 3 * pad as i64;
        let (clean, removed) = canceller.clean(&measured, first, 4 * pad);
        assert!(removed >= 1);
        let peak = clean.iter().map(|z| z.norm()).fold(0.0f32, f32::max);
        let before = canceller
            .window(&canceller.spectrum(&measured), first, 4 * pad)
            .iter()
            .map(|z| z.norm())
            .fold(0.0f32, f32::max);
        assert!(peak < before * 0.03, "{peak} vs {before}");
    }
}
