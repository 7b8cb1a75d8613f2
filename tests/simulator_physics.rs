//! The forward simulator against closed forms: a point target, a plate (image theory and the
//! specular cone), a sphere (geometric optics), shadowing, the cardboard sheet, the noise floor
//! and seeding.

use std::f64::consts::TAU;
use std::path::Path;

use mmnormd::SPEED_OF_LIGHT_M_PER_S as C;
use mmnormd::capture::read_capture_dir;
use mmnormd::sim::{Scene, simulate};
use num_complex::Complex32;
use rustfft::FftPlanner;

const PLAN: &str = r#"
[radar]
start_frequency_hz = 77.5e9
frequency_step_hz = 5.859375e6
samples_per_chirp = 512
range_offset_m = 0.15
"#;

fn scene(body: &str) -> Scene {
    let text = format!("{PLAN}\n{body}");
    Scene::parse(
        &text,
        Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("tests/inline.toml")
            .as_path(),
    )
    .unwrap_or_else(|e| panic!("{e}"))
}

fn single_antenna(x: f64, y: f64, z: f64) -> String {
    format!("[aperture]\nwidth_m = 0.0\nheight_m = 0.0\nz_m = {z}\ncenter_m = [{x}, {y}]\n")
}

fn wrap(phase: f64) -> f64 {
    (phase + std::f64::consts::PI).rem_euclid(TAU) - std::f64::consts::PI
}

/// Mean ratio and worst phase error of `h` against `amp·exp(+j2π f_t (path + 0.15)/c)`.
fn compare_to_tone(scene: &Scene, h: &[Complex32], path_m: f64) -> (f64, f64) {
    let mut ratio = 0.0;
    let mut worst_phase = 0.0f64;
    for (t, s) in h.iter().enumerate() {
        let expected = TAU * scene.plan.frequency_hz(t) * (path_m + 0.15) / C;
        let got = f64::from(s.im).atan2(f64::from(s.re));
        worst_phase = worst_phase.max(wrap(got - expected).abs());
        ratio += f64::from(s.norm());
    }
    (ratio / h.len() as f64, worst_phase)
}

#[test]
fn point_target_range_bin_and_phase_match_the_closed_form() {
    let s = scene(&format!(
        "{}\n[[object]]\nshape = \"point\"\nposition_m = [0.013, -0.021, 0.0]\nrcs_m2 = 0.01\n",
        single_antenna(0.0, 0.0, 0.4)
    ));
    let out = simulate(&s, true);
    let h = out.capture.chirp(0);
    let d = 2.0 * (0.013f64.powi(2) + 0.021f64.powi(2) + 0.4f64.powi(2)).sqrt();
    let (mean_amp, worst_phase) = compare_to_tone(&s, h, d);
    let expected_amp = (0.01 / (4.0 * std::f64::consts::PI)).sqrt() / (d / 2.0).powi(2);
    println!(
        "point target: amplitude {mean_amp:.6} (closed form {expected_amp:.6}), worst phase error {worst_phase:.2e} rad"
    );
    assert!(worst_phase < 1e-3, "phase error {worst_phase} rad");
    assert!((mean_amp / expected_amp - 1.0).abs() < 1e-4);

    // Range FFT (16× zero padding): the peak lies within ½ bin of the true round trip.
    let t = h.len();
    let pad = 16 * t;
    let mut buf = vec![Complex32::new(0.0, 0.0); pad];
    buf[..t].copy_from_slice(h);
    FftPlanner::new().plan_fft_forward(pad).process(&mut buf);
    let peak = (0..pad / 2)
        .max_by(|&a, &b| buf[a].norm().total_cmp(&buf[b].norm()))
        .unwrap();
    let bin_m = C / (s.plan.frequency_step_hz * t as f64); // round trip per unpadded bin
    let measured = peak as f64 / 16.0 * bin_m;
    let error_bins = (measured - (d + 0.15)) / bin_m;
    println!(
        "range peak at {measured:.4} m round trip, true {:.4} m: {error_bins:+.3} bins",
        d + 0.15
    );
    assert!(error_bins.abs() <= 0.5);
}

fn plate_scene(antennas: &str, extra: &str) -> Scene {
    scene(&format!(
        "{antennas}\n[[object]]\nshape = \"plate\"\nsize_m = [0.4, 0.4]\ndiffuse = 0.0\nedge = 0.0\n{extra}"
    ))
}

