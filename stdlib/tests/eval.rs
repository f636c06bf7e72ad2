//! Evaluation of scene files: loops, defaults, value errors.

use sdfl_lang::{codes, SourceFile};
use sdfl_stdlib::{load, StdEnv};

fn codes_of(src: &str) -> Vec<&'static str> {
    match load(&SourceFile::new("test.sdfl", src)) {
        Ok(_) => Vec::new(),
        Err(d) => d.diags.iter().map(|d| d.code).collect(),
    }
}

#[test]
fn every_default_evaluates() {
    // Defaults are sdfl source; each one must parse and evaluate.
    let env = StdEnv::get();
    for b in env.builtins() {
        let args: Vec<String> = b
            .sig
            .params
            .iter()
            .filter(|p| p.default.is_none())
            .map(|p| {
                use sdfl_lang::types::Type;
                // The first placeholder whose type the parameter accepts.
                let candidates = [
                    (Type::Named("shape"), "sphere()"),
                    (Type::Named("material"), "rainbow()"),
                    (Type::Named("field"), "sdf_volume(sphere())"),
                    (Type::Named("sampler"), "stratified()"),
                    (Type::Named("camera"), "look_at([0, 0, 3])"),
                    (Type::list(Type::Named("camera")), "[look_at([0, 0, 3])]"),
                    (Type::list(Type::Str), "[\"x.npy\"]"),
                    (Type::Str, "\"x.png\""),
                    (Type::Number, "1"),
                    (Type::Vec3, "[1, 2, 3]"),
                ];
                let v = candidates
                    .iter()
                    .find(|(t, _)| p.ty.accepts(t))
                    .map_or("1", |c| c.1);
                format!("{}: {v}", p.name)
            })
            .collect();
        let rest = if b.sig.rest.is_some() {
            "sphere(), "
        } else {
            ""
        };
        let src = format!("let x = {}({rest}{})", b.sig.name, args.join(", "));
        let r = load(&SourceFile::new("t", src.clone()));
        // Outputs need a .gif name etc.; only defaults matter here, so any
        // failure must be a value error of the placeholder arguments.
        if let Err(d) = r {
            assert!(
                d.diags.iter().all(|d| d.code == codes::VALUE),
                "{src}: {d:?}"
            );
        }
    }
}

#[test]
fn torus_example_loads() {
    let src = std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../examples/torus.sdfl"
    ))
    .unwrap();
    let p = load(&SourceFile::new("torus.sdfl", src)).unwrap();
    let r = &p.renders[0];
    assert_eq!(
        (r.width, r.height, r.iterations, r.cameras.len()),
        (256, 256, 64, 20)
    );
    assert_eq!((r.near, r.far), (0.0, 5.0));
}

#[test]
fn loops_build_many_shapes() {
    let src = "let s = union(for i in 0..10, j in 0..=4 { let r = 0.1 + i * 0.01; sphere(r, center: [i, j, 0]) })\n\
               render r { scene: s, camera: look_at([0, 0, 5]), outputs: [image(\"a.png\")] }";
    let p = load(&SourceFile::new("t", src)).unwrap();
    assert_eq!(p.renders[0].scene.primitive_count(), 50);
}

#[test]
fn value_errors_are_all_reported() {
    let src = "let a = sphere(-1)\nlet b = box([1, 0, 1])\nlet c = 1 / 0\n\
               render r { scene: torus(), camera: orbit(views: 0), near: 3, far: 1, size: [0, 10], outputs: [image(\"../x.png\")] }";
    let c = codes_of(src);
    assert_eq!(c.iter().filter(|c| **c == codes::VALUE).count(), 3, "{c:?}");
    assert!(c.contains(&codes::ARITHMETIC), "{c:?}");
    assert!(c.contains(&codes::PATH), "{c:?}");
}

#[test]
fn huge_loops_are_refused_quickly() {
    let t = std::time::Instant::now();
    let c = codes_of("let s = union(for i in 0..1e9 { sphere() })");
    assert_eq!(c, vec![codes::TOO_LARGE]);
    let c = codes_of("let s = union(for i in 0..1e5, j in 0..1e5 { sphere() })");
    assert_eq!(c, vec![codes::TOO_LARGE]);
    assert!(t.elapsed().as_secs() < 30);
}

#[test]
fn arithmetic_on_vectors_broadcasts() {
    let src = "let v = [1, 2, 3] * 2 + 1\nlet s = sphere(center: v / 10)\n\
               render r { scene: s, camera: look_at([0, 0, 5]), outputs: [image(\"a.png\")] }";
    let p = load(&SourceFile::new("t", src)).unwrap();
    let c = p.renders[0].scene.primitive_center().unwrap();
    assert!((c - glam::DVec3::new(0.3, 0.5, 0.7)).length() < 1e-12);
}

#[test]
fn deep_let_chains_are_refused() {
    let mut src = String::from("let s0 = sphere()\n");
    for i in 1..5000 {
        src.push_str(&format!("let s{i} = s{}.translate([0.001, 0, 0])\n", i - 1));
    }
    let c = codes_of(&src);
    assert!(
        !c.is_empty() && c.iter().all(|c| *c == codes::TOO_LARGE),
        "{c:?}"
    );
}

