//! The LPIPS backbones (AlexNet, VGG16 as in torchvision's `features`) and linear heads.

use super::{Backbone, NORM_EPS};
use crate::gemm::{conv2d_relu, out_size, PackedWeights};
use rayon::prelude::*;

/// A CHW float tensor.
#[derive(Clone, Debug)]
pub struct Tensor {
    /// Channels.
    pub c: usize,
    /// Height.
    pub h: usize,
    /// Width.
    pub w: usize,
    /// `c × h × w` values.
    pub data: Vec<f32>,
}

/// One backbone step.
#[derive(Clone, Debug)]
pub enum Layer {
    /// Convolution followed by ReLU; `index` is the torch `features.{index}` number.
    Conv {
        /// torch `features` index.
        index: usize,
        /// Stride.
        stride: usize,
        /// Zero padding on every side.
        pad: usize,
        /// Packed weights and bias.
        weights: PackedWeights,
    },
    /// Max-pooling (no padding, floor mode).
    MaxPool {
        /// Window size.
        kernel: usize,
        /// Stride.
        stride: usize,
    },
    /// Keep the current activation as an LPIPS tap.
    Tap,
}

/// A backbone with its five linear heads.
#[derive(Clone, Debug)]
pub struct Net {
    /// Which backbone.
    pub backbone: Backbone,
    /// The steps in order.
    pub layers: Vec<Layer>,
    /// Linear head weights, one vector of channel weights per tap.
    pub heads: Vec<Vec<f32>>,
}

/// `(features index, out channels, in channels, kernel, stride, pad)` of every convolution,
/// and where max-pools (`Pool`) and taps (`Tap`) go.
enum Step {
    Conv(usize, usize, usize, usize, usize, usize),
    Pool(usize, usize),
    Tap,
}

fn architecture(backbone: Backbone) -> Vec<Step> {
    use Step::*;
    match backbone {
        Backbone::Alex => vec![
            Conv(0, 64, 3, 11, 4, 2),
            Tap,
            Pool(3, 2),
            Conv(3, 192, 64, 5, 1, 2),
            Tap,
            Pool(3, 2),
            Conv(6, 384, 192, 3, 1, 1),
            Tap,
            Conv(8, 256, 384, 3, 1, 1),
            Tap,
            Conv(10, 256, 256, 3, 1, 1),
            Tap,
        ],
        Backbone::Vgg => vec![
            Conv(0, 64, 3, 3, 1, 1),
            Conv(2, 64, 64, 3, 1, 1),
            Tap,
            Pool(2, 2),
            Conv(5, 128, 64, 3, 1, 1),
            Conv(7, 128, 128, 3, 1, 1),
            Tap,
            Pool(2, 2),
            Conv(10, 256, 128, 3, 1, 1),
            Conv(12, 256, 256, 3, 1, 1),
            Conv(14, 256, 256, 3, 1, 1),
            Tap,
            Pool(2, 2),
            Conv(17, 512, 256, 3, 1, 1),
            Conv(19, 512, 512, 3, 1, 1),
            Conv(21, 512, 512, 3, 1, 1),
            Tap,
            Pool(2, 2),
            Conv(24, 512, 512, 3, 1, 1),
            Conv(26, 512, 512, 3, 1, 1),
            Conv(28, 512, 512, 3, 1, 1),
            Tap,
        ],
    }
}

type Getter<'a> = dyn Fn(&str) -> Result<(Vec<usize>, Vec<f32>), String> + 'a;

impl Net {
    /// Builds the network from a tensor getter (name → shape, values), checking every shape.
    pub fn from_tensors(
        backbone: Backbone,
        get: impl Fn(&str) -> Result<(Vec<usize>, Vec<f32>), String>,
    ) -> Result<Net, String> {
        let get: &Getter<'_> = &get;
        let mut layers = Vec::new();
        let mut tap_channels = Vec::new();
        let mut channels = 3;
        for step in architecture(backbone) {
            match step {
                Step::Conv(index, m, c_in, k, stride, pad) => {
                    let wname = format!("features.{index}.weight");
                    let bname = format!("features.{index}.bias");
                    let (ws, w) = get(&wname)?;
                    let (bs, b) = get(&bname)?;
                    if ws != [m, c_in, k, k] {
                        return Err(format!(
                            "{wname} has shape {ws:?}, {backbone} needs {:?}",
                            [m, c_in, k, k]
                        ));
                    }
                    if bs != [m] {
                        return Err(format!("{bname} has shape {bs:?}, {backbone} needs [{m}]"));
                    }
                    if let Some(bad) = w.iter().chain(&b).find(|v| !v.is_finite()) {
                        return Err(format!("{wname}/{bname} hold a non-finite value {bad}"));
                    }
                    layers.push(Layer::Conv {
                        index,
                        stride,
                        pad,
                        weights: PackedWeights::new(&w, &b, m, c_in, k, k),
                    });
                    channels = m;
                }
                Step::Pool(kernel, stride) => layers.push(Layer::MaxPool { kernel, stride }),
                Step::Tap => {
                    layers.push(Layer::Tap);
                    tap_channels.push(channels);
                }
            }
        }
        let mut heads = Vec::new();
        for (i, &c) in tap_channels.iter().enumerate() {
            let name = format!("lin{i}.model.1.weight");
            let (shape, w) = get(&name)?;
            if shape != [1, c, 1, 1] {
                return Err(format!(
                    "{name} has shape {shape:?}, {backbone} needs [1, {c}, 1, 1]"
                ));
            }
            if let Some(bad) = w.iter().find(|v| !v.is_finite()) {
                return Err(format!("{name} holds a non-finite value {bad}"));
            }
            heads.push(w);
        }
        Ok(Net {
            backbone,
            layers,
            heads,
        })
    }