#[test]
fn plate_return_matches_image_theory() {
    // An infinite mirror at R returns 1/(2R) with the phase of the 2R path.
    let r = 0.4;
    let s = plate_scene(&single_antenna(0.0, 0.0, r), "");
    let out = simulate(&s, true);
    let (amp, worst_phase) = compare_to_tone(&s, out.capture.chirp(0), 2.0 * r);
    let expected = 1.0 / (2.0 * r);
    println!(
        "plate: amplitude {amp:.5} vs 1/(2R) = {expected:.5} ({:+.2} %), worst phase error {worst_phase:.3} rad",
        (amp / expected - 1.0) * 100.0
    );
    assert!((amp / expected - 1.0).abs() < 0.02);
    assert!(worst_phase < 0.03);
}

#[test]
fn sphere_return_matches_geometric_optics() {
    // Convex mirror of radius a at distance R: amplitude a / (2R(R + a)), phase of the 2R path.
    let (a, r) = (0.05, 0.35);
    let s = scene(&format!(
        "{}\n[[object]]\nshape = \"sphere\"\nradius_m = {a}\nposition_m = [0.0, 0.0, 0.0]\ndiffuse = 0.0\n",
        single_antenna(0.0, 0.0, a + r)
    ));
    let out = simulate(&s, true);
    let (amp, worst_phase) = compare_to_tone(&s, out.capture.chirp(0), 2.0 * r);
    let expected = a / (2.0 * r * (r + a));
    println!(
        "sphere: amplitude {amp:.5} vs a/(2R(R+a)) = {expected:.5} ({:+.2} %), worst phase error {worst_phase:.3} rad",
        (amp / expected - 1.0) * 100.0
    );
    assert!((amp / expected - 1.0).abs() < 0.03);
    assert!(worst_phase < 0.05);
}

/// Received power (dB) of a row of antennas along x at y = 0, z = 0.4, with a 12 cm plate
/// tilted about y.
fn row_power_db(tilt_deg: f64) -> (Vec<f64>, Vec<f64>) {
    let s = scene(&format!(
        "[aperture]\nwidth_m = 0.36\nheight_m = 0.0\nspacing_m = 0.004\nz_m = 0.4\n\
         [[object]]\nshape = \"plate\"\nsize_m = [0.12, 0.12]\nrotation_deg = [0.0, {tilt_deg}, 0.0]\n"
    ));
    let out = simulate(&s, true);
    let t = s.plan.samples_per_chirp;
    let xs = out.capture.tx_m.iter().map(|p| p[0]).collect();
    let p = (0..out.capture.antennas())
        .map(|i| {
            let e: f32 = out.capture.chirp(i).iter().map(|c| c.norm_sqr()).sum();
            10.0 * (f64::from(e) / t as f64).log10()
        })
        .collect();
    (xs, p)
}

/// Power-weighted centroid of the antennas within 6 dB of the peak.
fn bright_centroid(xs: &[f64], p: &[f64]) -> f64 {
    let peak = p.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    let (mut sx, mut sw) = (0.0, 0.0);
    for (x, v) in xs.iter().zip(p) {
        if *v > peak - 6.0 {
            let w = 10f64.powf(v / 10.0);
            sx += x * w;
            sw += w;
        }
    }
    sx / sw
}

#[test]
fn flat_plate_is_bright_only_inside_its_specular_cone() {
    let (xs, p) = row_power_db(0.0);
    let inside = xs
        .iter()
        .zip(&p)
        .filter(|(x, _)| x.abs() < 0.04)
        .map(|(_, v)| *v)
        .fold(f64::INFINITY, f64::min);
    let outside = xs
        .iter()
        .zip(&p)
        .filter(|(x, _)| x.abs() > 0.12)
        .map(|(_, v)| *v)
        .fold(f64::NEG_INFINITY, f64::max);
    println!(
        "flat plate: weakest inside the cone {inside:.1} dB, strongest outside {outside:.1} dB"
    );
    assert!(inside > outside + 15.0);
    let c = bright_centroid(&xs, &p);
    println!("flat plate: bright-patch centroid x = {:.2} cm", c * 100.0);
    assert!(c.abs() < 0.005);
}

