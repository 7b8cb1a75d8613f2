//! Loading meshes from STL (binary or ASCII), Wavefront OBJ and PLY files.

use std::path::{Path, PathBuf};

use super::{TriMesh, ply};

/// Vertices closer than this are merged after loading (STL repeats each corner per triangle).
const WELD_TOLERANCE_M: f64 = 1e-9;

/// A mesh file that could not be loaded, with its path.
#[derive(Debug, thiserror::Error)]
#[error("mesh {path}: {reason}")]
pub struct MeshError {
    pub path: PathBuf,
    pub reason: String,
}

/// Loads a mesh by file extension (`.stl`, `.obj`, `.ply`, case-insensitive) and welds duplicate
/// vertices. An OBJ file whose material library is missing still loads: materials are not used.
pub fn load_mesh(path: &Path) -> Result<TriMesh, MeshError> {
    let err = |reason: String| MeshError {
        path: path.to_path_buf(),
        reason,
    };
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase)
        .unwrap_or_default();
    let mesh = match ext.as_str() {
        "stl" => load_stl(path).map_err(err)?,
        "obj" => load_obj(path).map_err(err)?,
        "ply" => {
            let bytes = std::fs::read(path).map_err(|e| err(e.to_string()))?;
            let data = ply::parse(&bytes).map_err(err)?;
            TriMesh {
                vertices_m: data.vertices_m,
                triangles: data.triangles,
            }
        }
        other => {
            return Err(err(format!(
                "unknown mesh format `.{other}`; use .stl, .obj or .ply"
            )));
        }
    };
    let mesh = mesh.welded(WELD_TOLERANCE_M);
    mesh.validate().map_err(err)?;
    Ok(mesh)
}

fn load_stl(path: &Path) -> Result<TriMesh, String> {
    let mut file = std::fs::File::open(path).map_err(|e| e.to_string())?;
    let indexed = stl_io::read_stl(&mut file).map_err(|e| format!("not a readable STL: {e}"))?;
    Ok(TriMesh {
        vertices_m: indexed
            .vertices
            .iter()
            .map(|v| [f64::from(v[0]), f64::from(v[1]), f64::from(v[2])])
            .collect(),
        triangles: indexed
            .faces
            .iter()
            .map(|f| f.vertices.map(|k| k as u32))
            .collect(),
    })
}

fn load_obj(path: &Path) -> Result<TriMesh, String> {
    let options = tobj::LoadOptions {
        triangulate: true,
        single_index: false,
        ignore_points: true,
        ignore_lines: true,
    };
    // The second element carries the materials; a missing .mtl only makes it an Err.
    let (models, _materials) =
        tobj::load_obj(path, &options).map_err(|e| format!("not a readable OBJ: {e}"))?;
    let mut mesh = TriMesh::default();
    for model in models {
        let m = model.mesh;
        let part = TriMesh {
            vertices_m: m
                .positions
                .chunks_exact(3)
                .map(|p| [f64::from(p[0]), f64::from(p[1]), f64::from(p[2])])
                .collect(),
            triangles: m
                .indices
                .chunks_exact(3)
                .map(|t| [t[0], t[1], t[2]])
                .collect(),
        };
        mesh.append(&part);
    }
    Ok(mesh)
}
