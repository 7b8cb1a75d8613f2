//! Reconstruction parameters: `recon.toml` (every key optional) and the command-line overrides.
//!
//! The defaults reproduce the paper's settings where it gives them (1 mm voxels, candidates every
//! λ/2, 50 antennas, Li thresholding, 6-connectivity). Where the authors' code departs from the
//! paper, the field's doc says which one the default follows.

use serde::{Deserialize, Serialize};

pub use super::isosurface::ComponentGains;
pub use super::subset::SubsetRule;

/// Which reconstruction to run.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Method {
    /// Normal field, RSDF and isosurface selection (paper §2–§4).
    Mmnorm,
    /// Voxels whose |S| exceeds a fraction of the maximum (paper §5 baseline).
    Backprojection,
    /// Depth from the phase change between sub-band 2-D images (Gao et al., paper §5 baseline).
    Interferometric,
}

impl Method {
    /// The name on the command line and in config files.
    pub fn name(self) -> &'static str {
        match self {
            Method::Mmnorm => "mmnorm",
            Method::Backprojection => "backprojection",
            Method::Interferometric => "interferometric",
        }
    }

    /// The name in pictures and reports.
    pub fn title(self) -> &'static str {
        match self {
            Method::Mmnorm => "mmNorm",
            Method::Backprojection => "Backprojection",
            Method::Interferometric => "Interferometric",
        }
    }
}

/// How S(v) is formed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "snake_case")]
pub enum Imaging {
    /// Range migration when the phase centres form a raster, backprojection otherwise.
    Auto,
    /// Range migration (ω-k, `recon::rma`); fails on a capture that is not a raster.
    Rma,
    /// Interpolated backprojection (`recon::image`).
    Backprojection,
}

/// Which voxels Li's threshold is computed over (`recon::mask`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum LiVoxels {
    /// Every voxel of the imaged box, as the authors do.
    All,
    /// Only the voxels above `normal_floor` of the maximum: the empty space that pads the
    /// objects in the box does not move the threshold.
    AboveFloor,
}

/// How each component's isosurface constant is chosen.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "snake_case")]
pub enum Isosurface {
    /// Simulate candidate surfaces and match the measured spectra (§4, Eq. 11–13).
    Optimized,
    /// (max f + min f)/2 (ablation, §6.3.2).
    Center,
    /// The |S|-weighted mean of the candidates (ablation, §6.3.2).
    Weighted,
}

/// How the normal field is integrated into the RSDF.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Integration {
    /// Least squares over every edge (the default; see `recon::rsdf`).
    LeastSquares,
    /// The authors' breadth-first single-path integral.
    Bfs,
}

/// The volume to image.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum VolumeSpec {
    /// Found from the data (see `recon::volume`).
    Auto,
    /// `[x0, x1, y0, y1, z0, z1]` in the capture frame, metres.
    Box([f64; 6]),
}

impl<'de> Deserialize<'de> for VolumeSpec {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<VolumeSpec, D::Error> {
        #[derive(Deserialize)]
        #[serde(untagged)]
        enum Raw {
            Name(String),
            Bounds([f64; 6]),
        }
        match Raw::deserialize(d)? {
            Raw::Name(s) if s == "auto" => Ok(VolumeSpec::Auto),
            Raw::Name(s) => Err(serde::de::Error::custom(format!(
                "volume = \"{s}\": expected \"auto\" or [x0, x1, y0, y1, z0, z1]"
            ))),
            Raw::Bounds(b) => Ok(VolumeSpec::Box(b)),
        }
    }
}

impl std::str::FromStr for VolumeSpec {
    type Err = String;

    /// `auto` or `x0,x1,y0,y1,z0,z1` (metres).
    fn from_str(s: &str) -> Result<VolumeSpec, String> {
        if s.trim() == "auto" {
            return Ok(VolumeSpec::Auto);
        }
        let parts: Vec<&str> = s.split(',').map(str::trim).collect();
        if parts.len() != 6 {
            return Err(format!(
                "volume \"{s}\": expected auto or six numbers x0,x1,y0,y1,z0,z1 in metres, got {} values",
                parts.len()
            ));
        }
        let mut b = [0.0f64; 6];
        for (o, p) in b.iter_mut().zip(&parts) {
            *o = p
                .parse()
                .map_err(|_| format!("volume \"{s}\": \"{p}\" is not a number"))?;
        }
        Ok(VolumeSpec::Box(b))
    }
}

