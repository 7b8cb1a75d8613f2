//! S(v) and the spectral normal field by range migration (ω-k), for raster apertures.
//!
//! Backprojection costs voxels × antennas; range migration costs a few FFTs of the aperture.
//! For a capture whose phase centres lie on a [`Lattice`]:
//!
//! 1. **Per antenna**: the chirp is multiplied by `exp(−j k_t (offset + δ_j + 2 dz_j))`, with
//!    `k_t = 2π f_t/c`. `offset` is the radar's range offset. `δ_j = |TX − RX|²/(4 R_ref)` turns the
//!    bistatic round trip into twice the range from the phase centre (exact at broadside for
//!    scatterers at the reference depth R_ref, the grid centre's depth; elsewhere the error is
//!    `|TX − RX|²/4·|1/R − 1/R_ref|` plus an angle term, 0.1 mm for the IWR1443BOOST's 11 mm at
//!    0.4 ± 0.15 m). `dz_j` is the centre's height above the lattice plane, removed exactly for
//!    broadside echoes; the lateral snap to the node is the error [`super::lattice`] bounds.
//! 2. **Range gate and decimation**: the T-point range FFT keeps the bins that round trips into
//!    the grid can reach (±2 bins, with a raised-cosine edge over 2 more), centred and
//!    inverse-transformed at M = T/s points, M ≥ 4× the kept bins. The gated chirp is then known
//!    exactly on every s-th sample and, being four times oversampled, between them by 4-point
//!    Lagrange interpolation. Echoes outside the gate cannot alias into the grid.
//! 3. **Aperture FFT**: antennas on one node add; each of the M planes gets a 2-D FFT over the
//!    lattice, zero-padded to at least the aperture plus the grid's width so that nothing wraps.
//! 4. **Stolt**: on a uniform kz grid spanning 2·k_min·cos θ_max to 2·k_max (θ_max the widest
//!    angle between the aperture and the grid), with a period in z longer than the deepest gated
//!    echo, each (kx, ky, kz) reads the chirp at `k = |K|/2`, weighted by
//!    `−j·Δkx·Δky·Δkz/(4π kz |Δk| N)`, and the image is multiplied by the voxel's depth d below
//!    the aperture. Together they make S(v) equal backprojection's mean over antennas, direction
//!    by direction: by stationary phase the aperture FFT of a point echo at range R is
//!    `j·2πR/kz` per unit area; the antennas-to-K Jacobian is `R²/kz²` and `dkz/dk = 4k/kz`, so a
//!    backprojected direction weighs `kz/(8πkR)` = `1/(4π d)` times the unweighted spectral
//!    one, with `R·cos θ = d` and `kz = 2k·cos θ`.
//! 5. **To the voxels**: inverse chirp-z transforms ([`crate::signal::Czt`]) along kx and ky for
//!    every kz plane, then along kz for every column, land exactly on the grid's voxel centres.
//!
//! **Spectral normal field.** The plane-wave component K of the image comes, by stationary
//! phase, from the antennas in direction `u = K/|K|` (an antenna at u contributes
//! `exp(j 2k u·v)` near v). So `Σ_j I_j(v)·u_j`, which Eq. 3 with the weights of Eq. 6 needs as
//! `Re(conj(S)·Σ_j I_j u_j)/|S|`, is three more transforms of the same spectrum weighted by
//! `K/|K|`. It holds where stationary phase does: far from the aperture's edges in angle, and
//! for the paper's unit candidate vectors only (the authors' displacement variant weights by
//! distance and has no spectral form); `tests` compare it with exact votes. Measured against
//! exact votes (median cosine on the voxels above 30 % of the peak): 0.9998–1.0000 for a tilted
//! plate, a sphere and a cylinder 25 cm under an 8×8 cm aperture; 0.9996 for a sphere 5 cm under
//! it, where |S| itself correlates with backprojection at 0.988 only; 1.0000 for a sphere under
//! the aperture's corner. No case tried needed the exact votes, which stay available
//! (`spectral_normals = false`) and are used for non-raster apertures.

use std::f64::consts::{PI, TAU};

use num_complex::{Complex32, Complex64};
use rayon::prelude::*;
use rustfft::FftPlanner;
use serde::Serialize;

use super::image::{VoxelGrid, round_trip_bounds};
use super::lattice::Lattice;
use crate::SPEED_OF_LIGHT_M_PER_S;
use crate::capture::Capture;
use crate::progress::Progress;
use crate::signal::{Czt, CztAxes, fft_friendly};

