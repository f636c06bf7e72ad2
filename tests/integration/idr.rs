//! IDR's and NeuS's layout (DTU, BlendedMVS as they ship): a tiny set
//! written here the way those releases are (RGB images in `image/`,
//! masks under other names in `mask/`, `cameras_sphere.npz` with
//! `world_mat_i = K[R|t]` in a far-off world frame, `scale_mat_i` and
//! arrays NeuS ignores), its pictures traced through NeuS's own pixel
//! model; read by `capture(...)`'s reader and trained on by the CLI.

use std::fs;
use std::io::Write;
use std::path::{Path, PathBuf};

use crate::common::{assert_outcome, case_dir, head, run_into, run_report, sdfl, Expect};
use glam::{DMat3, DVec3};
use sdfl_runtime::data::capture;
use sdfl_runtime::data::normalize::SceneFrame;
use sdfl_runtime::data::DataNeeds;
use sdfl_stdlib::value::{CaptureFormat, CaptureSpec, ObjectMasks};

const W: u32 = 24;
const H: u32 = 18;
/// The object's sphere in the world: `scale_mat`'s translation and scale.
const CENTRE: DVec3 = DVec3::new(120.0, -40.0, 650.0);
const SCALE: f64 = 200.0;
/// The object: a ball of this radius in the unit sphere's frame.
const BALL: f64 = 0.5;
const VIEWS: usize = 6;

/// One camera as NeuS's files hold it: `K`, and world to OpenCV camera.
#[derive(Clone, Copy)]
struct Cam {
    k: DMat3,
    r: DMat3,
    t: DVec3,
}

impl Cam {
    fn eye(&self) -> DVec3 {
        -(self.r.transpose() * self.t)
    }

    /// `world_mat`: `K[R | t]` over `0 0 0 1`, rows.
    fn world_mat(&self) -> [[f64; 4]; 4] {
        let (m, p) = (self.k * self.r, self.k * self.t);
        let mut w = [[0.0, 0.0, 0.0, 1.0]; 4];
        for (i, row) in w.iter_mut().take(3).enumerate() {
            *row = [m.row(i).x, m.row(i).y, m.row(i).z, p[i]];
        }
        w
    }

    /// NeuS's pixel of a world point: `P · X`, centres at whole numbers.
    fn pixel(&self, x: DVec3) -> (f64, f64) {
        let q = self.k * (self.r * x + self.t);
        (q.x / q.z, q.y / q.z)
    }

    /// NeuS's ray of pixel position `(u, v)`: through `K⁻¹ (u, v, 1)`.
    fn ray(&self, u: f64, v: f64) -> DVec3 {
        (self.r.transpose() * (self.k.inverse() * DVec3::new(u, v, 1.0))).normalize()
    }
}

/// `VIEWS` cameras 3 sphere radii from the centre, around it at varying
/// heights, each looking at it, with an off-centre principal point and
/// `fx ≠ fy`.
fn cameras() -> Vec<Cam> {
    let k = DMat3::from_cols_array_2d(&[[40.0, 0.0, 11.3], [0.0, 41.0, 8.6], [0.0, 0.0, 1.0]])
        .transpose();
    (0..VIEWS)
        .map(|n| {
            let a = n as f64 * std::f64::consts::TAU / VIEWS as f64;
            let dir = DVec3::new(a.cos(), 0.3 * (n as f64 - 2.5) / 2.5, a.sin()).normalize();
            let eye = CENTRE + dir * 3.0 * SCALE;
            // OpenCV axes: z forward, x right, y down; world up +y.
            let z = (CENTRE - eye).normalize();
            let x = z.cross(DVec3::Y).normalize();
            let y = z.cross(x);
            let r = DMat3::from_cols(x, y, z).transpose();
            Cam {
                k,
                r,
                t: -(r * eye),
            }
        })
        .collect()
}