/// Automatic volume selection (`recon::volume`).
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct AutoVolume {
    /// One-way range window below the aperture searched for echoes, metres (range offset removed).
    pub range_window_m: [f64; 2],
    /// Coarse voxel edge, metres.
    pub coarse_voxel_m: f64,
    /// Antennas used for the coarse image (a seeded random subset: a sparse random array has no
    /// grating lobes, unlike a decimated raster).
    pub coarse_antennas: usize,
    /// Coarse voxels with |S| above this fraction of the maximum form the high-power region.
    /// 0.25 (−12 dB): a specular object returns most of its power from a few highlights, and
    /// 0.5 (the default until 2026-11-25) cut the rest of a long object out of the box (see
    /// `recon::volume`).
    pub power_fraction: f64,
    /// Padding around the high-power region, metres. The padded region is the volume's core:
    /// Li's threshold is computed over it, and only mask components that reach into it are kept.
    pub pad_m: f64,
    /// How far the imaged volume extends beyond the core, metres, so that a component which
    /// crosses the core's faces is imaged whole instead of cut (see `recon::volume`).
    pub margin_m: f64,
    /// How far the coarse search looks beyond the aperture's x–y extent, as an angle off
    /// vertical at the deepest echo, degrees: a surface tilted towards the aperture returns its
    /// echo from out there. 0 searches the footprint alone; see `recon::volume` and
    /// `docs/bench/physics/notes.md` for what the default 10° gains on an object wider than the
    /// aperture.
    pub reach_deg: f64,
    /// Where the coarse image comes from a random draw of the antennas (more than
    /// `coarse_antennas`), a coarse voxel counts as strong only if |S| is also this many
    /// standard errors of the draw's estimate clear of zero. A draw seen by few antennas (a
    /// specular patch) leaves a sidelobe floor that the whole aperture does not have; 0 turns
    /// the test off (see `recon::volume`).
    pub subset_sigmas: f64,
}

impl Default for AutoVolume {
    fn default() -> AutoVolume {
        AutoVolume {
            range_window_m: [0.05, 1.5],
            coarse_voxel_m: 0.006,
            coarse_antennas: 10000,
            power_fraction: 0.25,
            pad_m: 0.03,
            margin_m: 0.03,
            reach_deg: 10.0,
            subset_sigmas: 4.0,
        }
    }
}

