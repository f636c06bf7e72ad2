//! Writing data sets that sdfl renders (the `dataset(...)` output), in a
//! layout that nerfstudio's `blender-data` and `nerfstudio-data` parsers,
//! instant-ngp and sdfl's own `nerf_synthetic(...)` read unchanged:
//!
//! * `r_<k>.png`: view `k`, RGBA (alpha = the hit mask, or opaque).
//! * `transforms_train.json`, `transforms_val.json`, `transforms_test.json`
//!   (Blender form): `camera_angle_x`, and frames whose `file_path` is
//!   `./r_<k>` *without* extension (the Blender parser appends `.png`;
//!   instant-ngp and sdfl try the path, then with an image extension).
//! * `transforms.json` (nerfstudio form): every frame with `file_path`
//!   `r_<k>.png` *with* extension (the nerfstudio parser opens it as
//!   given), `camera_model`, `train_filenames` / `val_filenames` /
//!   `test_filenames`.
//!
//! Every file states the intrinsics as `fl_x fl_y cx cy w h` with the
//! distortion (`k1 k2 p1 p2`, or `k1..k4` and `is_fisheye` for a fisheye),
//! at the top when every view shares them, else per frame; and, when the
//! views are one centred pinhole camera, also as the Blender form's
//! `camera_angle_x`. For other views that key is left out: a Blender-format
//! reader assumes a centred pinhole, and stops at the missing key instead
//! of reading such views wrongly (`check` warns). Poses are OpenGL
//! camera-to-world matrices (`transform_matrix`: the camera looks down −z,
//! +y up, +x right), pixel centres at `i + ½` (OpenCV's `cx`).
//!
//! instant-ngp is pointed at `transforms.json` (every view) or
//! `transforms_train.json`: given the directory it loads every JSON file
//! in it, so each view would count four times, held-out ones included.
//!
//! The `val` and `test` splits are the held-out views (the same views in
//! both: nerfstudio evaluates on `val`, NeRF-synthetic codes on `test`);
//! with none held out they list every view, so every parser finds them.

use std::io;
use std::path::{Path, PathBuf};

use sdfl_lang::codes;
use sdfl_stdlib::camera::Camera;
use sdfl_stdlib::lens::{Distortion, Intrinsics};
use sdfl_stdlib::outputs::{llff_refusal, not_one_pinhole, BLENDER_LENS_HELP, DATASET_JSON};
use sdfl_stdlib::value::held_out;
use serde_json::{json, Map, Value};

use crate::output::{with_path, write_bytes, write_png, write_png_rgba};
use crate::output::{Written, WrittenKind, WrittenWarning};

/// The key of the transforms files a [`DatasetWriter`] leaves while it
/// moves a finished set into place over an earlier one.
pub const INCOMPLETE: &str = "sdfl_incomplete";

/// The folder, inside the set's directory, where a [`DatasetWriter`] writes
/// the new set until it is complete: an earlier set there stays whole and
/// loadable until then. What a stopped run left in it is removed by the
/// next writer of the set.
pub const STAGING: &str = ".sdfl-partial";

/// The distortion keys and values of `d`. Only the model's own keys:
/// instant-ngp reads `p1`, `p2` into the slots of `k3`, `k4`, so a fisheye
/// file holding `p1` would lose its `k3`.
fn distortion_keys(d: &Distortion) -> Vec<(&'static str, Value)> {
    match *d {
        Distortion::None => Vec::new(),
        Distortion::OpenCv { k1, k2, p1, p2 } => vec![
            ("k1", k1.into()),
            ("k2", k2.into()),
            ("p1", p1.into()),
            ("p2", p2.into()),
        ],
        Distortion::Fisheye { k1, k2, k3, k4 } => vec![
            ("k1", k1.into()),
            ("k2", k2.into()),
            ("k3", k3.into()),
            ("k4", k4.into()),
            // instant-ngp's switch to its fisheye model (nerfstudio
            // takes `camera_model`).
            ("is_fisheye", true.into()),
        ],
    }
}

fn is_fisheye(i: &Intrinsics) -> bool {
    matches!(i.distortion, Distortion::Fisheye { .. })
}

/// `fl_x fl_y cx cy w h` and the distortion, as JSON keys.
fn intrinsic_keys(i: &Intrinsics) -> Vec<(&'static str, Value)> {
    let mut v: Vec<(&'static str, Value)> = vec![
        ("fl_x", i.fx.into()),
        ("fl_y", i.fy.into()),
        ("cx", i.cx.into()),
        ("cy", i.cy.into()),
        ("w", i.width.into()),
        ("h", i.height.into()),
    ];
    v.extend(distortion_keys(&i.distortion));
    v
}

