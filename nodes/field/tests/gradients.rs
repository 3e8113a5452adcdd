//! Analytic gradients of every kernel against central finite differences of the independent
//! f64 references, and the fast forward passes against the references.
#![allow(clippy::needless_range_loop)]

use augsplat_core::Rng;
use augsplat_field::constants::GEO_FEAT_DIM;
use augsplat_field::contraction::{contract_backward, contract_f64, contract_jacobian_f64};
use augsplat_field::field::{ChunkState, Field, FieldConfig, RayInput};
use augsplat_field::hashgrid::{HashGrid, HashGridConfig, PointBatch};
use augsplat_field::mlp::{padded, BackwardScratch, ForwardPass, InputGrad, Mlp};
use augsplat_field::occupancy::OccupancyGrid;
use augsplat_field::{reference, volume};

fn close(a: f64, b: f64, rel: f64, abs: f64) -> bool {
    (a - b).abs() <= abs + rel * a.abs().max(b.abs())
}

fn small_grid() -> HashGrid {
    // Mix of dense (coarse) and hashed (fine) levels.
    HashGrid::new(HashGridConfig {
        levels: 4,
        features_per_level: 2,
        log2_table_size: 8,
        base_resolution: 3,
        max_resolution: 40,
    })
    .unwrap()
}

#[test]
fn hash_encoding_matches_reference_and_finite_differences() {
    let grid = small_grid();
    assert!(
        grid.dense[0] && !grid.dense[3],
        "test should cover dense and hashed levels"
    );
    let mut rng = Rng::new(1);
    let table: Vec<f32> = (0..grid.n_params())
        .map(|_| rng.uniform(-1.0, 1.0) as f32)
        .collect();
    let n = 7;
    let ld = padded(n);
    let pts: Vec<[f32; 3]> = (0..n)
        .map(|_| [rng.next_f32(), rng.next_f32(), rng.next_f32()])
        .collect();
    let (px, py, pz): (Vec<f32>, Vec<f32>, Vec<f32>) = (
        pts.iter().map(|p| p[0]).collect(),
        pts.iter().map(|p| p[1]).collect(),
        pts.iter().map(|p| p[2]).collect(),
    );
    let mut out = vec![0f32; grid.output_dim() * ld];
    let batch = PointBatch {
        px: &px,
        py: &py,
        pz: &pz,
        n,
        ld,
    };
    grid.encode(&table, batch, &mut out);
    let t64: Vec<f64> = table.iter().map(|&v| v as f64).collect();
    for i in 0..n {
        let r = reference::hash_encode(&grid, &t64, pts[i].map(|v| v as f64));
        for k in 0..grid.output_dim() {
            assert!(
                close(out[k * ld + i] as f64, r[k], 1e-5, 1e-6),
                "point {i} channel {k}: {} vs {}",
                out[k * ld + i],
                r[k]
            );
        }
    }
    // L = Σ_i Σ_k c_ik enc_ik; analytic table gradient vs central differences.
    let coef: Vec<f32> = (0..grid.output_dim() * ld)
        .map(|j| {
            if j % ld < n {
                rng.uniform(-1.0, 1.0) as f32
            } else {
                0.0
            }
        })
        .collect();
    let mut grad = vec![0f32; grid.n_params()];
    for l in 0..grid.levels() {
        let range = grid.level_range(l);
        grid.backward_level(l, batch, &coef, &mut grad[range]);
    }
    let loss = |t: &[f64]| -> f64 {
        let mut s = 0.0;
        for i in 0..n {
            let r = reference::hash_encode(&grid, t, pts[i].map(|v| v as f64));
            for k in 0..grid.output_dim() {
                s += coef[k * ld + i] as f64 * r[k];
            }
        }
        s
    };
    let mut checked = 0;
    for j in (0..grid.n_params()).step_by(3) {
        let mut tp = t64.clone();
        let h = 1e-4;
        tp[j] += h;
        let lp = loss(&tp);
        tp[j] -= 2.0 * h;
        let lm = loss(&tp);
        let fd = (lp - lm) / (2.0 * h);
        assert!(
            close(grad[j] as f64, fd, 1e-4, 1e-6),
            "entry {j}: analytic {} fd {fd}",
            grad[j]
        );
        checked += (fd != 0.0) as usize;
    }
    assert!(checked > 20, "too few touched entries checked ({checked})");
}