/// Where the ray of pixel `(i, j)` meets the ball (world), if it does.
fn hit(cam: &Cam, i: u32, j: u32) -> Option<DVec3> {
    let (o, d) = (cam.eye(), cam.ray(i as f64, j as f64));
    let oc = o - CENTRE;
    let b = oc.dot(d);
    let disc = b * b - (oc.length_squared() - (BALL * SCALE).powi(2));
    (disc >= 0.0).then(|| o + d * (-b - disc.sqrt()))
}

/// The archive's arrays: names and `.npy` bytes.
type Arrays = Vec<(String, Vec<u8>)>;

/// An array of the archive, `.npy` bytes of a `<f8` 4 × 4.
fn array(name: &str, m: &[[f64; 4]; 4]) -> (String, Vec<u8>) {
    let flat: Vec<f64> = m.iter().flatten().copied().collect();
    (
        name.to_string(),
        sdfl_runtime::data::npy::encode_f64(&[4, 4], &flat),
    )
}

fn scale_mat() -> [[f64; 4]; 4] {
    [
        [SCALE, 0.0, 0.0, CENTRE.x],
        [0.0, SCALE, 0.0, CENTRE.y],
        [0.0, 0.0, SCALE, CENTRE.z],
        [0.0, 0.0, 0.0, 1.0],
    ]
}

/// The archive's arrays as NeuS's DTU release has them: `world_mat_i`,
/// `scale_mat_i`, and the ones NeuS does not read.
fn arrays(cams: &[Cam]) -> Arrays {
    let mut out = Vec::new();
    for (n, c) in cams.iter().enumerate() {
        out.push(array(&format!("world_mat_{n}"), &c.world_mat()));
        out.push(array(&format!("scale_mat_{n}"), &scale_mat()));
        out.push(array(
            &format!("world_mat_inv_{n}"),
            &[[9.0; 4], [9.0; 4], [9.0; 4], [9.0; 4]],
        ));
        out.push(array(&format!("camera_mat_{n}"), &[[f64::NAN; 4]; 4]));
    }
    out
}

fn write_npz(path: &Path, arrays: &[(String, Vec<u8>)]) {
    let mut z = zip::ZipWriter::new(fs::File::create(path).unwrap());
    let opts = zip::write::SimpleFileOptions::default()
        .compression_method(zip::CompressionMethod::Deflated);
    for (name, bytes) in arrays {
        z.start_file(format!("{name}.npy"), opts).unwrap();
        z.write_all(bytes).unwrap();
    }
    z.finish().unwrap();
}

/// Writes the set into `dir`: images `image/00000n.png` (the ball shaded
/// by its normal over grey, RGB), masks `mask/00n.png` (white on the
/// ball), the archive of `arrays`.
fn write_set(dir: &Path, cams: &[Cam], arrays: &[(String, Vec<u8>)]) {
    fs::create_dir_all(dir.join("image")).unwrap();
    fs::create_dir_all(dir.join("mask")).unwrap();
    for (n, cam) in cams.iter().enumerate() {
        image::RgbImage::from_fn(W, H, |i, j| match hit(cam, i, j) {
            Some(p) => {
                let nrm = (p - CENTRE).normalize() * 0.5 + DVec3::splat(0.5);
                image::Rgb((nrm * 255.0).round().to_array().map(|v| v as u8))
            }
            None => image::Rgb([60, 60, 60]),
        })
        .save(dir.join(format!("image/{n:06}.png")))
        .unwrap();
        image::GrayImage::from_fn(W, H, |i, j| {
            image::Luma([if hit(cam, i, j).is_some() { 255 } else { 0 }])
        })
        .save(dir.join(format!("mask/{n:03}.png")))
        .unwrap();
    }
    // Other files beside the pictures are ignored.
    fs::write(dir.join("image/notes.txt"), "not a picture").unwrap();
    write_npz(&dir.join("cameras_sphere.npz"), arrays);
}

fn spec(path: &Path) -> CaptureSpec {
    CaptureSpec {
        test_every: 0,
        ..CaptureSpec::at(path)
    }
}

fn err<T>(r: std::io::Result<T>) -> String {
    match r {
        Ok(_) => panic!("expected an error"),
        Err(e) => e.to_string(),
    }
}

