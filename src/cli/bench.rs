use std::path::PathBuf;

use anyhow::{Result, bail};
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
    /// Run only the cases whose id contains this text.
    #[arg(long)]
    only: Option<String>,
    /// Run nothing; write the report from the cases already finished.
    #[arg(long)]
    report_only: bool,
    /// Markdown with a hand-written analysis of the run, included in the report.
    #[arg(long)]
    notes: Option<PathBuf>,
}

/// Memory available to new work (MemAvailable), bytes; None off Linux.
fn available_memory_bytes() -> Option<u64> {
    let text = std::fs::read_to_string("/proc/meminfo").ok()?;
    let line = text.lines().find(|l| l.starts_with("MemAvailable:"))?;
    let kib: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kib * 1024)
}

pub fn accuracy(a: AccuracyArgs, quiet: bool) -> Result<()> {
    let mut suite = Suite::load(&a.suite)?;
    if let Some(only) = &a.only {
        suite.cases.retain(|c| c.id.contains(only.as_str()));
        if suite.cases.is_empty() {
            bail!(
                "--only {only:?}: no case id of {} contains it",
                a.suite.display()
            );
        }
    }
    if let Some(n) = &a.notes
        && !n.is_file()
    {
        bail!("--notes {}: no such file", n.display());
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
        "{} cases from {}, {jobs} at a time within {:.1} GiB",
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
            notes: a.notes,
            quiet,
        },
    )?;
    println!(
        "wrote {}: {} cases scored, {} failed, {:.0} s; see report.md",
        a.out.display(),
        outcome.results.len(),
        outcome.failed_cases.len(),
        outcome.wall_s
    );
    for (id, e) in &outcome.failed_cases {
        eprintln!("case {id} failed: {e}");
    }
    Ok(())
}
