//! Running the cases: capture (cached), one image shared by every method, mmNorm with its two
//! ablations sharing the normal field and RSDFs, the two baselines, and the scores. Each case
//! leaves `runs/<id>/`: the points of each method (`<method>.ply`), their per-point scores
//! (`<method>.scores.npy`: point error, relative error, normal cosine), the reconstruction's
//! summary (`<method>.summary.json`, as `reconstruct` writes it, with the case's exact
//! parameters) and, written last, `result.json`. A case whose `result.json` carries the same
//! key and was written by the same build (the running executable's hash, [`build_id`]) is not
//! run again, so an interrupted bench resumes where it stopped, and a rebuilt one reconstructs
//! every case again from the cached captures. `--report-only` reads the results of any build.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Condvar, Mutex};
use std::time::Instant;

use serde::{Deserialize, Serialize};
use sha2::Digest;

use super::cache::{capture_for, capture_key};
use super::scene_png::write_scene_png;
use super::suite::{Case, Condition, Pose, hex};
use super::{BenchError, io};
use crate::capture::dir::write_atomically;
use crate::capture::npy;
use crate::eval::{Metrics, PointScores, estimate_normals, evaluate_points};
use crate::progress::Progress;
use crate::recon::config::{Isosurface, Method};
use crate::recon::output::write_summary;
use crate::recon::{
    ReconConfig, Reconstruction, image_volume, reconstruct_imaged, reconstruct_isosurfaces,
};
use crate::sim::truth::{TOP_GRID_M, top_surface_with_normals};

/// The methods of the paper's evaluation, in report order.
pub const METHODS: [&str; 5] = [
    "mmnorm",
    "backprojection",
    "interferometric",
    "center",
    "weighted",
];

/// Baseline normals (paper §6.3.1): PCA over this many nearest neighbours within this radius.
const PCA_NEIGHBOURS: usize = 30;
const PCA_RADIUS_M: f64 = 0.01;

/// One method's outcome on one case.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct MethodResult {
    pub method: String,
    /// None when the method failed; the report then counts it with F = 0.
    pub metrics: Option<Metrics>,
    pub error: Option<String>,
    /// Where the normals came from: `mmnorm` (the vote), `pca` (estimated from the points).
    pub normals: String,
    pub stage_s: Vec<(String, f64)>,
    pub total_s: f64,
}

/// One case's outcome.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct CaseResult {
    pub key: String,
    /// The build that reconstructed the case ([`build_id`]; empty in results written before
    /// it was recorded).
    #[serde(default)]
    pub build: String,
    pub id: String,
    pub scene: String,
    pub pose: Pose,
    pub condition: Condition,
    /// The physics model the case was simulated under (results written before it was recorded
    /// were all physical optics).
    #[serde(default = "physical_optics")]
    pub physics: String,
    /// The scene's object class ("" where the suite gives none).
    #[serde(default)]
    pub class: String,
    pub capture_key: String,
    pub antennas: usize,
    pub simulate_s: f64,
    pub truth_points: usize,
    pub methods: Vec<MethodResult>,
}

fn physical_optics() -> String {
    super::suite::PHYSICAL_OPTICS.to_string()
}

/// Where things go and how much may run at once.
pub struct RunOptions {
    pub cache_dir: PathBuf,
    pub runs_dir: PathBuf,
    pub scenes_dir: PathBuf,
    pub tau_m: f64,
    /// Cases run side by side (each also parallel inside).
    pub jobs: usize,
    /// Memory the concurrent cases may hold together, bytes.
    pub memory_budget_bytes: u64,
    pub quiet: bool,
}

/// The build that runs: the first 16 hex digits of the SHA-256 of the running executable, so
/// that any change to the code makes finished cases run again. When the executable cannot be
/// read it is the package version alone, with a warning.
pub fn build_id() -> &'static str {
    static ID: std::sync::OnceLock<String> = std::sync::OnceLock::new();
    ID.get_or_init(|| {
        let exe = std::env::current_exe().and_then(std::fs::read);
        match exe {
            Ok(bytes) => hex(&sha2::Sha256::digest(&bytes))[..16].to_string(),
            Err(e) => {
                tracing::warn!(
                    "cannot read the running executable ({e}): finished cases are reused \
                     whichever build of mmnormd {} wrote them",
                    env!("CARGO_PKG_VERSION")
                );
                env!("CARGO_PKG_VERSION").to_string()
            }
        }
    })
}

