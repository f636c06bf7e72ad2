//! Tests of training's parts: checkpoints, logs, tapes, parameters, the
//! trainer.

mod checkpoint;
mod export_names;
mod frame;
mod graph_ops;
mod log;
mod params;
mod tape;
mod tensorboard;
mod trainer;
