//! The scene file (TOML): objects, an optional cardboard occluder, the aperture, the radar and
//! the noise. [`Scene::load`] parses, checks every field (errors name the field and the value)
//! and resolves paths relative to the scene file's directory.

use std::path::{Path, PathBuf};

use serde::Deserialize;

use crate::capture::FrequencyPlan;
use crate::geometry::{self, MeshError, TriMesh};
use crate::radar::{ProfileError, RadarProfile};

/// Wall thickness of a `cup` or `bowl` without `wall_m`: a ceramic mug's is 3–5 mm.
const DEFAULT_WALL_M: f64 = 0.004;

/// The TI IWR1443's internal round-trip offset that mmNorm's code adds (docs/mmnorm-reference.md §1).
pub const DEFAULT_RANGE_OFFSET_M: f64 = 0.15;

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct SceneFile {
    #[serde(default)]
    description: String,
    radar: RadarSpec,
    aperture: ApertureSpec,
    noise: Option<NoiseSpec>,
    occluder: Option<OccluderSpec>,
    #[serde(default)]
    simulation: SimulationSpec,
    #[serde(default)]
    physics: PhysicsSpec,
    #[serde(default, rename = "object")]
    objects: Vec<ObjectSpec>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RadarSpec {
    profile: Option<PathBuf>,
    start_frequency_hz: Option<f64>,
    frequency_step_hz: Option<f64>,
    samples_per_chirp: Option<usize>,
    range_offset_m: Option<f64>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct ApertureSpec {
    width_m: f64,
    height_m: f64,
    spacing_m: Option<f64>,
    z_m: f64,
    #[serde(default)]
    center_m: [f64; 2],
    #[serde(default)]
    layout: Layout,
    #[serde(default)]
    rx_axis: Axis,
    antenna_pattern: Option<PatternKind>,
}

/// Transmit/receive geometry of each raster position.
#[derive(Debug, Clone, Copy, Default, PartialEq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Layout {
    /// TX and RX at the same point: one virtual antenna per position.
    #[default]
    Monostatic,
    /// The IWR1443BOOST: TX plus four RX at −(5 mm + (3−k)·λ0/2) along `rx_axis`.
    Iwr1443boost,
}

/// The board axis along which the RX array lies.
#[derive(Debug, Clone, Copy, Default, PartialEq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Axis {
    #[default]
    X,
    Y,
}

