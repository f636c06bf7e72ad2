//! `sdfl view`'s HTTP API, driven as a browser would: the binary started
//! with `--port 0`, requests over a plain TcpStream.

use crate::common;
use std::io::{BufRead, BufReader, Read, Write};
use std::net::TcpStream;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::Duration;

fn temp(name: &str) -> PathBuf {
    common::temp_dir("view", name)
}

/// Saved as editors do: written beside, then renamed into place.
fn save(file: &Path, text: &str) {
    let tmp = file.with_extension("sdfl~");
    std::fs::write(&tmp, text).unwrap();
    std::fs::rename(&tmp, file).unwrap();
}

/// A render of a non-square image and a training run (never run here).
fn scene(radius: f64) -> String {
    format!(
        "let target = sdf_volume(sphere(1), color: [0.2, 0.6, 0.9])\n\
         render ball {{\n\
           scene: union(sphere({radius}), box(size: [0.5, 0.5, 0.5], center: [1, 0, 0])),\n\
           material: lambert(albedo: [0.9, 0.5, 0.3], light: [1, 1, -1]),\n\
           camera: look_at(eye: [1, 1, -3], at: [0, 0, 0], up: [0, 1, 0], focal: 1.5),\n\
           size: [48, 32],\n\
           outputs: [image(\"ball.png\")],\n\
         }}\n\
         train fit {{\n\
           model: sdf_volume(sphere(1, center: param([0.3, 0.2, 0])), color: param([0.3, 0.1, 0.1])),\n\
           data: render_views(target, cameras: [look_at(eye: [0, 0, -3])], size: [16, 16], sampler: stratified(samples: 8, near: 0, far: 6)),\n\
           sampler: stratified(samples: 8, near: 0, far: 6), rays: 64, optimizer: adam(lr: 1e-2), iterations: 10,\n\
         }}\n"
    )
}

/// `sdfl view FILE --port 0`, stopped when dropped.
struct Server {
    child: Child,
    addr: String,
}

impl Server {
    fn start(file: &Path, out: &Path) -> Server {
        let mut child = Command::new(env!("CARGO_BIN_EXE_sdfl"))
            .args(["view", file.to_str().unwrap(), "--port", "0"])
            .args(["--out", out.to_str().unwrap(), "--threads", "2"])
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .unwrap();
        let mut line = String::new();
        BufReader::new(child.stdout.take().unwrap())
            .read_line(&mut line)
            .unwrap();
        let addr = line
            .split("http://")
            .nth(1)
            .and_then(|r| r.split('/').next())
            .unwrap_or_else(|| panic!("no address in {line:?}"))
            .to_string();
        assert!(addr.starts_with("127.0.0.1:"), "served on {addr}");
        Server { child, addr }
    }

    /// (status, body) of `GET target`.
    fn get(&self, target: &str) -> (u16, Vec<u8>) {
        self.raw(&format!(
            "GET {target} HTTP/1.1\r\nHost: {}\r\nConnection: close\r\n\r\n",
            self.addr
        ))
    }

    /// (status, body) of a raw request.
    fn raw(&self, request: &str) -> (u16, Vec<u8>) {
        let mut s = TcpStream::connect(&self.addr).unwrap();
        s.set_read_timeout(Some(Duration::from_secs(120))).unwrap();
        s.write_all(request.as_bytes()).unwrap();
        let mut bytes = Vec::new();
        let _ = s.read_to_end(&mut bytes);
        let split = bytes
            .windows(4)
            .position(|w| w == b"\r\n\r\n")
            .unwrap_or_else(|| panic!("no response to {request:?}: {bytes:?}"));
        let head = String::from_utf8_lossy(&bytes[..split]).into_owned();
        let status = head
            .split_whitespace()
            .nth(1)
            .and_then(|s| s.parse().ok())
            .unwrap_or_else(|| panic!("bad status line: {head}"));
        (status, bytes[split + 4..].to_vec())
    }

    fn json(&self, target: &str) -> serde_json::Value {
        let (status, body) = self.get(target);
        assert_eq!(status, 200, "{}", String::from_utf8_lossy(&body));
        serde_json::from_slice(&body).unwrap()
    }
}