/// The horizontal field of view of a centred pinhole with `i`'s `fx`.
fn camera_angle_x(i: &Intrinsics) -> f64 {
    2.0 * (i.width as f64 / 2.0 / i.fx).atan()
}

/// Equal up to rounding (views of one camera model computed apart).
fn same(a: &Intrinsics, b: &Intrinsics) -> bool {
    let close = |x: f64, y: f64| (x - y).abs() <= 1e-9 * x.abs().max(y.abs()).max(1.0);
    let all = |x: [f64; 4], y: [f64; 4]| x.iter().zip(&y).all(|(p, q)| close(*p, *q));
    let lens = match (a.distortion, b.distortion) {
        (Distortion::None, Distortion::None) => true,
        (
            Distortion::OpenCv { k1, k2, p1, p2 },
            Distortion::OpenCv {
                k1: q,
                k2: r,
                p1: s,
                p2: t,
            },
        ) => all([k1, k2, p1, p2], [q, r, s, t]),
        (
            Distortion::Fisheye { k1, k2, k3, k4 },
            Distortion::Fisheye {
                k1: q,
                k2: r,
                k3: s,
                k4: t,
            },
        ) => all([k1, k2, k3, k4], [q, r, s, t]),
        _ => false,
    };
    lens && (a.width, a.height) == (b.width, b.height)
        && all([a.fx, a.fy, a.cx, a.cy], [b.fx, b.fy, b.cx, b.cy])
}

struct FrameRecord {
    k: usize,
    c2w: [[f64; 4]; 4],
    intrinsics: Intrinsics,
}

/// Writes a data set: `r_<k>.png` per view as it is pushed, and on
/// [`DatasetWriter::finish`] the transforms files, each atomically, all into
/// [`STAGING`]; only a complete set is moved into place (every refusal
/// comes before), so a refused, failed or stopped rewrite leaves an
/// earlier set as it was. While the files move, the transforms files mark
/// the set incomplete (a run stopped then leaves no silent mix of two).
/// Dropped unfinished, the staged files are removed.
pub struct DatasetWriter {
    /// Relative to the output directory.
    dir: PathBuf,
    out_dir: PathBuf,
    frames: Vec<FrameRecord>,
    size: (u32, u32),
    /// Per view, whether it is held out.
    held: Vec<bool>,
    /// Whether images keep an alpha channel (the hit mask); without, they
    /// are RGB, as photographs are.
    alpha: bool,
    /// LLFF's layout too, with these depth bounds for every frame.
    llff_bounds: Option<[f64; 2]>,
    /// Whether [`STAGING`] holds this writer's files.
    staged: bool,
}

impl DatasetWriter {
    /// A writer of `views` views of `w × h`, `test_views` of them held out
    /// by the seeded shuffle `render_views` uses.
    pub fn new(
        out_dir: &Path,
        dir: &Path,
        (w, h): (u32, u32),
        views: usize,
        test_views: usize,
        seed: u64,
    ) -> Self {
        let mut held = vec![false; views];
        for k in held_out(views, test_views, seed) {
            held[k] = true;
        }
        DatasetWriter {
            dir: dir.to_path_buf(),
            out_dir: out_dir.to_path_buf(),
            frames: Vec::new(),
            size: (w, h),
            held,
            alpha: true,
            llff_bounds: None,
            staged: false,
        }
    }

    /// Also LLFF's layout: `images/<kkkk>.png` in view order and
    /// `poses_bounds.npy`, every frame with depth bounds `[near, far]`.
    pub fn with_llff(mut self, bounds: [f64; 2]) -> Self {
        self.llff_bounds = Some(bounds);
        self
    }

    /// Images without alpha (RGB PNGs), as a camera records them.
    pub fn without_alpha(mut self) -> Self {
        self.alpha = false;
        self
    }

    /// The writer of a `dataset(...)` output (`None` for other outputs).
    pub fn for_output(
        out_dir: &Path,
        o: &sdfl_stdlib::value::Output,
        size: (u32, u32),
        views: usize,
    ) -> Option<Self> {
        match o.kind {
            sdfl_stdlib::value::OutputKind::Dataset {
                test_views,
                seed,
                alpha,
                llff_bounds,
            } => {
                let w = Self::new(out_dir, &o.path, size, views, test_views, seed);
                let w = if alpha { w } else { w.without_alpha() };
                Some(match llff_bounds {
                    Some(b) => w.with_llff(b),
                    None => w,
                })
            }
            _ => None,
        }
    }