#[test]
fn the_reader_puts_the_object_sphere_at_the_unit_sphere() {
    let dir = case_dir("idr_read");
    let cams = cameras();
    write_set(&dir, &cams, &arrays(&cams));
    assert_eq!(capture::detect(&dir), Some(CaptureFormat::Idr));
    let coverage = DataNeeds {
        coverage: true,
        held_out: None,
    };
    let v = capture::read_for(&spec(&dir), Path::new("/"), coverage).unwrap();
    assert_eq!((v.train.len(), v.test.len()), (VIEWS, 0));
    // The scene frame is (x − c)/s: the world's centre and scale.
    assert_eq!(
        v.frame,
        SceneFrame::new(1.0 / SCALE, CENTRE, DMat3::IDENTITY)
    );
    assert!((v.frame.to_data(DVec3::ZERO) - CENTRE).length() < 1e-12);
    assert!(
        v.report.iter().any(|l| l.contains("unit sphere")),
        "{:?}",
        v.report
    );
    for (n, (view, cam)) in v.train.iter().zip(&cams).enumerate() {
        let c = &view.camera;
        // Three unit-sphere radii out, as written in the world.
        assert!((c.eye - v.frame.to_scene(cam.eye())).length() < 1e-9, "{n}");
        assert!((c.eye.length() - 3.0).abs() < 1e-9, "{n}: {}", c.eye);
        // The ray through the pixel position where NeuS projects a point
        // passes through that point: the pixel-centre convention, end to
        // end through the reader (points on and off the ball).
        for x in [
            CENTRE,
            CENTRE + DVec3::new(0.3, -0.2, 0.1) * SCALE,
            CENTRE + DVec3::new(-0.4, 0.25, 0.3) * SCALE,
        ] {
            let (u, vv) = cam.pixel(x);
            let d = c.pixel_direction(u, vv, W, H);
            let to = v.frame.to_scene(x) - c.eye;
            let off = d.cross(to).length() / to.length();
            assert!(off < 1e-9, "view {n}: {off} at ({u}, {vv})");
        }
        // Coverage is the mask (RGB images without alpha), not alpha.
        let cov = view.coverage.as_deref().expect("coverage from the mask");
        for j in 0..H {
            for i in 0..W {
                let want = if hit(cam, i, j).is_some() { 255 } else { 0 };
                assert_eq!(cov[(j * W + i) as usize], want, "view {n} ({i}, {j})");
            }
        }
        assert!(cov.contains(&255) && cov.contains(&0));
        assert!(
            view.mask.is_none(),
            "object masks leave every pixel trained"
        );
    }
    // Without `silhouette()` the masks are not read.
    let v = capture::read(&spec(&dir), Path::new("/")).unwrap();
    assert!(v.train.iter().all(|t| t.coverage.is_none()));
    // normalize: false keeps the world frame.
    let mut s = spec(&dir);
    s.normalize = false;
    s.test_every = 4;
    let v = capture::read(&s, Path::new("/")).unwrap();
    assert_eq!(v.frame, SceneFrame::IDENTITY);
    assert_eq!((v.train.len(), v.test.len()), (4, 2));
    // Held out: images 0 and 4; trained: 1, 2, 3, 5.
    for (view, k) in v.train.iter().zip([1, 2, 3, 5]) {
        assert!((view.camera.eye - cams[k].eye()).length() < 1e-9 * SCALE);
    }
    // Without `mask/`, no coverage: RGB images cannot give it.
    fs::remove_dir_all(dir.join("mask")).unwrap();
    capture::read(&spec(&dir), Path::new("/")).unwrap();
    let e = capture::read_for(&spec(&dir), Path::new("/"), coverage).unwrap_err();
    assert_eq!(
        sdfl_runtime::data::coded(&e).map(|c| c.code),
        Some(sdfl_runtime::data::NO_COVERAGE),
        "{e}"
    );
}

