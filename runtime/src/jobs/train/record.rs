//! What a run's outputs were made from, kept beside its checkpoint
//! (`<name>.outputs.json`, named by [`sdfl_stdlib::outputs::TrainingLogs`]):
//! a finished run that is run again keeps each output whose declaration,
//! views and files are unchanged since the same checkpoint, and renders
//! only the others. Adding an output to a finished run renders that one
//! output, and its held-out views are scored again only for a comparison
//! that must be redrawn.

use serde::{Deserialize, Serialize};

use super::super::*;
use crate::neural::distance::MeshFit;
use crate::train::log::HeldOut;
use sdfl_stdlib::outputs::TrainingLogs;

/// The record of one run's outputs.
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
pub(super) struct OutputsRecord {
    /// The checkpoint step the outputs were made at.
    pub step: usize,
    /// The run's fingerprint ([`super::fingerprint`]) at that step.
    pub fingerprint: [String; 4],
    /// Each output written, by key.
    pub outputs: Vec<RecordedOutput>,
    /// The held-out scores at `step` (the final evaluation's).
    pub held_out: Option<HeldOut>,
    /// [`held_out_key`] of the views those scores are of.
    #[serde(default)]
    pub held_out_key: String,
    /// The first mesh's fit.
    pub mesh_fit: Option<RecordedFit>,
}

/// One output: what it was made from and the files it wrote.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub(super) struct RecordedOutput {
    /// [`output_key`] of the output.
    pub key: String,
    /// Its files as the report lists them, with each one's length (none
    /// for a directory).
    pub written: Vec<(Written, Option<u64>)>,
}

/// [`MeshFit`] as the record keeps it.
#[derive(Debug, Clone, Copy, Serialize, Deserialize)]
pub(super) struct RecordedFit {
    chamfer: f64,
    points_to_mesh: f64,
    mesh_to_points: f64,
    /// Against the data's points (else the true surface).
    data: bool,
    points: usize,
    samples: usize,
}

impl From<&MeshFit> for RecordedFit {
    fn from(f: &MeshFit) -> Self {
        RecordedFit {
            chamfer: f.chamfer,
            points_to_mesh: f.points_to_mesh,
            mesh_to_points: f.mesh_to_points,
            data: f.against == "data",
            points: f.points,
            samples: f.samples,
        }
    }
}

impl From<RecordedFit> for MeshFit {
    fn from(f: RecordedFit) -> Self {
        MeshFit {
            chamfer: f.chamfer,
            points_to_mesh: f.points_to_mesh,
            mesh_to_points: f.mesh_to_points,
            against: if f.data { "data" } else { "true surface" },
            points: f.points,
            samples: f.samples,
        }
    }
}

/// What an output of `job` depends on beyond the checkpoint: its
/// declaration (not where it is written in the file), whether it comes
/// before or after training, the views and their size, and how held-out
/// views are scored.
pub(super) fn output_key(
    job: &TrainJob,
    output: &Output,
    after: bool,
    cameras: &[Camera],
    size: (u32, u32),
) -> String {
    let mut h = crate::train::checkpoint::Fnv::default();
    h.str(&serde_json::to_string(output).unwrap_or_default())
        .str(if after { "after" } else { "before" })
        .str(&format!("{cameras:?}"))
        .str(&format!(
            "{size:?} {:?} {} {:?}",
            job.eval_views, job.eval_downscale, job.view_path
        ));
    h.finish()
}

/// What held-out scores depend on beyond the checkpoint: the views
/// scored (their cameras and sizes) and how (`eval_views`,
/// `eval_downscale`).
pub(super) fn held_out_key(job: &TrainJob, views: &[TrainView]) -> String {
    let mut h = crate::train::checkpoint::Fnv::default();
    for v in views {
        h.str(&format!(
            "{:?} {}x{}",
            v.camera, v.image.width, v.image.height
        ));
    }
    h.str(&format!("{:?} {}", job.eval_views, job.eval_downscale));
    h.finish()
}

impl OutputsRecord {
    /// The record under `out_dir` for `job`, if there is one made at
    /// `step` with `fingerprint`; an unreadable or other run's record is
    /// none (everything is rendered again).
    pub fn read(
        job: &TrainJob,
        out_dir: &Path,
        step: usize,
        fingerprint: &[String; 4],
    ) -> Option<OutputsRecord> {
        let path = out_dir.join(TrainingLogs::of(&job.name).outputs_record);
        let bytes = sdfl_stdlib::files::read_capped(&path, 1 << 24).ok()?;
        let record: OutputsRecord = serde_json::from_slice(&bytes).ok()?;
        (record.step == step && &record.fingerprint == fingerprint).then_some(record)
    }

    /// The files of the output with `key`, if it was written and every
    /// one of them is still there as it was.
    pub fn kept(&self, key: &str, out_dir: &Path) -> Option<Vec<Written>> {
        let o = self.outputs.iter().find(|o| o.key == key)?;
        let intact = o.written.iter().all(|(w, bytes)| {
            let meta = std::fs::symlink_metadata(out_dir.join(&w.path));
            match (meta, bytes) {
                (Ok(m), Some(b)) => m.is_file() && m.len() == *b,
                (Ok(m), None) => m.is_dir(),
                (Err(_), _) => false,
            }
        });
        (intact && !o.written.is_empty()).then(|| o.written.iter().map(|w| w.0.clone()).collect())
    }