    /// Writes view `k` of an sdfl camera: `rgb` (8-bit) and `alpha` (one
    /// byte a pixel; `None` is opaque).
    pub fn push(
        &mut self,
        k: usize,
        camera: &Camera,
        rgb: &[u8],
        alpha: Option<&[u8]>,
    ) -> io::Result<Written> {
        let (c2w, intrinsics) = camera.to_opengl_intrinsics(self.size.0, self.size.1);
        self.push_view(k, c2w, intrinsics, rgb, alpha)
    }

    /// Writes view `k` with an OpenGL camera-to-world pose and pixel
    /// intrinsics (for the image size the writer was made with).
    pub fn push_view(
        &mut self,
        k: usize,
        c2w: [[f64; 4]; 4],
        intrinsics: Intrinsics,
        rgb: &[u8],
        alpha: Option<&[u8]>,
    ) -> io::Result<Written> {
        let (w, h) = self.size;
        let bad = |m: String| io::Error::new(io::ErrorKind::InvalidInput, m);
        if (intrinsics.width, intrinsics.height) != (w, h) {
            return Err(bad(format!(
                "{}: view {k}'s intrinsics are for {}x{} images, the data set's are {w}x{h}",
                self.dir.display(),
                intrinsics.width,
                intrinsics.height
            )));
        }
        if self.frames.iter().any(|f| f.k == k) {
            return Err(bad(format!(
                "{}: view {k} written twice",
                self.dir.display()
            )));
        }
        if let Some(f) = self.frames.first() {
            if is_fisheye(&f.intrinsics) != is_fisheye(&intrinsics) {
                return Err(bad(format!(
                    "{}: view {k} mixes a fisheye and a perspective lens, and a data set has one `camera_model`",
                    self.dir.display()
                )));
            }
        }
        // Refused at the first view that LLFF cannot hold, not after all.
        if self.llff_bounds.is_some() {
            let seen = self.frames.first().map(|f| (f.k, f.intrinsics));
            if let Some(why) = llff_refusal(seen.into_iter().chain([(k, intrinsics)])) {
                return Err(bad(format!(
                    "{}: {why}: write this set without `llff_bounds`",
                    self.dir.display()
                )));
            }
        }
        let rgba: Vec<u8> = rgb
            .chunks_exact(3)
            .enumerate()
            .flat_map(|(i, c)| [c[0], c[1], c[2], alpha.map_or(255, |a| a[i])])
            .collect();
        self.stage()?;
        let staging = self.staging();
        for path in self.view_files(k) {
            let path = staging.join(path);
            if self.alpha {
                write_png_rgba(&path, w, h, &rgba)?;
            } else {
                write_png(&path, w, h, rgb)?;
            }
        }
        self.frames.push(FrameRecord { k, c2w, intrinsics });
        Ok(Written {
            path: self.dir.join(format!("r_{k}.png")),
            kind: WrittenKind::Dataset,
            width: w,
            height: h,
            frames: 1,
            mesh: None,
            warning: None,
        })
    }

    /// The set's directory under the output directory.
    fn set_dir(&self) -> PathBuf {
        self.out_dir.join(&self.dir)
    }

    /// Where the new set is written until it is complete.
    fn staging(&self) -> PathBuf {
        self.set_dir().join(STAGING)
    }

    /// View `k`'s images, relative to the set: `r_<k>.png`, and for LLFF
    /// `images/<kkkk>.png` (LLFF pairs `poses_bounds.npy`'s rows with
    /// `images/` sorted by name: zero-padded numbers sort in view order).
    fn view_files(&self, k: usize) -> Vec<PathBuf> {
        let mut files = vec![PathBuf::from(format!("r_{k}.png"))];
        if self.llff_bounds.is_some() {
            files.push(PathBuf::from(format!("images/{k:04}.png")));
        }
        files
    }

    /// Before this writer's first file: an empty staging folder, after
    /// what a stopped run left there. The way to it is checked first
    /// (no links), so nothing outside the set is ever removed.
    fn stage(&mut self) -> io::Result<()> {
        if self.staged {
            return Ok(());
        }
        crate::output::ensure_dir(&self.set_dir())?;
        let staging = self.staging();
        match std::fs::remove_dir_all(&staging) {
            Err(e) if e.kind() != io::ErrorKind::NotFound => {
                // A file or link there: removed as such (links not followed).
                std::fs::remove_file(&staging).map_err(|_| with_path(&staging, e))?;
            }
            _ => {}
        }
        self.staged = true;
        Ok(())
    }

