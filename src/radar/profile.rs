//! `RadarProfile`: a parsed and validated IWR1443 CLI profile.
//!
//! Conversions follow the mmWave SDK CLI handlers (`cli_mmwave.c`, see docs/protocols.md B2):
//! - start frequency code = trunc(f_GHz · 2²⁶ / 3.6), computed in double (LSB 53.644 Hz);
//! - slope code = (int16) trunc(S_MHz/µs · 2²⁶ / (3.6e3 · 900)), in double (LSB 48.2798 kHz/µs);
//! - idle, ADC start, ramp end and TX start times = trunc((float)t_µs · 1000 / 10) in single
//!   precision (LSB 10 ns);
//! - frame periodicity and trigger delay = trunc((float)t_ms · 1000000 / 5) in single precision
//!   (LSB 5 ns).
//!
//! The frequency of ADC sample 0 is start + slope · ADC start time; the frequency step per ADC
//! sample is slope / sample rate (the "slope" of the authors' params.json is this step).

use std::path::Path;

use crate::SPEED_OF_LIGHT_M_PER_S;
use crate::capture::FrequencyPlan;

/// 2²⁶, the scale of the mmWaveLink frequency codes.
const FREQ_CODE_SCALE: f64 = (1u64 << 26) as f64;
/// GHz per start-frequency code unit numerator (76–81 GHz parts).
const FREQ_SCALE_GHZ: f64 = 3.6;
/// Lowest and highest frequency the IWR1443 may sweep, Hz.
const BAND_MIN_HZ: f64 = 76.0e9;
const BAND_MAX_HZ: f64 = 81.0e9;
/// Largest programmable sweep, Hz.
const MAX_SWEEP_HZ: f64 = 4.0e9;
/// Largest slope magnitude, MHz/µs.
const MAX_SLOPE_MHZ_PER_US: f64 = 100.0;
/// Largest complex ADC output rate, ksps (DFE limit).
const MAX_COMPLEX_SAMPLE_RATE_KSPS: u32 = 18_750;
/// Frame periodicity limits, seconds.
const MIN_FRAME_PERIOD_S: f64 = 300e-6;
const MAX_FRAME_PERIOD_S: f64 = 1.342;

/// Commands that the mmWave Studio CLI firmware or the LVDS-stream test application accept and
/// that do not change the chirp itself. They are kept so a script that uses them still loads.
const PASS_THROUGH_COMMANDS: &[&str] = &[
    "sensorStop",
    "flushCfg",
    "sensorStart",
    "lowPower",
    "lvdsStreamCfg",
    "hsiClkCfg",
    "calibConfig",
    "calibMonCfg",
    "ldoBypass",
    "setProfileCfg",
    "version",
    "CQRxSatMonitor",
    "CQSigImgMonitor",
    "analogMonitor",
];

/// Where the receive antennas sit relative to the transmitter on the board.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum RxLayout {
    /// IWR1443BOOST: the four RX patches lie on a line at λ0/2 pitch, 5 mm from TX1.
    /// RX k sits at −(5 mm + (3 − k)·λ0/2) along the array axis (docs/mmnorm-reference.md §1: channel 0 is
    /// the farthest from the transmitter), with λ0 the wavelength of ADC sample 0.
    Iwr1443Boost,
}