#[test]
fn broken_sets_are_refused_naming_the_file_and_the_image() {
    let dir = case_dir("idr_broken");
    let cams = cameras();
    let read = |d: &Path| err(capture::read(&spec(d), Path::new("/")));
    type Spoil = fn(&mut Arrays, &[Cam]);
    let cases: Vec<(&str, Spoil, &str)> = vec![
        (
            "skew",
            |a, cams| {
                let mut c = cams[3];
                c.k.y_axis.x = 2.0; // K[0][1]
                a[3 * 4] = array("world_mat_3", &c.world_mat());
            },
            "image 3 (000003.png): `world_mat_3` has a skew of",
        ),
        (
            "missing world_mat",
            |a, _| a[5 * 4].0 = "world_mat_6".into(),
            "image 5 (000005.png): it has no `world_mat_5`",
        ),
        (
            "missing scale_mat",
            |a, _| {
                a.remove(2 * 4 + 1);
            },
            "image 2 (000002.png): it has no `scale_mat_2`",
        ),
        (
            "one camera short",
            |a, _| {
                a.remove(4 * 4);
            },
            "5 cameras (world_mat_<i>) for 6 images",
        ),
        (
            "another sphere",
            |a, _| {
                let mut m = scale_mat();
                m[0][3] += 1.0;
                a[4 * 4 + 1] = array("scale_mat_4", &m);
            },
            "`scale_mat_4` (scale 200, centre [121, -40, 650]) differs from scale_mat_0's",
        ),
        (
            "non-uniform scale",
            |a, _| {
                let mut m = scale_mat();
                m[2][2] = 2.0 * SCALE;
                for k in 0..VIEWS {
                    a[k * 4 + 1] = array(&format!("scale_mat_{k}"), &m);
                }
            },
            "image 0 (000000.png): `scale_mat_0`: it is not a uniform scale",
        ),
        (
            "NaN",
            |a, cams| {
                let mut m = cams[1].world_mat();
                m[1][2] = f64::NAN;
                a[4] = array("world_mat_1", &m);
            },
            "image 1 (000001.png): `world_mat_1`[1][2] is not a finite number",
        ),
        (
            "zero",
            |a, _| {
                a[2 * 4] = array(
                    "world_mat_2",
                    &[[0.0; 4], [0.0; 4], [0.0; 4], [0.0, 0.0, 0.0, 1.0]],
                )
            },
            "image 2 (000002.png): `world_mat_2`: the projection's left 3x3 part is singular",
        ),
        (
            "far camera",
            |a, cams| {
                let mut c = cams[0];
                c.t = -(c.r * DVec3::new(1e30, 0.0, 0.0));
                a[0] = array("world_mat_0", &c.world_mat());
            },
            "image 0 (000000.png): `world_mat_0`: the camera position in the unit sphere's frame",
        ),
    ];
    for (what, spoil, says) in cases {
        let d = dir.join(what.replace(' ', "_"));
        let mut a = arrays(&cams);
        spoil(&mut a, &cams);
        write_set(&d, &cams, &a);
        let e = read(&d);
        assert!(
            e.contains("cameras_sphere.npz") && e.contains(says),
            "{what}: {e}"
        );
    }
    // A mask short: the pairing by sorted name would be off.
    let d = dir.join("mask_short");
    write_set(&d, &cams, &arrays(&cams));
    fs::remove_file(d.join("mask/005.png")).unwrap();
    let e = read(&d);
    assert!(
        e.contains("mask") && e.contains("5 masks for 6 images"),
        "{e}"
    );
    // A link out of the capture is refused, as the other readers do.
    #[cfg(unix)]
    {
        let d = dir.join("link_out");
        write_set(&d, &cams, &arrays(&cams));
        fs::copy(d.join("image/000002.png"), dir.join("outside.png")).unwrap();
        fs::remove_file(d.join("image/000002.png")).unwrap();
        std::os::unix::fs::symlink(dir.join("outside.png"), d.join("image/000002.png")).unwrap();
        let e = read(&d);
        assert!(
            e.contains("image 2") && e.contains("leads outside the data set"),
            "{e}"
        );
    }
    // A mask of another size than its image, read for `silhouette()`.
    let d = dir.join("mask_size");
    write_set(&d, &cams, &arrays(&cams));
    image::GrayImage::new(12, 9)
        .save(d.join("mask/003.png"))
        .unwrap();
    let e = err(capture::read_for(
        &spec(&d),
        Path::new("/"),
        DataNeeds {
            coverage: true,
            held_out: None,
        },
    ));
    assert!(
        e.contains("003.png") && e.contains("image 3 (000003.png)") && e.contains("12x9"),
        "{e}"
    );
    // Downscaled folders do not exist in this layout.
    let d = dir.join("downscale");
    write_set(&d, &cams, &arrays(&cams));
    let mut s = spec(&d);
    s.downscale = 2;
    let e = err(capture::read(&s, Path::new("/")));
    assert!(e.contains("full-size images only"), "{e}");
}

