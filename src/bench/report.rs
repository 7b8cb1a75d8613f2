//! From case results to `results.csv`, the CDF plots and `report.md`, side by side with the
//! paper's figures (§6.2–§6.3). Per-object metrics (F-score, position error) are distributions
//! over cases; per-point metrics (relative and point error, normal cosine) pool every point of
//! every case, as the paper's Fig. 12c, 13, 14 and 15 do. A method that failed on a case counts
//! as F = 0 there and adds no points.

use std::fmt::Write as _;
use std::path::Path;

use super::BenchError;
use super::run::{CaseResult, METHODS, read_scores};
use super::suite::Condition;
use crate::capture::dir::write_atomically;
use crate::eval::quantile;
use crate::plot::{BLUE, CdfChart, GREEN, Marker, ORANGE, PINK, RED, Rgb, Series};

/// The stage columns of `results.csv`, in pipeline order.
const STAGES: [&str; 10] = [
    "volume",
    "image",
    "mask",
    "normals",
    "components",
    "rsdf",
    "isosurface",
    "points",
    "threshold",
    "interferometry",
];

/// The paper's figures (§6.2–§6.3).
pub mod paper {
    /// (median, 25th percentile) F-score: mmNorm, Backprojection, Interferometric.
    pub const F_SCORE: [(f64, f64); 3] = [(0.96, 0.84), (0.72, 0.60), (0.78, 0.49)];
    /// (median, 90th percentile) position error, metres.
    pub const POSITION_M: [(f64, f64); 3] = [(0.006, 0.024), (0.008, 0.043), (0.013, 0.058)];
    /// Fraction of points with relative error under 5 %.
    pub const REL_UNDER_5: [f64; 3] = [0.85, 0.44, 0.44];
    /// (median, 25th percentile) normal cosine similarity.
    pub const NORMAL_COS: [(f64, f64); 3] = [(0.99, 0.94), (0.54, 0.22), (0.66, 0.36)];
    /// (median, 90th percentile) point error, metres: mmNorm, centre, weighted (§6.3.2).
    pub const ABLATION_M: [(f64, f64); 3] = [(0.004, 0.012), (0.016, 0.033), (0.011, 0.029)];
    /// (median, 90th percentile) mmNorm point error, metres: LOS, NLOS (§6.3.3).
    pub const LOS_NLOS_M: [(f64, f64); 2] = [(0.0039, 0.011), (0.0043, 0.012)];
}

fn label(method: &str) -> &'static str {
    match method {
        "mmnorm" => "mmNorm",
        "backprojection" => "Backprojection",
        "interferometric" => "Interferometric",
        "center" => "RSDF centre",
        _ => "weighted centre",
    }
}

fn colour(method: &str) -> Rgb {
    match method {
        "mmnorm" => BLUE,
        "backprojection" => GREEN,
        "interferometric" => ORANGE,
        "center" => RED,
        _ => PINK,
    }
}

/// `text` with the target of every inline Markdown link or image that is a relative path
/// (written from the output directory) passed through `link`, so that the notes' links hold
/// in a copy of the report written elsewhere. URLs, absolute paths and anchors are kept.
pub fn relink(text: &str, link: &dyn Fn(&str) -> String) -> String {
    let mut out = String::with_capacity(text.len());
    let mut rest = text;
    while let Some(at) = rest.find("](") {
        let (head, tail) = rest.split_at(at + 2);
        out.push_str(head);
        let Some(end) = tail.find(')') else {
            rest = tail;
            break;
        };
        let target = &tail[..end];
        let keep = target.is_empty()
            || target.contains("://")
            || target.starts_with(['/', '#'])
            || target.starts_with("mailto:");
        if keep {
            out.push_str(target);
        } else {
            out.push_str(&link(target));
        }
        rest = &tail[end..];
    }
    out.push_str(rest);
    out
}

fn csv_field(s: &str) -> String {
    if s.contains([',', '"', '\n']) {
        format!("\"{}\"", s.replace('"', "\"\""))
    } else {
        s.to_string()
    }
}

