//! Charts drawn and read back: colours, legends, log axes, point labels,
//! hard data that must never panic, tick labels.

use plotters::prelude::*;
use sdfl_runtime::plot::*;

fn chart(series: Vec<Series>) -> Chart {
    Chart {
        title: "Training loss".into(),
        x: Axis::new("step"),
        y: Axis::new("loss (MSE)"),
        series,
    }
}

fn pixel(p: &Plot, x: i32, y: i32) -> [u8; 3] {
    let k = (y as usize * p.width as usize + x as usize) * 3;
    [p.rgb[k], p.rgb[k + 1], p.rgb[k + 2]]
}

/// Pixels of exactly `c` inside the plotting area.
fn count_in_area(p: &Plot, c: [u8; 3]) -> usize {
    let [l, t, r, b] = p.area;
    (t..b)
        .flat_map(|y| (l..r).map(move |x| (x, y)))
        .filter(|&(x, y)| pixel(p, x, y) == c)
        .count()
}

/// Pixels that are neither white nor grid grey inside the plotting area.
fn ink_in_area(p: &Plot) -> usize {
    let [l, t, r, b] = p.area;
    (t..b)
        .flat_map(|y| (l..r).map(move |x| (x, y)))
        .filter(|&(x, y)| {
            let c = pixel(p, x, y);
            c.iter().any(|&v| v < 200)
        })
        .count()
}

fn decay(n: usize, rate: f64) -> Vec<(f64, f64)> {
    (1..=n)
        .map(|k| (k as f64, (-rate * k as f64).exp()))
        .collect()
}

#[test]
fn the_embedded_font_parses() {
    assert!(plotters::style::register_font("sdfl-test", FontStyle::Normal, FONT).is_ok());
}

#[test]
fn a_loss_curve_is_drawn_in_its_colour() {
    let p = render(
        &chart(vec![Series::new("loss", decay(500, 0.01))]),
        640,
        400,
    )
    .unwrap();
    assert_eq!((p.width, p.height, p.rgb.len()), (640, 400, 640 * 400 * 3));
    let [l, t, r, b] = p.area;
    assert!(
        l > 40 && t > 20 && r < 640 && b < 400 && r - l > 400 && b - t > 250,
        "{:?}",
        p.area
    );
    assert!(count_in_area(&p, PALETTE[0]) > 300, "the line is drawn");
    assert!(p.notes.is_empty(), "{:?}", p.notes);
    // Axis titles and tick labels are drawn outside the plotting area.
    let outside = (0..p.height as i32)
        .flat_map(|y| (0..l).map(move |x| (x, y)))
        .filter(|&(x, y)| pixel(&p, x, y)[0] < 128)
        .count();
    assert!(outside > 100, "y tick labels and title: {outside}");
    let png = p.png().unwrap();
    assert_eq!(&png[1..4], b"PNG");
    let back = image::load_from_memory(&png).unwrap().to_rgb8();
    assert_eq!(back.dimensions(), (640, 400));
    assert_eq!(back.as_raw(), &p.rgb);
}

#[test]
fn series_get_distinct_colours_and_a_legend() {
    let a = Series::new("train", decay(200, 0.02));
    let b = Series::new("held out", decay(200, 0.01));
    let c = Series::new("", vec![(50.0, 0.5), (150.0, 0.3)]);
    let p = render(&chart(vec![a, b, c]), 640, 400).unwrap();
    for (k, &colour) in PALETTE.iter().take(3).enumerate() {
        assert!(count_in_area(&p, colour) > 10, "series {k}");
    }
    // One series: no legend; two named series: a legend box, whose
    // swatches add colour to a corner of the plot.
    let one = render(
        &chart(vec![Series::new("loss", decay(200, 0.01))]),
        640,
        400,
    )
    .unwrap();
    assert!(count_in_area(&one, PALETTE[1]) == 0);
}

