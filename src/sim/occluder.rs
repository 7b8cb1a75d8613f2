//! The cardboard sheet of a non-line-of-sight scene: a dielectric slab at a height.
//!
//! - **Transmission.** A path from below the sheet to an antenna above crosses it once. It is
//!   attenuated by `loss_db`/cos θ_t (longer path inside at oblique incidence) and delayed by the
//!   slab's extra optical path `t·(√(n² − sin²θ_i) − cos θ_i)`. Refraction's lateral shift is
//!   ignored (under 1 mm for 4 mm of n = 1.6 at 30°). Both legs of a round trip are treated.
//! - **Reflection.** The sheet itself returns an image-theory specular reflection with the
//!   normal-incidence Fabry–Pérot coefficient of the slab,
//!   Γ(f) = r·(1 − A²e^{+2jδ}) / (1 − r²A²e^{+2jδ}), r = (1 − n)/(1 + n),
//!   δ = 2π·f·n·t·cos θ_t / c, A the one-way amplitude loss; its reference plane is the top face.
//! - Multiple bounces between sheet and objects are not modelled.

use num_complex::Complex32;

use super::scene::Occluder;
use crate::SPEED_OF_LIGHT_M_PER_S;
use crate::capture::FrequencyPlan;

impl Occluder {
    fn contains_xy(&self, x: f64, y: f64) -> bool {
        match self.size_m {
            None => true,
            Some([sx, sy]) => {
                (x - self.center_m[0]).abs() <= sx / 2.0 && (y - self.center_m[1]).abs() <= sy / 2.0
            }
        }
    }

    /// The power that a round trip through the sheet at normal incidence keeps: `loss_db` on
    /// each leg.
    pub fn round_trip_power_transmission(&self) -> f64 {
        10f64.powf(-2.0 * self.loss_db / 10.0)
    }

    /// Amplitude factor and extra path (metres) of the straight leg from `p` to `a`; (1, 0)
    /// when the leg does not cross the sheet.
    #[inline]
    pub fn leg(&self, p: [f32; 3], a: [f32; 3]) -> (f32, f32) {
        let (pz, az) = (f64::from(p[2]), f64::from(a[2]));
        let (lo, hi) = (pz.min(az), pz.max(az));
        if !(lo < self.z_m && self.z_m < hi) {
            return (1.0, 0.0);
        }
        let s = (self.z_m - pz) / (az - pz);
        let x = f64::from(p[0]) + s * f64::from(a[0] - p[0]);
        let y = f64::from(p[1]) + s * f64::from(a[1] - p[1]);
        if !self.contains_xy(x, y) {
            return (1.0, 0.0);
        }
        let d = [a[0] - p[0], a[1] - p[1], a[2] - p[2]].map(f64::from);
        let len = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
        let cos_i = (d[2].abs() / len).clamp(0.0, 1.0);
        let sin2_i = 1.0 - cos_i * cos_i;
        let n = self.refractive_index;
        let cos_t = (1.0 - sin2_i / (n * n)).max(1e-6).sqrt();
        let amplitude = 10f64.powf(-self.loss_db / (20.0 * cos_t));
        let extra = self.thickness_m * ((n * n - sin2_i).sqrt() - cos_i);
        (amplitude as f32, extra as f32)
    }

    /// The sheet's own specular return for one virtual antenna, as (per-sample complex factors,
    /// image path length), or `None` when the specular point misses the sheet or the antennas
    /// are not above it.
    pub fn reflection(
        &self,
        plan: &FrequencyPlan,
        tx: [f64; 3],
        rx: [f64; 3],
    ) -> Option<(Vec<Complex32>, f64)> {
        let top = self.z_m + self.thickness_m / 2.0;
        if tx[2] <= top || rx[2] <= top {
            return None;
        }
        let image = [rx[0], rx[1], 2.0 * top - rx[2]];
        let d = [image[0] - tx[0], image[1] - tx[1], image[2] - tx[2]];
        let len = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
        let s = (top - tx[2]) / d[2];
        if !self.contains_xy(tx[0] + s * d[0], tx[1] + s * d[1]) {
            return None;
        }
        let cos_i = d[2].abs() / len;
        let n = self.refractive_index;
        let cos_t = (1.0 - (1.0 - cos_i * cos_i) / (n * n)).max(1e-6).sqrt();
        let r = (1.0 - n) / (1.0 + n);
        let a2 = 10f64.powf(-self.loss_db / (10.0 * cos_t));
        let factors = (0..plan.samples_per_chirp)
            .map(|t| {
                let delta =
                    std::f64::consts::TAU * plan.frequency_hz(t) * n * self.thickness_m * cos_t
                        / SPEED_OF_LIGHT_M_PER_S;
                let (s2, c2) = (2.0 * delta).sin_cos();
                let e = (a2 * c2, a2 * s2);
                let num = (r * (1.0 - e.0), -r * e.1);
                let den = (1.0 - r * r * e.0, -r * r * e.1);
                let den2 = den.0 * den.0 + den.1 * den.1;
                Complex32::new(
                    ((num.0 * den.0 + num.1 * den.1) / den2) as f32,
                    ((num.1 * den.0 - num.0 * den.1) / den2) as f32,
                )
            })
            .collect();
        Some((factors, len))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sheet() -> Occluder {
        Occluder {
            z_m: 0.2,
            thickness_m: 0.004,
            refractive_index: 1.6,
            loss_db: 1.0,
            size_m: Some([0.2, 0.2]),
            center_m: [0.0, 0.0],
        }
    }

    #[test]
    fn vertical_leg_loses_the_normal_loss_and_gains_the_slab_delay() {
        let (a, extra) = sheet().leg([0.0, 0.0, 0.0], [0.0, 0.0, 0.4]);
        assert!((a - 10f32.powf(-0.05)).abs() < 1e-6);
        assert!((extra - 0.004 * 0.6).abs() < 1e-7);
        assert_eq!(sheet().leg([0.0, 0.0, 0.0], [0.0, 0.0, 0.1]), (1.0, 0.0));
        assert_eq!(sheet().leg([0.5, 0.0, 0.0], [0.5, 0.0, 0.4]), (1.0, 0.0));
    }

    #[test]
    fn thin_lossless_slab_reflection_matches_the_closed_form() {
        let mut o = sheet();
        o.loss_db = 0.0;
        let plan = FrequencyPlan {
            start_frequency_hz: 77e9,
            frequency_step_hz: 1e6,
            samples_per_chirp: 1,
        };
        let (g, len) = o
            .reflection(&plan, [0.0, 0.0, 0.4], [0.0, 0.0, 0.4])
            .unwrap();
        assert!((len - 2.0 * (0.4 - 0.202)).abs() < 1e-12);
        let r = (1.0 - 1.6) / 2.6f64;
        let delta = std::f64::consts::TAU * 77e9 * 1.6 * 0.004 / SPEED_OF_LIGHT_M_PER_S;
        let mag = (2.0 * r.abs() * delta.sin().abs())
            / (1.0 - 2.0 * r * r * (2.0 * delta).cos() + r.powi(4)).sqrt();
        assert!(
            (f64::from(g[0].norm()) - mag).abs() < 1e-5,
            "{} vs {mag}",
            g[0].norm()
        );
    }
}
