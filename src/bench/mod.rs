//! The benchmarks. `mmnormd bench accuracy` is the paper's evaluation (§6.2–§6.3) over a suite
//! of simulated scenes; `mmnormd bench perf` times the pipeline at full scale.
//!
//! - [`suite`]: the suite file and its expansion into cases (scene × pose × condition);
//! - [`cache`]: simulated captures cached by content hash;
//! - [`run`]: each case simulated, imaged once, reconstructed by every method and scored,
//!   several cases at a time within a memory budget, resumable;
//! - [`report`]: `results.csv`, the CDF plots and `report.md` beside the paper's figures;
//! - [`scene_png`]: one picture per case (Fig. 10 style);
//! - [`perf`]: `mmnormd bench perf`, the full-scale speed benchmark;
//! - [`coverage`]: `mmnormd bench coverage`, the F-score an ideal specular reconstruction
//!   gets under each suite's aperture, from the geometry alone;
//! - [`kernel`]: `mmnormd bench kernel`, the exact per-antenna kernel's throughput;
//! - [`stream`]: `mmnormd bench stream`, the DCA1000 receive path's throughput.

pub mod by_physics;
pub mod cache;
pub mod coverage;
pub mod kernel;
pub mod perf;
pub mod report;
pub mod run;
pub mod scene_png;
pub mod stream;
pub mod suite;
pub mod tones;

use std::path::{Path, PathBuf};
use std::time::Instant;

pub use run::{CaseResult, METHODS, RunOptions};
pub use suite::{Case, Suite, SuiteError};

use crate::capture::dir::{CaptureDirError, write_atomically};
use crate::geometry::MeshError;
use crate::preview::PreviewError;
use crate::recon::output::OutputError;
use crate::recon::pipeline::ReconError;

