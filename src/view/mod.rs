//! `sdfl view`: a local web viewer of a scene file, served on 127.0.0.1
//! only (tiny_http).
//!
//! The page (`page.html`, embedded) orbits and zooms the file's `render`
//! scenes, and the fields its `train` statements keep in checkpoints, with
//! frames rendered by sdfl on request (small while the camera moves,
//! larger when it stops; a field's frame reads a newer checkpoint when
//! training has written one), reloads when the file is saved (a
//! version counter it polls), and shows each `train` statement's loss and
//! PSNR curves and its current held-out view beside its truth, read from
//! the files training writes in `--out` (`<name>.metrics.csv`,
//! `<name>.heldout.png`), so it also follows a `sdfl run` in another
//! process.
//!
//! Requests reach only fixed routes; names are looked up in the program,
//! never used as paths as given; parameters are checked and capped
//! ([`request`]); frames are traced one at a time.

mod field;
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
    tracing: Arc<Mutex<()>>,
    /// The trained fields on view.
    fields: field::Fields,
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
    let tracing = Arc::new(Mutex::new(()));
    let base = v.file.parent().map(Path::to_path_buf).unwrap_or_default();
    let shared = Arc::new(Shared {
        file: v.file.clone(),
        out: v.out.clone(),
        loaded: Mutex::new(Loaded {
            version: 0,
            program: None,
            diagnostics: String::new(),
            lowered: HashMap::new(),
        }),
        tracing: tracing.clone(),
        fields: field::Fields::start(v.out.clone(), base, tracing),
    });
    // Stamped before the first read, so a save at any moment after it,
    // even before the follower thread first runs, is seen as a change.
    let seen = crate::watch::sources_stamp(&shared.file);
    reload(&shared);
    crate::Stdout::new().line(&format!(
        "sdfl view: http://{addr}/  ({}; Ctrl-C stops)",
        v.file.display()
    ));
    {
        let shared = shared.clone();
        std::thread::spawn(move || follow(&shared, seen));
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

/// Reloads the file whenever it (or a `.sdfl` file beside it) differs
/// from `seen`, its stamp when it was last read.
fn follow(shared: &Shared, mut seen: String) {
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
        Route::Field => field_frame(shared, &target, version, program),
        Route::Train => Ok(json(&trains(shared, program.as_deref()))),
        Route::HeldOut => held_out(shared, &target, program.as_deref()),
    }
}

/// Frame sides the page asks for while a camera moves and once it stops
/// (it refines through the still sides in order).
const SCENE_SIDES: (u32, [u32; 2]) = (64, [256, 512]);
/// The same for trained fields, which render more slowly.
const FIELD_SIDES: (u32, [u32; 2]) = (field::MOVING_SIDE, [128, 384]);

/// A camera, size and frame sides as the page receives them.
fn view_entry(
    kind: &str,
    name: &str,
    c: &sdfl_stdlib::camera::Camera,
    (width, height): (u32, u32),
    (moving, still): (u32, [u32; 2]),
) -> serde_json::Value {
    serde_json::json!({
        "kind": kind,
        "name": name,
        "eye": c.eye.to_array(),
        "at": c.at.to_array(),
        "up": c.up.to_array(),
        "focal": c.focal,
        "width": width,
        "height": height,
        "moving": moving,
        "still": still,
    })
}

/// Every `render` statement with its first camera and size, then every
/// `train` statement (its field, seen from its checkpoint).
fn scenes(program: Option<&Program>) -> serde_json::Value {
    let renders = program.into_iter().flat_map(|p| &p.renders);
    let mut list: Vec<serde_json::Value> = renders
        .filter_map(|job| {
            let c = frame::initial_camera(job)?;
            let mut e = view_entry(
                "render",
                &job.name,
                &c,
                (job.width, job.height),
                SCENE_SIDES,
            );
            e["primitives"] = job.scene.primitive_count().into();
            Some(e)
        })
        .collect();
    for job in program.into_iter().flat_map(|p| &p.trains) {
        let c = field::initial_camera(job);
        let mut e = view_entry("train", &job.name, &c, (job.width, job.height), FIELD_SIDES);
        e["checkpoint"] = job.checkpoint.is_some().into();
        list.push(e);
    }
    serde_json::json!({ "scenes": list })
}

