//! An abort in the middle of a row, with a radar whose `sensorStop` takes 3 s to answer (a
//! stalled UART, or a host too busy to serve it): the recording must be finished before the
//! radar is stopped, so that the daemon's 1.5 s shutdown never leaves an unfinished file, and
//! the radar must still be stopped.

mod common;

use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use mmnormd::lab::LabConfig;
use mmnormd::lab::devices::LabDevices;
use mmnormd::lab::job::{JobError, JobEvent, LiveJob, ScanRequest, run_live};
use mmnormd::lab::scan::{Devices, ScanError, ScanSetup};
use mmnormd::lab::simlab::SimLab;
use mmnormd::radar::cli::CliError;
use mmnormd::radar::cli::CommandOutcome;
use mmnormd::radar::{RadarControl, RadarProfile};

/// A radar whose `sensorStop` answers `delay` late once `abort` is set; notes, as each stop
/// begins, whether the recording is already a finished MCAP file.
struct SlowStop<'a> {
    inner: &'a mut dyn RadarControl,
    mcap: PathBuf,
    abort: Arc<AtomicBool>,
    delay: Duration,
    /// (when the stop began, whether the file was finished then)
    stops: Vec<(Instant, bool)>,
}

impl RadarControl for SlowStop<'_> {
    fn configure(&mut self, profile: &RadarProfile) -> Result<Vec<CommandOutcome>, CliError> {
        self.inner.configure(profile)
    }
    fn start(&mut self) -> Result<(), CliError> {
        self.inner.start()
    }
    fn stop(&mut self) -> Result<(), CliError> {
        let finished = std::fs::read(&self.mcap)
            .ok()
            .and_then(|bytes| mcap::Summary::read(&bytes).ok().flatten())
            .is_some();
        self.stops.push((Instant::now(), finished));
        if self.abort.load(Ordering::Relaxed) {
            std::thread::sleep(self.delay);
        }
        self.inner.stop()
    }
}

#[test]
fn an_abort_mid_row_finishes_the_file_before_a_slow_sensor_stop() {
    let dir = tempfile::tempdir().unwrap();
    let (path, _) = common::write_config(dir.path(), |t| {
        // Three rows of 16 cm at 8 cm/s: the abort falls in the second.
        let scan = t["scan"].as_table_mut().unwrap();
        scan.insert("height_m".into(), (2.0 * 0.003868).into());
        // The simulated radar renders on this CPU; beside other work its first frame of a row
        // can come later than sim.toml's 500 ms margin, which is not what this test is about.
        let board = t["dca1000"].as_table_mut().unwrap();
        board.insert("first_frame_margin_ms".into(), 3000.into());
    });
    let lab = LabConfig::load(&path).unwrap();
    let request = ScanRequest::default();
    let setup = ScanSetup::new(&lab, request.apply(&lab.scan)).unwrap();
    assert_eq!(setup.plan.rows.len(), 3);
    let _sim = SimLab::start(&lab, &setup, None).unwrap();
    let mut devices = LabDevices::connect(&lab, &setup.profile).unwrap();
    let name = "aborted";
    let abort = Arc::new(AtomicBool::new(false));
    let mut radar = SlowStop {
        inner: &mut devices.radar,
        mcap: lab.recording.data_dir.join(name).join("scan.mcap"),
        abort: abort.clone(),
        delay: Duration::from_secs(3),
        stops: Vec::new(),
    };
    let job = LiveJob {
        lab: &lab,
        setup: &setup,
        request: &request,
        name,
        truth: None,
        truth_mesh: None,
        quiet: true,
    };
    let aborted_at = Arc::new(Mutex::new(None::<Instant>));
    // 700 ms into the second row, from another thread, as the control port would.
    let events = |e: JobEvent| {
        // The first row's accepted attempt: on a loaded host a rescan of row 0 also reports
        // row 0, and an abort timed from it would fall in row 0.
        if let JobEvent::Row { row, .. } = e
            && row.row == 0
            && row.accepted
        {
            let (abort, at) = (abort.clone(), aborted_at.clone());
            std::thread::spawn(move || {
                std::thread::sleep(Duration::from_millis(700));
                *at.lock().unwrap() = Some(Instant::now());
                abort.store(true, Ordering::Relaxed);
            });
        }
    };
    let result = run_live(
        &job,
        &mut Devices {
            radar: &mut radar,
            board: &mut devices.board,
            robot: &mut devices.robot,
        },
        &abort,
        &events,
    );
    let ended = Instant::now();
    assert!(
        matches!(result, Err(JobError::Scan(ScanError::Aborted { row: 1 }))),
        "{result:?}"
    );
    let aborted_at = aborted_at.lock().unwrap().expect("the abort was sent");
    let after: Vec<(f64, bool)> = radar
        .stops
        .iter()
        .filter(|(at, _)| *at >= aborted_at)
        .map(|(at, finished)| (at.duration_since(aborted_at).as_secs_f64(), *finished))
        .collect();
    println!(
        "abort mid-row: sensorStop began {:?} s after it (file finished then: {:?}); the job ended {:.2} s after it",
        after.iter().map(|a| a.0).collect::<Vec<_>>(),
        after.iter().map(|a| a.1).collect::<Vec<_>>(),
        ended.duration_since(aborted_at).as_secs_f64()
    );
    // One stop after the abort, and the file was finished by then.
    assert_eq!(after.len(), 1, "{after:?}");
    assert!(
        after[0].1,
        "sensorStop was sent before the file was finished"
    );
    assert!(
        after[0].0 < 1.0,
        "the file took {:.2} s to finish after the abort",
        after[0].0
    );
    // The rows before the abort are in it.
    let bytes = std::fs::read(&radar.mcap).unwrap();
    let stats = mcap::Summary::read(&bytes).unwrap().unwrap().stats.unwrap();
    assert!(stats.message_count > 0);
}
