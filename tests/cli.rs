//! The `mmnormd` binary as a user runs it: profile, simulate, inspect, and clear refusals.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn mmnormd(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_mmnormd"))
        .args(args)
        .env("RUST_LOG", "warn")
        .output()
        .expect("the mmnormd binary runs")
}

fn simulate(scene: &Path, out: &Path) -> Output {
    mmnormd(&[
        "simulate",
        "--scene",
        scene.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ])
}

fn text(o: &Output) -> String {
    format!(
        "{}{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    )
}

fn repo(rel: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join(rel)
}

fn write_scene(dir: &Path, body: &str) -> PathBuf {
    let path = dir.join("scene.toml");
    let profile = repo("firmware_cfg/iwr1443_mmnorm.cfg");
    std::fs::write(
        &path,
        format!(
            "[radar]\nprofile = {:?}\n\n{body}",
            profile.display().to_string()
        ),
    )
    .unwrap();
    path
}

const SMALL: &str = "[aperture]\nwidth_m = 0.03\nheight_m = 0.02\nspacing_m = 0.005\nz_m = 0.4\nlayout = \"iwr1443boost\"\n\
[noise]\nsnr_db = 30.0\nseed = 5\n\
[[object]]\nshape = \"cylinder\"\nradius_m = 0.02\nlength_m = 0.08\nposition_m = [0.0, 0.0, 0.02]\nrotation_deg = [0.0, 90.0, 0.0]\n";

#[test]
fn profile_prints_the_derived_frequency_plan() {
    let o = mmnormd(&[
        "profile",
        repo("firmware_cfg/iwr1443_mmnorm.cfg").to_str().unwrap(),
    ]);
    let t = text(&o);
    assert!(o.status.success(), "{t}");
    assert!(t.contains("77.500092 GHz"), "{t}");
    assert!(t.contains("5861163.139 Hz"), "{t}");
    assert!(t.contains("code 1214"), "{t}");
}

/// `mmnormd profile … | head -1`: the reader has gone before the first line is printed. The
/// pipe's read end is closed before the program starts, so every write fails with EPIPE.
#[cfg(unix)]
#[test]
fn a_report_into_a_closed_pipe_ends_quietly_instead_of_panicking() {
    use std::os::unix::process::ExitStatusExt;
    let (reader, writer) = std::io::pipe().unwrap();
    drop(reader);
    let o = Command::new(env!("CARGO_BIN_EXE_mmnormd"))
        .args([
            "profile",
            repo("firmware_cfg/iwr1443_mmnorm.cfg").to_str().unwrap(),
        ])
        .env("RUST_LOG", "warn")
        .stdout(writer)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(!stderr.contains("panicked"), "{stderr}");
    assert_eq!(
        o.status.signal(),
        Some(libc::SIGPIPE),
        "{:?}: {stderr}",
        o.status
    );
}

#[test]
fn simulate_then_inspect_writes_a_capture_truth_and_a_picture() {
    let dir = tempfile::tempdir().unwrap();
    let scene = write_scene(dir.path(), SMALL);
    let out = dir.path().join("cap");
    let o = simulate(&scene, &out);
    assert!(o.status.success(), "{}", text(&o));
    for f in [
        "capture.json",
        "tx.npy",
        "rx.npy",
        "samples.npy",
        "truth.ply",
        "truth_top.npy",
    ] {
        assert!(out.join(f).is_file(), "{f} missing");
    }
    // 7 × 5 positions × 4 RX.
    let capture = mmnormd::capture::read_capture_dir(&out).unwrap();
    assert_eq!(capture.antennas(), 140);
    assert_eq!(
        capture.extra["simulation"]["aperture"]["layout"],
        "iwr1443boost"
    );
    let top = mmnormd::capture::dir::read_points_npy(&out.join("truth_top.npy")).unwrap();
    assert!(
        top.iter().all(|p| p[2] <= 0.04 + 1e-4 && p[2] >= 0.0),
        "truth_top leaves the cylinder"
    );

    let png = dir.path().join("power.png");
    let o = mmnormd(&[
        "inspect",
        out.to_str().unwrap(),
        "--png",
        png.to_str().unwrap(),
    ]);
    let t = text(&o);
    assert!(o.status.success(), "{t}");
    assert!(t.contains("140 × 512 samples"), "{t}");
    assert!(
        std::fs::read(&png)
            .unwrap()
            .starts_with(b"\x89PNG\r\n\x1a\n")
    );

    // A range gate around the cylinder (one-way 0.36–0.40 m below the aperture).
    let o = mmnormd(&[
        "inspect",
        out.to_str().unwrap(),
        "--png",
        png.to_str().unwrap(),
        "--gate",
        "0.3,0.45",
    ]);
    let t = text(&o);
    assert!(o.status.success(), "{t}");
    assert!(t.contains("strongest echo between 0.3 m and 0.45 m"), "{t}");
    for bad in ["0.45,0.3", "x,1", "-1,2", "0.3"] {
        let o = mmnormd(&["inspect", out.to_str().unwrap(), "--gate", bad]);
        assert!(
            !o.status.success() && text(&o).contains("--gate"),
            "{bad}: {}",
            text(&o)
        );
    }

    // A second run into the same directory needs --force.
    let o = simulate(&scene, &out);
    assert!(!o.status.success());
    assert!(text(&o).contains("--force"));
}

#[test]
fn bad_scenes_are_refused_naming_field_and_value() {
    let dir = tempfile::tempdir().unwrap();
    let cases = [
        (SMALL.replace("z_m = 0.4", "z_m = nan"), "aperture.z_m"),
        (
            SMALL.replace("radius_m = 0.02", "radius_m = -0.02"),
            "object[0].radius_m",
        ),
        (
            SMALL.replace("length_m = 0.08", "length_m = 0.08\nsize_m = [1.0, 2.0]"),
            "object[0].size_m",
        ),
        (
            SMALL.replace("snr_db = 30.0", "snr_db = 30.0\ncolour = \"red\""),
            "colour",
        ),
        (
            SMALL.replace("shape = \"cylinder\"", "shape = \"torus\""),
            "torus",
        ),
        (SMALL.replace("z_m = 0.4", "z_m = 0.01"), "aperture plane"),
        (
            SMALL
                .replace("shape = \"cylinder\"", "shape = \"bottle\"")
                .replace("length_m = 0.08", "length_m = 0.03"),
            "object[0].length_m",
        ),
        (
            format!("{SMALL}\n[physics]\nmodel = \"raytrace\"\n"),
            "physics.model",
        ),
        (
            format!("{SMALL}\n[physics]\nspecular_cone_deg = 5.0\n"),
            "physics.specular_cone_deg",
        ),
        (
            format!("{SMALL}\n[physics]\nmodel = \"point-scatterer\"\nedge_spacing_m = 0.0\n"),
            "physics.edge_spacing_m",
        ),
    ];
    for (body, needle) in cases {
        let scene = write_scene(dir.path(), &body);
        let o = simulate(&scene, &dir.path().join("x"));
        let t = text(&o);
        assert!(!o.status.success(), "accepted a bad scene ({needle})");
        assert!(t.contains(needle), "error does not name `{needle}`: {t}");
    }
    assert!(!dir.path().join("x").join("capture.json").exists());
}

#[test]
fn inspect_refuses_a_directory_that_is_not_a_capture() {
    let dir = tempfile::tempdir().unwrap();
    let o = mmnormd(&["inspect", dir.path().to_str().unwrap()]);
    assert!(!o.status.success());
    assert!(text(&o).contains("capture.json"), "{}", text(&o));
}

#[test]
fn every_example_scene_loads() {
    let mut n = 0;
    for entry in std::fs::read_dir(repo("tools/scenes")).unwrap() {
        let path = entry.unwrap().path();
        if path.extension().is_some_and(|e| e == "toml") {
            mmnormd::sim::Scene::load(&path).unwrap_or_else(|e| panic!("{e}"));
            n += 1;
        }
    }
    assert!(n >= 4);
}

#[test]
fn eval_scores_the_truth_as_perfect_and_separates_position_from_shape() {
    let dir = tempfile::tempdir().unwrap();
    let scene = write_scene(dir.path(), SMALL);
    let out = dir.path().join("cap");
    assert!(simulate(&scene, &out).status.success());
    let top = mmnormd::capture::dir::read_points_npy(&out.join("truth_top.npy")).unwrap();
    let write_cloud = |name: &str, dz: f64| {
        let col = |k: usize| {
            top.iter()
                .map(|p| p[k] + if k == 2 { dz } else { 0.0 })
                .collect::<Vec<_>>()
        };
        let bytes = mmnormd::geometry::ply::encode(
            &[
                mmnormd::geometry::ply::Column::F64("x", col(0)),
                mmnormd::geometry::ply::Column::F64("y", col(1)),
                mmnormd::geometry::ply::Column::F64("z", col(2)),
            ],
            &[],
        );
        let path = dir.path().join(name);
        std::fs::write(&path, bytes).unwrap();
        path
    };
    let json = |points: &Path| {
        let o = mmnormd(&[
            "eval",
            "--points",
            points.to_str().unwrap(),
            "--truth",
            out.to_str().unwrap(),
            "--json",
        ]);
        assert!(o.status.success(), "{}", text(&o));
        serde_json::from_slice::<serde_json::Value>(&o.stdout).unwrap()
    };
    let same = json(&write_cloud("same.ply", 0.0));
    for key in [
        "f_score",
        "precision",
        "recall",
        "f_score_raw",
        "position_error_m",
        "point_error_median_m",
        "point_error_p90_m",
        "rel_error_under_5pct",
        "normal_cos_median",
        "normal_cos_p25",
        "points",
        "truth_points",
    ] {
        assert!(same.get(key).is_some(), "missing {key}");
    }
    assert_eq!(same["f_score"], 1.0);
    assert_eq!(same["point_error_median_m"], 0.0);
    assert!(
        same["normal_cos_median"].is_null(),
        "the cloud has no normals"
    );
    let lifted = json(&write_cloud("lifted.ply", 0.03));
    assert_eq!(lifted["f_score"], 1.0);
    assert!((lifted["position_error_m"].as_f64().unwrap() - 0.03).abs() < 1e-9);
    assert!(lifted["f_score_raw"].as_f64().unwrap() < 0.5);

    let eval = |points: &str, extra: &[&str]| {
        let points = dir.path().join(points);
        let mut args = vec![
            "eval",
            "--points",
            points.to_str().unwrap(),
            "--truth",
            out.to_str().unwrap(),
        ];
        args.extend_from_slice(extra);
        mmnormd(&args)
    };
    let o = eval("none.ply", &[]);
    assert!(!o.status.success() && text(&o).contains("none.ply"));
    let o = eval("same.ply", &["--tau-m", "0"]);
    assert!(!o.status.success() && text(&o).contains("--tau-m"));
    let o = eval("same.ply", &[]);
    assert!(
        text(&o).contains("F-score (τ = 1.5 cm)   1.0000"),
        "{}",
        text(&o)
    );
}

const PLATE: &str = "[aperture]\nwidth_m = 0.10\nheight_m = 0.10\nspacing_m = 0.0025\nz_m = 0.2\nlayout = \"monostatic\"\n\
[noise]\nsnr_db = 30.0\nseed = 6\n\
[[object]]\nshape = \"plate\"\nsize_m = [0.06, 0.06]\n";

#[test]
fn reconstruct_writes_points_summary_and_previews_then_eval_scores_them() {
    let dir = tempfile::tempdir().unwrap();
    let scene = write_scene(dir.path(), PLATE);
    let cap = dir.path().join("cap");
    assert!(simulate(&scene, &cap).status.success());
    let out = dir.path().join("recon");
    let args = |method: &str, out: &Path| {
        vec![
            "reconstruct".to_string(),
            cap.to_str().unwrap().to_string(),
            "--out".into(),
            out.to_str().unwrap().to_string(),
            "--method".into(),
            method.into(),
            "--voxel-mm".into(),
            "2".into(),
            "--volume".into(),
            "-0.05,0.05,-0.05,0.05,-0.03,0.03".into(),
        ]
    };
    let run = |a: Vec<String>| mmnormd(&a.iter().map(String::as_str).collect::<Vec<_>>());
    let o = run(args("mmnorm", &out));
    assert!(o.status.success(), "{}", text(&o));
    for f in [
        "points.ply",
        "summary.json",
        "points_top.png",
        "points_side.png",
        "image_max_z.png",
        "image_max_y.png",
    ] {
        assert!(out.join(f).is_file(), "{f} missing");
    }
    let ply =
        mmnormd::geometry::ply::parse(&std::fs::read(out.join("points.ply")).unwrap()).unwrap();
    assert!(ply.normals.is_some());
    assert!(ply.vertex_properties.iter().any(|(n, _)| n == "component"));
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap();
    let result = &summary["result"];
    assert_eq!(result["grid"]["dims"], serde_json::json!([51, 51, 31]));
    assert_eq!(result["optimisation"]["seed"], 1);
    assert_eq!(
        result["optimisation"]["antennas"].as_array().unwrap().len(),
        50
    );
    assert!(result["mask"]["attempts"][0]["threshold"].is_f64());
    assert!(result["stage_s"].as_array().unwrap().len() >= 6);

    // Refuses to overwrite without --force.
    let again = run(args("mmnorm", &out));
    assert!(!again.status.success());
    assert!(text(&again).contains("--force"), "{}", text(&again));

    let o = mmnormd(&[
        "eval",
        "--points",
        out.join("points.ply").to_str().unwrap(),
        "--truth",
        cap.to_str().unwrap(),
        "--json",
    ]);
    assert!(o.status.success(), "{}", text(&o));
    let m: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let f = m["f_score"].as_f64().unwrap();
    println!("CLI plate: F {f}, normal cos {}", m["normal_cos_median"]);
    assert!(f >= 0.95, "{m}");

    // The backprojection baseline has no normals.
    let bp = dir.path().join("bp");
    let o = run(args("backprojection", &bp));
    assert!(o.status.success(), "{}", text(&o));
    let ply =
        mmnormd::geometry::ply::parse(&std::fs::read(bp.join("points.ply")).unwrap()).unwrap();
    assert!(ply.normals.is_none());
    assert!(!ply.vertices_m.is_empty());

    // The ablations: `center` takes (max f + min f)/2; `weighted` lies inside the RSDF's range.
    for iso in ["center", "weighted"] {
        let dir_iso = dir.path().join(iso);
        let mut a = args("mmnorm", &dir_iso);
        a.extend(["--isosurface".to_string(), iso.to_string()]);
        let o = run(a);
        assert!(o.status.success(), "{}", text(&o));
        let summary: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(dir_iso.join("summary.json")).unwrap())
                .unwrap();
        assert_eq!(summary["result"]["isosurface"], iso);
        assert!(summary["result"]["optimisation"].is_null());
        for c in summary["result"]["components"].as_array().unwrap() {
            let (lo, hi, k) = (
                c["rsdf_min_m"].as_f64().unwrap(),
                c["rsdf_max_m"].as_f64().unwrap(),
                c["constant_m"].as_f64().unwrap(),
            );
            if iso == "center" {
                assert!((k - 0.5 * (lo + hi)).abs() < 1e-12, "{c}");
            } else {
                assert!(k > lo && k < hi, "{c}");
            }
            assert!(c["points"].as_u64().unwrap() > 0, "{c}");
        }
    }
}