#[test]
fn log_axes_where_data_span_decades() {
    let wide: Vec<(f64, f64)> = (0..=80)
        .map(|k| (k as f64, 10f64.powf(-k as f64 / 10.0)))
        .collect();
    let p = render(&chart(vec![Series::new("loss", wide.clone())]), 640, 400).unwrap();
    assert!(
        p.log_y && !p.log_x,
        "1e-8..1 gets a log y axis, steps stay linear"
    );
    // On a log axis an exponential decay is a straight line: the
    // curve's pixel at the middle step lies halfway up.
    assert!(count_in_area(&p, PALETTE[0]) > 300);
    let narrow = render(
        &chart(vec![Series::new("loss", decay(100, 0.01))]),
        640,
        400,
    )
    .unwrap();
    assert!(!narrow.log_y, "1..0.37 stays linear");
    let forced = chart(vec![Series::new("loss", decay(100, 0.01))]);
    let forced = Chart {
        y: Axis::new("loss").scale(Scale::Log),
        ..forced
    };
    assert!(render(&forced, 640, 400).unwrap().log_y);
    // Zero among the values keeps Auto linear; a forced log axis skips
    // it and says so.
    let with_zero = vec![(0.0, 0.0), (1.0, 1e-6), (2.0, 1.0)];
    let p = render(&chart(vec![Series::new("e", with_zero.clone())]), 640, 400).unwrap();
    assert!(!p.log_y);
    let c = Chart {
        y: Axis::new("error").scale(Scale::Log),
        ..chart(vec![Series::new("e", with_zero)])
    };
    let p = render(&c, 640, 400).unwrap();
    assert!(
        p.log_y && p.notes.iter().any(|n| n.contains("≤ 0 on a log axis")),
        "{:?}",
        p.notes
    );
    assert!(count_in_area(&p, PALETTE[0]) > 20);
    // Both axes log.
    let c = Chart {
        x: Axis::new("seconds"),
        ..chart(vec![Series::new(
            "",
            vec![(0.01, 1e-8), (1.0, 1e-4), (100.0, 1.0)],
        )])
    };
    let p = render(&c, 640, 400).unwrap();
    assert!(p.log_x && p.log_y);
}

/// A β sweep's held-out PSNR against seconds, each point labelled.
fn beta_sweep(name: &str) -> Series {
    Series::labelled(
        name,
        [
            (100.1, 25.07, "beta=0.02"),
            (91.0, 36.41, "beta=0.05"),
            (79.2, 35.76, "beta=0.1"),
            (78.5, 35.21, "beta=0.2"),
        ]
        .map(|(x, y, l)| (x, y, l.to_string())),
    )
}

#[test]
fn points_are_labelled_with_their_settings() {
    let s = beta_sweep("held-out PSNR");
    let c = Chart {
        title: "sweep".into(),
        x: Axis::new("time per run (s)"),
        y: Axis::new("held-out PSNR (dB)"),
        series: vec![s.clone()],
    };
    let p = render(&c, 640, 400).unwrap();
    assert!(
        p.notes.is_empty(),
        "every label found a place: {:?}",
        p.notes
    );
    // The labels are dark text in the plotting area, beyond the line
    // and markers.
    let unlabelled = Series::new("held-out PSNR", s.points.iter().map(|p| (p.x, p.y)));
    let q = render(
        &Chart {
            series: vec![unlabelled],
            ..c.clone()
        },
        640,
        400,
    )
    .unwrap();
    assert!(
        ink_in_area(&p) > ink_in_area(&q) + 100,
        "{} vs {}",
        ink_in_area(&p),
        ink_in_area(&q)
    );
    // Very long labels are cut, never drawn outside the plot; with no
    // room a label is left out and noted.
    let long = "x".repeat(10_000);
    let s = Series::labelled(
        "",
        (0..30).map(|k| (k as f64, (k % 3) as f64, long.clone())),
    );
    let p = render(
        &Chart {
            series: vec![s],
            ..c.clone()
        },
        640,
        400,
    )
    .unwrap();
    assert!(
        p.notes.iter().any(|n| n.contains("left out")),
        "{:?}",
        p.notes
    );
    let long_title = Chart {
        title: "t".repeat(5000),
        x: Axis::new("x ".repeat(3000)),
        y: Axis::new("y ".repeat(3000)),
        series: vec![
            Series::new(long.clone(), vec![(1.0, 2.0), (2.0, 3.0)]),
            Series::new(long, vec![(1.0, 3.0)]),
        ],
    };
    assert!(render(&long_title, 640, 400).is_ok());
}

