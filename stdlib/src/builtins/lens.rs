//! `lens(...)`: a real camera's intrinsics and distortion on cameras, so
//! that sdfl renders what such a camera sees (and writes it as such).

use super::*;
use crate::camera::{Distortion, Intrinsics, Lens};

/// The numbers of a list argument, exactly `n` of them.
fn numbers(a: &Args, name: &str, n: usize, what: &str) -> Result<Vec<f64>, Diag> {
    let (v, span) = a.get(name);
    let got: Option<Vec<f64>> = match v {
        Value::List(items) => items
            .iter()
            .map(|i| match i {
                Value::Number(x) => Some(*x),
                _ => None,
            })
            .collect(),
        _ => None,
    };
    match got {
        Some(x) if x.len() == n && x.iter().all(|v| v.is_finite()) => Ok(x),
        _ => Err(value_error(
            span,
            format!("`{name}` must be {what}"),
            format!("not {n} finite numbers"),
            format!("give `{name}` as {what}"),
        )),
    }
}

pub(super) fn lens(a: &Args) -> Result<Value, Diag> {
    let cameras = camera_list(a, "cameras")?;
    let (width, height) = image_size(a, "size")?;
    let focal = numbers(a, "focal", 2, "[fx, fy] in pixels")?;
    let center = if a.given("center") {
        numbers(a, "center", 2, "[cx, cy] in pixels")?
    } else {
        vec![width as f64 / 2.0, height as f64 / 2.0]
    };
    let (model, model_span) = a.string("model")?;
    let distortion_span = a.get("distortion").1;
    let distortion = match model.to_ascii_lowercase().as_str() {
        "pinhole" => {
            if a.given("distortion") {
                return Err(value_error(
                    distortion_span,
                    "a pinhole has no distortion",
                    "ignored by a pinhole",
                    "use `model: \"opencv\"` (k1, k2, p1, p2) or `\"opencv_fisheye\"` (k1 to k4)",
                ));
            }
            Distortion::None
        }
        "opencv" => {
            let k = numbers(a, "distortion", 4, "[k1, k2, p1, p2]")?;
            Distortion::OpenCv {
                k1: k[0],
                k2: k[1],
                p1: k[2],
                p2: k[3],
            }
        }
        "opencv_fisheye" | "fisheye" => {
            let k = numbers(a, "distortion", 4, "[k1, k2, k3, k4]")?;
            Distortion::Fisheye {
                k1: k[0],
                k2: k[1],
                k3: k[2],
                k4: k[3],
            }
        }
        other => return Err(value_error(
            model_span,
            format!("unknown camera model `{other}`"),
            "not a camera model",
            "use \"pinhole\", \"opencv\" or \"opencv_fisheye\" (COLMAP's and nerfstudio's names)",
        )),
    };
    let k = Intrinsics {
        width,
        height,
        fx: focal[0],
        fy: focal[1],
        cx: center[0],
        cy: center[1],
        distortion,
    };
    if let Err(why) = k.check() {
        return Err(value_error(
            a.span,
            format!("these intrinsics are not a usable lens: {why}"),
            "not a usable lens",
            "check the focal lengths (pixels), the principal point and the distortion coefficients",
        ));
    }
    let short = width.min(height) as f64;
    let out = cameras
        .into_iter()
        .map(|c| {
            let mut c = c.with_pixel_centers(crate::camera::PixelCenters::Half);
            c.focal = 2.0 * k.fy / short;
            c.lens = Lens::Pixels(k);
            Value::Camera(c)
        })
        .collect();
    Ok(Value::List(Arc::new(out)))
}
