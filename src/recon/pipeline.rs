//! The reconstruction from a capture to points: volume, image, then the chosen method.
//!
//! For mmNorm: mask → normal field on the mask (the authors compute normals on every voxel above
//! 5 % and mask afterwards; a voxel's normal depends on that voxel alone, so computing only the
//! masked ones gives the same values for less work) → components → one RSDF per component → one isosurface
//! constant per component → the voxel centres within half a voxel of each chosen level, with
//! their estimated normals. (The authors keep |f − C| < 1 mm, a two-voxel shell; half a voxel
//! gives one layer, which is all a point cloud needs.)

use std::borrow::Cow;
use std::time::Instant;

use num_complex::Complex32;
use rayon::prelude::*;
use serde::Serialize;

use super::baselines::{backprojection_points, interferometric_points};
use super::components::{label_6, label_6_keyed, retain_reaching};
use super::config::{Imaging, Integration, Isosurface, Method, ReconConfig};
use super::hidden::{
    HiddenSummary, RISE_RANGE_BINS, flagged_components, hidden_voxels, keep_above,
};
use super::image::{RangeProfiles, VoxelGrid, backproject};
use super::isosurface::{
    OptimisationError, OptimisationReport, candidates, centre_constant, nearest_candidate,
    optimise, weighted_constant,
};
use super::lattice::{Lattice, NotRaster, detect};
use super::mask::{MaskAttempt, MaskError, li_mask};
use super::near_echo::{NearEchoCanceller, without_near_echoes, without_strongest_echoes};
use super::normals::{Candidates, normal_field};
use super::rma::{RmaReport, rma_image};
use super::rsdf::{ComponentField, integrate_bfs, integrate_least_squares};
use super::sidelobe::{SidelobeSummary, drop_sidelobes};
use super::split::{SplitSummary, split_at_transitions};
use super::trace::SampledField;
use super::volume::{AutoReport, Core, VolumeError, select};
use crate::capture::{Capture, InvalidCapture};
use crate::geometry::ply::{self, Column};
use crate::progress::Progress;

