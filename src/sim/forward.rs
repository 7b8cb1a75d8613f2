//! The forward model: a scene in, a capture out.
//!
//! Every reflection is single-bounce, with free-space spreading 1/(d_tx·d_rx) and visibility
//! checked by shadow rays on both the TX and the RX leg: against other objects through their
//! BVHs, and against the scatterer's own object through the exact per-triangle candidate lists
//! of [`FrontOccluders`] (the BVH where a list is too long). Amplitudes are in *image units*: a
//! scatterer of bistatic RCS σ returns `√(σ/4π)/(d_tx·d_rx)`, so an infinite mirror at distance R
//! returns 1/(2R). Three surface terms, one per physical mechanism:
//!
//! 1. **Specular (physical optics).** Each λ/4 sample of area A contributes
//!    `−j·ρ·A/λ_t · ½(cos θ_tx + cos θ_rx) · W(θ_b) / (d_tx·d_rx)` along its path, the scalar PO
//!    integrand. Specularity is not imposed: it emerges from the coherent sum, whose stationary
//!    point is the mirror point. W is a smooth window on θ_b, the angle between the sample
//!    normal and the bistatic bisector, measured in Fresnel zones: near a mirror point the
//!    first zone spans θ_F = √(λ0·(κ + 1/d)/2) of θ_b, with κ the surface curvature and d the
//!    mean leg length (4° for a plate at 40 cm, 12° for a 5 cm sphere). W is 1 up to
//!    `specular_full_zones`·θ_F and falls as a raised cosine to 0 at
//!    `specular_cutoff_zones`·θ_F. It keeps the stationary-phase region and drops the
//!    far-off-specular part of the integral, which cancels anyway except at discontinuities;
//!    those are handled by term 3. The −j and the 1/λ_t make the stationary-phase sum equal
//!    image theory. The tests `plate_return_matches_image_theory` and
//!    `sphere_return_matches_geometric_optics` (a/(2R(R+a))) check both.
//! 2. **Diffuse (directive model).** One sample per λ0² of area, each with a fixed random
//!    phase (frozen roughness), scatter with the Degli-Esposti directive lobe: bistatic RCS
//!    `σ = 4π·S²·A·cos θ_i·((1 + cos ψ)/2)^α · (α + 1)/(4π)`, where ψ is the angle between the
//!    scattered direction and the specular direction. The (α + 1)/4π normalises the lobe over
//!    the sphere.
//! 3. **Edge diffraction.** Pieces of sharp edges of length dl contribute
//!    `e·dl/(2π)/(d_tx·d_rx)` (e: the material's `edge` scale), visible only from the wedge's exterior. Summed coherently along a
//!    straight edge this gives the half-plane's broadside RCS L²/π, and Keller's cone emerges
//!    from the stationary phase along the edge.
//!
//! Point targets (calibration objects) return `√(σ/4π)/(d_tx·d_rx)` with no phase shift. The
//! reconstruction's own forward model is not used here.

use std::f32::consts::PI;

use num_complex::Complex32;
use rayon::prelude::*;

mod points;

use super::aperture::{Antennas, Pattern, raster_antennas};
use super::scene::{ObjectGeometry, Occluder, PatternKind, Physics, Scene};
use super::surface::{self, Cluster, EdgeSample, Samples};
use super::truth;
use crate::SPEED_OF_LIGHT_M_PER_S;
use crate::capture::{Capture, FrequencyPlan};
use crate::geometry::vec3::{add, dot, scale, sub};
use crate::geometry::{Bvh, FrontOccluders, LocalVisibility, TriMesh, ViewRegion};
use crate::progress::Progress;
use crate::signal::{Rng, ToneAccumulator};

/// Shadow-ray origins are moved this far off the surface.
const RAY_OFFSET_M: f32 = 1e-4;
/// Stream keys of the seeded generator.
const ROUGHNESS_STREAM: u64 = 1;
const NOISE_STREAM: u64 = 2;

/// Counts and timings of one simulation.
#[derive(Debug, Clone, Default, serde::Serialize)]
pub struct SimStats {
    pub antennas: usize,
    pub triangles: usize,
    pub specular_samples: usize,
    pub diffuse_samples: usize,
    pub edge_samples: usize,
    pub point_targets: usize,
    /// Visible scatterer–antenna pairs that were summed.
    pub contributions: u64,
    pub noise_sigma: f64,
    pub seconds: f64,
}

