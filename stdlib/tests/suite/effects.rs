use glam::DVec3;
use sdfl_stdlib::effects::*;

#[test]
fn fog_follows_the_exponential() {
    let fog = Fog {
        color: DVec3::new(0.5, 0.6, 0.7),
        density: 0.3,
    };
    let c = DVec3::new(1.0, 0.0, 0.2);
    assert_eq!(fog.apply(c, 0.0), c);
    let t = 2.5;
    let want = fog.color + (c - fog.color) * (-0.75f64).exp();
    assert!((fog.apply(c, t) - want).length() < 1e-15);
    // Huge distances reach the fog's colour, never NaN.
    assert_eq!(fog.apply(c, 1e300), fog.color);
    assert_eq!(fog.apply(c, f64::INFINITY), fog.color);
}

#[test]
fn occlusion_is_one_in_the_open_and_falls_in_a_crevice() {
    let ao = AmbientOcclusion {
        samples: 5,
        distance: 0.5,
    };
    // An open plane: the distance along the normal is the height.
    assert_eq!(occlusion(&ao, |h| h), 1.0);
    // Further than the height (a convex surface) is open too.
    assert_eq!(occlusion(&ao, |h| 2.0 * h), 1.0);
    // Filled: every sample inside something.
    assert_eq!(occlusion(&ao, |_| -1.0), 0.0);
    // A wall 0.2 away along the surface: the samples above 0.2 are
    // occluded by (h - 0.2)/h, weighted.
    let got = occlusion(&ao, |h: f64| h.min(0.2));
    let (mut o, mut w) = (0.0, 0.0);
    for i in 0..5 {
        let h = 0.5 * (i as f64 + 0.5) / 5.0;
        let wi = 1.0 - h / 0.5;
        o += wi * ((h - h.min(0.2)) / h);
        w += wi;
    }
    assert!((got - (1.0 - o / w)).abs() < 1e-15 && got < 1.0 && got > 0.5);
    // NaN distances are open space, not NaN.
    assert_eq!(occlusion(&ao, |_| f64::NAN), 1.0);
}

#[test]
fn subpixel_offsets_are_stratified_rooks() {
    assert_eq!(subpixel_offsets(1), vec![(0.0, 0.0)]);
    for m in 2..=16u32 {
        let n = m * m;
        let v = subpixel_offsets(n);
        assert_eq!(v.len(), n as usize);
        let fine = |x: f64| ((x + 0.5) * n as f64).floor() as u32;
        let coarse = |x: f64| ((x + 0.5) * m as f64).floor() as u32;
        let mut cols: Vec<u32> = v.iter().map(|p| fine(p.0)).collect();
        let mut rows: Vec<u32> = v.iter().map(|p| fine(p.1)).collect();
        cols.sort();
        rows.sort();
        assert_eq!(cols, (0..n).collect::<Vec<_>>(), "n-rooks in x");
        assert_eq!(rows, (0..n).collect::<Vec<_>>(), "n-rooks in y");
        let mut strata: Vec<u32> = v.iter().map(|p| coarse(p.0) * m + coarse(p.1)).collect();
        strata.sort();
        assert_eq!(strata, (0..n).collect::<Vec<_>>(), "one per stratum");
        let mean = v.iter().fold((0.0, 0.0), |a, p| (a.0 + p.0, a.1 + p.1));
        assert!(mean.0.abs() < 1e-12 && mean.1.abs() < 1e-12, "centred");
    }
}
