//! Materials: how a surface point is coloured.

use glam::DVec3;

use crate::effects::{AmbientOcclusion, Open, SoftShadows, Surroundings};
use crate::num::{Real, V3};
use crate::param::ArgSource;
use crate::param::{Arg, ParamUse};

#[derive(Debug, Clone, PartialEq)]
/// How a surface point is coloured: a colour, or shading of an albedo under
/// lights.
pub enum Material {
    /// `clamp(|p - c|, 0.02, 0.98)` componentwise, `c` the primitive's centre.
    Rainbow,
    /// One colour (trainable).
    Constant(Arg<DVec3>),
    /// `albedo · (ambient·ao + (1 - ambient)·max(0, n·l)·shadow)` under a
    /// directional light coming from `light` (unit vector towards the
    /// light); `ao` and `shadow` are 1 unless the material asks for them.
    Lambert {
        /// The surface colour before lighting (itself a material).
        albedo: Box<Material>,
        /// Unit vector towards the light.
        light: DVec3,
        /// Fraction of the albedo lit regardless of the light.
        ambient: f64,
        /// Soft shadows and ambient occlusion, if asked for.
        effects: Effects,
    },
    /// The surface normal as a colour, `(n + 1) / 2`.
    Normals,
    /// Blinn-Phong under directional lights: see [`blinn_phong`].
    Phong {
        /// The surface colour before lighting (itself a material).
        albedo: Box<Material>,
        /// The directional lights, each with its colour.
        lights: Vec<Light>,
        /// Fraction of the albedo lit regardless of the lights.
        ambient: f64,
        /// Strength of the highlights.
        specular: f64,
        /// Exponent of the highlights: larger is sharper.
        shininess: f64,
        /// Soft shadows and ambient occlusion, if asked for.
        effects: Effects,
    },
}

/// The effects a lit material asks for; each costs SDF evaluations per
/// shaded point (see `sdfl plan`), none when absent.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Effects {
    /// Lights are blocked by the scene, with penumbrae. A surface facing
    /// away from a light is in its own shadow (no ray is marched).
    pub shadows: Option<SoftShadows>,
    /// The ambient term is darkened where the scene crowds the surface.
    pub occlusion: Option<AmbientOcclusion>,
}

impl Effects {
    /// The fraction of the light from unit direction `l` reaching a point
    /// with normal `n`: 1 without shadows, else 0 facing away and the
    /// scene's soft shadow facing it.
    fn visibility(&self, n: DVec3, l: DVec3, env: &dyn Surroundings) -> f64 {
        match &self.shadows {
            None => 1.0,
            Some(_) if n.dot(l) <= 0.0 => 0.0,
            Some(s) => env.light_visibility(l, s),
        }
    }

    /// The fraction of ambient light reaching the point.
    fn ambient(&self, env: &dyn Surroundings) -> f64 {
        self.occlusion
            .as_ref()
            .map_or(1.0, |ao| env.ambient_visibility(ao))
    }
}

/// A directional light.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Light {
    /// Unit vector from the surface towards the light.
    pub direction: DVec3,
    /// Linear RGB intensity, each component in 0..1.
    pub color: DVec3,
}

/// Blinn-Phong shading, in any number type: `albedo·ambient·ao + Σ_l
/// color_l·shadow_l·(albedo·(1 - ambient)·max(0, n·l) +
/// specular·max(0, n·h)^shininess)` with `h = normalize(l - view)`, `view`
/// the unit ray direction (from the eye towards the surface), clamped to
/// 0..1 componentwise. Where `h` is undefined (light straight along the
/// ray) the highlight is 0. `ao` and `shadow_l` (the visible fraction of
/// light `l`, see [`Effects`]) are 1 without occlusion and shadows.
#[inline]
#[allow(clippy::too_many_arguments)]
pub fn blinn_phong<T: Real>(
    albedo: V3<T>,
    n: V3<T>,
    view: V3<T>,
    lights: &[Light],
    ambient: f64,
    specular: f64,
    shininess: f64,
    ao: f64,
    mut shadow: impl FnMut(&Light) -> f64,
) -> V3<T> {
    let mut c = albedo * T::lit(ambient * ao);
    for light in lights {
        let visible = shadow(light);
        if visible <= 0.0 {
            continue;
        }
        let l = V3::lit(light.direction.to_array());
        let diffuse = n.dot(l).max(T::zero());
        let half = l - view;
        let len = half.length();
        let highlight = if len.val() > 1e-12 {
            let cos = (n.dot(half) / len).max(T::zero());
            // x^s = exp(s·ln x); 0 where x is 0 (no ln of 0).
            if cos.val() > 0.0 {
                (cos.ln() * T::lit(shininess)).exp() * T::lit(specular)
            } else {
                T::zero()
            }
        } else {
            T::zero()
        };
        let lit = (albedo * (diffuse * T::lit(1.0 - ambient))).map(|x| x + highlight);
        c = c + lit.zip(V3::lit((light.color * visible).to_array()), |a, b| a * b);
    }
    c.map(|x| x.clamp(0.0, 1.0))
}

impl Material {
    /// A constant colour that is not trained.
    pub fn constant(c: DVec3) -> Self {
        Material::Constant(Arg::fixed(c))
    }