/// What a simulation produces.
#[derive(Debug, Clone)]
pub struct SimOutput {
    pub capture: Capture,
    pub antennas: Antennas,
    /// All surface objects as one mesh (the occluder is not part of the truth).
    pub truth_mesh: TriMesh,
    pub stats: SimStats,
}

/// Scatterers in the form the per-antenna loop wants.
struct Scatterers {
    spec: Samples,
    /// ρ·A per specular sample.
    spec_weight: Vec<f32>,
    clusters: Vec<Cluster>,
    /// Cosine and sine of (widest window + cone half-angle) per cluster, for culling.
    cluster_limit: Vec<(f32, f32)>,
    diff: Samples,
    /// S·√(A·(α+1)/4π) per diffuse sample, α/2, and the roughness phasor.
    diff_weight: Vec<f32>,
    diff_half_alpha: Vec<f32>,
    diff_phasor: Vec<Complex32>,
    edges: Vec<EdgeSample>,
    edge_weight: Vec<f32>,
    points: Vec<([f32; 3], f32)>,
    /// Object index of each cluster, diffuse sample and edge sample.
    cluster_object: Vec<u16>,
    diff_object: Vec<u16>,
    edge_object: Vec<u16>,
    /// One BVH per object (empty for point targets) and its front-side occluder lists.
    bvhs: Vec<Bvh>,
    local: Vec<FrontOccluders>,
    /// The point-scatterer model's scatterers; the surface terms above are then empty.
    point_model: Option<points::PointScatterers>,
}

/// Longest per-triangle occluder list kept before falling back to the BVH.
const MAX_LOCAL_OCCLUDERS: usize = 48;

/// No object: point targets test every object's geometry.
const NO_OBJECT: u16 = u16::MAX;

struct Ctx<'a> {
    s: &'a Scatterers,
    pattern: Pattern,
    occluder: Option<&'a Occluder>,
    full_zones: f32,
    cutoff_zones: f32,
    /// λ0/2, for the Fresnel-zone width.
    half_lambda0_m: f32,
}

/// Largest window the specular term uses, radians.
const MAX_WINDOW_RAD: f32 = 1.45;

/// Angular width of the first Fresnel zone in θ_b for curvature `kappa` and leg length `d`.
#[inline]
fn fresnel_zone_rad(half_lambda0_m: f32, kappa_per_m: f32, d_m: f32) -> f32 {
    (half_lambda0_m * (kappa_per_m + 1.0 / d_m)).sqrt()
}

/// Direction and distance from `p` to `a`.
#[inline]
fn towards(p: [f32; 3], a: [f32; 3]) -> ([f32; 3], f32) {
    let v = sub(a, p);
    let d = dot(v, v).sqrt();
    (scale(v, 1.0 / d), d)
}

fn f32v(p: [f64; 3]) -> [f32; 3] {
    p.map(|c| c as f32)
}

/// The scene's scatterers, prepared once, rendered at any antenna positions.
pub struct ForwardModel {
    scatterers: Scatterers,
    pattern: Pattern,
    occluder: Option<Occluder>,
    plan: FrequencyPlan,
    range_offset_m: f64,
    full_zones: f32,
    cutoff_zones: f32,
    half_lambda0_m: f32,
    inv_wavelength: Vec<f32>,
    /// All surface objects as one mesh (the occluder is not part of the truth).
    pub truth_mesh: TriMesh,
}

/// What [`ForwardModel::render_position`] rendered besides the chirps.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Rendered {
    /// Visible scatterer–antenna pairs that were summed.
    pub contributions: u64,
    /// Σ|s|² over the chirps' samples before the sheet's own reflection was added: the
    /// objects' echoes alone (through the sheet where it lies between).
    pub objects_energy: f64,
}

impl std::ops::Add for Rendered {
    type Output = Rendered;
    fn add(self, other: Rendered) -> Rendered {
        Rendered {
            contributions: self.contributions + other.contributions,
            objects_energy: self.objects_energy + other.objects_energy,
        }
    }
}

/// Σ|s|² of a chirp, in f64.
fn energy(chirp: &[Complex32]) -> f64 {
    chirp.iter().map(|s| f64::from(s.norm_sqr())).sum()
}

/// Per-thread accumulators of [`ForwardModel::render_position`].
pub struct RenderScratch {
    spec: Vec<ToneAccumulator>,
    other: Vec<ToneAccumulator>,
}

