//! The built-in functions and statements: signature, docs and evaluation of
//! each, in one table. Defaults are sdfl source text, evaluated by the
//! language itself.

use std::collections::HashMap;
use std::path::{Component, Path, PathBuf};
use std::sync::{Arc, OnceLock};

use glam::{DQuat, DVec3};
use sdfl_lang::diag::{codes, Diag};
use sdfl_lang::types::{BlockSig, Env, Param, Signature, Type};
use sdfl_lang::Span;

use crate::camera::{Camera, OrbitUp};
use crate::eval::describe;
use crate::material::Material;
use crate::shape::Shape;
use crate::value::{Output, OutputKind, RenderJob, Value};

pub const SHAPE: Type = Type::Named("shape");
pub const MATERIAL: Type = Type::Named("material");
pub const CAMERA: Type = Type::Named("camera");
pub const OUTPUT: Type = Type::Named("output");

/// Largest image side in pixels.
pub const MAX_IMAGE_SIDE: u32 = 16_384;
/// Most camera views of one render.
pub const MAX_VIEWS: usize = 10_000;
/// Most sphere-tracing iterations per ray.
pub const MAX_ITERATIONS: u32 = 100_000;

/// Arguments bound to parameter names, each with the span it came from
/// (the call's span for defaults).
pub struct Args {
    pub named: HashMap<&'static str, (Value, Span)>,
    pub rest: Vec<(Value, Span)>,
    pub span: Span,
}

fn value_error(
    span: Span,
    message: impl Into<String>,
    label: impl Into<String>,
    help: impl Into<String>,
) -> Diag {
    Diag::new(codes::VALUE, span, message)
        .label(label)
        .help(help)
}

fn type_error(span: Span, want: &str, got: &Value) -> Diag {
    Diag::new(
        codes::TYPE,
        span,
        format!("expected a {want}, found a {}", describe(got)),
    )
    .label(format!("this is a {}", describe(got)))
    .help(format!("pass a {want} here"))
}

impl Args {
    pub fn new(span: Span) -> Self {
        Args {
            named: HashMap::new(),
            rest: Vec::new(),
            span,
        }
    }

    fn get(&self, name: &str) -> (&Value, Span) {
        let (v, s) = self.named.get(name).unwrap_or_else(|| {
            panic!("parameter `{name}` is neither given nor defaulted: the checker guarantees one")
        });
        (v, *s)
    }

    pub fn number(&self, name: &str) -> Result<f64, Diag> {
        match self.get(name) {
            (Value::Number(x), _) => Ok(*x),
            (v, s) => Err(type_error(s, "number", v)),
        }
    }

    /// A finite number `> 0`.
    pub fn positive(&self, name: &str) -> Result<f64, Diag> {
        let x = self.number(name)?;
        if x > 0.0 {
            Ok(x)
        } else {
            Err(value_error(
                self.get(name).1,
                format!("`{name}` must be positive, got {x}"),
                "not > 0",
                format!("give `{name}` a value greater than zero"),
            ))
        }
    }

    /// A whole number in `lo..=hi`.
    pub fn count(&self, name: &str, lo: u64, hi: u64) -> Result<u64, Diag> {
        let x = self.number(name)?;
        if x.fract() != 0.0 || x < lo as f64 || x > hi as f64 {
            return Err(value_error(
                self.get(name).1,
                format!("`{name}` must be a whole number from {lo} to {hi}, got {x}"),
                "out of range",
                format!("use a whole number between {lo} and {hi}"),
            ));
        }
        Ok(x as u64)
    }

    pub fn vec3(&self, name: &str) -> Result<DVec3, Diag> {
        let (v, s) = self.get(name);
        match v {
            Value::Number(x) => Ok(DVec3::splat(*x)),
            _ => v
                .as_vec3()
                .ok_or_else(|| type_error(s, "vector [x, y, z]", v)),
        }
    }

