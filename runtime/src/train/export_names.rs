//! How a checkpoint names and shapes a model's tensors, and the model's
//! specification it carries, so that the file is usable without sdfl (see
//! docs/checkpoints.md).
//!
//! The trainer keeps each model's parameters as flat named tensors in its
//! own order (a dense layer's `W` row-major as `(in, out)`); a file stores
//! each as one or more *pieces*: named by role, shaped, a layer's weight in
//! PyTorch's `(out, in)` order. Moving between the two is a permutation, so
//! a resumed run reads back the same bits.
//!
//! What is generic lives here; each model kind's own names and shapes
//! (`Layout::of`) live with the models, in `neural::layout`.

use serde_json::Value;

use super::frame::ModelFrame;
use super::TensorSpec;
use crate::data::normalize::SceneFrame;

/// One tensor of a checkpoint file.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Piece {
    /// The tensor's name in the file.
    pub name: String,
    /// The tensor's dimensions as stored.
    pub shape: Vec<usize>,
    /// Stored as `(out, in)` = `shape`, held by the trainer as the
    /// row-major transpose `(in, out)`.
    pub transposed: bool,
}

impl Piece {
    /// A tensor stored whole, one-dimensional, under the trainer's name.
    pub fn flat(name: &str, len: usize) -> Piece {
        Piece {
            name: name.to_string(),
            shape: vec![len],
            transposed: false,
        }
    }

    /// Scalars in the piece (`None` on overflow: a hostile shape).
    pub fn len(&self) -> Option<usize> {
        self.shape.iter().try_fold(1usize, |a, &d| a.checked_mul(d))
    }

    /// Whether the piece holds no scalars.
    pub fn is_empty(&self) -> bool {
        self.len() == Some(0)
    }
}

/// The pieces of each of a model's tensors (in the trainer's order) and
/// the model's specification.
#[derive(Debug, Clone, PartialEq)]
pub struct Layout {
    /// Each parameter tensor's pieces, in the trainer's order.
    pub params: Vec<Vec<Piece>>,
    /// The model's specification (JSON), stored in the file's metadata.
    pub model: Value,
    /// Where the model sits relative to its data, stored beside it.
    pub frame: ModelFrame,
}

impl Layout {
    /// Every tensor stored whole under its own name.
    pub fn flat(tensors: &[TensorSpec], model: Value) -> Layout {
        Layout {
            params: tensors
                .iter()
                .map(|t| vec![Piece::flat(&t.name, t.len)])
                .collect(),
            model,
            frame: ModelFrame::default(),
        }
    }

    /// This layout for a model trained in `frame` (the data loader's
    /// similarity; `None`: the data's own frame).
    pub fn in_data_frame(self, frame: Option<SceneFrame>) -> Layout {
        Layout {
            frame: self.frame.in_data_frame(frame),
            ..self
        }
    }

    /// This layout for a model trained on views taken by `cameras` (in the
    /// model's frame).
    pub fn with_cameras<'c>(
        self,
        cameras: impl ExactSizeIterator<Item = &'c sdfl_stdlib::camera::Camera>,
    ) -> Layout {
        Layout {
            frame: self.frame.with_cameras(cameras),
            ..self
        }
    }
}
