//! mmNorm end to end on simulated captures (issue 4's acceptance cases): a tilted plate, a sphere
//! cap, a cylinder on its side and two separated objects.
//!
//! Apertures are 14–18 cm at 2 mm spacing and voxels are 2 mm, so each case takes seconds in
//! release mode; the example scenes in tools/scenes are the full-size runs.
//!
//! The truth is the part of the object's top surface that the aperture can see: the points whose
//! outward normal, followed up to the aperture plane, lands inside the aperture (a specular
//! surface returns energy only there). For a 4 cm sphere under a 16 cm aperture that is a cap of
//! about 1.5 cm radius; the rest of the hemisphere is invisible to any radar at this aperture.
//! Each test also prints the score against the whole top surface.

use mmnormd::eval::{Metrics, evaluate};
use mmnormd::recon::config::{Method, SubsetRule};
use mmnormd::recon::{ReconConfig, Reconstruction, reconstruct};
use mmnormd::sim::truth::top_surface_with_normals;
use mmnormd::sim::{Scene, simulate};

struct Case {
    recon: Reconstruction,
    truth: Vec<[f64; 3]>,
    truth_normals: Vec<[f64; 3]>,
    capture: mmnormd::capture::Capture,
}

const RADAR: &str = "[radar]\nstart_frequency_hz = 77.5e9\nfrequency_step_hz = 5.861163e6\nsamples_per_chirp = 512\nrange_offset_m = 0.15\n\
    [noise]\nsnr_db = 30.0\nseed = 4\n";

fn config(method: Method) -> ReconConfig {
    ReconConfig {
        method,
        voxel_m: 0.002,
        ..ReconConfig::default()
    }
}

/// Simulates `aperture` + `objects`, reconstructs with mmNorm, and returns the visible truth.
fn run(aperture: &str, objects: &str) -> Case {
    run_with(aperture, objects, &config(Method::Mmnorm))
}

/// [`run`] with the reconstruction's parameters given.
fn run_with(aperture: &str, objects: &str, recon_config: &ReconConfig) -> Case {
    let text = format!("{RADAR}[aperture]\n{aperture}\nlayout = \"monostatic\"\n{objects}");
    let scene = Scene::parse(&text, std::path::Path::new("inline.toml")).unwrap();
    let sim = simulate(&scene, true);
    let (top, normals) = top_surface_with_normals(&sim.truth_mesh, 0.001);
    let a = &scene.aperture;
    let visible = |p: &[f64; 3], n: &[f64; 3]| {
        if n[2] <= 1e-6 {
            return false;
        }
        let t = (a.z_m - p[2]) / n[2];
        let (x, y) = (p[0] + t * n[0], p[1] + t * n[1]);
        (x - a.center_m[0]).abs() <= 0.5 * a.width_m
            && (y - a.center_m[1]).abs() <= 0.5 * a.height_m
    };
    let (truth, truth_normals): (Vec<_>, Vec<_>) = top
        .iter()
        .zip(&normals)
        .filter(|(p, n)| visible(p, n))
        .map(|(p, n)| (*p, *n))
        .unzip();
    let recon = reconstruct(&sim.capture, recon_config, true).unwrap();
    let full = evaluate(
        &recon.points_m,
        recon.normals.as_deref(),
        &top,
        Some(&normals),
        0.015,
    );
    println!(
        "whole top surface ({} points): F {:.3}, recall {:.3}",
        top.len(),
        full.f_score,
        full.recall
    );
    Case {
        recon,
        truth,
        truth_normals,
        capture: sim.capture,
    }
}

fn score(case: &Case, recon: &Reconstruction) -> Metrics {
    evaluate(
        &recon.points_m,
        recon.normals.as_deref(),
        &case.truth,
        Some(&case.truth_normals),
        0.015,
    )
}

fn check_mmnorm(case: &Case, label: &str) -> Metrics {
    let m = score(case, &case.recon);
    let stages: Vec<String> = case
        .recon
        .summary
        .stage_s
        .iter()
        .map(|(n, t)| format!("{n} {t:.1}s"))
        .collect();
    println!(
        "{label}: {} points vs {} visible truth points: F {:.4} (P {:.3}, R {:.3}), position error {:.2} mm, point error median {:.2} mm, normal cos median {:.4}; {}",
        m.points,
        m.truth_points,
        m.f_score,
        m.precision,
        m.recall,
        m.position_error_m.unwrap_or(f64::NAN) * 1e3,
        m.point_error_median_m.unwrap_or(f64::NAN) * 1e3,
        m.normal_cos_median.unwrap_or(f64::NAN),
        stages.join(", ")
    );
    assert!(case.truth.len() > 100, "{label}: visible truth too small");
    assert!(m.f_score >= 0.95, "{label}: F = {}", m.f_score);
    let cos = m.normal_cos_median.unwrap_or(0.0);
    assert!(cos >= 0.98, "{label}: normal cosine median {cos}");
    m
}

