use glam::DVec3;
use sdfl_stdlib::camera_path::*;

fn path(frames: &str) -> String {
    format!(
        r#"{{"camera_type": "perspective", "render_width": 64, "render_height": 48, "fps": 24, "seconds": 1,
            "camera_path": [{frames}]}}"#
    )
}

const AT_Z3: &str =
    r#"{"camera_to_world": [1,0,0,0, 0,1,0,0, 0,0,1,3, 0,0,0,1], "fov": 50, "aspect": 1.333}"#;

#[test]
fn a_path_reads_back_its_poses_and_field_of_view() {
    // Second camera: at x = 3 looking down −x (turned 90° about y).
    let turned = r#"{"camera_to_world": [0,0,1,3, 0,1,0,0, -1,0,0,0, 0,0,0,1], "fov": 50}"#;
    let p = parse_camera_path(path(&format!("{AT_Z3}, {turned}")).as_bytes()).unwrap();
    assert_eq!((p.width, p.height, p.fps), (64, 48, 24.0));
    assert_eq!(p.cameras.len(), 2);
    let c = p.cameras[0];
    assert!((c.eye - DVec3::new(0.0, 0.0, 3.0)).length() < 1e-12);
    // Looks down −z with +y up: the centre ray goes to the origin.
    let d = c.pixel_direction(31.5, 23.5, 64, 48);
    assert!((d - DVec3::new(0.0, 0.0, -1.0)).length() < 1e-9, "{d}");
    // The top row is 25° above the axis (fov 50, vertical).
    let top = c.pixel_direction(31.5, -0.5, 64, 48);
    assert!(
        (top.y.atan2(-top.z).to_degrees() - 25.0).abs() < 1e-6,
        "{top}"
    );
    let d = p.cameras[1].pixel_direction(31.5, 23.5, 64, 48);
    assert!((d - DVec3::new(-1.0, 0.0, 0.0)).length() < 1e-9, "{d}");
}

#[test]
fn hostile_paths_are_refused_with_the_frame_named() {
    let cases: Vec<(String, &str)> = vec![
        ("[1, 2]".into(), "not a JSON object"),
        ("{".into(), "not JSON"),
        (
            r#"{"render_height": 4, "camera_path": []}"#.into(),
            "`render_width` is missing",
        ),
        (path("").replace("64", "0"), "`render_width` is 0"),
        (path("").replace("64", "100000"), "`render_width` is 100000"),
        (path("").replace("48", "4.5"), "`render_height` is 4.5"),
        (path(""), "no cameras"),
        (
            path(AT_Z3).replace("perspective", "fisheye"),
            "only \"perspective\"",
        ),
        (
            path(AT_Z3).replace("\"fps\": 24", "\"fps\": -1"),
            "`fps` is -1",
        ),
        (
            path(AT_Z3).replace("\"seconds\": 1", "\"seconds\": \"x\""),
            "`seconds`",
        ),
        (
            path(&format!("{AT_Z3}, {}", AT_Z3.replace("0,0,0,1]", "0,0,1]"))),
            "camera_path[1]: `camera_to_world` has 15 numbers",
        ),
        (
            path(&AT_Z3.replace("\"fov\": 50", "\"fov\": 0")),
            "camera_path[0]: `fov` is 0",
        ),
        (
            path(&AT_Z3.replace("\"fov\": 50", "\"fov\": 180")),
            "`fov` is 180",
        ),
        (
            path(&AT_Z3.replace("\"fov\": 50", "\"fov\": null")),
            "`fov` is null",
        ),
        (
            path(&AT_Z3.replace(", \"fov\": 50", "")),
            "`fov` is missing",
        ),
        (path(&AT_Z3.replace("1.333", "-1")), "`aspect` is -1"),
        (
            path(&AT_Z3.replace("[1,0,0,0,", "[2,0,0,0,")),
            "not orthonormal",
        ),
        (
            path(&AT_Z3.replace("[1,0,0,0,", "[-1,0,0,0,")),
            "reflection",
        ),
        (
            path(&AT_Z3.replace("[1,0,0,0,", "[\"1\",0,0,0,")),
            "`camera_to_world[0]` is \"1\"",
        ),
        (path(&AT_Z3.replace("0,0,0,1]", "0,0,0,2]")), "last row"),
        (
            path(&AT_Z3.replace("0,0,1,3,", "0,0,1,1e300,")),
            "out of range",
        ),
        (
            path(&AT_Z3.replace("[1,0,0,0,", "[1e999,0,0,0,")),
            "not JSON",
        ),
        (
            format!("{}1{}", "[".repeat(100_000), "]".repeat(100_000)),
            "not JSON",
        ),
    ];
    for (src, says) in cases {
        let e = parse_camera_path(src.as_bytes()).unwrap_err();
        assert!(e.contains(says), "{says:?} not in {e:?}");
    }
    let many = vec![AT_Z3; MAX_CAMERAS + 1].join(",");
    let e = parse_camera_path(path(&many).as_bytes()).unwrap_err();
    assert!(e.contains("at most"), "{e}");
}

#[test]
fn files_are_capped_and_regular() {
    let dir = std::env::temp_dir().join(format!("sdfl-camera-path-{}", std::process::id()));
    let _ = std::fs::create_dir_all(&dir);
    let f = dir.join("camera_path.json");
    std::fs::write(&f, path(AT_Z3)).unwrap();
    assert_eq!(read_camera_path(&f).unwrap().cameras.len(), 1);
    assert!(read_camera_path(&dir).is_err(), "a directory is no file");
    let big = dir.join("big.json");
    let file = std::fs::File::create(&big).unwrap();
    file.set_len(MAX_BYTES + 1).unwrap();
    let e = read_camera_path(&big).unwrap_err().to_string();
    assert!(e.contains("larger than"), "{e}");
    let _ = std::fs::remove_dir_all(&dir);
}
