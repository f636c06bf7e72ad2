//! Shapes, combinators and transforms: the primitives' and operators'
//! signatures, docs and evaluation.

use super::*;

/// The shape built-ins, in the order `sdfl docs` lists them.
pub(super) fn builtins() -> Vec<Builtin> {
    let center = || opt("center", Type::Vec3, "[0, 0, 0]", "centre of the shape");
    // Any number of shapes (lists flattened), blended pairwise in order;
    // `k` is named.
    let smooth = |name: &'static str, doc: &'static str, eval: EvalFn| Builtin {
        sig: Signature {
            name,
            params: vec![opt("k", Type::Number, "0.25", "blend radius (> 0)")],
            rest: Some(req(
                "shapes",
                SHAPE,
                "two or more shapes, or lists of shapes (the blend radius is named: `k: 0.2`)",
            )),
            named_rest: None,
            returns: SHAPE,
            doc,
        },
        eval,
    };
    let mut rows = Vec::new();
    Primitive::for_each_kind(&mut Rows(&mut rows));
    // `cone` also takes its base's `radius` (a `capped_cone` with `top: 0`),
    // first, so `cone(0.5, 1)` keeps its meaning.
    let cone = rows
        .iter_mut()
        .find(|r| r.sig.name == "cone")
        .expect("a declared cone");
    cone.sig.params.insert(
        0,
        opt("radius", Type::Number, "0.5", "radius of the base (> 0): a `capped_cone` with `top: 0`, unless `angle` is given instead"),
    );
    cone.eval = cone_by_radius_or_angle;
    rows.extend(vec![
        // ---- shapes written by the user
        Builtin {
            sig: Signature {
                name: crate::shape::user::BUILTIN,
                params: vec![
                    req("f", sdfl_lang::check::FUNCTION, "a `fn` of the point giving its signed distance, GLSL-style: `fn torus_d(p, major: 1, minor: 0.25) { length([length(p.xz) - major, p.y]) - minor }`"),
                    req("bound", num_or_vec(), "the box the shape lies in, from -bound to +bound (a number: a cube); the function is evaluated only inside it and bounded by interval arithmetic over it"),
                    opt("lipschitz", Type::Number, "0", "a bound on the function's gradient norm (its value is divided by it); 0: derived by interval arithmetic over the box, or 1 where none is derived"),
                ],
                rest: None,
                named_rest: Some(req("argument", Type::Any, "the `fn`'s other arguments, by name (`major: param(0.8)` trains)")),
                returns: SHAPE,
                doc: "A shape written as a `fn` of the point: compiled once into a flat list of operations (vectors as numbers), run by every evaluator (f64, f32 lanes, training). Its value is `max(f(clamp(p, box)) / L, box(p))`: exact inside the box where `f` is, a bound beyond it.",
            },
            // Evaluated by the evaluator (it compiles the `fn`'s body).
            eval: |a| Err(value_error(a.span, "`sdf` outside the evaluator", "not compiled", "evaluate the file with `stdlib::load`")),
        },
        // ---- shapes that are sugar over primitives
        func(
            "rounded_box",
            "A box of full side lengths `size` with edges rounded by `radius`: sugar for `round(box(size - 2·radius), radius)`, so it spans exactly `size` (exact outside, a bound inside). Not trainable: write `round(box(size: param(..)), param(..))` to fit one.",
            vec![
                opt("size", num_or_vec(), "[1, 1, 1]", "side lengths (> 0); a number for a cube"),
                opt("radius", Type::Number, "0.1", "edge radius (> 0, below half the smallest side)"),
                center(),
            ],
            SHAPE,
            |a| {
                let size = a.vec3_arg("size", Bound::AtLeast(MIN_LENGTH))?;
                let radius = a.length_arg("radius")?;
                if size.param.is_some() || radius.param.is_some() {
                    return Err(value_error(a.span, "`rounded_box` with trainable arguments", "param", "write `round(box(size: param(..)), param(..))` to train them"));
                }
                if radius.value * 2.0 >= size.value.min_element() {
                    return Err(value_error(
                        a.get("radius").1,
                        format!("`radius` {} is not below half the smallest side {}", sdfl_lang::fmt_num(radius.value), sdfl_lang::fmt_num(size.value.min_element())),
                        "too round",
                        "use a smaller radius, or `sphere`/`capsule`",
                    ));
                }
                let inner: Shape = Cuboid { center: a.vec3_arg("center", Bound::Free)?, size: (size.value - DVec3::splat(2.0 * radius.value)).into() }.into();
                shape(Shape::Round(Arc::new(inner), radius))
            },
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
        smooth("smooth_union", "Union of any number of shapes or lists, blended over radius `k` (polynomial smooth minimum, folded left: `smooth_union(a, b, c)` is `smooth_union(smooth_union(a, b), c)`; a bound).", |a| {
            blend(a, Shape::SmoothUnion)
        }),
        smooth("smooth_intersection", "Intersection of any number of shapes or lists, blended over radius `k`, folded left like `smooth_union` (a bound).", |a| {
            blend(a, Shape::SmoothIntersection)
        }),
        smooth("smooth_subtraction", "The first shape minus each of the others, blended over radius `k` (a bound).", |a| {
            blend(a, Shape::SmoothSubtraction)
        }),
        // ---- transforms
        func(
            "translate",
            "Moves a shape by `by`.",
            vec![req("shape", SHAPE, "the shape"), req("by", Type::Vec3, "offset")],
            SHAPE,
            |a| shape(Shape::Translate(a.shape("shape")?, a.vec3_arg("by", Bound::Free)?)),
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
                shape(Shape::Rotate {
                    shape: a.shape("shape")?,
                    axis: a.direction("axis")?,
                    angle: a.scalar_arg("angle", Bound::Free)?,
                })
            },
        ),
        func(
            "scale",
            "Scales a shape about the origin: by a number, uniformly (keeps exactness); by `[sx, sy, sz]`, per axis: `max(min(s)·d(p/s), distance to the scaled bounding box)`, a bound with Lipschitz constant that of the shape (at least 1).",
            vec![req("shape", SHAPE, "the shape"), req("factor", num_or_vec(), "scale factor (> 0), or one per axis")],
            SHAPE,
            |a| {
                let s = a.shape("shape")?;
                match a.get("factor").0 {
                    Value::Number(_) => shape(Shape::Scale(s, a.length_arg("factor")?)),
                    Value::Param(d) if matches!(d.init, ParamInit::Scalar(_)) => shape(Shape::Scale(s, a.length_arg("factor")?)),
                    _ => {
                        let f = a.vec3_arg("factor", Bound::AtLeast(MIN_LENGTH))?;
                        let v = f.value;
                        if f.param.is_none() && v.x == v.y && v.y == v.z {
                            return shape(Shape::Scale(s, v.x.into()));
                        }
                        shape(Shape::ScaleXyz(s, f))
                    }
                }
            },
        ),
        func(
            "elongate",
            "Cuts a shape at the planes through the origin and pulls the halves `by` apart on each side (`d(p - clamp(p, -by, by))`), filling the gap with the section there: a sphere at the origin becomes a capsule, a torus a link (build the shape around the origin, then `translate`). Exact outside an exact shape, a bound inside.",
            vec![req("shape", SHAPE, "the shape"), req("by", num_or_vec(), "half the added length on each axis (≥ 0)")],
            SHAPE,
            |a| shape(Shape::Elongate(a.shape("shape")?, a.vec3_arg("by", Bound::Within(0.0, f64::MAX))?)),
        ),
        func(
            "repeat",
            "Copies of a shape `spacing` apart on each axis (0: not repeated on that axis), `count` of them per axis centred on the origin, or infinitely many where `count` is 0 (unbounded: never culled). Each point looks at every copy that can be nearest (those whose centre is within ½ + extent/spacing cells, `extent` how far the shape reaches from the origin), so the result is the union of all copies: exact for an exact shape whose copies do not overlap (extent ≤ spacing/2), a bound otherwise.",
            vec![
                req("shape", SHAPE, "the shape, around the origin"),
                req("spacing", num_or_vec(), "distance between copies per axis (≥ 0; 0: not repeated)"),
                opt("count", num_or_vec(), "0", "copies per axis (whole numbers; 0: infinitely many)"),
            ],
            SHAPE,
            |a| {
                let s = a.shape("shape")?;
                let mut spacing = a.vec3_arg("spacing", Bound::Within(0.0, f64::MAX))?;
                // Training may not pack the copies much closer than they
                // start (each point would evaluate ever more of them).
                if let Some(u) = &mut spacing.param {
                    let least = spacing.value.min_element();
                    if least <= 0.0 {
                        return Err(value_error(a.get("spacing").1, "a trainable `spacing` is 0 on some axis", "not repeated there", "give every axis a spacing and `count: 1` where it is not repeated"));
                    }
                    u.bound = Bound::AtLeast(least * 0.5);
                }
                let (cv, cspan) = (a.vec3("count")?, a.get("count").1);
                if cv.to_array().iter().any(|c| c.fract() != 0.0 || *c < 0.0 || *c > 1e6) {
                    return Err(value_error(cspan, "`count` must be whole numbers from 0 to 1000000", "not a count", "write e.g. `count: [5, 1, 5]` (0: infinitely many)"));
                }
                let count = cv.to_array().map(|c| c as u32);
                if spacing.value.max_element() <= 0.0 {
                    return Err(value_error(a.get("spacing").1, "`spacing` is 0 on every axis", "nothing repeated", "give the distance between copies on at least one axis"));
                }
                if s.bounds().is_none() {
                    return Err(value_error(a.get("shape").1, "`repeat` of an unbounded shape (a plane)", "unbounded", "repeat bounded shapes; a repeated plane is the plane"));
                }
                let r = Shape::Repeat { shape: s, spacing, count };
                if r.copies_per_point() > MAX_COPIES_PER_POINT {
                    return Err(value_error(
                        a.get("spacing").1,
                        format!("copies overlap so much that each point would evaluate {} of them (at most {MAX_COPIES_PER_POINT})", r.copies_per_point()),
                        "spacing too small for the shape",
                        "space the copies further apart or make the shape smaller",
                    ));
                }
                shape(r)
            },
        ),
        func(
            "mirror",
            "Keeps the shape's half on the positive side of `axis` and reflects it onto the other (`d(|x|, y, z)` for \"x\"). Exact for an exact shape lying on the positive side, a bound otherwise.",
            vec![req("shape", SHAPE, "the shape"), opt("axis", Type::Str, "\"x\"", "the axis flipped: \"x\", \"y\" or \"z\"")],
            SHAPE,
            |a| shape(Shape::Mirror(a.shape("shape")?, axis_arg(a)?)),
        ),
        func(
            "twist",
            "Turns each slice of a shape across Z by `rate·z` radians about the Z axis. A bound with Lipschitz constant `L·(1 + |rate|·R)` (`L` the shape's, `R` the radius of the cylinder about Z holding its bounds), traced with proportionally shorter steps; outside that cylinder it is at least the distance to it.",
            vec![req("shape", SHAPE, "the shape"), req("rate", Type::Number, "radians per unit of z")],
            SHAPE,
            |a| {
                let s = a.shape("shape")?;
                unbounded_warp(a, &s, "twist")?;
                shape(Shape::Twist(s, a.scalar_arg("rate", Bound::Free)?))
            },
        ),
        func(
            "bend",
            "Bends a shape in the XY plane: each slice across X turned by `rate·x` radians about the Z axis. A bound with Lipschitz constant `L·(1 + |rate|·R)` like `twist`.",
            vec![req("shape", SHAPE, "the shape"), req("rate", Type::Number, "radians per unit of x")],
            SHAPE,
            |a| {
                let s = a.shape("shape")?;
                unbounded_warp(a, &s, "bend")?;
                shape(Shape::Bend(s, a.scalar_arg("rate", Bound::Free)?))
            },
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
                    amplitude: a.length_arg("amplitude")?,
                    frequency: a.length_arg("frequency")?,
                })
            },
        ),
        func(
            "round",
            "The shape grown by `radius`, `d - radius`: rounds its edges (a box of side s rounded by r spans s + 2r). Exact outside an exact convex shape, a bound elsewhere.",
            vec![req("shape", SHAPE, "the shape"), opt("radius", Type::Number, "0.1", "how far to grow (> 0)")],
            SHAPE,
            |a| shape(Shape::Round(a.shape("shape")?, a.length_arg("radius")?)),
        ),
        func(
            "onion",
            "A shell of `thickness` around the shape's surface, `|d| - thickness` (a bound).",
            vec![req("shape", SHAPE, "the shape"), opt("thickness", Type::Number, "0.05", "half the shell's width (> 0)")],
            SHAPE,
            |a| shape(Shape::Onion(a.shape("shape")?, a.length_arg("thickness")?)),
        ),
        func(
            "xor",
            "Inside exactly one of `a` and `b`: `max(min(a, b), -max(a, b))` (a bound).",
            vec![req("a", SHAPE, "first shape"), req("b", SHAPE, "second shape")],
            SHAPE,
            |a| shape(Shape::Xor(a.shape("a")?, a.shape("b")?)),
        ),
        func(
            "paint",
            "Gives a shape's primitives a material (overriding the render's).",
            vec![req("shape", SHAPE, "the shape"), req("material", Type::OneOf(vec![MATERIAL, Type::Vec3]), "a material or a colour [r, g, b]")],
            SHAPE,
            |a| shape(Shape::Paint(a.shape("shape")?, a.material("material")?)),
        ),
    ]);
    rows
}

