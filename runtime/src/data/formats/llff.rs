//! LLFF forward-facing captures (the original NeRF's `nerf_llff_data`, the
//! reference assignment's `nerf_fern`): `poses_bounds.npy`, N × 17 numbers
//! a frame: a 3 × 5 matrix row by row, `[R | t | hwf]` with the rotation's
//! columns in LLFF's axes (down, right, back) and the last column the
//! full-resolution height, width and focal length in pixels, then the
//! frame's near and far depth bounds. Images are the files of `images/`
//! (or `images_<downscale>/`) sorted by name, one per row.
//!
//! Normalised as NeRF does for these scenes: the average camera becomes
//! the origin looking down −z, and lengths are scaled so the nearest
//! bound is 4/3 (NeRF's `bd_factor` 0.75), which puts the `near = 1`
//! plane of NDC rays ([`crate::data::normalize::ndc_ray`]) in front of
//! every camera's content. So normalised, a capture is forward-facing: it
//! declares the NDC camera ([`ForwardFacing`]) that training warps rays
//! into.

use std::io;
use std::path::Path;

use glam::{DMat3, DVec3};
use sdfl_stdlib::builtins::MAX_VIEWS;
use sdfl_stdlib::value::{CaptureFormat, NdcFrame};

use crate::data::camera::{
    check_position, check_rotation, CheckNamed, Distortion, Intrinsics, Keys,
};
use crate::data::error::invalid;
use crate::data::format::{ForwardFacing, Format, FormatViews, PlannedView, Request};
use crate::data::frames::{held_out_every, load, planned_every_nth, Capture, CaptureFrame};
use crate::data::image::{image_dimensions, MAX_SIDE};
use crate::data::normalize::SceneFrame;
use crate::data::paths::{image_files, images_folder, inside};

/// The LLFF format.
pub struct Llff;

impl Format for Llff {
    fn name(&self) -> &'static str {
        "llff"
    }

    fn capture_format(&self) -> Option<CaptureFormat> {
        Some(CaptureFormat::Llff)
    }

    fn marker(&self) -> &'static str {
        "poses_bounds.npy"
    }

    fn detect(&self, path: &Path) -> bool {
        path.join("poses_bounds.npy").is_file()
    }

    fn own_frame(&self) -> Option<&'static str> {
        Some("recentred on the average camera (looking down -z), the nearest depth bound at 4/3 (as NeRF does)")
    }

    /// The images of the folder, without reading the poses.
    fn plan(&self, request: &Request) -> io::Result<Vec<PlannedView>> {
        let images = image_files(&request.path.join(images_folder(request.downscale)))?;
        Ok(planned_every_nth(images, request.test_every()))
    }

    fn read(&self, request: &Request) -> io::Result<FormatViews> {
        let (capture, frame) = read(&request.path, request.downscale, request.test_every())?;
        let mut views = load(&capture, request, Some(frame))?;
        // NeRF's normalisation puts the average camera at the origin
        // looking down −z and the nearest bound at 1/BD_FACTOR: NDC's near
        // plane is 1, as NeRF's. Every frame shares one camera
        // (poses_bounds.npy's hwf).
        let scene = views.frame.filter(|_| request.normalize.enabled);
        if let (Some(scene), Some(first), Some((_, far))) =
            (scene, capture.frames.first(), capture.bounds)
        {
            let i = &first.intrinsics;
            views.forward_facing = Some(ForwardFacing {
                ndc: NdcFrame {
                    width: i.width as f64,
                    height: i.height as f64,
                    fx: i.fx,
                    fy: i.fy,
                    near: 1.0,
                },
                far: far * scene.scale,
            });
        }
        Ok(views)
    }
}

/// NeRF's `bd_factor`: the nearest bound lands at `1 / BD_FACTOR`.
pub const BD_FACTOR: f64 = 0.75;

/// One row of `poses_bounds.npy`, checked.
#[derive(Debug, Clone, Copy)]
pub struct LlffPose {
    /// OpenGL camera-to-world (right, up, back, position).
    pub c2w: [[f64; 4]; 4],
    /// Full-resolution height, width and focal length in pixels.
    pub hwf: [f64; 3],
    /// Nearest scene depth seen by this camera, in the data's units.
    pub near: f64,
    /// Farthest scene depth seen by this camera, in the data's units.
    pub far: f64,
}