/// What the range migration did, for summary.json.
#[derive(Debug, Clone, Serialize)]
pub struct RmaReport {
    pub lattice: Lattice,
    /// Padded aperture FFT size (x, y).
    pub fft_dims: [usize; 2],
    /// Chirp samples kept after gating and decimation, and the stride.
    pub decimated_samples: usize,
    pub decimation: usize,
    /// Round trips into the grid (range offset removed), metres; the gate adds its margins.
    pub gate_round_trip_m: [f64; 2],
    /// kz samples and their span, rad/m.
    pub kz_samples: usize,
    pub kz_range_rad_per_m: [f64; 2],
    /// Depth period of the kz grid, metres.
    pub depth_period_m: f64,
    /// Reference depth of the bistatic correction, metres.
    pub reference_depth_m: f64,
    /// Upper bound of the lateral snap's phase error at θ_max, radians.
    pub snap_phase_error_rad: f64,
}

/// S(v) on the grid, and with `votes` the vote vectors `Re(conj(S)·Σ_j I_j u_j)/|S|`.
pub struct RmaImage {
    pub image: Vec<Complex32>,
    pub votes: Option<Vec<[f32; 3]>>,
    pub report: RmaReport,
}

/// The normalised correlation Σab/√(Σa²·Σb²) of two magnitude images.
pub fn magnitude_correlation(a: &[f32], b: &[f32]) -> f64 {
    let dot: f64 = a
        .iter()
        .zip(b)
        .map(|(x, y)| f64::from(*x) * f64::from(*y))
        .sum();
    let na: f64 = a.iter().map(|x| f64::from(*x).powi(2)).sum::<f64>().sqrt();
    let nb: f64 = b.iter().map(|x| f64::from(*x).powi(2)).sum::<f64>().sqrt();
    dot / (na * nb)
}

/// Decimation keeps at least this many samples per gated range bin.
const OVERSAMPLING: usize = 4;
/// Gate margin and raised-cosine edge, in range bins of the T-point FFT.
const GATE_MARGIN_BINS: f64 = 2.0;
const GATE_EDGE_BINS: f64 = 2.0;

