//! The DCA1000's complex sample layouts (docs/protocols.md A6), chosen by the FPGA's
//! `lvds_mode` and the firmware's I/Q order.
//!
//! **4-lane** (`lvds_mode = 1`, xWR12xx/14xx such as the IWR1443): each sample instant of a chirp
//! is 8 little-endian `i16`, one LVDS lane per receiver, sample after sample, chirp after chirp:
//!
//! | word | 0 | 1 | 2 | 3 | 4 | 5 | 6 | 7 |
//! |---|---|---|---|---|---|---|---|---|
//! | I-first (studio_cli, MITO) | I lane 0 | I lane 1 | I lane 2 | I lane 3 | Q lane 0 | Q lane 1 | Q lane 2 | Q lane 3 |
//! | Q-first (SDK IQ swap) | Q lane 0 | … | | Q lane 3 | I lane 0 | … | | I lane 3 |
//!
//! Enabled receivers map to lanes in ascending channel order; the lanes of disabled receivers
//! carry zeros [verify on hardware].
//!
//! **2-lane** (`lvds_mode = 2`, xWR16xx/18xx/68xx): chirp after chirp, each enabled receiver's
//! samples in turn, in groups of two samples: `I(n) I(n+1) Q(n) Q(n+1)` (I-first) or
//! `Q(n) Q(n+1) I(n) I(n+1)` (Q-first). Only enabled receivers are sent, and a chirp holds an
//! even number of samples.
//!
//! The I/Q order is configured (`[dca1000] iq_order`) and, where the profile says it
//! (`adcbufCfg` SampleSwap, `testFmkCfg` iqSwapSel), checked against the profile.

use num_complex::Complex;

use crate::radar::RadarProfile;

/// LVDS lanes on the IWR1443.
pub const LANES: usize = 4;
/// Bytes per complex sample instant over the four lanes.
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

impl IqOrder {
    /// The name in the lab config.
    pub fn name(self) -> &'static str {
        match self {
            IqOrder::IFirst => "i_first",
            IqOrder::QFirst => "q_first",
        }
    }
}

/// The LVDS lane layout, from the FPGA's `lvds_mode`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Lanes {
    /// `lvds_mode = 1`: xWR12xx/14xx.
    #[default]
    Four,
    /// `lvds_mode = 2`: xWR16xx/18xx/68xx.
    Two,
}

impl Lanes {
    /// The layout of `lvds_mode` (1 or 2).
    pub fn from_lvds_mode(mode: u8) -> Result<Lanes, LayoutError> {
        match mode {
            1 => Ok(Lanes::Four),
            2 => Ok(Lanes::Two),
            other => Err(LayoutError::LvdsMode { mode: other }),
        }
    }
}

/// Why frame bytes could not be decoded, or a layout not formed.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum LayoutError {
    #[error("frame of {got} bytes; the profile's frames are {expected} bytes")]
    FrameSize { expected: usize, got: usize },
    #[error("{rx} receivers do not fit the {LANES} LVDS lanes")]
    TooManyReceivers { rx: usize },
    #[error("[dca1000.fpga] lvds_mode = {mode} is neither 1 (4-lane) nor 2 (2-lane)")]
    LvdsMode { mode: u8 },
    #[error(
        "the 2-lane layout sends samples in pairs; the profile's {samples} samples per chirp are odd"
    )]
    OddSamples { samples: usize },
    #[error(
        "[dca1000] iq_order = \"{iq_order}\" contradicts the profile's `{command}` {field} = {} ({}): the samples would decode with I and Q swapped",
        u8::from(*.swap),
        if *.swap { "Q first" } else { "I first" }
    )]
    IqOrderMismatch {
        iq_order: &'static str,
        command: &'static str,
        field: &'static str,
        swap: bool,
    },
}

/// The shape of one frame on the wire.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct FrameLayout {
    pub chirps_per_frame: usize,
    pub samples_per_chirp: usize,
    /// Enabled receivers; receiver i of this list rides lane i (4-lane) or comes i-th (2-lane).
    pub rx_count: usize,
    pub iq_order: IqOrder,
    pub lanes: Lanes,
}

