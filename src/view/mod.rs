//! `sdfl view`: a local web viewer of a scene file, served on 127.0.0.1
//! only.
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
//! ([`request`]); files are read only where they resolve inside `--out`;
//! frames are traced one at a time.
//!
//! The server (hyper, HTTP/1 only, on tokio's current-thread runtime) is
//! built for hostile clients: connections are tasks, not threads, so a
//! client that stops reading holds no worker; a stalled write
//! ([`WRITE_STALL`]) or headers that do not arrive ([`HEADER_READ`], also
//! the idle keep-alive limit) end the connection; at most
//! [`MAX_CONNECTIONS`] are open (more wait in the kernel's backlog); an
//! accept that fails (out of files, EMFILE) is retried after a pause, never
//! fatal. Work that blocks (tracing, reading files) runs on a few blocking
//! threads in bounded slots, each request with a deadline; `/` and
//! `/api/version` are answered on the I/O thread without waiting for a
//! slot.

mod field;
mod frame;
mod metrics;
pub mod request;

use std::collections::HashMap;
use std::convert::Infallible;
use std::future::Future;
use std::io::{self, Read};
use std::net::{Ipv4Addr, SocketAddr};
use std::path::{Path, PathBuf};
use std::pin::Pin;
use std::process::ExitCode;
use std::sync::{Arc, Mutex, MutexGuard};
use std::task::{ready, Context, Poll};
use std::time::{Duration, Instant};

use hyper::body::{Body as HttpBody, Bytes, Frame, Incoming, SizeHint};
use hyper::header::{HeaderValue, CACHE_CONTROL, CONTENT_TYPE, HOST};
use hyper::{Method, Request, Response, StatusCode};
use hyper_util::rt::{TokioIo, TokioTimer};
use sdfl_runtime::Lowered;
use sdfl_stdlib::Program;
use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};
use tokio::net::{TcpListener, TcpSocket, TcpStream};
use tokio::sync::{OwnedSemaphorePermit, Semaphore};
use tokio::time::Sleep;

use request::{Refusal, Route, Target};

/// The page, embedded in the binary.
const PAGE: &str = include_str!("page.html");

/// Largest held-out image served (a 16 384² PNG is far below this).
const MAX_IMAGE_BYTES: u64 = 256 << 20;

/// Connections open at once; further ones wait, unaccepted, in the
/// kernel's backlog (a browser opens about six).
const MAX_CONNECTIONS: usize = 256;
/// The listening socket's backlog.
const BACKLOG: u32 = 1024;
/// A request's headers must arrive within this, counted from when the
/// connection is ready for them (so it also closes idle keep-alive
/// connections and clients that send headers a byte at a time).
const HEADER_READ: Duration = Duration::from_secs(10);
/// A write that makes no progress for this long ends the connection: a
/// client that stops reading a large response frees it (`--write-stall`).
pub const WRITE_STALL: Duration = Duration::from_secs(10);
/// A connection is asked to close after this long (a client trickling a
/// large response never stalls a write outright); one still busy
/// [`CLOSE_GRACE`] later is dropped.
const MAX_LIFETIME: Duration = Duration::from_secs(600);
const CLOSE_GRACE: Duration = Duration::from_secs(60);
/// Largest request head buffered (targets are capped far below at
/// [`request::MAX_URL`]; hyper answers 431 beyond it).
const MAX_HEAD_BYTES: usize = 64 << 10;
/// After an accept fails for want of files or memory: time for connections
/// to close before the next try.
const ACCEPT_PAUSE: Duration = Duration::from_millis(100);
/// How often a run of failing accepts is reported.
const ACCEPT_REPORT: Duration = Duration::from_secs(60);

/// Frame requests in progress at once (traced one at a time; the rest wait
/// for the tracing lock on a blocking thread).
const FRAME_SLOTS: usize = 4;
/// Requests that read files or walk the program (`/api/scenes`,
/// `/api/train`, opening a held-out view) in progress at once.
const FILE_SLOTS: usize = 4;
/// Threads for blocking work: the slots, and the chunked reads of the
/// files being sent.
const BLOCKING_THREADS: usize = FRAME_SLOTS + FILE_SLOTS + 4;
/// How long a request waits for a slot before it is refused (503).
const SLOT_WAIT: Duration = Duration::from_secs(30);
/// How long a request's blocking work may take before the client is told
/// (503); the work itself runs on, holding its slot.
const REQUEST_DEADLINE: Duration = Duration::from_secs(120);
/// Bytes read from a file per piece of a response.
const CHUNK: usize = 256 << 10;

