//! The NDC warp: the reference projective map, depths along NDC rays,
//! hard cases.

use glam::DVec3;
use sdfl_runtime::data::normalize::{ndc_point, ndc_ray};
use sdfl_runtime::neural::warp::*;
use sdfl_stdlib::value::{NdcFrame, Unbounded};

fn frame() -> NdcFrame {
    NdcFrame {
        width: 80.0,
        height: 60.0,
        fx: 70.0,
        fy: 72.0,
        near: 1.0,
    }
}

#[test]
fn the_warp_is_the_reference_projective_map() {
    // f64 reference: normalize::ndc_point (fx for both axes there).
    let f = NdcFrame {
        fy: 70.0,
        ..frame()
    };
    let n = Ndc::new(&f).unwrap();
    for p in [
        [0.3, -0.2, -1.0],
        [2.0, 1.5, -7.0],
        [-40.0, 12.0, -300.0],
        [0.0, 0.0, -1e5],
    ] {
        let got = n.apply(p.map(|v| v as f32));
        let want = ndc_point(80.0, 60.0, 70.0, 1.0, DVec3::from_array(p));
        for a in 0..3 {
            assert!(
                (got[a] as f64 - want[a]).abs() <= 1e-5 * (1.0 + want[a].abs()),
                "{p:?}: {got:?} vs {want}"
            );
        }
    }
    // The near plane and infinity are NDC's z = −1 and 1.
    assert!((n.apply([0.1, 0.1, -1.0])[2] + 1.0).abs() < 1e-6);
    assert!((n.apply([0.0, 0.0, -1e9])[2] - 1.0).abs() < 1e-6);
}

#[test]
fn depths_are_even_in_ndc_depth_along_the_ndc_ray() {
    let f = NdcFrame {
        fy: 70.0,
        ..frame()
    };
    let n = Ndc::new(&f).unwrap();
    // A camera a little off the reference one, looking mostly ahead.
    let o = DVec3::new(0.2, -0.1, 0.3);
    let d = DVec3::new(0.15, 0.05, -1.0).normalize();
    let t: Vec<f32> = (0..9).map(|k| k as f32 * 0.125e6).collect();
    let mut out = Vec::new();
    n.depths(
        o.as_vec3().to_array(),
        d.as_vec3().to_array(),
        0.0,
        1e6,
        &t,
        &mut out,
    );
    // Sorted, starting at the near plane.
    assert!(out.windows(2).all(|w| w[0] < w[1]));
    let p0 = o + d * out[0] as f64;
    assert!((p0.z + 1.0).abs() < 1e-4, "{p0}");
    // Each sample lies on NeRF's NDC ray (the f64 reference), at NDC
    // depths evenly spaced (z' = −1 + 2s for the ray parameter s).
    let (ro, rd) = ndc_ray(80.0, 60.0, 70.0, 1.0, o, d).unwrap();
    for (k, &tk) in out.iter().enumerate().take(8) {
        let q = ndc_point(80.0, 60.0, 70.0, 1.0, o + d * tk as f64);
        let s = (q.z - ro.z) / rd.z;
        let on_ray = ro + rd * s;
        assert!((on_ray - q).length() < 1e-3, "{k}: {q} vs {on_ray}");
        assert!(
            (q.z - (-1.0 + 2.0 * k as f64 * 0.125)).abs() < 1e-3,
            "{k}: {q}"
        );
    }
}

#[test]
fn hard_cases_stay_finite() {
    let n = Ndc::new(&frame()).unwrap();
    // Behind the camera's plane, on it, far, huge.
    for p in [
        [1.0, 1.0, 0.0],
        [1.0, -1.0, 5.0],
        [0.0, 0.0, -1e30],
        [1e30, -1e30, -1.0],
        [0.0, 0.0, -0.0],
    ] {
        let y = n.apply(p);
        assert!(y.iter().all(|v| v.is_finite()), "{p:?} -> {y:?}");
        assert!(n.world_per_unit(y).is_finite());
    }
    // Rays sideways or backwards: no length; a far below the near
    // plane, or a camera beyond it: still sorted, never negative.
    let t = [0.0f32, 0.5, 1.0];
    for (o, d, far) in [
        ([0.0, 0.0, 0.0], [1.0, 0.0, 0.0], 100.0),
        ([0.0, 0.0, 0.0], [0.0, 0.0, 1.0], 100.0),
        ([0.0, 0.0, 0.0], [0.0, 0.0, -1.0], 0.5),
        ([0.0, 0.0, -5.0], [0.0, 0.0, -1.0], 100.0),
    ] {
        let mut out = Vec::new();
        n.depths(o, d, 0.0, far, &t, &mut out);
        assert_eq!(out.len(), 3);
        assert!(out.iter().all(|v| v.is_finite() && *v >= 0.0), "{out:?}");
        assert!(out.windows(2).all(|w| w[0] <= w[1]), "{out:?}");
    }
    for bad in [
        NdcFrame { fx: 0.0, ..frame() },
        NdcFrame {
            near: -1.0,
            ..frame()
        },
        NdcFrame {
            width: f64::NAN,
            ..frame()
        },
    ] {
        assert!(Ndc::new(&bad).is_err());
    }
    assert!(Warp::new(&Unbounded::Ndc(None)).is_err());
}