#[test]
fn mlp_matches_reference_and_finite_differences() {
    let mlp = Mlp::new(5, 12, 2, 3);
    let mut rng = Rng::new(2);
    let mut params = vec![0f32; mlp.n_params()];
    mlp.init(&mut params, &mut rng);
    for p in params.iter_mut() {
        *p += rng.uniform(-0.1, 0.1) as f32; // non-zero biases
    }
    let n = 21;
    let ld = padded(n);
    let mut x = vec![0f32; 5 * ld];
    for k in 0..5 {
        for i in 0..n {
            x[k * ld + i] = rng.uniform(-1.0, 1.0) as f32;
        }
    }
    let mut acts = Vec::new();
    mlp.forward(&params, &x, ld, &mut acts);
    let p64: Vec<f64> = params.iter().map(|&v| v as f64).collect();
    let xs = |i: usize| (0..5).map(|k| x[k * ld + i] as f64).collect::<Vec<f64>>();
    for i in 0..n {
        let r = reference::mlp_forward(&mlp, &p64, &xs(i));
        for k in 0..3 {
            assert!(close(acts[2][k * ld + i] as f64, r[k], 1e-5, 1e-6));
        }
    }
    let coef: Vec<f32> = (0..3 * ld)
        .map(|j| {
            if j % ld < n {
                rng.uniform(-1.0, 1.0) as f32
            } else {
                0.0
            }
        })
        .collect();
    let d_out = coef.clone();
    let mut grad = vec![0f32; mlp.n_params()];
    let mut dx = Vec::new();
    let pass = ForwardPass {
        params: &params,
        x: &x,
        acts: &acts,
        ld,
    };
    let d_x = InputGrad {
        d_x: &mut dx,
        rows: usize::MAX,
    };
    let mut scratch = BackwardScratch::default();
    mlp.backward(pass, &d_out, &mut grad, Some(d_x), &mut scratch);
    let loss = |p: &[f64], xv: &dyn Fn(usize) -> Vec<f64>| -> f64 {
        (0..n)
            .map(|i| {
                let r = reference::mlp_forward(&mlp, p, &xv(i));
                (0..3).map(|k| coef[k * ld + i] as f64 * r[k]).sum::<f64>()
            })
            .sum()
    };
    let h = 1e-6;
    for j in 0..mlp.n_params() {
        let mut pp = p64.clone();
        pp[j] += h;
        let lp = loss(&pp, &xs);
        pp[j] -= 2.0 * h;
        let lm = loss(&pp, &xs);
        let fd = (lp - lm) / (2.0 * h);
        assert!(
            close(grad[j] as f64, fd, 1e-3, 1e-5),
            "param {j}: analytic {} fd {fd}",
            grad[j]
        );
    }
    for i in 0..n {
        for k in 0..5 {
            let shifted = |s: f64| {
                move |q: usize| {
                    let mut v = xs(q);
                    if q == i {
                        v[k] += s;
                    }
                    v
                }
            };
            let fd = (loss(&p64, &shifted(h)) - loss(&p64, &shifted(-h))) / (2.0 * h);
            assert!(
                close(dx[k * ld + i] as f64, fd, 1e-3, 1e-5),
                "input ({k},{i}): {} vs {fd}",
                dx[k * ld + i]
            );
        }
    }
}

