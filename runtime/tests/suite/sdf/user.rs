//! User shapes: one pack wide equals two.

use glam::Vec3A;
use sdfl_runtime::lanes::{self, F16, F8, LANES, P8};
use sdfl_runtime::sdf::user::*;
use sdfl_runtime::sdf::*;
use sdfl_stdlib::eval::globals_of;
use sdfl_stdlib::shape::Shape;
use sdfl_stdlib::value::Value;
use std::mem::MaybeUninit;

/// The column code one pack wide (what a CPU without AVX-512 runs)
/// equals it two packs wide, bit for bit, on every lane; this machine
/// may pick either in `dist_packs`, so both are called by name here.
#[test]
fn one_pack_wide_equals_two_packs_wide() {
    let src = "fn twisted(p, k: 1.5) { let c = cos(k * p.y); let s = sin(k * p.y); let q = [c * p.x - s * p.z, p.y, s * p.x + c * p.z]; let d = abs(q) - [0.4, 0.8, 0.2]; length(max(d, 0)) + min(max(d.x, max(d.y, d.z)), 0) }\nlet s = sdf(twisted, bound: [0.5, 0.8, 0.5])";
    let Some(Value::Shape(shape)) = globals_of(src).expect("parses").remove("s") else {
        panic!("not a shape");
    };
    let Shape::User(u) = &*shape else {
        panic!("not a user shape");
    };
    let leaf = UserLeaf::new(u, Frame::identity().xform(), 1.0, 0);
    // Odd pack counts (a half-used F16), hard values, and points
    // outside the bound box.
    for packs in [1, 3, 7, 40, 301] {
        let points: Vec<Vec3A> = (0..packs * LANES)
            .map(|i| {
                let t = i as f32 * 0.618_034;
                match i % 11 {
                    0 => Vec3A::new(-0.0, 0.0, -0.0),
                    1 => Vec3A::new(1e30, -1e30, 3.0),
                    2 => Vec3A::new(f32::MIN_POSITIVE / 4.0, 0.8, -0.5),
                    _ => Vec3A::new(t.sin(), (1.3 * t).cos(), (0.7 * t).sin()) * 0.9,
                }
            })
            .collect();
        let p: Vec<P8> = points.chunks(LANES).map(lanes::pack).collect();
        let mut narrow = vec![F8::splat(0.0); packs];
        let mut wide = vec![F8::splat(0.0); packs];
        let mut cols8 = vec![MaybeUninit::<F8>::uninit(); COLUMN_BUFFER];
        let mut cols16 = vec![MaybeUninit::<F16>::uninit(); COLUMN_BUFFER / 2];
        user_packs(&leaf, &p, &mut narrow, &mut cols8);
        user_packs(&leaf, &p, &mut wide, &mut cols16);
        for (k, (a, b)) in narrow.iter().zip(&wide).enumerate() {
            for i in 0..LANES {
                assert_eq!(
                    a.0[i].to_bits(),
                    b.0[i].to_bits(),
                    "pack {k} lane {i} of {packs}"
                );
                let one = leaf.dist(points[k * LANES + i]);
                assert_eq!(
                    a.0[i].to_bits(),
                    one.to_bits(),
                    "pack {k} lane {i}: point by point"
                );
            }
        }
    }
}