impl ForwardModel {
    /// Samples the scene's objects for antennas inside `view`.
    pub fn new(scene: &Scene, view: &ViewRegion) -> Self {
        let plan = scene.plan;
        let lambda0_m = plan.first_wavelength_m();
        let (scatterers, truth_mesh) = prepare(scene, view);
        let set = &scene.settings;
        // The point-scatterer model has no antenna pattern.
        let pattern = match scene.physics {
            Physics::PhysicalOptics => scene.aperture.pattern,
            Physics::PointScatterer(_) => PatternKind::Isotropic,
        };
        Self {
            scatterers,
            pattern: Pattern::new(pattern, scene.aperture.rx_axis),
            occluder: scene.occluder,
            plan,
            range_offset_m: scene.range_offset_m,
            full_zones: set.specular_full_zones as f32,
            cutoff_zones: set.specular_cutoff_zones as f32,
            half_lambda0_m: (lambda0_m / 2.0) as f32,
            inv_wavelength: (0..plan.samples_per_chirp)
                .map(|k| (plan.frequency_hz(k) / SPEED_OF_LIGHT_M_PER_S) as f32)
                .collect(),
            truth_mesh,
        }
    }

    /// Accumulators for positions with up to `rx_per_position` receivers.
    pub fn scratch(&self, rx_per_position: usize) -> RenderScratch {
        let acc = ToneAccumulator::new(&self.plan, self.range_offset_m);
        RenderScratch {
            spec: vec![acc.clone(); rx_per_position],
            other: vec![acc; rx_per_position],
        }
    }

    /// The noise-free chirps of one TX position and its receivers, written into `out`
    /// (`rxs.len()` chirps of T samples, RX-minor), with what [`Rendered`] counts.
    pub fn render_position(
        &self,
        tx_m: [f64; 3],
        rxs_m: &[[f64; 3]],
        scratch: &mut RenderScratch,
        out: &mut [Complex32],
    ) -> Rendered {
        let ctx = Ctx {
            s: &self.scatterers,
            pattern: self.pattern,
            occluder: self.occluder.as_ref(),
            full_zones: self.full_zones,
            cutoff_zones: self.cutoff_zones,
            half_lambda0_m: self.half_lambda0_m,
        };
        let per = rxs_m.len();
        if scratch.spec.len() < per {
            *scratch = self.scratch(per);
        }
        let (spec, other) = (&mut scratch.spec[..per], &mut scratch.other[..per]);
        spec.iter_mut()
            .chain(other.iter_mut())
            .for_each(ToneAccumulator::clear);
        let rxs: Vec<[f32; 3]> = rxs_m.iter().map(|r| f32v(*r)).collect();
        let count = ctx.position(f32v(tx_m), &rxs, spec, other);
        let t = self.plan.samples_per_chirp;
        let mut objects_energy = 0.0;
        for (k, chirp) in out.chunks_exact_mut(t).take(per).enumerate() {
            chirp.fill(Complex32::new(0.0, 0.0));
            spec[k].scale_by(&self.inv_wavelength);
            spec[k].add_into(chirp);
            other[k].add_into(chirp);
            objects_energy += energy(chirp);
            if let Some(occ) = &self.occluder
                && let Some((factors, path_m)) = occ.reflection(&self.plan, tx_m, rxs_m[k])
            {
                add_sheet_reflection(&self.plan, self.range_offset_m, &factors, path_m, chirp);
            }
        }
        Rendered {
            contributions: count,
            objects_energy,
        }
    }

    /// σ per sample of noise `snr_db` below the objects' echo in `samples`, which
    /// [`Self::render_position`] rendered with `rendered`.
    ///
    /// Receiver noise is the receiver's, not the scene's: the same objects must meet the same
    /// noise floor with the cardboard and without it. So the reference is the objects' mean
    /// echo power as it would arrive without the sheet: their power as rendered (the sheet's
    /// own reflection left out) over the sheet's round-trip power transmission at normal
    /// incidence (exact for paths at normal incidence; paths at θ cross it with
    /// loss_db/cos θ_t per leg, 0.1 dB more at 30°). Neither the sheet's reflection, often far
    /// stronger than the objects, nor its loss moves the floor. A scene whose objects return
    /// nothing is referred to the mean power of `samples` instead.
    pub fn noise_sigma(&self, snr_db: f64, rendered: &Rendered, samples: &[Complex32]) -> f64 {
        let count = samples.len().max(1) as f64;
        let objects_power = rendered.objects_energy / count;
        let reference = if objects_power > 0.0 {
            let transmission = self
                .occluder
                .as_ref()
                .map_or(1.0, Occluder::round_trip_power_transmission);
            objects_power / transmission
        } else {
            samples
                .par_iter()
                .map(|s| f64::from(s.norm_sqr()))
                .sum::<f64>()
                / count
        };
        (reference / 10f64.powf(snr_db / 10.0)).sqrt()
    }

