//! Hostile data sets, point files and checkpoints, through the real binary:
//! decompression bombs, readers that mistook one thing for another, values
//! outside their ranges, paths that leave the data set, tampered
//! checkpoints. Each ends as a diagnostic (or loads correctly), never an
//! abort, a hang or a silently wrong result.

use std::fs;
use std::path::Path;
use std::process::{Command, Stdio};
use std::time::Instant;

use crate::common::*;

/// Address space the binary may use in the bomb cases: far below what the
/// bombs inflate to (2 GiB and more).
const MEMORY_LIMIT: u64 = 1 << 30;

/// Runs `sdfl` with `args` in `dir` with its address space limited to
/// [`MEMORY_LIMIT`] (through util-linux `prlimit` where it is installed).
fn sdfl_limited(dir: &Path, args: &[&str]) -> Outcome {
    let prlimit = Path::new("/usr/bin/prlimit");
    if !prlimit.exists() {
        eprintln!("note: no prlimit; running without a memory limit");
        return sdfl(dir, args);
    }
    let t0 = Instant::now();
    let out = Command::new(prlimit)
        .arg(format!("--as={MEMORY_LIMIT}"))
        .arg("--")
        .arg(env!("CARGO_BIN_EXE_sdfl"))
        .args(args)
        .current_dir(dir)
        // Address space, not memory, is limited: each thread's stack and
        // each malloc arena (64 MiB reserved apiece, up to 8 a core) count,
        // so the machine's core count would decide the case. Two threads
        // and two arenas, as on the 2-core machine the limit was set on.
        .env("RAYON_NUM_THREADS", "2")
        .env("MALLOC_ARENA_MAX", "2")
        .stdin(Stdio::null())
        .output()
        .expect("prlimit starts");
    Outcome {
        code: out.status.code(),
        stderr: String::from_utf8_lossy(&out.stderr).into_owned(),
        elapsed: t0.elapsed(),
    }
}

/// Whether the rendered diagnostics in `stderr` tell `text`, wherever they
/// wrapped it (lines of 100 columns, continued after a `│`).
fn tells(stderr: &str, text: &str) -> bool {
    let squash = |s: &str| -> String {
        s.chars()
            .filter(|c| !c.is_whitespace() && *c != '│')
            .collect()
    };
    squash(stderr).contains(&squash(text))
}

/// Writes `scene` to `dir/scene.sdfl` and runs it (`run`, output in
/// `dir/out`), memory-limited.
fn run_scene(dir: &Path, scene: &str) -> Outcome {
    let file = dir.join("scene.sdfl");
    fs::write(&file, scene).unwrap();
    let out = dir.join("out");
    sdfl_limited(
        dir,
        &[
            "run",
            file.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ],
    )
}

/// A raw deflate stream of `mib` MiB of zeros in about 1 KiB a MiB: one
/// sync-flushed block of a MiB, repeated, then a final empty block.
fn zeros_deflated(mib: usize) -> Vec<u8> {
    use flate2::{Compress, Compression, FlushCompress};
    let mut block = Vec::with_capacity(1 << 16);
    Compress::new(Compression::best(), false)
        .compress_vec(&vec![0u8; 1 << 20], &mut block, FlushCompress::Sync)
        .unwrap();
    let mut out = block.repeat(mib);
    let mut end = Vec::with_capacity(64);
    Compress::new(Compression::best(), false)
        .compress_vec(&[], &mut end, FlushCompress::Finish)
        .unwrap();
    out.extend(end);
    out
}

