//! Camera paths: a smooth closed loop through (or near) a set of cameras,
//! looking at their common focus, for rendering a trained model from new
//! views that stay where the training views were (an orbit of the equator
//! leaves a hemisphere's views).
//!
//! The loop: the point nearest every camera's optical axis (least squares)
//! is the focus; the mean of the cameras' `up` the axis; cameras are
//! grouped into `keyframes` equal sectors of azimuth about that axis
//! through the focus, each sector's mean position (at the sector's mean
//! distance from the focus) a control point; a closed centripetal
//! Catmull-Rom spline through the control points in order of azimuth gives
//! the eyes, every frame looking at the focus with the cameras' mean focal
//! length. With at least as many keyframes as cameras, each camera is a
//! control point and the path passes through it.

use super::*;

/// Most frames of a path (as views: the most views of a statement).
pub const MAX_FRAMES: u64 = MAX_VIEWS as u64;

/// The type of `training_loop(...)`.
pub const VIEW_PATH: Type = Type::Named("camera path");

pub(crate) fn builtins() -> Vec<Builtin> {
    vec![func(
        "training_path",
        "As a `train`'s `views` (its default): nerfstudio's interpolated path through the training cameras in the order the data lists them, made when the run has read its data. Positions follow a centripetal Catmull-Rom spline through every camera, orientations a slerp between consecutive cameras, focal lengths a blend; the path starts at the first camera and ends at the last, an equal share of frames between each two. Views are pinhole cameras (a lens's distortion is not rendered) at the data's aspect unless the `train` gives `size`.",
        vec![opt("frames", Type::Number, "60", "cameras on the path (1 to 10 000)")],
        VIEW_PATH,
        |a| {
            let frames = a.count("frames", 1, MAX_FRAMES)? as usize;
            Ok(Value::ViewPath(ViewPath::TrainingPath { frames }))
        },
    ), func(
        "training_loop",
        "As a `train`'s `views`: `camera_loop` through the training cameras, made when the run has read its data (a data set from files has its cameras only then).",
        vec![
            opt("frames", Type::Number, "60", "cameras on the loop (1 to 10 000)"),
            opt("keyframes", Type::Number, "8", "sectors of azimuth, one control point each (1 to 10 000)"),
        ],
        VIEW_PATH,
        |a| {
            let frames = a.count("frames", 1, MAX_FRAMES)? as usize;
            let keyframes = a.count("keyframes", 1, MAX_FRAMES)? as usize;
            Ok(Value::ViewPath(ViewPath::TrainingLoop { frames, keyframes }))
        },
    ), func(
        "camera_loop",
        "A smooth closed loop of `frames` cameras through (or near) `cameras`, looking at their common focus (the point nearest all their optical axes): a centripetal Catmull-Rom spline through the mean position of each of `keyframes` sectors of azimuth about the cameras' mean up axis (through each camera when `keyframes` ≥ their number); the cameras' mean focal length. Use it as a `train`'s `views` to render a trained model where its training cameras were.",
        vec![
            req("cameras", Type::list(CAMERA), "the cameras to pass through (e.g. the training cameras)"),
            opt("frames", Type::Number, "60", "cameras on the loop (1 to 10 000)"),
            opt("keyframes", Type::Number, "8", "sectors of azimuth, one control point each (1 to 10 000)"),
        ],
        Type::list(CAMERA),
        |a| {
            let cams = camera_list(a, "cameras")?;
            let frames = a.count("frames", 1, MAX_FRAMES)? as usize;
            let keyframes = a.count("keyframes", 1, MAX_FRAMES)? as usize;
            let path = camera_loop(&cams, frames, keyframes).map_err(|e| {
                value_error(
                    a.get("cameras").1,
                    format!("no loop through these cameras: {e}"),
                    "no loop",
                    "give cameras around a common subject",
                )
            })?;
            Ok(Value::List(Arc::new(path.into_iter().map(Value::Camera).collect())))
        },
    ), func(
        "camera_path",
        "The cameras of nerfstudio's `camera_path.json` (what its viewer exports for `ns-render camera-path`): `camera_path[].camera_to_world` (OpenGL, row by row) and `fov` (vertical, degrees), read when the file is evaluated. Render at the path's `render_width` × `render_height` for its framing (the field of view is the shorter side's).",
        vec![req("path", Type::Str, "the camera_path.json file (relative to the scene file)")],
        Type::list(CAMERA),
        |a| {
            let (path, span) = a.string("path")?;
            if path.is_empty() || path.contains('\0') {
                return Err(Diag::new(codes::PATH, span, "not a usable path").label("empty or holds a NUL byte").help("name the camera_path.json file"));
            }
            let full = match &a.base {
                Some(base) => base.join(path.as_ref()),
                None => PathBuf::from(path.as_ref()),
            };
            let cams = crate::camera_path::read_camera_path(&full).map_err(|e| {
                Diag::new(codes::IO, span, format!("cannot read the camera path: {e}"))
                    .label("not a usable camera_path.json")
                    .help("name a camera_path.json that nerfstudio's viewer exported (paths are relative to the scene file)")
            })?;
            Ok(Value::List(Arc::new(cams.cameras.into_iter().map(Value::Camera).collect())))
        },
    )]
}

