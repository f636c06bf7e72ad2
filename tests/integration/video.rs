//! `video(...)`: an MP4 through the ffmpeg found (`SDFL_FFMPEG`, else
//! `PATH`), and the GIF fallback, said once, where none is found or it
//! fails. A fake ffmpeg (a shell script recording its arguments and
//! copying its input) checks the command and the frames; a real one, where
//! installed, checks that the file plays back at its size.

use std::fs;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

use crate::common::case_dir;

/// Six 33 × 21 views (odd sides: the video pads them to 34 × 22).
const SCENE: &str = r#"
render spin {
  scene: torus(major: 1, minor: 0.25),
  material: rainbow(),
  camera: orbit(radius: 3, up: [0, 0, 1], views: 6),
  size: [33, 21],
  far: 5,
  outputs: [video("clips/spin.mp4", fps: 12)],
}
"#;

/// A fake ffmpeg: records its arguments in `args.txt` beside it, and copies
/// its input to its last argument (or discards it for `-`); `exit` is its
/// status after that, `say` what it prints on stderr.
fn fake_ffmpeg(dir: &Path, exit: u8, say: &str) -> PathBuf {
    let path = dir.join("ffmpeg");
    let script = format!(
        "#!/bin/sh\nprintf '%s\\n' \"$*\" >> '{}'\nfor last; do :; done\nif [ \"$last\" = - ]; then cat > /dev/null; else cat > \"$last\"; fi\necho '{say}' >&2\nexit {exit}\n",
        dir.join("args.txt").display()
    );
    fs::write(&path, script).unwrap();
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        fs::set_permissions(&path, fs::Permissions::from_mode(0o755)).unwrap();
    }
    path
}

/// Runs `sdfl run --json` on [`SCENE`] in `dir` with `env` (and nothing
/// else of this process's ffmpeg settings), under umask 027: the exit
/// status, stderr and the JSON report.
fn run(dir: &Path, env: &[(&str, &str)]) -> (bool, String, serde_json::Value) {
    fs::write(dir.join("spin.sdfl"), SCENE).unwrap();
    let sdfl = env!("CARGO_BIN_EXE_sdfl");
    let mut cmd = Command::new("/bin/sh");
    cmd.arg("-c")
        .arg("umask 027 && exec \"$0\" run spin.sdfl --out out --json")
        .arg(sdfl)
        .current_dir(dir)
        .env_remove("SDFL_FFMPEG")
        .stdin(Stdio::null());
    for (k, v) in env {
        cmd.env(k, v);
    }
    let o = cmd.output().unwrap();
    let stderr = String::from_utf8_lossy(&o.stderr).into_owned();
    let json = serde_json::from_slice(&o.stdout).unwrap_or(serde_json::Value::Null);
    (o.status.success(), stderr, json)
}

fn written(json: &serde_json::Value) -> Vec<serde_json::Value> {
    json["jobs"][0]["report"]["written"]
        .as_array()
        .cloned()
        .unwrap_or_default()
}

/// No file of the output directory is a temporary one.
fn no_temporaries(out: &Path) {
    for e in fs::read_dir(out).unwrap().flatten() {
        let name = e.file_name().to_string_lossy().into_owned();
        assert!(!name.ends_with(".tmp"), "left behind: {name}");
        if e.file_type().unwrap().is_dir() {
            no_temporaries(&e.path());
        }
    }
}

#[cfg(unix)]
fn mode(p: &Path) -> u32 {
    use std::os::unix::fs::PermissionsExt;
    fs::metadata(p).unwrap().permissions().mode() & 0o777
}

/// The fallback's warning, once, naming the GIF; the GIF holds every frame.
fn assert_fell_back(dir: &Path, ok: bool, stderr: &str, json: &serde_json::Value, why: &str) {
    assert!(ok, "{stderr}");
    let warnings: Vec<&str> = stderr
        .lines()
        .filter(|l| l.starts_with("warning[sdfl::warn::video-fallback]"))
        .collect();
    assert_eq!(warnings.len(), 1, "{stderr}");
    assert!(warnings[0].contains("`clips/spin.gif`"), "{stderr}");
    assert!(warnings[0].contains(why), "{stderr}");
    let out = dir.join("out/clips");
    assert!(!out.join("spin.mp4").exists());
    let gif = image::open(out.join("spin.gif")).unwrap();
    assert_eq!((gif.width(), gif.height()), (33, 21));
    let w = written(json);
    assert_eq!(w.len(), 1, "{json}");
    assert_eq!(w[0]["kind"], "gif");
    assert_eq!(w[0]["path"], "clips/spin.gif");
    assert_eq!(w[0]["frames"], 6);
    assert_eq!(w[0]["warning"]["code"], sdfl_runtime::video::FALLBACK);
    assert!(
        w[0]["warning"]["message"].as_str().unwrap().contains(why),
        "{json}"
    );
    no_temporaries(&dir.join("out"));
}

