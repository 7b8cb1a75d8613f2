//! `mmnormd bench kernel`: the exact per-antenna kernel alone (`recon::kernel`), in
//! (voxel, antenna) updates per second, and as a fraction of the machine's arithmetic peak.
//!
//! **Workload**: the capture of `bench perf` at `scale` (0.3 gives 1.05·10⁵ virtual channels)
//! and a cube of `edge`³ voxels at the grid's 1 mm pitch, in the middle of its box. Two
//! kernels, each timed `repeats` times on all threads and on one, medians reported:
//! - **image**: interpolated backprojection ([`backproject`]) over the cube;
//! - **votes**: exact per-antenna normal votes ([`normal_field`]) on every voxel of the cube.
//!
//! The kernel runs in [`KernelIsa::active`]: the widest instruction set the CPU has, or the
//! one `MMNORMD_KERNEL` names, so that two runs compare them.
//!
//! **Peak**: the arithmetic of one update in the vector kernels is [`FLOPS_PER_UPDATE`]
//! single-precision operations (an FMA counts two). A core with two FMA pipes as wide as the
//! instruction set's vectors (8 lanes in AVX2, 16 in AVX-512) does at most `2 · 2 · lanes` of
//! them per cycle, so the bound is `threads · 4 · lanes · f / 60.75` updates/s at clock `f`
//! (read from `/proc/cpuinfo`; absent elsewhere). A core that splits 512-bit operations in
//! two halves the AVX-512 bound.

use serde::Serialize;

use super::median_seconds;
use super::perf::{PerfError, synthesize};
use crate::recon::ReconConfig;
use crate::recon::image::{RangeProfiles, VoxelGrid, backproject};
use crate::recon::kernel::KernelIsa;
use crate::recon::normals::{Candidates, normal_field};

/// Single-precision arithmetic per update in the vector kernel (`recon::kernel::vector`, the
/// same in AVX2 and AVX-512; FMA = 2; clamps and conversions not counted):
/// - the RX leg 9 (3 sub, 1 mul, 2 FMA, 1 sqrt);
/// - the TX leg's 15 (its distance 9, the offset 1, its bin share and whole turns 5), shared
///   by a group of four: 3.75;
/// - the bin 3 and the carrier's turns 2;
/// - the sine and cosine 29: the reduction 3, the two polynomials 23 (5 FMA for the sine's 6
///   coefficients, 6 for the cosine's 7, and the sine's factor u), the double angle 3;
/// - the interpolation 6, the rotation 6 and the sum 2.
///
/// That is 60.75. (An earlier count gave 60: it put the two polynomials at 10 FMA.)
pub const FLOPS_PER_UPDATE: f64 = 60.75;

/// Single-precision operations per cycle per core for `isa`: 2 FMA pipes × lanes × 2.
fn flops_per_cycle(isa: KernelIsa) -> f64 {
    4.0 * isa.lanes() as f64
}

