//! What a training run says as it goes. To whoever watches (the CLI's
//! progress): typed [`TrainEvent`]s. To files beside its outputs, written
//! during the run so another process can follow it:
//!
//! * `<out>/<name>.metrics.csv`: `step,seconds,loss,lr,psnr,ssim`, one row
//!   per step (psnr and ssim empty without a held-out evaluation), flushed
//!   every [`FLUSH_EVERY`] and at every evaluation and checkpoint;
//! * `<out>/tensorboard/<name>/events.out.tfevents.sdfl`: the same scalars
//!   for TensorBoard ([`tensorboard`]);
//! * `<out>/<name>.heldout.png`: at each held-out evaluation, the first
//!   held-out view as predicted beside its truth (replaced atomically).
//!
//! The checkpoint carries the run's [`History`] (held-out scores, training
//! seconds), so a resumed run keeps its whole curve. On resume both logs
//! keep their whole records of steps 1, 2, … in sequence before the
//! checkpoint's step, read as streams (a log of any size costs only what
//! is kept); steps from the first one missing, torn or out of sequence up
//! to the checkpoint's are written again from the checkpoint, which holds
//! every loss and held-out score (their seconds only where an evaluation
//! recorded them; the events' wall time is the resume's), and a note says
//! so. Rows past the checkpoint (a `kill -9` after it) are dropped: none is
//! missing, none repeated.

pub mod tensorboard;

use std::io::{self, BufRead, Read, Write};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant, SystemTime};

use serde::{Deserialize, Serialize};

use sdfl_stdlib::value::Optimizer;

use crate::data::TrainView;
use crate::output::{to_u8, Atomic};

/// How often the logs reach their files while steps run (also at every
/// evaluation and checkpoint): a dashboard or `tail -f` following them
/// lags by at most this and a step. Flushing costs a write per interval.
pub const FLUSH_EVERY: Duration = Duration::from_secs(2);

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
    /// The held-out views scored (`eval_views` of the data's, or all);
    /// 0 in a checkpoint written before this was kept.
    #[serde(default)]
    pub views: usize,
    /// Mean over the views of each view's PSNR inside its object mask
    /// (dB), where the data have object masks (IDR's `mask/`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub psnr_in_mask: Option<f64>,
}

/// What one held-out evaluation measured.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Scores {
    /// Mean PSNR over the views (dB).
    pub psnr: f64,
    /// Mean SSIM over the views.
    pub ssim: f64,
    /// Mean PSNR inside the views' object masks, where they have them.
    pub psnr_in_mask: Option<f64>,
    /// The views scored.
    pub views: usize,
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
    /// Unknown (empty) for a row written again from a checkpoint between
    /// its evaluations.
    seconds: Option<f64>,
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
        let seconds = self.seconds.map_or(String::new(), |s| format!("{s:.3}"));
        format!(
            "{},{seconds},{},{},{psnr},{ssim}\n",
            self.step, self.loss, self.lr
        )
    }
}

fn wall_time() -> f64 {
    SystemTime::now()
        .duration_since(SystemTime::UNIX_EPOCH)
        .map_or(0.0, |d| d.as_secs_f64())
}

/// Longest CSV line read back: a row is six numbers, a few hundred bytes
/// even with a rate of 1e-300 written out in full.
const MAX_CSV_LINE: u64 = 4096;

/// Largest event record read back (sdfl writes them under 200 bytes).
const MAX_EVENT_RECORD: u64 = 1 << 16;

/// An append-only file whose kept prefix, written by `prefix`, replaced it
/// atomically on opening (a link planted there is replaced, not followed).
fn reopen<T>(
    path: &Path,
    prefix: impl FnOnce(&mut dyn Write) -> io::Result<T>,
) -> io::Result<(io::BufWriter<std::fs::File>, T)> {
    let mut f = Atomic::create(path)?;
    let kept = prefix(f.writer())?;
    f.commit()?;
    let file = std::fs::OpenOptions::new().append(true).open(path)?;
    Ok((io::BufWriter::new(file), kept))
}

/// The log at `path` to read back, if it is a regular file there (not a
/// link, a FIFO or a device): streamed, never read whole.
fn read_back(path: &Path) -> Option<io::BufReader<std::fs::File>> {
    sdfl_stdlib::files::open_regular_unlinked(path)
        .ok()
        .map(io::BufReader::new)
}