#[test]
fn contraction_jacobian_matches_finite_differences() {
    let mut rng = Rng::new(3);
    for trial in 0..40 {
        let s = if trial < 10 { 0.8 } else { 6.0 };
        let x = [rng.uniform(-s, s), rng.uniform(-s, s), rng.uniform(-s, s)];
        let r = (x[0] * x[0] + x[1] * x[1] + x[2] * x[2]).sqrt();
        if (r - 1.0).abs() < 1e-3 {
            continue;
        }
        let j = contract_jacobian_f64(x);
        let h = 1e-6;
        for b in 0..3 {
            let mut xp = x;
            xp[b] += h;
            let mut xm = x;
            xm[b] -= h;
            let (cp, cm) = (contract_f64(xp), contract_f64(xm));
            for a in 0..3 {
                let fd = (cp[a] - cm[a]) / (2.0 * h);
                assert!(
                    close(j[a][b], fd, 1e-6, 1e-8),
                    "x {x:?} J[{a}][{b}] {} vs {fd}",
                    j[a][b]
                );
            }
        }
        // Contracted points stay inside radius 2; the f32 chain rule agrees.
        let c = contract_f64(x);
        assert!((c[0] * c[0] + c[1] * c[1] + c[2] * c[2]).sqrt() < 2.0);
        let dc = [0.3f32, -0.7, 1.1];
        let dx = contract_backward(x.map(|v| v as f32), dc);
        for b in 0..3 {
            let want: f64 = (0..3).map(|a| j[a][b] * dc[a] as f64).sum();
            assert!(close(dx[b] as f64, want, 1e-5, 1e-6));
        }
    }
    // Extreme radii: finite, bounded.
    for r in [1e-30f64, 1e6, 1e30] {
        let c = contract_f64([r, 0.0, 0.0]);
        assert!(c[0].is_finite() && c[0] <= 2.0);
        let j = contract_jacobian_f64([r, 0.0, 0.0]);
        assert!(j.iter().flatten().all(|v| v.is_finite()));
    }
}

/// Volume rendering + DS-NeRF depth + distortion losses of one ray: analytic ∂/∂σ and ∂/∂c
/// against central differences of the f64 reference (with the early-termination cut fixed).
#[test]
fn volume_rendering_matches_finite_differences() {
    let mut rng = Rng::new(4);
    for trial in 0..6 {
        let n = 14;
        let sigma: Vec<f32> = (0..n)
            .map(|_| rng.uniform(0.0, if trial % 2 == 0 { 3.0 } else { 30.0 }) as f32)
            .collect();
        let dt: Vec<f32> = (0..n).map(|_| rng.uniform(0.02, 0.2) as f32).collect();
        let mut t = Vec::new();
        let mut acc = 0.3f32;
        for i in 0..n {
            t.push(acc + 0.5 * dt[i]);
            acc += dt[i];
        }
        let m: Vec<f32> = (0..n).map(|i| 0.1 * i as f32 + 0.05).collect();
        let ds = vec![0.1f32; n];
        let rgb: Vec<[f32; 3]> = (0..n)
            .map(|_| [rng.next_f32(), rng.next_f32(), rng.next_f32()])
            .collect();
        let bg = [0.2f32, 0.5, 0.9];
        let mut w = vec![0f32; n];
        let n_color = volume::weights_forward(&sigma, &dt, &mut w);
        let (dc, da, dd, z, s, lam_d, lam_x) = (
            [0.7f32, -0.4, 0.25],
            0.3f32,
            -0.2f32,
            t[n / 2] + 0.01,
            0.08f32,
            0.05f32,
            0.3f32,
        );
        // Analytic: g_i and dc_i as the field does it.
        let mut g = vec![0f32; n];
        let da_eff = da - (dc[0] * bg[0] + dc[1] * bg[1] + dc[2] * bg[2]);
        let mut drgb = vec![[0f32; 3]; n];
        for i in 0..n {
            g[i] += da_eff + dd * t[i];
            if i < n_color {
                g[i] += dc[0] * rgb[i][0] + dc[1] * rgb[i][1] + dc[2] * rgb[i][2];
                for k in 0..3 {
                    drgb[i][k] = w[i] * dc[k];
                }
            }
        }
        volume::ds_nerf_depth(&w, &t, &dt, z, s, lam_d, &mut g);
        volume::distortion(&w, &m, &ds, lam_x, &mut g);
        let mut d_sigma = vec![0f32; n];
        volume::weights_backward(&sigma, &dt, &w, &g, &mut d_sigma);
        let f64v = |v: &[f32]| v.iter().map(|&x| x as f64).collect::<Vec<f64>>();
        let (dt64, t64, m64, ds64) = (f64v(&dt), f64v(&t), f64v(&m), f64v(&ds));
        let loss = |sg: &[f64], col: &[[f64; 3]]| -> f64 {
            let (c, a, d, w) =
                reference::render_ray(sg, &dt64, &t64, col, n_color, bg.map(|v| v as f64));
            (0..3).map(|k| dc[k] as f64 * c[k]).sum::<f64>()
                + da as f64 * a
                + dd as f64 * d
                + lam_d as f64 * reference::ds_nerf_depth(&w, &t64, &dt64, z as f64, s as f64)
                + lam_x as f64 * reference::distortion(&w, &m64, &ds64)
        };
        let s64 = f64v(&sigma);
        let c64: Vec<[f64; 3]> = rgb.iter().map(|c| c.map(|v| v as f64)).collect();
        // Forward agrees with the reference.
        let (_, a_ref, d_ref, w_ref) =
            reference::render_ray(&s64, &dt64, &t64, &c64, n_color, [0.0; 3]);
        let (a32, d32) = volume::opacity_depth(&w, &t);
        assert!(close(a32 as f64, a_ref, 1e-5, 1e-6) && close(d32 as f64, d_ref, 1e-5, 1e-6));
        for i in 0..n {
            assert!(close(w[i] as f64, w_ref[i], 1e-4, 1e-7));
        }
        for i in 0..n {
            let h = 1e-6 * s64[i].max(1.0);
            let mut sp = s64.clone();
            sp[i] += h;
            let lp = loss(&sp, &c64);
            sp[i] -= 2.0 * h;
            let lm = loss(&sp, &c64);
            let fd = (lp - lm) / (2.0 * h);
            assert!(
                close(d_sigma[i] as f64, fd, 2e-3, 1e-5),
                "trial {trial} σ_{i}: analytic {} fd {fd}",
                d_sigma[i]
            );
            for k in 0..3 {
                let mut cp = c64.clone();
                cp[i][k] += 1e-6;
                let lp = loss(&s64, &cp);
                cp[i][k] -= 2e-6;
                let lm = loss(&s64, &cp);
                let fd = (lp - lm) / 2e-6;
                assert!(
                    close(drgb[i][k] as f64, fd, 1e-3, 1e-6),
                    "c_{i}[{k}]: {} vs {fd}",
                    drgb[i][k]
                );
            }
        }
    }
}