/// A validated chirp profile with its register codes and derived figures.
#[derive(Debug, Clone, PartialEq)]
pub struct RadarProfile {
    /// Start-frequency register code (LSB 3.6 GHz / 2²⁶).
    pub start_frequency_code: u32,
    /// Slope register code (LSB 3.6e3·900 / 2²⁶ MHz/µs).
    pub slope_code: i16,
    /// Idle time, ADC start time and ramp end time as register codes (LSB 10 ns).
    pub idle_time_code: u32,
    pub adc_start_time_code: u32,
    pub ramp_end_time_code: u32,
    /// Complex ADC samples per chirp.
    pub samples_per_chirp: u32,
    /// ADC output rate, samples per second.
    pub sample_rate_hz: f64,
    /// Frame periodicity register code (LSB 5 ns).
    pub frame_period_code: u32,
    /// Frames per `sensorStart` (0 = until `sensorStop`).
    pub frames: u32,
    /// Chirp loops per frame.
    pub chirp_loops: u32,
    /// Chirps per loop (chirpEnd − chirpStart + 1).
    pub chirps_per_loop: u32,
    /// Enabled receive channels, in channel order (0..=3).
    pub rx_channels: Vec<u8>,
    /// Transmit enable mask of `channelCfg`.
    pub tx_mask: u8,
    /// ADC bits (12, 14 or 16).
    pub adc_bits: u8,
    /// The I/Q order the script sets, where it sets one: (command, field, true for Q first),
    /// from `adcbufCfg` SampleSwap or `testFmkCfg` iqSwapSel, the last one given.
    pub sample_swap: Option<(&'static str, &'static str, bool)>,
    /// The script lines that were accepted, comments removed, in order.
    pub script: Vec<String>,
}

/// Why a profile was refused. Every variant names the line where the problem is.
#[derive(Debug, thiserror::Error)]
pub enum ProfileError {
    #[error("cannot read radar profile {path}: {source}")]
    Io {
        path: String,
        #[source]
        source: std::io::Error,
    },
    #[error("line {line} (`{command}`): {reason}")]
    Line {
        line: usize,
        command: String,
        reason: String,
    },
    #[error("the profile has no `{command}` line; it is required")]
    Missing { command: &'static str },
}

fn line_err(line: usize, command: &str, reason: impl Into<String>) -> ProfileError {
    ProfileError::Line {
        line,
        command: command.to_string(),
        reason: reason.into(),
    }
}

/// Emulates `(uint32_t)((float)atof(s) * scale / div)` of the SDK CLI.
fn float_code(value: f64, scale: f32, div: f32) -> Option<u32> {
    let v = (value as f32) * scale / div;
    (v.is_finite() && v >= 0.0 && v < u32::MAX as f32).then_some(v as u32)
}

struct Args<'a> {
    line: usize,
    command: &'a str,
    words: Vec<&'a str>,
}

impl<'a> Args<'a> {
    fn expect_count(&self, counts: &[usize]) -> Result<(), ProfileError> {
        if counts.contains(&self.words.len()) {
            return Ok(());
        }
        let want = counts
            .iter()
            .map(|c| c.to_string())
            .collect::<Vec<_>>()
            .join(" or ");
        Err(line_err(
            self.line,
            self.command,
            format!("takes {want} arguments, found {}", self.words.len()),
        ))
    }

    fn float(&self, index: usize, name: &str) -> Result<f64, ProfileError> {
        let word = self.words.get(index).copied().unwrap_or("");
        word.parse::<f64>()
            .ok()
            .filter(|v| v.is_finite())
            .ok_or_else(|| {
                line_err(
                    self.line,
                    self.command,
                    format!("{name} must be a number, found `{word}`"),
                )
            })
    }

    fn int(&self, index: usize, name: &str) -> Result<i64, ProfileError> {
        let word = self.words.get(index).copied().unwrap_or("");
        word.parse::<i64>().map_err(|_| {
            line_err(
                self.line,
                self.command,
                format!("{name} must be an integer, found `{word}`"),
            )
        })
    }

    fn int_in(&self, index: usize, name: &str, lo: i64, hi: i64) -> Result<i64, ProfileError> {
        let v = self.int(index, name)?;
        if v < lo || v > hi {
            return Err(self.fail(format!("{name} = {v} is outside {lo}..={hi}")));
        }
        Ok(v)
    }

    fn fail(&self, reason: impl Into<String>) -> ProfileError {
        line_err(self.line, self.command, reason)
    }
}

#[derive(Default)]
struct Partial {
    output_mode_seen: bool,
    channel: Option<(u8, u8)>,
    adc: Option<u8>,
    profile: Option<ProfileFields>,
    chirps: Vec<(u32, u32, u8)>,
    frame: Option<FrameFields>,
    sample_swap: Option<(&'static str, &'static str, bool)>,
}

