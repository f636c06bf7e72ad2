//! `sdfl view` under hostile load, on 127.0.0.1 only: a flood of
//! connections under a low file limit, slow readers of a large file, a
//! FIFO beside the viewed file. Every loop is bounded in count and time,
//! and each test ends by asking `/api/version`, which must still answer.

use crate::common;
use std::io::{BufRead, BufReader, Read, Write};
use std::net::{SocketAddr, TcpStream};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

fn temp(name: &str) -> PathBuf {
    common::temp_dir("view-load", name)
}

/// A render and a training run (never run here) whose held-out view the
/// server may be asked for.
const SCENE: &str = "let target = sdf_volume(sphere(1), color: [0.2, 0.6, 0.9])\n\
     render ball {\n\
       scene: sphere(0.8),\n\
       material: lambert(albedo: [0.9, 0.5, 0.3], light: [1, 1, -1]),\n\
       camera: look_at(eye: [1, 1, -3], at: [0, 0, 0], up: [0, 1, 0], focal: 1.5),\n\
       size: [16, 16],\n\
       outputs: [image(\"ball.png\")],\n\
     }\n\
     train fit {\n\
       model: sdf_volume(sphere(1, center: param([0.3, 0.2, 0])), color: param([0.3, 0.1, 0.1])),\n\
       data: render_views(target, cameras: [look_at(eye: [0, 0, -3])], size: [16, 16], sampler: stratified(samples: 8, near: 0, far: 6)),\n\
       sampler: stratified(samples: 8, near: 0, far: 6), rays: 64, optimizer: adam(lr: 1e-2), iterations: 10,\n\
     }\n";

/// How long the server may take to print its address (a hang trips it).
const START: Duration = Duration::from_secs(30);

/// `sdfl view FILE --port 0`, optionally with at most `nofile` open
/// files; killed when dropped.
struct Viewer {
    child: Child,
    addr: SocketAddr,
    stderr: PathBuf,
}

impl Viewer {
    fn start(dir: &Path, file: &Path, nofile: Option<u64>) -> Viewer {
        Viewer::start_with(dir, file, nofile, &[])
    }

    /// [`Viewer::start`] with further arguments.
    fn start_with(dir: &Path, file: &Path, nofile: Option<u64>, extra: &[&str]) -> Viewer {
        let stderr = dir.join("viewer-stderr.txt");
        let mut cmd = Command::new(env!("CARGO_BIN_EXE_sdfl"));
        cmd.args(["view", file.to_str().unwrap(), "--port", "0"])
            .args(["--out", dir.join("out").to_str().unwrap()])
            .args(["--threads", "2"])
            .args(extra)
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(std::fs::File::create(&stderr).unwrap());
        if let Some(n) = nofile {
            use std::os::unix::process::CommandExt;
            // SAFETY: only setrlimit, async-signal-safe, between fork and exec.
            unsafe {
                cmd.pre_exec(move || {
                    let limit = libc::rlimit {
                        rlim_cur: n,
                        rlim_max: n,
                    };
                    if libc::setrlimit(libc::RLIMIT_NOFILE, &limit) != 0 {
                        return Err(std::io::Error::last_os_error());
                    }
                    Ok(())
                });
            }
        }
        let mut child = cmd.spawn().unwrap();
        // Read on a thread: a server that hangs before printing fails the
        // test instead of blocking it.
        let stdout = child.stdout.take().unwrap();
        let (tx, rx) = mpsc::channel();
        std::thread::spawn(move || {
            let mut line = String::new();
            let _ = BufReader::new(stdout).read_line(&mut line);
            let _ = tx.send(line);
        });
        let mut v = Viewer {
            child,
            addr: "127.0.0.1:1".parse().unwrap(),
            stderr,
        };
        let line = match rx.recv_timeout(START) {
            Ok(line) => line,
            Err(_) => panic!(
                "no address within {START:?} (a hang at start-up); stderr:\n{}",
                v.stderr_text()
            ),
        };
        let addr = line
            .split("http://")
            .nth(1)
            .and_then(|r| r.split('/').next())
            .unwrap_or_else(|| panic!("no address in {line:?}"));
        v.addr = addr.parse().unwrap();
        assert!(v.addr.ip().is_loopback(), "served on {addr}");
        v
    }

    fn stderr_text(&self) -> String {
        String::from_utf8_lossy(&std::fs::read(&self.stderr).unwrap_or_default()).into_owned()
    }

    fn connect(&self) -> std::io::Result<TcpStream> {
        TcpStream::connect_timeout(&self.addr, Duration::from_secs(2))
    }

