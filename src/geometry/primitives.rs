//! Primitive shapes as triangle meshes, centred on the origin, with every edge no longer than a
//! given length so that sampling and normals stay accurate on curved parts.

use std::f64::consts::PI;

use super::TriMesh;

fn divisions(length_m: f64, max_edge_m: f64) -> usize {
    ((length_m / max_edge_m).ceil() as usize).max(1)
}

/// Adds a grid of `nu`×`nv` quads spanning `origin + u·[0,1] + v·[0,1]` (normal along u×v).
fn add_grid(mesh: &mut TriMesh, origin: [f64; 3], u: [f64; 3], v: [f64; 3], nu: usize, nv: usize) {
    let base = mesh.vertices_m.len() as u32;
    for j in 0..=nv {
        for i in 0..=nu {
            let (a, b) = (i as f64 / nu as f64, j as f64 / nv as f64);
            mesh.vertices_m
                .push([0, 1, 2].map(|k| origin[k] + a * u[k] + b * v[k]));
        }
    }
    let idx = |i: usize, j: usize| base + (j * (nu + 1) + i) as u32;
    for j in 0..nv {
        for i in 0..nu {
            mesh.triangles
                .push([idx(i, j), idx(i + 1, j), idx(i + 1, j + 1)]);
            mesh.triangles
                .push([idx(i, j), idx(i + 1, j + 1), idx(i, j + 1)]);
        }
    }
}

/// A one-sided rectangle in the xy-plane facing +z, `size_m = [x, y]`. Its rim is a free edge.
pub fn plate_mesh(size_m: [f64; 2], max_edge_m: f64) -> TriMesh {
    let mut m = TriMesh::default();
    let (nx, ny) = (
        divisions(size_m[0], max_edge_m),
        divisions(size_m[1], max_edge_m),
    );
    add_grid(
        &mut m,
        [-size_m[0] / 2.0, -size_m[1] / 2.0, 0.0],
        [size_m[0], 0.0, 0.0],
        [0.0, size_m[1], 0.0],
        nx,
        ny,
    );
    m.welded(1e-12)
}

/// A closed box with `size_m = [x, y, z]`.
pub fn box_mesh(size_m: [f64; 3], max_edge_m: f64) -> TriMesh {
    let [sx, sy, sz] = size_m;
    let (hx, hy, hz) = (sx / 2.0, sy / 2.0, sz / 2.0);
    let (nx, ny, nz) = (
        divisions(sx, max_edge_m),
        divisions(sy, max_edge_m),
        divisions(sz, max_edge_m),
    );
    let mut m = TriMesh::default();
    // Each face: origin, u, v with u×v pointing outward.
    add_grid(
        &mut m,
        [-hx, -hy, hz],
        [sx, 0.0, 0.0],
        [0.0, sy, 0.0],
        nx,
        ny,
    );
    add_grid(
        &mut m,
        [-hx, hy, -hz],
        [sx, 0.0, 0.0],
        [0.0, -sy, 0.0],
        nx,
        ny,
    );
    add_grid(
        &mut m,
        [hx, -hy, -hz],
        [0.0, sy, 0.0],
        [0.0, 0.0, sz],
        ny,
        nz,
    );
    add_grid(
        &mut m,
        [-hx, hy, -hz],
        [0.0, -sy, 0.0],
        [0.0, 0.0, sz],
        ny,
        nz,
    );
    add_grid(
        &mut m,
        [hx, hy, -hz],
        [-sx, 0.0, 0.0],
        [0.0, 0.0, sz],
        nx,
        nz,
    );
    add_grid(
        &mut m,
        [-hx, -hy, -hz],
        [sx, 0.0, 0.0],
        [0.0, 0.0, sz],
        nx,
        nz,
    );
    m.welded(1e-12)
}