    /// The four transforms files' names and contents, in the order they
    /// are written.
    pub fn documents(&self) -> Vec<(&'static str, Value)> {
        let mut frames: Vec<&FrameRecord> = self.frames.iter().collect();
        frames.sort_by_key(|f| f.k);
        let first = frames.first().map(|f| f.intrinsics);
        let shared = first.filter(|i| frames.iter().all(|f| same(&f.intrinsics, i)));
        let held = |k: usize| self.held.get(k).copied().unwrap_or(false);
        let any_held = frames.iter().any(|f| held(f.k));
        // nerfstudio's `camera_model` is one for the set: OPENCV as soon as
        // one view is distorted (pinhole views then have zeros).
        let model = if frames.iter().any(|f| is_fisheye(&f.intrinsics)) {
            "OPENCV_FISHEYE"
        } else if frames
            .iter()
            .any(|f| f.intrinsics.distortion != Distortion::None)
        {
            "OPENCV"
        } else {
            "PINHOLE"
        };
        let widen = |i: Intrinsics| match (model, i.distortion) {
            ("OPENCV", Distortion::None) => Intrinsics {
                distortion: Distortion::OpenCv {
                    k1: 0.0,
                    k2: 0.0,
                    p1: 0.0,
                    p2: 0.0,
                },
                ..i
            },
            _ => i,
        };
        let blender_holds = not_one_pinhole(frames.iter().map(|f| (f.k, f.intrinsics))).is_none();
        let top = || {
            let mut m = Map::new();
            m.insert("camera_model".into(), model.into());
            // The field of view the Blender form states is that of one
            // centred pinhole camera: for other views it is left out, so a
            // Blender-format reader stops at the missing key instead of
            // reading the views wrongly (the lens keys below hold them).
            if blender_holds {
                let angle = first.map_or(std::f64::consts::FRAC_PI_2, |i| camera_angle_x(&i));
                m.insert("camera_angle_x".into(), angle.into());
            }
            if let Some(i) = shared {
                m.extend(
                    intrinsic_keys(&widen(i))
                        .into_iter()
                        .map(|(k, v)| (k.to_string(), v)),
                );
            }
            m
        };
        let frame = |f: &FrameRecord, with_extension: bool| {
            let mut m = Map::new();
            let path = if with_extension {
                format!("r_{}.png", f.k)
            } else {
                format!("./r_{}", f.k)
            };
            m.insert("file_path".into(), path.into());
            m.insert("transform_matrix".into(), json!(f.c2w));
            if shared.is_none() {
                m.extend(
                    intrinsic_keys(&widen(f.intrinsics))
                        .into_iter()
                        .map(|(k, v)| (k.to_string(), v)),
                );
            }
            Value::Object(m)
        };
        let in_split = |split: &str, f: &FrameRecord| match split {
            "train" => !held(f.k),
            _ => !any_held || held(f.k),
        };
        let mut docs = Vec::new();
        for (name, split) in DATASET_JSON.iter().zip(["train", "val", "test"]) {
            let mut m = top();
            m.insert(
                "frames".into(),
                frames
                    .iter()
                    .filter(|f| in_split(split, f))
                    .map(|f| frame(f, false))
                    .collect(),
            );
            docs.push((*name, Value::Object(m)));
        }
        let mut m = top();
        m.insert(
            "frames".into(),
            frames.iter().map(|f| frame(f, true)).collect(),
        );
        for split in ["train", "val", "test"] {
            m.insert(
                format!("{split}_filenames"),
                frames
                    .iter()
                    .filter(|f| in_split(split, f))
                    .map(|f| Value::from(format!("r_{}.png", f.k)))
                    .collect(),
            );
        }
        docs.push((DATASET_JSON[3], Value::Object(m)));
        docs
    }

