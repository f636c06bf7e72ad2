//! The expanded size of values, measured on the DAG before anything is
//! expanded: limits bound what lowering and tracing will cost (memory,
//! tree walks), not how many calls built the value.

use std::collections::HashMap;
use std::sync::Arc;

use sdfl_lang::diag::{codes, fmt_num, Diag};
use sdfl_lang::Span;

use crate::shape::Shape;
use crate::value::{Field, Value};

/// Deepest nesting of shapes and lists (built through chains of `let`s,
/// which brackets do not limit): tree walkers recurse this deep.
pub const MAX_DEPTH: usize = 200;

/// Most primitives one value may hold once expanded. Values are DAGs
/// (`union(a, a)` shares `a`), but lowering and tracing copy every use, so
/// this bounds lowering time and memory (see [`BYTES_PER_PRIMITIVE`]).
pub const MAX_PRIMITIVES: u64 = 2_000_000;
/// Most nodes (list items, shape nodes, transforms) one value may hold
/// once expanded: what tree walks over it visit.
pub const MAX_NODES: u64 = 16_000_000;
/// Peak memory per primitive of evaluating and lowering a scene, measured
/// (a million spheres: 567 MB at peak, scene IR, evaluator leaves, BVH
/// and primitive table); for the estimates printed in diagnostics.
pub const BYTES_PER_PRIMITIVE: u64 = 570;

/// The expanded size of a value: what walking it as a tree would visit.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Size {
    /// All nodes: list items, shape nodes, scalars.
    pub nodes: u64,
    /// Primitive shapes (leaves of shape trees).
    pub primitives: u64,
    /// Nodes on the longest path from the root (a scalar is 1).
    pub depth: usize,
    /// Items of lists, nested lists included (not what shapes hold): what
    /// a builtin flattening a list argument walks.
    pub items: u64,
    /// The most instructions of one leaf (a user function's; 0 for
    /// built-in primitives): what a step near it may pay.
    pub leaf_ops: u64,
}

impl Size {
    /// What one evaluation near the costliest leaf counts, in primitive
    /// distances (at least one).
    pub fn leaf_cost(&self) -> f64 {
        (self.leaf_ops as f64 / crate::shape::user::UserShape::OPS_PER_EVALUATION as f64).max(1.0)
    }
}

impl Size {
    pub(crate) const SCALAR: Size = Size {
        nodes: 1,
        primitives: 0,
        depth: 1,
        items: 0,
        leaf_ops: 0,
    };
    /// A node over `children` (saturating: expanded sizes of shared values
    /// grow exponentially with the sharing depth).
    pub(crate) fn node(children: impl IntoIterator<Item = Size>, primitive: bool) -> Size {
        let mut s = Size {
            nodes: 1,
            primitives: primitive as u64,
            depth: 0,
            items: 0,
            leaf_ops: 0,
        };
        for c in children {
            s.nodes = s.nodes.saturating_add(c.nodes);
            s.primitives = s.primitives.saturating_add(c.primitives);
            s.depth = s.depth.max(c.depth);
            s.items = s.items.saturating_add(c.items);
            s.leaf_ops = s.leaf_ops.max(c.leaf_ops);
        }
        s.depth = s.depth.saturating_add(1);
        s
    }
}

/// Expanded sizes of values, memoised by `Arc` identity so a DAG is
/// measured in time linear in its distinct nodes. The memo keeps each
/// measured `Arc` alive so its address is never reused by another value.
#[derive(Default)]
pub struct Sizes {
    shapes: HashMap<usize, (Arc<Shape>, Size)>,
    lists: HashMap<usize, (Arc<Vec<Value>>, Size)>,
}

/// Lists of scalars up to this long are not memoised.
const SMALL_LIST: usize = 16;

/// Recursion guard for values built outside the evaluator (never reached
/// for evaluated values, whose parts were measured when built).
const MEASURE_LIMIT: usize = MAX_DEPTH + 8;

impl Sizes {
    /// The expanded size of a value.
    pub fn of(&mut self, v: &Value) -> Size {
        self.value(v, 0)
    }