/// The point nearest every camera's optical axis in the least-squares
/// sense, pulled slightly towards the eyes' centroid so that parallel axes
/// still give a point.
pub fn common_focus(cams: &[Camera]) -> DVec3 {
    let n = cams.len().max(1) as f64;
    let centroid = cams.iter().map(|c| c.eye).sum::<DVec3>() / n;
    let scale = cams
        .iter()
        .map(|c| (c.eye - centroid).length_squared())
        .sum::<f64>()
        / n;
    let eps = 1e-6 * n;
    let mut a = glam::DMat3::from_diagonal(DVec3::splat(eps));
    let mut b = centroid * eps;
    for c in cams {
        let d = (c.at - c.eye).normalize_or_zero();
        let m = glam::DMat3::IDENTITY - glam::DMat3::from_cols(d * d.x, d * d.y, d * d.z);
        a += m;
        b += m * c.eye;
    }
    let p = a.inverse() * b;
    // A focus absurdly far away (nearly parallel axes) is no focus.
    if p.is_finite() && (p - centroid).length_squared() <= 1e6 * scale.max(1e-12) {
        p
    } else {
        centroid
            + cams
                .iter()
                .map(|c| (c.at - c.eye).normalize_or_zero())
                .sum::<DVec3>()
                / n
    }
}

/// A point of the centripetal Catmull-Rom segment from `p[1]` to `p[2]` at
/// `u` in 0..1 (Barry and Goldman's pyramid; knots spaced by the square
/// root of the distances, so the curve neither cusps nor self-intersects
/// within a segment).
fn catmull_rom(p: [DVec3; 4], u: f64) -> DVec3 {
    let knot = |a: DVec3, b: DVec3| (a - b).length().sqrt().max(1e-9);
    let t0 = 0.0;
    let t1 = t0 + knot(p[0], p[1]);
    let t2 = t1 + knot(p[1], p[2]);
    let t3 = t2 + knot(p[2], p[3]);
    let t = t1 + u * (t2 - t1);
    let lerp = |a: DVec3, b: DVec3, ta: f64, tb: f64| {
        a * ((tb - t) / (tb - ta)) + b * ((t - ta) / (tb - ta))
    };
    let a1 = lerp(p[0], p[1], t0, t1);
    let a2 = lerp(p[1], p[2], t1, t2);
    let a3 = lerp(p[2], p[3], t2, t3);
    let b1 = lerp(a1, a2, t0, t2);
    let b2 = lerp(a2, a3, t1, t3);
    lerp(b1, b2, t1, t2)
}

/// The control points of the loop (see the module) with the focus and up
/// axis.
pub fn loop_controls(cams: &[Camera], keyframes: usize) -> (Vec<DVec3>, DVec3, DVec3) {
    let focus = common_focus(cams);
    let up = cams.iter().map(|c| c.up.normalize_or_zero()).sum::<DVec3>();
    let up = if up.length() > 1e-9 {
        up.normalize()
    } else {
        DVec3::Y
    };
    let (u, v) = up.any_orthonormal_pair();
    let azimuth = |p: DVec3| {
        let q = p - focus;
        q.dot(v).atan2(q.dot(u))
    };
    let mut sorted: Vec<(f64, DVec3)> = cams.iter().map(|c| (azimuth(c.eye), c.eye)).collect();
    sorted.sort_by(|a, b| a.0.total_cmp(&b.0));
    if keyframes >= cams.len() {
        return (sorted.into_iter().map(|(_, e)| e).collect(), focus, up);
    }
    let tau = std::f64::consts::TAU;
    let mut sectors = vec![(DVec3::ZERO, 0.0, 0usize); keyframes];
    for (a, e) in &sorted {
        let k = (((a + std::f64::consts::PI) / tau * keyframes as f64) as usize).min(keyframes - 1);
        sectors[k].0 += *e - focus;
        sectors[k].1 += (*e - focus).length();
        sectors[k].2 += 1;
    }
    let controls = sectors
        .into_iter()
        .filter(|s| s.2 > 0)
        .map(|(sum, dist, n)| {
            // The mean direction at the mean distance: averaging positions
            // on a sphere would pull them inwards.
            let dir = (sum / n as f64).normalize_or_zero();
            focus + dir * (dist / n as f64)
        })
        .collect();
    (controls, focus, up)
}