    /// A vector whose components are all positive.
    pub fn positive_vec3(&self, name: &str) -> Result<DVec3, Diag> {
        let v = self.vec3(name)?;
        if v.min_element() > 0.0 {
            Ok(v)
        } else {
            Err(value_error(
                self.get(name).1,
                format!(
                    "every component of `{name}` must be positive, got [{}, {}, {}]",
                    v.x, v.y, v.z
                ),
                "not all > 0",
                format!("give `{name}` positive components"),
            ))
        }
    }

    /// A nonzero vector, normalised.
    pub fn direction(&self, name: &str) -> Result<DVec3, Diag> {
        let v = self.vec3(name)?;
        let len = v.length();
        if len > 1e-12 {
            Ok(v / len)
        } else {
            Err(value_error(
                self.get(name).1,
                format!("`{name}` must be a nonzero direction"),
                "zero vector",
                "give a direction such as [0, 0, 1]",
            ))
        }
    }

    pub fn string(&self, name: &str) -> Result<(Arc<str>, Span), Diag> {
        match self.get(name) {
            (Value::Str(s), span) => Ok((s.clone(), span)),
            (v, s) => Err(type_error(s, "string", v)),
        }
    }

    pub fn shape(&self, name: &str) -> Result<Arc<Shape>, Diag> {
        match self.get(name) {
            (Value::Shape(s), _) => Ok(s.clone()),
            (v, s) => Err(type_error(s, "shape", v)),
        }
    }

    /// A material, or a colour `[r, g, b]` meaning a constant material.
    pub fn material(&self, name: &str) -> Result<Arc<Material>, Diag> {
        match self.get(name) {
            (Value::Material(m), _) => Ok(m.clone()),
            (v, s) => match v.as_vec3() {
                Some(c) => Ok(Arc::new(Material::Constant(colour(c, s)?))),
                None => Err(type_error(s, "material", v)),
            },
        }
    }

    /// The rest arguments, with lists flattened, as shapes.
    pub fn rest_shapes(&self) -> Result<Vec<Arc<Shape>>, Diag> {
        fn walk(v: &Value, span: Span, out: &mut Vec<Arc<Shape>>) -> Result<(), Diag> {
            match v {
                Value::Shape(s) => Ok(out.push(s.clone())),
                Value::List(items) => items.iter().try_for_each(|i| walk(i, span, out)),
                other => Err(type_error(span, "shape", other)),
            }
        }
        let mut out = Vec::new();
        for (v, s) in &self.rest {
            walk(v, *s, &mut out)?;
        }
        Ok(out)
    }
}

fn colour(c: DVec3, span: Span) -> Result<DVec3, Diag> {
    if c.min_element() >= 0.0 && c.max_element() <= 1.0 {
        Ok(c)
    } else {
        Err(value_error(
            span,
            format!(
                "colour components must be in 0..1, got [{}, {}, {}]",
                c.x, c.y, c.z
            ),
            "out of 0..1",
            "colours are linear RGB with components from 0 to 1",
        ))
    }
}

pub type EvalFn = fn(&Args) -> Result<Value, Diag>;

pub struct Builtin {
    pub sig: Signature,
    pub eval: EvalFn,
}

/// The standard library as the checker and evaluator see it.
pub struct StdEnv {
    builtins: Vec<Builtin>,
    index: HashMap<&'static str, usize>,
    blocks: Vec<BlockSig>,
    constants: Vec<(&'static str, f64)>,
}

impl StdEnv {
    /// The one standard library, built on first use.
    pub fn get() -> &'static StdEnv {
        static ENV: OnceLock<StdEnv> = OnceLock::new();
        ENV.get_or_init(|| {
            let builtins = table();
            let index = builtins
                .iter()
                .enumerate()
                .map(|(i, b)| (b.sig.name, i))
                .collect();
            StdEnv {
                builtins,
                index,
                blocks: vec![render_sig()],
                constants: vec![("pi", std::f64::consts::PI), ("tau", std::f64::consts::TAU)],
            }
        })
    }

    pub fn builtin(&self, name: &str) -> Option<&Builtin> {
        self.index.get(name).map(|i| &self.builtins[*i])
    }

    pub fn builtins(&self) -> &[Builtin] {
        &self.builtins
    }

