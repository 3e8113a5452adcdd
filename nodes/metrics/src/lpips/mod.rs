//! LPIPS v0.1 (Zhang et al. 2018) with AlexNet or VGG16 backbones, from safetensors weights.
//!
//! Pipeline for each image (values in [0, 1]): map to [−1, 1], apply the scaling layer
//! `(x − shift) / scale` with shift (−.030, −.088, −.188) and scale (.458, .448, .450), run the
//! backbone and keep five ReLU outputs (AlexNet: after convolutions 0, 3, 6, 8, 10 with 3/2
//! max-pools after the first two and torchvision's stride 4 / padding 2 first layer; VGG16:
//! relu1_2, relu2_2, relu3_3, relu4_3, relu5_3 with 2/2 max-pools). For each tap, unit-normalise
//! every pixel's feature vector (`x / (‖x‖ + 1e-10)`), take the squared difference of the two
//! images, apply the 1×1 linear head, average over the pixels; the distance is the sum over taps.
//!
//! Weights: torch names and OIHW layout, `features.{i}.weight|bias` and
//! `lin{0..4}.model.1.weight` (shape [1, C, 1, 1]), float32 or float16 (upcast to float32 on
//! load). The backbone is recognised from the tensor names. [`find_weights`] locates the files;
//! `augsplat weights import-lpips` makes them. The AlexNet weights ship with the project in
//! float16 ([`bundled_dir`]); VGG16 is an install.

mod net;

use crate::{check_pair, MetricsError};
use augsplat_core::ImageF32;
use std::path::{Path, PathBuf};

pub use net::{Layer, Net};

/// Shift of the LPIPS scaling layer (applied to inputs in [−1, 1]).
pub const SHIFT: [f32; 3] = [-0.030, -0.088, -0.188];
/// Scale of the LPIPS scaling layer.
pub const SCALE: [f32; 3] = [0.458, 0.448, 0.450];
/// Added to the feature norm before dividing.
pub const NORM_EPS: f32 = 1e-10;

/// An LPIPS backbone.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Backbone {
    /// AlexNet (LPIPS default, what AugSplat reports).
    Alex,
    /// VGG16 (what 3DGS papers report).
    Vgg,
}

impl Backbone {
    /// Lower-case name: "alex" or "vgg".
    pub fn name(self) -> &'static str {
        match self {
            Backbone::Alex => "alex",
            Backbone::Vgg => "vgg",
        }
    }
    /// The weight file name this project uses: `lpips_{alex,vgg}_v0.1.safetensors`.
    pub fn file_name(self) -> &'static str {
        match self {
            Backbone::Alex => "lpips_alex_v0.1.safetensors",
            Backbone::Vgg => "lpips_vgg_v0.1.safetensors",
        }
    }
}

impl std::str::FromStr for Backbone {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s.to_ascii_lowercase().as_str() {
            "alex" | "alexnet" => Ok(Backbone::Alex),
            "vgg" | "vgg16" => Ok(Backbone::Vgg),
            other => Err(format!(
                "unknown LPIPS backbone {other:?} (expected alex or vgg)"
            )),
        }
    }
}

impl std::fmt::Display for Backbone {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// A loaded LPIPS model.
#[derive(Clone, Debug)]
pub struct Lpips {
    net: Net,
}

impl Lpips {
    /// Loads a safetensors weight file; the backbone is recognised from its tensor names and
    /// every shape is checked.
    pub fn load(path: &Path) -> Result<Lpips, MetricsError> {
        let bytes = std::fs::read(path).map_err(|e| MetricsError::io(path, e))?;
        Self::from_safetensors(&bytes).map_err(|m| MetricsError::format(path, m))
    }

    /// Builds the model from the bytes of a safetensors file. Tensors may be F32 or F16; F16
    /// values are upcast to f32 exactly.
    pub fn from_safetensors(bytes: &[u8]) -> Result<Lpips, String> {
        let st = safetensors::SafeTensors::deserialize(bytes)
            .map_err(|e| format!("not a safetensors file: {e}"))?;
        let get = |name: &str| -> Result<(Vec<usize>, Vec<f32>), String> {
            let t = st
                .tensor(name)
                .map_err(|_| format!("missing tensor {name:?}"))?;
            let data = match t.dtype() {
                safetensors::Dtype::F32 => t
                    .data()
                    .chunks_exact(4)
                    .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
                    .collect(),
                safetensors::Dtype::F16 => t
                    .data()
                    .chunks_exact(2)
                    .map(|c| crate::float16::to_f32(u16::from_le_bytes([c[0], c[1]])))
                    .collect(),
                other => return Err(format!("tensor {name:?} is {other:?}, expected F32 or F16")),
            };
            Ok((t.shape().to_vec(), data))
        };
        let names: Vec<String> = st.names().into_iter().map(|s| s.to_string()).collect();
        let backbone = if names.iter().any(|n| n == "features.28.weight") {
            Backbone::Vgg
        } else if names.iter().any(|n| n == "features.3.weight") {
            Backbone::Alex
        } else {
            return Err(
                "no LPIPS backbone recognised (expected features.3.weight for AlexNet or \
                 features.28.weight for VGG16)"
                    .into(),
            );
        };
        Ok(Lpips {
            net: Net::from_tensors(backbone, get)?,
        })
    }

    /// The backbone of the loaded weights.
    pub fn backbone(&self) -> Backbone {
        self.net.backbone
    }

    /// The network (layers and heads), for inspection and reference implementations.
    pub fn net(&self) -> &Net {
        &self.net
    }

