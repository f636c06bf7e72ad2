//! Diagnostic figures as RGB8 pixel buffers (row-major from the top-left,
//! 3 bytes a pixel): the assignment's "xy grid" and "rays" checks
//! (CONVENTIONS.md), a side view of one camera's sample points, the part-0
//! transmittance figure. All are pure; writing files is
//! [`crate::output::write_png`]'s job. Charts for people (loss curves,
//! sweeps) are [`crate::plot`]'s.
//!
//! The transmittance figure and the sample-point view are charts, drawn
//! with plotters on [`crate::plot`]'s font: one plotting stack.

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
/// so a large image at stride 1 stays quick and the chart legible.
const MAX_POINTS: u64 = 1 << 15;

/// Colour of a sample at depth `t`: the colour map from 0.2 up, because its
/// low end is nearly black.
#[doc(hidden)]
pub fn depth_colour(t: f64, near: f64, far: f64) -> [u8; 3] {
    let u = if far > near {
        (t - near) / (far - near)
    } else {
        0.0
    };
    colormap((0.2 + 0.8 * u.clamp(0.0, 1.0)) as f32)
}

/// The eye's marker colour.
pub const EYE: RGBColor = RGBColor(220, 30, 30);

/// The sample points `eye + t_k·d` of every `rays_stride`-th pixel (in both
/// directions, from the top-left) of a `width × height` image of `cam`, as a
/// 3-D chart with titled world axes, drawn with plotters: the frustum in
/// grey, the eye in red, points coloured by depth (dark purple at near to
/// yellow at far, as the legend says) and painted far to near. The world
/// axis closest to the camera's up is drawn vertical, and the chart is
/// turned so the frustum is seen from its side, where the spacing along each
/// ray shows.
///
/// An invalid camera, or an image smaller than a chart can hold
/// ([`crate::plot::MIN_SIDE`]), gives a white image; an invalid sampler
/// draws the frustum to depth 1 without points.
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
    let mut rgb = vec![255u8; out_width as usize * out_height as usize * 3];
    let (min_w, min_h) = crate::plot::MIN_SIDE;
    let drawable = (min_w..=crate::plot::MAX_SIDE).contains(&out_width)
        && (min_h..=crate::plot::MAX_SIDE).contains(&out_height);
    if !drawable || !cam.is_valid() {
        return rgb;
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
    let frustum = Frustum {
        eye: cam.eye,
        forward: cam.axes().2,
        up: cam.axes().1,
        far: corners.iter().map(|&d| cam.eye + d * far).collect(),
        near: if near > 0.0 {
            corners.iter().map(|&d| cam.eye + d * near).collect()
        } else {
            Vec::new()
        },
        depth: (near, far),
    };
    // A failed drawing leaves the image as far as it got.
    let _ = draw_sample_points(&mut rgb, (out_width, out_height), &frustum, &points);
    rgb
}

/// What the sample-point chart shows besides the points.
struct Frustum {
    eye: DVec3,
    /// The camera's viewing direction and up, for turning the chart.
    forward: DVec3,
    up: DVec3,
    /// Corner points at the far and (when positive) near depth.
    far: Vec<DVec3>,
    near: Vec<DVec3>,
    /// The sampler's near and far depth, for the colours and legend.
    depth: (f64, f64),
}

