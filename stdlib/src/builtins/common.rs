//! Helpers the built-ins share: reading cameras, image sizes and outputs,
//! confining output paths, blends, axes, ranges and `random`.

use super::*;

/// `min`/`max` of the rest arguments, lists flattened.
pub(super) fn extreme(a: &Args, name: &str, pick: fn(f64, f64) -> f64) -> Result<Value, Diag> {
    let xs = a.rest_numbers()?;
    match xs.into_iter().reduce(pick) {
        Some(x) => Ok(Value::Number(x)),
        None => Err(value_error(
            a.span,
            format!("`{name}` of no numbers"),
            "empty",
            "give at least one number",
        )),
    }
}

/// SplitMix64's output function (Steele, Lea and Flood, 2014).
pub(super) fn splitmix64(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9e37_79b9_7f4a_7c15);
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

/// `random(seed, i)`: the hash of both numbers' bits, its top 53 bits as
/// a fraction in [0, 1). (`+ 0.0` makes -0 and 0 the same seed.)
pub fn random(seed: f64, i: f64) -> f64 {
    let h = splitmix64(splitmix64((seed + 0.0).to_bits()) ^ (i + 0.0).to_bits());
    (h >> 11) as f64 / (1u64 << 53) as f64
}

/// Most copies a repetition may evaluate at one point.
pub(super) const MAX_COPIES_PER_POINT: u64 = 64;

/// The `axis` argument: `"x"`, `"y"` or `"z"`.
pub(super) fn axis_arg(a: &Args) -> Result<Axis, Diag> {
    let (name, span) = a.string("axis")?;
    match &*name {
        "x" => Ok(Axis::X),
        "y" => Ok(Axis::Y),
        "z" => Ok(Axis::Z),
        other => Err(value_error(
            span,
            format!("unknown axis `{other}`"),
            "not an axis",
            "use \"x\", \"y\" or \"z\"",
        )),
    }
}

/// Twists and bends need a bounded shape: their Lipschitz constant grows
/// with its radius.
pub(super) fn unbounded_warp(a: &Args, s: &Shape, name: &str) -> Result<(), Diag> {
    if s.bounds().is_none() {
        return Err(value_error(
            a.get("shape").1,
            format!("`{name}` of an unbounded shape (a plane)"),
            "unbounded",
            format!("{name} bounded shapes (intersect a plane with a box first)"),
        ));
    }
    Ok(())
}

pub(super) fn blend(
    a: &Args,
    op: fn(Arc<Shape>, Arc<Shape>, Arg<f64>) -> Shape,
) -> Result<Value, Diag> {
    let shapes = a.rest_shapes()?;
    let k = a.length_arg("k")?;
    let mut it = shapes.into_iter();
    let Some(first) = it.next() else {
        return Err(value_error(
            a.span,
            "a blend of no shapes",
            "empty",
            "give at least two shapes",
        ));
    };
    let mut acc = first;
    for s in it {
        acc = Arc::new(op(acc, s, k.clone()));
    }
    Ok(Value::Shape(acc))
}

pub(super) fn check_range(a: &Args, near: f64, far: f64) -> Result<(), Diag> {
    if near < 0.0 {
        return Err(value_error(
            a.get("near").1,
            format!("`near` must be ≥ 0, got {}", sdfl_lang::fmt_num(near)),
            "negative",
            "rays start at the camera or in front of it",
        ));
    }
    if far <= near {
        return Err(value_error(
            a.get("far").1,
            format!(
                "`far` ({}) must be greater than `near` ({})",
                sdfl_lang::fmt_num(far),
                sdfl_lang::fmt_num(near)
            ),
            "not beyond near",
            "rays march from near to far: make far larger",
        ));
    }
    Ok(())
}

/// A value that is one `T` or a list of them (as `pick` reads each), or
/// `None` if any item is something else.
pub(crate) fn one_or_list<T>(v: &Value, pick: impl Fn(&Value) -> Option<T>) -> Option<Vec<T>> {
    match v {
        Value::List(items) => items.iter().map(&pick).collect(),
        one => pick(one).map(|t| vec![t]),
    }
}

pub(super) fn camera_list(a: &Args, name: &str) -> Result<Vec<Camera>, Diag> {
    let (v, s) = a.get(name);
    let cams = one_or_list(v, |v| match v {
        Value::Camera(c) => Some(*c),
        _ => None,
    });
    match cams {
        Some(c) if c.is_empty() => Err(value_error(
            s,
            "no camera views",
            "empty list",
            "give at least one camera",
        )),
        Some(c) if c.len() > MAX_VIEWS => Err(value_error(
            s,
            format!("{} views (at most {MAX_VIEWS})", c.len()),
            "too many views",
            "use fewer views",
        )),
        Some(c) => Ok(c),
        None => Err(type_error(s, "camera or list of cameras", v)),
    }
}

pub(super) fn image_size(a: &Args, name: &str) -> Result<(u32, u32), Diag> {
    let (size, size_span) = a.get(name);
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
    match dims.as_deref() {
        Some([w, h])
            if w.fract() == 0.0
                && h.fract() == 0.0
                && (1.0..=MAX_IMAGE_SIDE as f64).contains(w)
                && (1.0..=MAX_IMAGE_SIDE as f64).contains(h) =>
        {
            Ok((*w as u32, *h as u32))
        }
        _ => Err(value_error(
            size_span,
            format!("`{name}` must be [width, height] in whole pixels from 1 to {MAX_IMAGE_SIDE}"),
            "invalid image size",
            "for example `size: [256, 256]`",
        )),
    }
}