    /// Whether an image of `w × h` pixels is large enough for the backbone (every layer keeps
    /// at least one pixel; AlexNet needs about 31×31, VGG16 16×16). LPIPS of a smaller image is
    /// undefined: callers report it as unavailable.
    pub fn accepts(&self, w: usize, h: usize) -> bool {
        self.net.check_size(w, h).is_ok()
    }

    /// LPIPS distance between two RGB images with values in [0, 1].
    ///
    /// Errors on mismatched sizes, non-finite values, images that are not 3-channel, or images
    /// too small for the backbone (AlexNet needs about 31×31, VGG16 16×16).
    pub fn distance(&self, a: &ImageF32, b: &ImageF32) -> Result<f64, MetricsError> {
        check_pair(a, b)?;
        if a.channels != 3 {
            return Err(MetricsError::BadImage(format!(
                "LPIPS needs RGB images, got {} channels",
                a.channels
            )));
        }
        self.net
            .check_size(a.width as usize, a.height as usize)
            .map_err(MetricsError::BadImage)?;
        let fa = self.net.features(&scaled_input(a));
        let fb = self.net.features(&scaled_input(b));
        Ok(self.net.compare(&fa, &fb))
    }
}

/// The LPIPS input of an image: CHW, mapped to [−1, 1] and through the scaling layer.
pub fn scaled_input(img: &ImageF32) -> net::Tensor {
    let (w, h) = (img.width as usize, img.height as usize);
    let mut data = vec![0f32; 3 * w * h];
    for c in 0..3 {
        let plane = &mut data[c * w * h..(c + 1) * w * h];
        for (p, v) in plane.iter_mut().enumerate() {
            *v = (img.data[p * 3 + c] * 2.0 - 1.0 - SHIFT[c]) / SCALE[c];
        }
    }
    net::Tensor { c: 3, h, w, data }
}

/// Environment variable naming an LPIPS weight file or a folder holding them.
pub const WEIGHTS_ENV: &str = "AUGSPLAT_LPIPS_WEIGHTS";

/// The default folder for LPIPS weights: `$XDG_DATA_HOME/augsplat/lpips`, else
/// `~/.local/share/augsplat/lpips`; `None` when neither variable is set.
pub fn default_dir() -> Option<PathBuf> {
    if let Some(x) = std::env::var_os("XDG_DATA_HOME").filter(|v| !v.is_empty()) {
        return Some(PathBuf::from(x).join("augsplat").join("lpips"));
    }
    std::env::var_os("HOME")
        .filter(|v| !v.is_empty())
        .map(|h| PathBuf::from(h).join(".local/share/augsplat/lpips"))
}

/// The folder of the weights that ship with the project (`nodes/metrics/weights` of the
/// source tree this binary was built from): `lpips_alex_v0.1.safetensors` in float16 and its
/// `LICENSE.md`. It holds no VGG16 weights.
pub fn bundled_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("weights")
}

/// The shipped weight file of `backbone`, when there is one and it exists (AlexNet only).
pub fn bundled_weights(backbone: Backbone) -> Option<PathBuf> {
    let f = bundled_dir().join(backbone.file_name());
    f.is_file().then_some(f)
}

/// Where weights found without an explicit path come from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum WeightSource {
    /// The file or folder `AUGSPLAT_LPIPS_WEIGHTS` names.
    Env,
    /// The user's [`default_dir`].
    DefaultDir,
    /// The weights shipped with the project ([`bundled_dir`]).
    Bundled,
}

impl std::fmt::Display for WeightSource {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            WeightSource::Env => WEIGHTS_ENV,
            WeightSource::DefaultDir => "the default folder",
            WeightSource::Bundled => "shipped with augsplat, float16",
        })
    }
}

/// Locates the weight file for `backbone` without an explicit path, and says where it was
/// found: `AUGSPLAT_LPIPS_WEIGHTS` (file or folder), then [`default_dir`], then the shipped
/// weights ([`bundled_weights`]).
pub fn locate_weights(backbone: Backbone) -> Option<(PathBuf, WeightSource)> {
    if let Some(v) = std::env::var_os(WEIGHTS_ENV).filter(|v| !v.is_empty()) {
        if let Some(f) = in_path(Path::new(&v), backbone) {
            return Some((f, WeightSource::Env));
        }
    }
    if let Some(f) = default_dir()
        .map(|d| d.join(backbone.file_name()))
        .filter(|f| f.is_file())
    {
        return Some((f, WeightSource::DefaultDir));
    }
    bundled_weights(backbone).map(|f| (f, WeightSource::Bundled))
}

/// `p` itself when it is a file, else the weight file of `backbone` inside folder `p`.
fn in_path(p: &Path, backbone: Backbone) -> Option<PathBuf> {
    if p.is_file() {
        Some(p.to_path_buf())
    } else if p.is_dir() {
        let f = p.join(backbone.file_name());
        f.is_file().then_some(f)
    } else {
        None
    }
}

/// Locates the weight file for `backbone`: first `explicit` (a file, or a folder holding
/// `lpips_{alex,vgg}_v0.1.safetensors`), then `AUGSPLAT_LPIPS_WEIGHTS` (file or folder), then
/// [`default_dir`], then the shipped weights (see [`locate_weights`]). A file given explicitly
/// or by the variable is returned as is (loading checks its backbone). An explicit path that
/// holds nothing gives `None` (it is never replaced by another file); so does a backbone found
/// nowhere.
pub fn find_weights(explicit: Option<&Path>, backbone: Backbone) -> Option<PathBuf> {
    match explicit {
        Some(p) => in_path(p, backbone),
        None => locate_weights(backbone).map(|(f, _)| f),
    }
}