#[test]
fn without_ffmpeg_the_video_is_a_gif_and_the_run_says_so() {
    let dir = case_dir("no_ffmpeg");
    // A PATH with no ffmpeg on it.
    let empty = dir.join("bin");
    fs::create_dir_all(&empty).unwrap();
    let (ok, stderr, json) = run(&dir, &[("PATH", empty.to_str().unwrap())]);
    assert_fell_back(&dir, ok, &stderr, &json, "no `ffmpeg` was found on PATH");
    // A missing SDFL_FFMPEG is named.
    let missing = dir.join("nowhere/ffmpeg");
    let (ok, stderr, json) = run(&dir, &[("SDFL_FFMPEG", missing.to_str().unwrap())]);
    assert_fell_back(&dir, ok, &stderr, &json, "SDFL_FFMPEG names");
}

#[test]
fn an_ffmpeg_that_fails_leaves_the_gif_and_its_words() {
    let dir = case_dir("failing_ffmpeg");
    let bin = dir.join("bin");
    fs::create_dir_all(&bin).unwrap();
    let ffmpeg = fake_ffmpeg(&bin, 1, "Unknown encoder libx264");
    let (ok, stderr, json) = run(&dir, &[("SDFL_FFMPEG", ffmpeg.to_str().unwrap())]);
    assert_fell_back(&dir, ok, &stderr, &json, "Unknown encoder libx264");
    // Only the one-frame check ran: nothing was encoded.
    let args = fs::read_to_string(bin.join("args.txt")).unwrap();
    assert_eq!(args.lines().count(), 1, "{args}");
    assert!(args.contains("-f null -"), "{args}");
}

#[test]
fn frames_are_piped_to_ffmpeg_as_rgb24_at_even_sides() {
    let dir = case_dir("fake_ffmpeg");
    let bin = dir.join("bin");
    fs::create_dir_all(&bin).unwrap();
    fake_ffmpeg(&bin, 0, "");
    // Found on PATH, before any real one.
    let path = format!("{}:/usr/bin:/bin", bin.display());
    let (ok, stderr, json) = run(&dir, &[("PATH", &path)]);
    assert!(ok, "{stderr}");
    assert!(!stderr.contains("warning"), "{stderr}");
    let args = fs::read_to_string(bin.join("args.txt")).unwrap();
    let lines: Vec<&str> = args.lines().collect();
    assert_eq!(lines.len(), 2, "the check, then the video: {args}");
    let command =
        "-f rawvideo -pix_fmt rgb24 -s 34x22 -r 12 -i - -c:v libx264 -pix_fmt yuv420p -crf 18";
    for l in &lines {
        assert!(l.contains(command), "{l}");
    }
    assert!(lines[0].ends_with("-f null -"), "{}", lines[0]);
    // Written to a temporary file in the output directory, renamed.
    let tmp = lines[1].rsplit(' ').next().unwrap();
    let out = dir.join("out/clips");
    assert_eq!(
        Path::new(tmp).parent(),
        Some(fs::canonicalize(&out).unwrap().as_path())
    );
    assert!(tmp.ends_with(".tmp"), "{tmp}");
    no_temporaries(&dir.join("out"));
    // The fake copied the frames: 6 of 34 × 22 RGB, the 33rd column and
    // 21st row repeated into the 34th and 22nd.
    let raw = fs::read(out.join("spin.mp4")).unwrap();
    let (w, h) = (34, 22);
    assert_eq!(raw.len(), 6 * w * h * 3);
    let px = |f: usize, x: usize, y: usize| &raw[((f * h + y) * w + x) * 3..][..3];
    for f in 0..6 {
        for y in 0..h {
            assert_eq!(px(f, 33, y), px(f, 32, y), "frame {f} row {y}");
        }
        for x in 0..w {
            assert_eq!(px(f, x, 21), px(f, x, 20), "frame {f} column {x}");
        }
    }
    // Some frame shows the torus (not all black).
    assert!(raw.iter().any(|&b| b > 0));
    #[cfg(unix)]
    assert_eq!(mode(&out.join("spin.mp4")), 0o640, "the umask is kept");
    let w = written(&json);
    assert_eq!(w.len(), 1, "{json}");
    assert_eq!(w[0]["kind"], "video");
    assert_eq!(w[0]["path"], "clips/spin.mp4");
    assert_eq!(
        (w[0]["width"].as_u64(), w[0]["height"].as_u64()),
        (Some(34), Some(22))
    );
    assert_eq!(w[0]["frames"], 6);
    assert!(w[0].get("warning").is_none(), "{json}");
}

