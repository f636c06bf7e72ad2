//! What a training run says as it goes. To whoever watches (the CLI's
//! progress): typed [`TrainEvent`]s. To files beside its outputs, written
//! during the run so another process can follow it:
//!
//! * `<out>/<name>.metrics.csv`: `step,seconds,loss,lr,psnr,ssim`, one row
//!   per step (psnr and ssim empty without a held-out evaluation), flushed
//!   at every evaluation and checkpoint;
//! * `<out>/tensorboard/<name>/events.out.tfevents.sdfl`: the same scalars
//!   for TensorBoard ([`tensorboard`]);
//! * `<out>/<name>.heldout.png`: at each held-out evaluation, the first
//!   held-out view as predicted beside its truth (replaced atomically).
//!
//! The checkpoint carries the run's [`History`] (held-out scores, training
//! seconds), so a resumed run keeps its whole curve. On resume both logs
//! keep what precedes the checkpoint's step and the checkpoint's own step
//! is written again from its history: rows past it (a `kill -9` after the
//! checkpoint) are dropped, none is missing, none repeated.

pub mod tensorboard;

use std::io::{self, Write};
use std::path::{Path, PathBuf};
use std::time::{Instant, SystemTime};

use serde::{Deserialize, Serialize};

use sdfl_stdlib::value::Optimizer;

use crate::data::TrainView;
use crate::output::{to_u8, Atomic};

/// What a run reports to its observer.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum TrainEvent<'a> {
    /// The data is loaded and training starts at `step` (0, or the step
    /// resumed from) of `total`: the training clock starts now.
    Started {
        /// The `train` statement's name.
        name: &'a str,
        /// Steps already done.
        step: usize,
        /// Steps the run ends at.
        total: usize,
    },
    /// A step done.
    Step {
        /// Steps done, this one included.
        step: usize,
        /// Its loss.
        loss: f32,
        /// Its learning rate.
        lr: f64,
    },
    /// The held-out views scored.
    Evaluated {
        /// The step scored at.
        step: usize,
        /// Mean PSNR (dB).
        psnr: f64,
        /// Mean SSIM.
        ssim: f64,
    },
    /// A line worth showing as it is (the data set read, a warning).
    Note(&'a str),
    /// The run's current state in a few words (a loss, parameters), for a
    /// display that shows one line and replaces it.
    Status(&'a str),
}

/// Whoever watches a run.
pub type Observer<'a> = dyn Fn(&TrainEvent<'_>) + Sync + 'a;

/// Quality on the held-out views at a step.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct HeldOut {
    /// The training step evaluated at.
    pub step: usize,
    /// Seconds of training up to that step, over every run that led to it
    /// (evaluation excluded).
    pub seconds: f64,
    /// Mean over the views of each view's PSNR (dB).
    pub psnr: f64,
    /// Mean over the views of each view's SSIM.
    pub ssim: f64,
}

/// A run's history beyond its losses, carried by its checkpoint.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct History {
    /// Seconds of training up to the checkpoint's step.
    pub seconds: f64,
    /// Every held-out evaluation so far.
    pub held_out: Vec<HeldOut>,
}

/// The CSV's first line.
pub const CSV_HEADER: &str = "step,seconds,loss,lr,psnr,ssim";

pub use sdfl_stdlib::outputs::{TrainingLogs, EVENTS_FILE};

/// Where the logs of training `name` go under `out_dir`: the CSV, the
/// event file and the held-out image, named by [`TrainingLogs`] (which
/// the file's check keeps other outputs off).
pub fn paths(out_dir: &Path, name: &str) -> (PathBuf, PathBuf, PathBuf) {
    let logs = TrainingLogs::of(name);
    (
        out_dir.join(&logs.metrics_csv),
        out_dir.join(logs.events()),
        out_dir.join(&logs.held_out_image),
    )
}

/// One CSV row.
#[derive(Debug, Clone, Copy)]
struct Row {
    step: usize,
    seconds: f64,
    loss: f32,
    lr: f64,
    scores: Option<(f64, f64)>,
}