fn num(v: Option<f64>) -> String {
    v.map_or(String::new(), |x| format!("{x:.6}"))
}

/// `results.csv`: one row per (case, method).
pub fn results_csv(results: &[CaseResult]) -> String {
    let mut out = String::from(
        "scene,condition,method,f_score,precision,recall,position_error_m,point_error_median_m,\
point_error_p90_m,rel_error_under_5pct,normal_cos_median,normal_cos_p25,total_s,\
pose,f_score_raw,points,truth_points,antennas,normals_from,simulate_s,physics,class",
    );
    for s in STAGES {
        let _ = write!(out, ",{s}_s");
    }
    out.push_str(",error\n");
    for r in results {
        for m in &r.methods {
            let x = m.metrics.as_ref();
            let stage = |name: &str| {
                m.stage_s
                    .iter()
                    .find(|(n, _)| n == name)
                    .map(|(_, t)| format!("{t:.3}"))
                    .unwrap_or_default()
            };
            let mut row = vec![
                format!("{}-{}", r.scene, r.pose.name()),
                r.condition.name().to_string(),
                m.method.clone(),
                format!("{:.6}", x.map_or(0.0, |x| x.f_score)),
                num(x.map(|x| x.precision)),
                num(x.map(|x| x.recall)),
                num(x.and_then(|x| x.position_error_m)),
                num(x.and_then(|x| x.point_error_median_m)),
                num(x.and_then(|x| x.point_error_p90_m)),
                num(x.and_then(|x| x.rel_error_under_5pct)),
                num(x.and_then(|x| x.normal_cos_median)),
                num(x.and_then(|x| x.normal_cos_p25)),
                format!("{:.3}", m.total_s),
                r.pose.name().to_string(),
                num(x.map(|x| x.f_score_raw)),
                x.map_or(String::new(), |x| x.points.to_string()),
                r.truth_points.to_string(),
                r.antennas.to_string(),
                m.normals.clone(),
                num(Some(r.simulate_s).filter(|s| s.is_finite())),
                r.physics.clone(),
                r.class.clone(),
            ];
            row.extend(STAGES.iter().map(|s| stage(s)));
            row.push(m.error.clone().unwrap_or_default());
            let row: Vec<String> = row.iter().map(|f| csv_field(f)).collect();
            out.push_str(&row.join(","));
            out.push('\n');
        }
    }
    out
}

/// Every statistic of the report, for one set of cases.
#[derive(Debug, Clone, Default)]
pub struct Stats {
    /// Per method (METHODS order): F-scores per case (0 where it failed).
    pub f_scores: Vec<Vec<f64>>,
    /// Per method: position error per case where it produced points.
    pub position_m: Vec<Vec<f64>>,
    /// Per method: every point's (point error, relative error, normal cosine).
    pub points: Vec<Vec<[f64; 3]>>,
    /// mmNorm's pooled point errors in LOS and in NLOS.
    pub los_nlos_m: [Vec<f64>; 2],
    pub failures: Vec<(String, String, String)>,
}

/// Gathers the statistics, reading each case's per-point scores from `runs_dir`.
pub fn gather(results: &[CaseResult], runs_dir: &Path) -> Result<Stats, BenchError> {
    let mut s = Stats {
        f_scores: vec![Vec::new(); METHODS.len()],
        position_m: vec![Vec::new(); METHODS.len()],
        points: vec![Vec::new(); METHODS.len()],
        ..Stats::default()
    };
    for r in results {
        for (k, name) in METHODS.iter().enumerate() {
            let Some(m) = r.methods.iter().find(|m| m.method == *name) else {
                continue;
            };
            s.f_scores[k].push(m.metrics.as_ref().map_or(0.0, |x| x.f_score));
            if let Some(p) = m.metrics.as_ref().and_then(|x| x.position_error_m) {
                s.position_m[k].push(p);
            }
            if let Some(e) = &m.error {
                s.failures.push((r.id.clone(), name.to_string(), e.clone()));
            }
            let rows = read_scores(runs_dir, &r.id, name)?;
            if *name == "mmnorm" {
                let slot = usize::from(r.condition == Condition::Nlos);
                s.los_nlos_m[slot].extend(rows.iter().map(|x| x[0]));
            }
            s.points[k].extend(rows);
        }
    }
    Ok(s)
}