/// A UV sphere of `radius_m`.
pub fn sphere_mesh(radius_m: f64, max_edge_m: f64) -> TriMesh {
    let rings = divisions(PI * radius_m, max_edge_m).max(4);
    let segments = divisions(2.0 * PI * radius_m, max_edge_m).max(8);
    let mut m = TriMesh::default();
    m.vertices_m.push([0.0, 0.0, radius_m]);
    for r in 1..rings {
        let theta = PI * r as f64 / rings as f64;
        for s in 0..segments {
            let phi = 2.0 * PI * s as f64 / segments as f64;
            m.vertices_m.push([
                radius_m * theta.sin() * phi.cos(),
                radius_m * theta.sin() * phi.sin(),
                radius_m * theta.cos(),
            ]);
        }
    }
    m.vertices_m.push([0.0, 0.0, -radius_m]);
    let south = (m.vertices_m.len() - 1) as u32;
    let ring = |r: usize, s: usize| (1 + (r - 1) * segments + s % segments) as u32;
    for s in 0..segments {
        m.triangles.push([0, ring(1, s), ring(1, s + 1)]);
        m.triangles
            .push([south, ring(rings - 1, s + 1), ring(rings - 1, s)]);
    }
    for r in 1..rings - 1 {
        for s in 0..segments {
            m.triangles
                .push([ring(r, s), ring(r + 1, s), ring(r + 1, s + 1)]);
            m.triangles
                .push([ring(r, s), ring(r + 1, s + 1), ring(r, s + 1)]);
        }
    }
    m
}

/// A closed cylinder of `radius_m` and `length_m` along z.
pub fn cylinder_mesh(radius_m: f64, length_m: f64, max_edge_m: f64) -> TriMesh {
    let segments = divisions(2.0 * PI * radius_m, max_edge_m).max(8);
    let stacks = divisions(length_m, max_edge_m);
    let rings = divisions(radius_m, max_edge_m);
    let h = length_m / 2.0;
    let mut m = TriMesh::default();
    let at = |s: usize, r: f64, z: f64| {
        let phi = 2.0 * PI * (s % segments) as f64 / segments as f64;
        [r * phi.cos(), r * phi.sin(), z]
    };
    // Side.
    for k in 0..=stacks {
        let z = -h + length_m * k as f64 / stacks as f64;
        for s in 0..segments {
            m.vertices_m.push(at(s, radius_m, z));
        }
    }
    let side = |k: usize, s: usize| (k * segments + s % segments) as u32;
    for k in 0..stacks {
        for s in 0..segments {
            m.triangles
                .push([side(k, s), side(k, s + 1), side(k + 1, s + 1)]);
            m.triangles
                .push([side(k, s), side(k + 1, s + 1), side(k + 1, s)]);
        }
    }
    // Caps: concentric rings down to a centre vertex.
    for (z, up) in [(h, true), (-h, false)] {
        let centre = m.vertices_m.len() as u32;
        m.vertices_m.push([0.0, 0.0, z]);
        let first = m.vertices_m.len() as u32;
        for q in 1..=rings {
            let r = radius_m * q as f64 / rings as f64;
            for s in 0..segments {
                m.vertices_m.push(at(s, r, z));
            }
        }
        let v = |q: usize, s: usize| first + ((q - 1) * segments + s % segments) as u32;
        let mut push = |a: u32, b: u32, c: u32| {
            m.triangles.push(if up { [a, b, c] } else { [a, c, b] });
        };
        for s in 0..segments {
            push(centre, v(1, s), v(1, s + 1));
        }
        for q in 1..rings {
            for s in 0..segments {
                push(v(q, s), v(q + 1, s), v(q + 1, s + 1));
                push(v(q, s), v(q + 1, s + 1), v(q, s + 1));
            }
        }
    }
    m.welded(1e-12)
}

