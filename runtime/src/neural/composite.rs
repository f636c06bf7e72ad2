//! Compositing of per-sample densities and colours along one ray, forward
//! and reverse, for fields that output density directly (NeRF).
//!
//! With `τ_k = σ_k·Δ_k`, `T_k = exp(−Σ_{j<k} τ_j)` and `w_k = T_k·(1 − e^{−τ_k})`,
//! the colour is `C = Σ w_k c_k + T_n·bg` (the background seen through
//! whatever is left). Its adjoint needs no division and no stored
//! transmittance table: `∂C/∂τ_k = T_{k+1}·c_k − S_k` where
//! `S_k = Σ_{j>k} w_j c_j + T_n·bg` is what lies behind sample `k`, so one
//! sweep from the back gives every `∂L/∂σ_k = Δ_k·g·∂C/∂τ_k`.

/// The composite of one ray.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Composite {
    /// `Σ w_k·c_k`, background included.
    pub colour: [f32; 3],
    /// `Σ w_k`, the ray's opacity.
    pub opacity: f32,
    /// `Σ w_k t_k` (expected depth, unnormalised).
    pub depth: f32,
}

/// Composites samples `(σ_k, c_k)` with intervals `delta` at depths `t`.
pub fn composite(
    sigma: &[f32],
    rgb: &[f32],
    t: &[f32],
    delta: &[f32],
    background: [f32; 3],
) -> Composite {
    let mut trans = 1.0f32;
    let mut out = Composite {
        colour: [0.0; 3],
        opacity: 0.0,
        depth: 0.0,
    };
    for k in 0..sigma.len() {
        let tau = sigma[k] * delta[k];
        // 1 − e^{−τ} without cancellation for small τ.
        let w = trans * -(-tau).exp_m1();
        for i in 0..3 {
            out.colour[i] += w * rgb[3 * k + i];
        }
        out.opacity += w;
        out.depth += w * t[k];
        trans *= (-tau).exp();
    }
    for (c, b) in out.colour.iter_mut().zip(background) {
        *c += trans * b;
    }
    out
}

/// One ray's squared colour error against `target`, times `scale`, with
/// its adjoints written as [`composite_backward`] writes them.
#[allow(clippy::too_many_arguments)]
pub fn squared_error_backward(
    sigma: &[f32],
    rgb: &[f32],
    t: &[f32],
    delta: &[f32],
    background: [f32; 3],
    target: [f32; 3],
    scale: f32,
    d_sigma: &mut [f32],
    d_rgb: &mut [f32],
    trans: &mut Vec<f32>,
) -> f64 {
    let mut d_background = [0.0; 3];
    squared_error_backward_bg(
        sigma,
        rgb,
        t,
        delta,
        background,
        target,
        scale,
        d_sigma,
        d_rgb,
        &mut d_background,
        trans,
    )
}

/// [`squared_error_backward`] that also writes `∂L/∂background`
/// (`T_n·∂L/∂C`: the background is seen through what is left).
#[allow(clippy::too_many_arguments)]
pub fn squared_error_backward_bg(
    sigma: &[f32],
    rgb: &[f32],
    t: &[f32],
    delta: &[f32],
    background: [f32; 3],
    target: [f32; 3],
    scale: f32,
    d_sigma: &mut [f32],
    d_rgb: &mut [f32],
    d_background: &mut [f32; 3],
    trans: &mut Vec<f32>,
) -> f64 {
    let out = composite(sigma, rgb, t, delta, background);
    let (mut loss, mut g) = (0f64, [0f32; 3]);
    for i in 0..3 {
        let e = out.colour[i] - target[i];
        loss += (e * e * scale) as f64;
        g[i] = 2.0 * e * scale;
    }
    composite_backward(sigma, rgb, delta, background, g, d_sigma, d_rgb, trans);
    // `trans` now holds the transmittances, the last one behind every sample.
    let left = trans[sigma.len()];
    for i in 0..3 {
        d_background[i] = left * g[i];
    }
    loss
}

/// A covered pixel's opacity is taken as at least this in
/// [`silhouette_backward`], so that a ray that sees nothing there costs at
/// most `-ln 1e-6 ≈ 14` and its gradient stays finite.
pub const OPACITY_FLOOR: f32 = 1e-6;

/// One ray's binary cross-entropy of its opacity `O = 1 − T_n` against the
/// pixel's coverage `a`, times `scale` (NeuS's mask loss), written as
/// `(1 − a)·τ − a·ln O` with `τ = Σ σ_k·δ_k` (`−ln(1 − O) = τ` exactly), and
/// adds `∂L/∂σ_k = scale·δ_k·((1 − a) − a·T_n/O)` into `d_sigma`. Unlike the
/// colour error, its gradient does not fade with the contrast between the
/// object and the background: an uncovered pixel pushes its ray's density
/// down however opaque the ray is, and a covered one pulls it up through
/// `1/O` however faint the ray is, until `O` falls below
/// [`OPACITY_FLOOR`], where that half's gradient is 0, as the floor's.
pub fn silhouette_backward(
    sigma: &[f32],
    delta: &[f32],
    coverage: f32,
    scale: f32,
    d_sigma: &mut [f32],
) -> f64 {
    // In f64: the cross-entropy of an opacity near ½ is about 0.7 a ray,
    // and its change with a parameter is small next to that.
    let tau: f64 = sigma.iter().zip(delta).map(|(s, d)| (s * d) as f64).sum();
    let t_n = (-tau).exp();
    let opacity = -(-tau).exp_m1();
    let floor = OPACITY_FLOOR as f64;
    let (a, scale) = (coverage as f64, scale as f64);
    let loss = ((1.0 - a) * tau - a * opacity.max(floor).ln()) * scale;
    // ∂L/∂τ: the uncovered part's 1 − a, the covered part's −a·T/O.
    let covered = if opacity > floor {
        a * t_n / opacity
    } else {
        0.0
    };
    let g_tau = ((1.0 - a) - covered) * scale;
    for (ds, &d) in d_sigma.iter_mut().zip(delta) {
        *ds += (g_tau * d as f64) as f32;
    }
    loss
}

/// Given `g = ∂L/∂C`, writes `∂L/∂σ_k` into `d_sigma` and `∂L/∂c_k` into
/// `d_rgb` (3 per sample); `trans` is scratch space.
#[allow(clippy::too_many_arguments)]
pub fn composite_backward(
    sigma: &[f32],
    rgb: &[f32],
    delta: &[f32],
    background: [f32; 3],
    g: [f32; 3],
    d_sigma: &mut [f32],
    d_rgb: &mut [f32],
    trans: &mut Vec<f32>,
) {
    let n = sigma.len();
    // Forward again for the transmittances before each sample (cheap next
    // to the network); `trans` is the caller's reused buffer.
    trans.clear();
    trans.resize(n + 1, 1.0);
    for k in 0..n {
        trans[k + 1] = trans[k] * (-(sigma[k] * delta[k])).exp();
    }
    let mut behind = g[0] * background[0] + g[1] * background[1] + g[2] * background[2];
    behind *= trans[n];
    for k in (0..n).rev() {
        let c = &rgb[3 * k..3 * k + 3];
        let gc = g[0] * c[0] + g[1] * c[1] + g[2] * c[2];
        let w = trans[k] * -(-(sigma[k] * delta[k])).exp_m1();
        d_sigma[k] = delta[k] * (trans[k + 1] * gc - behind);
        for i in 0..3 {
            d_rgb[3 * k + i] = w * g[i];
        }
        behind += w * gc;
    }
}