/// A 16×16 grey PNG whose iCCP colour profile inflates to 2 GiB, every
/// CRC right.
fn iccp_bomb() -> Vec<u8> {
    let mut png = Vec::new();
    image::RgbImage::from_pixel(16, 16, image::Rgb([128, 128, 128]))
        .write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)
        .unwrap();
    let n: u64 = 1 << 31;
    let mut data = b"bomb\0\0\x78\x9c".to_vec();
    data.extend(zeros_deflated((n >> 20) as usize));
    // Adler-32 of n zeros: a stays 1, b adds 1 per byte.
    data.extend((((n % 65521) << 16) as u32 | 1).to_be_bytes());
    let mut chunk = (data.len() as u32).to_be_bytes().to_vec();
    chunk.extend(b"iCCP");
    chunk.extend(&data);
    chunk.extend(crc32fast::hash(&chunk[4..]).to_be_bytes());
    // After the signature (8 bytes) and IHDR (25).
    png.splice(33..33, chunk);
    png
}

/// A PNG of 2 MB whose colour profile inflates to 2 GiB took 2 GiB and
/// 5.5 s to load, and aborted (exit 134) under a memory limit. Its profile
/// now inflates to at most 16 MiB and is dropped (sdfl applies no colour
/// profiles): the pixels train within 1 GiB of address space.
#[test]
fn a_colour_profile_bomb_loads_in_bounded_memory() {
    let dir = case_dir("data_iccp_bomb");
    let bomb = iccp_bomb();
    assert!(bomb.len() < 3 << 20, "{}", bomb.len());
    fs::write(dir.join("bomb.png"), bomb).unwrap();
    let o = run_scene(
        &dir,
        "train t {\n  model: sdf_volume(sphere(param(0.8))),\n  \
         data: views(images: [\"bomb.png\"], cameras: [look_at([0, 0, -3])]),\n  \
         iterations: 1,\n  size: [16, 16],\n}\n",
    );
    assert_outcome("iCCP bomb", &o, Expect::Ok);
}

/// A zip archive of one deflated entry `name` of `mib` MiB of zeros, with
/// its true size (the CRC is not needed: it is refused before).
fn zip_bomb(name: &str, mib: usize) -> Vec<u8> {
    zip_of(name, &zeros_deflated(mib), (mib as u64) << 20)
}

/// A zip archive of one entry `name` holding the raw deflate stream
/// `data`, declared to inflate to `size` bytes (CRC left 0).
fn zip_of(name: &str, data: &[u8], size: u64) -> Vec<u8> {
    let le32 = |v: u32| v.to_le_bytes();
    let mut fields = vec![20u8, 0, 0, 0, 8, 0, 0, 0, 0, 0];
    fields.extend(le32(0));
    fields.extend(le32(data.len() as u32));
    fields.extend(le32(u32::try_from(size).unwrap()));
    fields.extend((name.len() as u16).to_le_bytes());
    fields.extend([0, 0]);
    let mut z = le32(0x0403_4b50).to_vec();
    z.extend(&fields);
    z.extend(name.as_bytes());
    z.extend(data);
    let cd_at = z.len() as u32;
    z.extend(le32(0x0201_4b50));
    z.extend([20, 0]);
    z.extend(&fields);
    z.extend([0u8; 10]);
    z.extend(le32(0));
    z.extend(name.as_bytes());
    let cd_len = z.len() as u32 - cd_at;
    z.extend(le32(0x0605_4b50));
    z.extend([0, 0, 0, 0, 1, 0, 1, 0]);
    z.extend(le32(cd_len));
    z.extend(le32(cd_at));
    z.extend([0, 0]);
    z
}

/// An `.npz` point cloud whose entry inflates to 3 GiB was refused only
/// after 1.96 GB: now from its declared size, before inflating.
#[test]
fn an_npz_bomb_is_refused_from_its_declared_size() {
    let dir = case_dir("data_npz_bomb");
    fs::write(dir.join("bomb.npz"), zip_bomb("verts.npy", 3 << 10)).unwrap();
    let o = run_scene(
        &dir,
        "train t {\n  model: neural_sdf(layers: 2, width: 8, skips: []),\n  data: points(\"bomb.npz\"),\n  \
         iterations: 1,\n}\n",
    );
    assert_outcome("npz bomb", &o, Expect::Error);
    assert!(
        tells(&o.stderr, "declares 3221225472 bytes"),
        "{}",
        head(&o.stderr)
    );
}