    /// (status, body) of `GET target`, or why none came within `limit`.
    fn get(&self, target: &str, limit: Duration) -> Result<(u16, Vec<u8>), String> {
        let t0 = Instant::now();
        let mut s = self.connect().map_err(|e| format!("connect: {e}"))?;
        s.set_read_timeout(Some(limit)).unwrap();
        s.set_write_timeout(Some(limit)).unwrap();
        let request = format!(
            "GET {target} HTTP/1.1\r\nHost: {}\r\nConnection: close\r\n\r\n",
            self.addr
        );
        s.write_all(request.as_bytes())
            .map_err(|e| format!("write: {e}"))?;
        let mut bytes = Vec::new();
        let mut buf = [0u8; 1 << 16];
        loop {
            if t0.elapsed() > limit {
                return Err(format!("no whole answer within {limit:?}"));
            }
            match s.read(&mut buf) {
                Ok(0) => break,
                Ok(n) => bytes.extend_from_slice(&buf[..n]),
                Err(e) => return Err(format!("read after {:?}: {e}", t0.elapsed())),
            }
        }
        let split = bytes
            .windows(4)
            .position(|w| w == b"\r\n\r\n")
            .ok_or_else(|| format!("no response head in {} bytes", bytes.len()))?;
        let head = String::from_utf8_lossy(&bytes[..split]).into_owned();
        let status = head
            .split_whitespace()
            .nth(1)
            .and_then(|s| s.parse().ok())
            .ok_or_else(|| format!("bad status line: {head}"))?;
        Ok((status, bytes[split + 4..].to_vec()))
    }

    /// `/api/version`'s JSON, asked again until it answers or `limit`
    /// has passed.
    fn version_within(&self, limit: Duration) -> serde_json::Value {
        let t0 = Instant::now();
        let mut last = String::new();
        while t0.elapsed() < limit {
            let left = limit
                .saturating_sub(t0.elapsed())
                .max(Duration::from_millis(100));
            match self.get("/api/version", left) {
                Ok((200, body)) => return serde_json::from_slice(&body).unwrap(),
                Ok((status, body)) => {
                    last = format!("{status}: {}", String::from_utf8_lossy(&body))
                }
                Err(e) => last = e,
            }
            std::thread::sleep(Duration::from_millis(100));
        }
        panic!(
            "/api/version did not answer within {limit:?} ({last}); stderr:\n{}",
            self.stderr_text()
        );
    }

    /// The server is still running and has not panicked.
    fn assert_alive(&mut self) {
        let exited = self.child.try_wait().unwrap();
        let stderr = self.stderr_text();
        assert!(exited.is_none(), "the server exited: {exited:?}\n{stderr}");
        assert!(!stderr.contains("panicked"), "{stderr}");
    }
}

