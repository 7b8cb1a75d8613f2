//! Progress reporting for long work: a bar on a terminal, a log line every 10 % elsewhere
//! (systemd, CI, pipes). Safe to share between rayon workers.

use std::io::IsTerminal;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Instant;

use indicatif::{ProgressBar, ProgressStyle};

/// One stage's progress.
pub struct Progress {
    bar: Option<ProgressBar>,
    label: String,
    total: u64,
    done: AtomicU64,
    started: Instant,
}

impl Progress {
    /// Starts reporting `total` units of `label`. `quiet` hides everything.
    pub fn new(label: &str, total: u64, quiet: bool) -> Progress {
        let bar = (!quiet && std::io::stderr().is_terminal()).then(|| {
            let bar = ProgressBar::new(total);
            let style = ProgressStyle::with_template(
                "{msg:>12} [{bar:40}] {pos}/{len} ({percent}%) {elapsed_precise} eta {eta}",
            )
            .map(|s| s.progress_chars("=> "))
            .unwrap_or_else(|_| ProgressStyle::default_bar());
            bar.set_style(style);
            bar.set_message(label.to_string());
            bar
        });
        Progress {
            bar,
            label: label.to_string(),
            total: if quiet { 0 } else { total },
            done: AtomicU64::new(0),
            started: Instant::now(),
        }
    }

    /// Records `n` more units done.
    pub fn inc(&self, n: u64) {
        let before = self.done.fetch_add(n, Ordering::Relaxed);
        if let Some(bar) = &self.bar {
            bar.inc(n);
        } else if self.total > 0 {
            let decile = |x: u64| x * 10 / self.total;
            if decile(before + n) > decile(before) {
                tracing::info!(
                    "{}: {}/{} ({}%) after {:.1} s",
                    self.label,
                    before + n,
                    self.total,
                    (before + n) * 100 / self.total,
                    self.started.elapsed().as_secs_f64()
                );
            }
        }
    }

    /// Shows `message` beside the bar; off a terminal it is logged at debug level.
    pub fn set_message(&self, message: &str) {
        if let Some(bar) = &self.bar {
            bar.set_message(format!("{} {message}", self.label));
        } else if self.total > 0 {
            tracing::debug!("{}: {message}", self.label);
        }
    }

    /// Ends the stage and returns its wall time in seconds.
    pub fn finish(self) -> f64 {
        if let Some(bar) = &self.bar {
            bar.finish();
        }
        self.started.elapsed().as_secs_f64()
    }
}
