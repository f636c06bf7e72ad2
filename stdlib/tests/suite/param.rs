use sdfl_stdlib::param::*;

#[test]
fn projection_keeps_nan() {
    for b in [Bound::Free, Bound::AtLeast(1e-4), Bound::Within(0.0, 1.0)] {
        assert!(b.project(f64::NAN).is_nan(), "{b:?}");
    }
    assert_eq!(Bound::AtLeast(1e-4).project(-5.0), 1e-4);
    assert_eq!(Bound::Within(0.0, 1.0).project(f64::INFINITY), 1.0);
    assert_eq!(Bound::Within(0.0, 1.0).project(0.25), 0.25);
}