/// mmNorm's F-score must beat the backprojection baseline's on curved surfaces.
fn beats_backprojection(case: &Case, mmnorm: &Metrics, label: &str) {
    let bp = reconstruct(&case.capture, &config(Method::Backprojection), true).unwrap();
    let b = score(case, &bp);
    println!(
        "{label}: backprojection {} points, F {:.4} (P {:.3}, R {:.3}), point error median {:.2} mm",
        b.points,
        b.f_score,
        b.precision,
        b.recall,
        b.point_error_median_m.unwrap_or(f64::NAN) * 1e3
    );
    assert!(
        mmnorm.f_score > b.f_score,
        "{label}: mmNorm F {} vs backprojection F {}",
        mmnorm.f_score,
        b.f_score
    );
}

#[test]
fn tilted_plate() {
    let case = run(
        "width_m = 0.14\nheight_m = 0.14\nspacing_m = 0.002\nz_m = 0.22",
        "[[object]]\nshape = \"plate\"\nsize_m = [0.08, 0.08]\nrotation_deg = [0.0, 5.0, 0.0]\n",
    );
    check_mmnorm(&case, "plate");
    assert_eq!(case.recon.summary.components.len(), 1);
}

#[test]
fn sphere_cap() {
    let case = run(
        "width_m = 0.16\nheight_m = 0.16\nspacing_m = 0.002\nz_m = 0.20",
        "[[object]]\nshape = \"sphere\"\nradius_m = 0.04\nposition_m = [0.0, 0.0, 0.0]\n",
    );
    let m = check_mmnorm(&case, "sphere");
    beats_backprojection(&case, &m, "sphere");
}

#[test]
fn cylinder_on_its_side() {
    let case = run(
        "width_m = 0.16\nheight_m = 0.16\nspacing_m = 0.002\nz_m = 0.20",
        "[[object]]\nshape = \"cylinder\"\nradius_m = 0.03\nlength_m = 0.10\nposition_m = [0.0, 0.0, 0.0]\nrotation_deg = [0.0, 90.0, 0.0]\n",
    );
    let m = check_mmnorm(&case, "cylinder");
    beats_backprojection(&case, &m, "cylinder");
}

#[test]
fn two_separated_objects_are_two_components() {
    let case = run(
        "width_m = 0.18\nheight_m = 0.14\nspacing_m = 0.002\nz_m = 0.20",
        "[[object]]\nshape = \"plate\"\nsize_m = [0.045, 0.045]\nposition_m = [-0.045, 0.0, 0.0]\nrotation_deg = [0.0, -5.0, 0.0]\n\
         [[object]]\nshape = \"plate\"\nsize_m = [0.045, 0.045]\nposition_m = [0.045, 0.0, 0.025]\n",
    );
    check_mmnorm(&case, "two objects");
    let s = &case.recon.summary;
    assert_eq!(s.components.len(), 2, "{:?}", s.components);
    let opt = s.optimisation.as_ref().unwrap();
    let check = opt.product_check.as_ref().unwrap();
    println!(
        "coordinate descent {:?} (cost {:.4}, {} sweeps) vs product search {:?} (cost {:.4})",
        opt.components.iter().map(|c| c.chosen).collect::<Vec<_>>(),
        opt.total_cost,
        opt.sweeps,
        check.choice,
        check.cost
    );
    assert!(check.agrees);
}

/// The median distance from component `component`'s points to the visible truth, metres.
fn component_error_m(case: &Case, recon: &Reconstruction, component: u32) -> f64 {
    let points: Vec<[f64; 3]> = recon
        .points_m
        .iter()
        .zip(&recon.components)
        .filter(|(_, c)| **c == component)
        .map(|(p, _)| *p)
        .collect();
    let m = evaluate(&points, None, &case.truth, None, 0.015);
    m.point_error_median_m.unwrap_or(f64::INFINITY)
}

