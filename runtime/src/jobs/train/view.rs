//! A trained field read back from its checkpoint, to be seen from any
//! camera while (or after) another process trains it: what `sdfl view`
//! orbits. The checkpoint is checked as a resume checks it (the file's
//! own consistency, the model's fingerprint, each tensor's name, shape and
//! range), so one of another model, or corrupt, is refused with a reason.

use std::time::SystemTime;

use super::super::*;
use super::field::{needs_ndc_frame, trained_field, with_ndc_frame};
use crate::train::export_names::Layout;
use crate::train::TrainedField;

/// What identifies one version of a checkpoint file on disk: training
/// replaces it by a rename, which changes both.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CheckpointStamp {
    /// Its length in bytes.
    pub bytes: u64,
    /// When it was last modified (`None` where the platform does not say).
    pub modified: Option<SystemTime>,
}

impl CheckpointStamp {
    /// The stamp of the file at `path`; `None` when there is no regular
    /// file there (not yet written).
    pub fn of(path: &Path) -> Option<CheckpointStamp> {
        let meta = std::fs::symlink_metadata(path).ok()?;
        meta.is_file().then(|| CheckpointStamp {
            bytes: meta.len(),
            modified: meta.modified().ok(),
        })
    }
}

/// Why a trained field cannot be shown.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum FieldUnavailable {
    /// Nothing to read yet: the statement names no `checkpoint`, or its
    /// run has not written one.
    NoCheckpoint(String),
    /// A checkpoint that is not this field's: unreadable, corrupt, of
    /// another model, or the field cannot be built.
    Refused(String),
}

impl std::fmt::Display for FieldUnavailable {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            FieldUnavailable::NoCheckpoint(m) | FieldUnavailable::Refused(m) => f.write_str(m),
        }
    }
}

/// A `train` statement's field at the values of its checkpoint.
pub struct CheckpointedField {
    /// The statement, its NDC frame filled in where the model needs one.
    job: TrainJob,
    field: Box<dyn TrainedField>,
    values: Vec<f32>,
    step: usize,
    stamp: CheckpointStamp,
}

/// Where `job`'s checkpoint lives under `out_dir`, if it names one.
pub fn checkpoint_path(job: &TrainJob, out_dir: &Path) -> Option<PathBuf> {
    job.checkpoint.as_ref().map(|c| out_dir.join(c))
}

impl CheckpointedField {
    /// `job`'s field at the values of its checkpoint under `out_dir`. A
    /// NeRF in NDC reads its data (relative to `base`) once, for the
    /// capture's frame; other fields read only the checkpoint.
    pub fn load(job: &TrainJob, out_dir: &Path, base: &Path) -> Result<Self, FieldUnavailable> {
        let refused = |e: &dyn std::fmt::Display| FieldUnavailable::Refused(e.to_string());
        let resolved = if needs_ndc_frame(job) {
            let views = load_views(&job.data, base).map_err(|e| refused(&e))?;
            with_ndc_frame(job, views.forward_facing, &|_| {})
                .map_err(|e| refused(&e))?
                .unwrap_or_else(|| job.clone())
        } else {
            job.clone()
        };
        Self::read(resolved, out_dir)
    }

    /// This field at a newer checkpoint, if the file changed since it was
    /// read (`Ok(None)` while it has not).
    pub fn refreshed(&self, out_dir: &Path) -> Result<Option<Self>, FieldUnavailable> {
        let now = checkpoint_path(&self.job, out_dir).and_then(|p| CheckpointStamp::of(&p));
        if now == Some(self.stamp) {
            return Ok(None);
        }
        Self::read(self.job.clone(), out_dir).map(Some)
    }

    /// Builds the field of `job` (resolved) and loads its checkpoint.
    fn read(job: TrainJob, out_dir: &Path) -> Result<Self, FieldUnavailable> {
        let Some(path) = checkpoint_path(&job, out_dir) else {
            return Err(FieldUnavailable::NoCheckpoint(format!(
                "`{}` names no `checkpoint`, so its field is not kept: add `checkpoint: \"{}.ckpt\"` to the statement",
                job.name, job.name
            )));
        };
        // Taken before reading: a newer file renamed in between is read
        // again at the next refresh, never missed.
        let Some(stamp) = CheckpointStamp::of(&path) else {
            return Err(FieldUnavailable::NoCheckpoint(format!(
                "`{}` has no checkpoint yet ({}): `sdfl run` writes it as it trains",
                job.name,
                path.display()
            )));
        };
        let refused = |e: &dyn std::fmt::Display| {
            FieldUnavailable::Refused(format!("checkpoint {}: {e}", path.display()))
        };
        let ck = Checkpoint::read(&path).map_err(|e| {
            // Read errors name the checkpoint already.
            FieldUnavailable::Refused(e.to_string())
        })?;
        // Any step count: the statement may have been shortened since.
        ck.check(ck.step).map_err(|e| refused(&e))?;
        let model = fingerprint(&job, &[])[0].clone();
        if ck.fingerprint[0] != model {
            return Err(refused(&format!(
                "it is of another model than `{}` now has (its model changed since, or the checkpoint is another run's)",
                job.name
            )));
        }
        let field = trained_field(&job, job.iterations, &[]).map_err(|e| refused(&e))?;
        let mut run = Run::for_optimizer(field, &job.optimizer).map_err(|e| refused(&e))?;
        run.describe(Layout::of(&job.model, &run.objective.tensors()));
        // The same checks as a resume: names, shapes, ranges, state.
        run.resume(&ck).map_err(|e| refused(&e))?;
        Ok(CheckpointedField {
            values: run.values(),
            step: run.step,
            field: run.objective,
            job,
            stamp,
        })
    }

    /// The steps the checkpoint holds.
    pub fn step(&self) -> usize {
        self.step
    }

    /// The version of the file read.
    pub fn stamp(&self) -> CheckpointStamp {
        self.stamp
    }

    /// The region meshes of the field cover, where it has one.
    pub fn region(&self) -> Option<crate::train::field::Region> {
        self.field.region()
    }

    /// The field seen from `cam`, `width`×`height` pixels: RGB8, row by row.
    pub fn render_rgb8(&self, cam: &Camera, (width, height): (u32, u32)) -> io::Result<Vec<u8>> {
        let view = self
            .field
            .render_view(&self.values, cam, ImageSize { width, height }, false)
            .map_err(|e| invalid(format!("rendering `{}`: {e}", self.job.name)))?;
        Ok(rgb8(&view.colour))
    }
}