/// Images `grid` from a raster capture; with `votes`, the spectral vote field as well. The
/// progress bar counts kz planes, then one step per field for the kz → z transforms.
pub fn rma_image(
    capture: &Capture,
    grid: &VoxelGrid,
    lattice: &Lattice,
    votes: bool,
    quiet: bool,
) -> RmaImage {
    let plan = capture.plan;
    let t_len = plan.samples_per_chirp;
    let c = SPEED_OF_LIGHT_M_PER_S;
    let (grid_lo, grid_hi) = grid.extent();
    let reference_depth_m = lattice.z_m - 0.5 * (grid_lo[2] + grid_hi[2]);

    // 1–2. Gate and decimation plan.
    let (near, far) = round_trip_bounds(capture, grid);
    let bin_of = |d: f64| plan.frequency_step_hz * d * t_len as f64 / c;
    let (b_near, b_far) = (bin_of(near), bin_of(far));
    let (b_lo, b_hi) = (
        b_near.min(b_far) - GATE_MARGIN_BINS - GATE_EDGE_BINS,
        b_near.max(b_far) + GATE_MARGIN_BINS + GATE_EDGE_BINS,
    );
    let occupied = (b_hi - b_lo).ceil() as usize + 1;
    let decimation = (1..=t_len)
        .rev()
        .find(|s| t_len.is_multiple_of(*s) && t_len / s >= OVERSAMPLING * occupied)
        .unwrap_or(1);
    let m_len = t_len / decimation;
    let centre_bin = (0.5 * (b_lo + b_hi)).round() as i64;
    let gate = |b: f64| {
        let inner = (
            b_near.min(b_far) - GATE_MARGIN_BINS,
            b_near.max(b_far) + GATE_MARGIN_BINS,
        );
        let outside = if b < inner.0 {
            inner.0 - b
        } else {
            (b - inner.1).max(0.0)
        };
        if outside >= GATE_EDGE_BINS {
            0.0
        } else {
            0.5 + 0.5 * (PI * outside / GATE_EDGE_BINS).cos()
        }
    };

    // Antennas grouped by node.
    let nodes = lattice.dims[0] * lattice.dims[1];
    let mut start = vec![0usize; nodes + 1];
    for &n in &lattice.node_of {
        start[n + 1] += 1;
    }
    for n in 0..nodes {
        start[n + 1] += start[n];
    }
    let mut members = vec![0usize; lattice.node_of.len()];
    let mut fill = start.clone();
    for (a, &n) in lattice.node_of.iter().enumerate() {
        members[fill[n]] = a;
        fill[n] += 1;
    }
    let mut planner = FftPlanner::<f32>::new();
    let range_fft = planner.plan_fft_forward(t_len);
    let decimated_ifft = planner.plan_fft_inverse(m_len);
    let k_of = |t: usize| TAU * plan.frequency_hz(t) / c;
    let dk_signed = TAU * plan.frequency_step_hz / c;
    // The gate's weight of each kept bin, the same for every antenna.
    let half = (m_len / 2) as i64;
    let kept: Vec<(usize, usize, f32)> = (0..m_len as i64)
        .map(|m| {
            let offset = m - half;
            let b = centre_bin + offset;
            (
                b.rem_euclid(t_len as i64) as usize,
                offset.rem_euclid(m_len as i64) as usize,
                gate(b as f64) as f32 / t_len as f32,
            )
        })
        .collect();
    // Per node: the sum of its antennas' gated, decimated chirps (M samples).
    let mut node_chirps = vec![Complex32::new(0.0, 0.0); nodes * m_len];
    node_chirps.par_chunks_mut(m_len).enumerate().for_each_init(
        || {
            (
                vec![Complex32::new(0.0, 0.0); t_len],
                vec![Complex32::new(0.0, 0.0); m_len],
            )
        },
        |(full, short), (n, out)| {
            for &a in &members[start[n]..start[n + 1]] {
                let (tx, rx) = (capture.tx_m[a], capture.rx_m[a]);
                let baseline2: f64 = (0..3).map(|k| (tx[k] - rx[k]).powi(2)).sum();
                let extra_m = capture.range_offset_m
                    + baseline2 / (4.0 * reference_depth_m.max(1e-3))
                    + 2.0 * lattice.offset_m[a][2];
                // exp(−j k_t extra) by a rotator in f64, re-seeded every 64 samples.
                let step = Complex64::from_polar(1.0, -dk_signed * extra_m);
                let mut w = Complex64::new(1.0, 0.0);
                for (t, (f, h)) in full.iter_mut().zip(capture.chirp(a)).enumerate() {
                    if t % 64 == 0 {
                        w = Complex64::from_polar(1.0, (-k_of(t) * extra_m).rem_euclid(TAU));
                    }
                    *f = h * Complex32::new(w.re as f32, w.im as f32);
                    w *= step;
                }
                range_fft.process(full);
                for &(bin, slot, weight) in &kept {
                    short[slot] = full[bin] * weight;
                }
                decimated_ifft.process(short);
                for (o, s) in out.iter_mut().zip(short.iter()) {
                    *o += s;
                }
            }
        },
    );

    // 3. Aperture FFT of each decimated sample plane, stored kx-fastest per ky row, samples
    // innermost: spectrum[(ky·nfx + kx)·M + t'].
    let (gx, gy) = (grid_hi[0] - grid_lo[0], grid_hi[1] - grid_lo[1]);
    let [nx, ny] = lattice.dims;
    let [dx, dy] = lattice.spacing_m;
    let nfx = fft_friendly(nx + (gx / dx).ceil() as usize + 2);
    let nfy = fft_friendly(ny + (gy / dy).ceil() as usize + 2);
    let spectrum = aperture_spectrum(&node_chirps, [nx, ny], [nfx, nfy], m_len, &mut planner);
    drop(node_chirps);

    // 4. The kz grid.
    let (k_min, k_max) = {
        let (a, b) = (k_of(0), k_of(t_len - 1));
        (a.min(b), a.max(b))
    };
    let lattice_hi = [
        lattice.origin_m[0] + dx * (nx - 1) as f64,
        lattice.origin_m[1] + dy * (ny - 1) as f64,
    ];
    let lateral = (0..2)
        .map(|k| {
            let lo = [lattice.origin_m[0], lattice.origin_m[1]][k];
            (grid_hi[k] - lo)
                .abs()
                .max((lattice_hi[k] - grid_lo[k]).abs())
        })
        .collect::<Vec<_>>();
    let shallowest = (lattice.z_m - grid_hi[2]).max(1e-3);
    let cos_max = (shallowest / (lateral[0].hypot(lateral[1]).hypot(shallowest))).max(0.05);
    let depth_period_m = 0.5 * far
        + (GATE_MARGIN_BINS + GATE_EDGE_BINS) * c
            / (2.0 * plan.frequency_step_hz.abs() * t_len as f64);
    let dkz = TAU / depth_period_m;
    let kz_lo = 2.0 * k_min * cos_max;
    let kz_hi = 2.0 * k_max;
    let nkz = ((kz_hi - kz_lo) / dkz).ceil() as usize + 1;

    // 5. Per kz plane: Stolt, then chirp-z along kx and ky onto the voxel centres.
    let fields = if votes { 4 } else { 1 };
    let progress = Progress::new("image (range migration)", (nkz + fields) as u64, quiet);
    let [vx, vy, vz] = grid.dims;
    let dkx = TAU / (nfx as f64 * dx);
    let dky = TAU / (nfy as f64 * dy);
    // From the shifted lateral wavenumbers to the voxel centres, relative to the lattice origin.
    let mut lateral_czt = |axis: usize, nf: usize, dk: f64, m: usize| {
        let axes = CztAxes {
            n: nf,
            k0: -((nf / 2) as f64) * dk,
            dk,
            m,
            x0: grid.origin_m[axis] - lattice.origin_m[axis],
            dx: grid.voxel_m,
        };
        Czt::new(axes, &mut planner)
    };
    let czt_x = lateral_czt(0, nfx, dkx, vx);
    let czt_y = lateral_czt(1, nfy, dky, vy);
    let dk = TAU * plan.frequency_step_hz.abs() / c;
    let weight_base = dkx * dky * dkz / (4.0 * PI * dk * capture.antennas().max(1) as f64);
    let plane_len = vx * vy;
    let mut planes = vec![Complex32::new(0.0, 0.0); nkz * fields * plane_len];
    let stolt = Stolt {
        spectrum: &spectrum,
        nf: [nfx, nfy],
        dk_xy: [dkx, dky],
        m_len,
        decimation,
        centre_bin,
        t_len,
        k0: k_of(0),
        dk_signed,
        z_m: lattice.z_m,
        weight_base,
    };
    planes
        .par_chunks_mut(fields * plane_len)
        .enumerate()
        .for_each_init(
            || PlaneScratch::new(nfx, nfy, fields),
            |scratch, (j, out)| {
                let kz = kz_lo + dkz * j as f64;
                stolt.fill(kz, scratch);
                for f in 0..fields {
                    scratch.transform_to_voxels(
                        f,
                        &czt_x,
                        &czt_y,
                        &mut out[f * plane_len..(f + 1) * plane_len],
                    );
                }
                progress.inc(1);
            },
        );
    drop(spectrum);

    // kz → z for every column.
    let czt_z = Czt::new(
        CztAxes {
            n: nkz,
            k0: kz_lo,
            dk: dkz,
            m: vz,
            x0: grid.origin_m[2],
            dx: grid.voxel_m,
        },
        &mut planner,
    );
    // The depth factor of the weight (step 4).
    let depth: Vec<f32> = (0..vz)
        .map(|k| (lattice.z_m - (grid.origin_m[2] + grid.voxel_m * k as f64)) as f32)
        .collect();
    let column = |f: usize,
                  out: &mut [Complex32],
                  xy: usize,
                  buf: &mut Vec<Complex32>,
                  s: &mut Vec<Complex32>| {
        buf.clear();
        buf.extend((0..nkz).map(|j| planes[(j * fields + f) * plane_len + xy]));
        czt_z.apply(buf, out, s);
        for (o, d) in out.iter_mut().zip(&depth) {
            *o *= *d;
        }
    };
    let mut image = vec![Complex32::new(0.0, 0.0); grid.len()];
    image.par_chunks_mut(vz).enumerate().for_each_init(
        || (Vec::new(), Vec::new()),
        |(buf, s), (xy, out)| column(0, out, xy, buf, s),
    );
    progress.inc(1);
    let votes = votes.then(|| {
        let mut votes = vec![[0.0f32; 3]; grid.len()];
        votes
            .par_chunks_mut(vz)
            .zip(image.par_chunks(vz))
            .enumerate()
            .for_each_init(
                || (Vec::new(), Vec::new(), vec![Complex32::new(0.0, 0.0); vz]),
                |(buf, s, v), (xy, (out, image))| {
                    for q in 0..3 {
                        column(1 + q, v, xy, buf, s);
                        for ((o, sv), w) in out.iter_mut().zip(image).zip(v.iter()) {
                            let magnitude = sv.norm();
                            o[q] = if magnitude > 0.0 {
                                (sv.re * w.re + sv.im * w.im) / magnitude
                            } else {
                                0.0
                            };
                        }
                    }
                },
            );
        progress.inc(3);
        votes
    });
    progress.finish();
    let max_sin = (1.0 - cos_max * cos_max).sqrt();
    RmaImage {
        image,
        votes,
        report: RmaReport {
            fft_dims: [nfx, nfy],
            decimated_samples: m_len,
            decimation,
            gate_round_trip_m: [near, far],
            kz_samples: nkz,
            kz_range_rad_per_m: [kz_lo, kz_hi],
            depth_period_m,
            reference_depth_m,
            snap_phase_error_rad: 2.0 * k_max * lattice.max_lateral_offset_m * max_sin,
            lattice: lattice.clone(),
        },
    }
}

