//! Charts for people to read: loss curves, held-out PSNR curves and sweeps.
//! [`render_stacked`] draws several charts one above another on one image
//! (a sweep's measures against the same seconds, one panel each).
//!
//! A [`Chart`] is typed: a title, two [`Axis`]es whose titles carry their
//! units, and named [`Series`] whose points may carry a label (a sweep's
//! setting, `samples=64`). [`render`] draws it with plotters (bitmap
//! backend; text through ab_glyph with DejaVu Sans embedded, so no system
//! font is looked up) and returns a [`Plot`]: RGB pixels, PNG bytes on
//! demand, which axes came out logarithmic and notes on what was left out.
//!
//! Never a panic on data: non-finite values and values a log axis cannot
//! show are skipped and noted (in the image and in [`Plot::notes`]); empty
//! input gives a placeholder saying so. An axis is logarithmic when asked,
//! or with [`Scale::Auto`] when its values are all positive and span two
//! decades or more.
//!
//! The assignment's transmittance figure ([`crate::volume::figures`]) is
//! drawn with plotters too, on this module's font; its pixel checks (grid,
//! rays) are images by definition.

use std::ops::Range;
use std::sync::Once;

use plotters::coord::ranged1d::{AsRangedCoord, BoldPoints, Ranged, ValueFormatter};
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};

/// DejaVu Sans 2.37 (licence in `runtime/assets/DejaVuSans.LICENSE.md`).
#[doc(hidden)]
pub static FONT: &[u8] = include_bytes!("../../assets/DejaVuSans.ttf");
/// Registered as the generic family, which plotters' defaults also name.
pub(crate) const FAMILY: &str = "sans-serif";

/// Smallest image side [`render`] draws (width, height).
pub const MIN_SIDE: (u32, u32) = (200, 150);
/// Largest image side [`render`] draws.
pub const MAX_SIDE: u32 = 8192;
/// Nonzero magnitudes outside this range are not drawn (noted): plotters'
/// tick search needs spans and ratios that stay finite.
const MAX_ABS: f64 = 1e100;
const MIN_ABS: f64 = 1e-100;
/// Labels (series names, point labels) longer than this are cut with "…".
const MAX_LABEL_CHARS: usize = 40;
/// Series with at most this many points get a marker on every point.
const MARKED_POINTS: usize = 60;

/// Matplotlib's "tab10": distinct, and readable on white.
pub const PALETTE: [[u8; 3]; 10] = [
    [31, 119, 180],
    [255, 127, 14],
    [44, 160, 44],
    [214, 39, 40],
    [148, 103, 189],
    [140, 86, 75],
    [227, 119, 194],
    [127, 127, 127],
    [188, 189, 34],
    [23, 190, 207],
];
const INK: RGBColor = RGBColor(40, 40, 40);
const NOTE: RGBColor = RGBColor(110, 110, 110);
const GRID: RGBColor = RGBColor(225, 225, 225);

/// How an axis maps values to pixels.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Scale {
    /// Logarithmic when every value is positive and they span ≥ 2 decades.
    #[default]
    Auto,
    /// Values to pixels in proportion.
    Linear,
    /// Logarithmic; values ≤ 0 are skipped and noted.
    Log,
    /// As [`Scale::Auto`], but a linear axis starts at zero: for
    /// magnitudes (a distance, an error), whose heights then compare as
    /// ratios, and whose small differences are not blown up by an axis
    /// cut to the data.
    AutoFromZero,
}

/// An axis: its title with units (`"time per run (s)"`) and scale.
#[derive(Debug, Clone, PartialEq)]
pub struct Axis {
    /// The title with units, drawn along the axis.
    pub title: String,
    /// How values map to pixels.
    pub scale: Scale,
}

impl Axis {
    /// An axis whose scale is chosen from the data ([`Scale::Auto`]).
    pub fn new(title: impl Into<String>) -> Axis {
        Axis {
            title: title.into(),
            scale: Scale::Auto,
        }
    }