/// Parses the rows of `poses_bounds.npy` (shape `(N, 17)`).
pub fn parse(shape: &[usize], v: &[f64], at: &Path) -> io::Result<Vec<LlffPose>> {
    let n = match shape {
        [n, 17] if *n >= 1 && *n <= MAX_VIEWS => *n,
        _ => {
            return Err(invalid(
                at,
                format!(
                "shape {shape:?}, but poses_bounds.npy holds (N, 17) with N from 1 to {MAX_VIEWS}"
            ),
            ))
        }
    };
    (0..n)
        .map(|k| {
            let r = &v[k * 17..k * 17 + 17];
            let bad = |m: String| invalid(at, format!("frame {k}: {m}"));
            if let Some(i) = r.iter().position(|x| !x.is_finite()) {
                return Err(bad(format!("value {i} is not a finite number")));
            }
            let m = |row: usize, col: usize| r[row * 5 + col];
            let col = |c: usize| DVec3::new(m(0, c), m(1, c), m(2, c));
            // LLFF (down, right, back) → OpenGL (right, up, back).
            let (right, up, back, eye) = (col(1), -col(0), col(2), col(3));
            let rot = DMat3::from_cols(right, up, back);
            check_rotation(rot).map_err(&bad)?;
            check_position("camera position", eye).map_err(&bad)?;
            let hwf = [m(0, 4), m(1, 4), m(2, 4)];
            let max = MAX_SIDE as f64;
            if !(hwf[0] >= 1.0 && hwf[0] <= max && hwf[1] >= 1.0 && hwf[1] <= max) {
                return Err(bad(format!(
                    "image size {}x{} is not 1 to {max} pixels a side",
                    sdfl_lang::fmt_num(hwf[1]),
                    sdfl_lang::fmt_num(hwf[0])
                )));
            }
            let (near, far) = (r[15], r[16]);
            if !(near > 0.0 && far > near && far < 1e18) {
                return Err(bad(format!(
                    "depth bounds {} to {} are not 0 < near < far",
                    sdfl_lang::fmt_num(near),
                    sdfl_lang::fmt_num(far)
                )));
            }
            let mut c2w = [[0.0; 4]; 4];
            for (c, v) in [right, up, back, eye].iter().enumerate() {
                for (row, out) in c2w.iter_mut().take(3).enumerate() {
                    out[c] = v[row];
                }
            }
            c2w[3][3] = 1.0;
            Ok(LlffPose {
                c2w,
                hwf,
                near,
                far,
            })
        })
        .collect()
}

/// NeRF's normalisation of forward-facing poses: centred on the mean
/// camera, turned so the average camera looks down −z with the average up
/// as +y, scaled so the nearest bound is `1 / BD_FACTOR`.
pub fn scene_frame(poses: &[LlffPose]) -> SceneFrame {
    let n = poses.len().max(1) as f64;
    let col = |m: &[[f64; 4]; 4], c: usize| DVec3::new(m[0][c], m[1][c], m[2][c]);
    let center = poses.iter().map(|p| col(&p.c2w, 3)).sum::<DVec3>() / n;
    let back = poses
        .iter()
        .map(|p| col(&p.c2w, 2))
        .sum::<DVec3>()
        .normalize_or(DVec3::Z);
    let up = poses.iter().map(|p| col(&p.c2w, 1)).sum::<DVec3>();
    let right = up.cross(back).normalize_or(DVec3::X);
    let up = back.cross(right);
    // The average camera's axes as rows: world → its frame.
    let rotation = DMat3::from_cols(right, up, back).transpose();
    let near = poses.iter().map(|p| p.near).fold(f64::INFINITY, f64::min);
    SceneFrame::new(1.0 / (near * BD_FACTOR), center, rotation)
}

/// An LLFF capture in `dir` and its normalising scene frame.
pub fn read(dir: &Path, downscale: u32, test_every: usize) -> io::Result<(Capture, SceneFrame)> {
    let file = dir.join("poses_bounds.npy");
    let (shape, values) = crate::data::npy::read_f64(&file).map_err(|e| invalid(&file, e))?;
    let poses = parse(&shape, &values, &file)?;
    let folder_name = images_folder(downscale);
    let files = image_files(&dir.join(&folder_name))?;
    if files.len() != poses.len() {
        return Err(invalid(
            &file,
            format!(
                "{} poses but {} images in {folder_name}/",
                poses.len(),
                files.len()
            ),
        ));
    }
    let d = downscale.max(1) as f64;
    let mut frames = Vec::with_capacity(poses.len());
    for (k, (p, f)) in poses.iter().zip(&files).enumerate() {
        let at = |m: String| invalid(&file, format!("frame {k} ({}): {m}", f.display()));
        let name = f.file_name().and_then(|n| n.to_str()).unwrap_or_default();
        let image = inside(dir, &Path::new(&folder_name).join(name), name).map_err(at)?;
        let (w, h) = image_dimensions(&image)?;
        let (hf, wf, focal) = (p.hwf[0], p.hwf[1], p.hwf[2]);
        if (wf / d - w as f64).abs() >= 1.0 || (hf / d - h as f64).abs() >= 1.0 {
            return Err(at(format!(
                "the image is {w}x{h} pixels but the poses say {}x{}{}",
                sdfl_lang::fmt_num(wf),
                sdfl_lang::fmt_num(hf),
                if d > 1.0 {
                    format!(" (read at 1/{downscale})")
                } else {
                    String::new()
                }
            )));
        }
        let intrinsics = Intrinsics {
            width: w,
            height: h,
            fx: focal / d,
            fy: focal / d,
            cx: w as f64 / 2.0,
            cy: h as f64 / 2.0,
            distortion: Distortion::None,
        };
        intrinsics
            .check_named(
                Keys {
                    fx: "focal",
                    fy: "focal",
                },
                (focal, focal),
            )
            .map_err(at)?;
        frames.push(CaptureFrame {
            label: format!("frame {k}"),
            image,
            mask: None,
            object_mask: None,
            c2w: p.c2w,
            intrinsics,
        });
    }
    let test = held_out_every(frames.len(), test_every, &file, "frames")?;
    let frame = scene_frame(&poses);
    let near = poses.iter().map(|p| p.near).fold(f64::INFINITY, f64::min);
    let far = poses.iter().map(|p| p.far).fold(0.0, f64::max);
    Ok((
        Capture {
            source: file,
            frames,
            test,
            applied: None,
            points: Vec::new(),
            bounds: Some((near, far)),
        },
        frame,
    ))
}