const POSE: &str = "[[1,0,0,0],[0,1,0,0],[0,0,1,3],[0,0,0,1]]";

/// A NeRF-synthetic data set in `dir/set`: one 4×4 image `r_0.png` and
/// `transforms_train.json` with `keys` and frames of `file_paths`; a
/// `set.png` beside the directory. Runs a one-step training on it.
fn run_nerf_synthetic(
    name: &str,
    keys: &str,
    file_paths: &[&str],
) -> (std::path::PathBuf, Outcome) {
    let dir = case_dir(name);
    fs::create_dir_all(dir.join("set")).unwrap();
    let img = image::RgbaImage::from_pixel(4, 4, image::Rgba([200, 100, 50, 255]));
    img.save(dir.join("set/r_0.png")).unwrap();
    img.save(dir.join("set.png")).unwrap();
    img.save(dir.join("outside.png")).unwrap();
    let frames: Vec<String> = file_paths
        .iter()
        .map(|f| format!("{{\"file_path\": \"{f}\", \"transform_matrix\": {POSE}}}"))
        .collect();
    fs::write(
        dir.join("set/transforms_train.json"),
        format!("{{{keys}, \"frames\": [{}]}}", frames.join(", ")),
    )
    .unwrap();
    #[cfg(unix)]
    std::os::unix::fs::symlink("../outside.png", dir.join("set/link.png")).unwrap();
    let o = run_scene(
        &dir,
        "train t {\n  model: sdf_volume(sphere(param(0.8))),\n  data: nerf_synthetic(\"set\"),\n  \
         iterations: 1,\n  size: [4, 4],\n}\n",
    );
    (dir, o)
}

/// Data-set focal lengths skipped the range `look_at(focal: ...)` has:
/// `fl_x: 1e300`, `camera_angle_x: 1e-300` and `fl_x: 1e-300` trained.
#[test]
fn data_set_focal_lengths_are_range_checked() {
    let (_, o) = run_nerf_synthetic("nerf_focal_ok", "\"camera_angle_x\": 0.7", &["./r_0"]);
    assert_outcome("a sound data set", &o, Expect::Ok);
    for (name, keys, key) in [
        (
            "nerf_fl_huge",
            "\"camera_angle_x\": 0.7, \"fl_x\": 1e300",
            "`fl_x`",
        ),
        (
            "nerf_fl_tiny",
            "\"camera_angle_x\": 0.7, \"fl_x\": 1e-300",
            "`fl_x`",
        ),
        (
            "nerf_fl_negative",
            "\"camera_angle_x\": 0.7, \"fl_x\": -5",
            "`fl_x`",
        ),
        (
            "nerf_fl_y_tiny",
            "\"camera_angle_x\": 0.7, \"fl_y\": 1e-300",
            "`fl_y`",
        ),
        (
            "nerf_angle_tiny",
            "\"camera_angle_x\": 1e-300",
            "`camera_angle_x`",
        ),
    ] {
        let (_, o) = run_nerf_synthetic(name, keys, &["./r_0"]);
        assert_outcome(name, &o, Expect::Error);
        assert!(
            tells(&o.stderr, key)
                && tells(&o.stderr, "focal length")
                && tells(&o.stderr, "transforms_train.json"),
            "{name}: {}",
            head(&o.stderr)
        );
    }
}

/// `file_path: "."` named the file beside the data set's directory
/// (`set` + `.png`), which was read. Frame images must be files strictly
/// inside the directory, links followed.
#[test]
fn frame_images_stay_inside_the_data_set() {
    for (name, path, says) in [
        ("nerf_path_dot", ".", "inside the data set"),
        ("nerf_path_dot_slash", "./", "inside the data set"),
        ("nerf_path_dot_dot", "./../set", "inside the data set"),
        ("nerf_path_link", "link", "leads outside the data set"),
    ] {
        let (_, o) = run_nerf_synthetic(name, "\"camera_angle_x\": 0.7", &["r_0", path]);
        assert_outcome(name, &o, Expect::Error);
        assert!(
            tells(&o.stderr, says) && tells(&o.stderr, "frame 1"),
            "{name}: {}",
            head(&o.stderr)
        );
    }
}

