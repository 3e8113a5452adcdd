//! The per-chunk backward pass: output gradients onto the samples, then the volume-rendering
//! weights, the colour MLP (and appearance embeddings) and the density MLP, down to the
//! gradient of the hash encoding.

use super::{ChunkState, Field, RayInput};
use crate::constants::{GEO_FEAT_DIM, SH_COMPONENTS};
use crate::mlp::{ForwardPass, InputGrad};
use crate::volume;

impl Field {
    /// Adds the photometric/opacity/depth output gradients of ray `r` to the chunk's
    /// per-sample gradients: `d_rgb_out` = ∂L/∂(composited colour), `d_acc` = ∂L/∂A,
    /// `d_depth` = ∂L/∂(Σ w t).
    pub fn add_ray_output_grad(
        &self,
        st: &mut ChunkState,
        rays: &[RayInput],
        r: usize,
        d_rgb_out: [f32; 3],
        d_acc: f32,
        d_depth: f32,
    ) {
        let (a, b) = (st.ray_start[r], st.ray_start[r + 1]);
        let j0: usize = st.n_color[..r].iter().sum();
        let ldc = st.ldc;
        let bg = rays[r].background;
        let d_a = d_acc - (d_rgb_out[0] * bg[0] + d_rgb_out[1] * bg[1] + d_rgb_out[2] * bg[2]);
        for i in a..b {
            st.g[i] += d_a + d_depth * st.t[i];
        }
        for q in 0..st.n_color[r] {
            let j = j0 + q;
            let i = st.alive[j] as usize;
            let c = [st.rgb[j], st.rgb[ldc + j], st.rgb[2 * ldc + j]];
            st.g[i] += d_rgb_out[0] * c[0] + d_rgb_out[1] * c[1] + d_rgb_out[2] * c[2];
            for k in 0..3 {
                st.d_rgb[k * ldc + j] += st.w[i] * d_rgb_out[k];
            }
        }
    }

    /// Backward pass of a chunk after the loss filled `st.g` and `st.d_rgb`. Adds MLP and
    /// embedding gradients to `grad` (the parameter range from `density_offset` on) and leaves
    /// the encoding gradient in `st.d_enc` for [`crate::hashgrid::HashGrid::backward_level`].
    pub fn backward_chunk(
        &self,
        params: &[f32],
        rays: &[RayInput],
        st: &mut ChunkState,
        grad: &mut [f32],
    ) {
        let n = st.n();
        let (ld, ldc) = (st.ld, st.ldc);
        let nc = st.alive.len();
        let e = self.config.appearance_dim as usize;
        let base = self.density_offset;
        // σ gradients through the weights.
        st.d_sigma.clear();
        st.d_sigma.resize(n, 0.0);
        for r in 0..rays.len() {
            let (a, b) = (st.ray_start[r], st.ray_start[r + 1]);
            volume::weights_backward(
                &st.sigma[a..b],
                &st.dt[a..b],
                &st.w[a..b],
                &st.g[a..b],
                &mut st.d_sigma[a..b],
            );
        }
        // Colour MLP backward.
        let mut d_out = std::mem::take(&mut st.scratch2);
        d_out.resize(3 * ldc, 0.0);
        for k in 0..3 {
            d_out[k * ldc + nc..(k + 1) * ldc].fill(0.0);
            for j in 0..nc {
                let c = st.rgb[k * ldc + j];
                d_out[k * ldc + j] = st.d_rgb[k * ldc + j] * c * (1.0 - c);
            }
        }
        let cp = &params[self.color_offset..self.embedding_offset];
        let mut d_cin = std::mem::take(&mut st.d_cin);
        {
            let (cg, eg) = grad[self.color_offset - base..]
                .split_at_mut(self.embedding_offset - self.color_offset);
            let pass = ForwardPass {
                params: cp,
                x: &st.col_in,
                acts: &st.col_acts,
                ld: ldc,
            };
            let d_x = InputGrad {
                d_x: &mut d_cin,
                // Without an appearance embedding only the leading geometry-feature rows
                // need an input gradient, not the 16 SH rows of the view direction; an
                // embedding's rows come last, so then every row is computed.
                rows: if e == 0 { GEO_FEAT_DIM } else { usize::MAX },
            };
            self.color
                .backward(pass, &d_out, cg, Some(d_x), &mut st.mlp_scratch);
            // Embedding gradients.
            if e > 0 {
                let mut j = 0;
                for (r, ray) in rays.iter().enumerate() {
                    for _ in 0..st.n_color[r] {
                        if ray.image < self.config.n_images {
                            let o = ray.image as usize * e;
                            for k in 0..e {
                                eg[o + k] += d_cin[(GEO_FEAT_DIM + SH_COMPONENTS + k) * ldc + j];
                            }
                        }
                        j += 1;
                    }
                }
            }
        }
        // Density MLP output gradient: σ through trunc_exp, geometry features from colour.
        d_out.clear();
        d_out.resize((1 + GEO_FEAT_DIM) * ld, 0.0);
        for i in 0..n {
            // Truncated exp: the gradient is exp of the clamped argument everywhere.
            d_out[i] = st.d_sigma[i] * st.sigma[i];
        }
        // Row by row (sequential reads of each gradient row; the same stores as sample by
        // sample).
        for k in 0..GEO_FEAT_DIM {
            let dst = &mut d_out[(1 + k) * ld..(2 + k) * ld];
            for (&g, &i) in d_cin[k * ldc..k * ldc + nc].iter().zip(&st.alive) {
                dst[i as usize] = g;
            }
        }
        let dp = &params[self.density_offset..self.color_offset];
        let dg = &mut grad[..self.color_offset - base];
        let mut d_enc = std::mem::take(&mut st.d_enc);
        let pass = ForwardPass {
            params: dp,
            x: &st.enc,
            acts: &st.dens_acts,
            ld,
        };
        let d_x = InputGrad {
            d_x: &mut d_enc,
            rows: usize::MAX,
        };
        self.density
            .backward(pass, &d_out, dg, Some(d_x), &mut st.mlp_scratch);
        st.d_enc = d_enc;
        st.scratch2 = d_out;
        st.d_cin = d_cin;
    }
}
