//! Checkpoints of a training run: where they go, the fingerprint that
//! ties one to its run, resuming from one (refused when from another
//! run) and writing them as training goes.

use super::super::*;
use crate::train::log::History;
use crate::train::Objective;
use sdfl_stdlib::value::Moments;

/// The optimizer as the fingerprint sees it. Adam's moments join it only
/// when not the defaults, so checkpoints written before they could be set
/// still resume: the text is then what `{:?}` gave before.
pub fn optimizer_key(o: &sdfl_stdlib::value::Optimizer) -> String {
    if o.moments == Moments::default() {
        format!("Optimizer {{ lr: {:?}, schedule: {:?} }}", o.lr, o.schedule)
    } else {
        format!("{o:?}")
    }
}

/// Text that `{:?}` writes as it is (not quoted, as a `String` would be).
pub struct Verbatim(pub String);

impl std::fmt::Debug for Verbatim {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

/// How often a checkpoint is written.
pub(crate) const CHECKPOINT_EVERY: usize = 100;

/// The fingerprint of what a run depends on: one hash per
/// [`crate::train::checkpoint::PARTS`] entry (not the step count, so a run can be
/// continued for longer).
pub fn fingerprint(job: &TrainJob, views: &[TrainView]) -> [String; 4] {
    use std::fmt::Write;
    let mut data = Fnv::default();
    for v in views {
        data.str(&format!("{:?}", v.camera))
            .f32s(&[v.image.width as f32, v.image.height as f32]);
        for p in v.image.colours() {
            data.f32s(&p);
        }
    }
    let hash = |value: &dyn std::fmt::Debug| {
        let mut h = Fnv::default();
        let _ = write!(h, "{value:?}");
        h.finish()
    };
    let optimizer = Verbatim(optimizer_key(&job.optimizer));
    [
        hash(&job.model),
        data.finish(),
        hash(&job.sampler),
        hash(&(optimizer, &job.losses, job.rays, job.seed, job.backend)),
    ]
}

/// A run's checkpoint file, if it names one, and its fingerprint.
pub(super) struct Checkpoints {
    /// Where the checkpoint is kept, under `--out`.
    pub path: Option<PathBuf>,
    /// What the run depends on (empty without a checkpoint).
    pub fingerprint: [String; 4],
}

impl Checkpoints {
    /// The checkpoint `job` names under `out_dir`.
    pub fn of(job: &TrainJob, views: &[TrainView], out_dir: &Path) -> Self {
        Checkpoints {
            // Only a checkpoint needs the fingerprint (it walks the whole model).
            fingerprint: if job.checkpoint.is_some() {
                fingerprint(job, views)
            } else {
                Default::default()
            },
            path: job.checkpoint.as_ref().map(|c| out_dir.join(c)),
        }
    }

    /// Resumes `run` from the checkpoint where there is one (unless
    /// `restart`), refusing one of another run or beyond `steps`; else
    /// writes one of the start, so that a run that diverges at once still
    /// leaves a good state to resume from. The step resumed from, if any,
    /// and the history the checkpoint carries.
    pub fn resume_or_start<O: Objective + ?Sized>(
        &self,
        run: &mut Run<O>,
        steps: usize,
        restart: bool,
    ) -> io::Result<(Option<usize>, History)> {
        let Some(cp) = &self.path else {
            return Ok((None, History::default()));
        };
        if !cp.exists() || restart {
            self.write(run, History::default())?;
            return Ok((None, History::default()));
        }
        let refused = |e: &dyn std::fmt::Display| {
            invalid(format!(
                "checkpoint {}: {e}; run with --restart to start over",
                cp.display()
            ))
        };
        let ck = Checkpoint::read(cp).map_err(|e| {
            // Read errors name the checkpoint already.
            let m = e.to_string();
            let prefix = format!("checkpoint {}: ", cp.display());
            refused(&m.strip_prefix(&prefix).unwrap_or(&m))
        })?;
        ck.check(steps).map_err(|e| refused(&e))?;
        let differs = ck.differences(&self.fingerprint);
        if !differs.is_empty() {
            return Err(invalid(format!(
                "checkpoint {} is from another run: its {} differ{}; run with --restart to start over, or name another `checkpoint`",
                cp.display(),
                differs.join(", "),
                if differs.len() == 1 { "s" } else { "" }
            )));
        }
        run.resume(&ck).map_err(|e| match e {
            TrainError::Invalid(m) => refused(&m),
            e => refused(&e),
        })?;
        Ok((Some(run.step), ck.history))
    }

    /// `run` as it is now, with its `history`.
    pub fn of_run<O: Objective + ?Sized>(&self, run: &Run<O>, history: History) -> Checkpoint {
        run.checkpoint(self.fingerprint.clone())
            .with_history(history)
    }

    /// Writes `run` as it is now, with its `history`, where a checkpoint
    /// is named.
    pub fn write<O: Objective + ?Sized>(&self, run: &Run<O>, history: History) -> io::Result<()> {
        match &self.path {
            Some(cp) => self.of_run(run, history).write(cp),
            None => Ok(()),
        }
    }
}