    /// Checks that an image of `w × h` survives every layer with at least one pixel.
    pub fn check_size(&self, w: usize, h: usize) -> Result<(), String> {
        let (mut cw, mut ch) = (w, h);
        for layer in &self.layers {
            let (k, s, p) = match layer {
                Layer::Conv {
                    weights,
                    stride,
                    pad,
                    ..
                } => (weights.kh, *stride, *pad),
                Layer::MaxPool { kernel, stride } => (*kernel, *stride, 0),
                Layer::Tap => continue,
            };
            match (out_size(cw, k, s, p), out_size(ch, k, s, p)) {
                (Some(a), Some(b)) if a > 0 && b > 0 => (cw, ch) = (a, b),
                _ => {
                    return Err(format!(
                        "image of {w}×{h} pixels is too small for LPIPS-{} (a layer would \
                         get a {cw}×{ch} input)",
                        self.backbone
                    ))
                }
            }
        }
        Ok(())
    }

    /// Runs the backbone; returns the five tapped activations. The input must pass
    /// [`Net::check_size`].
    pub fn features(&self, input: &Tensor) -> Vec<Tensor> {
        let mut taps = Vec::with_capacity(5);
        let mut x = input.clone();
        for layer in &self.layers {
            match layer {
                Layer::Conv {
                    weights,
                    stride,
                    pad,
                    ..
                } => {
                    let (data, h, w) = conv2d_relu(&x.data, x.h, x.w, weights, *stride, *pad);
                    x = Tensor {
                        c: weights.m,
                        h,
                        w,
                        data,
                    };
                }
                Layer::MaxPool { kernel, stride } => x = max_pool(&x, *kernel, *stride),
                Layer::Tap => taps.push(x.clone()),
            }
        }
        taps
    }

    /// The LPIPS distance between two images' taps: per tap, unit-normalise the channel vectors,
    /// square the difference, weight by the head, average over pixels; sum over taps.
    pub fn compare(&self, a: &[Tensor], b: &[Tensor]) -> f64 {
        a.iter()
            .zip(b)
            .zip(&self.heads)
            .map(|((fa, fb), head)| tap_distance(fa, fb, head))
            .sum()
    }
}

const PIXELS_PER_CHUNK: usize = 1024;

/// Spatial mean of `Σ_c w_c (a_c/(‖a‖+ε) − b_c/(‖b‖+ε))²` for one tap.
fn tap_distance(a: &Tensor, b: &Tensor, head: &[f32]) -> f64 {
    let hw = a.h * a.w;
    let chunks: Vec<f64> = (0..hw.div_ceil(PIXELS_PER_CHUNK))
        .into_par_iter()
        .map(|k| {
            let p0 = k * PIXELS_PER_CHUNK;
            let n = PIXELS_PER_CHUNK.min(hw - p0);
            let mut na = vec![0f32; n];
            let mut nb = vec![0f32; n];
            for c in 0..a.c {
                let (ra, rb) = (&a.data[c * hw + p0..][..n], &b.data[c * hw + p0..][..n]);
                for i in 0..n {
                    na[i] += ra[i] * ra[i];
                    nb[i] += rb[i] * rb[i];
                }
            }
            for i in 0..n {
                na[i] = 1.0 / (na[i].sqrt() + NORM_EPS);
                nb[i] = 1.0 / (nb[i].sqrt() + NORM_EPS);
            }
            let mut acc = vec![0f32; n];
            for (c, &wc) in head.iter().enumerate() {
                let (ra, rb) = (&a.data[c * hw + p0..][..n], &b.data[c * hw + p0..][..n]);
                for i in 0..n {
                    let d = ra[i] * na[i] - rb[i] * nb[i];
                    acc[i] += wc * d * d;
                }
            }
            acc.iter().map(|&v| v as f64).sum::<f64>()
        })
        .collect();
    chunks.iter().sum::<f64>() / hw as f64
}

/// Max-pooling without padding, floor mode.
pub fn max_pool(x: &Tensor, kernel: usize, stride: usize) -> Tensor {
    let oh = out_size(x.h, kernel, stride, 0).unwrap_or(0);
    let ow = out_size(x.w, kernel, stride, 0).unwrap_or(0);
    let mut data = vec![0f32; x.c * oh * ow];
    if oh * ow > 0 {
        data.par_chunks_mut(oh * ow)
            .enumerate()
            .for_each(|(c, out)| {
                let plane = &x.data[c * x.h * x.w..(c + 1) * x.h * x.w];
                for oy in 0..oh {
                    for ox in 0..ow {
                        let mut m = f32::NEG_INFINITY;
                        for ky in 0..kernel {
                            let row = &plane[(oy * stride + ky) * x.w + ox * stride..][..kernel];
                            for &v in row {
                                m = m.max(v);
                            }
                        }
                        out[oy * ow + ox] = m;
                    }
                }
            });
    }
    Tensor {
        c: x.c,
        h: oh,
        w: ow,
        data,
    }
}