#[test]
fn hard_cases_never_panic_and_say_what_was_left_out() {
    let nan = f64::NAN;
    let inf = f64::INFINITY;
    // A single point: drawn as a marker, in a range around it.
    let p = render(&chart(vec![Series::new("one", vec![(5.0, 5.0)])]), 400, 300).unwrap();
    assert!(count_in_area(&p, PALETTE[0]) > 10);
    // All-equal values.
    let flat: Vec<(f64, f64)> = (0..100).map(|k| (k as f64, 3.0)).collect();
    let p = render(&chart(vec![Series::new("flat", flat)]), 400, 300).unwrap();
    assert!(count_in_area(&p, PALETTE[0]) > 100 && !p.log_y);
    // The same x everywhere; zeros everywhere.
    for pts in [
        vec![(1.0, 0.0), (1.0, 1.0), (1.0, 2.0)],
        vec![(0.0, 0.0); 3],
    ] {
        let p = render(&chart(vec![Series::new("s", pts)]), 400, 300).unwrap();
        assert!(count_in_area(&p, PALETTE[0]) > 10);
    }
    // NaN and ±∞ are skipped and counted; the rest is drawn.
    let broken = vec![
        (0.0, 1.0),
        (1.0, nan),
        (2.0, 2.0),
        (inf, 3.0),
        (4.0, -inf),
        (5.0, 1.5),
    ];
    let p = render(&chart(vec![Series::new("b", broken)]), 400, 300).unwrap();
    assert_eq!(p.notes, ["3 points not finite (NaN or ±∞): not drawn"]);
    assert!(count_in_area(&p, PALETTE[0]) > 10);
    // Nothing but NaN, no points, no series: a placeholder saying so.
    for series in [
        vec![Series::new("nan", vec![(nan, nan), (nan, 1.0)])],
        vec![Series::new("", vec![])],
        vec![],
    ] {
        let p = render(&chart(series), 400, 300).unwrap();
        assert!(
            p.notes.iter().any(|n| n == "no data to plot"),
            "{:?}",
            p.notes
        );
        assert!(ink_in_area(&p) > 50, "the placeholder text is drawn");
    }
    // Extreme magnitudes: skipped beyond 1e±200, never a hang.
    let extreme = vec![
        (-f64::MAX, f64::MAX),
        (0.0, 5e-324),
        (1.0, 1e-300),
        (2.0, 1e50),
        (3.0, -1e50),
    ];
    let p = render(&chart(vec![Series::new("x", extreme)]), 400, 300).unwrap();
    assert!(
        p.notes.iter().any(|n| n.starts_with("3 points beyond")),
        "{:?}",
        p.notes
    );
    for pts in [
        vec![(0.0, 1e8), (1.0, 1e8 + 1e-7)],
        vec![(0.0, 1e-100), (1.0, 1e100)],
        vec![(1e-100, 1.0), (1e-99, 2.0)],
        vec![(0.0, -1e-100), (1.0, 1e-100)],
    ] {
        let p = render(&chart(vec![Series::new("x", pts)]), 400, 300).unwrap();
        assert!(count_in_area(&p, PALETTE[0]) > 5);
    }
    // Many series cycle the palette.
    let many: Vec<Series> = (0..13)
        .map(|k| Series::new(format!("s{k}"), decay(20, 0.1 * k as f64)))
        .collect();
    assert!(render(&chart(many), 640, 400).is_ok());
    // Sizes outside the bounds are errors, not panics.
    for (w, h) in [(0, 0), (10, 10), (199, 300), (400, 149), (9000, 400)] {
        let e = render(&chart(vec![]), w, h).unwrap_err();
        assert_eq!(
            e,
            PlotError::Size {
                width: w,
                height: h
            }
        );
    }
    let big = render(
        &chart(vec![Series::new("loss", decay(50, 0.1))]),
        2000,
        1200,
    )
    .unwrap();
    assert!(count_in_area(&big, PALETTE[0]) > 1000);
}