#[test]
fn reconstruct_refuses_impossible_volumes_and_malformed_captures() {
    let dir = tempfile::tempdir().unwrap();
    let scene = write_scene(dir.path(), SMALL);
    let cap = dir.path().join("cap");
    assert!(simulate(&scene, &cap).status.success());
    let out = dir.path().join("recon");
    let attempt = |extra: &[&str]| {
        let mut a = vec![
            "reconstruct",
            cap.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ];
        a.extend_from_slice(extra);
        text(&mmnormd(&a))
    };
    let t = attempt(&["--volume", "-0.05,0.05,-0.05,0.05,0.3,0.5"]);
    assert!(t.contains("z1 = 0.5") && t.contains("aperture"), "{t}");
    let t = attempt(&["--volume", "-1,1,-1,1,-1,0.3"]);
    assert!(t.contains("voxels") && t.contains("more than"), "{t}");
    let t = attempt(&["--volume", "0,0.0005,-0.05,0.05,-0.05,0.05"]);
    assert!(t.contains("along x"), "{t}");
    let t = attempt(&["--volume", "0,1,2"]);
    assert!(t.contains("six numbers"), "{t}");
    let t = attempt(&["--voxel-mm", "0"]);
    assert!(t.contains("voxel_m = 0"), "{t}");
    let cfg = dir.path().join("recon.toml");
    std::fs::write(&cfg, "[optimisation]\nantenas = 10\n").unwrap();
    let t = attempt(&["--config", cfg.to_str().unwrap()]);
    assert!(t.contains("recon.toml") && t.contains("antenas"), "{t}");
    assert!(!out.join("points.ply").exists());

    // A truncated sample file is named.
    let samples = cap.join("samples.npy");
    let bytes = std::fs::read(&samples).unwrap();
    std::fs::write(&samples, &bytes[..bytes.len() / 2]).unwrap();
    let t = attempt(&[]);
    assert!(t.contains("samples.npy"), "{t}");
}