/// Draws the sample-point chart into `rgb`; `points` are (position, depth).
fn draw_sample_points(
    rgb: &mut [u8],
    (width, height): (u32, u32),
    fr: &Frustum,
    points: &[(DVec3, f64)],
) -> Result<(), String> {
    let err = |e: &dyn std::fmt::Debug| format!("{e:?}");
    // Chart axes (x, vertical, depth) as world axes: the vertical one is
    // the world axis closest to the camera's up, the others in cyclic order.
    let v = (0..3)
        .max_by(|&a, &b| fr.up[a].abs().total_cmp(&fr.up[b].abs()))
        .unwrap_or(1);
    let axes = [(v + 1) % 3, v, (v + 2) % 3];
    let chart_of = |p: DVec3| (p[axes[0]], p[axes[1]], p[axes[2]]);

    // A cube around everything, so the geometry is not stretched.
    let all = || {
        std::iter::once(fr.eye)
            .chain(fr.far.iter().copied())
            .chain(points.iter().map(|p| p.0))
            .filter(|p| p.is_finite())
    };
    let (lo, hi) = all().fold(
        (DVec3::splat(f64::MAX), DVec3::splat(f64::MIN)),
        |(l, h), p| (l.min(p), h.max(p)),
    );
    let centre = (lo + hi) * 0.5;
    let half = 0.55 * (hi - lo).max_element().max(1e-9);
    if !(centre.is_finite() && half.is_finite()) {
        return Ok(());
    }
    let range = |k: usize| centre[axes[k]] - half..centre[axes[k]] + half;

    crate::plot::register_font();
    let root = BitMapBackend::with_buffer(rgb, (width, height)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| err(&e))?;
    let scale = (width.min(height) as f64 / 512.0).clamp(0.5, 4.0);
    let px = |v: f64| (v * scale).round().max(1.0) as u32;
    let font = |size: f64| (crate::plot::FAMILY, size * scale).into_font();
    let ink = RGBColor(40, 40, 40);
    let mut chart = ChartBuilder::on(&root)
        .caption(
            "Sample points along the camera's rays",
            font(19.0).color(&ink),
        )
        .margin(px(12.0))
        .build_cartesian_3d(range(0), range(1), range(2))
        .map_err(|e| err(&e))?;
    // Turn the chart about its vertical axis until the camera's viewing
    // direction lies most nearly across the page: depth along each ray shows.
    let pitch = 0.35;
    let side_on = |yaw: f64, chart: &mut ChartContext<_, _>| {
        chart.with_projection(|mut pb| {
            pb.yaw = yaw;
            pb.pitch = pitch;
            pb.scale = 0.85;
            pb.into_matrix()
        });
        let depth = |p: DVec3| {
            let (x, y, z) = chart_of(p);
            chart.as_coord_spec().projected_depth(&x, &y, &z) as f64
        };
        (depth(fr.eye + fr.forward * half) - depth(fr.eye)).abs()
    };
    // Yaws within 25° of an axis flatten the chart (an axis points at
    // the reader), so those are not tried.
    let yaw = (0..72)
        .filter(|k| (5..=13).contains(&(k % 18)))
        .map(|k| k as f64 * std::f64::consts::PI / 36.0)
        .min_by(|&a, &b| side_on(a, &mut chart).total_cmp(&side_on(b, &mut chart)))
        .unwrap_or(0.5);
    side_on(yaw, &mut chart);
    let names = ["x", "y", "z"];
    chart
        .configure_axes()
        .label_style(font(12.0).color(&ink))
        .x_formatter(&|v| format!("{names_x} {v:.1}", names_x = names[axes[0]]))
        .y_formatter(&|v| format!("{names_y} {v:.1}", names_y = names[axes[1]]))
        .z_formatter(&|v| format!("{names_z} {v:.1}", names_z = names[axes[2]]))
        .x_labels(4)
        .y_labels(4)
        .z_labels(4)
        .light_grid_style(RGBColor(240, 240, 240))
        .bold_grid_style(RGBColor(215, 215, 215))
        .axis_panel_style(RGBColor(248, 248, 248))
        .draw()
        .map_err(|e| err(&e))?;

    let grey = RGBColor(130, 130, 130).stroke_width(px(1.0));
    let mut edges: Vec<(DVec3, DVec3)> = Vec::new();
    for k in 0..fr.far.len() {
        let next = (k + 1) % fr.far.len();
        edges.push((fr.eye, fr.far[k]));
        edges.push((fr.far[k], fr.far[next]));
        if !fr.near.is_empty() {
            edges.push((fr.near[k], fr.near[next]));
        }
    }
    chart
        .draw_series(
            edges
                .iter()
                .map(|&(a, b)| PathElement::new(vec![chart_of(a), chart_of(b)], grey)),
        )
        .map_err(|e| err(&e))?;
    // Far to near, so nearer points cover farther ones.
    let mut order: Vec<(i32, usize)> = points
        .iter()
        .enumerate()
        .filter(|(_, p)| p.0.is_finite())
        .map(|(k, p)| {
            let (x, y, z) = chart_of(p.0);
            (chart.as_coord_spec().projected_depth(&x, &y, &z), k)
        })
        .collect();
    order.sort_by(|a, b| b.cmp(a));
    let (near, far) = fr.depth;
    let dot = px(1.5);
    chart
        .draw_series(order.iter().map(|&(_, k)| {
            let (p, t) = points[k];
            let [r, g, b] = depth_colour(t, near, far);
            Circle::new(chart_of(p), dot, RGBColor(r, g, b).filled())
        }))
        .map_err(|e| err(&e))?;
    chart
        .draw_series(std::iter::once(Circle::new(
            chart_of(fr.eye),
            px(5.0),
            EYE.filled(),
        )))
        .map_err(|e| err(&e))?;

    // Legend: the eye and the depth colours, top left below the caption.
    let (lx, ly) = (px(14.0) as i32, px(48.0) as i32);
    let line = px(18.0) as i32;
    let swatch = |c: [u8; 3]| RGBColor(c[0], c[1], c[2]).filled();
    let legend: [(String, ShapeStyle); 3] = [
        ("eye".to_string(), EYE.filled()),
        (
            format!("near, t = {near}"),
            swatch(depth_colour(near, near, far)),
        ),
        (
            format!("far, t = {far}"),
            swatch(depth_colour(far, near, far)),
        ),
    ];
    for (k, (label, style)) in legend.iter().enumerate() {
        let y = ly + k as i32 * line;
        root.draw(&Circle::new((lx, y), px(5.0), *style))
            .map_err(|e| err(&e))?;
        root.draw(&Text::new(
            label.clone(),
            (lx + px(12.0) as i32, y),
            font(13.0)
                .color(&ink)
                .pos(Pos::new(HPos::Left, VPos::Center)),
        ))
        .map_err(|e| err(&e))?;
    }
    root.present().map_err(|e| err(&e))?;
    Ok(())
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
