//! `mmnormd bench coverage`: how much of each case's truth an aperture can show a method that
//! sees specular echoes, found from the geometry alone, without simulating.
//!
//! A point of the top-view truth ([`crate::sim::truth::top_surface_with_normals`]) is *seen* when the line along
//! its normal (its mirror direction for a monostatic antenna) reaches the aperture's plane inside
//! the rectangle that the antennas span, with no geometry of the scene in the way. The *ideal*
//! reconstruction is the seen points themselves, scored against the whole truth exactly as a
//! method's points are ([`evaluate`], with the paper's §5 position correction). Its F-score is
//! what a method would get that puts a point on every seen truth point and nowhere else.
//!
//! It is an estimate, not a strict bound. A real echo also comes from within a Fresnel zone of
//! the mirror direction, from edges and from diffuse scattering, so a method can recall a little
//! more; the cardboard sheet, the antenna pattern and the TX–RX separation (millimetres) are
//! left out. It answers one question: how much of a case's F-score is lost because the surface
//! faces away from this aperture.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use rayon::prelude::*;

use super::suite::{Case, PHYSICAL_OPTICS, Suite, physics_suffix};
use super::{BenchError, io};
use crate::capture::dir::write_atomically;
use crate::eval::{Metrics, evaluate, quantile};
use crate::geometry::Bvh;
use crate::plot::{BLACK, BLUE, CdfChart, GREEN, Marker, ORANGE, PINK, RED, Rgb, Series};
use crate::progress::Progress;
use crate::sim::aperture::raster_antennas;
use crate::sim::scene::Scene;
use crate::sim::truth::{TOP_GRID_M, scene_mesh, top_surface_in};

/// Shadow rays start this far off the surface along the normal, metres.
const RAY_OFFSET_M: f64 = 1e-4;

/// The rectangle of the aperture's plane that the antennas span.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ApertureRect {
    pub x_m: [f64; 2],
    pub y_m: [f64; 2],
    pub z_m: f64,
}

impl ApertureRect {
    /// The span of every TX and RX antenna of `scene`'s raster.
    pub fn of(scene: &Scene) -> ApertureRect {
        let antennas = raster_antennas(
            &scene.aperture,
            &scene.rx_channels(),
            scene.plan.first_wavelength_m(),
        );
        let mut r = ApertureRect {
            x_m: [f64::INFINITY, f64::NEG_INFINITY],
            y_m: [f64::INFINITY, f64::NEG_INFINITY],
            z_m: scene.aperture.z_m,
        };
        for p in antennas.tx_m.iter().chain(&antennas.rx_m) {
            r.x_m = [r.x_m[0].min(p[0]), r.x_m[1].max(p[0])];
            r.y_m = [r.y_m[0].min(p[1]), r.y_m[1].max(p[1])];
        }
        r
    }

    /// Where the line from `p` along `n` crosses the aperture's plane, if it does so ahead of
    /// `p` and inside the rectangle: the distance along the unit `n`, metres.
    pub fn mirror_hit(&self, p: [f64; 3], n: [f64; 3]) -> Option<f64> {
        if n[2] <= 0.0 || p[2] >= self.z_m {
            return None;
        }
        let s = (self.z_m - p[2]) / n[2];
        let x = p[0] + s * n[0];
        let y = p[1] + s * n[1];
        (x >= self.x_m[0] && x <= self.x_m[1] && y >= self.y_m[0] && y <= self.y_m[1]).then_some(s)
    }
}

/// Which `points` (with unit `normals`) `rect` sees along their mirror lines, none of which
/// may cross a triangle of `bvh` on the way.
pub fn seen(
    points: &[[f64; 3]],
    normals: &[[f64; 3]],
    bvh: &Bvh,
    rect: &ApertureRect,
) -> Vec<bool> {
    points
        .par_iter()
        .zip(normals)
        .map(|(&p, &n)| {
            rect.mirror_hit(p, n).is_some_and(|s| {
                let o = [0, 1, 2].map(|k| (p[k] + RAY_OFFSET_M * n[k]) as f32);
                !bvh.occluded(o, n.map(|c| c as f32), (s - RAY_OFFSET_M) as f32)
            })
        })
        .collect()
}