#[test]
fn the_robot_simulators_fault_flags_are_refused_naming_flag_and_value() {
    let o = mmnormd(&["sim", "robot", "--input-loss", "3"]);
    assert!(!o.status.success());
    assert!(
        text(&o).contains("--input-loss 3: expected MOVE:SECONDS"),
        "{}",
        text(&o)
    );
    let o = mmnormd(&["sim", "robot", "--protective-stop", "1:soon"]);
    assert!(!o.status.success());
    assert!(
        text(&o).contains("--protective-stop seconds `soon`"),
        "{}",
        text(&o)
    );
}

#[test]
fn bench_accuracy_refuses_a_selection_that_matches_nothing_or_comes_with_report_only() {
    let out = tempfile::tempdir().unwrap();
    let suite = repo("tools/bench/smoke.toml");
    let args = |extra: &[&str]| {
        let mut a = vec![
            "bench",
            "accuracy",
            "--suite",
            suite.to_str().unwrap(),
            "--out",
            out.path().to_str().unwrap(),
        ];
        a.extend_from_slice(extra);
        mmnormd(&a)
    };
    let o = args(&["--only", "cube"]);
    assert!(!o.status.success());
    assert!(
        text(&o).contains("`--only` = \"cube\": no case id is or contains it"),
        "{}",
        text(&o)
    );
    let o = args(&["--only", "sphere", "--report-only"]);
    assert!(!o.status.success());
    assert!(text(&o).contains("cannot be used with"), "{}", text(&o));
    // Neither wrote anything.
    assert_eq!(std::fs::read_dir(out.path()).unwrap().count(), 0);
}

