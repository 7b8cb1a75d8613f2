//! The physical forward simulator: scenes in, captures out.
//!
//! This module owns the scene format ([`scene`]), the raster aperture ([`aperture`]), the
//! conversion of geometry into scatterers ([`surface`]), the cardboard occluder ([`occluder`]),
//! the forward models ([`forward`]) and the top-view ground truth ([`truth`]). It must never use
//! the reconstruction's forward model. Its default physics (physical optics) puts no isotropic
//! point scatterers on surfaces: mmNorm lives on specularity, and a simulator that hides it
//! would test nothing. The second physics (`[physics] model = "point-scatterer"`) keeps
//! specularity with a cone per surface sample and adds edge points that radiate everywhere, as
//! the simulator the paper's authors used does; docs/simulation.md compares the two.

pub mod aperture;
pub mod forward;
pub mod occluder;
pub mod output;
pub mod scene;
pub mod surface;
pub mod truth;

pub use forward::{ForwardModel, SimOutput, SimStats, simulate, simulate_with};
pub use output::write_simulation;
pub use scene::{Scene, SceneError};
