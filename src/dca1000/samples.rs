//! The IWR1443's 4-lane complex sample layout (docs/protocols.md A6).
//!
//! Each sample instant of a chirp is 8 little-endian `i16`, one LVDS lane per receiver:
//!
//! | word | 0 | 1 | 2 | 3 | 4 | 5 | 6 | 7 |
//! |---|---|---|---|---|---|---|---|---|
//! | I-first (studio_cli, MITO) | I lane 0 | I lane 1 | I lane 2 | I lane 3 | Q lane 0 | Q lane 1 | Q lane 2 | Q lane 3 |
//! | Q-first (SDK IQ swap) | Q lane 0 | … | | Q lane 3 | I lane 0 | … | | I lane 3 |
//!
//! Sample after sample, chirp after chirp. Enabled receivers map to lanes in ascending channel
//! order; the lanes of disabled receivers carry zeros [verify on hardware].

use num_complex::Complex;

use crate::radar::RadarProfile;

/// LVDS lanes on the IWR1443.
pub const LANES: usize = 4;
/// Bytes per complex sample instant over all lanes.
const BYTES_PER_INSTANT: usize = LANES * 2 * 2;

/// Which half of a sample instant carries I.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum IqOrder {
    /// I words first (mmWave Studio and its CLI firmware; what MITO's loader assumes).
    #[default]
    IFirst,
    /// Q words first (mmWave SDK with SampleSwap = 1).
    QFirst,
}

/// Why frame bytes could not be decoded.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum LayoutError {
    #[error("frame of {got} bytes; the profile's frames are {expected} bytes")]
    FrameSize { expected: usize, got: usize },
    #[error("{rx} receivers do not fit the {LANES} LVDS lanes")]
    TooManyReceivers { rx: usize },
}

/// The shape of one frame on the wire.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct FrameLayout {
    pub chirps_per_frame: usize,
    pub samples_per_chirp: usize,
    /// Enabled receivers; receiver i of this list rides lane i.
    pub rx_count: usize,
    pub iq_order: IqOrder,
}

impl FrameLayout {
    /// The layout a profile produces.
    pub fn from_profile(profile: &RadarProfile, iq_order: IqOrder) -> Result<Self, LayoutError> {
        let rx_count = profile.rx_count();
        if rx_count > LANES {
            return Err(LayoutError::TooManyReceivers { rx: rx_count });
        }
        Ok(Self {
            chirps_per_frame: (profile.chirp_loops * profile.chirps_per_loop) as usize,
            samples_per_chirp: profile.samples_per_chirp as usize,
            rx_count,
            iq_order,
        })
    }

    /// Bytes of one frame: chirps × samples × 4 lanes × (I, Q) × 2 bytes.
    pub fn frame_bytes(&self) -> usize {
        self.chirps_per_frame * self.samples_per_chirp * BYTES_PER_INSTANT
    }

    /// Decodes a frame into `[chirp][rx][sample]` complex samples.
    pub fn decode(&self, frame: &[u8]) -> Result<Vec<Complex<i16>>, LayoutError> {
        if frame.len() != self.frame_bytes() {
            return Err(LayoutError::FrameSize {
                expected: self.frame_bytes(),
                got: frame.len(),
            });
        }
        let (i_at, q_at) = match self.iq_order {
            IqOrder::IFirst => (0, LANES),
            IqOrder::QFirst => (LANES, 0),
        };
        let n = self.samples_per_chirp;
        let mut out = vec![Complex::new(0i16, 0i16); self.chirps_per_frame * self.rx_count * n];
        let word =
            |instant: &[u8], w: usize| i16::from_le_bytes([instant[2 * w], instant[2 * w + 1]]);
        for (c, chirp) in frame.chunks_exact(n * BYTES_PER_INSTANT).enumerate() {
            for (s, instant) in chirp.chunks_exact(BYTES_PER_INSTANT).enumerate() {
                for rx in 0..self.rx_count {
                    out[(c * self.rx_count + rx) * n + s] =
                        Complex::new(word(instant, i_at + rx), word(instant, q_at + rx));
                }
            }
        }
        Ok(out)
    }