    /// Writes the record for `job` under `out_dir`.
    pub fn write(&self, job: &TrainJob, out_dir: &Path) -> io::Result<()> {
        let path = out_dir.join(TrainingLogs::of(&job.name).outputs_record);
        let json = serde_json::to_vec_pretty(self).map_err(io::Error::other)?;
        crate::output::write_bytes(&path, &json)
    }
}

/// The files among `written` that `output` wrote: its path, its GIF
/// fallback, or one of its per-view names for `views` views.
pub(super) fn files_of(output: &Output, views: usize, written: &[Written]) -> Vec<Written> {
    let per_view = sdfl_stdlib::outputs::per_view(&output.kind);
    let fallback = output.fallback();
    written
        .iter()
        .filter(|w| {
            w.path == output.path
                || fallback.as_ref() == Some(&w.path)
                || (per_view
                    && (0..views)
                        .any(|k| sdfl_stdlib::outputs::view_path(&output.path, k, views) == w.path))
        })
        .cloned()
        .collect()
}

/// `written`'s entry with each file's length now (none for a directory).
pub(super) fn with_lengths(written: Vec<Written>, out_dir: &Path) -> Vec<(Written, Option<u64>)> {
    written
        .into_iter()
        .map(|w| {
            let len = std::fs::symlink_metadata(out_dir.join(&w.path))
                .ok()
                .filter(|m| m.is_file())
                .map(|m| m.len());
            (w, len)
        })
        .collect()
}

/// The scores a recorded evaluation measured.
pub(super) fn scores(h: &HeldOut) -> crate::train::log::Scores {
    crate::train::log::Scores {
        psnr: h.psnr,
        ssim: h.ssim,
        psnr_in_mask: h.psnr_in_mask,
        views: h.views,
    }
}

/// Which of a run's outputs are kept from its record, and the record of
/// what it writes.
pub(super) struct Kept<'a> {
    job: &'a TrainJob,
    out_dir: &'a Path,
    cameras: &'a [Camera],
    size: (u32, u32),
    record: Option<&'a OutputsRecord>,
    /// The outputs kept, with their files.
    kept: Vec<(Output, Vec<Written>)>,
}

impl<'a> Kept<'a> {
    /// Nothing kept yet from `record` (none: everything is rendered).
    pub fn new(
        job: &'a TrainJob,
        (cameras, size): (&'a [Camera], (u32, u32)),
        record: Option<&'a OutputsRecord>,
        out_dir: &'a Path,
    ) -> Self {
        Kept {
            job,
            out_dir,
            cameras,
            size,
            record,
            kept: Vec::new(),
        }
    }

    /// The outputs of `list` (the `after` list or the `before` one) that
    /// must be rendered; the others are kept.
    pub fn needing_render(&mut self, list: &[Output], after: bool) -> Vec<Output> {
        let mut render = Vec::new();
        for o in list {
            let key = output_key(self.job, o, after, self.cameras, self.size);
            match self.record.and_then(|r| r.kept(&key, self.out_dir)) {
                Some(files) => self.kept.push((o.clone(), files)),
                None => render.push(o.clone()),
            }
        }
        render
    }

    /// The recorded fit, where the mesh it measured (the first `after`
    /// mesh) is kept.
    pub fn mesh_fit(&self) -> Option<MeshFit> {
        let first = self
            .job
            .after
            .iter()
            .find(|o| matches!(o.kind, OutputKind::Mesh { .. }))?;
        self.kept.iter().find(|(o, _)| o == first)?;
        self.record?.mesh_fit.map(Into::into)
    }

    /// The recorded held-out scores at this step, where they are of
    /// `views` scored as now.
    pub fn held_out(&self, views: &[TrainView]) -> Option<HeldOut> {
        let r = self.record?;
        (r.held_out_key == held_out_key(self.job, views))
            .then_some(r.held_out)
            .flatten()
    }

    /// Steps ran after the record's: nothing more is kept from it (what
    /// was kept before training stays kept).
    pub fn forget_record(&mut self) {
        self.record = None;
    }

    /// The kept outputs' paths.
    pub fn paths(&self) -> Vec<PathBuf> {
        self.kept.iter().map(|(o, _)| o.path.clone()).collect()
    }

    /// The kept outputs' files.
    pub fn written(&self) -> Vec<Written> {
        self.kept.iter().flat_map(|(_, w)| w.clone()).collect()
    }

    /// Every output of the run with its key and its files among `written`.
    pub fn record(&self, written: &[Written]) -> Vec<RecordedOutput> {
        let before = self.job.before.iter().map(|o| (o, false));
        let after = self.job.after.iter().map(|o| (o, true));
        before
            .chain(after)
            .map(|(o, is_after)| RecordedOutput {
                key: output_key(self.job, o, is_after, self.cameras, self.size),
                written: with_lengths(files_of(o, self.cameras.len(), written), self.out_dir),
            })
            .collect()
    }
}
