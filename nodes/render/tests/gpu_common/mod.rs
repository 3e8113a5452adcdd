//! What the GPU tests share: a context on the first adapter (or a skip when there is none), and
//! the one-tile case of many faint Gaussians that lavapipe's loop cap once cut short.

use augsplat_render::gpu::{GpuContext, GpuError};

/// A context on the first adapter (named on stderr), or `None` after a skip message when no
/// GPU adapter is found — a failure under `CI=true`, where `.ci/run` installs lavapipe. Any
/// other error opening the device fails `test`.
pub fn context(test: &str) -> Option<GpuContext> {
    match GpuContext::new() {
        Ok(c) => {
            eprintln!("{test}: on {}", c.adapter());
            Some(c)
        }
        Err(e @ GpuError::NoAdapter { .. }) => {
            augsplat_testkit::skip(test, &e.to_string());
            None
        }
        Err(e) => panic!("{test}: {e}"),
    }
}

/// A 16×16 view (one tile) of 40,000 faint Gaussians (α at most 0.005, about two pixels wide,
/// anisotropic): every one bins into the tile, and no pixel reaches the transmittance cut, so
/// each runs through more than 32,768 pairs. Lavapipe ends an invocation's loops after 65,535
/// iterations in all (Mesa's `LP_MAX_TGSI_LOOP_ITERATIONS`, shared by every loop of a shader):
/// a kernel that loops more than once a pair cuts this tile short there. Asserts that the
/// CPU's render is such a case.
#[allow(dead_code)]
pub fn faint_tile() -> (augsplat_core::Camera, augsplat_render::Gaussians) {
    let (cam, g) = faint_tile_of(40_000);
    let out = augsplat_render::render(&g, &cam, &faint_settings());
    assert!(
        out.stats.visible > 36_000 && out.alpha.iter().all(|&a| a < 0.999),
        "the case must put more than 32,768 pairs in the tile and leave its pixels open: {:?}",
        out.stats
    );
    (cam, g)
}

/// The settings [`faint_tile`] is rendered with.
#[allow(dead_code)]
pub fn faint_settings() -> augsplat_render::RenderSettings {
    augsplat_render::RenderSettings {
        sh_degree: 0,
        ..Default::default()
    }
}

/// [`faint_tile`]'s view with `n` of its Gaussians (nearly all of them bin into the tile).
#[allow(dead_code)]
pub fn faint_tile_of(n: usize) -> (augsplat_core::Camera, augsplat_render::Gaussians) {
    let cam = augsplat_testkit::cameras::facing(16, 16, 4.0);
    let mut g = augsplat_render::Gaussians::random_cloud(n, 4.0 / cam.fx, 7);
    let scale = (2.0 * 4.0 / cam.fx as f32).ln();
    for (l, s) in g.opacity_logits.iter_mut().zip(g.log_scales.iter_mut()) {
        *l = -5.3;
        *s = [scale + 0.3, scale, scale - 0.3];
    }
    (cam, g)
}
