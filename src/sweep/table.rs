//! A sweep's table and plots, rebuilt from its rows on disk: quality
//! (held-out PSNR, PSNR against the reference's images, parameter error,
//! mesh Chamfer distance) beside time.

use std::path::{Path, PathBuf};

use sdfl_runtime::plot::{Axis, Chart, Series};

use super::rows::Row;

/// Mean squared error of two 8-bit images of the same size.
fn mse(a: &Path, b: &Path) -> Option<f64> {
    let (a, b) = (
        image::open(a).ok()?.to_rgb8(),
        image::open(b).ok()?.to_rgb8(),
    );
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

/// The mean over a run's training statements of their last held-out PSNR.
fn held_out_psnr(reports: &[serde_json::Value]) -> Option<f64> {
    let last: Vec<f64> = reports
        .iter()
        .filter_map(|r| r["held_out"].as_array()?.last()?["psnr"].as_f64())
        .collect();
    (!last.is_empty()).then(|| last.iter().sum::<f64>() / last.len() as f64)
}

/// The mean over a run's training statements of their mesh's Chamfer
/// distance (to the data's points or the true surface).
/// An empty mesh (no surface found) has no finite distance: infinity.
fn mesh_chamfer(reports: &[serde_json::Value]) -> Option<f64> {
    let c: Vec<f64> = reports
        .iter()
        .filter(|r| r["mesh_fit"].is_object())
        .map(|r| r["mesh_fit"]["chamfer"].as_f64().unwrap_or(f64::INFINITY))
        .collect();
    (!c.is_empty()).then(|| c.iter().sum::<f64>() / c.len() as f64)
}

/// One setting's measures, for the plots.
#[derive(Clone, Copy)]
struct Quality {
    value: f64,
    secs: f64,
    held: Option<f64>,
    psnr: Option<f64>,
    perr: Option<f64>,
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

/// The table and plots of settings `rows` (in `--set` order, each with its
/// folder); the last is the reference.
pub(super) fn tables(name: &str, rows: &[(Row, PathBuf)]) -> std::io::Result<Tables> {
    let (ref_row, ref_dir) = rows.last().expect("at least two settings");
    let reference = format!("{name}={}", ref_row.value);
    let ref_images = images_of(&ref_row.reports);
    let ref_params = params_of(&ref_row.reports);
    let mut markdown = format!("| {name} | seconds | PSNR vs {reference} (dB) | max parameter error | held-out PSNR (dB) | mesh Chamfer |\n|---:|---:|---:|---:|---:|---:|\n");
    let mut csv = format!("{name},seconds,psnr_db,param_error,held_out_psnr_db,mesh_chamfer\n");
    let held_out_any = rows.iter().any(|r| held_out_psnr(&r.0.reports).is_some());
    let mut quality: Vec<Quality> = Vec::new();
    for (i, (row, dir)) in rows.iter().enumerate() {
        let is_ref = i + 1 == rows.len();
        // PSNR of the mean squared error over all images of the run.
        let errors: Vec<f64> = ref_images
            .iter()
            .filter_map(|rel| mse(&dir.join(rel), &ref_dir.join(rel)))
            .collect();
        let mean_psnr =
            (!errors.is_empty()).then(|| psnr(errors.iter().sum::<f64>() / errors.len() as f64));
        let params = params_of(&row.reports);
        let perr = (!params.is_empty() && params.len() == ref_params.len()).then(|| {
            params
                .iter()
                .zip(&ref_params)
                .map(|(a, b)| (a - b).abs())
                .fold(0.0, f64::max)
        });
        // Only the reference row is "ref"; another run whose images equal
        // the reference's has an infinite PSNR and says so.
        let fmt = |x: Option<f64>, prec: usize| {
            x.map_or("-".to_string(), |x| {
                if is_ref {
                    "ref".into()
                } else if x.is_infinite() {
                    "identical (∞)".into()
                } else {
                    format!("{x:.prec$}")
                }
            })
        };
        let held = held_out_psnr(&row.reports);
        let chamfer = mesh_chamfer(&row.reports);
        markdown.push_str(&format!(
            "| {} | {:.3} | {} | {} | {} | {} |\n",
            row.value,
            row.seconds,
            fmt(mean_psnr, 2),
            fmt(perr, 5),
            held.map_or("-".to_string(), |x| format!("{x:.2}")),
            chamfer.map_or("-".to_string(), |x| if x.is_finite() {
                format!("{x:.4}")
            } else {
                "no surface".to_string()
            })
        ));
        csv.push_str(&format!(
            "{},{},{},{},{},{}\n",
            row.value,
            row.seconds,
            mean_psnr.map_or(String::new(), |x| x.to_string()),
            perr.map_or(String::new(), |x| x.to_string()),
            held.map_or(String::new(), |x| x.to_string()),
            chamfer.map_or(String::new(), |x| x.to_string())
        ));
        quality.push(Quality {
            value: row.value,
            secs: row.seconds,
            held,
            psnr: mean_psnr,
            perr,
            is_ref,
        });
    }
    // Points in the order of the swept value, so the line runs along it.
    quality.sort_by(|a, b| a.value.total_cmp(&b.value));
    let png = |against| {
        let chart = chart(name, &reference, held_out_any, &quality, against);
        sdfl_runtime::plot::render(&chart, 640, 400).and_then(|p| p.png())
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

/// One measure of a setting (none where it does not apply).
type Measure = fn(&Quality) -> Option<f64>;

/// The horizontal axis of a sweep's plot.
#[derive(Clone, Copy)]
enum Against {
    /// Seconds per run; each point labelled with its setting.
    Time,
    /// The swept value (time may hardly change); labelled with seconds.
    Value,
}

/// The quality a plot shows: held-out PSNR where training held views out
/// (an absolute score, the reference's included), else PSNR against the
/// reference's images, else parameter error against the reference's.
/// Settings identical to the reference (the reference itself, and any
/// whose PSNR is infinite or parameter error zero) are drawn as their own
/// marked series at the best end of the axis, not dropped.
fn chart(
    name: &str,
    reference: &str,
    held_out_any: bool,
    quality: &[Quality],
    against: Against,
) -> Chart {
    let images_any = quality.iter().any(|q| q.psnr.is_some());
    // (title, the measure, whether higher is better)
    let (y_title, pick, higher): (String, Measure, bool) = if held_out_any {
        ("held-out PSNR (dB)".into(), |q| q.held, true)
    } else if images_any {
        (format!("PSNR vs {reference} (dB)"), |q| q.psnr, true)
    } else {
        (
            format!("max parameter error vs {reference}"),
            |q| q.perr,
            false,
        )
    };
    let identical = |q: &Quality| {
        !held_out_any && (q.is_ref || pick(q).is_some_and(|y| y.is_infinite() || y == 0.0))
    };
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
    let x = |q: &Quality| match against {
        Against::Time => q.secs,
        Against::Value => q.value,
    };
    let label = |q: &Quality| match against {
        Against::Time => format!("{name}={}", q.value),
        Against::Value if q.secs < 1.0 => format!("{:.3} s", q.secs),
        Against::Value => format!("{:.1} s", q.secs),
    };
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
    let (x_title, against_what) = match against {
        Against::Time => ("time per run (s)".to_string(), "time".to_string()),
        Against::Value => (
            format!("{name} (the value of `let {name}`)"),
            name.to_string(),
        ),
    };
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
            held: None,
            psnr: Some(psnr),
            perr: None,
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
        let by_value = chart("n", "n=16", false, &quality, Against::Value);
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
        let by_time = chart("n", "n=16", false, &quality, Against::Time);
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
                held: Some(x.value),
                ..*x
            })
            .collect();
        let held_out = chart("n", "n=16", true, &held, Against::Value);
        assert_eq!(held_out.series.len(), 1);
        assert_eq!(xs(&held_out.series[0]), [2.0, 4.0, 8.0, 16.0, 32.0]);
    }
}