/// `cone(angle:, ...)`: the declared cone; otherwise by its base's `radius`.
fn cone_by_radius_or_angle(a: &Args) -> Result<Value, Diag> {
    if a.given("angle") {
        if a.given("radius") {
            return Err(value_error(
                a.get("radius").1,
                "`cone` with both `radius` and `angle`",
                "both given",
                "give the base's `radius` or the side's `angle`, not both",
            ));
        }
        return build_primitive::<crate::shape::Cone>(a);
    }
    let top = Arg {
        value: 0.0,
        param: None,
    };
    let bottom = a.length_arg("radius")?;
    let cone = CappedCone {
        center: a.vec3_arg("center", Bound::Free)?,
        height: a.length_arg("height")?,
        bottom,
        top,
        axis: axis_arg(a)?,
    };
    shape(cone.into())
}

/// Collects every primitive's built-in row ([`primitive_row`]).
struct Rows<'a>(&'a mut Vec<Builtin>);

impl KindVisitor for Rows<'_> {
    fn visit<K: Declared>(&mut self) {
        self.0.push(primitive_row::<K>());
    }
}

/// The built-in of primitive `K`, from its declaration: the signature
/// (types from the arguments' kinds and checks, defaults, docs) and the
/// evaluation (each argument read and checked as declared, then the
/// checks between arguments).
fn primitive_row<K: Declared>() -> Builtin {
    let spec = K::SPEC;
    let params = spec
        .args
        .iter()
        .map(|a| {
            let ty = match (a.kind, a.check) {
                (ArgKind::Scalar, _) => Type::Number,
                (ArgKind::Axis, _) => Type::Str,
                (_, Check::Size) => num_or_vec(),
                (ArgKind::Point | ArgKind::Vector, _) => Type::Vec3,
            };
            match a.default {
                Some(d) => opt(a.name, ty, d, a.doc),
                None => req(a.name, ty, a.doc),
            }
        })
        .collect();
    func(spec.name, spec.doc, params, SHAPE, build_primitive::<K>)
}