/// The antenna gain pattern.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum PatternKind {
    Isotropic,
    /// 6 dB beamwidths of 100° along the RX array axis and 40° across it (paper §5).
    Iwr1443boost,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct NoiseSpec {
    snr_db: f64,
    #[serde(default)]
    seed: u64,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct OccluderSpec {
    z_m: f64,
    #[serde(default = "default_thickness")]
    thickness_m: f64,
    #[serde(default = "default_index")]
    refractive_index: f64,
    #[serde(default = "default_loss")]
    loss_db: f64,
    size_m: Option<[f64; 2]>,
    #[serde(default)]
    center_m: [f64; 2],
}

fn default_thickness() -> f64 {
    0.004
}
fn default_index() -> f64 {
    1.6
}
fn default_loss() -> f64 {
    1.0
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct SimulationSpec {
    #[serde(default = "default_full")]
    specular_full_zones: f64,
    #[serde(default = "default_cutoff")]
    specular_cutoff_zones: f64,
    #[serde(default = "default_crease")]
    crease_angle_deg: f64,
    sample_spacing_m: Option<f64>,
    diffuse_spacing_m: Option<f64>,
    #[serde(default = "default_tessellation")]
    tessellation_m: f64,
}

impl Default for SimulationSpec {
    fn default() -> Self {
        SimulationSpec {
            specular_full_zones: default_full(),
            specular_cutoff_zones: default_cutoff(),
            crease_angle_deg: default_crease(),
            sample_spacing_m: None,
            diffuse_spacing_m: None,
            tessellation_m: default_tessellation(),
        }
    }
}

fn default_full() -> f64 {
    1.5
}
fn default_cutoff() -> f64 {
    3.0
}
fn default_crease() -> f64 {
    30.0
}
fn default_tessellation() -> f64 {
    0.0025
}

#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct PhysicsSpec {
    model: Option<String>,
    specular_cone_deg: Option<f64>,
    surface_spacing_m: Option<f64>,
    edge_spacing_m: Option<f64>,
    edge_dihedral_deg: Option<f64>,
    edge_strength: Option<f64>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct ObjectSpec {
    shape: String,
    name: Option<String>,
    #[serde(default)]
    position_m: [f64; 3],
    #[serde(default)]
    rotation_deg: [f64; 3],
    path: Option<PathBuf>,
    scale: Option<f64>,
    recenter: Option<bool>,
    size_m: Option<Vec<f64>>,
    radius_m: Option<f64>,
    length_m: Option<f64>,
    wall_m: Option<f64>,
    rcs_m2: Option<f64>,
    reflectivity: Option<f64>,
    diffuse: Option<f64>,
    diffuse_exponent: Option<f64>,
    edge: Option<f64>,
}

/// How a surface scatters (per object).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Material {
    /// Specular (physical-optics) reflection coefficient magnitude; 1 for a metal.
    pub reflectivity: f64,
    /// Diffuse scattering coefficient S of the directive model (fraction of reflected field
    /// amplitude scattered diffusely).
    pub diffuse: f64,
    /// Exponent α of the directive lobe ((1 + cos ψ)/2)^α.
    pub diffuse_exponent: f64,
    /// Scale of the edge-diffraction term; 1 gives a half-plane's broadside RCS L²/π.
    pub edge: f64,
}

impl Default for Material {
    fn default() -> Self {
        Material {
            reflectivity: 1.0,
            diffuse: 0.1,
            diffuse_exponent: 4.0,
            edge: 1.0,
        }
    }
}

/// What an object is, placed in the scene frame.
#[derive(Debug, Clone)]
pub enum ObjectGeometry {
    Surface(TriMesh),
    /// An ideal point scatterer (a calibration target) of the given RCS.
    Point {
        position_m: [f64; 3],
        rcs_m2: f64,
    },
}

/// One object of the scene.
#[derive(Debug, Clone)]
pub struct SceneObject {
    pub name: String,
    pub geometry: ObjectGeometry,
    pub material: Material,
}

/// The cardboard sheet between the aperture and the objects.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Occluder {
    pub z_m: f64,
    pub thickness_m: f64,
    pub refractive_index: f64,
    /// One-way amplitude loss at normal incidence, dB.
    pub loss_db: f64,
    /// Extent in x and y (None: infinite), centred on `center_m`.
    pub size_m: Option<[f64; 2]>,
    pub center_m: [f64; 2],
}

/// The raster aperture.
#[derive(Debug, Clone, PartialEq)]
pub struct ApertureGrid {
    pub width_m: f64,
    pub height_m: f64,
    pub spacing_m: f64,
    pub z_m: f64,
    pub center_m: [f64; 2],
    pub layout: Layout,
    pub rx_axis: Axis,
    pub pattern: PatternKind,
}

impl ApertureGrid {
    /// Raster positions along x and along y.
    pub fn raster_size(&self) -> (usize, usize) {
        let count = |len: f64| ((len / self.spacing_m + 1e-9).floor() as usize).saturating_add(1);
        (count(self.width_m), count(self.height_m))
    }
}

/// Numerical settings of the simulator.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SimSettings {
    /// The specular window is 1 up to this many Fresnel zones from the mirror point...
    pub specular_full_zones: f64,
    /// ...and falls to 0 (raised cosine) at this many.
    pub specular_cutoff_zones: f64,
    pub crease_angle_deg: f64,
    pub sample_spacing_m: f64,
    pub diffuse_spacing_m: f64,
    pub tessellation_m: f64,
}

/// Which physics turns the scene's surfaces into echoes (`[physics] model`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Physics {
    /// `"physical-optics"` (the default): coherent PO surface integral, directive diffuse
    /// scattering and edge diffraction ([`super::forward`]).
    PhysicalOptics,
    /// `"point-scatterer"`: an independent, simpler model ([`PointScatterer`]).
    PointScatterer(PointScatterer),
}

impl Physics {
    /// Every model's name, as the scene file gives it, the default first.
    pub const MODELS: [&'static str; 2] = ["physical-optics", "point-scatterer"];

    /// The name the scene file uses.
    pub fn name(&self) -> &'static str {
        match self {
            Physics::PhysicalOptics => Physics::MODELS[0],
            Physics::PointScatterer(_) => Physics::MODELS[1],
        }
    }
}

