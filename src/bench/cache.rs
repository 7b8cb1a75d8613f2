//! Simulated captures cached by content: the key is the SHA-256 of the case's scene with every
//! file replaced by the hash of its bytes, plus the simulator's revision. A capture is written
//! under a temporary name and renamed into place, so a cache entry is whole or absent.

use std::path::Path;

use sha2::Digest;

use super::suite::{Case, hex};
use super::{BenchError, io};
use crate::capture::space::{available_bytes, capture_dir_bytes};
use crate::capture::{Capture, read_capture_dir};
use crate::geometry::{TriMesh, load_mesh};
use crate::progress::Progress;
use crate::sim::{simulate_with, write_simulation};

fn gigabytes(bytes: u64) -> f64 {
    bytes as f64 / 1e9
}

/// Writes a cache entry with `write` under a temporary name in `cache_dir` and renames it to
/// `dir`. On any failure the temporary directory is removed, so the cache holds the entry
/// whole or not at all, and no orphan takes up the disk.
fn store(
    cache_dir: &Path,
    dir: &Path,
    key: &str,
    write: impl FnOnce(&Path) -> Result<(), BenchError>,
) -> Result<(), BenchError> {
    let partial = cache_dir.join(format!(
        ".{key}.partial-{}-{:?}",
        std::process::id(),
        std::thread::current().id()
    ));
    if partial.exists() {
        std::fs::remove_dir_all(&partial).map_err(io(&partial))?;
    }
    let written = write(&partial).and_then(|()| match std::fs::rename(&partial, dir) {
        Ok(()) => Ok(()),
        // Another run stored the same capture meanwhile: keep theirs.
        Err(_) if dir.join("capture.json").is_file() => {
            std::fs::remove_dir_all(&partial).map_err(io(&partial))
        }
        Err(e) => Err(io(dir)(e)),
    });
    if written.is_err() && partial.exists() {
        // Best effort: the write's own error is the one to report.
        let _ = std::fs::remove_dir_all(&partial);
    }
    written
}

/// Bumped whenever the simulator's output for the same scene changes, so stale captures are
/// not reused.
pub const SIMULATOR_REVISION: &str = "2026-11-23";

/// Bumped whenever the output changes for scenes with a cardboard sheet alone, so that their
/// captures are simulated again and the others are kept. Keyed only for those scenes.
/// 2026-12-03: the noise floor no longer rises with the sheet's own reflection.
pub const OCCLUDER_REVISION: &str = "2026-12-03";

/// The cache key of a case's capture.
pub fn capture_key(case: &Case) -> String {
    let mut h = sha2::Sha256::new();
    h.update(b"mmnormd simulate\n");
    h.update(env!("CARGO_PKG_VERSION").as_bytes());
    h.update(b"\n");
    h.update(SIMULATOR_REVISION.as_bytes());
    h.update(b"\n");
    if case.scene.occluder.is_some() {
        h.update(b"occluder ");
        h.update(OCCLUDER_REVISION.as_bytes());
        h.update(b"\n");
    }
    h.update(case.keyed_text.as_bytes());
    hex(&h.finalize())[..32].to_string()
}

/// A case's capture and its truth mesh, from the cache or freshly simulated.
pub struct CachedCapture {
    pub capture: Capture,
    pub truth_mesh: TriMesh,
    /// Seconds the simulation took when it ran.
    pub simulate_s: f64,
}

/// Free space left on the cache's filesystem beyond a capture, so that storing one does not
/// fill the disk for the rest of the run (its results) and for the machine.
pub const DISK_MARGIN_BYTES: u64 = 1 << 30;

/// Bytes a case's capture takes on disk, about (see [`capture_dir_bytes`]).
pub fn capture_bytes(case: &Case) -> u64 {
    capture_dir_bytes(case.scene.channels(), case.scene.plan.samples_per_chirp)
}

/// Reads the case's capture (`key`, from [`capture_key`]) from `cache_dir`, simulating and
/// storing it first when absent.
///
/// A capture that cannot be stored is not lost: when the disk holds less than its size plus
/// [`DISK_MARGIN_BYTES`], or writing it fails, a warning says so and the case goes on with the
/// capture in memory; the cache keeps no part of it.
///
/// A simulation that runs longer than [`SIMULATION_QUIET_S`] logs a line at each further
/// tenth of its antennas, naming the case, unless `quiet`.
pub fn capture_for(
    cache_dir: &Path,
    case: &Case,
    key: &str,
    quiet: bool,
) -> Result<CachedCapture, BenchError> {
    capture_for_with(cache_dir, case, key, quiet, available_bytes)
}

/// A case's simulation logs its progress only after running this long, seconds.
pub const SIMULATION_QUIET_S: f64 = 30.0;

