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
