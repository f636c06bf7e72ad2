//! `cargo run --release -p sdfl-bench -- view [FILE] [FRAMES]`: frames per
//! second of `sdfl view`'s frame endpoint at 256², orbiting the first
//! `render` statement's camera (default `examples/large_scene.sdfl`, 625
//! primitives), against the same frames traced in this process (no HTTP,
//! no PNG) in the same run. Needs `target/release/sdfl` built
//! (`cargo build --release`).

use std::io::{BufRead, BufReader, Read, Write};
use std::net::TcpStream;
use std::process::{Command, Stdio};
use std::time::Instant;

use glam::DVec3;
use sdfl_runtime::render::{render_view, Needs};
use sdfl_runtime::{LowerOptions, Lowered};
use sdfl_stdlib::camera::Camera;

/// The frame side measured.
const SIDE: u32 = 256;

/// The `k`-th of `n` cameras orbiting `c.at` about `c.up`.
fn orbit(c: &Camera, k: usize, n: usize) -> Camera {
    let up = c.up.normalize();
    let d = c.eye - c.at;
    let along = up * d.dot(up);
    let radial = d - along;
    let a = std::f64::consts::TAU * k as f64 / n as f64;
    let side = up.cross(radial);
    let eye = c.at + along + radial * a.cos() + side * a.sin();
    Camera { eye, ..*c }
}

fn get(addr: &str, target: &str) -> Vec<u8> {
    let mut s = TcpStream::connect(addr).expect("the viewer listens");
    write!(
        s,
        "GET {target} HTTP/1.1\r\nHost: {addr}\r\nConnection: close\r\n\r\n"
    )
    .unwrap();
    let mut bytes = Vec::new();
    s.read_to_end(&mut bytes).unwrap();
    assert!(
        bytes.starts_with(b"HTTP/1.1 200"),
        "{}",
        String::from_utf8_lossy(&bytes[..bytes.len().min(300)])
    );
    bytes
}

fn v(p: DVec3) -> String {
    format!("{},{},{}", p.x, p.y, p.z)
}

/// Runs the benchmark and prints one Markdown table.
pub fn main(file: &str, frames: usize) {
    let src = std::fs::read_to_string(file).expect("the scene file reads");
    let program = sdfl_stdlib::load(&sdfl_lang::SourceFile::new(file, src)).expect("it loads");
    let job = program.renders.first().expect("a render statement");
    let first = job.cameras[0];
    let cams: Vec<Camera> = (0..frames).map(|k| orbit(&first, k, frames)).collect();

    // In process: lowered once, every frame traced (what the server does
    // per request, less HTTP and PNG).
    let scene = Lowered::relative_to(&job.scene, LowerOptions::default(), DVec3::ZERO);
    let needs = Needs {
        color: true,
        depth: false,
        normals: false,
        mask: false,
    };
    let _ = render_view(&scene, job, &cams[0], (SIDE, SIDE), needs, &|_| {});
    let t = Instant::now();
    for c in &cams {
        let _ = render_view(&scene, job, c, (SIDE, SIDE), needs, &|_| {});
    }
    let direct = frames as f64 / t.elapsed().as_secs_f64();

    let exe = std::env::current_exe()
        .unwrap()
        .with_file_name("sdfl")
        .with_extension(std::env::consts::EXE_EXTENSION);
    let mut child = Command::new(&exe)
        .args([
            "view",
            file,
            "--port",
            "0",
            "--out",
            "target/bench-view-out",
        ])
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .unwrap_or_else(|e| panic!("{}: {e} (cargo build --release first)", exe.display()));
    let mut line = String::new();
    BufReader::new(child.stdout.take().unwrap())
        .read_line(&mut line)
        .unwrap();
    let addr = line
        .split("http://")
        .nth(1)
        .and_then(|r| r.split('/').next())
        .expect("the viewer prints its address")
        .to_string();
    let target = |c: &Camera| {
        format!(
            "/api/frame?scene={}&eye={}&at={}&up={}&focal={}&size={SIDE}x{SIDE}",
            job.name,
            v(c.eye),
            v(c.at),
            v(c.up),
            c.focal
        )
    };
    // The first request lowers the scene (once per reload).
    let t = Instant::now();
    let _ = get(&addr, &target(&cams[0]));
    let first_s = t.elapsed().as_secs_f64();
    let t = Instant::now();
    let mut bytes = 0;
    for c in &cams {
        bytes += get(&addr, &target(c)).len();
    }
    let served = frames as f64 / t.elapsed().as_secs_f64();
    let _ = child.kill();
    let _ = child.wait();

    let load = std::fs::read_to_string("/proc/loadavg").unwrap_or_default();
    println!(
        "{file}: {} primitives, {frames} frames of {SIDE}x{SIDE} orbiting, {} threads, load average {}\n",
        job.scene.primitive_count(),
        rayon::current_num_threads(),
        load.split_whitespace().take(3).collect::<Vec<_>>().join(" ")
    );
    println!("| path | frames/s | ratio |");
    println!("|---|---|---|");
    println!("| traced in process (render_view) | {direct:.1} | 1.00 |");
    println!(
        "| `sdfl view` /api/frame (HTTP + PNG, {:.1} kB/frame) | {served:.1} | {:.2} |",
        bytes as f64 / frames as f64 / 1e3,
        served / direct
    );
    println!(
        "\nfirst frame after a (re)load, lowering included: {:.3} s",
        first_s
    );
}
