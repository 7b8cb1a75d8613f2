//! Time synchronisation in the simulated lab (docs/protocols.md D3 step 3): a point target
//! scanned with one forward and one backward row. A timing error δt moves each row's antennas
//! by v·δt along its own direction, so the target focuses at x ± v·δt: the two rows disagree by
//! 2·v·δt. The live alignment must make them agree within 0.1 mm; the same rows re-aligned with
//! a deliberate 2 ms error must not (the check can fail). The calibration (`mmnormd calibrate`)
//! must undo a wrong offset and a wrong mount from the same rows.

mod common;

use std::path::Path;
use std::sync::atomic::AtomicBool;
use std::time::Instant;

use mmnormd::align::RowAlignment;
use mmnormd::capture::Capture;
use mmnormd::dca1000::Frame;
use mmnormd::dca1000::packet::PacketArrival;
use mmnormd::lab::LabConfig;
use mmnormd::lab::calibrate::{calibrate, focus_axis};
use mmnormd::lab::devices::LabDevices;
use mmnormd::lab::scan::{
    RowRecording, RowSummary, ScanLog, ScanSetup, align_recording, build_capture, run_scan,
};
use mmnormd::lab::simlab::SimLab;
use mmnormd::ur::rtde::Sample;

/// Keeps every row attempt.
#[derive(Default)]
struct Keep {
    rows: Vec<(RowRecording, RowAlignment)>,
}

impl ScanLog for Keep {
    fn frame(&mut self, _: usize, _: u32, _: &Frame) -> Result<(), String> {
        Ok(())
    }
    fn packet(&mut self, _: usize, _: u32, _: &PacketArrival) -> Result<(), String> {
        Ok(())
    }
    fn rtde(&mut self, _: usize, _: u32, _: &Sample) -> Result<(), String> {
        Ok(())
    }
    fn row(&mut self, rec: &RowRecording, aligned: &RowAlignment) -> Result<(), String> {
        self.rows.push((rec.clone(), aligned.clone()));
        Ok(())
    }
    fn progress(&mut self, _: &RowSummary) {}
}

const TARGET_M: [f64; 3] = [0.45, -0.20, 0.05];

/// The x (metres) at which the row's echoes focus on the line through the target along x,
/// within ±3 mm: the matched filter of `mmnormd calibrate` (tested on a closed-form point
/// target in `lab::calibrate`).
fn focus_x_m(capture: &Capture) -> f64 {
    focus_axis(capture, TARGET_M, 0, 0.003, 61)
}

