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
        let rest = match &b.sig.rest {
            Some(r) if r.ty == sdfl_lang::types::Type::Number => "1, ",
            Some(_) => "sphere(), ",
            None => "",
        };
        // `sdf` takes a `fn` defined in the file.
        let (prelude, args) = if b.sig.name == "sdf" {
            (
                "fn f(p) { length(p) - 1 }\n",
                vec!["f".to_string(), "bound: 1".to_string()],
            )
        } else {
            ("", args)
        };
        let src = format!("{prelude}let x = {}({rest}{})", b.sig.name, args.join(", "));
        let r = load(&SourceFile::new("t", src.clone()));
        // Outputs need a .gif name etc.; only defaults matter here, so any
        // failure must be a value error of the placeholder arguments.
        // `camera_path` reads its file when evaluated: the placeholder
        // names none, an input error.
        let reads = b.sig.name == "camera_path";
        if let Err(d) = r {
            assert!(
                d.diags
                    .iter()
                    .all(|d| d.code == codes::VALUE || (reads && d.code == codes::IO)),
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
    // Three in the lets, and the render's `near`/`far` and `size` (its
    // poisoned camera does not stop its other fields being checked).
    assert_eq!(c.iter().filter(|c| **c == codes::VALUE).count(), 5, "{c:?}");
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
    assert!(t.elapsed().as_secs() < 60);
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
        sdfl_stdlib::shape::Shape::Prim(sdfl_stdlib::shape::Primitive::Sphere(
            sdfl_stdlib::shape::Sphere { radius, .. },
        )) => radius.value,
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

/// The number `expr` evaluates to (as a sphere's radius).
fn number(expr: &str) -> f64 {
    radius_of(expr)
}

#[test]
fn conditions_pick_one_branch() {
    let cases = [
        ("if 1 < 2 { 1 } else { 2 }", 1.0),
        ("if 1 > 2 { 1 } else if 2 >= 2 { 3 } else { 2 }", 3.0),
        ("if 1 == 2 || 2 != 3 && !false { 4 } else { 5 }", 4.0),
        // `&&` binds tighter than `||`; comparisons below `+`.
        ("if true || false && false { 1 } else { 2 }", 1.0),
        ("if 1 + 1 == 2 { 6 } else { 7 }", 6.0),
        (
            "if [1, 2, 3] == [1, 2, 3] && \"a\" != \"b\" { 1 } else { 2 }",
            1.0,
        ),
        ("if 1 <= 1 { let k = 2; k * 4 } else { 0 }", 8.0),
    ];
    for (expr, want) in cases {
        assert_eq!(number(expr), want, "{expr}");
    }
    // The branch not taken is not evaluated: its division by zero is no error.
    assert_eq!(number("if true { 1 } else { 1 / 0 }"), 1.0);
    assert_eq!(number("if false && 1 / 0 > 0 { 2 } else { 3 }"), 3.0);
    // Conditions are bools: a number is a type error, found by the checker
    // or, for values it cannot know, by the evaluator.
    assert_eq!(codes_of("let a = if 1 { 1 } else { 2 }"), [codes::TYPE]);
    assert_eq!(codes_of("let a = !3"), [codes::TYPE]);
    assert_eq!(codes_of("let a = sphere() < 1"), [codes::TYPE]);
    assert_eq!(
        codes_of("fn f(c) { if c { 1 } else { 2 } }\nlet a = f(1)"),
        [codes::TYPE]
    );
    assert_eq!(
        codes_of("fn f(a, b) { a == b }\nlet x = f(sphere(), 1)"),
        [codes::TYPE]
    );
}

#[test]
fn functions_bind_arguments_like_builtins() {
    let f = "fn f(a, b: 2, c: [0, 0, 1]) { let s = a * b; s + c.z }\n";
    let at = |call: &str| {
        let src = format!(
            "{f}render r {{ scene: sphere({call}), camera: look_at(eye: [0, 0, -3]), outputs: [image(\"a.png\")] }}"
        );
        let p = load(&SourceFile::new("f.sdfl", src)).unwrap_or_else(|d| panic!("{call}: {d:?}"));
        match &*p.renders[0].scene {
            sdfl_stdlib::shape::Shape::Prim(sdfl_stdlib::shape::Primitive::Sphere(
                sdfl_stdlib::shape::Sphere { radius, .. },
            )) => radius.value,
            other => panic!("{other:?}"),
        }
    };
    assert_eq!(at("f(1)"), 3.0);
    assert_eq!(at("f(1, 3)"), 4.0);
    assert_eq!(at("f(b: 1, a: 2)"), 3.0);
    assert_eq!(at("f(1, c: [0, 0, 0.5])"), 2.5);
    assert_eq!(at("(1).f(4)"), 5.0);
    // Parameters are the function's own: a loop variable of the caller
    // with the name of a global is not seen inside.
    let src = "let k = 1\nfn g(x) { x + k }\nlet v = for k in [10] { g(0) }\n\
               render r { scene: sphere(v[0]), camera: look_at([0, 0, 5]), outputs: [image(\"a.png\")] }";
    let p = load(&SourceFile::new("t", src)).unwrap();
    assert!(
        matches!(&*p.renders[0].scene, sdfl_stdlib::shape::Shape::Prim(sdfl_stdlib::shape::Primitive::Sphere(sdfl_stdlib::shape::Sphere { radius, .. })) if radius.value == 1.0)
    );
    // A call's cost is bounded: so is a `fn`'s parameter count.
    let params: Vec<String> = (0..=sdfl_lang::check::MAX_FN_PARAMS)
        .map(|i| format!("p{i}: 1"))
        .collect();
    assert_eq!(
        codes_of(&format!("fn f({}) {{ 1 }}", params.join(", "))),
        [codes::TOO_LARGE]
    );
    for (src, code) in [
        ("fn f(a) { a }\nlet x = f()", codes::MISSING_ARG),
        ("fn f(a) { a }\nlet x = f(1, 2)", codes::TOO_MANY_ARGS),
        ("fn f(a) { a }\nlet x = f(1, b: 1)", codes::UNKNOWN_ARG),
        ("fn f(a) { a }\nlet x = f(1, a: 1)", codes::DUPLICATE_ARG),
        (
            "fn f(a, b: 1) { a }\nlet x = f(1, b: 1, 2)",
            codes::POSITIONAL_AFTER_NAMED,
        ),
        ("fn f(a, a) { a }", codes::DUPLICATE_NAME),
        ("fn f(a) { a }\nfn f(b) { b }", codes::DUPLICATE_NAME),
        ("fn sphere(a) { a }", codes::SHADOWS_BUILTIN),
        ("fn f(a) { f(a) }", codes::FN_ORDER),
        ("fn f(a) { g(a) }\nfn g(a) { f(a) }", codes::FN_ORDER),
        ("let x = f(1)\nfn f(a) { a }", codes::FN_ORDER),
        ("fn f(a) { a + later }\nlet later = 1", codes::UNKNOWN_NAME),
    ] {
        assert_eq!(codes_of(src), [code], "{src}");
    }
}

#[test]
fn functions_stay_inside_the_work_budget() {
    let t = std::time::Instant::now();
    // Each level calls the one before twice: 2^40 calls if unbounded.
    let mut src = String::from("fn f0(s) { union(s, s.translate([0.1, 0, 0])) }\n");
    for i in 1..40 {
        src.push_str(&format!("fn f{i}(s) {{ f{0}(f{0}(s)) }}\n", i - 1));
    }
    src.push_str("let a = f39(sphere())\n");
    let c = codes_of(&src);
    assert!(
        !c.is_empty() && c.iter().all(|c| *c == codes::TOO_LARGE),
        "{c:?}"
    );
    // A doubling function called in nested loops.
    let src = "fn dbl(s) { union(s, s.translate([0.1, 0, 0])) }\n\
               let a = for i in 0..1000, j in 0..1000 { dbl(dbl(sphere())) }";
    let c = codes_of(src);
    assert!(
        !c.is_empty() && c.iter().all(|c| *c == codes::TOO_LARGE),
        "{c:?}"
    );
    assert!(t.elapsed().as_secs() < 60, "{:?}", t.elapsed());
}

#[test]
fn lists_are_indexed_from_zero() {
    assert_eq!(number("[4, 5, 6][1]"), 5.0);
    assert_eq!(number("[[1, 2], [3, 7]][1][1]"), 7.0);
    assert_eq!(
        number("[1, 2, 3].y + len([1, 2]) + len(for i in 0..4 { i })"),
        8.0
    );
    assert_eq!(number("(for i in 0..5 { i * i })[4]"), 16.0);
    for bad in ["[1, 2][2]", "[1, 2][-1]", "[1, 2][0.5]"] {
        assert_eq!(codes_of(&format!("let x = {bad}")), [codes::INDEX], "{bad}");
    }
    assert_eq!(codes_of("let x = [1, 2][\"a\"]"), [codes::TYPE]);
    assert_eq!(codes_of("let x = sphere()[0]"), [codes::TYPE]);
    assert_eq!(codes_of("let x = len(1)"), [codes::TYPE]);
}

#[test]
fn more_math_builtins() {
    let cases = [
        ("min(3, 1, 2)", 1.0),
        ("max(3, 1, 2)", 3.0),
        ("min([4, 5], 6)", 4.0),
        ("max(7)", 7.0),
        ("mix([0, 0, 0], [2, 4, 8], 0.5).z", 4.0),
        ("mix(1, [3, 3, 3], 0.5).x", 2.0),
    ];
    for (expr, want) in cases {
        assert_eq!(number(expr), want, "{expr}");
    }
    // Deterministic, in [0, 1), and different for different inputs.
    let r = number("random(seed: 7) + 1");
    assert!((1.0..2.0).contains(&r));
    assert_eq!(r, number("random(7, 0) + 1"));
    let xs: Vec<f64> = (0..50)
        .map(|i| sdfl_stdlib::builtins::random(1.0, i as f64))
        .collect();
    assert!(xs.iter().all(|x| (0.0..1.0).contains(x)));
    assert!(xs.windows(2).all(|w| w[0] != w[1]));
    let mean = xs.iter().sum::<f64>() / 50.0;
    assert!((0.3..0.7).contains(&mean), "{mean}");
    assert_eq!(codes_of("let x = min()"), [codes::VALUE]);
    assert_eq!(codes_of("let x = min(sphere())"), [codes::TYPE]);
    assert_eq!(codes_of("let x = normalize([0, 0, 0])"), [codes::VALUE]);
}

#[test]
fn statements_are_kept_in_file_order() {
    use sdfl_stdlib::value::Statement;
    let block = |name: &str, scene: &str| {
        format!("render {name} {{ scene: {scene}, camera: look_at([0, 0, 3]), outputs: [image(\"{name}.png\")] }}\n")
    };
    let src = [
        block("a", "sphere()"),
        block("v", "sdf_volume(sphere())"),
        block("b", "box()"),
    ]
    .concat();
    let p = load(&SourceFile::new("order.sdfl", src)).unwrap();
    assert_eq!(
        p.order,
        [
            Statement::Render(0),
            Statement::Volume(0),
            Statement::Render(1)
        ]
    );
}

#[test]
fn indexing_is_cheap_and_comparing_lists_is_budgeted() {
    let t = std::time::Instant::now();
    // Indexing a long list costs one unit, not its length.
    let src =
        "let xs = for i in 0..400000 { i }\nlet ys = for i in 0..400000 { xs[i] }\nlet n = len(ys)";
    assert_eq!(codes_of(src), Vec::<&str>::new());
    // Comparing lists walks them: 1e5 comparisons of 4e5 items is refused.
    let src = "let xs = for i in 0..400000 { i }\nlet ys = for i in 0..100000 { xs == xs }";
    assert_eq!(codes_of(src), [codes::TOO_LARGE]);
    assert!(t.elapsed().as_secs() < 60, "{:?}", t.elapsed());
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

#[test]
fn one_mlp_value_shapes_every_network_it_is_given_to() {
    use sdfl_stdlib::value::Field;
    let src = r#"
let net = mlp(layers: 3, width: 24, skips: [2])
let cams = orbit(views: 4)
let truth = volsdf(sphere(0.5))
train by_value {
  model: nerf(network: net),
  data: render_views(truth, cameras: cams, size: [8, 8]),
}
train by_arguments {
  model: nerf(layers: 3, width: 24, skips: [2]),
  data: render_views(truth, cameras: cams, size: [8, 8]),
}
train surface {
  model: volsdf(neural_sdf(network: net)),
  data: render_views(truth, cameras: cams, size: [8, 8]),
}
"#;
    let p = load(&SourceFile::new("mlp.sdfl", src)).unwrap();
    let (Field::Nerf(a), Field::Nerf(b)) = (&*p.trains[0].model, &*p.trains[1].model) else {
        panic!("two NeRFs")
    };
    assert_eq!((a.layers, a.width, &a.skips), (3, 24, &vec![2]));
    assert_eq!(a, b);
    let Field::NeuralSurface(s) = &*p.trains[2].model else {
        panic!("a neural surface")
    };
    assert_eq!((s.sdf.layers, s.sdf.width, &s.sdf.skips), (3, 24, &vec![2]));
}

/// `cone` by the side's `angle` (the declared primitive) or by the base's
/// `radius` (a capped cone), never both; positional arguments keep the
/// radius form's order.
#[test]
fn cone_by_angle_or_by_radius() {
    let scene = |call: &str| {
        let src = format!(
            "render r {{ scene: {call}, camera: look_at([0, 0, -3]), outputs: [image(\"a.png\")] }}"
        );
        load(&SourceFile::new("t", src)).map(|p| p.renders[0].scene.name())
    };
    assert_eq!(scene("cone(angle: 30deg, height: 1)").unwrap(), "cone");
    assert_eq!(
        scene("cone(radius: 0.5, height: 1)").unwrap(),
        "capped_cone"
    );
    assert_eq!(scene("cone(0.5, 1)").unwrap(), "capped_cone");
    assert_eq!(scene("cone()").unwrap(), "capped_cone");
    assert_eq!(
        codes_of("let c = cone(radius: 0.5, angle: 0.3)"),
        [codes::VALUE]
    );
    assert_eq!(codes_of("let c = cone(angle: 2)"), [codes::VALUE]);
    assert_eq!(codes_of("let c = capped_torus(angle: -1)"), [codes::VALUE]);
}