impl FrameLayout {
    /// The layout a profile produces under `iq_order` and `lanes`. A profile that states its
    /// I/Q order ([`RadarProfile::sample_swap`]) must agree with `iq_order`.
    pub fn from_profile(
        profile: &RadarProfile,
        iq_order: IqOrder,
        lanes: Lanes,
    ) -> Result<Self, LayoutError> {
        let rx_count = profile.rx_count();
        if rx_count > LANES {
            return Err(LayoutError::TooManyReceivers { rx: rx_count });
        }
        if let Some((command, field, swap)) = profile.sample_swap
            && swap != (iq_order == IqOrder::QFirst)
        {
            return Err(LayoutError::IqOrderMismatch {
                iq_order: iq_order.name(),
                command,
                field,
                swap,
            });
        }
        let samples_per_chirp = profile.samples_per_chirp as usize;
        if lanes == Lanes::Two && samples_per_chirp % 2 == 1 {
            return Err(LayoutError::OddSamples {
                samples: samples_per_chirp,
            });
        }
        Ok(Self {
            chirps_per_frame: (profile.chirp_loops * profile.chirps_per_loop) as usize,
            samples_per_chirp,
            rx_count,
            iq_order,
            lanes,
        })
    }

    /// Bytes of one frame: chirps × samples × (4 lanes, or the enabled receivers under 2-lane)
    /// × (I, Q) × 2 bytes.
    pub fn frame_bytes(&self) -> usize {
        match self.lanes {
            Lanes::Four => self.chirps_per_frame * self.samples_per_chirp * BYTES_PER_INSTANT,
            Lanes::Two => self.chirps_per_frame * self.rx_count * self.samples_per_chirp * 4,
        }
    }

    /// Word offsets of (I, Q) of receiver `rx`, sample `s` of a chirp, from the chirp's first
    /// word.
    fn words(&self, rx: usize, s: usize) -> (usize, usize) {
        match self.lanes {
            Lanes::Four => {
                let (i_at, q_at) = match self.iq_order {
                    IqOrder::IFirst => (0, LANES),
                    IqOrder::QFirst => (LANES, 0),
                };
                let base = s * 2 * LANES;
                (base + i_at + rx, base + q_at + rx)
            }
            Lanes::Two => {
                let (i_at, q_at) = match self.iq_order {
                    IqOrder::IFirst => (0, 2),
                    IqOrder::QFirst => (2, 0),
                };
                let base = rx * self.samples_per_chirp * 2 + (s / 2) * 4 + s % 2;
                (base + i_at, base + q_at)
            }
        }
    }

    /// Words of one chirp.
    fn chirp_words(&self) -> usize {
        self.frame_bytes() / 2 / self.chirps_per_frame.max(1)
    }