    /// Scatterer counts for [`SimStats`].
    fn counts(&self) -> (usize, usize, usize, usize) {
        let s = &self.scatterers;
        match &s.point_model {
            Some(ps) => (ps.surface_samples(), 0, ps.edges.len(), s.points.len()),
            None => (s.spec.len(), s.diff.len(), s.edges.len(), s.points.len()),
        }
    }
}

/// Runs the forward model over every antenna of the scene's aperture, with a progress bar
/// (`quiet` hides it).
pub fn simulate(scene: &Scene, quiet: bool) -> SimOutput {
    simulate_with(scene, |antennas| Progress::new("simulate", antennas, quiet))
}

/// [`simulate`], reporting through the [`Progress`] that `progress` makes for the number of
/// antennas.
pub fn simulate_with(scene: &Scene, progress: impl FnOnce(u64) -> Progress) -> SimOutput {
    let started = std::time::Instant::now();
    let plan = scene.plan;
    let lambda0_m = plan.first_wavelength_m();
    let antennas = raster_antennas(&scene.aperture, &scene.rx_channels(), lambda0_m);
    let model = ForwardModel::new(scene, &view_region(&antennas));
    let t = plan.samples_per_chirp;
    let n = antennas.tx_m.len();
    let mut samples = vec![Complex32::new(0.0, 0.0); n * t];
    let per = antennas.per_position.max(1);
    let progress = progress(n as u64);
    let rendered = samples
        .par_chunks_mut(t * per)
        .enumerate()
        .map_init(
            || model.scratch(per),
            |scratch, (position, out)| {
                let first = position * per;
                let rendered = model.render_position(
                    antennas.tx_m[first],
                    &antennas.rx_m[first..first + per],
                    scratch,
                    out,
                );
                progress.inc(per as u64);
                rendered
            },
        )
        .reduce(Rendered::default, |a, b| a + b);
    progress.finish();

    let noise_sigma = match scene.noise {
        Some((snr_db, seed)) => {
            let sigma = model.noise_sigma(snr_db, &rendered, &samples);
            add_noise(&mut samples, t, sigma, seed);
            sigma
        }
        None => 0.0,
    };
    let (specular_samples, diffuse_samples, edge_samples, point_targets) = model.counts();
    let stats = SimStats {
        antennas: n,
        triangles: model.truth_mesh.triangles.len(),
        specular_samples,
        diffuse_samples,
        edge_samples,
        point_targets,
        contributions: rendered.contributions,
        noise_sigma,
        seconds: started.elapsed().as_secs_f64(),
    };
    let capture = Capture {
        plan,
        range_offset_m: scene.range_offset_m,
        tx_m: antennas.tx_m.clone(),
        rx_m: antennas.rx_m.clone(),
        samples: samples.into(),
        description: scene.description.clone(),
        extra: serde_json::Map::new(),
    };
    SimOutput {
        capture,
        antennas,
        truth_mesh: model.truth_mesh,
        stats,
    }
}

/// The direction shadow rays leave an edge sample by: a rim's (one face, `n1 == n2`) normal
/// turned to the side `towards_tx` lies on, or a crease's normal bisector (both face normals
/// point into the open side, convex or not).
fn edge_offset_dir(e: &EdgeSample, towards_tx: [f32; 3]) -> [f32; 3] {
    if e.n1 == e.n2 {
        if dot(e.n1, towards_tx) >= 0.0 {
            e.n1
        } else {
            scale(e.n1, -1.0)
        }
    } else {
        let m = add(e.n1, e.n2);
        scale(m, 1.0 / dot(m, m).sqrt().max(1e-6))
    }
}

fn add_sheet_reflection(
    plan: &FrequencyPlan,
    range_offset_m: f64,
    factors: &[Complex32],
    path_m: f64,
    out: &mut [Complex32],
) {
    for (k, (o, g)) in out.iter_mut().zip(factors).enumerate() {
        let phase = std::f64::consts::TAU
            * (plan.frequency_hz(k) * (path_m + range_offset_m) / SPEED_OF_LIGHT_M_PER_S).fract();
        let (s, c) = phase.sin_cos();
        *o += g * Complex32::new(c as f32, s as f32) / path_m as f32;
    }
}

