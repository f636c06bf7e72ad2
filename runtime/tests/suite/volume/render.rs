//! Volume rendering: depth only when asked, every density model finite.

use sdfl_runtime::volume::rays::{ImageSize, Stratified};
use sdfl_runtime::volume::render::*;
use sdfl_stdlib::camera::{Camera, OrbitUp};
use sdfl_stdlib::value::{DensityKind, LastInterval};

fn model(kind: DensityKind, alpha: f32, beta: f32) -> DensityModel {
    DensityModel {
        kind,
        alpha,
        beta,
        last_interval: LastInterval::Zero,
    }
}

#[test]
fn depth_is_computed_only_when_asked() {
    let cam = Camera::orbit(3.0, OrbitUp::Y, 1.0, 1)[0];
    let s = Stratified::new(32, 0.0, 5.0).unwrap();
    let size = ImageSize {
        width: 16,
        height: 16,
    };
    let field = |p: [f32; 3]| {
        let d = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt() - 1.0;
        (d, [0.5, 0.2, 0.9])
    };
    let m = model(DensityKind::Opacity, 1.0, 0.05);
    let with = render_field_image_with(field, m, &s, &cam, size, true).unwrap();
    let without = render_field_image_with(field, m, &s, &cam, size, false).unwrap();
    assert_eq!(with.colour, without.colour);
    assert_eq!(with.depth.len(), 256);
    assert!(without.depth.is_empty());
}

#[test]
fn density_models_render_finite_images() {
    let cam = Camera::orbit(3.0, OrbitUp::Y, 1.0, 4)[1];
    let s = Stratified::new(64, 0.0, 5.0).unwrap();
    let size = ImageSize {
        width: 17,
        height: 17,
    };
    let sphere = |p: [f32; 3]| {
        (
            (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt() - 1.0,
            [0.5; 3],
        )
    };
    for &kind in DensityKind::ALL {
        // The centre ray hits the unit sphere at depth 2 (within `tol`).
        // NeuS's symmetric density with plain compositing absorbs
        // mostly in front of the surface (the bias NeuS's own weighting
        // removes); ∫σ across a surface is α: large enough to be opaque.
        let (alpha, beta, tol) = match kind {
            DensityKind::Opacity => (1.0, 1e-4, 0.1),
            DensityKind::VolSdf => (10.0, 0.05, 0.1),
            DensityKind::Neus => (50.0, 0.05, 0.3),
        };
        let m = model(kind, alpha, beta);
        let img = render_field_image(sphere, m, &s, &cam, size).unwrap();
        let centre = 8 * 17 + 8;
        assert!(img
            .colour
            .iter()
            .flatten()
            .all(|x| x.is_finite() && (0.0..=0.5 + 1e-5).contains(x)));
        // A corner misses.
        assert!(
            (img.depth[centre] - 2.0).abs() < tol,
            "{m:?}: {}",
            img.depth[centre]
        );
        assert!(img.colour[centre][0] > 0.45);
        assert!(img.depth[0] < 1e-3);
    }
    let bad = model(DensityKind::Opacity, 2.0, 0.05);
    assert!(render_field_image(sphere, bad, &s, &cam, size).is_err());
    let bad_sampler = Stratified {
        n: 1,
        near: 0.0,
        far: 1.0,
    };
    let neus = model(DensityKind::Neus, 1.0, 0.1);
    assert!(render_field_image(sphere, neus, &bad_sampler, &cam, size).is_err());
}
