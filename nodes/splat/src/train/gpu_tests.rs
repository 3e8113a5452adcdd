//! A view's forward pass sized ahead of its pair count (no wait for the count) against one
//! sized by its count: the same bits in the step's sums and statistics when the slots
//! suffice, nothing at all when they do not. Skips without an adapter (fails under
//! `CI=true`).

use super::gpu::{GpuTarget, GpuTrainer, ViewLoss, ViewResult};
use crate::adam::Adam;
use crate::densify::Densifier;
use crate::gpu::{GpuContext, GpuError, GpuLoss};
use crate::loss::PixelLoss;
use crate::{Gaussians, RenderSettings};

#[test]
fn a_pass_sized_ahead_adds_the_same_bits_and_an_outgrown_one_nothing() {
    let test = "a_pass_sized_ahead_adds_the_same_bits_and_an_outgrown_one_nothing";
    let ctx = match GpuContext::new() {
        Ok(c) => c,
        Err(e @ GpuError::NoAdapter { .. }) => return augsplat_testkit::skip(test, &e.to_string()),
        Err(e) => panic!("{test}: {e}"),
    };
    let cam = augsplat_testkit::cameras::square_pixels(
        64,
        48,
        [
            [1.0, 0.0, 0.0, 0.0],
            [0.0, 1.0, 0.0, 0.0],
            [0.0, 0.0, 1.0, 4.0],
            [0.0, 0.0, 0.0, 1.0],
        ],
    );
    let g = Gaussians::random_cloud(400, 6.0 / cam.fx, 5);
    let n = g.len();
    let adam = Adam::new(n, g.coeffs());
    let stats = Densifier::new(n);
    let rgb: Vec<f32> = (0..64 * 48 * 3).map(|k| (k % 17) as f32 / 16.0).collect();
    let target = GpuTarget::upload(&ctx, &rgb, None, None).unwrap();
    let settings = RenderSettings::default();
    let run = |slots: Option<u32>| -> (ViewResult, Vec<Vec<u32>>) {
        let t = GpuTrainer::upload(&ctx, &g, &adam, &stats).unwrap();
        t.begin_step(&ctx).unwrap();
        let loss = ViewLoss::Gpu {
            target: &target,
            loss: GpuLoss::Photometric {
                kind: PixelLoss::L1,
                ssim_lambda: 0.2,
            },
            scale: 1.0,
        };
        let pending = t
            .add_view(&ctx, &cam, &settings, loss, Some(1.0), 12, slots)
            .unwrap();
        let r = t.finish(&ctx, &[pending]).unwrap()[0];
        let words = |b: &wgpu::Buffer, len: usize| ctx.read_words(b, len).unwrap();
        let sums = vec![
            words(&t.acc_grads, crate::gpu::PARAM_GRAD_STRIDE * n),
            words(&t.acc_sh, 3 * g.coeffs() * n),
            words(&t.acc_visible, n),
            words(&t.grad2d, n),
            words(&t.count, n),
        ];
        (r, sums)
    };
    let (exact, exact_sums) = run(None);
    assert!(!exact.overflowed && exact.tile_pairs > 1000, "{exact:?}");
    assert!(
        exact_sums[0].iter().any(|&w| w != 0),
        "the view adds gradients"
    );
    for slots in [exact.tile_pairs, exact.tile_pairs + 1, 3 * exact.tile_pairs] {
        let (r, sums) = run(Some(slots));
        assert_eq!(r, exact, "{slots} slots");
        assert!(sums == exact_sums, "{slots} slots: the sums differ");
    }
    let (short, sums) = run(Some(exact.tile_pairs - 1));
    assert!(short.overflowed, "{short:?}");
    assert_eq!(short.tile_pairs, exact.tile_pairs);
    for (k, s) in sums.iter().enumerate() {
        assert!(
            s.iter().all(|&w| w == 0),
            "array {k} changed by an outgrown pass"
        );
    }
}

#[test]
fn a_photo_kept_as_bytes_gives_the_bits_of_its_f32_upload() {
    let test = "a_photo_kept_as_bytes_gives_the_bits_of_its_f32_upload";
    let ctx = match GpuContext::new() {
        Ok(c) => c,
        Err(e @ GpuError::NoAdapter { .. }) => return augsplat_testkit::skip(test, &e.to_string()),
        Err(e) => panic!("{test}: {e}"),
    };
    // Which colours are kept as bytes: exactly the decoded bytes' values.
    let table = crate::gpu::u8_values_table();
    assert!(crate::gpu::pack_u8(&table).is_some());
    for off in [
        f32::from_bits(table[77].to_bits() + 1),
        -table[1],
        1.5,
        f32::NAN,
        0.5,
    ] {
        assert!(crate::gpu::pack_u8(&[table[3], off]).is_none(), "{off:e}");
    }
    let cam = augsplat_testkit::cameras::square_pixels(
        40,
        32,
        [
            [1.0, 0.0, 0.0, 0.0],
            [0.0, 1.0, 0.0, 0.0],
            [0.0, 0.0, 1.0, 4.0],
            [0.0, 0.0, 0.0, 1.0],
        ],
    );
    let g = Gaussians::random_cloud(300, 6.0 / cam.fx, 8);
    let n = g.len();
    let (adam, stats) = (Adam::new(n, g.coeffs()), Densifier::new(n));
    // A photo as decoded (odd length: the last word holds three bytes).
    let photo: Vec<f32> = (0..40 * 32 * 3).map(|k| table[(k * 37) % 256]).collect();
    for loss in [
        GpuLoss::Photometric {
            kind: PixelLoss::L1,
            ssim_lambda: 0.2,
        },
        GpuLoss::Photometric {
            kind: PixelLoss::L2,
            ssim_lambda: 0.0,
        },
    ] {
        let run = |bytes_allowed: bool| {
            let target = GpuTarget::upload_as(&ctx, &photo, None, None, bytes_allowed).unwrap();
            assert_eq!(target.is_bytes(), bytes_allowed);
            let t = GpuTrainer::upload(&ctx, &g, &adam, &stats).unwrap();
            t.begin_step(&ctx).unwrap();
            let view = ViewLoss::Gpu {
                target: &target,
                loss,
                scale: 1.0,
            };
            let p = t
                .add_view(&ctx, &cam, &RenderSettings::default(), view, None, 12, None)
                .unwrap();
            let r = t.finish(&ctx, &[p]).unwrap()[0];
            let grads = ctx
                .read_words(&t.acc_grads, crate::gpu::PARAM_GRAD_STRIDE * n)
                .unwrap();
            (r.loss.to_bits(), grads)
        };
        assert!(run(true) == run(false), "{loss:?}");
    }
}