/// Adds complex Gaussian noise of σ per sample (σ/√2 on I and on Q), chirp i from the seeded
/// stream i.
fn add_noise(samples: &mut [Complex32], t: usize, sigma: f64, seed: u64) {
    let per_component = sigma / std::f64::consts::SQRT_2;
    samples
        .par_chunks_mut(t)
        .enumerate()
        .for_each(|(i, chirp)| add_noise_to_chirp(chirp, per_component, seed, i as u64));
}

/// Adds complex Gaussian noise of `per_component_sigma` on I and on Q to one chirp, from the
/// seeded stream `index` of the noise generator.
pub fn add_noise_to_chirp(
    chirp: &mut [Complex32],
    per_component_sigma: f64,
    seed: u64,
    index: u64,
) {
    let mut rng = Rng::for_stream(seed, NOISE_STREAM, index);
    for s in chirp {
        let (a, b) = rng.normal_pair();
        s.re += (a * per_component_sigma) as f32;
        s.im += (b * per_component_sigma) as f32;
    }
}

/// The rectangle that holds every TX and RX position (all lie in the aperture plane).
fn view_region(antennas: &Antennas) -> ViewRegion {
    let mut x_m = [f64::INFINITY, f64::NEG_INFINITY];
    let mut y_m = x_m;
    let mut z_m = f64::NEG_INFINITY;
    for p in antennas.tx_m.iter().chain(&antennas.rx_m) {
        x_m = [x_m[0].min(p[0]), x_m[1].max(p[0])];
        y_m = [y_m[0].min(p[1]), y_m[1].max(p[1])];
        z_m = z_m.max(p[2]);
    }
    ViewRegion { x_m, y_m, z_m }
}

/// Samples every object and merges the surfaces into the truth mesh.
fn prepare(scene: &Scene, view: &ViewRegion) -> (Scatterers, TriMesh) {
    let set = &scene.settings;
    let mut s = Scatterers {
        spec: Samples::default(),
        spec_weight: Vec::new(),
        clusters: Vec::new(),
        cluster_limit: Vec::new(),
        diff: Samples::default(),
        diff_weight: Vec::new(),
        diff_half_alpha: Vec::new(),
        diff_phasor: Vec::new(),
        edges: Vec::new(),
        edge_weight: Vec::new(),
        points: Vec::new(),
        cluster_object: Vec::new(),
        diff_object: Vec::new(),
        edge_object: Vec::new(),
        bvhs: Vec::new(),
        local: Vec::new(),
        point_model: match &scene.physics {
            Physics::PhysicalOptics => None,
            Physics::PointScatterer(model) => Some(points::PointScatterers::new(model)),
        },
    };
    let lambda0_m = scene.plan.first_wavelength_m();
    let half_lambda0_m = (scene.plan.first_wavelength_m() / 2.0) as f32;
    let mut rough = Rng::for_stream(scene.seed, ROUGHNESS_STREAM, 0);
    for (index, object) in scene.objects.iter().enumerate() {
        let m = object.material;
        let id = index.min(usize::from(NO_OBJECT) - 1) as u16;
        match &object.geometry {
            ObjectGeometry::Point { position_m, rcs_m2 } => {
                let amp = (rcs_m2 / (4.0 * std::f64::consts::PI)).sqrt() as f32;
                s.points.push((f32v(*position_m), amp));
                s.bvhs.push(Bvh::build(&TriMesh::default()));
                s.local.push(FrontOccluders::default());
            }
            ObjectGeometry::Surface(mesh)
                if let Physics::PointScatterer(model) = &scene.physics =>
            {
                if let Some(ps) = s.point_model.as_mut() {
                    ps.add_object(model, mesh, id, lambda0_m, (m.reflectivity, m.edge));
                }
                push_visibility(&mut s, mesh, view, &object.name);
            }
            ObjectGeometry::Surface(mesh) => {
                let normals = surface::corner_normals(mesh, set.crease_angle_deg);
                let base = s.spec.len() as u32;
                let (spec, clusters) =
                    surface::sample_surface(mesh, &normals, set.sample_spacing_m);
                s.spec_weight
                    .extend(spec.area_m2.iter().map(|a| a * m.reflectivity as f32));
                for mut c in clusters {
                    c.first += base;
                    // The widest window any antenna can give this cluster: the nearest
                    // antenna is at least the height gap away.
                    let gap = (scene.aperture.z_m as f32 - c.centre[2] - c.radius_m).max(1e-3);
                    let widest = (set.specular_cutoff_zones as f32
                        * fresnel_zone_rad(half_lambda0_m, c.curvature_per_m, gap))
                    .min(MAX_WINDOW_RAD);
                    let limit = (f64::from(widest) + f64::from(c.cos_half_angle).acos())
                        .min(std::f64::consts::PI);
                    s.cluster_limit
                        .push((limit.cos() as f32, limit.sin() as f32));
                    s.clusters.push(c);
                    s.cluster_object.push(id);
                }
                s.spec.append(spec);
                if m.diffuse > 0.0 {
                    let diff =
                        surface::sample_by_area(mesh, &normals, set.diffuse_spacing_m, &mut rough);
                    s.diff_object.extend(std::iter::repeat_n(id, diff.len()));
                    let norm = (m.diffuse_exponent + 1.0) / (4.0 * std::f64::consts::PI);
                    for &a in &diff.area_m2 {
                        s.diff_weight
                            .push((m.diffuse * (f64::from(a) * norm).sqrt()) as f32);
                        s.diff_half_alpha.push((m.diffuse_exponent / 2.0) as f32);
                        let (sn, cs) = (std::f64::consts::TAU * rough.uniform()).sin_cos();
                        s.diff_phasor.push(Complex32::new(cs as f32, sn as f32));
                    }
                    s.diff.append(diff);
                }
                if m.edge > 0.0 {
                    let edges =
                        surface::sample_edges(mesh, set.crease_angle_deg, set.sample_spacing_m);
                    s.edge_weight.extend(
                        edges
                            .iter()
                            .map(|e| (m.edge as f32) * e.length_m / (2.0 * PI)),
                    );
                    s.edge_object.extend(std::iter::repeat_n(id, edges.len()));
                    s.edges.extend(edges);
                }
                push_visibility(&mut s, mesh, view, &object.name);
            }
        }
    }
    (s, truth::scene_mesh(scene))
}

