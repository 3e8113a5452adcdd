//! Shared data types of augsplat's 3D nodes.
//!
//! Everything that more than one node family needs lives here and nowhere else:
//! [`camera::Camera`] (OpenCV axes, world-to-camera), [`image::ImageF32`] and its file
//! formats (PNG/JPEG in, PNG/EXR/NPY out), the on-disk [`scene::Scene`] artifact that the
//! import node writes and every later stage reads, small fixed-size linear algebra in
//! [`linalg`], the deterministic [`rng::Rng`], [`cputime`] for benchmarks on shared machines,
//! [`bench_record`], the JSON record of one benchmark figure, and [`simd`], the one answer to
//! "which instruction set do the kernels run?".

// Index loops read best in small fixed-size numeric code.
#![allow(clippy::needless_range_loop)]

pub mod artifacts;
pub mod bench_record;
pub mod camera;
pub mod cputime;
pub mod error;
pub mod float16;
pub mod image;
pub mod jpeg_check;
pub mod linalg;
pub mod rng;
pub mod scene;
pub mod simd;
pub mod state;

pub use bench_record::BenchRecord;
pub use camera::Camera;
pub use error::{CoreError, FileError};
pub use image::ImageF32;
pub use rng::Rng;
pub use scene::{PointCloud, Scene, SceneView};
