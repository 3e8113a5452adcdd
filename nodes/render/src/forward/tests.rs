//! Tests of the forward pass: every instruction-set tier against the portable twin bit for
//! bit, the tile kernel against a direct per-pixel loop, the exponential's accuracy.

use super::exp2::exp2_neg;
use super::project_chunk::{
    make_splat, project_chunk_dispatch, ProjectJob, CULLED, INVALID, VISIBLE,
};
use super::tile::{transpose_portable, ForwardKernel, TileState};
use super::*;
use crate::buffers::uninit_vec;
use crate::constants::TRANSMITTANCE_THRESHOLD;
use augsplat_core::simd::for_each_isa;

#[test]
fn vector_and_portable_projection_chunks_agree_bit_for_bit() {
    let mut rng = augsplat_core::Rng::new(21);
    let mut g = Gaussians::empty(3);
    let n = 1000; // not a multiple of the lane count
    for i in 0..n {
        g.means.push([
            rng.uniform(-3.0, 3.0) as f32,
            rng.uniform(-2.0, 2.0) as f32,
            rng.uniform(-1.0, 5.0) as f32,
        ]);
        let s = rng.uniform(-5.0, 0.0) as f32;
        g.log_scales.push([s, s + 0.3, s - 0.4]);
        g.quats
            .push([1.0, rng.uniform(-1.0, 1.0) as f32, 0.2, -0.1]);
        g.opacity_logits.push(rng.uniform(-7.0, 5.0) as f32);
        for q in 0..48 {
            let v = rng.uniform(-0.5, 0.5) as f32;
            // A few Gaussians with a non-finite coefficient (active or not).
            g.sh.push(if i % 97 == 0 && q == (i / 97) % 48 {
                f32::NAN
            } else {
                v
            });
        }
    }
    let cam = augsplat_core::Camera {
        width: 83,
        height: 45,
        fx: 60.0,
        fy: 58.0,
        cx: 40.0,
        cy: 23.0,
        world_to_camera: augsplat_core::linalg::mat4_from_rt(
            &[[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
            [0.1, 0.0, 1.5],
        ),
    };
    let cm = CameraModel::new(&cam);
    let grid = TileGrid::new(cam.width, cam.height);
    for degree in [1, 3] {
        for antialiased in [false, true] {
            let s = RenderSettings {
                antialiased,
                ..RenderSettings::default()
            };
            let job = ProjectJob {
                g: &g,
                cm: &cm,
                s: &s,
                degree,
                grid: &grid,
                first: 0,
            };
            let run = |isa: Isa| {
                let mut sp = uninit_vec::<Splat2D>(n);
                let mut rc = uninit_vec::<[u32; 4]>(n);
                let mut st = vec![9u8; n];
                project_chunk_dispatch(isa, &job, &mut sp, &mut rc, &mut st);
                let out: Vec<Option<(Splat2D, [u32; 4])>> = (0..n)
                    .map(|i| {
                        // SAFETY: written where the status is VISIBLE.
                        (st[i] == VISIBLE)
                            .then(|| unsafe { (sp[i].assume_init(), rc[i].assume_init()) })
                    })
                    .collect();
                (st, out)
            };
            let runs = for_each_isa("projection chunks", run);
            let b = &runs[0].1;
            for (isa, a) in &runs[1..] {
                assert_eq!(a.0, b.0, "{isa:?}");
                let bits = |o: &Option<(Splat2D, [u32; 4])>| {
                    o.map(|(p, r)| {
                        let f = [
                            p.x,
                            p.y,
                            p.a,
                            p.b,
                            p.c,
                            p.opacity,
                            p.rgb[0],
                            p.rgb[1],
                            p.rgb[2],
                            p.depth,
                            p.ymin,
                            p.ymax,
                            p.sigma_max,
                            p.row_q,
                            p.row_w,
                            p.row_shift,
                        ];
                        (f.map(f32::to_bits), r)
                    })
                };
                assert!(
                    a.1.iter().zip(&b.1).all(|(x, y)| bits(x) == bits(y)),
                    "{isa:?}"
                );
            }
            for code in [VISIBLE, CULLED, INVALID] {
                assert!(b.0.contains(&code), "status {code} never occurs");
            }
        }
    }
}

/// Random projected Gaussians around one tile.
pub(crate) fn random_tile_splats(seed: u64, n: usize) -> Vec<Splat2D> {
    let mut rng = augsplat_core::Rng::new(seed);
    (0..n)
        .map(|i| {
            let (sx, sy) = (rng.uniform(0.7, 6.0), rng.uniform(0.7, 6.0));
            let rho = rng.uniform(-0.8, 0.8);
            let cov = [sx * sx, rho * sx * sy, sy * sy];
            let det = cov[0] * cov[2] - cov[1] * cov[1];
            let o = rng.uniform(0.02, 0.999);
            let y = rng.uniform(-6.0, 22.0);
            let ry = (3.33 * cov[2].sqrt()).ceil();
            let p = crate::project::Projected {
                mean2d: [rng.uniform(-6.0, 22.0), y],
                conic: [cov[2] / det, -cov[1] / det, cov[0] / det],
                opacity: o,
                depth: 1.0 + i as f64 * 0.01,
                radius: [(3.33 * cov[0].sqrt()).ceil() as i32, ry as i32],
            };
            let rgb = [
                rng.uniform(0.0, 1.0),
                rng.uniform(0.0, 1.0),
                rng.uniform(0.0, 1.0),
            ];
            let lr = crate::project::log_alpha_ratio(p.opacity);
            make_splat(&p, rgb, lr).unwrap()
        })
        .collect()
}

/// The mask of a fully active tile with pixel 17 (row 1, column 1) switched off.
fn active_mask() -> [u16; 16] {
    let mut active = [0xffffu16; 16];
    active[1] &= !(1 << 1);
    active
}

fn run(isa: Isa, smooth: bool, splats: &[Splat2D], list: &[u32]) -> (u64, TileState) {
    let mut st = TileState::default();
    let p = if smooth {
        raster_tile_dispatch::<true>(isa, splats, list, 0, 0, &active_mask(), 0.99, &mut st)
    } else {
        raster_tile_dispatch::<false>(isa, splats, list, 0, 0, &active_mask(), 0.99, &mut st)
    };
    (p, st)
}

fn bits(st: &TileState) -> Vec<u32> {
    let mut v = Vec::new();
    for r in &st.rows {
        v.extend(r.t.iter().map(|x| x.to_bits()));
        for ch in 0..3 {
            v.extend(r.c[ch].iter().map(|x| x.to_bits()));
        }
        v.extend(r.d.iter().map(|x| x.to_bits()));
        v.extend(r.last.iter().copied());
    }
    v
}

#[test]
fn vector_variants_are_bit_identical_to_the_portable_kernel() {
    let splats = random_tile_splats(3, 300);
    let list: Vec<u32> = (0..300).collect();
    for smooth in [false, true] {
        let runs = for_each_isa("forward tile kernel", |isa| {
            let (p, s) = run(isa, smooth, &splats, &list);
            (p, bits(&s))
        });
        let (p0, s0) = &runs[0].1;
        assert!(*p0 > 1000);
        for (isa, (p, s)) in &runs[1..] {
            assert_eq!(p0, p, "{isa:?}");
            assert_eq!(s0, s, "{isa:?} smooth {smooth}");
        }
    }
}

/// The tile kernel against a direct per-pixel f32 evaluation of the same compositing rule
/// over the whole list (no row test, no batching): the row test must never drop a pixel.
#[test]
fn tile_kernel_matches_a_direct_per_pixel_loop() {
    let splats = random_tile_splats(11, 400);
    let list: Vec<u32> = (0..400).collect();
    let (pairs, st) = run(augsplat_core::simd::active(), false, &splats, &list);
    let active = active_mask();
    let mut direct_pairs = 0u64;
    for ly in 0..16 {
        for lx in 0..16 {
            let (px, py) = (lx as f32 + 0.5, ly as f32 + 0.5);
            let (mut t, mut c, mut last) = (1.0f64, [0.0f64; 3], 0u32);
            if (active[ly] >> lx) & 1 != 0 {
                for (k, sp) in splats.iter().enumerate() {
                    let (dx, dy) = ((sp.x - px) as f64, (sp.y - py) as f64);
                    let sigma = 0.5 * (sp.a as f64 * dx * dx + sp.c as f64 * dy * dy)
                        + sp.b as f64 * dx * dy;
                    let a = (sp.opacity as f64 * (-sigma).exp()).min(0.99);
                    if sigma < 0.0 || a < ALPHA_THRESHOLD as f64 {
                        continue;
                    }
                    if t * (1.0 - a) <= TRANSMITTANCE_THRESHOLD as f64 {
                        break;
                    }
                    for ch in 0..3 {
                        c[ch] += a * t * sp.rgb[ch] as f64;
                    }
                    t *= 1.0 - a;
                    last = k as u32 + 1;
                    direct_pairs += 1;
                }
            }
            let row = &st.rows[ly];
            assert_eq!(row.last[lx], last, "pixel ({lx}, {ly})");
            assert!((row.t[lx] as f64 - t).abs() < 1e-5, "pixel ({lx}, {ly})");
            for ch in 0..3 {
                assert!((row.c[ch][lx] as f64 - c[ch]).abs() < 1e-5);
            }
        }
    }
    assert_eq!(pairs, direct_pairs);
}

#[cfg(target_arch = "x86_64")]
#[test]
fn vector_transpose_matches_the_portable_one() {
    let mut rng = augsplat_core::Rng::new(21);
    for round in 0..20 {
        let masks: [u16; BATCH] = std::array::from_fn(|j| match round {
            0 => 0xffff,
            1 => 0x8001 << (j % 2),
            _ => rng.below(1 << 16) as u16,
        });
        let want = transpose_portable(&masks);
        for ly in 0..16 {
            for j in 0..BATCH {
                assert_eq!((want[ly] >> j) & 1, ((masks[j] >> ly) & 1) as u64);
            }
        }
        for_each_isa("row-mask transpose", |isa| {
            if isa == Isa::Avx2 {
                #[target_feature(enable = "avx2,fma")]
                fn go2(m: &[u16; BATCH]) -> [u64; 16] {
                    // SAFETY: the caller runs this only in the AVX2 tier.
                    unsafe { <avx2::Avx2 as ForwardKernel>::transpose(m) }
                }
                // SAFETY: `for_each_isa` runs the AVX2 tier only where the CPU has it.
                assert_eq!(unsafe { go2(&masks) }, want);
            }
        });
    }
}

#[test]
fn base_two_exponential_is_accurate() {
    // Coarse steps over the whole range, fine ones over one period of the polynomial.
    let coarse = (0..9190).map(|i| -(i as f32) * 0.0137);
    let fine = (0..=20_000).map(|i| -(i as f32) / 20_000.0);
    let mut worst = 0.0f64;
    for x in coarse.chain(fine) {
        let e = exp2_neg(x) as f64;
        let r = (x as f64).exp2();
        worst = worst.max(((e - r) / r).abs());
    }
    assert!(worst < 2.4e-7, "worst relative error {worst}");
    assert!((exp2_neg(0.0) - 1.0).abs() <= 2.0 * f32::EPSILON);
    assert!(exp2_neg(-1e30) >= 0.0 && exp2_neg(-1e30) < 1e-37);
    assert!(exp2_neg(f32::NEG_INFINITY) < 1e-37);
}

#[test]
fn row_geometry_in_bits_gives_the_gaussian_falloff() {
    // e^−σ from the kernels' base-2 form, against f64 on a rotated anisotropic conic.
    let sp = Splat2D {
        x: 10.3,
        y: -4.7,
        a: 0.37,
        b: -0.11,
        c: 0.21,
        ..Splat2D::default()
    };
    for py in [-9.5f32, -4.5, 0.5, 3.5] {
        let g = RowGeom::new(&sp, py);
        for px in [2.5f32, 8.5, 10.5, 17.5] {
            let dx = sp.x - px;
            let dy = (sp.y - py) as f64;
            let sigma = 0.5 * sp.a as f64 * (dx as f64).powi(2)
                + sp.b as f64 * dx as f64 * dy
                + 0.5 * sp.c as f64 * dy * dy;
            let want = (-sigma).exp();
            let got = gauss_of_exponent(g.exponent(dx)) as f64;
            assert!(
                (got - want).abs() <= 1e-6 * want + 1e-12,
                "({px}, {py}): {got} vs {want}"
            );
        }
    }
}

#[cfg(target_arch = "x86_64")]
#[test]
fn avx2_gaussian_falloff_matches_the_scalar_one_bit_for_bit() {
    if for_each_isa("AVX2 Gaussian falloff", |isa| isa)
        .iter()
        .all(|(isa, _)| *isa != Isa::Avx2)
    {
        return;
    }
    let mut exponents: Vec<f32> = (0..4096).map(|i| i as f32 * -0.0093).collect();
    exponents.extend([
        1.0,
        -0.0,
        0.0,
        f32::NAN,
        f32::INFINITY,
        f32::NEG_INFINITY,
        -SIGMA_CLAMP,
        SIGMA_CLAMP,
        1e-30,
        -1e-30,
        -0.5,
        -43.5,
    ]);
    for chunk in exponents.chunks(8) {
        let mut v = [0.0f32; 8];
        v[..chunk.len()].copy_from_slice(chunk);
        let mut out = [0.0f32; 8];
        // SAFETY: AVX2 + FMA availability was checked above.
        unsafe {
            use std::arch::x86_64::*;
            #[target_feature(enable = "avx2,fma")]
            unsafe fn go(v: &[f32; 8], out: &mut [f32; 8]) {
                let s = _mm256_loadu_ps(v.as_ptr());
                _mm256_storeu_ps(out.as_mut_ptr(), avx2::gauss_v(s));
            }
            go(&v, &mut out);
        }
        for l in 0..8 {
            assert_eq!(
                out[l].to_bits(),
                gauss_of_exponent(v[l]).to_bits(),
                "exponent {}",
                v[l]
            );
        }
    }
}
