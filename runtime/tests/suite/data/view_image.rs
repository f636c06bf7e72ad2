//! A view's pixels as 8-bit composites or f32 values.

use sdfl_runtime::data::image::composite_over;
use sdfl_runtime::data::npy::RgbImage;
use sdfl_runtime::data::view_image::*;

/// Every 8-bit colour and alpha over several backgrounds: the pixel read
/// is bit for bit what compositing the decoded f32 RGBA gives.
#[test]
fn an_8_bit_pixel_reads_as_its_composite() {
    let mut rgba = Vec::new();
    for a in 0..=255u8 {
        for c in (0..=255u8).step_by(3) {
            rgba.push([c, 255 - c, c / 2, a]);
        }
    }
    for bg in [[1.0, 1.0, 1.0], [0.0, 0.0, 0.0], [0.25, 0.5, 0.75]] {
        let f32s: Vec<[f32; 4]> = rgba.iter().map(|p| p.map(|x| x as f32 / 255.0)).collect();
        let truth = composite_over(&f32s, bg);
        let img = ViewImage::rgba8(rgba.len() as u32, 1, rgba.clone(), bg);
        assert_eq!(img.len(), truth.len());
        for (i, t) in truth.iter().enumerate() {
            let p = img.pixel(i);
            assert!(
                p.iter().zip(t).all(|(a, b)| a.to_bits() == b.to_bits()),
                "pixel {i}: {p:?} against {t:?}"
            );
        }
        assert_eq!(img.to_rgb(), truth);
    }
}

#[test]
fn an_f32_view_keeps_its_values_and_sizes() {
    let px = vec![[0.1, 0.2, 0.3], [2.0, -1.0, 0.5]];
    let img = ViewImage::from(RgbImage {
        width: 2,
        height: 1,
        pixels: px.clone(),
    });
    assert_eq!(img.to_rgb(), px);
    assert_eq!(img.pixel(1), px[1]);
    assert_eq!(img.bytes_per_pixel(), RGB32_BYTES);
    let small = ViewImage::rgba8(1, 1, vec![[1, 2, 3, 4]], [0.0; 3]);
    assert_eq!(small.bytes_per_pixel(), RGBA8_BYTES);
}
