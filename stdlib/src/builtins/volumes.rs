//! Volumes: an SDF (a shape or a neural SDF) seen through a density
//! model, `sdf_volume`, `volsdf` and `neus`.

use super::*;
use crate::density::{visit_densities, Density, DensityVisitor, NeuralUse, ALPHA_MIN};

/// One built-in per density, from its [`Density`] definition.
pub(super) fn builtins() -> Vec<Builtin> {
    struct Rows(Vec<Builtin>);
    impl DensityVisitor for Rows {
        fn visit<D: Density>(&mut self) {
            self.0.push(volume_fn::<D>());
        }
    }
    let mut rows = Rows(Vec::new());
    visit_densities(&mut rows);
    rows.0
}

fn volume_fn<D: Density>() -> Builtin {
    func(
        D::NAME,
        D::DOC,
        vec![
            req("shape", Type::OneOf(vec![SHAPE, FIELD]), "the signed distance function: a shape, or a `neural_sdf(...)` to train from images"),
            opt("alpha", Type::Number, D::ALPHA_DEFAULT, "density scale (> 0)"),
            opt(
                "beta",
                Type::Number,
                "0.05",
                "sharpness: the Laplace/logistic scale (> 0; smaller is sharper)",
            ),
            opt(
                "color",
                Type::OneOf(vec![MATERIAL, Type::Vec3]),
                "rainbow()",
                "colour of the volume (rainbow or constant); a neural SDF's colour is learnt",
            ),
            opt("view_dependent", Type::Bool, "true", "a neural SDF's colour network sees the view direction"),
            opt("background", Type::Vec3, "[0, 0, 0]", "a neural SDF's volume: colour seen where it is not opaque"),
            opt("beta_end", Type::Number, "0", "a neural SDF's volume: β falls geometrically from `beta` at the first training step to this (> 0, at most `beta`) at the last, sharpening the surface as training goes; 0: β stays `beta` (or is trained, when a `param`)"),
            opt("fine", Type::Number, "0", "a neural SDF's volume: samples per ray added where the surface is, placed by inverse CDF on the weights of a distance-only pass over the stratified samples (0: none)"),
        ],
        FIELD,
        |a| field(a, D::KIND),
    )
}

/// A neural SDF as a volume with a learnt colour.
fn neural_surface(a: &Args, density: DensityKind, sdf: &NeuralSdf) -> Result<Value, Diag> {
    let given = |name: &str| a.get(name).1 != a.span;
    if given("color") {
        return Err(value_error(
            a.get("color").1,
            "a neural SDF's colour is learnt from the images",
            "not used by a neural SDF",
            "leave `color` out",
        ));
    }
    if !density.neural().takes_alpha() && given("alpha") {
        return Err(value_error(
            a.get("alpha").1,
            format!("a neural SDF's {} volume has no `alpha`", density.title()),
            "not used",
            "leave `alpha` out: NeuS's opacity across a surface comes from the SDF and `beta` alone",
        ));
    }
    if matches!(a.get("alpha").0, Value::Param(_)) {
        return Err(value_error(
            a.get("alpha").1,
            "`alpha` of a neural SDF's volume is fixed while its network trains",
            "cannot be a `param` here",
            "give `alpha` a number; `beta` can be a `param`",
        ));
    }
    let alpha = a.positive("alpha")?;
    // A trainable β starts at the param's value.
    let (beta, train_beta) = match a.get("beta").0 {
        Value::Param(_) => (a.scalar_arg("beta", Bound::AtLeast(MIN_BETA))?.value, true),
        _ => (a.positive("beta")?, false),
    };
    crate::precision::beta(beta, a.get("beta").1)?;
    let beta_end = if given("beta_end") {
        let span = a.get("beta_end").1;
        if train_beta {
            return Err(value_error(
                span,
                "a trained `beta` has no schedule",
                "not with `beta: param(...)`",
                "give `beta` a number to anneal it to `beta_end`, or leave `beta_end` out to train β",
            ));
        }
        let end = a.positive("beta_end")?;
        if end > beta {
            return Err(value_error(
                span,
                format!(
                    "`beta_end` ({}) is above `beta` ({}): the schedule sharpens the surface, it does not blur it",
                    sdfl_lang::fmt_num(end),
                    sdfl_lang::fmt_num(beta)
                ),
                "above the starting β",
                "give `beta_end` a value at most `beta`",
            ));
        }
        crate::precision::beta(end, span)?;
        Some(end)
    } else {
        None
    };
    Ok(Value::Field(Arc::new(Field::NeuralSurface(
        NeuralSurface {
            sdf: sdf.clone(),
            density,
            alpha,
            beta,
            train_beta,
            beta_end,
            color_layers: 2,
            color_width: 64,
            color_freqs: 4,
            view_dependent: matches!(a.get("view_dependent").0, Value::Bool(true)),
            background: a.vec3("background")?.to_array(),
            fine: a.count("fine", 0, MAX_SAMPLES)? as usize,
        },
    ))))
}

