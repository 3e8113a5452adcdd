//! DropGaussian inside the trainer: off, it leaves every byte and key as they were; on, it
//! drops Gaussians in the training renders only (reproducibly, for any thread count), still
//! learns, and is refused on the GPU backend.

mod train_util;

use augsplat_splat::dropout::DropGaussian;
use augsplat_splat::train::{evaluate, TrainArgs, Trainer};
use augsplat_splat::{Backend, Gaussians};
use train_util::param_bits as bits;

fn initial(dir: &std::path::Path, sscale: f64) -> Gaussians {
    train_util::initial(dir, 1, sscale)
}

#[test]
fn dropgaussian_is_off_by_default_reproducible_and_training_only() {
    // Off: not in the serialised args (no key moved), and the default trainer unchanged.
    let off = serde_json::to_string(&TrainArgs::default()).unwrap();
    assert!(!off.contains("drop_gaussians"), "{off}");
    let on = TrainArgs {
        drop_gaussians: Some(DropGaussian::default()),
        ..Default::default()
    };
    let text = serde_json::to_string(&on).unwrap();
    assert!(
        text.contains("\"drop_gaussians\":{\"max_rate\":0.2}"),
        "{text}"
    );
    let gpu = TrainArgs {
        backend: Backend::Gpu,
        ..on.clone()
    };
    let e = gpu.validate().unwrap_err();
    assert!(e.contains("drop_gaussians"), "{e}");

    let tmp = tempfile::tempdir().unwrap();
    let (train, test) = train_util::make_scene(tmp.path(), 48, 40, 13, 600);
    let (real, test, ss) = train_util::real_case(&train, &test);
    let steps = 120;
    let args = |drop: Option<DropGaussian>| TrainArgs {
        steps,
        sh_degree: 1,
        sh_increase_every: 40,
        drop_gaussians: drop,
        ..Default::default()
    };
    let run = |a: &TrainArgs, threads: usize| {
        augsplat_testkit::with_threads(threads, || {
            let mut t = Trainer::new(a.clone(), initial(&train, ss), ss, &real, None);
            let reps: Vec<_> = (0..steps).map(|_| t.step()).collect();
            (bits(t.gaussians()), reps, t.gaussians().clone())
        })
    };
    let with = args(Some(DropGaussian::default()));
    let (a, ra, ga) = run(&with, 1);
    let (b, rb, _) = run(&with, 2);
    assert_eq!(ra, rb);
    assert!(a == b, "DropGaussian's run differs between 1 and 2 threads");
    let (c, rc, gc) = run(&args(None), 2);
    // Step 0 drops nothing (rate 0): the first step is the plain run's.
    assert_eq!(ra[0], rc[0]);
    assert_ne!(ra.last(), rc.last());
    assert!(a != c, "DropGaussian changed nothing");
    // A late step's render composites fewer pairs than the plain run's on average.
    let pairs =
        |r: &[augsplat_splat::train::StepReport]| r[80..].iter().map(|x| x.pairs).sum::<u64>();
    assert!(pairs(&ra) < pairs(&rc), "{} vs {}", pairs(&ra), pairs(&rc));
    // Evaluations render every Gaussian: the settings carry no factors, and the run learns.
    let s = with.render_settings(steps);
    assert!(s.opacity_scale.is_none());
    let before = evaluate(&initial(&train, ss), &test, &s, None).unwrap();
    let after = evaluate(&ga, &test, &s, None).unwrap();
    let plain = evaluate(&gc, &test, &s, None).unwrap();
    eprintln!(
        "held-out PSNR: start {:.2}, DropGaussian {:.2}, plain {:.2} dB",
        before.psnr, after.psnr, plain.psnr
    );
    assert!(after.psnr > before.psnr + 2.0);
}