/// Why the benchmark stopped. A single case's failure does not stop it: it is reported.
#[derive(Debug, thiserror::Error)]
pub enum BenchError {
    #[error(transparent)]
    Suite(#[from] SuiteError),
    #[error(transparent)]
    Capture(#[from] CaptureDirError),
    #[error(transparent)]
    Mesh(#[from] MeshError),
    #[error(transparent)]
    Recon(#[from] ReconError),
    #[error(transparent)]
    Picture(#[from] PreviewError),
    #[error(transparent)]
    Output(#[from] OutputError),
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{path} line {line}: {what}")]
    Results {
        path: PathBuf,
        line: usize,
        what: String,
    },
    #[error("result file: {0}")]
    Json(#[from] serde_json::Error),
    #[error(
        "--report-only: no case of the suite has finished under {work} (pass the run's --work); nothing was written"
    )]
    NothingFinished { work: PathBuf },
}

/// The median of timed repeats (the upper one of an even count); NaN for none.
pub(crate) fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v.get(v.len() / 2).copied().unwrap_or(f64::NAN)
}

/// Median wall time of `repeats` calls, seconds.
pub(crate) fn median_seconds(repeats: usize, mut call: impl FnMut()) -> f64 {
    median(
        (0..repeats)
            .map(|_| {
                let started = Instant::now();
                call();
                started.elapsed().as_secs_f64()
            })
            .collect(),
    )
}

/// Maps an IO error on `path` into [`BenchError::Io`].
fn io(path: &Path) -> impl FnOnce(std::io::Error) -> BenchError + '_ {
    move |source| BenchError::Io {
        path: path.to_path_buf(),
        source,
    }
}

/// How to run a suite.
#[derive(Debug, Clone)]
pub struct BenchOptions {
    /// The capture cache (`captures/`) and the per-case runs (`runs/`) [default: `OUT/work`].
    pub work_dir: Option<PathBuf>,
    pub jobs: usize,
    pub memory_budget_bytes: u64,
    /// Also write the report here, its links pointing into `OUT`.
    pub markdown: Option<PathBuf>,
    /// The command line, quoted in the report.
    pub command: String,
    /// Run nothing: report the cases an earlier run finished (the others as not run).
    pub report_only: bool,
    /// Run only the cases these patterns select ([`Suite::selection`]; empty: every case). The
    /// report still covers the whole suite: the other cases an earlier run finished in the work
    /// directory are read back, the rest listed as not run.
    pub only: Vec<String>,
    /// A markdown file of hand-written analysis to include in the report.
    pub notes: Option<PathBuf>,
    /// Markdown files included verbatim before the plots (e.g. `bench perf --markdown`'s).
    pub includes: Vec<PathBuf>,
    pub quiet: bool,
}

/// What a run produced.
pub struct BenchOutcome {
    pub results: Vec<CaseResult>,
    pub failed_cases: Vec<(String, String)>,
    /// Cases this run did not select and no earlier run finished.
    pub not_run: Vec<String>,
    pub wall_s: f64,
}

/// Runs `suite` into `out`: `results.csv`, `report.md`, the CDF plots, `scenes/*.png`, and under
/// the work directory (default `OUT/work`) the capture cache and the per-case runs.
pub fn run_suite(
    suite: &Suite,
    out: &Path,
    opts: &BenchOptions,
) -> Result<BenchOutcome, BenchError> {
    let started = Instant::now();
    let work = opts.work_dir.clone().unwrap_or_else(|| out.join("work"));
    let run_opts = RunOptions {
        cache_dir: work.join("captures"),
        runs_dir: work.join("runs"),
        scenes_dir: out.join("scenes"),
        tau_m: suite.tau_m,
        jobs: opts.jobs,
        memory_budget_bytes: opts.memory_budget_bytes,
        quiet: opts.quiet,
    };
    let to_run = if opts.report_only {
        vec![false; suite.cases.len()]
    } else if opts.only.is_empty() {
        vec![true; suite.cases.len()]
    } else {
        suite.selection(&opts.only)?
    };
    let selected: Vec<Case> = suite
        .cases
        .iter()
        .zip(&to_run)
        .filter(|(_, run)| **run)
        .map(|(c, _)| c.clone())
        .collect();
    if !selected.is_empty() {
        std::fs::create_dir_all(&run_opts.runs_dir).map_err(io(&run_opts.runs_dir))?;
        std::fs::create_dir_all(out).map_err(io(out))?;
    }
    let mut ran = match selected.is_empty() {
        true => Vec::new(),
        false => run::run_cases(&selected, &run_opts),
    }
    .into_iter();
    let mut results = Vec::new();
    let mut failed_cases = Vec::new();
    let mut not_run = Vec::new();
    for (case, run) in suite.cases.iter().zip(&to_run) {
        if !run {
            match run::finished_result(case, &run_opts) {
                Some(r) => results.push(r),
                None => not_run.push(case.id.clone()),
            }
            continue;
        }
        match ran.next().unwrap_or_else(|| Err("not run".into())) {
            Ok(r) => results.push(r),
            Err(e) => failed_cases.push((case.id.clone(), e)),
        }
    }
    if opts.report_only && results.is_empty() {
        // An empty report would overwrite the results of the run it was meant to describe.
        return Err(BenchError::NothingFinished { work });
    }
    std::fs::create_dir_all(out).map_err(io(out))?;
    let wall_s = started.elapsed().as_secs_f64();
    let notes = match &opts.notes {
        Some(p) => Some((
            p.display().to_string(),
            std::fs::read_to_string(p).map_err(io(p))?,
        )),
        None => None,
    };
    let includes = opts
        .includes
        .iter()
        .map(|p| std::fs::read_to_string(p).map_err(io(p)))
        .collect::<Result<Vec<_>, _>>()?;
    report::write_csv(&results, out)?;
    let stats = report::gather(&results, &run_opts.runs_dir)?;
    let plots = report::write_plots(&stats, out)?;
    let a = suite
        .cases
        .first()
        .map(|c| &c.scene.aperture)
        .map_or(String::new(), |a| {
            format!(
                "{:.0}×{:.0} cm at {:.3} mm ({:?} layout)",
                a.width_m * 100.0,
                a.height_m * 100.0,
                a.spacing_m * 1e3,
                a.layout
            )
        });
    let info = report::RunInfo {
        suite: suite.path.display().to_string(),
        description: suite.description.clone(),
        command: opts.command.clone(),
        aperture: a,
        wall_s,
        report_only: opts.report_only,
        cases: suite.cases.len(),
        failed_cases: failed_cases.clone(),
        not_run: not_run.clone(),
        notes,
        includes,
        by_physics: by_physics::section(&results, &run_opts.runs_dir)?,
    };
    let md = report::report_md(&info, &results, &stats, &plots, &|f| f.to_string());
    write_atomically(&out.join("report.md"), md.as_bytes())?;
    if let Some(path) = &opts.markdown {
        let prefix = relative_prefix(path, out);
        let md = report::report_md(&info, &results, &stats, &plots, &|f| format!("{prefix}{f}"));
        write_atomically(path, md.as_bytes())?;
    }
    Ok(BenchOutcome {
        results,
        failed_cases,
        not_run,
        wall_s,
    })
}

/// The path prefix from the directory of `file` to `dir` (both as given, relative or not).
fn relative_prefix(file: &Path, dir: &Path) -> String {
    let base = file.parent().unwrap_or(Path::new(""));
    match dir.strip_prefix(base) {
        Ok(rel) if !rel.as_os_str().is_empty() => format!("{}/", rel.display()),
        Ok(_) => String::new(),
        Err(_) => format!("{}/", dir.display()),
    }
}
