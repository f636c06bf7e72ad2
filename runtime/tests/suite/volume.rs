//! Volume rendering through the language: images must not depend on where
//! `far` lies unless the reference assignment's infinite last interval is
//! asked for. The submodules test `volume`'s modules one by one.

mod composite;
mod figures;
mod importance;
mod march;
mod rays;
mod render;

use sdfl_lang::SourceFile;
use sdfl_runtime::volume::march::{intervals_into, march, Depths};
use sdfl_stdlib::num::V3;

/// Opacity of the centre ray from (0, 0, −3) through a VolSDF torus tilted
/// by 60°, whose hole that ray crosses.
fn centre_opacity(far: f64, last: &str) -> f64 {
    let src = format!(
        "render r {{ scene: volsdf(rotate(torus(major: 1, minor: 0.3), 60deg, axis: [1, 0, 0]), alpha: 10, beta: 0.05), \
         camera: look_at(eye: [0, 0, -3]), sampler: stratified(samples: 64, near: 0, far: {far}, last_interval: \"{last}\"), \
         outputs: [image(\"r.png\")] }}"
    );
    let program = sdfl_stdlib::load(&SourceFile::new("far.sdfl", src)).unwrap();
    let job = &program.volumes[0];
    let s = job.sampler;
    let t: Vec<f32> = (0..s.samples)
        .map(|k| (s.near + (s.far - s.near) * k as f64 / (s.samples - 1) as f64) as f32)
        .collect();
    let mut delta = Vec::new();
    intervals_into(&t, s.last_interval, &mut delta);
    let f = job.field.as_sdf().expect("an analytic field");
    march::<f64>(
        |p| (f.shape.distance(p.into()), V3::splat(1.0)),
        f.density,
        f.alpha.value,
        f.beta.value,
        [0.0, 0.0, -3.0],
        [0.0, 0.0, 1.0],
        Depths {
            t: &t,
            delta: &delta,
        },
        false,
    )
    .opacity
}

#[test]
fn volsdf_images_do_not_depend_on_far() {
    let (a, b) = (centre_opacity(5.0, "zero"), centre_opacity(8.0, "zero"));
    assert!(
        a < 0.1 && (a - b).abs() < 0.02,
        "the hole: {a} at far 5, {b} at far 8"
    );
    // The reference assignment's last interval closes the hole at far 5.
    assert!(centre_opacity(5.0, "infinite") > 0.9);
    assert!(centre_opacity(8.0, "infinite") < 0.1);
}