/// The resume key of a case: its capture, its reconstruction settings, τ and the package
/// version (the build is compared apart, [`build_id`]).
pub fn result_key(case: &Case, capture_key: &str, tau_m: f64) -> String {
    let mut h = sha2::Sha256::new();
    h.update(env!("CARGO_PKG_VERSION").as_bytes());
    h.update(capture_key.as_bytes());
    h.update(
        serde_json::to_string(&case.recon)
            .unwrap_or_default()
            .as_bytes(),
    );
    h.update(tau_m.to_le_bytes());
    hex(&h.finalize())[..32].to_string()
}

/// A rough upper bound of one case's memory: the capture three times over (simulation,
/// capture, range profiles), once more where a known sheet's echo is removed before imaging
/// (the cleaned copy), and the volume's per-voxel arrays.
pub fn memory_estimate_bytes(case: &Case) -> u64 {
    let a = &case.scene.aperture;
    let (columns, rows) = a.raster_size();
    let per = match a.layout {
        crate::sim::scene::Layout::Monostatic => 1.0,
        crate::sim::scene::Layout::Iwr1443boost => 4.0,
    };
    let channels = columns as f64 * rows as f64 * per;
    let capture = channels * case.scene.plan.samples_per_chirp as f64 * 8.0;
    let voxels = 0.3f64.powi(3) / case.recon.voxel_m.powi(3);
    let copies = match case.recon.occluder {
        Some(o) if o.remove_echo => 4.0,
        _ => 3.0,
    };
    (copies * capture + voxels.min(6.0e7) * 64.0) as u64
}

/// A counting semaphore over bytes.
struct Budget {
    free: Mutex<u64>,
    changed: Condvar,
    total: u64,
}

impl Budget {
    fn take(&self, want: u64) -> u64 {
        let want = want.min(self.total);
        let mut free = self.free.lock().unwrap_or_else(|p| p.into_inner());
        while *free < want {
            free = self.changed.wait(free).unwrap_or_else(|p| p.into_inner());
        }
        *free -= want;
        want
    }

    fn give(&self, n: u64) {
        let mut free = self.free.lock().unwrap_or_else(|p| p.into_inner());
        *free += n;
        self.changed.notify_all();
    }
}

/// Runs every case (resuming finished ones), `jobs` at a time within the memory budget, with one
/// progress bar naming each running case and its stage. Returns each case's result or error.
pub fn run_cases(cases: &[Case], opts: &RunOptions) -> Vec<Result<CaseResult, String>> {
    let progress = Progress::new("bench", cases.len() as u64, opts.quiet);
    let active: Mutex<Vec<(usize, String)>> = Mutex::new(Vec::new());
    let show = |slot: usize, text: Option<String>| {
        let mut a = active.lock().unwrap_or_else(|p| p.into_inner());
        a.retain(|(s, _)| *s != slot);
        if let Some(t) = text {
            a.push((slot, t));
        }
        a.sort();
        let line: Vec<&str> = a.iter().map(|(_, t)| t.as_str()).collect();
        progress.set_message(&line.join(" | "));
    };
    let budget = Budget {
        free: Mutex::new(opts.memory_budget_bytes.max(1)),
        changed: Condvar::new(),
        total: opts.memory_budget_bytes.max(1),
    };
    let next = AtomicUsize::new(0);
    let results: Mutex<Vec<Option<Result<CaseResult, String>>>> =
        Mutex::new(vec![None; cases.len()]);
    std::thread::scope(|scope| {
        for slot in 0..opts.jobs.max(1) {
            let (next, budget, results, show, progress) =
                (&next, &budget, &results, &show, &progress);
            scope.spawn(move || {
                loop {
                    let i = next.fetch_add(1, Ordering::SeqCst);
                    let Some(case) = cases.get(i) else { break };
                    let held = budget.take(memory_estimate_bytes(case));
                    let stage = |s: &str| show(slot, Some(format!("{} {s}", case.id)));
                    let started = Instant::now();
                    let outcome = run_case(case, opts, &stage).map_err(|e| {
                        tracing::error!("{}: {e}", case.id);
                        e.to_string()
                    });
                    if let Ok(r) = &outcome {
                        let f: Vec<String> = r
                            .methods
                            .iter()
                            .take(3)
                            .map(|m| {
                                let f = m.metrics.as_ref().map_or(0.0, |x| x.f_score);
                                format!("{} {f:.2}", m.method)
                            })
                            .collect();
                        tracing::info!(
                            "{}: F {} ({:.0} s)",
                            case.id,
                            f.join(", "),
                            started.elapsed().as_secs_f64()
                        );
                    }
                    budget.give(held);
                    show(slot, None);
                    progress.inc(1);
                    results.lock().unwrap_or_else(|p| p.into_inner())[i] = Some(outcome);
                }
            });
        }
    });
    progress.finish();
    results
        .into_inner()
        .unwrap_or_else(|p| p.into_inner())
        .into_iter()
        .map(|r| r.unwrap_or_else(|| Err("not run".into())))
        .collect()
}