pub(super) fn outputs(a: &Args, name: &str, allow_empty: bool) -> Result<Vec<Output>, Diag> {
    match a.get(name) {
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
                Some(o) if !o.is_empty() || allow_empty => Ok(o),
                Some(_) => Err(value_error(
                    s,
                    "no outputs requested",
                    "empty",
                    "ask for e.g. `outputs: [image(\"out.png\")]`",
                )),
                None => Err(type_error(s, "list of outputs", a.get(name).0)),
            }
        }
        (v, s) => Err(type_error(s, "list of outputs", v)),
    }
}

/// Output names must stay inside the output directory: relative, no `..`.
pub fn safe_output_path(p: &str, span: Span) -> Result<PathBuf, Diag> {
    let path = Path::new(p);
    // A trailing `/` names a directory, which an output cannot be.
    let ok = !p.is_empty()
        && path.components().all(|c| matches!(c, Component::Normal(_)))
        && !p.contains('\0')
        && !p.ends_with('/');
    if ok {
        Ok(path.to_path_buf())
    } else if p.ends_with('/') && !p.starts_with('/') && !p.contains("..") {
        Err(Diag::new(
            codes::PATH,
            span,
            format!("output path `{p}` names a directory"),
        )
        .label("ends with `/`")
        .help("name a file, e.g. `dir/name.png`"))
    } else {
        Err(Diag::new(codes::PATH, span, format!("output path `{p}` leaves the output directory"))
            .label("not a plain relative path")
            .help("name files relative to the output directory, without `..` or a leading `/`; choose the directory with `--out`"))
    }
}

/// A neural SDF is fitted to points; rendering one is not built yet.
pub(crate) fn not_a_volume(span: Span) -> Diag {
    value_error(
        span,
        "a neural SDF is rendered by the `train` statement that fits it",
        "a neural SDF",
        "train it (from points, or from images as `volsdf(neural_sdf(...))`) and ask for `after: [gif(...)]` there",
    )
}

/// A NeRF in NDC (`unbounded: ndc()`) takes its camera from the capture
/// it trains on: rendered outside a `train` it has none.
pub(crate) fn ndc_outside_training(field: &crate::value::Field, span: Span) -> Result<(), Diag> {
    match field {
        crate::value::Field::Nerf(n)
            if matches!(n.unbounded, Some(crate::value::Unbounded::Ndc(_))) =>
        {
            Err(value_error(
                span,
                "a NeRF in NDC (`unbounded: ndc()`) takes its camera from the forward-facing capture it trains on, and is rendered by that `train`",
                "rendered outside a `train`",
                "train it on `capture(..., format: \"llff\")` and ask for its outputs in `after: [...]`, or use `unbounded: contraction()` here",
            ))
        }
        _ => Ok(()),
    }
}

/// Arguments that are angles in radians.
const ANGLES: &[(&str, &str)] = &[
    ("rotate", "angle"),
    ("sin", "x"),
    ("cos", "x"),
    ("tan", "x"),
];
/// Focal lengths in NDC units.
const FOCALS: &[&str] = &["look_at", "orbit", "sphere_views"];
/// A focal length above this is a field of view under 5.7°: far more
/// likely a lens's millimetres than an NDC focal.
const MAX_PLAUSIBLE_FOCAL: f64 = 20.0;

/// Warnings for numbers likely written in the wrong unit: a whole angle of
/// 7 radians or more (more than a turn: degrees meant), a focal length in
/// millimetres. They run as written.
pub(crate) fn unit_warnings(owner: &str, a: &Args) -> Vec<Diag> {
    let number = |name: &str| match a.named.get(name) {
        Some((Value::Number(x), s)) => Some((*x, *s)),
        Some((Value::Param(d), s)) => match d.init {
            ParamInit::Scalar(x) => Some((x, *s)),
            ParamInit::Vec3(_) => None,
        },
        _ => None,
    };
    let mut found = Vec::new();
    for &(_, name) in ANGLES.iter().filter(|(f, _)| *f == owner) {
        if let Some((x, span)) = number(name).filter(|(x, _)| x.fract() == 0.0 && x.abs() >= 7.0) {
            let n = sdfl_lang::fmt_num(x);
            found.push(
                Diag::new(
                    codes::DEGREES,
                    span,
                    format!("`{name}` is {n} radians, {} turns: were degrees meant?", sdfl_lang::fmt_num((x / std::f64::consts::TAU * 100.0).round() / 100.0)),
                )
                .label("radians")
                .help(format!("angles are radians unless marked: write `{n}deg` for degrees, or radians such as `pi / 4`")),
            );
        }
    }
    if FOCALS.contains(&owner) {
        if let Some((f, span)) = number("focal").filter(|(f, _)| *f > MAX_PLAUSIBLE_FOCAL) {
            let fov = 2.0 * (1.0 / f).atan().to_degrees();
            found.push(
                Diag::new(
                    codes::FOCAL,
                    span,
                    format!("`focal` {} is a field of view of {fov:.1}°: was a lens's millimetres meant?", sdfl_lang::fmt_num(f)),
                )
                .label("NDC units")
                .help(format!(
                    "sdfl's focal is in NDC units, where 1 is a 90° field of view (`focal = 1/tan(fov/2)`); a lens of f mm on a 36 mm-wide sensor is f/18: {} mm is `focal: {:.2}`",
                    sdfl_lang::fmt_num(f),
                    f / 18.0
                )),
            );
        }
    }
    found
}