    /// Whether shading needs the surface normal.
    pub fn needs_normal(&self) -> bool {
        match self {
            Material::Rainbow | Material::Constant(_) => false,
            Material::Lambert { .. } | Material::Normals | Material::Phong { .. } => true,
        }
    }

    /// Whether shading needs the view (ray) direction.
    pub fn needs_view(&self) -> bool {
        match self {
            Material::Phong { .. } => true,
            Material::Lambert { albedo, .. } => albedo.needs_view(),
            _ => false,
        }
    }

    /// The effects the material and its albedo ask for.
    pub fn effects(&self) -> Vec<Effects> {
        match self {
            Material::Lambert {
                albedo, effects, ..
            }
            | Material::Phong {
                albedo, effects, ..
            } => {
                let mut all = albedo.effects();
                all.push(*effects);
                all
            }
            _ => Vec::new(),
        }
    }

    /// The lights a material with shadows marches shadow rays towards, per
    /// shaded point (its albedo's included).
    pub fn shadowed_lights(&self) -> usize {
        match self {
            Material::Lambert {
                albedo, effects, ..
            } => albedo.shadowed_lights() + usize::from(effects.shadows.is_some()),
            Material::Phong {
                albedo,
                effects,
                lights,
                ..
            } => {
                albedo.shadowed_lights()
                    + if effects.shadows.is_some() {
                        lights.len()
                    } else {
                        0
                    }
            }
            _ => 0,
        }
    }

    /// Most SDF evaluations the material's effects take per shaded point:
    /// `steps` per shadowed light, `samples` for ambient occlusion.
    pub fn effect_evaluations(&self) -> u64 {
        let own = |e: &Effects, lights: usize| {
            e.shadows.map_or(0, |s| s.steps as u64 * lights as u64)
                + e.occlusion.map_or(0, |o| o.samples as u64)
        };
        match self {
            Material::Lambert {
                albedo, effects, ..
            } => albedo.effect_evaluations() + own(effects, 1),
            Material::Phong {
                albedo,
                effects,
                lights,
                ..
            } => albedo.effect_evaluations() + own(effects, lights.len()),
            _ => 0,
        }
    }

    /// The colour at world point `p` of a primitive centred at `center`,
    /// with unit normal `n` (ignored unless [`Self::needs_normal`]), seen
    /// along the unit ray direction `view` (ignored unless
    /// [`Self::needs_view`]), with nothing around it: no shadows, no
    /// occlusion (see [`Self::shade_in`]).
    pub fn shade(&self, p: DVec3, center: DVec3, n: DVec3, view: DVec3) -> DVec3 {
        self.shade_in(p, center, n, view, &Open)
    }

    /// [`Self::shade`] in a scene: shadows and ambient occlusion, where the
    /// material asks for them, come from `env`, which is asked nothing
    /// otherwise.
    pub fn shade_in(
        &self,
        p: DVec3,
        center: DVec3,
        n: DVec3,
        view: DVec3,
        env: &dyn Surroundings,
    ) -> DVec3 {
        match self {
            Material::Lambert {
                albedo,
                light,
                ambient,
                effects,
            } => {
                let diffuse = n.dot(*light).max(0.0);
                let direct = if diffuse > 0.0 {
                    diffuse * effects.visibility(n, *light, env)
                } else {
                    0.0
                };
                let ao = if *ambient > 0.0 {
                    effects.ambient(env)
                } else {
                    1.0
                };
                albedo.shade_in(p, center, n, view, env) * (ambient * ao + (1.0 - ambient) * direct)
            }
            Material::Phong {
                albedo,
                lights,
                ambient,
                specular,
                shininess,
                effects,
            } => {
                let a = albedo.shade_in(p, center, n, view, env);
                let ao = if *ambient > 0.0 {
                    effects.ambient(env)
                } else {
                    1.0
                };
                let c = blinn_phong(
                    V3::from(a),
                    V3::from(n),
                    V3::from(view),
                    lights,
                    *ambient,
                    *specular,
                    *shininess,
                    ao,
                    |l| effects.visibility(n, l.direction, env),
                );
                DVec3::from_array(c.to_array())
            }
            Material::Normals => (n + DVec3::ONE) * 0.5,
            unlit => unlit
                .unlit_color(p.into(), center.into(), &crate::param::Fixed)
                .map(DVec3::from)
                .unwrap_or(DVec3::ZERO),
        }
    }

    /// The colour of a material that needs no normal (what volumes use), in
    /// any number type; `None` for materials that need a normal.
    #[inline]
    pub fn unlit_color<T: Real, A: ArgSource<T>>(
        &self,
        p: V3<T>,
        center: V3<T>,
        args: &A,
    ) -> Option<V3<T>> {
        match self {
            Material::Rainbow => Some(crate::sdf::rainbow(p, center)),
            Material::Constant(c) => Some(args.vector(c)),
            Material::Lambert { .. } | Material::Normals | Material::Phong { .. } => None,
        }
    }

    /// Trainable arguments (a constant colour's).
    pub fn visit_params<'s>(&'s self, f: &mut dyn FnMut(&'s ParamUse)) {
        match self {
            Material::Constant(Arg { param: Some(u), .. }) => f(u),
            Material::Lambert { albedo, .. } | Material::Phong { albedo, .. } => {
                albedo.visit_params(f)
            }
            _ => {}
        }
    }
}