impl Drop for Viewer {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

#[test]
fn a_connection_flood_under_a_low_file_limit_leaves_it_answering() {
    let dir = temp("flood");
    let file = dir.join("scene.sdfl");
    std::fs::write(&file, SCENE).unwrap();
    let mut v = Viewer::start(&dir, &file, Some(128));
    assert_eq!(v.version_within(Duration::from_secs(10))["ok"], true);

    // More connections at once than the server may hold files: it runs out
    // (EMFILE) while they are open.
    let t0 = Instant::now();
    let mut held = Vec::new();
    for _ in 0..300 {
        if t0.elapsed() > Duration::from_secs(30) {
            break;
        }
        if let Ok(s) = v.connect() {
            held.push(s);
        }
    }
    eprintln!("{} connections held at once", held.len());
    std::thread::sleep(Duration::from_millis(500));
    drop(held);

    // Then connections opened and closed one after another, some with half
    // a request.
    let t0 = Instant::now();
    for k in 0..500 {
        if t0.elapsed() > Duration::from_secs(30) {
            break;
        }
        if let Ok(mut s) = v.connect() {
            if k % 3 == 0 {
                let _ = s.write_all(b"GET /api/version HTTP/1.1\r\nHost: 127.");
            }
        }
    }
    // While files ran out the follower may have failed to read the scene
    // (the page then says so); once they are back it reads it again.
    let t0 = Instant::now();
    while v.version_within(Duration::from_secs(15))["ok"] != true {
        assert!(
            t0.elapsed() < Duration::from_secs(15),
            "the file was never read again"
        );
        std::thread::sleep(Duration::from_millis(200));
    }
    v.assert_alive();
}

#[test]
fn slow_readers_of_a_large_file_do_not_hold_the_server() {
    let dir = temp("slow");
    let file = dir.join("scene.sdfl");
    std::fs::write(&file, SCENE).unwrap();
    let out = dir.join("out");
    std::fs::create_dir_all(&out).unwrap();
    // Far more than the sockets buffer: a client that reads none of it
    // leaves the server's writes stalled.
    const BIG: usize = 48 << 20;
    let big: Vec<u8> = (0..BIG).map(|i| (i * 7 % 251) as u8).collect();
    std::fs::write(out.join("fit.heldout.png"), &big).unwrap();
    // Stalled writes are given up after 3 s here (10 s by default): a
    // stall is a write that makes no progress, which the reader below,
    // reading all the while, never makes.
    const STALL: u64 = 3;
    let mut v = Viewer::start_with(&dir, &file, None, &["--write-stall", &STALL.to_string()]);
    assert_eq!(v.version_within(Duration::from_secs(10))["ok"], true);

    let request = format!(
        "GET /api/heldout?train=fit HTTP/1.1\r\nHost: {}\r\n\r\n",
        v.addr
    );
    let slow: Vec<TcpStream> = (0..8)
        .map(|_| {
            let mut s = v.connect().unwrap();
            s.write_all(request.as_bytes()).unwrap();
            s
        })
        .collect();
    std::thread::sleep(Duration::from_secs(1));
    let t0 = Instant::now();
    assert_eq!(v.version_within(Duration::from_secs(5))["ok"], true);
    let (status, _) = v.get("/api/scenes", Duration::from_secs(10)).unwrap();
    assert_eq!(status, 200);
    // A reader that does read gets the whole file meanwhile.
    let (status, body) = v
        .get("/api/heldout?train=fit", Duration::from_secs(30))
        .unwrap();
    assert_eq!(status, 200);
    assert!(body == big, "{} of {BIG} bytes", body.len());
    eprintln!("answered beside 8 stalled readers in {:?}", t0.elapsed());

    // A stalled write is given up: the slow clients get part of the file,
    // then the end of the connection.
    std::thread::sleep(Duration::from_secs(2 * STALL).saturating_sub(t0.elapsed()));
    for mut s in slow {
        s.set_read_timeout(Some(Duration::from_secs(10))).unwrap();
        let mut got = Vec::new();
        let _ = s.read_to_end(&mut got);
        assert!(got.len() < BIG, "a stalled reader got the whole file");
    }
    v.assert_alive();
}

#[test]
fn a_fifo_beside_the_file_does_not_hang_the_viewer() {
    let dir = temp("fifo");
    let file = dir.join("scene.sdfl");
    std::fs::write(&file, SCENE).unwrap();
    let fifo = dir.join("beside.sdfl");
    let made = Command::new("mkfifo").arg(&fifo).status().unwrap();
    assert!(made.success(), "mkfifo failed");
    let mut v = Viewer::start(&dir, &file, None);
    let v0 = v.version_within(Duration::from_secs(10));
    assert_eq!(v0["ok"], true);
    // A save is still followed (the follower looks at the FIFO again).
    let tmp = dir.join("scene.sdfl~");
    std::fs::write(&tmp, SCENE.replace("sphere(0.8)", "sphere(0.7)")).unwrap();
    std::fs::rename(&tmp, &file).unwrap();
    let t0 = Instant::now();
    loop {
        let now = v.version_within(Duration::from_secs(10));
        if now["version"].as_u64() > v0["version"].as_u64() {
            break;
        }
        assert!(t0.elapsed() < common::HANG_GUARD, "the save was never seen");
        std::thread::sleep(Duration::from_millis(100));
    }
    // FIFOs where training writes its held-out view and metrics are
    // refused, never waited on.
    let out = dir.join("out");
    std::fs::create_dir_all(&out).unwrap();
    for name in ["fit.heldout.png", "fit.metrics.csv"] {
        let made = Command::new("mkfifo").arg(out.join(name)).status().unwrap();
        assert!(made.success(), "mkfifo failed");
    }
    let (status, _) = v
        .get("/api/heldout?train=fit", Duration::from_secs(10))
        .unwrap();
    assert_eq!(status, 404);
    let (status, body) = v.get("/api/train", Duration::from_secs(10)).unwrap();
    assert_eq!(status, 200);
    let t: serde_json::Value = serde_json::from_slice(&body).unwrap();
    assert!(t["trains"][0]["metrics"].is_null(), "{t}");
    assert_eq!(t["trains"][0]["heldout"], false, "{t}");
    // Viewing the FIFO itself is an error on the page, not a hang.
    let mut w = Viewer::start(&dir, &fifo, None);
    assert_eq!(w.version_within(Duration::from_secs(10))["ok"], false);
    v.assert_alive();
    w.assert_alive();
}
