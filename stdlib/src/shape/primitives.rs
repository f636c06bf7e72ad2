//! Every analytic primitive, declared once: its built-in's name and doc,
//! its arguments (kind, check, default as sdfl source, range the tests draw
//! from, doc), the formula call (written once over `Real` in
//! [`crate::sdf`]), the rainbow's centre, bounds, exactness, Lipschitz
//! constant, whether the formula runs on lanes, and checks between
//! arguments. [`primitives!`](super::declare) derives the rest.
//!
//! Argument order is the built-in's (positional calls follow it).

use glam::DVec3;
use sdfl_lang::diag::Diag;

use super::declare::*;
use super::{Aabb, ArgSource, Exactness, Shape};
use crate::num::{Real, V3};
use crate::param::ParamUse;
use crate::sdf;

/// `"[0, 0, 0]"`, the centre every centred primitive takes.
macro_rules! centre {
    () => {
        "centre of the shape"
    };
}
/// The axis argument's doc.
macro_rules! axis_doc {
    () => {
        "the axis the shape is built along: \"x\", \"y\" or \"z\""
    };
}

fn ok() -> Result<(), Invalid> {
    Ok(())
}

primitives! {
    Sphere "sphere" "A sphere: `|p - center| - radius` (exact)." {
        radius: scalar(Check::Length, "1", 0.05..1.0, "radius (> 0)"),
        center: point(Check::Free, "[0, 0, 0]", -1.0..1.0, centre!()),
    }
    distance(s, p) = sdf::sphere(p, s.center, s.radius);
    center(s) = s.center;
    bounds(s) = Some(Aabb::around(s.center, DVec3::splat(s.radius)));
    exactness = Exact;
    lipschitz = 1.0;
    lanes = true;
    check(_s) = ok();

    Cuboid "box" "A box with full side lengths `size` (exact)." {
        size: vector(Check::Size, "[1, 1, 1]", 0.05..1.0, "side lengths (> 0); a number for a cube"),
        center: point(Check::Free, "[0, 0, 0]", -1.0..1.0, centre!()),
    }
    distance(s, p) = sdf::cuboid(p, s.center, s.size);
    center(s) = s.center;
    bounds(s) = Some(Aabb::around(s.center, s.size * 0.5));
    exactness = Exact;
    lipschitz = 1.0;
    lanes = true;
    check(_s) = ok();

    BoxFrame "box_frame" "The edges of a box: side lengths `size`, edge `thickness` (exact)." {
        size: vector(Check::Size, "[1, 1, 1]", 0.3..1.3, "side lengths (> 0)"),
        thickness: scalar(Check::Length, "0.05", 0.01..0.3, "edge thickness (> 0, below half the smallest side)"),
        center: point(Check::Free, "[0, 0, 0]", -1.0..1.0, centre!()),
    }
    distance(s, p) = sdf::box_frame(p, s.center, s.size, s.thickness);
    center(s) = s.center;
    bounds(s) = Some(Aabb::around(s.center, s.size * 0.5));
    exactness = Exact;
    lipschitz = 1.0;
    lanes = true;
    check(s) = if s.thickness >= s.size.min_element() * 0.5 {
        Err(Invalid {
            arg: Some("thickness"),
            message: format!("`thickness` {} is not below half the smallest side {}", s.thickness, s.size.min_element()),
            label: "too thick",
            help: "a frame this thick is a solid box: use `box`, or thinner edges",
        })
    } else {
        ok()
    };

    Ellipsoid "ellipsoid" "An ellipsoid with semi-axes `radii` (a bound with Lipschitz constant 1)." {
        radii: vector(Check::Size, "[1, 0.5, 0.5]", 0.02..1.0, "semi-axes (> 0); a number for a sphere"),
        center: point(Check::Free, "[0, 0, 0]", -1.0..1.0, centre!()),
    }
    distance(s, p) = sdf::ellipsoid(p, s.center, s.radii);
    center(s) = s.center;
    // The circumscribed sphere's cube: the bound grows like a distance
    // only beyond that sphere.
    bounds(s) = Some(Aabb::around(s.center, DVec3::splat(s.radii.max_element())));
    exactness = Bound;
    lipschitz = 1.0;
    lanes = true;
    check(_s) = ok();

    Octahedron "octahedron" "An octahedron with vertices at `±size` on each axis (a bound with Lipschitz constant 1)." {
        size: scalar(Check::Length, "1", 0.05..1.0, "distance from the centre to a vertex (> 0)"),
        center: point(Check::Free, "[0, 0, 0]", -1.0..1.0, centre!()),
    }
    distance(s, p) = sdf::octahedron(p, s.center, s.size);
    center(s) = s.center;
    bounds(s) = Some(Aabb::around(s.center, DVec3::splat(s.size)));
    exactness = Bound;
    lipschitz = 1.0;
    lanes = true;
    check(_s) = ok();

    CappedCone "capped_cone" "A cone cut at both ends, along the Z axis (or `axis`): radius `bottom` at z = -height/2, `top` at +height/2 (exact; `top: 0` is a cone)." {
        height: scalar(Check::Length, "1", 0.05..1.0, "full height (> 0)"),
        bottom: scalar(Check::NonNegative, "0.5", 0.0..0.6, "radius of the lower cap (≥ 0)"),
        top: scalar(Check::NonNegative, "0.2", 0.0..0.6, "radius of the upper cap (≥ 0)"),
        center: point(Check::Free, "[0, 0, 0]", -1.0..1.0, centre!()),
        axis: axis(Check::Axis, "\"z\"", 0.0..1.0, axis_doc!()),
    }
    distance(s, p) = sdf::capped_cone(sdf::along(p, s.center, s.axis), s.height, s.bottom, s.top);
    center(s) = s.center;
    bounds(s) = {
        let r = s.bottom.max(s.top);
        Some(Aabb::around(s.center, s.axis.to_world(DVec3::new(r, r, s.height * 0.5))))
    };
    exactness = Exact;
    lipschitz = 1.0;
    lanes = false;
    check(s) = if s.bottom <= 0.0 && s.top <= 0.0 {
        Err(Invalid {
            arg: None,
            message: "a cone with no radius at either end".into(),
            label: "both radii 0",
            help: "give `bottom` or `top` a radius above 0",
        })
    } else {
        ok()
    };

    RoundCone "round_cone" "Two spheres, radius `bottom` at z = -height/2 and `top` at +height/2, joined by the cone tangent to both (their convex hull; exact). Needs |bottom - top| < height." {
        bottom: scalar(Check::Length, "0.5", 0.1..0.5, "radius of the lower sphere (> 0)"),
        top: scalar(Check::Length, "0.2", 0.02..0.5, "radius of the upper sphere (> 0)"),
        height: scalar(Check::Length, "1", 0.05..1.0, "distance between the spheres' centres (> |bottom - top|)"),
        center: point(Check::Free, "[0, 0, 0]", -1.0..1.0, centre!()),
        axis: axis(Check::Axis, "\"z\"", 0.0..1.0, axis_doc!()),
    }
    distance(s, p) = sdf::round_cone(sdf::along(p, s.center, s.axis), s.bottom, s.top, s.height);
    center(s) = s.center;
    bounds(s) = {
        let (b, t, h) = (s.bottom, s.top, s.height * 0.5);
        let r = b.max(t);
        let (lo, hi) = (DVec3::new(-r, -r, -h - b), DVec3::new(r, r, h + t));
        Some(Aabb::new(s.center + s.axis.to_world(lo), s.center + s.axis.to_world(hi)))
    };
    exactness = Exact;
    lipschitz = 1.0;
    lanes = false;
    check(s) = if (s.bottom - s.top).abs() >= s.height {
        Err(Invalid {
            arg: Some("height"),
            message: format!(
                "`height` {} is not above |bottom - top| = |{} - {}|",
                sdfl_lang::fmt_num(s.height),
                sdfl_lang::fmt_num(s.bottom),
                sdfl_lang::fmt_num(s.top)
            ),
            label: "one sphere holds the other",
            help: "make `height` larger than |bottom - top|, or use `sphere`",
        })
    } else {
        ok()
    };

    HexPrism "hex_prism" "A hexagonal prism along the Z axis (or `axis`): flat sides `radius` from the axis, two of them parallel to X, full `height` (exact)." {
        radius: scalar(Check::Length, "0.5", 0.05..0.8, "distance from the axis to each flat side (> 0)"),
        height: scalar(Check::Length, "1", 0.05..1.0, "full height (> 0)"),
        center: point(Check::Free, "[0, 0, 0]", -1.0..1.0, centre!()),
        axis: axis(Check::Axis, "\"z\"", 0.0..1.0, axis_doc!()),
    }
    distance(s, p) = sdf::hex_prism(sdf::along(p, s.center, s.axis), s.radius, s.height);
    center(s) = s.center;
    bounds(s) = {
        let r = s.radius;
        let half = DVec3::new(r * 2.0 / 3f64.sqrt(), r, s.height * 0.5);
        Some(Aabb::around(s.center, s.axis.to_world(half)))
    };
    exactness = Exact;
    lipschitz = 1.0;
    lanes = false;
    check(_s) = ok();

    TriPrism "tri_prism" "A prism along the Z axis (or `axis`) over an equilateral triangle of `side`, centred on its centroid with a vertex towards +Y, full `height` (exact)." {
        side: scalar(Check::Length, "1", 0.05..1.0, "side of the triangle (> 0)"),
        height: scalar(Check::Length, "1", 0.05..1.0, "full height (> 0)"),
        center: point(Check::Free, "[0, 0, 0]", -1.0..1.0, centre!()),
        axis: axis(Check::Axis, "\"z\"", 0.0..1.0, axis_doc!()),
    }
    distance(s, p) = sdf::tri_prism(sdf::along(p, s.center, s.axis), s.side, s.height);
    center(s) = s.center;
    bounds(s) = {
        let (w, h) = (s.side, s.height * 0.5);
        let inr = w / (2.0 * 3f64.sqrt());
        let (lo, hi) = (DVec3::new(-w * 0.5, -inr, -h), DVec3::new(w * 0.5, 2.0 * inr, h));
        Some(Aabb::new(s.center + s.axis.to_world(lo), s.center + s.axis.to_world(hi)))
    };
    exactness = Exact;
    lipschitz = 1.0;
    lanes = false;
    check(_s) = ok();

    Link "link" "A chain link around the Z axis (or `axis`): a torus (`major`, `minor`) cut across Y and pulled apart by straight parts of `length` (exact)." {
        length: scalar(Check::Length, "1", 0.05..1.0, "length of the straight parts (> 0)"),
        major: scalar(Check::Length, "0.4", 0.2..0.6, "distance from the centre line to the tube's centre (> 0)"),
        minor: scalar(Check::Length, "0.1", 0.02..0.15, "radius of the tube (> 0)"),
        center: point(Check::Free, "[0, 0, 0]", -1.0..1.0, centre!()),
        axis: axis(Check::Axis, "\"z\"", 0.0..1.0, axis_doc!()),
    }
    distance(s, p) = sdf::link(sdf::along(p, s.center, s.axis), s.length, s.major, s.minor);
    center(s) = s.center;
    bounds(s) = {
        let (r, m) = (s.major, s.minor);
        let half = DVec3::new(r + m, s.length * 0.5 + r + m, m);
        Some(Aabb::around(s.center, s.axis.to_world(half)))
    };
    exactness = Exact;
    lipschitz = 1.0;
    lanes = false;
    check(_s) = ok();

    Torus "torus" "A torus around the Z axis (or `axis`), in the XY plane (exact)." {
        major: scalar(Check::Length, "1", 0.3..1.0, "distance from the centre to the tube's centre (> 0)"),
        minor: scalar(Check::Length, "0.25", 0.05..0.25, "radius of the tube (> 0)"),
        center: point(Check::Free, "[0, 0, 0]", -1.0..1.0, centre!()),
        axis: axis(Check::Axis, "\"z\"", 0.0..1.0, axis_doc!()),
    }
    distance(s, p) = sdf::torus(sdf::along(p, s.center, s.axis), s.major, s.minor);
    center(s) = s.center;
    bounds(s) = {
        let (r, m) = (s.major, s.minor);
        Some(Aabb::around(s.center, s.axis.to_world(DVec3::new(r + m, r + m, m))))
    };
    exactness = Exact;
    lipschitz = 1.0;
    lanes = true;
    check(_s) = ok();

    Capsule "capsule" "A segment from `a` to `b` thickened by `radius` (exact)." {
        a: point(Check::Free, req, -1.0..1.0, "one end"),
        b: point(Check::Free, req, -1.0..1.0, "the other end"),
        radius: scalar(Check::Length, "0.25", 0.03..0.5, "radius (> 0)"),
    }
    distance(s, p) = sdf::capsule(p, s.a, s.b, s.radius);
    center(s) = (s.a + s.b) * T::lit(0.5);
    bounds(s) = Some(Aabb::new(s.a.min(s.b), s.a.max(s.b)).expand(s.radius));
    exactness = Exact;
    lipschitz = 1.0;
    lanes = false;
    check(_s) = ok();

    Cylinder "cylinder" "A capped cylinder along the Z axis (or `axis`) (exact)." {
        radius: scalar(Check::Length, "0.5", 0.05..0.6, "radius (> 0)"),
        height: scalar(Check::Length, "1", 0.05..1.0, "full height (> 0)"),
        center: point(Check::Free, "[0, 0, 0]", -1.0..1.0, centre!()),
        axis: axis(Check::Axis, "\"z\"", 0.0..1.0, axis_doc!()),
    }
    distance(s, p) = sdf::cylinder(sdf::along(p, s.center, s.axis), s.radius, s.height);
    center(s) = s.center;
    bounds(s) = Some(Aabb::around(s.center, s.axis.to_world(DVec3::new(s.radius, s.radius, s.height * 0.5))));
    exactness = Exact;
    lipschitz = 1.0;
    lanes = true;
    check(_s) = ok();

    Plane "plane" "The half-space below a plane: `dot(p, normal) - height` (exact, unbounded)." {
        normal: vector(Check::Direction, "[0, 1, 0]", -1.0..1.0, "the plane's normal (nonzero)"),
        height: scalar(Check::Free, "0", -1.0..1.0, "offset along the normal"),
    }
    distance(s, p) = sdf::plane(p, s.normal, s.height);
    center(s) = s.normal * s.height;
    bounds(_s) = None;
    exactness = Exact;
    lipschitz = 1.0;
    lanes = true;
    check(_s) = ok();

    CappedTorus "capped_torus" "Inigo Quilez's capped torus: the part of a torus (`major`, `minor`) around the Z axis (or `axis`) within `angle` of +Y on either side, its ends rounded (exact; `angle: 180deg` is the whole torus)." {
        angle: scalar(Check::Within(0.0, std::f64::consts::PI), "120deg", 0.2..3.0, "half the opening: the arc spans `angle` each side of +Y (radians; 0..180deg)"),
        major: scalar(Check::Length, "1", 0.3..1.0, "distance from the centre to the tube's centre (> 0)"),
        minor: scalar(Check::Length, "0.25", 0.05..0.25, "radius of the tube (> 0)"),
        center: point(Check::Free, "[0, 0, 0]", -1.0..1.0, centre!()),
        axis: axis(Check::Axis, "\"z\"", 0.0..1.0, axis_doc!()),
    }
    distance(s, p) = sdf::capped_torus(sdf::along(p, s.center, s.axis), s.angle, s.major, s.minor);
    center(s) = s.center;
    // The whole torus's box.
    bounds(s) = {
        let (r, m) = (s.major, s.minor);
        Some(Aabb::around(s.center, s.axis.to_world(DVec3::new(r + m, r + m, m))))
    };
    exactness = Exact;
    lipschitz = 1.0;
    lanes = true;
    check(_s) = ok();

    Cone "cone" "A pointed cone along the Z axis (or `axis`), as SDF artists write it: `cone(angle:, height:)`, its side at `angle` to the axis, tip at +height/2, base of radius height·tan(angle) at -height/2 (exact)." {
        height: scalar(Check::Length, "1", 0.1..1.0, "full height (> 0)"),
        center: point(Check::Free, "[0, 0, 0]", -1.0..1.0, centre!()),
        axis: axis(Check::Axis, "\"z\"", 0.0..1.0, axis_doc!()),
        angle: scalar(Check::Within(0.001, 1.56), "30deg", 0.1..1.3, "angle between the side and the axis (radians; below 90deg)"),
    }
    distance(s, p) = sdf::cone(sdf::along(p, s.center, s.axis), s.angle, s.height);
    center(s) = s.center;
    bounds(s) = {
        let r = s.height * s.angle.tan();
        Some(Aabb::around(s.center, s.axis.to_world(DVec3::new(r, r, s.height * 0.5))))
    };
    exactness = Exact;
    lipschitz = 1.0;
    lanes = true;
    check(_s) = ok();
}
