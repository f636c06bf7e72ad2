//! A whole scene file's statements, by kind and in file order.

use super::{RenderJob, TrainJob, VolumeJob};

/// Everything a scene file asks for, by kind, each in file order.
#[derive(Debug, Clone, Default)]
pub struct Program {
    /// `render` statements of shapes.
    pub renders: Vec<RenderJob>,
    /// `render` statements of fields (volume rendering).
    pub volumes: Vec<VolumeJob>,
    /// `train` statements.
    pub trains: Vec<TrainJob>,
    /// Every statement in file order (statements run in this order).
    pub order: Vec<Statement>,
}

/// What a statement runs: a `render` of a shape, a `render` of a field
/// (volume rendering) or a `train`. Named in reports as `render`, `volume`
/// and `train`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum StatementKind {
    /// A shape sphere-traced.
    Render,
    /// A field volume-rendered.
    Volume,
    /// A field trained.
    Train,
}

impl StatementKind {
    /// The kind of a statement written with `keyword` (`render`, `train`),
    /// whose `scene` field (if any) holds a field.
    pub fn of(keyword: &str, scene_is_field: bool) -> StatementKind {
        match (keyword, scene_is_field) {
            ("train", _) => StatementKind::Train,
            (_, true) => StatementKind::Volume,
            _ => StatementKind::Render,
        }
    }

    /// The statement of this kind at `index` of its list in a [`Program`].
    pub fn at(self, index: usize) -> Statement {
        match self {
            StatementKind::Render => Statement::Render(index),
            StatementKind::Volume => Statement::Volume(index),
            StatementKind::Train => Statement::Train(index),
        }
    }
}

/// A statement of a [`Program`]: which list, and where in it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Statement {
    /// The `render` of a shape at this index of [`Program::renders`].
    Render(usize),
    /// The volume render at this index of [`Program::volumes`].
    Volume(usize),
    /// The `train` at this index of [`Program::trains`].
    Train(usize),
}

impl Statement {
    /// What it runs.
    pub fn kind(self) -> StatementKind {
        match self {
            Statement::Render(_) => StatementKind::Render,
            Statement::Volume(_) => StatementKind::Volume,
            Statement::Train(_) => StatementKind::Train,
        }
    }
}