/// Why a reconstruction failed.
#[derive(Debug, thiserror::Error)]
pub enum ReconError {
    #[error(transparent)]
    Capture(#[from] InvalidCapture),
    #[error(transparent)]
    Config(#[from] super::config::InvalidParameter),
    #[error(transparent)]
    Volume(#[from] VolumeError),
    #[error(transparent)]
    Mask(#[from] MaskError),
    #[error(transparent)]
    Optimisation(#[from] OptimisationError),
    #[error("imaging = \"rma\" needs a raster aperture: {0}")]
    NotRaster(#[from] NotRaster),
    #[error(
        "no connected high-power component of at least {fallback_voxels} voxels ({fallback_m3:e} m³) in the volume"
    )]
    NoComponent {
        fallback_voxels: usize,
        fallback_m3: f64,
    },
}

/// One component in the summary.
#[derive(Debug, Clone, Serialize)]
pub struct ComponentSummary {
    /// 1-based, as in `points.ply`'s `component` column.
    pub component: u32,
    pub voxels: usize,
    pub rsdf_min_m: f64,
    pub rsdf_max_m: f64,
    pub constant_m: f64,
    pub points: usize,
}

/// The mask stage in the summary.
#[derive(Debug, Clone, Serialize)]
pub struct MaskSummary {
    pub normal_floor: f64,
    pub exponent: f64,
    pub attempts: Vec<MaskAttempt>,
    /// Voxels in the mask: those that got a normal.
    pub voxels: usize,
    pub min_component_voxels: usize,
    pub used_fallback_size: bool,
}

/// Everything summary.json records besides the configuration.
#[derive(Debug, Clone, Serialize)]
pub struct Summary {
    pub method: Method,
    pub isosurface: Option<Isosurface>,
    pub imaging: ImagingReport,
    /// mmNorm's normal votes: "spectral" (from the range-migration spectrum) or "exact".
    pub normal_votes: Option<&'static str>,
    pub antennas: usize,
    pub samples_per_chirp: usize,
    pub grid: VoxelGrid,
    /// The grid's voxels that hold the echo region; the rest is the margin (`recon::volume`).
    pub core: Core,
    pub auto_volume: Option<AutoReport>,
    /// (stage, seconds), in order.
    pub stage_s: Vec<(String, f64)>,
    pub image_peak: f32,
    pub mask: Option<MaskSummary>,
    /// How the components were split at sharp transitions, when they were.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub split: Option<SplitSummary>,
    /// What the search for surfaces hidden in a brighter one's range lobe added, when it ran.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub hidden: Option<HiddenSummary>,
    /// The components dropped as a brighter one's range sidelobe, when the rule ran.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub sidelobes: Option<SidelobeSummary>,
    pub components: Vec<ComponentSummary>,
    pub optimisation: Option<OptimisationReport>,
    pub interferometric_reference_z_m: Option<f64>,
    pub points: usize,
}

/// Points, with normals where the method has them, and what made them.
#[derive(Debug, Clone)]
pub struct Reconstruction {
    pub points_m: Vec<[f64; 3]>,
    pub normals: Option<Vec<[f64; 3]>>,
    /// Component per point (1-based; 0 where the method has no components).
    pub components: Vec<u32>,
    pub summary: Summary,
}

impl Reconstruction {
    /// The points as binary little-endian PLY: `x y z` (double), `nx ny nz` (float) where the
    /// method has normals, and `component` (int).
    pub fn encode_ply(&self) -> Vec<u8> {
        let col = |k: usize| self.points_m.iter().map(|p| p[k]).collect::<Vec<f64>>();
        let mut columns = vec![
            Column::F64("x", col(0)),
            Column::F64("y", col(1)),
            Column::F64("z", col(2)),
        ];
        if let Some(normals) = &self.normals {
            for (k, name) in ["nx", "ny", "nz"].into_iter().enumerate() {
                columns.push(Column::F32(
                    name,
                    normals.iter().map(|n| n[k] as f32).collect(),
                ));
            }
        }
        columns.push(Column::I32(
            "component",
            self.components.iter().map(|&c| c as i32).collect(),
        ));
        ply::encode(&columns, &[])
    }
}

/// How the image was formed, for summary.json.
#[derive(Debug, Clone, Serialize)]
pub struct ImagingReport {
    pub requested: Imaging,
    /// `rma` or `backprojection`.
    pub used: Imaging,
    /// Why `auto` chose what it did.
    pub reason: String,
    pub rma: Option<RmaReport>,
    /// With a known sheet: the antennas whose chirps had echoes nearer than the box removed
    /// before imaging (`occluder.remove_echo`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub near_echo_antennas: Option<usize>,
}

/// The volume and its image, shared by every method.
pub struct Imaged {
    pub grid: VoxelGrid,
    /// The voxels of `grid` that hold the echo region (`recon::volume::Core`).
    pub core: Core,
    pub auto_volume: Option<AutoReport>,
    /// The cropped range profiles, when backprojection made the image (exact votes reuse them).
    pub profiles: Option<RangeProfiles>,
    pub image: Vec<Complex32>,
    pub magnitude: Vec<f32>,
    /// |S| of the capture with each chirp's strongest echo removed (`recon::hidden`), imaged
    /// the same way, when `hidden_surfaces` is on and the method is mmNorm.
    pub hidden_magnitude: Option<Vec<f32>>,
    /// Range migration's spectral vote vectors `Re(conj(S)·Σ_j I_j u_j)/|S|`, when it made the
    /// image for mmNorm with unit candidates and `spectral_normals`.
    pub votes: Option<Vec<[f32; 3]>>,
    pub imaging: ImagingReport,
    /// Times of the shared stages (volume, image).
    stages: Vec<(String, f64)>,
}

/// The capture as the reconstruction sees it: with `config.occluder`, a clone whose range
/// offset includes the sheet's excess round trip; otherwise the capture itself. The clone
/// shares the samples and copies only the antenna positions (48 bytes an antenna).
fn through_occluder<'a>(capture: &'a Capture, config: &ReconConfig) -> Cow<'a, Capture> {
    match config.occluder {
        Some(o) => {
            let mut adjusted = capture.clone();
            adjusted.range_offset_m += o.extra_round_trip_m();
            Cow::Owned(adjusted)
        }
        None => Cow::Borrowed(capture),
    }
}

/// Runs the reconstruction `config` describes.
pub fn reconstruct(
    capture: &Capture,
    config: &ReconConfig,
    quiet: bool,
) -> Result<Reconstruction, ReconError> {
    let imaged = image_volume(capture, config, quiet)?;
    reconstruct_imaged(capture, config, &imaged, quiet)
}

/// Validates the inputs, selects the volume and images it.
pub fn image_volume(
    capture: &Capture,
    config: &ReconConfig,
    quiet: bool,
) -> Result<Imaged, ReconError> {
    capture.validate()?;
    config.validate()?;
    let capture = &*through_occluder(capture, config);
    let mut stages = Stages::default();
    let (grid, core, auto_volume) = select(
        capture,
        config.volume,
        config.voxel_m,
        config.pad_factor,
        &config.auto_volume,
    )?;
    tracing::info!(
        "volume: {:?} voxels of {} mm from {:?}",
        grid.dims,
        grid.voxel_m * 1e3,
        grid.origin_m
    );
    if !core.is_whole(&grid) {
        tracing::info!(
            "volume core: voxels {:?}..{:?}; the rest is the margin",
            core.lo,
            core.hi
        );
    }
    stages.lap("volume");
    // Timed with the image it serves.
    let cleaned = match config.occluder {
        Some(o) if o.remove_echo => {
            // Echoes nearer than the core are the sheet's and the clutter's, as with no margin.
            let (lo, hi) = core.extent_m(&grid);
            let opts = &config.optimisation;
            let canceller = NearEchoCanceller::of_cost(capture.plan.samples_per_chirp, opts);
            let pad_bins = opts.cost_pad_factor as i64;
            let (clean, antennas) = without_near_echoes(capture, lo, hi, &canceller, pad_bins);
            tracing::info!(
                "near echoes: removed before imaging on {antennas} of {} antennas",
                capture.antennas()
            );
            Some((clean, antennas))
        }
        _ => None,
    };
    let near_echo_antennas = cleaned.as_ref().map(|c| c.1);
    let capture = cleaned.as_ref().map_or(capture, |c| &c.0);
    let lattice = match config.imaging {
        Imaging::Backprojection => Err("imaging = \"backprojection\"".to_string()),
        Imaging::Rma => Ok(detect(capture, config.raster_tolerance)?),
        Imaging::Auto => detect(capture, config.raster_tolerance).map_err(|e| e.to_string()),
    };
    let want_votes =
        config.method == Method::Mmnorm && config.unit_candidates && config.spectral_normals;
    let formed = form_image(
        capture,
        &grid,
        &core,
        &lattice,
        config.pad_factor,
        want_votes,
        quiet,
    );
    let imaging = match &lattice {
        Ok(lattice) => {
            let reason = format!(
                "the phase centres form a {}×{} raster of {:.3}×{:.3} mm (largest snap {:.3} mm)",
                lattice.dims[0],
                lattice.dims[1],
                lattice.spacing_m[0] * 1e3,
                lattice.spacing_m[1] * 1e3,
                lattice.max_lateral_offset_m * 1e3
            );
            tracing::info!("imaging: range migration; {reason}");
            ImagingReport {
                requested: config.imaging,
                used: Imaging::Rma,
                reason,
                rma: formed.rma.clone(),
                near_echo_antennas,
            }
        }
        Err(reason) => {
            if config.imaging == Imaging::Auto {
                tracing::info!("imaging: backprojection; not a raster: {reason}");
            }
            ImagingReport {
                requested: config.imaging,
                used: Imaging::Backprojection,
                reason: reason.clone(),
                rma: None,
                near_echo_antennas,
            }
        }
    };
    let magnitude: Vec<f32> = formed.image.iter().map(|s| s.norm()).collect();
    stages.lap("image");
    let hidden_magnitude = (config.method == Method::Mmnorm && config.hidden_surfaces).then(|| {
        let (lo, hi) = core.extent_m(&grid);
        let opts = &config.optimisation;
        let canceller = NearEchoCanceller::of_cost(capture.plan.samples_per_chirp, opts);
        let residual =
            without_strongest_echoes(capture, lo, hi, &canceller, opts.cost_pad_factor as i64);
        // The core alone is imaged (one transform, not the whole grid and the core again):
        // the margin stays zero, so a hidden component never reaches into it.
        let inner_grid = core.grid(&grid);
        let inner = form_image(
            &residual,
            &inner_grid,
            &Core::whole(&inner_grid),
            &lattice,
            config.pad_factor,
            false,
            true,
        )
        .image;
        let mut magnitude = vec![0.0f32; grid.dims.iter().product()];
        let inner: Vec<f32> = inner.iter().map(|s| s.norm()).collect();
        core.paste(&grid, &mut magnitude, &inner);
        stages.lap("hidden image");
        magnitude
    });
    Ok(Imaged {
        grid,
        core,
        auto_volume,
        profiles: formed.profiles,
        image: formed.image,
        magnitude,
        hidden_magnitude,
        votes: formed.votes,
        imaging,
        stages: stages.list,
    })
}

/// An image and what its method made beside it.
struct Formed {
    image: Vec<Complex32>,
    profiles: Option<RangeProfiles>,
    votes: Option<Vec<[f32; 3]>>,
    rma: Option<RmaReport>,
}

/// One image of `capture` on `grid`: by range migration on `lattice` (the core imaged on its
/// own and pasted in, so the margin does not change it), or by backprojection when the capture
/// is not a raster.
fn form_image(
    capture: &Capture,
    grid: &VoxelGrid,
    core: &Core,
    lattice: &Result<Lattice, String>,
    pad_factor: usize,
    want_votes: bool,
    quiet: bool,
) -> Formed {
    match lattice {
        Ok(lattice) => {
            let mut rma = rma_image(capture, grid, lattice, want_votes, quiet);
            if !core.is_whole(grid) {
                // The transform's gate and kz grid follow the grid's extent, so the core is
                // imaged on its own too and keeps that image: the margin adds voxels around
                // the unmargined image without changing it.
                let inner = rma_image(capture, &core.grid(grid), lattice, want_votes, quiet);
                core.paste(grid, &mut rma.image, &inner.image);
                if let (Some(votes), Some(inner_votes)) = (rma.votes.as_mut(), &inner.votes) {
                    core.paste(grid, votes, inner_votes);
                }
                rma.report = inner.report;
            }
            Formed {
                image: rma.image,
                profiles: None,
                votes: rma.votes,
                rma: Some(rma.report),
            }
        }
        Err(_) => {
            let profiles = RangeProfiles::new(capture, grid, pad_factor);
            let progress = Progress::new("image", grid.dims[0] as u64, quiet);
            let image = backproject(capture, grid, &profiles, Some(&progress));
            progress.finish();
            Formed {
                image,
                profiles: Some(profiles),
                votes: None,
                rma: None,
            }
        }
    }
}

/// Runs `config.method` on an imaged volume (made by [`image_volume`] with the same capture
/// and the same volume, voxel and padding settings). The summary's stage times start with the
/// shared volume and image stages.
pub fn reconstruct_imaged(
    capture: &Capture,
    config: &ReconConfig,
    imaged: &Imaged,
    quiet: bool,
) -> Result<Reconstruction, ReconError> {
    config.validate()?;
    let capture = &*through_occluder(capture, config);
    let (mut summary, mut stages) = start_summary(capture, config, imaged);
    let grid = imaged.grid;
    let magnitude = &imaged.magnitude;
    // The baselines threshold the image as a whole, so they see the core only: the margin is
    // there for mmNorm's components that cross the core's faces.
    let baseline_view = || {
        let core = &imaged.core;
        (core.grid(&grid), core.crop(&grid, magnitude))
    };
    let (points_m, normals, components) = match config.method {
        Method::Backprojection => {
            let (grid, magnitude) = baseline_view();
            let (points, kept) =
                backprojection_points(&magnitude, &grid, config.backprojection_fraction);
            let mut mask = vec![false; grid.len()];
            for &v in &kept {
                mask[v] = true;
            }
            let labels = label_6(&mask, grid.dims, 1).labels;
            let comps = kept.iter().map(|&v| labels[v]).collect();
            stages.lap("threshold");
            (points, None, comps)
        }
        Method::Interferometric => {
            let (grid, magnitude) = baseline_view();
            let (points, z_ref) = interferometric_points(
                capture,
                &grid,
                &magnitude,
                config.interferometric_subbands,
                config.interferometric_fraction,
                config.pad_factor,
                quiet,
            );
            summary.interferometric_reference_z_m = z_ref.is_finite().then_some(z_ref);
            stages.lap("interferometry");
            let n = points.len();
            (points, None, vec![0; n])
        }
        Method::Mmnorm => {
            let fields = mmnorm_fields(capture, config, imaged, quiet, &mut summary, &mut stages)?;
            mmnorm_points(
                capture,
                config,
                config.isosurface,
                &grid,
                &fields,
                magnitude,
                quiet,
                &mut summary,
                &mut stages,
            )?
        }
    };
    Ok(assemble(summary, stages, (points_m, normals, components)))
}

/// Runs mmNorm once up to the RSDFs and then finishes it with each of `isosurfaces` (the
/// optimisation and the §6.3.2 ablations share everything before the choice of constants).
/// Each reconstruction's stage times hold the shared stages and then its own.
pub fn reconstruct_isosurfaces(
    capture: &Capture,
    config: &ReconConfig,
    imaged: &Imaged,
    isosurfaces: &[Isosurface],
    quiet: bool,
) -> Result<Vec<Reconstruction>, ReconError> {
    config.validate()?;
    let capture = &*through_occluder(capture, config);
    let config = ReconConfig {
        method: Method::Mmnorm,
        ..config.clone()
    };
    let (mut shared_summary, mut stages) = start_summary(capture, &config, imaged);
    let grid = imaged.grid;
    let fields = mmnorm_fields(
        capture,
        &config,
        imaged,
        quiet,
        &mut shared_summary,
        &mut stages,
    )?;
    let shared_stages = stages.list.clone();
    isosurfaces
        .iter()
        .map(|&isosurface| {
            let mut summary = shared_summary.clone();
            summary.isosurface = Some(isosurface);
            let mut own = Stages {
                list: shared_stages.clone(),
                ..Stages::default()
            };
            let points = mmnorm_points(
                capture,
                &config,
                isosurface,
                &grid,
                &fields,
                &imaged.magnitude,
                quiet,
                &mut summary,
                &mut own,
            )?;
            Ok(assemble(summary, own, points))
        })
        .collect()
}

/// The reconstruction of `points`, with the summary's stage times and point count filled in.
fn assemble(mut summary: Summary, stages: Stages, points: Points) -> Reconstruction {
    let (points_m, normals, components) = points;
    summary.stage_s = stages.list;
    summary.points = points_m.len();
    Reconstruction {
        points_m,
        normals,
        components,
        summary,
    }
}

/// An empty summary for `config` on `imaged`, and a stage clock that starts with the shared
/// volume and image stages.
fn start_summary(capture: &Capture, config: &ReconConfig, imaged: &Imaged) -> (Summary, Stages) {
    let stages = Stages {
        list: imaged.stages.clone(),
        ..Stages::default()
    };
    let image_peak = imaged.magnitude.iter().copied().fold(0.0f32, f32::max);
    let summary = Summary {
        method: config.method,
        isosurface: (config.method == Method::Mmnorm).then_some(config.isosurface),
        imaging: imaged.imaging.clone(),
        normal_votes: None,
        antennas: capture.antennas(),
        samples_per_chirp: capture.plan.samples_per_chirp,
        grid: imaged.grid,
        core: imaged.core,
        auto_volume: imaged.auto_volume.clone(),
        stage_s: Vec::new(),
        image_peak,
        mask: None,
        split: None,
        hidden: None,
        sidelobes: None,
        components: Vec::new(),
        optimisation: None,
        interferometric_reference_z_m: None,
        points: 0,
    };
    (summary, stages)
}

/// Wall time per stage.
struct Stages {
    clock: Instant,
    list: Vec<(String, f64)>,
}

impl Default for Stages {
    fn default() -> Stages {
        Stages {
            clock: Instant::now(),
            list: Vec::new(),
        }
    }
}

impl Stages {
    /// Records the time since the previous lap under `name`.
    fn lap(&mut self, name: &str) {
        self.list
            .push((name.to_string(), self.clock.elapsed().as_secs_f64()));
        self.clock = Instant::now();
    }
}

type Points = (Vec<[f64; 3]>, Option<Vec<[f64; 3]>>, Vec<u32>);

/// What every isosurface choice shares: the normal field, the components and their RSDFs.
struct Fields {
    normals: Vec<[f32; 3]>,
    sizes: Vec<usize>,
    /// Per component: found under a brighter surface's range lobe (empty when not searched).
    hidden: Vec<bool>,
    fields: Vec<SampledField>,
    ranges: Vec<(f64, f64)>,
    candidate_sets: Vec<Vec<f64>>,
    step_m: f64,
}

fn mmnorm_fields(
    capture: &Capture,
    config: &ReconConfig,
    imaged: &Imaged,
    quiet: bool,
    summary: &mut Summary,
    stages: &mut Stages,
) -> Result<Fields, ReconError> {
    let grid = &imaged.grid;
    let (image, magnitude) = (&imaged.image, &imaged.magnitude);
    let candidates_kind = if config.unit_candidates {
        Candidates::Unit
    } else {
        Candidates::Displacement
    };
    let li = |m: &[f32]| {
        li_mask(
            m,
            grid,
            &imaged.core,
            config.normal_floor,
            config.li_voxels,
            &config.li_exponents,
            config.li_max_iterations,
            config.max_mask_box_m3,
        )
    };
    let mut mask = li(magnitude)?;
    // Surfaces hidden in a brighter one's range lobe join the mask under a key of their own.
    let hidden = match &imaged.hidden_magnitude {
        Some(residual) => li(residual).ok().map(|r| {
            let floor = mask.peak * config.hidden_floor as f32;
            let hidden = hidden_voxels(&r.mask, residual, &mask.mask, floor);
            mask.mask
                .par_iter_mut()
                .zip(&hidden)
                .for_each(|(m, &h)| *m |= h);
            hidden
        }),
        None => None,
    };
    stages.lap("mask");
    let mask_voxels = mask.mask.iter().filter(|&&m| m).count();
    let spectral = imaged
        .votes
        .as_ref()
        .filter(|_| candidates_kind == Candidates::Unit && config.spectral_normals);
    let normals = match spectral {
        Some(votes) => {
            summary.normal_votes = Some("spectral");
            normalised_votes(votes, &mask.mask)
        }
        None => {
            summary.normal_votes = Some("exact");
            let built;
            let profiles = match &imaged.profiles {
                Some(p) => p,
                None => {
                    built = RangeProfiles::new(capture, grid, config.pad_factor);
                    &built
                }
            };
            let progress = Progress::new("normals", grid.dims[0] as u64, quiet);
            let normals = normal_field(
                capture,
                grid,
                profiles,
                image,
                &mask.mask,
                candidates_kind,
                Some(&progress),
            );
            progress.finish();
            normals
        }
    };
    stages.lap("normals");

    let voxel_m3 = grid.voxel_m.powi(3);
    let to_voxels = |m3: f64| (m3 / voxel_m3).round() as usize;
    let with_normal: Vec<bool> = mask
        .mask
        .iter()
        .zip(&normals)
        .map(|(&m, n)| m && n[0].is_finite())
        .collect();
    // Components that lie in the margin alone are not the echo region's.
    let label = |min_voxels: usize| {
        // Hidden voxels (key 2) never join the others (key 1).
        let keys: Vec<u32> = (with_normal.par_iter().enumerate())
            .map(|(v, &m)| u32::from(m) * (1 + u32::from(hidden.as_ref().is_some_and(|h| h[v]))))
            .collect();
        let labelled = label_6_keyed(&keys, grid.dims, min_voxels);
        if imaged.core.is_whole(grid) {
            return labelled;
        }
        retain_reaching(labelled, |v| imaged.core.contains(grid, v))
    };
    let mut min_voxels = to_voxels(config.min_component_m3);
    let mut labelled = label(min_voxels);
    let mut used_fallback = false;
    if labelled.sizes.is_empty() {
        min_voxels = to_voxels(config.fallback_component_m3);
        labelled = label(min_voxels);
        used_fallback = true;
    }
    // One range bin (c/2B) in voxels: the unit of the hidden search's rise and of the sidelobes.
    let bin_voxels = capture.plan.range_bin_m() / grid.voxel_m;
    if let (Some(hidden), Some(residual)) = (&hidden, &imaged.hidden_magnitude) {
        let rise_voxels = RISE_RANGE_BINS * bin_voxels;
        let (kept, report) = keep_above(
            labelled,
            hidden,
            magnitude,
            residual,
            grid.dims,
            rise_voxels,
        );
        tracing::info!(
            "hidden surfaces: {} voxels, {} components, {} kept",
            report.voxels,
            report.components,
            report.kept
        );
        labelled = kept;
        summary.hidden = Some(report);
    }
    if config.drop_sidelobes {
        let skip = hidden
            .as_deref()
            .map_or_else(Vec::new, |hidden| flagged_components(&labelled, hidden));
        let (kept, report) = drop_sidelobes(
            labelled,
            &skip,
            magnitude,
            grid.dims,
            grid.voxel_m,
            bin_voxels,
        );
        for d in &report.dropped {
            tracing::info!(
                "component {} ({} voxels) dropped as the range sidelobe of component {}: {:.1} cm under it, {:.1} dB",
                d.component,
                d.voxels,
                d.under,
                d.depth_m * 100.0,
                d.level_db
            );
        }
        labelled = kept;
        summary.sidelobes = Some(report);
    }
    summary.mask = Some(MaskSummary {
        normal_floor: config.normal_floor,
        exponent: mask.exponent,
        attempts: mask.attempts,
        voxels: mask_voxels,
        min_component_voxels: min_voxels,
        used_fallback_size: used_fallback,
    });
    if labelled.sizes.is_empty() {
        return Err(ReconError::NoComponent {
            fallback_voxels: min_voxels,
            fallback_m3: config.fallback_component_m3,
        });
    }
    if config.split_transitions {
        let (split, report) = split_at_transitions(
            &labelled,
            magnitude,
            &normals,
            grid.dims,
            grid.voxel_m,
            config.split_jump_m,
            min_voxels,
        );
        // A split that leaves nothing (every region under the size floor) keeps the components.
        if !split.sizes.is_empty() {
            labelled = split;
        }
        summary.split = Some(report);
    }
    stages.lap("components");

    let count = labelled.sizes.len();
    let hidden_components = hidden
        .as_deref()
        .map_or_else(Vec::new, |hidden| flagged_components(&labelled, hidden));
    let progress = Progress::new("rsdf", count as u64, quiet);
    let fields: Vec<SampledField> = (1..=count as u32)
        .map(|label| {
            let field = ComponentField {
                dims: grid.dims,
                voxel_m: grid.voxel_m,
                normals: &normals,
                labels: &labelled.labels,
                label,
            };
            let f = match config.integration {
                Integration::LeastSquares => integrate_least_squares(&field, 1e-6, 20_000),
                Integration::Bfs => integrate_bfs(&field),
            };
            progress.inc(1);
            crop(grid, &f)
        })
        .collect();
    progress.finish();
    stages.lap("rsdf");

    let range = |f: &SampledField| {
        f.values
            .iter()
            .filter(|v| v.is_finite())
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &v| {
                (a.min(f64::from(v)), b.max(f64::from(v)))
            })
    };
    let ranges: Vec<(f64, f64)> = fields.iter().map(range).collect();
    let step_m = config.optimisation.step_wavelengths * capture.plan.first_wavelength_m();
    let candidate_sets: Vec<Vec<f64>> = ranges
        .iter()
        .map(|&(lo, hi)| candidates(lo, hi, step_m, config.optimisation.bound_inset_m))
        .collect();
    Ok(Fields {
        normals,
        sizes: labelled.sizes,
        hidden: hidden_components,
        fields,
        ranges,
        candidate_sets,
        step_m,
    })
}

/// Chooses each component's constant by `isosurface` and extracts the points.
#[allow(clippy::too_many_arguments)]
fn mmnorm_points(
    capture: &Capture,
    config: &ReconConfig,
    isosurface: Isosurface,
    grid: &VoxelGrid,
    shared: &Fields,
    magnitude: &[f32],
    quiet: bool,
    summary: &mut Summary,
    stages: &mut Stages,
) -> Result<Points, ReconError> {
    let Fields {
        normals,
        sizes,
        hidden,
        fields,
        ranges,
        candidate_sets,
        step_m,
    } = shared;
    let weighted = |n: usize| {
        let values = component_values(grid, &fields[n], magnitude);
        let all = candidates(ranges[n].0, ranges[n].1, *step_m, 0.0);
        weighted_constant(&values, &all)
    };
    let constants: Vec<f64> = match isosurface {
        Isosurface::Center => ranges
            .iter()
            .map(|&(lo, hi)| centre_constant(lo, hi))
            .collect(),
        Isosurface::Weighted => (0..fields.len()).map(weighted).collect(),
        Isosurface::Optimized => {
            let o = &config.optimisation;
            let band_m = o.level_band_resolutions * capture.plan.range_bin_m();
            // The |S|-weighted levels, needed by the band, the edge fallback and the evidence
            // test alone; the optimiser gets them for the latter two.
            let judged_by_prior = o.evidence_t > 0.0 || o.edge_fallback;
            let priors: Vec<f64> = if band_m > 0.0 || judged_by_prior {
                (0..fields.len()).map(weighted).collect()
            } else {
                Vec::new()
            };
            let banded: Vec<Vec<f64>> = if band_m > 0.0 {
                (0..fields.len())
                    .map(|n| within_band(&candidate_sets[n], priors[n], band_m))
                    .collect()
            } else {
                candidate_sets.clone()
            };
            let priors = judged_by_prior.then_some(priors.as_slice());
            let report = optimise(capture, fields, &banded, hidden, priors, o, quiet)?;
            let c = report.components.iter().map(|c| c.constant).collect();
            summary.optimisation = Some(report);
            c
        }
    };
    stages.lap("isosurface");

    let mut points = Vec::new();
    let mut point_normals = Vec::new();
    let mut comps = Vec::new();
    for (n, field) in fields.iter().enumerate() {
        let g = &field.grid;
        let before = points.len();
        for (v, &f) in field.values.iter().enumerate() {
            if f.is_finite() && (f64::from(f) - constants[n]).abs() < 0.5 * g.voxel_m {
                let p = g.centre_of(v);
                let normal = normals[flat_index(grid, &p)];
                points.push(p);
                point_normals.push(normal.map(f64::from));
                comps.push(n as u32 + 1);
            }
        }
        summary.components.push(ComponentSummary {
            component: n as u32 + 1,
            voxels: sizes[n],
            rsdf_min_m: ranges[n].0,
            rsdf_max_m: ranges[n].1,
            constant_m: constants[n],
            points: points.len() - before,
        });
    }
    stages.lap("points");
    Ok((points, Some(point_normals), comps))
}

/// The candidates within `band_m` of `level`; the nearest one when none is.
fn within_band(candidates: &[f64], level: f64, band_m: f64) -> Vec<f64> {
    let inside: Vec<f64> = candidates
        .iter()
        .copied()
        .filter(|c| (c - level).abs() <= band_m)
        .collect();
    if !inside.is_empty() {
        return inside;
    }
    nearest_candidate(candidates, level)
        .map(|i| candidates[i])
        .into_iter()
        .collect()
}

/// The flat index in `grid` of the voxel centred at `p` (a centre of a sub-grid of `grid`).
/// Unit normals from vote vectors where `selected` (NaN elsewhere and where the votes vanish).
fn normalised_votes(votes: &[[f32; 3]], selected: &[bool]) -> Vec<[f32; 3]> {
    votes
        .iter()
        .zip(selected)
        .map(|(w, &on)| {
            let len = (w[0] * w[0] + w[1] * w[1] + w[2] * w[2]).sqrt();
            if on && len > 0.0 {
                w.map(|c| c / len)
            } else {
                [f32::NAN; 3]
            }
        })
        .collect()
}

fn flat_index(grid: &VoxelGrid, p: &[f64; 3]) -> usize {
    let [_, ny, nz] = grid.dims;
    let i = [0, 1, 2].map(|a| ((p[a] - grid.origin_m[a]) / grid.voxel_m).round() as usize);
    (i[0] * ny + i[1]) * nz + i[2]
}

/// The component's RSDF cropped to its bounding box plus one voxel.
fn crop(grid: &VoxelGrid, f: &[f32]) -> SampledField {
    let [nx, ny, nz] = grid.dims;
    let mut lo = [usize::MAX; 3];
    let mut hi = [0usize; 3];
    for (v, x) in f.iter().enumerate() {
        if x.is_finite() {
            let c = [v / (ny * nz), (v / nz) % ny, v % nz];
            for a in 0..3 {
                lo[a] = lo[a].min(c[a]);
                hi[a] = hi[a].max(c[a]);
            }
        }
    }
    let lo = [0, 1, 2].map(|a| lo[a].saturating_sub(1));
    let hi = [
        hi[0].min(nx - 2) + 1,
        hi[1].min(ny - 2) + 1,
        hi[2].min(nz - 2) + 1,
    ];
    let dims = [0, 1, 2].map(|a| hi[a] - lo[a] + 1);
    let sub = VoxelGrid {
        origin_m: grid.centre(lo[0], lo[1], lo[2]),
        voxel_m: grid.voxel_m,
        dims,
    };
    let mut values = Vec::with_capacity(sub.len());
    for i in lo[0]..=hi[0] {
        for j in lo[1]..=hi[1] {
            for k in lo[2]..=hi[2] {
                values.push(f[(i * ny + j) * nz + k]);
            }
        }
    }
    SampledField { grid: sub, values }
}

/// (f, |S|) for the component's voxels.
fn component_values(grid: &VoxelGrid, field: &SampledField, magnitude: &[f32]) -> Vec<(f32, f32)> {
    let g = &field.grid;
    field
        .values
        .iter()
        .enumerate()
        .filter(|(_, f)| f.is_finite())
        .map(|(v, &f)| {
            let p = g.centre_of(v);
            (f, magnitude[flat_index(grid, &p)])
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::recon::config::{KnownOccluder, VolumeSpec};
    use crate::sim::{Scene, simulate};
    use std::sync::Arc;

    /// `imaging = "auto"` takes range migration for a raster and says why, and backprojection
    /// once one antenna sits off the lattice by more than `raster_tolerance`; `"rma"` then
    /// refuses the capture instead of falling back.
    #[test]
    fn auto_imaging_takes_range_migration_only_for_a_raster() {
        let text = "[radar]\nstart_frequency_hz = 77e9\nfrequency_step_hz = 7.8125e6\nsamples_per_chirp = 128\n\
            [aperture]\nwidth_m = 0.024\nheight_m = 0.024\nspacing_m = 0.003\nz_m = 0.3\n\
            [[object]]\nshape = \"point\"\nposition_m = [0.0, 0.0, 0.0]\nrcs_m2 = 1.0\n";
        let scene = Scene::parse(text, std::path::Path::new("inline.toml")).unwrap();
        let raster = simulate(&scene, true).capture;
        let config = |imaging| ReconConfig {
            imaging,
            volume: VolumeSpec::Box([-0.004, 0.004, -0.004, 0.004, -0.004, 0.004]),
            voxel_m: 0.002,
            ..ReconConfig::default()
        };
        let used = |capture: &Capture, imaging| {
            image_volume(capture, &config(imaging), true).map(|i| i.imaging)
        };
        let on_raster = used(&raster, Imaging::Auto).unwrap();
        assert_eq!(on_raster.used, Imaging::Rma);
        assert!(on_raster.reason.contains("raster"), "{}", on_raster.reason);
        assert!(on_raster.rma.is_some());

        // One antenna 1 mm off its node: a third of the spacing, past the 0.1 tolerance.
        let mut moved = raster.clone();
        moved.tx_m[5][0] += 0.001;
        moved.rx_m[5][0] += 0.001;
        let off_raster = used(&moved, Imaging::Auto).unwrap();
        assert_eq!(off_raster.used, Imaging::Backprojection);
        assert!(!off_raster.reason.is_empty() && off_raster.rma.is_none());
        assert!(used(&moved, Imaging::Rma).is_err());
    }

    /// The capture of a point target of `rcs_m2` at the origin, under the `[radar]` and
    /// `[aperture]` tables of `setup` and `sheet` (an `[occluder]` table, or nothing).
    fn point_target_capture(setup: &str, sheet: &str, rcs_m2: f64) -> Capture {
        let text = format!(
            "{setup}{sheet}[[object]]\nshape = \"point\"\nposition_m = [0.0, 0.0, 0.0]\nrcs_m2 = {rcs_m2:?}\n"
        );
        let scene = Scene::parse(&text, std::path::Path::new("inline.toml")).unwrap();
        simulate(&scene, true).capture
    }

    /// A weak point target 12 cm under an unbounded sheet, as in the accuracy suite's NLOS
    /// scenes. The sheet's echo is far stronger than the target's and lies 2.4 raw range bins
    /// nearer, so its range sidelobes spread over the whole imaged box. Removed before imaging,
    /// the box holds the target's image alone again, as in the open scene.
    #[test]
    fn a_known_sheets_echo_is_kept_out_of_the_image() {
        let scene = |sheet: &str| {
            point_target_capture(
                "[radar]\nstart_frequency_hz = 77.5e9\nfrequency_step_hz = 5.859375e6\nsamples_per_chirp = 512\n\
                 [aperture]\nwidth_m = 0.06\nheight_m = 0.06\nspacing_m = 0.003\nz_m = 0.3\n",
                sheet,
                1e-4,
            )
        };
        let open = scene("");
        let covered = scene(
            "[occluder]\nz_m = 0.12\nthickness_m = 0.004\nrefractive_index = 1.6\nloss_db = 1.0\n",
        );
        // Share of |S|² more than 1.5 cm from the target.
        let stray = |capture: &Capture, remove_echo: Option<bool>| {
            let config = ReconConfig {
                volume: VolumeSpec::Box([-0.03, 0.03, -0.03, 0.03, -0.03, 0.05]),
                voxel_m: 0.002,
                occluder: remove_echo.map(|remove_echo| KnownOccluder {
                    thickness_m: 0.004,
                    refractive_index: 1.6,
                    remove_echo,
                }),
                ..ReconConfig::default()
            };
            let imaged = image_volume(capture, &config, true).unwrap();
            let [nx, ny, nz] = imaged.grid.dims;
            let (mut far, mut all) = (0.0f64, 0.0f64);
            for i in 0..nx {
                for j in 0..ny {
                    for k in 0..nz {
                        let p = imaged.grid.centre(i, j, k);
                        let e = f64::from(imaged.magnitude[(i * ny + j) * nz + k]).powi(2);
                        all += e;
                        if (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt() > 0.015 {
                            far += e;
                        }
                    }
                }
            }
            (far / all, imaged.imaging.near_echo_antennas)
        };
        let (reference, _) = stray(&open, None);
        let (left_in, _) = stray(&covered, Some(false));
        let (removed, antennas) = stray(&covered, Some(true));
        println!(
            "|S|² beyond 1.5 cm of the target: {reference:.3} in the open, {left_in:.3} under the \
             sheet with its echo left in, {removed:.3} with it removed ({antennas:?} antennas)"
        );
        assert_eq!(antennas, Some(open.antennas()));
        assert!(left_in > reference + 0.3, "{left_in} vs {reference}");
        assert!(
            (removed - reference).abs() < 0.05,
            "{removed} vs {reference}"
        );
    }

    /// A point target under a 4 mm sheet of index 1.6, imaged from 30 cm with a narrow
    /// aperture (incidence below 4°): each leg is (n − 1)·t = 2.4 mm longer, so the image
    /// peak sits 2.4 mm deeper than without the sheet, and with the sheet known it returns to
    /// where the open scene puts it. (A 3 cm aperture localises depth by bandwidth alone: the
    /// peak of |S| is flat and rippled to a few tenths of a millimetre, so the checks compare
    /// the images with and without the sheet rather than with the target.) The sheet is 4 cm
    /// wide, enough to cover every path, and the target strong, so that the sheet's own echo,
    /// 15 cm nearer, stays out of the target's peak.
    #[test]
    fn a_known_sheet_moves_the_image_back_to_the_target() {
        let scene = |sheet: &str| {
            point_target_capture(
                "[radar]\nstart_frequency_hz = 77e9\nfrequency_step_hz = 7.8125e6\nsamples_per_chirp = 512\n\
                 [aperture]\nwidth_m = 0.03\nheight_m = 0.03\nspacing_m = 0.003\nz_m = 0.3\n",
                sheet,
                1.0,
            )
        };
        let open = scene("");
        let covered = scene(
            "[occluder]\nz_m = 0.15\nthickness_m = 0.004\nrefractive_index = 1.6\nloss_db = 1.0\nsize_m = [0.04, 0.04]\n",
        );
        let peak_z_m = |capture: &Capture, occluder: Option<KnownOccluder>| {
            let config = ReconConfig {
                imaging: Imaging::Backprojection,
                volume: VolumeSpec::Box([-0.002, 0.002, -0.002, 0.002, -0.006, 0.004]),
                voxel_m: 0.0002,
                occluder,
                ..ReconConfig::default()
            };
            let imaged = image_volume(capture, &config, true).unwrap();
            let m = &imaged.magnitude;
            let peak = (0..m.len()).max_by(|&a, &b| m[a].total_cmp(&m[b])).unwrap();
            let [_, ny, nz] = imaged.grid.dims;
            imaged
                .grid
                .centre(peak / (ny * nz), peak / nz % ny, peak % nz)[2]
        };
        let known = KnownOccluder {
            thickness_m: 0.004,
            refractive_index: 1.6,
            remove_echo: true,
        };
        let reference = peak_z_m(&open, None);
        let plain = peak_z_m(&covered, None);
        let compensated = peak_z_m(&covered, Some(known));
        println!(
            "peak z: {:.2} mm without the sheet, {:.2} mm under it, {:.2} mm under it known \
             (expected shift 2.4 mm)",
            reference * 1e3,
            plain * 1e3,
            compensated * 1e3
        );
        assert!(
            (compensated - plain - 0.0024).abs() <= 0.0003,
            "{plain} → {compensated}"
        );
        assert!(
            (compensated - reference).abs() <= 0.0011,
            "{compensated} vs {reference}"
        );
        assert!(
            (plain - reference).abs() >= 0.0015,
            "{plain} vs {reference}"
        );
        // The capture seen through the sheet shares its samples: at the paper's aperture they
        // are 4.7 GB, and every entry point takes this view.
        let config = ReconConfig {
            occluder: Some(known),
            ..ReconConfig::default()
        };
        let seen = through_occluder(&covered, &config);
        assert!(matches!(seen, Cow::Owned(_)));
        assert!(Arc::ptr_eq(&seen.samples, &covered.samples));
        assert!(
            (seen.range_offset_m - covered.range_offset_m - known.extra_round_trip_m()).abs()
                < 1e-12
        );
        // Bad values are named.
        let bad = ReconConfig {
            occluder: Some(KnownOccluder {
                thickness_m: 0.004,
                refractive_index: 0.5,
                remove_echo: true,
            }),
            ..ReconConfig::default()
        };
        let e = bad.validate().unwrap_err().to_string();
        assert!(e.contains("occluder.refractive_index = 0.5"), "{e}");
    }

    /// The band keeps the candidates within its half-width of the level, and the nearest one
    /// when it holds none.
    #[test]
    fn the_band_keeps_candidates_near_the_weighted_level() {
        let all: Vec<f64> = (0..10).map(|i| 0.002 * f64::from(i)).collect();
        let kept = within_band(&all, 0.0101, 0.0045);
        assert_eq!(kept.len(), 5, "{kept:?}");
        assert!((kept[0] - 0.006).abs() < 1e-12 && (kept[4] - 0.014).abs() < 1e-12);
        assert_eq!(within_band(&all, 0.0101, 0.0005), vec![all[5]]);
        assert_eq!(within_band(&all, 0.05, 0.001), vec![all[9]]);
    }
}