/// A sweep's Chamfer distance against seconds (a diverged setting's
/// infinite), on an axis from zero.
fn chamfer_sweep() -> Chart {
    Chart {
        title: "Sweep of `steps`: mesh Chamfer to the true surface against time".into(),
        x: Axis::new("time per run (s)"),
        y: Axis::new("Chamfer distance (scene units)").scale(Scale::AutoFromZero),
        series: vec![Series::labelled(
            "mesh Chamfer",
            [
                (100.1, 0.041, "steps=200"),
                (150.0, f64::INFINITY, "steps=300"),
                (191.0, 0.017, "steps=400"),
                (379.2, 0.009, "steps=800"),
            ]
            .map(|(x, y, l)| (x, y, l.to_string())),
        )],
    }
}

#[test]
fn stacked_charts_are_one_panel_each_one_above_another() {
    let psnr = Chart {
        title: "Sweep of `beta`: held-out PSNR against time".into(),
        x: Axis::new("time per run (s)"),
        y: Axis::new("held-out PSNR (dB)"),
        series: vec![beta_sweep("held-out PSNR")],
    };
    let f = render_stacked(&[psnr.clone(), chamfer_sweep()], 640, 400).unwrap();
    assert_eq!((f.width, f.height, f.rgb.len()), (640, 800, 640 * 800 * 3));
    assert_eq!(f.panels.len(), 2);
    let (top, bottom) = (&f.panels[0], &f.panels[1]);
    // Each panel's plotting area lies in its own half, in figure pixels.
    assert!(top.area[1] > 0 && top.area[3] < 400, "{:?}", top.area);
    assert!(
        bottom.area[1] > 400 && bottom.area[3] < 800,
        "{:?}",
        bottom.area
    );
    // Both span less than two decades: linear (Chamfer's from zero).
    assert!(!top.log_y && !bottom.log_y);
    assert!(top.notes.is_empty(), "{:?}", top.notes);
    // The diverged setting is skipped, said so, and the rest is drawn.
    assert_eq!(
        bottom.notes,
        ["1 point not finite (NaN or ±∞): not drawn"],
        "{:?}",
        bottom.notes
    );
    let as_plot = |p: &Panel| Plot {
        width: f.width,
        height: f.height,
        rgb: f.rgb.clone(),
        log_x: p.log_x,
        log_y: p.log_y,
        area: p.area,
        notes: p.notes.clone(),
    };
    for p in &f.panels {
        assert!(count_in_area(&as_plot(p), PALETTE[0]) > 100, "{:?}", p.area);
    }
    // Each panel is the chart drawn alone, pixel for pixel; one chart
    // stacked is `render`'s image.
    let alone = render(&psnr, 640, 400).unwrap();
    assert_eq!(&f.rgb[..alone.rgb.len()], &alone.rgb[..]);
    let below = render(&chamfer_sweep(), 640, 400).unwrap();
    assert_eq!(&f.rgb[alone.rgb.len()..], &below.rgb[..]);
    // Chamfer spanning two decades (a setting that failed): log.
    let mut failed = chamfer_sweep();
    failed.series[0].points[1].y = 2.5;
    let f = render_stacked(&[psnr.clone(), failed], 640, 400).unwrap();
    assert!(!f.panels[0].log_y && f.panels[1].log_y);
    let one = render_stacked(std::slice::from_ref(&psnr), 640, 400).unwrap();
    assert_eq!((one.height, one.rgb), (400, alone.rgb));
    // No charts: a placeholder; too tall or too small: an error, no panic.
    let none = render_stacked(&[], 640, 400).unwrap();
    assert_eq!(none.panels.len(), 1);
    assert_eq!(none.panels[0].notes, ["no data to plot"]);
    let many = vec![psnr.clone(); 30];
    assert!(matches!(
        render_stacked(&many, 640, 400),
        Err(PlotError::Size { .. })
    ));
    assert!(render_stacked(std::slice::from_ref(&psnr), 640, 100).is_err());
    assert!(render_stacked(&[psnr], 640, u32::MAX).is_err());
}

