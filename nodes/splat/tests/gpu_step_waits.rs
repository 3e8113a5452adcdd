//! The GPU trainer's waits on the host: a step waits once for its losses and counts and
//! submits once; steps recorded ahead of the device's work change no bit; a refinement waits
//! once and brings nothing back; held-out evaluations render from the device's model; decoded
//! photos are kept on the device as bytes. Skips with a message when no GPU adapter is found
//! (fails under `CI=true`, where `.ci/run` installs lavapipe).

mod gpu_case;
mod train_util;

use augsplat_splat::densify::{self, OpacityReset};
use augsplat_splat::train::{Schedule, Supervision, Trainer};
use gpu_case::{args, case, context, short_dual, train};

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
