//! Diagnostic figures as RGB8 pixel buffers (row-major from the top-left,
//! 3 bytes a pixel): the assignment's "xy grid" and "rays" checks
//! (CONVENTIONS.md), a side view of one camera's sample points, the part-0
//! transmittance figure. All are pure; writing files is
//! [`crate::output::write_png`]'s job. Charts for people (loss curves,
//! sweeps) are [`crate::plot`]'s.
//!
//! The transmittance figure is a chart, drawn with plotters on
//! [`crate::plot`]'s font; the sample-point view is a projection of
//! points and lines, rasterised here (no text or axes).

use glam::DVec3;
use sdfl_stdlib::camera::{pixel_ndc, Camera};

use super::composite::transmittance;
use super::rays::{camera_rays, pixel_ray, ImageSize, Stratified};
use crate::output::{colormap, to_u8};
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};

/// The "xy grid" check: RGB = `((x_ndc+1)/2.001, (y_ndc+1)/2.001, 0)`.
/// The top-left pixel is yellow, the bottom-right black.
pub fn xy_grid_image(width: u32, height: u32) -> Vec<u8> {
    let mut out = Vec::with_capacity(width as usize * height as usize * 3);
    for j in 0..height {
        for i in 0..width {
            let (x, y) = pixel_ndc(i, j, width, height);
            out.extend_from_slice(&[to_u8((x + 1.0) / 2.001), to_u8((y + 1.0) / 2.001), 0]);
        }
    }
    out
}

/// The "rays" check: RGB = `|direction|` componentwise, the directions being
/// the runtime's own camera rays. An invalid camera gives a black image.
pub fn rays_image(cam: &Camera, width: u32, height: u32) -> Vec<u8> {
    let size = ImageSize { width, height };
    match camera_rays(cam, size) {
        Ok(rays) => rays
            .iter()
            .flat_map(|r| r.dir.map(|d| to_u8(d.abs() as f64)))
            .collect(),
        Err(_) => vec![0; size.pixels() * 3],
    }
}

/// More sample points than this are thinned by coarsening the ray stride,
/// so a large image at stride 1 stays quick and bounded in memory.
const MAX_POINTS: u64 = 1 << 22;

/// Colour of a sample at depth `t`: the colour map from 0.2 up, because its
/// low end is nearly black and would vanish on the black background.
fn depth_colour(t: f64, near: f64, far: f64) -> [u8; 3] {
    let u = if far > near {
        (t - near) / (far - near)
    } else {
        0.0
    };
    colormap((0.2 + 0.8 * u.clamp(0.0, 1.0)) as f32)
}

