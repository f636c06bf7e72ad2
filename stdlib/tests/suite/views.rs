use glam::DVec3;
use sdfl_stdlib::value::{held_out, spread_views};
#[test]
fn sizes_at_the_data_aspect_keep_the_shorter_side() {
    use sdfl_stdlib::value::size_at_aspect;
    assert_eq!(size_at_aspect(800, 800, 128), (128, 128));
    assert_eq!(size_at_aspect(1600, 1200, 128), (170, 128));
    assert_eq!(size_at_aspect(1920, 1080, 128), (228, 128));
    assert_eq!(size_at_aspect(1080, 1920, 128), (128, 228));
    assert_eq!(size_at_aspect(1000, 999, 128), (128, 128));
    let (w, _) = size_at_aspect(16_384, 1, 128);
    assert_eq!(w, sdfl_stdlib::limits::MAX_IMAGE_SIDE);
}

#[test]
fn held_out_views_are_a_seeded_sorted_subset() {
    let a = held_out(100, 10, 3);
    assert_eq!(a, held_out(100, 10, 3));
    assert_eq!(a.len(), 10);
    assert!(a.windows(2).all(|w| w[0] < w[1]) && a[9] < 100);
    assert_ne!(a, held_out(100, 10, 4));
    // Not simply the first or last views.
    assert_ne!(a, (0..10).collect::<Vec<_>>());
    assert_ne!(a, (90..100).collect::<Vec<_>>());
    assert!(held_out(5, 0, 1).is_empty());
    assert_eq!(held_out(3, 3, 9), vec![0, 1, 2]);
    assert!(held_out(0, 2, 0).is_empty());
}

#[test]
fn spread_views_are_nested_far_apart_and_never_held_out() {
    // On a line: the first, the far end, then the middle.
    let line: Vec<DVec3> = (0..=10).map(|x| DVec3::new(x as f64, 0.0, 0.0)).collect();
    assert_eq!(spread_views(&line, &[], 3), [0, 5, 10]);
    assert_eq!(spread_views(&line, &[0, 10], 2), [1, 9]);
    // Hard case: every camera at one place: ties go to the lowest index.
    let same = vec![DVec3::ONE; 6];
    assert_eq!(spread_views(&same, &[1], 3), [0, 2, 3]);
    // Asking for more than there are gives every view not held out.
    assert_eq!(spread_views(&same, &[1], 9), [0, 2, 3, 4, 5]);
    assert!(spread_views(&[], &[], 3).is_empty());

    // On a Fibonacci sphere: nested, and within the greedy rule's
    // factor of 2 of the best smallest gap (brute force over subsets).
    let eyes: Vec<DVec3> = sdfl_stdlib::camera::Camera::sphere(16, 3.0, DVec3::Y, 1.0, false)
        .iter()
        .map(|c| c.eye)
        .collect();
    let held = held_out(eyes.len(), 4, 7);
    let gap = |set: &[usize]| {
        let mut g = f64::INFINITY;
        for (i, &a) in set.iter().enumerate() {
            for &b in &set[i + 1..] {
                g = g.min(eyes[a].distance(eyes[b]));
            }
        }
        g
    };
    let free: Vec<usize> = (0..eyes.len()).filter(|i| !held.contains(i)).collect();
    let mut before: Vec<usize> = Vec::new();
    for k in 1..=free.len() {
        let picked = spread_views(&eyes, &held, k);
        assert_eq!(picked.len(), k);
        assert!(picked.iter().all(|p| !held.contains(p)));
        assert!(before.iter().all(|b| picked.contains(b)), "k = {k}: nested");
        if (2..=4).contains(&k) {
            let mut best = 0.0f64;
            let n = free.len();
            for mask in 0u32..1 << n {
                if mask.count_ones() as usize == k {
                    let set: Vec<usize> = (0..n)
                        .filter(|j| mask >> j & 1 == 1)
                        .map(|j| free[j])
                        .collect();
                    best = best.max(gap(&set));
                }
            }
            assert!(
                gap(&picked) >= 0.5 * best - 1e-12,
                "k = {k}: {} vs best {best}",
                gap(&picked)
            );
        }
        before = picked;
    }
}
