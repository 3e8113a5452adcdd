//! The training step on the GPU (state kept there between steps: Adam, the per-view sums and
//! the densification statistics in WGSL) against the CPU trainer on a small generated scene:
//! the same losses step by step (on lavapipe within 5e-7 relative; asserted within 1e-4),
//! every parameter within a small fraction of an Adam step, the same densification, Dual's
//! synthetic batches, the losses on the GPU (`loss/loss.wgsl`) and on the host, selective
//! Adam, checkpoints taken mid-run, identical bytes on every run, and a 50-step Dual run
//! written once and run through both devices of the seam. Skips with a message when no GPU
//! adapter is found (fails under `CI=true`, where `.ci/run` installs lavapipe).

mod train_util;

use augsplat_core::Scene;
use augsplat_splat::adam::AdamUpdates;
use augsplat_splat::densify::{self, DensifyArgs, OpacityReset};
use augsplat_splat::gpu::{GpuContext, GpuError};
use augsplat_splat::train::{
    scene_scale, RealImages, RealLoss, RealView, Schedule, StepReport, Supervision, SynthView,
    SyntheticImages, TrainArgs, Trainer,
};
use augsplat_splat::{init, loss::WeightNorm, Gaussians};
use std::path::Path;
use std::sync::Arc;

fn context(test: &str) -> Option<Arc<GpuContext>> {
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

struct Case {
    real: RealImages,
    synth: SyntheticImages,
    init: Gaussians,
    scale: f64,
}

fn case(root: &Path) -> Case {
    case_of(root, 1, 400)
}

/// The generated case with SH of `degree`, from `points` SfM points.
fn case_of(root: &Path, degree: u32, points: u32) -> Case {
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

fn args(steps: u64, densify: bool) -> TrainArgs {
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
fn short_dual() -> Schedule {
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
fn train(
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

/// Real images whose loss only the host computes (no `gpu_loss`).
struct HostLoss<'a>(&'a RealImages);

impl Supervision for HostLoss<'_> {
    fn len(&self) -> usize {
        self.0.len()
    }
    fn camera(&self, i: usize) -> &augsplat_core::Camera {
        self.0.camera(i)
    }
    fn loss(&self, i: usize, rgb: &[f32], scale: f32, grad: &mut [f32]) -> f64 {
        self.0.loss(i, rgb, scale, grad)
    }
}

use train_util::param_bits as bits;

/// The losses of two runs agree step by step within `tol` relative.
fn same_losses(cpu: &[StepReport], gpu: &[StepReport], tol: f64, what: &str) {
    assert_eq!(cpu.len(), gpu.len());
    let mut worst = 0.0f64;
    for (a, b) in cpu.iter().zip(gpu) {
        assert_eq!(a.step, b.step);
        assert_eq!(a.real_loss.is_some(), b.real_loss.is_some(), "{what}");
        assert_eq!(
            a.synthetic_loss.is_some(),
            b.synthetic_loss.is_some(),
            "{what}"
        );
        // The composited pairs, counted on the GPU by block sums: the CPU's count, up to the
        // rare α-cutoff flip (a pair or two per render).
        let dp = a.pairs.abs_diff(b.pairs);
        assert!(
            a.pairs > 0 && dp <= 2 + a.pairs / 10_000,
            "{what}, step {}: CPU pairs {} GPU pairs {}",
            a.step,
            a.pairs,
            b.pairs
        );
        let rel = (a.loss - b.loss).abs() / a.loss.abs().max(1e-12);
        worst = worst.max(rel);
        assert!(
            rel <= tol,
            "{what}, step {}: CPU loss {} GPU loss {} ({rel:.2e} relative)",
            a.step,
            a.loss,
            b.loss
        );
    }
    eprintln!("{what}: losses agree within {worst:.2e} relative");
}

/// Each parameter's difference between two sets of equal size, in units of its group's
/// Adam step (the learning rates of `TrainArgs::default()`).
fn param_gaps(a: &Gaussians, b: &Gaussians, scale: f64) -> Vec<f64> {
    assert_eq!(a.len(), b.len());
    let lr = augsplat_splat::adam::LearningRates::default();
    let gap = |x: &[f32], y: &[f32], step: f64| -> Vec<f64> {
        x.iter()
            .zip(y)
            .map(|(p, q)| (f64::from(*p) - f64::from(*q)).abs() / step)
            .collect()
    };
    [
        gap(
            a.means.as_flattened(),
            b.means.as_flattened(),
            lr.means * scale,
        ),
        gap(
            a.log_scales.as_flattened(),
            b.log_scales.as_flattened(),
            lr.scales,
        ),
        gap(a.quats.as_flattened(), b.quats.as_flattened(), lr.quats),
        gap(&a.opacity_logits, &b.opacity_logits, lr.opacities),
        gap(&a.sh, &b.sh, lr.shn),
    ]
    .concat()
}

#[test]
fn gpu_training_follows_the_cpu_and_repeats_bit_for_bit() {
    let test = "gpu_training_follows_the_cpu_and_repeats_bit_for_bit";
    let Some(gpu) = context(test) else { return };
    let tmp = tempfile::tempdir().unwrap();
    let c = case(tmp.path());

    // Without densification the two backends hold the same set: the losses agree step by
    // step and every parameter within a few of Adam's steps (a gradient within rounding of
    // zero can flip the sign of one update).
    let a = args(6, false);
    let (cpu_reps, cpu_g) = train(&c, &a, false, None);
    let (gpu_reps, gpu_g) = train(&c, &a, false, Some(&gpu));
    same_losses(&cpu_reps, &gpu_reps, 1e-4, "baseline, 6 steps");
    let gaps = param_gaps(&cpu_g, &gpu_g, c.scale);
    let worst = gaps.iter().copied().fold(0.0, f64::max);
    let close = gaps.iter().filter(|&&g| g <= 0.01).count();
    eprintln!(
        "baseline, 6 steps: largest parameter gap {worst:.3} Adam steps; {close} of {} within 0.01",
        gaps.len()
    );
    assert!(worst < 4.0, "parameters {worst} Adam steps apart");
    {
        let n = cpu_g.len();
        let k = cpu_g.sh.len() / n;
        let mut off = 0;
        for (name, w) in [
            ("means", 3),
            ("scales", 3),
            ("quats", 4),
            ("opacity", 1),
            ("sh", k),
        ] {
            let g = &gaps[off..off + w * n];
            off += w * n;
            eprintln!(
                "{name}: {} of {} within 0.01, max {:.3}",
                g.iter().filter(|&&x| x <= 0.01).count(),
                g.len(),
                g.iter().copied().fold(0.0, f64::max)
            );
        }
    }
    // Most parameters agree far closer than one step.
    assert!(
        close as f64 >= 0.98 * gaps.len() as f64,
        "only {close} of {} parameters within 0.01 Adam steps",
        gaps.len()
    );

    // With densification (the state goes back to the host at each refinement and up again)
    // and Dual's synthetic batches: the same losses and the same refinements.
    let mut a = args(8, true);
    a.schedule = short_dual();
    let (cpu_reps, cpu_g) = train(&c, &a, true, None);
    let (gpu_reps, gpu_g) = train(&c, &a, true, Some(&gpu));
    same_losses(
        &cpu_reps,
        &gpu_reps,
        1e-4,
        "Dual with densification, 8 steps",
    );
    let refine = |r: &[StepReport]| {
        r.iter()
            .map(|s| (s.refine, s.gaussians))
            .collect::<Vec<_>>()
    };
    assert_eq!(refine(&cpu_reps), refine(&gpu_reps));
    assert!(
        cpu_reps
            .iter()
            .any(|r| r.refine.cloned + r.refine.split > 0),
        "the case must densify: {:?}",
        refine(&cpu_reps)
    );
    assert_eq!(cpu_g.len(), gpu_g.len());

    // The same with statistics from the synthetic views too, each divided by its loss
    // weight: the factor the GPU's statistics kernel receives must match the CPU's.
    let mut u = a.clone();
    u.synthetic.densify_from_synthetic = true;
    u.synthetic.unweighted_stats = true;
    let (cpu_u, _) = train(&c, &u, true, None);
    let (gpu_u, _) = train(&c, &u, true, Some(&gpu));
    same_losses(&cpu_u, &gpu_u, 1e-4, "Dual, unweighted statistics, 8 steps");
    assert_eq!(refine(&cpu_u), refine(&gpu_u));
    assert_ne!(
        refine(&cpu_u),
        refine(&cpu_reps),
        "unweighted statistics must change what densifies"
    );

    // Two GPU runs: identical bytes.
    let (again_reps, again_g) = train(&c, &a, true, Some(&gpu));
    assert_eq!(bits(&gpu_g), bits(&again_g), "two GPU runs differ");
    let losses = |r: &[StepReport]| r.iter().map(|s| s.loss.to_bits()).collect::<Vec<_>>();
    assert_eq!(losses(&gpu_reps), losses(&again_reps));

    // A supervision source the GPU's loss kernels do not cover: its loss runs on the host
    // (the render read back, the colour gradient sent up), with the same result.
    let a = args(6, false);
    let host = HostLoss(&c.real);
    let mut t = Trainer::new(a.clone(), c.init.clone(), c.scale, &host, None);
    t.on_device(&augsplat_splat::Device::gpu(gpu.clone()));
    let host_reps: Vec<StepReport> = (0..a.steps).map(|_| t.step()).collect();
    let (cpu_reps, _) = train(&c, &a, false, None);
    same_losses(&cpu_reps, &host_reps, 1e-4, "host loss, 6 steps");

    // Selective Adam (only the step's visible Gaussians move) on the GPU too.
    let mut a = args(5, false);
    a.adam = AdamUpdates::Selective;
    let (cpu_reps, _) = train(&c, &a, false, None);
    let (gpu_reps, _) = train(&c, &a, false, Some(&gpu));
    same_losses(&cpu_reps, &gpu_reps, 1e-4, "selective Adam, 5 steps");
}

#[test]
fn a_gpu_run_resumes_from_a_checkpoint_as_if_uninterrupted() {
    let test = "a_gpu_run_resumes_from_a_checkpoint_as_if_uninterrupted";
    let Some(gpu) = context(test) else { return };
    let tmp = tempfile::tempdir().unwrap();
    let c = case(tmp.path());
    let a = args(7, true);
    let (_, whole) = train(&c, &a, false, Some(&gpu));
    // Four steps, a checkpoint (the state comes back from the GPU), a fresh trainer restored
    // from it, three more steps.
    let mut t = Trainer::new(a.clone(), c.init.clone(), c.scale, &c.real, None);
    t.on_device(&augsplat_splat::Device::gpu(gpu.clone()));
    for _ in 0..4 {
        t.step();
    }
    let mut w = augsplat_core::state::StateWriter::new();
    t.write_state(&mut w);
    // Stepping on after the checkpoint is unaffected by having taken it.
    for _ in 4..7 {
        t.step();
    }
    assert_eq!(bits(&t.into_gaussians()), bits(&whole));
    let bytes = w.finish();
    let mut r = augsplat_core::state::StateReader::new(&bytes);
    let mut resumed = Trainer::new(a.clone(), c.init.clone(), c.scale, &c.real, None);
    resumed.on_device(&augsplat_splat::Device::gpu(gpu.clone()));
    resumed.restore_state(&mut r).unwrap();
    for _ in 4..7 {
        resumed.step();
    }
    assert_eq!(bits(&resumed.into_gaussians()), bits(&whole));
}

/// Arrays larger than one storage binding give the same bytes as whole ones, under a binding
/// cap lowered to 92 KiB: per-Gaussian arrays that kernels touch only at their own Gaussian
/// (the degree-3 SH coefficients, their gradients and Adam moments, 192 bytes per Gaussian:
/// five chunks) run in chunks — projection, its VJP, the per-view sums and Adam each bind
/// their own range — and buffers read or written at any index are bound as consecutive
/// ranges (the splats and the screen-space gradients two, the backward's pair slots up to
/// four). A cap below what those bindings hold is a clear error naming the buffer.
#[test]
fn arrays_past_one_binding_run_in_chunks_with_the_same_bytes() {
    let Some(gpu) = context("arrays_past_one_binding_run_in_chunks_with_the_same_bytes") else {
        return;
    };
    let cap = 92 * 1024;
    let capped = Arc::new(GpuContext::new().unwrap().with_binding_limit(cap));
    let tmp = tempfile::tempdir().unwrap();
    let mut c = case_of(tmp.path(), 3, 2500);
    // Small Gaussians, so that the pair slots (40 bytes per pair) fit two bindings.
    for s in c.init.log_scales.iter_mut().flatten() {
        *s -= 1.5;
    }
    let sh_bytes = 4 * c.init.sh.len() as u64;
    let n0 = c.init.len() as u64;
    assert!(
        sh_bytes > 4 * cap,
        "the SH array ({sh_bytes} bytes) must need five chunks"
    );
    // The splats (48 bytes per Gaussian) and the screen-space gradients (40) are read or
    // written at any index: each needs its two bindings from the first step on.
    assert!(40 * n0 > cap && 48 * n0 <= 2 * cap, "{n0} Gaussians");
    let mut a = args(8, true);
    // Densify, but not past what the splats (48 bytes per Gaussian) fit in the cap.
    a.densify.grad_threshold = 1e-3;
    a.sh_degree = 3;
    a.sh_increase_every = 2;
    a.schedule = short_dual();
    let (whole_reps, whole_g) = train(&c, &a, true, Some(&gpu));
    let (chunked_reps, chunked_g) = train(&c, &a, true, Some(&capped));
    let losses = |r: &[StepReport]| r.iter().map(|s| s.loss.to_bits()).collect::<Vec<_>>();
    assert_eq!(losses(&whole_reps), losses(&chunked_reps));
    assert_eq!(
        bits(&whole_g),
        bits(&chunked_g),
        "chunking changed the result"
    );
    assert!(whole_g.len() > c.init.len(), "the run must densify");

    let settings = a.render_settings(a.steps);
    // The pair slots in three or four bindings: larger Gaussians (several tiles each) and a
    // cap set from the pair count, with the backward alone (gradients bit for bit).
    let mut big = c.init.clone();
    for s in big.log_scales.iter_mut().flatten() {
        *s += 3.0;
    }
    let cam = c.real.camera(0);
    let d_rgb: Vec<f32> = (0..3 * cam.width * cam.height)
        .map(|i| ((i % 17) as f32 - 8.0) * 1e-3)
        .collect();
    let backward = |ctx: &GpuContext| {
        let scene = augsplat_splat::gpu::GpuScene::upload(ctx, &big).unwrap();
        augsplat_splat::gpu::backward_gpu_timed(ctx, &scene, cam, &settings, &d_rgb, false).unwrap()
    };
    let (whole_grads, stage) = backward(&gpu);
    let pair_bytes = 40 * u64::from(stage.pairs);
    let cap3 = (pair_bytes * 2 / 7).next_multiple_of(1024);
    assert!(
        pair_bytes > 2 * cap3 && 48 * big.len() as u64 <= 2 * cap3 && cap3 >= 91_200,
        "{} pairs of {} Gaussians do not make a three-binding case",
        stage.pairs,
        big.len()
    );
    let capped3 = GpuContext::new().unwrap().with_binding_limit(cap3);
    let (split_grads, _) = backward(&capped3);
    let fbits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
    assert_eq!(fbits(&whole_grads.params), fbits(&split_grads.params));
    assert_eq!(fbits(&whole_grads.sh), fbits(&split_grads.sh));

    // Two 4 KiB bindings cannot hold the screen-space splats (48 bytes per Gaussian, read at
    // any index).
    let tiny = GpuContext::new().unwrap().with_binding_limit(4096);
    match augsplat_splat::gpu::render_gpu(&tiny, &c.init, c.real.camera(0), &settings) {
        Err(GpuError::TooLarge {
            what, bytes, limit, ..
        }) => {
            assert_eq!(what, "splats (2 bindings)");
            assert_eq!(bytes, 48 * c.init.len() as u64);
            assert_eq!(limit, 2 * 4096);
        }
        other => panic!(
            "expected a TooLarge error, got {:?}",
            other.map(|f| f.width)
        ),
    }
}

#[test]
fn a_50_step_dual_run_is_one_loop_over_either_device() {
    let test = "a_50_step_dual_run_is_one_loop_over_either_device";
    let Some(gpu) = context(test) else { return };
    let tmp = tempfile::tempdir().unwrap();
    let c = case(tmp.path());
    // Dual with densification (a refinement every 10 steps), its branch switched off at step 21 (w̃ = 2·4^(−t/20) < 0.5)
    // with the opacity reset there (on the device, as every refinement).
    let mut a = args(50, true);
    a.densify.every = 10;
    a.densify.grad_threshold = 1e-4;
    a.schedule = Schedule::Dual {
        w_nerf0: 2.0,
        w_real: 1.0,
        quarter_decay: 20.0,
        off_below: Some(0.5),
        synthetic_batch: 3,
        reset_at_off: true,
    };
    // The same code for both devices: only the device differs.
    let runs: Vec<(Vec<StepReport>, Gaussians)> = [
        augsplat_splat::Device::cpu(),
        augsplat_splat::Device::gpu(gpu),
    ]
    .iter()
    .map(|device| {
        let mut t = Trainer::new(a.clone(), c.init.clone(), c.scale, &c.real, Some(&c.synth));
        t.on_device(device);
        let reps = (0..a.steps).map(|_| t.step()).collect();
        (reps, t.into_gaussians())
    })
    .collect();
    let ((cpu, cpu_g), (gpu_reps, gpu_g)) = (&runs[0], &runs[1]);
    let branch = |r: &[StepReport]| {
        r.iter()
            .map(|s| (s.real_loss.is_some(), s.synthetic_loss.is_some()))
            .collect::<Vec<_>>()
    };
    assert_eq!(branch(cpu), branch(gpu_reps), "the schedule differs");
    assert_eq!(
        cpu.iter().position(|s| s.synthetic_loss.is_none()),
        Some(21),
        "Dual's branch must switch off at step 21"
    );
    assert!(
        cpu.iter().any(|r| r.refine.cloned + r.refine.split > 0),
        "the case must densify"
    );
    // The same refinements at the same steps, and the losses step by step.
    let refine = |r: &[StepReport]| {
        r.iter()
            .map(|s| (s.refine, s.gaussians))
            .collect::<Vec<_>>()
    };
    assert_eq!(refine(cpu), refine(gpu_reps));
    let mut worst = 0.0f64;
    for (x, y) in cpu.iter().zip(gpu_reps) {
        let rel = (x.loss - y.loss).abs() / x.loss.abs().max(1e-12);
        worst = worst.max(rel);
        assert!(
            rel <= 1e-3,
            "step {}: CPU loss {} GPU loss {}",
            x.step,
            x.loss,
            y.loss
        );
    }
    eprintln!(
        "{test}: losses within {worst:.2e} relative; {} Gaussians",
        cpu_g.len()
    );
    assert_eq!(cpu_g.len(), gpu_g.len());
}

#[test]
fn pixel_masks_train_on_the_gpu_as_on_the_cpu() {
    let test = "pixel_masks_train_on_the_gpu_as_on_the_cpu";
    let Some(gpu) = context(test) else { return };
    let tmp = tempfile::tempdir().unwrap();
    let mut c = case(tmp.path());
    // skip_below 0.5: the synthetic pixels of weight 0.25–0.375 are neither rendered nor
    // back-propagated (about a third of them).
    c.synth.views = c
        .synth
        .views
        .iter()
        .map(|v| {
            SynthView::new(
                v.name.clone(),
                v.camera.clone(),
                v.target.clone(),
                v.weight.clone(),
                0.5,
            )
        })
        .collect();
    let masked = c.synth.views[0].mask.as_ref().unwrap();
    let off = masked.iter().filter(|&&m| m == 0).count();
    assert!(off * 4 > masked.len() && off * 2 < masked.len(), "{off}");
    let mut a = args(12, false);
    a.schedule = short_dual();
    a.synthetic.skip_below = 0.5;
    assert!(
        TrainArgs {
            backend: augsplat_splat::Backend::Gpu,
            ..a.clone()
        }
        .validate()
        .is_ok(),
        "masks are allowed on the GPU"
    );
    let (cpu, cpu_g) = train(&c, &a, true, None);
    let (gpu_reps, gpu_g) = train(&c, &a, true, Some(&gpu));
    let (again, again_g) = train(&c, &a, true, Some(&gpu));
    assert_eq!(gpu_reps, again, "the same bytes run to run");
    assert!(bits(&gpu_g) == bits(&again_g));
    assert!(cpu.iter().any(|r| r.synthetic_loss.is_some()));
    same_losses(&cpu, &gpu_reps, 1e-4, test);
    // The composited pairs leave out the masked pixels on both devices.
    for (x, y) in cpu.iter().zip(&gpu_reps) {
        assert_eq!(x.pairs, y.pairs, "step {}", x.step);
    }
    let gaps = param_gaps(&cpu_g, &gpu_g, c.scale);
    eprintln!(
        "{test}: largest parameter gap {:.2e}",
        gaps.iter().fold(0.0f64, |m, v| m.max(*v))
    );
    // Without the mask the run differs (the masked pixels really were left out).
    let mut plain = a.clone();
    plain.synthetic.skip_below = 0.0;
    let unmasked = {
        let mut c2 = case(&tmp.path().join("b"));
        c2.synth.views = c
            .synth
            .views
            .iter()
            .map(|v| SynthView {
                mask: None,
                ..v.clone()
            })
            .collect();
        train(&c2, &plain, true, Some(&gpu)).0
    };
    assert_ne!(
        unmasked.iter().map(|r| r.pairs).sum::<u64>(),
        gpu_reps.iter().map(|r| r.pairs).sum::<u64>()
    );
}

#[test]
fn a_step_waits_once_and_submits_once() {
    let test = "a_step_waits_once_and_submits_once";
    let Some(gpu) = context(test) else { return };
    let tmp = tempfile::tempdir().unwrap();
    let c = case(tmp.path());
    // Dual with a batch of 3 for 5 steps, then the real view alone, with the opacity reset
    // at the switch (on the device: no wait); no refinement. The 9 real views each come
    // once per epoch.
    let mut a = args(24, false);
    a.schedule = short_dual();
    if let Schedule::Dual { reset_at_off, .. } = &mut a.schedule {
        *reset_at_off = true;
    }
    let synth = Some(&c.synth as &dyn Supervision);
    let mut t = Trainer::new(a.clone(), c.init.clone(), c.scale, &c.real, synth);
    t.on_device(&augsplat_splat::Device::gpu(gpu.clone()));
    let mut per_step = Vec::new();
    let mut submissions = Vec::new();
    for _ in 0..a.steps {
        let before = gpu.host_waits();
        let submitted = gpu.submissions();
        let r = t.step();
        let views = 1 + if r.synthetic_loss.is_some() { 3 } else { 0 };
        per_step.push((views, gpu.host_waits() - before));
        submissions.push(gpu.submissions() - submitted);
    }
    eprintln!("{test}: (views, waits) per step {per_step:?}, submissions {submissions:?}");
    // A step waits once, for every view's loss and counts together. Only the first view of
    // each size counts its pairs first (one more wait): a view's pass is sized from its last
    // count, or from the largest count of a view of its size. The upload and Adam do not
    // wait.
    let size = |src: &dyn Supervision| (src.camera(0).width, src.camera(0).height);
    let sizes = 1 + u64::from(size(&c.real) != size(&c.synth));
    assert_eq!(per_step[0].1, 1 + sizes, "{per_step:?}");
    for (step, &(_, waits)) in per_step.iter().enumerate().skip(1) {
        assert_eq!(waits, 1, "step {step}: {per_step:?}");
    }
    // A step's views are small: everything of the step (its clears, its views, the last
    // step's Adam update, the read-back) goes in one submission; a first pass submits what
    // is kept before its count's wait.
    assert!(submissions[0] <= 2 * per_step[0].1, "{submissions:?}");
    for (step, &n) in submissions.iter().enumerate().skip(1) {
        assert_eq!(n, 1, "step {step}: {submissions:?}");
    }
}

#[test]
fn advancing_steps_keeps_the_device_busy_and_changes_no_bit() {
    let test = "advancing_steps_keeps_the_device_busy_and_changes_no_bit";
    let Some(gpu) = context(test) else { return };
    let tmp = tempfile::tempdir().unwrap();
    let c = case(tmp.path());
    // Dual with a batch of 3, then the real view alone (no reset, no refinement), and a
    // refining baseline.
    let mut dual = args(24, false);
    dual.schedule = short_dual();
    let refining = args(10, true);
    for (a, synthetic) in [(dual, true), (refining, false)] {
        let synth = synthetic.then_some(&c.synth as &dyn Supervision);
        let (want, want_g) = train(&c, &a, synthetic, Some(&gpu));
        let mut t = Trainer::new(a.clone(), c.init.clone(), c.scale, &c.real, synth);
        t.on_device(&augsplat_splat::Device::gpu(gpu.clone()));
        let mut reports = Vec::new();
        let mut per_step = Vec::new();
        for step in 0..a.steps {
            let (waits, draining) = (gpu.host_waits(), gpu.draining_waits());
            let got = t.advance();
            let refined = densify::acts_at(step, &t.densify_schedule(), &a.densify);
            if synthetic {
                // The step before comes back while this one is queued (none at the first).
                let expected: Vec<u64> = (step > 0).then(|| step - 1).into_iter().collect();
                let steps: Vec<u64> = got.iter().map(|r| r.step).collect();
                assert_eq!(steps, expected, "step {step}");
            }
            reports.extend(got);
            per_step.push((
                step,
                refined,
                gpu.host_waits() - waits,
                gpu.draining_waits() - draining,
            ));
        }
        reports.extend(t.finish_steps());
        eprintln!("{test}: (step, refined, waits, draining) {per_step:?}");
        // After the first step (whose passes count their pairs first) a step waits once, for
        // the step before, while the device has this step queued: no wait drains it. (A
        // refinement reads the statistics of every step before it, and a view whose pairs it
        // grew past their slots runs again, counted first: the refining run only checks the
        // bits.)
        if synthetic {
            for &(step, _, waits, draining) in per_step.iter().skip(1) {
                assert_eq!((waits, draining), (1, 0), "step {step}: {per_step:?}");
            }
        } else {
            assert!(per_step.iter().any(|p| p.1), "{per_step:?}");
            // A refinement grows a view's pairs past the slots sized before it: the step is
            // found a step late and runs again with the one behind it (their passes counted
            // first, each one more wait), and the bits below still match.
            assert!(
                per_step.iter().any(|&(s, r, w, _)| s > 0 && !r && w > 2),
                "no step ran again: {per_step:?}"
            );
        }
        // The same reports and Gaussians as steps resolved one by one.
        assert_eq!(reports.len(), want.len());
        for (g, w) in reports.iter().zip(&want) {
            assert_eq!(g.step, w.step);
            assert_eq!(g.loss.to_bits(), w.loss.to_bits(), "step {}", g.step);
            assert_eq!(g, w, "step {}", g.step);
        }
        assert!(t.into_gaussians() == want_g, "the Gaussians differ");
    }
}

#[test]
fn a_refinement_on_the_gpu_waits_once_and_brings_nothing_back() {
    let test = "a_refinement_on_the_gpu_waits_once_and_brings_nothing_back";
    let Some(gpu) = context(test) else { return };
    let tmp = tempfile::tempdir().unwrap();
    let c = case(tmp.path());
    // Refinements at steps 3, 6, 9; opacity resets at 4 and 8, of either kind.
    for reset in [OpacityReset::Periodic, OpacityReset::KeepVisible] {
        let mut a = args(10, true);
        a.densify.reset_every = 4;
        a.densify.reset = reset;
        let mut t = Trainer::new(a.clone(), c.init.clone(), c.scale, &c.real, None);
        t.on_device(&augsplat_splat::Device::gpu(gpu.clone()));
        let mut per_step = Vec::new();
        for _ in 0..a.steps {
            let before = gpu.host_waits();
            let r = t.step();
            per_step.push((r.step, r.refine, gpu.host_waits() - before));
        }
        // A step of one view waits once, twice at the view's first pass (or when
        // densification grew its pairs past the slots); a refinement adds one wait (its
        // totals and split parents), a reset none: the state is never read back whole.
        for (step, refine, waits) in &per_step {
            let grows = [3, 6, 9].contains(step);
            let view = waits - u64::from(grows);
            assert!(
                (1..=2).contains(&view),
                "{reset:?}, step {step}: {per_step:?}"
            );
            assert_eq!(
                refine.reset,
                [4, 8].contains(step),
                "{reset:?}, step {step}"
            );
        }
        let grown: usize = per_step.iter().map(|(_, r, _)| r.cloned + r.split).sum();
        assert!(grown > 0, "the run densifies: {per_step:?}");
        // The same run on the CPU refines identically (same counts at every step).
        let (cpu, _) = train(&c, &a, false, None);
        for ((step, g, _), c) in per_step.iter().zip(&cpu) {
            assert_eq!(*g, c.refine, "{reset:?}, step {step}");
        }
    }
}

#[test]
fn held_out_evaluations_render_on_the_gpu_without_the_model() {
    let test = "held_out_evaluations_render_on_the_gpu_without_the_model";
    let Some(gpu) = context(test) else { return };
    let tmp = tempfile::tempdir().unwrap();
    let c = case(tmp.path());
    let a = args(6, true);
    let mut t = Trainer::new(a.clone(), c.init.clone(), c.scale, &c.real, None);
    t.on_device(&augsplat_splat::Device::gpu(gpu.clone()));
    for _ in 0..a.steps {
        t.step();
    }
    let views = &c.real.views[..3];
    let settings = a.render_settings(a.steps);
    let before = gpu.host_waits();
    let on_gpu = t.evaluate(views, &settings, None).unwrap();
    let waits = gpu.host_waits() - before;
    // Each view's render waits for its pair count and its image planes (4 read-backs); the
    // model itself (17 arrays) is not read back.
    assert!(waits <= 4 * views.len() as u64, "{waits} waits");
    assert_eq!(t.primitives(), t.gaussians().len());
    let on_cpu = augsplat_splat::train::evaluate(t.gaussians(), views, &settings, None).unwrap();
    assert!(
        (on_gpu.psnr - on_cpu.psnr).abs() < 1e-3 && (on_gpu.ssim - on_cpu.ssim).abs() < 1e-4,
        "GPU {on_gpu:?}, CPU {on_cpu:?}"
    );
}

#[test]
fn decoded_photos_are_kept_on_the_gpu_as_bytes() {
    // The generated scene's photos (8-bit PNGs) decode to exactly the byte values the GPU
    // target keeps, so they take a quarter of the memory there.
    let tmp = tempfile::tempdir().unwrap();
    let c = case(tmp.path());
    for v in &c.real.views {
        assert!(
            augsplat_splat::gpu::pack_u8(&v.image).is_some(),
            "{}: a value is not a byte's",
            v.name
        );
    }
    // A resized photo is not.
    let half = augsplat_core::ImageF32::from_vec(48, 40, 3, c.real.views[0].image.clone())
        .downscale(2)
        .data;
    assert!(augsplat_splat::gpu::pack_u8(&half).is_none());
}
