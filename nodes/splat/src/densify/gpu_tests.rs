//! Densification on the GPU against the CPU's [`Densifier::step_post_update`] fed the same
//! Gaussians, moments and statistics: the resulting sets, moments and statistics compared
//! bit for bit, with Gaussians placed on every boundary the device tests (the grow
//! threshold per count, the clone/split scale, the prune opacity and scale), NaN and infinite
//! parameters, the cap, and the opacity reset. Skips without an adapter (fails under
//! `CI=true`).

use super::gpu::Refinement;
use super::thresholds::{from_key, grow_keys, log_scale_key_at_most, ord_key};
use super::*;
use crate::gpu::{GpuContext, GpuError, GpuTrainer};
use augsplat_core::Rng;

fn context(test: &str) -> Option<GpuContext> {
    match GpuContext::new() {
        Ok(c) => Some(c),
        Err(e @ GpuError::NoAdapter { .. }) => {
            augsplat_testkit::skip(test, &e.to_string());
            None
        }
        Err(e) => panic!("{test}: {e}"),
    }
}

/// A change that puts one Gaussian (by index) on an edge case.
type Edge<'a> = Box<dyn Fn(&mut Gaussians, &mut Densifier, usize) + 'a>;

/// The host's state for a refinement.
#[derive(Clone)]
struct State {
    g: Gaussians,
    adam: Adam,
    stats: Densifier,
}

const MAX_COUNT: u32 = 12;

/// `n` random Gaussians (SH degree 1) with random moments and statistics, and Gaussians on
/// and beside each boundary of `args` at `extents`.
fn state(n: usize, args: &DensifyArgs, extents: Extents, seed: u64) -> State {
    let mut rng = Rng::new(seed);
    let mut u = |lo: f64, hi: f64| (lo + (hi - lo) * rng.next_f64()) as f32;
    let mut g = Gaussians::empty(1);
    let k3 = 3 * g.coeffs();
    let mut stats = Densifier::new(0);
    let table = grow_keys(args.grad_threshold, MAX_COUNT);
    for i in 0..n {
        g.means.push([u(-2.0, 2.0), u(-2.0, 2.0), u(1.0, 5.0)]);
        g.log_scales
            .push([u(-7.0, 0.5), u(-7.0, 0.5), u(-7.0, 0.5)]);
        g.quats
            .push([u(-1.0, 1.0), u(-1.0, 1.0), u(-1.0, 1.0), u(-1.0, 1.0)]);
        g.opacity_logits.push(u(-7.0, 3.0));
        g.sh.extend((0..k3).map(|_| u(-1.0, 1.0)));
        let c = (i as u32 * 7) % (MAX_COUNT + 1);
        stats.count.push(c);
        stats
            .grad2d
            .push(u(0.0, 2.0 * args.grad_threshold * f64::from(c.max(1))));
    }
    let clone_key = log_scale_key_at_most(args.grow_scale3d * extents.scene).unwrap();
    let big_key = log_scale_key_at_most(args.prune_scale3d * extents.prune).unwrap();
    let thr_logit = crate::init::logit(args.prune_opacity) as f32;
    // Edge cases, each on one Gaussian (i = 0, 1, …), all with statistics that grow.
    let edges: Vec<Edge<'_>> = vec![
        Box::new(|g, _, i| g.log_scales[i] = [from_key(clone_key), -9.0, -9.0]),
        Box::new(|g, _, i| g.log_scales[i] = [-9.0, from_key(clone_key + 1), -9.0]),
        Box::new(|g, _, i| g.log_scales[i] = [-9.0, -9.0, from_key(big_key)]),
        Box::new(|g, _, i| g.log_scales[i] = [from_key(big_key + 1), -9.0, -9.0]),
        Box::new(|g, _, i| g.log_scales[i] = [f32::NAN, -3.0, -9.0]),
        Box::new(|g, _, i| g.log_scales[i] = [f32::NAN; 3]),
        Box::new(|g, _, i| g.log_scales[i] = [f32::INFINITY, -3.0, -9.0]),
        Box::new(|g, _, i| g.log_scales[i] = [f32::NEG_INFINITY; 3]),
        Box::new(|g, _, i| g.means[i] = [0.0, f32::INFINITY, 1.0]),
        Box::new(|g, _, i| g.means[i] = [f32::NAN, 0.0, 1.0]),
        Box::new(|g, _, i| g.opacity_logits[i] = thr_logit),
        Box::new(|g, _, i| g.opacity_logits[i] = from_key(ord_key(thr_logit) - 1)),
        Box::new(|g, _, i| g.opacity_logits[i] = f32::NAN),
        Box::new(|g, _, i| g.opacity_logits[i] = f32::INFINITY),
        Box::new(|g, _, i| g.quats[i] = [0.0; 4]),
        Box::new(|g, _, i| g.quats[i] = [f32::NAN, 0.0, 0.0, 1.0]),
        Box::new(|_, s, i| s.grad2d[i] = f32::NAN),
        Box::new(|_, s, i| s.grad2d[i] = f32::INFINITY),
        Box::new(|_, s, i| s.count[i] = 0),
    ];
    let grow = |s: &mut Densifier, i: usize| {
        s.grad2d[i] = from_key(table[s.count[i] as usize]);
    };
    let edged = n >= edges.len() + 2 * (MAX_COUNT as usize + 1);
    for (i, edge) in edges.iter().enumerate().filter(|_| edged) {
        grow(&mut stats, i);
        edge(&mut g, &mut stats, i);
    }
    // The grow boundary itself, and one key below it, at every count.
    let base = edges.len();
    for c in (0..=MAX_COUNT as usize).filter(|_| edged) {
        let (a, b) = (base + 2 * c, base + 2 * c + 1);
        stats.count[a] = c as u32;
        stats.count[b] = c as u32;
        stats.grad2d[a] = from_key(table[c]);
        stats.grad2d[b] = from_key(table[c] - 1);
    }
    let mut adam = Adam::new(n, g.coeffs());
    for group in [
        Group::Means,
        Group::Scales,
        Group::Quats,
        Group::Opacities,
        Group::Sh,
    ] {
        let (m, v) = adam.moments_mut(group);
        m.iter_mut().for_each(|x| *x = u(-1.0, 1.0));
        v.iter_mut().for_each(|x| *x = u(0.0, 1.0));
    }
    State { g, adam, stats }
}