/// The sample points `eye + t_k·d` of every `rays_stride`-th pixel (in both
/// directions, from the top-left) of a `width × height` image of `cam`, seen
/// from an oblique viewpoint beside the frustum so their spacing along each
/// ray is visible. The view is chosen from the camera pose and near/far and
/// fitted to the frame: the camera's up stays up, the frustum (grey) and the
/// eye (white) are drawn, points are coloured by depth (dark purple at near
/// to yellow at far) and splatted with a z-buffer onto black.
///
/// An invalid camera gives a black image; an invalid sampler draws the
/// frustum to depth 1 without points.
#[allow(clippy::too_many_arguments)]
pub fn sample_points_image(
    cam: &Camera,
    sampler: &Stratified,
    width: u32,
    height: u32,
    rays_stride: u32,
    out_width: u32,
    out_height: u32,
) -> Vec<u8> {
    let mut cv = Canvas::new(out_width, out_height, [0; 3]);
    if cv.px.is_empty() || !cam.is_valid() {
        return cv.px;
    }
    let valid = sampler.validate().is_ok();
    let depths: Vec<f64> = if valid {
        sampler.depths().iter().map(|&t| t as f64).collect()
    } else {
        Vec::new()
    };
    let (near, far) = if valid {
        (sampler.near as f64, sampler.far as f64)
    } else {
        (0.0, 1.0)
    };
    let size = ImageSize { width, height };
    // Pixel indices are u32 in the runtime's rays; beyond that, draw no rays.
    let indexable = size.pixels() as u64 <= u32::MAX as u64;
    let dir = |i: u32, j: u32| {
        let r = pixel_ray(cam, size, 0, j * width + i);
        DVec3::new(r.dir[0] as f64, r.dir[1] as f64, r.dir[2] as f64)
    };

    let mut stride = rays_stride.max(1) as u64;
    let count =
        |s: u64| (width as u64).div_ceil(s) * (height as u64).div_ceil(s) * depths.len() as u64;
    while count(stride) > MAX_POINTS {
        stride *= 2;
    }
    let mut points: Vec<(DVec3, f64)> = Vec::new();
    if indexable {
        for j in (0..height as u64).step_by(stride as usize) {
            for i in (0..width as u64).step_by(stride as usize) {
                let d = dir(i as u32, j as u32);
                points.extend(depths.iter().map(|&t| (cam.eye + d * t, t)));
            }
        }
    }

    // Frustum: the corner rays, cut at near and far.
    let corners: Vec<DVec3> = if indexable && width > 0 && height > 0 {
        let (r, b) = (width - 1, height - 1);
        [(0, 0), (r, 0), (r, b), (0, b)]
            .iter()
            .map(|&(i, j)| dir(i, j))
            .collect()
    } else {
        Vec::new()
    };
    let far_pts: Vec<DVec3> = corners.iter().map(|&d| cam.eye + d * far).collect();
    let near_pts: Vec<DVec3> = corners.iter().map(|&d| cam.eye + d * near).collect();

    // Viewer: beside the camera (along its x), a little above and ahead, far
    // enough back that everything lies in front of it.
    let (ax, ay, az) = cam.axes();
    let mid = cam.eye + az * (0.5 * (near + far));
    let radius = std::iter::once(cam.eye)
        .chain(std::iter::once(cam.eye + az * far))
        .chain(far_pts.iter().copied())
        .chain(points.iter().map(|p| p.0))
        .map(|p| (p - mid).length())
        .filter(|r| r.is_finite())
        .fold(0.0f64, f64::max);
    let radius = if radius > 0.0 { radius } else { 1.0 };
    let side = (ax + ay * 0.6 + az * 0.25).normalize();
    let viewer = Camera::look_at(mid + side * (3.0 * radius), mid, ay, 1.0);
    let min_depth = radius * 1e-9;
    let project = |p: DVec3| {
        let c = viewer.to_camera(p);
        (c.z > min_depth).then(|| (c.x / c.z, c.y / c.z, c.z))
    };

    // Fit the projected extent into the frame, keeping the aspect ratio.
    let (mut x0, mut x1, mut y0, mut y1) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
    let all = std::iter::once(cam.eye)
        .chain(far_pts.iter().copied())
        .chain(near_pts.iter().copied())
        .chain(points.iter().map(|p| p.0));
    for (x, y, _) in all.filter_map(project) {
        x0 = x0.min(x);
        x1 = x1.max(x);
        y0 = y0.min(y);
        y1 = y1.max(y);
    }
    let (w, h) = ((out_width - 1) as f64, (out_height - 1) as f64);
    let fits = [(w, x1 - x0), (h, y1 - y0)]
        .iter()
        .filter(|(_, span)| *span > 0.0)
        .map(|(n, span)| n / span)
        .fold(f64::INFINITY, f64::min);
    let scale = if fits.is_finite() { 0.9 * fits } else { 1.0 };
    let (xm, ym) = (0.5 * (x0 + x1), 0.5 * (y0 + y1));
    // NDC +x points left and +y up.
    let to_px =
        |(x, y, z): (f64, f64, f64)| (0.5 * w - (x - xm) * scale, 0.5 * h - (y - ym) * scale, z);

    let thick = (out_width.min(out_height) as i64 / 512).max(0);
    let grey = [110, 110, 110];
    let seg = |cv: &mut Canvas, a: DVec3, b: DVec3, c: [u8; 3]| {
        if let (Some(p), Some(q)) = (project(a).map(to_px), project(b).map(to_px)) {
            cv.line((p.0, p.1), (q.0, q.1), thick, c);
        }
    };
    for k in 0..far_pts.len() {
        let next = (k + 1) % far_pts.len();
        seg(&mut cv, cam.eye, far_pts[k], grey);
        seg(&mut cv, far_pts[k], far_pts[next], grey);
        if near > 0.0 {
            seg(&mut cv, near_pts[k], near_pts[next], grey);
        }
    }

    let splat = if out_width.min(out_height) >= 256 {
        1
    } else {
        0
    };
    let mut zbuf = vec![f64::INFINITY; out_width as usize * out_height as usize];
    for &(p, t) in &points {
        let Some((px, py, z)) = project(p).map(to_px) else {
            continue;
        };
        let c = depth_colour(t, near, far);
        let (cx, cy) = (px.round() as i64, py.round() as i64);
        for y in cy - splat..=cy + splat {
            for x in cx - splat..=cx + splat {
                if let Some(k) = cv.index(x, y) {
                    if z < zbuf[k / 3] {
                        zbuf[k / 3] = z;
                        cv.px[k..k + 3].copy_from_slice(&c);
                    }
                }
            }
        }
    }
    if let Some((px, py, _)) = project(cam.eye).map(to_px) {
        cv.dot(px, py, 1 + 2 * splat, [255, 255, 255]);
    }
    cv.px
}