impl Row {
    fn line(&self) -> String {
        let (psnr, ssim) = self
            .scores
            .map_or((String::new(), String::new()), |(p, s)| {
                (p.to_string(), s.to_string())
            });
        format!(
            "{},{:.3},{},{},{psnr},{ssim}\n",
            self.step, self.seconds, self.loss, self.lr
        )
    }
}

fn wall_time() -> f64 {
    SystemTime::now()
        .duration_since(SystemTime::UNIX_EPOCH)
        .map_or(0.0, |d| d.as_secs_f64())
}

/// An append-only file whose kept prefix was rewritten atomically on
/// opening (a link planted there is replaced, not followed).
fn reopen(path: &Path, prefix: &[u8]) -> io::Result<io::BufWriter<std::fs::File>> {
    let mut f = Atomic::create(path)?;
    f.writer().write_all(prefix)?;
    f.commit()?;
    let file = std::fs::OpenOptions::new().append(true).open(path)?;
    Ok(io::BufWriter::new(file))
}

/// The bytes of `path` if it is a regular file (not through a link).
fn existing(path: &Path) -> Vec<u8> {
    match std::fs::symlink_metadata(path) {
        Ok(m) if m.is_file() => std::fs::read(path).unwrap_or_default(),
        _ => Vec::new(),
    }
}

/// The CSV's header and rows before step `before`, in order; stops at the
/// first row that is torn, malformed or out of order.
fn csv_prefix(text: &[u8], before: usize) -> Vec<u8> {
    let mut keep = format!("{CSV_HEADER}\n").into_bytes();
    let Some(body) = text.strip_prefix(keep.as_slice()) else {
        return keep;
    };
    let mut last = 0;
    let mut at = 0;
    for line in body.split_inclusive(|&b| b == b'\n') {
        let step = std::str::from_utf8(line)
            .ok()
            .filter(|l| l.ends_with('\n') && l.split(',').count() == 6)
            .and_then(|l| l.split(',').next()?.parse::<usize>().ok());
        match step {
            Some(s) if s > last && s < before => {
                last = s;
                at += line.len();
            }
            _ => break,
        }
    }
    keep.extend_from_slice(&body[..at]);
    keep
}

/// The event file's records before step `before` (the version record
/// first), whole and in order.
fn events_prefix(bytes: &[u8], before: usize) -> Vec<u8> {
    let records = tensorboard::records(bytes);
    let mut end = 0;
    for (i, (e, data)) in records.iter().enumerate() {
        let step = tensorboard::event_step(data).ok();
        let keep = match step {
            Some(s) if i == 0 => s == 0 && tensorboard::fields(data).is_ok(),
            Some(s) => (s as usize) < before,
            None => false,
        };
        if !keep {
            break;
        }
        end = *e;
    }
    if end == 0 {
        return tensorboard::record(&tensorboard::version_event(wall_time()));
    }
    bytes[..end].to_vec()
}

/// A training run's logs and clock.
pub struct TrainLog<'o> {
    observer: &'o Observer<'o>,
    optimizer: Optimizer,
    csv: io::BufWriter<std::fs::File>,
    events: io::BufWriter<std::fs::File>,
    heldout_png: PathBuf,
    /// The last step's row, until it is known whether it is scored.
    pending: Option<Row>,
    history: History,
    /// Training seconds before this process's run.
    seconds_before: f64,
    clock: Instant,
    /// Seconds this process spent evaluating (not training).
    evaluating: f64,
    /// Training seconds at the last step.
    last_seconds: f64,
    /// The first write that failed, reported by [`TrainLog::finish`].
    error: Option<io::Error>,
}