/// `frames` cameras on the closed loop through the controls of `cams`.
pub fn camera_loop(
    cams: &[Camera],
    frames: usize,
    keyframes: usize,
) -> Result<Vec<Camera>, String> {
    if cams.is_empty() {
        return Err("no cameras".into());
    }
    if cams.len() == 1 {
        // One camera has no focus of several axes: the path stays there.
        return Ok(vec![cams[0]; frames]);
    }
    let (controls, focus, up) = loop_controls(cams, keyframes.max(1));
    let focal = cams.iter().map(|c| c.focal).sum::<f64>() / cams.len() as f64;
    let n = controls.len();
    let path: Vec<Camera> = (0..frames)
        .map(|k| {
            let s = k as f64 * n as f64 / frames as f64;
            let i = (s.floor() as usize).min(n - 1);
            let at = |j: isize| controls[(i as isize + j).rem_euclid(n as isize) as usize];
            let eye = catmull_rom([at(-1), at(0), at(1), at(2)], s - i as f64);
            // The up axis, tilted where the view looks along it.
            let fwd = (focus - eye).normalize_or_zero();
            let cam_up = if fwd.cross(up).length() > 1e-6 {
                up
            } else {
                up.any_orthogonal_vector()
            };
            Camera::look_at(eye, focus, cam_up, focal)
        })
        .collect();
    if let Some(c) = path.iter().find(|c| !(c.is_valid() && c.eye.is_finite())) {
        return Err(format!(
            "a camera at {} does not look anywhere (an eye at the focus)",
            c.eye
        ));
    }
    Ok(path)
}

/// A camera's orientation as a unit quaternion: the rotation whose
/// columns are its axes (left, up, forward), a right-handed frame.
#[doc(hidden)]
pub fn orientation(c: &Camera) -> glam::DQuat {
    let (x, y, z) = c.axes();
    glam::DQuat::from_mat3(&glam::DMat3::from_cols(x, y, z)).normalize()
}

/// `frames` cameras along nerfstudio's interpolated path through `cams` in
/// their order (its `get_interpolated_camera_path`, with a smooth curve for
/// the positions where it has straight segments): eyes on the centripetal
/// Catmull-Rom spline through every camera (the ends continued by
/// reflecting their neighbour), orientations slerped between consecutive
/// cameras, focal lengths blended; an equal share of frames between each
/// two cameras, the first frame the first camera and the last the last.
/// Each is an NDC pinhole with half-pixel centres, as data sets' cameras
/// (a real lens's intrinsics become its focal length, centred).
pub fn training_path(cams: &[Camera], frames: usize) -> Result<Vec<Camera>, String> {
    let Some(first) = cams.first() else {
        return Err("no cameras".into());
    };
    let pinhole = |eye: DVec3, q: glam::DQuat, focal: f64| {
        let (z, y) = (q * DVec3::Z, q * DVec3::Y);
        Camera::look_at(eye, eye + z, y, focal).with_pixel_centers(PixelCenters::Half)
    };
    if cams.len() == 1 {
        return Ok(vec![
            pinhole(first.eye, orientation(first), first.focal);
            frames
        ]);
    }
    let n = cams.len();
    let eyes: Vec<DVec3> = cams.iter().map(|c| c.eye).collect();
    // Each orientation on the side of its predecessor, so that slerp takes
    // the short way round.
    let mut turns: Vec<glam::DQuat> = Vec::with_capacity(n);
    for c in cams {
        let q = orientation(c);
        let q = match turns.last() {
            Some(prev) if prev.dot(q) < 0.0 => -q,
            _ => q,
        };
        turns.push(q);
    }
    let eye_at = |j: isize| -> DVec3 {
        match j {
            -1 => 2.0 * eyes[0] - eyes[1],
            j if j as usize >= n => 2.0 * eyes[n - 1] - eyes[n - 2],
            j => eyes[j as usize],
        }
    };
    let path: Vec<Camera> = (0..frames)
        .map(|k| {
            let s = if frames > 1 {
                k as f64 * (n - 1) as f64 / (frames - 1) as f64
            } else {
                0.0
            };
            let i = (s.floor() as usize).min(n - 2);
            let u = s - i as f64;
            let j = i as isize;
            let eye = catmull_rom([eye_at(j - 1), eye_at(j), eye_at(j + 1), eye_at(j + 2)], u);
            let q = turns[i].slerp(turns[i + 1], u).normalize();
            let focal = cams[i].focal * (1.0 - u) + cams[i + 1].focal * u;
            pinhole(eye, q, focal)
        })
        .collect();
    if let Some(c) = path.iter().find(|c| !(c.is_valid() && c.eye.is_finite())) {
        return Err(format!("a camera at {} has no orientation", c.eye));
    }
    Ok(path)
}
