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
    /// Off a bar, no line is logged before the stage has run this long.
    quiet_for_s: f64,
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
            quiet_for_s: 0.0,
        }
    }

    /// A stage inside another stage's bar (a case of `bench accuracy`): never a bar of its
    /// own, a log line at each further tenth once it has run `quiet_for_s`, so that only long
    /// work speaks. `quiet` hides everything.
    pub fn lines(label: &str, total: u64, quiet: bool, quiet_for_s: f64) -> Progress {
        Progress {
            bar: None,
            label: label.to_string(),
            total: if quiet { 0 } else { total },
            done: AtomicU64::new(0),
            started: Instant::now(),
            quiet_for_s,
        }
    }

    /// Records `n` more units done.
    pub fn inc(&self, n: u64) {
        let before = self.done.fetch_add(n, Ordering::Relaxed);
        if let Some(bar) = &self.bar {
            bar.inc(n);
        } else {
            let elapsed_s = self.started.elapsed().as_secs_f64();
            if line_due(before, n, self.total, elapsed_s, self.quiet_for_s) {
                tracing::info!(
                    "{}: {}/{} ({}%) after {:.1} s",
                    self.label,
                    before + n,
                    self.total,
                    (before + n) * 100 / self.total,
                    elapsed_s
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

/// Whether a step from `before` by `n` of `total` units (0: quiet) logs a line after
/// `elapsed_s`: when it crosses a further tenth, once `quiet_for_s` have passed.
fn line_due(before: u64, n: u64, total: u64, elapsed_s: f64, quiet_for_s: f64) -> bool {
    total > 0 && (before + n) * 10 / total > before * 10 / total && elapsed_s >= quiet_for_s
}

#[cfg(test)]
mod tests {
    use super::line_due;

    #[test]
    fn a_line_is_due_at_each_further_tenth_once_the_quiet_time_has_passed() {
        let due = |before, n| line_due(before, n, 100, 5.0, 0.0);
        assert!(!due(0, 9) && due(9, 1) && !due(10, 1) && due(10, 10) && due(95, 5));
        // Off, or not yet long enough: no line at any tenth.
        assert!(!line_due(9, 1, 0, 5.0, 0.0));
        assert!(!line_due(9, 1, 100, 5.0, 30.0));
        assert!(line_due(9, 1, 100, 30.0, 30.0));
    }
}