/// The point-scatterer model: the kind of simulator the mmNorm authors used, written here from
/// its description only. Surfaces become samples at `surface_spacing_m` that reflect only where
/// the bisector of their two legs lies within `specular_cone_deg` of their face normal; sharp
/// edges (dihedral above `edge_dihedral_deg`, or a free rim) become samples at `edge_spacing_m`
/// that radiate to every antenna that sees them. Every sample's amplitude falls as 1/d of its
/// round trip d; there is no antenna pattern, no diffuse term and no obliquity factor.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PointScatterer {
    pub specular_cone_deg: f64,
    pub surface_spacing_m: f64,
    pub edge_spacing_m: f64,
    pub edge_dihedral_deg: f64,
    /// An edge sample's strength relative to a surface sample (1: equal points).
    pub edge_strength: f64,
}

impl Default for PointScatterer {
    fn default() -> Self {
        PointScatterer {
            specular_cone_deg: 5.0,
            surface_spacing_m: 0.0015,
            edge_spacing_m: 0.001,
            edge_dihedral_deg: 20.0,
            edge_strength: 1.0,
        }
    }
}

/// A loaded and validated scene.
#[derive(Debug, Clone)]
pub struct Scene {
    pub source: PathBuf,
    pub description: String,
    pub plan: FrequencyPlan,
    pub range_offset_m: f64,
    /// The radar profile the plan came from, if any.
    pub profile: Option<RadarProfile>,
    pub aperture: ApertureGrid,
    pub objects: Vec<SceneObject>,
    pub occluder: Option<Occluder>,
    /// (SNR in dB, seed) when noise is added: the objects' mean echo power without the sheet
    /// over the noise power per sample ([`super::ForwardModel::noise_sigma`]).
    pub noise: Option<(f64, u64)>,
    /// Seed of the surface roughness phases (the noise seed, or 0).
    pub seed: u64,
    pub settings: SimSettings,
    pub physics: Physics,
}

/// Why a scene was refused.
#[derive(Debug, thiserror::Error)]
pub enum SceneError {
    #[error("cannot read scene {path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("scene {path}: {message}")]
    Syntax { path: PathBuf, message: String },
    #[error("scene {path}: `{field}` = {value}: {reason}")]
    Field {
        path: PathBuf,
        field: String,
        value: String,
        reason: String,
    },
    #[error("scene {path}: radar profile: {source}")]
    Profile {
        path: PathBuf,
        #[source]
        source: ProfileError,
    },
    #[error("scene {path}: {source}")]
    Mesh {
        path: PathBuf,
        #[source]
        source: MeshError,
    },
}

struct Checker<'a> {
    path: &'a Path,
}

impl Checker<'_> {
    fn fail(&self, field: &str, value: impl std::fmt::Debug, reason: &str) -> SceneError {
        SceneError::Field {
            path: self.path.to_path_buf(),
            field: field.to_string(),
            value: format!("{value:?}"),
            reason: reason.to_string(),
        }
    }

    fn finite(&self, field: &str, v: f64) -> Result<f64, SceneError> {
        if v.is_finite() {
            Ok(v)
        } else {
            Err(self.fail(field, v, "must be a finite number"))
        }
    }

    fn positive(&self, field: &str, v: f64) -> Result<f64, SceneError> {
        if v.is_finite() && v > 0.0 {
            Ok(v)
        } else {
            Err(self.fail(field, v, "must be a positive number"))
        }
    }

    fn non_negative(&self, field: &str, v: f64) -> Result<f64, SceneError> {
        if v.is_finite() && v >= 0.0 {
            Ok(v)
        } else {
            Err(self.fail(field, v, "must be zero or positive"))
        }
    }

    fn vec(&self, field: &str, v: &[f64]) -> Result<(), SceneError> {
        if v.iter().all(|c| c.is_finite()) {
            Ok(())
        } else {
            Err(self.fail(field, v, "every component must be finite"))
        }
    }
}

impl Scene {
    /// The RX channels a scan records: the profile's, or all four without one.
    pub fn rx_channels(&self) -> Vec<u8> {
        self.profile
            .as_ref()
            .map_or_else(|| vec![0, 1, 2, 3], |p| p.rx_channels.clone())
    }