/// One case's coverage under one aperture.
#[derive(Debug, Clone, PartialEq)]
pub struct CaseCoverage {
    pub id: String,
    pub truth_points: usize,
    /// The share of truth points seen.
    pub seen_fraction: f64,
    /// The seen points scored as a reconstruction.
    pub ideal: Metrics,
}

/// The coverage of `case` at F-score threshold `tau_m`.
pub fn case_coverage(case: &Case, tau_m: f64) -> CaseCoverage {
    let mesh = scene_mesh(&case.scene);
    let bvh = Bvh::build(&mesh);
    let (truth, normals) = top_surface_in(&mesh, &bvh, TOP_GRID_M);
    let rect = ApertureRect::of(&case.scene);
    let mask = seen(&truth, &normals, &bvh, &rect);
    let (points, point_normals): (Vec<[f64; 3]>, Vec<[f64; 3]>) = truth
        .iter()
        .zip(&normals)
        .zip(&mask)
        .filter(|(_, s)| **s)
        .map(|((p, n), _)| (*p, *n))
        .unzip();
    let ideal = evaluate(&points, Some(&point_normals), &truth, Some(&normals), tau_m);
    CaseCoverage {
        id: case.id.clone(),
        truth_points: truth.len(),
        seen_fraction: if truth.is_empty() {
            0.0
        } else {
            points.len() as f64 / truth.len() as f64
        },
        ideal,
    }
}

/// One suite's coverage, case by case, in the suite's order.
pub struct SuiteCoverage {
    /// The suite file's stem (`reduced`, `paper`): the columns' prefix.
    pub label: String,
    pub path: PathBuf,
    /// "W×H cm at S mm, C cm above the objects" (the first case's clearance): the aperture.
    pub aperture: String,
    pub cases: Vec<CaseCoverage>,
}

/// Every case of `suite`, with a progress bar.
pub fn suite_coverage(suite: &Suite, quiet: bool) -> SuiteCoverage {
    let progress = Progress::new("coverage", suite.cases.len() as u64, quiet);
    let cases = suite
        .cases
        .iter()
        .map(|c| {
            progress.set_message(&c.id);
            let r = case_coverage(c, suite.tau_m);
            progress.inc(1);
            r
        })
        .collect();
    progress.finish();
    let aperture = suite.cases.first().map_or(String::new(), |c| {
        let a = &c.scene.aperture;
        let top_m = scene_mesh(&c.scene).bounds().map_or(0.0, |(_, hi)| hi[2]);
        format!(
            "{:.0}×{:.0} cm at {:.2} mm, {:.0} cm above the objects",
            a.width_m * 100.0,
            a.height_m * 100.0,
            a.spacing_m * 1e3,
            (a.z_m - top_m) * 100.0
        )
    });
    SuiteCoverage {
        label: suite
            .path
            .file_stem()
            .map_or("suite".into(), |s| s.to_string_lossy().into_owned()),
        path: suite.path.clone(),
        aperture,
        cases,
    }
}

/// A method's F-score and recall on one case, read from a `bench accuracy` results.csv.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Achieved {
    pub f_score: f64,
    pub recall: f64,
}