/// What `sdfl view` was asked to serve.
pub struct View {
    /// The scene file.
    pub file: PathBuf,
    /// Where training writes its metrics and held-out views.
    pub out: PathBuf,
    /// The port on 127.0.0.1 (0: any free one).
    pub port: u16,
    /// How long a write may make no progress before its connection ends
    /// (default [`WRITE_STALL`]).
    pub write_stall: Duration,
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
    /// The port served on (the `Host` a request must name).
    port: u16,
    /// [`View::write_stall`].
    write_stall: Duration,
    loaded: Mutex<Loaded>,
    /// Frames are traced one at a time (each uses every core).
    tracing: Arc<Mutex<()>>,
    /// The trained fields on view.
    fields: field::Fields,
    /// Slots for frame requests ([`FRAME_SLOTS`]).
    frames: Arc<Semaphore>,
    /// Slots for requests that read files ([`FILE_SLOTS`]).
    files: Arc<Semaphore>,
}

fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

/// Serves until interrupted. Prints the address on stdout first (with
/// `--port 0`, the port chosen).
pub fn view(v: View) -> ExitCode {
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_io()
        .enable_time()
        .max_blocking_threads(BLOCKING_THREADS)
        .build();
    let runtime = match runtime {
        Ok(r) => r,
        Err(e) => {
            say!("error[sdfl::io]: cannot start the server: {e}");
            return ExitCode::FAILURE;
        }
    };
    let listener = {
        let _in_runtime = runtime.enter();
        listen(v.port)
    };
    let (listener, addr) = match listener.and_then(|l| Ok((l.local_addr()?, l))) {
        Ok((addr, l)) => (l, addr),
        Err(e) => {
            say!(
                "error[sdfl::io]: cannot listen on 127.0.0.1:{}: {e}\n  help: choose another `--port` (0 picks a free one)",
                v.port
            );
            return ExitCode::FAILURE;
        }
    };
    let tracing = Arc::new(Mutex::new(()));
    let base = v.file.parent().map(Path::to_path_buf).unwrap_or_default();
    let shared = Arc::new(Shared {
        file: v.file.clone(),
        out: v.out.clone(),
        port: addr.port(),
        write_stall: v.write_stall,
        loaded: Mutex::new(Loaded {
            version: 0,
            program: None,
            diagnostics: String::new(),
            lowered: HashMap::new(),
        }),
        tracing: tracing.clone(),
        fields: field::Fields::start(v.out.clone(), base, tracing),
        frames: Arc::new(Semaphore::new(FRAME_SLOTS)),
        files: Arc::new(Semaphore::new(FILE_SLOTS)),
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
    runtime.block_on(accept(listener, shared));
    ExitCode::SUCCESS
}

/// The listening socket on 127.0.0.1 (loopback only: nothing else on the
/// network can reach the viewer).
fn listen(port: u16) -> io::Result<TcpListener> {
    let socket = TcpSocket::new_v4()?;
    // As std's listeners do: a restart binds while the last run's
    // connections linger in TIME_WAIT.
    #[cfg(unix)]
    socket.set_reuseaddr(true)?;
    socket.bind(SocketAddr::from((Ipv4Addr::LOCALHOST, port)))?;
    socket.listen(BACKLOG)
}

/// Accepts connections forever. A failed accept (EMFILE, ENFILE, ENOMEM…)
/// is said once a minute at most and retried after a pause: it passes as
/// connections close.
async fn accept(listener: TcpListener, shared: Arc<Shared>) {
    let open = Arc::new(Semaphore::new(MAX_CONNECTIONS));
    let mut reported: Option<Instant> = None;
    let mut unreported = 0u64;
    loop {
        // At the cap, stop accepting until a connection closes.
        let Ok(permit) = open.clone().acquire_owned().await else {
            // Never closed; were it, pause rather than spin.
            tokio::time::sleep(ACCEPT_PAUSE).await;
            continue;
        };
        match listener.accept().await {
            Ok((stream, _)) => {
                tokio::spawn(connection(stream, shared.clone(), permit));
            }
            Err(e) => {
                drop(permit);
                // A client that gave up before its connection was accepted
                // costs nothing: no pause.
                let transient = matches!(
                    e.kind(),
                    io::ErrorKind::ConnectionAborted
                        | io::ErrorKind::ConnectionReset
                        | io::ErrorKind::Interrupted
                );
                if transient {
                    continue;
                }
                if reported.is_none_or(|t| t.elapsed() >= ACCEPT_REPORT) {
                    let more = if unreported > 0 {
                        format!(" ({unreported} more since the last report)")
                    } else {
                        String::new()
                    };
                    say!("sdfl view: cannot accept a connection: {e}{more}; retrying");
                    reported = Some(Instant::now());
                    unreported = 0;
                } else {
                    unreported += 1;
                }
                tokio::time::sleep(ACCEPT_PAUSE).await;
            }
        }
    }
}

/// Serves one connection (HTTP/1.1 with keep-alive) until it closes, fails
/// or outlives [`MAX_LIFETIME`]; `_open` is its place under
/// [`MAX_CONNECTIONS`].
async fn connection(stream: TcpStream, shared: Arc<Shared>, _open: OwnedSemaphorePermit) {
    // Frames are single responses: no point delaying their last packet.
    let _ = stream.set_nodelay(true);
    let io = TokioIo::new(WriteDeadline::new(stream, shared.write_stall));
    let service = hyper::service::service_fn(move |request| {
        let shared = shared.clone();
        async move { Ok::<_, Infallible>(respond(&shared, request).await) }
    });
    let mut http = hyper::server::conn::http1::Builder::new();
    http.timer(TokioTimer::new())
        .header_read_timeout(HEADER_READ)
        .max_buf_size(MAX_HEAD_BYTES);
    let mut conn = std::pin::pin!(http.serve_connection(io, service));
    // Errors (a client gone, a stalled write, malformed HTTP) end only
    // this connection.
    if tokio::time::timeout(MAX_LIFETIME, conn.as_mut())
        .await
        .is_err()
    {
        conn.as_mut().graceful_shutdown();
        let _ = tokio::time::timeout(CLOSE_GRACE, conn).await;
    }
}

/// A TCP stream whose writes fail after `limit` without progress.
struct WriteDeadline {
    stream: TcpStream,
    limit: Duration,
    stall: Pin<Box<Sleep>>,
    /// Whether `stall` is counting (a write is pending).
    armed: bool,
}

impl WriteDeadline {
    fn new(stream: TcpStream, limit: Duration) -> WriteDeadline {
        WriteDeadline {
            stream,
            limit,
            stall: Box::pin(tokio::time::sleep(limit)),
            armed: false,
        }
    }

    /// `polled` as it is, unless it has been pending for `limit`.
    fn guard<T>(
        &mut self,
        cx: &mut Context<'_>,
        polled: Poll<io::Result<T>>,
    ) -> Poll<io::Result<T>> {
        if polled.is_ready() {
            self.armed = false;
            return polled;
        }
        if !self.armed {
            self.armed = true;
            let deadline = tokio::time::Instant::now() + self.limit;
            self.stall.as_mut().reset(deadline);
        }
        ready!(self.stall.as_mut().poll(cx));
        Poll::Ready(Err(io::Error::new(
            io::ErrorKind::TimedOut,
            "the client stopped reading",
        )))
    }
}

impl AsyncRead for WriteDeadline {
    fn poll_read(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &mut ReadBuf<'_>,
    ) -> Poll<io::Result<()>> {
        Pin::new(&mut self.get_mut().stream).poll_read(cx, buf)
    }
}

impl AsyncWrite for WriteDeadline {
    fn poll_write(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &[u8],
    ) -> Poll<io::Result<usize>> {
        let this = self.get_mut();
        let polled = Pin::new(&mut this.stream).poll_write(cx, buf);
        this.guard(cx, polled)
    }

    fn poll_write_vectored(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        bufs: &[io::IoSlice<'_>],
    ) -> Poll<io::Result<usize>> {
        let this = self.get_mut();
        let polled = Pin::new(&mut this.stream).poll_write_vectored(cx, bufs);
        this.guard(cx, polled)
    }

    fn is_write_vectored(&self) -> bool {
        self.stream.is_write_vectored()
    }

    fn poll_flush(self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        let this = self.get_mut();
        let polled = Pin::new(&mut this.stream).poll_flush(cx);
        this.guard(cx, polled)
    }

    fn poll_shutdown(self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        let this = self.get_mut();
        let polled = Pin::new(&mut this.stream).poll_shutdown(cx);
        this.guard(cx, polled)
    }
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
        // `crate::read` has said why on stderr.
        Err(()) => (None, format!("cannot read {}", shared.file.display())),
        Ok(src) => {
            let (program, diagnostics) = match sdfl_stdlib::load_warned(&src) {
                Ok((program, warnings)) => {
                    let text = if warnings.is_empty() {
                        String::new()
                    } else {
                        sdfl_lang::render(&src, &warnings, false)
                    };
                    (Some(Arc::new(program)), text)
                }
                Err(diags) => (None, sdfl_lang::render(&src, &diags, false)),
            };
            if !diagnostics.is_empty() {
                crate::term::say_raw(&diagnostics);
            }
            (program, diagnostics)
        }
    };
    let mut l = lock(&shared.loaded);
    l.version += 1;
    l.program = program;
    l.diagnostics = diagnostics;
    l.lowered.clear();
    say!("sdfl view: loaded version {}", l.version);
}

/// What a request is answered with.
enum Served {
    /// Bytes and their content type.
    Bytes(Vec<u8>, &'static str),
    /// A PNG file, sent as it is read.
    Png(FileBody),
}

/// A response body and its content type.
type Body = (Vec<u8>, &'static str);

const JSON: &str = "application/json";
const PNG: &str = "image/png";
const TEXT: &str = "text/plain; charset=utf-8";

fn json(v: &serde_json::Value) -> Body {
    (v.to_string().into_bytes(), JSON)
}

/// Answers one request; every failure is a status with a message.
async fn respond(shared: &Arc<Shared>, request: Request<Incoming>) -> Response<Reply> {
    let (status, body, kind) = match serve(shared, &request).await {
        Ok(Served::Bytes(bytes, kind)) => (200, Reply::bytes(bytes), kind),
        Ok(Served::Png(file)) => (200, Reply::File(file), PNG),
        Err(r) => (
            r.status,
            Reply::bytes(format!("{}\n", r.message).into_bytes()),
            TEXT,
        ),
    };
    let mut response = Response::new(body);
    *response.status_mut() =
        StatusCode::from_u16(status).unwrap_or(StatusCode::INTERNAL_SERVER_ERROR);
    let headers = response.headers_mut();
    headers.insert(CONTENT_TYPE, HeaderValue::from_static(kind));
    headers.insert(CACHE_CONTROL, HeaderValue::from_static("no-store"));
    headers.insert(
        "x-content-type-options",
        HeaderValue::from_static("nosniff"),
    );
    response
}

async fn serve(shared: &Arc<Shared>, request: &Request<Incoming>) -> Result<Served, Refusal> {
    if request.method() != Method::GET {
        return Err(Refusal {
            status: 405,
            message: "only GET is served".into(),
        });
    }
    // Only pages opened as this address: a page elsewhere that points a
    // name at 127.0.0.1 (DNS rebinding) is refused. Every `Host` given
    // counts, and the authority of an absolute target.
    let port = shared.port;
    let allowed = [format!("127.0.0.1:{port}"), format!("localhost:{port}")];
    let hosts = request
        .headers()
        .get_all(HOST)
        .iter()
        .map(|h| h.to_str().ok())
        .chain(request.uri().authority().map(|a| Some(a.as_str())));
    for host in hosts {
        if !host.is_some_and(|h| allowed.iter().any(|a| a == h)) {
            return Err(Refusal {
                status: 403,
                message: format!("served only as http://127.0.0.1:{port}/"),
            });
        }
    }
    let path = request.uri().path_and_query().map_or("/", |p| p.as_str());
    let target = Target::parse(path)?;
    let (version, program, diagnostics) = {
        let l = lock(&shared.loaded);
        (l.version, l.program.clone(), l.diagnostics.clone())
    };
    let bytes = |(bytes, kind): Body| Served::Bytes(bytes, kind);
    let s = shared.clone();
    match target.route {
        Route::Page => Ok(Served::Bytes(
            PAGE.as_bytes().to_vec(),
            "text/html; charset=utf-8",
        )),
        Route::Version => Ok(bytes(json(&serde_json::json!({
            "version": version,
            "ok": program.is_some(),
            "diagnostics": diagnostics,
            "file": shared.file.display().to_string(),
        })))),
        Route::Scenes => blocking(&shared.files, move || {
            Ok(json(&scenes(program.as_deref(), &s.out)))
        })
        .await
        .map(bytes),
        Route::Frame => blocking(&shared.frames, move || frame(&s, &target, program))
            .await
            .map(bytes),
        Route::Field => blocking(&shared.frames, move || {
            field_frame(&s, &target, version, program)
        })
        .await
        .map(bytes),
        Route::Train => blocking(&shared.files, move || {
            Ok(json(&trains(&s, program.as_deref())))
        })
        .await
        .map(bytes),
        Route::HeldOut => blocking(&shared.files, move || {
            held_out(&s, &target, program.as_deref())
        })
        .await
        .map(Served::Png),
    }
}

/// Runs `work` on a blocking thread once one of `slots` is free, refusing
/// (503) when none frees within [`SLOT_WAIT`] or the work outlasts
/// [`REQUEST_DEADLINE`] (it then finishes unseen, keeping its slot, so
/// slow work cannot pile up).
async fn blocking<T: Send + 'static>(
    slots: &Arc<Semaphore>,
    work: impl FnOnce() -> Result<T, Refusal> + Send + 'static,
) -> Result<T, Refusal> {
    let busy = |message: String| Refusal {
        status: 503,
        message,
    };
    let slot = match tokio::time::timeout(SLOT_WAIT, slots.clone().acquire_owned()).await {
        Ok(Ok(slot)) => slot,
        _ => {
            return Err(busy(format!(
                "the viewer is busy: no slot freed within {} s; try again",
                SLOT_WAIT.as_secs()
            )))
        }
    };
    let task = tokio::task::spawn_blocking(move || {
        let _slot = slot;
        work()
    });
    match tokio::time::timeout(REQUEST_DEADLINE, task).await {
        Ok(Ok(done)) => done,
        Ok(Err(_)) => Err(Refusal {
            status: 500,
            message: "the request failed inside the viewer".into(),
        }),
        Err(_) => Err(busy(format!(
            "the request took longer than {} s",
            REQUEST_DEADLINE.as_secs()
        ))),
    }
}

/// A response body: bytes in memory, or a file read a chunk at a time on
/// a blocking thread as the client takes it (a slow client holds one
/// chunk, not the file).
enum Reply {
    Bytes(Option<Bytes>),
    File(FileBody),
}

impl Reply {
    fn bytes(b: Vec<u8>) -> Reply {
        Reply::Bytes(Some(Bytes::from(b)))
    }
}

/// An open regular file and how much of it is still to send.
struct FileBody {
    file: Option<std::fs::File>,
    left: u64,
    /// The chunk being read, and the file, handed back with it.
    reading: Option<tokio::task::JoinHandle<(std::fs::File, io::Result<Vec<u8>>)>>,
}

impl FileBody {
    fn new(file: std::fs::File, len: u64) -> FileBody {
        FileBody {
            file: Some(file),
            left: len,
            reading: None,
        }
    }
}

impl HttpBody for Reply {
    type Data = Bytes;
    type Error = io::Error;

    fn poll_frame(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
    ) -> Poll<Option<Result<Frame<Bytes>, io::Error>>> {
        let f = match self.get_mut() {
            Reply::Bytes(b) => return Poll::Ready(b.take().map(|b| Ok(Frame::data(b)))),
            Reply::File(f) => f,
        };
        loop {
            if let Some(reading) = f.reading.as_mut() {
                let done = ready!(Pin::new(reading).poll(cx));
                f.reading = None;
                let (file, chunk) = done.map_err(|_| io::Error::other("a read failed"))?;
                f.file = Some(file);
                let chunk = chunk?;
                if chunk.is_empty() {
                    // Cut short since it was opened: the length sent is
                    // wrong, so the connection must end.
                    return Poll::Ready(Some(Err(io::ErrorKind::UnexpectedEof.into())));
                }
                f.left = f.left.saturating_sub(chunk.len() as u64);
                return Poll::Ready(Some(Ok(Frame::data(Bytes::from(chunk)))));
            }
            let Some(mut file) = f.file.take().filter(|_| f.left > 0) else {
                return Poll::Ready(None);
            };
            let want = f.left.min(CHUNK as u64) as usize;
            f.reading = Some(tokio::task::spawn_blocking(move || {
                let mut chunk = vec![0; want];
                let read = read_some(&mut file, &mut chunk).map(|n| {
                    chunk.truncate(n);
                    chunk
                });
                (file, read)
            }));
        }
    }

    fn is_end_stream(&self) -> bool {
        match self {
            Reply::Bytes(b) => b.is_none(),
            Reply::File(f) => f.left == 0,
        }
    }

    fn size_hint(&self) -> SizeHint {
        match self {
            Reply::Bytes(b) => SizeHint::with_exact(b.as_ref().map_or(0, |b| b.len() as u64)),
            Reply::File(f) => SizeHint::with_exact(f.left),
        }
    }
}

/// One read, retried when interrupted.
fn read_some(file: &mut std::fs::File, buf: &mut [u8]) -> io::Result<usize> {
    loop {
        match file.read(buf) {
            Err(e) if e.kind() == io::ErrorKind::Interrupted => continue,
            r => return r,
        }
    }
}

/// `path` with every link resolved, if it lies inside `out` (resolved
/// too); a path leading out of it, through a link anywhere along it, is
/// refused as `PermissionDenied`.
fn confined(out: &Path, path: &Path) -> io::Result<PathBuf> {
    let root = std::fs::canonicalize(out)?;
    let real = std::fs::canonicalize(path)?;
    if real.starts_with(&root) {
        Ok(real)
    } else {
        Err(io::Error::new(
            io::ErrorKind::PermissionDenied,
            format!("{} leads outside {}", path.display(), out.display()),
        ))
    }
}

/// The regular file at `path`, resolved inside `out`, open for reading
/// (a FIFO or device is refused, never waited on), and its length.
fn open_confined(out: &Path, path: &Path) -> io::Result<(std::fs::File, u64)> {
    let real = confined(out, path)?;
    // The resolved path names no link: one swapped in since is refused.
    let file = sdfl_stdlib::files::open_regular_unlinked(&real)?;
    let len = file.metadata()?.len();
    Ok((file, len))
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
/// `train` statement (its field, seen from its checkpoint under `out`,
/// with the training cameras it records).
fn scenes(program: Option<&Program>, out: &Path) -> serde_json::Value {
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
        let recorded = field::training_cameras(job, out);
        let c = field::initial_camera(job, &recorded);
        let mut e = view_entry("train", &job.name, &c, (job.width, job.height), FIELD_SIDES);
        e["checkpoint"] = job.checkpoint.is_some().into();
        e["training_cameras"] = recorded
            .iter()
            .map(|c| {
                serde_json::json!({
                    "eye": c.eye.to_array(),
                    "at": c.at.to_array(),
                    "up": c.up.to_array(),
                    "focal": c.focal,
                })
            })
            .collect::<Vec<_>>()
            .into();
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
    let recorded = field::training_cameras(job, &shared.out);
    let camera = frame_camera(t, Some(&field::initial_camera(job, &recorded)))?;
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
                // Read only where they resolve inside `--out`.
                "metrics": confined(&shared.out, &csv).ok().and_then(|p| metrics::read(&p)),
                "heldout": confined(&shared.out, &heldout).is_ok_and(|p| p.is_file()),
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

/// A `train` statement's held-out view as it stands in `--out`: a file
/// that resolves outside it is refused (403), never read.
fn held_out(shared: &Shared, t: &Target, program: Option<&Program>) -> Result<FileBody, Refusal> {
    let name = request::name("train", t.require("train")?)?;
    let known = program.is_some_and(|p| p.trains.iter().any(|j| j.name == name));
    if !known {
        return Err(Refusal::missing(format!(
            "no train statement named `{name}`"
        )));
    }
    let (_, _, path) = log_paths(&shared.out, name);
    let (file, len) = open_confined(&shared.out, &path).map_err(|e| {
        if e.kind() == io::ErrorKind::PermissionDenied {
            Refusal {
                status: 403,
                message: format!("`{name}`'s held-out view leads outside `--out`: not served"),
            }
        } else {
            Refusal::missing(format!("`{name}` has no held-out view yet"))
        }
    })?;
    if len > MAX_IMAGE_BYTES {
        return Err(Refusal::missing(format!(
            "`{name}`'s held-out view is larger than {} MiB: not served",
            MAX_IMAGE_BYTES >> 20
        )));
    }
    Ok(FileBody::new(file, len))
}
