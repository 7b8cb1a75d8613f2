//! A live radar source for the simulated lab: every frame is rendered by the forward model
//! from where the radar is at that frame's chirp, as the simulated arm's motion decides it.
//!
//! The board asks for a frame's bytes when its chirps end; a render worker works ahead of
//! that, as far as the arm's motion is decided ([`crate::ur::sim::state::ArmState::pose_at`]): up
//! to the end of the running move, or up to now while the arm rests. While the arm rests,
//! frames repeat one noise-free render with fresh noise. Frames the board had to wait for are
//! counted by the board ([`crate::dca1000::sim::SimStats::packets_late`]).
//!
//! Scale: one capture unit (see [`crate::capture`]) is `adc_counts_per_unit` ADC counts, fixed
//! for the whole scan: `full_scale` over the largest |I| or |Q| of a render at the reference
//! pose (the raster's centre), so amplitudes compare across frames and rows. Noise: complex
//! Gaussian at the scene's SNR below the mean power of the objects' echoes in that reference
//! render, as they would arrive without the cardboard
//! ([`ForwardModel::noise_sigma`]), from the scene's seed and a per-frame stream.

use std::collections::VecDeque;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Condvar, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use num_complex::{Complex, Complex32};
use rayon::prelude::*;

use crate::align::AlignConfig;
use crate::align::pose::{apply, isometry_of_pose};
use crate::dca1000::samples::FrameLayout;
use crate::dca1000::sim::{FrameSource, StreamPlan};
use crate::sim::ForwardModel;
use crate::sim::forward::{RenderScratch, Rendered, add_noise_to_chirp};
use crate::ur::sim::PoseOracle;

/// Frames rendered ahead of the board at most.
const AHEAD_FRAMES: u64 = 256;
/// Frames rendered in one parallel batch.
const BATCH_FRAMES: usize = 8;

/// How the source renders.
#[derive(Clone)]
pub struct SceneFramesConfig {
    pub layout: FrameLayout,
    /// From a frame's start to the middle of its first chirp, seconds.
    pub chirp_centre_s: f64,
    /// Where the antennas sit on the flange.
    pub geometry: AlignConfig,
    /// TCP pose whose render sets the scale and the noise level.
    pub reference_pose: [f64; 6],
    pub full_scale: i16,
    /// (SNR in dB, seed), or no noise.
    pub noise: Option<(f64, u64)>,
}

/// Counters of the source.
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Serialize)]
pub struct SceneFramesStats {
    pub frames_rendered: u64,
    /// Frames that reused the previous noise-free render (the arm at rest).
    pub renders_reused: u64,
    /// I or Q words clipped at full scale.
    pub clipped_words: u64,
    pub adc_counts_per_unit: f64,
    pub noise_sigma_counts: f64,
}

struct Stream {
    t0: Instant,
    frame_period_s: f64,
    frames: u64,
    /// Index of `ready[0]`.
    first: u64,
    ready: VecDeque<Vec<u8>>,
    /// Frames the board has read past (none of its bytes will be asked again).
    consumed: u64,
    generation: u64,
}

struct Shared {
    stream: Mutex<Option<Stream>>,
    wake: Condvar,
    stats: Mutex<SceneFramesStats>,
    stop: AtomicBool,
}

/// The live source; its worker stops when it is dropped.
pub struct SceneFrames {
    shared: Arc<Shared>,
    frame_bytes: usize,
    worker: Option<JoinHandle<()>>,
}

impl SceneFrames {
    /// Renders the reference, fixes the scale and noise, and starts the worker.
    pub fn start(
        model: Arc<ForwardModel>,
        pose_at: PoseOracle,
        config: SceneFramesConfig,
    ) -> std::io::Result<Self> {
        let renderer = Renderer::new(model, config);
        let shared = Arc::new(Shared {
            stream: Mutex::new(None),
            wake: Condvar::new(),
            stats: Mutex::new(SceneFramesStats {
                adc_counts_per_unit: renderer.scale,
                noise_sigma_counts: renderer.noise_sigma
                    * renderer.scale
                    * std::f64::consts::SQRT_2,
                ..SceneFramesStats::default()
            }),
            stop: AtomicBool::new(false),
        });
        let frame_bytes = renderer.config.layout.frame_bytes();
        let worker = {
            let shared = shared.clone();
            std::thread::Builder::new()
                .name("sim-radar-render".into())
                .spawn(move || renderer.run(&shared, &pose_at))?
        };
        Ok(Self {
            shared,
            frame_bytes,
            worker: Some(worker),
        })
    }

