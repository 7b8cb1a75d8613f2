//! Accumulating FMCW returns: `h[t] += a·exp(+j·2π·f_t·(d + offset)/c)`.
//!
//! Per reflection the phase at sample 0 is reduced in turns in f64, then the chirp is swept by a
//! phasor recurrence on eight lanes in f32 (`z ← z·w⁸`), so each reflection costs two `sin_cos`
//! and T/8 eight-wide complex multiplies. The recurrence drifts by less than 1e-5 rad over 512
//! samples (tested against direct evaluation in f64).

use num_complex::Complex32;

use crate::SPEED_OF_LIGHT_M_PER_S;
use crate::capture::FrequencyPlan;

const LANES: usize = 8;

/// A chirp being built, stored as separate real and imaginary parts.
#[derive(Debug, Clone)]
pub struct ToneAccumulator {
    start_turns_per_m: f64,
    step_turns_per_m: f64,
    range_offset_m: f64,
    re: Vec<f32>,
    im: Vec<f32>,
}

impl ToneAccumulator {
    pub fn new(plan: &FrequencyPlan, range_offset_m: f64) -> ToneAccumulator {
        let t = plan.samples_per_chirp;
        ToneAccumulator {
            start_turns_per_m: plan.start_frequency_hz / SPEED_OF_LIGHT_M_PER_S,
            step_turns_per_m: plan.frequency_step_hz / SPEED_OF_LIGHT_M_PER_S,
            range_offset_m,
            re: vec![0.0; t],
            im: vec![0.0; t],
        }
    }

    /// Clears the chirp for reuse.
    pub fn clear(&mut self) {
        self.re.fill(0.0);
        self.im.fill(0.0);
    }

    /// Adds one reflection of complex amplitude `amplitude` over the round trip `path_m`
    /// (the range offset is added here).
    pub fn add(&mut self, amplitude: Complex32, path_m: f64) {
        let d = path_m + self.range_offset_m;
        let turns0 = (self.start_turns_per_m * d).fract();
        let dturn = (self.step_turns_per_m * d).fract();
        let (s0, c0) = (std::f64::consts::TAU * turns0).sin_cos();
        let (s1, c1) = (std::f64::consts::TAU * dturn).sin_cos();
        let a = (f64::from(amplitude.re), f64::from(amplitude.im));
        // Lane phasors z_j = a·exp(j(φ0 + j·Δφ)), j = 0..8, built in f64.
        let mut zr = [0f32; LANES];
        let mut zi = [0f32; LANES];
        let (mut pr, mut pi) = (a.0 * c0 - a.1 * s0, a.0 * s0 + a.1 * c0);
        for j in 0..LANES {
            zr[j] = pr as f32;
            zi[j] = pi as f32;
            (pr, pi) = (pr * c1 - pi * s1, pr * s1 + pi * c1);
        }
        let (s8, c8) = (std::f64::consts::TAU * (8.0 * dturn).fract()).sin_cos();
        let (wr, wi) = (c8 as f32, s8 as f32);
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma")
        {
            // SAFETY: the CPU supports AVX2 and FMA (checked just above).
            unsafe { sweep_avx2_fma(&mut self.re, &mut self.im, zr, zi, (wr, wi)) };
            return;
        }
        sweep(&mut self.re, &mut self.im, zr, zi, (wr, wi));
    }

    /// Multiplies sample t by `scale[t]` (for frequency-dependent factors common to all
    /// reflections).
    pub fn scale_by(&mut self, scale: &[f32]) {
        for ((re, im), s) in self.re.iter_mut().zip(&mut self.im).zip(scale) {
            *re *= s;
            *im *= s;
        }
    }

    /// Adds this chirp into `out`.
    pub fn add_into(&self, out: &mut [Complex32]) {
        for ((o, re), im) in out.iter_mut().zip(&self.re).zip(&self.im) {
            o.re += re;
            o.im += im;
        }
    }
}

/// Adds the eight-lane phasor sweep `z, z·w, z·w², …` (in blocks of eight samples) to the chirp.
#[inline(always)]
fn sweep(
    re: &mut [f32],
    im: &mut [f32],
    mut zr: [f32; LANES],
    mut zi: [f32; LANES],
    (wr, wi): (f32, f32),
) {
    let n = re.len().min(im.len());
    let full = n / LANES * LANES;
    for (re, im) in re[..full]
        .chunks_exact_mut(LANES)
        .zip(im[..full].chunks_exact_mut(LANES))
    {
        for j in 0..LANES {
            re[j] += zr[j];
            im[j] += zi[j];
            let r = zr[j] * wr - zi[j] * wi;
            zi[j] = zr[j] * wi + zi[j] * wr;
            zr[j] = r;
        }
    }
    for j in 0..n - full {
        re[full + j] += zr[j];
        im[full + j] += zi[j];
    }
}

/// [`sweep`] compiled for AVX2 and FMA.
///
/// # Safety
/// The CPU must support AVX2 and FMA.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn sweep_avx2_fma(
    re: &mut [f32],
    im: &mut [f32],
    zr: [f32; LANES],
    zi: [f32; LANES],
    w: (f32, f32),
) {
    sweep(re, im, zr, zi, w)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn recurrence_matches_direct_f64_evaluation() {
        let plan = FrequencyPlan {
            start_frequency_hz: 77.5001e9,
            frequency_step_hz: 5.861163e6,
            samples_per_chirp: 515,
        };
        let mut acc = ToneAccumulator::new(&plan, 0.15);
        let reflections = [
            (Complex32::new(0.3, -0.2), 0.8123456),
            (Complex32::new(1.0, 0.0), 1.37),
        ];
        for (a, d) in reflections {
            acc.add(a, d);
        }
        let mut out = vec![Complex32::new(0.0, 0.0); 515];
        acc.add_into(&mut out);
        let mut worst = 0.0f64;
        for (t, o) in out.iter().enumerate() {
            let mut want = (0.0f64, 0.0f64);
            for (a, d) in reflections {
                let phase = std::f64::consts::TAU * plan.frequency_hz(t) * (d + 0.15)
                    / SPEED_OF_LIGHT_M_PER_S;
                let (s, c) = phase.sin_cos();
                want.0 += f64::from(a.re) * c - f64::from(a.im) * s;
                want.1 += f64::from(a.re) * s + f64::from(a.im) * c;
            }
            let err =
                ((f64::from(o.re) - want.0).powi(2) + (f64::from(o.im) - want.1).powi(2)).sqrt();
            worst = worst.max(err);
        }
        println!("worst error {worst:.2e}");
        assert!(worst < 2e-5, "{worst}");
    }
}
