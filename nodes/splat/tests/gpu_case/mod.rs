//! What the GPU trainer's tests share: a context (or a skip without an adapter), the small
//! generated case trained on both devices, short training arguments and a runner.
#![allow(dead_code)]

use crate::train_util;
use augsplat_core::Scene;
use augsplat_splat::densify::DensifyArgs;
use augsplat_splat::gpu::{GpuContext, GpuError};
use augsplat_splat::train::{
    scene_scale, RealImages, RealLoss, RealView, Schedule, StepReport, Supervision, SynthView,
    SyntheticImages, TrainArgs, Trainer,
};
use augsplat_splat::{init, loss::WeightNorm, Gaussians};
use std::path::Path;
use std::sync::Arc;

pub fn context(test: &str) -> Option<Arc<GpuContext>> {
    match GpuContext::new() {
        Ok(c) => {
            eprintln!("{test}: on {}", c.adapter());
            Some(Arc::new(c))
        }
        Err(e @ GpuError::NoAdapter { .. }) => {
            augsplat_testkit::skip(test, &e.to_string());
            None
        }
        Err(e) => panic!("{test}: {e}"),
    }
}

pub struct Case {
    pub real: RealImages,
    pub synth: SyntheticImages,
    pub init: Gaussians,
    pub scale: f64,
}

pub fn case(root: &Path) -> Case {
    case_of(root, 1, 400)
}

/// The generated case with SH of `degree`, from `points` SfM points.
pub fn case_of(root: &Path, degree: u32, points: u32) -> Case {
    let (train, _) = train_util::make_scene(root, 48, 40, 9, points);
    let scene = Scene::load(&train).unwrap();
    let views: Vec<RealView> = (0..scene.views.len())
        .map(|i| RealView {
            name: scene.views[i].name.clone(),
            camera: scene.views[i].camera.clone(),
            image: scene.load_image(&train, i).unwrap().data,
        })
        .collect();
    let cams: Vec<_> = views.iter().map(|v| &v.camera).collect();
    let scale = scene_scale(&cams);
    let cloud = scene.load_points(&train).unwrap();
    let mut init = init::from_points(&cloud, degree, &Default::default(), scale, 1);
    // Anisotropic, so that the quaternions' gradients are not rounding noise around zero
    // (Adam would turn noise into full steps of either sign on both backends).
    for (i, s) in init.log_scales.iter_mut().enumerate() {
        s[i % 3] += 0.7;
    }
    let synth = SyntheticImages {
        views: views
            .iter()
            .map(|v| {
                let cam = v.camera.resized(24, 20);
                let img =
                    augsplat_core::ImageF32::from_vec(48, 40, 3, v.image.clone()).downscale(2);
                let w: Vec<f32> = (0..24 * 20).map(|p| 0.25 + (p % 7) as f32 / 8.0).collect();
                SynthView::new(v.name.clone(), cam, img.data, w, 0.0)
            })
            .collect(),
        norm: WeightNorm::WeightSum,
    };
    Case {
        real: RealImages {
            views,
            loss: RealLoss::default(),
        },
        synth,
        init,
        scale,
    }
}

pub fn args(steps: u64, densify: bool) -> TrainArgs {
    TrainArgs {
        steps,
        sh_degree: 1,
        sh_increase_every: 3,
        densify: DensifyArgs {
            enabled: densify,
            start: 2,
            every: 3,
            reset_every: 0,
            scale_with_steps: false,
            grad_threshold: 2e-5,
            ..Default::default()
        },
        ..Default::default()
    }
}

/// Dual for a few steps: its synthetic branch off from step 5 (w̃ = 2·4^(−t/4) < 0.5).
pub fn short_dual() -> Schedule {
    Schedule::Dual {
        w_nerf0: 2.0,
        w_real: 1.0,
        quarter_decay: 4.0,
        off_below: Some(0.5),
        synthetic_batch: 3,
        reset_at_off: false,
    }
}

/// Runs `steps` steps (on the GPU when given) and returns the reports and the Gaussians.
pub fn train(
    c: &Case,
    args: &TrainArgs,
    synthetic: bool,
    gpu: Option<&Arc<GpuContext>>,
) -> (Vec<StepReport>, Gaussians) {
    let synth = synthetic.then_some(&c.synth as &dyn Supervision);
    let mut t = Trainer::new(args.clone(), c.init.clone(), c.scale, &c.real, synth);
    if let Some(g) = gpu {
        t.on_device(&augsplat_splat::Device::gpu(g.clone()));
    }
    let reps = (0..args.steps).map(|_| t.step()).collect();
    (reps, t.into_gaussians())
}
