//! Simulated captures cached by content: the key is the SHA-256 of the case's scene with every
//! file replaced by the hash of its bytes, plus the simulator's revision. A capture is written
//! under a temporary name and renamed into place, so a cache entry is whole or absent.

use std::path::Path;

use sha2::Digest;

use super::suite::{Case, hex};
use super::{BenchError, io};
use crate::capture::{Capture, read_capture_dir};
use crate::geometry::{TriMesh, load_mesh};
use crate::sim::{simulate, write_simulation};

/// Bumped whenever the simulator's output for the same scene changes, so stale captures are
/// not reused.
pub const SIMULATOR_REVISION: &str = "2026-11-23";

/// The cache key of a case's capture.
pub fn capture_key(case: &Case) -> String {
    let mut h = sha2::Sha256::new();
    h.update(b"mmnormd simulate\n");
    h.update(env!("CARGO_PKG_VERSION").as_bytes());
    h.update(b"\n");
    h.update(SIMULATOR_REVISION.as_bytes());
    h.update(b"\n");
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

/// Reads the case's capture (`key`, from [`capture_key`]) from `cache_dir`, simulating and
/// storing it first when absent.
pub fn capture_for(cache_dir: &Path, case: &Case, key: &str) -> Result<CachedCapture, BenchError> {
    let dir = cache_dir.join(key);
    let hit = dir.join("capture.json").is_file() && dir.join("truth.ply").is_file();
    if !hit {
        std::fs::create_dir_all(cache_dir).map_err(io(cache_dir))?;
        let partial = cache_dir.join(format!(
            ".{key}.partial-{}-{:?}",
            std::process::id(),
            std::thread::current().id()
        ));
        if partial.exists() {
            std::fs::remove_dir_all(&partial).map_err(io(&partial))?;
        }
        let mut result = simulate(&case.scene, true);
        write_simulation(&partial, &case.scene, &case.id, &mut result)?;
        let scene_file = partial.join("scene.toml");
        std::fs::write(&scene_file, &case.scene_text).map_err(io(&scene_file))?;
        if let Err(e) = std::fs::rename(&partial, &dir) {
            // Another run stored the same capture meanwhile: keep theirs.
            if dir.join("capture.json").is_file() {
                std::fs::remove_dir_all(&partial).map_err(io(&partial))?;
            } else {
                return Err(io(&dir)(e));
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
