//! Frames of a `train` statement's field at its latest checkpoint, from
//! any camera: the runtime builds the field and checks the checkpoint
//! ([`CheckpointedField`]); here it is kept between frames (by a thread
//! of its own, [`Fields`]), refreshed when
//! training writes a newer one, and its frames encoded as PNG.

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::{mpsc, Arc, Mutex, MutexGuard};

use glam::DVec3;
use sdfl_runtime::jobs::{CheckpointedField, FieldUnavailable};
use sdfl_runtime::train::checkpoint::Checkpoint;
use sdfl_runtime::train::frame::TrainingCamera;
use sdfl_stdlib::camera::Camera;
use sdfl_stdlib::value::TrainJob;

use super::frame::{png, FrameCamera};
use super::request::Refusal;

/// The side of a frame while the camera moves, in pixels: a NeRF of
/// `examples/nerf_fast.sdfl`'s size (hash grid, 192 samples, occupancy
/// grid; 300 steps trained) renders 64² in about 0.08 s on 2 cores under
/// a load of 6 (128²: 0.25 s, 384²: 2.2 s).
pub const MOVING_SIDE: u32 = 64;

/// The camera the page starts from: the statement's first output view;
/// else, where its checkpoint records the training cameras (`recorded`),
/// the first of them, turned about the middle of the field's region (the
/// point of its axis nearest it, so the page orbits the object, not a
/// point a unit ahead); else one looking at that middle from outside.
pub fn initial_camera(job: &TrainJob, recorded: &[TrainingCamera]) -> Camera {
    if job.view_path.is_none() {
        if let Some(c) = job.views.first() {
            return *c;
        }
    }
    let (lo, hi) = job.model.export_region().unwrap_or(([-1.0; 3], [1.0; 3]));
    let (lo, hi) = (DVec3::from_array(lo), DVec3::from_array(hi));
    let center = 0.5 * (lo + hi);
    let radius = (0.5 * (hi - lo).length()).max(1e-3);
    if let Some(c) = recorded.first() {
        let forward = (c.at - c.eye).normalize();
        let depth = (center - c.eye).dot(forward).max(1e-3 * radius);
        return Camera::look_at(c.eye, c.eye + depth * forward, c.up, c.focal);
    }
    let eye = center + radius * DVec3::new(0.8, 0.9, -2.2);
    Camera::look_at(eye, center, DVec3::Y, 1.5)
}

/// The training cameras `job`'s checkpoint under `out` records: none
/// where it has no checkpoint yet, or one outside `out`, or unreadable
/// (the field's frames say why).
pub fn training_cameras(job: &TrainJob, out: &Path) -> Vec<TrainingCamera> {
    sdfl_runtime::jobs::checkpoint_path(job, out)
        .and_then(|p| super::confined(out, &p).ok())
        .and_then(|p| Checkpoint::read_frame(&p).ok())
        .map(|f| f.cameras)
        .unwrap_or_default()
}

/// A refusal for a field that cannot be shown: nothing written yet is
/// 404, a checkpoint that is not the field's 409 (the file conflicts with
/// the statement as it is now).
fn refusal(e: FieldUnavailable) -> Refusal {
    match e {
        FieldUnavailable::NoCheckpoint(m) => Refusal::missing(m),
        FieldUnavailable::Refused(m) => Refusal {
            status: 409,
            message: m,
        },
    }
}

/// What the field thread is asked for: a frame of `job`'s field, for the
/// file as loaded at `version`.
struct Work {
    job: TrainJob,
    version: u64,
    camera: FrameCamera,
    reply: mpsc::Sender<Result<Vec<u8>, Refusal>>,
}

/// The fields shown, kept by one thread of their own: a trained field is
/// `Sync` but not `Send`, so it lives where it was built. Frames are
/// rendered there one at a time, under the viewer's tracing lock.
pub struct Fields {
    work: Mutex<mpsc::Sender<Work>>,
    /// The step each field was last read at, by statement name.
    steps: Arc<Mutex<HashMap<String, usize>>>,
}

impl Fields {
    /// Starts the thread, which reads checkpoints under `out` (and a NeRF
    /// in NDC's data relative to `base`) and renders while holding `tracing`.
    pub fn start(out: PathBuf, base: PathBuf, tracing: Arc<Mutex<()>>) -> Fields {
        let (work, todo) = mpsc::channel::<Work>();
        let steps = Arc::new(Mutex::new(HashMap::new()));
        let shown = steps.clone();
        std::thread::spawn(move || {
            let mut kept: HashMap<String, CheckpointedField> = HashMap::new();
            let mut version = 0;
            for w in todo {
                if w.version != version {
                    // The file changed: its statements may have.
                    kept.clear();
                    lock(&shown).clear();
                    version = w.version;
                }
                let _one_at_a_time = lock(&tracing);
                let frame = frame(&mut kept, &w, &out, &base);
                if let Some(f) = kept.get(&w.job.name) {
                    lock(&shown).insert(w.job.name.clone(), f.step());
                } else {
                    lock(&shown).remove(&w.job.name);
                }
                // A client gone meanwhile is not an error.
                let _ = w.reply.send(frame);
            }
        });
        Fields {
            work: Mutex::new(work),
            steps,
        }
    }

    /// A frame of `job`'s field from `camera` (the file loaded at `version`).
    pub fn frame(
        &self,
        job: &TrainJob,
        version: u64,
        camera: FrameCamera,
    ) -> Result<Vec<u8>, Refusal> {
        let (reply, answer) = mpsc::channel();
        let work = Work {
            job: job.clone(),
            version,
            camera,
            reply,
        };
        let gone = || Refusal {
            status: 500,
            message: "the field renderer stopped".into(),
        };
        lock(&self.work).send(work).map_err(|_| gone())?;
        answer.recv().map_err(|_| gone())?
    }

    /// The step each field on view was last read at.
    pub fn steps(&self) -> HashMap<String, usize> {
        lock(&self.steps).clone()
    }
}

fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

/// The frame `w` asks for: the field as kept if there is one and (for a
/// still frame) its checkpoint has not changed, else read again. A newer
/// checkpoint that is refused is not hidden behind an older one: the field
/// is dropped and the refusal said.
fn frame(
    kept: &mut HashMap<String, CheckpointedField>,
    w: &Work,
    out: &Path,
    base: &Path,
) -> Result<Vec<u8>, Refusal> {
    let name = &w.job.name;
    let newer = match kept.get(name) {
        Some(_) if w.camera.draft => Ok(None),
        Some(f) => f.refreshed(out).map_err(refusal),
        None => CheckpointedField::load(&w.job, out, base)
            .map(Some)
            .map_err(refusal),
    };
    match newer {
        Ok(Some(f)) => {
            kept.insert(name.clone(), f);
        }
        Ok(None) => {}
        Err(e) => {
            kept.remove(name);
            return Err(e);
        }
    }
    let field = kept
        .get(name)
        .ok_or_else(|| Refusal::missing(format!("`{name}` has no field")))?;
    render(field, w.camera)
}

/// The frame as PNG bytes.
fn render(field: &CheckpointedField, c: FrameCamera) -> Result<Vec<u8>, Refusal> {
    let cam = Camera::look_at(c.eye, c.at, c.up, c.focal);
    if !cam.is_valid() {
        return Err(Refusal::bad(
            "the camera is degenerate: `eye` equals `at`, or `up` is parallel to the view",
        ));
    }
    let rgb = field.render_rgb8(&cam, c.size).map_err(|e| Refusal {
        status: 500,
        message: e.to_string(),
    })?;
    png(c.size, &rgb)
}