    /// The same axis with `scale`.
    pub fn scale(self, scale: Scale) -> Axis {
        Axis { scale, ..self }
    }
}

/// A data point, with an optional label drawn beside it.
#[derive(Debug, Clone, PartialEq)]
pub struct Point {
    /// Horizontal value.
    pub x: f64,
    /// Vertical value.
    pub y: f64,
    /// Drawn beside the point, if any.
    pub label: Option<String>,
}

/// A named series, drawn as a line through its points in order (broken
/// where a point is skipped), with markers when it is short.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Series {
    /// Shown in the legend when the chart has two or more named series.
    pub name: String,
    /// In drawing order.
    pub points: Vec<Point>,
}

impl Series {
    /// A series of unlabelled points.
    pub fn new(name: impl Into<String>, points: impl IntoIterator<Item = (f64, f64)>) -> Series {
        Series {
            name: name.into(),
            points: points
                .into_iter()
                .map(|(x, y)| Point { x, y, label: None })
                .collect(),
        }
    }

    /// A series whose every point is labelled.
    pub fn labelled(
        name: impl Into<String>,
        points: impl IntoIterator<Item = (f64, f64, String)>,
    ) -> Series {
        Series {
            name: name.into(),
            points: points
                .into_iter()
                .map(|(x, y, l)| Point {
                    x,
                    y,
                    label: Some(l),
                })
                .collect(),
        }
    }
}

/// What to draw. A legend is drawn when more than one series has a name.
#[derive(Debug, Clone, PartialEq)]
pub struct Chart {
    /// Drawn above the plot.
    pub title: String,
    /// The horizontal axis.
    pub x: Axis,
    /// The vertical axis.
    pub y: Axis,
    /// The data, each with its own colour.
    pub series: Vec<Series>,
}

/// A drawn chart.
#[derive(Debug, Clone)]
pub struct Plot {
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// RGB8, row-major from the top-left.
    pub rgb: Vec<u8>,
    /// Whether the x axis came out logarithmic.
    pub log_x: bool,
    /// Whether the y axis came out logarithmic.
    pub log_y: bool,
    /// The plotting area in pixels: `[left, top, right, bottom)`.
    pub area: [i32; 4],
    /// What was not drawn and why ("2 points not finite (NaN or ±∞)"),
    /// also written under the chart; "no data to plot" for a placeholder.
    pub notes: Vec<String>,
}

impl Plot {
    /// The image as PNG bytes (for [`crate::output::write_bytes`]).
    pub fn png(&self) -> Result<Vec<u8>, PlotError> {
        png(&self.rgb, self.width, self.height)
    }
}

/// Charts drawn one above another on one image ([`render_stacked`]): a
/// sweep's measures against the same seconds, one panel each.
#[derive(Debug, Clone)]
pub struct Figure {
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels (the panels' heights together).
    pub height: u32,
    /// RGB8, row-major from the top-left.
    pub rgb: Vec<u8>,
    /// Each chart's panel, top to bottom.
    pub panels: Vec<Panel>,
}

/// One chart of a [`Figure`]: what [`Plot`] says of a chart drawn alone,
/// its plotting area in the figure's pixels.
#[derive(Debug, Clone)]
pub struct Panel {
    /// Whether the x axis came out logarithmic.
    pub log_x: bool,
    /// Whether the y axis came out logarithmic.
    pub log_y: bool,
    /// The plotting area in the figure's pixels: `[left, top, right, bottom)`.
    pub area: [i32; 4],
    /// What was not drawn and why (see [`Plot::notes`]).
    pub notes: Vec<String>,
}

impl Figure {
    /// The image as PNG bytes (for [`crate::output::write_bytes`]).
    pub fn png(&self) -> Result<Vec<u8>, PlotError> {
        png(&self.rgb, self.width, self.height)
    }
}

fn png(rgb: &[u8], width: u32, height: u32) -> Result<Vec<u8>, PlotError> {
    use image::ImageEncoder;
    let mut out = Vec::new();
    image::codecs::png::PngEncoder::new(&mut out)
        .write_image(rgb, width, height, image::ExtendedColorType::Rgb8)
        .map_err(|e| PlotError::Draw(e.to_string()))?;
    Ok(out)
}

/// Why a chart could not be drawn (never the data: see the module docs).
#[derive(Debug, Clone, PartialEq)]
pub enum PlotError {
    /// Outside [`MIN_SIDE`]..=[`MAX_SIDE`].
    Size {
        /// The width asked for.
        width: u32,
        /// The height asked for.
        height: u32,
    },
    /// The drawing library failed.
    Draw(String),
}

impl std::fmt::Display for PlotError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            PlotError::Size { width, height } => write!(
                f,
                "a plot of {width}×{height} pixels cannot be drawn: sides must be {}..={MAX_SIDE} wide and {}..={MAX_SIDE} high",
                MIN_SIDE.0, MIN_SIDE.1
            ),
            PlotError::Draw(e) => write!(f, "drawing a plot failed: {e}"),
        }
    }
}