    pub fn stats(&self) -> SceneFramesStats {
        *lock(&self.shared.stats)
    }
}

impl Drop for SceneFrames {
    fn drop(&mut self) {
        self.shared.stop.store(true, Ordering::Relaxed);
        self.shared.wake.notify_all();
        if let Some(w) = self.worker.take() {
            w.join().ok();
        }
    }
}

fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|p| p.into_inner())
}

impl FrameSource for SceneFrames {
    fn frame_bytes(&self) -> usize {
        self.frame_bytes
    }

    fn frames(&self) -> u64 {
        u64::MAX
    }

    fn begin(&self, t0: Instant, plan: &StreamPlan) {
        let mut stream = lock(&self.shared.stream);
        let generation = stream.as_ref().map_or(0, |s| s.generation + 1);
        *stream = Some(Stream {
            t0,
            frame_period_s: plan.frame_period_s,
            frames: plan.frames,
            first: 0,
            ready: VecDeque::new(),
            consumed: 0,
            generation,
        });
        self.shared.wake.notify_all();
    }

    fn read(&self, offset: usize, buf: &mut [u8]) -> bool {
        let fb = self.frame_bytes.max(1);
        let mut guard = lock(&self.shared.stream);
        let Some(stream) = guard.as_mut() else {
            return false;
        };
        let (first_frame, last_frame) = (offset / fb, (offset + buf.len().max(1) - 1) / fb);
        let have = stream.first + stream.ready.len() as u64;
        if (last_frame as u64) >= have || (first_frame as u64) < stream.first {
            return false;
        }
        for (i, b) in buf.iter_mut().enumerate() {
            let at = offset + i;
            let frame = &stream.ready[(at / fb) - stream.first as usize];
            *b = frame[at % fb];
        }
        // Bytes are asked in order: frames before this read's first one are done with.
        stream.consumed = stream.consumed.max(first_frame as u64);
        while stream.first < stream.consumed && !stream.ready.is_empty() {
            stream.ready.pop_front();
            stream.first += 1;
        }
        self.shared.wake.notify_all();
        true
    }
}

struct Renderer {
    model: Arc<ForwardModel>,
    config: SceneFramesConfig,
    /// ADC counts per capture unit.
    scale: f64,
    /// Noise σ per I or Q component, capture units.
    noise_sigma: f64,
}

impl Renderer {
    fn new(model: Arc<ForwardModel>, config: SceneFramesConfig) -> Self {
        let mut this = Self {
            model,
            config,
            scale: 1.0,
            noise_sigma: 0.0,
        };
        let (reference, rendered) = this.render(&this.config.reference_pose, &mut None);
        let peak = reference
            .iter()
            .map(|c| c.re.abs().max(c.im.abs()))
            .fold(0.0f32, f32::max);
        if let Some((snr_db, _)) = this.config.noise {
            this.noise_sigma =
                this.model.noise_sigma(snr_db, &rendered, &reference) / std::f64::consts::SQRT_2;
        }
        // The reference is the strongest view; keep 6 dB of headroom over it and the noise.
        let headroom = 2.0 * (f64::from(peak) + 4.0 * this.noise_sigma);
        if headroom > 0.0 {
            this.scale = f64::from(this.config.full_scale) / headroom;
        }
        this
    }

    /// Antenna positions of a TCP pose.
    fn antennas(&self, tcp_pose: &[f64; 6]) -> ([f64; 3], Vec<[f64; 3]>) {
        let g = &self.config.geometry;
        let base_from_radar = isometry_of_pose(tcp_pose) * isometry_of_pose(&g.tcp_from_radar);
        (
            apply(&base_from_radar, &g.tx_in_radar_m),
            g.rx_in_radar_m
                .iter()
                .map(|rx| apply(&base_from_radar, rx))
                .collect(),
        )
    }

    /// The noise-free chirps at a TCP pose, with what [`Rendered`] counts of them.
    fn render(
        &self,
        tcp_pose: &[f64; 6],
        scratch: &mut Option<RenderScratch>,
    ) -> (Vec<Complex32>, Rendered) {
        let (tx, rxs) = self.antennas(tcp_pose);
        let t = self.config.layout.samples_per_chirp;
        let mut out = vec![Complex32::new(0.0, 0.0); rxs.len() * t];
        let scratch = scratch.get_or_insert_with(|| self.model.scratch(rxs.len()));
        let rendered = self.model.render_position(tx, &rxs, scratch, &mut out);
        (out, rendered)
    }