/// A flat plate returns far more than a sphere beside it, and only to the antennas above it. The
/// authors' strong-return filter then draws every antenna from over the plate, and the sphere's
/// level is left to chance; a share of antennas per component finds both levels.
#[test]
fn a_weak_sphere_beside_a_strong_plate_gets_antennas_of_its_own() {
    let aperture = "width_m = 0.24\nheight_m = 0.14\nspacing_m = 0.002\nz_m = 0.22";
    let objects = "[[object]]\nshape = \"plate\"\nsize_m = [0.04, 0.04]\nposition_m = [-0.07, 0.0, 0.02]\n\
         [[object]]\nshape = \"sphere\"\nradius_m = 0.05\nposition_m = [0.07, 0.0, -0.03]\n";
    let case = run(aperture, objects);
    let s = &case.recon.summary;
    assert_eq!(s.components.len(), 2, "{:?}", s.components);
    let shares = s
        .optimisation
        .as_ref()
        .and_then(|o| o.per_component.clone())
        .expect("two components draw a share each");
    println!("per component: {shares:?}");
    assert!(shares.drawn.iter().all(|&d| d > 0), "{shares:?}");
    let strongest = reconstruct(
        &case.capture,
        &ReconConfig {
            optimisation: mmnormd::recon::config::Optimisation {
                subset: SubsetRule::Strongest,
                ..Default::default()
            },
            ..config(Method::Mmnorm)
        },
        true,
    )
    .unwrap();
    // The sphere is the component whose points lie at x > 0.
    let sphere = (1..=2u32)
        .find(|&c| {
            let xs: Vec<f64> = case
                .recon
                .points_m
                .iter()
                .zip(&case.recon.components)
                .filter(|(_, k)| **k == c)
                .map(|(p, _)| p[0])
                .collect();
            !xs.is_empty() && xs.iter().sum::<f64>() / xs.len() as f64 > 0.0
        })
        .expect("a component at the sphere");
    let plate = 3 - sphere;
    let error_mm = |recon: &Reconstruction, c: u32| component_error_m(&case, recon, c) * 1e3;
    for (name, c) in [("plate", plate), ("sphere", sphere)] {
        println!(
            "{name}: median error {:.2} mm with a share each, {:.2} mm with the authors' filter",
            error_mm(&case.recon, c),
            error_mm(&strongest, c)
        );
        assert!(error_mm(&case.recon, c) < 1.5, "{name} with a share each");
    }
    assert!(
        error_mm(&strongest, sphere) > 3.0,
        "the authors' filter found the sphere too: the scene no longer tests the shares"
    );
    check_mmnorm(&case, "plate and sphere");
}

/// A thin rod beside a plate forms a component of its own far smaller than the authors' 3 × 3 × 4
/// cm floor, as a screwdriver's shaft did at the paper's aperture. The default floor keeps it;
/// the authors' floor drops it and the rod's whole surface with it.
#[test]
fn a_thin_rod_beside_a_plate_is_kept() {
    let aperture = "width_m = 0.20\nheight_m = 0.14\nspacing_m = 0.002\nz_m = 0.22";
    let objects = "[[object]]\nshape = \"plate\"\nsize_m = [0.05, 0.05]\nposition_m = [-0.05, 0.0, 0.0]\n\
         [[object]]\nshape = \"cylinder\"\nradius_m = 0.004\nlength_m = 0.05\nposition_m = [0.05, 0.0, 0.0]\nrotation_deg = [90.0, 0.0, 0.0]\n";
    let case = run(aperture, objects);
    let s = &case.recon.summary;
    println!("components {:?}", s.components);
    assert_eq!(s.components.len(), 2, "{:?}", s.components);
    let authors_floor = ReconConfig {
        min_component_m3: 3.6e-5,
        ..config(Method::Mmnorm)
    };
    let authors = reconstruct(&case.capture, &authors_floor, true).unwrap();
    println!(
        "authors' floor: components {:?}",
        authors.summary.components
    );
    let rod_voxels = s.components.iter().map(|c| c.voxels).min().unwrap_or(0);
    let authors_voxels =
        (authors_floor.min_component_m3 / authors_floor.voxel_m.powi(3)).round() as usize;
    assert!(
        rod_voxels < authors_voxels,
        "the rod's component ({rod_voxels} voxels) reaches the authors' floor: the scene no longer tests it"
    );
    assert_eq!(authors.summary.components.len(), 1);
    let rod: Vec<[f64; 3]> = case.truth.iter().filter(|p| p[0] > 0.0).copied().collect();
    let rod_truth = rod.len();
    let recall_on_rod =
        |recon: &Reconstruction| evaluate(&recon.points_m, None, &rod, None, 0.015).recall;
    let (kept, dropped) = (recall_on_rod(&case.recon), recall_on_rod(&authors));
    println!(
        "rod: {rod_truth} truth points, recall {kept:.3} kept, {dropped:.3} with the authors' floor"
    );
    assert!(rod_truth > 50, "rod truth too small");
    assert!(
        kept > 0.9 && dropped < 0.1,
        "rod recall {kept} kept, {dropped} dropped"
    );
    check_mmnorm(&case, "plate and rod");
}