/// The assignment's part 0: a ray from y4 back to the eye at x through
/// x–y1 empty (1 m), y1–y2 2 m σ=1, y2–y3 1 m σ=0.5, y3–y4 3 m σ=10.
/// Returns the plot and `[T(y1,y2), T(y2,y4), T(x,y4), T(x,y3)]`, computed
/// in f32 with the runtime's [`transmittance`]
/// (≈ e^-2, e^-30.5, e^-32.5, e^-2.5).
///
/// Drawn with plotters ([`crate::plot`]'s font): the distance from the eye
/// horizontally, the slabs as bands whose height and shade grow with σ
/// (σ written on each), and `T(x, s)` on a log axis from 1 down to 1e-15
/// with markers at x, y1..y4. An image smaller than a chart can hold
/// ([`crate::plot::MIN_SIDE`]) is left white.
pub fn transmittance_figure(width: u32, height: u32) -> (Vec<u8>, [f64; 4]) {
    let sigma = [0.0f32, 1.0, 0.5, 10.0];
    let delta = [1.0f32, 2.0, 1.0, 3.0];
    let starts = [0.0f32, 1.0, 3.0, 4.0];
    let t = |a: usize, b: usize| {
        transmittance(&sigma[a..b], &delta[a..b]).map_or(f64::NAN, |v| v as f64)
    };
    let values = [t(1, 2), t(2, 4), t(0, 4), t(0, 3)];
    // T(x, s): the slabs cut off at distance s from the eye.
    let t_at = |s: f64| {
        let cut: Vec<f32> = (0..4)
            .map(|k| (s as f32 - starts[k]).clamp(0.0, delta[k]))
            .collect();
        transmittance(&sigma, &cut).map_or(f64::NAN, |v| v as f64)
    };
    let mut rgb = vec![255u8; width as usize * height as usize * 3];
    let (min_w, min_h) = crate::plot::MIN_SIDE;
    if (min_w..=crate::plot::MAX_SIDE).contains(&width)
        && (min_h..=crate::plot::MAX_SIDE).contains(&height)
    {
        let slabs: Vec<(f64, f64, f64)> = (1..4)
            .map(|k| {
                let (a, d) = (starts[k] as f64, delta[k] as f64);
                (a, a + d, sigma[k] as f64)
            })
            .collect();
        // A failed drawing leaves the image as far as it got; the values stand.
        let _ = draw_transmittance(&mut rgb, (width, height), &slabs, &t_at);
    }
    (rgb, values)
}

