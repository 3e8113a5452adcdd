//! The viewer's model payload (layout version 1): 24 bytes per Gaussian, little-endian.
//!
//! | bytes | field | encoding |
//! |---|---|---|
//! | 0–5 | centre x, y, z | u16 each, `min + q / 65535 · (max − min)` over the model's box |
//! | 6–11 | log-scales | IEEE half each |
//! | 12–17 | SH DC coefficients R, G, B | IEEE half each |
//! | 18–19 | opacity, sigmoid(logit) | IEEE half |
//! | 20–23 | rotation quaternion w, x, y, z | i8 each, normalised × 127, rounded |
//!
//! Only the SH DC term is kept: the viewer shows degree-0 colour `max(0.5 + C0·dc, 0)` (the
//! higher bands would take 45 more values per Gaussian). A model above the cap keeps its most
//! opaque Gaussians (ties by index), so the payload is deterministic.

use augsplat_splat::Gaussians;

/// Bytes per Gaussian in the payload.
pub const BYTES_PER_GAUSSIAN: usize = 24;

/// A model quantised for the viewer.
#[derive(Clone, Debug, PartialEq)]
pub struct PackedModel {
    /// Gaussians in the payload.
    pub count: usize,
    /// Gaussians of the model before the cap and the removal of invalid ones.
    pub total: usize,
    /// The box the centres are quantised over: min x, y, z then max x, y, z.
    pub bounds: [f32; 6],
    /// [`BYTES_PER_GAUSSIAN`] bytes per Gaussian.
    pub payload: Vec<u8>,
}

/// IEEE 754 binary16 bits of `v`, rounded to nearest even (overflow gives ±∞; the packer never
/// stores a non-finite value: it drops Gaussians with one).
pub fn f16_bits(v: f32) -> u16 {
    augsplat_core::float16::from_f32(v)
}

/// The value of binary16 bits (for tests and the f64 reference of the viewer's decode).
pub fn f16_value(h: u16) -> f32 {
    let sign = if h & 0x8000 != 0 { -1.0f32 } else { 1.0 };
    let exp = ((h >> 10) & 0x1f) as i32;
    let man = (h & 0x3ff) as f32;
    match exp {
        0 => sign * man * 2f32.powi(-24),
        0x1f if man == 0.0 => sign * f32::INFINITY,
        0x1f => f32::NAN,
        _ => sign * (1.0 + man / 1024.0) * 2f32.powi(exp - 15),
    }
}

fn sigmoid(x: f32) -> f32 {
    1.0 / (1.0 + (-x).exp())
}

/// Whether Gaussian `i` can be shown: finite values, a non-zero quaternion and an opacity of
/// at least 1/255 (the rasteriser culls the rest).
fn showable(g: &Gaussians, i: usize) -> bool {
    let k = g.coeffs();
    let q = g.quats[i];
    let qn = q.iter().map(|v| v * v).sum::<f32>();
    g.means[i].iter().all(|v| v.is_finite())
        && g.log_scales[i]
            .iter()
            .all(|v| v.is_finite() && v.abs() < 60.0)
        && q.iter().all(|v| v.is_finite())
        && qn > 1e-24
        && g.opacity_logits[i].is_finite()
        && sigmoid(g.opacity_logits[i]) >= 1.0 / 255.0
        && g.sh[i * k * 3..i * k * 3 + 3].iter().all(|v| v.is_finite())
}