#[test]
fn a_real_ffmpeg_writes_a_video_that_decodes_at_its_size() {
    // Where no ffmpeg is installed there is nothing to play it back with;
    // the fake one above checks the command and the frames.
    let Some(ffmpeg) = std::env::var_os("PATH").and_then(|p| {
        std::env::split_paths(&p)
            .map(|d| d.join("ffmpeg"))
            .find(|f| f.is_file())
    }) else {
        eprintln!("no ffmpeg on PATH: the MP4 is checked with a fake one only");
        return;
    };
    let dir = case_dir("real_ffmpeg");
    let (ok, stderr, json) = run(&dir, &[("SDFL_FFMPEG", ffmpeg.to_str().unwrap())]);
    assert!(ok, "{stderr}");
    let w = written(&json);
    if w.first().is_some_and(|w| w["warning"].is_object()) {
        // An ffmpeg without libx264 is a fallback, said as such.
        assert!(stderr.contains("video-fallback"), "{stderr}");
        return;
    }
    assert_eq!(w[0]["kind"], "video", "{json}");
    let mp4 = dir.join("out/clips/spin.mp4");
    let decoded = Command::new(&ffmpeg)
        .args(["-v", "error", "-i"])
        .arg(&mp4)
        .args(["-f", "rawvideo", "-pix_fmt", "rgb24", "-"])
        .stdin(Stdio::null())
        .output()
        .unwrap();
    assert!(
        decoded.status.success(),
        "{}",
        String::from_utf8_lossy(&decoded.stderr)
    );
    assert_eq!(decoded.stdout.len(), 6 * 34 * 22 * 3);
    // H.264 at crf 18: close to the frames, not equal.
    assert!(decoded.stdout.iter().any(|&b| b > 32));
}

/// A fit to four 48 × 32 views, with nothing said of its before/after views.
const FIT: &str = r#"
let cameras = for eye in [[0, 0, -3], [2.6, 0, -1.5], [0, 2.6, -1.5], [-2.6, 0, 1.5]] { look_at(eye: eye) }
let target = sdf_volume(torus(major: 1.0, minor: 0.25), color: [0.9, 0.5, 0.2])

train fit {
  model: sdf_volume(torus(major: param(0.8), minor: param(0.3)), color: [0.9, 0.5, 0.2]),
  data: render_views(target, cameras: cameras, size: [48, 32], sampler: stratified(samples: 16, near: 0, far: 6)),
  sampler: stratified(samples: 16, near: 0, far: 6),
  rays: 64, iterations: 1,
  after: [video("fit.mp4")],
}
"#;

#[test]
fn a_fit_is_seen_along_its_training_cameras_at_their_aspect() {
    let dir = case_dir("fit_path");
    let bin = dir.join("bin");
    fs::create_dir_all(&bin).unwrap();
    let ffmpeg = fake_ffmpeg(&bin, 0, "");
    fs::write(dir.join("fit.sdfl"), FIT).unwrap();
    let o = Command::new(env!("CARGO_BIN_EXE_sdfl"))
        .args(["run", "fit.sdfl", "--out", "out", "--json"])
        .current_dir(&dir)
        .env("SDFL_FFMPEG", &ffmpeg)
        .stdin(Stdio::null())
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{stderr}");
    // 48 × 32 data: 128 pixels on the shorter side, 192 on the longer;
    // training_path()'s 60 frames.
    let args = fs::read_to_string(bin.join("args.txt")).unwrap();
    assert!(
        args.lines().all(|l| l.contains("-s 192x128 -r 24 ")),
        "{args}"
    );
    let raw = fs::read(dir.join("out/fit.mp4")).unwrap();
    assert_eq!(raw.len(), 60 * 192 * 128 * 3);
    let json: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let w = written(&json);
    let video = w.iter().find(|w| w["kind"] == "video").expect("a video");
    assert_eq!(
        (video["width"].as_u64(), video["height"].as_u64()),
        (Some(192), Some(128))
    );
    assert_eq!(video["frames"], 60);
}

#[test]
fn views_read_from_files_give_their_aspect_once_read() {
    let dir = case_dir("files_path");
    let bin = dir.join("bin");
    fs::create_dir_all(&bin).unwrap();
    let ffmpeg = fake_ffmpeg(&bin, 0, "");
    // Three portrait 30 × 50 photographs: 128 wide, 214 (213.3 rounded to
    // even) tall.
    for k in 0..3 {
        let img = image::RgbImage::from_pixel(30, 50, image::Rgb([40 * k, 90, 200]));
        img.save(dir.join(format!("v{k}.png"))).unwrap();
    }
    let scene = r#"
train fit {
  model: sdf_volume(sphere(radius: param(0.5)), color: param([0.5, 0.5, 0.5])),
  data: views(["v0.png", "v1.png", "v2.png"], cameras: [look_at([0, 0, -3]), look_at([3, 0, 0]), look_at([0, 3, 0.1])]),
  sampler: stratified(samples: 8, near: 1, far: 5),
  rays: 16, iterations: 1,
  views: training_path(frames: 5),
  after: [video("files.mp4", fps: 10)],
}
"#;
    fs::write(dir.join("files.sdfl"), scene).unwrap();
    let o = Command::new(env!("CARGO_BIN_EXE_sdfl"))
        .args(["run", "files.sdfl", "--out", "out"])
        .current_dir(&dir)
        .env("SDFL_FFMPEG", &ffmpeg)
        .stdin(Stdio::null())
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let args = fs::read_to_string(bin.join("args.txt")).unwrap();
    assert!(
        args.lines().all(|l| l.contains("-s 128x214 -r 10 ")),
        "{args}"
    );
    let raw = fs::read(dir.join("out/files.mp4")).unwrap();
    assert_eq!(raw.len(), 5 * 128 * 214 * 3);
}
