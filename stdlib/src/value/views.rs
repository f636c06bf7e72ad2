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