/// A closed solid of revolution about z: the profile `(r, z)` runs from a point on the axis to
/// another point on the axis, each straight piece cut to `max_edge_m`. The mesh is oriented
/// outwards whichever way the profile runs.
fn revolve(profile: &[[f64; 2]], max_edge_m: f64) -> TriMesh {
    let r_max = profile.iter().map(|p| p[0]).fold(0.0, f64::max);
    let segments = divisions(2.0 * PI * r_max, max_edge_m).max(8);
    let mut points: Vec<[f64; 2]> = vec![profile[0]];
    for w in profile.windows(2) {
        let [a, b] = [w[0], w[1]];
        let n = divisions(
            ((b[0] - a[0]).powi(2) + (b[1] - a[1]).powi(2)).sqrt(),
            max_edge_m,
        );
        for k in 1..=n {
            let f = k as f64 / n as f64;
            points.push([a[0] + f * (b[0] - a[0]), a[1] + f * (b[1] - a[1])]);
        }
    }
    let mut m = TriMesh::default();
    // One vertex for a profile point on the axis, a ring of `segments` otherwise.
    let mut first = Vec::with_capacity(points.len());
    for p in &points {
        first.push(m.vertices_m.len() as u32);
        if p[0] <= 0.0 {
            m.vertices_m.push([0.0, 0.0, p[1]]);
        } else {
            for s in 0..segments {
                let phi = 2.0 * PI * s as f64 / segments as f64;
                m.vertices_m
                    .push([p[0] * phi.cos(), p[0] * phi.sin(), p[1]]);
            }
        }
    }
    let at = |k: usize, s: usize| {
        if points[k][0] <= 0.0 {
            first[k]
        } else {
            first[k] + (s % segments) as u32
        }
    };
    for k in 0..points.len() - 1 {
        for s in 0..segments {
            let (a, b, c, d) = (at(k, s), at(k, s + 1), at(k + 1, s + 1), at(k + 1, s));
            if a != b {
                m.triangles.push([a, b, c]);
            }
            if c != d {
                m.triangles.push([a, c, d]);
            }
        }
    }
    if m.signed_volume_m3() < 0.0 {
        for t in &mut m.triangles {
            t.swap(1, 2);
        }
    }
    m.welded(1e-12)
}

/// An open-topped cup: a cylindrical wall of outer `radius_m` and `wall_m` thickness on a
/// bottom of the same thickness, `height_m` tall, with a flat rim; centred on the origin.
pub fn cup_mesh(radius_m: f64, height_m: f64, wall_m: f64, max_edge_m: f64) -> TriMesh {
    let h = height_m / 2.0;
    let inner = radius_m - wall_m;
    revolve(
        &[
            [0.0, -h],
            [radius_m, -h],
            [radius_m, h],
            [inner, h],
            [inner, -h + wall_m],
            [0.0, -h + wall_m],
        ],
        max_edge_m,
    )
}

/// An open bowl: a hemispherical shell of outer `radius_m` and `wall_m` thickness, opening
/// upwards, with a flat rim; its bounding box is centred on the origin.
pub fn bowl_mesh(radius_m: f64, wall_m: f64, max_edge_m: f64) -> TriMesh {
    let inner = radius_m - wall_m;
    let arc = |r: f64| {
        let n = divisions(PI / 2.0 * r, max_edge_m).max(4);
        (0..=n).map(move |k| {
            let a = PI / 2.0 * k as f64 / n as f64;
            [r * a.sin(), -r * a.cos() + radius_m / 2.0]
        })
    };
    let mut profile: Vec<[f64; 2]> = arc(radius_m).collect();
    profile.extend(arc(inner).collect::<Vec<_>>().into_iter().rev());
    revolve(&profile, max_edge_m)
}

