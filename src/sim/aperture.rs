//! The raster aperture: antenna positions and the antenna gain pattern.
//!
//! Positions are ordered row by row: x varies fastest (rows run along x), y increases from row to
//! row. With the IWR1443BOOST layout each position yields one virtual antenna per enabled RX
//! channel, position-major and RX-minor (index = channels·position + k), as the authors' code
//! orders them.

use super::scene::{ApertureGrid, Axis, Layout, PatternKind};
use crate::radar::iwr1443boost_rx_offset_m;

/// TX and RX positions of every virtual antenna, metres.
#[derive(Debug, Clone, PartialEq)]
pub struct Antennas {
    pub tx_m: Vec<[f64; 3]>,
    pub rx_m: Vec<[f64; 3]>,
    /// Raster points along x and y.
    pub columns: usize,
    pub rows: usize,
    /// Virtual antennas per raster point.
    pub per_position: usize,
}

/// Builds the antennas of a raster; `rx_channels` are the enabled RX channels (IWR1443BOOST
/// layout only) and `lambda0_m` the wavelength of ADC sample 0.
pub fn raster_antennas(grid: &ApertureGrid, rx_channels: &[u8], lambda0_m: f64) -> Antennas {
    let (columns, rows) = grid.raster_size();
    let x0 = grid.center_m[0] - (columns - 1) as f64 * grid.spacing_m / 2.0;
    let y0 = grid.center_m[1] - (rows - 1) as f64 * grid.spacing_m / 2.0;
    let offsets: Vec<[f64; 3]> = match grid.layout {
        Layout::Monostatic => vec![[0.0; 3]],
        Layout::Iwr1443boost => rx_channels
            .iter()
            .map(|&k| {
                let o = iwr1443boost_rx_offset_m(k, lambda0_m);
                match grid.rx_axis {
                    Axis::X => [o, 0.0, 0.0],
                    Axis::Y => [0.0, o, 0.0],
                }
            })
            .collect(),
    };
    let n = columns * rows * offsets.len();
    let mut tx_m = Vec::with_capacity(n);
    let mut rx_m = Vec::with_capacity(n);
    for r in 0..rows {
        for c in 0..columns {
            let tx = [
                x0 + c as f64 * grid.spacing_m,
                y0 + r as f64 * grid.spacing_m,
                grid.z_m,
            ];
            for o in &offsets {
                tx_m.push(tx);
                rx_m.push([tx[0] + o[0], tx[1] + o[1], tx[2] + o[2]]);
            }
        }
    }
    Antennas {
        tx_m,
        rx_m,
        columns,
        rows,
        per_position: offsets.len(),
    }
}

/// Field-amplitude gain of one antenna towards a direction, boresight −z.
#[derive(Debug, Clone, Copy)]
pub struct Pattern {
    /// Exponents of cos θ in the two principal planes; `None` for isotropic.
    exponents: Option<(f32, f32)>,
    along_x: bool,
}

impl Pattern {
    pub fn new(kind: PatternKind, rx_axis: Axis) -> Pattern {
        // cos^q(θ_half) = 0.5 (−6 dB in power at half the 6 dB beamwidth).
        let q = |beamwidth_deg: f64| {
            (0.5f64.ln() / (beamwidth_deg / 2.0).to_radians().cos().ln()) as f32
        };
        Pattern {
            exponents: match kind {
                PatternKind::Isotropic => None,
                PatternKind::Iwr1443boost => Some((q(100.0), q(40.0))),
            },
            along_x: rx_axis == Axis::X,
        }
    }

    pub fn is_isotropic(&self) -> bool {
        self.exponents.is_none()
    }

    /// Gain towards the unit direction `u` (from the antenna to the scatterer).
    #[inline]
    pub fn gain(&self, u: [f32; 3]) -> f32 {
        let Some((q_az, q_el)) = self.exponents else {
            return 1.0;
        };
        let down = -u[2];
        if down <= 0.0 {
            return 0.0;
        }
        let (a, e) = if self.along_x {
            (u[0], u[1])
        } else {
            (u[1], u[0])
        };
        // cos^q = (cos²)^(q/2): one exponential of two logarithms instead of two powers.
        let down2 = down * down;
        let cos2_az = down2 / (a * a + down2);
        let cos2_el = down2 / (e * e + down2);
        (0.5 * (q_az * cos2_az.ln() + q_el * cos2_el.ln())).exp()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn grid(layout: Layout) -> ApertureGrid {
        ApertureGrid {
            width_m: 0.01,
            height_m: 0.004,
            spacing_m: 0.002,
            z_m: 0.4,
            center_m: [0.1, 0.0],
            layout,
            rx_axis: Axis::X,
            pattern: PatternKind::Isotropic,
        }
    }

    #[test]
    fn raster_is_centred_and_row_major() {
        let a = raster_antennas(&grid(Layout::Monostatic), &[], 0.0039);
        assert_eq!((a.columns, a.rows), (6, 3));
        assert_eq!(a.tx_m.len(), 18);
        assert!((a.tx_m[0][0] - 0.095).abs() < 1e-12);
        assert!((a.tx_m[1][0] - 0.097).abs() < 1e-12);
        assert!((a.tx_m[6][1] - 0.0).abs() < 1e-12);
        assert_eq!(a.tx_m, a.rx_m);
        let b = raster_antennas(&grid(Layout::Iwr1443boost), &[0, 1, 2, 3], 0.004);
        assert_eq!(b.tx_m.len(), 72);
        assert!((b.rx_m[3][0] - (b.tx_m[3][0] - 0.005)).abs() < 1e-12);
        assert!((b.rx_m[0][0] - (b.tx_m[0][0] - 0.011)).abs() < 1e-12);
    }

    #[test]
    fn iwr_pattern_is_6_db_down_at_half_beamwidth() {
        let p = Pattern::new(PatternKind::Iwr1443boost, Axis::X);
        let dir = |deg: f32, along_x: bool| {
            let (s, c) = deg.to_radians().sin_cos();
            if along_x { [s, 0.0, -c] } else { [0.0, s, -c] }
        };
        assert!((p.gain(dir(0.0, true)) - 1.0).abs() < 1e-6);
        assert!((p.gain(dir(50.0, true)) - 0.5).abs() < 1e-4);
        assert!((p.gain(dir(20.0, false)) - 0.5).abs() < 1e-4);
        assert_eq!(p.gain([0.0, 0.0, 1.0]), 0.0);
        // Off both planes: the product of the two cosine powers, in f64.
        let u = [0.3f64, -0.2, -(1.0f64 - 0.13).sqrt()];
        let (q_az, q_el) = p
            .exponents
            .map(|(a, e)| (f64::from(a), f64::from(e)))
            .unwrap();
        let want = (-u[2] / (u[0] * u[0] + u[2] * u[2]).sqrt()).powf(q_az)
            * (-u[2] / (u[1] * u[1] + u[2] * u[2]).sqrt()).powf(q_el);
        let got = f64::from(p.gain(u.map(|c| c as f32)));
        assert!((got - want).abs() < 1e-6 * want, "{got} against {want}");
    }
}
