//! The accuracy benchmark end to end on the smoke suite (two scenes, a small aperture, LOS and
//! NLOS), and the suites that ship with the repository.

use std::path::Path;

use mmnormd::bench::{BenchOptions, Suite, run_suite};

fn suite_path(name: &str) -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tools/bench")
        .join(name)
}

#[test]
fn smoke_suite_scores_mmnorm_above_its_floor_and_ahead_of_backprojection() {
    let suite = Suite::load(&suite_path("smoke.toml")).expect("smoke suite");
    assert_eq!(suite.cases.len(), 4);
    let out = tempfile::tempdir().expect("tempdir");
    let opts = BenchOptions {
        work_dir: None,
        jobs: 2,
        memory_budget_bytes: 8 << 30,
        markdown: Some(out.path().join("BENCH.md")),
        command: "test".into(),
        report_only: false,
        only: Vec::new(),
        notes: None,
        includes: Vec::new(),
        quiet: true,
    };
    let outcome = run_suite(&suite, out.path(), &opts).expect("bench runs");
    assert!(
        outcome.failed_cases.is_empty(),
        "{:?}",
        outcome.failed_cases
    );
    assert_eq!(outcome.results.len(), 4);
    for r in &outcome.results {
        let f = |name: &str| {
            r.methods
                .iter()
                .find(|m| m.method == name)
                .and_then(|m| m.metrics.clone())
                .unwrap_or_else(|| panic!("{} {name} has no metrics", r.id))
        };
        let (mm, bp) = (f("mmnorm"), f("backprojection"));
        println!(
            "{}: mmNorm F {:.3} (P {:.3} R {:.3}), backprojection F {:.3}, interferometric F {:.3}",
            r.id,
            mm.f_score,
            mm.precision,
            mm.recall,
            bp.f_score,
            f("interferometric").f_score
        );
        // The small aperture caps recall (it sees a cap of each surface), not precision.
        assert!(mm.f_score >= 0.45, "{}: {}", r.id, mm.f_score);
        assert!(mm.precision >= 0.95, "{}: {}", r.id, mm.precision);
        assert!(
            mm.f_score > bp.f_score + 0.1,
            "{}: {} vs {}",
            r.id,
            mm.f_score,
            bp.f_score
        );
        assert!(mm.normal_cos_median.unwrap_or(0.0) >= 0.98, "{}", r.id);
        for name in ["center", "weighted", "interferometric"] {
            assert!(f(name).points > 0, "{} {name}", r.id);
        }
    }

    // The outputs the issue names.
    let csv = std::fs::read_to_string(out.path().join("results.csv")).expect("results.csv");
    assert!(csv.starts_with(
        "scene,condition,method,f_score,precision,recall,position_error_m,point_error_median_m,\
point_error_p90_m,rel_error_under_5pct,normal_cos_median,normal_cos_p25,total_s,"
    ));
    assert_eq!(csv.lines().count(), 1 + 4 * 5);
    for name in [
        "report.md",
        "fig12a_f_score.png",
        "fig12b_position_error.png",
        "fig12c_relative_error.png",
        "fig13_normal_cosine.png",
        "fig14_ablation_point_error.png",
        "fig15_los_nlos_point_error.png",
        "scenes/sphere-flat-nlos.png",
        "scenes/soup_can-side-los.png",
    ] {
        let p = out.path().join(name);
        assert!(
            p.is_file() && p.metadata().map(|m| m.len() > 0).unwrap_or(false),
            "{name}"
        );
    }
    let report = std::fs::read_to_string(out.path().join("report.md")).expect("report");
    for heading in [
        "## Targets",
        "## Shape, position and point error (Fig. 12)",
        "## Normals (Fig. 13)",
        "## Isosurface optimisation against its ablations",
        "## Line of sight against cardboard",
        "| sphere-flat-los |",
    ] {
        assert!(report.contains(heading), "{heading}");
    }
    // The copy elsewhere links back into OUT.
    let copy = std::fs::read_to_string(out.path().join("BENCH.md")).expect("markdown copy");
    assert!(copy.contains("](fig12a_f_score.png)") || copy.contains("/fig12a_f_score.png)"));

    // Each method's summary holds the parameters it ran with; the NLOS case's search for
    // echoes from past the sheet.
    let runs = out.path().join("work/runs");
    let window_start_m = |summary: &serde_json::Value| {
        summary["parameters"]["auto_volume"]["range_window_m"][0]
            .as_f64()
            .expect("range_window_m")
    };
    let mut starts_m = Vec::new();
    for case in ["sphere-flat-los", "sphere-flat-nlos"] {
        for (method, isosurface) in [
            ("mmnorm", "optimized"),
            ("center", "center"),
            ("backprojection", "optimized"),
        ] {
            let path = runs.join(case).join(format!("{method}.summary.json"));
            let text = std::fs::read_to_string(&path).expect("summary.json");
            let summary: serde_json::Value = serde_json::from_str(&text).expect("JSON");
            let parameters = &summary["parameters"];
            let expected_method = if method == "backprojection" {
                "backprojection"
            } else {
                "mmnorm"
            };
            assert_eq!(parameters["method"], expected_method, "{path:?}");
            assert_eq!(parameters["isosurface"], isosurface, "{path:?}");
            assert!(summary["result"]["grid"]["dims"].is_array(), "{path:?}");
            starts_m.push(window_start_m(&summary));
        }
    }
    assert!(
        starts_m[..3].iter().all(|&s| s == starts_m[0]),
        "{starts_m:?}"
    );
    assert!(
        starts_m[3..].iter().all(|&s| s > starts_m[0] + 0.05),
        "{starts_m:?}"
    );

    // A second run finds every case finished and runs none of them again.
    let result_json = |case: &str| runs.join(case).join("result.json");
    let written = |case: &str| {
        std::fs::metadata(result_json(case))
            .and_then(|m| m.modified())
            .expect("result.json")
    };
    let before = written("sphere-flat-los");
    let again = run_suite(&suite, out.path(), &opts).expect("second run");
    assert_eq!(again.results.len(), 4);
    assert_eq!(before, written("sphere-flat-los"));
    let cached = std::fs::read_dir(out.path().join("work/captures"))
        .expect("cache")
        .filter_map(Result::ok)
        .filter(|e| e.path().join("capture.json").is_file())
        .count();
    assert_eq!(cached, 4);

    // A case finished by another build is reconstructed again from its cached capture; the
    // others are not.
    let set_build = |case: &str, build: &str| {
        let path = result_json(case);
        let mut json: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(&path).expect("result.json"))
                .expect("json");
        json["build"] = build.into();
        std::fs::write(&path, json.to_string()).expect("rewrite result.json");
    };
    let build_of = |case: &str| {
        let text = std::fs::read_to_string(result_json(case)).expect("json");
        serde_json::from_str::<serde_json::Value>(&text).expect("json")["build"]
            .as_str()
            .map(str::to_string)
    };
    let ours = mmnormd::bench::run::build_id();
    assert_eq!(ours.len(), 16);
    assert_eq!(build_of("sphere-flat-los").as_deref(), Some(ours));
    let other = outcome.results[1].id.clone();
    assert_ne!(other, "sphere-flat-los");
    let other_before = written(&other);
    set_build("sphere-flat-los", "0123456789abcdef");
    let third = run_suite(&suite, out.path(), &opts).expect("third run");
    assert_eq!(third.results.len(), 4);
    assert_eq!(build_of("sphere-flat-los").as_deref(), Some(ours));
    assert_eq!(other_before, written(&other), "{other} was run again");

    // A report of the finished cases into a directory that does not exist yet: it takes any
    // build's results and says which.
    set_build(&other, "0123456789abcdef");
    let elsewhere = out.path().join("reports/again");
    let report_only = BenchOptions {
        work_dir: Some(out.path().join("work")),
        markdown: None,
        report_only: true,
        ..opts
    };
    // Pointed at a work directory without results, it refuses and writes nothing: an empty
    // report must not replace the one it was meant to redo.
    let empty = BenchOptions {
        work_dir: Some(out.path().join("no-work")),
        ..report_only.clone()
    };
    let csv_before = std::fs::read(out.path().join("results.csv")).expect("results.csv");
    let refused = run_suite(&suite, out.path(), &empty)
        .err()
        .map(|e| e.to_string());
    assert!(
        refused
            .as_deref()
            .is_some_and(|e| e.contains("no case of the suite has finished")),
        "{refused:?}"
    );
    assert_eq!(
        std::fs::read(out.path().join("results.csv")).expect("results.csv"),
        csv_before
    );
    let reported = run_suite(&suite, &elsewhere, &report_only).expect("report only");
    assert_eq!(reported.results.len(), 4);
    assert!(elsewhere.join("report.md").is_file() && elsewhere.join("results.csv").is_file());
    let report = std::fs::read_to_string(elsewhere.join("report.md")).expect("report");
    assert!(
        report.contains(&format!(
            "several builds of mmnormd: 0123456789abcdef, {ours}"
        )) || report.contains(&format!(
            "several builds of mmnormd: {ours}, 0123456789abcdef"
        )),
        "{report}"
    );

    // Running one case keeps the report whole: the selected case runs (again, as another
    // build wrote it), the others that finished are read back whichever build wrote them, and
    // a case with no result is listed as not run yet rather than as failed.
    let removed = suite
        .cases
        .iter()
        .map(|c| c.id.clone())
        .find(|id| id != "sphere-flat-los" && *id != other)
        .expect("a third case");
    std::fs::remove_file(result_json(&removed)).expect("remove a result");
    set_build("sphere-flat-los", "0123456789abcdef");
    let one = BenchOptions {
        report_only: false,
        only: vec!["sphere-flat-los".into()],
        ..report_only.clone()
    };
    let partial = run_suite(&suite, out.path(), &one).expect("one case");
    assert!(
        partial.failed_cases.is_empty(),
        "{:?}",
        partial.failed_cases
    );
    assert_eq!(partial.not_run, vec![removed.clone()]);
    assert_eq!(partial.results.len(), 3);
    assert_eq!(build_of("sphere-flat-los").as_deref(), Some(ours));
    assert_eq!(build_of(&other).as_deref(), Some("0123456789abcdef"));
    let report = std::fs::read_to_string(out.path().join("report.md")).expect("report");
    assert!(report.contains("4 cases (3 with results)"), "{report}");
    assert!(
        report.contains(&format!(
            "the results come from several builds of mmnormd: 0123456789abcdef, {ours})"
        )) || report.contains(&format!(
            "the results come from several builds of mmnormd: {ours}, 0123456789abcdef)"
        )),
        "{report}"
    );
    assert!(
        report.contains(&format!("## Not run yet\n\n1 of 4 cases: {removed}.")),
        "{report}"
    );
    assert!(!report.contains("## Failures"), "{report}");
}