/// Why the benchmark could not run.
#[derive(Debug, thiserror::Error)]
pub enum KernelBenchError {
    #[error("--edge {0}: must lie in 4..=128")]
    Edge(usize),
    #[error("--repeats {0}: must be at least 1")]
    Repeats(usize),
    #[error(transparent)]
    Workload(#[from] PerfError),
    #[error("a one-thread pool: {0}")]
    Pool(#[from] rayon::ThreadPoolBuildError),
}

/// One kernel's medians.
#[derive(Debug, Clone, Serialize)]
pub struct KernelTiming {
    /// Updates per call: voxels × antennas.
    pub updates: f64,
    pub median_s: f64,
    pub updates_per_s: f64,
    pub median_one_thread_s: f64,
    pub updates_per_s_one_thread: f64,
    /// Cycles per update on one thread, at the clock in [`KernelReport::clock_hz`].
    pub cycles_per_update_one_thread: Option<f64>,
    /// `updates_per_s` over the arithmetic bound of the image kernel on all threads.
    pub fraction_of_peak: Option<f64>,
}

/// The benchmark's result.
#[derive(Debug, Clone, Serialize)]
pub struct KernelReport {
    pub antennas: usize,
    pub voxels: usize,
    pub threads: usize,
    pub repeats: usize,
    /// The instruction set the kernel ran in.
    pub isa: KernelIsa,
    /// The CPU's model name, family and model from `/proc/cpuinfo`.
    pub cpu: Option<String>,
    /// The CPU clock from `/proc/cpuinfo`, Hz.
    pub clock_hz: Option<f64>,
    /// The bound `threads · 4 · lanes · clock / FLOPS_PER_UPDATE`, updates/s.
    pub peak_updates_per_s: Option<f64>,
    pub image: KernelTiming,
    pub votes: KernelTiming,
}

/// Runs the benchmark (see the module docs).
pub fn run_kernel_bench(
    scale: f64,
    edge: usize,
    repeats: usize,
    quiet: bool,
) -> Result<KernelReport, KernelBenchError> {
    if !(4..=128).contains(&edge) {
        return Err(KernelBenchError::Edge(edge));
    }
    if repeats == 0 {
        return Err(KernelBenchError::Repeats(repeats));
    }
    let (capture, box_m) = synthesize(scale, quiet)?;
    let defaults = ReconConfig::default();
    let voxel_m = defaults.voxel_m;
    let centre = [0, 1, 2].map(|q| 0.5 * (box_m[2 * q] + box_m[2 * q + 1]));
    let cube = VoxelGrid {
        origin_m: centre.map(|c| c - 0.5 * edge as f64 * voxel_m),
        voxel_m,
        dims: [edge; 3],
    };
    let profiles = RangeProfiles::new(&capture, &cube, defaults.pad_factor);
    let image = backproject(&capture, &cube, &profiles, None);
    let everything = vec![true; cube.len()];
    let one_thread = rayon::ThreadPoolBuilder::new().num_threads(1).build()?;
    let threads = rayon::current_num_threads();
    let clock_hz = cpu_clock_hz();
    let isa = KernelIsa::active();
    let peak = clock_hz.map(|f| threads as f64 * flops_per_cycle(isa) * f / FLOPS_PER_UPDATE);
    let updates = (cube.len() * capture.antennas()) as f64;
    let image_call = || {
        std::hint::black_box(backproject(&capture, &cube, &profiles, None));
    };
    let votes_call = || {
        let field = normal_field(
            &capture,
            &cube,
            &profiles,
            &image,
            &everything,
            Candidates::Unit,
            None,
        );
        std::hint::black_box(field);
    };
    let time = |call: &(dyn Fn() + Sync)| -> KernelTiming {
        let median_s = median_seconds(repeats, call);
        let median_one_thread_s = one_thread.install(|| median_seconds(repeats, call));
        let one = updates / median_one_thread_s;
        KernelTiming {
            updates,
            median_s,
            updates_per_s: updates / median_s,
            median_one_thread_s,
            updates_per_s_one_thread: one,
            cycles_per_update_one_thread: clock_hz.map(|f| f / one),
            fraction_of_peak: peak.map(|p| updates / median_s / p),
        }
    };
    Ok(KernelReport {
        antennas: capture.antennas(),
        voxels: cube.len(),
        threads,
        repeats,
        isa,
        cpu: cpu_description(),
        clock_hz,
        peak_updates_per_s: peak,
        image: time(&image_call),
        votes: time(&votes_call),
    })
}

/// The first `cpu MHz` of `/proc/cpuinfo`, Hz; None where there is none.
fn cpu_clock_hz() -> Option<f64> {
    let cpuinfo = std::fs::read_to_string("/proc/cpuinfo").ok()?;
    let mhz: f64 = cpuinfo_field(&cpuinfo, "cpu MHz")?.parse().ok()?;
    (mhz > 0.0).then_some(mhz * 1e6)
}

/// "model name (family F, model M)" from `/proc/cpuinfo`; None where there is none. Virtual
/// machines often give a bare model name ("AMD EPYC"): the family tells the generation.
pub(crate) fn cpu_description() -> Option<String> {
    let cpuinfo = std::fs::read_to_string("/proc/cpuinfo").ok()?;
    let field = |key| cpuinfo_field(&cpuinfo, key);
    let name = field("model name")?;
    Some(match (field("cpu family"), field("model")) {
        (Some(family), Some(model)) => format!("{name} (family {family}, model {model})"),
        _ => name,
    })
}

/// The value of the first line of `/proc/cpuinfo`'s `text` whose key is `key`.
fn cpuinfo_field(text: &str, key: &str) -> Option<String> {
    text.lines().find_map(|line| {
        let (k, v) = line.split_once(':')?;
        (k.trim() == key).then(|| v.trim().to_string())
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A tiny run: every figure is finite and positive, and bad arguments are named.
    #[test]
    fn a_small_run_reports_positive_throughputs() {
        let report = run_kernel_bench(0.05, 4, 1, true).unwrap();
        assert_eq!(report.voxels, 64);
        assert!(report.antennas > 0);
        for t in [&report.image, &report.votes] {
            assert!(t.updates_per_s.is_finite() && t.updates_per_s > 0.0);
            assert!(t.updates_per_s_one_thread > 0.0);
        }
        assert!(matches!(
            run_kernel_bench(0.05, 2, 1, true),
            Err(KernelBenchError::Edge(2))
        ));
        assert!(matches!(
            run_kernel_bench(0.05, 8, 0, true),
            Err(KernelBenchError::Repeats(0))
        ));
    }
}