/// The scene text of each physics model: physical optics (the default) and point scatterers.
const PHYSICS: [(&str, &str); 2] = [
    ("physical optics", ""),
    (
        "point scatterers",
        "[physics]\nmodel = \"point-scatterer\"\n",
    ),
];

/// The median height of the points whose x lies in `x_m`, metres.
fn median_z(points: &[[f64; 3]], x_m: std::ops::Range<f64>) -> f64 {
    let z: Vec<f64> = points
        .iter()
        .filter(|p| x_m.contains(&p[0]))
        .map(|p| p[2])
        .collect();
    mmnormd::eval::quantile(&z, 0.5).unwrap_or(f64::NAN)
}

/// Two flat tops 8 mm apart in height, side by side: closer than the 5 cm range resolution, so
/// the image blurs them into one component, and both tops' normals point up, so its RSDF is one
/// plane and one level (the paper's) leaves a top millimetres off. The split at the transition
/// gives each top its own level under both physics models. The hidden-surface search (on by
/// default) may add nothing, and the tops must come back where they do without it. `objects`
/// holds the low top over x < 0 at `low_m` and the high one over x > 0 at `low_m` + 8 mm.
fn check_step(objects: &str, low_m: f64, label: &str) {
    let aperture = "width_m = 0.14\nheight_m = 0.14\nspacing_m = 0.002\nz_m = 0.24";
    let high_m = low_m + 0.008;
    for (name, physics) in PHYSICS {
        let case = run(aperture, &format!("{physics}{objects}"));
        let s = &case.recon.summary;
        let split = s.split.expect("the split ran");
        let error_mm = |recon: &Reconstruction| {
            [
                (median_z(&recon.points_m, -0.04..-0.01) - low_m).abs() * 1e3,
                (median_z(&recon.points_m, 0.01..0.04) - high_m).abs() * 1e3,
            ]
        };
        let ours = error_mm(&case.recon);
        // The tops' errors of the same capture reconstructed with other parameters.
        let again = |what: &str, recon_config: ReconConfig| {
            let recon = reconstruct(&case.capture, &recon_config, true).unwrap();
            let e = error_mm(&recon);
            println!(
                "{label}, {name}, {what}: tops off by {:.1} and {:.1} mm",
                e[0], e[1]
            );
            e
        };
        println!(
            "{label}, {name}: {split:?}; top heights off by {:.1} and {:.1} mm",
            ours[0], ours[1]
        );
        assert!(
            split.components_after > split.components_before,
            "{label}, {name}: {split:?}"
        );
        // Points are voxel centres (2 mm): one voxel is the resolution.
        assert!(
            ours.iter().all(|e| *e <= 2.0 + 1e-9),
            "{label}, {name}: tops off by {ours:?} mm"
        );
        // The paper's one level per component, once: the scene must need the split.
        let paper = again(
            "one level per component",
            ReconConfig {
                split_transitions: false,
                ..config(Method::Mmnorm)
            },
        );
        assert!(
            paper.iter().any(|e| *e > 2.0 + 1e-9),
            "{label}, {name}: one level per component already finds both tops ({paper:?} mm): the scene no longer tests the split"
        );
        // The hidden-surface search must leave the step alone: the other top lies inside the
        // strongest echo's range bin, so what the fit leaves of it is no surface.
        let found = s.hidden.clone().expect("the search ran (on by default)");
        println!("{label}, {name}, hidden surfaces: {found:?}");
        let without_hidden = again(
            "without the hidden-surface search",
            ReconConfig {
                hidden_surfaces: false,
                ..config(Method::Mmnorm)
            },
        );
        assert_eq!(found.kept, 0, "{label}, {name}: {found:?}");
        assert_eq!(ours, without_hidden, "{label}, {name}");
        check_mmnorm(&case, &format!("{label}, {name}"));
    }
}

#[test]
fn a_step_gets_a_level_on_each_side() {
    check_step(
        "[[object]]\nshape = \"box\"\nsize_m = [0.05, 0.10, 0.02]\nposition_m = [-0.025, 0.0, 0.01]\n\
         [[object]]\nshape = \"box\"\nsize_m = [0.05, 0.10, 0.028]\nposition_m = [0.025, 0.0, 0.014]\n",
        0.02,
        "step",
    );
}

