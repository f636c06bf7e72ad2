//! A sweep's table and plots, rebuilt from its rows on disk: quality
//! (PSNR against the reference's images, parameter error, and what each
//! run measured: held-out PSNR and SSIM, Chamfer distances) beside time.

use std::path::{Path, PathBuf};

use sdfl_runtime::plot::{Axis, Chart, Scale, Series};

use super::metrics::{ChamferReference, Metric, Metrics};
use super::rows::Row;
/// An image a setting wrote, as 8-bit RGB: only a regular file (a FIFO
/// copied in would block), of at most the largest side sdfl renders.
fn rgb8(path: &Path) -> Option<image::RgbImage> {
    let file = sdfl_stdlib::files::open_regular(path).ok()?;
    let mut reader = image::ImageReader::new(std::io::BufReader::new(file))
        .with_guessed_format()
        .ok()?;
    let mut limits = image::Limits::default();
    let side = sdfl_runtime::data::image::MAX_SIDE;
    (limits.max_image_width, limits.max_image_height) = (Some(side), Some(side));
    reader.limits(limits);
    Some(reader.decode().ok()?.to_rgb8())
}

/// Mean squared error of two 8-bit images of the same size.
fn mse(a: &Path, b: &Path) -> Option<f64> {
    let (a, b) = (rgb8(a)?, rgb8(b)?);
    if a.dimensions() != b.dimensions() {
        return None;
    }
    let n = a.as_raw().len() as f64;
    Some(
        a.as_raw()
            .iter()
            .zip(b.as_raw())
            .map(|(x, y)| (*x as f64 - *y as f64).powi(2))
            .sum::<f64>()
            / n,
    )
}

/// Peak signal-to-noise ratio in dB of a mean squared error on 0..255.
fn psnr(mse: f64) -> f64 {
    if mse == 0.0 {
        f64::INFINITY
    } else {
        10.0 * (255.0f64 * 255.0 / mse).log10()
    }
}

/// Written colour images of a setting, by path relative to its folder.
fn images_of(reports: &[serde_json::Value]) -> Vec<String> {
    reports
        .iter()
        .flat_map(|r| r["written"].as_array().cloned().unwrap_or_default())
        .filter(|w| w["kind"] == "image")
        .filter_map(|w| w["path"].as_str().map(str::to_string))
        .collect()
}

fn params_of(reports: &[serde_json::Value]) -> Vec<f64> {
    reports
        .iter()
        .flat_map(|r| r["params"].as_array().cloned().unwrap_or_default())
        .flat_map(|p| p[1].as_array().cloned().unwrap_or_default())
        .filter_map(|v| v.as_f64())
        .collect()
}

/// One setting's measures, for the table and the plots.
#[derive(Clone, Copy)]
struct Quality {
    value: f64,
    secs: f64,
    /// PSNR of its images against the reference's (dB).
    psnr: Option<f64>,
    /// Largest difference of its learnt parameters from the reference's.
    perr: Option<f64>,
    /// What its run measured.
    metrics: Metrics,
    is_ref: bool,
}

/// What a sweep writes: the table (Markdown, also printed), the CSV and
/// the two plots (PNG).
pub(super) struct Tables {
    pub markdown: String,
    pub csv: String,
    pub against_time: Vec<u8>,
    pub against_value: Vec<u8>,
}

/// The CSV's measure columns, in the order earlier versions wrote the
/// first two. Every one is written, empty where a row has no value, so
/// sweeps of one file or another read alike.
const CSV_METRICS: [Metric; 4] = [
    Metric::HeldOutPsnr,
    Metric::MeshChamfer,
    Metric::HeldOutSsim,
    Metric::FieldChamfer,
];

/// Width of a plot, and height of each of its panels.
const PANEL: (u32, u32) = (640, 400);