/// The curve's colour.
const CURVE: RGBColor = RGBColor(200, 30, 30);

/// Draws the transmittance figure into `rgb`: `slabs` as (start, end, σ),
/// `t_at(s)` the transmittance from the eye to distance `s`.
fn draw_transmittance(
    rgb: &mut [u8],
    (width, height): (u32, u32),
    slabs: &[(f64, f64, f64)],
    t_at: &dyn Fn(f64) -> f64,
) -> Result<(), String> {
    let err = |e: &dyn std::fmt::Debug| format!("{e:?}");
    crate::plot::register_font();
    let root = BitMapBackend::with_buffer(rgb, (width, height)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| err(&e))?;
    // Sizes in pixels at 640 × 400, scaled with the image.
    let scale = (width as f64 / 640.0)
        .min(height as f64 / 400.0)
        .clamp(0.6, 4.0);
    let px = |v: f64| (v * scale).round().max(1.0) as u32;
    let font = |size: f64| (crate::plot::FAMILY, size * scale).into_font();
    let ink = RGBColor(40, 40, 40);
    let (lo, hi) = (1e-15f64, 1.0f64);
    let mut chart = ChartBuilder::on(&root)
        .caption(
            "Transmittance from the eye x through three slabs",
            font(19.0).color(&ink),
        )
        .margin(px(10.0))
        .margin_right(px(22.0))
        .x_label_area_size(px(46.0))
        .y_label_area_size(px(70.0))
        .build_cartesian_2d(-0.3f64..7.3f64, (lo / 3.0..hi * 3.0).log_scale())
        .map_err(|e| err(&e))?;
    let decade = |v: &f64| {
        let e = v.log10().round();
        if e == 0.0 {
            "1".to_string()
        } else {
            format!("1e{e}")
        }
    };
    chart
        .configure_mesh()
        .x_labels(8)
        .y_labels(6)
        .x_label_formatter(&|v| format!("{v}"))
        .y_label_formatter(&decade)
        .x_desc("distance s from the eye x along the ray (m)")
        .y_desc("T(x, s), log scale")
        .label_style(font(14.0).color(&ink))
        .axis_desc_style(font(16.0).color(&ink))
        .bold_line_style(RGBColor(225, 225, 225))
        .light_line_style(WHITE)
        .axis_style(ink)
        .draw()
        .map_err(|e| err(&e))?;
    // Bands: height and shade by ln(1 + σ), so σ = 0.5 and 1 stay visible
    // beside σ = 10 (top: the highest band reaches the top of the axis).
    let most = slabs.iter().map(|s| (1.0 + s.2).ln()).fold(0.0, f64::max);
    // The y axis from lo/3 to 3, as a fraction of its (log) height.
    let (bottom, span) = ((lo / 3.0).log10(), (9.0 / lo).log10());
    let at = |u: f64| 10f64.powf(bottom + u * span);
    let top_at = |g: f64| at(0.15 + 0.8 * g);
    for &(a, b, sigma) in slabs {
        let g = (1.0 + sigma).ln() / most.max(1e-12);
        let shade = |k: usize| {
            let base = [70u8, 110, 190][k] as f64;
            (255.0 + (base - 255.0) * (0.2 + 0.5 * g)).round() as u8
        };
        let fill = RGBColor(shade(0), shade(1), shade(2));
        let top = top_at(g);
        chart
            .draw_series(std::iter::once(Rectangle::new(
                [(a, lo / 3.0), (b, top)],
                fill.filled(),
            )))
            .map_err(|e| err(&e))?;
        let text_ink = if g > 0.5 {
            WHITE
        } else {
            RGBColor(30, 50, 110)
        };
        let label = Text::new(
            format!("σ = {sigma}"),
            (0.5 * (a + b), top / 2.5),
            font(14.0)
                .color(&text_ink)
                .pos(Pos::new(HPos::Center, VPos::Top)),
        );
        chart
            .draw_series(std::iter::once(label))
            .map_err(|e| err(&e))?;
    }
    // The named points, each a dashed line with its name at the bottom.
    let marks = [
        (0.0, "x"),
        (1.0, "y1"),
        (3.0, "y2"),
        (4.0, "y3"),
        (7.0, "y4"),
    ];
    for &(s, name) in &marks {
        let dashes = (0..24).map(|k| {
            let u = k as f64 / 24.0;
            PathElement::new(
                vec![(s, at(u)), (s, at(u + 0.5 / 24.0))],
                RGBColor(150, 150, 150),
            )
        });
        chart.draw_series(dashes).map_err(|e| err(&e))?;
        let label = Text::new(
            name.to_string(),
            (s + 0.08, lo / 1.5),
            font(15.0)
                .color(&ink)
                .pos(Pos::new(HPos::Left, VPos::Bottom)),
        );
        chart
            .draw_series(std::iter::once(label))
            .map_err(|e| err(&e))?;
    }
    let n = 4 * width as usize;
    let curve = (0..=n).map(|k| {
        let s = 7.0 * k as f64 / n as f64;
        (s, t_at(s))
    });
    chart
        .draw_series(LineSeries::new(curve, CURVE.stroke_width(px(2.0))))
        .map_err(|e| err(&e))?;
    chart
        .draw_series(
            marks
                .iter()
                .map(|&(s, _)| Circle::new((s, t_at(s)), px(4.0), CURVE.filled())),
        )
        .map_err(|e| err(&e))?;
    root.present().map_err(|e| err(&e))?;
    Ok(())
}