impl<'o> TrainLog<'o> {
    /// Opens the logs of training `name` under `out_dir` at the run's
    /// current state (`losses` of the steps done, `history` from the
    /// checkpoint resumed, or empty), starts the training clock and tells
    /// `observer` that training starts.
    pub fn open(
        out_dir: &Path,
        name: &str,
        optimizer: Optimizer,
        losses: &[f32],
        history: History,
        total: usize,
        observer: &'o Observer<'o>,
    ) -> io::Result<TrainLog<'o>> {
        let (csv_path, events_path, heldout_png) = paths(out_dir, name);
        let step = losses.len();
        let csv = reopen(&csv_path, &csv_prefix(&existing(&csv_path), step))?;
        let events = reopen(&events_path, &events_prefix(&existing(&events_path), step))?;
        let mut log = TrainLog {
            observer,
            optimizer,
            csv,
            events,
            heldout_png,
            pending: None,
            seconds_before: history.seconds,
            last_seconds: history.seconds,
            history,
            clock: Instant::now(),
            evaluating: 0.0,
            error: None,
        };
        // The checkpoint's own step, again from its history.
        if let Some(&loss) = losses.last() {
            let scores = log
                .history
                .held_out
                .last()
                .filter(|h| h.step == step)
                .map(|h| (h.psnr, h.ssim));
            log.record_step(step, loss, log.history.seconds);
            if let Some((psnr, ssim)) = scores {
                log.record_scores(step, psnr, ssim);
            }
        }
        observer(&TrainEvent::Started { name, step, total });
        Ok(log)
    }

    /// Keeps the first error.
    fn check(&mut self, r: io::Result<()>) {
        if let (Err(e), None) = (r, &self.error) {
            self.error = Some(e);
        }
    }

    fn write_pending(&mut self) {
        if let Some(row) = self.pending.take() {
            let r = self.csv.write_all(row.line().as_bytes());
            self.check(r);
        }
    }

    fn lr(&self, step: usize) -> f64 {
        // Step k (1-based) ran at the rate of the k − 1 steps before it.
        self.optimizer.lr_at(step.saturating_sub(1))
    }

    fn record_step(&mut self, step: usize, loss: f32, seconds: f64) {
        self.write_pending();
        let lr = self.lr(step);
        self.pending = Some(Row {
            step,
            seconds,
            loss,
            lr,
            scores: None,
        });
        let e = tensorboard::scalars_event(
            wall_time(),
            step as i64,
            &[("train/loss", loss), ("train/lr", lr as f32)],
        );
        let r = self.events.write_all(&tensorboard::record(&e));
        self.check(r);
    }

    fn record_scores(&mut self, step: usize, psnr: f64, ssim: f64) {
        if let Some(row) = self.pending.as_mut().filter(|r| r.step == step) {
            row.scores = Some((psnr, ssim));
            self.write_pending();
        }
        let e = tensorboard::scalars_event(
            wall_time(),
            step as i64,
            &[
                ("held_out/psnr", psnr as f32),
                ("held_out/ssim", ssim as f32),
            ],
        );
        let r = self.events.write_all(&tensorboard::record(&e));
        self.check(r);
    }

    /// Training seconds now: every earlier run's and this one's, less
    /// the time spent evaluating.
    fn seconds(&self) -> f64 {
        self.seconds_before + self.clock.elapsed().as_secs_f64() - self.evaluating
    }

    /// Step `step` is done with `loss`.
    pub fn step(&mut self, step: usize, loss: f32) {
        let seconds = self.seconds();
        self.last_seconds = seconds;
        self.record_step(step, loss, seconds);
        (self.observer)(&TrainEvent::Step {
            step,
            loss,
            lr: self.lr(step),
        });
    }

    /// The held-out views were scored at `step`, which took `took` seconds
    /// (left out of the training time); `first` is the first view and its
    /// render, shown beside each other in the held-out image. Returns the
    /// evaluation as the history keeps it.
    pub fn evaluated(
        &mut self,
        step: usize,
        psnr: f64,
        ssim: f64,
        took: f64,
        first: Option<(&TrainView, &[[f32; 3]])>,
    ) -> HeldOut {
        let t = Instant::now();
        let h = HeldOut {
            step,
            seconds: self.last_seconds,
            psnr,
            ssim,
        };
        if self.history.held_out.last().map(|h| h.step) != Some(step) {
            self.history.held_out.push(h);
            self.record_scores(step, psnr, ssim);
        }
        if let Some((view, render)) = first {
            let r = write_side_by_side(&self.heldout_png, view, render);
            self.check(r);
        }
        let r = self.flush();
        self.check(r);
        (self.observer)(&TrainEvent::Evaluated { step, psnr, ssim });
        self.evaluating += took + t.elapsed().as_secs_f64();
        h
    }

    fn flush(&mut self) -> io::Result<()> {
        self.csv.flush()?;
        self.events.flush()
    }

    /// Every held-out evaluation so far.
    pub fn held_out(&self) -> &[HeldOut] {
        &self.history.held_out
    }

    /// The history a checkpoint of the last step carries; first the logs
    /// are flushed, so they hold every step before it (the last one is
    /// written again from this history on resume). A failed write is kept
    /// for [`TrainLog::finish`]: the checkpoint is worth writing anyway.
    pub fn history(&mut self) -> History {
        let r = self.flush();
        self.check(r);
        History {
            seconds: self.last_seconds,
            held_out: self.history.held_out.clone(),
        }
    }

    /// Training seconds at the last step.
    pub fn training_seconds(&self) -> f64 {
        self.last_seconds
    }

    /// Writes the last row and flushes; returns the held-out history.
    pub fn finish(mut self) -> io::Result<Vec<HeldOut>> {
        self.write_pending();
        if let Some(e) = self.error.take() {
            return Err(e);
        }
        self.flush()?;
        Ok(self.history.held_out)
    }
}