/// A checkpoint from a real two-step run, tampered: a NaN radius (taken
/// as "already trained", then kept as "the last good checkpoint"), a
/// radius of −5, a negative Adam second moment (which made the fit its
/// lower bound), a step of 2^62. Each is refused, naming the checkpoint,
/// what is wrong, and `--restart`; the untouched one resumes.
#[test]
fn tampered_checkpoints_are_refused() {
    use sdfl_runtime::train::checkpoint::Checkpoint;
    let dir = case_dir("data_checkpoints");
    let scene = "train t {\n  model: sdf_volume(sphere(param(0.8))),\n  \
         data: render_views(sdf_volume(sphere()), cameras: [look_at([0, 0, -3])], size: [8, 8]),\n  \
         iterations: 2,\n  checkpoint: \"t.ckpt\",\n}\n";
    assert_outcome("first run", &run_scene(&dir, scene), Expect::Ok);
    let path = dir.join("out/t.ckpt");
    let good = Checkpoint::read(&path).unwrap();
    assert_eq!(good.step, 2);
    assert_outcome("resumed run", &run_scene(&dir, scene), Expect::Ok);
    type Tamper = fn(&mut Checkpoint);
    let cases: Vec<(Tamper, &str)> = vec![
        (|c| c.params[0].values[0] = f32::NAN, "is NaN"),
        (|c| c.params[0].values[0] = -5.0, "is -5, outside its range"),
        (
            |c| c.params[0].adam_v[0] = -1.0,
            "(Adam's second moment) is -1",
        ),
        (|c| c.step = 1 << 62, "past this run's 2 steps"),
        (|c| c.losses[1] = f32::INFINITY, "the loss of step 2 is inf"),
    ];
    for (tamper, says) in cases {
        let mut c = good.clone();
        tamper(&mut c);
        c.write(&path).unwrap();
        let bytes = fs::read(&path).unwrap();
        let o = run_scene(&dir, scene);
        assert_outcome(says, &o, Expect::Error);
        assert!(
            tells(&o.stderr, says) && tells(&o.stderr, "t.ckpt") && tells(&o.stderr, "--restart"),
            "{says}: {}",
            head(&o.stderr)
        );
        // Refused, not overwritten.
        assert!(fs::read(&path).unwrap() == bytes, "{says}");
    }
}

/// The diagnostics of loading `scene`, written as `dir/scene.sdfl` (so
/// that it has a directory): each one's code, the text under its span, its
/// message and help.
fn load_errors(dir: &Path, scene: &str) -> Vec<(&'static str, String, String, String)> {
    let file = dir.join("scene.sdfl");
    fs::write(&file, scene).unwrap();
    let src = sdfl_lang::SourceFile::new("scene.sdfl", scene).at(&file);
    match sdfl_stdlib::load(&src) {
        Ok(_) => Vec::new(),
        Err(d) => d
            .diags
            .into_iter()
            .map(|d| {
                let d = d.into_data();
                let under = scene
                    .get(d.span.start..d.span.end)
                    .unwrap_or("")
                    .to_string();
                (d.code, under, d.message, d.help.unwrap_or_default())
            })
            .collect(),
    }
}