/// Structural isosurface optimisation (`recon::isosurface`).
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Optimisation {
    /// Candidate spacing as a fraction of the carrier wavelength λ0 (paper: λ/2).
    pub step_wavelengths: f64,
    /// Candidates stay this far inside each component's RSDF range, metres (authors: 15 mm).
    pub bound_inset_m: f64,
    /// Antennas in the random subset (paper: 50).
    pub antennas: usize,
    /// Seed of the subset (recorded in summary.json).
    pub seed: u64,
    /// Strong-return filter: an antenna qualifies when its peak in the object's range window is
    /// at least this fraction of the strongest antenna's (with a share per component: when its
    /// simulated echo amplitude is at least this fraction of the component's strongest).
    pub strong_fraction: f64,
    /// Angular spacing of the traced rays, degrees.
    pub ray_step_deg: f64,
    /// Zero padding of the cost's range FFT (factor over the chirp length).
    pub cost_pad_factor: usize,
    /// Coordinate-descent sweeps over components at most.
    pub max_sweeps: usize,
    /// Echoes peaking nearer than the objects' range window projected out of each antenna's
    /// spectra before the cost, at most (0: none; `recon::near_echo`).
    pub near_echo_tones: usize,
    /// A near echo is taken while its peak is at least this fraction of the window's peak.
    pub near_echo_ratio: f64,
    /// Specular window of the simulated chirps: a hit whose surface normal lies within the first
    /// angle (degrees) of the bistatic bisector counts fully, falling as a raised cosine to
    /// nothing at the second; `[0, 0]` counts every hit alike (the paper's Eq. 11).
    pub specular_window_deg: [f64; 2],
    /// How the antennas are chosen: `per_component` (with several components, a share for each
    /// among the antennas its simulated echo dominates) or `strongest` (the authors' measured
    /// filter alone).
    pub subset: SubsetRule,
    /// How the components' simulated echoes are weighed against each other in a joint choice:
    /// `common` (one gain for all, Eq. 11 as printed) or `fitted` (each antenna fits each
    /// component's gain, so a level is judged by where its echo falls, not by how strong the
    /// simulation makes it; `recon::isosurface`).
    pub component_gains: ComponentGains,
    /// Candidates lie within this many range resolutions (c/2B) of the component's
    /// |S|-weighted level (`recon::pipeline`, [`super::isosurface::weighted_constant`]); 0
    /// searches the whole RSDF range as the paper does.
    pub level_band_resolutions: f64,
    /// A component's level leaves the candidate nearest its |S|-weighted level only when the
    /// per-antenna cost gain is significant at this paired t (`recon::isosurface`); 0 (the
    /// default: it helped under one physics model and hurt under the other) takes the cost's
    /// minimum as the paper does.
    pub evidence_t: f64,
    /// A component whose cost is least on the first or the last of its candidates (at least
    /// three) takes the candidate nearest its |S|-weighted level instead: the cost falls
    /// towards the edge of the search and has no minimum inside it (`recon::isosurface`).
    /// False takes the cost's least candidate as the paper does.
    pub edge_fallback: bool,
}

impl Default for Optimisation {
    fn default() -> Optimisation {
        Optimisation {
            step_wavelengths: 0.5,
            bound_inset_m: 0.015,
            antennas: 50,
            seed: 1,
            strong_fraction: 0.5,
            ray_step_deg: 0.25,
            cost_pad_factor: 4,
            max_sweeps: 8,
            near_echo_tones: 4,
            near_echo_ratio: 0.3,
            specular_window_deg: [10.0, 20.0],
            subset: SubsetRule::PerComponent,
            component_gains: ComponentGains::Fitted,
            level_band_resolutions: 0.25,
            evidence_t: 0.0,
            edge_fallback: true,
        }
    }
}