// ---------------------------------------------------------------------------
// Drawing

/// An RGB8 image; every write is clipped to it.
struct Canvas {
    w: i64,
    h: i64,
    px: Vec<u8>,
}

impl Canvas {
    fn new(w: u32, h: u32, bg: [u8; 3]) -> Canvas {
        let n = w as usize * h as usize;
        Canvas {
            w: w as i64,
            h: h as i64,
            px: bg.iter().copied().cycle().take(n * 3).collect(),
        }
    }

    fn index(&self, x: i64, y: i64) -> Option<usize> {
        (x >= 0 && y >= 0 && x < self.w && y < self.h).then(|| (y * self.w + x) as usize * 3)
    }

    /// Fills the rectangle between two corners, inclusive.
    fn fill(&mut self, x0: i64, y0: i64, x1: i64, y1: i64, c: [u8; 3]) {
        let (xa, xb) = (x0.min(x1).max(0), x0.max(x1).min(self.w - 1));
        let (ya, yb) = (y0.min(y1).max(0), y0.max(y1).min(self.h - 1));
        for y in ya..=yb {
            for x in xa..=xb {
                if let Some(k) = self.index(x, y) {
                    self.px[k..k + 3].copy_from_slice(&c);
                }
            }
        }
    }

    /// A square of half-width `r` centred at a (sub)pixel position.
    fn dot(&mut self, x: f64, y: f64, r: i64, c: [u8; 3]) {
        if x.is_finite() && y.is_finite() {
            let (x, y) = (x.round() as i64, y.round() as i64);
            self.fill(x - r, y - r, x + r, y + r, c);
        }
    }

