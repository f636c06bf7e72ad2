//! The terminal: messages on stderr that never fail a run, and whether
//! diagnostics are coloured.

use std::ffi::OsStr;
use std::io::IsTerminal;

/// `eprintln!` that ignores a closed or full stderr (which would panic):
/// every message of the CLI goes through `sdfl_runtime::output::stderr`.
macro_rules! say {
    ($($arg:tt)*) => {
        sdfl_runtime::output::stderr(&format!("{}\n", format_args!($($arg)*)))
    };
}

/// `eprint!` that ignores a closed or full stderr.
pub fn say_raw(text: &str) {
    sdfl_runtime::output::stderr(text);
}

/// Whether to colour, from `NO_COLOR`, `CLICOLOR` and whether stderr is a
/// terminal: never off a terminal, never when `NO_COLOR` is set to
/// anything but the empty string (no-color.org) or `CLICOLOR` is `0`.
pub fn wants_color(no_color: Option<&OsStr>, clicolor: Option<&OsStr>, terminal: bool) -> bool {
    let no_color = no_color.is_some_and(|v| !v.is_empty());
    let clicolor_off = clicolor.is_some_and(|v| v == "0");
    terminal && !no_color && !clicolor_off
}

/// Whether diagnostics on stderr are coloured here and now.
pub fn color() -> bool {
    wants_color(
        std::env::var_os("NO_COLOR").as_deref(),
        std::env::var_os("CLICOLOR").as_deref(),
        std::io::stderr().is_terminal(),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn colour_follows_no_color_clicolor_and_the_terminal() {
        let s = |v: &'static str| Some(OsStr::new(v));
        assert!(wants_color(None, None, true));
        assert!(!wants_color(None, None, false));
        assert!(!wants_color(s("1"), None, true));
        assert!(!wants_color(s("false"), None, true), "any value counts");
        assert!(wants_color(s(""), None, true), "empty is unset");
        assert!(!wants_color(None, s("0"), true));
        assert!(wants_color(None, s("1"), true));
        assert!(!wants_color(None, s("1"), false), "never off a terminal");
    }
}