/// Every reconstruction parameter.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ReconConfig {
    pub method: Method,
    pub isosurface: Isosurface,
    /// How S(v) is formed: `auto` takes range migration for raster captures.
    pub imaging: Imaging,
    /// With range migration, the normal field comes from the spectrum (`recon::rma`) instead of
    /// exact per-antenna votes (unit candidates only).
    pub spectral_normals: bool,
    /// A capture is a raster when every phase centre lies within this fraction of the spacing
    /// of its lattice node (`recon::lattice`).
    pub raster_tolerance: f64,
    pub volume: VolumeSpec,
    /// Voxel edge, metres (paper: 1 mm).
    pub voxel_m: f64,
    /// Range-FFT zero padding of the image (factor over the chirp length).
    pub pad_factor: usize,
    /// Normals are computed where |S| exceeds this fraction of the maximum (authors: 5 %).
    pub normal_floor: f64,
    /// Unit candidate vectors (paper Eq. 1) or the authors' un-normalised displacements.
    pub unit_candidates: bool,
    /// Exponents e tried in order for Li's threshold on |S|^e (authors: 2, 2.5, 3.5, 4).
    pub li_exponents: Vec<f64>,
    /// Li iterations before an attempt counts as failed (authors: 1000).
    pub li_max_iterations: usize,
    /// The voxels Li's threshold is computed over (authors: every voxel of the box).
    pub li_voxels: LiVoxels,
    /// A mask attempt is accepted when its oriented bounding box is at most this volume, m³
    /// (authors: 0.03).
    pub max_mask_box_m3: f64,
    /// Smallest component kept, m³: 1.5 cm × 1.5 cm × 2 cm = 4.5 cm³. The authors keep 3 × 3 × 4
    /// cm (3.6e-5 m³) and fall back to 1.5 × 1.5 × 2 cm only when nothing reaches that; the paper
    /// names no floor. Their floor drops whole parts of thin objects: at the paper's aperture a
    /// screwdriver's shaft formed a 34.6 cm³ component of its own and was lost (F 0.77; 0.97 with
    /// it kept; `docs/bench/history.md`). `fallback_component_m3` is used when no component
    /// reaches `min_component_m3` (it matters only when that is set above it).
    pub min_component_m3: f64,
    pub fallback_component_m3: f64,
    /// Split components where their column peaks jump by more than `split_jump_m` beyond what
    /// the normals predict, and choose a level per region (paper §8; `recon/split.rs`). False
    /// keeps the paper's one level per component.
    pub split_transitions: bool,
    /// The jump, metres, that splits a component.
    pub split_jump_m: f64,
    /// Look for surfaces hidden in a brighter surface's range lobe, such as an open cup's rim
    /// above its floor: each chirp's strongest echo is removed, the rest imaged again, and what
    /// its mask adds above the brighter surface becomes components of its own
    /// (`recon/hidden.rs`). On by default; it costs a second image of the volume's core, and
    /// false keeps the paper's components only.
    pub hidden_surfaces: bool,
    /// The residual image's voxels join only where its |S| is at least this fraction of the
    /// first image's peak (0.0316: −30 dB).
    pub hidden_floor: f64,
    /// Drop a component that lies under a brighter one, in the columns they share, 0.8–3 range
    /// bins down and at least 6 dB under it: that echo's range sidelobe (`recon/sidelobe.rs`).
    /// On by default; false keeps every component of Li's mask.
    pub drop_sidelobes: bool,
    pub integration: Integration,
    pub optimisation: Optimisation,
    pub auto_volume: AutoVolume,
    /// Backprojection baseline: keep voxels with |S| ≥ this fraction of the maximum.
    pub backprojection_fraction: f64,
    /// Interferometric baseline: number of sub-bands.
    pub interferometric_subbands: usize,
    /// Interferometric baseline: keep pixels with |S| ≥ this fraction of the maximum.
    pub interferometric_fraction: f64,
    /// A sheet of known thickness and refractive index between the aperture and the objects
    /// (the cardboard box of an NLOS scan), compensated for; none by default.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub occluder: Option<KnownOccluder>,
}

/// A flat sheet parallel to the aperture that every path to the objects crosses twice, once
/// each way: the box of an NLOS scan. Each crossing is slower than free space by
/// (n − 1)·t at normal incidence, so every echo from behind the sheet arrives as if the round
/// trip were [`Self::extra_round_trip_m`] longer; the reconstruction adds that to the
/// capture's range offset. At incidence θ the excess is t·(√(n² − sin²θ) − cos θ) instead:
/// for n = 1.6, 9 % more at 30° and 4 % more at 20°, which this constant leaves uncorrected.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct KnownOccluder {
    pub thickness_m: f64,
    pub refractive_index: f64,
    /// Subtract the echoes that peak nearer than the imaged box (the sheet's own) from every
    /// chirp before imaging ([`super::near_echo::without_near_echoes`]), so that their range
    /// sidelobes do not enter S(v). The isosurface cost keeps the raw chirps and projects the
    /// echoes out itself. On by default.
    #[serde(default = "yes")]
    pub remove_echo: bool,
}

fn yes() -> bool {
    true
}

impl KnownOccluder {
    /// 2·(n − 1)·t: the round trip's excess at normal incidence, metres.
    pub fn extra_round_trip_m(&self) -> f64 {
        2.0 * (self.refractive_index - 1.0) * self.thickness_m
    }
}