impl std::error::Error for PlotError {}

impl From<PlotError> for std::io::Error {
    fn from(e: PlotError) -> std::io::Error {
        std::io::Error::other(e)
    }
}

fn draw_err(e: impl std::fmt::Debug) -> PlotError {
    PlotError::Draw(format!("{e:?}"))
}

pub(crate) fn register_font() {
    static ONCE: Once = Once::new();
    ONCE.call_once(|| {
        // The embedded font parses (tested); were it not to, text would be
        // missing and drawing would report the error.
        let _ = plotters::style::register_font(FAMILY, FontStyle::Normal, FONT);
    });
}

/// Draws `chart` on a `width × height` white image.
pub fn render(chart: &Chart, width: u32, height: u32) -> Result<Plot, PlotError> {
    if !(MIN_SIDE.0..=MAX_SIDE).contains(&width) || !(MIN_SIDE.1..=MAX_SIDE).contains(&height) {
        return Err(PlotError::Size { width, height });
    }
    register_font();
    let data = Prepared::new(chart);
    let mut rgb = vec![255u8; width as usize * height as usize * 3];
    let area = {
        let root = BitMapBackend::with_buffer(&mut rgb, (width, height)).into_drawing_area();
        let area = match (data.log_x, data.log_y) {
            (false, false) => draw(&root, chart, &data, data.xr.clone(), data.yr.clone()),
            (true, false) => draw(
                &root,
                chart,
                &data,
                data.xr.clone().log_scale(),
                data.yr.clone(),
            ),
            (false, true) => draw(
                &root,
                chart,
                &data,
                data.xr.clone(),
                data.yr.clone().log_scale(),
            ),
            (true, true) => draw(
                &root,
                chart,
                &data,
                data.xr.clone().log_scale(),
                data.yr.clone().log_scale(),
            ),
        }?;
        root.present().map_err(draw_err)?;
        area
    };
    Ok(Plot {
        width,
        height,
        rgb,
        log_x: data.log_x,
        log_y: data.log_y,
        area: area.0,
        notes: area.1,
    })
}

/// Draws `charts` one above another, each on a `width × panel_height`
/// panel exactly as [`render`] draws it alone, so one chart gives
/// [`render`]'s image. No charts give one placeholder panel ("no data to
/// plot"). The whole image must be within [`MIN_SIDE`]..=[`MAX_SIDE`].
pub fn render_stacked(
    charts: &[Chart],
    width: u32,
    panel_height: u32,
) -> Result<Figure, PlotError> {
    let placeholder = [Chart {
        title: String::new(),
        x: Axis::new(""),
        y: Axis::new(""),
        series: Vec::new(),
    }];
    let charts = if charts.is_empty() {
        &placeholder[..]
    } else {
        charts
    };
    let height = u32::try_from(charts.len())
        .ok()
        .and_then(|n| n.checked_mul(panel_height))
        .filter(|&h| h <= MAX_SIDE && panel_height >= MIN_SIDE.1)
        .ok_or(PlotError::Size {
            width,
            height: panel_height.saturating_mul(charts.len().min(u32::MAX as usize) as u32),
        })?;
    let mut rgb = Vec::new();
    let mut panels = Vec::with_capacity(charts.len());
    for (k, chart) in charts.iter().enumerate() {
        let p = render(chart, width, panel_height)?;
        let top = (k as u32 * panel_height) as i32;
        let [l, t, r, b] = p.area;
        panels.push(Panel {
            log_x: p.log_x,
            log_y: p.log_y,
            area: [l, t + top, r, b + top],
            notes: p.notes,
        });
        rgb.extend_from_slice(&p.rgb);
    }
    Ok(Figure {
        width,
        height,
        rgb,
        panels,
    })
}

