use sdfl_lang::types::*;

#[test]
fn acceptance() {
    assert!(Type::Vec3.accepts(&Type::list(Type::Number)));
    assert!(!Type::Vec3.accepts(&Type::Named("shape")));
    assert!(Type::Named("shape").accepts(&Type::Any));
    let cam = Type::OneOf(vec![
        Type::Named("camera"),
        Type::list(Type::Named("camera")),
    ]);
    assert!(cam.accepts(&Type::list(Type::Named("camera"))));
    assert!(!cam.accepts(&Type::Number));
}

#[test]
fn articles() {
    assert_eq!(Type::Number.with_article(), "a number");
    assert_eq!(Type::Named("output").with_article(), "an output");
    assert_eq!(Type::Any.with_article(), "any value");
}