impl Default for ReconConfig {
    fn default() -> ReconConfig {
        ReconConfig {
            method: Method::Mmnorm,
            isosurface: Isosurface::Optimized,
            imaging: Imaging::Auto,
            spectral_normals: true,
            raster_tolerance: 0.1,
            volume: VolumeSpec::Auto,
            voxel_m: 0.001,
            pad_factor: 32,
            normal_floor: 0.05,
            unit_candidates: true,
            li_exponents: vec![2.0, 2.5, 3.5, 4.0],
            li_max_iterations: 1000,
            li_voxels: LiVoxels::All,
            max_mask_box_m3: 0.03,
            min_component_m3: 4.5e-6,
            fallback_component_m3: 4.5e-6,
            split_transitions: true,
            split_jump_m: 0.004,
            hidden_surfaces: true,
            hidden_floor: 0.0316,
            drop_sidelobes: true,
            integration: Integration::LeastSquares,
            optimisation: Optimisation::default(),
            auto_volume: AutoVolume::default(),
            backprojection_fraction: 0.3,
            interferometric_subbands: 8,
            interferometric_fraction: 0.3,
            occluder: None,
        }
    }
}

/// A parameter outside its domain, named with its value.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{field} = {value}: {reason}")]
pub struct InvalidParameter {
    pub field: &'static str,
    pub value: String,
    pub reason: &'static str,
}

impl ReconConfig {
    /// Parses `recon.toml` text; unknown keys are errors.
    pub fn parse(text: &str) -> Result<ReconConfig, String> {
        let config: ReconConfig = toml::from_str(text).map_err(|e| e.to_string())?;
        config.validate().map_err(|e| e.to_string())?;
        Ok(config)
    }