/// The table and plots of settings `rows` (in `--set` order, each with its
/// folder); the last is the reference. The Markdown table has a column
/// for each measure some row has; the plots a panel each for the
/// measures the runs reported (else one of the error against the
/// reference).
pub(super) fn tables(name: &str, rows: &[(Row, PathBuf)]) -> std::io::Result<Tables> {
    let (ref_row, ref_dir) = rows.last().expect("at least two settings");
    let reference = format!("{name}={}", ref_row.value);
    let ref_images = images_of(&ref_row.reports);
    let ref_params = params_of(&ref_row.reports);
    let mut quality: Vec<Quality> = Vec::new();
    for (i, (row, dir)) in rows.iter().enumerate() {
        // PSNR of the mean squared error over all images of the run.
        let errors: Vec<f64> = ref_images
            .iter()
            .filter_map(|rel| mse(&dir.join(rel), &ref_dir.join(rel)))
            .collect();
        let psnr =
            (!errors.is_empty()).then(|| psnr(errors.iter().sum::<f64>() / errors.len() as f64));
        let params = params_of(&row.reports);
        let perr = (!params.is_empty() && params.len() == ref_params.len()).then(|| {
            params
                .iter()
                .zip(&ref_params)
                .map(|(a, b)| (a - b).abs())
                .fold(0.0, f64::max)
        });
        quality.push(Quality {
            value: row.value,
            secs: row.seconds,
            psnr,
            perr,
            metrics: row.metrics(),
            is_ref: i + 1 == rows.len(),
        });
    }
    let to = chamfer_reference(&quality);
    let markdown = markdown(name, &reference, to, &quality);
    let csv = csv(name, &quality);
    // Points in the order of the swept value, so the line runs along it.
    quality.sort_by(|a, b| a.value.total_cmp(&b.value));
    let png = |against| {
        let charts = charts(name, &reference, to, &quality, against);
        sdfl_runtime::plot::render_stacked(&charts, PANEL.0, PANEL.1).and_then(|f| f.png())
    };
    let against_time = png(Against::Time)?;
    let against_value = png(Against::Value)?;
    Ok(Tables {
        markdown,
        csv,
        against_time,
        against_value,
    })
}

/// What every setting's mesh was measured against, if the same for all.
fn chamfer_reference(quality: &[Quality]) -> Option<ChamferReference> {
    let mut to = quality
        .iter()
        .filter(|q| q.metrics.mesh_chamfer.is_some())
        .map(|q| q.metrics.mesh_chamfer_to);
    let first = to.next().flatten()?;
    to.all(|t| t == Some(first)).then_some(first)
}

/// The measures some setting has, in column order.
fn present(quality: &[Quality]) -> Vec<Metric> {
    Metric::ALL
        .into_iter()
        .filter(|m| quality.iter().any(|q| m.of(&q.metrics).is_some()))
        .collect()
}

/// The Markdown table: the value, seconds, and a column per measure some
/// setting has.
fn markdown(
    name: &str,
    reference: &str,
    to: Option<ChamferReference>,
    quality: &[Quality],
) -> String {
    let images = quality.iter().any(|q| q.psnr.is_some());
    let params = quality.iter().any(|q| q.perr.is_some());
    let metrics = present(quality);
    let mut titles = vec![name.to_string(), "seconds".to_string()];
    if images {
        titles.push(format!("PSNR vs {reference} (dB)"));
    }
    if params {
        titles.push("max parameter error".into());
    }
    titles.extend(
        metrics
            .iter()
            .map(|m| format!("{} ({})", m.name(to), m.unit())),
    );
    let mut out = format!(
        "| {} |\n|{}\n",
        titles.join(" | "),
        "---:|".repeat(titles.len())
    );
    for q in quality {
        // Only the reference row is "ref"; another run whose images equal
        // the reference's has an infinite PSNR and says so.
        let relative = |x: Option<f64>, prec: usize| {
            x.map_or("-".to_string(), |x| {
                if q.is_ref {
                    "ref".into()
                } else if x.is_infinite() {
                    "identical (∞)".into()
                } else {
                    format!("{x:.prec$}")
                }
            })
        };
        let mut cells = vec![q.value.to_string(), format!("{:.3}", q.secs)];
        if images {
            cells.push(relative(q.psnr, 2));
        }
        if params {
            cells.push(relative(q.perr, 5));
        }
        cells.extend(
            metrics
                .iter()
                .map(|m| m.of(&q.metrics).map_or("-".to_string(), |x| m.cell(x))),
        );
        out.push_str(&format!("| {} |\n", cells.join(" | ")));
    }
    out
}