struct ProfileFields {
    line: usize,
    start_frequency_code: u32,
    slope_code: i16,
    idle_time_code: u32,
    adc_start_time_code: u32,
    ramp_end_time_code: u32,
    samples_per_chirp: u32,
    sample_rate_ksps: u32,
}

struct FrameFields {
    line: usize,
    chirp_start: u32,
    chirp_end: u32,
    loops: u32,
    frames: u32,
    period_code: u32,
}

impl RadarProfile {
    /// Reads and validates a `.cfg` file.
    pub fn from_cfg_file(path: &Path) -> Result<Self, ProfileError> {
        let text = std::fs::read_to_string(path).map_err(|source| ProfileError::Io {
            path: path.display().to_string(),
            source,
        })?;
        Self::from_cfg_str(&text)
    }

    /// Parses and validates the text of a `.cfg` script. Lines starting with `%` are comments.
    pub fn from_cfg_str(text: &str) -> Result<Self, ProfileError> {
        let mut partial = Partial::default();
        let mut script = Vec::new();
        for (index, raw) in text.lines().enumerate() {
            let line = index + 1;
            let trimmed = raw.trim();
            if trimmed.is_empty() || trimmed.starts_with('%') {
                continue;
            }
            let mut words = trimmed.split_whitespace();
            let Some(command) = words.next() else {
                continue;
            };
            let args = Args {
                line,
                command,
                words: words.collect(),
            };
            partial.apply(&args)?;
            script.push(trimmed.to_string());
        }
        partial.finish(script)
    }

    /// Start frequency of the ramp as programmed (after code truncation), Hz.
    pub fn ramp_start_frequency_hz(&self) -> f64 {
        self.start_frequency_code as f64 * FREQ_SCALE_GHZ * 1e9 / FREQ_CODE_SCALE
    }

    /// Slope as programmed (after code truncation), Hz/s.
    pub fn slope_hz_per_s(&self) -> f64 {
        slope_mhz_per_us_of_code(self.slope_code) * 1e12
    }

    /// ADC start time after the ramp start, seconds.
    pub fn adc_start_time_s(&self) -> f64 {
        self.adc_start_time_code as f64 * 10e-9
    }

    /// Ramp end time, seconds.
    pub fn ramp_end_time_s(&self) -> f64 {
        self.ramp_end_time_code as f64 * 10e-9
    }

    /// Idle time before each chirp, seconds.
    pub fn idle_time_s(&self) -> f64 {
        self.idle_time_code as f64 * 10e-9
    }

    /// Frame period, seconds.
    pub fn frame_period_s(&self) -> f64 {
        self.frame_period_code as f64 * 5e-9
    }

    /// From a frame's start to the end of its last chirp, when all its samples are on the LVDS
    /// lanes: chirps per frame × (idle + ramp end), seconds.
    pub fn frame_active_s(&self) -> f64 {
        f64::from(self.chirp_loops * self.chirps_per_loop)
            * (self.idle_time_s() + self.ramp_end_time_s())
    }

    /// From a frame's start to the middle of its first chirp's ADC window:
    /// idle + ADC start + N/(2·f_s), seconds.
    pub fn first_chirp_centre_s(&self) -> f64 {
        self.idle_time_s()
            + self.adc_start_time_s()
            + f64::from(self.samples_per_chirp) / (2.0 * self.sample_rate_hz)
    }

    /// Frequency of ADC sample 0: ramp start + slope · ADC start time, Hz.
    pub fn first_sample_frequency_hz(&self) -> f64 {
        self.ramp_start_frequency_hz() + self.slope_hz_per_s() * self.adc_start_time_s()
    }

    /// Frequency step between consecutive ADC samples: slope / sample rate, Hz.
    pub fn frequency_step_hz(&self) -> f64 {
        self.slope_hz_per_s() / self.sample_rate_hz
    }

    /// Wavelength at the frequency of ADC sample 0, metres.
    pub fn first_sample_wavelength_m(&self) -> f64 {
        SPEED_OF_LIGHT_M_PER_S / self.first_sample_frequency_hz()
    }