    /// Noise and quantisation of one frame; returns the bytes and the clipped words.
    fn finish_frame(&self, clean: &[Complex32], stream_index: u64) -> (Vec<u8>, u64) {
        let mut chirps = clean.to_vec();
        if let Some((_, seed)) = self.config.noise {
            let t = self.config.layout.samples_per_chirp.max(1);
            let per_frame = (chirps.len() / t) as u64;
            for (k, chirp) in chirps.chunks_exact_mut(t).enumerate() {
                add_noise_to_chirp(
                    chirp,
                    self.noise_sigma,
                    seed,
                    stream_index * per_frame + k as u64,
                );
            }
        }
        let mut clipped = 0;
        let mut quantise = |v: f32| {
            let q = (f64::from(v) * self.scale).round();
            if !(-32768.0..=32767.0).contains(&q) {
                clipped += 1;
            }
            q.clamp(-32768.0, 32767.0) as i16
        };
        let words: Vec<Complex<i16>> = chirps
            .iter()
            .map(|c| Complex::new(quantise(c.re), quantise(c.im)))
            .collect();
        // The layout matches the profile by construction; a mismatch would be a bug upstream.
        let bytes = self
            .config
            .layout
            .encode(&words)
            .unwrap_or_else(|_| vec![0; self.config.layout.frame_bytes()]);
        (bytes, clipped)
    }

    fn run(&self, shared: &Shared, pose_at: &PoseOracle) {
        let mut last_clean: Option<([f64; 6], Vec<Complex32>)> = None;
        let mut frame_counter = 0u64;
        while !shared.stop.load(Ordering::Relaxed) {
            // The next frames to render, with their chirp instants.
            let work = {
                let guard = lock(&shared.stream);
                guard.as_ref().and_then(|s| {
                    let next = s.first + s.ready.len() as u64;
                    let room = (s.consumed + AHEAD_FRAMES).saturating_sub(next);
                    let left = s.frames.saturating_sub(next);
                    let n = room.min(left).min(BATCH_FRAMES as u64);
                    (n > 0).then(|| {
                        let at = |k: u64| {
                            s.t0 + Duration::from_secs_f64(
                                k as f64 * s.frame_period_s + self.config.chirp_centre_s,
                            )
                        };
                        (s.generation, (next..next + n).map(at).collect::<Vec<_>>())
                    })
                })
            };
            let Some((generation, instants)) = work else {
                let guard = lock(&shared.stream);
                let _unused = shared.wake.wait_timeout(guard, Duration::from_millis(5));
                continue;
            };
            let poses: Vec<[f64; 6]> = instants.iter().map_while(|t| pose_at(*t)).collect();
            if poses.is_empty() {
                std::thread::sleep(Duration::from_micros(500));
                continue;
            }
            // Resting frames share one render; moving ones render in parallel.
            let mut uniques: Vec<[f64; 6]> = Vec::new();
            let mut which = Vec::with_capacity(poses.len());
            for p in &poses {
                if uniques.last() != Some(p) {
                    uniques.push(*p);
                }
                which.push(uniques.len() - 1);
            }
            let rendered: Vec<(Vec<Complex32>, bool)> = uniques
                .par_iter()
                .map_init(
                    || None,
                    |scratch, pose| match &last_clean {
                        Some((p, clean)) if p == pose => (clean.clone(), false),
                        _ => (self.render(pose, scratch).0, true),
                    },
                )
                .collect();
            let renders = rendered.iter().filter(|r| r.1).count() as u64;
            let cleans: Vec<&Vec<Complex32>> = which.iter().map(|&u| &rendered[u].0).collect();
            let reused = poses.len() as u64 - renders;
            let mut frames = Vec::with_capacity(cleans.len());
            let mut clipped = 0;
            for clean in &cleans {
                let (bytes, c) = self.finish_frame(clean, frame_counter);
                frame_counter += 1;
                clipped += c;
                frames.push(bytes);
            }
            if let (Some(pose), Some(clean)) = (poses.last(), cleans.last()) {
                last_clean = Some((*pose, (*clean).clone()));
            }
            let mut guard = lock(&shared.stream);
            if let Some(s) = guard.as_mut()
                && s.generation == generation
            {
                s.ready.extend(frames);
                let mut stats = lock(&shared.stats);
                stats.frames_rendered += poses.len() as u64;
                stats.renders_reused += reused;
                stats.clipped_words += clipped;
            }
        }
    }
}
