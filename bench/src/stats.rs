//! What every benchmark reports: medians with minima, and the machine's
//! load while it ran.

/// The median and the minimum of `ms` (not empty).
pub fn median_min(mut ms: Vec<f64>) -> (f64, f64) {
    ms.sort_by(f64::total_cmp);
    (ms[ms.len() / 2], ms[0])
}

/// The 1-, 5- and 15-minute load averages, or "unknown".
pub fn load() -> String {
    std::fs::read_to_string("/proc/loadavg")
        .map(|s| s.split_whitespace().take(3).collect::<Vec<_>>().join(" "))
        .unwrap_or_else(|_| "unknown".into())
}
