//! Lit materials and a render's options for effects: `phong(...)`, the
//! soft shadows and ambient occlusion a lit material may ask for, fog and
//! samples per pixel.

use super::*;

pub(super) fn phong(a: &Args) -> Result<Value, Diag> {
    let fraction = |name: &str| -> Result<f64, Diag> {
        let x = a.number(name)?;
        if (0.0..=1.0).contains(&x) {
            Ok(x)
        } else {
            Err(value_error(
                a.get(name).1,
                format!("`{name}` must be in 0..1, got {}", sdfl_lang::fmt_num(x)),
                "out of 0..1",
                "use a fraction such as 0.5",
            ))
        }
    };
    let (ambient, specular) = (fraction("ambient")?, fraction("specular")?);
    let shininess = a.positive("shininess")?;
    let (lights_v, lights_span) = a.get("lights");
    let lights = one_or_list(lights_v, |v| match v {
        Value::Light(l) => Some(*l),
        _ => None,
    });
    let lights = match lights {
        Some(l) if l.is_empty() => {
            return Err(value_error(
                lights_span,
                "a `phong` material with no lights",
                "empty list",
                "give at least one light, e.g. `lights: [light(direction: [1, 1, 1])]`",
            ))
        }
        Some(l) => l,
        None => return Err(type_error(lights_span, "list of lights", lights_v)),
    };
    let albedo = a.material("albedo")?;
    if albedo.needs_view() {
        return Err(value_error(
            a.get("albedo").1,
            "a `phong` albedo cannot itself depend on the view",
            "a view-dependent material",
            "use a colour, `rainbow()`, `lambert(...)` or `normals()` as the albedo",
        ));
    }
    Ok(Value::Material(Arc::new(Material::Phong {
        albedo: Box::new((*albedo).clone()),
        lights,
        ambient,
        specular,
        shininess,
        effects: effects(a)?,
    })))
}

/// An effect option: `false` (none) or the value of its built-in. `true`
/// is refused with the call to write, so that the built-in's signature
/// stays the one place its defaults are written.
fn effect_option<T>(
    a: &Args,
    name: &str,
    builtin: &str,
    expected: &str,
    pick: impl Fn(&Value) -> Option<T>,
) -> Result<Option<T>, Diag> {
    match a.get(name) {
        (Value::Bool(false), _) => Ok(None),
        (Value::Bool(true), span) => Err(value_error(
            span,
            format!("`{name}: true` does not say which {expected} to compute"),
            format!("use `{builtin}(...)`"),
            format!("write `{name}: {builtin}()` for the defaults (`sdfl docs {builtin}`), or `false` for none"),
        )),
        (v, span) => pick(v).map(Some).ok_or_else(|| type_error(span, expected, v)),
    }
}

/// The `shadows` and `ao` options of a lit material.
pub(super) fn effects(a: &Args) -> Result<Effects, Diag> {
    Ok(Effects {
        shadows: effect_option(a, "shadows", "soft", "soft shadow", |v| match v {
            Value::Shadows(s) => Some(*s),
            _ => None,
        })?,
        occlusion: effect_option(a, "ao", "ao", "ambient occlusion", |v| match v {
            Value::Occlusion(o) => Some(*o),
            _ => None,
        })?,
    })
}

/// A render's `fog` option.
pub(crate) fn fog_option(a: &Args) -> Result<Option<Fog>, Diag> {
    effect_option(a, "fog", "fog", "fog", |v| match v {
        Value::Fog(f) => Some(*f),
        _ => None,
    })
}

/// A render's `samples_per_pixel`: a square from 1 to
/// [`MAX_SAMPLES_PER_PIXEL`] (an `m × m` rotated grid in each pixel).
pub(crate) fn samples_per_pixel(a: &Args) -> Result<u32, Diag> {
    let n = a.count("samples_per_pixel", 1, MAX_SAMPLES_PER_PIXEL as u64)? as u32;
    let m = (n as f64).sqrt().round() as u32;
    if m * m != n {
        let (below, above) = (
            (n as f64).sqrt().floor() as u32,
            (n as f64).sqrt().ceil() as u32,
        );
        return Err(value_error(
            a.get("samples_per_pixel").1,
            format!("`samples_per_pixel` must be a square (an m × m grid in each pixel), got {n}"),
            "not a square",
            format!(
                "use {} ({below}×{below}) or {} ({above}×{above})",
                below * below,
                above * above
            ),
        ));
    }
    Ok(n)
}