/// The value of a sphere's radius computed by `expr`.
fn radius_of(expr: &str) -> f64 {
    let src = format!(
        "render r {{ scene: sphere({expr}), camera: look_at(eye: [0, 0, -3]), outputs: [image(\"a.png\")] }}"
    );
    let program =
        load(&SourceFile::new("math.sdfl", src)).unwrap_or_else(|d| panic!("{expr}: {d:?}"));
    match &*program.renders[0].scene {
        sdfl_stdlib::shape::Shape::Sphere { radius, .. } => radius.value,
        other => panic!("{other:?}"),
    }
}

#[test]
fn math_builtins_compute_what_they_say() {
    let cases = [
        ("clamp(3, 0, 1)", 1.0),
        ("clamp(-1, 0.5, 1)", 0.5),
        ("mix(2, 10, 0.25)", 4.0),
        ("fract(2.75)", 0.75),
        ("fract(-0.25)", 0.75),
        ("exp(1)", std::f64::consts::E),
        ("log(exp(2))", 2.0),
        ("length([3, 4, 0])", 5.0),
        ("dot([1, 2, 3], [4, 5, 6])", 32.0),
        ("length(cross([1, 0, 0], [0, 2, 0]))", 2.0),
        ("dot(cross([1, 0, 0], [0, 1, 0]), [0, 0, 1])", 1.0),
        ("length(normalize([3, 0, 4])) * 0.5", 0.5),
    ];
    for (expr, want) in cases {
        let got = radius_of(expr);
        assert!((got - want).abs() < 1e-12, "{expr}: {got}, want {want}");
    }
    for bad in ["log(0)", "clamp(1, 2, 0)", "normalize([0, 0, 0])"] {
        assert!(
            !codes_of(&format!("let x = {bad}")).is_empty(),
            "{bad} is accepted"
        );
    }
}

#[test]
fn smooth_operators_take_any_number_of_shapes() {
    let scene = |expr: &str| {
        let src = format!(
            "render r {{ scene: {expr}, camera: look_at(eye: [0, 0, -3]), outputs: [image(\"a.png\")] }}"
        );
        load(&SourceFile::new("blend.sdfl", src))
            .unwrap_or_else(|d| panic!("{expr}: {d:?}"))
            .renders[0]
            .scene
            .clone()
    };
    let (a, b, c) = (
        "sphere(0.5, center: [-0.6, 0, 0])",
        "sphere(0.4)",
        "box(center: [0.6, 0, 0])",
    );
    for op in ["smooth_union", "smooth_intersection", "smooth_subtraction"] {
        let flat = scene(&format!("{op}({a}, {b}, {c}, k: 0.2)"));
        let nested = scene(&format!("{op}({op}({a}, {b}, k: 0.2), {c}, k: 0.2)"));
        let listed = scene(&format!("{op}([{a}, {b}], {c}, k: 0.2)"));
        assert_eq!(flat, nested, "{op}");
        assert_eq!(flat, listed, "{op}");
    }
    // A positional blend radius is a shape slot: a type error, not a silent k.
    assert_eq!(
        codes_of("let s = smooth_union(sphere(), box(), 0.3)"),
        [codes::TYPE]
    );
}

/// A repetition lowers its child once, but each point evaluates it in every
/// copy within reach: training's work estimate counts those evaluations.
#[test]
fn repeats_count_their_copies_per_point_in_training_work() {
    let load_one = |scene: &str| {
        let src = format!(
            "let cams = [look_at(eye: [0, 0, -3])]\n\
             train t {{ model: sdf_volume({scene}), data: render_views(sdf_volume(sphere()), cameras: cams, size: [4, 4]) }}"
        );
        load(&SourceFile::new("work.sdfl", src)).unwrap_or_else(|e| panic!("{e:?}"))
    };
    let one = load_one("sphere(param(0.2))");
    let rows = load_one("repeat(sphere(param(0.2)), spacing: [1, 0, 1], count: [5, 1, 5])");
    let endless = load_one("repeat(sphere(param(0.2)), spacing: [1, 1, 1])");
    let (a, b, c) = (&one.trains[0], &rows.trains[0], &endless.trains[0]);
    let cost = |t: &sdfl_stdlib::value::TrainJob| t.model.as_sdf().unwrap().shape.evaluation_cost();
    // Copies 0.2 wide, 1 apart: the two nearest per repeated axis.
    assert_eq!(cost(a), 1.0);
    assert_eq!(cost(b), 4.0);
    assert_eq!(cost(c), 8.0);
    assert_eq!(b.model.as_sdf().unwrap().shape.primitive_count(), 1);
    let work = |t| sdfl_stdlib::work::train_work(t, None).evaluations;
    assert!(work(b) > work(a) && work(c) > work(b));
}

/// A trainable spacing must repeat on every axis, and training may not pack
/// the copies closer than half their starting spacing.
#[test]
fn trainable_spacings_are_kept_apart() {
    assert_eq!(
        codes_of("let r = repeat(sphere(0.2), spacing: param([1, 0, 1]))"),
        vec!["sdfl::value::range"]
    );
    let src = "let cams = [look_at(eye: [0, 0, -3])]\n\
               train t { model: sdf_volume(repeat(sphere(0.2), spacing: param([1, 0.8, 1]), count: [3, 1, 3])), data: render_views(sdf_volume(sphere()), cameras: cams, size: [4, 4]) }";
    let p = load(&SourceFile::new("t.sdfl", src)).unwrap_or_else(|e| panic!("{e:?}"));
    let mut bounds = Vec::new();
    p.trains[0]
        .model
        .visit_params(&mut |u| bounds.push(u.bound));
    assert_eq!(bounds, vec![sdfl_stdlib::param::Bound::AtLeast(0.4)]);
}
