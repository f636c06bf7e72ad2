//! Writing data sets that sdfl renders (the `dataset(...)` output).

use std::io;
use std::path::{Path, PathBuf};

use sdfl_stdlib::camera::Camera;
use serde_json::{json, Value};

use crate::output::{write_bytes, write_png_rgba};
use crate::render::Written;

/// The key of the `transforms.json` a [`DatasetWriter`] leaves while it
/// writes.
pub(crate) const INCOMPLETE: &str = "sdfl_incomplete";

/// Writes a data set as NeRF-synthetic files: `r_<k>.png` (RGBA, alpha =
/// the hit mask, or opaque) per view and, on [`DatasetWriter::finish`],
/// `transforms.json`, each atomically. Until then `transforms.json` marks
/// the set incomplete.
pub struct DatasetWriter {
    /// Relative to the output directory.
    dir: PathBuf,
    out_dir: PathBuf,
    frames: Vec<Value>,
    camera_angle_x: Option<f64>,
    focal: Option<(f64, f64)>,
    size: (u32, u32),
}

impl DatasetWriter {
    pub fn new(out_dir: &Path, dir: &Path, (w, h): (u32, u32)) -> Self {
        DatasetWriter {
            dir: dir.to_path_buf(),
            out_dir: out_dir.to_path_buf(),
            frames: Vec::new(),
            camera_angle_x: None,
            focal: None,
            size: (w, h),
        }
    }

    /// Writes view `k`: `rgb` (8-bit) and `alpha` (one byte a pixel; `None`
    /// is opaque).
    pub fn push(
        &mut self,
        k: usize,
        camera: &Camera,
        rgb: &[u8],
        alpha: Option<&[u8]>,
    ) -> io::Result<Written> {
        let (w, h) = self.size;
        let rgba: Vec<u8> = rgb
            .chunks_exact(3)
            .enumerate()
            .flat_map(|(i, c)| [c[0], c[1], c[2], alpha.map_or(255, |a| a[i])])
            .collect();
        if self.frames.is_empty() {
            // Until `finish`, the data set says it is being written: a run
            // stopped half-way (or a rerun stopped over an older set) leaves
            // a set that refuses to load, not a silent mix of two runs.
            let marker = format!("{{\"{INCOMPLETE}\": true}}\n");
            write_bytes(
                &self.out_dir.join(self.dir.join("transforms.json")),
                marker.as_bytes(),
            )?;
        }
        let rel = self.dir.join(format!("r_{k}.png"));
        write_png_rgba(&self.out_dir.join(&rel), w, h, &rgba)?;
        let pose = camera.to_opengl(w, h);
        // One focal for the whole file: the first view's (the others are
        // checked equal, as the format has one).
        let focal = *self.focal.get_or_insert((pose.fl_x, pose.fl_y));
        if (focal.0 - pose.fl_x).abs() > 1e-9 * focal.0
            || (focal.1 - pose.fl_y).abs() > 1e-9 * focal.1
        {
            return Err(io::Error::new(
                io::ErrorKind::InvalidInput,
                format!(
                    "{}: a NeRF-synthetic data set has one focal length, but view {k}'s differs from view 0's",
                    self.dir.display()
                ),
            ));
        }
        self.camera_angle_x
            .get_or_insert(2.0 * (w as f64 / 2.0 / pose.fl_x).atan());
        self.frames.push(json!({
            "file_path": format!("./r_{k}"),
            "transform_matrix": pose.c2w,
        }));
        Ok(Written {
            path: rel,
            kind: "dataset",
            width: w,
            height: h,
            frames: 1,
            mesh: None,
        })
    }

    /// Writes `transforms.json` for the views pushed.
    pub fn finish(self) -> io::Result<Written> {
        let (w, h) = self.size;
        let (fl_x, fl_y) = self.focal.unwrap_or((1.0, 1.0));
        let doc = json!({
            "camera_angle_x": self.camera_angle_x.unwrap_or(std::f64::consts::FRAC_PI_2),
            "fl_x": fl_x,
            "fl_y": fl_y,
            "cx": w as f64 / 2.0,
            "cy": h as f64 / 2.0,
            "w": w,
            "h": h,
            "frames": self.frames,
        });
        let rel = self.dir.join("transforms.json");
        let text = serde_json::to_string_pretty(&doc).map_err(io::Error::other)?;
        write_bytes(&self.out_dir.join(&rel), text.as_bytes())?;
        Ok(Written {
            path: rel,
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
    use crate::data::nerf_synthetic::read_transforms;

    /// A data set whose writing stopped half-way refuses to load (it may
    /// mix two runs' images); once finished it loads.
    #[test]
    fn a_data_set_written_half_way_refuses_to_load() {
        let out = std::env::temp_dir().join(format!("sdfl-writer-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&out);
        std::fs::create_dir_all(&out).unwrap();
        let cam = Camera::look_at(
            glam::DVec3::new(0.0, 0.0, -3.0),
            glam::DVec3::ZERO,
            glam::DVec3::Y,
            1.0,
        );
        let rgb = vec![128u8; 4 * 4 * 3];
        let mut w = DatasetWriter::new(&out, Path::new("set"), (4, 4));
        w.push(0, &cam, &rgb, None).unwrap();
        let err = read_transforms(&out.join("set/transforms.json"))
            .unwrap_err()
            .to_string();
        assert!(err.contains("stopped while it wrote"), "{err}");
        w.push(1, &cam, &rgb, None).unwrap();
        w.finish().unwrap();
        let t = read_transforms(&out.join("set/transforms.json")).unwrap();
        assert_eq!(t.frames.len(), 2);
        let _ = std::fs::remove_dir_all(&out);
    }
}
