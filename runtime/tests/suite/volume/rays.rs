//! Camera rays: the camera model, chunks, random rays, stratified depths.

use glam::DVec3;
use sdfl_runtime::volume::rays::*;
use sdfl_runtime::volume::VolumeError;
use sdfl_stdlib::camera::Camera;

fn cam() -> Camera {
    Camera::look_at(DVec3::new(-1.0, 0.0, -2.2), DVec3::ZERO, DVec3::Y, 1.0)
}

#[test]
fn rays_match_camera_model() {
    let size = ImageSize {
        width: 5,
        height: 4,
    };
    let rays = camera_rays(&cam(), size).unwrap();
    assert_eq!(rays.len(), 20);
    for r in &rays {
        let n: f32 = r.dir.iter().map(|v| v * v).sum();
        assert!((n - 1.0).abs() < 1e-6);
        let (i, j) = (r.pixel % 5, r.pixel / 5);
        let (x, y) = sdfl_stdlib::camera::pixel_ndc(i, j, 5, 4);
        let d = cam().ray_direction(x, y);
        for k in 0..3 {
            assert!((r.dir[k] as f64 - d[k]).abs() < 1e-7);
        }
    }
    // The centre-most ray of an odd image looks at the target.
    let size = ImageSize {
        width: 3,
        height: 3,
    };
    let r = camera_rays(&cam(), size).unwrap()[4];
    let want = (DVec3::ZERO - cam().eye).normalize();
    assert!((r.dir[0] as f64 - want.x).abs() < 1e-7);
    assert!(camera_rays(
        &Camera::look_at(DVec3::ZERO, DVec3::ZERO, DVec3::Y, 1.0),
        size
    )
    .is_err());
}

#[test]
fn chunks_cover_every_pixel_once() {
    let size = ImageSize {
        width: 37,
        height: 11,
    };
    let mut out = vec![u32::MAX; size.pixels()];
    for_each_ray_chunk(&cam(), size, 50, &mut out, |rays, o| {
        for (r, v) in rays.iter().zip(o) {
            *v = r.pixel;
        }
        Ok(())
    })
    .unwrap();
    assert!(out.iter().enumerate().all(|(k, &p)| p == k as u32));
    assert!(for_each_ray_chunk(&cam(), size, 50, &mut out[1..], |_, _| Ok(())).is_err());
    let failing = |_: &[Ray], _: &mut [u32]| Err(VolumeError::Invalid("x".into()));
    assert!(for_each_ray_chunk(&cam(), size, 50, &mut out, failing).is_err());
}

#[test]
fn random_rays_are_distinct_seeded_and_in_range() {
    let cams = [cam(), cam()];
    let size = ImageSize {
        width: 8,
        height: 8,
    };
    let a = random_rays(&cams, size, 100, &mut SplitMix64::new(7)).unwrap();
    let b = random_rays(&cams, size, 100, &mut SplitMix64::new(7)).unwrap();
    assert_eq!(a, b);
    let mut ids: Vec<u32> = a.iter().map(|r| r.view * 64 + r.pixel).collect();
    ids.sort();
    ids.dedup();
    assert_eq!(ids.len(), 100);
    assert!(a.iter().all(|r| r.view < 2 && r.pixel < 64));
    // All pixels: a permutation.
    let all = random_rays(&cams, size, 128, &mut SplitMix64::new(1)).unwrap();
    let mut ids: Vec<u32> = all.iter().map(|r| r.view * 64 + r.pixel).collect();
    ids.sort();
    assert_eq!(ids, (0..128).collect::<Vec<_>>());
    assert!(random_rays(&cams, size, 129, &mut SplitMix64::new(1)).is_err());
    assert!(random_rays(&[], size, 1, &mut SplitMix64::new(1)).is_err());
}

#[test]
fn stratified_depths() {
    let s = Stratified::new(64, 0.0, 5.0).unwrap();
    let t = s.depths();
    assert_eq!(t.len(), 64);
    assert_eq!(t[0], 0.0);
    assert_eq!(t[63], 5.0);
    assert!((t[1] - 5.0 / 63.0).abs() < 1e-7);
    let mut j = vec![0f32; 64];
    let mut rng = SplitMix64::new(3);
    s.jittered_into(&mut rng, &mut j).unwrap();
    assert!(s.jittered_into(&mut rng, &mut j[1..]).is_err());
    assert!(j.windows(2).all(|w| w[0] <= w[1]));
    assert!(j.iter().all(|&v| (0.0..=5.0).contains(&v)));
    assert!(j.iter().zip(&t).any(|(a, b)| a != b));
    assert!(Stratified::new(1, 0.0, 1.0).is_err());
    assert!(Stratified::new(4, 2.0, 1.0).is_err());
    assert!(Stratified::new(4, 0.0, f32::NAN).is_err());
}