/// The records of CSV `text` (RFC 4180: quoted fields may hold commas, doubled quotes and
/// line breaks), each with the line it starts on (from 1).
fn csv_records(text: &str) -> Vec<(usize, Vec<String>)> {
    let mut records = Vec::new();
    let (mut fields, mut field) = (Vec::new(), String::new());
    let (mut line, mut start, mut quoted) = (1, 1, false);
    let mut chars = text.chars().peekable();
    while let Some(c) = chars.next() {
        match (quoted, c) {
            (true, '"') if chars.peek() == Some(&'"') => {
                chars.next();
                field.push('"');
            }
            (true, '"') => quoted = false,
            (false, '"') if field.is_empty() => quoted = true,
            (false, ',') => fields.push(std::mem::take(&mut field)),
            (false, '\r') if chars.peek() == Some(&'\n') => {}
            (false, '\n') => {
                fields.push(std::mem::take(&mut field));
                records.push((start, std::mem::take(&mut fields)));
                line += 1;
                start = line;
            }
            (_, c) => {
                line += usize::from(c == '\n');
                field.push(c);
            }
        }
    }
    if !field.is_empty() || !fields.is_empty() {
        fields.push(field);
        records.push((start, fields));
    }
    records
}

/// Reads the `method` rows of a `bench accuracy` results.csv, keyed by case id
/// (`scene-pose-condition`, with the physics model's suffix where a `physics` column names one
/// other than the default). A failed method's empty recall reads as 0, as the report counts it.
pub fn read_results(path: &Path, method: &str) -> Result<Vec<(String, Achieved)>, BenchError> {
    let text = std::fs::read_to_string(path).map_err(io(path))?;
    let bad = |line: usize, what: String| BenchError::Results {
        path: path.to_path_buf(),
        line,
        what,
    };
    let mut records = csv_records(&text).into_iter();
    let header = records.next().map(|(_, h)| h).unwrap_or_default();
    let col = |name: &str| {
        header
            .iter()
            .position(|h| h == name)
            .ok_or_else(|| bad(1, format!("no `{name}` column")))
    };
    let (scene, condition, m, f, recall) = (
        col("scene")?,
        col("condition")?,
        col("method")?,
        col("f_score")?,
        col("recall")?,
    );
    // Results written before the physics model was recorded have no such column, and an empty
    // field is the default model too.
    let physics = header.iter().position(|h| h == "physics");
    let mut out = Vec::new();
    for (line, fields) in records {
        let get = |k: usize, name: &str| {
            fields
                .get(k)
                .map(String::as_str)
                .ok_or_else(|| bad(line, format!("no `{name}` field")))
        };
        if get(m, "method")? != method {
            continue;
        }
        let number = |k: usize, name: &str| -> Result<f64, BenchError> {
            let v = get(k, name)?;
            if v.is_empty() {
                return Ok(0.0);
            }
            v.parse::<f64>()
                .map_err(|_| bad(line, format!("`{name}` = {v:?} is not a number")))
        };
        let model = match physics {
            Some(k) => get(k, "physics")?,
            None => "",
        };
        let suffix = physics_suffix(if model.is_empty() {
            PHYSICAL_OPTICS
        } else {
            model
        });
        out.push((
            format!(
                "{}-{}{suffix}",
                get(scene, "scene")?,
                get(condition, "condition")?
            ),
            Achieved {
                f_score: number(f, "f_score")?,
                recall: number(recall, "recall")?,
            },
        ));
    }
    Ok(out)
}

fn cell(v: Option<f64>) -> String {
    v.map_or(String::new(), |x| format!("{x:.6}"))
}

