//! SIMD lanes: the scalar operations lane by lane, packs, constants.

use glam::Vec3A;
use sdfl_runtime::lanes::*;
use sdfl_stdlib::num::Real;

#[test]
fn lanes_equal_scalar_operations() {
    let a = F8([0.0, -0.0, 1.5, -2.25, 1e30, 3.0, f32::MIN_POSITIVE, 7.0]);
    let b = F8([0.0, 0.0, -1.5, 4.0, -1e30, 3.0, 2.0, f32::INFINITY]);
    let check = |r: F8, f: &dyn Fn(f32, f32) -> f32| {
        for i in 0..LANES {
            assert_eq!(r.0[i].to_bits(), f(a.0[i], b.0[i]).to_bits(), "lane {i}");
        }
    };
    check(a + b, &|x, y| x + y);
    check(a * b, &|x, y| x * y);
    check(a.min(b), &|x, y| Real::min(x, y));
    check(a.max(b), &|x, y| Real::max(x, y));
    check(a.abs().sqrt(), &|x, _| x.abs().sqrt());
}

#[test]
fn packs_hold_their_points_lane_by_lane() {
    let pts: Vec<Vec3A> = (0..8)
        .map(|i| {
            let f = i as f32;
            Vec3A::new(f - 3.5, [-0.0, 1e30, -f32::INFINITY, 2.0][i % 4], f * 1e-38)
        })
        .collect();
    // Whole packs (transposed in registers) and partial ones (the
    // last point repeated).
    for n in 1..=8 {
        let p = pack(&pts[..n]);
        for i in 0..LANES {
            let want = pts[i.min(n - 1)];
            let got = lane(&p, i);
            assert_eq!(
                got.to_array().map(f32::to_bits),
                want.to_array().map(f32::to_bits),
                "{n} points, lane {i}"
            );
        }
    }
}

#[test]
fn a_constant_pack_has_a_value() {
    assert_eq!(F8::splat(0.5).val(), 0.5);
    let mixed = F8([0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]);
    assert!(std::panic::catch_unwind(|| mixed.val()).is_err());
}