/// The 2-D FFT over the zero-padded lattice of each decimated sample, laid out
/// `[(ky·nfx + kx)·M + t']` in FFT order.
fn aperture_spectrum(
    node_chirps: &[Complex32],
    dims: [usize; 2],
    nf: [usize; 2],
    m_len: usize,
    planner: &mut FftPlanner<f32>,
) -> Vec<Complex32> {
    let [nx, ny] = dims;
    let [nfx, nfy] = nf;
    let fft_x = planner.plan_fft_forward(nfx);
    let fft_y = planner.plan_fft_forward(nfy);
    // Planes per sample: [t'][ky][kx].
    let mut planes = vec![Complex32::new(0.0, 0.0); m_len * nfx * nfy];
    planes.par_chunks_mut(nfx * nfy).enumerate().for_each_init(
        || vec![Complex32::new(0.0, 0.0); nfy],
        |column, (t, plane)| {
            for j in 0..ny {
                for i in 0..nx {
                    plane[j * nfx + i] = node_chirps[(i + nx * j) * m_len + t];
                }
            }
            for row in plane.chunks_mut(nfx).take(ny) {
                fft_x.process(row);
            }
            for i in 0..nfx {
                for j in 0..nfy {
                    column[j] = plane[j * nfx + i];
                }
                fft_y.process(column);
                for j in 0..nfy {
                    plane[j * nfx + i] = column[j];
                }
            }
        },
    );
    // Transpose to samples innermost.
    let mut spectrum = vec![Complex32::new(0.0, 0.0); m_len * nfx * nfy];
    spectrum
        .par_chunks_mut(m_len)
        .enumerate()
        .for_each(|(p, out)| {
            for (t, o) in out.iter_mut().enumerate() {
                *o = planes[t * nfx * nfy + p];
            }
        });
    spectrum
}

