//! A stop by a signal is an error that says so.

use sdfl_runtime::interrupt::*;
use std::io;

#[test]
fn a_stop_is_an_error_that_says_so() {
    let e = Stopped::error(2, "training `t` stopped at step 7".into());
    let s = Stopped::of(&e).expect("a Stopped");
    assert_eq!(s.signal, 2);
    assert_eq!(
        e.to_string(),
        "stopped by SIGINT: training `t` stopped at step 7"
    );
    assert!(Stopped::of(&io::Error::other("other")).is_none());
    assert_eq!((exit_code(2), exit_code(15)), (130, 143));
}