#[test]
fn the_paper_suite_uses_every_vendored_mesh_and_the_reduced_suite_the_same_scenes() {
    let meshes = Path::new(env!("CARGO_MANIFEST_DIR")).join("data/meshes");
    let paper_text = std::fs::read_to_string(suite_path("paper.toml")).expect("paper.toml");
    let mut files = 0;
    for e in std::fs::read_dir(&meshes)
        .expect("data/meshes")
        .filter_map(Result::ok)
    {
        let name = e.file_name().to_string_lossy().to_string();
        if name.ends_with(".stl") || name.ends_with(".obj") {
            files += 1;
            assert!(paper_text.contains(&name), "paper.toml does not use {name}");
        }
    }
    assert!(files >= 13, "{files}");
    let paper = Suite::load(&suite_path("paper.toml")).expect("paper suite");
    let reduced = Suite::load(&suite_path("reduced.toml")).expect("reduced suite");
    let ids = |s: &Suite| s.cases.iter().map(|c| c.id.clone()).collect::<Vec<_>>();
    assert_eq!(ids(&paper), ids(&reduced));
    assert!(paper.cases.len() >= 90, "{}", paper.cases.len());
    // The paper's aperture: 60×45 cm at λ/4, 4 RX, 40 cm above the highest point.
    let a = &paper.cases[0].scene.aperture;
    assert_eq!((a.width_m, a.height_m), (0.60, 0.45));
    assert!((a.spacing_m - paper.cases[0].scene.plan.first_wavelength_m() / 4.0).abs() < 1e-9);
    assert_eq!(a.layout, mmnormd::sim::scene::Layout::Iwr1443boost);
    for c in &paper.cases {
        let nlos = c.id.ends_with("-nlos");
        assert_eq!(c.scene.occluder.is_some(), nlos, "{}", c.id);
    }
}

