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
//! Every file states the intrinsics in both spellings: `camera_angle_x`
//! (Blender, sdfl) and `fl_x fl_y cx cy w h` with the distortion
//! (`k1 k2 p1 p2`, or `k1..k4` and `is_fisheye` for a fisheye), at the top
//! when every view shares them, else per frame. Poses are OpenGL
//! camera-to-world matrices (`transform_matrix`: the camera looks down −z,
//! +y up, +x right), pixel centres at `i + ½` (OpenCV's `cx`).
//!
//! The `val` and `test` splits are the held-out views (the same views in
//! both: nerfstudio evaluates on `val`, NeRF-synthetic codes on `test`);
//! with none held out they list every view, so every parser finds them.

use std::io;
use std::path::{Path, PathBuf};

use sdfl_stdlib::camera::Camera;
use sdfl_stdlib::outputs::DATASET_JSON;
use sdfl_stdlib::value::held_out;
use serde_json::{json, Map, Value};

use crate::output::{write_bytes, write_png_rgba};
use crate::render::Written;

/// The key of the transforms files a [`DatasetWriter`] leaves while it
/// writes.
pub(crate) const INCOMPLETE: &str = "sdfl_incomplete";

/// Lens distortion as the files state it (OpenCV's models, as COLMAP and
/// nerfstudio name them).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Lens {
    /// No distortion: `camera_model` `PINHOLE`.
    Pinhole,
    /// `OPENCV`: radial `k1 k2`, tangential `p1 p2`.
    OpenCv { k1: f64, k2: f64, p1: f64, p2: f64 },
    /// `OPENCV_FISHEYE`: equidistant with `k1..k4`.
    Fisheye { k1: f64, k2: f64, k3: f64, k4: f64 },
}

impl Lens {
    fn is_fisheye(&self) -> bool {
        matches!(self, Lens::Fisheye { .. })
    }

    /// The distortion keys and values. Only the model's own keys: instant-ngp
    /// reads `p1`, `p2` into the slots of `k3`, `k4`, so a fisheye file
    /// holding `p1` would lose its `k3`.
    fn keys(&self) -> Vec<(&'static str, Value)> {
        match *self {
            Lens::Pinhole => Vec::new(),
            Lens::OpenCv { k1, k2, p1, p2 } => {
                vec![
                    ("k1", k1.into()),
                    ("k2", k2.into()),
                    ("p1", p1.into()),
                    ("p2", p2.into()),
                ]
            }
            Lens::Fisheye { k1, k2, k3, k4 } => vec![
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
}

/// One view's pixel intrinsics (OpenCV convention: pixel `(i, j)` has its
/// centre at `(i + ½, j + ½)`, x right, y down).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ViewIntrinsics {
    pub w: u32,
    pub h: u32,
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
    pub lens: Lens,
}

impl ViewIntrinsics {
    /// The horizontal field of view of a centred pinhole with this `fx`.
    pub fn camera_angle_x(&self) -> f64 {
        2.0 * (self.w as f64 / 2.0 / self.fx).atan()
    }

    /// `fl_x fl_y cx cy w h` and the distortion, as JSON keys.
    fn keys(&self) -> Vec<(&'static str, Value)> {
        let mut v: Vec<(&'static str, Value)> = vec![
            ("fl_x", self.fx.into()),
            ("fl_y", self.fy.into()),
            ("cx", self.cx.into()),
            ("cy", self.cy.into()),
            ("w", self.w.into()),
            ("h", self.h.into()),
        ];
        v.extend(self.lens.keys());
        v
    }

    /// Equal up to rounding (views of one camera model computed apart).
    fn same(&self, o: &ViewIntrinsics) -> bool {
        let close = |a: f64, b: f64| (a - b).abs() <= 1e-9 * a.abs().max(b.abs()).max(1.0);
        let lens = match (self.lens, o.lens) {
            (Lens::Pinhole, Lens::Pinhole) => true,
            (
                Lens::OpenCv { k1, k2, p1, p2 },
                Lens::OpenCv {
                    k1: a,
                    k2: b,
                    p1: c,
                    p2: d,
                },
            ) => close(k1, a) && close(k2, b) && close(p1, c) && close(p2, d),
            (
                Lens::Fisheye { k1, k2, k3, k4 },
                Lens::Fisheye {
                    k1: a,
                    k2: b,
                    k3: c,
                    k4: d,
                },
            ) => close(k1, a) && close(k2, b) && close(k3, c) && close(k4, d),
            _ => false,
        };
        lens && (self.w, self.h) == (o.w, o.h)
            && close(self.fx, o.fx)
            && close(self.fy, o.fy)
            && close(self.cx, o.cx)
            && close(self.cy, o.cy)
    }
}

/// The OpenGL pose and pixel intrinsics of an sdfl camera for `w × h`
/// images.
pub fn view_of(camera: &Camera, (w, h): (u32, u32)) -> ([[f64; 4]; 4], ViewIntrinsics) {
    let pose = camera.to_opengl(w, h);
    (
        pose.c2w,
        ViewIntrinsics {
            w,
            h,
            fx: pose.fl_x,
            fy: pose.fl_y,
            cx: w as f64 / 2.0,
            cy: h as f64 / 2.0,
            lens: Lens::Pinhole,
        },
    )
}

struct FrameRecord {
    k: usize,
    c2w: [[f64; 4]; 4],
    intrinsics: ViewIntrinsics,
}

/// Writes a data set: `r_<k>.png` per view as it is pushed, and on
/// [`DatasetWriter::finish`] the transforms files, each atomically. From the
/// first view until then every transforms file marks the set incomplete.
pub struct DatasetWriter {
    /// Relative to the output directory.
    dir: PathBuf,
    out_dir: PathBuf,
    frames: Vec<FrameRecord>,
    size: (u32, u32),
    /// Per view, whether it is held out.
    held: Vec<bool>,
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
        }
    }

