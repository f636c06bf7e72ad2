use glam::DVec3;
use sdfl_stdlib::effects::{AmbientOcclusion, SoftShadows, Surroundings};
use sdfl_stdlib::material::*;
use sdfl_stdlib::num::V3;

fn phong(lights: Vec<Light>) -> Material {
    Material::Phong {
        albedo: Box::new(Material::constant(DVec3::new(0.5, 0.4, 0.2))),
        lights,
        ambient: 0.1,
        specular: 0.5,
        shininess: 32.0,
        effects: Effects::default(),
    }
}

#[test]
fn blinn_phong_matches_hand_computed_values() {
    let white = Light {
        direction: DVec3::Z,
        color: DVec3::ONE,
    };
    // Seen head-on under a light behind the eye: full diffuse, full
    // highlight, albedo + 0.5, clamped.
    let c = phong(vec![white]).shade(DVec3::ZERO, DVec3::ZERO, DVec3::Z, -DVec3::Z);
    assert!((c - DVec3::new(1.0, 0.9, 0.7)).length() < 1e-12, "{c}");
    // At 45°, with a grazing coloured light too: both half vectors are
    // 22.5° off the normal, highlight 0.5·cos(22.5°)^32 each
    // (computed independently in Python).
    let m = phong(vec![
        white,
        Light {
            direction: DVec3::X,
            color: DVec3::new(0.2, 0.3, 0.4),
        },
    ]);
    let view = DVec3::new(1.0, 0.0, -1.0).normalize();
    let c = m.shade(DVec3::ZERO, DVec3::ZERO, DVec3::Z, view);
    let want = DVec3::new(0.5476258039474218, 0.4515946209430403, 0.2555634379386589);
    assert!((c - want).length() < 1e-12, "{c} vs {want}");
    assert!(m.needs_normal() && m.needs_view());
    assert!(!Material::Rainbow.needs_view());
}

#[test]
fn the_highlight_follows_the_view() {
    // A light from +x+z: the highlight is strongest where the view is
    // the mirror of the light about the normal, and moves with it.
    let light = Light {
        direction: DVec3::new(1.0, 0.0, 1.0).normalize(),
        color: DVec3::ONE,
    };
    let m = Material::Phong {
        albedo: Box::new(Material::constant(DVec3::splat(0.2))),
        lights: vec![light],
        ambient: 0.0,
        specular: 0.6,
        shininess: 64.0,
        effects: Effects::default(),
    };
    let shade = |angle: f64| {
        // The ray travels towards -z, tilted by `angle` about y.
        let view = DVec3::new(angle.sin(), 0.0, -angle.cos());
        m.shade(DVec3::ZERO, DVec3::ZERO, DVec3::Z, view).x
    };
    // h = n where -view mirrors the light: view = (1, 0, -1)/√2, +45°.
    let mirror = std::f64::consts::FRAC_PI_4;
    let best = (-80..=80)
        .map(|k| (k as f64).to_radians())
        .max_by(|a, b| shade(*a).total_cmp(&shade(*b)))
        .unwrap();
    assert!((best - mirror).abs() < 1.5f64.to_radians(), "{best}");
    assert!(shade(mirror) > shade(0.0) + 0.3);
}

/// Surroundings that answer fixed fractions and count the questions.
struct Fixed {
    light: f64,
    ambient: f64,
    asked: std::cell::Cell<(u32, u32)>,
}

impl Surroundings for Fixed {
    fn light_visibility(&self, _: DVec3, _: &SoftShadows) -> f64 {
        let (l, a) = self.asked.get();
        self.asked.set((l + 1, a));
        self.light
    }
    fn ambient_visibility(&self, _: &AmbientOcclusion) -> f64 {
        let (l, a) = self.asked.get();
        self.asked.set((l, a + 1));
        self.ambient
    }
}

