//! `mmnormd bench perf`: the whole pipeline on the paper's full-scale workload, against our
//! exact reference path measured on a sub-volume in the same run.
//!
//! **Workload** (`scale` = 1): a 60×45 cm raster at λ0/4 with the IWR1443BOOST's four RX
//! channels, 55 cm above the table (1.16 M virtual channels × 512 samples,
//! `firmware_cfg/iwr1443_mmnorm.cfg`), and the paper's grid: 0.55 × 0.60 × 0.25 m at 1 mm
//! (8.3·10⁷ voxels). `scale` shrinks every length but the wavelength. The scene is evaluated
//! analytically instead of by the simulator: a sphere and a cylinder lying along y, each
//! returning one geometric-optics specular echo per channel (the point of the surface whose
//! normal points at the channel's phase centre, amplitude √(ρ1ρ2)/d² with ρ the principal radii
//! of curvature, none where the specular point falls off the cylinder's length), and three
//! point targets; 25 dB SNR of seeded noise.
//!
//! **Run**: the pipeline with its defaults (`imaging = auto`, so range migration and the
//! spectral normal field) on the explicit grid, stage by stage. Then the **reference** on a
//! cube of `reference_edge`³ voxels around the image's peak: interpolated backprojection and
//! exact per-antenna votes on the voxels above 30 % of its peak. Their times scale linearly with
//! voxels, so the reference's full-grid time is extrapolated: backprojection over every voxel,
//! exact votes over the voxels the full run computed normals for, plus the stages both paths
//! share. The same cube gives the parity of the two paths (|S| correlation, normal cosines) and
//! the exact kernel's throughput in (voxel, antenna) updates per second.

use std::time::Instant;

use num_complex::Complex32;
use serde::Serialize;

use crate::capture::Capture;
use crate::radar::{RadarProfile, RxLayout};
use crate::recon::config::{ReconConfig, VolumeSpec};
use crate::recon::image::{RangeProfiles, VoxelGrid, backproject};
use crate::recon::kernel::KernelIsa;
use crate::recon::normals::{Candidates, normal_field};
use crate::recon::pipeline::ReconError;
use crate::recon::rma::magnitude_correlation;
use crate::recon::{image_volume, reconstruct_imaged};
use crate::signal::{Rng, ToneAccumulator};
use crate::sim::scene::DEFAULT_RANGE_OFFSET_M;

/// The radar profile of the workload.
pub(crate) const PROFILE: &str = include_str!("../../firmware_cfg/iwr1443_mmnorm.cfg");

