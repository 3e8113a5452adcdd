//! mip-NeRF 360 scene contraction: identity inside the unit ball, `(2 − 1/r) x / r` outside,
//! mapping all of space into a ball of radius 2. Points are first expressed in *field units*
//! `(p − centre) / radius`, so the unit ball holds the well-observed part of the scene.

/// Contracts `x` (field units).
#[inline]
pub fn contract(x: [f32; 3]) -> [f32; 3] {
    let r2 = x[0] * x[0] + x[1] * x[1] + x[2] * x[2];
    if r2 <= 1.0 {
        return x;
    }
    let r = r2.sqrt();
    let s = (2.0 - 1.0 / r) / r;
    [x[0] * s, x[1] * s, x[2] * s]
}

/// Jacobian `∂contract/∂x` (row-major 3×3) at `x`, f32.
pub fn contract_jacobian(x: [f32; 3]) -> [[f32; 3]; 3] {
    let j = contract_jacobian_f64([x[0] as f64, x[1] as f64, x[2] as f64]);
    j.map(|row| row.map(|v| v as f32))
}

/// Contraction in f64.
pub fn contract_f64(x: [f64; 3]) -> [f64; 3] {
    let r2 = x[0] * x[0] + x[1] * x[1] + x[2] * x[2];
    if r2 <= 1.0 {
        return x;
    }
    let r = r2.sqrt();
    let s = (2.0 - 1.0 / r) / r;
    [x[0] * s, x[1] * s, x[2] * s]
}

/// Analytic Jacobian in f64: with `g(r) = 2/r − 1/r²`, `J = g I + g'(r) x xᵀ / r`.
pub fn contract_jacobian_f64(x: [f64; 3]) -> [[f64; 3]; 3] {
    let r2 = x[0] * x[0] + x[1] * x[1] + x[2] * x[2];
    let mut j = [[0f64; 3]; 3];
    if r2 <= 1.0 {
        for (a, row) in j.iter_mut().enumerate() {
            row[a] = 1.0;
        }
        return j;
    }
    let r = r2.sqrt();
    let g = 2.0 / r - 1.0 / r2;
    let dg = -2.0 / r2 + 2.0 / (r2 * r);
    for a in 0..3 {
        for b in 0..3 {
            j[a][b] = dg * x[a] * x[b] / r + if a == b { g } else { 0.0 };
        }
    }
    j
}

/// Chain rule through the contraction: `∂L/∂x = Jᵀ ∂L/∂c`.
pub fn contract_backward(x: [f32; 3], d_c: [f32; 3]) -> [f32; 3] {
    let j = contract_jacobian(x);
    let mut out = [0f32; 3];
    for (b, o) in out.iter_mut().enumerate() {
        *o = j[0][b] * d_c[0] + j[1][b] * d_c[1] + j[2][b] * d_c[2];
    }
    out
}

/// The largest stretch factor of the contraction at field-unit radius `r`
/// (max singular value of `J`): 1 inside the ball, `(2r − 1)/r²` outside. Marching with world
/// steps `Δ / stretch` keeps every contracted step at most `Δ`.
#[inline]
pub fn max_stretch(r: f32) -> f32 {
    if r <= 1.0 {
        1.0
    } else {
        (2.0 * r - 1.0) / (r * r)
    }
}

/// Inverse of the contraction's radial map: contracted radius `ρ ∈ [0, 2)` to field radius.
#[inline]
pub fn uncontract_radius(rho: f32) -> f32 {
    if rho <= 1.0 {
        rho
    } else {
        1.0 / (2.0 - rho).max(1e-6)
    }
}