    /// Swept bandwidth covered by the ADC samples (step · samples), Hz.
    pub fn sampled_bandwidth_hz(&self) -> f64 {
        self.frequency_step_hz().abs() * self.samples_per_chirp as f64
    }

    /// One-way range resolution c / (2·B), metres.
    pub fn range_resolution_m(&self) -> f64 {
        SPEED_OF_LIGHT_M_PER_S / (2.0 * self.sampled_bandwidth_hz())
    }

    /// Largest one-way range with complex sampling, c·f_s / (2·slope), metres.
    pub fn max_range_m(&self) -> f64 {
        SPEED_OF_LIGHT_M_PER_S / (2.0 * self.frequency_step_hz().abs())
    }

    /// Number of enabled receive channels.
    pub fn rx_count(&self) -> usize {
        self.rx_channels.len()
    }

    /// Offsets of the enabled RX antennas from the TX antenna along the board's array axis,
    /// metres, in channel order.
    pub fn rx_offsets_m(&self, layout: RxLayout) -> Vec<f64> {
        let lambda0_m = self.first_sample_wavelength_m();
        match layout {
            RxLayout::Iwr1443Boost => self
                .rx_channels
                .iter()
                .map(|&k| iwr1443boost_rx_offset_m(k, lambda0_m))
                .collect(),
        }
    }

    /// The sampled frequency plan (start, step, count).
    pub fn frequency_plan(&self) -> FrequencyPlan {
        FrequencyPlan {
            start_frequency_hz: self.first_sample_frequency_hz(),
            frequency_step_hz: self.frequency_step_hz(),
            samples_per_chirp: self.samples_per_chirp as usize,
        }
    }
}

/// Offset of RX channel `k` (0..=3) from TX1 along the IWR1443BOOST's array axis, metres:
/// −(5 mm + (3 − k)·λ0/2).
pub fn iwr1443boost_rx_offset_m(k: u8, lambda0_m: f64) -> f64 {
    -(0.005 + f64::from(3u8.saturating_sub(k)) * lambda0_m / 2.0)
}

fn slope_mhz_per_us_of_code(code: i16) -> f64 {
    f64::from(code) * (FREQ_SCALE_GHZ * 1e3 * 900.0) / FREQ_CODE_SCALE
}

