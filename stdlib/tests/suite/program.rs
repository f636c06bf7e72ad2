use sdfl_stdlib::value::StatementKind;
#[test]
fn statement_kinds_round_trip_and_read_their_keyword() {
    use StatementKind::*;
    for k in [Render, Volume, Train] {
        assert_eq!(k.at(3).kind(), k);
    }
    assert_eq!(StatementKind::of("train", true), Train);
    assert_eq!(StatementKind::of("render", true), Volume);
    assert_eq!(StatementKind::of("render", false), Render);
    let names = [Render, Volume, Train].map(|k| serde_json::to_string(&k).unwrap());
    assert_eq!(names, ["\"render\"", "\"volume\"", "\"train\""]);
}
