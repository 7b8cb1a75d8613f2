//! The commands of the mmWave Studio CLI firmware and the LVDS-stream test application
//! (docs/protocols.md B2), with the argument counts each accepts.

/// `(command, accepted argument counts)`; an empty list accepts any count.
pub const COMMANDS: &[(&str, &[usize])] = &[
    ("sensorStop", &[0]),
    ("flushCfg", &[0]),
    ("sensorStart", &[0, 1]),
    ("dfeDataOutputMode", &[1]),
    ("channelCfg", &[3]),
    ("adcCfg", &[2]),
    ("adcbufCfg", &[4, 5]),
    ("lowPower", &[2]),
    ("profileCfg", &[14]),
    ("chirpCfg", &[8]),
    ("frameCfg", &[7]),
    ("lvdsStreamCfg", &[4]),
    ("hsiClkCfg", &[1]),
    ("testFmkCfg", &[4]),
    ("setProfileCfg", &[3]),
    ("version", &[0]),
    ("calibConfig", &[]),
    ("calibMonCfg", &[]),
    ("ldoBypass", &[]),
    ("CQRxSatMonitor", &[]),
    ("CQSigImgMonitor", &[]),
    ("analogMonitor", &[]),
];

/// The argument counts of `command`, or `None` for a command the firmware does not have.
pub fn argument_counts(command: &str) -> Option<&'static [usize]> {
    COMMANDS
        .iter()
        .find(|(name, _)| *name == command)
        .map(|(_, counts)| *counts)
}
