//! A seeded fault injector for the recorder's disk: a writer that fails with "no space left on
//! device" once a byte budget is spent, as a full disk would. The simulated lab can put it under
//! the recorder (`sim.record_fail_after_bytes`) to show that a failed disk aborts the scan.

use std::io::{Seek, SeekFrom, Write};

/// Wraps a writer; writes past `budget` bytes fail (the part that fits is written).
pub struct FailingWriter<W> {
    inner: W,
    budget: u64,
    written: u64,
}

impl<W> FailingWriter<W> {
    pub fn new(inner: W, budget: u64) -> Self {
        Self {
            inner,
            budget,
            written: 0,
        }
    }
}

fn disk_full() -> std::io::Error {
    std::io::Error::from_raw_os_error(28)
}

impl<W: Write> Write for FailingWriter<W> {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        let room = self.budget.saturating_sub(self.written);
        if room == 0 {
            return Err(disk_full());
        }
        let n = self.inner.write(&buf[..buf.len().min(room as usize)])?;
        self.written += n as u64;
        Ok(n)
    }

    fn flush(&mut self) -> std::io::Result<()> {
        if self.written >= self.budget {
            return Err(disk_full());
        }
        self.inner.flush()
    }
}

impl<W: Seek> Seek for FailingWriter<W> {
    fn seek(&mut self, pos: SeekFrom) -> std::io::Result<u64> {
        self.inner.seek(pos)
    }
}