/// Everything the Stolt mapping of one kz plane reads.
struct Stolt<'a> {
    spectrum: &'a [Complex32],
    nf: [usize; 2],
    dk_xy: [f64; 2],
    m_len: usize,
    decimation: usize,
    centre_bin: i64,
    t_len: usize,
    k0: f64,
    dk_signed: f64,
    z_m: f64,
    weight_base: f64,
}

/// One kz plane's fields in (ky, kx) order, kx fastest, shifted so kx and ky increase, and the
/// chirp-z scratch.
struct PlaneScratch {
    nf: [usize; 2],
    fields: Vec<Vec<Complex32>>,
    rows: Vec<Complex32>,
    line_in: Vec<Complex32>,
    czt: Vec<Complex32>,
}

impl PlaneScratch {
    fn new(nfx: usize, nfy: usize, fields: usize) -> PlaneScratch {
        PlaneScratch {
            nf: [nfx, nfy],
            fields: vec![vec![Complex32::new(0.0, 0.0); nfx * nfy]; fields],
            rows: Vec::new(),
            line_in: Vec::new(),
            czt: Vec::new(),
        }
    }

    /// Field `f` of the plane onto the voxel centres: `out[x·vy + y]`.
    fn transform_to_voxels(&mut self, f: usize, czt_x: &Czt, czt_y: &Czt, out: &mut [Complex32]) {
        let [nfx, nfy] = self.nf;
        let (vx, vy) = (czt_x.outputs(), czt_y.outputs());
        // Along kx for every ky row: rows[ky·vx + x].
        self.rows.resize(nfy * vx, Complex32::new(0.0, 0.0));
        let field = &self.fields[f];
        for (row_in, row_out) in field.chunks(nfx).zip(self.rows.chunks_mut(vx)) {
            if row_in.iter().all(|z| z.re == 0.0 && z.im == 0.0) {
                row_out.fill(Complex32::new(0.0, 0.0));
            } else {
                czt_x.apply(row_in, row_out, &mut self.czt);
            }
        }
        // Along ky for every x, from a blocked transpose of the rows: columns[x·nfy + ky].
        self.line_in.resize(nfy * vx, Complex32::new(0.0, 0.0));
        const BLOCK: usize = 32;
        for ky0 in (0..nfy).step_by(BLOCK) {
            for x0 in (0..vx).step_by(BLOCK) {
                for ky in ky0..(ky0 + BLOCK).min(nfy) {
                    for x in x0..(x0 + BLOCK).min(vx) {
                        self.line_in[x * nfy + ky] = self.rows[ky * vx + x];
                    }
                }
            }
        }
        for (column, o) in self.line_in.chunks(nfy).zip(out.chunks_mut(vy)) {
            czt_y.apply(column, o, &mut self.czt);
        }
    }
}

