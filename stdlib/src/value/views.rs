//! Which views a data set holds out and trains on, and views made from training cameras.

use glam::DVec3;

/// A `train`'s views resolved when it runs, from its training cameras.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum ViewPath {
    /// nerfstudio's interpolated path through the training cameras in the
    /// order the data lists them (`training_path`).
    TrainingPath {
        /// Views made along the path.
        frames: usize,
    },
    /// `camera_loop` through the training cameras.
    TrainingLoop {
        /// Views made along the loop.
        frames: usize,
        /// Sectors of azimuth, one control point each.
        keyframes: usize,
    },
}

impl ViewPath {
    /// How many views it makes.
    pub fn frames(&self) -> usize {
        match self {
            ViewPath::TrainingPath { frames } | ViewPath::TrainingLoop { frames, .. } => *frames,
        }
    }
}

/// The shorter side of a `train`'s before/after views where neither `size`
/// is written nor the data's images are square: the default `[128, 128]`'s.
pub const DATA_ASPECT_SHORT_SIDE: u32 = 128;

/// A `short`-pixel image at the aspect of `width × height` images (pixels
/// are square, CONVENTIONS.md: the shorter side is the one the focal length
/// refers to, so a camera frames the same view): the shorter side `short`,
/// the longer one in proportion, rounded to an even number of pixels (as a
/// video needs), at most [`MAX_IMAGE_SIDE`](crate::limits::MAX_IMAGE_SIDE).
pub fn size_at_aspect(width: u32, height: u32, short: u32) -> (u32, u32) {
    let (w, h) = (width.max(1) as f64, height.max(1) as f64);
    let long = |ratio: f64| {
        let even = ((short as f64 * ratio / 2.0).round() * 2.0) as u32;
        even.clamp(short, crate::limits::MAX_IMAGE_SIDE)
    };
    if w >= h {
        (long(w / h), short)
    } else {
        (short, long(h / w))
    }
}

/// The `test` of `n` views held out, by a seeded shuffle (SplitMix64 and
/// Fisher-Yates): the same for the same `(n, test, seed)` on every machine.
/// Sorted; `test` is at most `n`.
pub fn held_out(n: usize, test: usize, seed: u64) -> Vec<usize> {
    let mut state = seed;
    let mut next = move || {
        state = state.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = state;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    };
    let mut order: Vec<usize> = (0..n).collect();
    for i in (1..n).rev() {
        // Modulo bias is below 2^-40 for n ≤ 10 000 views.
        let j = (next() % (i as u64 + 1)) as usize;
        order.swap(i, j);
    }
    let mut test: Vec<usize> = order.into_iter().take(test.min(n)).collect();
    test.sort_unstable();
    test
}

/// `k` training views among `eyes` (camera positions) that are not in
/// `held` (sorted indices held out), spread out: the first view not held
/// out, then each next the one farthest from those picked (ties to the
/// lowest index). Deterministic, and nested: the views for `k` are among
/// those for any larger `k`, so a fewer-views sweep only ever takes views
/// away, and never changes what it is scored on. Sorted; `k` is at most
/// the views not held out.
pub fn spread_views(eyes: &[DVec3], held: &[usize], k: usize) -> Vec<usize> {
    let mut free: Vec<usize> = (0..eyes.len())
        .filter(|i| held.binary_search(i).is_err())
        .collect();
    let mut picked = Vec::with_capacity(k.min(free.len()));
    // Squared distance of each free view to the nearest picked one.
    let mut nearest = vec![f64::INFINITY; free.len()];
    while picked.len() < k && !free.is_empty() {
        // The first free view while none is picked (all at ∞), then the farthest.
        let (at, _) = nearest
            .iter()
            .enumerate()
            .fold((0, f64::NEG_INFINITY), |best, (j, &d)| {
                if d > best.1 {
                    (j, d)
                } else {
                    best
                }
            });
        // `remove` keeps `free` in index order, for the tie rule.
        let view = free.remove(at);
        nearest.remove(at);
        for (j, &f) in free.iter().enumerate() {
            nearest[j] = nearest[j].min(eyes[f].distance_squared(eyes[view]));
        }
        picked.push(view);
    }
    picked.sort_unstable();
    picked
}

#[cfg(test)]
mod tests {
    use super::{held_out, spread_views};
    use glam::DVec3;
    #[test]
    fn sizes_at_the_data_aspect_keep_the_shorter_side() {
        use super::size_at_aspect;
        assert_eq!(size_at_aspect(800, 800, 128), (128, 128));
        assert_eq!(size_at_aspect(1600, 1200, 128), (170, 128));
        assert_eq!(size_at_aspect(1920, 1080, 128), (228, 128));
        assert_eq!(size_at_aspect(1080, 1920, 128), (128, 228));
        assert_eq!(size_at_aspect(1000, 999, 128), (128, 128));
        let (w, _) = size_at_aspect(16_384, 1, 128);
        assert_eq!(w, crate::limits::MAX_IMAGE_SIDE);
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
        let eyes: Vec<DVec3> = crate::camera::Camera::sphere(16, 3.0, DVec3::Y, 1.0, false)
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
}