    /// A segment of half-width `r`, clipped to the image first so that far
    /// off-screen ends cost nothing.
    fn line(&mut self, a: (f64, f64), b: (f64, f64), r: i64, c: [u8; 3]) {
        let m = (r + 1) as f64;
        let Some((a, b)) = clip(
            a,
            b,
            -m,
            self.w as f64 - 1.0 + m,
            -m,
            self.h as f64 - 1.0 + m,
        ) else {
            return;
        };
        let (dx, dy) = (b.0 - a.0, b.1 - a.1);
        let n = dx.abs().max(dy.abs()).ceil() as i64;
        for k in 0..=n {
            let t = if n == 0 { 0.0 } else { k as f64 / n as f64 };
            self.dot(a.0 + t * dx, a.1 + t * dy, r, c);
        }
    }
}

/// Cohen–Sutherland clipping of a segment to a rectangle; `None` when it
/// misses or is not finite. Each cut sets the crossed coordinate exactly, so
/// very long segments keep their position (a parametric clip loses it).
fn clip(
    mut a: (f64, f64),
    mut b: (f64, f64),
    xmin: f64,
    xmax: f64,
    ymin: f64,
    ymax: f64,
) -> Option<((f64, f64), (f64, f64))> {
    let finite = |p: (f64, f64)| p.0.is_finite() && p.1.is_finite();
    let code = |p: (f64, f64)| {
        (p.0 < xmin) as u8
            | ((p.0 > xmax) as u8) << 1
            | ((p.1 < ymin) as u8) << 2
            | ((p.1 > ymax) as u8) << 3
    };
    // `u + d·r`, d given halved, with every partial sum finite for r in [0, 1].
    let lerp = |u: f64, d_half: f64, r: f64| u + d_half * r + d_half * r;
    for _ in 0..16 {
        if !(finite(a) && finite(b)) {
            return None;
        }
        let (ca, cb) = (code(a), code(b));
        if ca | cb == 0 {
            return Some((a, b));
        }
        if ca & cb != 0 {
            return None;
        }
        let c = if ca != 0 { ca } else { cb };
        // Halves: differences of coordinates near ±f64::MAX overflow.
        let (dx, dy) = (b.0 * 0.5 - a.0 * 0.5, b.1 * 0.5 - a.1 * 0.5);
        let p = if c & 3 != 0 {
            let x = if c & 1 != 0 { xmin } else { xmax };
            (x, lerp(a.1, dy, (x * 0.5 - a.0 * 0.5) / dx))
        } else {
            let y = if c & 4 != 0 { ymin } else { ymax };
            (lerp(a.0, dx, (y * 0.5 - a.1 * 0.5) / dy), y)
        };
        if ca != 0 {
            a = p;
        } else {
            b = p;
        }
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pixel(img: &[u8], w: u32, i: u32, j: u32) -> [u8; 3] {
        let k = (j * w + i) as usize * 3;
        [img[k], img[k + 1], img[k + 2]]
    }

    fn colours(img: &[u8]) -> std::collections::HashSet<[u8; 3]> {
        img.chunks_exact(3).map(|p| [p[0], p[1], p[2]]).collect()
    }

    #[test]
    fn xy_grid_corners() {
        let img = xy_grid_image(64, 48);
        assert_eq!(img.len(), 64 * 48 * 3);
        assert_eq!(pixel(&img, 64, 0, 0), [255, 255, 0]);
        assert_eq!(pixel(&img, 64, 63, 47), [0, 0, 0]);
        // Top-right: x_ndc = -1, y_ndc = 1 → green; bottom-left red.
        assert_eq!(pixel(&img, 64, 63, 0), [0, 255, 0]);
        assert_eq!(pixel(&img, 64, 0, 47), [255, 0, 0]);
        assert!(xy_grid_image(0, 5).is_empty());
        assert_eq!(xy_grid_image(1, 1), vec![127, 127, 0]);
    }

    #[test]
    fn rays_image_matches_hand_computation() {
        // Eye on -x looking at the origin, up +y: z = (1,0,0),
        // x = cross(y, z) = (0,0,-1), y = (0,1,0). Pixels are square, so on
        // a 5×3 image the top-left pixel is at NDC (2, 1) (the 3-pixel side
        // spans ±1). With f = 2 it looks along x + y/2 + z = (1, 0.5, -1),
        // whose unit vector is (2/3, 1/3, 2/3) → (170, 85, 170).
        let cam = Camera::look_at(DVec3::new(-2.5, 0.0, 0.0), DVec3::ZERO, DVec3::Y, 2.0);
        let img = rays_image(&cam, 5, 3);
        assert_eq!(img.len(), 5 * 3 * 3);
        assert_eq!(pixel(&img, 5, 0, 0), [170, 85, 170]);
        // A square image's corner keeps the conventions' NDC (1, 1):
        // x/2 + y/2 + z = (1, 0.5, -0.5) → (208, 104, 104).
        assert_eq!(pixel(&rays_image(&cam, 3, 3), 3, 0, 0), [208, 104, 104]);
        // The centre pixel looks straight at the target, along +x.
        assert_eq!(pixel(&img, 5, 2, 1), [255, 0, 0]);
        let bad = Camera::look_at(DVec3::ZERO, DVec3::ZERO, DVec3::Y, 1.0);
        assert_eq!(rays_image(&bad, 4, 4), vec![0; 48]);
        assert!(rays_image(&cam, 0, 4).is_empty());
    }

    fn nerf_cam() -> Camera {
        Camera::look_at(DVec3::new(0.0, 4.0, 2.0), DVec3::ZERO, DVec3::Z, 2.0)
    }

    #[test]
    fn sample_points_show_near_and_far() {
        let s = Stratified::new(32, 2.0, 6.0).unwrap();
        let img = sample_points_image(&nerf_cam(), &s, 32, 32, 8, 200, 150);
        assert_eq!(img.len(), 200 * 150 * 3);
        let cs = colours(&img);
        assert!(img.iter().any(|&v| v > 0));
        let (near, far) = (depth_colour(2.0, 2.0, 6.0), depth_colour(6.0, 2.0, 6.0));
        assert_ne!(near, far);
        assert!(cs.contains(&near) && cs.contains(&far), "{cs:?}");
        assert!(cs.contains(&[255, 255, 255]), "the eye is drawn");
        // Points fill a fair part of the frame: the fit works.
        let lit = img.chunks_exact(3).filter(|p| p != &[0, 0, 0]).count();
        assert!(lit > 200, "{lit}");
    }

    #[test]
    fn sample_points_edge_cases() {
        let s = Stratified::new(16, 0.0, 5.0).unwrap();
        let cam = nerf_cam();
        for stride in [0, 1, 3, u32::MAX] {
            let img = sample_points_image(&cam, &s, 20, 10, stride, 64, 40);
            assert_eq!(img.len(), 64 * 40 * 3);
            assert!(img.iter().any(|&v| v > 0), "stride {stride}");
        }
        // Stride 1 on a large image is thinned, not slow or huge.
        let big = Stratified::new(128, 2.0, 6.0).unwrap();
        let img = sample_points_image(&cam, &big, 1024, 1024, 1, 32, 32);
        assert_eq!(img.len(), 32 * 32 * 3);
        assert!(sample_points_image(&cam, &s, 20, 10, 1, 0, 40).is_empty());
        assert_eq!(sample_points_image(&cam, &s, 20, 10, 1, 1, 1).len(), 3);
        assert!(sample_points_image(&cam, &s, 0, 0, 1, 16, 16)
            .iter()
            .any(|&v| v > 0));
        let bad = Camera::look_at(DVec3::ZERO, DVec3::ZERO, DVec3::Y, 1.0);
        assert_eq!(sample_points_image(&bad, &s, 8, 8, 1, 4, 4), vec![0; 48]);
        let invalid = Stratified {
            n: 1,
            near: 3.0,
            far: 1.0,
        };
        let img = sample_points_image(&cam, &invalid, 8, 8, 1, 32, 32);
        assert_eq!(img.len(), 32 * 32 * 3);
    }

    #[test]
    fn transmittance_values_match_assignment() {
        let (img, t) = transmittance_figure(480, 320);
        assert_eq!(img.len(), 480 * 320 * 3);
        let want = [-2.0f64, -30.5, -32.5, -2.5].map(f64::exp);
        for (got, want) in t.iter().zip(want) {
            assert!(((got - want) / want).abs() < 1e-3, "{got} vs {want}");
        }
        let cs = colours(&img);
        assert!(cs.contains(&[200, 30, 30]), "the curve is drawn");
        assert!(cs.len() > 5, "bands, axes and curve");
        for (w, h) in [(0, 0), (1, 1), (10, 7), (2000, 40)] {
            let (img, v) = transmittance_figure(w, h);
            assert_eq!(img.len(), (w * h * 3) as usize);
            assert_eq!(v, t);
        }
    }

    #[test]
    fn clipping_stays_in_bounds() {
        const AXIS: [u8; 3] = [40, 40, 40];
        let mut cv = Canvas::new(10, 10, [255; 3]);
        cv.line((-1e300, 5.0), (1e300, 5.0), 1, AXIS);
        cv.line((f64::NAN, 0.0), (3.0, 3.0), 0, AXIS);
        cv.line((-50.0, -50.0), (-20.0, -1.0), 0, AXIS);
        cv.dot(f64::INFINITY, 2.0, 3, AXIS);
        assert_eq!(cv.px.len(), 300);
        assert_eq!(&cv.px[(5 * 10 + 9) * 3..][..3], &AXIS);
        assert_eq!(
            clip((0.0, 0.0), (20.0, 0.0), 0.0, 9.0, 0.0, 9.0),
            Some(((0.0, 0.0), (9.0, 0.0)))
        );
        let m = f64::MAX;
        let c = clip((-m, -m), (m, m), 0.0, 9.0, 0.0, 9.0).unwrap();
        assert!((c.0 .0 - c.0 .1).abs() < 1e-9 && (c.1 .0 - 9.0).abs() < 1e-9);
        assert_eq!(clip((-m, 20.0), (m, 20.0), 0.0, 9.0, 0.0, 9.0), None);
    }

    /// Writes the figures as PNGs for a look: `SDFL_WRITE_FIGURES=1 cargo test -p sdfl-runtime
    /// figures`; they land in `$TMPDIR/sdfl-figures`.
    #[test]
    fn write_figures_for_inspection() {
        if std::env::var_os("SDFL_WRITE_FIGURES").is_none() {
            return;
        }
        use crate::output::write_png;
        let dir = std::env::temp_dir().join("sdfl-figures");
        let cam = Camera::look_at(DVec3::new(-1.0, 0.0, -2.2), DVec3::ZERO, DVec3::Y, 1.0);
        write_png(&dir.join("xy_grid.png"), 256, 256, &xy_grid_image(256, 256)).unwrap();
        write_png(&dir.join("rays.png"), 256, 256, &rays_image(&cam, 256, 256)).unwrap();
        let s = Stratified::new(64, 0.0, 5.0).unwrap();
        let img = sample_points_image(&cam, &s, 256, 256, 32, 512, 512);
        write_png(&dir.join("sample_points.png"), 512, 512, &img).unwrap();
        let s = Stratified::new(128, 2.0, 6.0).unwrap();
        let img = sample_points_image(&nerf_cam(), &s, 128, 128, 16, 400, 300);
        write_png(&dir.join("sample_points_nerf.png"), 400, 300, &img).unwrap();
        let (img, _) = transmittance_figure(640, 400);
        write_png(&dir.join("transmittance.png"), 640, 400, &img).unwrap();
        eprintln!("figures in {}", dir.display());
    }
}
