//! Tests of the lowered SDF evaluators' parts: lanes, tiles, user shapes.

mod lanes;
mod tiles;
mod user;
