//! The accuracy suite file (TOML) and its expansion into cases: one simulated scene per
//! (scene, pose, condition), written as an ordinary scene file that `mmnormd simulate` runs.
//!
//! Each case's objects are posed (flat as given, on their side, or rotated about z), the group is
//! set down on the table (z = 0) centred under the aperture, the aperture plane is put
//! `clearance_m` above the highest point, and for NLOS a cardboard sheet is put `gap_m` above it.
//! Everything comes from the suite's geometry; nothing looks at a reconstruction.

use std::path::{Path, PathBuf};

use nalgebra::{Rotation3, Vector3};
use serde::Deserialize;

use crate::recon::ReconConfig;
use crate::recon::config::KnownOccluder;
use crate::sim::scene::{ObjectGeometry, Physics};
use crate::sim::{Scene, SceneError};

/// Why a suite was refused. Each variant names the file and, where there is one, the field.
#[derive(Debug, thiserror::Error)]
pub enum SuiteError {
    #[error("cannot read suite {path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("suite {path}: {message}")]
    Syntax { path: PathBuf, message: String },
    #[error("suite {path}: `{field}` = {value}: {reason}")]
    Field {
        path: PathBuf,
        field: String,
        value: String,
        reason: String,
    },
    #[error("suite {path}: case {case}: {source}")]
    Scene {
        path: PathBuf,
        case: String,
        #[source]
        source: Box<SceneError>,
    },
}

/// How a scene's objects are posed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Deserialize, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Pose {
    /// As the objects are given.
    Flat,
    /// Turned 90° about x: lying on its side.
    Side,
    /// Turned `rotated_deg` about z.
    Rotated,
}

impl Pose {
    pub fn name(self) -> &'static str {
        match self {
            Pose::Flat => "flat",
            Pose::Side => "side",
            Pose::Rotated => "rotated",
        }
    }
}

/// Line of sight, or through the cardboard sheet.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Deserialize, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Condition {
    Los,
    Nlos,
}

impl Condition {
    pub fn name(self) -> &'static str {
        match self {
            Condition::Los => "los",
            Condition::Nlos => "nlos",
        }
    }
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct SuiteFile {
    #[serde(default)]
    description: String,
    #[serde(default)]
    seed: u64,
    #[serde(default = "default_tau")]
    tau_m: f64,
    #[serde(default = "default_conditions")]
    conditions: Vec<Condition>,
    /// The physics models every case is simulated under (`[physics] model` of a scene).
    #[serde(default = "default_physics")]
    physics: Vec<String>,
    radar: toml::Table,
    aperture: ApertureSpec,
    noise: Option<NoiseSpec>,
    occluder: OccluderSpec,
    #[serde(default)]
    poses: PoseSpec,
    #[serde(default)]
    recon: toml::Table,
    /// Another suite file whose `[[scene]]` list this suite uses (its paths resolve against
    /// that file's directory).
    scenes_from: Option<PathBuf>,
    #[serde(default, rename = "scene")]
    scenes: Vec<SceneSpec>,
}

#[derive(Debug, Deserialize)]
struct ScenesOnly {
    #[serde(default, rename = "scene")]
    scenes: Vec<SceneSpec>,
}

fn default_tau() -> f64 {
    0.015
}

fn default_physics() -> Vec<String> {
    vec![PHYSICAL_OPTICS.to_string()]
}

/// The default physics model; its cases' ids carry no suffix.
pub const PHYSICAL_OPTICS: &str = Physics::MODELS[0];

/// The suffix of a case id under `physics`: none for the default model, `-point` for the
/// point-scatterer model.
pub fn physics_suffix(physics: &str) -> String {
    match physics {
        PHYSICAL_OPTICS => String::new(),
        other => format!("-{}", other.split('-').next().unwrap_or(other)),
    }
}

