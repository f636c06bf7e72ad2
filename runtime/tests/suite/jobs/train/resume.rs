//! Resuming: default moments keep the fingerprint of older checkpoints.

use sdfl_runtime::jobs::train::resume::*;
use sdfl_stdlib::value::{Moments, Optimizer, Schedule};

#[test]
fn default_moments_keep_the_fingerprint_of_checkpoints_before_them() {
    let mut o = Optimizer {
        lr: 0.01,
        schedule: Schedule::Step {
            factor: 0.5,
            every: 100,
        },
        moments: Moments::default(),
    };
    // The text `{:?}` gave before `moments` existed.
    let before = "Optimizer { lr: 0.01, schedule: Step { factor: 0.5, every: 100 } }";
    assert_eq!(optimizer_key(&o), before);
    assert_eq!(
        format!("{:?}", (Verbatim(optimizer_key(&o)), 1)),
        format!("({before}, 1)")
    );
    o.moments.beta2 = 0.99;
    assert_ne!(optimizer_key(&o), before);
}