    pub fn block_sig(&self, kind: &str) -> Option<&BlockSig> {
        self.blocks.iter().find(|b| b.kind == kind)
    }

    pub fn blocks(&self) -> &[BlockSig] {
        &self.blocks
    }

    pub fn constant_value(&self, name: &str) -> Option<Value> {
        self.constants
            .iter()
            .find(|c| c.0 == name)
            .map(|c| Value::Number(c.1))
    }
}

impl Env for StdEnv {
    fn function(&self, name: &str) -> Option<&Signature> {
        self.builtin(name).map(|b| &b.sig)
    }
    fn block(&self, kind: &str) -> Option<&BlockSig> {
        self.block_sig(kind)
    }
    fn constant(&self, name: &str) -> Option<Type> {
        self.constant_value(name).map(|_| Type::Number)
    }
    fn function_names(&self) -> Vec<&'static str> {
        self.builtins.iter().map(|b| b.sig.name).collect()
    }
    fn block_names(&self) -> Vec<&'static str> {
        self.blocks.iter().map(|b| b.kind).collect()
    }
    fn constant_names(&self) -> Vec<&'static str> {
        self.constants.iter().map(|c| c.0).collect()
    }
}

// ------------------------------------------------------------------ the table

fn req(name: &'static str, ty: Type, doc: &'static str) -> Param {
    Param::required(name, ty, doc)
}
fn opt(name: &'static str, ty: Type, default: &'static str, doc: &'static str) -> Param {
    Param::optional(name, ty, default, doc)
}
fn num_or_vec() -> Type {
    Type::OneOf(vec![Type::Number, Type::Vec3])
}

fn func(
    name: &'static str,
    doc: &'static str,
    params: Vec<Param>,
    returns: Type,
    eval: EvalFn,
) -> Builtin {
    Builtin {
        sig: Signature {
            name,
            params,
            rest: None,
            returns,
            doc,
        },
        eval,
    }
}

fn variadic(
    name: &'static str,
    doc: &'static str,
    rest: Param,
    returns: Type,
    eval: EvalFn,
) -> Builtin {
    Builtin {
        sig: Signature {
            name,
            params: Vec::new(),
            rest: Some(rest),
            returns,
            doc,
        },
        eval,
    }
}

fn shape(s: Shape) -> Result<Value, Diag> {
    Ok(Value::Shape(Arc::new(s)))
}

fn math1(name: &'static str, doc: &'static str, eval: EvalFn) -> Builtin {
    func(
        name,
        doc,
        vec![req("x", Type::Number, "the argument")],
        Type::Number,
        eval,
    )
}

fn finite(x: f64, args: &Args, what: &str) -> Result<Value, Diag> {
    if x.is_finite() {
        Ok(Value::Number(x))
    } else {
        Err(Diag::new(
            codes::ARITHMETIC,
            args.span,
            format!("{what} is not a finite number"),
        )
        .label(format!("gives {x}"))
        .help("check the argument's domain"))
    }
}