/// The case's result in `dir` if it carries `key` and, when `build` is given, was written by it.
fn finished(dir: &Path, key: &str, build: Option<&str>) -> Option<CaseResult> {
    let text = std::fs::read_to_string(dir.join("result.json")).ok()?;
    let r: CaseResult = serde_json::from_str(&text).ok()?;
    (r.key == key && build.is_none_or(|b| r.build == b)).then_some(r)
}

/// The case's capture key and result key.
fn keys(case: &Case, opts: &RunOptions) -> (String, String) {
    let capture_key = capture_key(case);
    let key = result_key(case, &capture_key, opts.tau_m);
    (capture_key, key)
}

/// The case's result if an earlier run finished it with the same settings, by any build.
pub fn finished_result(case: &Case, opts: &RunOptions) -> Option<CaseResult> {
    finished(&opts.runs_dir.join(&case.id), &keys(case, opts).1, None)
}

/// Runs one case (or reads it back when already done).
pub fn run_case(
    case: &Case,
    opts: &RunOptions,
    stage: &dyn Fn(&str),
) -> Result<CaseResult, BenchError> {
    let dir = opts.runs_dir.join(&case.id);
    let (capture_key, key) = keys(case, opts);
    if let Some(done) = finished(&dir, &key, Some(build_id())) {
        return Ok(done);
    }
    stage("simulate");
    let cached = capture_for(&opts.cache_dir, case, &capture_key, opts.quiet)?;
    let capture = &cached.capture;
    let (truth, truth_normals) = top_surface_with_normals(&cached.truth_mesh, TOP_GRID_M);
    stage("image");
    let imaged = image_volume(capture, &case.recon, true)?;
    std::fs::create_dir_all(&dir).map_err(io(&dir))?;
    // Each method's result with the parameters it ran with (its summary.json records them).
    let mut outcomes: Vec<(String, ReconConfig, Result<Reconstruction, String>)> = Vec::new();
    stage("mmnorm");
    let ablations = [
        ("mmnorm", Isosurface::Optimized),
        ("center", Isosurface::Center),
        ("weighted", Isosurface::Weighted),
    ];
    let isosurfaces = ablations.map(|(_, i)| i);
    let config_with = |isosurface| ReconConfig {
        isosurface,
        ..case.recon.clone()
    };
    match reconstruct_isosurfaces(capture, &case.recon, &imaged, &isosurfaces, true) {
        Ok(list) => {
            for ((name, isosurface), r) in ablations.into_iter().zip(list) {
                outcomes.push((name.into(), config_with(isosurface), Ok(r)));
            }
        }
        Err(e) => {
            for (name, isosurface) in ablations {
                outcomes.push((name.into(), config_with(isosurface), Err(e.to_string())));
            }
        }
    }
    stage("baselines");
    for (name, method) in [
        ("backprojection", Method::Backprojection),
        ("interferometric", Method::Interferometric),
    ] {
        let config = ReconConfig {
            method,
            ..case.recon.clone()
        };
        let r = reconstruct_imaged(capture, &config, &imaged, true).map_err(|e| e.to_string());
        outcomes.push((name.into(), config, r));
    }
    stage("score");
    let capture_label = opts.cache_dir.join(&capture_key).display().to_string();
    let mut methods = Vec::new();
    let mut clouds = Vec::new();
    for name in METHODS {
        let Some((_, config, outcome)) = outcomes.iter().find(|(n, _, _)| n == name) else {
            continue;
        };
        let result = match outcome {
            Ok(recon) => {
                let estimated;
                let (normals, source) = match &recon.normals {
                    Some(n) => (n.as_slice(), "mmnorm"),
                    None => {
                        estimated = estimate_normals(&recon.points_m, PCA_NEIGHBOURS, PCA_RADIUS_M);
                        (estimated.as_slice(), "pca")
                    }
                };
                let (metrics, scores) = evaluate_points(
                    &recon.points_m,
                    Some(normals),
                    &truth,
                    Some(&truth_normals),
                    opts.tau_m,
                );
                let ply = dir.join(format!("{name}.ply"));
                write_atomically(&ply, &recon.encode_ply())?;
                let summary = dir.join(format!("{name}.summary.json"));
                write_summary(&summary, &capture_label, config, recon)?;
                let npy_path = dir.join(format!("{name}.scores.npy"));
                write_atomically(&npy_path, &npy::encode_f64_rows(&score_rows(&scores)))?;
                clouds.push((name, recon.points_m.as_slice()));
                MethodResult {
                    method: name.into(),
                    metrics: Some(metrics),
                    error: None,
                    normals: source.into(),
                    total_s: recon.summary.stage_s.iter().map(|(_, t)| t).sum(),
                    stage_s: recon.summary.stage_s.clone(),
                }
            }
            Err(e) => MethodResult {
                method: name.into(),
                metrics: None,
                error: Some(e.clone()),
                normals: String::new(),
                stage_s: Vec::new(),
                total_s: 0.0,
            },
        };
        methods.push(result);
    }
    stage("picture");
    let find = |n: &str| clouds.iter().find(|(m, _)| *m == n).map(|(_, p)| *p);
    std::fs::create_dir_all(&opts.scenes_dir).map_err(io(&opts.scenes_dir))?;
    write_scene_png(
        &opts.scenes_dir.join(format!("{}.png", case.id)),
        &case.id,
        &truth,
        find("mmnorm").unwrap_or(&[]),
        find("backprojection").unwrap_or(&[]),
        case.recon.voxel_m,
    )?;
    let result = CaseResult {
        key,
        build: build_id().to_string(),
        id: case.id.clone(),
        scene: case.scene_name.clone(),
        pose: case.pose,
        condition: case.condition,
        physics: case.physics.clone(),
        class: case.class.clone(),
        capture_key,
        antennas: capture.antennas(),
        simulate_s: cached.simulate_s,
        truth_points: truth.len(),
        methods,
    };
    let mut text = serde_json::to_string_pretty(&result)?;
    text.push('\n');
    write_atomically(&dir.join("result.json"), text.as_bytes())?;
    Ok(result)
}

/// Rows of (point error, relative error, normal cosine or NaN).
fn score_rows(s: &PointScores) -> Vec<[f64; 3]> {
    (0..s.error_m.len())
        .map(|i| {
            [
                s.error_m[i],
                s.relative[i],
                s.normal_cos.as_ref().map_or(f64::NAN, |c| c[i]),
            ]
        })
        .collect()
}

/// Reads back the per-point scores of one method of one case (empty when it has none).
pub fn read_scores(runs_dir: &Path, id: &str, method: &str) -> Result<Vec<[f64; 3]>, BenchError> {
    let path = runs_dir.join(id).join(format!("{method}.scores.npy"));
    if !path.exists() {
        return Ok(Vec::new());
    }
    Ok(crate::capture::dir::read_points_npy(&path)?)
}
