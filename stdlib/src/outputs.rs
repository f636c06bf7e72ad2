//! Which files a program writes, decided when the file is evaluated: every
//! output of every statement (one file per view where outputs are per
//! view) and checkpoints. Two writers of one file, or a file where another
//! output needs a directory, are diagnostics with both spans, before
//! anything runs. The runtime names files with the same [`view_path`] and
//! [`TrainingLogs`], so both sides agree on every name.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use sdfl_lang::diag::{codes, fmt_num, Diag};
use sdfl_lang::Span;

use crate::lens::{Distortion, Intrinsics};
use crate::value::{Output, OutputKind, Program, StatementKind};

/// Most files one scene file may write (all statements, all views).
pub const MAX_FILES: u64 = 100_000;
/// Longest file or directory name, and whole relative path, of an output
/// (the usual file system limits are 255 and 4096).
pub const MAX_NAME_BYTES: usize = 255;
/// Longest relative path of an output, in bytes.
pub const MAX_PATH_BYTES: usize = 1024;

/// The file name for view `k` of `n`: `{view}` is replaced by the padded
/// index; otherwise `_NN` is added before the extension when `n > 1`.
pub fn view_path(path: &Path, k: usize, n: usize) -> PathBuf {
    let digits = (n.max(2) - 1).to_string().len().max(2);
    let idx = format!("{k:0digits$}");
    let s = path.to_string_lossy();
    if s.contains("{view}") {
        return PathBuf::from(s.replace("{view}", &idx));
    }
    if n == 1 {
        return path.to_path_buf();
    }
    let stem = path
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default();
    let ext = path
        .extension()
        .map(|e| format!(".{}", e.to_string_lossy()))
        .unwrap_or_default();
    path.with_file_name(format!("{stem}_{idx}{ext}"))
}

/// The files of a `dataset` output in `dir` for `views` views: the
/// NeRF-synthetic layout, `r_<k>.png` per view and `transforms.json`.
pub fn dataset_files(dir: &Path, views: usize) -> Vec<PathBuf> {
    (0..views)
        .map(|k| dir.join(format!("r_{k}.png")))
        .chain(DATASET_JSON.iter().map(|f| dir.join(f)))
        .collect()
}

/// The JSON files of a `dataset` output: one per split (Blender form), then
/// the whole set (nerfstudio form), in the order they are finished.
pub const DATASET_JSON: [&str; 4] = [
    "transforms_train.json",
    "transforms_val.json",
    "transforms_test.json",
    "transforms.json",
];

/// Why these views, each numbered, through these intrinsics are not one
/// centred pinhole camera (`None`: they are). Layouts with one focal length
/// for the set and no principal point or distortion hold only such views:
/// LLFF's `poses_bounds.npy` and the Blender form's `camera_angle_x`.
pub fn not_one_pinhole(views: impl IntoIterator<Item = (usize, Intrinsics)>) -> Option<String> {
    let close = |x: f64, y: f64| (x - y).abs() <= 1e-9 * x.abs().max(y.abs()).max(1.0);
    let mut first: Option<(usize, Intrinsics)> = None;
    views.into_iter().find_map(|(k, i)| {
        let (w, h) = (i.width as f64, i.height as f64);
        let why = if i.distortion != Distortion::None {
            Some(format!("view {k} is seen through a distorted lens"))
        } else if !close(i.fx, i.fy) {
            Some(format!(
                "view {k} has two focal lengths ({} and {} pixels)",
                fmt_num(i.fx),
                fmt_num(i.fy)
            ))
        } else if !(close(i.cx, w / 2.0) && close(i.cy, h / 2.0)) {
            Some(format!(
                "view {k}'s principal point ({}, {}) is not the {}x{} image's centre",
                fmt_num(i.cx),
                fmt_num(i.cy),
                i.width,
                i.height
            ))
        } else {
            match first {
                Some((j, f))
                    if !(close(i.fx, f.fx) && (i.width, i.height) == (f.width, f.height)) =>
                {
                    Some(format!("view {k}'s camera differs from view {j}'s"))
                }
                _ => None,
            }
        };
        first.get_or_insert((k, i));
        why
    })
}

