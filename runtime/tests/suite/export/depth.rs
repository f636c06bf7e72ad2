//! Depth exports: the `.npy` header, the colour map's ends, the bar and
//! the black holes.

use sdfl_runtime::export::depth::*;
use sdfl_runtime::output::colour;
use sdfl_stdlib::value::Colormap;

#[test]
fn npy_header_is_aligned_and_values_follow() {
    let v = [1.5f32, f32::NAN, -2.0, 0.25, 3.0, 4.0];
    let b = npy_bytes(&v, 2, 3);
    assert_eq!(&b[..8], b"\x93NUMPY\x01\x00");
    let hl = u16::from_le_bytes([b[8], b[9]]) as usize;
    assert_eq!((10 + hl) % 64, 0);
    let header = std::str::from_utf8(&b[10..10 + hl]).unwrap();
    assert!(
        header.contains("'shape': (2, 3)") && header.ends_with('\n'),
        "{header}"
    );
    let body: Vec<f32> = b[10 + hl..]
        .chunks(4)
        .map(|c| f32::from_le_bytes(c.try_into().unwrap()))
        .collect();
    assert_eq!(body.len(), 6);
    assert!(body[1].is_nan());
    assert_eq!(body[0], 1.5);
    assert_eq!(body[5], 4.0);
}

#[test]
fn colour_map_endpoints() {
    // Turbo runs from near black through blue, green and yellow to dark
    // red; viridis from dark purple to yellow.
    assert_eq!(colour(Colormap::Turbo, 0.0), [34, 23, 27]);
    let hi = colour(Colormap::Turbo, 1.0);
    assert!(hi[0] > 100 && hi[1] < 30 && hi[2] < 30, "{hi:?}");
    let mid = colour(Colormap::Turbo, 0.5);
    assert!(mid[1] > mid[0] && mid[1] > mid[2], "{mid:?}");
    assert_eq!(colour(Colormap::Viridis, 0.0), [68, 1, 84]);
    assert_eq!(colour(Colormap::Viridis, 1.0), [253, 231, 37]);
    // Out of range clamps, NaN is the low end.
    assert_eq!(colour(Colormap::Viridis, 7.0), [253, 231, 37]);
    assert_eq!(colour(Colormap::Viridis, f64::NAN), [68, 1, 84]);
}

#[test]
fn depth_map_has_its_bar_and_black_holes() {
    let depth = [2.0, 3.0, f32::NAN, 4.0];
    let r = depth_range(&depth, None);
    assert_eq!(r, [2.0, 4.0]);
    let (w, h, rgb) = depth_map(&depth, (2, 2), Colormap::Viridis, r).unwrap();
    assert_eq!((w, h), (2 + BAR_WIDTH, MIN_HEIGHT));
    assert_eq!(rgb.len(), (w * h * 3) as usize);
    let px = |i: usize, j: usize| {
        let o = (j * w as usize + i) * 3;
        [rgb[o], rgb[o + 1], rgb[o + 2]]
    };
    assert_eq!(px(0, 0), [68, 1, 84]);
    assert_eq!(px(1, 1), [253, 231, 37]);
    assert_eq!(px(0, 1), [0, 0, 0]);
    // The bar holds both ends of the map somewhere in its panel.
    let bar: Vec<[u8; 3]> = (0..h as usize)
        .flat_map(|j| (2..w as usize).map(move |i| (i, j)))
        .map(|(i, j)| px(i, j))
        .collect();
    assert!(
        bar.contains(&[253, 231, 37]) || bar.iter().any(|c| c[0] > 240 && c[1] > 220 && c[2] < 60)
    );
    assert!(bar.iter().any(|c| c[0] < 80 && c[1] < 10 && c[2] > 70));
    // A fixed range is kept; a flat image gets a non-empty one.
    assert_eq!(depth_range(&depth, Some([0.0, 9.0])), [0.0, 9.0]);
    let flat = depth_range(&[3.0, 3.0], None);
    assert!(flat[0] < 3.0 && flat[1] > 3.0);
    assert_eq!(depth_range(&[f32::NAN], None), [0.0, 1.0]);
}
