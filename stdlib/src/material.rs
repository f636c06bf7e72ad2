//! Materials: how a surface point is coloured.

use glam::DVec3;

use crate::num::{Real, V3};
use crate::param::{Arg, ParamUse};
use crate::shape::ArgSource;

#[derive(Debug, Clone, PartialEq)]
pub enum Material {
    /// `clamp(|p - c|, 0.02, 0.98)` componentwise, `c` the primitive's centre.
    Rainbow,
    /// One colour (trainable).
    Constant(Arg<DVec3>),
    /// `albedo · (ambient + (1 - ambient)·max(0, n·l))` under a directional
    /// light coming from `light` (unit vector towards the light).
    Lambert {
        albedo: Box<Material>,
        light: DVec3,
        ambient: f64,
    },
    /// The surface normal as a colour, `(n + 1) / 2`.
    Normals,
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
            Material::Lambert { .. } | Material::Normals => true,
        }
    }

    /// The colour at world point `p` of a primitive centred at `center`,
    /// with unit normal `n` (ignored unless [`Self::needs_normal`]).
    pub fn shade(&self, p: DVec3, center: DVec3, n: DVec3) -> DVec3 {
        match self {
            Material::Lambert {
                albedo,
                light,
                ambient,
            } => {
                let diffuse = n.dot(*light).max(0.0);
                albedo.shade(p, center, n) * (ambient + (1.0 - ambient) * diffuse)
            }
            Material::Normals => (n + DVec3::ONE) * 0.5,
            unlit => unlit
                .unlit_color(p.into(), center.into(), &crate::shape::Fixed)
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
            Material::Lambert { .. } | Material::Normals => None,
        }
    }

    /// Trainable arguments (a constant colour's).
    pub fn visit_params<'s>(&'s self, f: &mut dyn FnMut(&'s ParamUse)) {
        match self {
            Material::Constant(Arg { param: Some(u), .. }) => f(u),
            Material::Lambert { albedo, .. } => albedo.visit_params(f),
            _ => {}
        }
    }
}
