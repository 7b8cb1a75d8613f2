//! The mmNorm reconstruction (paper §2–§4) and its baselines (§5).
//!
//! Everything between a [`crate::capture::Capture`] and a point cloud; it reads captures and
//! never reaches back into acquisition or simulation. In pipeline order:
//! - [`config`]: the parameters (`recon.toml`);
//! - [`volume`]: the imaged box, explicit or found from the data;
//! - [`image`]: S(v) by range-FFT backprojection (Eq. 4–5);
//! - [`normals`]: the normal field (Eq. 1–3, 6);
//! - [`mask`] with [`threshold`]: the Li-thresholded binary image (Eq. 9–10);
//! - [`components`]: 6-connected components;
//! - [`rsdf`]: one relative signed distance function per component (Eq. 8);
//! - [`trace`] and [`isosurface`]: the structural isosurface optimisation (Eq. 11–13) and the
//!   ablations, with [`subset`] choosing its antennas and [`near_echo`] keeping the echoes
//!   nearer than the objects out of its cost;
//! - [`baselines`]: backprojection and interferometric points;
//! - [`pipeline`]: the stages run in order, with timings, for `mmnormd reconstruct`.

pub mod baselines;
pub mod components;
pub mod config;
pub mod hidden;
pub mod image;
pub mod isosurface;
pub mod kernel;
pub mod lattice;
pub mod mask;
pub mod near_echo;
pub mod normals;
pub mod output;
pub mod pipeline;
pub mod rma;
pub mod rsdf;
pub mod sidelobe;
pub mod split;
pub mod subset;
pub mod threshold;
pub mod trace;
pub mod volume;

pub use config::ReconConfig;
pub use pipeline::{
    Imaged, Reconstruction, image_volume, reconstruct, reconstruct_imaged, reconstruct_isosurfaces,
};
