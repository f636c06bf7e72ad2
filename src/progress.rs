//! A run's progress on stderr: a bar on a terminal; elsewhere (a log
//! file, a pipe, a batch job) a plain line every few seconds, so a long
//! run piped to a file is not silent. Training shows its step, loss, last
//! held-out PSNR, steps per second and an ETA counted from its first step
//! (loading data is not training time).

use std::io::IsTerminal;
use std::sync::Mutex;
use std::time::{Duration, Instant};

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use sdfl_runtime::train::log::TrainEvent;

/// Seconds between plain lines, unless `SDFL_PROGRESS_SECS` says otherwise.
const DEFAULT_EVERY: f64 = 5.0;

/// Seconds between plain lines: `SDFL_PROGRESS_SECS` when it is a number
/// of seconds ≥ 0 (0: a line at every update, for tests), else the default.
pub fn interval(setting: Option<&std::ffi::OsStr>) -> Duration {
    setting
        .and_then(|v| v.to_str()?.trim().parse::<f64>().ok())
        .filter(|s| s.is_finite() && *s >= 0.0 && *s < 1e9)
        .map_or(
            Duration::from_secs_f64(DEFAULT_EVERY),
            Duration::from_secs_f64,
        )
}

/// `3h 05m`, `4m 12s`, `42s`.
pub fn duration(secs: f64) -> String {
    if !secs.is_finite() || secs < 0.0 {
        return "?".into();
    }
    let s = secs.round() as u64;
    match (s / 3600, s / 60 % 60, s % 60) {
        (0, 0, s) => format!("{s}s"),
        (0, m, s) => format!("{m}m {s:02}s"),
        (h, m, _) => format!("{h}h {m:02}m"),
    }
}

/// What the current statement has done.
#[derive(Debug, Clone, Default)]
struct Job {
    name: String,
    /// Units (pixels, or steps) done and in all.
    done: u64,
    total: u64,
    /// When and at which unit the clock started: the job's start for a
    /// render, the first step for training.
    clock: Option<(Instant, u64)>,
    training: bool,
    loss: Option<f32>,
    /// The last held-out evaluation: step and PSNR.
    psnr: Option<(usize, f64)>,
}

impl Job {
    /// Units per second since the clock started, and the seconds left.
    fn pace(&self, now: Instant) -> Option<(f64, f64)> {
        let (t0, at) = self.clock?;
        let secs = now.duration_since(t0).as_secs_f64();
        let done = self.done.saturating_sub(at);
        if done == 0 || secs <= 0.0 {
            return None;
        }
        let rate = done as f64 / secs;
        Some((rate, self.total.saturating_sub(self.done) as f64 / rate))
    }

    /// The plain line: `nerf: step 1200/5000, loss 2.345e-3, held-out PSNR
    /// 27.31 dB (step 1000), 12.3 steps/s, ETA 5m 12s`.
    fn line(&self, now: Instant) -> String {
        let mut parts = Vec::new();
        if self.training {
            parts.push(format!("step {}/{}", self.done, self.total));
            if let Some(l) = self.loss {
                parts.push(format!("loss {l:.3e}"));
            }
            if let Some((step, p)) = self.psnr {
                parts.push(format!("held-out PSNR {p:.2} dB (step {step})"));
            }
        } else {
            let pct = 100.0 * self.done as f64 / self.total.max(1) as f64;
            parts.push(format!("{pct:.0}% of {} pixels", self.total));
        }
        match self.pace(now) {
            Some((rate, left)) => {
                if self.training {
                    parts.push(format!("{rate:.1} steps/s"));
                }
                parts.push(format!("ETA {}", duration(left)));
            }
            None => parts.push("ETA ?".into()),
        }
        format!("{}: {}", self.name, parts.join(", "))
    }
}

/// Progress on stderr, shared by the threads that report it.
pub struct Progress {
    /// On a terminal: one bar per statement.
    bar: Option<ProgressBar>,
    /// Elsewhere: the seconds between lines.
    every: Duration,
    state: Mutex<(Job, Instant)>,
}

impl Progress {
    /// A bar on a terminal (none with `quiet`, the `--json` report's
    /// wish), plain lines every `every` elsewhere.
    pub fn new(quiet: bool, every: Duration) -> Progress {
        let bar = std::io::stderr().is_terminal().then(|| {
            let bar = ProgressBar::new(0);
            if quiet {
                bar.set_draw_target(ProgressDrawTarget::hidden());
            }
            bar.set_style(
                ProgressStyle::with_template(
                    "{msg:>12} [{bar:40}] {percent:>3}% {elapsed_precise} eta {eta}",
                )
                .expect("valid template")
                .progress_chars("=> "),
            );
            bar
        });
        Progress {
            bar,
            every,
            state: Mutex::new((Job::default(), Instant::now())),
        }
    }

    fn with<R>(&self, f: impl FnOnce(&mut Job, &mut Instant) -> R) -> R {
        let mut s = self.state.lock().unwrap_or_else(|p| p.into_inner());
        let (job, last) = &mut *s;
        f(job, last)
    }