/// The same scene and pose with and without the cardboard: mmNorm's NLOS over LOS median point
/// error, one ratio per case pair where both have points.
pub fn nlos_over_los(results: &[CaseResult]) -> Vec<f64> {
    let median_of = |r: &CaseResult| {
        r.methods
            .iter()
            .find(|m| m.method == "mmnorm")
            .and_then(|m| m.metrics.as_ref())
            .and_then(|x| x.point_error_median_m)
    };
    results
        .iter()
        .filter(|r| r.condition == Condition::Los)
        .filter_map(|los| {
            let nlos = results.iter().find(|r| {
                r.condition == Condition::Nlos
                    && r.scene == los.scene
                    && r.pose == los.pose
                    && r.physics == los.physics
            })?;
            let (l, n) = (median_of(los)?, median_of(nlos)?);
            (l > 0.0).then(|| n / l)
        })
        .collect()
}

/// One line on [`nlos_over_los`]: the median ratio and how many pairs lie within 10 %.
fn paired_line(ratios: &[f64]) -> Option<String> {
    let median = quantile(ratios, 0.5)?;
    let within = ratios.iter().filter(|r| (**r - 1.0).abs() <= 0.1).count();
    let better = ratios.iter().filter(|r| **r < 0.9).count();
    let worse = ratios.iter().filter(|r| **r > 1.1).count();
    Some(format!(
        "NLOS/LOS median {median:.2}; {within} of {} pairs within 10 %, NLOS better by more in \
         {better} and worse by more in {worse}",
        ratios.len()
    ))
}

fn column(rows: &[[f64; 3]], k: usize) -> Vec<f64> {
    rows.iter().map(|r| r[k]).filter(|x| !x.is_nan()).collect()
}

fn fraction_below(values: &[f64], limit: f64) -> Option<f64> {
    (!values.is_empty())
        .then(|| values.iter().filter(|&&v| v < limit).count() as f64 / values.len() as f64)
}

fn pct(v: Option<f64>) -> String {
    v.map_or("—".into(), |x| format!("{:.0} %", 100.0 * x))
}

fn cm(v: Option<f64>) -> String {
    v.map_or("—".into(), |x| format!("{:.2} cm", 100.0 * x))
}

fn two(v: Option<f64>) -> String {
    v.map_or("—".into(), |x| format!("{x:.2}"))
}