/// Why LLFF's layout (`dataset(..., llff_bounds: ...)`) cannot hold these
/// views (`None`: it can): see [`not_one_pinhole`]. Checked when the file
/// is evaluated and again by the writer, for views made at run time.
pub fn llff_refusal(views: impl IntoIterator<Item = (usize, Intrinsics)>) -> Option<String> {
    not_one_pinhole(views).map(|problem| llff_message(&problem))
}

/// Why LLFF's layout cannot hold views, given what they are.
fn llff_message(problem: &str) -> String {
    format!(
        "LLFF's `poses_bounds.npy` holds one centred pinhole camera (one focal length, no distortion) for every view, and {problem}"
    )
}

/// What a `dataset` of views that are not one centred pinhole camera
/// writes in place of the Blender form's `camera_angle_x`: nothing, so that
/// a Blender-format reader (which assumes a centred pinhole) stops at the
/// missing key rather than reading the views wrongly.
pub const BLENDER_LENS_HELP: &str = "nerfstudio's `nerfstudio-data` parser, instant-ngp and sdfl's `capture(...)` read the lens from the set's `fl_x fl_y cx cy` and distortion keys; for Blender-format readers, give every view one centred pinhole camera (`look_at(...)`, or `lens(...)` with one focal length, the principal point at the centre and no distortion)";

/// The data sets among `outputs`, with LLFF's layout (`llff`) or without,
/// whose views through `cameras` at `size` are not one centred pinhole
/// camera: `diag(set, why)` for each.
fn not_pinhole_sets<'a>(
    outputs: impl IntoIterator<Item = &'a Output>,
    cameras: &[crate::camera::Camera],
    (w, h): (u32, u32),
    llff: bool,
    diag: impl Fn(&Output, &str) -> Diag,
) -> Vec<Diag> {
    let sets: Vec<&Output> = outputs
        .into_iter()
        .filter(|o| {
            matches!(o.kind, OutputKind::Dataset { llff_bounds, .. } if llff_bounds.is_some() == llff)
        })
        .collect();
    if sets.is_empty() {
        return Vec::new();
    }
    let intrinsics = cameras
        .iter()
        .enumerate()
        .map(|(k, c)| (k, c.to_opengl_intrinsics(w, h).1));
    match not_one_pinhole(intrinsics) {
        Some(why) => sets.into_iter().map(|o| diag(o, &why)).collect(),
        None => Vec::new(),
    }
}

/// Warnings for the data sets among `outputs` whose views through
/// `cameras` at `size` the Blender form cannot state (LLFF sets, refused
/// by [`llff_errors`], excepted).
fn blender_warnings<'a>(
    outputs: impl IntoIterator<Item = &'a Output>,
    cameras: &[crate::camera::Camera],
    size: (u32, u32),
) -> Vec<Diag> {
    not_pinhole_sets(outputs, cameras, size, false, |o, why| {
        Diag::new(
            codes::BLENDER_LENS,
            o.span,
            format!("this data set's transforms files leave out the Blender form's `camera_angle_x`, which states one centred pinhole camera, because {why}"),
        )
        .label("Blender-format readers cannot read these views")
        .help(BLENDER_LENS_HELP)
    })
}

/// The `llff_bounds` data sets among `outputs` that views through
/// `cameras` at `size` cannot be written as.
fn llff_errors<'a>(
    outputs: impl IntoIterator<Item = &'a Output>,
    cameras: &[crate::camera::Camera],
    size: (u32, u32),
) -> Vec<Diag> {
    not_pinhole_sets(outputs, cameras, size, true, |o, why| {
        Diag::new(codes::VALUE, o.span, llff_message(why))
            .label("LLFF's layout needs one centred pinhole camera")
            .help("write this set without `llff_bounds` (its `transforms.json` keeps the lens), or give every view one pinhole camera: `look_at(...)`, or `lens(...)` with one focal length, the principal point at the centre and no distortion")
    })
}

/// The event file's name in a training run's TensorBoard directory: fixed,
/// so a resumed run continues the same file (TensorBoard reads every file
/// whose name holds `tfevents`).
pub const EVENTS_FILE: &str = "events.out.tfevents.sdfl";