fn scene(dir: &Path, data: &str, after: &str) -> PathBuf {
    let f = dir.join("scene.sdfl");
    let text = format!(
        r#"let grid = hashgrid(levels: 4, log2_table: 10, min_res: 4, max_res: 24, min: [-1.2, -1.2, -1.2], max: [1.2, 1.2, 1.2])
train fit {{
  model: neus(neural_sdf(encoding: grid, network: mlp(layers: 1, width: 16, skips: []), radius: 0.4), beta: param(0.08), view_dependent: false),
  data: {data},
  sampler: stratified(samples: 16, near: 1.8, far: 4.2, jitter: true),
  rays: 128,
  losses: [mse(), silhouette()],
  optimizer: adam(lr: 1e-2),
  iterations: 3,
  bounds: 1.2,
  after: [{after}],
}}
"#
    );
    fs::write(&f, text).unwrap();
    f
}

/// Whether `stderr` underlines `arg` on the line holding `code`.
fn underlines(stderr: &str, code: &str, arg: &str) -> bool {
    let lines: Vec<&str> = stderr.lines().collect();
    let Some(at) = lines.iter().position(|l| l.contains(code)) else {
        return false;
    };
    let column = |l: &str, s: &str| l.find(s).map(|b| l[..b].chars().count());
    let mark = lines.get(at + 1).copied().unwrap_or_default();
    let start = mark.find(['─', '┬']).map(|b| mark[..b].chars().count());
    start.is_some() && start == column(lines[at], arg)
}