/// The CSV: every column always, a value's full precision, empty where a
/// setting has none, `NaN` or `inf` where it is not finite.
fn csv(name: &str, quality: &[Quality]) -> String {
    let mut out = format!("{name},seconds,psnr_db,param_error");
    for m in CSV_METRICS {
        out.push(',');
        out.push_str(m.csv_name());
    }
    out.push('\n');
    let cell = |x: Option<f64>| x.map_or(String::new(), |x| x.to_string());
    for q in quality {
        let mut cells = vec![
            q.value.to_string(),
            q.secs.to_string(),
            cell(q.psnr),
            cell(q.perr),
        ];
        cells.extend(CSV_METRICS.iter().map(|m| cell(m.of(&q.metrics))));
        out.push_str(&cells.join(","));
        out.push('\n');
    }
    out
}

/// The horizontal axis of a sweep's plot.
#[derive(Clone, Copy)]
enum Against {
    /// Seconds per run; each point labelled with its setting.
    Time,
    /// The swept value (time may hardly change); labelled with seconds.
    Value,
}

impl Against {
    fn x(self, q: &Quality) -> f64 {
        match self {
            Against::Time => q.secs,
            Against::Value => q.value,
        }
    }

    /// A point's label: its setting against time, its seconds against
    /// the value.
    fn label(self, name: &str, q: &Quality) -> String {
        match self {
            Against::Time => format!("{name}={}", q.value),
            Against::Value if q.secs < 1.0 => format!("{:.3} s", q.secs),
            Against::Value => format!("{:.1} s", q.secs),
        }
    }

    /// The axis' title, and what the chart's title says it is against.
    fn titles(self, name: &str) -> (String, String) {
        match self {
            Against::Time => ("time per run (s)".to_string(), "time".to_string()),
            Against::Value => (
                format!("{name} (the value of `let {name}`)"),
                name.to_string(),
            ),
        }
    }
}

/// A plot's panels: one per measure the runs reported (held-out PSNR,
/// Chamfer distance…), one above another against the same axis; where
/// they reported none (renders), the error against the reference alone.
fn charts(
    name: &str,
    reference: &str,
    to: Option<ChamferReference>,
    quality: &[Quality],
    against: Against,
) -> Vec<Chart> {
    let metrics = present(quality);
    if metrics.is_empty() {
        return vec![chart(name, reference, quality, against)];
    }
    metrics
        .into_iter()
        .map(|m| metric_chart(name, m, to, quality, against))
        .collect()
}

/// One measure of the settings. A distance (Chamfer) is drawn on an axis
/// from zero, so heights compare as ratios (half the height is half the
/// distance: "0.01 against 0.019" reads as about half) and a small
/// difference is not blown up, or on a log axis where the values span two
/// decades (a failed setting beside good ones), which would otherwise
/// flatten the good ones. (Log on a narrower span would show a single
/// tick: ticks fall on powers of ten.) A non-finite value (a diverged
/// run, an empty mesh) is left out and noted under the panel.
fn metric_chart(
    name: &str,
    metric: Metric,
    to: Option<ChamferReference>,
    quality: &[Quality],
    against: Against,
) -> Chart {
    let (x_title, against_what) = against.titles(name);
    let what = metric.name(to);
    let (y_title, scale) = if metric.is_distance() {
        (
            format!("Chamfer distance ({})", metric.unit()),
            Scale::AutoFromZero,
        )
    } else {
        (
            format!("{} ({})", metric.name(to), metric.unit()),
            Scale::Auto,
        )
    };
    Chart {
        title: format!("Sweep of `{name}`: {what} against {against_what}"),
        x: Axis::new(x_title),
        y: Axis::new(y_title).scale(scale),
        series: vec![Series::labelled(
            what,
            quality.iter().filter_map(|q| {
                metric
                    .of(&q.metrics)
                    .map(|y| (against.x(q), y, against.label(name, q)))
            }),
        )],
    }
}