/// The object's BVH and its front-side occluder lists, for shadow rays.
fn push_visibility(s: &mut Scatterers, mesh: &TriMesh, view: &ViewRegion, name: &str) {
    s.bvhs.push(Bvh::build(mesh));
    // Ray origins sit RAY_OFFSET_M off the surface; allow twice that.
    let margin = 2.0 * f64::from(RAY_OFFSET_M);
    let local = FrontOccluders::build(mesh, view, margin, MAX_LOCAL_OCCLUDERS);
    tracing::debug!(
        "{name}: {} of {} triangles need the BVH for self-occlusion",
        local.overflowing(),
        mesh.triangles.len()
    );
    s.local.push(local);
}

/// Whether any sample of cluster `c` can face an antenna within `spread` of `centre`, for a
/// normal cone widened by the window `limit` = (cos, sin) of the widest angle a sample may
/// be off the bisector.
#[inline]
fn cluster_in_view(
    c: &Cluster,
    (cos_lim, sin_lim): (f32, f32),
    centre: [f32; 3],
    spread: f32,
) -> bool {
    let (v, dist) = towards(c.centre, centre);
    // Widen the cone by the cluster's angular radius and the antennas' spread.
    let delta = 1.01 * (c.radius_m + spread) / dist;
    let threshold = cos_lim * (1.0 - 0.5 * delta * delta) - sin_lim * delta;
    !(sin_lim > 0.0 && dot(v, c.axis) < threshold)
}

/// One leg of a path, from a scatterer to an antenna: direction, length, the pattern and sheet
/// amplitude factor and the sheet's extra path.
#[derive(Clone, Copy)]
struct Leg {
    u: [f32; 3],
    d: f32,
    factor: f32,
    extra_m: f32,
}