#[test]
fn reconstruct_refuses_an_output_that_is_a_file_before_any_work() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("taken");
    std::fs::write(&file, b"not a directory").unwrap();
    // The capture does not exist either: the output is checked first, so its error comes alone.
    let started = std::time::Instant::now();
    let o = mmnormd(&[
        "reconstruct",
        dir.path().join("no-capture").to_str().unwrap(),
        "--out",
        file.to_str().unwrap(),
    ]);
    let t = text(&o);
    println!("{t} after {:.2} s", started.elapsed().as_secs_f64());
    assert!(!o.status.success());
    assert!(
        t.contains("--out") && t.contains("exists and is not a directory"),
        "{t}"
    );
    assert_eq!(std::fs::read(&file).unwrap(), b"not a directory");
}

#[test]
fn logs_are_plain_text_when_not_on_a_terminal() {
    // A capture whose truth file is unreadable: the reconstruction goes on and warns.
    let dir = tempfile::tempdir().unwrap();
    let scene = write_scene(dir.path(), SMALL);
    let cap = dir.path().join("cap");
    assert!(simulate(&scene, &cap).status.success());
    std::fs::write(cap.join("truth_top.npy"), b"broken").unwrap();
    let out = dir.path().join("recon");
    let o = mmnormd(&[
        "reconstruct",
        cap.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--voxel-mm",
        "2",
    ]);
    let err = String::from_utf8_lossy(&o.stderr).to_string();
    assert!(o.status.success(), "{}", text(&o));
    assert!(
        err.contains("WARN") && err.contains("previews without the truth"),
        "{err}"
    );
    assert!(
        !err.contains('\u{1b}'),
        "escape sequences in a pipe: {err:?}"
    );
    assert!(out.join("points_top.png").is_file());
}

#[test]
fn ctl_takes_negative_values_and_says_to_start_a_daemon_that_is_not_there() {
    // Bind and drop: nothing listens on the port afterwards.
    let port = std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    let addr = format!("localhost:{port}");
    let o = mmnormd(&["ctl", "--addr", &addr, "scan", "--width-m", "-1"]);
    let t = text(&o);
    assert!(!o.status.success());
    assert!(!t.contains("unexpected argument"), "{t}");
    assert!(t.contains(&format!(":{port}")), "{t}");
    assert!(
        t.contains("is the daemon running?") && t.contains("mmnormd --config"),
        "{t}"
    );
}

#[test]
fn calibrate_refuses_a_reflector_position_that_is_not_three_numbers() {
    for bad in ["0.45,-0.2", "0.45,-0.2,x", "0.45,-0.2,inf"] {
        let o = mmnormd(&["calibrate", "no-such.mcap", "--reflector-in-base-m", bad]);
        let t = text(&o);
        assert!(!o.status.success());
        assert!(
            t.contains(&format!("--reflector-in-base-m {bad}")) && t.contains("X,Y,Z in metres"),
            "{t}"
        );
    }
}