    /// Writes the transforms files for the views pushed, then moves the
    /// complete set into place: the images, `poses_bounds.npy`, the splits,
    /// `transforms.json` last. Everything that can refuse the set does so
    /// before the first move.
    pub fn finish(mut self) -> io::Result<Written> {
        let (w, h) = self.size;
        // LLFF's refusal says as much, and more.
        let blender_gap = match self.llff_bounds {
            None => not_one_pinhole(self.frames.iter().map(|f| (f.k, f.intrinsics))),
            Some(_) => None,
        };
        let poses_bounds = match self.llff_bounds {
            Some(bounds) => Some(self.poses_bounds(bounds)?),
            None => None,
        };
        let docs = self
            .documents()
            .into_iter()
            .map(|(name, doc)| {
                Ok((
                    name,
                    serde_json::to_string_pretty(&doc).map_err(io::Error::other)?,
                ))
            })
            .collect::<io::Result<Vec<_>>>()?;
        self.stage()?;
        let staging = self.staging();
        let mut moves: Vec<PathBuf> = self
            .frames
            .iter()
            .flat_map(|f| self.view_files(f.k))
            .collect();
        if let Some(bytes) = &poses_bounds {
            write_bytes(&staging.join("poses_bounds.npy"), bytes)?;
            moves.push("poses_bounds.npy".into());
        }
        for (name, text) in &docs {
            write_bytes(&staging.join(name), text.as_bytes())?;
            moves.push(name.into());
        }
        // An earlier set's transforms files say it is being replaced until
        // the last move: a stop in between leaves a set that refuses to
        // load in every reader (nerfstudio finds no `frames`; instant-ngp
        // skips a file without them), not a silent mix of two runs.
        let set = self.set_dir();
        let marker = format!("{{\"{INCOMPLETE}\": true}}\n");
        for name in DATASET_JSON {
            if std::fs::symlink_metadata(set.join(name)).is_ok() {
                write_bytes(&set.join(name), marker.as_bytes())?;
            }
        }
        if self.llff_bounds.is_some() {
            crate::output::ensure_dir(&set.join("images"))?;
        }
        for rel in &moves {
            let to = set.join(rel);
            std::fs::rename(staging.join(rel), &to).map_err(|e| with_path(&to, e))?;
        }
        self.staged = false;
        // Only emptied folders are left; a failure to remove them is no
        // failure of the set.
        let _ = std::fs::remove_dir_all(&staging);
        Ok(Written {
            path: self.dir.join(DATASET_JSON[3]),
            kind: WrittenKind::Dataset,
            width: w,
            height: h,
            frames: 0,
            mesh: None,
            warning: blender_gap.map(|why| WrittenWarning {
                code: codes::BLENDER_LENS.to_string(),
                message: format!(
                    "{}: the transforms files leave out the Blender form's `camera_angle_x`, which states one centred pinhole camera, because {why}; {BLENDER_LENS_HELP}",
                    self.dir.display()
                ),
            }),
        })
    }
}

impl Drop for DatasetWriter {
    fn drop(&mut self) {
        // Unfinished (refused, or its job failed): the new set goes, an
        // earlier one stays as it was.
        if self.staged {
            let _ = std::fs::remove_dir_all(self.staging());
        }
    }
}

impl DatasetWriter {
    /// `poses_bounds.npy`: per view in order, the OpenGL pose's rotation
    /// columns in LLFF's axes (down, right, back), its position and the
    /// height, width and focal length, row by row as a 3 × 5 matrix, then
    /// the depth bounds. LLFF holds one centred pinhole for every view.
    fn poses_bounds(&self, [near, far]: [f64; 2]) -> io::Result<Vec<u8>> {
        let mut frames: Vec<&FrameRecord> = self.frames.iter().collect();
        frames.sort_by_key(|f| f.k);
        let Some(i) = frames.first().map(|f| f.intrinsics) else {
            return Err(io::Error::new(
                io::ErrorKind::InvalidInput,
                format!(
                    "{}: LLFF's layout needs at least one view",
                    self.dir.display()
                ),
            ));
        };
        let (w, h) = (i.width as f64, i.height as f64);
        if let Some(why) = llff_refusal(frames.iter().map(|f| (f.k, f.intrinsics))) {
            return Err(io::Error::new(
                io::ErrorKind::InvalidInput,
                format!(
                    "{}: {why}: write this set without `llff_bounds`",
                    self.dir.display()
                ),
            ));
        }
        let mut rows = Vec::with_capacity(frames.len() * 17);
        for f in &frames {
            let m = &f.c2w;
            let hwf = [h, w, i.fx];
            for (r, row) in m.iter().take(3).enumerate() {
                let (right, up, back, t) = (row[0], row[1], row[2], row[3]);
                rows.extend([-up, right, back, t, hwf[r]]);
            }
            rows.extend([near, far]);
        }
        Ok(crate::data::npy::encode_f64(&[frames.len(), 17], &rows))
    }
}
