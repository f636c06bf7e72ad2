//! `sdfl view`: a local web viewer of a scene file, served on 127.0.0.1
//! only (tiny_http).
//!
//! The page (`page.html`, embedded) orbits and zooms the file's `render`
//! scenes with frames traced by sdfl on request (small while the camera
//! moves, larger when it stops), reloads when the file is saved (a
//! version counter it polls), and shows each `train` statement's loss and
//! PSNR curves and its current held-out view beside its truth, read from
//! the files training writes in `--out` (`<name>.metrics.csv`,
//! `<name>.heldout.png`), so it also follows a `sdfl run` in another
//! process.
//!
//! Requests reach only fixed routes; names are looked up in the program,
//! never used as paths as given; parameters are checked and capped
//! ([`request`]); frames are traced one at a time.

mod frame;
mod metrics;
pub mod request;

use std::collections::HashMap;
use std::io::Read;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::{Arc, Mutex, MutexGuard};

use sdfl_runtime::Lowered;
use sdfl_stdlib::Program;
use tiny_http::{Header, Response, Server};

use request::{Refusal, Route, Target};

/// The page, embedded in the binary.
const PAGE: &str = include_str!("page.html");

/// Threads answering requests (frames still trace one at a time, on every
/// core).
const WORKERS: usize = 4;

/// Largest held-out image served (a 16 384² PNG is far below this).
const MAX_IMAGE_BYTES: u64 = 256 << 20;

/// What `sdfl view` was asked to serve.
pub struct View {
    /// The scene file.
    pub file: PathBuf,
    /// Where training writes its metrics and held-out views.
    pub out: PathBuf,
    /// The port on 127.0.0.1 (0: any free one).
    pub port: u16,
}

/// The file as last loaded.
struct Loaded {
    /// Bumped at each reload.
    version: u64,
    /// The program, `None` while the file has errors.
    program: Option<Arc<Program>>,
    /// The diagnostics of the last load (errors and warnings), uncoloured.
    diagnostics: String,
    /// Scenes lowered since the last reload, by statement name.
    lowered: HashMap<String, Arc<Lowered>>,
}

struct Shared {
    file: PathBuf,
    out: PathBuf,
    loaded: Mutex<Loaded>,
    /// Frames are traced one at a time (each uses every core).
    tracing: Mutex<()>,
}

fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

/// Serves until interrupted. Prints the address on stdout first (with
/// `--port 0`, the port chosen).
pub fn view(v: View) -> ExitCode {
    let server = match Server::http(("127.0.0.1", v.port)) {
        Ok(s) => Arc::new(s),
        Err(e) => {
            say!(
                "error[sdfl::io]: cannot listen on 127.0.0.1:{}: {e}\n  help: choose another `--port` (0 picks a free one)",
                v.port
            );
            return ExitCode::FAILURE;
        }
    };
    let Some(addr) = server.server_addr().to_ip() else {
        say!("error[sdfl::io]: the server has no IP address");
        return ExitCode::FAILURE;
    };
    let shared = Arc::new(Shared {
        file: v.file.clone(),
        out: v.out.clone(),
        loaded: Mutex::new(Loaded {
            version: 0,
            program: None,
            diagnostics: String::new(),
            lowered: HashMap::new(),
        }),
        tracing: Mutex::new(()),
    });
    reload(&shared);
    crate::Stdout::new().line(&format!(
        "sdfl view: http://{addr}/  ({}; Ctrl-C stops)",
        v.file.display()
    ));
    {
        let shared = shared.clone();
        std::thread::spawn(move || follow(&shared));
    }
    let workers: Vec<_> = (0..WORKERS)
        .map(|_| {
            let (server, shared) = (server.clone(), shared.clone());
            std::thread::spawn(move || {
                while let Ok(request) = server.recv() {
                    answer(&shared, addr.port(), request);
                }
            })
        })
        .collect();
    for w in workers {
        let _ = w.join();
    }
    ExitCode::SUCCESS
}