/// `check` passed `nerf_synthetic("nowhere/data")`, failing only when run.
/// Inputs the language names (data-set directories and their transforms
/// files, point files, image files) are checked when the file is loaded,
/// relative to its directory, at the argument that names them. A program
/// built in memory, with no directory, is checked when run.
#[test]
fn missing_inputs_are_found_by_check() {
    let dir = case_dir("data_missing_inputs");
    fs::create_dir_all(dir.join("empty")).unwrap();
    fs::create_dir_all(dir.join("set")).unwrap();
    fs::write(dir.join("set/transforms_train.json"), "{}").unwrap();
    fs::write(dir.join("cloud.xyz"), "0 0 1\n").unwrap();
    let train = |data: &str| {
        format!(
            "train t {{ model: sdf_volume(sphere(param(0.8))), iterations: 1, data: {data} }}\n"
        )
    };
    for (data, under, message) in [
        ("nerf_synthetic(\"nowhere/data\")", "\"nowhere/data\"", "not found"),
        ("nerf_synthetic(\"nowhere.json\")", "\"nowhere.json\"", "not found"),
        ("nerf_synthetic(\"cloud.xyz\")", "\"cloud.xyz\"", "not a directory"),
        ("nerf_synthetic(\"empty\")", "\"empty\"", "no transforms_train.json"),
        (
            "nerf_synthetic(\"set\", test_split: \"test\")",
            "\"test\"",
            "no transforms_test.json",
        ),
        (
            "views(images: [\"cloud.xyz\", \"gone.png\"], cameras: [look_at([0, 0, -3]), look_at([0, 0, 3])])",
            "[\"cloud.xyz\", \"gone.png\"]",
            "gone.png` not found",
        ),
    ] {
        let errors = load_errors(&dir, &train(data));
        assert!(
            matches!(&errors[..], [(code, u, m, _)] if *code == "sdfl::io" && u == under && m.contains(message)),
            "{data}: {errors:?}"
        );
    }
    let errors = load_errors(
        &dir,
        "train t { model: neural_sdf(layers: 2, width: 8, skips: []), data: points(\"gone.ply\") }\n",
    );
    assert!(
        matches!(&errors[..], [(_, u, m, _)] if u == "\"gone.ply\"" && m.contains("not found")),
        "{errors:?}"
    );
    // Through the binary: `check` fails.
    let file = dir.join("scene.sdfl");
    fs::write(&file, train("nerf_synthetic(\"nowhere/data\")")).unwrap();
    let o = sdfl(&dir, &["check", file.to_str().unwrap()]);
    assert_outcome("check", &o, Expect::Error);
    // Present inputs load; a program with no file is not checked.
    assert!(load_errors(&dir, &train("nerf_synthetic(\"set\")")).is_empty());
    let src = sdfl_lang::SourceFile::new("memory.sdfl", train("nerf_synthetic(\"nowhere/data\")"));
    assert!(sdfl_stdlib::load(&src).is_ok());
}

/// Without `test_split`, `psnr_curve` and `comparison` of a NeRF-synthetic
/// data set said to hold views out with `render_views(..., test_views:
/// 5)`; the fix there is `test_split: "test"`.
#[test]
fn held_out_help_fits_the_data_set() {
    let dir = case_dir("data_held_out_help");
    fs::create_dir_all(dir.join("set")).unwrap();
    fs::write(dir.join("set/transforms_train.json"), "{}").unwrap();
    // A set without a test split (as `dataset(...)` writes them) is not
    // sent round in a circle to `test_split`.
    let errors = load_errors(
        &dir,
        "train t { model: sdf_volume(sphere(param(0.8))), data: nerf_synthetic(\"set\"), after: [psnr_curve(\"p.png\")] }\n",
    );
    assert!(
        matches!(&errors[..], [(_, _, _, help)] if help.contains("no `transforms_test.json`")),
        "{errors:?}"
    );
    fs::write(dir.join("set/transforms_test.json"), "{}").unwrap();
    for output in ["psnr_curve(\"p.png\")", "comparison(\"c.png\")"] {
        let errors = load_errors(
            &dir,
            &format!("train t {{ model: sdf_volume(sphere(param(0.8))), data: nerf_synthetic(\"set\"), after: [{output}] }}\n"),
        );
        assert!(
            matches!(&errors[..], [(_, _, m, help)] if m.contains("needs held-out views") && help.contains("test_split: \"test\"")),
            "{output}: {errors:?}"
        );
    }
}

