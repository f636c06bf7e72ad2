//! Materials: how a surface point is coloured.

use glam::DVec3;

#[derive(Debug, Clone, PartialEq)]
pub enum Material {
    /// `clamp(|p - c|, 0.02, 0.98)` componentwise, `c` the primitive's centre.
    Rainbow,
    Constant(DVec3),
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
            Material::Rainbow => (p - center)
                .abs()
                .clamp(DVec3::splat(0.02), DVec3::splat(0.98)),
            Material::Constant(c) => *c,
            Material::Lambert {
                albedo,
                light,
                ambient,
            } => {
                let diffuse = n.dot(*light).max(0.0);
                albedo.shade(p, center, n) * (ambient + (1.0 - ambient) * diffuse)
            }
            Material::Normals => (n + DVec3::ONE) * 0.5,
        }
    }
}