fn field(a: &Args, density: DensityKind) -> Result<Value, Diag> {
    if let Value::Field(f) = a.get("shape").0 {
        return match &**f {
            Field::NeuralSdf(n) if density.neural() != NeuralUse::Refused => {
                neural_surface(a, density, n)
            }
            _ => Err(value_error(
                a.get("shape").1,
                "this field is not a distance function",
                "not a shape or a `neural_sdf(...)`",
                if density.neural() == NeuralUse::Refused {
                    format!(
                        "the {} form takes shapes; train a neural SDF from images with {}",
                        density.title(),
                        names(|k| k.neural() != NeuralUse::Refused)
                    )
                } else {
                    "give a shape or a `neural_sdf(...)`".to_string()
                },
            )),
        };
    }
    let given = |name: &str| a.get(name).1 != a.span;
    if let Some(name) = ["view_dependent", "background", "fine", "beta_end"]
        .into_iter()
        .find(|n| given(n))
    {
        return Err(value_error(
            a.get(name).1,
            format!("`{name}` applies to a neural SDF's volume only"),
            "ignored for a shape",
            format!("leave `{name}` out, or give a `neural_sdf(...)`"),
        ));
    }
    // α is an opacity (at most 1) in the assignment's form, a density scale
    // otherwise; trained values stay in range.
    let max = density.alpha_max();
    let alpha_bound = if max.is_finite() {
        Bound::Within(ALPHA_MIN, max)
    } else {
        Bound::AtLeast(ALPHA_MIN)
    };
    let alpha = a.scalar_arg("alpha", Bound::AtLeast(ALPHA_MIN))?;
    if alpha.value > max {
        let max = sdfl_lang::fmt_num(max);
        return Err(value_error(
            a.get("alpha").1,
            format!(
                "`alpha` of `{}` must be at most {max}, got {}",
                density.name(),
                alpha.value
            ),
            format!("above {max}"),
            format!(
                "use {} for a density scale above {max}",
                names(|k| k.alpha_max() > density.alpha_max())
            ),
        ));
    }
    let alpha = Arg {
        param: alpha.param.map(|u| ParamUse {
            bound: alpha_bound,
            ..u
        }),
        ..alpha
    };
    let color = a.material("color")?;
    let shape = a.shape("shape")?;
    if paints_with_normals(&shape) {
        return Err(value_error(
            a.get("shape").1,
            "a volume's shape cannot be painted with a material that needs normals",
            "painted with `lambert` or `normals`",
            "paint volume parts with `rainbow()` or a constant colour",
        ));
    }
    if color.needs_normal() {
        return Err(value_error(
            a.get("color").1,
            "volume colours cannot use normals",
            "needs a normal",
            "use `rainbow()` or a constant colour",
        ));
    }
    Ok(Value::Field(Arc::new(Field::Sdf(SdfField {
        shape,
        density,
        alpha,
        beta: {
            let b = a.scalar_arg("beta", Bound::AtLeast(MIN_BETA))?;
            beta(b.value, a.get("beta").1)?;
            b
        },
        color,
    }))))
}

/// The densities' built-ins that `keep`, as "`a` or `b`".
fn names(keep: impl Fn(DensityKind) -> bool) -> String {
    let names: Vec<String> = DensityKind::ALL
        .iter()
        .filter(|&&k| keep(k))
        .map(|k| format!("`{}`", k.name()))
        .collect();
    names.join(" or ")
}

/// Whether any `paint` in the tree uses a material that needs normals
/// (volumes have none to give).
fn paints_with_normals(s: &Shape) -> bool {
    matches!(s, Shape::Paint(_, m) if m.needs_normal())
        || s.children().into_iter().any(|c| paints_with_normals(c))
}
