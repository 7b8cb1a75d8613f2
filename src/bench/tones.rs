//! `mmnormd bench tones`: the cost of one chirp of R reflections, swept directly and gridded
//! ([`crate::signal::ToneAccumulator`]), and the R from which gridding wins.
//!
//! **Workload**: chirps of the project's radar profile (512 samples), each with R reflections of
//! seeded amplitudes and paths between 0.2 and 1.2 m; per R, `chirps` chirps are built
//! (clear, R additions, read) on one thread, `repeats` times, and the median reported.

use num_complex::Complex32;
use serde::Serialize;

use crate::radar::RadarProfile;
use crate::signal::{GRID_AFTER, Rng, ToneAccumulator};

/// Reflections per chirp that are timed.
pub const REFLECTIONS: [usize; 12] = [1, 2, 4, 8, 12, 16, 24, 32, 48, 64, 256, 4096];

/// Why the benchmark could not run.
#[derive(Debug, thiserror::Error)]
pub enum TonesBenchError {
    #[error("--chirps {0}: must be at least 1")]
    Chirps(usize),
    #[error("--repeats {0}: must be at least 1")]
    Repeats(usize),
    #[error("the built-in radar profile: {0}")]
    Profile(#[from] crate::radar::ProfileError),
}

/// One R's medians.
#[derive(Debug, Clone, Serialize)]
pub struct TonesRow {
    pub reflections: usize,
    pub direct_ns_per_chirp: f64,
    pub gridded_ns_per_chirp: f64,
}

/// The benchmark's result.
#[derive(Debug, Clone, Serialize)]
pub struct TonesReport {
    pub samples_per_chirp: usize,
    pub chirps: usize,
    pub repeats: usize,
    pub rows: Vec<TonesRow>,
    /// The smallest R timed from which gridding is faster at every larger R timed.
    pub gridding_wins_from: Option<usize>,
    /// The switch the accumulator uses.
    pub grid_after: usize,
}

/// Runs the benchmark (see the module docs).
pub fn run_tones_bench(chirps: usize, repeats: usize) -> Result<TonesReport, TonesBenchError> {
    if chirps == 0 {
        return Err(TonesBenchError::Chirps(chirps));
    }
    if repeats == 0 {
        return Err(TonesBenchError::Repeats(repeats));
    }
    let profile = RadarProfile::from_cfg_str(super::perf::PROFILE)?;
    let plan = profile.frequency_plan();
    let t = plan.samples_per_chirp;
    let mut rows = Vec::new();
    for &r in &REFLECTIONS {
        let mut rng = Rng::for_stream(2026, 11, r as u64);
        let reflections: Vec<(Complex32, f64)> = (0..r)
            .map(|_| {
                let (re, im) = rng.normal_pair();
                (Complex32::new(re as f32, im as f32), 0.2 + rng.uniform())
            })
            .collect();
        // Fewer chirps for many reflections keep each R to a similar time.
        let n = (chirps * 16 / r.max(16)).max(1);
        let time = |grid_after: usize| {
            let mut acc = ToneAccumulator::with_grid_after(&plan, 0.15, grid_after);
            let mut out = vec![Complex32::new(0.0, 0.0); t];
            let seconds = super::median_seconds(repeats, || {
                for _ in 0..n {
                    acc.clear();
                    for &(a, d) in &reflections {
                        acc.add(a, d);
                    }
                    acc.add_into(&mut out);
                }
                std::hint::black_box(&out);
            });
            seconds * 1e9 / n as f64
        };
        rows.push(TonesRow {
            reflections: r,
            direct_ns_per_chirp: time(usize::MAX),
            gridded_ns_per_chirp: time(1),
        });
    }
    let gridding_wins_from = rows
        .iter()
        .rposition(|row| row.gridded_ns_per_chirp >= row.direct_ns_per_chirp)
        .map_or(Some(0), |last_loss| {
            rows.get(last_loss + 1).map(|_| last_loss + 1)
        })
        .map(|i| rows[i].reflections);
    Ok(TonesReport {
        samples_per_chirp: t,
        chirps,
        repeats,
        rows,
        gridding_wins_from,
        grid_after: GRID_AFTER,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A tiny run: every figure is positive, and bad arguments are named.
    #[test]
    fn a_small_run_reports_every_reflection_count() {
        let report = run_tones_bench(2, 1).unwrap();
        assert_eq!(report.rows.len(), REFLECTIONS.len());
        assert!(
            report
                .rows
                .iter()
                .all(|r| r.direct_ns_per_chirp > 0.0 && r.gridded_ns_per_chirp > 0.0)
        );
        assert!(matches!(
            run_tones_bench(0, 1),
            Err(TonesBenchError::Chirps(0))
        ));
        assert!(matches!(
            run_tones_bench(1, 0),
            Err(TonesBenchError::Repeats(0))
        ));
    }
}