/// One line of `from` with its newline, at most `max` bytes; `None` at the
/// end, on an error, or for a line torn or too long.
fn line(from: &mut impl BufRead, max: u64) -> Option<Vec<u8>> {
    let mut line = Vec::new();
    from.take(max).read_until(b'\n', &mut line).ok()?;
    line.ends_with(b"\n").then_some(line)
}

/// Copies to `to` the CSV's header and its rows of steps 1, 2, … in
/// sequence before step `before`, read from `from`; stops at the first row
/// that is torn, malformed or out of sequence. Returns the last step kept
/// (0 for none).
pub fn copy_csv_prefix(
    from: Option<impl BufRead>,
    before: usize,
    to: &mut dyn Write,
) -> io::Result<usize> {
    let header = format!("{CSV_HEADER}\n");
    to.write_all(header.as_bytes())?;
    let Some(mut from) = from else {
        return Ok(0);
    };
    if line(&mut from, MAX_CSV_LINE).is_none_or(|l| l != header.as_bytes()) {
        return Ok(0);
    }
    let mut last = 0;
    while last + 1 < before {
        let Some(row) = line(&mut from, MAX_CSV_LINE) else {
            break;
        };
        let step = std::str::from_utf8(&row)
            .ok()
            .filter(|l| l.split(',').count() == 6)
            .and_then(|l| l.split(',').next()?.parse::<usize>().ok());
        if step != Some(last + 1) {
            break;
        }
        to.write_all(&row)?;
        last += 1;
    }
    Ok(last)
}

/// The next whole record of an event stream with a valid checksum, at most
/// [`MAX_EVENT_RECORD`] long: its bytes and where its data starts.
fn next_record(from: &mut impl Read) -> Option<Vec<u8>> {
    let mut record = vec![0u8; 12];
    from.read_exact(&mut record).ok()?;
    let (len, crc) = record.split_at(8);
    if tensorboard::masked_crc(len).to_le_bytes() != crc {
        return None;
    }
    let n = u64::from_le_bytes(len.try_into().expect("8 bytes"));
    if n > MAX_EVENT_RECORD {
        return None;
    }
    let want = n as usize + 4;
    from.take(want as u64).read_to_end(&mut record).ok()?;
    // Whole, and its data's checksum right.
    let whole = tensorboard::records(&record);
    (whole.len() == 1 && whole[0].0 == record.len()).then_some(record)
}

/// The first length-delimited field numbered `n`.
fn bytes_field<'a>(fields: Vec<(u64, tensorboard::Field<'a>)>, n: u64) -> Option<&'a [u8]> {
    fields.into_iter().find_map(|(k, f)| match f {
        tensorboard::Field::Bytes(b) if k == n => Some(b),
        _ => None,
    })
}

/// The first tag of an `Event`'s summary, if it has one.
fn first_tag(event: &[u8]) -> Option<&[u8]> {
    let summary = bytes_field(tensorboard::fields(event).ok()?, 5)?;
    let value = bytes_field(tensorboard::fields(summary).ok()?, 1)?;
    bytes_field(tensorboard::fields(value).ok()?, 1)
}

/// Copies to `to` the event file's version record and its records before
/// step `before`: the loss of steps 1, 2, … in sequence, a step's held-out
/// scores once after its loss; stops at the first record that is torn,
/// corrupt or out of sequence. Returns the last step whose loss was kept
/// (0 for none) and whether its scores were.
pub fn copy_events_prefix(
    from: Option<impl Read>,
    before: usize,
    to: &mut dyn Write,
) -> io::Result<(usize, bool)> {
    let version = |to: &mut dyn Write| {
        to.write_all(&tensorboard::record(&tensorboard::version_event(
            wall_time(),
        )))
    };
    let Some(mut from) = from else {
        version(to)?;
        return Ok((0, false));
    };
    let first = next_record(&mut from).filter(|r| {
        let data = &r[12..r.len() - 4];
        tensorboard::fields(data).is_ok_and(|f| {
            f.iter().any(|(k, v)| {
                *k == 3 && *v == tensorboard::Field::Bytes(tensorboard::FILE_VERSION.as_bytes())
            })
        })
    });
    let Some(first) = first else {
        version(to)?;
        return Ok((0, false));
    };
    to.write_all(&first)?;
    let (mut last, mut scored) = (0, false);
    while let Some(record) = next_record(&mut from) {
        let data = &record[12..record.len() - 4];
        let Ok(step) = tensorboard::event_step(data).map(|s| s as usize) else {
            break;
        };
        let keep = match first_tag(data) {
            Some(b"train/loss") if step == last + 1 && step < before => {
                (last, scored) = (step, false);
                true
            }
            Some(t) if t.starts_with(b"held_out/") && step == last && last > 0 && !scored => {
                scored = true;
                true
            }
            _ => false,
        };
        if !keep {
            break;
        }
        to.write_all(&record)?;
    }
    Ok((last, scored))
}