/// The first held-out view and its render, for [`TrainLog::evaluated`].
pub fn first_view<'a>(
    views: &'a [TrainView],
    renders: &'a [Vec<[f32; 3]>],
) -> Option<(&'a TrainView, &'a [[f32; 3]])> {
    views.first().zip(renders.first().map(|r| &r[..]))
}

/// The prediction of a held-out view beside its truth, as a PNG.
fn write_side_by_side(path: &Path, view: &TrainView, render: &[[f32; 3]]) -> io::Result<()> {
    let (w, h) = (view.image.width as usize, view.image.height as usize);
    let mut rgb = vec![0u8; 2 * w * h * 3];
    for y in 0..h {
        for x in 0..w {
            let i = y * w + x;
            for (panel, px) in [render.get(i).copied(), Some(view.image.pixels[i])]
                .into_iter()
                .enumerate()
            {
                let o = 3 * (y * 2 * w + panel * w + x);
                for k in 0..3 {
                    rgb[o + k] = to_u8(px.map_or(0.0, |p| p[k] as f64));
                }
            }
        }
    }
    crate::output::write_png(path, 2 * w as u32, h as u32, &rgb)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_csv_keeps_whole_ordered_rows_before_the_step() {
        let head = format!("{CSV_HEADER}\n");
        let text =
            format!("{head}1,0.1,0.5,0.01,,\n2,0.2,0.4,0.01,30,0.9\n3,0.3,0.3,0.01,,\n4,0.4,0.");
        let kept = |before| String::from_utf8(csv_prefix(text.as_bytes(), before)).unwrap();
        assert_eq!(
            kept(3),
            format!("{head}1,0.1,0.5,0.01,,\n2,0.2,0.4,0.01,30,0.9\n")
        );
        assert_eq!(kept(1), head);
        // The torn row 4 is dropped whatever the step.
        assert!(kept(100).ends_with("3,0.3,0.3,0.01,,\n"));
        // A foreign file keeps only a header.
        assert_eq!(csv_prefix(b"a,b\n1,2\n", 5), head.as_bytes());
        let disordered = format!("{head}2,0,0,0,,\n1,0,0,0,,\n");
        assert_eq!(
            csv_prefix(disordered.as_bytes(), 5),
            format!("{head}2,0,0,0,,\n").as_bytes()
        );
    }

    #[test]
    fn the_event_file_keeps_whole_records_before_the_step() {
        let rec = |step| tensorboard::record(&tensorboard::scalars_event(1.0, step, &[("x", 1.0)]));
        let version = tensorboard::record(&tensorboard::version_event(1.0));
        let mut file = [version.clone(), rec(1), rec(2), rec(3)].concat();
        file.extend_from_slice(&rec(4)[..7]);
        let n = |before| tensorboard::records(&events_prefix(&file, before)).len();
        assert_eq!((n(3), n(1), n(100)), (3, 1, 4));
        assert_eq!(events_prefix(&file, 2), [version, rec(1)].concat());
        // No version record first: a fresh file.
        let fresh = events_prefix(&rec(1), 5);
        let first = tensorboard::records(&fresh);
        assert_eq!(first.len(), 1);
        assert_eq!(tensorboard::event_step(first[0].1).unwrap(), 0);
    }
}