/// The camera a frame request asks for; `up` and `focal` default to the
/// statement's (`first`).
fn frame_camera(
    t: &Target,
    first: Option<&sdfl_stdlib::camera::Camera>,
) -> Result<frame::FrameCamera, Refusal> {
    let up = match t.get("up") {
        Some(s) => request::vec3("up", s)?,
        None => first.map_or(glam::DVec3::Y, |c| c.up),
    };
    let focal = match t.get("focal") {
        Some(s) => request::focal(s)?,
        None => first.map_or(1.5, |c| c.focal),
    };
    Ok(frame::FrameCamera {
        eye: request::vec3("eye", t.require("eye")?)?,
        at: request::vec3("at", t.require("at")?)?,
        up,
        focal,
        size: request::size(t.require("size")?)?,
        draft: matches!(t.get("draft"), Some("1" | "true")),
    })
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
    let camera = frame_camera(t, frame::initial_camera(job).as_ref())?;
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

/// A frame of a `train` statement's field at its latest checkpoint: a
/// frame while the camera moves (`draft`) reuses the field as last read,
/// a still one first reads a newer checkpoint if training wrote one.
fn field_frame(
    shared: &Shared,
    t: &Target,
    version: u64,
    program: Option<Arc<Program>>,
) -> Result<Body, Refusal> {
    let name = request::name("train", t.require("train")?)?;
    let program =
        program.ok_or_else(|| Refusal::missing("the file has errors: nothing to render"))?;
    let job = program
        .trains
        .iter()
        .find(|j| j.name == name)
        .ok_or_else(|| Refusal::missing(format!("no train statement named `{name}`")))?;
    let camera = frame_camera(t, Some(&field::initial_camera(job)))?;
    Ok((shared.fields.frame(job, version, camera)?, PNG))
}

/// Each `train` statement's curves (from its metrics file, if any yet),
/// whether it has a held-out view, and its checkpoint's version (the page
/// asks for a new frame of a field whose checkpoint changed).
fn trains(shared: &Shared, program: Option<&Program>) -> serde_json::Value {
    let shown = shared.fields.steps();
    let list: Vec<serde_json::Value> = program
        .into_iter()
        .flat_map(|p| &p.trains)
        .map(|job| {
            let (csv, _, heldout) = log_paths(&shared.out, &job.name);
            let checkpoint = sdfl_runtime::jobs::checkpoint_path(job, &shared.out)
                .and_then(|p| sdfl_runtime::jobs::CheckpointStamp::of(&p))
                .map(|s| {
                    let modified = s
                        .modified
                        .and_then(|t| t.duration_since(std::time::UNIX_EPOCH).ok())
                        .map_or(0, |d| d.as_millis() as u64);
                    serde_json::json!({ "bytes": s.bytes, "modified_ms": modified })
                });
            serde_json::json!({
                "name": job.name,
                "iterations": job.iterations,
                "metrics": metrics::read(&csv),
                "heldout": heldout.is_file(),
                "checkpoint": checkpoint,
                "field_step": shown.get(&job.name),
            })
        })
        .collect();
    serde_json::json!({ "trains": list })
}

/// Where training `train` writes its metrics, events and held-out view.
fn log_paths(out: &Path, train: &str) -> (PathBuf, PathBuf, PathBuf) {
    sdfl_runtime::train::log::paths(out, train)
}

fn held_out(shared: &Shared, t: &Target, program: Option<&Program>) -> Result<Body, Refusal> {
    let name = request::name("train", t.require("train")?)?;
    let known = program.is_some_and(|p| p.trains.iter().any(|j| j.name == name));
    if !known {
        return Err(Refusal::missing(format!(
            "no train statement named `{name}`"
        )));
    }
    let (_, _, path) = log_paths(&shared.out, name);
    let missing = || Refusal::missing(format!("`{name}` has no held-out view yet"));
    let file = sdfl_runtime::data::image::open_regular(&path).map_err(|_| missing())?;
    let mut bytes = Vec::new();
    file.take(MAX_IMAGE_BYTES)
        .read_to_end(&mut bytes)
        .map_err(|_| missing())?;
    Ok((bytes, PNG))
}