#[test]
fn a_wider_aperture_sees_more_of_the_smoke_scenes_and_the_coverage_files_say_so() {
    use mmnormd::bench::coverage::{coverage_csv, suite_coverage, write_coverage};
    let path = suite_path("smoke.toml");
    let text = std::fs::read_to_string(&path).expect("smoke.toml");
    let small = Suite::parse(&text, &path).expect("smoke suite");
    let wide_text = text.replace(
        "width_m = 0.12\nheight_m = 0.12",
        "width_m = 0.60\nheight_m = 0.45",
    );
    assert_ne!(wide_text, text, "the smoke suite's aperture lines moved");
    let wide = Suite::parse(&wide_text, &path).expect("wide suite");
    let (a, b) = (suite_coverage(&small, true), suite_coverage(&wide, true));
    assert_eq!(a.cases.len(), 4);
    for (x, y) in a.cases.iter().zip(&b.cases) {
        assert_eq!(x.id, y.id);
        assert!(
            x.seen_fraction > 0.0 && x.seen_fraction < 1.0,
            "{}: {}",
            x.id,
            x.seen_fraction
        );
        assert!(
            y.seen_fraction > 1.5 * x.seen_fraction,
            "{}: {} → {}",
            x.id,
            x.seen_fraction,
            y.seen_fraction
        );
        assert!(y.ideal.f_score > x.ideal.f_score, "{}", x.id);
        // The ideal's points are truth points: every one lies on the surface.
        assert_eq!(x.ideal.precision, 1.0, "{}", x.id);
    }
    // The sheet does not enter the geometry: LOS and NLOS agree.
    assert_eq!(a.cases[0].seen_fraction, a.cases[1].seen_fraction);
    let csv = coverage_csv(&[a, b], &[]);
    assert_eq!(csv.lines().count(), 5, "{csv}");
    assert!(csv.starts_with("case,smoke_truth_points,smoke_seen_fraction,smoke_ideal_f_score"));
    let out = tempfile::tempdir().expect("tempdir");
    let small = suite_coverage(&small, true);
    write_coverage(&[small], &[], out.path()).expect("write");
    for f in ["coverage.csv", "coverage.md", "coverage_cdf.png"] {
        assert!(out.path().join(f).is_file(), "{f}");
    }
}
