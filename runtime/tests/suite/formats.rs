//! The registry of data formats: every format `capture(format: ...)` names
//! has one parser, `"auto"` looks for every capture format's files, and
//! every format refuses what is not its data set (without panicking).

use std::path::Path;

use sdfl_runtime::data::capture;
use sdfl_runtime::data::format::{Format, Normalize, Request, Split};
use sdfl_runtime::data::formats::FORMATS;
use sdfl_runtime::data::DataNeeds;
use sdfl_stdlib::value::{CaptureFormat, CaptureSpec, ObjectMasks};

/// What a statement would ask of `format` at `path`: its default split.
fn request(format: &dyn Format, path: &Path) -> Request {
    Request {
        path: path.to_path_buf(),
        downscale: 1,
        split: match format.capture_format() {
            Some(_) => Split::Every(8),
            None => Split::Files {
                train: "train".into(),
                test: Some("test".into()),
            },
        },
        normalize: Normalize::NONE,
        background: glam::DVec3::ONE,
        object_masks: ObjectMasks::Coverage,
        needs: DataNeeds::default(),
    }
}

#[test]
fn every_capture_format_has_one_parser_of_its_name() {
    for (name, format) in CaptureFormat::NAMES {
        let parsers: Vec<&str> = FORMATS
            .iter()
            .filter(|f| f.capture_format() == Some(format))
            .map(|f| f.name())
            .collect();
        let want: &[&str] = if format == CaptureFormat::Auto {
            &[]
        } else {
            &[name]
        };
        assert_eq!(parsers, want, "{name}");
    }
    let mut names: Vec<&str> = FORMATS.iter().map(|f| f.name()).collect();
    names.sort();
    names.dedup();
    assert_eq!(names.len(), FORMATS.len(), "{names:?}");
}

#[test]
fn auto_names_every_capture_format_it_looks_for() {
    let dir = tempfile::tempdir().unwrap();
    assert_eq!(capture::detect(dir.path()), None);
    let e = capture::read(&CaptureSpec::at(dir.path()), Path::new("/"))
        .unwrap_err()
        .to_string();
    for f in FORMATS.iter().filter(|f| f.capture_format().is_some()) {
        assert!(e.contains(f.marker()), "{}: {e}", f.name());
    }
}

#[test]
fn every_format_refuses_a_directory_without_its_files() {
    let dir = tempfile::tempdir().unwrap();
    let empty = dir.path().join("empty");
    std::fs::create_dir(&empty).unwrap();
    // A file of the wrong kind where each format looks for its own.
    let garbage = dir.path().join("garbage");
    std::fs::create_dir_all(garbage.join("sparse/0")).unwrap();
    for f in [
        "transforms.json",
        "transforms_train.json",
        "poses_bounds.npy",
        "cameras_sphere.npz",
        "sparse/0/cameras.txt",
        "sparse/0/images.txt",
    ] {
        std::fs::write(garbage.join(f), b"\x00not a data set").unwrap();
    }
    for format in FORMATS {
        assert!(!format.detect(&empty), "{}", format.name());
        for path in [&empty, &garbage] {
            let r = request(*format, path);
            let e = format.plan(&r).unwrap_err().to_string();
            assert!(!e.is_empty(), "{}", format.name());
            let e = format.read(&r).unwrap_err().to_string();
            assert!(
                e.contains(&*dir.path().to_string_lossy()),
                "{}: {e}",
                format.name()
            );
        }
    }
}
