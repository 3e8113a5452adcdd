//! augsplat-scene: the first stage of every pipeline — scene import, the sparse-view split,
//! depth for supervision, the generated default scene, inspection and export.
//!
//! - [`source`]: readers of COLMAP ([`colmap`]), transforms.json and LLFF sources into one
//!   format-neutral raw scene (original frame, distorted intrinsics, point tracks);
//! - [`intrinsics`]: camera models with distortion, undistortion of points and images,
//!   integer downscaling;
//! - [`import`]: normalisation, near/far bounds and writing the scene artifact
//!   ([`augsplat_core::scene`]);
//! - [`bounds`]: near/far from the cameras alone (where the optical axes converge);
//! - [`ply_points`]: points kept in a PLY beside a capture (nerfstudio's `sparse_pc.ply`);
//! - [`split`]: the paper's sparse-view split;
//! - [`depth`]: DS-NeRF-style sparse depth and dense depth maps;
//! - [`synthetic`]: the exactly ray-traced default scene;
//! - [`triangulate`]: sparse points from the photos and known poses (features, epipolar
//!   matching, tracks, triangulation);
//! - [`export`]: COLMAP text and transforms.json export;
//! - [`inspect`]: the report behind `augsplat inspect`;
//! - [`node`]: the node kinds (`ImportScene`, `SyntheticScene`, `SplitScene`, `SparseDepth`,
//!   `ExportScene`) and [`register`].

pub mod bounds;
pub mod colmap;
pub mod depth;
pub mod error;
pub mod export;
pub mod import;
pub mod inspect;
pub mod intrinsics;
pub mod node;
pub mod ply_points;
pub mod source;
pub mod split;
pub mod synthetic;
pub mod triangulate;

pub use error::SceneError;
pub use node::register;