/// A capped bottle standing upright: a cylindrical body of `radius_m`, a rounded shoulder, a
/// neck and a screw cap, `height_m` tall in all; centred on its bounding box.
///
/// The proportions are those of a drinks or detergent bottle and follow from the two sizes:
/// - the neck's radius is 0.4·`radius_m` (at least 4 mm) and the cap's 1.15 times the neck's,
///   so the cap overhangs the neck;
/// - the cap is 0.08·`height_m` tall, the neck 0.06·`height_m`;
/// - the shoulder is a quarter ellipse `radius_m` tall (at most half the height left under the
///   neck) from the body's wall, where it is vertical, to the neck, where it is level.
///
/// Seen from above it shows surfaces at three depths: the cap's flat top, the shoulder sloping
/// through every angle, and the flat ring of shoulder around the neck beyond the cap's
/// overhang. That is what makes a bottle hard for one isosurface level per component.
pub fn bottle_mesh(radius_m: f64, height_m: f64, max_edge_m: f64) -> TriMesh {
    let h = height_m / 2.0;
    let neck_m = (0.4 * radius_m).max(0.004).min(0.9 * radius_m);
    let cap_m = (1.15 * neck_m).min(radius_m);
    let cap_bottom = h - 0.08 * height_m;
    let neck_bottom = cap_bottom - 0.06 * height_m;
    let shoulder_m = radius_m.min(0.5 * (neck_bottom + h));
    let shoulder_bottom = neck_bottom - shoulder_m;
    let steps = divisions(PI / 2.0 * radius_m, max_edge_m).max(8);
    let mut profile = vec![[0.0, -h], [radius_m, -h], [radius_m, shoulder_bottom]];
    profile.extend((1..=steps).map(|k| {
        let a = PI / 2.0 * k as f64 / steps as f64;
        [
            neck_m + (radius_m - neck_m) * a.cos(),
            shoulder_bottom + shoulder_m * a.sin(),
        ]
    }));
    profile.extend([
        [neck_m, cap_bottom],
        [cap_m, cap_bottom],
        [cap_m, h],
        [0.0, h],
    ]);
    revolve(&profile, max_edge_m)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn closed_volume_close(m: &TriMesh, expected: f64, tol: f64) {
        let v = m.signed_volume_m3();
        assert!((v - expected).abs() / expected < tol, "{v} vs {expected}");
    }

    #[test]
    fn primitives_are_closed_and_outward() {
        closed_volume_close(&box_mesh([0.1, 0.2, 0.05], 0.01), 0.001, 1e-9);
        closed_volume_close(
            &sphere_mesh(0.05, 0.002),
            4.0 / 3.0 * PI * 0.05f64.powi(3),
            2e-3,
        );
        closed_volume_close(&cylinder_mesh(0.03, 0.1, 0.002), PI * 0.0009 * 0.1, 2e-3);
        let (r, h, w) = (0.04, 0.1, 0.003);
        let cup_volume = PI * r * r * h - PI * (r - w).powi(2) * (h - w);
        closed_volume_close(&cup_mesh(r, h, w, 0.002), cup_volume, 3e-3);
        let bowl_volume = 2.0 / 3.0 * PI * (r.powi(3) - (r - w).powi(3));
        closed_volume_close(&bowl_mesh(r, w, 0.002), bowl_volume, 5e-3);
        let bottle = bottle_mesh(0.035, 0.19, 0.002);
        let (lo, hi) = bottle.bounds().unwrap();
        assert!((lo[2] + 0.095).abs() < 1e-12 && (hi[2] - 0.095).abs() < 1e-12);
        assert!(
            (hi[0] - 0.035).abs() < 1e-4,
            "the body is the widest part: {hi:?}"
        );
        // Body, shoulder (a quarter ellipse), neck and cap, by parts.
        let (neck, cap) = (0.014, 0.0161);
        let (cap_h, neck_h) = (0.08 * 0.19, 0.06 * 0.19);
        let body_h = 0.19 - cap_h - neck_h - 0.035;
        let ellipse_volume = {
            // ∫ π (neck + (R−neck)·cos a)² · R·cos a da over a ∈ [0, π/2]
            let (a, b) = (neck, 0.035 - neck);
            PI * 0.035 * (a * a + PI / 2.0 * a * b + 2.0 / 3.0 * b * b)
        };
        let bottle_volume = PI * 0.035f64.powi(2) * body_h
            + ellipse_volume
            + PI * neck * neck * neck_h
            + PI * cap * cap * cap_h;
        closed_volume_close(&bottle, bottle_volume, 3e-3);
        let bowl = bowl_mesh(r, w, 0.002).bounds().unwrap();
        assert!((bowl.0[2] + r / 2.0).abs() < 1e-12 && (bowl.1[2] - r / 2.0).abs() < 1e-12);
        let plate = plate_mesh([0.1, 0.05], 0.01);
        assert!((plate.area_m2() - 0.005).abs() < 1e-12);
        assert!(plate.signed_volume_m3().abs() < 1e-15);
    }
}