/// Errors reading a data set pointed at the `train` statement; they point
/// at the argument that named the files: a NeRF-synthetic data set's
/// path, or the `data` argument.
#[test]
fn data_errors_point_at_the_argument() {
    let dir = case_dir("data_error_span");
    fs::create_dir_all(dir.join("set")).unwrap();
    fs::write(dir.join("set/transforms_train.json"), "{\"frames\": []}").unwrap();
    fs::write(dir.join("cloud.xyz"), "0 0 nan\n").unwrap();
    for (data, under) in [
        ("nerf_synthetic(\"set\")", "──┬──"),
        ("points(\"cloud.xyz\")", "─────────┬─────────"),
    ] {
        let model = if data.starts_with("points") {
            "neural_sdf(layers: 2, width: 8, skips: [])"
        } else {
            "sdf_volume(sphere(param(0.8)))"
        };
        let scene =
            format!("train t {{\n  model: {model},\n  data: {data},\n  iterations: 1,\n}}\n");
        let o = run_scene(&dir, &scene);
        assert_outcome(data, &o, Expect::Error);
        // The underline sits below the argument (line 3), labelled.
        let lines: Vec<&str> = o.stderr.lines().collect();
        let at = lines
            .iter()
            .position(|l| l.contains(&format!("data: {data}")))
            .unwrap_or_else(|| panic!("{data}: {}", head(&o.stderr)));
        let column = |l: &str, s: &str| l.find(s).map(|b| l[..b].chars().count());
        let (code_line, mark) = (lines[at], lines[at + 1]);
        let arg = if data.starts_with("points") {
            data
        } else {
            "\"set\""
        };
        assert_eq!(
            column(mark, under),
            column(code_line, arg),
            "{data}: {}",
            head(&o.stderr)
        );
        assert!(
            tells(&o.stderr, "read while running `t`"),
            "{}",
            head(&o.stderr)
        );
    }
}

/// A valid PNG header declaring `w`×`h`, with no pixels.
fn png_header(w: u32, h: u32) -> Vec<u8> {
    let mut ihdr = b"IHDR".to_vec();
    ihdr.extend(w.to_be_bytes());
    ihdr.extend(h.to_be_bytes());
    ihdr.extend([8, 6, 0, 0, 0]);
    let mut b = b"\x89PNG\r\n\x1a\n".to_vec();
    b.extend(13u32.to_be_bytes());
    b.extend(&ihdr);
    b.extend(crc32fast::hash(&ihdr).to_be_bytes());
    b.extend(0u32.to_be_bytes());
    b.extend(b"IDAT");
    b.extend(crc32fast::hash(b"IDAT").to_be_bytes());
    b
}

/// The decoded-size cap covers a data set's images together, across its
/// training and test splits: each split fits, both do not.
#[test]
fn the_decoded_size_cap_covers_every_split() {
    let dir = case_dir("data_cap_splits");
    fs::create_dir_all(dir.join("set")).unwrap();
    // 8-bit: 576 MB as training holds it; a split of two fits the 2 GB
    // cap, two splits do not.
    fs::write(dir.join("set/big.png"), png_header(12_000, 12_000)).unwrap();
    for split in ["train", "test"] {
        fs::write(
            dir.join(format!("set/transforms_{split}.json")),
            format!("{{\"camera_angle_x\": 0.7, \"frames\": [{{\"file_path\": \"big\", \"transform_matrix\": {POSE}}}, {{\"file_path\": \"big\", \"transform_matrix\": {POSE}}}]}}"),
        )
        .unwrap();
    }
    let scene = |test: &str| {
        format!("train t {{\n  model: sdf_volume(sphere(param(0.8))),\n  data: nerf_synthetic(\"set\"{test}),\n  iterations: 1,\n}}\n")
    };
    let o = run_scene(&dir, &scene(", test_split: \"test\""));
    assert_outcome("two splits", &o, Expect::Error);
    assert!(
        tells(&o.stderr, "(at most 2000000000)"),
        "{}",
        head(&o.stderr)
    );
    // One split alone fits the cap (and then fails to decode: no pixels).
    let o = run_scene(&dir, &scene(""));
    assert_outcome("one split", &o, Expect::Error);
    assert!(!tells(&o.stderr, "at most"), "{}", head(&o.stderr));
}

