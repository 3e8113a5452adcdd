//! Sources of supervision for the [`crate::train::Trainer`]: the [`Supervision`] trait, real
//! images with the photometric loss ([`RealImages`]) and synthetic views with the
//! confidence-weighted L2 ([`SyntheticImages`]).

use crate::loss;
use crate::loss::WeightNorm;
use crate::train::RealLoss;
use augsplat_core::Camera;

/// A source of supervision: views with cameras and a loss on the rendered colour.
pub trait Supervision: Send + Sync {
    /// Number of views.
    fn len(&self) -> usize;
    /// Whether there are no views.
    fn is_empty(&self) -> bool {
        self.len() == 0
    }
    /// The camera of view `i` (its resolution is the render resolution).
    fn camera(&self, i: usize) -> &Camera;
    /// Pixels to render (non-zero) for view `i`; `None` renders all.
    fn mask(&self, _i: usize) -> Option<&[u8]> {
        None
    }
    /// Whether view `i` has anything to supervise (e.g. a non-zero weight sum).
    fn usable(&self, _i: usize) -> bool {
        true
    }
    /// The loss of view `i` for rendered colour `rgb` (`H·W·3`); adds `scale · dL/d(rgb)`
    /// into `grad`.
    fn loss(&self, i: usize, rgb: &[f32], scale: f32, grad: &mut [f32]) -> f64;
    /// The same loss as [`Supervision::loss`], described for the GPU's loss kernels: the
    /// view's target colour, its per-pixel weights and the loss. `None` (the default, for
    /// sources the GPU kernels do not cover) computes the loss on the host when training on
    /// the GPU: the render is read back and the colour gradient sent up.
    fn gpu_loss(&self, _i: usize) -> Option<GpuLossView<'_>> {
        None
    }
}

/// One view's loss for the GPU (see [`Supervision::gpu_loss`]).
#[derive(Clone, Copy, Debug)]
pub struct GpuLossView<'a> {
    /// Target colour, `H·W·3`.
    pub target: &'a [f32],
    /// Per-pixel weights, `H·W` (the weighted L2).
    pub weights: Option<&'a [f32]>,
    /// The loss.
    pub loss: crate::gpu::GpuLoss,
}

/// One real training image.
#[derive(Clone, Debug)]
pub struct RealView {
    /// Name, for logs.
    pub name: String,
    /// Camera (its size equals the image size).
    pub camera: Camera,
    /// Interleaved RGB, `H·W·3`.
    pub image: Vec<f32>,
}

impl RealView {
    /// The view as [`crate::init::initial_gaussians`] reads it.
    pub fn init_view(&self) -> crate::init::InitView<'_> {
        crate::init::InitView {
            camera: &self.camera,
            image: &self.image,
        }
    }
}

/// Real images with the `(1 − λ)·P + λ·(1 − SSIM)` loss.
#[derive(Clone, Debug)]
pub struct RealImages {
    /// The views.
    pub views: Vec<RealView>,
    /// The loss.
    pub loss: RealLoss,
}

impl Supervision for RealImages {
    fn len(&self) -> usize {
        self.views.len()
    }
    fn camera(&self, i: usize) -> &Camera {
        &self.views[i].camera
    }
    fn loss(&self, i: usize, rgb: &[f32], scale: f32, grad: &mut [f32]) -> f64 {
        let v = &self.views[i];
        let (w, h) = (v.camera.width as usize, v.camera.height as usize);
        loss::photometric(
            rgb,
            &v.image,
            w,
            h,
            self.loss.kind,
            self.loss.ssim_lambda as f32,
            scale,
            grad,
        )
        .0
    }
    fn gpu_loss(&self, i: usize) -> Option<GpuLossView<'_>> {
        Some(GpuLossView {
            target: &self.views[i].image,
            weights: None,
            loss: crate::gpu::GpuLoss::Photometric {
                kind: self.loss.kind,
                ssim_lambda: self.loss.ssim_lambda as f32,
            },
        })
    }
}

/// One synthetic supervision view.
#[derive(Clone, Debug)]
pub struct SynthView {
    /// Name, for logs.
    pub name: String,
    /// Camera at the synthetic resolution.
    pub camera: Camera,
    /// Target colour (ensemble median), `H·W·3`.
    pub target: Vec<f32>,
    /// Confidence weights, `H·W` (already zeroed where masked out).
    pub weight: Vec<f32>,
    /// Render mask (1 = render) when pixels are skipped.
    pub mask: Option<Vec<u8>>,
    /// Sum of the (masked) weights.
    pub weight_sum: f64,
}

impl SynthView {
    /// Builds a view, applying `skip_below`: pixels with weight < `skip_below` get weight 0
    /// and, when `skip_below > 0`, are masked out of rendering. Non-finite weights become 0.
    pub fn new(
        name: String,
        camera: Camera,
        target: Vec<f32>,
        mut weight: Vec<f32>,
        skip_below: f64,
    ) -> Self {
        for w in &mut weight {
            if !w.is_finite() || (*w as f64) < skip_below || *w < 0.0 {
                *w = 0.0;
            }
        }
        let mask = (skip_below > 0.0).then(|| weight.iter().map(|&w| (w > 0.0) as u8).collect());
        let weight_sum = weight.iter().map(|&w| w as f64).sum();
        SynthView {
            name,
            camera,
            target,
            weight,
            mask,
            weight_sum,
        }
    }
}

/// Synthetic views with the confidence-weighted L2 loss.
#[derive(Clone, Debug)]
pub struct SyntheticImages {
    /// The views.
    pub views: Vec<SynthView>,
    /// Normalisation of the weighted L2.
    pub norm: WeightNorm,
}

impl Supervision for SyntheticImages {
    fn len(&self) -> usize {
        self.views.len()
    }
    fn camera(&self, i: usize) -> &Camera {
        &self.views[i].camera
    }
    fn mask(&self, i: usize) -> Option<&[u8]> {
        self.views[i].mask.as_deref()
    }
    fn usable(&self, i: usize) -> bool {
        self.views[i].weight_sum > 0.0
    }
    fn loss(&self, i: usize, rgb: &[f32], scale: f32, grad: &mut [f32]) -> f64 {
        let v = &self.views[i];
        loss::weighted_l2(rgb, &v.target, &v.weight, self.norm, scale, grad)
    }
    fn gpu_loss(&self, i: usize) -> Option<GpuLossView<'_>> {
        let v = &self.views[i];
        Some(GpuLossView {
            target: &v.target,
            weights: Some(&v.weight),
            loss: crate::gpu::GpuLoss::weighted_l2(self.norm, &v.weight),
        })
    }
}
