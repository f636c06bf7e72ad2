//! Stopping on SIGINT, SIGTERM or SIGHUP (a closed terminal or ssh
//! session) without leaving anything half-written.
//!
//! [`install`] starts a thread that waits for either signal (signal-hook's
//! handler only wakes it). What the thread does depends on what runs:
//! - A training loop (inside a [`Graceful`] scope) is asked to stop after
//!   its current step ([`stop_requested`]): it writes its checkpoint and
//!   returns a [`Stopped`] error saying where it stopped. A second signal
//!   stops at once.
//! - Anything else stops at once: the temporary files in flight are
//!   removed ([`crate::output::abandon_in_flight`]; finished outputs and
//!   checkpoints are renamed into place whole, so they stay intact), the
//!   statement that was running is named, and the process exits with
//!   128 + the signal: 130 for SIGINT, 143 for SIGTERM, 129 for SIGHUP,
//!   as a shell does.

use std::fmt;
use std::io;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Mutex, MutexGuard};

use crate::output::stderr;

struct State {
    /// The statement running, for the message.
    running: String,
    /// Inside a [`Graceful`] scope.
    graceful: bool,
    /// A signal the graceful scope has not yet acted on.
    pending: Option<i32>,
}

static STATE: Mutex<State> = Mutex::new(State {
    running: String::new(),
    graceful: false,
    pending: None,
});

fn state() -> MutexGuard<'static, State> {
    STATE.lock().unwrap_or_else(|e| e.into_inner())
}

/// The signals' numbers (the same on every Unix).
const SIGHUP: i32 = 1;
const SIGINT: i32 = 2;
const SIGTERM: i32 = 15;

/// Handles SIGINT, SIGTERM and SIGHUP from now on (see the module's docs).
#[cfg(unix)]
pub fn install() -> io::Result<()> {
    const _: () = assert!(SIGINT == signal_hook::consts::SIGINT);
    const _: () = assert!(SIGTERM == signal_hook::consts::SIGTERM);
    const _: () = assert!(SIGHUP == signal_hook::consts::SIGHUP);
    let mut signals = signal_hook::iterator::Signals::new([SIGINT, SIGTERM, SIGHUP])?;
    std::thread::Builder::new()
        .name("signals".into())
        .spawn(move || {
            for signal in signals.forever() {
                on_signal(signal);
            }
        })?;
    Ok(())
}

/// Elsewhere, Ctrl-C ends the process as it always does.
#[cfg(not(unix))]
pub fn install() -> io::Result<()> {
    Ok(())
}

/// Names the statement now running, for the message a signal prints.
pub fn running(statement: &str) {
    statement.clone_into(&mut state().running);
}

#[cfg_attr(not(unix), allow(dead_code))]
fn on_signal(signal: i32) {
    let mut s = state();
    if s.graceful && s.pending.is_none() {
        s.pending = Some(signal);
        stderr(&format!(
            "\n{}: stopping `{}` after this step (again to stop at once)\n",
            name(signal),
            s.running
        ));
        return;
    }
    let running = std::mem::take(&mut s.running);
    drop(s);
    exit_now(signal, &running)
}

/// Set once the process is exiting on a signal.
static EXITING: AtomicBool = AtomicBool::new(false);

/// Whether the process is exiting on a signal: an error met meanwhile
/// (a file refused because the process is stopping) is not the outcome,
/// and should not be reported or returned before the exit.
pub fn exiting() -> bool {
    EXITING.load(Ordering::SeqCst)
}

/// Waits for the exit under way, if the process is exiting on a signal:
/// for a caller about to report an error, which is then not the outcome.
pub fn wait_if_exiting() {
    while exiting() {
        std::thread::park();
    }
}

/// Removes the files in flight, says what stopped, and exits.
fn exit_now(signal: i32, running: &str) -> ! {
    EXITING.store(true, Ordering::SeqCst);
    let removed = crate::output::abandon_in_flight();
    let what = if running.is_empty() {
        "before any statement ran".to_string()
    } else {
        format!("while running `{running}`")
    };
    let files = match removed {
        0 => String::new(),
        1 => "; removed the unfinished file".to_string(),
        n => format!("; removed the {n} unfinished files"),
    };
    stderr(&format!(
        "\nsdfl: stopped by {} {what}{files}; finished outputs and checkpoints are kept\n",
        name(signal)
    ));
    std::process::exit(exit_code(signal).into())
}

fn name(signal: i32) -> &'static str {
    match signal {
        SIGINT => "SIGINT",
        SIGTERM => "SIGTERM",
        SIGHUP => "SIGHUP",
        _ => "a signal",
    }
}

/// The exit status for a stop by `signal`: 128 + its number, as a shell
/// reports a process the signal killed.
pub fn exit_code(signal: i32) -> u8 {
    (128 + signal).clamp(0, 255) as u8
}

/// While this lives, a signal asks its holder to stop at a point of its
/// choosing ([`stop_requested`]) instead of stopping the process at once.
/// Dropped with a request not taken, it stops the process then.
pub struct Graceful(());

impl Graceful {
    /// Starts deferring stop signals (SIGINT, SIGTERM, SIGHUP) to the holder.
    pub fn begin() -> Graceful {
        let mut s = state();
        s.graceful = true;
        s.pending = None;
        Graceful(())
    }
}

impl Drop for Graceful {
    fn drop(&mut self) {
        let mut s = state();
        s.graceful = false;
        if let Some(signal) = s.pending.take() {
            let running = std::mem::take(&mut s.running);
            drop(s);
            exit_now(signal, &running);
        }
    }
}

/// The signal that asked a [`Graceful`] scope to stop, if one did; taken
/// once, after which a further signal stops the process at once.
pub fn stop_requested() -> Option<i32> {
    let mut s = state();
    let signal = s.pending.take();
    if signal.is_some() {
        s.graceful = false;
    }
    signal
}

/// The error of a run stopped by a signal: not a failure of the input.
#[derive(Debug)]
pub struct Stopped {
    /// The signal's number.
    pub signal: i32,
    /// Where it stopped and what was kept.
    pub message: String,
}

impl Stopped {
    /// The error for a stop by `signal`, with `message` (where it stopped,
    /// what was kept).
    pub fn error(signal: i32, message: String) -> io::Error {
        io::Error::new(io::ErrorKind::Interrupted, Stopped { signal, message })
    }

    /// The [`Stopped`] inside `e`, if `e` is one.
    pub fn of(e: &io::Error) -> Option<&Stopped> {
        e.get_ref()
            .and_then(|inner| inner.downcast_ref::<Stopped>())
    }
}

impl fmt::Display for Stopped {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "stopped by {}: {}", name(self.signal), self.message)
    }
}

impl std::error::Error for Stopped {}