/// The whole field on one chunk of rays (encoding → density → weights → colour with SH and
/// appearance → compositing → losses → backward) against finite differences of the f64
/// reference evaluated at the same samples.
#[test]
fn field_chunk_gradient_matches_finite_differences() {
    let cfg = FieldConfig {
        grid: HashGridConfig {
            levels: 3,
            features_per_level: 2,
            log2_table_size: 9,
            base_resolution: 4,
            max_resolution: 24,
        },
        hidden_width: 8,
        appearance_dim: 3,
        n_images: 2,
        center: [0.0; 3],
        radius: 1.0,
        near: 0.1,
        far: 3.0,
        march_steps: 24,
        occupancy_resolution: 8,
    };
    let field = Field::new(cfg).unwrap();
    let mut params = field.init_params(5);
    let mut rng = Rng::new(6);
    for p in params[..field.density_offset].iter_mut() {
        *p = rng.uniform(-0.5, 0.5) as f32; // a non-trivial grid
    }
    let occ = OccupancyGrid::full(8);
    let rays: Vec<RayInput> = (0..3)
        .map(|r| {
            let d = augsplat_core::linalg::normalize([0.3 * r as f64 - 0.3, 0.2, 1.0]);
            RayInput {
                origin: [0.1, -0.2, -1.5],
                dir: d.map(|v| v as f32),
                image: r as u32 % 2,
                background: [0.3, 0.6, 0.1],
            }
        })
        .collect();
    let mean_emb = field.mean_embedding(&params);
    let mut st = ChunkState::default();
    field.forward_chunk(
        &params,
        &occ,
        &rays,
        &|r| 0.25 * r as f32,
        &mean_emb,
        &mut st,
    );
    let targets = [[0.2f32, 0.4, 0.6], [0.9, 0.1, 0.5], [0.5, 0.5, 0.5]];
    for r in 0..rays.len() {
        let o = st.out[r];
        let d = [0, 1, 2].map(|k| 2.0 * (o.rgb[k] - targets[r][k]));
        field.add_ray_output_grad(&mut st, &rays, r, d, 0.0, 0.1);
    }
    let mut grad = vec![0f32; field.n_params];
    let base = field.density_offset;
    field.backward_chunk(&params, &rays, &mut st, &mut grad[base..]);
    for l in 0..field.grid.levels() {
        let range = field.grid.level_range(l);
        field
            .grid
            .backward_level(l, st.points(), &st.d_enc, &mut grad[range]);
    }
    // Reference loss at the same samples and cuts.
    let samples: Vec<(usize, usize, usize)> = (0..rays.len())
        .map(|r| (st.ray_start[r], st.ray_start[r + 1], st.n_color[r]))
        .collect();
    let (px, py, pz, t, dt) = (
        st.px.clone(),
        st.py.clone(),
        st.pz.clone(),
        st.t.clone(),
        st.dt.clone(),
    );
    let e = 3usize;
    let loss = |p: &[f64]| -> f64 {
        let mut total = 0.0;
        for (r, &(a, b, nc)) in samples.iter().enumerate() {
            let img = rays[r].image as usize;
            let emb = &p[field.embedding_offset + img * e..field.embedding_offset + img * e + e];
            let dir = rays[r].dir.map(|v| v as f64);
            let mut sg = Vec::new();
            let mut col = Vec::new();
            for i in a..b {
                let (s, c) = reference::field_sample(
                    &field,
                    p,
                    [px[i] as f64, py[i] as f64, pz[i] as f64],
                    dir,
                    emb,
                );
                sg.push(s);
                col.push(c);
            }
            let dt64: Vec<f64> = dt[a..b].iter().map(|&v| v as f64).collect();
            let t64: Vec<f64> = t[a..b].iter().map(|&v| v as f64).collect();
            let (c, _, d, _) = reference::render_ray(
                &sg,
                &dt64,
                &t64,
                &col,
                nc,
                rays[r].background.map(|v| v as f64),
            );
            total += (0..3)
                .map(|k| (c[k] - targets[r][k] as f64).powi(2))
                .sum::<f64>()
                + 0.1 * d;
        }
        total
    };
    let p64: Vec<f64> = params.iter().map(|&v| v as f64).collect();
    assert!(st.n() > 10, "rays should produce samples");
    let mut idx: Vec<usize> = (0..field.n_params).filter(|&j| grad[j] != 0.0).collect();
    let nz = idx.len();
    idx.retain(|j| j % 7 == 0 || *j >= field.density_offset && j % 3 == 0);
    assert!(nz > 50);
    let mut worst = 0f64;
    for &j in &idx {
        let h = 1e-5;
        let mut pp = p64.clone();
        pp[j] += h;
        let lp = loss(&pp);
        pp[j] -= 2.0 * h;
        let lm = loss(&pp);
        let fd = (lp - lm) / (2.0 * h);
        let err = (grad[j] as f64 - fd).abs() / (1e-4 + fd.abs().max((grad[j] as f64).abs()));
        worst = worst.max(err);
        assert!(
            close(grad[j] as f64, fd, 5e-3, 5e-5),
            "param {j}: analytic {} fd {fd}",
            grad[j]
        );
    }
    // Every kind of parameter was exercised.
    for (name, lo, hi) in [
        ("grid", 0, field.density_offset),
        ("density", field.density_offset, field.color_offset),
        ("color", field.color_offset, field.embedding_offset),
        ("embedding", field.embedding_offset, field.n_params),
    ] {
        assert!(
            idx.iter().any(|&j| j >= lo && j < hi),
            "no {name} parameter checked"
        );
    }
    let _ = (worst, GEO_FEAT_DIM);
}
