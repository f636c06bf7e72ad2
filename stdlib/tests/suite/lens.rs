use sdfl_stdlib::lens::*;

fn lenses() -> Vec<Intrinsics> {
    let base = Intrinsics {
        width: 160,
        height: 120,
        fx: 140.0,
        fy: 138.0,
        cx: 83.2,
        cy: 57.9,
        distortion: Distortion::None,
    };
    vec![
        base,
        Intrinsics {
            distortion: Distortion::OpenCv {
                k1: -0.12,
                k2: 0.03,
                p1: 0.001,
                p2: -0.0015,
            },
            ..base
        },
        Intrinsics {
            distortion: Distortion::OpenCv {
                k1: 0.2,
                k2: 0.05,
                p1: -0.002,
                p2: 0.001,
            },
            ..base
        },
        Intrinsics {
            fx: 90.0,
            fy: 90.0,
            distortion: Distortion::Fisheye {
                k1: 0.05,
                k2: -0.01,
                k3: 0.002,
                k4: -0.0003,
            },
            ..base
        },
    ]
}

/// Every pixel of the image maps to a ray that the forward model sends
/// back to the same pixel within 1e-4 px (the bound; the
/// Newton solve gets far closer).
#[test]
fn undistortion_inverts_the_forward_model_over_the_image() {
    for lens in lenses() {
        lens.check().unwrap();
        let mut worst: f64 = 0.0;
        for j in 0..lens.height {
            for i in 0..lens.width {
                let (u, v) = (i as f64 + 0.5, j as f64 + 0.5);
                let (x, y) = lens.unproject(u, v).expect("inside the image");
                let (u2, v2) = lens.project([x * 2.5, y * 2.5, 2.5]).unwrap();
                worst = worst.max((u2 - u).abs().max((v2 - v).abs()));
            }
        }
        assert!(worst < 1e-4, "{lens:?}: {worst:e} px");
        assert!(worst < 1e-9, "{lens:?}: {worst:e} px");
    }
}

/// The forward models against their formulas written out in f64 once
/// more, at points chosen by hand.
#[test]
fn forward_models_match_their_formulas() {
    let d = Distortion::OpenCv {
        k1: 0.1,
        k2: -0.02,
        p1: 0.003,
        p2: 0.004,
    };
    let (x, y) = (0.3, -0.2);
    let r2 = 0.13;
    let radial = 1.0 + 0.1 * r2 - 0.02 * r2 * r2;
    let want = (
        x * radial + 2.0 * 0.003 * x * y + 0.004 * (r2 + 2.0 * x * x),
        y * radial + 0.003 * (r2 + 2.0 * y * y) + 2.0 * 0.004 * x * y,
    );
    let got = d.distort(x, y);
    assert!((got.0 - want.0).abs() < 1e-15 && (got.1 - want.1).abs() < 1e-15);
    let f = Distortion::Fisheye {
        k1: 0.1,
        k2: 0.0,
        k3: 0.0,
        k4: 0.0,
    };
    let r = (x * x + y * y).sqrt();
    let t = r.atan();
    let rd = t * (1.0 + 0.1 * t * t);
    let got = f.distort(x, y);
    assert!((got.0 - x * rd / r).abs() < 1e-15 && (got.1 - y * rd / r).abs() < 1e-15);
    // The fisheye with no coefficients is the equidistant projection:
    // radius = angle, not the pinhole's tan(angle).
    let equi = Distortion::Fisheye {
        k1: 0.0,
        k2: 0.0,
        k3: 0.0,
        k4: 0.0,
    };
    let (xd, _) = equi.distort(1.0, 0.0);
    assert!((xd - std::f64::consts::FRAC_PI_4).abs() < 1e-15);
}

/// Hard cases: the centre, points far out, non-finite input, and lenses
/// that fold over inside the image are refused rather than inverted
/// wrongly.
#[test]
fn hard_cases_stay_finite_or_are_refused() {
    for lens in lenses() {
        let (x, y) = lens.unproject(lens.cx, lens.cy).unwrap();
        assert!(x.abs() < 1e-15 && y.abs() < 1e-15);
        assert_eq!(lens.distortion.undistort(f64::NAN, 0.0), None);
        assert_eq!(lens.distortion.undistort(f64::INFINITY, 0.0), None);
    }
    let base = lenses()[0];
    // Strong barrel distortion: the radius stops growing inside the image.
    let folded = Intrinsics {
        distortion: Distortion::OpenCv {
            k1: -0.9,
            k2: 0.0,
            p1: 0.0,
            p2: 0.0,
        },
        fx: 60.0,
        fy: 60.0,
        ..base
    };
    assert!(folded.check().is_err());
    for bad in [
        Intrinsics { fx: -3.0, ..base },
        Intrinsics {
            fy: f64::NAN,
            ..base
        },
        Intrinsics { cx: 1e9, ..base },
        Intrinsics {
            distortion: Distortion::OpenCv {
                k1: f64::INFINITY,
                k2: 0.0,
                p1: 0.0,
                p2: 0.0,
            },
            ..base
        },
        // A fisheye wider than the depth-one plane allows.
        Intrinsics {
            fx: 20.0,
            fy: 20.0,
            distortion: Distortion::Fisheye {
                k1: 0.0,
                k2: 0.0,
                k3: 0.0,
                k4: 0.0,
            },
            ..base
        },
    ] {
        assert!(bad.check().is_err(), "{bad:?}");
    }
}

#[test]
fn scaling_keeps_the_rays_of_pixel_edges() {
    let lens = lenses()[1];
    let half = lens.scaled(80, 60);
    // The image's corner (0, 0) and the principal point are the same
    // rays at either size.
    let a = lens.unproject(0.0, 0.0).unwrap();
    let b = half.unproject(0.0, 0.0).unwrap();
    assert!((a.0 - b.0).abs() < 1e-12 && (a.1 - b.1).abs() < 1e-12);
}