/// Quantises `g` into the payload, keeping at most `max_gaussians` (the most opaque).
pub fn pack(g: &Gaussians, max_gaussians: usize) -> PackedModel {
    let mut keep: Vec<usize> = (0..g.len()).filter(|&i| showable(g, i)).collect();
    if keep.len() > max_gaussians {
        // Most opaque first, ties by index; then back to index order.
        keep.sort_by(|&a, &b| {
            g.opacity_logits[b]
                .total_cmp(&g.opacity_logits[a])
                .then(a.cmp(&b))
        });
        keep.truncate(max_gaussians);
        keep.sort_unstable();
    }
    let mut lo = [f32::INFINITY; 3];
    let mut hi = [f32::NEG_INFINITY; 3];
    for &i in &keep {
        for a in 0..3 {
            lo[a] = lo[a].min(g.means[i][a]);
            hi[a] = hi[a].max(g.means[i][a]);
        }
    }
    if keep.is_empty() {
        lo = [0.0; 3];
        hi = [0.0; 3];
    }
    let k = g.coeffs();
    let mut payload = Vec::with_capacity(keep.len() * BYTES_PER_GAUSSIAN);
    for &i in &keep {
        for a in 0..3 {
            let span = f64::from(hi[a]) - f64::from(lo[a]);
            let q = if span > 0.0 {
                ((f64::from(g.means[i][a]) - f64::from(lo[a])) / span * 65535.0).round()
            } else {
                0.0
            };
            payload.extend_from_slice(&(q.clamp(0.0, 65535.0) as u16).to_le_bytes());
        }
        for v in g.log_scales[i] {
            payload.extend_from_slice(&f16_bits(v).to_le_bytes());
        }
        for v in &g.sh[i * k * 3..i * k * 3 + 3] {
            payload.extend_from_slice(&f16_bits(*v).to_le_bytes());
        }
        payload.extend_from_slice(&f16_bits(sigmoid(g.opacity_logits[i])).to_le_bytes());
        let q = g.quats[i];
        let n = q.iter().map(|v| f64::from(*v).powi(2)).sum::<f64>().sqrt();
        for v in q {
            payload.push(((f64::from(v) / n * 127.0).round() as i8) as u8);
        }
    }
    PackedModel {
        count: keep.len(),
        total: g.len(),
        bounds: [lo[0], lo[1], lo[2], hi[0], hi[1], hi[2]],
        payload,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn half_conversion_rounds_to_nearest_even() {
        for (v, bits) in [
            (0.0f32, 0x0000u16),
            (-0.0, 0x8000),
            (1.0, 0x3c00),
            (-2.0, 0xc000),
            (65504.0, 0x7bff),
            (65520.0, 0x7c00),
            (1e6, 0x7c00),
            (f32::INFINITY, 0x7c00),
            (6.103_515_6e-5, 0x0400),
            (5.960_464_5e-8, 0x0001),
            (2.98e-8, 0x0000),
            (0.333_333_34, 0x3555),
            (1.000_488_3, 0x3c00),
            (1.000_488_4, 0x3c01),
        ] {
            assert_eq!(f16_bits(v), bits, "{v}");
        }
        assert!(f16_value(f16_bits(f32::NAN)).is_nan());
        // Every half value round-trips.
        for h in 0..=0xffffu16 {
            let v = f16_value(h);
            if v.is_nan() {
                continue;
            }
            assert_eq!(f16_bits(v), h, "{h:#06x} = {v}");
        }
    }

    #[test]
    fn pack_layout_and_cap() {
        let mut g = Gaussians::empty(1);
        for i in 0..4 {
            g.means.push([i as f32, -1.0 + i as f32 * 0.5, 2.0]);
            g.log_scales.push([-1.0, -2.0, -3.0]);
            g.quats.push([2.0, 0.0, 0.0, 0.0]);
            g.opacity_logits.push(i as f32 - 1.0);
            g.sh.extend((0..12).map(|k| k as f32 * 0.1));
        }
        let p = pack(&g, 10);
        assert_eq!((p.count, p.total), (4, 4));
        assert_eq!(p.payload.len(), 4 * BYTES_PER_GAUSSIAN);
        assert_eq!(p.bounds, [0.0, -1.0, 2.0, 3.0, 0.5, 2.0]);
        let g1 = &p.payload[BYTES_PER_GAUSSIAN..2 * BYTES_PER_GAUSSIAN];
        let u16_at = |o: usize| u16::from_le_bytes([g1[o], g1[o + 1]]);
        assert_eq!(u16_at(0), 21845); // 1/3 of the x range
        assert_eq!(u16_at(4), 0); // z range is empty
        assert_eq!(f16_value(u16_at(6)), -1.0);
        assert_eq!(f16_value(u16_at(12)), 0.0);
        assert!((f16_value(u16_at(16)) - 0.2).abs() < 1e-3);
        assert_eq!(f16_value(u16_at(18)), 0.5); // sigmoid(0)
        assert_eq!(&g1[20..24], &[127, 0, 0, 0]);
        // The cap keeps the most opaque, in index order.
        let c = pack(&g, 2);
        assert_eq!((c.count, c.total), (2, 4));
        assert_eq!(c.bounds[0], 2.0);
        // Invalid Gaussians are dropped.
        g.means[0][1] = f32::NAN;
        g.quats[3] = [0.0; 4];
        assert_eq!(pack(&g, 10).count, 2);
    }
}