#[test]
fn the_cli_trains_on_an_idr_capture_and_exports_in_the_world_frame() {
    let dir = case_dir("idr_cli");
    let cams = cameras();
    write_set(&dir.join("dtu_scan0"), &cams, &arrays(&cams));
    for data in [
        "capture(\"dtu_scan0\", format: \"idr\", test_every: 3)",
        "capture(\"dtu_scan0\", test_every: 3)",
    ] {
        let f = scene(&dir, data, "mesh(\"m.ply\", resolution: 16)");
        let o = sdfl(&dir, &["check", f.to_str().unwrap()]);
        assert_outcome(data, &o, Expect::Ok);
        let out = dir.join("out");
        let _ = fs::remove_dir_all(&out);
        let o = run_into(&dir, &f, &out, &[]);
        assert_outcome(data, &o, Expect::Ok);
        assert!(o.stderr.contains("unit sphere"), "{}", head(&o.stderr));
        // The mesh of the sphere the SDF starts as (radius 0.4 in the
        // unit sphere's frame) comes back around the world's centre.
        let points = sdfl_runtime::data::points::read_points(&out.join("m.ply")).unwrap();
        assert!(points.len() > 20, "{}", points.len());
        let p: Vec<DVec3> = points
            .iter()
            .map(|p| DVec3::new(p[0] as f64, p[1] as f64, p[2] as f64))
            .collect();
        let mean = p.iter().sum::<DVec3>() / p.len() as f64;
        assert!((mean - CENTRE).length() < 0.1 * SCALE, "{data}: {mean}");
        let r = p.iter().map(|x| (*x - mean).length()).sum::<f64>() / p.len() as f64;
        assert!((r / SCALE - 0.4).abs() < 0.1, "{data}: radius {r}");
    }
    let o = sdfl(
        &dir,
        &[
            "plan",
            scene(&dir, "capture(\"dtu_scan0\")", "").to_str().unwrap(),
        ],
    );
    assert_outcome("plan", &o, Expect::Ok);
    let plan = fs::read_to_string(dir.join("stdout.txt")).unwrap();
    assert!(
        plan.contains("capture dtu_scan0 (auto") && plan.contains("unit sphere"),
        "{plan}"
    );
    assert!(plan.contains("24x18"), "{plan}");

    // Broken sets stop the run with a diagnostic at the capture's path.
    let mut skew = arrays(&cams);
    let mut c = cams[2];
    c.k.y_axis.x = 1.5;
    skew[2 * 4] = array("world_mat_2", &c.world_mat());
    let mut missing = arrays(&cams);
    missing[4].0 = "world_mat_9".into();
    let cases: [(&str, Arrays, &str); 3] = [
        ("skew", skew, "has a skew"),
        ("missing", missing, "no `world_mat_1`"),
        ("masks", arrays(&cams), "5 masks for 6 images"),
    ];
    for (what, a, says) in cases {
        write_set(&dir.join(what), &cams, &a);
        if what == "masks" {
            fs::remove_file(dir.join("masks/mask/002.png")).unwrap();
        }
        let data = format!("capture(\"{what}\", format: \"idr\")");
        let f = scene(&dir, &data, "");
        let o = run_into(&dir, &f, &dir.join("out_bad"), &[]);
        assert_outcome(what, &o, Expect::Error);
        let flat = crate::common::unwrapped(&o.stderr);
        assert!(flat.contains(says), "{what}: {}", head(&o.stderr));
        assert!(
            underlines(&o.stderr, &format!("data: {data}"), &format!("\"{what}\"")),
            "{what}: {}",
            head(&o.stderr)
        );
    }
    // `downscale` is refused by the check for an IDR capture.
    let f = scene(
        &dir,
        "capture(\"dtu_scan0\", format: \"idr\", downscale: 2)",
        "",
    );
    let o = sdfl(&dir, &["check", f.to_str().unwrap()]);
    assert_outcome("downscale", &o, Expect::Error);
    assert!(o.stderr.contains("full-size"), "{}", head(&o.stderr));
}