fn capture_for_with(
    cache_dir: &Path,
    case: &Case,
    key: &str,
    quiet: bool,
    available: impl Fn(&Path) -> Option<u64>,
) -> Result<CachedCapture, BenchError> {
    let dir = cache_dir.join(key);
    let hit = dir.join("capture.json").is_file() && dir.join("truth.ply").is_file();
    if !hit {
        std::fs::create_dir_all(cache_dir).map_err(io(cache_dir))?;
        let label = format!("{} simulate", case.id);
        let mut result = simulate_with(&case.scene, |antennas| {
            Progress::lines(&label, antennas, quiet, SIMULATION_QUIET_S)
        });
        let needed = capture_bytes(case).saturating_add(DISK_MARGIN_BYTES);
        match available(cache_dir) {
            Some(free) if free < needed => tracing::warn!(
                "{}: capture not cached: it needs {:.1} GB with the {:.1} GB margin, and {} has {:.1} GB free; the case goes on from memory",
                case.id,
                gigabytes(needed - DISK_MARGIN_BYTES),
                gigabytes(DISK_MARGIN_BYTES),
                cache_dir.display(),
                gigabytes(free)
            ),
            _ => {
                let stored = store(cache_dir, &dir, key, |partial| {
                    write_simulation(partial, &case.scene, &case.id, &mut result)?;
                    let scene_file = partial.join("scene.toml");
                    std::fs::write(&scene_file, &case.scene_text).map_err(io(&scene_file))
                });
                if let Err(e) = stored {
                    tracing::warn!(
                        "{}: capture not cached ({e}); the case goes on from memory",
                        case.id
                    );
                }
            }
        }
        return Ok(CachedCapture {
            capture: result.capture,
            truth_mesh: result.truth_mesh,
            simulate_s: result.stats.seconds,
        });
    }
    let capture = read_capture_dir(&dir)?;
    let truth_mesh = load_mesh(&dir.join("truth.ply"))?;
    let simulate_s = capture
        .extra
        .get("simulation")
        .and_then(|s| s.pointer("/stats/seconds"))
        .and_then(serde_json::Value::as_f64)
        .unwrap_or(f64::NAN);
    Ok(CachedCapture {
        capture,
        truth_mesh,
        simulate_s,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bench::Suite;

    fn tiny_case() -> Case {
        let text = r#"
seed = 3
[radar]
profile = "../../firmware_cfg/iwr1443_mmnorm.cfg"
[aperture]
width_m = 0.02
height_m = 0.016
spacing_m = 0.004
clearance_m = 0.30
[noise]
snr_db = 25.0
[occluder]
gap_m = 0.10
[[scene]]
name = "ball"
poses = ["flat"]
[[scene.object]]
shape = "sphere"
radius_m = 0.02
"#;
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("tools/bench/unit.toml");
        let suite = Suite::parse(text, &path).expect("suite");
        suite.cases[0].clone()
    }

    fn entries(dir: &Path) -> Vec<String> {
        let mut names: Vec<String> = std::fs::read_dir(dir)
            .map(|d| {
                d.filter_map(|e| e.ok())
                    .map(|e| e.file_name().to_string_lossy().into_owned())
                    .collect()
            })
            .unwrap_or_default();
        names.sort();
        names
    }

    #[test]
    fn a_stored_capture_takes_the_size_the_space_check_expects() {
        let case = tiny_case();
        assert_eq!(case.scene.channels(), 6 * 5);
        let cache = std::env::temp_dir().join(format!("mmnormd-cache-size-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&cache);
        let key = capture_key(&case);
        let fresh = capture_for_with(&cache, &case, &key, true, |_| None).expect("simulated");
        assert_eq!(entries(&cache), std::slice::from_ref(&key));
        let on_disk: u64 = ["samples.npy", "tx.npy", "rx.npy"]
            .iter()
            .map(|f| std::fs::metadata(cache.join(&key).join(f)).map_or(0, |m| m.len()))
            .sum();
        let expected = capture_bytes(&case);
        // Three .npy headers of 128 bytes each on top of the data.
        assert!(
            on_disk >= expected && on_disk <= expected + 3 * 128,
            "{on_disk} bytes on disk against {expected} expected"
        );
        let cached = capture_for_with(&cache, &case, &key, true, |_| Some(0)).expect("read back");
        assert_eq!(cached.capture.antennas(), fresh.capture.antennas());
        assert_eq!(cached.capture.chirp(7), fresh.capture.chirp(7));
        let _ = std::fs::remove_dir_all(&cache);
    }

    #[test]
    fn a_capture_the_disk_cannot_hold_is_used_from_memory_and_leaves_nothing_behind() {
        let case = tiny_case();
        let cache = std::env::temp_dir().join(format!("mmnormd-cache-full-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&cache);
        let key = capture_key(&case);
        let room = capture_bytes(&case) + DISK_MARGIN_BYTES - 1;
        let got = capture_for_with(&cache, &case, &key, true, |_| Some(room)).expect("from memory");
        assert_eq!(got.capture.antennas(), case.scene.channels());
        assert!(got.capture.chirp(0).iter().any(|z| z.norm() > 0.0));
        assert!(entries(&cache).is_empty(), "{:?}", entries(&cache));
        let _ = std::fs::remove_dir_all(&cache);
    }

    #[test]
    fn a_failed_write_removes_its_partial_entry() {
        let cache = std::env::temp_dir().join(format!("mmnormd-cache-fail-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&cache);
        std::fs::create_dir_all(&cache).expect("cache dir");
        let dir = cache.join("k");
        let result = store(&cache, &dir, "k", |partial| {
            std::fs::create_dir_all(partial).map_err(io(partial))?;
            std::fs::write(partial.join("samples.npy"), vec![0u8; 4096]).map_err(io(partial))?;
            Err(io(partial)(std::io::Error::from_raw_os_error(28)))
        });
        let e = result.expect_err("the write failed").to_string();
        assert!(e.contains("No space left"), "{e}");
        assert!(entries(&cache).is_empty(), "{:?}", entries(&cache));
        // A rename onto an entry another writer left incomplete fails too, and cleans up.
        std::fs::create_dir_all(dir.join("stale")).expect("stale entry");
        let result = store(&cache, &dir, "k", |partial| {
            std::fs::create_dir_all(partial).map_err(io(partial))
        });
        assert!(result.is_err());
        assert_eq!(entries(&cache), ["k"]);
        let _ = std::fs::remove_dir_all(&cache);
    }
}