/// The bits of every array of a state, by name.
fn bits(s: &State) -> Vec<(&'static str, Vec<u32>)> {
    let f = |v: &mut dyn Iterator<Item = f32>| v.map(f32::to_bits).collect::<Vec<_>>();
    let mut out = vec![
        ("means", f(&mut s.g.means.iter().flatten().copied())),
        (
            "log-scales",
            f(&mut s.g.log_scales.iter().flatten().copied()),
        ),
        ("quaternions", f(&mut s.g.quats.iter().flatten().copied())),
        ("opacity logits", f(&mut s.g.opacity_logits.iter().copied())),
        ("SH", f(&mut s.g.sh.iter().copied())),
        ("grad2d", f(&mut s.stats.grad2d.iter().copied())),
        ("counts", s.stats.count.clone()),
    ];
    for (name, group) in [
        ("means moments", Group::Means),
        ("scales moments", Group::Scales),
        ("quats moments", Group::Quats),
        ("opacity moments", Group::Opacities),
        ("SH moments", Group::Sh),
    ] {
        let (m, v) = s.adam.moments(group);
        out.push((name, f(&mut m.iter().chain(v).copied())));
    }
    out
}

/// Runs step `step` of `sched` on both devices from `s` and compares the results.
fn compare(ctx: &GpuContext, s: &State, args: &DensifyArgs, sched: &DensifySchedule, step: u64) {
    let extents = Extents {
        scene: 3.0,
        prune: 4.5,
    };
    let seed = 0xDE45 ^ 7;
    let mut cpu = s.clone();
    let cpu_rep = cpu.stats.step_post_update(
        step,
        sched,
        args,
        &mut cpu.g,
        &mut cpu.adam,
        extents,
        seed,
        &mut |_| unreachable!("no KeepVisible reset here"),
    );
    let mut gpu = GpuTrainer::upload(ctx, &s.g, &s.adam, &s.stats).unwrap();
    let r = Refinement {
        step,
        sched,
        args,
        extents,
        seed,
        views: VisibilityViews::NONE,
    };
    let gpu_rep = gpu
        .refine(ctx, &r, u64::from(MAX_COUNT))
        .unwrap()
        .expect("refines on the device");
    let mut back = s.clone();
    gpu.download(ctx, &mut back.g, &mut back.adam, &mut back.stats)
        .unwrap();
    assert_eq!(gpu_rep, cpu_rep, "step {step}: the reports");
    assert_eq!(back.g.len(), cpu.g.len());
    for ((name, a), (_, b)) in bits(&back).into_iter().zip(bits(&cpu)) {
        assert_eq!(a.len(), b.len(), "step {step}: {name} sizes");
        if let Some(k) = (0..a.len()).find(|&k| a[k] != b[k]) {
            panic!(
                "step {step}: {name} differ first at word {k} of {}: GPU {:e}, CPU {:e}",
                a.len(),
                f32::from_bits(a[k]),
                f32::from_bits(b[k])
            );
        }
    }
}

