//! `sdfl view`'s page in a real headless browser (Chromium, Debian's
//! package; `.ci/run` installs it when missing). The page must load the
//! scenes, request a frame and draw it: its frame counter passes 0 and the
//! canvas in a screenshot is not blank.
//!
//! Without a browser these tests say so on stderr and pass, so that the
//! README's test command needs only the Rust toolchain; `.ci/run`, which
//! installs Chromium, sets `SDFL_REQUIRE_BROWSER=1`, under which a missing
//! browser fails them. `SDFL_BROWSER` names another Chromium-like binary.

use crate::common;
use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};

fn temp(name: &str) -> PathBuf {
    common::temp_dir("browser", name)
}

/// The variable under which a missing browser fails the tests.
const REQUIRE: &str = "SDFL_REQUIRE_BROWSER";

/// The browser: `SDFL_BROWSER`, else the first of Chromium's names on
/// PATH; `None` (said on stderr) where there is none and none is required.
fn browser() -> Option<PathBuf> {
    if let Some(b) = std::env::var_os("SDFL_BROWSER") {
        return Some(PathBuf::from(b));
    }
    let names = [
        "chromium",
        "chromium-headless-shell",
        "chromium-browser",
        "google-chrome",
    ];
    let path = std::env::var_os("PATH").unwrap_or_default();
    let found = std::env::split_paths(&path)
        .flat_map(|dir| names.map(|n| dir.join(n)))
        .find(|p| p.is_file());
    let why = format!(
        "no headless browser found (tried {names:?} on PATH): install Debian's `chromium` \
         (`apt-get install -y chromium`, as .ci/run does) or set SDFL_BROWSER"
    );
    match found {
        Some(p) => Some(p),
        None if std::env::var_os(REQUIRE).is_some_and(|v| v != "0") => {
            panic!("{why} ({REQUIRE} is set)")
        }
        None => {
            eprintln!("{why}: the viewer's page is not tested in a browser here");
            None
        }
    }
}

struct Server(Child);