#[test]
fn tilted_plate_moves_the_bright_patch_by_h_tan_theta() {
    let (xs, p) = row_power_db(10.0);
    let c = bright_centroid(&xs, &p);
    let expected = 0.4 * 10f64.to_radians().tan();
    println!(
        "tilted plate: bright-patch centroid x = {:.2} cm, geometry predicts {:.2} cm",
        c * 100.0,
        expected * 100.0
    );
    assert!((c - expected).abs() < 0.005);
}

/// The `[physics]` table that selects the point-scatterer model.
const POINT_MODEL: &str = "[physics]\nmodel = \"point-scatterer\"\n";

#[test]
fn an_object_hidden_under_another_adds_nothing() {
    let aperture = "[aperture]\nwidth_m = 0.1\nheight_m = 0.1\nspacing_m = 0.01\nz_m = 0.4\n";
    let plate =
        "[[object]]\nshape = \"plate\"\nsize_m = [0.4, 0.4]\nposition_m = [0.0, 0.0, 0.1]\n";
    let sphere = "[[object]]\nshape = \"sphere\"\nradius_m = 0.02\nposition_m = [0.0, 0.0, 0.02]\n";
    for physics in ["", POINT_MODEL] {
        let alone = simulate(&scene(&format!("{aperture}{physics}{plate}")), true);
        let both = simulate(&scene(&format!("{aperture}{physics}{plate}{sphere}")), true);
        let sphere_only = simulate(&scene(&format!("{aperture}{physics}{sphere}")), true);
        assert!(both.stats.specular_samples > alone.stats.specular_samples);
        assert!(sphere_only.stats.contributions > 0);
        println!(
            "hidden sphere ({}): {} contributions with the plate alone, {} with the sphere under it",
            if physics.is_empty() {
                "physical optics"
            } else {
                "point scatterers"
            },
            alone.stats.contributions,
            both.stats.contributions
        );
        assert_eq!(alone.stats.contributions, both.stats.contributions);
        assert_eq!(alone.capture.samples, both.capture.samples);
    }
}

#[test]
fn point_scatterer_plate_matches_its_closed_form() {
    // Under the 1/d point model a mirror much larger than the cone returns, at each frequency,
    // (2/λ0)·∫ e^{jk·2r}/(2r) dA over the disc the cone cuts out (r from R to R/cos θc):
    // (2π/λ0)·(e^{jk·2R_c} − e^{jk·2R})/(j·2k), each path with the 0.15 m offset. The first
    // term is the cone's hard edge, as strong as the mirror point: the model's own signature.
    let r = 0.4;
    let s = plate_scene(&single_antenna(0.0, 0.0, r), POINT_MODEL);
    let out = simulate(&s, true);
    let lambda0 = C / s.plan.frequency_hz(0);
    let r_cone = r / 5f64.to_radians().cos();
    let h = out.capture.chirp(0);
    let mut error = 0.0;
    let mut norm = 0.0;
    for (t, got) in h.iter().enumerate() {
        let k = TAU * s.plan.frequency_hz(t) / C;
        let tone = |path: f64| num_complex::Complex64::from_polar(1.0, k * (path + 0.15));
        let expected = (tone(2.0 * r_cone) - tone(2.0 * r))
            * (TAU / lambda0 / (2.0 * k))
            * num_complex::Complex64::new(0.0, -1.0);
        let got = num_complex::Complex64::new(f64::from(got.re), f64::from(got.im));
        error += (got - expected).norm_sqr();
        norm += expected.norm_sqr();
    }
    let relative = (error / norm).sqrt();
    println!(
        "point-scatterer plate: {} samples, rms error {:.2} % of the closed form",
        out.stats.specular_samples,
        relative * 100.0
    );
    assert!(relative < 0.05, "relative rms error {relative}");
}

#[test]
fn point_scatterer_surfaces_reflect_only_inside_the_cone() {
    // A 1 cm plate 40 cm below one antenna: every sample sees the antenna within 0.8° of the
    // plate's own tilt, so a 4° tilt is inside the 5° cone and a 6° tilt wholly outside.
    let plate = |tilt: f64| {
        let s = scene(&format!(
            "{}{POINT_MODEL}[[object]]\nshape = \"plate\"\nsize_m = [0.01, 0.01]\n\
             rotation_deg = [0.0, {tilt}, 0.0]\nedge = 0.0\n",
            single_antenna(0.0, 0.0, 0.4)
        ));
        let out = simulate(&s, true);
        out.capture.chirp(0).iter().map(|v| v.norm()).sum::<f32>()
            / out.capture.plan.samples_per_chirp as f32
    };
    let (inside, outside) = (plate(4.0), plate(6.0));
    println!("1 cm plate tilted 4°: mean amplitude {inside:.3e}; tilted 6°: {outside:.3e}");
    assert!(inside > 0.0);
    assert_eq!(outside, 0.0);
}