/// An `.npz` entry that declares its size honestly but holds more points
/// than a cloud may (here 40 million, 480 MB of zeros in half a megabyte)
/// was inflated whole before the point limit applied: it is refused from
/// the array's header, within the memory limit.
#[test]
fn too_many_points_are_refused_from_the_array_header() {
    use flate2::{Compress, Compression, FlushCompress};
    let rows: u64 = 40_000_000;
    let mut header = format!("{{'descr': '<f4', 'fortran_order': False, 'shape': ({rows}, 3), }}");
    while (10 + header.len() + 1) % 64 != 0 {
        header.push(' ');
    }
    header.push('\n');
    let mut npy_head = b"\x93NUMPY\x01\x00".to_vec();
    npy_head.extend((header.len() as u16).to_le_bytes());
    npy_head.extend(header.as_bytes());
    // compress_vec writes only into spare capacity.
    let mut data = Vec::with_capacity(4096);
    Compress::new(Compression::best(), false)
        .compress_vec(&npy_head, &mut data, FlushCompress::Sync)
        .unwrap();
    let zeros = zeros_deflated(((rows * 12) >> 20) as usize);
    data.extend(&zeros);
    let size = npy_head.len() as u64 + (((rows * 12) >> 20) << 20);
    // One zip entry around that stream, its size declared truthfully.
    let z = zip_of("verts.npy", &data, size);
    let dir = case_dir("data_npz_too_many_points");
    fs::write(dir.join("big.npz"), z).unwrap();
    let o = run_scene(
        &dir,
        "train t {\n  model: neural_sdf(layers: 2, width: 8, skips: []),\n  data: points(\"big.npz\"),\n  \
         iterations: 1,\n}\n",
    );
    assert_outcome("npz of too many points", &o, Expect::Error);
    assert!(
        tells(&o.stderr, "more than 30000000"),
        "{}",
        head(&o.stderr)
    );
}

/// A PLY header written with CRLF line endings (as Windows tools write
/// them) was "not a PLY file": no `end_header\n`. ASCII and binary read
/// alike; a binary body starts right after the header's last `\r\n`, so a
/// first coordinate whose bytes start with `\n` is not taken for it.
#[test]
fn ply_headers_with_crlf_line_endings_are_read() {
    use sdfl_runtime::data::points::read_points;
    let dir = case_dir("data_ply_crlf");
    let want = vec![
        [f32::from_le_bytes([b'\n', 0, 0, 64]), -1.0, 2.0],
        [3.25, 0.0, -0.125],
    ];
    let header = |format: &str| {
        format!("ply\r\nformat {format} 1.0\r\ncomment made on Windows\r\nelement vertex 2\r\nproperty float x\r\nproperty float y\r\nproperty float z\r\nend_header\r\n")
    };
    let mut ascii = header("ascii");
    for p in &want {
        ascii.push_str(&format!("{} {} {}\r\n", p[0], p[1], p[2]));
    }
    let mut binary = header("binary_little_endian").into_bytes();
    for p in &want {
        binary.extend(p.iter().flat_map(|x| x.to_le_bytes()));
    }
    for (name, bytes) in [("a.ply", ascii.into_bytes()), ("b.ply", binary)] {
        let path = dir.join(name);
        fs::write(&path, bytes).unwrap();
        assert_eq!(
            read_points(&path).map_err(|e| e.to_string()),
            Ok(want.clone()),
            "{name}"
        );
    }
    // Through the binary: a CRLF cloud trains.
    let o = run_scene(
        &dir,
        "train t {\n  model: neural_sdf(layers: 2, width: 8, skips: []),\n  data: points(\"b.ply\"),\n  iterations: 1,\n}\n",
    );
    assert_outcome("CRLF PLY", &o, Expect::Ok);
}
