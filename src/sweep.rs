//! `sdfl sweep`: a file re-run over values of one `let`, with quality and
//! time side by side.

use super::*;
use sdfl_runtime::plot::{Axis, Chart, Series};

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

/// Written colour images of a report set, by relative path.
fn images_of(reports: &[Report]) -> Vec<String> {
    reports
        .iter()
        .flat_map(|r| r.report["written"].as_array().cloned().unwrap_or_default())
        .filter(|w| w["kind"] == "image")
        .filter_map(|w| w["path"].as_str().map(str::to_string))
        .collect()
}

fn params_of(reports: &[Report]) -> Vec<f64> {
    reports
        .iter()
        .flat_map(|r| r.report["params"].as_array().cloned().unwrap_or_default())
        .flat_map(|p| p[1].as_array().cloned().unwrap_or_default())
        .filter_map(|v| v.as_f64())
        .collect()
}

/// The mean over a run's training statements of their last held-out PSNR.
fn held_out_psnr(reports: &[Report]) -> Option<f64> {
    let last: Vec<f64> = reports
        .iter()
        .filter_map(|r| r.report["held_out"].as_array()?.last()?["psnr"].as_f64())
        .collect();
    (!last.is_empty()).then(|| last.iter().sum::<f64>() / last.len() as f64)
}

/// The mean over a run's training statements of their mesh's Chamfer
/// distance (to the data's points or the true surface).
/// An empty mesh (no surface found) has no finite distance: infinity.
fn mesh_chamfer(reports: &[Report]) -> Option<f64> {
    let c: Vec<f64> = reports
        .iter()
        .filter(|r| r.report["mesh_fit"].is_object())
        .map(|r| {
            r.report["mesh_fit"]["chamfer"]
                .as_f64()
                .unwrap_or(f64::INFINITY)
        })
        .collect();
    (!c.is_empty()).then(|| c.iter().sum::<f64>() / c.len() as f64)
}

/// One run's measures, for the plots.
struct Quality {
    value: f64,
    secs: f64,
    held: Option<f64>,
    psnr: Option<f64>,
    perr: Option<f64>,
}