impl Partial {
    fn apply(&mut self, a: &Args<'_>) -> Result<(), ProfileError> {
        match a.command {
            "dfeDataOutputMode" => {
                a.expect_count(&[1])?;
                let mode = a.int(0, "mode")?;
                if mode != 1 {
                    return Err(a.fail(format!(
                        "mode {mode} is not supported; mmnormd records frame mode (1)"
                    )));
                }
                self.output_mode_seen = true;
            }
            "channelCfg" => {
                a.expect_count(&[3])?;
                let rx = a.int_in(0, "rxChannelEn", 1, 15)? as u8;
                let tx = a.int_in(1, "txChannelEn", 1, 7)? as u8;
                a.int_in(2, "cascading", 0, 0)?;
                self.channel = Some((rx, tx));
            }
            "adcCfg" => {
                a.expect_count(&[2])?;
                let bits = a.int_in(0, "numADCBits", 0, 2)?;
                let fmt = a.int_in(1, "adcOutputFmt", 0, 2)?;
                if fmt == 0 {
                    return Err(a.fail(
                        "adcOutputFmt 0 (real) is not supported; mmnormd needs complex samples (1 or 2)",
                    ));
                }
                self.adc = Some([12u8, 14, 16][bits as usize]);
            }
            "profileCfg" => self.apply_profile(a)?,
            "chirpCfg" => {
                a.expect_count(&[8])?;
                let start = a.int_in(0, "chirpStartIdx", 0, 511)? as u32;
                let end = a.int_in(1, "chirpEndIdx", 0, 511)? as u32;
                let profile = a.int_in(2, "profileId", 0, 3)? as u8;
                for (i, name) in [(3, "startFreqVar"), (4, "freqSlopeVar")] {
                    if a.float(i, name)? != 0.0 {
                        return Err(a.fail(format!(
                            "{name} must be 0: mmnormd assumes every chirp uses the profile's plan"
                        )));
                    }
                }
                a.float(5, "idleTimeVar")?;
                a.float(6, "adcStartTimeVar")?;
                a.int_in(7, "txEnable", 1, 7)?;
                if end < start {
                    return Err(
                        a.fail(format!("chirpEndIdx {end} is before chirpStartIdx {start}"))
                    );
                }
                if self.profile.is_none() || profile != 0 {
                    return Err(a.fail(format!(
                        "profileId {profile} is not defined by an earlier profileCfg"
                    )));
                }
                self.chirps.push((start, end, profile));
            }
            "frameCfg" => {
                a.expect_count(&[7])?;
                let chirp_start = a.int_in(0, "chirpStartIdx", 0, 511)? as u32;
                let chirp_end = a.int_in(1, "chirpEndIdx", 0, 511)? as u32;
                let loops = a.int_in(2, "numLoops", 1, 255)? as u32;
                let frames = a.int_in(3, "numFrames", 0, 65535)? as u32;
                let period_ms = a.float(4, "framePeriodicity")?;
                let period_code = float_code(period_ms, 1_000_000.0, 5.0)
                    .ok_or_else(|| a.fail(format!("framePeriodicity {period_ms} ms is invalid")))?;
                let period_s = period_code as f64 * 5e-9;
                if !(MIN_FRAME_PERIOD_S..=MAX_FRAME_PERIOD_S).contains(&period_s) {
                    return Err(a.fail(format!(
                        "framePeriodicity {period_ms} ms is outside 0.3 ms..=1342 ms"
                    )));
                }
                a.int_in(5, "triggerSelect", 1, 2)?;
                a.float(6, "frameTriggerDelay")?;
                if chirp_end < chirp_start {
                    return Err(a.fail(format!(
                        "chirpEndIdx {chirp_end} is before chirpStartIdx {chirp_start}"
                    )));
                }
                self.frame = Some(FrameFields {
                    line: a.line,
                    chirp_start,
                    chirp_end,
                    loops,
                    frames,
                    period_code,
                });
            }
            "adcbufCfg" => {
                // SDK 2.x and studio_cli: subFrameIdx first (5 words); SDK 1.x: 4 words.
                a.expect_count(&[4, 5])?;
                let at = a.words.len() - 4;
                a.int_in(at, "adcOutputFmt", 0, 0)?;
                let swap = a.int_in(at + 1, "SampleSwap", 0, 1)? == 1;
                a.int_in(at + 2, "ChanInterleave", 0, 1)?;
                self.sample_swap = Some(("adcbufCfg", "SampleSwap", swap));
            }
            "testFmkCfg" => {
                if a.words.len() < 2 {
                    return Err(a.fail("needs at least adcFmt and iqSwapSel"));
                }
                let swap = a.int_in(1, "iqSwapSel", 0, 1)? == 1;
                self.sample_swap = Some(("testFmkCfg", "iqSwapSel", swap));
            }
            other if PASS_THROUGH_COMMANDS.contains(&other) => {}
            other => {
                return Err(a.fail(format!(
                    "`{other}` is not a command of the mmWave CLI firmware that mmnormd drives"
                )));
            }
        }
        Ok(())
    }

