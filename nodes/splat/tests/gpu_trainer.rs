//! The training step on the GPU (state kept there between steps: Adam, the per-view sums and
//! the densification statistics in WGSL) against the CPU trainer on a small generated scene:
//! the same losses step by step (on lavapipe within 5e-7 relative; asserted within 1e-4),
//! every parameter within a small fraction of an Adam step, the same densification, Dual's
//! synthetic batches, the losses on the GPU (`loss/loss.wgsl`) and on the host, selective
//! Adam, checkpoints taken mid-run, identical bytes on every run, and a 50-step Dual run
//! written once and run through both devices of the seam. Skips with a message when no GPU
//! adapter is found (fails under `CI=true`, where `.ci/run` installs lavapipe).

mod gpu_case;
mod train_util;

use augsplat_splat::adam::AdamUpdates;
use augsplat_splat::gpu::{GpuContext, GpuError};
use augsplat_splat::train::{
    RealImages, Schedule, StepReport, Supervision, SynthView, TrainArgs, Trainer,
};
use augsplat_splat::Gaussians;
use gpu_case::{args, case, case_of, context, short_dual, train};
use std::sync::Arc;

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

/// Forty steps with a refinement every three and a low gradient threshold: the set grows to
/// about 206,000 Gaussians on the 48×40 views, with tiles of more than 35,000 pairs from step
/// 32 on. Until the compositor's done count stopped looping on one thread, lavapipe cut those
/// tiles short (its 65,535-iteration loop cap) and the GPU run left the CPU's at step 32 (loss
/// 0.2498 against 0.2240). About 75 s on lavapipe, so not in the default run:
/// `cargo test --release -p augsplat-splat --test gpu_trainer -- --ignored`.
#[test]
#[ignore = "75 s on lavapipe"]
fn gpu_training_follows_the_cpu_past_200k_gaussians() {
    let test = "gpu_training_follows_the_cpu_past_200k_gaussians";
    let Some(gpu) = context(test) else { return };
    let tmp = tempfile::tempdir().unwrap();
    let c = case(tmp.path());
    let mut a = args(40, true);
    a.densify.every = 3;
    let (cpu, cpu_g) = train(&c, &a, false, None);
    let (gpu_reps, gpu_g) = train(&c, &a, false, Some(&gpu));
    // A clone decided within rounding of its threshold may go the other way (a Gaussian more
    // or less, from step 27 on here); the losses still agree to a few 1e-4.
    same_losses(&cpu, &gpu_reps, 1e-3, test);
    let (n_cpu, n_gpu) = (cpu_g.len() as f64, gpu_g.len() as f64);
    assert!(n_cpu > 200_000.0, "the case must grow past 200k: {n_cpu}");
    assert!(
        (n_cpu - n_gpu).abs() <= 1e-4 * n_cpu,
        "{n_cpu} against {n_gpu} Gaussians"
    );
}