    /// Encodes `[chirp][rx][sample]` samples into frame bytes: the inverse of
    /// [`decode`](Self::decode), with zeros on unused lanes. `samples` must hold exactly one
    /// frame.
    pub fn encode(&self, samples: &[Complex<i16>]) -> Result<Vec<u8>, LayoutError> {
        let n = self.samples_per_chirp;
        let expected = self.chirps_per_frame * self.rx_count * n;
        if samples.len() != expected {
            return Err(LayoutError::FrameSize {
                expected: self.frame_bytes(),
                got: samples.len() / self.rx_count.max(1) * BYTES_PER_INSTANT,
            });
        }
        let (i_at, q_at) = match self.iq_order {
            IqOrder::IFirst => (0, LANES),
            IqOrder::QFirst => (LANES, 0),
        };
        let mut out = vec![0u8; self.frame_bytes()];
        for c in 0..self.chirps_per_frame {
            for s in 0..n {
                let base = (c * n + s) * BYTES_PER_INSTANT;
                for rx in 0..self.rx_count {
                    let v = samples[(c * self.rx_count + rx) * n + s];
                    out[base + 2 * (i_at + rx)..][..2].copy_from_slice(&v.re.to_le_bytes());
                    out[base + 2 * (q_at + rx)..][..2].copy_from_slice(&v.im.to_le_bytes());
                }
            }
        }
        Ok(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn layout(order: IqOrder) -> FrameLayout {
        FrameLayout {
            chirps_per_frame: 1,
            samples_per_chirp: 2,
            rx_count: 4,
            iq_order: order,
        }
    }

    #[test]
    fn i_first_words_decode_as_mito_reads_them() {
        // Rows of 8 int16: columns 0..4 are I of rx 0..3, 4..8 Q (generic_loader.py).
        let words: [i16; 16] = [1, 2, 3, 4, -1, -2, -3, -4, 5, 6, 7, 8, -5, -6, -7, -8];
        let bytes: Vec<u8> = words.iter().flat_map(|w| w.to_le_bytes()).collect();
        let d = layout(IqOrder::IFirst).decode(&bytes).unwrap();
        assert_eq!(d[0], Complex::new(1, -1)); // rx0 s0
        assert_eq!(d[1], Complex::new(5, -5)); // rx0 s1
        assert_eq!(d[2 * 3 + 1], Complex::new(8, -8)); // rx3 s1
        let q = layout(IqOrder::QFirst).decode(&bytes).unwrap();
        assert_eq!(q[0], Complex::new(-1, 1));
        assert_eq!(layout(IqOrder::IFirst).encode(&d).unwrap(), bytes);
        assert_eq!(layout(IqOrder::QFirst).encode(&q).unwrap(), bytes);
    }

    #[test]
    fn the_mmnorm_profile_gives_8192_byte_frames() {
        let text = std::fs::read_to_string("firmware_cfg/iwr1443_mmnorm.cfg").unwrap();
        let profile = RadarProfile::from_cfg_str(&text).unwrap();
        let l = FrameLayout::from_profile(&profile, IqOrder::IFirst).unwrap();
        assert_eq!(l.frame_bytes(), 8192);
        assert_eq!(
            l.decode(&[0u8; 100]),
            Err(LayoutError::FrameSize {
                expected: 8192,
                got: 100
            })
        );
    }

    #[test]
    fn fewer_receivers_leave_their_lanes_zero() {
        let l = FrameLayout {
            chirps_per_frame: 1,
            samples_per_chirp: 1,
            rx_count: 2,
            iq_order: IqOrder::IFirst,
        };
        let bytes = l.encode(&[Complex::new(3, 4), Complex::new(5, 6)]).unwrap();
        let words: Vec<i16> = bytes
            .chunks(2)
            .map(|b| i16::from_le_bytes([b[0], b[1]]))
            .collect();
        assert_eq!(words, vec![3, 5, 0, 0, 4, 6, 0, 0]);
    }
}