/// A training run's logs and clock.
pub struct TrainLog<'o> {
    observer: &'o Observer<'o>,
    /// When the logs last reached their files.
    flushed: Instant,
    /// At most this long between flushes while steps run.
    #[doc(hidden)]
    pub flush_every: Duration,
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
        let (csv, csv_kept) = reopen(&csv_path, |to| {
            copy_csv_prefix(read_back(&csv_path), step, to)
        })?;
        let (events, events_kept) = reopen(&events_path, |to| {
            copy_events_prefix(read_back(&events_path), step, to)
        })?;
        let mut log = TrainLog {
            observer,
            flushed: Instant::now(),
            flush_every: FLUSH_EVERY,
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
        log.rebuild(name, losses, csv_kept, events_kept);
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

    /// Writes again from the checkpoint (`losses`, the history) the steps
    /// the logs lack before the checkpoint's own: the CSV kept up to step
    /// `csv_kept`, the event file up to `events_kept.0` (with its scores
    /// if `events_kept.1`). Says which steps, where there are any.
    fn rebuild(&mut self, name: &str, losses: &[f32], csv_kept: usize, events_kept: (usize, bool)) {
        let step = losses.len();
        let held_out = self.history.held_out.clone();
        let scored = |k: usize| held_out.iter().find(|h| h.step == k).copied();
        let mut rows = String::new();
        for k in csv_kept + 1..step {
            let h = scored(k);
            let row = Row {
                step: k,
                seconds: h.map(|h| h.seconds),
                loss: losses[k - 1],
                lr: self.lr(k),
                scores: h.map(|h| (h.psnr, h.ssim)),
            };
            rows += &row.line();
        }
        let r = self.csv.write_all(rows.as_bytes());
        self.check(r);
        let (events_kept, kept_scores) = events_kept;
        let mut records = Vec::new();
        let now = wall_time();
        let scores = |k: usize, records: &mut Vec<u8>| {
            if let Some(h) = scored(k) {
                let values = [
                    ("held_out/psnr", h.psnr as f32),
                    ("held_out/ssim", h.ssim as f32),
                ];
                let e = tensorboard::scalars_event(now, k as i64, &values);
                records.extend(tensorboard::record(&e));
            }
        };
        if events_kept > 0 && events_kept < step && !kept_scores {
            scores(events_kept, &mut records);
        }
        for k in events_kept + 1..step {
            let values = [
                ("train/loss", losses[k - 1]),
                ("train/lr", self.lr(k) as f32),
            ];
            let e = tensorboard::scalars_event(now, k as i64, &values);
            records.extend(tensorboard::record(&e));
            scores(k, &mut records);
        }
        let r = self.events.write_all(&records);
        self.check(r);
        let logs = TrainingLogs::of(name);
        for (file, kept, what) in [
            (
                logs.metrics_csv.display().to_string(),
                csv_kept,
                "losses and held-out scores; seconds only where an evaluation recorded them",
            ),
            (
                logs.events().display().to_string(),
                events_kept,
                "losses and held-out scores, at the wall time of this run",
            ),
        ] {
            if kept + 1 < step {
                let steps = if kept + 2 == step {
                    format!("step {}", kept + 1)
                } else {
                    format!("steps {} to {}", kept + 1, step - 1)
                };
                let note = format!(
                    "{file}: {steps} missing or cut short; written again from the checkpoint ({what})"
                );
                (self.observer)(&TrainEvent::Note(&note));
            }
        }
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
            seconds: Some(seconds),
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
        if self.flushed.elapsed() >= self.flush_every {
            let r = self.flush();
            self.check(r);
        }
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
        scores: Scores,
        took: f64,
        first: Option<(&TrainView, &[[f32; 3]])>,
    ) -> HeldOut {
        let t = Instant::now();
        let Scores {
            psnr,
            ssim,
            psnr_in_mask,
            views,
        } = scores;
        let h = HeldOut {
            step,
            seconds: self.last_seconds,
            psnr,
            ssim,
            views,
            psnr_in_mask,
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

    /// Writes the steps and events held so far to the files.
    #[doc(hidden)]
    pub fn flush(&mut self) -> io::Result<()> {
        self.flushed = Instant::now();
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
            for (panel, px) in [render.get(i).copied(), Some(view.image.pixel(i))]
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