    fn apply_profile(&mut self, a: &Args<'_>) -> Result<(), ProfileError> {
        a.expect_count(&[14])?;
        if !self.output_mode_seen {
            return Err(a.fail("profileCfg must follow `dfeDataOutputMode 1`"));
        }
        if self.profile.is_some() {
            return Err(a.fail("only one profile is supported"));
        }
        a.int_in(0, "profileId", 0, 0)?;
        let start_ghz = a.float(1, "startFreq")?;
        let start_code_f = start_ghz * FREQ_CODE_SCALE / FREQ_SCALE_GHZ;
        if !(start_code_f >= 0.0 && start_code_f < u32::MAX as f64) {
            return Err(a.fail(format!("startFreq {start_ghz} GHz is out of range")));
        }
        let start_frequency_code = start_code_f as u32;
        let time_code = |i: usize, name: &str| -> Result<u32, ProfileError> {
            let us = a.float(i, name)?;
            float_code(us, 1000.0, 10.0)
                .ok_or_else(|| a.fail(format!("{name} {us} µs must be zero or positive")))
        };
        let idle_time_code = time_code(2, "idleTime")?;
        let adc_start_time_code = time_code(3, "adcStartTime")?;
        let ramp_end_time_code = time_code(4, "rampEndTime")?;
        a.int(5, "txOutPower")?;
        a.int(6, "txPhaseShifter")?;
        let slope = a.float(7, "freqSlopeConst")?;
        if slope.abs() > MAX_SLOPE_MHZ_PER_US {
            return Err(a.fail(format!(
                "slope {slope} MHz/µs exceeds the IWR1443 limit of {MAX_SLOPE_MHZ_PER_US} MHz/µs"
            )));
        }
        let slope_code = (slope * FREQ_CODE_SCALE / (FREQ_SCALE_GHZ * 1e3 * 900.0)) as i16;
        if slope_code == 0 {
            return Err(a.fail(format!("slope {slope} MHz/µs truncates to code 0")));
        }
        time_code(8, "txStartTime")?;
        let samples = a.int_in(9, "numAdcSamples", 1, 1024)? as u32;
        let rate_ksps = a.int_in(
            10,
            "digOutSampleRate",
            1,
            MAX_COMPLEX_SAMPLE_RATE_KSPS as i64,
        )?;
        a.int_in(11, "hpfCornerFreq1", 0, 3)?;
        a.int_in(12, "hpfCornerFreq2", 0, 3)?;
        let gain = a.int_in(13, "rxGain", 0, 52)?;
        if gain % 2 != 0 {
            return Err(a.fail(format!("rxGain {gain} dB must be even")));
        }

        let fields = ProfileFields {
            line: a.line,
            start_frequency_code,
            slope_code,
            idle_time_code,
            adc_start_time_code,
            ramp_end_time_code,
            samples_per_chirp: samples,
            sample_rate_ksps: rate_ksps as u32,
        };
        fields.check_physics(a)?;
        self.profile = Some(fields);
        Ok(())
    }

    fn finish(self, script: Vec<String>) -> Result<RadarProfile, ProfileError> {
        let (rx_mask, tx_mask) = self.channel.ok_or(ProfileError::Missing {
            command: "channelCfg",
        })?;
        let adc_bits = self
            .adc
            .ok_or(ProfileError::Missing { command: "adcCfg" })?;
        let p = self.profile.ok_or(ProfileError::Missing {
            command: "profileCfg",
        })?;
        let frame = self.frame.ok_or(ProfileError::Missing {
            command: "frameCfg",
        })?;
        for idx in frame.chirp_start..=frame.chirp_end {
            if !self.chirps.iter().any(|&(s, e, _)| (s..=e).contains(&idx)) {
                return Err(line_err(
                    frame.line,
                    "frameCfg",
                    format!("chirp {idx} is not defined by any chirpCfg"),
                ));
            }
        }
        let chirps_per_loop = frame.chirp_end - frame.chirp_start + 1;
        let chirp_s = (p.idle_time_code + p.ramp_end_time_code) as f64 * 10e-9;
        let active_s = chirp_s * f64::from(chirps_per_loop * frame.loops);
        let period_s = frame.period_code as f64 * 5e-9;
        if active_s > period_s {
            return Err(line_err(
                frame.line,
                "frameCfg",
                format!(
                    "the chirps take {:.3} ms, longer than the {:.3} ms frame period",
                    active_s * 1e3,
                    period_s * 1e3
                ),
            ));
        }
        let _ = p.line;
        Ok(RadarProfile {
            start_frequency_code: p.start_frequency_code,
            slope_code: p.slope_code,
            idle_time_code: p.idle_time_code,
            adc_start_time_code: p.adc_start_time_code,
            ramp_end_time_code: p.ramp_end_time_code,
            samples_per_chirp: p.samples_per_chirp,
            sample_rate_hz: f64::from(p.sample_rate_ksps) * 1e3,
            frame_period_code: frame.period_code,
            frames: frame.frames,
            chirp_loops: frame.loops,
            chirps_per_loop,
            rx_channels: (0..4u8).filter(|k| rx_mask & (1 << k) != 0).collect(),
            tx_mask,
            adc_bits,
            sample_swap: self.sample_swap,
            script,
        })
    }
}