/// The logs a `train` statement writes as it goes, relative to the output
/// directory: the one place that names them, for the runtime that writes
/// them and for [`check_job`], which keeps every other output off them.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct TrainingLogs {
    /// `<name>.metrics.csv`: a row per step, scores where evaluated.
    pub metrics_csv: PathBuf,
    /// `tensorboard/<name>`: the run's TensorBoard directory, kept to
    /// itself (TensorBoard reads every event file in it).
    pub tensorboard: PathBuf,
    /// `<name>.heldout.png`: the first held-out view beside its truth,
    /// replaced at each held-out evaluation.
    pub held_out_image: PathBuf,
    /// `<name>.outputs.json`: what each output was made from, so that a
    /// finished run run again writes only the outputs that changed.
    pub outputs_record: PathBuf,
}

impl TrainingLogs {
    /// The logs of training `name`.
    pub fn of(name: &str) -> TrainingLogs {
        TrainingLogs {
            metrics_csv: PathBuf::from(format!("{name}.metrics.csv")),
            tensorboard: Path::new("tensorboard").join(name),
            held_out_image: PathBuf::from(format!("{name}.heldout.png")),
            outputs_record: PathBuf::from(format!("{name}.outputs.json")),
        }
    }

    /// The event file in [`TrainingLogs::tensorboard`].
    pub fn events(&self) -> PathBuf {
        self.tensorboard.join(EVENTS_FILE)
    }
}

/// Whether an output kind is written once per view (else once per job).
pub fn per_view(kind: &OutputKind) -> bool {
    matches!(
        kind,
        OutputKind::Image
            | OutputKind::Depth
            | OutputKind::Normals
            | OutputKind::Mask
            | OutputKind::RawDepth { .. }
            | OutputKind::DepthMap { .. }
    )
}

/// Whether the runtime writes this output for a job of this kind at all
/// (evaluation refuses the others, so this only mirrors it).
fn written_by(kind: &OutputKind, job: JobKind) -> bool {
    match job {
        JobKind::Render => {
            !matches!(kind, OutputKind::SamplePoints)
                && !kind.training_only()
                && !kind.field_export()
        }
        JobKind::Volume | JobKind::TrainBefore => {
            !matches!(kind, OutputKind::Normals | OutputKind::Mask) && !kind.training_only()
        }
        JobKind::TrainAfter => !matches!(kind, OutputKind::Normals | OutputKind::Mask),
    }
}

#[derive(Clone, Copy, PartialEq)]
enum JobKind {
    Render,
    Volume,
    TrainBefore,
    TrainAfter,
}

/// Who writes a file or keeps a directory, in a diagnostic's words.
#[derive(Clone)]
struct Writer {
    span: Span,
    who: String,
    /// The training whose log this is, if it is one.
    log_of: Option<String>,
}

impl Writer {
    fn output(span: Span, who: String) -> Writer {
        Writer {
            span,
            who,
            log_of: None,
        }
    }
}

/// Files claimed so far, with who writes each, the directories they
/// need, and the directories one writer keeps to itself.
#[derive(Default)]
pub struct Files {
    files: HashMap<PathBuf, Writer>,
    dirs: HashMap<PathBuf, Writer>,
    kept: HashMap<PathBuf, Writer>,
}

/// The built-in that asks for an output of this kind.
pub fn kind_name(kind: &OutputKind) -> &'static str {
    match kind {
        OutputKind::Image => "image",
        OutputKind::Gif { .. } => "gif",
        OutputKind::Video { .. } => "video",
        OutputKind::DepthGif { .. } => "depth_gif",
        OutputKind::Depth => "depth",
        OutputKind::Normals => "normal_map",
        OutputKind::Mask => "mask",
        OutputKind::Grid => "grid",
        OutputKind::Rays => "rays",
        OutputKind::SamplePoints => "sample_points",
        OutputKind::LossCurve => "loss_curve",
        OutputKind::PsnrCurve => "psnr_curve",
        OutputKind::Comparison => "comparison",
        OutputKind::Dataset { .. } => "dataset",
        OutputKind::Mesh { .. } => "mesh",
        OutputKind::GeometryGif { .. } => "geometry_gif",
        OutputKind::DensityMesh { .. } => "density_mesh",
        OutputKind::PointCloud { .. } => "point_cloud",
        OutputKind::RawDepth { .. } => "raw_depth",
        OutputKind::DepthMap { .. } => "depth_map",
    }
}

fn describe(o: &Output, k: usize, n: usize) -> String {
    let what = kind_name(&o.kind);
    if per_view(&o.kind) && n > 1 {
        format!("`{what}` writes it (view {k} of {n})")
    } else {
        format!("`{what}` writes it")
    }
}