/// `coverage.csv`: one row per case of the first suite; per suite its seen share and the
/// ideal's F-score, recall and position error; then the achieved mmNorm figures, if given.
pub fn coverage_csv(suites: &[SuiteCoverage], achieved: &[(String, Achieved)]) -> String {
    let mut out = String::from("case");
    for s in suites {
        let l = &s.label;
        let _ = write!(
            out,
            ",{l}_truth_points,{l}_seen_fraction,{l}_ideal_f_score,{l}_ideal_recall,\
{l}_ideal_f_score_raw,{l}_ideal_position_error_m"
        );
    }
    if !achieved.is_empty() {
        out.push_str(",mmnorm_f_score,mmnorm_recall");
    }
    out.push('\n');
    let Some(first) = suites.first() else {
        return out;
    };
    for c in &first.cases {
        out.push_str(&c.id);
        for s in suites {
            match s.cases.iter().find(|x| x.id == c.id) {
                Some(x) => {
                    let _ = write!(
                        out,
                        ",{},{:.6},{:.6},{:.6},{:.6},{}",
                        x.truth_points,
                        x.seen_fraction,
                        x.ideal.f_score,
                        x.ideal.recall,
                        x.ideal.f_score_raw,
                        cell(x.ideal.position_error_m)
                    );
                }
                None => out.push_str(",,,,,,"),
            }
        }
        if !achieved.is_empty() {
            let a = achieved.iter().find(|(id, _)| *id == c.id).map(|(_, a)| a);
            let _ = write!(
                out,
                ",{},{}",
                cell(a.map(|a| a.f_score)),
                cell(a.map(|a| a.recall))
            );
        }
        out.push('\n');
    }
    out
}

const COLOURS: [Rgb; 4] = [GREEN, ORANGE, RED, PINK];

/// The CDF of the ideal F-score per suite (and of the achieved one), with the targets marked.
pub fn coverage_chart(suites: &[SuiteCoverage], achieved: &[(String, Achieved)]) -> CdfChart {
    let mut series: Vec<Series> = suites
        .iter()
        .zip(COLOURS.iter().cycle())
        .map(|(s, &colour)| Series {
            // The chart's font has no `×`.
            label: format!("ideal, {} ({})", s.label, s.aperture.replace('×', "x")),
            colour,
            values: s.ideal_f_scores(),
        })
        .collect();
    if !achieved.is_empty() {
        series.push(Series {
            label: "mmNorm, achieved".into(),
            colour: BLUE,
            values: achieved.iter().map(|(_, a)| a.f_score).collect(),
        });
    }
    CdfChart {
        title: "Specular coverage: F-score of the seen truth".into(),
        x_label: "F-score (tau = 1.5 cm)".into(),
        log_x: false,
        x_range: (0.0, 1.0),
        series,
        levels: vec![0.25, 0.5],
        verticals: vec![],
        markers: vec![
            Marker {
                x: 0.96,
                y: 0.5,
                colour: BLACK,
            },
            Marker {
                x: 0.84,
                y: 0.25,
                colour: BLACK,
            },
        ],
    }
}

impl SuiteCoverage {
    /// The ideal's F-score of every case, in the suite's order.
    pub fn ideal_f_scores(&self) -> Vec<f64> {
        self.cases.iter().map(|c| c.ideal.f_score).collect()
    }
}

fn fmt(v: Option<f64>) -> String {
    v.map_or("-".into(), |x| format!("{x:.2}"))
}

