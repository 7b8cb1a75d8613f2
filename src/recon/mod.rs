//! The mmNorm reconstruction (paper §2–§4).
//!
//! This module will own everything between a [`crate::capture::Capture`] and a point cloud:
//! imaging, the normal field, masks and components, the RSDF and the isosurface search. It
//! reads captures and never reaches back into acquisition or simulation. So far it holds the
//! image S(v) ([`image`]), the normal field ([`normals`]), the binary-mask threshold ([`threshold`]), 6-connected component
//! labelling ([`components`]) and RSDF integration ([`rsdf`]); the other stages arrive with the reconstruction issue.

pub mod components;
pub mod image;
pub mod normals;
pub mod rsdf;
pub mod threshold;