    /// Decodes a frame into `[chirp][rx][sample]` complex samples.
    pub fn decode(&self, frame: &[u8]) -> Result<Vec<Complex<i16>>, LayoutError> {
        if frame.len() != self.frame_bytes() {
            return Err(LayoutError::FrameSize {
                expected: self.frame_bytes(),
                got: frame.len(),
            });
        }
        let n = self.samples_per_chirp;
        let mut out = vec![Complex::new(0i16, 0i16); self.chirps_per_frame * self.rx_count * n];
        let word = |w: usize| i16::from_le_bytes([frame[2 * w], frame[2 * w + 1]]);
        let per_chirp = self.chirp_words();
        for c in 0..self.chirps_per_frame {
            for rx in 0..self.rx_count {
                for s in 0..n {
                    let (i, q) = self.words(rx, s);
                    out[(c * self.rx_count + rx) * n + s] =
                        Complex::new(word(c * per_chirp + i), word(c * per_chirp + q));
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
                got: samples.len() * 4,
            });
        }
        let mut out = vec![0u8; self.frame_bytes()];
        let per_chirp = self.chirp_words();
        for c in 0..self.chirps_per_frame {
            for rx in 0..self.rx_count {
                for s in 0..n {
                    let v = samples[(c * self.rx_count + rx) * n + s];
                    let (i, q) = self.words(rx, s);
                    let (i, q) = (c * per_chirp + i, c * per_chirp + q);
                    out[2 * i..][..2].copy_from_slice(&v.re.to_le_bytes());
                    out[2 * q..][..2].copy_from_slice(&v.im.to_le_bytes());
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
            lanes: Lanes::Four,
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
        let l = FrameLayout::from_profile(&profile, IqOrder::IFirst, Lanes::Four).unwrap();
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
            lanes: Lanes::Four,
        };
        let bytes = l.encode(&[Complex::new(3, 4), Complex::new(5, 6)]).unwrap();
        let words: Vec<i16> = bytes
            .chunks(2)
            .map(|b| i16::from_le_bytes([b[0], b[1]]))
            .collect();
        assert_eq!(words, vec![3, 5, 0, 0, 4, 6, 0, 0]);
    }

    /// 2-lane words as TI's reader for xWR16xx takes them: per chirp, per receiver, groups
    /// `I(n) I(n+1) Q(n) Q(n+1)`; Q-first swaps the pairs.
    #[test]
    fn two_lane_words_decode_in_pairs_per_receiver() {
        let l = |order| FrameLayout {
            chirps_per_frame: 2,
            samples_per_chirp: 4,
            rx_count: 2,
            iq_order: order,
            lanes: Lanes::Two,
        };
        // Chirp 0: rx0 s0..3, rx1 s0..3; chirp 1 the same plus 100.
        let mut words: Vec<i16> = Vec::new();
        for c in 0..2i16 {
            for rx in 0..2i16 {
                for pair in 0..2i16 {
                    let base = 100 * c + 10 * rx + 2 * pair;
                    words.extend([base, base + 1, -base, -base - 1]);
                }
            }
        }
        let bytes: Vec<u8> = words.iter().flat_map(|w| w.to_le_bytes()).collect();
        let i_first = l(IqOrder::IFirst);
        assert_eq!(i_first.frame_bytes(), bytes.len());
        let d = i_first.decode(&bytes).unwrap();
        for c in 0..2 {
            for rx in 0..2 {
                for s in 0..4 {
                    let v = (100 * c + 10 * rx + s) as i16;
                    assert_eq!(
                        d[(c * 2 + rx) * 4 + s],
                        Complex::new(v, -v),
                        "c{c} rx{rx} s{s}"
                    );
                }
            }
        }
        let q = l(IqOrder::QFirst).decode(&bytes).unwrap();
        assert_eq!(q[5], Complex::new(-11, 11));
        assert_eq!(i_first.encode(&d).unwrap(), bytes);
        assert_eq!(l(IqOrder::QFirst).encode(&q).unwrap(), bytes);
    }

    /// A profile whose `adcbufCfg` says Q first is refused with `iq_order = "i_first"`, naming
    /// both; odd sample counts are refused under 2-lane; lvds_mode 3 is refused.
    #[test]
    fn the_iq_order_is_checked_against_the_profile() {
        let text = std::fs::read_to_string("firmware_cfg/iwr1443_mmnorm.cfg").unwrap();
        let swapped = text.replace("adcbufCfg -1 0 0 1 1", "adcbufCfg -1 0 1 1 1");
        assert_ne!(swapped, text);
        let profile = RadarProfile::from_cfg_str(&swapped).unwrap();
        let e = FrameLayout::from_profile(&profile, IqOrder::IFirst, Lanes::Four).unwrap_err();
        let message = e.to_string();
        assert!(
            message.contains("iq_order = \"i_first\"")
                && message.contains("adcbufCfg` SampleSwap = 1"),
            "{message}"
        );
        assert!(FrameLayout::from_profile(&profile, IqOrder::QFirst, Lanes::Four).is_ok());
        let profile = RadarProfile::from_cfg_str(&text).unwrap();
        assert!(FrameLayout::from_profile(&profile, IqOrder::QFirst, Lanes::Two).is_err());
        assert_eq!(
            Lanes::from_lvds_mode(3),
            Err(LayoutError::LvdsMode { mode: 3 })
        );
    }
}