/// Two writers of one path: the diagnostic points at the user's output
/// (a training log is not what its author can rename), the other writer
/// in a note.
fn clash(path: &Path, what: &str, new: &Writer, first: &Writer) -> Diag {
    let (at, other) = if new.log_of.is_some() && first.log_of.is_none() {
        (first, new)
    } else {
        (new, first)
    };
    let note = match other.log_of {
        Some(_) => other.who.clone(),
        None => format!("{} first", other.who),
    };
    let help = match at.log_of.as_ref().or(other.log_of.as_ref()) {
        Some(name) => {
            let logs = TrainingLogs::of(name);
            format!(
                "`{}`, `{}`, `{}` and `{}/` are the logs of training `{name}`: give the output another name",
                logs.metrics_csv.display(),
                logs.held_out_image.display(),
                logs.outputs_record.display(),
                logs.tensorboard.display()
            )
        }
        None => {
            "give each output its own file name; outputs with several views add `_NN` to theirs"
                .to_string()
        }
    };
    Diag::new(
        codes::OUTPUT_COLLISION,
        at.span,
        format!("`{}` {what}", path.display()),
    )
    .label(at.who.clone())
    .note(other.span, note)
    .help(help)
}

const INSIDE_KEPT: &str = "is inside a directory that a training run keeps to itself";

impl Files {
    /// Claims the file `path` for `writer`; a diagnostic when it is taken.
    fn claim(&mut self, path: PathBuf, writer: Writer) -> Option<Diag> {
        if let Some(first) = self.files.get(&path) {
            return Some(clash(&path, "is written twice", &writer, first));
        }
        if let Some(first) = self.dirs.get(&path) {
            let what = "is a file here but a directory for another output";
            return Some(clash(&path, what, &writer, first));
        }
        for dir in path.ancestors().skip(1) {
            if dir.as_os_str().is_empty() {
                break;
            }
            if let Some(first) = self.files.get(dir) {
                let what = "needs a directory where another output writes a file";
                return Some(clash(&path, what, &writer, first));
            }
            if let Some(keeper) = self.kept.get(dir) {
                return Some(clash(&path, INSIDE_KEPT, &writer, keeper));
            }
        }
        self.need_dirs(&path, &writer);
        self.files.insert(path, writer);
        None
    }

    /// Keeps the directory `dir` (and all that will be in it) for
    /// `writer`; a diagnostic when a file is claimed in it or where it is.
    /// Kept even so, so that later outputs in it are found too.
    fn keep(&mut self, dir: PathBuf, writer: Writer) -> Option<Diag> {
        let clash = self.keep_clash(&dir, &writer);
        self.need_dirs(&dir.join(EVENTS_FILE), &writer);
        self.kept.insert(dir, writer);
        clash
    }

    fn keep_clash(&self, dir: &Path, writer: &Writer) -> Option<Diag> {
        if let Some(first) = self.files.get(dir) {
            let what = "is a file here but a directory for another output";
            return Some(clash(dir, what, writer, first));
        }
        // Outputs of earlier statements inside it (one walk per training).
        if let Some((path, first)) = self.files.iter().find(|(p, _)| p.starts_with(dir)) {
            return Some(clash(path, INSIDE_KEPT, writer, first));
        }
        dir.ancestors().skip(1).find_map(|up| {
            let first = self.files.get(up)?;
            let what = "needs a directory where another output writes a file";
            Some(clash(dir, what, writer, first))
        })
    }

    /// Notes the directories `path` needs.
    fn need_dirs(&mut self, path: &Path, writer: &Writer) {
        for dir in path.ancestors().skip(1) {
            if dir.as_os_str().is_empty() {
                break;
            }
            self.dirs
                .entry(dir.to_path_buf())
                .or_insert_with(|| writer.clone());
        }
    }
}

/// What training `name` logs to, claimed at `span` (its name).
fn log_claims(name: &str, span: Span) -> (Vec<(PathBuf, Writer)>, (PathBuf, Writer)) {
    let logs = TrainingLogs::of(name);
    let writer = |who: &str| Writer {
        span,
        who: format!("training `{name}` {who}"),
        log_of: Some(name.to_string()),
    };
    (
        vec![
            (logs.metrics_csv, writer("logs its metrics to it")),
            (logs.held_out_image, writer("shows its held-out view in it")),
            (logs.outputs_record, writer("records its outputs in it")),
        ],
        (
            logs.tensorboard,
            writer("keeps its TensorBoard events in it"),
        ),
    )
}

