//! Real spherical harmonics of a unit view direction up to degree 4 (16 components), the
//! directional encoding of nerfacto's colour network.

use crate::constants::SH_COMPONENTS;

/// The 16 real SH basis values of unit direction `d` (degrees 0–3, i.e. "degree 4" in
/// nerfstudio's counting).
pub fn sh_encode(d: [f32; 3]) -> [f32; SH_COMPONENTS] {
    let [x, y, z] = d;
    let (xx, yy, zz) = (x * x, y * y, z * z);
    [
        0.282_094_8,
        0.488_602_5 * y,
        0.488_602_5 * z,
        0.488_602_5 * x,
        1.092_548_4 * x * y,
        1.092_548_4 * y * z,
        0.946_174_7 * zz - 0.315_391_57,
        1.092_548_4 * x * z,
        0.546_274_2 * (xx - yy),
        0.590_043_6 * y * (3.0 * xx - yy),
        2.890_611_4 * x * y * z,
        0.457_045_8 * y * (5.0 * zz - 1.0),
        0.373_176_33 * z * (5.0 * zz - 3.0),
        0.457_045_8 * x * (5.0 * zz - 1.0),
        1.445_305_7 * z * (xx - yy),
        0.590_043_6 * x * (xx - 3.0 * yy),
    ]
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The basis is orthonormal on the sphere: a quadrature over a fine grid gives the identity.
    #[test]
    fn sh_basis_is_orthonormal() {
        let (nt, np) = (200, 400);
        let mut g = vec![0f64; SH_COMPONENTS * SH_COMPONENTS];
        for it in 0..nt {
            let th = std::f64::consts::PI * (it as f64 + 0.5) / nt as f64;
            for ip in 0..np {
                let ph = 2.0 * std::f64::consts::PI * (ip as f64 + 0.5) / np as f64;
                let d = [th.sin() * ph.cos(), th.sin() * ph.sin(), th.cos()];
                let y = sh_encode([d[0] as f32, d[1] as f32, d[2] as f32]);
                let dw = th.sin()
                    * (std::f64::consts::PI / nt as f64)
                    * (2.0 * std::f64::consts::PI / np as f64);
                for a in 0..SH_COMPONENTS {
                    for b in 0..SH_COMPONENTS {
                        g[a * SH_COMPONENTS + b] += y[a] as f64 * y[b] as f64 * dw;
                    }
                }
            }
        }
        for a in 0..SH_COMPONENTS {
            for b in 0..SH_COMPONENTS {
                let want = if a == b { 1.0 } else { 0.0 };
                assert!(
                    (g[a * SH_COMPONENTS + b] - want).abs() < 2e-3,
                    "({a},{b}) = {}",
                    g[a * SH_COMPONENTS + b]
                );
            }
        }
    }
}