    fn value(&mut self, v: &Value, level: usize) -> Size {
        if level > MEASURE_LIMIT {
            return Size {
                depth: MEASURE_LIMIT,
                ..Size::SCALAR
            };
        }
        match v {
            Value::List(items) => {
                let key = Arc::as_ptr(items) as usize;
                if let Some((_, s)) = self.lists.get(&key) {
                    return *s;
                }
                let sizes: Vec<Size> = items.iter().map(|i| self.value(i, level + 1)).collect();
                let mut s = Size::node(sizes, false);
                s.items = s.items.saturating_add(items.len() as u64);
                // Short lists of scalars (vectors) are cheaper to measure
                // again than to keep alive in the memo.
                if items.len() > SMALL_LIST || s.depth > 2 {
                    self.lists.insert(key, (items.clone(), s));
                }
                s
            }
            Value::Shape(sh) => self.shape(sh, level),
            Value::Field(f) => match &**f {
                Field::Sdf(f) => Size {
                    items: 0,
                    ..Size::node([self.shape(&f.shape, level + 1)], false)
                },
                Field::Nerf(_) | Field::NeuralSdf(_) | Field::NeuralSurface(_) => Size::SCALAR,
            },
            _ => Size::SCALAR,
        }
    }

    /// The expanded size of a shape tree at nesting `level`.
    pub fn shape(&mut self, sh: &Arc<Shape>, level: usize) -> Size {
        let key = Arc::as_ptr(sh) as usize;
        if let Some((_, s)) = self.shapes.get(&key) {
            return *s;
        }
        if level > MEASURE_LIMIT {
            return Size {
                depth: MEASURE_LIMIT,
                ..Size::SCALAR
            };
        }
        let children = sh.children();
        if children.is_empty() {
            // Measured in O(1); not kept alive by the memo.
            let leaf_ops = match &**sh {
                Shape::User(u) => u.tape.ops().len() as u64,
                _ => 0,
            };
            return Size {
                leaf_ops,
                ..Size::node([], true)
            };
        }
        let sizes: Vec<Size> = children
            .into_iter()
            .map(|c| self.shape(c, level + 1))
            .collect();
        let s = Size::node(sizes, false);
        self.shapes.insert(key, (sh.clone(), s));
        s
    }
}

/// Bytes as a short human figure (`1.5 GB`).
pub fn fmt_bytes(b: f64) -> String {
    const UNITS: [&str; 5] = ["bytes", "kB", "MB", "GB", "TB"];
    let mut x = b;
    let mut u = 0;
    while x >= 1000.0 && u < UNITS.len() - 1 {
        x /= 1000.0;
        u += 1;
    }
    if u == 0 {
        format!("{x:.0} bytes")
    } else if x >= 1000.0 {
        format!("{} {}", fmt_num(x.round()), UNITS[u])
    } else {
        format!("{x:.1} {}", UNITS[u])
    }
}

/// The diagnostic for a value whose expanded size is over the limits.
pub(crate) fn size_error(size: Size, span: Span) -> Option<Diag> {
    if size.primitives > MAX_PRIMITIVES {
        let bytes = size.primitives as f64 * BYTES_PER_PRIMITIVE as f64;
        return Some(
            Diag::new(
                codes::TOO_LARGE,
                span,
                format!(
                    "this scene would have {} primitives once expanded (at most {})",
                    fmt_count(size.primitives),
                    fmt_count(MAX_PRIMITIVES)
                ),
            )
            .label(format!(
                "{} primitives, about {} of memory",
                fmt_count(size.primitives),
                fmt_bytes(bytes)
            ))
            .help(
                "every use of a shape is a copy when rendered (`union(a, a)` holds `a` twice): \
                     reduce the loop counts or the repetition",
            ),
        );
    }
    if size.nodes > MAX_NODES {
        return Some(
            Diag::new(
                codes::TOO_LARGE,
                span,
                format!(
                    "this value would have {} items once expanded (at most {})",
                    fmt_count(size.nodes),
                    fmt_count(MAX_NODES)
                ),
            )
            .label("too many items")
            .help(
                "every use of a list or shape is a copy: reduce the loop counts or the repetition",
            ),
        );
    }
    None
}

/// A count in a message: exact below a billion, else short scientific
/// (saturated counts of shared values are astronomically large).
pub fn fmt_count(n: u64) -> String {
    if n < 1_000_000_000 {
        n.to_string()
    } else if n == u64::MAX {
        "more than 1.8e19".into()
    } else {
        fmt_num(n as f64)
    }
}