/// The files of `outputs` for `views` cameras, with who writes each.
fn output_files(outputs: &[Output], views: usize, job: JobKind) -> Vec<(PathBuf, Span, String)> {
    let mut out = Vec::new();
    for o in outputs.iter().filter(|o| written_by(&o.kind, job)) {
        if matches!(o.kind, OutputKind::Dataset { .. }) {
            for (k, path) in dataset_files(&o.path, views).into_iter().enumerate() {
                let who = if k < views {
                    describe(o, k, views)
                } else {
                    "`dataset` writes its transforms files".to_string()
                };
                out.push((path, o.span, who));
            }
        } else if per_view(&o.kind) {
            for k in 0..views {
                out.push((view_path(&o.path, k, views), o.span, describe(o, k, views)));
            }
        } else {
            out.push((o.path.clone(), o.span, describe(o, 0, 1)));
        }
        if let Some(gif) = o.fallback() {
            let who = "`video` writes its GIF fallback there (when no ffmpeg encodes the MP4)";
            out.push((gif, o.span, who.to_string()));
        }
    }
    out
}

fn file_count(outputs: &[Output], views: usize) -> u64 {
    outputs
        .iter()
        .map(|o| match o.kind {
            OutputKind::Dataset { llff_bounds, .. } => {
                let llff = llff_bounds.map_or(0, |_| views as u64 + 1);
                views as u64 + DATASET_JSON.len() as u64 + llff
            }
            _ if per_view(&o.kind) => views as u64,
            OutputKind::Video { .. } => 2,
            _ => 1,
        })
        .sum()
}

/// A `dataset` must keep a training view: its held-out views are fewer
/// than the statement's.
fn held_out_errors<'a>(outputs: impl IntoIterator<Item = &'a Output>, views: usize) -> Vec<Diag> {
    outputs
        .into_iter()
        .filter_map(|o| match o.kind {
            OutputKind::Dataset { test_views, .. } if test_views > 0 && test_views >= views => {
                Some(
                    Diag::new(
                        codes::VALUE,
                        o.span,
                        format!("`dataset` holds out {test_views} views of the statement's {views}, leaving none to train on"),
                    )
                    .label("no training view left")
                    .help(format!("hold out fewer than {views} views (`test_views`), or use more cameras")),
                )
            }
            _ => None,
        })
        .collect()
}