/// One measure of a setting (none where it does not apply).
type Measure = fn(&Quality) -> Option<f64>;

/// The error against the reference: PSNR against the reference's images,
/// else parameter error against the reference's. Settings identical to
/// the reference (the reference itself, and any whose PSNR is infinite or
/// parameter error zero) are drawn as their own marked series at the
/// best end of the axis, not dropped.
fn chart(name: &str, reference: &str, quality: &[Quality], against: Against) -> Chart {
    let images_any = quality.iter().any(|q| q.psnr.is_some());
    // (title, the measure, whether higher is better)
    let (y_title, pick, higher): (String, Measure, bool) = if images_any {
        (format!("PSNR vs {reference} (dB)"), |q| q.psnr, true)
    } else {
        (
            format!("max parameter error vs {reference}"),
            |q| q.perr,
            false,
        )
    };
    let identical = |q: &Quality| q.is_ref || pick(q).is_some_and(|y| y.is_infinite() || y == 0.0);
    let finite: Vec<f64> = quality
        .iter()
        .filter(|q| !identical(q))
        .filter_map(pick)
        .filter(|y| y.is_finite())
        .collect();
    // Identical settings: above the best PSNR (no finite height stands
    // for ∞), or at zero error.
    let marked_y = if higher {
        let (lo, hi) = finite
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), &y| {
                (l.min(y), h.max(y))
            });
        if hi.is_finite() {
            hi + (0.15 * (hi - lo)).max(1.0)
        } else {
            100.0
        }
    } else {
        0.0
    };
    let x = |q: &Quality| against.x(q);
    let label = |q: &Quality| against.label(name, q);
    let quality_name = y_title.split(" (").next().unwrap_or("quality").to_string();
    let measured = Series::labelled(
        quality_name.clone(),
        quality
            .iter()
            .filter(|q| !identical(q))
            .filter_map(|q| pick(q).map(|y| (x(q), y, label(q)))),
    );
    let marked = Series::labelled(
        if higher {
            "identical to the reference (∞ dB)"
        } else {
            "identical to the reference (error 0)"
        },
        quality.iter().filter(|q| identical(q)).map(|q| {
            let what = if q.is_ref { "reference" } else { "= ref" };
            (x(q), marked_y, format!("{} ({what})", label(q)))
        }),
    );
    let mut series = vec![measured];
    if !marked.points.is_empty() {
        series.push(marked);
    }
    let (x_title, against_what) = against.titles(name);
    Chart {
        title: format!("Sweep of `{name}`: {quality_name} against {against_what}"),
        x: Axis::new(x_title),
        y: Axis::new(y_title),
        series,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn q(value: f64, psnr: f64, is_ref: bool) -> Quality {
        Quality {
            value,
            secs: value / 10.0,
            psnr: Some(psnr),
            perr: None,
            metrics: Metrics::default(),
            is_ref,
        }
    }

    #[test]
    fn points_follow_the_value_and_identical_settings_are_marked() {
        // As `tables` hands them over: sorted by value, the reference (16)
        // listed last in `--set` but not the largest.
        let mut quality = vec![
            q(8.0, 30.0, false),
            q(2.0, 20.0, false),
            q(32.0, f64::INFINITY, false),
            q(4.0, 25.0, false),
            q(16.0, f64::INFINITY, true),
        ];
        quality.sort_by(|a, b| a.value.total_cmp(&b.value));
        let by_value = charts("n", "n=16", None, &quality, Against::Value);
        assert_eq!(by_value.len(), 1, "a render sweep: one panel");
        let by_value = &by_value[0];
        assert_eq!(by_value.series.len(), 2);
        let xs = |s: &Series| s.points.iter().map(|p| p.x).collect::<Vec<_>>();
        assert_eq!(xs(&by_value.series[0]), [2.0, 4.0, 8.0]);
        // Both identical settings drawn, above the best finite PSNR.
        let marked = &by_value.series[1];
        assert_eq!(xs(marked), [16.0, 32.0]);
        assert!(marked.points.iter().all(|p| p.y.is_finite() && p.y > 30.0));
        let labels: Vec<&str> = marked
            .points
            .iter()
            .filter_map(|p| p.label.as_deref())
            .collect();
        assert!(
            labels[0].ends_with("(reference)") && labels[1].ends_with("(= ref)"),
            "{labels:?}"
        );
        // Against time, in the order of the value too (not of time).
        let by_time = chart("n", "n=16", &quality, Against::Time);
        let labels: Vec<&str> = by_time.series[0]
            .points
            .iter()
            .filter_map(|p| p.label.as_deref())
            .collect();
        assert_eq!(labels, ["n=2", "n=4", "n=8"]);
        // Held-out PSNR is absolute: nothing is marked, the reference is a point.
        let held: Vec<Quality> = quality
            .iter()
            .map(|x| Quality {
                metrics: Metrics {
                    held_out_psnr_db: Some(x.value),
                    ..Metrics::default()
                },
                ..*x
            })
            .collect();
        let held_out = charts("n", "n=16", None, &held, Against::Value);
        assert_eq!(held_out.len(), 1);
        assert_eq!(held_out[0].series.len(), 1);
        assert_eq!(xs(&held_out[0].series[0]), [2.0, 4.0, 8.0, 16.0, 32.0]);
        assert_eq!(held_out[0].y.title, "held-out PSNR (dB)");
    }

    /// A NeuS sweep's row: held-out PSNR and a mesh against the truth.
    fn row(steps: f64, seconds: f64, psnr: f64, chamfer: f64) -> (Row, PathBuf) {
        let metrics = Metrics {
            held_out_psnr_db: Some(psnr),
            mesh_chamfer: Some(chamfer),
            mesh_chamfer_to: Some(ChamferReference::TrueSurface),
            ..Metrics::default()
        };
        let row = Row {
            format: super::super::rows::ROW_FORMAT,
            name: "steps".into(),
            value: steps,
            fingerprint: String::new(),
            seconds,
            reports: Vec::new(),
            metrics: Some(metrics),
        };
        (row, PathBuf::from(format!("steps={steps}")))
    }

    fn png_size(png: &[u8]) -> (u32, u32) {
        let img = image::load_from_memory(png).unwrap();
        (img.width(), img.height())
    }

    /// The rows' measures as the plots take them, `reference` marked.
    fn qualities(rows: &[(Row, PathBuf)], reference: Option<f64>) -> Vec<Quality> {
        rows.iter()
            .map(|(r, _)| Quality {
                value: r.value,
                secs: r.seconds,
                psnr: None,
                perr: None,
                metrics: r.metrics(),
                is_ref: Some(r.value) == reference,
            })
            .collect()
    }

    #[test]
    fn the_table_has_a_chamfer_column_and_the_plot_a_panel_for_it() {
        let rows = [
            row(200.0, 31.5, 24.126, 0.0412),
            row(400.0, 60.25, 26.5, 0.01934),
            row(800.0, 118.0, 28.75, 0.009_87),
        ];
        let t = tables("steps", &rows).unwrap();
        let md: Vec<&str> = t.markdown.lines().collect();
        assert_eq!(
            md[0],
            "| steps | seconds | held-out PSNR (dB) | mesh Chamfer to the true surface (scene units) |"
        );
        assert_eq!(md[1], "|---:|---:|---:|---:|");
        assert_eq!(md[2], "| 200 | 31.500 | 24.13 | 0.0412 |");
        assert_eq!(md[3], "| 400 | 60.250 | 26.50 | 0.0193 |");
        assert_eq!(md[4], "| 800 | 118.000 | 28.75 | 0.00987 |");
        let csv: Vec<&str> = t.csv.lines().collect();
        assert_eq!(
            csv[0],
            "steps,seconds,psnr_db,param_error,held_out_psnr_db,mesh_chamfer,held_out_ssim,field_chamfer"
        );
        assert_eq!(csv[1], "200,31.5,,,24.126,0.0412,,");
        assert_eq!(csv[3], "800,118,,,28.75,0.00987,,");
        // Two measures: two panels, one above the other.
        assert_eq!(png_size(&t.against_time), (640, 800));
        assert_eq!(png_size(&t.against_value), (640, 800));
        let quality = qualities(&rows, Some(800.0));
        let to = chamfer_reference(&quality);
        assert_eq!(to, Some(ChamferReference::TrueSurface));
        let panels = charts("steps", "steps=800", to, &quality, Against::Time);
        assert_eq!(panels.len(), 2);
        let (psnr, chamfer) = (&panels[0], &panels[1]);
        assert_eq!(psnr.y.title, "held-out PSNR (dB)");
        assert_eq!(psnr.y.scale, Scale::Auto);
        assert_eq!(chamfer.y.title, "Chamfer distance (scene units)");
        assert_eq!(chamfer.y.scale, Scale::AutoFromZero);
        assert_eq!(
            chamfer.title,
            "Sweep of `steps`: mesh Chamfer to the true surface against time"
        );
        assert_eq!(psnr.x.title, "time per run (s)");
        let points: Vec<(f64, f64, &str)> = chamfer.series[0]
            .points
            .iter()
            .map(|p| (p.x, p.y, p.label.as_deref().unwrap()))
            .collect();
        assert_eq!(
            points,
            [
                (31.5, 0.0412, "steps=200"),
                (60.25, 0.01934, "steps=400"),
                (118.0, 0.00987, "steps=800"),
            ]
        );
    }

    #[test]
    fn a_render_sweep_keeps_one_panel_and_its_columns() {
        // No measures reported, no images: value and seconds only, and one
        // panel (the placeholder of no data).
        let mut rows = vec![row(1.0, 1.0, 0.0, 0.0), row(2.0, 2.0, 0.0, 0.0)];
        for (r, _) in &mut rows {
            r.metrics = Some(Metrics::default());
        }
        let t = tables("n", &rows).unwrap();
        assert_eq!(t.markdown.lines().next(), Some("| n | seconds |"));
        assert_eq!(png_size(&t.against_time), (640, 400));
    }

    #[test]
    fn a_diverged_setting_says_so_and_its_point_is_left_out() {
        let mut rows = vec![
            row(200.0, 30.0, 24.0, 0.04),
            row(400.0, 60.0, f64::NAN, f64::INFINITY),
            row(800.0, 120.0, 28.0, 0.01),
        ];
        // One setting lacks a Chamfer distance (no mesh written).
        rows[0].0.metrics.as_mut().unwrap().mesh_chamfer = None;
        let t = tables("steps", &rows).unwrap();
        let md: Vec<&str> = t.markdown.lines().collect();
        assert_eq!(md[2], "| 200 | 30.000 | 24.00 | - |");
        assert_eq!(md[3], "| 400 | 60.000 | not finite | ∞ (no surface) |");
        let csv: Vec<&str> = t.csv.lines().collect();
        assert_eq!(csv[1], "200,30,,,24,,,");
        assert_eq!(csv[2], "400,60,,,NaN,inf,,");
        assert_eq!(png_size(&t.against_time), (640, 800));
        // Drawn, the non-finite points are left out and noted.
        let quality = qualities(&rows, None);
        let panels = charts("steps", "steps=800", None, &quality, Against::Time);
        let figure = sdfl_runtime::plot::render_stacked(&panels, 640, 400).unwrap();
        for p in &figure.panels {
            assert_eq!(p.notes, ["1 point not finite (NaN or ±∞): not drawn"]);
        }
        // Every setting's measures diverged: a panel saying there is no data.
        for (r, _) in &mut rows {
            r.metrics = Some(Metrics {
                held_out_psnr_db: Some(f64::NAN),
                ..Metrics::default()
            });
        }
        let t = tables("steps", &rows).unwrap();
        assert_eq!(png_size(&t.against_time), (640, 400));
    }
}
