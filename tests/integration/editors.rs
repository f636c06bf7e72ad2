//! Editor support end to end: `sdfl fmt` (in place, `--check`, stdin,
//! files that do not parse) and `sdfl completions`.

use crate::common;
use std::io::Write;
use std::path::PathBuf;
use std::process::{Command, Stdio};

use crate::common::run_sdfl as sdfl;

fn temp(name: &str) -> PathBuf {
    common::temp_dir("editors", name)
}

const MESSY: &str = "let  a=[1,2]  // two\nrender r{scene:sphere(a[0]),outputs:[image(\"r.png\")]}";
const TIDY: &str = "let a = [1, 2] // two\nrender r {\n  scene: sphere(a[0]),\n  outputs: [image(\"r.png\")],\n}\n";

#[test]
fn fmt_check_lists_files_that_would_change_and_writes_nothing() {
    let dir = temp("check");
    let messy = dir.join("messy.sdfl");
    let tidy = dir.join("tidy.sdfl");
    std::fs::write(&messy, MESSY).unwrap();
    std::fs::write(&tidy, TIDY).unwrap();
    let o = sdfl(&["fmt", "--check", dir.to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(1));
    assert_eq!(
        String::from_utf8_lossy(&o.stdout),
        format!("{}\n", messy.display())
    );
    assert_eq!(std::fs::read_to_string(&messy).unwrap(), MESSY);
    let o = sdfl(&["fmt", "--check", tidy.to_str().unwrap()]);
    assert!(o.status.success(), "{o:?}");
    assert!(o.stdout.is_empty());
}

#[test]
fn fmt_rewrites_in_place_keeping_permissions() {
    use std::os::unix::fs::PermissionsExt;
    let dir = temp("write");
    let messy = dir.join("messy.sdfl");
    std::fs::write(&messy, MESSY).unwrap();
    std::fs::set_permissions(&messy, std::fs::Permissions::from_mode(0o640)).unwrap();
    let o = sdfl(&["fmt", messy.to_str().unwrap()]);
    assert!(o.status.success(), "{o:?}");
    assert_eq!(std::fs::read_to_string(&messy).unwrap(), TIDY);
    let mode = std::fs::metadata(&messy).unwrap().permissions().mode() & 0o777;
    assert_eq!(mode, 0o640);
    // No temporary file is left beside it.
    assert_eq!(std::fs::read_dir(&dir).unwrap().count(), 1);
    // A second run changes nothing and lists nothing.
    let o = sdfl(&["fmt", messy.to_str().unwrap()]);
    assert!(o.status.success() && o.stdout.is_empty(), "{o:?}");
}

#[test]
fn fmt_leaves_a_file_that_does_not_parse_and_reports_it() {
    let dir = temp("broken");
    let broken = dir.join("broken.sdfl");
    let good = dir.join("good.sdfl");
    let text = "let a = (1 +\nlet b = ]\n";
    std::fs::write(&broken, text).unwrap();
    std::fs::write(&good, MESSY).unwrap();
    let o = sdfl(&["fmt", broken.to_str().unwrap(), good.to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(1));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("sdfl::syntax"), "{err}");
    assert!(err.contains("broken.sdfl"), "{err}");
    assert_eq!(std::fs::read_to_string(&broken).unwrap(), text);
    // The other files are still formatted.
    assert_eq!(std::fs::read_to_string(&good).unwrap(), TIDY);
}

#[test]
fn fmt_formats_stdin_to_stdout() {
    let mut child = Command::new(env!("CARGO_BIN_EXE_sdfl"))
        .args(["fmt", "-"])
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .spawn()
        .unwrap();
    child
        .stdin
        .take()
        .unwrap()
        .write_all(MESSY.as_bytes())
        .unwrap();
    let o = child.wait_with_output().unwrap();
    assert!(o.status.success());
    assert_eq!(String::from_utf8_lossy(&o.stdout), TIDY);
}

#[test]
fn fmt_refuses_what_is_no_text_file() {
    let dir = temp("refuse");
    let binary = dir.join("b.sdfl");
    std::fs::write(&binary, b"let a = \"\xff\"\n").unwrap();
    let o = sdfl(&["fmt", binary.to_str().unwrap(), "/dev/zero"]);
    assert_eq!(o.status.code(), Some(1));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("not UTF-8"), "{err}");
    assert!(err.contains("/dev/zero"), "{err}");
    assert_eq!(std::fs::read(&binary).unwrap(), b"let a = \"\xff\"\n");
}

#[test]
fn bash_completions_name_every_subcommand() {
    let o = sdfl(&["completions", "bash"]);
    assert!(o.status.success());
    let script = String::from_utf8_lossy(&o.stdout);
    let help = String::from_utf8_lossy(&sdfl(&["--help"]).stdout).into_owned();
    // The subcommands as `sdfl --help` lists them (two-space indented).
    let commands: Vec<&str> = help
        .split("Commands:")
        .nth(1)
        .expect("help lists commands")
        .lines()
        .skip(1)
        .take_while(|l| !l.trim().is_empty())
        .filter_map(|l| l.split_whitespace().next())
        .filter(|c| *c != "help")
        .collect();
    assert!(commands.len() >= 8, "{commands:?}");
    for c in ["run", "check", "fmt", "completions"] {
        assert!(commands.contains(&c), "{c} not in {commands:?}");
    }
    for c in commands {
        assert!(
            script.contains(&format!("sdfl,{c})")),
            "bash completions miss `{c}`"
        );
    }
    for shell in ["zsh", "fish", "powershell", "elvish"] {
        let o = sdfl(&["completions", shell]);
        assert!(o.status.success() && !o.stdout.is_empty(), "{shell}");
    }
    assert!(!sdfl(&["completions", "tcsh"]).status.success());
}