    /// The writer of a `dataset(...)` output (`None` for other outputs).
    pub fn for_output(
        out_dir: &Path,
        o: &sdfl_stdlib::value::Output,
        size: (u32, u32),
        views: usize,
    ) -> Option<Self> {
        match o.kind {
            sdfl_stdlib::value::OutputKind::Dataset { test_views, seed } => {
                Some(Self::new(out_dir, &o.path, size, views, test_views, seed))
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
        let (c2w, intrinsics) = view_of(camera, self.size);
        self.push_view(k, c2w, intrinsics, rgb, alpha)
    }

    /// Writes view `k` with an OpenGL camera-to-world pose and pixel
    /// intrinsics (for the image size the writer was made with).
    pub fn push_view(
        &mut self,
        k: usize,
        c2w: [[f64; 4]; 4],
        intrinsics: ViewIntrinsics,
        rgb: &[u8],
        alpha: Option<&[u8]>,
    ) -> io::Result<Written> {
        let (w, h) = self.size;
        let bad = |m: String| io::Error::new(io::ErrorKind::InvalidInput, m);
        if (intrinsics.w, intrinsics.h) != (w, h) {
            return Err(bad(format!(
                "{}: view {k}'s intrinsics are for {}x{} images, the data set's are {w}x{h}",
                self.dir.display(),
                intrinsics.w,
                intrinsics.h
            )));
        }
        if self.frames.iter().any(|f| f.k == k) {
            return Err(bad(format!(
                "{}: view {k} written twice",
                self.dir.display()
            )));
        }
        if let Some(f) = self.frames.first() {
            if f.intrinsics.lens.is_fisheye() != intrinsics.lens.is_fisheye() {
                return Err(bad(format!(
                    "{}: view {k} mixes a fisheye and a perspective lens, and a data set has one `camera_model`",
                    self.dir.display()
                )));
            }
        }
        let rgba: Vec<u8> = rgb
            .chunks_exact(3)
            .enumerate()
            .flat_map(|(i, c)| [c[0], c[1], c[2], alpha.map_or(255, |a| a[i])])
            .collect();
        if self.frames.is_empty() {
            // Until `finish`, the data set says it is being written: a run
            // stopped half-way (or a rerun stopped over an older set) leaves
            // a set that refuses to load in every reader, not a silent mix
            // of two runs. (nerfstudio finds no `frames`; instant-ngp skips
            // a file without them and then has no images.)
            let marker = format!("{{\"{INCOMPLETE}\": true}}\n");
            for name in DATASET_JSON {
                write_bytes(&self.out_dir.join(self.dir.join(name)), marker.as_bytes())?;
            }
        }
        let rel = self.dir.join(format!("r_{k}.png"));
        write_png_rgba(&self.out_dir.join(&rel), w, h, &rgba)?;
        self.frames.push(FrameRecord { k, c2w, intrinsics });
        Ok(Written {
            path: rel,
            kind: "dataset",
            width: w,
            height: h,
            frames: 1,
            mesh: None,
        })
    }

    /// The four transforms files' names and contents, in the order they
    /// are written.
    fn documents(&self) -> Vec<(&'static str, Value)> {
        let mut frames: Vec<&FrameRecord> = self.frames.iter().collect();
        frames.sort_by_key(|f| f.k);
        let first = frames.first().map(|f| f.intrinsics);
        let shared = first.filter(|i| frames.iter().all(|f| f.intrinsics.same(i)));
        let held = |k: usize| self.held.get(k).copied().unwrap_or(false);
        let any_held = frames.iter().any(|f| held(f.k));
        // nerfstudio's `camera_model` is one for the set: OPENCV as soon as
        // one view is distorted (pinhole views then have zeros).
        let model = if frames.iter().any(|f| f.intrinsics.lens.is_fisheye()) {
            "OPENCV_FISHEYE"
        } else if frames.iter().any(|f| f.intrinsics.lens != Lens::Pinhole) {
            "OPENCV"
        } else {
            "PINHOLE"
        };
        let widen = |i: ViewIntrinsics| match (model, i.lens) {
            ("OPENCV", Lens::Pinhole) => ViewIntrinsics {
                lens: Lens::OpenCv {
                    k1: 0.0,
                    k2: 0.0,
                    p1: 0.0,
                    p2: 0.0,
                },
                ..i
            },
            _ => i,
        };
        let top = || {
            let mut m = Map::new();
            m.insert("camera_model".into(), model.into());
            // The Blender parser and sdfl read the field of view; with
            // intrinsics per frame it is the first view's (the others'
            // `fl_x` say theirs).
            let angle = first.map_or(std::f64::consts::FRAC_PI_2, |i| i.camera_angle_x());
            m.insert("camera_angle_x".into(), angle.into());
            if let Some(i) = shared {
                m.extend(widen(i).keys().into_iter().map(|(k, v)| (k.to_string(), v)));
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
                    widen(f.intrinsics)
                        .keys()
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

    /// Writes the transforms files for the views pushed: the splits first,
    /// `transforms.json` last.
    pub fn finish(self) -> io::Result<Written> {
        let (w, h) = self.size;
        for (name, doc) in self.documents() {
            let text = serde_json::to_string_pretty(&doc).map_err(io::Error::other)?;
            write_bytes(&self.out_dir.join(self.dir.join(name)), text.as_bytes())?;
        }
        Ok(Written {
            path: self.dir.join(DATASET_JSON[3]),
            kind: "dataset",
            width: w,
            height: h,
            frames: 0,
            mesh: None,
        })
    }
}

#[cfg(test)]
mod writer_tests {
    use super::*;
    use crate::data::nerf_synthetic::{read_transforms, transforms_path};

    fn camera() -> Camera {
        Camera::look_at(
            glam::DVec3::new(0.0, 0.0, -3.0),
            glam::DVec3::ZERO,
            glam::DVec3::Y,
            1.0,
        )
    }

    /// A data set whose writing stopped half-way refuses to load from any
    /// of its transforms files (it may mix two runs' images); once finished
    /// every split loads.
    #[test]
    fn a_data_set_written_half_way_refuses_to_load() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path();
        let rgb = vec![128u8; 4 * 4 * 3];
        let mut w = DatasetWriter::new(out, Path::new("set"), (4, 4), 3, 1, 0);
        w.push(0, &camera(), &rgb, None).unwrap();
        for name in DATASET_JSON {
            let err = read_transforms(&out.join("set").join(name))
                .unwrap_err()
                .to_string();
            assert!(err.contains("stopped while it wrote"), "{name}: {err}");
        }
        w.push(1, &camera(), &rgb, None).unwrap();
        w.push(2, &camera(), &rgb, None).unwrap();
        w.finish().unwrap();
        let set = out.join("set");
        let count = |split| {
            read_transforms(&transforms_path(&set, split))
                .unwrap()
                .frames
                .len()
        };
        assert_eq!((count("train"), count("val"), count("test")), (2, 1, 1));
        assert_eq!(
            read_transforms(&set.join("transforms.json"))
                .unwrap()
                .frames
                .len(),
            3
        );
    }

    fn doc<'a>(docs: &'a [(&str, Value)], name: &str) -> &'a Value {
        &docs.iter().find(|d| d.0 == name).unwrap().1
    }

    /// Distorted views write their model's keys only, at the top when the
    /// views share them, per frame when they differ.
    #[test]
    fn distortion_and_per_frame_intrinsics() {
        let dir = tempfile::tempdir().unwrap();
        let rgb = vec![0u8; 6 * 4 * 3];
        let c2w = [
            [1.0, 0.0, 0.0, 0.0],
            [0.0, 1.0, 0.0, 0.0],
            [0.0, 0.0, 1.0, 2.0],
            [0.0, 0.0, 0.0, 1.0],
        ];
        let base = ViewIntrinsics {
            w: 6,
            h: 4,
            fx: 5.0,
            fy: 5.5,
            cx: 3.25,
            cy: 1.75,
            lens: Lens::OpenCv {
                k1: -0.1,
                k2: 0.01,
                p1: 1e-3,
                p2: -2e-3,
            },
        };
        let mut w = DatasetWriter::new(dir.path(), Path::new("a"), (6, 4), 2, 0, 0);
        w.push_view(0, c2w, base, &rgb, None).unwrap();
        w.push_view(1, c2w, base, &rgb, None).unwrap();
        let docs = w.documents();
        let t = doc(&docs, "transforms.json");
        assert_eq!(t["camera_model"], "OPENCV");
        assert_eq!(
            (t["k1"].as_f64(), t["p2"].as_f64()),
            (Some(-0.1), Some(-2e-3))
        );
        assert!(t.get("k3").is_none() && t.get("is_fisheye").is_none());
        assert!(t["frames"][0].get("fl_x").is_none());
        // Nothing held out: val and test list every view.
        assert_eq!(t["val_filenames"], json!(["r_0.png", "r_1.png"]));
        assert_eq!(
            doc(&docs, "transforms_test.json")["frames"]
                .as_array()
                .unwrap()
                .len(),
            2
        );

        let fish = ViewIntrinsics {
            lens: Lens::Fisheye {
                k1: 0.1,
                k2: 0.0,
                k3: -0.01,
                k4: 0.0,
            },
            ..base
        };
        let mut w = DatasetWriter::new(dir.path(), Path::new("b"), (6, 4), 2, 1, 7);
        w.push_view(0, c2w, fish, &rgb, None).unwrap();
        w.push_view(1, c2w, ViewIntrinsics { fx: 6.0, ..fish }, &rgb, None)
            .unwrap();
        let docs = w.documents();
        let t = doc(&docs, "transforms.json");
        assert_eq!(t["camera_model"], "OPENCV_FISHEYE");
        assert!(t.get("fl_x").is_none() && t.get("k1").is_none());
        let f1 = &t["frames"][1];
        assert_eq!(
            (f1["fl_x"].as_f64(), f1["k3"].as_f64()),
            (Some(6.0), Some(-0.01))
        );
        assert_eq!(f1["is_fisheye"], true);
        assert!(f1.get("p1").is_none());
        // A mixed set is refused.
        let err = w.push_view(2, c2w, base, &rgb, None).unwrap_err();
        assert!(err.to_string().contains("one `camera_model`"), "{err}");
        // A pinhole view beside distorted ones gets zeros under OPENCV.
        let mut w = DatasetWriter::new(dir.path(), Path::new("c"), (6, 4), 2, 0, 0);
        w.push_view(0, c2w, base, &rgb, None).unwrap();
        w.push_view(
            1,
            c2w,
            ViewIntrinsics {
                lens: Lens::Pinhole,
                ..base
            },
            &rgb,
            None,
        )
        .unwrap();
        let docs = w.documents();
        let f1 = &doc(&docs, "transforms.json")["frames"][1];
        assert_eq!(
            (f1["k1"].as_f64(), f1["p1"].as_f64()),
            (Some(0.0), Some(0.0))
        );
    }
}
