//! Mesh loading against the vendored YCB meshes (`data/meshes`) and their reference figures (`meshes.json`).

use std::path::{Path, PathBuf};

use mmnormd::geometry::load_mesh;

fn meshes_dir() -> PathBuf {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("data/meshes");
    assert!(
        dir.join("meshes.json").is_file(),
        "the YCB meshes are expected at {} (data/meshes in the repository)",
        dir.display()
    );
    dir
}

#[test]
fn every_vendored_mesh_loads_with_its_reference_bbox_and_area() {
    let dir = meshes_dir();
    let reference: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("meshes.json")).unwrap()).unwrap();
    let entries = reference.as_object().unwrap();
    assert!(entries.len() >= 13);
    for (name, info) in entries {
        let mesh = load_mesh(&dir.join(name)).unwrap_or_else(|e| panic!("{e}"));
        let expected = info["triangles"].as_u64().unwrap() as usize;
        // The file uses two spellings of its keys.
        let field = |a: &str, b: &str| {
            let v = &info[a];
            if v.is_null() {
                info[b].clone()
            } else {
                v.clone()
            }
        };
        let (lo, hi) = mesh.bounds().unwrap();
        for k in 0..3 {
            let want_lo = field("bbox_min_m", "bbox_min")[k].as_f64().unwrap();
            let want_hi = field("bbox_max_m", "bbox_max")[k].as_f64().unwrap();
            assert!(
                (lo[k] - want_lo).abs() < 1e-6,
                "{name} bbox min[{k}] {} vs {want_lo}",
                lo[k]
            );
            assert!(
                (hi[k] - want_hi).abs() < 1e-6,
                "{name} bbox max[{k}] {} vs {want_hi}",
                hi[k]
            );
        }
        let area = mesh.area_m2();
        let want_area = field("surface_area_m2", "area_m2").as_f64().unwrap();
        assert!(
            (area / want_area - 1.0).abs() < 1e-3,
            "{name} area {area} vs {want_area}"
        );
        // Welding drops only degenerate triangles.
        assert!(
            mesh.triangles.len() <= expected && mesh.triangles.len() + 16 >= expected,
            "{name}: {} triangles",
            mesh.triangles.len()
        );
    }
}

#[test]
fn soup_can_volume_matches_and_obj_without_its_mtl_equals_the_stl() {
    let dir = meshes_dir();
    let can = load_mesh(&dir.join("005_tomato_soup_can_google16k.stl")).unwrap();
    let volume = can.signed_volume_m3();
    assert!((volume / 0.0003193605 - 1.0).abs() < 0.01, "{volume}");
    let stl = load_mesh(&dir.join("030_fork_google16k.stl")).unwrap();
    let obj = load_mesh(&dir.join("030_fork_google16k_textured.obj")).unwrap();
    assert!(!dir.join("030_fork_google16k_textured.mtl").exists());
    let (a, b) = (stl.bounds().unwrap(), obj.bounds().unwrap());
    for k in 0..3 {
        assert!((a.0[k] - b.0[k]).abs() < 1e-6 && (a.1[k] - b.1[k]).abs() < 1e-6);
    }
    assert!((stl.area_m2() / obj.area_m2() - 1.0).abs() < 1e-5);
}

#[test]
fn unreadable_meshes_are_refused_with_their_path() {
    let dir = tempfile::tempdir().unwrap();
    let bad = dir.path().join("broken.stl");
    std::fs::write(
        &bad,
        b"solid x\n facet normal 0 0 1\n  outer loop\n   vertex 0 0",
    )
    .unwrap();
    let e = load_mesh(&bad).unwrap_err().to_string();
    assert!(e.contains("broken.stl"), "{e}");
    let e = load_mesh(&dir.path().join("missing.ply"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("missing.ply"), "{e}");
    let e = load_mesh(&dir.path().join("model.glb"))
        .unwrap_err()
        .to_string();
    assert!(e.contains(".glb"), "{e}");
}