/// `object_masks: "alpha"` composites each photograph over `background`
/// through its mask (NeuS's "with mask" setting): on the ball the image's
/// own colour, elsewhere the background, where the photograph was grey.
/// Held-out views keep their masks, and held-out PSNR is also given
/// inside them (`psnr_in_mask`); the option is refused where no mask
/// can give the alpha.
#[test]
fn object_masks_as_alpha_composite_the_photographs_and_score_inside_them() {
    let dir = case_dir("idr_alpha");
    let cams = cameras();
    write_set(&dir, &cams, &arrays(&cams));
    let mut s = spec(&dir);
    s.background = Some(DVec3::new(0.0, 0.0, 1.0));
    s.object_masks = ObjectMasks::Alpha;
    s.test_every = 3;
    let v = capture::read(&s, Path::new("/")).unwrap();
    let mut photo = spec(&dir);
    photo.test_every = 3;
    let whole = capture::read(&photo, Path::new("/")).unwrap();
    assert_eq!((v.train.len(), v.test.len()), (4, 2));
    let (mut on, mut off) = (0, 0);
    for (n, (a, b)) in v.train.iter().zip(&whole.train).enumerate() {
        for i in 0..a.image.len() {
            let (got, photo) = (a.image.pixel(i), b.image.pixel(i));
            if photo == [60.0 / 255.0; 3] {
                assert_eq!(got, [0.0, 0.0, 1.0], "view {n} pixel {i}");
                off += 1;
            } else {
                assert_eq!(got, photo, "view {n} pixel {i}");
                on += 1;
            }
        }
        assert!(a.coverage.is_none(), "no `silhouette()` asked for coverage");
    }
    assert!(on > 100 && off > 100, "{on} {off}");
    // Held-out views carry their masks (for PSNR inside them).
    for t in v.test.iter().chain(&whole.test) {
        let c = t.coverage.as_deref().expect("a held-out view's mask");
        assert!(c.contains(&255) && c.contains(&0));
    }
    // No masks: refused, naming the image.
    fs::remove_dir_all(dir.join("mask")).unwrap();
    let e = err(capture::read(&s, Path::new("/")));
    assert!(e.contains("no object mask") && e.contains("image 0"), "{e}");

    // End to end: the report gives the PSNR inside the masks beside the
    // whole image's; `check` refuses alpha without a background.
    let dir = case_dir("idr_alpha_cli");
    write_set(&dir.join("scan"), &cams, &arrays(&cams));
    let f = scene(
        &dir,
        "capture(\"scan\", test_every: 3, object_masks: \"alpha\", background: [0, 0, 0])",
        "",
    );
    let r = run_report(&dir, f.file_name().unwrap().to_str().unwrap());
    let h = &r["held_out"][0];
    let (psnr, inside) = (h["psnr"].as_f64().unwrap(), h["psnr_in_mask"].as_f64());
    assert!(
        psnr.is_finite() && inside.is_some_and(f64::is_finite),
        "{r}"
    );
    assert_ne!(Some(psnr), inside, "{r}");
    let f = scene(&dir, "capture(\"scan\", object_masks: \"alpha\")", "");
    let o = sdfl(&dir, &["check", f.to_str().unwrap()]);
    assert_outcome("alpha without a background", &o, Expect::Error);
    assert!(
        crate::common::unwrapped(&o.stderr).contains("add background: [0, 0, 0]"),
        "{}",
        head(&o.stderr)
    );
}

/// examples/benchmarks/dtu.sdfl, its data path pointed at a small set of
/// IDR's layout, its steps and mesh cut down: it trains with the masks as
/// alpha, reports PSNR inside them and meshes in the world frame.
#[test]
fn the_dtu_benchmark_runs_on_a_set_of_its_layout() {
    let dir = case_dir("benchmark_dtu");
    let cams = cameras();
    write_set(&dir.join("scan"), &cams, &arrays(&cams));
    let example = Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/benchmarks/dtu.sdfl");
    let text = fs::read_to_string(example).unwrap();
    for line in [
        "let data = \"dtu_scan24\"",
        "let steps = 5000",
        "resolution: 256",
        "eval_downscale: 4,",
    ] {
        assert!(text.contains(line), "the example's `{line}` moved");
    }
    let text = text
        .replace("let data = \"dtu_scan24\"", "let data = \"scan\"")
        .replace("let steps = 5000", "let steps = 2")
        .replace("resolution: 256", "resolution: 16")
        // The set's 24×18 views scored at 12×9.
        .replace("eval_downscale: 4,", "eval_downscale: 2,");
    fs::write(dir.join("dtu.sdfl"), text).unwrap();
    let r = run_report(&dir, "dtu.sdfl");
    let h = &r["held_out"][0];
    assert!(
        h["psnr_in_mask"].as_f64().is_some_and(f64::is_finite),
        "{r}"
    );
    let points = sdfl_runtime::data::points::read_points(&dir.join("out/scan.ply")).unwrap();
    let mean = points
        .iter()
        .map(|p| DVec3::new(p[0] as f64, p[1] as f64, p[2] as f64))
        .sum::<DVec3>()
        / points.len().max(1) as f64;
    assert!((mean - CENTRE).length() < 0.1 * SCALE, "{mean}");
    // The comparison shows the views as scored: truth | render | error,
    // each at half the size.
    let comparison = image::open(dir.join("out/scan_test.png")).unwrap();
    assert_eq!(comparison.width(), 3 * W / 2, "{r}");
    assert_eq!(comparison.height() % (H / 2), 0, "{r}");
}