impl Drop for Server {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

fn triple(v: &serde_json::Value) -> String {
    let a: Vec<String> = v
        .as_array()
        .unwrap()
        .iter()
        .map(|x| format!("{}", x.as_f64().unwrap()))
        .collect();
    a.join(",")
}

#[test]
fn a_frame_is_the_run_s_render_of_the_same_camera() {
    let dir = temp("frame");
    let (file, out) = (dir.join("scene.sdfl"), dir.join("out"));
    save(&file, &scene(0.8));
    let run = Command::new(env!("CARGO_BIN_EXE_sdfl"))
        .args([
            "run",
            file.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ])
        .output()
        .unwrap();
    // The training run is not needed: only the render's image.
    let ran = image::open(out.join("ball.png"));
    let ran = match ran {
        Ok(i) => i.to_rgb8(),
        Err(e) => panic!("{e}: {}", String::from_utf8_lossy(&run.stderr)),
    };
    let server = Server::start(&file, &out);
    let scenes = server.json("/api/scenes");
    let ball = &scenes["scenes"][0];
    assert_eq!(ball["name"], "ball");
    assert_eq!(
        (ball["width"].as_u64(), ball["height"].as_u64()),
        (Some(48), Some(32))
    );
    let target = format!(
        "/api/frame?scene=ball&eye={}&at={}&up={}&focal={}&size=48x32",
        triple(&ball["eye"]),
        triple(&ball["at"]),
        triple(&ball["up"]),
        ball["focal"]
    );
    let (status, png) = server.get(&target);
    assert_eq!(status, 200, "{}", String::from_utf8_lossy(&png));
    let frame = image::load_from_memory(&png).unwrap().to_rgb8();
    assert_eq!(frame.dimensions(), (48, 32));
    let worst = frame
        .as_raw()
        .iter()
        .zip(ran.as_raw())
        .map(|(a, b)| a.abs_diff(*b))
        .max()
        .unwrap();
    assert!(
        worst <= 2,
        "the frame differs from `sdfl run`'s by {worst} levels"
    );
    // Another size and a draft: other pixels, the asked size.
    let (status, png) = server.get(&target.replace("48x32", "64x64&draft=1"));
    assert_eq!(status, 200);
    let small = image::load_from_memory(&png).unwrap();
    assert_eq!((small.width(), small.height()), (64, 64));
    // A camera elsewhere sees something else.
    let (_, moved) = server.get(&target.replace("eye=", "eye=0.5,2,-2&was="));
    let moved = image::load_from_memory(&moved).unwrap().to_rgb8();
    assert_ne!(moved.as_raw(), frame.as_raw());
}

#[test]
fn the_version_bumps_when_the_file_is_saved_and_errors_are_shown() {
    let dir = temp("version");
    let (file, out) = (dir.join("scene.sdfl"), dir.join("out"));
    save(&file, &scene(0.8));
    let server = Server::start(&file, &out);
    let v0 = server.json("/api/version");
    assert_eq!(v0["ok"], true);
    let v0 = v0["version"].as_u64().unwrap();
    let primitives = |s: &Server| s.json("/api/scenes")["scenes"][0]["primitives"].clone();
    assert_eq!(primitives(&server), 2);

    // A bounded wait for the reload (a guard, not a timing assertion).
    let wait_past = |v: u64| {
        for _ in 0..600 {
            let now = server.json("/api/version");
            if now["version"].as_u64().unwrap() > v {
                return now;
            }
            std::thread::sleep(Duration::from_millis(100));
        }
        panic!("the version never passed {v}");
    };
    save(
        &file,
        &scene(0.8).replace("size: [48, 32]", "size: [40, 40]"),
    );
    let v1 = wait_past(v0);
    assert_eq!(v1["ok"], true);
    assert_eq!(server.json("/api/scenes")["scenes"][0]["width"], 40);

    save(&file, &scene(0.8).replace("union(", "union(("));
    let v2 = wait_past(v1["version"].as_u64().unwrap());
    assert_eq!(v2["ok"], false);
    assert!(
        v2["diagnostics"].as_str().unwrap().contains("error"),
        "{v2}"
    );
    assert_eq!(server.json("/api/scenes")["scenes"], serde_json::json!([]));
    let (status, _) = server.get("/api/frame?scene=ball&eye=0,0,-3&at=0,0,0&size=8x8");
    assert_eq!(status, 404);
}

#[test]
fn hostile_requests_are_refused_and_the_server_carries_on() {
    let dir = temp("hostile");
    let (file, out) = (dir.join("scene.sdfl"), dir.join("out"));
    save(&file, &scene(0.8));
    std::fs::create_dir_all(&out).unwrap();
    std::fs::write(dir.join("secret.txt"), "secret").unwrap();
    let server = Server::start(&file, &out);
    let frame = "/api/frame?scene=ball&eye=1,1,-3&at=0,0,0";
    let cases: &[(&str, u16)] = &[
        ("/../secret.txt", 404),
        ("/api/../../secret.txt", 404),
        ("/api/frame", 400),
        ("/api/frame?scene=../../secret", 400),
        ("/api/frame?scene=nope&eye=1,1,1&at=0,0,0&size=8x8", 404),
        (&format!("{frame}&size=100000x100000"), 400),
        (&format!("{frame}&size=1024x1025"), 400),
        (&format!("{frame}&size=0x8"), 400),
        (&format!("{frame}&size=-8x8"), 400),
        (&format!("{frame}&size=8x8&focal=0"), 400),
        (&format!("{frame}&size=8x8&focal=nan"), 400),
        (&format!("{frame}&size=8x8&up=0,0,0"), 400),
        ("/api/frame?scene=ball&eye=0,0,0&at=0,0,0&size=8x8", 400),
        ("/api/frame?scene=ball&eye=1e300,0,0&at=0,0,0&size=8x8", 400),
        ("/api/frame?scene=ball&eye=inf,0,0&at=0,0,0&size=8x8", 400),
        ("/api/frame?scene=ball&eye=1,2&at=0,0,0&size=8x8", 400),
        ("/api/frame?scene=%ZZ", 400),
        ("/api/heldout?train=../secret.txt", 400),
        ("/api/heldout?train=secret", 404),
        ("/api/heldout?train=fit", 404),
        ("/api/heldout", 400),
    ];
    for (target, want) in cases {
        let (status, body) = server.get(target);
        assert_eq!(
            status,
            *want,
            "{target}: {}",
            String::from_utf8_lossy(&body)
        );
        assert!(!body.is_empty(), "{target}: a refusal says why");
        assert!(!String::from_utf8_lossy(&body).contains("secret\n"));
    }
    let long = format!("/api/frame?scene={}", "a".repeat(5000));
    assert_eq!(server.get(&long).0, 414);
    let (status, _) = server.raw(&format!(
        "POST /api/frame HTTP/1.1\r\nHost: {}\r\nContent-Length: 0\r\nConnection: close\r\n\r\n",
        server.addr
    ));
    assert_eq!(status, 405);
    let (status, _) = server
        .raw("GET /api/version HTTP/1.1\r\nHost: evil.example:80\r\nConnection: close\r\n\r\n");
    assert_eq!(status, 403);
    // Garbage on the socket, then the server still answers.
    {
        let mut s = TcpStream::connect(&server.addr).unwrap();
        let _ = s.write_all(b"\x00\xff\r\n\r\nGARBAGE / HTTP/9\r\n\r\n");
    }
    assert_eq!(server.json("/api/version")["ok"], true);
}

#[test]
fn training_metrics_and_the_held_out_view_are_read_from_out() {
    let dir = temp("train");
    let (file, out) = (dir.join("scene.sdfl"), dir.join("out"));
    save(&file, &scene(0.8));
    std::fs::create_dir_all(&out).unwrap();
    let server = Server::start(&file, &out);
    let t = server.json("/api/train");
    assert_eq!(t["trains"][0]["name"], "fit");
    assert!(t["trains"][0]["metrics"].is_null());
    assert_eq!(t["trains"][0]["heldout"], false);

    // As a run in another process writes them.
    std::fs::write(
        out.join("fit.metrics.csv"),
        "step,seconds,loss,lr,psnr,ssim\n1,0.1,0.5,0.01,,\n2,0.2,0.25,0.01,20.5,0.75\n",
    )
    .unwrap();
    let img = image::RgbImage::from_pixel(6, 3, image::Rgb([10, 200, 30]));
    img.save(out.join("fit.heldout.png")).unwrap();
    let t = server.json("/api/train");
    let m = &t["trains"][0]["metrics"];
    assert_eq!(m["step"], serde_json::json!([1.0, 2.0]));
    assert_eq!(m["loss"], serde_json::json!([0.5, 0.25]));
    assert_eq!(m["psnr"], serde_json::json!([[2.0, 20.5]]));
    assert_eq!(t["trains"][0]["heldout"], true);
    let (status, png) = server.get("/api/heldout?train=fit");
    assert_eq!(status, 200);
    assert_eq!(image::load_from_memory(&png).unwrap().to_rgb8(), img);
}

/// A fit whose field is kept in `fit.ckpt` (`iterations` steps), with a
/// held-out view scored every 5 steps.
fn training(iterations: usize, shape: &str) -> String {
    format!(
        "let target = sdf_volume(sphere(1), color: [0.2, 0.6, 0.9])\n\
         train fit {{\n\
           model: sdf_volume({shape}, color: param([0.3, 0.1, 0.1])),\n\
           data: render_views(target, cameras: [look_at(eye: [0, 0, -3]), look_at(eye: [3, 0, 0]), look_at(eye: [0, 3, 0.1])], size: [16, 16], sampler: stratified(samples: 8, near: 0, far: 6), test_views: 1),\n\
           sampler: stratified(samples: 8, near: 0, far: 6), rays: 64, optimizer: adam(lr: 5e-2), iterations: {iterations},\n\
           eval_every: 5, checkpoint: \"fit.ckpt\",\n\
         }}\n"
    )
}

const SPHERE: &str = "sphere(1, center: param([0.3, 0.2, 0]))";

/// `sdfl run FILE --out OUT`, which must succeed.
fn run(file: &Path, out: &Path) {
    let run = Command::new(env!("CARGO_BIN_EXE_sdfl"))
        .args([
            "run",
            file.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ])
        .args(["--threads", "2"])
        .output()
        .unwrap();
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
}

const FIELD: &str = "/api/field?train=fit&eye=0.5,0.4,-3&at=0,0,0&up=0,1,0&focal=1.5";

#[test]
fn a_trained_field_is_rendered_from_its_latest_checkpoint() {
    let dir = temp("field");
    let (file, out) = (dir.join("fit.sdfl"), dir.join("out"));
    save(&file, &training(10, SPHERE));
    run(&file, &out);
    let server = Server::start(&file, &out);
    let scenes = server.json("/api/scenes");
    let fit = &scenes["scenes"][0];
    assert_eq!(
        (&fit["kind"], &fit["name"]),
        (&"train".into(), &"fit".into())
    );
    assert!(fit["moving"].as_u64().unwrap() < fit["still"][0].as_u64().unwrap());
    // With no views of its own, the page starts at the first training
    // camera its checkpoint records (one of the three is held out), turned
    // about the middle of the field.
    let eyes = [[0.0, 0.0, -3.0], [3.0, 0.0, 0.0], [0.0, 3.0, 0.1]];
    let recorded = fit["training_cameras"].as_array().unwrap();
    assert_eq!(recorded.len(), 2, "{fit}");
    let eye_of = |v: &serde_json::Value| -> [f64; 3] { serde_json::from_value(v.clone()).unwrap() };
    for c in recorded {
        let e = eye_of(&c["eye"]);
        assert!(
            eyes.iter()
                .any(|w| (0..3).all(|i| (w[i] - e[i]).abs() < 1e-12)),
            "{c}"
        );
    }
    assert_eq!(fit["eye"], recorded[0]["eye"], "{fit}");
    let at = eye_of(&fit["at"]);
    assert!(at.iter().all(|x| x.abs() < 1e-9), "{fit}");

    let frame = |target: &str| {
        let (status, png) = server.get(target);
        assert_eq!(status, 200, "{}", String::from_utf8_lossy(&png));
        image::load_from_memory(&png).unwrap().to_rgb8()
    };
    let first = frame(&format!("{FIELD}&size=40x24"));
    assert_eq!(first.dimensions(), (40, 24));
    // The sphere, bluish where it is, in front of a background.
    let colours: std::collections::HashSet<_> = first.pixels().map(|p| p.0).collect();
    assert!(colours.len() > 10, "a flat frame: {colours:?}");
    let shown = |s: &Server| s.json("/api/train")["trains"][0]["field_step"].clone();
    assert_eq!(shown(&server), 10);

    // Training goes on in another process (another file, the same model,
    // the same checkpoint), as `sdfl run` beside `sdfl view` does.
    let longer = dir.join("longer.sdfl");
    std::fs::write(&longer, training(40, SPHERE)).unwrap();
    run(&longer, &out);
    // A frame while the camera moves keeps the field as read…
    let draft = frame(&format!("{FIELD}&size=40x24&draft=1"));
    assert_eq!(draft, first);
    assert_eq!(shown(&server), 10);
    // …a still one reads the newer checkpoint.
    let newer = frame(&format!("{FIELD}&size=40x24"));
    assert_eq!(shown(&server), 40);
    assert_ne!(newer, first, "the field moved on between steps 10 and 40");
    let t = server.json("/api/train");
    assert!(t["trains"][0]["checkpoint"]["bytes"].as_u64().unwrap() > 0);
    // Another camera sees another image.
    let (status, png) = server.get("/api/field?train=fit&eye=3,0.2,0.1&at=0,0,0&size=40x24");
    assert_eq!(status, 200);
    assert_ne!(image::load_from_memory(&png).unwrap().to_rgb8(), newer);
}

#[test]
fn a_missing_corrupt_or_foreign_checkpoint_is_refused_and_the_server_carries_on() {
    let dir = temp("checkpoint");
    let (file, out) = (dir.join("fit.sdfl"), dir.join("out"));
    save(&file, &training(10, SPHERE));
    std::fs::create_dir_all(&out).unwrap();
    let server = Server::start(&file, &out);
    let target = format!("{FIELD}&size=16x16");
    let refused = |want: u16, says: &str| {
        let (status, body) = server.get(&target);
        let body = String::from_utf8_lossy(&body);
        assert_eq!(status, want, "{body}");
        assert!(body.contains(says), "{body}");
    };
    refused(404, "has no checkpoint yet");
    let ckpt = out.join("fit.ckpt");
    std::fs::write(&ckpt, b"not a checkpoint at all").unwrap();
    refused(409, "fit.ckpt");

    // A real checkpoint cut short, then one with a flipped byte inside.
    let good_dir = dir.join("good");
    run(&file, &good_dir);
    let good = std::fs::read(good_dir.join("fit.ckpt")).unwrap();
    std::fs::write(&ckpt, &good[..good.len() / 2]).unwrap();
    refused(409, "fit.ckpt");
    let mut flipped = good.clone();
    let k = flipped.len() - 5;
    flipped[k] ^= 0xff;
    std::fs::write(&ckpt, &flipped).unwrap();
    let (status, _) = server.get(&target);
    assert!(
        status == 200 || status == 409,
        "a flipped value is read or refused, never a crash: {status}"
    );

    // A checkpoint of another model under the same name.
    let other_dir = dir.join("other");
    let other = dir.join("other.sdfl");
    std::fs::write(
        &other,
        training(10, "box(size: param([1, 1, 1]), center: [0, 0, 0])"),
    )
    .unwrap();
    run(&other, &other_dir);
    std::fs::copy(other_dir.join("fit.ckpt"), &ckpt).unwrap();
    refused(409, "another model");

    // The right one is shown again.
    std::fs::write(&ckpt, &good).unwrap();
    refused(200, "");

    // A statement that keeps no checkpoint says how to keep one.
    save(
        &file,
        &training(10, SPHERE).replace("checkpoint: \"fit.ckpt\",", ""),
    );
    for _ in 0..600 {
        let (status, body) = server.get(&target);
        if status == 404 {
            assert!(String::from_utf8_lossy(&body).contains("names no `checkpoint`"));
            return;
        }
        std::thread::sleep(Duration::from_millis(100));
    }
    panic!("the reload never dropped the checkpoint");
}

#[test]
fn hostile_field_requests_are_refused() {
    let dir = temp("field-hostile");
    let (file, out) = (dir.join("fit.sdfl"), dir.join("out"));
    save(&file, &training(5, SPHERE));
    run(&file, &out);
    let server = Server::start(&file, &out);
    let at = "/api/field?train=fit&eye=1,1,-3&at=0,0,0";
    let cases: &[(&str, u16)] = &[
        ("/api/field", 400),
        (
            "/api/field?train=../out/fit.ckpt&eye=1,1,1&at=0,0,0&size=8x8",
            400,
        ),
        ("/api/field?train=nope&eye=1,1,1&at=0,0,0&size=8x8", 404),
        ("/api/field?train=fit&at=0,0,0&size=8x8", 400),
        (&format!("{at}&size=100000x100000"), 400),
        (&format!("{at}&size=0x8"), 400),
        (&format!("{at}&size=8x8&focal=0"), 400),
        (&format!("{at}&size=8x8&focal=inf"), 400),
        (&format!("{at}&size=8x8&up=0,0,0"), 400),
        ("/api/field?train=fit&eye=0,0,0&at=0,0,0&size=8x8", 400),
        ("/api/field?train=fit&eye=nan,0,0&at=0,0,0&size=8x8", 400),
        ("/api/field?train=fit&eye=1e300,0,0&at=0,0,0&size=8x8", 400),
        ("/api/field?train=fit&eye=1,2&at=0,0,0&size=8x8", 400),
        ("/api/field?train=%ZZ", 400),
    ];
    for (target, want) in cases {
        let (status, body) = server.get(target);
        assert_eq!(
            status,
            *want,
            "{target}: {}",
            String::from_utf8_lossy(&body)
        );
        assert!(!body.is_empty(), "{target}: a refusal says why");
    }
    let (status, png) = server.get(&format!("{at}&size=8x8"));
    assert_eq!(status, 200, "{}", String::from_utf8_lossy(&png));
}

#[cfg(unix)]
#[test]
fn files_linked_from_out_to_elsewhere_are_not_served() {
    let dir = temp("links");
    let (file, out) = (dir.join("scene.sdfl"), dir.join("out"));
    save(&file, &scene(0.8));
    std::fs::create_dir_all(&out).unwrap();
    // Outside `--out`: what a planted link must not reveal.
    let secret = image::RgbImage::from_pixel(5, 4, image::Rgb([1, 2, 3]));
    secret.save(dir.join("secret.png")).unwrap();
    std::fs::write(
        dir.join("secret.csv"),
        "step,seconds,loss,lr,psnr,ssim\n1,0.1,0.4242,0.01,,\n",
    )
    .unwrap();
    let link = |to: &Path, name: &str| {
        let at = out.join(name);
        let _ = std::fs::remove_file(&at);
        std::os::unix::fs::symlink(to, &at).unwrap();
    };
    link(&dir.join("secret.png"), "fit.heldout.png");
    link(Path::new("../secret.csv"), "fit.metrics.csv");
    let server = Server::start(&file, &out);
    let (status, body) = server.get("/api/heldout?train=fit");
    assert!(
        status == 403 || status == 404,
        "{status}: a file outside --out was served"
    );
    assert!(image::load_from_memory(&body).is_err());
    let t = server.json("/api/train");
    assert_eq!(t["trains"][0]["heldout"], false, "{t}");
    assert!(t["trains"][0]["metrics"].is_null(), "{t}");
    assert!(!t.to_string().contains("0.4242"), "{t}");

    // A link that stays inside `--out` is followed.
    let inside = image::RgbImage::from_pixel(3, 2, image::Rgb([9, 8, 7]));
    inside.save(out.join("kept.png")).unwrap();
    link(&out.join("kept.png"), "fit.heldout.png");
    let (status, png) = server.get("/api/heldout?train=fit");
    assert_eq!(status, 200, "{}", String::from_utf8_lossy(&png));
    assert_eq!(image::load_from_memory(&png).unwrap().to_rgb8(), inside);
    assert_eq!(server.json("/api/train")["trains"][0]["heldout"], true);
}