fn schedule() -> DensifySchedule {
    DensifySchedule {
        start: 10,
        stop: 1000,
        every: 10,
        reset_every: 60,
    }
}

#[test]
fn refinement_on_the_gpu_gives_the_cpus_set_bit_for_bit() {
    let Some(ctx) = context("refinement_on_the_gpu_gives_the_cpus_set_bit_for_bit") else {
        return;
    };
    let args = DensifyArgs::default();
    let extents = Extents {
        scene: 3.0,
        prune: 4.5,
    };
    let s = state(900, &args, extents, 3);
    let sched = schedule();
    // Grow and prune (small Gaussians only), with large ones too, with a reset as well.
    for step in [20, 70, 120] {
        compare(&ctx, &s, &args, &sched, step);
    }
    let cpu_grown = {
        let mut c = s.clone();
        c.stats.step_post_update(
            70,
            &sched,
            &args,
            &mut c.g,
            &mut c.adam,
            extents,
            1,
            &mut |_| Vec::new(),
        )
    };
    assert!(
        cpu_grown.cloned > 20 && cpu_grown.split > 20 && cpu_grown.pruned > 20,
        "the case exercises every operation: {cpu_grown:?}"
    );
    // A reset alone, and the cap (clones first, then splits).
    compare(&ctx, &s, &args, &DensifySchedule { every: 7, ..sched }, 60);
    for room in [0, 5, 40, 400] {
        let capped = DensifyArgs {
            max_gaussians: 900 + room,
            ..args.clone()
        };
        compare(&ctx, &s, &capped, &sched, 70);
    }
    // An empty set.
    compare(&ctx, &state(0, &args, extents, 4), &args, &sched, 70);
}

/// Two views of the test states' Gaussians (means in [−2, 2]² × [1, 5]): from the origin
/// along +z, and from beside it.
fn views() -> Vec<augsplat_core::Camera> {
    let pose = |x: f64| {
        [
            [1.0, 0.0, 0.0, x],
            [0.0, 1.0, 0.0, 0.0],
            [0.0, 0.0, 1.0, 0.5],
            [0.0, 0.0, 0.0, 1.0],
        ]
    };
    vec![
        augsplat_testkit::cameras::square_pixels(64, 48, pose(0.0)),
        augsplat_testkit::cameras::square_pixels(40, 56, pose(-0.8)),
    ]
}