/// Why the benchmark could not run.
#[derive(Debug, thiserror::Error)]
pub enum PerfError {
    #[error("--scale {0}: must lie in (0, 1]")]
    Scale(f64),
    #[error("--reference-edge {0}: must lie in 4..=128")]
    ReferenceEdge(usize),
    #[error("the built-in radar profile: {0}")]
    Profile(#[from] crate::radar::ProfileError),
    #[error(transparent)]
    Recon(#[from] ReconError),
}

/// The workload's size.
#[derive(Debug, Clone, Serialize)]
pub struct WorkloadSummary {
    pub scale: f64,
    pub aperture_m: [f64; 2],
    pub spacing_m: f64,
    pub channels: usize,
    pub samples_per_chirp: usize,
    pub capture_bytes: usize,
    pub grid_dims: [usize; 3],
    pub voxels: usize,
    pub synthesis_s: f64,
}

/// The reference path on the sub-volume, and extrapolated.
#[derive(Debug, Clone, Serialize)]
pub struct ReferenceSummary {
    pub sub_voxels: usize,
    pub profiles_s: f64,
    pub backprojection_s: f64,
    pub backprojection_updates_per_s: f64,
    pub vote_voxels: usize,
    pub exact_votes_s: f64,
    pub exact_votes_updates_per_s: f64,
    /// The reference's full-grid time: profiles, backprojection over every voxel, exact votes
    /// over the full run's normal voxels, and the stages the paths share.
    pub extrapolated_total_s: f64,
    /// `extrapolated_total_s / total_s`.
    pub speedup: f64,
}

/// The two paths on the sub-volume.
#[derive(Debug, Clone, Serialize)]
pub struct Parity {
    pub image_magnitude_correlation: f64,
    /// Chebyshev distance between the two images' peaks, voxels.
    pub peak_offset_voxels: usize,
    pub normal_cosine_median: f64,
    pub normal_cosine_p10: f64,
}

/// Everything `bench perf` measured.
#[derive(Debug, Clone, Serialize)]
pub struct PerfReport {
    /// The pipeline's wall time (every stage below; synthesis excluded).
    pub total_s: f64,
    pub peak_rss_bytes: Option<u64>,
    /// Exact kernel throughput: the reference backprojection's (voxel, antenna) updates/s.
    pub exact_updates_per_s: f64,
    pub stages: serde_json::Map<String, serde_json::Value>,
    pub imaging: String,
    pub normal_votes: Option<&'static str>,
    pub points: Option<usize>,
    pub error: Option<String>,
    pub workload: WorkloadSummary,
    pub reference: ReferenceSummary,
    pub parity: Parity,
    /// The instruction set of the exact kernel.
    pub kernel_isa: KernelIsa,
    /// The CPU's model name, family and model from `/proc/cpuinfo`.
    pub cpu: Option<String>,
}

/// Runs the benchmark at `scale` with a reference cube of `reference_edge`³ voxels.
pub fn run_perf(scale: f64, reference_edge: usize, quiet: bool) -> Result<PerfReport, PerfError> {
    if !(scale > 0.0 && scale <= 1.0) {
        return Err(PerfError::Scale(scale));
    }
    if !(4..=128).contains(&reference_edge) {
        return Err(PerfError::ReferenceEdge(reference_edge));
    }
    let started = Instant::now();
    let (capture, box_m) = synthesize(scale, quiet)?;
    let synthesis_s = started.elapsed().as_secs_f64();
    let config = ReconConfig {
        volume: VolumeSpec::Box(box_m),
        ..ReconConfig::default()
    };

    let started = Instant::now();
    let imaged = image_volume(&capture, &config, quiet)?;
    let outcome = reconstruct_imaged(&capture, &config, &imaged, quiet);
    let total_s = started.elapsed().as_secs_f64();
    let grid = imaged.grid;
    let (stage_s, points, error, mask_voxels, normal_votes) = match &outcome {
        Ok(r) => (
            r.summary.stage_s.clone(),
            Some(r.points_m.len()),
            None,
            r.summary.mask.as_ref().map(|m| m.voxels),
            r.summary.normal_votes,
        ),
        Err(e) => (Vec::new(), None, Some(e.to_string()), None, None),
    };
    let stages: serde_json::Map<String, serde_json::Value> = stage_s
        .iter()
        .map(|(name, s)| (name.clone(), serde_json::json!(s)))
        .collect();

    // The reference on a cube around the peak.
    let peak = (0..imaged.magnitude.len())
        .max_by(|&a, &b| imaged.magnitude[a].total_cmp(&imaged.magnitude[b]))
        .unwrap_or(0);
    let [_, ny, nz] = grid.dims;
    let peak_ijk = [peak / (ny * nz), peak / nz % ny, peak % nz];
    let start: [usize; 3] = std::array::from_fn(|q| {
        let n = grid.dims[q];
        let edge = reference_edge.min(n);
        peak_ijk[q].saturating_sub(edge / 2).min(n - edge)
    });
    let sub_dims: [usize; 3] = std::array::from_fn(|q| reference_edge.min(grid.dims[q]));
    let sub = VoxelGrid {
        origin_m: std::array::from_fn(|q| grid.origin_m[q] + grid.voxel_m * start[q] as f64),
        voxel_m: grid.voxel_m,
        dims: sub_dims,
    };
    let full_index =
        |i: usize, j: usize, k: usize| ((start[0] + i) * ny + start[1] + j) * nz + start[2] + k;
    let clock = Instant::now();
    let profiles = RangeProfiles::new(&capture, &sub, config.pad_factor);
    let profiles_s = clock.elapsed().as_secs_f64();
    let clock = Instant::now();
    let reference = backproject(&capture, &sub, &profiles, None);
    let backprojection_s = clock.elapsed().as_secs_f64();
    let sub_magnitude: Vec<f32> = reference.iter().map(|s| s.norm()).collect();
    let sub_peak = sub_magnitude.iter().copied().fold(0.0f32, f32::max);
    let selected: Vec<bool> = sub_magnitude.iter().map(|m| *m >= 0.3 * sub_peak).collect();
    let clock = Instant::now();
    let exact = normal_field(
        &capture,
        &sub,
        &profiles,
        &reference,
        &selected,
        Candidates::Unit,
        None,
    );
    let exact_votes_s = clock.elapsed().as_secs_f64();
    let vote_voxels = selected.iter().filter(|&&s| s).count();
    let antennas = capture.antennas() as f64;

    // Parity on the cube.
    let mut fast_magnitude = Vec::with_capacity(sub.len());
    let mut cosines = Vec::new();
    for i in 0..sub_dims[0] {
        for j in 0..sub_dims[1] {
            for k in 0..sub_dims[2] {
                let f = full_index(i, j, k);
                let s = (i * sub_dims[1] + j) * sub_dims[2] + k;
                fast_magnitude.push(imaged.magnitude[f]);
                if let Some(votes) = &imaged.votes
                    && selected[s]
                    && exact[s][0].is_finite()
                {
                    let w = votes[f];
                    let len = (w[0] * w[0] + w[1] * w[1] + w[2] * w[2]).sqrt();
                    if len > 0.0 {
                        cosines.push(f64::from(
                            (0..3).map(|q| w[q] * exact[s][q]).sum::<f32>() / len,
                        ));
                    }
                }
            }
        }
    }
    cosines.sort_by(f64::total_cmp);
    let quantile = |q: f64| {
        cosines
            .get(((cosines.len().max(1) - 1) as f64 * q).round() as usize)
            .copied()
            .unwrap_or(f64::NAN)
    };
    let argmax = |m: &[f32]| {
        (0..m.len())
            .max_by(|&a, &b| m[a].total_cmp(&m[b]))
            .unwrap_or(0)
    };
    let ijk = |p: usize| {
        [
            p / (sub_dims[1] * sub_dims[2]),
            p / sub_dims[2] % sub_dims[1],
            p % sub_dims[2],
        ]
    };
    let (pa, pb) = (ijk(argmax(&fast_magnitude)), ijk(argmax(&sub_magnitude)));
    let parity = Parity {
        image_magnitude_correlation: magnitude_correlation(&fast_magnitude, &sub_magnitude),
        peak_offset_voxels: (0..3).map(|q| pa[q].abs_diff(pb[q])).max().unwrap_or(0),
        normal_cosine_median: quantile(0.5),
        normal_cosine_p10: quantile(0.1),
    };

    let shared: f64 = stage_s
        .iter()
        .filter(|(n, _)| n != "image" && n != "normals")
        .map(|(_, s)| s)
        .sum();
    let full_votes = mask_voxels.unwrap_or(0) as f64;
    let extrapolated_total_s = profiles_s
        + backprojection_s * grid.len() as f64 / sub.len() as f64
        + exact_votes_s * full_votes / vote_voxels.max(1) as f64
        + shared;
    let exact_updates_per_s = sub.len() as f64 * antennas / backprojection_s;
    Ok(PerfReport {
        total_s,
        peak_rss_bytes: peak_rss_bytes(),
        exact_updates_per_s,
        stages,
        imaging: format!("{:?}", imaged.imaging.used).to_lowercase(),
        normal_votes,
        points,
        error,
        workload: WorkloadSummary {
            scale,
            aperture_m: [0.60 * scale, 0.45 * scale],
            spacing_m: capture.plan.first_wavelength_m() / 4.0,
            channels: capture.antennas(),
            samples_per_chirp: capture.plan.samples_per_chirp,
            capture_bytes: capture.samples.len() * std::mem::size_of::<Complex32>(),
            grid_dims: grid.dims,
            voxels: grid.len(),
            synthesis_s,
        },
        reference: ReferenceSummary {
            sub_voxels: sub.len(),
            profiles_s,
            backprojection_s,
            backprojection_updates_per_s: exact_updates_per_s,
            vote_voxels,
            exact_votes_s,
            exact_votes_updates_per_s: vote_voxels as f64 * antennas / exact_votes_s,
            extrapolated_total_s,
            speedup: extrapolated_total_s / total_s,
        },
        parity,
        kernel_isa: KernelIsa::active(),
        cpu: super::kernel::cpu_description(),
    })
}

/// The report as a Markdown section for BENCHMARKS.md, with the targets, the command
/// that made it and the machine's thread count.
pub fn markdown(r: &PerfReport, command: &str) -> String {
    use std::fmt::Write as _;
    let mut md = String::new();
    let w = &r.workload;
    let f = &r.reference;
    let p = &r.parity;
    let threads = rayon::current_num_threads();
    let _ = writeln!(md, "## Speed (`mmnormd bench perf`)\n");
    let _ = writeln!(
        md,
        "Generated by `{command}` on {threads} threads of {}; the exact kernel in {}. Workload: {} channels × {} samples \
         ({:.1} GB of complex64; {:.0}×{:.0} cm at {:.3} mm, 4 RX), grid {}×{}×{} = {:.2}·10⁷ voxels; \
         the scene is evaluated analytically in {:.0} s (not counted). Imaging: {}, normal votes: {}; \
         {} points.\n",
        r.cpu.as_deref().unwrap_or("an unknown CPU"),
        r.kernel_isa,
        w.channels,
        w.samples_per_chirp,
        w.capture_bytes as f64 / 1e9,
        w.aperture_m[0] * 100.0,
        w.aperture_m[1] * 100.0,
        w.spacing_m * 1e3,
        w.grid_dims[0],
        w.grid_dims[1],
        w.grid_dims[2],
        w.voxels as f64 / 1e7,
        w.synthesis_s,
        r.imaging,
        r.normal_votes.unwrap_or("-"),
        r.points.map_or("no".to_string(), |n| n.to_string()),
    );
    let _ = writeln!(md, "| stage | wall s |\n|---|---|");
    for (name, s) in &r.stages {
        let _ = writeln!(md, "| {name} | {:.2} |", s.as_f64().unwrap_or(f64::NAN));
    }
    let _ = writeln!(md, "| **total** | **{:.1}** |\n", r.total_s);
    if let Some(e) = &r.error {
        let _ = writeln!(md, "The pipeline stopped: {e}\n");
    }
    let _ = writeln!(
        md,
        "The exact reference (interpolated backprojection and exact per-antenna votes) ran on a \
         cube of {} voxels around the image peak in the same process: backprojection {:.1} s \
         ({:.2e} updates/s), exact votes on {} voxels {:.2} s ({:.2e} updates/s), range profiles \
         {:.1} s. Extrapolated linearly to the full grid it takes {:.0} s ({:.1} h): range migration \
         is **{:.0}×** faster. On the cube the two paths agree: |S| correlation {:.4}, peaks {} \
         voxel(s) apart, normal cosine median {:.4} (10th percentile {:.4}).\n",
        f.sub_voxels,
        f.backprojection_s,
        f.backprojection_updates_per_s,
        f.vote_voxels,
        f.exact_votes_s,
        f.exact_votes_updates_per_s,
        f.profiles_s,
        f.extrapolated_total_s,
        f.extrapolated_total_s / 3600.0,
        f.speedup,
        p.image_magnitude_correlation,
        p.peak_offset_voxels,
        p.normal_cosine_median,
        p.normal_cosine_p10,
    );
    let verdict = |ok: bool| if ok { "met" } else { "**missed**" };
    let rss = r.peak_rss_bytes.map_or(f64::NAN, |b| b as f64 / 1e9);
    let _ = writeln!(md, "| target | ours | |\n|---|---|---|");
    let _ = writeln!(
        md,
        "| full pipeline ≤ 60 s | {:.1} s | {} |",
        r.total_s,
        verdict(r.total_s <= 60.0)
    );
    let _ = writeln!(
        md,
        "| peak RSS ≤ 12 GB | {rss:.1} GB | {} |",
        verdict(rss <= 12.0)
    );
    let _ = writeln!(
        md,
        "| exact kernel ≥ 1.5·10⁹ updates/s | {:.2e} | {} |",
        r.exact_updates_per_s,
        verdict(r.exact_updates_per_s >= 1.5e9)
    );
    let _ = writeln!(
        md,
        "| parity: \\|S\\| correlation ≥ 0.99, peak within 1 voxel, normal cosine median ≥ 0.99 | {:.4}, {}, {:.4} | {} |",
        p.image_magnitude_correlation,
        p.peak_offset_voxels,
        p.normal_cosine_median,
        verdict(
            p.image_magnitude_correlation >= 0.99
                && p.peak_offset_voxels <= 1
                && p.normal_cosine_median >= 0.99
        )
    );
    md
}

/// The process's peak resident set (VmHWM), bytes; None off Linux.
pub fn peak_rss_bytes() -> Option<u64> {
    let text = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = text.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kib: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kib * 1024)
}

/// One object of the analytic scene.
enum Object {
    Sphere {
        centre: [f64; 3],
        radius: f64,
    },
    /// Lying along y.
    Cylinder {
        axis: [f64; 3],
        radius: f64,
        half_length: f64,
    },
    Point {
        at: [f64; 3],
        amplitude: f64,
    },
}

impl Object {
    /// The specular point seen from the phase centre `c` and its geometric-optics amplitude
    /// √(ρ1ρ2)/d² (d the distance from `c`); None when there is none.
    fn echo(&self, c: [f64; 3]) -> Option<([f64; 3], f64)> {
        let sub = |a: [f64; 3], b: [f64; 3]| [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
        let norm = |v: [f64; 3]| (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
        match *self {
            Object::Sphere { centre, radius } => {
                let v = sub(c, centre);
                let l = norm(v);
                let p = std::array::from_fn(|q| centre[q] + v[q] * radius / l);
                let d = l - radius;
                Some((p, radius / (d * d)))
            }
            Object::Cylinder {
                axis,
                radius,
                half_length,
            } => {
                if (c[1] - axis[1]).abs() > half_length {
                    return None;
                }
                let v = [c[0] - axis[0], 0.0, c[2] - axis[2]];
                let l = norm(v);
                let p = [
                    axis[0] + v[0] * radius / l,
                    c[1],
                    axis[2] + v[2] * radius / l,
                ];
                let d = l - radius;
                // One radius is infinite: the line reflector's √(ρ·d)/d².
                Some((p, (radius * d).sqrt() / (d * d)))
            }
            Object::Point { at, amplitude } => {
                let d = norm(sub(c, at));
                Some((at, amplitude / (d * d)))
            }
        }
    }
}

/// The workload capture and the grid box [x0, x1, y0, y1, z0, z1].
pub(crate) fn synthesize(scale: f64, quiet: bool) -> Result<(Capture, [f64; 6]), PerfError> {
    use rayon::prelude::*;
    let profile = RadarProfile::from_cfg_str(PROFILE)?;
    let plan = profile.frequency_plan();
    let lambda0 = plan.first_wavelength_m();
    let spacing = lambda0 / 4.0;
    let s = scale;
    let z_aperture = 0.55 * s;
    let count = |len: f64| (len / spacing + 1e-9).floor() as usize + 1;
    let (columns, rows) = (count(0.60 * s), count(0.45 * s));
    let offsets = profile.rx_offsets_m(RxLayout::Iwr1443Boost);
    let (x0, y0) = (
        -0.5 * (columns - 1) as f64 * spacing,
        -0.5 * (rows - 1) as f64 * spacing,
    );
    let mut tx_m = Vec::with_capacity(columns * rows * offsets.len());
    let mut rx_m = Vec::with_capacity(columns * rows * offsets.len());
    for r in 0..rows {
        for c in 0..columns {
            let t = [x0 + c as f64 * spacing, y0 + r as f64 * spacing, z_aperture];
            for o in &offsets {
                tx_m.push(t);
                rx_m.push([t[0] + o, t[1], t[2]]);
            }
        }
    }
    let objects = [
        Object::Sphere {
            centre: [0.10 * s, -0.08 * s, 0.08 * s],
            radius: 0.06 * s,
        },
        Object::Cylinder {
            axis: [-0.12 * s, 0.05 * s, 0.04 * s],
            radius: 0.04 * s,
            half_length: 0.10 * s,
        },
        Object::Point {
            at: [0.20 * s, 0.20 * s, 0.02 * s],
            amplitude: 0.01 * s,
        },
        Object::Point {
            at: [-0.20 * s, -0.20 * s, 0.10 * s],
            amplitude: 0.01 * s,
        },
        Object::Point {
            at: [0.0, 0.22 * s, 0.15 * s],
            amplitude: 0.01 * s,
        },
    ];
    let t_len = plan.samples_per_chirp;
    let n = tx_m.len();
    let mut samples = vec![Complex32::new(0.0, 0.0); n * t_len];
    let progress = crate::progress::Progress::new("synthesis", n as u64, quiet);
    // Seeded noise 25 dB under the sphere's broadside echo after the range FFT: an echo of
    // amplitude A sums to A·T, complex noise of σ per part to σ·√(2T).
    let echo = 0.06 * s / (z_aperture - 0.14 * s).powi(2);
    let sigma = echo * (t_len as f64).sqrt() / (2f64.sqrt() * 10f64.powf(25.0 / 20.0));
    samples.par_chunks_mut(t_len).enumerate().for_each_init(
        || ToneAccumulator::new(&plan, DEFAULT_RANGE_OFFSET_M),
        |tones, (a, out)| {
            tones.clear();
            let (tx, rx) = (tx_m[a], rx_m[a]);
            let centre = [0, 1, 2].map(|q| 0.5 * (tx[q] + rx[q]));
            let dist = |p: [f64; 3], q: [f64; 3]| {
                ((p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2) + (p[2] - q[2]).powi(2)).sqrt()
            };
            for o in &objects {
                if let Some((p, amplitude)) = o.echo(centre) {
                    tones.add(
                        Complex32::new(amplitude as f32, 0.0),
                        dist(tx, p) + dist(p, rx),
                    );
                }
            }
            tones.add_into(out);
            let mut rng = Rng::for_stream(2026, 7, a as u64);
            for z in out.iter_mut() {
                let (re, im) = rng.normal_pair();
                *z += Complex32::new((sigma * re) as f32, (sigma * im) as f32);
            }
            progress.inc(1);
        },
    );
    progress.finish();
    let capture = Capture {
        plan,
        range_offset_m: DEFAULT_RANGE_OFFSET_M,
        tx_m,
        rx_m,
        samples: samples.into(),
        description: format!("bench perf workload at scale {scale}"),
        extra: Default::default(),
    };
    Ok((
        capture,
        [-0.275 * s, 0.275 * s, -0.30 * s, 0.30 * s, 0.0, 0.25 * s],
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A small workload: range migration runs, agrees with the reference on the cube, and
    /// the report's figures are finite.
    #[test]
    fn small_workload_runs_and_agrees_with_the_reference() {
        let report = run_perf(0.12, 16, true).unwrap();
        println!("{}", serde_json::to_string_pretty(&report).unwrap());
        assert_eq!(report.imaging, "rma");
        assert_eq!(report.normal_votes, Some("spectral"));
        assert!(report.error.is_none(), "{:?}", report.error);
        assert!(report.total_s > 0.0 && report.exact_updates_per_s > 0.0);
        assert!(
            report.parity.image_magnitude_correlation >= 0.99,
            "{:?}",
            report.parity
        );
        assert!(report.parity.peak_offset_voxels <= 1, "{:?}", report.parity);
        assert!(
            report.parity.normal_cosine_median >= 0.99,
            "{:?}",
            report.parity
        );
    }
}
