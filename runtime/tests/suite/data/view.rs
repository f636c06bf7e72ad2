//! A downscaled training view: each block's unmasked pixels averaged.

use sdfl_runtime::data::view::*;
use sdfl_runtime::data::view_image::ViewImage;
use std::sync::Arc;

#[test]
fn a_downscaled_view_averages_its_blocks_unmasked_pixels() {
    // 4×2 pixels, scored at 2×1: the left block's masked pixel (a
    // garbage colour) is left out of its mean; the right block is all
    // masked and stays masked.
    let colours = vec![
        [0.2, 0.4, 0.6],
        [9.0, 9.0, 9.0],
        [1.0, 1.0, 1.0],
        [1.0, 1.0, 1.0],
        [0.4, 0.4, 0.6],
        [0.6, 0.4, 0.6],
        [1.0, 1.0, 1.0],
        [0.0, 0.0, 0.0],
    ];
    let mask: Arc<[bool]> = [true, false, false, false, true, true, false, false].into();
    let coverage: Arc<[u8]> = [255, 255, 0, 0, 255, 0, 0, 0].into();
    let view = TrainView {
        camera: sdfl_stdlib::camera::Camera::look_at(
            glam::DVec3::Z * 3.0,
            glam::DVec3::ZERO,
            glam::DVec3::Y,
            1.0,
        ),
        image: ViewImage::rgb32(4, 2, colours),
        mask: Some(mask),
        coverage: Some(coverage),
    };
    let small = view.downscaled(2).unwrap();
    assert_eq!((small.image.width, small.image.height), (2, 1));
    let left = small.image.pixel(0);
    for (got, want) in left.iter().zip([0.4, 0.4, 0.6]) {
        assert!((got - want).abs() < 1e-6, "{left:?}");
    }
    assert_eq!(&*small.mask.unwrap(), &[true, false]);
    assert_eq!(&*small.coverage.unwrap(), &[191, 0]);
    assert_eq!(small.camera, view.camera);
    // A factor that does not divide the size is refused, naming ones
    // that do.
    let e = view.downscaled(3).unwrap_err();
    assert!(
        e.contains("3 does not divide its 4x2 images (factors that do: 2)"),
        "{e}"
    );
    assert_eq!(view.downscaled(1).unwrap().image.width, 4);
}