#[test]
fn a_keep_visible_reset_on_the_gpu_gives_the_cpus_caps() {
    let Some(ctx) = context("a_keep_visible_reset_on_the_gpu_gives_the_cpus_caps") else {
        return;
    };
    let args = DensifyArgs {
        reset: OpacityReset::KeepVisible,
        ..Default::default()
    };
    let extents = Extents::uniform(3.0);
    let mut s = state(2000, &args, extents, 5);
    // Smaller Gaussians than the state's, so that many peak below full alpha.
    for ls in &mut s.g.log_scales[40..] {
        ls.iter_mut().for_each(|v| *v = v.min(-3.0));
    }
    let cams = views();
    for antialiased in [false, true] {
        let cam_refs: Vec<&augsplat_core::Camera> = cams.iter().collect();
        let views = VisibilityViews {
            cameras: &cam_refs,
            antialiased,
            near: 0.01,
        };
        // A reset alone (step 60 is no refinement step of this schedule).
        let sched = DensifySchedule {
            every: 7,
            ..schedule()
        };
        let (step, seed) = (60, 1);
        let mut cpu = s.clone();
        let cpu_rep = cpu.stats.step_post_update(
            step,
            &sched,
            &args,
            &mut cpu.g,
            &mut cpu.adam,
            extents,
            seed,
            &mut |g| views.peak_alpha_ratios(g),
        );
        assert!(cpu_rep.reset && cpu_rep.cloned + cpu_rep.split + cpu_rep.pruned == 0);
        let mut gpu = GpuTrainer::upload(&ctx, &s.g, &s.adam, &s.stats).unwrap();
        let r = Refinement {
            step,
            sched: &sched,
            args: &args,
            extents,
            seed,
            views,
        };
        let gpu_rep = gpu.refine(&ctx, &r, 100).unwrap().expect("on the device");
        assert_eq!(gpu_rep, cpu_rep);
        let mut back = s.clone();
        gpu.download(&ctx, &mut back.g, &mut back.adam, &mut back.stats)
            .unwrap();
        // Everything but the logits to the bit (the opacity moments cleared on both).
        for ((name, a), (_, b)) in bits(&back).into_iter().zip(bits(&cpu)) {
            if name != "opacity logits" {
                assert!(a == b, "{name} differ");
            }
        }
        // The logits within rounding of the host's f64 caps (the f32 projection's
        // compensation loses digits on thin Gaussians: a few are further off); the case must
        // hold Gaussians kept above the plain reset's cap, and Gaussians that no view sees.
        let plain = crate::init::logit(2.0 * args.prune_opacity) as f32;
        let (mut worst, mut close, mut kept, mut unseen) = (0f32, 0, 0, 0);
        let ratios = views.peak_alpha_ratios(&s.g);
        let logits = back.g.opacity_logits.iter().zip(&cpu.g.opacity_logits);
        for (i, (&a, &b)) in logits.enumerate() {
            let gap = (a - b).abs();
            assert!(
                gap <= 1e-3 * b.abs().max(1.0),
                "Gaussian {i}: GPU {a} CPU {b}"
            );
            worst = worst.max(gap);
            close += usize::from(gap <= 1e-5);
            kept += usize::from(b > plain + 1e-3);
            unseen += usize::from(ratios[i] == 0.0 && s.g.opacity_logits[i] > plain);
        }
        let n = s.g.len();
        eprintln!(
            "antialiased {antialiased}: {kept} kept above the plain cap, {unseen} unseen; \
             logits within {worst:e}, {close} of {n} within 1e-5"
        );
        assert!(close * 100 >= 99 * n, "{close} of {n} within 1e-5");
        assert!(kept > 100 && unseen > 50, "{kept} kept, {unseen} unseen");
    }
    // An empty set resets too (nothing to clamp).
    let empty = state(0, &args, extents, 6);
    let mut gpu = GpuTrainer::upload(&ctx, &empty.g, &empty.adam, &empty.stats).unwrap();
    let sched = DensifySchedule {
        every: 7,
        ..schedule()
    };
    let r = Refinement {
        step: 60,
        sched: &sched,
        args: &args,
        extents,
        seed: 1,
        views: VisibilityViews::NONE,
    };
    let rep = gpu.refine(&ctx, &r, 100).unwrap().expect("on the device");
    assert!(rep.reset && gpu.len() == 0, "{rep:?}");
}

#[test]
fn a_switch_reset_on_the_gpu_gives_the_cpus_state() {
    let Some(ctx) = context("a_switch_reset_on_the_gpu_gives_the_cpus_state") else {
        return;
    };
    let args = DensifyArgs::default();
    let s = state(700, &args, Extents::uniform(3.0), 9);
    let mut cpu = s.clone();
    reset_opacities(&mut cpu.g, &mut cpu.adam, 0.1);
    cpu.adam.clear();
    cpu.stats.clear();
    let gpu = GpuTrainer::upload(&ctx, &s.g, &s.adam, &s.stats).unwrap();
    gpu.reset_for_switch(&ctx, 0.1).unwrap();
    let mut back = s.clone();
    gpu.download(&ctx, &mut back.g, &mut back.adam, &mut back.stats)
        .unwrap();
    for ((name, a), (_, b)) in bits(&back).into_iter().zip(bits(&cpu)) {
        assert!(a == b, "{name} differ");
    }
    assert!(
        s.g.opacity_logits
            .iter()
            .zip(&cpu.g.opacity_logits)
            .any(|(a, b)| a != b),
        "the reset lowers some opacities"
    );
}

#[test]
fn refinement_on_the_gpu_declines_what_needs_the_host() {
    let Some(ctx) = context("refinement_on_the_gpu_declines_what_needs_the_host") else {
        return;
    };
    let args = DensifyArgs::default();
    let extents = Extents::uniform(3.0);
    let s = state(200, &args, extents, 5);
    let mut gpu = GpuTrainer::upload(&ctx, &s.g, &s.adam, &s.stats).unwrap();
    let sched = schedule();
    // A count above the bound the trainer gave is an error, not a wrong set.
    let r = Refinement {
        step: 20,
        sched: &sched,
        args: &args,
        extents,
        seed: 1,
        views: VisibilityViews::NONE,
    };
    let err = gpu.refine(&ctx, &r, 3).unwrap_err();
    assert!(err.to_string().contains("bound 3"), "{err}");
    // Arrays past one binding: declined (the host refines).
    let narrow = GpuContext::new().unwrap().with_binding_limit(4096);
    let mut gpu = GpuTrainer::upload(&narrow, &s.g, &s.adam, &s.stats).unwrap();
    assert!(gpu.refine(&narrow, &r, 100).unwrap().is_none(), "binding");
}