/// Checks the files of the job a statement just added to `program` (the
/// last one of its kind) against those
/// of earlier statements. `field` gives the span of a statement field,
/// `name` the span of the statement's name (where a training's logs,
/// named after it, are claimed).
pub fn check_job(
    program: &Program,
    kind: StatementKind,
    files: &mut Files,
    field: &dyn Fn(&str) -> Span,
    name: Span,
) -> Vec<Diag> {
    let mut claims = Vec::new();
    let mut logs = None;
    let count;
    let held;
    let llff;
    let lens;
    match kind {
        StatementKind::Train => {
            let Some(j) = program.trains.last() else {
                return Vec::new();
            };
            count = file_count(&j.before, j.views.len()) + file_count(&j.after, j.views.len());
            held = held_out_errors(j.before.iter().chain(&j.after), j.views.len());
            // Views made from the data at run time are the writer's to check.
            (llff, lens) = match j.view_path {
                None => {
                    let outputs = || j.before.iter().chain(&j.after);
                    (
                        llff_errors(outputs(), &j.views, (j.width, j.height)),
                        blender_warnings(outputs(), &j.views, (j.width, j.height)),
                    )
                }
                Some(_) => (Vec::new(), Vec::new()),
            };
            if count <= MAX_FILES {
                claims = output_files(&j.before, j.views.len(), JobKind::TrainBefore);
                claims.extend(output_files(&j.after, j.views.len(), JobKind::TrainAfter));
                if let Some(c) = &j.checkpoint {
                    claims.push((
                        c.clone(),
                        field("checkpoint"),
                        "the checkpoint is kept in it".to_string(),
                    ));
                }
                logs = Some(log_claims(&j.name, name));
            }
        }
        StatementKind::Volume => {
            let Some(j) = program.volumes.last() else {
                return Vec::new();
            };
            count = file_count(&j.outputs, j.cameras.len());
            held = held_out_errors(&j.outputs, j.cameras.len());
            llff = llff_errors(&j.outputs, &j.cameras, (j.width, j.height));
            lens = blender_warnings(&j.outputs, &j.cameras, (j.width, j.height));
            if count <= MAX_FILES {
                claims = output_files(&j.outputs, j.cameras.len(), JobKind::Volume);
            }
        }
        StatementKind::Render => {
            let Some(j) = program.renders.last() else {
                return Vec::new();
            };
            count = file_count(&j.outputs, j.cameras.len());
            held = held_out_errors(&j.outputs, j.cameras.len());
            llff = llff_errors(&j.outputs, &j.cameras, (j.width, j.height));
            lens = blender_warnings(&j.outputs, &j.cameras, (j.width, j.height));
            if count <= MAX_FILES {
                claims = output_files(&j.outputs, j.cameras.len(), JobKind::Render);
            }
        }
    }
    let total = count + files.files.len() as u64;
    if total > MAX_FILES {
        let span = if kind == StatementKind::Train {
            field("after")
        } else {
            field("outputs")
        };
        return vec![Diag::new(
            codes::TOO_LARGE,
            span,
            format!("the file would write {total} files (at most {MAX_FILES})"),
        )
        .label("one file per output and view")
        .help("use fewer views, or a `gif(...)` output, which holds every view in one file")];
    }
    if !held.is_empty() || !llff.is_empty() {
        return held.into_iter().chain(llff).collect();
    }
    // Names the file system refuses fail here, not after rendering.
    let log_paths = logs.iter().flat_map(|(files, (dir, w))| {
        let events = (dir.join(EVENTS_FILE), w.span);
        files
            .iter()
            .map(|(p, w)| (p.clone(), w.span))
            .chain([events])
    });
    let paths = claims.iter().map(|(p, span, _)| (p.clone(), *span));
    if let Some((path, span)) = paths.chain(log_paths).find(|(p, _)| {
        p.as_os_str().len() > MAX_PATH_BYTES
            || p.components().any(|c| c.as_os_str().len() > MAX_NAME_BYTES)
    }) {
        return vec![Diag::new(
            codes::PATH,
            span,
            format!(
                "output path of {} bytes is too long",
                path.as_os_str().len()
            ),
        )
        .label("too long a name")
        .help(format!(
            "keep each name within {MAX_NAME_BYTES} bytes and the whole path within {MAX_PATH_BYTES}"
        ))];
    }
    // One diagnostic per pair of clashing outputs, not one per view.
    let mut seen = std::collections::HashSet::new();
    let mut found: Vec<Diag> = claims
        .into_iter()
        .filter_map(|(path, span, who)| files.claim(path, Writer::output(span, who)))
        .collect();
    if let Some((log_files, (dir, keeper))) = logs {
        found.extend(
            log_files
                .into_iter()
                .filter_map(|(path, w)| files.claim(path, w)),
        );
        found.extend(files.keep(dir, keeper));
    }
    found
        .into_iter()
        .filter(|d| seen.insert((d.span, d.notes.first().map(|n| n.0))))
        .take(10)
        .chain(lens)
        .collect()
}

/// The directories, relative to the output directory, that the program's
/// outputs and checkpoints go to (a data set's own directory included),
/// each once: what the CLI checks can be written before any work.
pub fn output_dirs(program: &Program) -> Vec<PathBuf> {
    let mut dirs: Vec<PathBuf> = Vec::new();
    let mut seen = std::collections::HashSet::new();
    let mut add = |dir: PathBuf| {
        if seen.insert(dir.clone()) {
            dirs.push(dir);
        }
    };
    let parent = |p: &Path| p.parent().map(Path::to_path_buf).unwrap_or_default();
    let outputs = program
        .renders
        .iter()
        .flat_map(|j| &j.outputs)
        .chain(program.volumes.iter().flat_map(|j| &j.outputs))
        .chain(
            program
                .trains
                .iter()
                .flat_map(|j| j.before.iter().chain(&j.after)),
        );
    for o in outputs {
        add(if matches!(o.kind, OutputKind::Dataset { .. }) {
            o.path.clone()
        } else {
            parent(&o.path)
        });
    }
    for c in program.trains.iter().filter_map(|j| j.checkpoint.as_ref()) {
        add(parent(c));
    }
    dirs
}
