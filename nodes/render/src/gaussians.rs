//! The Gaussian parameter set, structure-of-arrays, raw (pre-activation) values as in the
//! Inria PLY layout: quaternion (w, x, y, z) normalised before use, scale = exp(log_scale),
//! opacity = sigmoid(logit), SH coefficients per Gaussian as `sh[(i·K + k)·3 + c]` with
//! K = (degree + 1)² coefficients and c the colour channel (k = 0 is the DC term).

/// Number of SH coefficients per channel for a degree.
pub const fn sh_coeffs(degree: u32) -> usize {
    ((degree + 1) * (degree + 1)) as usize
}

/// A set of Gaussians (raw parameters).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Gaussians {
    /// Centres, world frame.
    pub means: Vec<[f32; 3]>,
    /// Natural log of the per-axis scales.
    pub log_scales: Vec<[f32; 3]>,
    /// Unnormalised rotation quaternions (w, x, y, z).
    pub quats: Vec<[f32; 4]>,
    /// Opacity logits.
    pub opacity_logits: Vec<f32>,
    /// SH coefficients, `len() · sh_coeffs(sh_degree) · 3` values.
    pub sh: Vec<f32>,
    /// The SH degree the coefficients are stored for (0–3).
    pub sh_degree: u32,
}

impl Gaussians {
    /// Appends the Gaussians, bit for bit, to a checkpoint.
    pub fn write_state(&self, w: &mut augsplat_core::state::StateWriter) {
        use augsplat_core::state::flat;
        w.tag("gaussians");
        w.u32(self.sh_degree);
        w.f32s(&flat(&self.means));
        w.f32s(&flat(&self.log_scales));
        w.f32s(&flat(&self.quats));
        w.f32s(&self.opacity_logits);
        w.f32s(&self.sh);
    }

    /// The Gaussians [`Gaussians::write_state`] wrote.
    pub fn read_state(
        r: &mut augsplat_core::state::StateReader<'_>,
    ) -> Result<Gaussians, augsplat_core::state::StateError> {
        use augsplat_core::state::{unflat, StateError};
        r.tag("gaussians")?;
        let sh_degree = r.u32()?;
        let g = Gaussians {
            sh_degree,
            means: unflat(&r.f32s()?)?,
            log_scales: unflat(&r.f32s()?)?,
            quats: unflat(&r.f32s()?)?,
            opacity_logits: r.f32s()?,
            sh: r.f32s()?,
        };
        let n = g.means.len();
        if sh_degree > 3
            || g.log_scales.len() != n
            || g.quats.len() != n
            || g.opacity_logits.len() != n
            || g.sh.len() != n * sh_coeffs(sh_degree) * 3
        {
            return Err(StateError("inconsistent Gaussians".into()));
        }
        Ok(g)
    }
    /// A seeded random cloud for benchmarks and tests (what `train_step_bench` and
    /// `bench_raster` render): `n` Gaussians uniform in the box [−2, 2]² × [−1.5, 1.5] (for a
    /// camera 4 units away, the box's centre), scales of 0.7–3 × `pixel` (world units; mildly
    /// anisotropic), rotations near the identity, opacity logits in [−2, 2], SH degree 3 with
    /// coefficients in [−0.3, 0.3].
    pub fn random_cloud(n: usize, pixel: f64, seed: u64) -> Self {
        let mut rng = augsplat_core::Rng::new(seed);
        let mut g = Gaussians::empty(3);
        for _ in 0..n {
            g.means.push([
                rng.uniform(-2.0, 2.0) as f32,
                rng.uniform(-2.0, 2.0) as f32,
                rng.uniform(-1.5, 1.5) as f32,
            ]);
            let s = (pixel * rng.uniform(0.7, 3.0)).ln() as f32;
            g.log_scales.push([
                s,
                s + rng.uniform(-0.3, 0.3) as f32,
                s + rng.uniform(-0.3, 0.3) as f32,
            ]);
            g.quats.push([
                1.0,
                rng.uniform(-0.5, 0.5) as f32,
                rng.uniform(-0.5, 0.5) as f32,
                rng.uniform(-0.5, 0.5) as f32,
            ]);
            g.opacity_logits.push(rng.uniform(-2.0, 2.0) as f32);
            for _ in 0..48 {
                g.sh.push(rng.uniform(-0.3, 0.3) as f32);
            }
        }
        g
    }

    /// An empty set with SH storage for `sh_degree`.
    pub fn empty(sh_degree: u32) -> Self {
        Gaussians {
            sh_degree,
            ..Default::default()
        }
    }
    /// Number of Gaussians.
    pub fn len(&self) -> usize {
        self.means.len()
    }
    /// Whether there are none.
    pub fn is_empty(&self) -> bool {
        self.means.is_empty()
    }
    /// Coefficients per channel.
    pub fn coeffs(&self) -> usize {
        sh_coeffs(self.sh_degree)
    }
    /// The SH coefficients of Gaussian i (`coeffs() · 3` values).
    pub fn sh_of(&self, i: usize) -> &[f32] {
        let k = self.coeffs() * 3;
        &self.sh[i * k..(i + 1) * k]
    }
}