pub(crate) fn sweep(
    file: &Path,
    name: &str,
    values: &[f64],
    out: &Path,
    size: Option<(u32, u32)>,
) -> ExitCode {
    let Ok(src) = read(file) else {
        return ExitCode::FAILURE;
    };
    let Ok((out, _lock)) = out_dir(out) else {
        return ExitCode::FAILURE;
    };
    let out = out.as_path();
    let mut rows = Vec::new();
    for v in values {
        let program = match sdfl_stdlib::load_with(&src, &[(name.to_string(), *v)]) {
            Ok(p) => p,
            Err(d) => {
                say_raw(&sdfl_lang::render(&src, &d, term::color()));
                return ExitCode::FAILURE;
            }
        };
        // Each setting runs from scratch: its folder (made by sdfl) is
        // emptied first, so no checkpoint of an earlier sweep is resumed.
        let dir = out.join(format!("{name}={v}"));
        if dir.exists() {
            if let Err(e) = std::fs::remove_dir_all(&dir) {
                say!("error[sdfl::io]: cannot clear {}: {e}", dir.display());
                return ExitCode::FAILURE;
            }
        }
        say!("{name}={v}");
        let every = progress::interval(std::env::var_os("SDFL_PROGRESS_SECS").as_deref());
        let progress = Progress::new(false, every);
        let t = Instant::now();
        match execute(
            &program,
            &dir,
            RunOptions {
                size,
                no_cull: false,
                restart: true,
            },
            &base_dir(Some(file)),
            &progress,
        ) {
            Ok(reports) => {
                progress.finish();
                rows.push((*v, t.elapsed().as_secs_f64(), dir, reports));
            }
            Err((job, e)) => {
                progress.finish();
                return failed(&src, &job, &e);
            }
        }
    }
    let (_, _, ref_dir, ref_reports) = rows.last().expect("at least two settings");
    let ref_images = images_of(ref_reports);
    let ref_params = params_of(ref_reports);
    let mut table = format!("| {name} | seconds | PSNR vs {name}={} (dB) | max parameter error | held-out PSNR (dB) | mesh Chamfer |\n|---:|---:|---:|---:|---:|---:|\n", values[values.len() - 1]);
    let mut csv = format!("{name},seconds,psnr_db,param_error,held_out_psnr_db,mesh_chamfer\n");
    let held_out_any = rows.iter().any(|r| held_out_psnr(&r.3).is_some());
    // What the plots show: held-out PSNR where training held views out,
    // else PSNR against the reference's images, else parameter error; the
    // last two leave the reference row out (it is what they compare with).
    let mut quality: Vec<Quality> = Vec::new();
    for (row, (v, secs, dir, reports)) in rows.iter().enumerate() {
        let is_ref = row + 1 == rows.len();
        // PSNR of the mean squared error over all images of the run.
        let errors: Vec<f64> = ref_images
            .iter()
            .filter_map(|rel| mse(&dir.join(rel), &ref_dir.join(rel)))
            .collect();
        let mean_psnr =
            (!errors.is_empty()).then(|| psnr(errors.iter().sum::<f64>() / errors.len() as f64));
        let params = params_of(reports);
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
        let held = held_out_psnr(reports);
        let chamfer = mesh_chamfer(reports);
        table.push_str(&format!(
            "| {v} | {secs:.3} | {} | {} | {} | {} |\n",
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
            "{v},{secs},{},{},{},{}\n",
            mean_psnr.map_or(String::new(), |x| x.to_string()),
            perr.map_or(String::new(), |x| x.to_string()),
            held.map_or(String::new(), |x| x.to_string()),
            chamfer.map_or(String::new(), |x| x.to_string())
        ));
        if !is_ref || held_out_any {
            quality.push(Quality {
                value: *v,
                secs: *secs,
                held,
                psnr: mean_psnr,
                perr,
            });
        }
    }
    Stdout::new().print(&table);
    let write = |rel: &str, bytes: &[u8]| -> std::io::Result<()> {
        let mut f = sdfl_runtime::output::Atomic::create(&out.join(rel))?;
        std::io::Write::write_all(f.writer(), bytes)?;
        f.commit()
    };
    let reference = format!("{name}={}", values[values.len() - 1]);
    let images_any = quality.iter().any(|q| q.psnr.is_some());
    let (y_title, pick): (String, fn(&Quality) -> Option<f64>) = if held_out_any {
        ("held-out PSNR (dB)".into(), |q| q.held)
    } else if images_any {
        (format!("PSNR vs {reference} (dB)"), |q| q.psnr)
    } else {
        (format!("max parameter error vs {reference}"), |q| q.perr)
    };
    let quality_name = y_title.split(" (").next().unwrap_or("quality").to_string();
    let plot = |x_title: &str,
                against: &str,
                x: &dyn Fn(f64, f64) -> f64,
                label: &dyn Fn(f64, f64) -> String| {
        let series = Series::labelled(
            "",
            quality
                .iter()
                .filter_map(|q| pick(q).map(|y| (x(q.value, q.secs), y, label(q.value, q.secs)))),
        );
        let chart = Chart {
            title: format!("Sweep of `{name}`: {quality_name} against {against}"),
            x: Axis::new(x_title),
            y: Axis::new(y_title.clone()),
            series: vec![series],
        };
        sdfl_runtime::plot::render(&chart, 640, 400).and_then(|p| p.png())
    };
    // Quality against time, each point labelled with its setting; and
    // against the swept value (time may hardly change), labelled with time.
    let png = plot("time per run (s)", "time", &|_, secs| secs, &|v, _| {
        format!("{name}={v}")
    });
    let value_png = plot(
        &format!("{name} (the value of `let {name}`)"),
        name,
        &|v, _| v,
        &|_, secs| format!("{secs:.1} s"),
    );
    let result = write("sweep.csv", csv.as_bytes())
        .and_then(|_| write("sweep.md", table.as_bytes()))
        .and_then(|_| write("sweep.png", &png?))
        .and_then(|_| write("sweep_value.png", &value_png?));
    match result {
        Ok(()) => {
            say!(
                "wrote {0}/sweep.csv, {0}/sweep.md, {0}/sweep.png (against seconds) and {0}/sweep_value.png (against the value)",
                out.display()
            );
            ExitCode::SUCCESS
        }
        Err(e) => {
            sdfl_runtime::interrupt::wait_if_exiting();
            say!(
                "error[sdfl::io]: writing the sweep results under {}: {e}",
                out.display()
            );
            ExitCode::FAILURE
        }
    }
}
