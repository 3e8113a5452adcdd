//! augsplat-scene: the first stage of every pipeline.
//!
//! - [`source`]: readers of COLMAP ([`colmap`]), transforms.json and LLFF sources into one
//!   format-neutral raw scene;
//! - [`intrinsics`]: camera models with distortion, undistortion of points and images,
//!   integer downscaling;
//! - [`import`]: normalisation, near/far bounds and writing the scene artifact;

pub mod colmap;
pub mod error;
pub mod import;
pub mod intrinsics;
pub mod source;

pub use error::SceneError;
pub mod depth;
pub mod split;
pub mod synthetic;