/// Consecutive drawable points of a series: x, y and label.
type Run = Vec<(f64, f64, Option<String>)>;

/// The chart's points sorted into what is drawn, with ranges and scales.
struct Prepared {
    /// Per series: its runs.
    runs: Vec<Vec<Run>>,
    log_x: bool,
    log_y: bool,
    xr: Range<f64>,
    yr: Range<f64>,
    notes: Vec<String>,
    empty: bool,
}

impl Prepared {
    fn new(chart: &Chart) -> Prepared {
        let in_range = |v: f64| v == 0.0 || (MIN_ABS..=MAX_ABS).contains(&v.abs());
        let all = || chart.series.iter().flat_map(|s| s.points.iter());
        let finite = |p: &&Point| p.x.is_finite() && p.y.is_finite();
        let not_finite = all().filter(|p| !finite(p)).count();
        let out_of_range = all()
            .filter(finite)
            .filter(|p| !(in_range(p.x) && in_range(p.y)))
            .count();
        let usable =
            |p: &Point| p.x.is_finite() && p.y.is_finite() && in_range(p.x) && in_range(p.y);
        let log = |scale: Scale, v: &dyn Fn(&Point) -> f64| match scale {
            Scale::Linear => false,
            Scale::Log => true,
            Scale::Auto | Scale::AutoFromZero => {
                let (lo, hi, pos) = all()
                    .filter(|p| usable(p))
                    .map(v)
                    .fold((f64::INFINITY, 0.0f64, true), |(lo, hi, pos), v| {
                        (lo.min(v), hi.max(v), pos && v > 0.0)
                    });
                pos && lo.is_finite() && hi >= 100.0 * lo
            }
        };
        let log_x = log(chart.x.scale, &|p| p.x);
        let log_y = log(chart.y.scale, &|p| p.y);
        let drawable = |p: &Point| usable(p) && (!log_x || p.x > 0.0) && (!log_y || p.y > 0.0);
        let not_positive = all().filter(|p| usable(p) && !drawable(p)).count();

        let runs: Vec<Vec<Run>> = chart
            .series
            .iter()
            .map(|s| {
                let mut runs = vec![Vec::new()];
                for p in &s.points {
                    if drawable(p) {
                        let label = p.label.as_deref().map(|l| shorten(l, MAX_LABEL_CHARS));
                        runs.last_mut().expect("one run").push((p.x, p.y, label));
                    } else if !runs.last().expect("one run").is_empty() {
                        runs.push(Vec::new());
                    }
                }
                runs.retain(|r| !r.is_empty());
                runs
            })
            .collect();
        let pts = || runs.iter().flatten().flatten();
        let empty = pts().next().is_none();
        let from_zero = |a: &Axis, log: bool| a.scale == Scale::AutoFromZero && !log;
        let xr = range(pts().map(|p| p.0), log_x, from_zero(&chart.x, log_x));
        let yr = range(pts().map(|p| p.1), log_y, from_zero(&chart.y, log_y));

        let mut notes = Vec::new();
        let plural = |n: usize| if n == 1 { "point" } else { "points" };
        if not_finite > 0 {
            notes.push(format!(
                "{not_finite} {} not finite (NaN or ±∞): not drawn",
                plural(not_finite)
            ));
        }
        if out_of_range > 0 {
            notes.push(format!(
                "{out_of_range} {} beyond 1e±100: not drawn",
                plural(out_of_range)
            ));
        }
        if not_positive > 0 {
            notes.push(format!(
                "{not_positive} {} ≤ 0 on a log axis: not drawn",
                plural(not_positive)
            ));
        }
        if empty {
            notes.push("no data to plot".to_string());
        }
        Prepared {
            runs,
            log_x,
            log_y,
            xr,
            yr,
            notes,
            empty,
        }
    }
}