fn table() -> Vec<Builtin> {
    let center = || opt("center", Type::Vec3, "[0, 0, 0]", "centre of the shape");
    let smooth = |name: &'static str, doc: &'static str, eval: EvalFn| {
        func(
            name,
            doc,
            vec![
                req("a", SHAPE, "first shape"),
                req("b", SHAPE, "second shape"),
                opt("k", Type::Number, "0.25", "blend radius (> 0)"),
            ],
            SHAPE,
            eval,
        )
    };
    let output = |name: &'static str, doc: &'static str, eval: EvalFn| {
        func(
            name,
            doc,
            vec![req(
                "path",
                Type::Str,
                "file name inside the output directory",
            )],
            OUTPUT,
            eval,
        )
    };
    vec![
        // ---- shapes
        func(
            "sphere",
            "A sphere: `|p - center| - radius` (exact).",
            vec![opt("radius", Type::Number, "1", "radius (> 0)"), center()],
            SHAPE,
            |a| shape(Shape::Sphere { center: a.vec3("center")?, radius: a.positive("radius")? }),
        ),
        func(
            "box",
            "A box with full side lengths `size` (exact).",
            vec![opt("size", num_or_vec(), "[1, 1, 1]", "side lengths (> 0); a number for a cube"), center()],
            SHAPE,
            |a| shape(Shape::Box { center: a.vec3("center")?, size: a.positive_vec3("size")? }),
        ),
        func(
            "box_frame",
            "The edges of a box: side lengths `size`, edge `thickness` (exact).",
            vec![
                opt("size", num_or_vec(), "[1, 1, 1]", "side lengths (> 0)"),
                opt("thickness", Type::Number, "0.05", "edge thickness (> 0, below half the smallest side)"),
                center(),
            ],
            SHAPE,
            |a| {
                let size = a.positive_vec3("size")?;
                let thickness = a.positive("thickness")?;
                if thickness >= size.min_element() * 0.5 {
                    return Err(value_error(
                        a.get("thickness").1,
                        format!("`thickness` {thickness} is not below half the smallest side {}", size.min_element()),
                        "too thick",
                        "a frame this thick is a solid box: use `box`, or thinner edges",
                    ));
                }
                shape(Shape::BoxFrame { center: a.vec3("center")?, size, thickness })
            },
        ),
        func(
            "torus",
            "A torus in the XY plane around the Z axis (exact).",
            vec![
                opt("major", Type::Number, "1", "distance from the centre to the tube's centre (> 0)"),
                opt("minor", Type::Number, "0.25", "radius of the tube (> 0)"),
                center(),
            ],
            SHAPE,
            |a| shape(Shape::Torus { center: a.vec3("center")?, major: a.positive("major")?, minor: a.positive("minor")? }),
        ),
        func(
            "capsule",
            "A segment from `a` to `b` thickened by `radius` (exact).",
            vec![
                req("a", Type::Vec3, "one end"),
                req("b", Type::Vec3, "the other end"),
                opt("radius", Type::Number, "0.25", "radius (> 0)"),
            ],
            SHAPE,
            |a| shape(Shape::Capsule { a: a.vec3("a")?, b: a.vec3("b")?, radius: a.positive("radius")? }),
        ),
        func(
            "cylinder",
            "A capped cylinder along the Z axis (exact).",
            vec![
                opt("radius", Type::Number, "0.5", "radius (> 0)"),
                opt("height", Type::Number, "1", "full height (> 0)"),
                center(),
            ],
            SHAPE,
            |a| shape(Shape::Cylinder { center: a.vec3("center")?, radius: a.positive("radius")?, height: a.positive("height")? }),
        ),
        func(
            "plane",
            "The half-space below a plane: `dot(p, normal) - height` (exact, unbounded).",
            vec![
                opt("normal", Type::Vec3, "[0, 1, 0]", "the plane's normal (nonzero)"),
                opt("height", Type::Number, "0", "offset along the normal"),
            ],
            SHAPE,
            |a| shape(Shape::Plane { normal: a.direction("normal")?, height: a.number("height")? }),
        ),
        // ---- combinators
        variadic(
            "union",
            "The union (minimum) of shapes; lists are flattened. Culled with a BVH when large.",
            req("shapes", SHAPE, "shapes or lists of shapes"),
            SHAPE,
            |a| {
                let shapes = a.rest_shapes()?;
                if shapes.is_empty() {
                    return Err(value_error(a.span, "`union` of no shapes", "empty", "give at least one shape"));
                }
                shape(if shapes.len() == 1 { (*shapes[0]).clone() } else { Shape::Union(shapes) })
            },
        ),
        variadic(
            "intersection",
            "The intersection (maximum) of shapes (a bound).",
            req("shapes", SHAPE, "shapes or lists of shapes"),
            SHAPE,
            |a| {
                let shapes = a.rest_shapes()?;
                if shapes.is_empty() {
                    return Err(value_error(a.span, "`intersection` of no shapes", "empty", "give at least one shape"));
                }
                shape(Shape::Intersection(shapes))
            },
        ),
        func(
            "subtraction",
            "`a` with `b` cut away: `max(a, -b)` (a bound).",
            vec![req("a", SHAPE, "the shape to cut"), req("b", SHAPE, "the shape removed")],
            SHAPE,
            |a| shape(Shape::Subtraction(a.shape("a")?, a.shape("b")?)),
        ),
        smooth("smooth_union", "Union blended over radius `k` (polynomial smooth minimum; a bound).", |a| {
            shape(Shape::SmoothUnion(a.shape("a")?, a.shape("b")?, a.positive("k")?))
        }),
        smooth("smooth_intersection", "Intersection blended over radius `k` (a bound).", |a| {
            shape(Shape::SmoothIntersection(a.shape("a")?, a.shape("b")?, a.positive("k")?))
        }),
        smooth("smooth_subtraction", "`a` minus `b`, blended over radius `k` (a bound).", |a| {
            shape(Shape::SmoothSubtraction(a.shape("a")?, a.shape("b")?, a.positive("k")?))
        }),
        // ---- transforms
        func(
            "translate",
            "Moves a shape by `by`.",
            vec![req("shape", SHAPE, "the shape"), req("by", Type::Vec3, "offset")],
            SHAPE,
            |a| shape(Shape::Translate(a.shape("shape")?, a.vec3("by")?)),
        ),
        func(
            "rotate",
            "Rotates a shape by `angle` (radians; write `30deg` for degrees) around `axis` through the origin.",
            vec![
                req("shape", SHAPE, "the shape"),
                req("angle", Type::Number, "angle in radians"),
                opt("axis", Type::Vec3, "[0, 0, 1]", "rotation axis (nonzero)"),
            ],
            SHAPE,
            |a| {
                let q = DQuat::from_axis_angle(a.direction("axis")?, a.number("angle")?);
                shape(Shape::Rotate(a.shape("shape")?, q))
            },
        ),
        func(
            "scale",
            "Scales a shape uniformly about the origin (keeps exactness).",
            vec![req("shape", SHAPE, "the shape"), req("factor", Type::Number, "scale factor (> 0)")],
            SHAPE,
            |a| shape(Shape::Scale(a.shape("shape")?, a.positive("factor")?)),
        ),
        func(
            "displace",
            "Adds `amplitude·sin(f·x)·sin(f·y)·sin(f·z)`: a bound with Lipschitz constant `1 + √3·amplitude·frequency`, traced with proportionally shorter steps.",
            vec![
                req("shape", SHAPE, "the shape"),
                opt("amplitude", Type::Number, "0.05", "displacement amplitude (> 0)"),
                opt("frequency", Type::Number, "10", "spatial frequency (> 0)"),
            ],
            SHAPE,
            |a| {
                shape(Shape::Displace {
                    shape: a.shape("shape")?,
                    amplitude: a.positive("amplitude")?,
                    frequency: a.positive("frequency")?,
                })
            },
        ),
        func(
            "paint",
            "Gives a shape's primitives a material (overriding the render's).",
            vec![req("shape", SHAPE, "the shape"), req("material", Type::OneOf(vec![MATERIAL, Type::Vec3]), "a material or a colour [r, g, b]")],
            SHAPE,
            |a| shape(Shape::Paint(a.shape("shape")?, a.material("material")?)),
        ),
        // ---- materials
        func("rainbow", "Colour `clamp(|p - c|, 0.02, 0.98)`, `c` the primitive's centre.", vec![], MATERIAL, |_| {
            Ok(Value::Material(Arc::new(Material::Rainbow)))
        }),
        func(
            "constant",
            "One colour everywhere.",
            vec![req("color", Type::Vec3, "linear RGB in 0..1")],
            MATERIAL,
            |a| Ok(Value::Material(Arc::new(Material::Constant(colour(a.vec3("color")?, a.get("color").1)?)))),
        ),
        func(
            "lambert",
            "Diffuse shading under a directional light: `albedo·(ambient + (1 - ambient)·max(0, n·light))`.",
            vec![
                opt("albedo", Type::OneOf(vec![MATERIAL, Type::Vec3]), "rainbow()", "base colour or material"),
                opt("light", Type::Vec3, "[1, 1, 1]", "direction towards the light"),
                opt("ambient", Type::Number, "0.2", "light reaching surfaces facing away (0..1)"),
            ],
            MATERIAL,
            |a| {
                let ambient = a.number("ambient")?;
                if !(0.0..=1.0).contains(&ambient) {
                    return Err(value_error(a.get("ambient").1, format!("`ambient` must be in 0..1, got {ambient}"), "out of 0..1", "use a fraction such as 0.2"));
                }
                Ok(Value::Material(Arc::new(Material::Lambert {
                    albedo: Box::new((*a.material("albedo")?).clone()),
                    light: a.direction("light")?,
                    ambient,
                })))
            },
        ),
        func("normals", "The surface normal as a colour, `(n + 1)/2`.", vec![], MATERIAL, |_| {
            Ok(Value::Material(Arc::new(Material::Normals)))
        }),
        // ---- cameras
        func(
            "look_at",
            "A camera at `eye` looking at `at` (PyTorch3D conventions, see CONVENTIONS.md).",
            vec![
                req("eye", Type::Vec3, "camera position"),
                opt("at", Type::Vec3, "[0, 0, 0]", "point looked at"),
                opt("up", Type::Vec3, "[0, 1, 0]", "up direction"),
                opt("focal", Type::Number, "1", "focal length in NDC units (> 0)"),
            ],
            CAMERA,
            |a| {
                let cam = Camera::look_at(a.vec3("eye")?, a.vec3("at")?, a.vec3("up")?, a.positive("focal")?);
                if !cam.is_valid() {
                    return Err(value_error(a.span, "camera has no well-defined orientation", "eye equals `at`, or `up` is parallel to the view", "move `eye` away from `at` and pick an `up` not along the view direction"));
                }
                Ok(Value::Camera(cam))
            },
        ),
        func(
            "orbit",
            "`views` cameras around the origin for a spiral GIF: θ = 2πk/views; up [0,1,0]: eye (r·cos(θ+π/2), 0, -r·sin(θ+π/2)); up [0,0,1]: eye (r·cos(θ+π/2), r·sin(θ+π/2), 2).",
            vec![
                opt("radius", Type::Number, "3", "distance from the axis (> 0)"),
                opt("up", Type::Vec3, "[0, 1, 0]", "[0, 1, 0] or [0, 0, 1]"),
                opt("focal", Type::Number, "1", "focal length in NDC units (> 0)"),
                opt("views", Type::Number, "20", "number of cameras"),
            ],
            Type::list(CAMERA),
            |a| {
                let up = match a.vec3("up")? {
                    v if v == DVec3::Y => OrbitUp::Y,
                    v if v == DVec3::Z => OrbitUp::Z,
                    v => {
                        return Err(value_error(
                            a.get("up").1,
                            format!("orbits go around [0, 1, 0] or [0, 0, 1], not [{}, {}, {}]", v.x, v.y, v.z),
                            "unsupported axis",
                            "use `up: [0, 1, 0]` or `up: [0, 0, 1]`, or build cameras with `look_at` in a `for`",
                        ))
                    }
                };
                let views = a.count("views", 1, MAX_VIEWS as u64)? as usize;
                let cams = Camera::orbit(a.positive("radius")?, up, a.positive("focal")?, views);
                Ok(Value::List(Arc::new(cams.into_iter().map(Value::Camera).collect())))
            },
        ),
        // ---- outputs
        output("image", "Shaded colour as PNG; one file per view (`{view}` in the name, or `_NN` added).", |a| {
            out(a, OutputKind::Image, "png")
        }),
        func(
            "gif",
            "All views as an animated GIF.",
            vec![
                req("path", Type::Str, "file name inside the output directory"),
                opt("fps", Type::Number, "10", "frames per second (> 0)"),
            ],
            OUTPUT,
            |a| {
                let fps = a.positive("fps")?;
                out(a, OutputKind::Gif { fps }, "gif")
            },
        ),
        output("depth", "Hit depth normalised by its maximum, colour-mapped, as PNG per view; misses black.", |a| {
            out(a, OutputKind::Depth, "png")
        }),
        output("normal_map", "Surface normals `(n + 1)/2` as PNG per view; misses black.", |a| {
            out(a, OutputKind::Normals, "png")
        }),
        output("mask", "Hit mask as PNG per view: white hit, black miss.", |a| out(a, OutputKind::Mask, "png")),
        // ---- math
        math1("sin", "Sine (radians).", |a| finite(a.number("x")?.sin(), a, "sin")),
        math1("cos", "Cosine (radians).", |a| finite(a.number("x")?.cos(), a, "cos")),
        math1("tan", "Tangent (radians).", |a| finite(a.number("x")?.tan(), a, "tan")),
        math1("sqrt", "Square root (of a number ≥ 0).", |a| finite(a.number("x")?.sqrt(), a, "sqrt")),
        math1("abs", "Absolute value.", |a| finite(a.number("x")?.abs(), a, "abs")),
        math1("floor", "Largest whole number ≤ x.", |a| finite(a.number("x")?.floor(), a, "floor")),
        math1("radians", "Degrees to radians.", |a| finite(a.number("x")?.to_radians(), a, "radians")),
        func(
            "atan2",
            "Angle of the point (x, y) in radians.",
            vec![req("y", Type::Number, "y"), req("x", Type::Number, "x")],
            Type::Number,
            |a| finite(a.number("y")?.atan2(a.number("x")?), a, "atan2"),
        ),
        func("min", "The smaller of two numbers.", vec![req("a", Type::Number, "a"), req("b", Type::Number, "b")], Type::Number, |a| {
            Ok(Value::Number(a.number("a")?.min(a.number("b")?)))
        }),
        func("max", "The larger of two numbers.", vec![req("a", Type::Number, "a"), req("b", Type::Number, "b")], Type::Number, |a| {
            Ok(Value::Number(a.number("a")?.max(a.number("b")?)))
        }),
    ]
}

