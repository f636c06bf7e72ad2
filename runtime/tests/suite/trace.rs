//! Relaxed sphere-tracing steps never leap past `far` over a surface.

use glam::Vec3A;
use sdfl_runtime::sdf::{LowerOptions, Lowered};
use sdfl_runtime::trace::*;
use sdfl_stdlib::param::Arg;
use sdfl_stdlib::shape::Shape;

/// A relaxed step from the camera can pass `far` although the surface is
/// nearer: the ray must still find it (it was a miss once).
#[test]
fn relaxed_steps_never_leap_past_far_over_a_surface() {
    let torus: Shape = sdfl_stdlib::shape::Torus {
        center: Arg::fixed(glam::DVec3::ZERO),
        major: Arg::fixed(1.0),
        minor: Arg::fixed(0.3),
        axis: sdfl_stdlib::sdf::Axis::Z,
    }
    .into();
    let scene = Lowered::new(&torus, LowerOptions::default());
    let origin = Vec3A::new(0.0, 0.0, -4.0);
    for far in [4.0f32, 5.0, 10.0] {
        for relax in [false, true] {
            let s = TraceSettings {
                near: 0.0,
                far,
                max_steps: 64,
                epsilon: 1e-5,
                footprint: 1e-3,
                relax,
                lipschitz: 1.0,
            };
            // Towards the ring: it is 3.7 to 4.3 away.
            let dir = Vec3A::new(1.0, 0.0, 4.0).normalize();
            let hit = sphere_trace(&*scene.root, origin, dir, &s);
            assert!(hit.hit, "far {far}, relaxed {relax}: {hit:?}");
            let p = origin + dir * hit.t;
            assert!(scene.dist(p).abs() < 1e-3, "far {far}: off the surface");
            // Through the hole: a miss, decided.
            let hit = sphere_trace(&*scene.root, origin, Vec3A::Z, &s);
            assert!(!hit.hit && !hit.undecided && hit.t.is_finite());
        }
    }
}