/// Reloads the file whenever it (or a `.sdfl` file beside it) is saved.
fn follow(shared: &Shared) {
    let mut seen = crate::watch::sources_stamp(&shared.file);
    loop {
        seen = crate::watch::next_change(&shared.file, seen);
        reload(shared);
    }
}

/// Loads the file, keeping its diagnostics for the page (and printing
/// them), and bumps the version.
fn reload(shared: &Shared) {
    let (program, diagnostics) = match crate::read(&shared.file) {
        Err(()) => (None, format!("cannot read {}", shared.file.display())),
        Ok(src) => match sdfl_stdlib::load_warned(&src) {
            Ok((program, warnings)) => {
                let text = if warnings.is_empty() {
                    String::new()
                } else {
                    sdfl_lang::render(&src, &warnings, false)
                };
                (Some(Arc::new(program)), text)
            }
            Err(diags) => (None, sdfl_lang::render(&src, &diags, false)),
        },
    };
    if !diagnostics.is_empty() {
        crate::term::say_raw(&diagnostics);
    }
    let mut l = lock(&shared.loaded);
    l.version += 1;
    l.program = program;
    l.diagnostics = diagnostics;
    l.lowered.clear();
    say!("sdfl view: loaded version {}", l.version);
}

/// A response body and its content type.
type Body = (Vec<u8>, &'static str);

const JSON: &str = "application/json";
const PNG: &str = "image/png";

fn json(v: &serde_json::Value) -> Body {
    (v.to_string().into_bytes(), JSON)
}

/// Answers one request; every failure is a status with a message.
fn answer(shared: &Shared, port: u16, request: tiny_http::Request) {
    let result = serve(shared, port, &request);
    let (status, body, kind) = match result {
        Ok((body, kind)) => (200, body, kind),
        Err(r) => (
            r.status,
            format!("{}\n", r.message).into_bytes(),
            "text/plain; charset=utf-8",
        ),
    };
    let mut response = Response::from_data(body).with_status_code(status);
    for (k, v) in [
        ("Content-Type", kind),
        ("Cache-Control", "no-store"),
        ("X-Content-Type-Options", "nosniff"),
    ] {
        if let Ok(h) = Header::from_bytes(k, v) {
            response.add_header(h);
        }
    }
    // A client gone before its frame is not an error.
    let _ = request.respond(response);
}

fn serve(shared: &Shared, port: u16, request: &tiny_http::Request) -> Result<Body, Refusal> {
    if *request.method() != tiny_http::Method::Get {
        return Err(Refusal {
            status: 405,
            message: "only GET is served".into(),
        });
    }
    // Only pages opened as this address: a page elsewhere that points a
    // name at 127.0.0.1 (DNS rebinding) is refused.
    let host = request
        .headers()
        .iter()
        .find(|h| h.field.equiv("Host"))
        .map(|h| h.value.as_str().to_string());
    let allowed = [format!("127.0.0.1:{port}"), format!("localhost:{port}")];
    if let Some(h) = host {
        if !allowed.contains(&h) {
            return Err(Refusal {
                status: 403,
                message: format!("served only as http://127.0.0.1:{port}/"),
            });
        }
    }
    let target = Target::parse(request.url())?;
    let (version, program, diagnostics) = {
        let l = lock(&shared.loaded);
        (l.version, l.program.clone(), l.diagnostics.clone())
    };
    match target.route {
        Route::Page => Ok((PAGE.as_bytes().to_vec(), "text/html; charset=utf-8")),
        Route::Version => Ok(json(&serde_json::json!({
            "version": version,
            "ok": program.is_some(),
            "diagnostics": diagnostics,
            "file": shared.file.display().to_string(),
        }))),
        Route::Scenes => Ok(json(&scenes(program.as_deref()))),
        Route::Frame => frame(shared, &target, program),
        Route::Train => Ok(json(&trains(shared, program.as_deref()))),
        Route::HeldOut => held_out(shared, &target, program.as_deref()),
    }
}

/// Every `render` statement with its first camera and size.
fn scenes(program: Option<&Program>) -> serde_json::Value {
    let list: Vec<serde_json::Value> = program
        .into_iter()
        .flat_map(|p| &p.renders)
        .filter_map(|job| {
            let c = frame::initial_camera(job)?;
            Some(serde_json::json!({
                "name": job.name,
                "eye": c.eye.to_array(),
                "at": c.at.to_array(),
                "up": c.up.to_array(),
                "focal": c.focal,
                "width": job.width,
                "height": job.height,
                "primitives": job.scene.primitive_count(),
            }))
        })
        .collect();
    serde_json::json!({ "scenes": list })
}

fn frame(shared: &Shared, t: &Target, program: Option<Arc<Program>>) -> Result<Body, Refusal> {
    let name = request::name("scene", t.require("scene")?)?;
    let program =
        program.ok_or_else(|| Refusal::missing("the file has errors: nothing to render"))?;
    let job = program
        .renders
        .iter()
        .find(|j| j.name == name)
        .ok_or_else(|| Refusal::missing(format!("no render statement named `{name}`")))?;
    let first = frame::initial_camera(job);
    let up = match t.get("up") {
        Some(s) => request::vec3("up", s)?,
        None => first.map_or(glam::DVec3::Y, |c| c.up),
    };
    let focal = match t.get("focal") {
        Some(s) => request::focal(s)?,
        None => first.map_or(1.5, |c| c.focal),
    };
    let camera = frame::FrameCamera {
        eye: request::vec3("eye", t.require("eye")?)?,
        at: request::vec3("at", t.require("at")?)?,
        up,
        focal,
        size: request::size(t.require("size")?)?,
        draft: matches!(t.get("draft"), Some("1" | "true")),
    };
    let _one_at_a_time = lock(&shared.tracing);
    let world = {
        let cached = lock(&shared.loaded).lowered.get(name).cloned();
        match cached {
            Some(w) => w,
            None => {
                let w = Arc::new(frame::lower(job));
                let mut l = lock(&shared.loaded);
                // Not kept if the file was reloaded meanwhile.
                if l.program.as_ref().is_some_and(|p| Arc::ptr_eq(p, &program)) {
                    l.lowered.insert(name.to_string(), w.clone());
                }
                w
            }
        }
    };
    Ok((frame::render(job, &world, camera)?, PNG))
}

/// Each `train` statement's curves (from its metrics file, if any yet)
/// and whether it has a held-out view.
fn trains(shared: &Shared, program: Option<&Program>) -> serde_json::Value {
    let list: Vec<serde_json::Value> = program
        .into_iter()
        .flat_map(|p| &p.trains)
        .map(|job| {
            let curves = metrics::read(&metrics_path(&shared.out, &job.name));
            serde_json::json!({
                "name": job.name,
                "iterations": job.iterations,
                "metrics": curves,
                "heldout": held_out_path(&shared.out, &job.name).is_file(),
            })
        })
        .collect();
    serde_json::json!({ "trains": list })
}

/// `<out>/<train name>.metrics.csv` (h-log's file contract).
fn metrics_path(out: &Path, train: &str) -> PathBuf {
    out.join(format!("{train}.metrics.csv"))
}

/// `<out>/<train name>.heldout.png`.
fn held_out_path(out: &Path, train: &str) -> PathBuf {
    out.join(format!("{train}.heldout.png"))
}

fn held_out(shared: &Shared, t: &Target, program: Option<&Program>) -> Result<Body, Refusal> {
    let name = request::name("train", t.require("train")?)?;
    let known = program.is_some_and(|p| p.trains.iter().any(|j| j.name == name));
    if !known {
        return Err(Refusal::missing(format!(
            "no train statement named `{name}`"
        )));
    }
    let path = held_out_path(&shared.out, name);
    let missing = || Refusal::missing(format!("`{name}` has no held-out view yet"));
    let file = sdfl_runtime::data::image::open_regular(&path).map_err(|_| missing())?;
    let mut bytes = Vec::new();
    file.take(MAX_IMAGE_BYTES)
        .read_to_end(&mut bytes)
        .map_err(|_| missing())?;
    Ok((bytes, PNG))
}