impl ProfileFields {
    /// Checks the ramp against the band, the sweep limit and the ADC window.
    fn check_physics(&self, a: &Args<'_>) -> Result<(), ProfileError> {
        let start_hz = self.start_frequency_code as f64 * FREQ_SCALE_GHZ * 1e9 / FREQ_CODE_SCALE;
        let slope_hz_per_s = slope_mhz_per_us_of_code(self.slope_code) * 1e12;
        let ramp_end_s = self.ramp_end_time_code as f64 * 10e-9;
        let end_hz = start_hz + slope_hz_per_s * ramp_end_s;
        let (lo, hi) = (start_hz.min(end_hz), start_hz.max(end_hz));
        if lo < BAND_MIN_HZ || hi > BAND_MAX_HZ {
            return Err(a.fail(format!(
                "the sweep {:.4}–{:.4} GHz leaves the 76–81 GHz band",
                lo / 1e9,
                hi / 1e9
            )));
        }
        if hi - lo > MAX_SWEEP_HZ {
            return Err(a.fail(format!(
                "the sweep spans {:.4} GHz, more than the 4 GHz the IWR1443 can ramp",
                (hi - lo) / 1e9
            )));
        }
        let adc_start_s = self.adc_start_time_code as f64 * 10e-9;
        let window_s = f64::from(self.samples_per_chirp) / (f64::from(self.sample_rate_ksps) * 1e3);
        if adc_start_s + window_s > ramp_end_s {
            return Err(a.fail(format!(
                "the ADC window ends at {:.3} µs ({:.3} µs start + {} samples at {} ksps), after the ramp ends at {:.3} µs",
                (adc_start_s + window_s) * 1e6,
                adc_start_s * 1e6,
                self.samples_per_chirp,
                self.sample_rate_ksps,
                ramp_end_s * 1e6
            )));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const SHIPPED: &str = include_str!("../../firmware_cfg/iwr1443_mmnorm.cfg");

    fn with_profile_line(line: &str) -> String {
        SHIPPED
            .lines()
            .map(|l| if l.starts_with("profileCfg") { line } else { l })
            .collect::<Vec<_>>()
            .join("\n")
    }

    fn refusal(text: &str) -> (usize, String) {
        match RadarProfile::from_cfg_str(text) {
            Err(ProfileError::Line { line, reason, .. }) => (line, reason),
            other => panic!("expected a line error, got {other:?}"),
        }
    }

    fn profile_line_number() -> usize {
        SHIPPED
            .lines()
            .position(|l| l.starts_with("profileCfg"))
            .map(|i| i + 1)
            .unwrap()
    }

    #[test]
    fn shipped_profile_matches_the_authors_frequency_plan() {
        let p = RadarProfile::from_cfg_str(SHIPPED).unwrap();
        let f0 = p.first_sample_frequency_hz();
        let step = p.frequency_step_hz();
        println!("f0 = {f0:.1} Hz, step = {step:.3} Hz/sample");
        assert!((f0 - 77.5001e9).abs() <= 0.1e6, "f0 = {f0}");
        assert!((step - 5.861163e6).abs() <= 1.0, "step = {step}");
        assert_eq!(p.slope_code, 1214);
        assert_eq!(p.adc_start_time_code, 512);
        assert_eq!(p.ramp_end_time_code, 6000);
        assert_eq!(p.samples_per_chirp, 512);
        assert_eq!(p.sample_rate_hz, 10e6);
        assert!((p.frame_period_s() - 3e-3).abs() < 1e-12);
        assert_eq!(p.frames, 4000);
        assert_eq!(p.rx_count(), 4);
        let offsets = p.rx_offsets_m(RxLayout::Iwr1443Boost);
        let lambda = p.first_sample_wavelength_m();
        assert!((offsets[3] + 0.005).abs() < 1e-12);
        assert!((offsets[0] + 0.005 + 1.5 * lambda).abs() < 1e-12);
        assert!((lambda - 3.8683e-3).abs() < 1e-6, "λ0 = {lambda}");
        assert!((p.range_resolution_m() - 0.04995).abs() < 1e-4);
        assert!((p.max_range_m() - 25.57).abs() < 0.01);
    }

    #[test]
    fn slope_typed_with_too_few_digits_truncates_to_the_lower_code() {
        let p = RadarProfile::from_cfg_str(&with_profile_line(
            "profileCfg 0 77.2 10 5.12 60 0 0 58.6116 1 512 10000 0 0 30",
        ))
        .unwrap();
        assert_eq!(p.slope_code, 1213);
    }

    #[test]
    fn slope_over_100_mhz_per_us_is_refused_with_its_line() {
        let (line, reason) = refusal(&with_profile_line(
            "profileCfg 0 77 10 1 8 0 0 100.5 1 64 10000 0 0 30",
        ));
        assert_eq!(line, profile_line_number());
        assert!(reason.contains("100.5"), "{reason}");
    }

    #[test]
    fn adc_window_longer_than_the_ramp_is_refused() {
        let (line, reason) = refusal(&with_profile_line(
            "profileCfg 0 77.2 10 5.12 50 0 0 58.612 1 512 10000 0 0 30",
        ));
        assert_eq!(line, profile_line_number());
        assert!(reason.contains("ADC window"), "{reason}");
    }

    #[test]
    fn sweep_leaving_the_band_is_refused() {
        let (_, reason) = refusal(&with_profile_line(
            "profileCfg 0 79.5 10 5.12 60 0 0 58.612 1 512 10000 0 0 30",
        ));
        assert!(reason.contains("76–81 GHz"), "{reason}");
        let (_, reason) = refusal(&with_profile_line(
            "profileCfg 0 75.9 10 5.12 60 0 0 58.612 1 512 10000 0 0 30",
        ));
        assert!(reason.contains("76–81 GHz"), "{reason}");
    }

    #[test]
    fn unknown_commands_and_bad_numbers_name_their_line() {
        let text = format!("{}\nfrobnicate 1 2\n", SHIPPED.trim_end());
        let (line, reason) = refusal(&text);
        assert_eq!(line, SHIPPED.lines().count() + 1);
        assert!(reason.contains("frobnicate"));
        let (line, reason) = refusal(&with_profile_line(
            "profileCfg 0 77.2 10 5.12 60 0 0 fast 1 512 10000 0 0 30",
        ));
        assert_eq!(line, profile_line_number());
        assert!(reason.contains("`fast`"), "{reason}");
        let (_, reason) = refusal(&with_profile_line("profileCfg 0 77.2 10"));
        assert!(reason.contains("takes 14 arguments"), "{reason}");
    }

    #[test]
    fn missing_frame_and_undefined_chirps_are_refused() {
        let no_frame: String = SHIPPED
            .lines()
            .filter(|l| !l.starts_with("frameCfg"))
            .collect::<Vec<_>>()
            .join("\n");
        assert!(matches!(
            RadarProfile::from_cfg_str(&no_frame),
            Err(ProfileError::Missing {
                command: "frameCfg"
            })
        ));
        let text = SHIPPED.replace("frameCfg 0 0 1", "frameCfg 0 1 1");
        let (_, reason) = refusal(&text);
        assert!(reason.contains("chirp 1"), "{reason}");
    }

    #[test]
    fn frame_shorter_than_its_chirps_is_refused() {
        let text = SHIPPED.replace("frameCfg 0 0 1 4000 3 1 0", "frameCfg 0 0 255 4000 3 1 0");
        let (_, reason) = refusal(&text);
        assert!(reason.contains("frame period"), "{reason}");
    }
}
