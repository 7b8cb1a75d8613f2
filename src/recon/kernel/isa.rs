//! Which instruction set the kernel runs in: the widest the CPU has, unless the environment
//! variable [`KERNEL_ENV`] asks for a narrower one (to compare them, or to rule one out).

use std::sync::OnceLock;

/// The environment variable that picks the kernel's instruction set: `avx512`, `avx2` or
/// `scalar`. Unset, the widest the CPU runs is used.
pub const KERNEL_ENV: &str = "MMNORMD_KERNEL";

/// An instruction set the kernel is written in, narrowest first.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum KernelIsa {
    /// The plain statement of the kernel, one voxel at a time.
    Scalar,
    /// AVX2 and FMA, eight voxels a step.
    Avx2,
    /// AVX-512F, sixteen voxels a step.
    Avx512,
}

/// Why [`KERNEL_ENV`] cannot be honoured.
#[derive(Debug, thiserror::Error)]
pub enum KernelIsaError {
    #[error("{KERNEL_ENV}={0:?}: expected avx512, avx2 or scalar")]
    Unknown(String),
    #[error("{KERNEL_ENV}={asked}: this CPU runs at most {best}")]
    Unsupported { asked: KernelIsa, best: KernelIsa },
}

impl std::fmt::Display for KernelIsa {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Self::Scalar => "scalar",
            Self::Avx2 => "avx2",
            Self::Avx512 => "avx512",
        })
    }
}

impl KernelIsa {
    /// Voxels per step.
    pub fn lanes(self) -> usize {
        match self {
            Self::Scalar => 1,
            Self::Avx2 => 8,
            Self::Avx512 => 16,
        }
    }

    /// The widest instruction set this CPU runs.
    pub fn best() -> Self {
        #[cfg(target_arch = "x86_64")]
        {
            if super::avx512::available() {
                return Self::Avx512;
            }
            if super::avx2::available() {
                return Self::Avx2;
            }
        }
        Self::Scalar
    }

    /// Every instruction set this CPU runs, widest first.
    pub fn available() -> Vec<Self> {
        let best = Self::best();
        [Self::Avx512, Self::Avx2, Self::Scalar]
            .into_iter()
            .filter(|&isa| isa <= best)
            .collect()
    }

    /// Parses a name, and checks that this CPU runs it.
    pub fn parse(name: &str) -> Result<Self, KernelIsaError> {
        let asked = match name.trim().to_ascii_lowercase().as_str() {
            "avx512" => Self::Avx512,
            "avx2" => Self::Avx2,
            "scalar" => Self::Scalar,
            _ => return Err(KernelIsaError::Unknown(name.to_string())),
        };
        let best = Self::best();
        if asked > best {
            return Err(KernelIsaError::Unsupported { asked, best });
        }
        Ok(asked)
    }

    /// [`KERNEL_ENV`]'s choice, checked against the CPU; None where it is unset or empty. The
    /// command line calls this first, so that a bad value stops it with this error.
    pub fn from_env() -> Result<Option<Self>, KernelIsaError> {
        match std::env::var(KERNEL_ENV) {
            Ok(name) if !name.trim().is_empty() => Self::parse(&name).map(Some),
            Ok(_) | Err(std::env::VarError::NotPresent) => Ok(None),
            Err(std::env::VarError::NotUnicode(raw)) => {
                Err(KernelIsaError::Unknown(raw.to_string_lossy().into_owned()))
            }
        }
    }

    /// The instruction set of every kernel call in this process, fixed at the first call:
    /// [`KERNEL_ENV`]'s choice where it is valid, otherwise (with a warning) the widest.
    pub fn active() -> Self {
        static ACTIVE: OnceLock<KernelIsa> = OnceLock::new();
        *ACTIVE.get_or_init(|| match Self::from_env() {
            Ok(Some(isa)) => isa,
            Ok(None) => Self::best(),
            Err(e) => {
                let best = Self::best();
                tracing::warn!("{e}; the kernel runs in {best}");
                best
            }
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_parse_and_unknown_ones_are_named() {
        for isa in KernelIsa::available() {
            assert_eq!(KernelIsa::parse(&isa.to_string()).unwrap(), isa);
        }
        assert_eq!(KernelIsa::parse(" Scalar ").unwrap(), KernelIsa::Scalar);
        let e = KernelIsa::parse("sse9").unwrap_err().to_string();
        assert_eq!(
            e,
            "MMNORMD_KERNEL=\"sse9\": expected avx512, avx2 or scalar"
        );
        if KernelIsa::best() < KernelIsa::Avx512 {
            let e = KernelIsa::parse("avx512").unwrap_err().to_string();
            assert!(
                e.starts_with("MMNORMD_KERNEL=avx512: this CPU runs at most"),
                "{e}"
            );
        }
        assert_eq!(KernelIsa::available().last(), Some(&KernelIsa::Scalar));
    }
}