#[test]
fn two_plates_joined_by_a_wall_get_a_level_each() {
    check_step(
        "[[object]]\nshape = \"plate\"\nsize_m = [0.05, 0.10]\nposition_m = [-0.025, 0.0, 0.0]\n\
         [[object]]\nshape = \"plate\"\nsize_m = [0.05, 0.10]\nposition_m = [0.025, 0.0, 0.008]\n\
         [[object]]\nshape = \"plate\"\nsize_m = [0.008, 0.10]\nposition_m = [0.0, 0.0, 0.004]\nrotation_deg = [0.0, 90.0, 0.0]\n",
        0.0,
        "plates and wall",
    );
}

/// The fraction of `from` within `tau_m` of some point of `to`, with no alignment (the paper's
/// 80th-percentile shift is ill-posed on a cup, whose rim and floor lie 6 cm apart).
fn fraction_within(from: &[[f64; 3]], to: &[[f64; 3]], tau_m: f64) -> f64 {
    let index = mmnormd::eval::NearestNeighbours::new(to, tau_m);
    let near = from.iter().filter(|p| index.within(p, tau_m)).count();
    near as f64 / from.len().max(1) as f64
}

/// Simulates `object` (a hollow shape) under each physics and checks that both of its visible
/// surfaces come back: the truth above `upper.1` (named `upper.0`) and below `lower.1`, each
/// recalled ≥ 0.8 at 5 mm, at precision ≥ 0.9. `min_truth`, when given, guards each surface's truth size.
fn check_two_surfaces(
    object: &str,
    label: &str,
    upper: (&str, f64),
    lower: (&str, f64),
    min_truth: Option<[usize; 2]>,
) {
    let aperture = "width_m = 0.16\nheight_m = 0.16\nspacing_m = 0.002\nz_m = 0.26";
    for (name, physics) in PHYSICS {
        let case = run(aperture, &format!("{physics}[[object]]\n{object}"));
        let part = |keep: &dyn Fn(f64) -> bool| -> Vec<[f64; 3]> {
            case.truth.iter().filter(|p| keep(p[2])).copied().collect()
        };
        let (top, bottom) = (part(&|z| z > upper.1), part(&|z| z < lower.1));
        let points = &case.recon.points_m;
        let (top_recall, bottom_recall, precision) = (
            fraction_within(&top, points, 0.005),
            fraction_within(&bottom, points, 0.005),
            fraction_within(points, &case.truth, 0.005),
        );
        println!(
            "{label}, {name}: {} points, {} components; {} recall {top_recall:.3} ({} truth points), {} recall {bottom_recall:.3} ({}), precision {precision:.3} (all at 5 mm)",
            points.len(),
            case.recon.summary.components.len(),
            upper.0,
            top.len(),
            lower.0,
            bottom.len()
        );
        if let Some([top_min, bottom_min]) = min_truth {
            assert!(
                top.len() > top_min && bottom.len() > bottom_min,
                "{label} truth: {} {} {} {}",
                upper.0,
                top.len(),
                lower.0,
                bottom.len()
            );
        }
        for (surface, recall) in [(upper.0, top_recall), (lower.0, bottom_recall)] {
            assert!(recall >= 0.8, "{label}, {name}: {surface} recall {recall}");
        }
        assert!(precision >= 0.9, "{label}, {name}: precision {precision}");
    }
}

/// An open cup seen from above shows its rim and, 6 cm below, the floor inside it; the wall
/// between them returns nothing upwards. Both surfaces must come back, under either physics.
/// Under point scatterers the rim is seen through its edges, which the isosurface cost's
/// specular simulation does not model: its cost falls towards the top of the candidates, and
/// without the edge fallback (`edge_fallback`) the rim came back 8 mm high (recall 0.000).
#[test]
fn an_open_cup_returns_its_rim_and_its_floor() {
    check_two_surfaces(
        "shape = \"cup\"\nradius_m = 0.04\nlength_m = 0.06\nposition_m = [0.0, 0.0, 0.03]\n",
        "cup",
        ("rim", 0.05),
        ("floor", 0.01),
        Some([100, 1000]),
    );
}

/// An open bowl seen from above: its rim and the part of its inside whose normal points into the
/// aperture (the visible truth). Both must come back, under either physics.
#[test]
#[ignore = "known failure (issue 40, item 4): under point scatterers both levels sit 6-10 mm deep (physical optics passes)"]
fn an_open_bowl_returns_its_rim_and_its_inside() {
    check_two_surfaces(
        "shape = \"bowl\"\nradius_m = 0.06\nposition_m = [0.0, 0.0, 0.03]\n",
        "bowl",
        ("rim", 0.055),
        ("inside", 0.05),
        None,
    );
}