#[test]
fn point_scatterer_edges_radiate_everywhere_and_fall_as_one_over_d() {
    // The same 1 cm plate tilted 30°, far outside the cone: only its rim returns, and along
    // one direction its amplitude falls as 1/d of the round trip (2 between 30 and 60 cm).
    let rim = |height: f64| {
        let s = scene(&format!(
            "{}{POINT_MODEL}[[object]]\nshape = \"plate\"\nsize_m = [0.01, 0.01]\n\
             rotation_deg = [0.0, 30.0, 0.0]\n",
            single_antenna(0.0, 0.0, height)
        ));
        let out = simulate(&s, true);
        assert!(
            out.stats.edge_samples >= 40,
            "{} edge samples",
            out.stats.edge_samples
        );
        out.capture
            .chirp(0)
            .iter()
            .map(|v| f64::from(v.norm()))
            .sum::<f64>()
            / out.capture.plan.samples_per_chirp as f64
    };
    let (near, far) = (rim(0.3), rim(0.6));
    println!(
        "rim of a plate tilted 30°: amplitude at 30 cm / at 60 cm = {:.4} (1/d: 2)",
        near / far
    );
    assert!(near > 0.0);
    assert!((near / far / 2.0 - 1.0).abs() < 0.03);
}

#[test]
fn cardboard_attenuates_both_ways_and_reflects_weakly() {
    let antenna = single_antenna(0.0, 0.0, 0.4);
    let target = "[[object]]\nshape = \"point\"\nposition_m = [0.0, 0.0, 0.0]\nrcs_m2 = 0.01\n";
    let sheet =
        "[occluder]\nz_m = 0.2\nthickness_m = 0.004\nrefractive_index = 1.6\nloss_db = 1.5\n";
    let open = simulate(&scene(&format!("{antenna}{target}")), true);
    let covered = simulate(&scene(&format!("{antenna}{sheet}{target}")), true);
    // Separate the target (0.8 m round trip) from the sheet (0.396 m) in range.
    let range_peak = |h: &[Complex32], round_trip_m: f64| {
        let t = h.len();
        let pad = 8 * t;
        let mut buf = vec![Complex32::new(0.0, 0.0); pad];
        for (k, (b, s)) in buf.iter_mut().zip(h).enumerate() {
            // Hann window: the sheet's range sidelobes must not leak into the target's bin.
            let w = 0.5 - 0.5 * (TAU * k as f64 / t as f64).cos();
            *b = s * w as f32;
        }
        FftPlanner::new().plan_fft_forward(pad).process(&mut buf);
        let bin = ((round_trip_m + 0.15) * 5.859375e6 * t as f64 / C * 8.0).round() as usize;
        (bin - 8..bin + 8)
            .map(|k| buf[k].norm())
            .fold(0.0f32, f32::max)
    };
    let ratio = range_peak(covered.capture.chirp(0), 0.8) / range_peak(open.capture.chirp(0), 0.8);
    let expected = 10f32.powf(-2.0 * 1.5 / 20.0);
    let sheet_echo = range_peak(covered.capture.chirp(0), 0.396);
    let sheet_in_open = range_peak(open.capture.chirp(0), 0.396);
    println!(
        "cardboard: target amplitude ratio {ratio:.4} (two crossings of 1.5 dB: {expected:.4}); sheet echo {sheet_echo:.3} vs {sheet_in_open:.3} without"
    );
    assert!((ratio / expected - 1.0).abs() < 0.01);
    assert!(sheet_echo > 10.0 * sheet_in_open);
}

