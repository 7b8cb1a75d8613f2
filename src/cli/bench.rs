use std::path::PathBuf;

use anyhow::{Result, bail};
use mmnormd::bench::kernel::run_kernel_bench;
use mmnormd::bench::perf::{PerfReport, markdown, run_perf};
use mmnormd::bench::{BenchOptions, Suite, run_suite};

#[derive(clap::Args)]
pub struct AccuracyArgs {
    /// Suite file (TOML), e.g. tools/bench/reduced.toml.
    #[arg(long)]
    suite: PathBuf,
    /// Output directory. Finished cases found in the work directory are not run again.
    #[arg(long)]
    out: PathBuf,
    /// Cases run side by side [default: 2].
    #[arg(long)]
    jobs: Option<usize>,
    /// Working directory: the capture cache and each case's run, kept between runs so an
    /// interrupted bench resumes [default: OUT/work].
    #[arg(long)]
    work: Option<PathBuf>,
    /// Also write the report here (e.g. BENCHMARKS.md), linking into OUT.
    #[arg(long)]
    markdown: Option<PathBuf>,
    /// Run only these cases: a case id (e.g. `box-flat-los`) selects that case alone; text that
    /// is no case id selects every case whose id contains it (e.g. `nlos`). Comma-separated or
    /// repeated; the selection is the union. The report still covers the whole suite: cases
    /// that earlier runs finished in the work directory are read back, the rest listed as not
    /// run yet.
    #[arg(long, value_delimiter = ',')]
    only: Vec<String>,
    /// Run nothing; write the report from the cases already finished.
    #[arg(long, conflicts_with = "only")]
    report_only: bool,
    /// Markdown with a hand-written analysis of the run, included in the report. Its relative
    /// links are taken from OUT and rewritten for the --markdown copy.
    #[arg(long)]
    notes: Option<PathBuf>,
    /// Markdown included before the plots, such as `bench perf --markdown`'s section
    /// (repeatable); relative links as for --notes.
    #[arg(long)]
    include: Vec<PathBuf>,
}

#[derive(clap::Args)]
pub struct PerfArgs {
    /// Every length of the workload times this (the wavelength stays): 1 is the paper's.
    #[arg(long, default_value_t = 1.0)]
    scale: f64,
    /// Edge of the reference cube, voxels.
    #[arg(long, default_value_t = 24)]
    reference_edge: usize,
    /// Print the report as one JSON object on the last line of standard output.
    #[arg(long)]
    json: bool,
    /// Also write the report as a Markdown section (for `bench accuracy --include`).
    #[arg(long)]
    markdown: Option<PathBuf>,
}

#[derive(clap::Args)]
pub struct KernelArgs {
    /// The `bench perf` capture at this scale (0.3: 1.05·10⁵ virtual channels).
    #[arg(long, default_value_t = 0.3)]
    scale: f64,
    /// Edge of the voxel cube, in voxels (1 mm each).
    #[arg(long, default_value_t = 24)]
    edge: usize,
    /// Timed repeats of each kernel; the medians are reported.
    #[arg(long, default_value_t = 5)]
    repeats: usize,
    /// Print the report as one JSON object on the last line as well.
    #[arg(long)]
    json: bool,
}

pub fn kernel(a: KernelArgs, quiet: bool) -> Result<()> {
    let r = run_kernel_bench(a.scale, a.edge, a.repeats, quiet)?;
    println!(
        "{} antennas × {} voxels, {} threads, medians of {}; kernel {} ({}-lane); CPU {}, clock {}",
        r.antennas,
        r.voxels,
        r.threads,
        r.repeats,
        r.isa,
        r.isa.lanes(),
        r.cpu.as_deref().unwrap_or("unknown"),
        r.clock_hz
            .map_or("unknown".to_string(), |f| format!("{:.2} GHz", f / 1e9))
    );
    if let Some(p) = r.peak_updates_per_s {
        println!(
            "arithmetic bound: {p:.3e} updates/s ({} flops per update)",
            mmnormd::bench::kernel::FLOPS_PER_UPDATE
        );
    }
    println!("| kernel | updates/s | one thread | cycles/update (one thread) | of the bound |");
    println!("|---|---|---|---|---|");
    for (name, t) in [("image", &r.image), ("votes", &r.votes)] {
        println!(
            "| {name} | {:.3e} | {:.3e} | {} | {} |",
            t.updates_per_s,
            t.updates_per_s_one_thread,
            t.cycles_per_update_one_thread
                .map_or("-".to_string(), |c| format!("{c:.1}")),
            t.fraction_of_peak
                .map_or("-".to_string(), |f| format!("{:.0} %", 100.0 * f)),
        );
    }
    if a.json {
        println!("{}", serde_json::to_string(&r)?);
    }
    Ok(())
}

