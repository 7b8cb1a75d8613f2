//! `mmnormd --config lab.toml`: the daemon.

use std::path::Path;

use anyhow::{Context, Result};
use mmnormd::daemon::Daemon;
use mmnormd::lab::LabConfig;

pub fn run(config: &Path, quiet: bool) -> Result<()> {
    // Every field is checked before any device is touched.
    let lab = LabConfig::load(config)?;
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .context("starting the runtime")?;
    runtime.block_on(async {
        let daemon = Daemon::start(lab, quiet).await?;
        daemon.serve().await?;
        Ok::<(), anyhow::Error>(())
    })?;
    // Threads that own devices end with the process.
    runtime.shutdown_timeout(std::time::Duration::from_millis(100));
    Ok(())
}