impl Ctx<'_> {
    /// Whether the straight leg from `origin` (distance `d`, direction `u`) is free of every
    /// object's geometry. `front` = (object, triangle) when the leg leaves that triangle on its
    /// front side: then only the triangle's candidate occluders of its own object are tested.
    #[inline]
    fn clear(&self, origin: [f32; 3], u: [f32; 3], d: f32, front: Option<(u16, u32)>) -> bool {
        self.s.bvhs.iter().enumerate().all(|(k, bvh)| {
            if let Some((own, face)) = front
                && k == usize::from(own)
            {
                match self.s.local[k].test(face, origin, u, d) {
                    LocalVisibility::Clear => return true,
                    LocalVisibility::Blocked => return false,
                    LocalVisibility::Unknown => {}
                }
            }
            !bvh.occluded(origin, u, d)
        })
    }

    /// The leg from `p` to antenna `a` with its pattern and sheet factors.
    #[inline]
    fn leg(&self, p: [f32; 3], a: [f32; 3]) -> Leg {
        let (u, d) = towards(p, a);
        let mut factor = self.pattern.gain(scale(u, -1.0));
        let mut extra_m = 0.0;
        if let Some(o) = self.occluder {
            let (amp, extra) = o.leg(p, a);
            factor *= amp;
            extra_m = extra;
        }
        Leg {
            u,
            d,
            factor,
            extra_m,
        }
    }

    /// Whether `leg` is free of geometry, starting `RAY_OFFSET_M` along `offset_dir`. `faces`
    /// are (object, triangle, face normal) candidates at `p`: the first one whose front side the
    /// leg leaves lets [`FrontOccluders`] stand in for that object's BVH.
    #[inline]
    fn leg_clear(
        &self,
        p: [f32; 3],
        offset_dir: [f32; 3],
        leg: &Leg,
        faces: &[(u16, u32, [f32; 3])],
    ) -> bool {
        let front = faces
            .iter()
            .find(|(own, _, n)| *own != NO_OBJECT && dot(*n, leg.u) > 0.0)
            .map(|&(own, face, _)| (own, face));
        let o = add(p, scale(offset_dir, RAY_OFFSET_M));
        self.clear(o, leg.u, leg.d, front)
    }

    /// Whether a contribution of `amp` over the legs `(t, r, rx_is_tx)` is summed: `None`
    /// when the TX leg is blocked (no RX of this position can see the scatterer), otherwise
    /// whether this RX gets it. The TX leg's ray is cast once per scatterer and cached in
    /// `tx_clear`.
    #[inline]
    fn admit(
        &self,
        amp: f32,
        p: [f32; 3],
        offset_dir: [f32; 3],
        (t, r, rx_is_tx): (&Leg, &Leg, bool),
        faces: &[(u16, u32, [f32; 3])],
        tx_clear: &mut Option<bool>,
    ) -> Option<bool> {
        if amp == 0.0 {
            return Some(false);
        }
        if !*tx_clear.get_or_insert_with(|| self.leg_clear(p, offset_dir, t, faces)) {
            return None;
        }
        Some(rx_is_tx || self.leg_clear(p, offset_dir, r, faces))
    }

    /// Sums every scatterer's return for one raster position: one TX and the RX antennas that
    /// share it, so the TX leg (culling, geometry, shadow ray) is worked out once. Specular
    /// terms go to `spec[k]` (scaled by 1/λ_t afterwards), the others to `other[k]`. Returns
    /// the number of contributions.
    fn position(
        &self,
        tx: [f32; 3],
        rxs: &[[f32; 3]],
        spec: &mut [ToneAccumulator],
        other: &mut [ToneAccumulator],
    ) -> u64 {
        let s = self.s;
        let mut count = 0u64;
        // Every antenna lies within `spread` of `centre`.
        let mut centre = tx;
        for rx in rxs {
            centre = add(centre, *rx);
        }
        let centre = scale(centre, 1.0 / (rxs.len() + 1) as f32);
        let spread = std::iter::once(&tx)
            .chain(rxs)
            .map(|a| dot(sub(*a, centre), sub(*a, centre)).sqrt())
            .fold(0.0f32, f32::max);
        let rx_leg = |p: [f32; 3], rx: [f32; 3], tx_leg: &Leg| {
            if rx == tx { *tx_leg } else { self.leg(p, rx) }
        };

        if let Some(ps) = &s.point_model {
            count += self.point_scatterers(ps, tx, rxs, (centre, spread), other);
        }

        for ((c, &limit), &own) in s
            .clusters
            .iter()
            .zip(&s.cluster_limit)
            .zip(&s.cluster_object)
        {
            if !cluster_in_view(c, limit, centre, spread) {
                continue;
            }
            let faces = [(own, c.triangle, c.axis)];
            for i in c.first as usize..(c.first + c.count) as usize {
                let p = s.spec.position[i];
                let n = s.spec.normal[i];
                let t = self.leg(p, tx);
                let ct = dot(n, t.u);
                if ct <= 0.0 {
                    continue;
                }
                let mut tx_clear: Option<bool> = None;
                for (k, &rx) in rxs.iter().enumerate() {
                    let r = rx_leg(p, rx, &t);
                    let cr = dot(n, r.u);
                    if cr <= 0.0 {
                        continue;
                    }
                    let h = add(t.u, r.u);
                    let theta = (dot(n, h) / dot(h, h).sqrt()).min(1.0).acos();
                    let zone =
                        fresnel_zone_rad(self.half_lambda0_m, c.curvature_per_m, 0.5 * (t.d + r.d));
                    let full = self.full_zones * zone;
                    let cutoff = (self.cutoff_zones * zone).min(MAX_WINDOW_RAD);
                    if theta >= cutoff {
                        continue;
                    }
                    let w = if theta <= full {
                        1.0
                    } else {
                        0.5 * (1.0 + (PI * (theta - full) / (cutoff - full)).cos())
                    };
                    let amp =
                        s.spec_weight[i] * 0.5 * (ct + cr) * w * t.factor * r.factor / (t.d * r.d);
                    match self.admit(amp, p, n, (&t, &r, rx == tx), &faces, &mut tx_clear) {
                        None => break,
                        Some(false) => continue,
                        Some(true) => {}
                    }
                    spec[k].add(Complex32::new(0.0, -amp), path_m(&t, &r));
                    count += 1;
                }
            }
        }

        for i in 0..s.diff.len() {
            let p = s.diff.position[i];
            let n = s.diff.normal[i];
            let t = self.leg(p, tx);
            let ct = dot(n, t.u);
            if ct <= 0.0 {
                continue;
            }
            // Specular direction of the incident ray; the lobe lies around it.
            let specular = sub(scale(n, 2.0 * ct), t.u);
            let faces = [(s.diff_object[i], s.diff.triangle[i], s.diff.face_normal[i])];
            let mut tx_clear: Option<bool> = None;
            for (k, &rx) in rxs.iter().enumerate() {
                let r = rx_leg(p, rx, &t);
                if dot(n, r.u) <= 0.0 {
                    continue;
                }
                let lobe = (0.5 * (1.0 + dot(specular, r.u)))
                    .max(0.0)
                    .powf(s.diff_half_alpha[i]);
                let amp = s.diff_weight[i] * ct.sqrt() * lobe * t.factor * r.factor / (t.d * r.d);
                match self.admit(amp, p, n, (&t, &r, rx == tx), &faces, &mut tx_clear) {
                    None => break,
                    Some(false) => continue,
                    Some(true) => {}
                }
                other[k].add(s.diff_phasor[i] * amp, path_m(&t, &r));
                count += 1;
            }
        }

        for ((e, &weight), &own) in s.edges.iter().zip(&s.edge_weight).zip(&s.edge_object) {
            let p = e.position;
            let rim = e.n1 == e.n2;
            let outside = |u: [f32; 3]| {
                let (a, b) = (dot(e.n1, u), dot(e.n2, u));
                if e.convex {
                    a > 0.0 || b > 0.0
                } else {
                    a > 0.0 && b > 0.0
                }
            };
            let t = self.leg(p, tx);
            if !(rim || outside(t.u)) {
                continue;
            }
            let offset_dir = edge_offset_dir(e, t.u);
            let faces = [(own, e.faces[0], e.n1), (own, e.faces[1], e.n2)];
            let mut tx_clear: Option<bool> = None;
            for (k, &rx) in rxs.iter().enumerate() {
                let r = rx_leg(p, rx, &t);
                if !(rim || outside(r.u)) {
                    continue;
                }
                let amp = weight * t.factor * r.factor / (t.d * r.d);
                match self.admit(
                    amp,
                    p,
                    offset_dir,
                    (&t, &r, rx == tx),
                    &faces,
                    &mut tx_clear,
                ) {
                    None => break,
                    Some(false) => continue,
                    Some(true) => {}
                }
                other[k].add(Complex32::new(amp, 0.0), path_m(&t, &r));
                count += 1;
            }
        }

        for &(p, a) in &s.points {
            let t = self.leg(p, tx);
            if !self.leg_clear(p, [0.0; 3], &t, &[]) {
                continue;
            }
            for (k, &rx) in rxs.iter().enumerate() {
                let r = rx_leg(p, rx, &t);
                if rx != tx && !self.leg_clear(p, [0.0; 3], &r, &[]) {
                    continue;
                }
                other[k].add(
                    Complex32::new(a * t.factor * r.factor / (t.d * r.d), 0.0),
                    path_m(&t, &r),
                );
                count += 1;
            }
        }
        count
    }
}

/// Round-trip path of a TX leg and an RX leg, with the sheet's extra path, metres.
#[inline]
fn path_m(t: &Leg, r: &Leg) -> f64 {
    f64::from(t.d) + f64::from(r.d) + f64::from(t.extra_m) + f64::from(r.extra_m)
}