fn out(a: &Args, kind: OutputKind, ext: &str) -> Result<Value, Diag> {
    let (path, span) = a.string("path")?;
    let path = safe_output_path(&path, span)?;
    if path.extension().and_then(|e| e.to_str()) != Some(ext) {
        return Err(value_error(
            span,
            format!("this output is written as .{ext}"),
            format!("not a .{ext} name"),
            format!("name the file `something.{ext}`"),
        ));
    }
    Ok(Value::Output(Arc::new(Output { kind, path })))
}

/// Output names must stay inside the output directory: relative, no `..`.
pub fn safe_output_path(p: &str, span: Span) -> Result<PathBuf, Diag> {
    let path = Path::new(p);
    let ok = !p.is_empty()
        && path.components().all(|c| matches!(c, Component::Normal(_)))
        && !p.contains('\0');
    if ok {
        Ok(path.to_path_buf())
    } else {
        Err(Diag::new(codes::PATH, span, format!("output path `{p}` leaves the output directory"))
            .label("not a plain relative path")
            .help("name files relative to the output directory, without `..` or a leading `/`; choose the directory with `--out`"))
    }
}

// ------------------------------------------------------------ render block

fn render_sig() -> BlockSig {
    BlockSig {
        kind: "render",
        doc: "Sphere-traces `scene` from each camera and writes the requested outputs.",
        fields: vec![
            req("scene", SHAPE, "the shape to render"),
            req(
                "camera",
                Type::OneOf(vec![CAMERA, Type::list(CAMERA)]),
                "a camera or a list of cameras (views)",
            ),
            req(
                "outputs",
                Type::list(OUTPUT),
                "what to write: image, gif, depth, normal_map, mask",
            ),
            opt(
                "material",
                Type::OneOf(vec![MATERIAL, Type::Vec3]),
                "rainbow()",
                "how hit points are coloured",
            ),
            opt(
                "size",
                Type::list(Type::Number),
                "[256, 256]",
                "image width and height in pixels",
            ),
            opt("near", Type::Number, "0", "where rays start (≥ 0)"),
            opt("far", Type::Number, "5", "where rays give up (> near)"),
            opt(
                "iterations",
                Type::Number,
                "64",
                "most sphere-tracing steps per ray",
            ),
            opt(
                "epsilon",
                Type::Number,
                "1e-5",
                "a ray hits when the distance falls below this",
            ),
            opt(
                "background",
                Type::Vec3,
                "[0, 0, 0]",
                "colour of rays that miss",
            ),
        ],
    }
}