/// The axis range of the drawn values: padded by 5% each side, a range
/// around a lone value, and on a log axis at least one whole decade inside;
/// `from_zero` (linear): zero inside, as one end when the values are of one
/// sign.
#[doc(hidden)]
pub fn range(vals: impl Iterator<Item = f64>, log: bool, from_zero: bool) -> Range<f64> {
    let (mut lo, mut hi) = vals
        .map(|v| if log { v.log10() } else { v })
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| {
            (a.min(v), b.max(v))
        });
    if lo > hi {
        return if log { 1.0..10.0 } else { 0.0..1.0 };
    }
    if log {
        let pad = (0.05 * (hi - lo)).max(0.1);
        let (mut a, b) = (lo - pad, hi + pad);
        if b.floor() < a {
            a = a.floor();
        }
        return 10f64.powf(a)..10f64.powf(b);
    }
    if from_zero {
        (lo, hi) = (lo.min(0.0), hi.max(0.0));
    }
    let mid = 0.5 * lo + 0.5 * hi;
    let span = hi - lo;
    // Values equal to nine digits are drawn as one value: ticks a part in
    // 1e9 apart would all read the same.
    if span <= mid.abs() * 1e-9 {
        let pad = if mid == 0.0 { 1.0 } else { 0.1 * mid.abs() };
        return (mid - pad)..(mid + pad);
    }
    let pad = |end: f64| {
        if from_zero && end == 0.0 {
            0.0
        } else {
            0.05 * span
        }
    };
    (lo - pad(lo))..(hi + pad(hi))
}

/// `s` cut to `n` characters, ending in "…" when cut.
#[doc(hidden)]
pub fn shorten(s: &str, n: usize) -> String {
    if s.chars().count() <= n {
        s.to_string()
    } else {
        let mut t: String = s.chars().take(n.saturating_sub(1)).collect();
        t.push('…');
        t
    }
}

/// A tick value to `digits` significant digits (whole numbers whole),
/// without trailing zeros; exponent form outside 1e-3..1e5.
#[doc(hidden)]
pub fn fmt_value(v: f64, digits: usize) -> String {
    let a = v.abs();
    if a == 0.0 {
        return "0".into();
    }
    let trim = |s: String| {
        if s.contains('.') {
            s.trim_end_matches('0').trim_end_matches('.').to_string()
        } else {
            s
        }
    };
    if (1e-3..1e5).contains(&a) {
        let decimals = (digits as i32 - 1 - a.log10().floor() as i32).max(0) as usize;
        trim(format!("{v:.decimals$}"))
    } else {
        let s = format!("{v:.*e}", digits.saturating_sub(1));
        match s.split_once('e') {
            Some((m, e)) => format!("{}e{e}", trim(m.to_string())),
            None => s,
        }
    }
}

/// The fewest significant digits (up to 10) that tell `ticks` apart.
#[doc(hidden)]
pub fn tick_digits(ticks: &[f64]) -> usize {
    (1..=10)
        .find(|&d| {
            let labels: Vec<String> = ticks.iter().map(|&t| fmt_value(t, d)).collect();
            labels.windows(2).all(|w| w[0] != w[1])
        })
        .unwrap_or(10)
}

const X_LABELS: usize = 8;
const Y_LABELS: usize = 7;