    /// A statement named `name` of `total` units starts; a render's clock
    /// starts now, training's at its first step.
    pub fn start(&self, name: &str, total: u64, training: bool) {
        let now = Instant::now();
        self.with(|job, last| {
            *job = Job {
                name: name.to_string(),
                total,
                training,
                clock: (!training).then_some((now, 0)),
                ..Job::default()
            };
            *last = now;
        });
        if let Some(bar) = &self.bar {
            bar.reset();
            bar.set_length(total);
            bar.set_message(name.to_string());
        }
    }

    /// `n` more units done.
    pub fn inc(&self, n: u64) {
        self.with(|job, _| job.done += n);
        if let Some(bar) = &self.bar {
            bar.inc(n);
        }
        self.maybe_line();
    }

    /// A plain line if the interval has passed (never on a terminal).
    fn maybe_line(&self) {
        if self.bar.is_some() {
            return;
        }
        let now = Instant::now();
        let line = self.with(|job, last| {
            (now.duration_since(*last) >= self.every).then(|| {
                *last = now;
                job.line(now)
            })
        });
        if let Some(line) = line {
            say!("{line}");
        }
    }

    /// A line printed as it is, above the bar on a terminal.
    fn note(&self, text: &str) {
        match &self.bar {
            Some(bar) => bar.suspend(|| say!("{text}")),
            None => say!("{text}"),
        }
    }

    /// What a training run reports.
    pub fn train_event(&self, e: &TrainEvent) {
        match *e {
            TrainEvent::Started { step, total, .. } => {
                let now = Instant::now();
                self.with(|job, last| {
                    job.done = step as u64;
                    job.total = total as u64;
                    job.clock = Some((now, step as u64));
                    *last = now;
                });
                if let Some(bar) = &self.bar {
                    bar.set_length(total as u64);
                    bar.set_position(step as u64);
                    // The ETA from here: loading the data is not training.
                    bar.reset_eta();
                    bar.reset_elapsed();
                }
            }
            TrainEvent::Step { step, loss, .. } => {
                self.with(|job, _| {
                    job.done = step as u64;
                    job.loss = Some(loss);
                });
                if let Some(bar) = &self.bar {
                    bar.set_position(step as u64);
                }
                self.maybe_line();
            }
            TrainEvent::Evaluated { step, psnr, .. } => {
                self.with(|job, _| job.psnr = Some((step, psnr)));
            }
            TrainEvent::Note(text) => self.note(text),
            TrainEvent::Status(text) => match &self.bar {
                Some(bar) => bar.set_message(text.to_string()),
                // Piped: the status itself every interval, so the phases
                // after training (outputs, scoring) are not silent.
                None => {
                    let now = Instant::now();
                    let due = self.with(|job, last| {
                        // While steps run, their lines say more.
                        let stepping = job.training && job.done < job.total;
                        let due = !stepping && now.duration_since(*last) >= self.every;
                        if due {
                            *last = now;
                        }
                        due
                    });
                    if due {
                        say!("{text}");
                    }
                }
            },
        }
    }

    /// The run ended (well or not): the bar is cleared.
    pub fn finish(&self) {
        if let Some(bar) = &self.bar {
            bar.finish_and_clear();
        }
    }
}

/// Pixels of a render or volume statement (at `--size` when given).
pub fn pixels(w: u32, h: u32, views: usize, size: Option<(u32, u32)>) -> u64 {
    let (w, h) = size.unwrap_or((w, h));
    w as u64 * h as u64 * views as u64
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_interval_reads_seconds_and_falls_back() {
        let s = |v: &str| interval(Some(std::ffi::OsStr::new(v)));
        assert_eq!(s("0"), Duration::ZERO);
        assert_eq!(s(" 2.5 "), Duration::from_millis(2500));
        let default = Duration::from_secs_f64(DEFAULT_EVERY);
        for bad in ["-1", "soon", "inf", "NaN", "1e300"] {
            assert_eq!(s(bad), default, "{bad}");
        }
        assert_eq!(interval(None), default);
    }

    #[test]
    fn durations_read_at_a_glance() {
        assert_eq!(duration(42.4), "42s");
        assert_eq!(duration(252.0), "4m 12s");
        assert_eq!(duration(3.0 * 3600.0 + 300.0), "3h 05m");
        assert_eq!(duration(f64::INFINITY), "?");
    }

    #[test]
    fn the_eta_counts_steps_since_training_started() {
        let t0 = Instant::now();
        let job = Job {
            name: "nerf".into(),
            done: 1200,
            total: 5000,
            // Resumed at 1000: 200 steps in 20 s.
            clock: Some((t0, 1000)),
            training: true,
            loss: Some(2.345e-3),
            psnr: Some((1000, 27.314)),
        };
        let line = job.line(t0 + Duration::from_secs(20));
        assert_eq!(
            line,
            "nerf: step 1200/5000, loss 2.345e-3, held-out PSNR 27.31 dB (step 1000), 10.0 steps/s, ETA 6m 20s"
        );
        // Before the first step: no pace yet.
        let waiting = Job {
            done: 1000,
            ..job.clone()
        };
        assert!(waiting.line(t0).ends_with("ETA ?"), "{}", waiting.line(t0));
        let render = Job {
            name: "r".into(),
            done: 250,
            total: 1000,
            clock: Some((t0, 0)),
            training: false,
            ..Job::default()
        };
        assert_eq!(
            render.line(t0 + Duration::from_secs(1)),
            "r: 25% of 1000 pixels, ETA 3s"
        );
    }
}