pub(crate) fn render_block(name: &str, a: &Args) -> Result<RenderJob, Diag> {
    let cameras = match a.get("camera") {
        (Value::Camera(c), _) => vec![*c],
        (Value::List(items), s) => {
            let cams: Option<Vec<Camera>> = items
                .iter()
                .map(|i| {
                    if let Value::Camera(c) = i {
                        Some(*c)
                    } else {
                        None
                    }
                })
                .collect();
            match cams {
                Some(c) if !c.is_empty() && c.len() <= MAX_VIEWS => c,
                Some(c) if c.is_empty() => {
                    return Err(value_error(
                        s,
                        "no camera views",
                        "empty list",
                        "give at least one camera",
                    ))
                }
                Some(c) => {
                    return Err(value_error(
                        s,
                        format!("{} views (at most {MAX_VIEWS})", c.len()),
                        "too many views",
                        "render fewer views",
                    ))
                }
                None => {
                    return Err(type_error(
                        s,
                        "camera or list of cameras",
                        a.get("camera").0,
                    ))
                }
            }
        }
        (v, s) => return Err(type_error(s, "camera or list of cameras", v)),
    };
    let (size, size_span) = a.get("size");
    let dims: Option<Vec<f64>> = match size {
        Value::List(items) => items
            .iter()
            .map(|i| {
                if let Value::Number(x) = i {
                    Some(*x)
                } else {
                    None
                }
            })
            .collect(),
        _ => None,
    };
    let (width, height) = match dims.as_deref() {
        Some([w, h])
            if w.fract() == 0.0
                && h.fract() == 0.0
                && (1.0..=MAX_IMAGE_SIDE as f64).contains(w)
                && (1.0..=MAX_IMAGE_SIDE as f64).contains(h) =>
        {
            (*w as u32, *h as u32)
        }
        _ => {
            return Err(value_error(
                size_span,
                format!(
                    "`size` must be [width, height] in whole pixels from 1 to {MAX_IMAGE_SIDE}"
                ),
                "invalid image size",
                "for example `size: [256, 256]`",
            ))
        }
    };
    let near = a.number("near")?;
    let far = a.number("far")?;
    if near < 0.0 {
        return Err(value_error(
            a.get("near").1,
            format!("`near` must be ≥ 0, got {near}"),
            "negative",
            "rays start at the camera or in front of it",
        ));
    }
    if far <= near {
        return Err(value_error(
            a.get("far").1,
            format!("`far` ({far}) must be greater than `near` ({near})"),
            "not beyond near",
            "rays march from near to far: make far larger",
        ));
    }
    let outputs = match a.get("outputs") {
        (Value::List(items), s) => {
            let outs: Option<Vec<Output>> = items
                .iter()
                .map(|i| {
                    if let Value::Output(o) = i {
                        Some((**o).clone())
                    } else {
                        None
                    }
                })
                .collect();
            match outs {
                Some(o) if !o.is_empty() => o,
                Some(_) => {
                    return Err(value_error(
                        s,
                        "no outputs requested",
                        "empty",
                        "ask for e.g. `outputs: [image(\"out.png\")]`",
                    ))
                }
                None => return Err(type_error(s, "list of outputs", a.get("outputs").0)),
            }
        }
        (v, s) => return Err(type_error(s, "list of outputs", v)),
    };
    let (bg, bg_span) = (a.vec3("background")?, a.get("background").1);
    Ok(RenderJob {
        name: name.to_string(),
        scene: a.shape("scene")?,
        material: a.material("material")?,
        cameras,
        width,
        height,
        near,
        far,
        iterations: a.count("iterations", 1, MAX_ITERATIONS as u64)? as u32,
        epsilon: a.positive("epsilon")?,
        background: colour(bg, bg_span)?,
        outputs,
    })
}
