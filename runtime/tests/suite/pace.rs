//! The machine's pace: a plausible rate of multiply-adds.

use sdfl_runtime::pace::*;
use sdfl_stdlib::work::MULTIPLY_ADDS_PER_EVALUATION;

#[test]
fn the_rate_is_a_plausible_number_of_multiply_adds() {
    // Between a slow core's scalar loop and a large machine's peak.
    let r = layer_rate();
    assert!((1e8..1e14).contains(&r), "{r:e} multiply-adds a second");
    assert_eq!(
        evaluation_rate(),
        r / MULTIPLY_ADDS_PER_EVALUATION * RUN_EFFICIENCY
    );
}
