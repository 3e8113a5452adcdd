//! Tests of the projection: a lane of a batch is the single-Gaussian projection and its
//! backward, the AVX2 lanes equal the portable lanes bit for bit, the scale bound.

use super::*;

#[test]
fn the_scale_bound_is_exactly_where_exp_overflows() {
    assert!(LN_F64_MAX.exp().is_finite());
    // The f32 values on either side of the bound.
    let below = 709.782_65_f32;
    let above = f32::from_bits(below.to_bits() + 1);
    assert!((below as f64) <= LN_F64_MAX && (above as f64) > LN_F64_MAX);
    assert!((below as f64).exp().is_finite());
    assert!((above as f64).exp().is_infinite());
    // Behind the camera the one is culled and the other invalid, as when the
    // exponentials were taken before the near-plane test; in front both overflow the
    // covariance (invalid).
    let cam = augsplat_core::Camera {
        width: 32,
        height: 24,
        fx: 30.0,
        fy: 30.0,
        cx: 16.0,
        cy: 12.0,
        world_to_camera: augsplat_core::linalg::mat4_from_rt(
            &[[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
            [0.0, 0.0, 0.0],
        ),
    };
    let cm = CameraModel::new(&cam);
    let q = [1.0, 0.0, 0.0, 0.0];
    let go = |z: f32, ls: f32| project(&cm, [0.0, 0.0, z], [ls, -3.0, -3.0], q, 2.0, false, 0.01);
    assert!(matches!(go(2.0, below), Outcome::Invalid));
    assert!(matches!(go(2.0, above), Outcome::Invalid));
    assert!(matches!(go(-2.0, below), Outcome::Culled));
    assert!(matches!(go(-2.0, above), Outcome::Invalid));
}

/// Random Gaussians including every awkward case the projection must survive.
fn awkward_gaussians(rng: &mut augsplat_core::Rng, n: usize) -> crate::Gaussians {
    let mut g = crate::Gaussians::empty(0);
    for i in 0..n {
        let mut mean = [
            rng.uniform(-3.0, 3.0) as f32,
            rng.uniform(-2.0, 2.0) as f32,
            rng.uniform(-1.0, 6.0) as f32,
        ];
        let s = rng.uniform(-6.0, 0.5) as f32;
        let mut ls = [s, s + rng.uniform(-1.0, 1.0) as f32, s - 0.5];
        let mut q = [
            rng.uniform(-1.0, 1.0) as f32,
            rng.uniform(-1.0, 1.0) as f32,
            rng.uniform(-1.0, 1.0) as f32,
            rng.uniform(-1.0, 1.0) as f32,
        ];
        let mut logit = rng.uniform(-8.0, 8.0) as f32;
        match i % 13 {
            0 => mean[0] = f32::NAN,
            1 => ls[1] = f32::INFINITY,
            2 => ls[0] = 700.0,
            3 => ls = [-100.0, -100.0, -100.0],
            4 => q = [0.0; 4],
            5 => mean[2] = 0.0,
            6 => logit = -30.0,
            7 => mean = [40.0, 0.0, 1.0],
            8 => logit = f32::NEG_INFINITY,
            _ => {}
        }
        g.means.push(mean);
        g.log_scales.push(ls);
        g.quats.push(q);
        g.opacity_logits.push(logit);
    }
    g
}

fn camera() -> CameraModel {
    let r = [[0.96, 0.0, -0.28], [0.0, 1.0, 0.0], [0.28, 0.0, 0.96]];
    CameraModel::new(&augsplat_core::Camera {
        width: 61,
        height: 37,
        fx: 40.0,
        fy: 42.0,
        cx: 27.0,
        cy: 20.5,
        world_to_camera: augsplat_core::linalg::mat4_from_rt(&r, [0.2, -0.1, 1.0]),
    })
}

fn same(a: f64, b: f64) -> bool {
    a.to_bits() == b.to_bits() || (a.is_nan() && b.is_nan())
}

#[test]
fn a_lane_of_a_batch_is_the_single_gaussian_projection_and_its_backward() {
    let mut rng = augsplat_core::Rng::new(11);
    let g = awkward_gaussians(&mut rng, 64);
    let cam = camera();
    for aa in [false, true] {
        for b in 0..8 {
            let idx: [usize; LANES] = std::array::from_fn(|l| 8 * b + l);
            let gl = ParamLanes::<P8>::gather(
                &g.means,
                &g.log_scales,
                &g.quats,
                &g.opacity_logits,
                None,
                &idx,
            );
            let batch = project_lanes(&cam, &gl, aa, 0.01).unpack();
            let grad = ProjectedGradLanes {
                mean2d: [P8::splat(0.3), P8::splat(-0.2)],
                conic: [P8::splat(0.7), P8::splat(-0.4), P8::splat(0.1)],
                opacity: P8::splat(0.9),
                depth: P8::splat(0.05),
            };
            let back = project_vjp_lanes(&cam, &gl, aa, 0.01, &grad).unpack();
            for l in 0..LANES {
                let i = idx[l];
                let one = project(
                    &cam,
                    g.means[i],
                    g.log_scales[i],
                    g.quats[i],
                    g.opacity_logits[i],
                    aa,
                    0.01,
                );
                assert_eq!(
                    format!("{:?}", one),
                    format!("{:?}", batch[l]),
                    "Gaussian {i}"
                );
                let pg = ProjectedGrad {
                    mean2d: [0.3, -0.2],
                    conic: [0.7, -0.4, 0.1],
                    opacity: 0.9,
                    depth: 0.05,
                };
                let one = project_vjp(
                    &cam,
                    g.means[i],
                    g.log_scales[i],
                    g.quats[i],
                    g.opacity_logits[i],
                    aa,
                    0.01,
                    &pg,
                );
                assert_eq!(
                    format!("{:?}", one),
                    format!("{:?}", back[l]),
                    "Gaussian {i}"
                );
            }
        }
    }
}

#[cfg(target_arch = "x86_64")]
#[test]
fn vector_lanes_project_and_differentiate_bit_for_bit_like_portable_lanes() {
    type LaneOut = ([Outcome; LANES], [ParamGrad; LANES], Status, [f64; LANES]);
    #[inline(always)]
    fn run<L: Lanes>(
        cam: &CameraModel,
        g: &crate::Gaussians,
        idx: &[usize; LANES],
        aa: bool,
        grad: [[f64; LANES]; 7],
    ) -> LaneOut {
        let gl = ParamLanes::<L>::gather(
            &g.means,
            &g.log_scales,
            &g.quats,
            &g.opacity_logits,
            None,
            idx,
        );
        let p = project_lanes(cam, &gl, aa, 0.01);
        let pg = ProjectedGradLanes::<L>::from_rows(grad);
        (
            p.unpack(),
            project_vjp_lanes(cam, &gl, aa, 0.01, &pg).unpack(),
            p.status,
            p.log_alpha_ratio.to_array(),
        )
    }
    #[target_feature(enable = "avx2,fma")]
    fn y8(
        cam: &CameraModel,
        g: &crate::Gaussians,
        idx: &[usize; LANES],
        aa: bool,
        grad: [[f64; LANES]; 7],
    ) -> LaneOut {
        run::<crate::lanes::avx2::Y8>(cam, g, idx, aa, grad)
    }
    let avx2 = augsplat_core::simd::for_each_isa("projection lanes", |isa| isa)
        .iter()
        .any(|(isa, _)| *isa == augsplat_core::simd::Isa::Avx2);
    if !avx2 {
        return;
    }
    let mut rng = augsplat_core::Rng::new(12);
    let g = awkward_gaussians(&mut rng, 800);
    let cam = camera();
    let mut seen = [0usize; 3];
    for aa in [false, true] {
        for b in 0..100 {
            let idx: [usize; LANES] = std::array::from_fn(|l| 8 * b + l);
            let grad: [[f64; LANES]; 7] =
                std::array::from_fn(|_| std::array::from_fn(|_| rng.uniform(-1.0, 1.0)));
            {
                // SAFETY: AVX2 and FMA are supported (checked above).
                let (wp, wg, ws, wlr) = unsafe { y8(&cam, &g, &idx, aa, grad) };
                let gl = ParamLanes::<P8>::gather(
                    &g.means,
                    &g.log_scales,
                    &g.quats,
                    &g.opacity_logits,
                    None,
                    &idx,
                );
                let p = project_lanes(&cam, &gl, aa, 0.01);
                let pg = ProjectedGradLanes::<P8>::from_rows(grad);
                let (pp, pgr) = (
                    p.unpack(),
                    project_vjp_lanes(&cam, &gl, aa, 0.01, &pg).unpack(),
                );
                seen[0] += ws.visible().count_ones() as usize;
                seen[1] += ws.culled.count_ones() as usize;
                seen[2] += ws.invalid.count_ones() as usize;
                assert_eq!(
                    (ws.invalid, ws.culled, ws.visible()),
                    (p.status.invalid, p.status.culled, p.status.visible())
                );
                for l in 0..LANES {
                    match (&wp[l], &pp[l]) {
                        (Outcome::Visible(a), Outcome::Visible(b)) => {
                            let (fa, fb) = (
                                [
                                    a.mean2d[0],
                                    a.mean2d[1],
                                    a.conic[0],
                                    a.conic[1],
                                    a.conic[2],
                                    a.opacity,
                                    a.depth,
                                ],
                                [
                                    b.mean2d[0],
                                    b.mean2d[1],
                                    b.conic[0],
                                    b.conic[1],
                                    b.conic[2],
                                    b.opacity,
                                    b.depth,
                                ],
                            );
                            assert!(
                                fa.iter().zip(&fb).all(|(x, y)| same(*x, *y)),
                                "{a:?} vs {b:?}"
                            );
                            assert_eq!(a.radius, b.radius);
                            assert!(same(wlr[l], p.log_alpha_ratio.to_array()[l]));
                        }
                        (a, b) => assert_eq!(format!("{a:?}"), format!("{b:?}")),
                    }
                    let (a, b) = (wg[l], pgr[l]);
                    let fa = [a.mean, a.log_scale, [a.logit; 3]].concat();
                    let fb = [b.mean, b.log_scale, [b.logit; 3]].concat();
                    assert!(
                        fa.iter().zip(&fb).all(|(x, y)| same(*x, *y)),
                        "{a:?} vs {b:?}"
                    );
                    assert!(a.quat.iter().zip(&b.quat).all(|(x, y)| same(*x, *y)));
                }
            }
        }
    }
    // Every outcome occurs often.
    assert!(seen.iter().all(|&k| k > 100), "{seen:?}");
}