    /// Checks every numeric parameter's domain.
    pub fn validate(&self) -> Result<(), InvalidParameter> {
        fn check(
            field: &'static str,
            value: f64,
            ok: bool,
            reason: &'static str,
        ) -> Result<(), InvalidParameter> {
            if ok && value.is_finite() {
                Ok(())
            } else {
                Err(InvalidParameter {
                    field,
                    value: value.to_string(),
                    reason,
                })
            }
        }
        let unit = |x: f64| x > 0.0 && x <= 1.0;
        check(
            "voxel_m",
            self.voxel_m,
            self.voxel_m >= 1e-4 && self.voxel_m <= 0.05,
            "must lie in [0.0001, 0.05] m",
        )?;
        check(
            "pad_factor",
            self.pad_factor as f64,
            (1..=256).contains(&self.pad_factor),
            "must lie in 1..=256",
        )?;
        check(
            "normal_floor",
            self.normal_floor,
            (0.0..1.0).contains(&self.normal_floor),
            "must lie in [0, 1)",
        )?;
        if self.li_exponents.is_empty() || self.li_exponents.iter().any(|e| e.is_nan() || *e <= 0.0)
        {
            return Err(InvalidParameter {
                field: "li_exponents",
                value: format!("{:?}", self.li_exponents),
                reason: "must be a non-empty list of positive exponents",
            });
        }
        check(
            "max_mask_box_m3",
            self.max_mask_box_m3,
            self.max_mask_box_m3 > 0.0,
            "must be positive",
        )?;
        check(
            "hidden_floor",
            self.hidden_floor,
            self.hidden_floor > 0.0 && self.hidden_floor < 1.0,
            "must lie between 0 and 1 (a fraction of the image's peak)",
        )?;
        check(
            "min_component_m3",
            self.min_component_m3,
            self.min_component_m3 >= 0.0,
            "must not be negative",
        )?;
        check(
            "fallback_component_m3",
            self.fallback_component_m3,
            self.fallback_component_m3 >= 0.0,
            "must not be negative",
        )?;
        check(
            "split_jump_m",
            self.split_jump_m,
            self.split_jump_m > 0.0 && self.split_jump_m.is_finite(),
            "must be a positive number of metres",
        )?;
        check(
            "raster_tolerance",
            self.raster_tolerance,
            self.raster_tolerance > 0.0 && self.raster_tolerance <= 0.5,
            "must lie in (0, 0.5]",
        )?;
        let o = &self.optimisation;
        check(
            "optimisation.step_wavelengths",
            o.step_wavelengths,
            (0.05..=10.0).contains(&o.step_wavelengths),
            "must lie in [0.05, 10] wavelengths",
        )?;
        check(
            "optimisation.bound_inset_m",
            o.bound_inset_m,
            o.bound_inset_m >= 0.0,
            "must not be negative",
        )?;
        check(
            "optimisation.level_band_resolutions",
            o.level_band_resolutions,
            (0.0..=10.0).contains(&o.level_band_resolutions),
            "must lie in [0, 10] range resolutions (0: the whole RSDF range)",
        )?;
        check(
            "optimisation.evidence_t",
            o.evidence_t,
            (0.0..=100.0).contains(&o.evidence_t),
            "must lie in [0, 100] (0: the cost's minimum)",
        )?;
        check(
            "optimisation.antennas",
            o.antennas as f64,
            o.antennas >= 1,
            "must be at least 1",
        )?;
        check(
            "optimisation.strong_fraction",
            o.strong_fraction,
            unit(o.strong_fraction),
            "must lie in (0, 1]",
        )?;
        check(
            "optimisation.ray_step_deg",
            o.ray_step_deg,
            o.ray_step_deg >= 0.01 && o.ray_step_deg <= 5.0,
            "must lie in [0.01, 5] degrees",
        )?;
        check(
            "optimisation.cost_pad_factor",
            o.cost_pad_factor as f64,
            (1..=64).contains(&o.cost_pad_factor),
            "must lie in 1..=64",
        )?;
        check(
            "optimisation.max_sweeps",
            o.max_sweeps as f64,
            o.max_sweeps >= 1,
            "must be at least 1",
        )?;
        check(
            "optimisation.near_echo_tones",
            o.near_echo_tones as f64,
            o.near_echo_tones <= 64,
            "must lie in 0..=64",
        )?;
        let [full, cut] = o.specular_window_deg;
        check(
            "optimisation.specular_window_deg[1]",
            cut,
            (0.0..=90.0).contains(&cut),
            "(the cutoff) must lie in [0, 90] degrees",
        )?;
        check(
            "optimisation.specular_window_deg[0]",
            full,
            full >= 0.0 && full <= cut,
            "(full weight up to) must lie in [0, cutoff] degrees",
        )?;
        check(
            "optimisation.near_echo_ratio",
            o.near_echo_ratio,
            o.near_echo_ratio > 0.0 && o.near_echo_ratio <= 100.0,
            "must lie in (0, 100]",
        )?;
        let a = &self.auto_volume;
        check(
            "auto_volume.range_window_m",
            a.range_window_m[0],
            a.range_window_m[0] >= 0.0 && a.range_window_m[1] > a.range_window_m[0],
            "must be [min, max] with 0 ≤ min < max",
        )?;
        check(
            "auto_volume.coarse_voxel_m",
            a.coarse_voxel_m,
            a.coarse_voxel_m >= 1e-3 && a.coarse_voxel_m <= 0.05,
            "must lie in [0.001, 0.05] m",
        )?;
        check(
            "auto_volume.coarse_antennas",
            a.coarse_antennas as f64,
            a.coarse_antennas >= 16,
            "must be at least 16",
        )?;
        check(
            "auto_volume.power_fraction",
            a.power_fraction,
            unit(a.power_fraction),
            "must lie in (0, 1]",
        )?;
        check(
            "auto_volume.pad_m",
            a.pad_m,
            a.pad_m >= 0.0,
            "must not be negative",
        )?;
        check(
            "auto_volume.margin_m",
            a.margin_m,
            a.margin_m >= 0.0,
            "must not be negative",
        )?;
        check(
            "auto_volume.reach_deg",
            a.reach_deg,
            (0.0..=60.0).contains(&a.reach_deg),
            "must lie in [0, 60]",
        )?;
        check(
            "auto_volume.subset_sigmas",
            a.subset_sigmas,
            (0.0..=10.0).contains(&a.subset_sigmas),
            "must lie in [0, 10]",
        )?;
        check(
            "backprojection_fraction",
            self.backprojection_fraction,
            unit(self.backprojection_fraction),
            "must lie in (0, 1]",
        )?;
        check(
            "interferometric_subbands",
            self.interferometric_subbands as f64,
            (2..=64).contains(&self.interferometric_subbands),
            "must lie in 2..=64",
        )?;
        check(
            "interferometric_fraction",
            self.interferometric_fraction,
            unit(self.interferometric_fraction),
            "must lie in (0, 1]",
        )?;
        if let Some(o) = self.occluder {
            check(
                "occluder.thickness_m",
                o.thickness_m,
                (0.0..=0.1).contains(&o.thickness_m),
                "must lie in [0, 0.1] m",
            )?;
            check(
                "occluder.refractive_index",
                o.refractive_index,
                (1.0..=10.0).contains(&o.refractive_index),
                "must lie in [1, 10]",
            )?;
        }
        if let VolumeSpec::Box(b) = self.volume {
            for axis in 0..3 {
                let (lo, hi) = (b[2 * axis], b[2 * axis + 1]);
                if !(lo.is_finite() && hi.is_finite() && hi > lo) {
                    return Err(InvalidParameter {
                        field: "volume",
                        value: format!("{b:?}"),
                        reason: "each axis needs finite bounds with min < max",
                    });
                }
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_are_valid_and_keys_parse() {
        ReconConfig::default().validate().unwrap();
        let c = ReconConfig::parse(
            "method = \"backprojection\"\nvolume = [-0.1, 0.1, -0.1, 0.1, -0.05, 0.1]\n[optimisation]\nseed = 7\n",
        )
        .unwrap();
        assert_eq!(c.method, Method::Backprojection);
        assert_eq!(
            c.volume,
            VolumeSpec::Box([-0.1, 0.1, -0.1, 0.1, -0.05, 0.1])
        );
        assert_eq!(c.optimisation.seed, 7);
        assert_eq!(c.optimisation.antennas, 50);
    }

    #[test]
    fn the_reconstruction_doc_lists_the_defaults() {
        let readme = include_str!("../../docs/reconstruction.md");
        let start = readme
            .find("```toml\nmethod = ")
            .map(|i| i + "```toml\n".len())
            .expect("docs/reconstruction.md has the default recon.toml");
        let end = start + readme[start..].find("```").unwrap();
        let block = &readme[start..end];
        let parsed = ReconConfig::parse(block).unwrap();
        // Every key is listed, not only left to its default.
        let defaults = serde_json::to_value(ReconConfig::default()).unwrap();
        let mut keys = Vec::new();
        for (key, value) in defaults.as_object().unwrap() {
            match value.as_object() {
                Some(table) => keys.extend(table.keys().cloned()),
                None => keys.push(key.clone()),
            }
        }
        for key in keys {
            assert!(
                block.contains(&format!("\n{key} = ")) || block.starts_with(&format!("{key} = ")),
                "docs/reconstruction.md's defaults omit {key}"
            );
        }
        assert_eq!(
            serde_json::to_value(&parsed).unwrap(),
            serde_json::to_value(ReconConfig::default()).unwrap()
        );
    }

    #[test]
    fn errors_name_the_field_and_value() {
        let e = ReconConfig::parse("voxel_m = 0.0\n").unwrap_err();
        assert!(e.contains("voxel_m = 0"), "{e}");
        let e = ReconConfig::parse("[optimisation]\nantenas = 5\n").unwrap_err();
        assert!(e.contains("antenas"), "{e}");
        let e = ReconConfig::parse("volume = [0.1, 0.0, 0, 1, 0, 1]\n").unwrap_err();
        assert!(e.contains("volume"), "{e}");
        let e =
            ReconConfig::parse("[optimisation]\nspecular_window_deg = [25.0, 20.0]\n").unwrap_err();
        assert!(e.contains("specular_window_deg[0] = 25"), "{e}");
        let e = ReconConfig::parse("volume = \"big\"\n").unwrap_err();
        assert!(e.contains("big"), "{e}");
        assert!(
            "1,2,3"
                .parse::<VolumeSpec>()
                .unwrap_err()
                .contains("3 values")
        );
        assert!(
            "0,1,0,1,0,x"
                .parse::<VolumeSpec>()
                .unwrap_err()
                .contains("\"x\"")
        );
    }
}