#[test]
fn the_noise_floor_is_the_receivers_and_does_not_rise_with_the_sheet() {
    let aperture = "[aperture]\nwidth_m = 0.02\nheight_m = 0.02\nspacing_m = 0.005\nz_m = 0.4\n";
    let target = "[[object]]\nshape = \"point\"\nposition_m = [0.0, 0.0, 0.0]\nrcs_m2 = 0.01\n";
    let sheet =
        "[occluder]\nz_m = 0.2\nthickness_m = 0.004\nrefractive_index = 1.6\nloss_db = 1.5\n";
    let noise = "[noise]\nsnr_db = 20.0\nseed = 3\n";
    let open = simulate(&scene(&format!("{aperture}{noise}{target}")), true);
    let covered = simulate(&scene(&format!("{aperture}{noise}{sheet}{target}")), true);
    let clean = simulate(&scene(&format!("{aperture}{sheet}{target}")), true);
    let power =
        |s: &[Complex32]| s.iter().map(|z| f64::from(z.norm_sqr())).sum::<f64>() / s.len() as f64;
    // The sheet's echo outweighs the target's many times: a floor set against the whole
    // capture's power would rise with it.
    let whole_over_target = power(&clean.capture.samples) / power(&open.capture.samples);
    // The noise actually added, against the floor the open scene reports.
    let added: Vec<Complex32> = covered
        .capture
        .samples
        .iter()
        .zip(clean.capture.samples.iter())
        .map(|(n, c)| n - c)
        .collect();
    let measured_sigma = power(&added).sqrt();
    println!(
        "noise σ: open {:.3e}, under the sheet {:.3e} (measured {measured_sigma:.3e}); whole capture / target power {whole_over_target:.1}",
        open.stats.noise_sigma, covered.stats.noise_sigma
    );
    assert!(whole_over_target > 10.0);
    assert!((covered.stats.noise_sigma / open.stats.noise_sigma - 1.0).abs() < 0.01);
    assert!((measured_sigma / open.stats.noise_sigma - 1.0).abs() < 0.05);
}

#[test]
fn the_same_seed_gives_identical_files_and_another_seed_differs() {
    let body = |seed: u64| {
        format!(
            "[aperture]\nwidth_m = 0.02\nheight_m = 0.02\nspacing_m = 0.005\nz_m = 0.4\n\
             [noise]\nsnr_db = 20.0\nseed = {seed}\n\
             [[object]]\nshape = \"box\"\nsize_m = [0.05, 0.04, 0.03]\nrotation_deg = [0.0, 0.0, 20.0]\n"
        )
    };
    let dir = tempfile::tempdir().unwrap();
    let write = |seed: u64, name: &str| {
        let out = simulate(&scene(&body(seed)), true);
        let path = dir.path().join(name);
        mmnormd::capture::write_capture_dir(&path, &out.capture).unwrap();
        std::fs::read(path.join("samples.npy")).unwrap()
    };
    let a = write(7, "a");
    let b = write(7, "b");
    let c = write(8, "c");
    assert_eq!(a, b);
    assert_ne!(a, c);
    assert!(read_capture_dir(&dir.path().join("a")).is_ok());
}

#[test]
fn four_rx_point_target_matches_each_bistatic_path() {
    let s = scene(&format!(
        "{}layout = \"iwr1443boost\"\nantenna_pattern = \"isotropic\"\n\
         [[object]]\nshape = \"point\"\nposition_m = [0.02, 0.01, 0.0]\nrcs_m2 = 0.01\n",
        single_antenna(0.0, 0.0, 0.4)
    ));
    let out = simulate(&s, true);
    assert_eq!(out.capture.antennas(), 4);
    let p = [0.02, 0.01, 0.0];
    let dist = |a: &[f64; 3]| {
        ((a[0] - p[0]).powi(2) + (a[1] - p[1]).powi(2) + (a[2] - p[2]).powi(2)).sqrt()
    };
    for k in 0..4 {
        let (tx, rx) = (out.capture.tx_m[k], out.capture.rx_m[k]);
        let (amp, worst_phase) = compare_to_tone(&s, out.capture.chirp(k), dist(&tx) + dist(&rx));
        let expected = (0.01 / (4.0 * std::f64::consts::PI)).sqrt() / (dist(&tx) * dist(&rx));
        println!(
            "RX {k} at x offset {:+.4} m: amplitude error {:.1e}, worst phase error {worst_phase:.1e} rad",
            rx[0] - tx[0],
            amp / expected - 1.0
        );
        assert!(worst_phase < 1e-3 && (amp / expected - 1.0).abs() < 1e-4);
    }
}