#[derive(clap::Args)]
pub struct StreamArgs {
    /// Frames in the recording (4000 is one 12 s raster row).
    #[arg(long, default_value_t = 4000)]
    frames: usize,
    /// Timed repeats; the medians are reported.
    #[arg(long, default_value_t = 7)]
    repeats: usize,
    /// Print each run as one JSON object per line as well.
    #[arg(long)]
    json: bool,
}

pub fn stream(a: StreamArgs) -> Result<()> {
    anyhow::ensure!(a.frames > 0, "--frames 0: give at least one frame");
    for faults in [true, false] {
        let r = mmnormd::bench::stream::run_stream_bench(a.frames, a.repeats, faults);
        println!(
            "{} frames of {} B{}: reassembly {:.0} MB/s, decoding {:.0} MB/s, both {:.0} MB/s = {:.0}× the real {:.2} MB/s (medians of {})",
            r.frames,
            r.frame_bytes,
            if faults {
                ", 2 % reordered + 1 % duplicated"
            } else {
                ""
            },
            r.reassemble_mb_per_s,
            r.decode_mb_per_s,
            r.combined_mb_per_s,
            r.headroom,
            r.real_rate_mb_per_s,
            r.repeats
        );
        if a.json {
            println!("{}", serde_json::to_string(&r)?);
        }
    }
    Ok(())
}

#[derive(clap::Args)]
pub struct TonesArgs {
    /// Chirps per timed run at 16 reflections or fewer (fewer above, in proportion).
    #[arg(long, default_value_t = 2000)]
    chirps: usize,
    /// Timed repeats; the medians are reported.
    #[arg(long, default_value_t = 5)]
    repeats: usize,
    /// Print the report as one JSON object on the last line as well.
    #[arg(long)]
    json: bool,
}

pub fn tones(a: TonesArgs) -> Result<()> {
    let r = mmnormd::bench::tones::run_tones_bench(a.chirps, a.repeats)?;
    println!(
        "chirps of {} samples, one thread, medians of {}:",
        r.samples_per_chirp, r.repeats
    );
    println!("reflections  direct µs/chirp  gridded µs/chirp  direct/gridded");
    for row in &r.rows {
        println!(
            "{:>11}  {:>15.2}  {:>16.2}  {:>14.2}",
            row.reflections,
            row.direct_ns_per_chirp / 1e3,
            row.gridded_ns_per_chirp / 1e3,
            row.direct_ns_per_chirp / row.gridded_ns_per_chirp
        );
    }
    match r.gridding_wins_from {
        Some(n) => println!(
            "gridding is faster from {n} reflections on; the accumulator switches at {}",
            r.grid_after
        ),
        None => println!(
            "gridding was not faster at the largest count timed; the accumulator switches at {}",
            r.grid_after
        ),
    }
    if a.json {
        println!("{}", serde_json::to_string(&r)?);
    }
    Ok(())
}

pub fn perf(a: PerfArgs, quiet: bool) -> Result<()> {
    let report = run_perf(a.scale, a.reference_edge, quiet)?;
    print_perf(&report);
    if let Some(path) = &a.markdown {
        let command = std::iter::once("mmnormd".to_string())
            .chain(std::env::args().skip(1))
            .collect::<Vec<_>>()
            .join(" ");
        mmnormd::capture::dir::write_atomically(path, markdown(&report, &command).as_bytes())
            .map_err(|e| anyhow::anyhow!("--markdown {}: {e}", path.display()))?;
    }
    if a.json {
        println!("{}", serde_json::to_string(&report)?);
    }
    Ok(())
}

fn print_perf(r: &PerfReport) {
    let w = &r.workload;
    println!(
        "workload: {} channels × {} samples ({:.1} GB), grid {:?} = {:.2e} voxels, synthesised in {:.1} s",
        w.channels,
        w.samples_per_chirp,
        w.capture_bytes as f64 / 1e9,
        w.grid_dims,
        w.voxels as f64,
        w.synthesis_s
    );
    println!(
        "imaging: {}, normal votes: {}",
        r.imaging,
        r.normal_votes.unwrap_or("-")
    );
    println!("| stage | s |\n|---|---|");
    for (name, s) in &r.stages {
        println!("| {name} | {:.2} |", s.as_f64().unwrap_or(f64::NAN));
    }
    println!("| **total** | **{:.2}** |", r.total_s);
    if let Some(e) = &r.error {
        println!("the pipeline stopped: {e}");
    }
    let f = &r.reference;
    println!(
        "peak RSS {:.2} GB; reference on {} voxels: backprojection {:.2} s ({:.2e} updates/s), exact votes on {} voxels {:.2} s ({:.2e} updates/s)",
        r.peak_rss_bytes.unwrap_or(0) as f64 / 1e9,
        f.sub_voxels,
        f.backprojection_s,
        f.backprojection_updates_per_s,
        f.vote_voxels,
        f.exact_votes_s,
        f.exact_votes_updates_per_s
    );
    println!(
        "reference extrapolated to the full grid: {:.0} s; speed-up {:.0}×",
        f.extrapolated_total_s, f.speedup
    );
    let p = &r.parity;
    println!(
        "parity on the cube: |S| correlation {:.4}, peaks {} voxel(s) apart, normal cosine median {:.4} (p10 {:.4})",
        p.image_magnitude_correlation,
        p.peak_offset_voxels,
        p.normal_cosine_median,
        p.normal_cosine_p10
    );
}

