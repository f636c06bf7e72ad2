//! A training run's metrics as the viewer shows them, read from
//! `<out>/<train name>.metrics.csv` (header `step,seconds,loss,lr,psnr,ssim`;
//! psnr and ssim empty on rows without an evaluation), which the run
//! appends to as it goes, possibly in another process.

use std::io::Read;
use std::path::Path;

use serde::Serialize;

/// Most bytes of a metrics file read (a million steps is about 40 MB; the
/// curves need far fewer points).
const MAX_BYTES: u64 = 64 << 20;
/// Most loss points sent to the page: longer runs are thinned evenly.
pub const MAX_POINTS: usize = 2000;

/// The curves of one run.
#[derive(Debug, Default, Serialize, PartialEq)]
pub struct Curves {
    /// Steps of the loss points (thinned to [`MAX_POINTS`]).
    pub step: Vec<f64>,
    /// The training loss at those steps.
    pub loss: Vec<f64>,
    /// Every held-out evaluation: (step, PSNR in dB).
    pub psnr: Vec<(f64, f64)>,
    /// Every held-out evaluation: (step, SSIM).
    pub ssim: Vec<(f64, f64)>,
    /// The last row's step, elapsed seconds and learning rate.
    pub last: Option<(f64, f64, f64)>,
}

/// The run's curves; `None` while it has no metrics file.
pub fn read(path: &Path) -> Option<Curves> {
    // A FIFO or device planted there is refused, never waited on; the
    // path is the one resolved inside `--out`, so a link swapped in since
    // is refused too.
    let file = sdfl_stdlib::files::open_regular_unlinked(path).ok()?;
    let mut text = String::new();
    file.take(MAX_BYTES).read_to_string(&mut text).ok()?;
    Some(parse(&text))
}

/// Parses the CSV by its header's names; malformed rows (a line being
/// written, a torn tail after a kill) are skipped.
pub fn parse(text: &str) -> Curves {
    let mut lines = text.lines();
    let Some(header) = lines.next() else {
        return Curves::default();
    };
    let columns: Vec<&str> = header.split(',').map(str::trim).collect();
    let col = |name: &str| columns.iter().position(|c| *c == name);
    let (step, seconds, loss, lr, psnr, ssim) = (
        col("step"),
        col("seconds"),
        col("loss"),
        col("lr"),
        col("psnr"),
        col("ssim"),
    );
    let mut c = Curves::default();
    let mut rows = Vec::new();
    for line in lines {
        let cells: Vec<&str> = line.split(',').map(str::trim).collect();
        if cells.len() != columns.len() {
            continue;
        }
        let at = |i: Option<usize>| {
            i.and_then(|i| cells[i].parse::<f64>().ok())
                .filter(|v| v.is_finite())
        };
        let Some(s) = at(step) else { continue };
        if let Some(l) = at(loss) {
            rows.push((s, l));
        }
        if let Some(p) = at(psnr) {
            c.psnr.push((s, p));
        }
        if let Some(q) = at(ssim) {
            c.ssim.push((s, q));
        }
        c.last = Some((s, at(seconds).unwrap_or(0.0), at(lr).unwrap_or(0.0)));
    }
    let stride = rows.len().div_ceil(MAX_POINTS).max(1);
    for (k, (s, l)) in rows.iter().enumerate() {
        // Every stride-th point, and always the last.
        if k % stride == 0 || k + 1 == rows.len() {
            c.step.push(*s);
            c.loss.push(*l);
        }
    }
    c
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rows_with_and_without_evaluations() {
        let c = parse(
            "step,seconds,loss,lr,psnr,ssim\n\
             1,0.1,0.5,0.01,,\n\
             2,0.2,0.25,0.01,21.5,0.7\n\
             3,0.3,0.125,0.005,,\n\
             4,0.4,garbage\n",
        );
        assert_eq!(c.step, [1.0, 2.0, 3.0]);
        assert_eq!(c.loss, [0.5, 0.25, 0.125]);
        assert_eq!(c.psnr, [(2.0, 21.5)]);
        assert_eq!(c.ssim, [(2.0, 0.7)]);
        assert_eq!(c.last, Some((3.0, 0.3, 0.005)));
    }

    #[test]
    fn columns_are_found_by_name_and_long_runs_thinned() {
        let mut text = String::from("loss,step\n");
        for k in 0..10_000 {
            text.push_str(&format!("{},{k}\n", 1.0 / (k + 1) as f64));
        }
        let c = parse(&text);
        assert!(c.step.len() <= MAX_POINTS + 1 && c.step.len() >= MAX_POINTS / 2);
        assert_eq!(c.step.first(), Some(&0.0));
        assert_eq!(c.step.last(), Some(&9999.0));
        assert!(c.psnr.is_empty());
        assert_eq!(parse(""), Curves::default());
        assert_eq!(parse("nonsense\n\u{0}\n").step.len(), 0);
    }
}