    /// Channels of the simulated scan: raster positions times the channels per position.
    pub fn channels(&self) -> usize {
        let (columns, rows) = self.aperture.raster_size();
        let per_position = match self.aperture.layout {
            Layout::Monostatic => 1,
            Layout::Iwr1443boost => self.rx_channels().len(),
        };
        columns * rows * per_position
    }

    /// Loads and validates a scene file; meshes are loaded and placed.
    pub fn load(path: &Path) -> Result<Scene, SceneError> {
        let text = std::fs::read_to_string(path).map_err(|source| SceneError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        Scene::parse(&text, path)
    }

    /// Parses scene text; relative paths resolve against `path`'s directory.
    pub fn parse(text: &str, path: &Path) -> Result<Scene, SceneError> {
        let file: SceneFile = toml::from_str(text).map_err(|e| SceneError::Syntax {
            path: path.to_path_buf(),
            message: e.to_string(),
        })?;
        let base = path.parent().unwrap_or(Path::new(".")).to_path_buf();
        let c = Checker { path };

        let (plan, profile) = resolve_radar(&c, &file.radar, &base)?;
        let range_offset_m = c.finite(
            "radar.range_offset_m",
            file.radar.range_offset_m.unwrap_or(DEFAULT_RANGE_OFFSET_M),
        )?;
        let lambda0_m = plan.first_wavelength_m();

        let s = &file.simulation;
        let full = c.non_negative("simulation.specular_full_zones", s.specular_full_zones)?;
        let cutoff = c.positive("simulation.specular_cutoff_zones", s.specular_cutoff_zones)?;
        if cutoff <= full {
            return Err(c.fail(
                "simulation.specular_cutoff_zones",
                cutoff,
                "must be larger than specular_full_zones",
            ));
        }
        let sample_spacing_m = c.positive(
            "simulation.sample_spacing_m",
            s.sample_spacing_m.unwrap_or(lambda0_m / 4.0),
        )?;
        if sample_spacing_m > lambda0_m / 4.0 * (1.0 + 1e-9) {
            return Err(c.fail(
                "simulation.sample_spacing_m",
                sample_spacing_m,
                &format!("must be at most λ0/4 = {:.6} m", lambda0_m / 4.0),
            ));
        }
        let settings = SimSettings {
            specular_full_zones: full,
            specular_cutoff_zones: cutoff,
            crease_angle_deg: c.positive("simulation.crease_angle_deg", s.crease_angle_deg)?,
            sample_spacing_m,
            diffuse_spacing_m: c.positive(
                "simulation.diffuse_spacing_m",
                s.diffuse_spacing_m.unwrap_or(lambda0_m),
            )?,
            tessellation_m: c.positive("simulation.tessellation_m", s.tessellation_m)?,
        };

        let physics = resolve_physics(&c, &file.physics)?;
        let aperture = resolve_aperture(&c, &file.aperture, lambda0_m)?;
        let noise = match &file.noise {
            Some(n) => Some((c.finite("noise.snr_db", n.snr_db)?, n.seed)),
            None => None,
        };
        let occluder = match &file.occluder {
            Some(o) => Some(resolve_occluder(&c, o, aperture.z_m)?),
            None => None,
        };
        if file.objects.is_empty() {
            return Err(c.fail("object", "[]", "a scene needs at least one [[object]]"));
        }
        let objects = file
            .objects
            .iter()
            .enumerate()
            .map(|(i, o)| resolve_object(&c, i, o, &base, settings.tessellation_m))
            .collect::<Result<Vec<_>, _>>()?;
        for (i, o) in objects.iter().enumerate() {
            let top = match &o.geometry {
                ObjectGeometry::Surface(m) => m.bounds().map_or(f64::NEG_INFINITY, |b| b.1[2]),
                ObjectGeometry::Point { position_m, .. } => position_m[2],
            };
            if top >= aperture.z_m {
                return Err(c.fail(
                    &format!("object[{i}]"),
                    top,
                    &format!(
                        "reaches z = {top:.4} m, at or above the aperture plane z_m = {}",
                        aperture.z_m
                    ),
                ));
            }
        }
        Ok(Scene {
            source: path.to_path_buf(),
            description: file.description,
            plan,
            range_offset_m,
            profile,
            aperture,
            objects,
            occluder,
            seed: noise.map_or(0, |n| n.1),
            noise,
            settings,
            physics,
        })
    }
}

fn resolve_physics(c: &Checker<'_>, p: &PhysicsSpec) -> Result<Physics, SceneError> {
    let model = p.model.as_deref().unwrap_or("physical-optics");
    match model {
        "physical-optics" => {
            let given = [
                ("specular_cone_deg", p.specular_cone_deg),
                ("surface_spacing_m", p.surface_spacing_m),
                ("edge_spacing_m", p.edge_spacing_m),
                ("edge_dihedral_deg", p.edge_dihedral_deg),
                ("edge_strength", p.edge_strength),
            ];
            if let Some((field, Some(v))) = given.iter().find(|(_, v)| v.is_some()) {
                return Err(c.fail(
                    &format!("physics.{field}"),
                    v,
                    "belongs to model = \"point-scatterer\"; the physical-optics model is set in [simulation]",
                ));
            }
            Ok(Physics::PhysicalOptics)
        }
        "point-scatterer" => {
            let d = PointScatterer::default();
            let cone = c.positive(
                "physics.specular_cone_deg",
                p.specular_cone_deg.unwrap_or(d.specular_cone_deg),
            )?;
            if cone >= 90.0 {
                return Err(c.fail("physics.specular_cone_deg", cone, "must be below 90°"));
            }
            let dihedral = c.positive(
                "physics.edge_dihedral_deg",
                p.edge_dihedral_deg.unwrap_or(d.edge_dihedral_deg),
            )?;
            if dihedral >= 180.0 {
                return Err(c.fail("physics.edge_dihedral_deg", dihedral, "must be below 180°"));
            }
            Ok(Physics::PointScatterer(PointScatterer {
                specular_cone_deg: cone,
                surface_spacing_m: c.positive(
                    "physics.surface_spacing_m",
                    p.surface_spacing_m.unwrap_or(d.surface_spacing_m),
                )?,
                edge_spacing_m: c.positive(
                    "physics.edge_spacing_m",
                    p.edge_spacing_m.unwrap_or(d.edge_spacing_m),
                )?,
                edge_dihedral_deg: dihedral,
                edge_strength: c.non_negative(
                    "physics.edge_strength",
                    p.edge_strength.unwrap_or(d.edge_strength),
                )?,
            }))
        }
        other => Err(c.fail(
            "physics.model",
            other,
            "must be \"physical-optics\" or \"point-scatterer\"",
        )),
    }
}

fn resolve_radar(
    c: &Checker<'_>,
    r: &RadarSpec,
    base: &Path,
) -> Result<(FrequencyPlan, Option<RadarProfile>), SceneError> {
    let explicit = [
        r.start_frequency_hz.is_some(),
        r.frequency_step_hz.is_some(),
        r.samples_per_chirp.is_some(),
    ];
    match (&r.profile, explicit) {
        (Some(p), [false, false, false]) => {
            let profile =
                RadarProfile::from_cfg_file(&base.join(p)).map_err(|source| SceneError::Profile {
                    path: c.path.to_path_buf(),
                    source,
                })?;
            Ok((profile.frequency_plan(), Some(profile)))
        }
        (None, [true, true, true]) => {
            let plan = FrequencyPlan {
                start_frequency_hz: c.positive(
                    "radar.start_frequency_hz",
                    r.start_frequency_hz.unwrap_or(0.0),
                )?,
                frequency_step_hz: c
                    .finite("radar.frequency_step_hz", r.frequency_step_hz.unwrap_or(0.0))?,
                samples_per_chirp: r.samples_per_chirp.unwrap_or(0),
            };
            plan.validate()
                .map_err(|reason| c.fail("radar", plan, &reason))?;
            Ok((plan, None))
        }
        _ => Err(c.fail(
            "radar",
            r,
            "give either `profile` or all of start_frequency_hz, frequency_step_hz and samples_per_chirp",
        )),
    }
}

fn resolve_aperture(
    c: &Checker<'_>,
    a: &ApertureSpec,
    lambda0_m: f64,
) -> Result<ApertureGrid, SceneError> {
    let width_m = c.non_negative("aperture.width_m", a.width_m)?;
    let height_m = c.non_negative("aperture.height_m", a.height_m)?;
    let spacing_m = c.positive("aperture.spacing_m", a.spacing_m.unwrap_or(lambda0_m / 4.0))?;
    c.vec("aperture.center_m", &a.center_m)?;
    let grid = ApertureGrid {
        width_m,
        height_m,
        spacing_m,
        z_m: c.finite("aperture.z_m", a.z_m)?,
        center_m: a.center_m,
        layout: a.layout,
        rx_axis: a.rx_axis,
        pattern: a.antenna_pattern.unwrap_or(match a.layout {
            Layout::Monostatic => PatternKind::Isotropic,
            Layout::Iwr1443boost => PatternKind::Iwr1443boost,
        }),
    };
    // Float-to-int casts saturate, so an absurd spacing cannot overflow here.
    let (columns, rows) = grid.raster_size();
    let positions = columns.saturating_mul(rows);
    if positions > 5_000_000 {
        return Err(c.fail(
            "aperture.spacing_m",
            spacing_m,
            &format!("gives {positions} positions; at most 5 000 000 are supported"),
        ));
    }
    Ok(grid)
}

fn resolve_occluder(
    c: &Checker<'_>,
    o: &OccluderSpec,
    aperture_z_m: f64,
) -> Result<Occluder, SceneError> {
    let z_m = c.finite("occluder.z_m", o.z_m)?;
    if z_m >= aperture_z_m {
        return Err(c.fail("occluder.z_m", z_m, "must lie below the aperture plane"));
    }
    if let Some(s) = o.size_m {
        c.positive("occluder.size_m[0]", s[0])?;
        c.positive("occluder.size_m[1]", s[1])?;
    }
    c.vec("occluder.center_m", &o.center_m)?;
    let n = c.positive("occluder.refractive_index", o.refractive_index)?;
    if n < 1.0 {
        return Err(c.fail("occluder.refractive_index", n, "must be at least 1"));
    }
    Ok(Occluder {
        z_m,
        thickness_m: c.non_negative("occluder.thickness_m", o.thickness_m)?,
        refractive_index: n,
        loss_db: c.non_negative("occluder.loss_db", o.loss_db)?,
        size_m: o.size_m,
        center_m: o.center_m,
    })
}

fn resolve_object(
    c: &Checker<'_>,
    i: usize,
    o: &ObjectSpec,
    base: &Path,
    tessellation_m: f64,
) -> Result<SceneObject, SceneError> {
    let field = |name: &str| format!("object[{i}].{name}");
    c.vec(&field("position_m"), &o.position_m)?;
    c.vec(&field("rotation_deg"), &o.rotation_deg)?;
    let d = Material::default();
    let material = Material {
        reflectivity: c.non_negative(
            &field("reflectivity"),
            o.reflectivity.unwrap_or(d.reflectivity),
        )?,
        diffuse: c.non_negative(&field("diffuse"), o.diffuse.unwrap_or(d.diffuse))?,
        diffuse_exponent: c.non_negative(
            &field("diffuse_exponent"),
            o.diffuse_exponent.unwrap_or(d.diffuse_exponent),
        )?,
        edge: c.non_negative(&field("edge"), o.edge.unwrap_or(d.edge))?,
    };
    // Which optional keys each shape takes.
    let allowed: &[&str] = match o.shape.as_str() {
        "plate" | "box" => &["size_m"],
        "sphere" => &["radius_m"],
        "cylinder" | "bottle" => &["radius_m", "length_m"],
        "cup" => &["radius_m", "length_m", "wall_m"],
        "bowl" => &["radius_m", "wall_m"],
        "mesh" => &["path", "scale", "recenter"],
        "point" => &["rcs_m2"],
        other => {
            return Err(c.fail(
                &field("shape"),
                other,
                "must be one of plate, box, sphere, cylinder, bottle, cup, bowl, mesh, point",
            ));
        }
    };
    let shown = |v: &dyn std::fmt::Debug| format!("{v:?}");
    let given = [
        ("size_m", o.size_m.as_ref().map(|v| shown(v))),
        ("radius_m", o.radius_m.map(|v| shown(&v))),
        ("length_m", o.length_m.map(|v| shown(&v))),
        ("wall_m", o.wall_m.map(|v| shown(&v))),
        ("path", o.path.as_ref().map(|v| shown(v))),
        ("scale", o.scale.map(|v| shown(&v))),
        ("recenter", o.recenter.map(|v| shown(&v))),
        ("rcs_m2", o.rcs_m2.map(|v| shown(&v))),
    ];
    for (key, value) in given {
        if let Some(value) = value
            && !allowed.contains(&key)
        {
            return Err(SceneError::Field {
                path: c.path.to_path_buf(),
                field: field(key),
                value,
                reason: format!("does not apply to a {}", o.shape),
            });
        }
    }
    let required = |key: &str, v: Option<f64>| -> Result<f64, SceneError> {
        match v {
            Some(v) => c.positive(&field(key), v),
            None => Err(c.fail(&field(key), "missing", &format!("a {} needs it", o.shape))),
        }
    };
    let sizes = |n: usize| -> Result<Vec<f64>, SceneError> {
        let v = o.size_m.clone().ok_or_else(|| {
            c.fail(
                &field("size_m"),
                "missing",
                &format!("a {} needs it", o.shape),
            )
        })?;
        if v.len() != n {
            return Err(c.fail(&field("size_m"), &v, &format!("needs {n} values")));
        }
        for (k, s) in v.iter().enumerate() {
            c.positive(&format!("object[{i}].size_m[{k}]"), *s)?;
        }
        Ok(v)
    };
    let pose = geometry::pose_from(o.position_m, o.rotation_deg);
    let t = tessellation_m;
    let local = match o.shape.as_str() {
        "plate" => {
            let s = sizes(2)?;
            geometry::plate_mesh([s[0], s[1]], t)
        }
        "box" => {
            let s = sizes(3)?;
            geometry::box_mesh([s[0], s[1], s[2]], t)
        }
        "sphere" => geometry::sphere_mesh(required("radius_m", o.radius_m)?, t),
        "cylinder" => geometry::cylinder_mesh(
            required("radius_m", o.radius_m)?,
            required("length_m", o.length_m)?,
            t,
        ),
        "bottle" => {
            let radius_m = required("radius_m", o.radius_m)?;
            let height_m = required("length_m", o.length_m)?;
            if height_m < 2.0 * radius_m {
                return Err(c.fail(
                    &field("length_m"),
                    height_m,
                    "a bottle must be at least as tall as it is wide (2·radius_m)",
                ));
            }
            geometry::bottle_mesh(radius_m, height_m, t)
        }
        "cup" | "bowl" => {
            let radius_m = required("radius_m", o.radius_m)?;
            let wall_m = c.positive(&field("wall_m"), o.wall_m.unwrap_or(DEFAULT_WALL_M))?;
            if wall_m >= radius_m {
                return Err(c.fail(&field("wall_m"), wall_m, "must be thinner than radius_m"));
            }
            if o.shape == "cup" {
                let height_m = required("length_m", o.length_m)?;
                if wall_m >= height_m {
                    return Err(c.fail(&field("wall_m"), wall_m, "must be thinner than length_m"));
                }
                geometry::cup_mesh(radius_m, height_m, wall_m, t)
            } else {
                geometry::bowl_mesh(radius_m, wall_m, t)
            }
        }
        "mesh" => {
            let rel = o
                .path
                .as_ref()
                .ok_or_else(|| c.fail(&field("path"), "missing", "a mesh needs it"))?;
            let mesh = geometry::load_mesh(&base.join(rel)).map_err(|source| SceneError::Mesh {
                path: c.path.to_path_buf(),
                source,
            })?;
            let mesh = mesh.scaled(c.positive(&field("scale"), o.scale.unwrap_or(1.0))?);
            if o.recenter.unwrap_or(true) {
                mesh.centred()
            } else {
                mesh
            }
        }
        _ => {
            // "point"
            let rcs_m2 = c.positive(&field("rcs_m2"), o.rcs_m2.unwrap_or(1e-4))?;
            return Ok(SceneObject {
                name: o.name.clone().unwrap_or_else(|| format!("point{i}")),
                geometry: ObjectGeometry::Point {
                    position_m: o.position_m,
                    rcs_m2,
                },
                material,
            });
        }
    };
    Ok(SceneObject {
        name: o.name.clone().unwrap_or_else(|| format!("{}{i}", o.shape)),
        geometry: ObjectGeometry::Surface(local.transformed(&pose)),
        material,
    })
}