/// Memory available to new work (MemAvailable), bytes; None off Linux.
fn available_memory_bytes() -> Option<u64> {
    let text = std::fs::read_to_string("/proc/meminfo").ok()?;
    let line = text.lines().find(|l| l.starts_with("MemAvailable:"))?;
    let kib: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kib * 1024)
}

pub fn accuracy(a: AccuracyArgs, quiet: bool) -> Result<()> {
    let suite = Suite::load(&a.suite)?;
    let selected = match a.only.is_empty() {
        true => suite.cases.len(),
        false => suite.selection(&a.only)?.into_iter().filter(|&s| s).count(),
    };
    if let Some(n) = &a.notes
        && !n.is_file()
    {
        bail!("--notes {}: no such file", n.display());
    }
    if let Some(n) = a.include.iter().find(|n| !n.is_file()) {
        bail!("--include {}: no such file", n.display());
    }
    let jobs = a.jobs.unwrap_or(2);
    if jobs == 0 {
        bail!("--jobs 0: give at least 1");
    }
    // Leave a third of what is free to the rest of the machine.
    let budget = available_memory_bytes().map_or(4 << 30, |b| b / 3 * 2);
    let command = std::iter::once("mmnormd".to_string())
        .chain(std::env::args().skip(1))
        .map(|s| if s.contains(' ') { format!("'{s}'") } else { s })
        .collect::<Vec<_>>()
        .join(" ");
    tracing::info!(
        "{selected} of {} cases from {}, {jobs} at a time within {:.1} GiB",
        suite.cases.len(),
        a.suite.display(),
        budget as f64 / (1u64 << 30) as f64
    );
    let outcome = run_suite(
        &suite,
        &a.out,
        &BenchOptions {
            work_dir: a.work,
            jobs,
            memory_budget_bytes: budget,
            markdown: a.markdown,
            command,
            report_only: a.report_only,
            only: a.only,
            notes: a.notes,
            includes: a.include,
            quiet,
        },
    )?;
    println!(
        "wrote {}: {} cases scored, {} failed, {} not run yet, {:.0} s; see report.md",
        a.out.display(),
        outcome.results.len(),
        outcome.failed_cases.len(),
        outcome.not_run.len(),
        outcome.wall_s
    );
    for (id, e) in &outcome.failed_cases {
        eprintln!("case {id} failed: {e}");
    }
    Ok(())
}

#[derive(clap::Args)]
pub struct CoverageArgs {
    /// Suite file (TOML); repeat it to compare apertures (e.g. reduced.toml, then paper.toml).
    /// The rows are the first suite's cases, matched by id in the others.
    #[arg(long, required = true)]
    suite: Vec<PathBuf>,
    /// Output directory: coverage.csv, coverage.md and coverage_cdf.png.
    #[arg(long)]
    out: PathBuf,
    /// A `bench accuracy` results.csv of the first suite: its mmNorm F-score and recall are
    /// set beside the ideal.
    #[arg(long)]
    results: Option<PathBuf>,
}

pub fn coverage(a: CoverageArgs, quiet: bool) -> Result<()> {
    use mmnormd::bench::coverage::{read_results, suite_coverage, write_coverage};
    let suites = a
        .suite
        .iter()
        .map(|p| Suite::load(p).map(|s| suite_coverage(&s, quiet)))
        .collect::<Result<Vec<_>, _>>()?;
    let achieved = match &a.results {
        Some(p) => read_results(p, "mmnorm")?,
        None => Vec::new(),
    };
    write_coverage(&suites, &achieved, &a.out)?;
    for s in &suites {
        let f = s.ideal_f_scores();
        println!(
            "{} ({}): {} cases, ideal F median {:.3}, 25th percentile {:.3}",
            s.label,
            s.aperture,
            f.len(),
            mmnormd::eval::quantile(&f, 0.5).unwrap_or(f64::NAN),
            mmnormd::eval::quantile(&f, 0.25).unwrap_or(f64::NAN)
        );
    }
    println!(
        "wrote {}: coverage.csv, coverage.md, coverage_cdf.png",
        a.out.display()
    );
    Ok(())
}
