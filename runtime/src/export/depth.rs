//! Depth as numbers and as pictures: float32 `.npy` arrays (NaN where a
//! ray found no surface), and depth colour-mapped with a standard colour
//! map (the `colorous` crate's turbo, viridis, …) beside a colour bar whose
//! axis is titled and ticked (plotters, with the charts' embedded font).

use plotters::prelude::*;
use sdfl_stdlib::value::Colormap;

use super::RayEnd;
use crate::output::colour;

/// Depth per pixel: `Σ wᵢtᵢ / Σ wᵢ` where the opacity reaches
/// `min_opacity`, NaN elsewhere (no surface: NaN, not 0, so that a mean
/// or a point cloud made from it cannot mistake it for the camera centre).
pub fn depth_values(ends: &[RayEnd], min_opacity: f32) -> Vec<f32> {
    ends.iter()
        .map(|e| e.surface_depth(min_opacity).unwrap_or(f32::NAN))
        .collect()
}

/// A float32 array of `rows × cols` as a `.npy` file (version 1.0,
/// little-endian, C order).
pub fn npy_bytes(values: &[f32], rows: usize, cols: usize) -> Vec<u8> {
    debug_assert_eq!(values.len(), rows * cols);
    let mut out = crate::data::npy::encode_header("<f4", &[rows, cols]);
    for v in values {
        out.extend_from_slice(&v.to_le_bytes());
    }
    out
}

/// The depths at a colour map's ends: `fixed`, else the finite values'
/// own range (a single depth widened so that the range is not empty).
pub fn depth_range(depth: &[f32], fixed: Option<[f64; 2]>) -> [f64; 2] {
    if let Some(r) = fixed {
        return r;
    }
    let (lo, hi) = depth
        .iter()
        .filter(|d| d.is_finite())
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &d| {
            (lo.min(d as f64), hi.max(d as f64))
        });
    if !(lo.is_finite() && hi.is_finite()) {
        return [0.0, 1.0];
    }
    if hi - lo < 1e-6 * hi.abs().max(1.0) {
        let pad = 1e-3 * hi.abs().max(1.0);
        return [lo - pad, hi + pad];
    }
    [lo, hi]
}

/// Width of the colour bar panel beside a depth image.
pub const BAR_WIDTH: u32 = 150;
/// Smallest height of a depth map (the bar's ticks and title need room).
pub const MIN_HEIGHT: u32 = 200;

/// A depth image colour-mapped over `range` with the colour bar at its
/// right: `(width, height, rgb)`; pixels without depth black, the panel
/// white below a short image.
pub fn depth_map(
    depth: &[f32],
    (w, h): (u32, u32),
    map: Colormap,
    range: [f64; 2],
) -> Result<(u32, u32, Vec<u8>), crate::plot::PlotError> {
    let (tw, th) = (w + BAR_WIDTH, h.max(MIN_HEIGHT));
    let mut rgb = vec![255u8; tw as usize * th as usize * 3];
    let span = (range[1] - range[0]).max(f64::MIN_POSITIVE);
    {
        crate::plot::register_font();
        let root = BitMapBackend::with_buffer(&mut rgb, (tw, th)).into_drawing_area();
        let (_, bar) = root.split_horizontally(w);
        let err = |e: &dyn std::fmt::Debug| crate::plot::PlotError::Draw(format!("{e:?}"));
        let mut chart = ChartBuilder::on(&bar)
            .margin_top(10)
            .margin_bottom(10)
            .margin_left(4)
            .margin_right(16)
            .y_label_area_size(0)
            .right_y_label_area_size(70)
            .build_cartesian_2d(0f64..1f64, range[0]..range[1])
            .map_err(|e| err(&e))?;
        chart
            .configure_mesh()
            .disable_x_mesh()
            .disable_y_mesh()
            .disable_x_axis()
            .y_desc("depth (data units)")
            .y_labels(6)
            .label_style(("sans-serif", 11))
            .axis_desc_style(("sans-serif", 12))
            .draw()
            .map_err(|e| err(&e))?;
        let steps = 256;
        chart
            .draw_series((0..steps).map(|k| {
                let a = range[0] + span * k as f64 / steps as f64;
                let b = range[0] + span * (k + 1) as f64 / steps as f64;
                let c = colour(map, (k as f64 + 0.5) / steps as f64);
                Rectangle::new([(0.0, a), (1.0, b)], RGBColor(c[0], c[1], c[2]).filled())
            }))
            .map_err(|e| err(&e))?;
        root.present().map_err(|e| err(&e))?;
    }
    for j in 0..h as usize {
        for i in 0..w as usize {
            let d = depth[j * w as usize + i];
            let c = if d.is_finite() {
                colour(map, (d as f64 - range[0]) / span)
            } else {
                [0, 0, 0]
            };
            let o = (j * tw as usize + i) * 3;
            rgb[o..o + 3].copy_from_slice(&c);
        }
    }
    Ok((tw, th, rgb))
}