fn draw<X, Y>(
    root: &DrawingArea<BitMapBackend, plotters::coord::Shift>,
    chart: &Chart,
    data: &Prepared,
    xr: X,
    yr: Y,
) -> Result<([i32; 4], Vec<String>), PlotError>
where
    X: AsRangedCoord<Value = f64>,
    Y: AsRangedCoord<Value = f64>,
    X::CoordDescType: ValueFormatter<f64>,
    Y::CoordDescType: ValueFormatter<f64>,
{
    let (w, h) = root.dim_in_pixel();
    // Sizes in pixels at 640 × 400, scaled with the image.
    let s = (w as f64 / 640.0).min(h as f64 / 400.0).clamp(0.6, 4.0);
    let px = |v: f64| (v * s).round().max(1.0) as u32;
    let font = |size: f64| (FAMILY, size * s).into_font();
    let mut notes = data.notes.clone();

    root.fill(&WHITE).map_err(draw_err)?;
    let title_style = font(21.0).color(&INK);
    let title = fit(root, &chart.title, &title_style, w as f64 - 20.0 * s)?;
    let note_h = if notes.is_empty() { 0 } else { px(20.0) };

    let xc: X::CoordDescType = xr.into();
    let yc: Y::CoordDescType = yr.into();
    let xt = xc.key_points(BoldPoints(X_LABELS));
    let yt = yc.key_points(BoldPoints(Y_LABELS));
    let (xd, yd) = (tick_digits(&xt), tick_digits(&yt));
    let label_style = font(14.0).color(&INK);
    let y_label_w = yt
        .iter()
        .map(|&v| root.estimate_text_size(&fmt_value(v, yd), &label_style))
        .collect::<Result<Vec<_>, _>>()
        .map_err(draw_err)?
        .into_iter()
        .map(|(w, _)| w)
        .max()
        .unwrap_or(0);

    let mut builder = ChartBuilder::on(root);
    if !title.is_empty() {
        builder.caption(&title, title_style.clone());
    }
    let mut cc = builder
        .margin(px(10.0))
        .margin_right(px(22.0))
        .margin_bottom(px(6.0) + note_h)
        .x_label_area_size(px(48.0))
        .y_label_area_size(y_label_w + px(36.0))
        .build_cartesian_2d(xc, yc)
        .map_err(draw_err)?;
    let (ax, ay) = cc.plotting_area().get_pixel_range();
    let area = [ax.start, ay.start, ax.end, ay.end];

    let desc_style = font(16.0).color(&INK);
    let x_title = fit(
        root,
        &chart.x.title,
        &desc_style,
        (ax.end - ax.start) as f64,
    )?;
    let y_title = fit(
        root,
        &chart.y.title,
        &desc_style,
        (ay.end - ay.start) as f64,
    )?;
    let fx = |v: &f64| fmt_value(*v, xd);
    let fy = |v: &f64| fmt_value(*v, yd);
    cc.configure_mesh()
        .x_labels(X_LABELS)
        .y_labels(Y_LABELS)
        .x_label_formatter(&fx)
        .y_label_formatter(&fy)
        .x_desc(x_title)
        .y_desc(y_title)
        .label_style(label_style.clone())
        .axis_desc_style(desc_style)
        .bold_line_style(GRID)
        .light_line_style(WHITE)
        .axis_style(INK)
        .draw()
        .map_err(draw_err)?;

    let marker = px(3.5);
    let mut named = 0;
    for (k, (series, runs)) in chart.series.iter().zip(&data.runs).enumerate() {
        let [r, g, b] = PALETTE[k % PALETTE.len()];
        let colour = RGBColor(r, g, b);
        let n: usize = runs.iter().map(Vec::len).sum();
        let mut legend = false;
        for run in runs {
            let line = run.iter().map(|p| (p.0, p.1));
            let anno = cc
                .draw_series(LineSeries::new(line, colour.stroke_width(px(2.0))))
                .map_err(draw_err)?;
            if !legend && !series.name.is_empty() {
                legend = true;
                named += 1;
                let stroke = colour.stroke_width(px(2.0));
                let l = px(20.0) as i32;
                anno.label(shorten(&series.name, MAX_LABEL_CHARS))
                    .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + l, y)], stroke));
            }
            if n <= MARKED_POINTS || run.len() == 1 {
                cc.draw_series(
                    run.iter()
                        .map(|p| Circle::new((p.0, p.1), marker, colour.filled())),
                )
                .map_err(draw_err)?;
            }
        }
    }
    if named > 1 {
        let corner = emptiest_corner(data, &cc);
        cc.configure_series_labels()
            .position(corner)
            .margin(px(8.0))
            .label_font(font(14.0).color(&INK))
            .background_style(WHITE.mix(0.9))
            .border_style(RGBColor(170, 170, 170))
            .draw()
            .map_err(draw_err)?;
    }

    // Point labels: beside their point, inside the plotting area, never
    // over another label or a marker, and crossing as little of the lines
    // as the places tried allow; a label with no free place is left out
    // (noted). Each sits on a pale box so a line under it stays readable.
    let label_style = font(13.0).color(&INK);
    let gap = px(6.0) as i32;
    let labels: Vec<(i32, i32, &String)> = data
        .runs
        .iter()
        .flatten()
        .flatten()
        .filter_map(|(x, y, l)| {
            let (cx, cy) = cc.backend_coord(&(*x, *y));
            l.as_ref().map(|l| (cx, cy, l))
        })
        .collect();
    // The drawn lines as pixels about two apart (only when labels need them).
    let mut ink: Vec<(i32, i32)> = Vec::new();
    if !labels.is_empty() {
        for run in data.runs.iter().flatten() {
            let pts: Vec<(i32, i32)> = run.iter().map(|p| cc.backend_coord(&(p.0, p.1))).collect();
            ink.extend(&pts);
            for w in pts.windows(2) {
                let (a, b) = (w[0], w[1]);
                let n = ((b.0 - a.0).abs().max((b.1 - a.1).abs()) / 2).clamp(1, 4096);
                ink.extend((1..n).map(|k| {
                    let t = k as f64 / n as f64;
                    (
                        a.0 + ((b.0 - a.0) as f64 * t) as i32,
                        a.1 + ((b.1 - a.1) as f64 * t) as i32,
                    )
                }));
            }
        }
    }
    let markers: Vec<[i32; 4]> = labels
        .iter()
        .map(|&(cx, cy, _)| {
            let r = marker as i32 + 1;
            [cx - r, cy - r, cx + r, cy + r]
        })
        .collect();
    let overlaps =
        |a: &[i32; 4], b: &[i32; 4]| !(a[2] < b[0] || b[2] < a[0] || a[3] < b[1] || b[3] < a[1]);
    let mut boxes: Vec<[i32; 4]> = Vec::new();
    let mut left_out = 0;
    for &(cx, cy, label) in &labels {
        let (tw, th) = root
            .estimate_text_size(label, &label_style)
            .map_err(draw_err)?;
        let (tw, th) = (tw as i32 + 4, th as i32 + 2);
        let candidates = [
            (cx + gap, cy - gap - th),
            (cx + gap, cy + gap),
            (cx - gap - tw, cy - gap - th),
            (cx - gap - tw, cy + gap),
            (cx - tw / 2, cy - 2 * gap - th),
            (cx - tw / 2, cy + 2 * gap),
            (cx + 2 * gap, cy - th / 2),
            (cx - 2 * gap - tw, cy - th / 2),
        ];
        let place = candidates
            .into_iter()
            .map(|(x0, y0)| [x0, y0, x0 + tw, y0 + th])
            .filter(|b| {
                b[0] >= area[0]
                    && b[1] >= area[1]
                    && b[2] < area[2]
                    && b[3] < area[3]
                    && !boxes.iter().chain(&markers).any(|o| overlaps(b, o))
            })
            .enumerate()
            .min_by_key(|(k, b)| {
                let crossed = ink
                    .iter()
                    .filter(|p| (b[0]..=b[2]).contains(&p.0) && (b[1]..=b[3]).contains(&p.1))
                    .count();
                (crossed, *k)
            })
            .map(|(_, b)| b);
        match place {
            Some(b) => {
                boxes.push(b);
                root.draw(&Rectangle::new(
                    [(b[0], b[1]), (b[2], b[3])],
                    WHITE.mix(0.85).filled(),
                ))
                .map_err(draw_err)?;
                root.draw(&Text::new(
                    label.clone(),
                    (b[0] + 2, b[1] + 1),
                    label_style.clone(),
                ))
                .map_err(draw_err)?;
            }
            None => left_out += 1,
        }
    }
    if left_out > 0 {
        notes.push(format!(
            "{left_out} point {} left out (no room)",
            if left_out == 1 { "label" } else { "labels" }
        ));
    }

    if data.empty {
        let style = font(18.0)
            .color(&NOTE)
            .pos(Pos::new(HPos::Center, VPos::Center));
        let centre = ((area[0] + area[2]) / 2, (area[1] + area[3]) / 2);
        root.draw(&Text::new("no data to plot", centre, style))
            .map_err(draw_err)?;
    }
    if !notes.is_empty() {
        let style = font(13.0).color(&NOTE);
        // The placeholder says "no data" in the middle already.
        let shown: Vec<&str> = notes
            .iter()
            .map(String::as_str)
            .filter(|n| *n != "no data to plot")
            .collect();
        let text = fit(root, &shown.join("; "), &style, w as f64 - 20.0 * s)?;
        let y = h as i32 - px(6.0) as i32 - note_h as i32 + px(2.0) as i32;
        root.draw(&Text::new(text, (px(10.0) as i32, y), style))
            .map_err(draw_err)?;
    }
    Ok((area, notes))
}