/// Writes the six CDF plots into `dir`; returns their file names with captions.
pub fn write_plots(stats: &Stats, dir: &Path) -> Result<Vec<(String, String)>, BenchError> {
    let three = [0usize, 1, 2];
    let series = |ks: &[usize], values: &dyn Fn(usize) -> Vec<f64>| -> Vec<Series> {
        ks.iter()
            .map(|&k| Series {
                label: label(METHODS[k]).into(),
                colour: colour(METHODS[k]),
                values: values(k),
            })
            .collect()
    };
    let markers = |ks: &[usize], points: &dyn Fn(usize) -> Vec<(f64, f64)>| -> Vec<Marker> {
        ks.iter()
            .flat_map(|&k| {
                points(k).into_iter().map(move |(x, y)| Marker {
                    x,
                    y,
                    colour: colour(METHODS[k]),
                })
            })
            .collect()
    };
    let cm_of = |v: &[f64]| v.iter().map(|x| x * 100.0).collect::<Vec<_>>();
    let mut charts = vec![
        (
            "fig12a_f_score.png",
            "Fig. 12a: CDF of the 3-D F-score per case; dashed at the 50th and 25th percentiles",
            CdfChart {
                title: "Shape error: 3-D F-score".into(),
                x_label: "F-score (tau = 1.5 cm)".into(),
                log_x: false,
                x_range: (0.0, 1.0),
                series: series(&three, &|k| stats.f_scores[k].clone()),
                levels: vec![0.25, 0.5],
                verticals: vec![],
                markers: markers(&three, &|k| {
                    vec![(paper::F_SCORE[k].0, 0.5), (paper::F_SCORE[k].1, 0.25)]
                }),
            },
        ),
        (
            "fig12b_position_error.png",
            "Fig. 12b: CDF of the position error per case; dashed at the 50th and 90th percentiles",
            CdfChart {
                title: "Position error".into(),
                x_label: "position error (cm)".into(),
                log_x: false,
                x_range: (0.0, 8.0),
                series: series(&three, &|k| cm_of(&stats.position_m[k])),
                levels: vec![0.5, 0.9],
                verticals: vec![],
                markers: markers(&three, &|k| {
                    let (a, b) = paper::POSITION_M[k];
                    vec![(a * 100.0, 0.5), (b * 100.0, 0.9)]
                }),
            },
        ),
        (
            "fig12c_relative_error.png",
            "Fig. 12c: CDF of every point's error relative to its object's size; dashed at 5 %",
            CdfChart {
                title: "Relative point error".into(),
                x_label: "point error / object diameter (log)".into(),
                log_x: true,
                x_range: (1e-4, 1.0),
                series: series(&three, &|k| column(&stats.points[k], 1)),
                levels: vec![],
                verticals: vec![0.05],
                markers: markers(&three, &|k| vec![(0.05, paper::REL_UNDER_5[k])]),
            },
        ),
        (
            "fig13_normal_cosine.png",
            "Fig. 13: CDF of every point's normal cosine similarity (baselines: PCA normals); dashed at the 50th and 25th percentiles",
            CdfChart {
                title: "Normal accuracy: cosine similarity".into(),
                x_label: "|cos| to the truth normal".into(),
                log_x: false,
                x_range: (0.0, 1.0),
                series: series(&three, &|k| column(&stats.points[k], 2)),
                levels: vec![0.25, 0.5],
                verticals: vec![],
                markers: markers(&three, &|k| {
                    vec![
                        (paper::NORMAL_COS[k].0, 0.5),
                        (paper::NORMAL_COS[k].1, 0.25),
                    ]
                }),
            },
        ),
    ];
    let ablation = [0usize, 3, 4];
    charts.push((
        "fig14_ablation_point_error.png",
        "Fig. 14: CDF of every point's error for mmNorm and the two partial implementations; dashed at the 50th and 90th percentiles",
        CdfChart {
            title: "Isosurface optimisation: point error".into(),
            x_label: "point error (cm, log)".into(),
            log_x: true,
            x_range: (0.01, 20.0),
            series: series(&ablation, &|k| cm_of(&column(&stats.points[k], 0))),
            levels: vec![0.5, 0.9],
            verticals: vec![],
            markers: ablation
                .iter()
                .zip(paper::ABLATION_M)
                .flat_map(|(&k, (a, b))| {
                    [(a, 0.5), (b, 0.9)].map(|(x, y)| Marker {
                        x: x * 100.0,
                        y,
                        colour: colour(METHODS[k]),
                    })
                })
                .collect(),
        },
    ));
    let conditions = [("LOS", BLUE), ("NLOS", RED)];
    charts.push((
        "fig15_los_nlos_point_error.png",
        "Fig. 15: CDF of every mmNorm point's error in LOS and NLOS; dashed at the 50th and 90th percentiles",
        CdfChart {
            title: "Non-line-of-sight: mmNorm point error".into(),
            x_label: "point error (cm, log)".into(),
            log_x: true,
            x_range: (0.01, 20.0),
            series: conditions
                .iter()
                .enumerate()
                .map(|(i, (name, c))| Series {
                    label: (*name).into(),
                    colour: *c,
                    values: cm_of(&stats.los_nlos_m[i]),
                })
                .collect(),
            levels: vec![0.5, 0.9],
            verticals: vec![],
            markers: conditions
                .iter()
                .zip(paper::LOS_NLOS_M)
                .flat_map(|((_, c), (a, b))| {
                    [(a, 0.5), (b, 0.9)].map(|(x, y)| Marker {
                        x: x * 100.0,
                        y,
                        colour: *c,
                    })
                })
                .collect(),
        },
    ));
    let mut written = Vec::new();
    for (name, caption, chart) in charts {
        chart.draw().write_png(&dir.join(name))?;
        written.push((name.to_string(), caption.to_string()));
    }
    Ok(written)
}

