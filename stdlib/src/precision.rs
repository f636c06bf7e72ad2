//! Numbers in the precision the runtime computes in (f32): a value that
//! would flush to zero or overflow there is refused where it is written,
//! instead of giving an all-black image.

use sdfl_lang::diag::{codes, fmt_num, Diag};
use sdfl_lang::Span;

/// Magnitudes the f32 runtime represents with room to spare (products of
/// a few of them stay finite and normal).
pub const F32_SAFE: (f64, f64) = (1e-30, 1e18);

/// Smallest `beta` of a density: below it the density is a step function
/// whose gradients vanish in f32.
pub const MIN_BETA: f64 = 1e-6;

/// `x`, unless it is a nonzero number outside [`F32_SAFE`].
pub fn f32_range(x: f64, span: Span, name: &str) -> Result<f64, Diag> {
    let (lo, hi) = F32_SAFE;
    if x == 0.0 || (lo..=hi).contains(&x.abs()) {
        return Ok(x);
    }
    let (what, becomes) = if x.abs() < lo {
        ("small", "zero")
    } else {
        ("large", "infinity")
    };
    Err(Diag::new(
        codes::PRECISION,
        span,
        format!(
            "`{name}` is {}, too {what} for the renderer's 32-bit floats",
            fmt_num(x)
        ),
    )
    .label(format!("would become {becomes}"))
    .help(format!(
        "use 0 or a magnitude from {} to {}",
        fmt_num(lo),
        fmt_num(hi)
    )))
}

/// A density's `beta`, at least [`MIN_BETA`].
pub fn beta(b: f64, span: Span) -> Result<f64, Diag> {
    if b >= MIN_BETA {
        return Ok(b);
    }
    Err(Diag::new(
        codes::VALUE,
        span,
        format!("`beta` is {}, below {}", fmt_num(b), fmt_num(MIN_BETA)),
    )
    .label("too sharp for f32")
    .help(format!(
        "use `beta` ≥ {} (0.05 is typical)",
        fmt_num(MIN_BETA)
    )))
}