impl Stolt<'_> {
    /// Fills `scratch.fields` for the plane `kz`: S's spectrum and, with four fields, its
    /// products with K/|K|.
    fn fill(&self, kz: f64, scratch: &mut PlaneScratch) {
        let [nfx, nfy] = self.nf;
        let (hx, hy) = ((nfx / 2) as i64, (nfy / 2) as i64);
        let m_len = self.m_len as i64;
        let z_phase = Complex64::from_polar(1.0, (-kz * self.z_m).rem_euclid(TAU));
        for field in &mut scratch.fields {
            field.fill(Complex32::new(0.0, 0.0));
        }
        // Only (kx, ky) with 2k = |K| inside the sweep carry data: an annulus per plane.
        let (k_a, k_b) = (self.k0, self.k0 + self.dk_signed * (self.t_len - 1) as f64);
        let outer2 = 4.0 * k_a.max(k_b).powi(2) - kz * kz;
        if outer2 <= 0.0 {
            return;
        }
        for sy in 0..nfy {
            // Shifted index sy ↔ ky = (sy − hy)·Δky, stored in FFT order at (sy + nfy − hy) mod nfy.
            let ky = (sy as i64 - hy) as f64 * self.dk_xy[1];
            let py = (sy as i64 - hy).rem_euclid(nfy as i64) as usize;
            let room = outer2 - ky * ky;
            if room <= 0.0 {
                continue;
            }
            let kx_max = room.sqrt() / self.dk_xy[0];
            let sx_lo = (hx - kx_max.floor() as i64 - 1).max(0) as usize;
            let sx_hi = ((hx + kx_max.ceil() as i64 + 1) as usize).min(nfx);
            for sx in sx_lo..sx_hi {
                let kx = (sx as i64 - hx) as f64 * self.dk_xy[0];
                let px = (sx as i64 - hx).rem_euclid(nfx as i64) as usize;
                let slot = sy * nfx + sx;
                let big_k = (kx * kx + ky * ky + kz * kz).sqrt();
                let k = 0.5 * big_k;
                let t_frac = (k - self.k0) / self.dk_signed;
                let value = if t_frac >= 0.0 && t_frac <= (self.t_len - 1) as f64 {
                    let samples = &self.spectrum[(py * nfx + px) * self.m_len..][..self.m_len];
                    let u = t_frac / self.decimation as f64;
                    let base = u.floor() as i64;
                    let r = u - base as f64;
                    // 4-point Lagrange on base−1 … base+2 (periodic: the gated chirp is).
                    let w = [
                        -r * (r - 1.0) * (r - 2.0) / 6.0,
                        (r + 1.0) * (r - 1.0) * (r - 2.0) / 2.0,
                        -(r + 1.0) * r * (r - 2.0) / 2.0,
                        (r + 1.0) * r * (r - 1.0) / 6.0,
                    ];
                    let mut acc = Complex64::new(0.0, 0.0);
                    for (q, wq) in w.iter().enumerate() {
                        let z = samples[(base - 1 + q as i64).rem_euclid(m_len) as usize];
                        acc += Complex64::new(f64::from(z.re), f64::from(z.im)) * wq;
                    }
                    let carrier = Complex64::from_polar(
                        1.0,
                        (TAU * self.centre_bin as f64 * t_frac / self.t_len as f64).rem_euclid(TAU),
                    );
                    // −j·weight: the stationary-phase factor j removed.
                    acc * carrier * z_phase * Complex64::new(0.0, -self.weight_base / kz)
                } else {
                    Complex64::new(0.0, 0.0)
                };
                let narrow = |z: Complex64| Complex32::new(z.re as f32, z.im as f32);
                scratch.fields[0][slot] = narrow(value);
                if scratch.fields.len() == 4 {
                    let unit = [kx / big_k, ky / big_k, kz / big_k];
                    for (field, u) in scratch.fields[1..].iter_mut().zip(unit) {
                        field[slot] = narrow(value * u);
                    }
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::recon::image::{RangeProfiles, backproject};
    use crate::recon::lattice::detect;
    use crate::sim::{Scene, simulate};

    fn scene_capture(objects: &str, layout: &str, spacing: f64) -> Capture {
        capture_at(objects, layout, spacing, 0.25)
    }

    fn capture_at(objects: &str, layout: &str, spacing: f64, z_m: f64) -> Capture {
        let text = format!(
            "[radar]\nprofile = \"{}/firmware_cfg/iwr1443_mmnorm.cfg\"\n\
            [aperture]\nwidth_m = 0.08\nheight_m = 0.08\nspacing_m = {spacing}\nz_m = {z_m}\nlayout = \"{layout}\"\nantenna_pattern = \"isotropic\"\n{objects}",
            env!("CARGO_MANIFEST_DIR")
        );
        let scene = Scene::parse(&text, std::path::Path::new("inline.toml")).unwrap();
        simulate(&scene, true).capture
    }

    use super::magnitude_correlation as correlation;

    /// A point target, monostatic at λ/2 and with the IWR1443BOOST's four RX channels (11 mm
    /// TX–RX baselines, phase centres λ/4 apart) at λ/2: |S| correlates with backprojection
    /// to ≥ 0.99, peaks within a voxel of it (the 5 cm range envelope is flat over a few mm of
    /// depth), and at the same height within 5 %.
    #[test]
    fn matches_backprojection_on_a_point_target() {
        for layout in ["monostatic", "iwr1443boost"] {
            point_target_parity(layout);
        }
    }

    fn point_target_parity(layout: &str) {
        let capture = scene_capture(
            "[[object]]\nshape = \"point\"\nposition_m = [0.0042, -0.0031, 0.0]\nrcs_m2 = 0.01\n",
            layout,
            0.0019,
        );
        let lattice = detect(&capture, 0.1).unwrap();
        let grid = VoxelGrid {
            origin_m: [-0.012, -0.013, -0.010],
            voxel_m: 0.001,
            dims: [25, 24, 21],
        };
        let Both { ma, mb, .. } = both(&capture, &grid, &lattice, false);
        let r = correlation(&ma, &mb);
        let argmax = |m: &[f32]| (0..m.len()).max_by(|&a, &b| m[a].total_cmp(&m[b])).unwrap();
        let (pa, pb) = (argmax(&ma), argmax(&mb));
        let peak_ratio = ma[pa] / mb[pb];
        println!("{layout}: corr {r:.5}, peaks {pa} {pb}, ratio {peak_ratio:.4}");
        assert!(r >= 0.99, "{r}");
        let ijk = |p: usize| [p / (24 * 21), p / 21 % 24, p % 21];
        let (a, b) = (ijk(pa), ijk(pb));
        assert!(
            (0..3).all(|q| a[q].abs_diff(b[q]) <= 1),
            "{layout}: peak {a:?} vs {b:?}"
        );
        assert!((peak_ratio - 1.0).abs() < 0.05, "{peak_ratio}");
    }

    /// One grid imaged by range migration and by backprojection, with both magnitudes.
    struct Both {
        rma: RmaImage,
        profiles: RangeProfiles,
        bp: Vec<Complex32>,
        ma: Vec<f32>,
        mb: Vec<f32>,
    }

    fn both(capture: &Capture, grid: &VoxelGrid, lattice: &Lattice, votes: bool) -> Both {
        let rma = rma_image(capture, grid, lattice, votes, true);
        let profiles = RangeProfiles::new(capture, grid, 32);
        let bp = backproject(capture, grid, &profiles, None);
        let (ma, mb) = rma
            .image
            .iter()
            .zip(&bp)
            .map(|(a, b)| (a.norm(), b.norm()))
            .unzip();
        Both {
            rma,
            profiles,
            bp,
            ma,
            mb,
        }
    }

    /// 34×34×22 voxels of 1.5 mm from `origin_m`: about a 5 cm cube around an object.
    fn cube_from(origin_m: [f64; 3]) -> VoxelGrid {
        VoxelGrid {
            origin_m,
            voxel_m: 0.0015,
            dims: [34, 34, 22],
        }
    }

    /// |S| correlation with backprojection, and the median and 10th percentile of the cosine
    /// between spectral and exact votes on the voxels above 30 % of the peak.
    fn spectral_against_exact(capture: &Capture, grid: &VoxelGrid) -> (f64, f64, f64) {
        use crate::recon::normals::{Candidates, normal_field};
        let lattice = detect(capture, 0.1).unwrap();
        let Both {
            rma,
            profiles,
            bp,
            ma,
            mb,
        } = both(capture, grid, &lattice, true);
        let peak = mb.iter().copied().fold(0.0f32, f32::max);
        let selected: Vec<bool> = mb.iter().map(|m| *m >= 0.3 * peak).collect();
        let exact = normal_field(
            capture,
            grid,
            &profiles,
            &bp,
            &selected,
            Candidates::Unit,
            None,
        );
        let votes = rma.votes.as_ref().unwrap();
        let mut cosines: Vec<f64> = (0..grid.len())
            .filter(|&v| selected[v] && exact[v][0].is_finite())
            .map(|v| {
                let w = votes[v];
                let n = (w[0] * w[0] + w[1] * w[1] + w[2] * w[2]).sqrt();
                f64::from((0..3).map(|q| w[q] * exact[v][q]).sum::<f32>() / n)
            })
            .collect();
        cosines.sort_by(f64::total_cmp);
        (
            correlation(&ma, &mb),
            cosines[cosines.len() / 2],
            cosines[cosines.len() / 10],
        )
    }

    /// Spectral votes against exact per-antenna votes (unit candidates) on the voxels above 30 %
    /// of the peak, and |S| against backprojection, for a tilted plate, a sphere and a cylinder
    /// on its side, 25 cm under the middle of an 8×8 cm aperture.
    #[test]
    fn spectral_normals_match_exact_votes() {
        let cases = [
            (
                "plate",
                "shape = \"plate\"\nsize_m = [0.03, 0.03]\nrotation_deg = [12.0, 5.0, 0.0]\n",
            ),
            ("sphere", "shape = \"sphere\"\nradius_m = 0.02\n"),
            (
                "cylinder",
                "shape = \"cylinder\"\nradius_m = 0.015\nlength_m = 0.05\nrotation_deg = [0.0, 90.0, 0.0]\n",
            ),
        ];
        let grid = cube_from([-0.025, -0.025, -0.005]);
        for (name, object) in cases {
            let capture = scene_capture(
                &format!("[[object]]\nposition_m = [0.0, 0.0, 0.0]\n{object}"),
                "monostatic",
                0.0019,
            );
            let (r, median, p10) = spectral_against_exact(&capture, &grid);
            println!(
                "{name}: |S| correlation {r:.4}, normal cosine median {median:.4}, p10 {p10:.4}"
            );
            assert!(r >= 0.99, "{name}: {r}");
            assert!(median >= 0.99, "{name}: {median}");
        }
    }

    /// Where stationary phase is strained: a sphere 5 cm under the aperture (the aperture spans
    /// ±39° from it) and a sphere under the aperture's corner (it sees the aperture from one
    /// side only). Measured: |S| correlation 0.988 and 0.999, normal cosine median 0.9996 and
    /// 1.0000. Long: `cargo test --release -- --ignored spectral_normals_at`.
    #[test]
    #[ignore]
    fn spectral_normals_at_low_height_and_at_the_edge() {
        let sphere = "[[object]]\nshape = \"sphere\"\nradius_m = 0.02\n";
        let low = capture_at(
            &format!("{sphere}position_m = [0.0, 0.0, 0.0]\n"),
            "monostatic",
            0.0019,
            0.07,
        );
        let grid = cube_from([-0.025, -0.025, -0.005]);
        let (r, median, p10) = spectral_against_exact(&low, &grid);
        println!(
            "5 cm under the aperture: |S| correlation {r:.4}, normal cosine median {median:.4}, p10 {p10:.4}"
        );
        assert!(median >= 0.99, "low: {median}");
        assert!(r >= 0.98, "low: {r}");
        let corner = scene_capture(
            &format!("{sphere}position_m = [0.04, 0.04, 0.0]\n"),
            "monostatic",
            0.0019,
        );
        let grid = cube_from([0.015, 0.015, -0.005]);
        let (r, median, p10) = spectral_against_exact(&corner, &grid);
        println!(
            "under the corner: |S| correlation {r:.4}, normal cosine median {median:.4}, p10 {p10:.4}"
        );
        assert!(median >= 0.99, "corner: {median}");
    }
}