#[test]
fn forward_and_backward_rows_over_a_point_target_agree_and_a_calibration_undoes_a_wrong_config() {
    let dir = tempfile::tempdir().unwrap();
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let scene = dir.path().join("point.toml");
    std::fs::write(
        &scene,
        format!(
            "description = \"point target\"\n[radar]\nprofile = \"{}/firmware_cfg/iwr1443_demo.cfg\"\nrange_offset_m = 0.15\n\
             [aperture]\nwidth_m = 0.08\nheight_m = 0.0\nz_m = 0.32\ncenter_m = [0.45, -0.2]\nlayout = \"iwr1443boost\"\n\
             [noise]\nsnr_db = 30.0\nseed = 3\n[[object]]\nshape = \"point\"\nrcs_m2 = 0.01\nposition_m = [{}, {}, {}]\n",
            root.display(),
            TARGET_M[0],
            TARGET_M[1],
            TARGET_M[2]
        ),
    )
    .unwrap();
    let (path, _) = common::write_config(dir.path(), |t| {
        let sim = t["sim"].as_table_mut().unwrap();
        sim.insert("scene".into(), scene.display().to_string().into());
        // Two rows 3.9 mm apart on either side of the target: one forward, one backward.
        let spec = t["scan"].as_table_mut().unwrap();
        spec.insert("width_m".into(), 0.08.into());
        spec.insert("height_m".into(), 0.003868.into());
    });
    let lab = LabConfig::load(&path).unwrap();
    let setup = ScanSetup::new(&lab, lab.scan.clone()).unwrap();
    assert_eq!(setup.plan.rows.len(), 2);
    let _sim = SimLab::start(&lab, &setup, None).unwrap();
    let mut devices = LabDevices::connect(&lab, &setup.profile).unwrap();
    let mut keep = Keep::default();
    run_scan(
        &lab,
        &setup,
        &mut devices.devices(),
        Instant::now(),
        &mut keep,
        &AtomicBool::new(false),
    )
    .unwrap();
    let rows: Vec<&(RowRecording, RowAlignment)> = keep.rows.iter().collect();
    let directions: Vec<i8> = rows.iter().map(|r| r.0.direction).collect();
    assert!(
        directions.contains(&1) && directions.contains(&-1),
        "{directions:?}"
    );
    let names = vec!["timestamp".to_string(), "actual_TCP_pose".to_string()];
    let focus = |lab: &LabConfig, r: &(RowRecording, RowAlignment)| {
        // Re-align with `lab` (the live alignment when unchanged).
        let aligned = align_recording(lab, &setup, &names, &r.0).unwrap();
        focus_x_m(&build_capture(lab, &setup, &[(r.0.clone(), aligned)]))
    };
    let last = |d: i8| rows.iter().rev().find(|r| r.0.direction == d).unwrap();
    let (fwd, bwd) = (last(1), last(-1));
    let live = (focus(&lab, fwd), focus(&lab, bwd));
    let mut skewed = lab.clone();
    skewed.align.sync_offset_s = 0.002;
    let off = (focus(&skewed, fwd), focus(&skewed, bwd));
    let v = setup.spec.speed_m_per_s;
    println!(
        "point target at x = {:.3} mm: forward row focuses at {:+.4} mm, backward at {:+.4} mm: they differ by {:.4} mm; re-aligned 2 ms late: {:.4} mm (2·v·δt = {:.3} mm)",
        TARGET_M[0] * 1e3,
        (live.0 - TARGET_M[0]) * 1e3,
        (live.1 - TARGET_M[0]) * 1e3,
        (live.0 - live.1).abs() * 1e3,
        (off.0 - off.1).abs() * 1e3,
        2.0 * v * 0.002 * 1e3
    );
    assert!((live.0 - live.1).abs() < 1e-4);
    assert!(
        (off.0 - off.1).abs() > 2e-4,
        "the check cannot see a 2 ms error"
    );

    // `mmnormd calibrate`'s core on the same rows under a config 2 ms late whose mount is 4 mm
    // off along the tool's z: it must suggest an offset at which the rows agree again, and the
    // mount that the lab really has.
    let recordings = vec![fwd.0.clone(), bwd.0.clone()];
    let mut wrong = lab.clone();
    wrong.align.sync_offset_s += 0.002;
    wrong.align.tcp_from_radar[2] += 0.004;
    let started = Instant::now();
    let c = calibrate(&wrong, &setup, &names, &recordings, TARGET_M).unwrap();
    let mut fixed = lab.clone();
    fixed.align.sync_offset_s = c.suggested_sync_offset_s;
    let agree = (focus(&fixed, fwd), focus(&fixed, bwd));
    println!(
        "calibration in {:.1} s from a config 2 ms late and 4 mm off: found the target {:?} mm off, rows {:+.4} mm apart; suggests sync_offset_s = {:.5} s (the lab's: {:.5}), under which the rows are {:.4} mm apart; tcp_from_radar z {:.5} m (the lab's: {:.5})",
        started.elapsed().as_secs_f64(),
        c.error_in_base_m.map(|e| (e * 1e5).round() / 1e2),
        c.disagreement_m * 1e3,
        c.suggested_sync_offset_s,
        lab.align.sync_offset_s,
        (agree.0 - agree.1).abs() * 1e3,
        c.suggested_tcp_from_radar[2],
        lab.align.tcp_from_radar[2]
    );
    assert!(c.disagreement_m.abs() > 2e-4, "{c:?}");
    assert!((agree.0 - agree.1).abs() < 5e-5, "{c:?}");
    assert!(
        (c.suggested_sync_offset_s - lab.align.sync_offset_s).abs() < 1e-3,
        "{c:?}"
    );
    for k in [0, 2] {
        assert!(
            (c.suggested_tcp_from_radar[k] - lab.align.tcp_from_radar[k]).abs() < 5e-4,
            "axis {k}: {c:?}"
        );
    }
}
