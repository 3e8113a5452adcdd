//! The `weights` artifact: `field.safetensors` (parameters and occupancy grid),
//! `config.json` ([`WeightsMeta`]: architecture, contraction, bounds, render background,
//! training health) and `curve.json` (core's `TrainingCurve`).

use crate::error::FieldError;
use crate::field::{Field, FieldConfig};
use crate::occupancy::OccupancyGrid;
use serde::{Deserialize, Serialize};
use std::path::Path;

/// File name of the parameters.
pub const WEIGHTS_FILE: &str = "field.safetensors";
/// File name of the metadata.
pub const CONFIG_FILE: &str = "config.json";

/// Metadata stored beside the parameters.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct WeightsMeta {
    /// Field architecture and scene mapping.
    pub field: FieldConfig,
    /// Background colour renders are composited over.
    pub background: [f32; 3],
    /// Training steps run.
    pub steps: u32,
    /// Steps skipped because their gradients were not finite.
    pub skipped_steps: u32,
    /// Non-finite gradient values discarded.
    pub nonfinite_values: u64,
}

/// A loaded field.
#[derive(Clone, Debug)]
pub struct LoadedField {
    /// Metadata.
    pub meta: WeightsMeta,
    /// Layout.
    pub field: Field,
    /// Parameters.
    pub params: Vec<f32>,
    /// Occupancy grid.
    pub occupancy: OccupancyGrid,
}

fn tensors(field: &Field) -> Vec<(String, std::ops::Range<usize>, Vec<usize>)> {
    let mut out = vec![(
        "grid".to_string(),
        0..field.density_offset,
        vec![field.density_offset],
    )];
    for (name, mlp, base) in [
        ("density", &field.density, field.density_offset),
        ("color", &field.color, field.color_offset),
    ] {
        let mut off = base;
        for (l, s) in mlp.layers.iter().enumerate() {
            out.push((
                format!("{name}.{l}.weight"),
                off..off + s.inp * s.out,
                vec![s.out, s.inp],
            ));
            off += s.inp * s.out;
            out.push((format!("{name}.{l}.bias"), off..off + s.out, vec![s.out]));
            off += s.out;
        }
    }
    let e = field.config.appearance_dim as usize;
    if e > 0 {
        out.push((
            "appearance".to_string(),
            field.embedding_offset..field.n_params,
            vec![field.config.n_images as usize, e],
        ));
    }
    out
}

/// Writes the weights artifact into `dir`.
pub fn save(
    dir: &Path,
    meta: &WeightsMeta,
    field: &Field,
    params: &[f32],
    occ: &OccupancyGrid,
) -> Result<(), FieldError> {
    use safetensors::tensor::{Dtype, TensorView};
    let path = dir.join(WEIGHTS_FILE);
    let werr = |m: String| FieldError::Weights {
        path: path.clone(),
        message: m,
    };
    let list = tensors(field);
    let bytes: Vec<(String, Vec<u8>, Vec<usize>)> = list
        .into_iter()
        .map(|(n, r, s)| {
            (
                n,
                params[r].iter().flat_map(|v| v.to_le_bytes()).collect(),
                s,
            )
        })
        .collect();
    let ema: Vec<u8> = occ.ema.iter().flat_map(|v| v.to_le_bytes()).collect();
    let res = occ.res as usize;
    let mut views = Vec::new();
    for (n, b, s) in &bytes {
        views.push((
            n.clone(),
            TensorView::new(Dtype::F32, s.clone(), b).map_err(|e| werr(e.to_string()))?,
        ));
    }
    views.push((
        "occupancy".into(),
        TensorView::new(Dtype::U8, vec![res, res, res], &occ.occupied)
            .map_err(|e| werr(e.to_string()))?,
    ));
    views.push((
        "occupancy_ema".into(),
        TensorView::new(Dtype::F32, vec![res, res, res], &ema).map_err(|e| werr(e.to_string()))?,
    ));
    let data = safetensors::serialize(views, None).map_err(|e| werr(e.to_string()))?;
    std::fs::write(&path, data)
        .map_err(|e| FieldError::Core(augsplat_core::CoreError::io(&path, e)))?;
    augsplat_core::artifacts::write_json(&dir.join(CONFIG_FILE), meta)?;
    Ok(())
}

/// Reads a weights artifact, checking every tensor against the config.
pub fn load(dir: &Path) -> Result<LoadedField, FieldError> {
    let meta: WeightsMeta = augsplat_core::artifacts::read_json(&dir.join(CONFIG_FILE))?;
    let field = Field::new(meta.field.clone())?;
    let path = dir.join(WEIGHTS_FILE);
    let werr = |m: String| FieldError::Weights {
        path: path.clone(),
        message: m,
    };
    let data = std::fs::read(&path)
        .map_err(|e| FieldError::Core(augsplat_core::CoreError::io(&path, e)))?;
    let st = safetensors::SafeTensors::deserialize(&data)
        .map_err(|e| werr(format!("not a safetensors file: {e}")))?;
    let mut params = vec![0f32; field.n_params];
    for (name, range, shape) in tensors(&field) {
        let t = st
            .tensor(&name)
            .map_err(|e| werr(format!("missing tensor {name}: {e}")))?;
        if t.shape() != shape.as_slice() || t.dtype() != safetensors::Dtype::F32 {
            return Err(werr(format!(
                "tensor {name} has shape {:?} {:?}, expected {shape:?} F32",
                t.shape(),
                t.dtype()
            )));
        }
        for (p, b) in params[range].iter_mut().zip(t.data().chunks_exact(4)) {
            *p = f32::from_le_bytes([b[0], b[1], b[2], b[3]]);
        }
    }
    if params.iter().any(|p| !p.is_finite()) {
        return Err(werr("parameters contain non-finite values".into()));
    }
    let res = field.config.occupancy_resolution as usize;
    let occ_t = st
        .tensor("occupancy")
        .map_err(|e| werr(format!("missing tensor occupancy: {e}")))?;
    let ema_t = st
        .tensor("occupancy_ema")
        .map_err(|e| werr(format!("missing tensor occupancy_ema: {e}")))?;
    if occ_t.shape() != [res, res, res] || ema_t.shape() != [res, res, res] {
        return Err(werr(format!("occupancy grid is not {res}³")));
    }
    let occupancy = OccupancyGrid {
        res: res as u32,
        ema: ema_t
            .data()
            .chunks_exact(4)
            .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
            .collect(),
        occupied: occ_t.data().to_vec(),
    };
    Ok(LoadedField {
        meta,
        field,
        params,
        occupancy,
    })
}