/// `coverage.md`: the medians and 25th percentiles of each suite's ideal F-score, and the
/// cases whose ideal is under the 25th-percentile target (0.84) under any suite.
pub fn coverage_md(
    suites: &[SuiteCoverage],
    achieved: &[(String, Achieved)],
    chart: Option<&str>,
) -> String {
    let mut md = String::new();
    let _ = writeln!(md, "## Specular coverage (`mmnormd bench coverage`)\n");
    let _ = writeln!(
        md,
        "The F-score of an ideal specular reconstruction: every top-view truth point whose \
         normal, extended, meets the aperture unblocked, and no other point, scored as a \
         method's points are (τ = 1.5 cm, with the §5 position correction). Real echoes also \
         come from within a Fresnel zone, from edges and from diffuse scattering, which it \
         leaves out, so a method can recall somewhat more. The sheet, the antenna pattern and \
         the TX–RX spacing are left out too, so each NLOS row equals its LOS row.\n"
    );
    let _ = writeln!(
        md,
        "| suite | aperture | cases | ideal F median | ideal F p25 | cases with ideal F < 0.84 |"
    );
    let _ = writeln!(md, "|---|---|---|---|---|---|");
    for s in suites {
        let f = s.ideal_f_scores();
        let _ = writeln!(
            md,
            "| `{}` | {} | {} | {} | {} | {} |",
            s.path.display(),
            s.aperture,
            f.len(),
            fmt(quantile(&f, 0.5)),
            fmt(quantile(&f, 0.25)),
            f.iter().filter(|&&x| x < 0.84).count()
        );
    }
    if !achieved.is_empty() {
        let f: Vec<f64> = achieved.iter().map(|(_, a)| a.f_score).collect();
        let _ = writeln!(
            md,
            "\nmmNorm as run (the results given, {} cases): F median {}, 25th percentile {}.",
            f.len(),
            fmt(quantile(&f, 0.5)),
            fmt(quantile(&f, 0.25))
        );
    }
    if let Some(png) = chart {
        let _ = writeln!(md, "\n![ideal F-score CDF]({png})");
    }
    let Some(first) = suites.first() else {
        return md;
    };
    below_ideal(&mut md, first, achieved);
    let low: Vec<&CaseCoverage> = first
        .cases
        .iter()
        .filter(|c| {
            suites.iter().any(|s| {
                s.cases
                    .iter()
                    .find(|x| x.id == c.id)
                    .is_some_and(|x| x.ideal.f_score < 0.84)
            }) || achieved
                .iter()
                .any(|(id, a)| *id == c.id && a.f_score < 0.84)
        })
        .collect();
    if low.is_empty() {
        return md;
    }
    let _ = write!(
        md,
        "\nThe cases under 0.84 anywhere (ideal F, seen share):\n\n| case |"
    );
    for s in suites {
        let _ = write!(md, " {} |", s.label);
    }
    if !achieved.is_empty() {
        md.push_str(" mmNorm F (recall) |");
    }
    md.push_str("\n|---|");
    for _ in suites {
        md.push_str("---|");
    }
    if !achieved.is_empty() {
        md.push_str("---|");
    }
    md.push('\n');
    for c in low {
        let _ = write!(md, "| {} |", c.id);
        for s in suites {
            match s.cases.iter().find(|x| x.id == c.id) {
                Some(x) => {
                    let _ = write!(md, " {:.2} ({:.2}) |", x.ideal.f_score, x.seen_fraction);
                }
                None => md.push_str(" - |"),
            }
        }
        if !achieved.is_empty() {
            match achieved.iter().find(|(id, _)| *id == c.id) {
                Some((_, a)) => {
                    let _ = write!(md, " {:.2} ({:.2}) |", a.f_score, a.recall);
                }
                None => md.push_str(" - |"),
            }
        }
        md.push('\n');
    }
    md
}

/// How far under its ideal mmNorm may fall before a case is listed as a lead to trace.
const SHORT_OF_IDEAL: f64 = 0.05;

/// The cases where mmNorm's F-score is more than [`SHORT_OF_IDEAL`] under the first suite's
/// ideal: what coverage does not explain.
fn below_ideal(md: &mut String, first: &SuiteCoverage, achieved: &[(String, Achieved)]) {
    let mut short: Vec<(&CaseCoverage, &Achieved)> = first
        .cases
        .iter()
        .filter_map(|c| {
            achieved
                .iter()
                .find(|(id, _)| *id == c.id)
                .map(|(_, a)| (c, a))
        })
        .filter(|(c, a)| a.f_score < c.ideal.f_score - SHORT_OF_IDEAL)
        .collect();
    if short.is_empty() {
        return;
    }
    short.sort_by(|x, y| {
        (x.1.f_score - x.0.ideal.f_score).total_cmp(&(y.1.f_score - y.0.ideal.f_score))
    });
    let _ = writeln!(
        md,
        "\n{} cases where mmNorm is more than {SHORT_OF_IDEAL} under the ideal of `{}`, \
         largest gap first (coverage does not explain these):\n\n\
         | case | ideal F (recall) | mmNorm F (recall) |\n|---|---|---|",
        short.len(),
        first.label
    );
    for (c, a) in short {
        let _ = writeln!(
            md,
            "| {} | {:.2} ({:.2}) | {:.2} ({:.2}) |",
            c.id, c.ideal.f_score, c.ideal.recall, a.f_score, a.recall
        );
    }
}

