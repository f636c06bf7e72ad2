//! Tests of the jobs' parts: a training job's evaluation and resumption.

mod train {
    mod evaluation;
    mod resume;
}
