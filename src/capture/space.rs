//! Disk space: what a capture directory takes and what a filesystem has free, so that long
//! writers (a simulation of an hour, the bench's capture cache) can check before they start.

use std::path::Path;

/// Bytes a capture directory's arrays take, about: the samples (complex f32) and the TX and RX
/// position of every channel (f64), without the `.npy` headers and the truth. At the paper's
/// aperture (1.16 M channels of 512 samples) that is 4.8 GB.
pub fn capture_dir_bytes(channels: usize, samples_per_chirp: usize) -> u64 {
    channels as u64 * (samples_per_chirp as u64 * 8 + 2 * 3 * 8)
}

/// A capture that does not fit on its filesystem.
#[derive(Debug, thiserror::Error)]
#[error(
    "{}: the capture needs {:.2} GB ({channels} channels × {samples_per_chirp} samples) and its filesystem has {:.2} GB free",
    path.display(),
    *needed_bytes as f64 / 1e9,
    *free_bytes as f64 / 1e9
)]
pub struct NoRoom {
    pub path: std::path::PathBuf,
    pub channels: usize,
    pub samples_per_chirp: usize,
    pub needed_bytes: u64,
    pub free_bytes: u64,
}

/// Refuses a capture of `channels` × `samples_per_chirp` to be written under `path` when its
/// filesystem has less free space than [`capture_dir_bytes`]; passes where the free space
/// cannot be read. Long writers call it before their work, not after.
pub fn ensure_room(path: &Path, channels: usize, samples_per_chirp: usize) -> Result<(), NoRoom> {
    check_room(path, channels, samples_per_chirp, available_bytes(path))
}

fn check_room(
    path: &Path,
    channels: usize,
    samples_per_chirp: usize,
    free: Option<u64>,
) -> Result<(), NoRoom> {
    let needed = capture_dir_bytes(channels, samples_per_chirp);
    match free {
        Some(free_bytes) if free_bytes < needed => Err(NoRoom {
            path: path.to_path_buf(),
            channels,
            samples_per_chirp,
            needed_bytes: needed,
            free_bytes,
        }),
        _ => Ok(()),
    }
}

/// Free bytes (for an unprivileged user) on the filesystem that holds `path`, or the nearest
/// of its ancestors that exists; None where the platform or the call cannot tell.
pub fn available_bytes(path: &Path) -> Option<u64> {
    let existing = path
        .ancestors()
        .find(|p| !p.as_os_str().is_empty() && p.exists())
        .unwrap_or(Path::new("."));
    statvfs_available(existing)
}

#[cfg(unix)]
fn statvfs_available(path: &Path) -> Option<u64> {
    use std::os::unix::ffi::OsStrExt;
    let c_path = std::ffi::CString::new(path.as_os_str().as_bytes()).ok()?;
    let mut stats = std::mem::MaybeUninit::<libc::statvfs>::uninit();
    // SAFETY: `c_path` is a NUL-terminated string that outlives the call, and `stats` points to
    // writable memory of the size statvfs fills; it is read only on success.
    let rc = unsafe { libc::statvfs(c_path.as_ptr(), stats.as_mut_ptr()) };
    if rc != 0 {
        return None;
    }
    // SAFETY: statvfs returned 0, so it initialised `stats`.
    let stats = unsafe { stats.assume_init() };
    #[allow(clippy::useless_conversion)] // the field types differ between platforms
    let free = u64::from(stats.f_bavail).saturating_mul(u64::from(stats.f_frsize));
    Some(free)
}

#[cfg(not(unix))]
fn statvfs_available(_path: &Path) -> Option<u64> {
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_path_still_to_be_created_reports_its_filesystem() {
        let tmp = std::env::temp_dir();
        let here = available_bytes(&tmp);
        assert!(here.is_some(), "statvfs on the temporary directory failed");
        let below = available_bytes(&tmp.join("mmnormd-not-yet").join("capture"));
        assert!(below.is_some());
        assert!(available_bytes(Path::new("no-such-relative-dir/x")).is_some());
    }

    #[test]
    fn a_capture_larger_than_the_free_space_is_refused_naming_both() {
        let out = Path::new("/data/captures/soup");
        let paper = 624 * 466 * 4;
        let e = check_room(out, paper, 512, Some(1_200_000_000)).expect_err("4.8 GB in 1.2 GB");
        let text = e.to_string();
        assert!(
            text.contains("/data/captures/soup")
                && text.contains("4.82 GB")
                && text.contains("1.20 GB free")
                && text.contains("1163136 channels"),
            "{text}"
        );
        assert!(check_room(out, paper, 512, Some(4_900_000_000)).is_ok());
        assert!(check_room(out, paper, 512, None).is_ok());
    }

    #[test]
    fn the_paper_aperture_takes_4_8_gb() {
        // 624 × 466 positions, 4 RX, 512 samples.
        let bytes = capture_dir_bytes(624 * 466 * 4, 512);
        assert_eq!(bytes, 1_163_136 * 4144);
        assert!((bytes as f64 / 1e9 - 4.82).abs() < 0.01);
    }
}