#[test]
fn tick_labels_are_short_and_distinct() {
    assert_eq!(fmt_value(0.05, 1), "0.05");
    assert_eq!(fmt_value(36.5, 3), "36.5");
    assert_eq!(fmt_value(0.30000000000000004, 2), "0.3");
    assert_eq!(fmt_value(1e-8, 2), "1e-8");
    assert_eq!(fmt_value(2.5e7, 3), "2.5e7");
    assert_eq!(fmt_value(-0.0, 3), "0");
    assert_eq!(
        fmt_value(120.0, 1),
        "120",
        "whole numbers are never rounded"
    );
    assert_eq!(tick_digits(&[0.1, 0.2, 0.3]), 1);
    assert_eq!(tick_digits(&[1.0e8, 1.000001e8]), 7);
    assert_eq!(shorten("abcdef", 4), "abc…");
    assert_eq!(shorten("abc", 4), "abc");
    let r = range([3.0, 3.0].into_iter(), false, false);
    assert!(r.start < 3.0 && r.end > 3.0);
    let r = range([2.0, 5.0].into_iter(), true, false);
    assert!(r.start <= 1.0 && r.end > 5.0, "a decade inside: {r:?}");
    assert_eq!(range(std::iter::empty(), false, false), 0.0..1.0);
    // From zero: zero is the near end, the far end padded.
    let r = range([0.009, 0.041].into_iter(), false, true);
    assert!(r.start == 0.0 && r.end > 0.041 && r.end < 0.045, "{r:?}");
    let r = range([-2.0, -1.0].into_iter(), false, true);
    assert!(r.start < -2.0 && r.end == 0.0, "{r:?}");
    let r = range([0.0, 0.0].into_iter(), false, true);
    assert!(r.start < 0.0 && r.end > 0.0, "{r:?}");
}

/// Writes example plots for a look: `SDFL_WRITE_FIGURES=1 cargo test
/// --release -p sdfl-runtime plot::`; they land in `$TMPDIR/sdfl-figures`.
#[test]
fn write_plots_for_inspection() {
    if std::env::var_os("SDFL_WRITE_FIGURES").is_none() {
        return;
    }
    let dir = std::env::temp_dir().join("sdfl-figures");
    std::fs::create_dir_all(&dir).unwrap();
    let loss: Vec<(f64, f64)> = (1..=2000)
        .map(|k| {
            let k = k as f64;
            (
                k,
                0.08 * (-k / 300.0).exp() + 2e-4 + 1e-4 * (k * 0.7).sin().abs(),
            )
        })
        .collect();
    let p = render(&chart(vec![Series::new("loss", loss)]), 512, 320).unwrap();
    std::fs::write(dir.join("plot_loss.png"), p.png().unwrap()).unwrap();
    let sweep = beta_sweep("");
    let c = Chart {
        title: "Sweep of beta: held-out PSNR against time".into(),
        x: Axis::new("time per run (s)"),
        y: Axis::new("held-out PSNR (dB)"),
        series: vec![sweep],
    };
    let p = render(&c, 640, 400).unwrap();
    std::fs::write(dir.join("plot_sweep.png"), p.png().unwrap()).unwrap();
    let two = chart(vec![
        Series::new(
            "train",
            (0..=80).map(|k| (k as f64, 10f64.powf(-k as f64 / 10.0))),
        ),
        Series::new(
            "held out",
            (0..=80).map(|k| (k as f64, 3.0 * 10f64.powf(-k as f64 / 12.0))),
        ),
        Series::new(
            "broken",
            vec![(10.0, 0.1), (20.0, f64::NAN), (30.0, 1e-3), (40.0, 1e-4)],
        ),
    ]);
    let p = render(&two, 640, 400).unwrap();
    std::fs::write(dir.join("plot_log.png"), p.png().unwrap()).unwrap();
    let p = render(&chart(vec![]), 512, 320).unwrap();
    std::fs::write(dir.join("plot_empty.png"), p.png().unwrap()).unwrap();
    let psnr = Chart {
        title: "Sweep of `beta`: held-out PSNR against time".into(),
        x: Axis::new("time per run (s)"),
        y: Axis::new("held-out PSNR (dB)"),
        series: vec![beta_sweep("held-out PSNR")],
    };
    let f = render_stacked(&[psnr, chamfer_sweep()], 640, 400).unwrap();
    std::fs::write(dir.join("plot_stacked.png"), f.png().unwrap()).unwrap();
    eprintln!("plots in {}", dir.display());
}