impl Drop for Server {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// `sdfl view` on a free port: the server and its URL.
fn serve(file: &Path, out: &Path) -> (Server, String) {
    let mut child = Command::new(env!("CARGO_BIN_EXE_sdfl"))
        .args(["view", file.to_str().unwrap(), "--port", "0"])
        .args(["--out", out.to_str().unwrap()])
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let mut line = String::new();
    BufReader::new(child.stdout.take().unwrap())
        .read_line(&mut line)
        .unwrap();
    let url = line
        .split_whitespace()
        .find(|w| w.starts_with("http://"))
        .unwrap_or_else(|| panic!("no address in {line:?}"))
        .to_string();
    (Server(child), url)
}

/// Headless Chromium on `url` with `args`, its own profile; stdout.
fn chromium(browser: &Path, profile: &Path, url: &str, args: &[&str]) -> Vec<u8> {
    let out = Command::new(browser)
        .args([
            "--headless",
            // Root in containers has no user namespaces for the sandbox;
            // the page is our own, on 127.0.0.1.
            "--no-sandbox",
            "--disable-gpu",
            "--no-first-run",
            "--hide-scrollbars",
            // JavaScript runs (and fetches complete) for this much virtual
            // time before the DOM or the screenshot is taken.
            "--virtual-time-budget=20000",
            &format!("--user-data-dir={}", profile.display()),
        ])
        .args(args)
        .arg(url)
        .output()
        .expect("the browser starts");
    assert!(
        out.status.success(),
        "the browser failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    out.stdout
}

#[test]
fn the_page_draws_frames_in_a_headless_browser() {
    let Some(browser) = browser() else { return };
    let dir = temp("page");
    let file = dir.join("scene.sdfl");
    std::fs::write(
        &file,
        "render ball {\n\
           scene: union(sphere(0.8), box(size: [0.5, 0.5, 0.5], center: [1, 0, 0])),\n\
           material: lambert(albedo: [0.9, 0.5, 0.3], light: [1, 1, -1]),\n\
           camera: look_at(eye: [1, 1, -3], at: [0, 0, 0], up: [0, 1, 0], focal: 1.5),\n\
           size: [64, 64], background: [0, 0, 0],\n\
           outputs: [image(\"ball.png\")],\n\
         }\n",
    )
    .unwrap();
    let (_server, url) = serve(&file, &dir.join("out"));

    let dom = chromium(&browser, &dir.join("profile-dom"), &url, &["--dump-dom"]);
    let dom = String::from_utf8_lossy(&dom);
    let frames: u64 = dom
        .split("data-frames=\"")
        .nth(1)
        .and_then(|r| r.split('"').next())
        .and_then(|n| n.parse().ok())
        .unwrap_or_else(|| panic!("no frame counter in the page: {dom}"));
    assert!(frames > 0, "the page drew no frame: {dom}");
    assert!(dom.contains("ball (2 primitives)"), "{dom}");

    let shot = dir.join("shot.png");
    chromium(
        &browser,
        &dir.join("profile-shot"),
        &url,
        &[
            &format!("--screenshot={}", shot.display()),
            "--window-size=800,600",
        ],
    );
    let img = image::open(&shot).unwrap().to_rgb8();
    // The canvas starts at (12, 40) and is 512 px wide: the ball, shaded
    // orange, lies within it on a black background.
    let orange = (12..524)
        .flat_map(|x| (40..552).map(move |y| (x, y)))
        .filter(|&(x, y)| x < img.width() && y < img.height())
        .filter(|&(x, y)| {
            let p = img.get_pixel(x, y).0;
            p[0] > 60 && p[0] > p[2] + 30
        })
        .count();
    assert!(
        orange > 5000,
        "the canvas shows no scene ({orange} orange pixels); screenshot at {}",
        shot.display()
    );
}

#[test]
fn the_page_shows_a_trained_field_and_its_training_panel() {
    let Some(browser) = browser() else { return };
    let dir = temp("field");
    let (file, out) = (dir.join("fit.sdfl"), dir.join("out"));
    std::fs::write(
        &file,
        "let target = sdf_volume(sphere(1), color: [0.2, 0.6, 0.9])\n\
         train fit {\n\
           model: sdf_volume(sphere(1, center: param([0.3, 0.2, 0])), color: param([0.3, 0.1, 0.1])),\n\
           data: render_views(target, cameras: [look_at(eye: [0, 0, -3]), look_at(eye: [3, 0, 0]), look_at(eye: [0, 3, 0.1])], size: [16, 16], sampler: stratified(samples: 8, near: 0, far: 6), test_views: 1),\n\
           sampler: stratified(samples: 8, near: 0, far: 6), rays: 64, optimizer: adam(lr: 5e-2), iterations: 30,\n\
           eval_every: 5, checkpoint: \"fit.ckpt\",\n\
         }\n",
    )
    .unwrap();
    let run = Command::new(env!("CARGO_BIN_EXE_sdfl"))
        .args([
            "run",
            file.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ])
        .output()
        .unwrap();
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    let (_server, url) = serve(&file, &out);

    let dom = chromium(&browser, &dir.join("profile-dom"), &url, &["--dump-dom"]);
    let dom = String::from_utf8_lossy(&dom);
    let frames: u64 = dom
        .split("data-frames=\"")
        .nth(1)
        .and_then(|r| r.split('"').next())
        .and_then(|n| n.parse().ok())
        .unwrap_or_else(|| panic!("no frame counter in the page: {dom}"));
    assert!(frames > 0, "the page drew no frame of the field: {dom}");
    for shown in [
        "fit (trained field)",
        "train fit",
        "step 30 of 30",
        "held-out PSNR (dB)",
        "/api/heldout?train=fit",
        "field on view: checkpoint of step 30",
    ] {
        assert!(dom.contains(shown), "the page lacks {shown:?}: {dom}");
    }

    let shot = dir.join("shot.png");
    chromium(
        &browser,
        &dir.join("profile-shot"),
        &url,
        &[
            &format!("--screenshot={}", shot.display()),
            "--window-size=1000,700",
        ],
    );
    let img = image::open(&shot).unwrap().to_rgb8();
    let count =
        |xs: std::ops::Range<u32>, ys: std::ops::Range<u32>, f: &dyn Fn([u8; 3]) -> bool| {
            xs.flat_map(|x| ys.clone().map(move |y| (x, y)))
                .filter(|&(x, y)| x < img.width() && y < img.height() && f(img.get_pixel(x, y).0))
                .count()
        };
    // The canvas (from (12, 40), 512 px) shows the field: many colours.
    let mut colours = std::collections::HashSet::new();
    for x in (12..524).step_by(4) {
        for y in (40..552).step_by(4) {
            colours.insert(img.get_pixel(x, y).0);
        }
    }
    assert!(
        colours.len() > 50,
        "the canvas shows no field ({} colours); screenshot at {}",
        colours.len(),
        shot.display()
    );
    // The panel to its right draws the loss curve (#6cf).
    let loss = count(540..1000, 0..700, &|p| {
        p[0].abs_diff(0x66) < 40 && p[1].abs_diff(0xcc) < 40 && p[2] > 0xd0
    });
    assert!(
        loss > 50,
        "no loss curve in the panel ({loss} pixels); screenshot at {}",
        shot.display()
    );
}