fn default_conditions() -> Vec<Condition> {
    vec![Condition::Los, Condition::Nlos]
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct ApertureSpec {
    width_m: f64,
    height_m: f64,
    spacing_m: Option<f64>,
    /// The aperture plane lies this far above the scene's highest point.
    clearance_m: f64,
    layout: Option<String>,
    rx_axis: Option<String>,
    antenna_pattern: Option<String>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct NoiseSpec {
    snr_db: f64,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct OccluderSpec {
    /// The sheet's mid-plane lies this far above the scene's highest point.
    gap_m: f64,
    thickness_m: Option<f64>,
    refractive_index: Option<f64>,
    loss_db: Option<f64>,
    /// The sheet reaches this far beyond the aperture on every side.
    #[serde(default = "default_overhang")]
    overhang_m: f64,
    /// NLOS reconstructions search for echoes from this far past the sheet (one-way range).
    #[serde(default = "default_gate")]
    gate_margin_m: f64,
    /// NLOS reconstructions know the sheet's thickness and refractive index and compensate its
    /// delay (`recon.occluder`), as a user who knows the box does.
    #[serde(default)]
    compensate: bool,
}

fn default_overhang() -> f64 {
    0.1
}

fn default_gate() -> f64 {
    0.07
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct PoseSpec {
    #[serde(default = "default_rotated")]
    rotated_deg: f64,
}

impl Default for PoseSpec {
    fn default() -> Self {
        PoseSpec {
            rotated_deg: default_rotated(),
        }
    }
}

fn default_rotated() -> f64 {
    30.0
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct SceneSpec {
    name: String,
    /// The object class the report groups by (such as flat, tall, hollow, clutter).
    #[serde(default)]
    class: Option<String>,
    poses: Vec<Pose>,
    #[serde(rename = "object")]
    objects: Vec<toml::Table>,
}

/// One simulated scene of the suite and how to reconstruct it.
#[derive(Debug, Clone)]
pub struct Case {
    /// `scene-pose-condition`.
    pub id: String,
    pub scene_name: String,
    pub pose: Pose,
    pub condition: Condition,
    /// The physics model the case is simulated under (`[physics] model`).
    pub physics: String,
    /// The scene's object class, or "" where the suite gives none.
    pub class: String,
    /// A scene file that `mmnormd simulate` runs as it is (absolute paths).
    pub scene_text: String,
    /// The same scene with each file path replaced by the SHA-256 of its contents: what the
    /// capture cache is keyed on.
    pub keyed_text: String,
    pub scene: Scene,
    pub recon: ReconConfig,
}

/// A loaded suite.
#[derive(Debug, Clone)]
pub struct Suite {
    pub path: PathBuf,
    pub description: String,
    pub tau_m: f64,
    pub cases: Vec<Case>,
}

struct Ctx<'a> {
    path: &'a Path,
}

impl Ctx<'_> {
    fn field(&self, field: &str, value: impl std::fmt::Debug, reason: &str) -> SuiteError {
        SuiteError::Field {
            path: self.path.to_path_buf(),
            field: field.to_string(),
            value: format!("{value:?}"),
            reason: reason.to_string(),
        }
    }

    fn positive(&self, field: &str, v: f64) -> Result<f64, SuiteError> {
        if v.is_finite() && v > 0.0 {
            Ok(v)
        } else {
            Err(self.field(field, v, "must be a positive number"))
        }
    }
}

/// Stable 64-bit FNV-1a of a string: the per-case noise seed must not change between Rust
/// versions, so `std`'s hasher is not used.
fn fnv1a(text: &str) -> u64 {
    text.bytes().fold(0xcbf2_9ce4_8422_2325, |h, b| {
        (h ^ u64::from(b)).wrapping_mul(0x0100_0000_01b3)
    })
}

/// Hex SHA-256 of a file's bytes.
pub fn file_sha256(path: &Path) -> std::io::Result<String> {
    use sha2::Digest;
    let bytes = std::fs::read(path)?;
    Ok(hex(&sha2::Sha256::digest(&bytes)))
}

/// Lower-case hex of `bytes`.
pub fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

impl Suite {
    pub fn load(path: &Path) -> Result<Suite, SuiteError> {
        let text = std::fs::read_to_string(path).map_err(|source| SuiteError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        Suite::parse(&text, path)
    }

    /// Parses a suite; relative paths resolve against `path`'s directory.
    pub fn parse(text: &str, path: &Path) -> Result<Suite, SuiteError> {
        let mut file: SuiteFile = toml::from_str(text).map_err(|e| SuiteError::Syntax {
            path: path.to_path_buf(),
            message: e.to_string(),
        })?;
        let c = Ctx { path };
        let base = path.parent().unwrap_or(Path::new(".")).to_path_buf();
        let tau_m = c.positive("tau_m", file.tau_m)?;
        c.positive("aperture.clearance_m", file.aperture.clearance_m)?;
        c.positive("occluder.gap_m", file.occluder.gap_m)?;
        if file.occluder.gap_m >= file.aperture.clearance_m {
            return Err(c.field(
                "occluder.gap_m",
                file.occluder.gap_m,
                &format!(
                    "the sheet must lie between the objects and the aperture (clearance_m = {})",
                    file.aperture.clearance_m
                ),
            ));
        }
        if !(file.occluder.gate_margin_m.is_finite() && file.occluder.gate_margin_m >= 0.0) {
            return Err(c.field(
                "occluder.gate_margin_m",
                file.occluder.gate_margin_m,
                "must be zero or positive",
            ));
        }
        if file.conditions.is_empty() {
            return Err(c.field("conditions", "[]", "list at least one of los, nlos"));
        }
        if file.physics.is_empty() {
            return Err(c.field(
                "physics",
                "[]",
                "list at least one of \"physical-optics\", \"point-scatterer\"",
            ));
        }
        for (i, model) in file.physics.iter().enumerate() {
            if !Physics::MODELS.contains(&model.as_str()) {
                return Err(c.field(
                    &format!("physics[{i}]"),
                    model,
                    "must be \"physical-optics\" or \"point-scatterer\"",
                ));
            }
            if file.physics[..i].contains(model) {
                return Err(c.field(&format!("physics[{i}]"), model, "is listed twice"));
            }
        }
        let (scenes, scenes_base) = match &file.scenes_from {
            Some(other) if file.scenes.is_empty() => {
                let other = base.join(other);
                let text = std::fs::read_to_string(&other).map_err(|source| SuiteError::Io {
                    path: other.clone(),
                    source,
                })?;
                let list: ScenesOnly = toml::from_str(&text).map_err(|e| SuiteError::Syntax {
                    path: other.clone(),
                    message: e.to_string(),
                })?;
                let dir = other.parent().unwrap_or(Path::new(".")).to_path_buf();
                (list.scenes, dir)
            }
            Some(other) => {
                return Err(c.field(
                    "scenes_from",
                    other,
                    "give either scenes_from or [[scene]] tables, not both",
                ));
            }
            None => (std::mem::take(&mut file.scenes), base.clone()),
        };
        if scenes.is_empty() {
            return Err(c.field("scene", "[]", "a suite needs at least one [[scene]]"));
        }
        let recon_text = toml::to_string(&file.recon)
            .map_err(|e| c.field("recon", &file.recon, &e.to_string()))?;
        let recon =
            ReconConfig::parse(&recon_text).map_err(|reason| c.field("recon", "…", &reason))?;
        let mut names = std::collections::HashSet::new();
        let mut cases = Vec::new();
        for (i, s) in scenes.iter().enumerate() {
            let ok = !s.name.is_empty()
                && s.name
                    .chars()
                    .all(|ch| ch.is_ascii_lowercase() || ch.is_ascii_digit() || ch == '_');
            if !ok {
                return Err(c.field(
                    &format!("scene[{i}].name"),
                    &s.name,
                    "use lower-case letters, digits and _",
                ));
            }
            if !names.insert(s.name.clone()) {
                return Err(c.field(&format!("scene[{i}].name"), &s.name, "is used twice"));
            }
            if s.poses.is_empty() || s.objects.is_empty() {
                return Err(c.field(
                    &format!("scene[{i}]"),
                    &s.name,
                    "needs at least one pose and one [[scene.object]]",
                ));
            }
            if let Some(class) = &s.class {
                let ok = !class.is_empty()
                    && class.chars().all(|ch| ch.is_ascii_lowercase() || ch == '_');
                if !ok {
                    return Err(c.field(
                        &format!("scene[{i}].class"),
                        class,
                        "use lower-case letters and _",
                    ));
                }
            }
            for physics in &file.physics {
                for &pose in &s.poses {
                    for &condition in &file.conditions {
                        let bases = Bases {
                            suite: &base,
                            objects: &scenes_base,
                        };
                        let how = CaseOf {
                            pose,
                            condition,
                            physics,
                        };
                        cases.push(build_case(&c, &file, &bases, &recon, s, how)?);
                    }
                }
            }
        }
        Ok(Suite {
            path: path.to_path_buf(),
            description: file.description,
            tau_m,
            cases,
        })
    }

    /// Which cases `patterns` select, one flag per case in suite order. A pattern that is a
    /// case's id selects that case alone (`box-flat-los`, not `cracker_box-flat-los` too); any
    /// other pattern selects every case whose id contains it (`nlos`). The selection is the
    /// union. Refuses a pattern that selects nothing, naming it.
    pub fn selection(&self, patterns: &[String]) -> Result<Vec<bool>, SuiteError> {
        let mut keep = vec![false; self.cases.len()];
        for pattern in patterns {
            let exact = self.cases.iter().any(|c| c.id == *pattern);
            let mut hits = 0;
            for (k, case) in keep.iter_mut().zip(&self.cases) {
                let hit = if exact {
                    case.id == *pattern
                } else {
                    case.id.contains(pattern.as_str())
                };
                if hit {
                    *k = true;
                    hits += 1;
                }
            }
            if hits == 0 {
                return Err(SuiteError::Field {
                    path: self.path.clone(),
                    field: "--only".into(),
                    value: format!("{pattern:?}"),
                    reason: "no case id is or contains it".into(),
                });
            }
        }
        Ok(keep)
    }
}

/// The rotation of a pose.
fn pose_rotation(pose: Pose, rotated_deg: f64) -> Rotation3<f64> {
    match pose {
        Pose::Flat => Rotation3::identity(),
        Pose::Side => Rotation3::from_axis_angle(&Vector3::x_axis(), std::f64::consts::FRAC_PI_2),
        Pose::Rotated => Rotation3::from_axis_angle(&Vector3::z_axis(), rotated_deg.to_radians()),
    }
}

fn as_vec3(c: &Ctx<'_>, field: &str, v: Option<&toml::Value>) -> Result<[f64; 3], SuiteError> {
    let Some(v) = v else {
        return Ok([0.0; 3]);
    };
    let items: Option<Vec<f64>> = v.as_array().map(|a| {
        a.iter()
            .filter_map(|x| x.as_float().or_else(|| x.as_integer().map(|i| i as f64)))
            .collect()
    });
    match items {
        Some(items) if items.len() == 3 && items.iter().all(|x| x.is_finite()) => {
            Ok([items[0], items[1], items[2]])
        }
        _ => Err(c.field(field, v, "needs three finite numbers")),
    }
}

/// The directories relative paths resolve against: the suite's own (radar profile) and the one
/// of the file that lists the scenes (object files).
struct Bases<'a> {
    suite: &'a Path,
    objects: &'a Path,
}

/// Which variant of a scene a case is.
struct CaseOf<'a> {
    pose: Pose,
    condition: Condition,
    physics: &'a str,
}

fn build_case(
    c: &Ctx<'_>,
    file: &SuiteFile,
    base: &Bases<'_>,
    recon: &ReconConfig,
    spec: &SceneSpec,
    how: CaseOf<'_>,
) -> Result<Case, SuiteError> {
    let CaseOf {
        pose,
        condition,
        physics,
    } = how;
    let id = format!(
        "{}-{}-{}{}",
        spec.name,
        pose.name(),
        condition.name(),
        physics_suffix(physics)
    );
    let rotation = pose_rotation(pose, file.poses.rotated_deg);
    // Objects posed about the origin, with their own orientation composed under the pose.
    let mut objects = Vec::new();
    for (k, o) in spec.objects.iter().enumerate() {
        let field = |key: &str| format!("scene.{}.object[{k}].{key}", spec.name);
        if o.contains_key("position_m") {
            return Err(c.field(
                &field("position_m"),
                &o["position_m"],
                "the suite places objects itself; give offset_m = [x, y, z] to arrange a group",
            ));
        }
        let offset = as_vec3(c, &field("offset_m"), o.get("offset_m"))?;
        let own = as_vec3(c, &field("rotation_deg"), o.get("rotation_deg"))?.map(f64::to_radians);
        let r = rotation * Rotation3::from_euler_angles(own[0], own[1], own[2]);
        let (roll, pitch, yaw) = r.euler_angles();
        let at = rotation * Vector3::from(offset);
        let mut table = o.clone();
        table.remove("offset_m");
        table.insert(
            "rotation_deg".into(),
            toml::Value::Array(
                [roll, pitch, yaw]
                    .iter()
                    .map(|a| toml::Value::Float(round_to(a.to_degrees(), 1e-9)))
                    .collect(),
            ),
        );
        objects.push((table, [at.x, at.y, at.z]));
    }
    // Set the group down on the table, centred at the origin: parse once where posed, read the
    // placed bounds, shift.
    let provisional = scene_text(
        c, file, base, &objects, [0.0; 3], None, &id, false, 1e3, physics,
    )?;
    let scene = parse_scene(c, &provisional, &id)?;
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for o in &scene.objects {
        let b = match &o.geometry {
            ObjectGeometry::Surface(m) => m.bounds(),
            ObjectGeometry::Point { position_m, .. } => Some((*position_m, *position_m)),
        };
        if let Some((a, b)) = b {
            for i in 0..3 {
                lo[i] = lo[i].min(a[i]);
                hi[i] = hi[i].max(b[i]);
            }
        }
    }
    if !lo[0].is_finite() {
        return Err(c.field(&format!("scene.{}", spec.name), &id, "has no geometry"));
    }
    let shift = [-(lo[0] + hi[0]) / 2.0, -(lo[1] + hi[1]) / 2.0, -lo[2]];
    let top_m = hi[2] - lo[2];
    let aperture_z_m = top_m + file.aperture.clearance_m;
    let sheet_z_m = (condition == Condition::Nlos).then_some(top_m + file.occluder.gap_m);
    let text = |keyed| {
        scene_text(
            c,
            file,
            base,
            &objects,
            shift,
            sheet_z_m,
            &id,
            keyed,
            aperture_z_m,
            physics,
        )
    };
    let scene_text = text(false)?;
    let keyed_text = text(true)?;
    let scene = parse_scene(c, &scene_text, &id)?;
    let mut recon = recon.clone();
    if let Some(z) = sheet_z_m {
        // Start the echo search past the sheet, as a user does with `inspect --gate`.
        let sheet_range_m = aperture_z_m - z + file.occluder.thickness_m.unwrap_or(0.004) / 2.0;
        let window = &mut recon.auto_volume.range_window_m;
        window[0] = window[0].max(sheet_range_m + file.occluder.gate_margin_m);
        if window[0] >= window[1] {
            return Err(c.field(
                "recon.auto_volume.range_window_m",
                *window,
                "is empty once it starts past the NLOS sheet",
            ));
        }
        if file.occluder.compensate {
            recon.occluder = scene.occluder.map(|o| KnownOccluder {
                thickness_m: o.thickness_m,
                refractive_index: o.refractive_index,
                remove_echo: true,
            });
        }
    }
    Ok(Case {
        id,
        scene_name: spec.name.clone(),
        pose,
        condition,
        physics: physics.to_string(),
        class: spec.class.clone().unwrap_or_default(),
        scene_text,
        keyed_text,
        scene,
        recon,
    })
}

fn round_to(x: f64, step: f64) -> f64 {
    let r = (x / step).round() * step;
    if r == 0.0 { 0.0 } else { r }
}

fn parse_scene(c: &Ctx<'_>, text: &str, id: &str) -> Result<Scene, SuiteError> {
    Scene::parse(text, &c.path.with_file_name(format!("{id}.toml"))).map_err(|source| {
        SuiteError::Scene {
            path: c.path.to_path_buf(),
            case: id.to_string(),
            source: Box::new(source),
        }
    })
}

/// A file path of the suite: absolute, or (`keyed`) the SHA-256 of its contents.
fn file_value(
    c: &Ctx<'_>,
    base: &Path,
    field: &str,
    v: &toml::Value,
    keyed: bool,
) -> Result<toml::Value, SuiteError> {
    let rel = v
        .as_str()
        .ok_or_else(|| c.field(field, v, "must be a path (a string)"))?;
    let full = base.join(rel);
    let full = full
        .canonicalize()
        .map_err(|e| c.field(field, full.display().to_string(), &e.to_string()))?;
    if keyed {
        let sum = file_sha256(&full)
            .map_err(|e| c.field(field, full.display().to_string(), &e.to_string()))?;
        Ok(toml::Value::String(format!("sha256:{sum}")))
    } else {
        Ok(toml::Value::String(full.display().to_string()))
    }
}

/// The scene file of a case.
#[allow(clippy::too_many_arguments)]
fn scene_text(
    c: &Ctx<'_>,
    file: &SuiteFile,
    base: &Bases<'_>,
    objects: &[(toml::Table, [f64; 3])],
    shift: [f64; 3],
    sheet_z_m: Option<f64>,
    id: &str,
    keyed: bool,
    aperture_z_m: f64,
    physics: &str,
) -> Result<String, SuiteError> {
    let mut doc = toml::Table::new();
    doc.insert(
        "description".into(),
        toml::Value::String(format!("accuracy suite case {id}")),
    );
    let mut radar = file.radar.clone();
    if let Some(p) = radar.get("profile").cloned() {
        radar.insert(
            "profile".into(),
            file_value(c, base.suite, "radar.profile", &p, keyed)?,
        );
    }
    doc.insert("radar".into(), toml::Value::Table(radar));
    let a = &file.aperture;
    let mut ap = toml::Table::new();
    ap.insert("width_m".into(), a.width_m.into());
    ap.insert("height_m".into(), a.height_m.into());
    if let Some(s) = a.spacing_m {
        ap.insert("spacing_m".into(), s.into());
    }
    ap.insert("z_m".into(), round_to(aperture_z_m, 1e-9).into());
    for (key, v) in [
        ("layout", &a.layout),
        ("rx_axis", &a.rx_axis),
        ("antenna_pattern", &a.antenna_pattern),
    ] {
        if let Some(v) = v {
            ap.insert(key.into(), v.clone().into());
        }
    }
    doc.insert("aperture".into(), toml::Value::Table(ap));
    if let Some(n) = &file.noise {
        let mut t = toml::Table::new();
        t.insert("snr_db".into(), n.snr_db.into());
        // Each case draws its own noise, the same on every run.
        let seed = file.seed.wrapping_add(fnv1a(id)) >> 1;
        t.insert("seed".into(), toml::Value::Integer(seed as i64));
        doc.insert("noise".into(), toml::Value::Table(t));
    }
    if let Some(z) = sheet_z_m {
        let o = &file.occluder;
        let mut t = toml::Table::new();
        t.insert("z_m".into(), round_to(z, 1e-9).into());
        for (key, v) in [
            ("thickness_m", o.thickness_m),
            ("refractive_index", o.refractive_index),
            ("loss_db", o.loss_db),
        ] {
            if let Some(v) = v {
                t.insert(key.into(), v.into());
            }
        }
        let size = [
            a.width_m + 2.0 * o.overhang_m,
            a.height_m + 2.0 * o.overhang_m,
        ];
        t.insert(
            "size_m".into(),
            toml::Value::Array(size.iter().map(|&s| s.into()).collect()),
        );
        doc.insert("occluder".into(), toml::Value::Table(t));
    }
    if physics != PHYSICAL_OPTICS {
        let mut t = toml::Table::new();
        t.insert("model".into(), physics.into());
        doc.insert("physics".into(), toml::Value::Table(t));
    }
    let mut list = Vec::new();
    for (k, (table, at)) in objects.iter().enumerate() {
        let mut t = table.clone();
        if let Some(p) = t.get("path").cloned() {
            t.insert(
                "path".into(),
                file_value(c, base.objects, &format!("object[{k}].path"), &p, keyed)?,
            );
        }
        let position: Vec<toml::Value> = (0..3)
            .map(|i| toml::Value::Float(round_to(at[i] + shift[i], 1e-9)))
            .collect();
        t.insert("position_m".into(), toml::Value::Array(position));
        list.push(toml::Value::Table(t));
    }
    doc.insert("object".into(), toml::Value::Array(list));
    toml::to_string(&doc).map_err(|e| c.field("scene", id, &e.to_string()))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn suite_text(extra: &str) -> String {
        format!(
            r#"
seed = 5
[radar]
profile = "../../firmware_cfg/iwr1443_mmnorm.cfg"
[aperture]
width_m = 0.05
height_m = 0.05
spacing_m = 0.004
clearance_m = 0.35
[noise]
snr_db = 20.0
[occluder]
gap_m = 0.10
thickness_m = 0.004
gate_margin_m = 0.07
{extra}
"#
        )
    }

    fn path() -> PathBuf {
        Path::new(env!("CARGO_MANIFEST_DIR")).join("tools/bench/unit.toml")
    }

    fn bounds(scene: &Scene) -> ([f64; 3], [f64; 3]) {
        let mut lo = [f64::INFINITY; 3];
        let mut hi = [f64::NEG_INFINITY; 3];
        for o in &scene.objects {
            if let ObjectGeometry::Surface(m) = &o.geometry
                && let Some((a, b)) = m.bounds()
            {
                for i in 0..3 {
                    lo[i] = lo[i].min(a[i]);
                    hi[i] = hi[i].max(b[i]);
                }
            }
        }
        (lo, hi)
    }

    #[test]
    fn poses_rest_on_the_table_under_the_aperture_and_nlos_puts_the_sheet_between() {
        let text = suite_text(
            r#"
[[scene]]
name = "box"
poses = ["flat", "side", "rotated"]
[[scene.object]]
shape = "box"
size_m = [0.10, 0.06, 0.04]
"#,
        );
        let suite = Suite::parse(&text, &path()).expect("suite");
        let ids: Vec<&str> = suite.cases.iter().map(|c| c.id.as_str()).collect();
        assert_eq!(
            ids,
            [
                "box-flat-los",
                "box-flat-nlos",
                "box-side-los",
                "box-side-nlos",
                "box-rotated-los",
                "box-rotated-nlos"
            ]
        );
        for c in &suite.cases {
            let (lo, hi) = bounds(&c.scene);
            let height = match c.pose {
                Pose::Side => 0.06,
                _ => 0.04,
            };
            assert!(lo[2].abs() < 1e-9, "{}: {lo:?}", c.id);
            assert!((hi[2] - height).abs() < 1e-9, "{}: {hi:?}", c.id);
            assert!((lo[0] + hi[0]).abs() < 1e-9 && (lo[1] + hi[1]).abs() < 1e-9);
            assert!((c.scene.aperture.z_m - (height + 0.35)).abs() < 1e-9);
            if c.pose == Pose::Rotated {
                // A 10 × 6 cm footprint turned 30° spans 10·cos30 + 6·sin30 in x.
                let want = 0.10 * 30f64.to_radians().cos() + 0.06 * 30f64.to_radians().sin();
                assert!((hi[0] - lo[0] - want).abs() < 1e-6, "{}", hi[0] - lo[0]);
            }
            match c.condition {
                Condition::Los => {
                    assert!(c.scene.occluder.is_none());
                    assert_eq!(
                        c.recon.auto_volume.range_window_m,
                        ReconConfig::default().auto_volume.range_window_m
                    );
                }
                Condition::Nlos => {
                    let o = c.scene.occluder.expect("sheet");
                    assert!((o.z_m - (height + 0.10)).abs() < 1e-9);
                    // The echo search starts 7 cm past the sheet's far face, before the object.
                    let start = c.recon.auto_volume.range_window_m[0];
                    assert!(
                        (start - (0.35 - 0.10 + 0.002 + 0.07)).abs() < 1e-9,
                        "{start}"
                    );
                    assert!(start < 0.35);
                }
            }
            // Noise seeds differ per case and the cache key does not depend on where files are.
            assert!(!c.keyed_text.contains("firmware_cfg"));
            assert!(c.keyed_text.contains("sha256:"));
            assert!(c.scene_text.contains("firmware_cfg"));
        }
        let seeds: std::collections::HashSet<u64> = suite
            .cases
            .iter()
            .filter_map(|c| c.scene.noise.map(|n| n.1))
            .collect();
        assert_eq!(seeds.len(), suite.cases.len());
        // The same suite parsed again gives the same scenes.
        let again = Suite::parse(&text, &path()).expect("suite");
        assert_eq!(again.cases[3].keyed_text, suite.cases[3].keyed_text);
    }

    #[test]
    fn a_group_keeps_its_arrangement_and_turns_as_one() {
        let text = "conditions = [\"los\"]\n".to_string()
            + &suite_text(
                r#"
[[scene]]
name = "pair"
poses = ["flat", "rotated"]
[[scene.object]]
shape = "sphere"
radius_m = 0.01
offset_m = [0.05, 0.0, 0.0]
[[scene.object]]
shape = "sphere"
radius_m = 0.01
offset_m = [-0.05, 0.0, 0.0]
"#,
            );
        let suite = Suite::parse(&text, &path()).expect("suite");
        assert_eq!(suite.cases.len(), 2);
        let centres = |c: &Case| -> Vec<[f64; 3]> {
            c.scene
                .objects
                .iter()
                .filter_map(|o| match &o.geometry {
                    ObjectGeometry::Surface(m) => m.bounds().map(|(a, b)| {
                        [
                            (a[0] + b[0]) / 2.0,
                            (a[1] + b[1]) / 2.0,
                            (a[2] + b[2]) / 2.0,
                        ]
                    }),
                    ObjectGeometry::Point { .. } => None,
                })
                .collect()
        };
        let flat = centres(&suite.cases[0]);
        let turned = centres(&suite.cases[1]);
        let d = |p: &[[f64; 3]]| ((p[0][0] - p[1][0]).powi(2) + (p[0][1] - p[1][1]).powi(2)).sqrt();
        assert!((d(&flat) - 0.10).abs() < 1e-3 && (d(&turned) - 0.10).abs() < 1e-3);
        let angle = (turned[0][1] - turned[1][1]).atan2(turned[0][0] - turned[1][0]);
        assert!(
            (angle.to_degrees() - 30.0).abs() < 1.0,
            "{}",
            angle.to_degrees()
        );
    }

    #[test]
    fn an_exact_id_selects_one_case_and_other_text_selects_every_case_containing_it() {
        let scene = |name: &str| {
            format!(
                "[[scene]]\nname = \"{name}\"\nposes = [\"flat\", \"side\"]\n[[scene.object]]\nshape = \"sphere\"\nradius_m = 0.02\n"
            )
        };
        let text = suite_text(&format!("{}{}", scene("box"), scene("sugar_box")));
        let suite = Suite::parse(&text, &path()).expect("suite");
        let ids = |patterns: &[&str]| -> Result<Vec<String>, SuiteError> {
            let patterns: Vec<String> = patterns.iter().map(|p| p.to_string()).collect();
            let flags = suite.selection(&patterns)?;
            assert_eq!(flags.len(), suite.cases.len());
            Ok(suite
                .cases
                .iter()
                .zip(flags)
                .filter(|(_, f)| *f)
                .map(|(c, _)| c.id.clone())
                .collect())
        };
        assert_eq!(ids(&["box-flat-los"]).expect("exact"), ["box-flat-los"]);
        assert_eq!(
            ids(&["box-flat"]).expect("substring"),
            [
                "box-flat-los",
                "box-flat-nlos",
                "sugar_box-flat-los",
                "sugar_box-flat-nlos"
            ]
        );
        assert_eq!(
            ids(&["sugar_box-side-nlos", "box-flat-los"]).expect("union, in suite order"),
            ["box-flat-los", "sugar_box-side-nlos"]
        );
        let e = ids(&["nlos", "cube"])
            .expect_err("cube selects nothing")
            .to_string();
        assert!(e.contains("--only") && e.contains("\"cube\""), "{e}");
    }

    #[test]
    fn each_physics_model_gets_its_own_cases_and_scene_table() {
        let object = "[[scene]]\nname = \"s\"\nclass = \"hollow\"\nposes = [\"flat\"]\n[[scene.object]]\nshape = \"sphere\"\nradius_m = 0.02\n";
        let text = format!(
            "physics = [\"physical-optics\", \"point-scatterer\"]\nconditions = [\"los\"]\n{}",
            suite_text(object)
        );
        let suite = Suite::parse(&text, &path()).unwrap();
        let ids: Vec<&str> = suite.cases.iter().map(|c| c.id.as_str()).collect();
        assert_eq!(ids, ["s-flat-los", "s-flat-los-point"]);
        let [po, ps] = [&suite.cases[0], &suite.cases[1]];
        assert_eq!(po.scene.physics.name(), "physical-optics");
        assert_eq!(ps.scene.physics.name(), "point-scatterer");
        assert!(!po.scene_text.contains("[physics]"));
        assert!(ps.keyed_text.contains("[physics]"), "{}", ps.keyed_text);
        assert_ne!(
            po.keyed_text, ps.keyed_text,
            "the two share a capture cache key"
        );
        assert!(suite.cases.iter().all(|c| c.class == "hollow"));
        // Without a list, physical optics alone, and the ids are those of earlier runs.
        let suite = Suite::parse(&suite_text(object), &path()).unwrap();
        let ids: Vec<&str> = suite.cases.iter().map(|c| c.id.as_str()).collect();
        assert_eq!(ids, ["s-flat-los", "s-flat-nlos"]);
    }

    #[test]
    fn refusals_name_the_field_and_the_value() {
        let object = "[[scene]]\nname = \"s\"\nposes = [\"flat\"]\n[[scene.object]]\nshape = \"sphere\"\nradius_m = 0.02\n";
        let cases = [
            (
                suite_text(&format!("{object}position_m = [0.0, 0.0, 0.0]\n")),
                "position_m",
            ),
            (
                suite_text(object).replace("gap_m = 0.10", "gap_m = 0.5"),
                "occluder.gap_m",
            ),
            (
                suite_text(&object.replace("\"s\"", "\"Bad Name\"")),
                "scene[0].name",
            ),
            (suite_text(&format!("{object}{object}")), "is used twice"),
            (
                suite_text(&object.replace("radius_m = 0.02", "radius_m = -1.0")),
                "radius_m",
            ),
            (
                suite_text(&format!("[recon]\nvoxel_m = 0.0\n{object}")),
                "voxel_m",
            ),
            (
                suite_text(&object.replace("\"flat\"", "\"upside\"")),
                "upside",
            ),
            (
                format!("physics = [\"ray-tracing\"]\n{}", suite_text(object)),
                "physics[0]",
            ),
            (
                format!(
                    "physics = [\"point-scatterer\", \"point-scatterer\"]\n{}",
                    suite_text(object)
                ),
                "listed twice",
            ),
            (
                suite_text(&object.replace("poses", "class = \"Hollow\"\nposes")),
                "scene[0].class",
            ),
        ];
        for (text, want) in cases {
            let e = Suite::parse(&text, &path()).expect_err(want).to_string();
            assert!(e.contains(want), "{want}: {e}");
        }
    }
}