fn build_primitive<K: Declared>(a: &Args) -> Result<Value, Diag> {
    let x = K::read(&mut Reader(a))?;
    if let Err(e) = K::check(&crate::shape::declare::values(&x)) {
        let span = e.arg.map_or(a.span, |n| a.get(n).1);
        return Err(value_error(span, e.message, e.label, e.help));
    }
    shape(x.into().into())
}

/// A call's arguments read as a primitive declares them.
struct Reader<'a>(&'a Args);

/// The range a trained value is kept in.
fn bound_of(check: Check) -> Bound {
    match check {
        Check::Length | Check::Size => Bound::AtLeast(MIN_LENGTH),
        Check::NonNegative => Bound::Within(0.0, f64::MAX),
        Check::Within(lo, hi) => Bound::Within(lo, hi),
        Check::Free | Check::Direction | Check::Axis => Bound::Free,
    }
}

impl ArgReader for Reader<'_> {
    fn scalar(&mut self, name: &'static str, check: Check) -> Result<Arg<f64>, Diag> {
        self.0.scalar_arg(name, bound_of(check))
    }
    fn vector(&mut self, name: &'static str, check: Check) -> Result<Arg<DVec3>, Diag> {
        match check {
            Check::Direction => Ok(self.0.direction(name)?.into()),
            _ => self.0.vec3_arg(name, bound_of(check)),
        }
    }
    fn axis(&mut self, _name: &'static str) -> Result<Axis, Diag> {
        axis_arg(self.0)
    }
}