/// What the report says about how the run was made.
pub struct RunInfo {
    pub suite: String,
    pub description: String,
    pub command: String,
    pub aperture: String,
    pub wall_s: f64,
    /// Whether the run only reported finished cases.
    pub report_only: bool,
    pub cases: usize,
    pub failed_cases: Vec<(String, String)>,
    /// Cases neither run now nor finished by an earlier run.
    pub not_run: Vec<String>,
    /// Hand-written analysis (markdown) appended to the report, with the file it came from.
    pub notes: Option<(String, String)>,
    /// Further markdown sections (such as `bench perf --markdown`'s), included before the plots.
    pub includes: Vec<String>,
    /// The side-by-side section per physics model and object class (`by_physics`), if any.
    pub by_physics: Option<String>,
}

/// `report.md`. `link` turns a file name of the output directory into the link to use (so the
/// same report can live beside its plots or elsewhere, as `BENCHMARKS.md`).
pub fn report_md(
    info: &RunInfo,
    results: &[CaseResult],
    stats: &Stats,
    plots: &[(String, String)],
    link: &dyn Fn(&str) -> String,
) -> String {
    let q = |v: &[f64], p: f64| quantile(v, p);
    let mut md = String::new();
    let _ = writeln!(md, "# Accuracy benchmark\n");
    let _ = writeln!(
        md,
        "Generated by `{}` (mmnormd {}). Suite `{}`: {}.\n",
        info.command,
        env!("CARGO_PKG_VERSION"),
        info.suite,
        info.description
    );
    let _ = writeln!(
        md,
        "{} cases ({} with results), aperture {}; {}. Per-case metrics (F-score, position error) are \
distributions over cases; point metrics pool every point of every case, as the paper does. A \
method that failed on a case counts as F = 0. Baseline normals are estimated by PCA over 30 \
neighbours within 1 cm, as the paper does for its baselines (§6.3.1). Results: [results.csv]({}).\n",
        info.cases,
        results.len(),
        info.aperture,
        {
            let mut builds: Vec<&str> = results.iter().map(|r| r.build.as_str()).collect();
            builds.sort_unstable();
            builds.dedup();
            let named = builds
                .iter()
                .map(|b| if b.is_empty() { "unrecorded" } else { b })
                .collect::<Vec<_>>()
                .join(", ");
            let which = if builds.len() == 1 {
                "one build"
            } else {
                "several builds"
            };
            if info.report_only {
                format!(
                    "this report was written with --report-only from cases finished by earlier \
runs ({which} of mmnormd: {named})"
                )
            } else if builds.len() > 1 {
                format!(
                    "wall time of this run {:.0} s (cases already finished on disk were not run \
again: the results come from {which} of mmnormd: {named})",
                    info.wall_s
                )
            } else {
                format!(
                    "wall time of this run {:.0} s (cases already finished on disk were not run \
again)",
                    info.wall_s
                )
            }
        },
        link("results.csv")
    );
    if results.len() < info.cases {
        let _ = writeln!(
            md,
            "**Partial run: {} of {} cases have results.** Every figure below covers those \
cases only; the others are listed at the end. Running the same command again resumes.\n",
            results.len(),
            info.cases
        );
    }
    let _ = writeln!(md, "## Targets\n");
    let f_mm = &stats.f_scores[0];
    let cos_mm = column(&stats.points[0], 2);
    let los = q(&stats.los_nlos_m[0], 0.5);
    let nlos = q(&stats.los_nlos_m[1], 0.5);
    let ahead = |p: f64| {
        let ours = q(f_mm, p);
        let best_base = q(&stats.f_scores[1], p)
            .into_iter()
            .chain(q(&stats.f_scores[2], p))
            .fold(f64::NEG_INFINITY, f64::max);
        ours.map(|o| (o > best_base, o, best_base))
    };
    let yes = |b: bool| if b { "met" } else { "**missed**" };
    let _ = writeln!(md, "| target | ours | |\n|---|---|---|");
    let t = |md: &mut String, name: &str, ours: String, ok: Option<bool>| {
        let _ = writeln!(md, "| {name} | {ours} | {} |", ok.map_or("—", yes));
    };
    t(
        &mut md,
        "mmNorm median F-score ≥ 0.96",
        two(q(f_mm, 0.5)),
        q(f_mm, 0.5).map(|v| v >= 0.96),
    );
    t(
        &mut md,
        "mmNorm 25th percentile F-score ≥ 0.84",
        two(q(f_mm, 0.25)),
        q(f_mm, 0.25).map(|v| v >= 0.84),
    );
    for (p, name) in [(0.5, "median"), (0.25, "25th percentile")] {
        let a = ahead(p);
        t(
            &mut md,
            &format!("mmNorm ahead of both baselines at the {name} F-score"),
            a.map_or("—".into(), |(_, o, b)| {
                format!("{o:.2} vs best baseline {b:.2}")
            }),
            a.map(|(ok, _, _)| ok),
        );
    }
    t(
        &mut md,
        "normal cosine median ≥ 0.99",
        two(q(&cos_mm, 0.5)),
        q(&cos_mm, 0.5).map(|v| v >= 0.99),
    );
    let within = los.zip(nlos).map(|(l, n)| (n - l).abs() <= 0.1 * l);
    let paired = paired_line(&nlos_over_los(results));
    t(
        &mut md,
        "NLOS within 10 % of LOS in median point error",
        format!(
            "LOS {}, NLOS {} (all points pooled){}",
            cm(los),
            cm(nlos),
            paired
                .as_ref()
                .map_or(String::new(), |p| format!("; per scene, {p}"))
        ),
        within,
    );

    if let Some((file, text)) = &info.notes {
        let _ = writeln!(
            md,
            "\n## Analysis\n\n_From `{file}`, written by hand for this run._\n"
        );
        let _ = writeln!(md, "{}", relink(text.trim_end(), link));
    }
    let _ = writeln!(md, "\n## Shape, position and point error (Fig. 12)\n");
    let _ = writeln!(
        md,
        "| method | F-score median (paper) | F-score p25 (paper) | position error median (paper) | position error p90 (paper) | points under 5 % relative error (paper) |\n|---|---|---|---|---|---|"
    );
    for (k, method) in METHODS.iter().enumerate().take(3) {
        let f = &stats.f_scores[k];
        let p = &stats.position_m[k];
        let rel = column(&stats.points[k], 1);
        let _ = writeln!(
            md,
            "| {} | {} ({:.2}) | {} ({:.2}) | {} ({}) | {} ({}) | {} ({}) |",
            label(method),
            two(q(f, 0.5)),
            paper::F_SCORE[k].0,
            two(q(f, 0.25)),
            paper::F_SCORE[k].1,
            cm(q(p, 0.5)),
            cm(Some(paper::POSITION_M[k].0)),
            cm(q(p, 0.9)),
            cm(Some(paper::POSITION_M[k].1)),
            pct(fraction_below(&rel, 0.05)),
            pct(Some(paper::REL_UNDER_5[k])),
        );
    }
    let _ = writeln!(md, "\n## Normals (Fig. 13)\n");
    let _ = writeln!(
        md,
        "| method | normals from | cosine median (paper) | cosine p25 (paper) |\n|---|---|---|---|"
    );
    for (k, method) in METHODS.iter().enumerate().take(3) {
        let c = column(&stats.points[k], 2);
        let _ = writeln!(
            md,
            "| {} | {} | {} ({:.2}) | {} ({:.2}) |",
            label(method),
            if k == 0 {
                "the normal vote"
            } else {
                "PCA of the points"
            },
            two(q(&c, 0.5)),
            paper::NORMAL_COS[k].0,
            two(q(&c, 0.25)),
            paper::NORMAL_COS[k].1,
        );
    }
    let _ = writeln!(
        md,
        "\n## Isosurface optimisation against its ablations (§6.3.2, Fig. 14)\n"
    );
    let _ = writeln!(
        md,
        "| method | point error median (paper) | point error p90 (paper) | F-score median |\n|---|---|---|---|"
    );
    for (i, k) in [0usize, 3, 4].into_iter().enumerate() {
        let e = column(&stats.points[k], 0);
        let _ = writeln!(
            md,
            "| {} | {} ({}) | {} ({}) | {} |",
            label(METHODS[k]),
            cm(q(&e, 0.5)),
            cm(Some(paper::ABLATION_M[i].0)),
            cm(q(&e, 0.9)),
            cm(Some(paper::ABLATION_M[i].1)),
            two(q(&stats.f_scores[k], 0.5)),
        );
    }
    let _ = writeln!(
        md,
        "\n## Line of sight against cardboard (§6.3.3, Fig. 15)\n"
    );
    let _ = writeln!(
        md,
        "| condition | mmNorm point error median (paper) | p90 (paper) | mmNorm F median | Backprojection F median | Interferometric F median |\n|---|---|---|---|---|---|"
    );
    for (slot, cond) in [Condition::Los, Condition::Nlos].into_iter().enumerate() {
        let e = &stats.los_nlos_m[slot];
        let f_of = |k: usize| {
            let v: Vec<f64> = results
                .iter()
                .filter(|r| r.condition == cond)
                .filter_map(|r| r.methods.iter().find(|m| m.method == METHODS[k]))
                .map(|m| m.metrics.as_ref().map_or(0.0, |x| x.f_score))
                .collect();
            two(q(&v, 0.5))
        };
        let _ = writeln!(
            md,
            "| {} | {} ({}) | {} ({}) | {} | {} | {} |",
            cond.name().to_uppercase(),
            cm(q(e, 0.5)),
            cm(Some(paper::LOS_NLOS_M[slot].0)),
            cm(q(e, 0.9)),
            cm(Some(paper::LOS_NLOS_M[slot].1)),
            f_of(0),
            f_of(1),
            f_of(2),
        );
    }
    if let Some(p) = paired {
        let _ = writeln!(
            md,
            "\nThe rows above pool every point of every case, as Fig. 15 does, so the larger \
objects weigh the most. Scene by scene (mmNorm's median point error, the same scene and pose \
with and without the cardboard): {p}."
        );
    }
    if let Some(section) = &info.by_physics {
        let _ = writeln!(md, "\n{}", section.trim_end());
    }
    for text in &info.includes {
        let _ = writeln!(md, "\n{}", relink(text.trim_end(), link));
    }
    let _ = writeln!(md, "\n## Plots\n");
    for (name, caption) in plots {
        let _ = writeln!(md, "{caption}.\n\n![{caption}]({})\n", link(name));
    }
    let _ = writeln!(md, "## Every case\n");
    let _ = writeln!(
        md,
        "F-score per method; mmNorm's precision and recall show whether a low score comes from \
wrong points (precision) or from surface the reconstruction does not reach (recall).\n"
    );
    let _ = writeln!(
        md,
        "| case | mmNorm F | precision | recall | Backprojection F | Interferometric F | centre F | weighted F | picture |\n|---|---|---|---|---|---|---|---|---|"
    );
    for r in results {
        let f = |name: &str| {
            r.methods
                .iter()
                .find(|m| m.method == name)
                .map_or("—".to_string(), |m| {
                    m.metrics
                        .as_ref()
                        .map_or("failed".into(), |x| format!("{:.2}", x.f_score))
                })
        };
        let mm = r
            .methods
            .iter()
            .find(|m| m.method == "mmnorm")
            .and_then(|m| m.metrics.as_ref());
        let png = format!("scenes/{}.png", r.id);
        let _ = writeln!(
            md,
            "| {} | {} | {} | {} | {} | {} | {} | {} | [png]({}) |",
            r.id,
            f("mmnorm"),
            two(mm.map(|x| x.precision)),
            two(mm.map(|x| x.recall)),
            f("backprojection"),
            f("interferometric"),
            f("center"),
            f("weighted"),
            link(&png)
        );
    }
    if !info.not_run.is_empty() {
        let _ = writeln!(
            md,
            "\n## Not run yet\n\n{} of {} cases: {}.",
            info.not_run.len(),
            info.cases,
            info.not_run.join(", ")
        );
    }
    if !stats.failures.is_empty() || !info.failed_cases.is_empty() {
        let _ = writeln!(md, "\n## Failures\n");
        for (id, e) in &info.failed_cases {
            let _ = writeln!(md, "- case {id}: {e}");
        }
        for (id, m, e) in &stats.failures {
            let _ = writeln!(md, "- {id}, {m}: {e}");
        }
    }
    md
}