#[test]
fn effects_are_asked_for_only_when_the_material_has_them() {
    let env = |light, ambient| Fixed {
        light,
        ambient,
        asked: Default::default(),
    };
    let lambert = |effects| Material::Lambert {
        albedo: Box::new(Material::constant(DVec3::new(0.8, 0.6, 0.4))),
        light: DVec3::Y,
        ambient: 0.25,
        effects,
    };
    let (p, n, view) = (DVec3::ZERO, DVec3::Y, -DVec3::Y);
    // No effects: the surroundings are never asked.
    let e = env(0.0, 0.0);
    let plain = lambert(Effects::default()).shade_in(p, p, n, view, &e);
    assert_eq!(e.asked.get(), (0, 0));
    assert!((plain - DVec3::new(0.8, 0.6, 0.4)).length() < 1e-12);
    // Shadows only: in full shadow, only the ambient term is left.
    let shadows = Effects {
        shadows: Some(SoftShadows { k: 8.0, steps: 16 }),
        occlusion: None,
    };
    let e = env(0.0, 0.0);
    let c = lambert(shadows).shade_in(p, p, n, view, &e);
    assert_eq!(e.asked.get(), (1, 0));
    assert!((c - DVec3::new(0.8, 0.6, 0.4) * 0.25).length() < 1e-12);
    // Facing away from the light: in its own shadow, nothing marched.
    let e = env(1.0, 1.0);
    lambert(shadows).shade_in(p, p, -n, view, &e);
    assert_eq!(e.asked.get(), (0, 0));
    // Occlusion scales the ambient term only.
    let both = Effects {
        shadows: shadows.shadows,
        occlusion: Some(AmbientOcclusion {
            samples: 4,
            distance: 0.5,
        }),
    };
    let e = env(0.5, 0.5);
    let c = lambert(both).shade_in(p, p, n, view, &e);
    assert_eq!(e.asked.get(), (1, 1));
    let want = DVec3::new(0.8, 0.6, 0.4) * (0.25 * 0.5 + 0.75 * 0.5);
    assert!((c - want).length() < 1e-12);
    // Phong: a shadowed light loses its highlight too; one ray per
    // light the surface faces.
    let m = Material::Phong {
        albedo: Box::new(Material::constant(DVec3::new(0.5, 0.4, 0.2))),
        lights: vec![
            Light {
                direction: DVec3::Z,
                color: DVec3::ONE,
            },
            Light {
                direction: -DVec3::Z,
                color: DVec3::ONE,
            },
        ],
        ambient: 0.1,
        specular: 0.5,
        shininess: 32.0,
        effects: both,
    };
    let e = env(0.0, 1.0);
    let c = m.shade_in(p, p, DVec3::Z, -DVec3::Z, &e);
    assert_eq!(e.asked.get(), (1, 1));
    assert!(
        (c - DVec3::new(0.5, 0.4, 0.2) * 0.1).length() < 1e-12,
        "{c}"
    );
    assert_eq!(m.effect_evaluations(), 2 * 16 + 4);
    assert_eq!(m.shadowed_lights(), 2);
}

#[test]
fn blinn_phong_is_the_same_formula_in_f32() {
    let light = Light {
        direction: DVec3::new(0.3, 0.5, 0.8).normalize(),
        color: DVec3::new(0.9, 0.8, 0.7),
    };
    let (a, n, v) = ([0.3, 0.6, 0.9], [0.0, 0.6, 0.8], [0.6, 0.0, -0.8]);
    let c64: V3<f64> = blinn_phong(
        V3::lit(a),
        V3::lit(n),
        V3::lit(v),
        &[light],
        0.2,
        0.4,
        16.0,
        1.0,
        |_| 1.0,
    );
    let c32: V3<f32> = blinn_phong(
        V3::lit(a),
        V3::lit(n),
        V3::lit(v),
        &[light],
        0.2,
        0.4,
        16.0,
        1.0,
        |_| 1.0,
    );
    for (x, y) in c64.to_array().iter().zip(c32.to_array()) {
        assert!((x - y as f64).abs() < 1e-5);
    }
}