/// The corner of the plotting area with the fewest points near it.
fn emptiest_corner<X: Ranged<ValueType = f64>, Y: Ranged<ValueType = f64>>(
    data: &Prepared,
    cc: &ChartContext<BitMapBackend, Cartesian2d<X, Y>>,
) -> SeriesLabelPosition {
    let (ax, ay) = cc.plotting_area().get_pixel_range();
    let (w, h) = ((ax.end - ax.start) as f64, (ay.end - ay.start) as f64);
    let mut counts = [0usize; 4];
    for p in data.runs.iter().flatten().flatten() {
        let (x, y) = cc.backend_coord(&(p.0, p.1));
        let u = (x - ax.start) as f64 / w;
        let v = (y - ay.start) as f64 / h;
        let (right, lower) = (u > 0.55, v > 0.65);
        if (u < 0.45 || right) && (v < 0.35 || lower) {
            counts[right as usize + 2 * lower as usize] += 1;
        }
    }
    let order = [
        (1, SeriesLabelPosition::UpperRight),
        (0, SeriesLabelPosition::UpperLeft),
        (3, SeriesLabelPosition::LowerRight),
        (2, SeriesLabelPosition::LowerLeft),
    ];
    let best = order.iter().map(|(k, _)| counts[*k]).min().unwrap_or(0);
    order
        .into_iter()
        .find(|(k, _)| counts[*k] == best)
        .map_or(SeriesLabelPosition::UpperRight, |(_, p)| p)
}

/// `text` cut (with "…") to fit `max_w` pixels in `style`.
fn fit(
    root: &DrawingArea<BitMapBackend, plotters::coord::Shift>,
    text: &str,
    style: &TextStyle,
    max_w: f64,
) -> Result<String, PlotError> {
    let width = |t: &str| {
        root.estimate_text_size(t, style)
            .map(|(w, _)| w as f64)
            .map_err(draw_err)
    };
    if width(text)? <= max_w {
        return Ok(text.to_string());
    }
    let chars: Vec<char> = text.chars().collect();
    // Binary search on the kept prefix.
    let (mut lo, mut hi) = (0, chars.len());
    while lo < hi {
        let mid = (lo + hi).div_ceil(2);
        let t: String = chars[..mid].iter().chain(std::iter::once(&'…')).collect();
        if width(&t)? <= max_w {
            lo = mid;
        } else {
            hi = mid - 1;
        }
    }
    Ok(chars[..lo].iter().chain(std::iter::once(&'…')).collect())
}