/// Writes `coverage.csv`, `coverage.md` and `coverage_cdf.png` into `dir`.
pub fn write_coverage(
    suites: &[SuiteCoverage],
    achieved: &[(String, Achieved)],
    dir: &Path,
) -> Result<(), BenchError> {
    std::fs::create_dir_all(dir).map_err(io(dir))?;
    write_atomically(
        &dir.join("coverage.csv"),
        coverage_csv(suites, achieved).as_bytes(),
    )?;
    let png = "coverage_cdf.png";
    coverage_chart(suites, achieved)
        .draw()
        .write_png(&dir.join(png))?;
    write_atomically(
        &dir.join("coverage.md"),
        coverage_md(suites, achieved, Some(png)).as_bytes(),
    )?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::TriMesh;
    use crate::sim::truth::top_surface_with_normals;

    fn rect(half_x: f64, half_y: f64, z: f64) -> ApertureRect {
        ApertureRect {
            x_m: [-half_x, half_x],
            y_m: [-half_y, half_y],
            z_m: z,
        }
    }

    /// A square plate of side `side_m` at height `z_m`, tilted `tilt_deg` about y.
    fn plate(side_m: f64, z_m: f64, tilt_deg: f64) -> TriMesh {
        let h = side_m / 2.0;
        let (s, c) = tilt_deg.to_radians().sin_cos();
        let v = |x: f64, y: f64| [x * c, y, z_m - x * s];
        TriMesh {
            vertices_m: vec![v(-h, -h), v(h, -h), v(h, h), v(-h, h)],
            triangles: vec![[0, 1, 2], [0, 2, 3]],
        }
    }

    fn seen_share(mesh: &TriMesh, r: &ApertureRect) -> f64 {
        let (truth, normals) = top_surface_with_normals(mesh, TOP_GRID_M);
        let mask = seen(&truth, &normals, &Bvh::build(mesh), r);
        mask.iter().filter(|s| **s).count() as f64 / truth.len() as f64
    }

    #[test]
    fn a_flat_plate_wider_than_the_aperture_is_seen_under_the_aperture_only() {
        // 20 cm plate, aperture ±6 × ±4 cm: seen share 12·8 / 20² = 0.24.
        let share = seen_share(&plate(0.2, 0.1, 0.0), &rect(0.06, 0.04, 0.4));
        assert!((share - 0.24).abs() < 0.005, "{share}");
    }

    #[test]
    fn a_tilted_plate_is_seen_where_its_mirror_lines_land() {
        // Tilted by α about y, the plate point at horizontal x has height z0 − x·tan α and its
        // normal (sin α, 0, cos α) reaches height Z at x + (Z − z0 + x·tan α)·tan α. With
        // Z − z0 = 0.3, tan α = t and the aperture's x in [−0.05, 0.05]:
        // x (1 + t²) ∈ [−0.05 − 0.3 t, 0.05 − 0.3 t]. All of y (±0.1) is inside ±0.15.
        let alpha = 10f64.to_radians();
        let t = alpha.tan();
        let lo = (-0.05 - 0.3 * t) / (1.0 + t * t);
        let hi = (0.05 - 0.3 * t) / (1.0 + t * t);
        // The plate's horizontal extent is ±0.1·cos α.
        let half = 0.1 * alpha.cos();
        let expected = (hi.min(half) - lo.max(-half)) / (2.0 * half);
        let share = seen_share(&plate(0.2, 0.1, 10.0), &rect(0.05, 0.15, 0.4));
        assert!(
            (share - expected).abs() < 0.01,
            "{share} against {expected}"
        );
        // And where: the seen band's centre moves by about −0.3·t/(1 + t²) = −5.1 cm.
        let mesh = plate(0.2, 0.1, 10.0);
        let (truth, normals) = top_surface_with_normals(&mesh, TOP_GRID_M);
        let mask = seen(&truth, &normals, &Bvh::build(&mesh), &rect(0.05, 0.15, 0.4));
        let xs: Vec<f64> = truth
            .iter()
            .zip(&mask)
            .filter(|(_, s)| **s)
            .map(|(p, _)| p[0])
            .collect();
        let centre = xs.iter().sum::<f64>() / xs.len() as f64;
        let expected_centre = 0.5 * (hi.min(half) + lo.max(-half));
        assert!(
            (centre - expected_centre).abs() < 1e-3,
            "{centre} against {expected_centre}"
        );
    }

    #[test]
    fn a_plate_above_hides_the_mirror_lines_it_crosses() {
        // A 4 cm plate at 10 cm over a 20 cm one at 5 cm, under a wide aperture. Flat, every
        // point the top view sees has a clear vertical mirror line.
        let upper = plate(0.04, 0.10, 0.0);
        let wide = rect(0.5, 0.5, 0.4);
        let mut flat = plate(0.2, 0.05, 0.0);
        flat.append(&upper);
        assert_eq!(seen_share(&flat, &wide), 1.0);
        // Tilt the lower plate by α: its point at horizontal X (height 0.05 − X·t, t = tan α)
        // has a mirror line that reaches the upper plate's height at
        // X·(1 + t²) + 0.05·t, with y unchanged; it is blocked where that lies within ±2 cm
        // and |y| ≤ 2 cm.
        let mut mesh = plate(0.2, 0.05, 20.0);
        mesh.append(&upper);
        let t = 20f64.to_radians().tan();
        let (truth, normals) = top_surface_with_normals(&mesh, TOP_GRID_M);
        let mask = seen(&truth, &normals, &Bvh::build(&mesh), &wide);
        let (mut blocked, mut wrong) = (0, 0);
        for (p, s) in truth.iter().zip(&mask) {
            if p[2] > 0.095 {
                assert!(*s, "the upper plate is in the open: {p:?}");
                continue;
            }
            let cross = p[0] * (1.0 + t * t) + 0.05 * t;
            let margin = (cross.abs() - 0.02).abs().min((p[1].abs() - 0.02).abs());
            let hidden = cross.abs() <= 0.02 && p[1].abs() <= 0.02;
            blocked += usize::from(hidden);
            if margin > 1e-3 && hidden == *s {
                wrong += 1;
            }
        }
        // The band is about 1.4 × 4 cm: some 550 points of the 1 mm grid.
        assert!(blocked > 400, "{blocked}");
        assert_eq!(wrong, 0);
    }

    #[test]
    fn the_ideal_of_a_sphere_recalls_its_cap_and_scores_precision_one() {
        // A 5 cm sphere 30 cm under a ±8 × ±6 cm aperture: the cap whose normals meet it.
        let c = [0.0, 0.0, 0.05];
        let mesh = crate::geometry::sphere_mesh(0.05, 0.002)
            .transformed(&crate::geometry::pose_from(c, [0.0; 3]));
        let r = rect(0.08, 0.06, 0.35);
        let (truth, normals) = top_surface_with_normals(&mesh, TOP_GRID_M);
        let mask = seen(&truth, &normals, &Bvh::build(&mesh), &r);
        // On a sphere the normal is radial: the point (x, y, z) is seen when
        // |x − cx|·H ≤ 0.08·(z − cz) and |y − cy|·H ≤ 0.06·(z − cz), H = 0.30.
        let h = 0.30;
        let mut wrong = 0;
        for (p, s) in truth.iter().zip(&mask) {
            let dz = p[2] - c[2];
            let inside =
                (p[0] - c[0]).abs() * h <= 0.08 * dz && (p[1] - c[1]).abs() * h <= 0.06 * dz;
            // The facets' normals differ from the radial one by about 1° (slope 0.02).
            let slope = |d: f64| d.abs() / dz.max(1e-9);
            let margin = (slope(p[0] - c[0]) - 0.08 / h)
                .abs()
                .min((slope(p[1] - c[1]) - 0.06 / h).abs());
            if inside != *s && margin > 0.05 {
                wrong += 1;
            }
        }
        assert_eq!(wrong, 0);
        let points: Vec<[f64; 3]> = truth
            .iter()
            .zip(&mask)
            .filter(|(_, s)| **s)
            .map(|(p, _)| *p)
            .collect();
        let m = evaluate(&points, None, &truth, None, 0.015);
        assert_eq!(m.precision, 1.0);
        assert!(m.recall < 0.9 && m.recall > points.len() as f64 / truth.len() as f64);
    }

    #[test]
    fn results_are_read_by_column_name_and_bad_numbers_are_named() {
        let dir = std::env::temp_dir().join(format!("mmnormd-coverage-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("results.csv");
        std::fs::write(
            &path,
            "scene,condition,method,f_score,precision,recall\n\
             box-flat,los,mmnorm,0.9,1,0.8\nbox-flat,los,backprojection,0.5,1,0.4\n",
        )
        .unwrap();
        let r = read_results(&path, "mmnorm").unwrap();
        assert_eq!(r.len(), 1);
        // A failed method's error is quoted and may hold commas and line breaks.
        let mut text = std::fs::read_to_string(&path).unwrap();
        text.push_str("cup-flat,nlos,mmnorm,0.000000,,,\"no points, \"\"x\"\"\nat all\"\n");
        text.push_str("cup-side,los,mmnorm,0.5,1,0.4\n");
        std::fs::write(&path, &text).unwrap();
        let failed = read_results(&path, "mmnorm").unwrap();
        assert_eq!(failed.len(), 3, "{failed:?}");
        assert_eq!(failed[1].0, "cup-flat-nlos");
        assert_eq!(failed[1].1.f_score, 0.0);
        assert_eq!(failed[2].0, "cup-side-los");
        // Lines are counted through the quoted break: the last record starts on line 6.
        std::fs::write(
            &path,
            text.replace("cup-side,los,mmnorm,0.5", "cup-side,los,mmnorm,x"),
        )
        .unwrap();
        let e = read_results(&path, "mmnorm").unwrap_err().to_string();
        assert!(e.contains("line 6"), "{e}");
        assert_eq!(
            r,
            vec![(
                "box-flat-los".to_string(),
                Achieved {
                    f_score: 0.9,
                    recall: 0.8
                }
            )]
        );
        std::fs::write(
            &path,
            "scene,condition,method,f_score,recall\nbox-flat,los,mmnorm,high,0.8\n",
        )
        .unwrap();
        let e = read_results(&path, "mmnorm").unwrap_err().to_string();
        assert!(
            e.contains("line 2") && e.contains("f_score") && e.contains("high"),
            "{e}"
        );
        // A suite run under both physics models: each row keys the case id its model gives.
        std::fs::write(
            &path,
            "scene,condition,method,f_score,recall,physics\n\
             box-flat,los,mmnorm,0.9,0.8,physical-optics\n\
             box-flat,los,mmnorm,0.7,0.6,point-scatterer\n\
             cup-flat,los,mmnorm,0.5,0.4,\n",
        )
        .unwrap();
        let ids: Vec<String> = read_results(&path, "mmnorm")
            .unwrap()
            .into_iter()
            .map(|(id, _)| id)
            .collect();
        assert_eq!(ids, ["box-flat-los", "box-flat-los-point", "cup-flat-los"]);
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