/// Writes `results.csv` into `dir`.
pub fn write_csv(results: &[CaseResult], dir: &Path) -> Result<(), BenchError> {
    write_atomically(&dir.join("results.csv"), results_csv(results).as_bytes())?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::{nlos_over_los, paired_line, relink};
    use crate::bench::run::CaseResult;

    /// A case whose mmNorm median point error is `median_mm` (None: no points).
    fn case(scene: &str, pose: &str, condition: &str, median_mm: Option<f64>) -> CaseResult {
        let metrics = serde_json::json!({
            "f_score": 0.9, "precision": 0.9, "recall": 0.9, "f_score_raw": 0.9,
            "position_error_m": null, "point_error_median_m": median_mm.map(|m| m * 1e-3),
            "point_error_p90_m": null, "rel_error_under_5pct": null, "normal_cos_median": null,
            "normal_cos_p25": null, "points": 10, "truth_points": 10
        });
        serde_json::from_value(serde_json::json!({
            "key": "k", "id": format!("{scene}-{pose}-{condition}"), "scene": scene,
            "pose": pose, "condition": condition, "capture_key": "c", "antennas": 1,
            "simulate_s": 0.0, "truth_points": 10,
            "methods": [{"method": "mmnorm", "metrics": metrics, "error": null,
                         "normals": "mmnorm", "stage_s": [], "total_s": 0.0}]
        }))
        .unwrap()
    }

    #[test]
    fn los_and_nlos_pair_by_scene_and_pose() {
        let results = [
            case("a", "flat", "nlos", Some(1.04)),
            case("a", "flat", "los", Some(1.0)),
            case("a", "side", "los", Some(2.0)),
            case("a", "side", "nlos", Some(1.0)),
            case("b", "flat", "los", Some(4.0)),
            case("b", "flat", "nlos", None),
            case("c", "flat", "los", Some(1.0)),
        ];
        let ratios = nlos_over_los(&results);
        assert_eq!(ratios.len(), 2, "{ratios:?}");
        assert!((ratios[0] - 1.04).abs() < 1e-12 && (ratios[1] - 0.5).abs() < 1e-12);
        assert_eq!(
            paired_line(&ratios).unwrap(),
            "NLOS/LOS median 0.77; 1 of 2 pairs within 10 %, NLOS better by more in 1 and worse \
             by more in 0"
        );
        assert_eq!(paired_line(&[]), None);
    }

    #[test]
    fn relative_links_are_relinked_and_the_others_kept() {
        let text = "See [the paper rows](paper/report.md) and ![cdf](coverage/cdf.png), \
                    [a site](https://example.org/x), [top](#plots), [root](/etc/x) and a (plain) ] (bracket).";
        let out = relink(text, &|f| format!("docs/bench/{f}"));
        assert_eq!(
            out,
            "See [the paper rows](docs/bench/paper/report.md) and ![cdf](docs/bench/coverage/cdf.png), \
             [a site](https://example.org/x), [top](#plots), [root](/etc/x) and a (plain) ] (bracket)."
        );
        assert_eq!(relink(text, &|f| f.to_string()), text);
        assert_eq!(
            relink("[open](never closed", &|f| format!("x/{f}")),
            "[open](never closed"
        );
    }
}
