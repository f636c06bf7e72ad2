//! `.npy` and `.npz` files: round trips, hostile headers and bombs refused,
//! arrays read by name, the assignment's bunny when present.

use sdfl_runtime::data::npy::*;

fn sample() -> RgbImage {
    RgbImage {
        width: 3,
        height: 2,
        pixels: (0..6).map(|k| [k as f32, 0.5, -1.25 * k as f32]).collect(),
    }
}

#[test]
fn round_trip() {
    let img = sample();
    let bytes = encode_rgb_f32(&img);
    assert_eq!(bytes.len() % 4, 0);
    assert_eq!(parse_rgb_f32(&bytes).unwrap(), img);
}

fn with_header(h: &str, data_len: usize) -> Vec<u8> {
    let mut b = MAGIC.to_vec();
    b.extend_from_slice(&[1, 0]);
    b.extend_from_slice(&(h.len() as u16).to_le_bytes());
    b.extend_from_slice(h.as_bytes());
    b.extend(std::iter::repeat_n(0u8, data_len));
    b
}

#[test]
fn rejects_everything_else() {
    let bad = [
        with_header(
            "{'descr': '>f4', 'fortran_order': False, 'shape': (2, 3, 3), }",
            72,
        ),
        with_header(
            "{'descr': '<f8', 'fortran_order': False, 'shape': (2, 3, 3), }",
            144,
        ),
        with_header(
            "{'descr': '<f4', 'fortran_order': True, 'shape': (2, 3, 3), }",
            72,
        ),
        with_header(
            "{'descr': '<f4', 'fortran_order': False, 'shape': (2, 3), }",
            24,
        ),
        with_header(
            "{'descr': '<f4', 'fortran_order': False, 'shape': (2, 3, 4), }",
            96,
        ),
        with_header(
            "{'descr': '<f4', 'fortran_order': False, 'shape': (2, 3, 3), }",
            71,
        ),
        with_header(
            "{'descr': '<f4', 'fortran_order': False, 'shape': (2, x, 3), }",
            72,
        ),
        with_header(
            "{'descr': '<f4', 'fortran_order': False, 'shape': (0, 3, 3), }",
            0,
        ),
        with_header("{'descr': '<f4', 'shape': (2, 3, 3), }", 72),
        with_header(
            "{'descr': '<f4', 'fortran_order': False, 'shape': (99999999999, 99999999999, 3), }",
            0,
        ),
        b"NUMPY".to_vec(),
        Vec::new(),
    ];
    for b in &bad {
        assert!(parse_rgb_f32(b).is_err());
    }
    let mut v2 = encode_rgb_f32(&sample());
    v2[6] = 2;
    assert!(matches!(parse_rgb_f32(&v2), Err(NpyError::Unsupported(_))));
    let mut trunc = encode_rgb_f32(&sample());
    trunc.truncate(20);
    assert!(parse_rgb_f32(&trunc).is_err());
    assert!(matches!(
        read_rgb_f32("/nonexistent/x.npy"),
        Err(NpyError::Io(_))
    ));
}

#[test]
fn header_keys_are_never_read_from_inside_strings() {
    // The old scan found `'descr':` inside the string value first and
    // read 8-byte floats as float32.
    let h = "{'note': \"'descr': '<f4', \", 'descr': '<f8', 'fortran_order': False, 'shape': (2, 3, 3), }";
    assert!(matches!(
        parse_rgb_f32(&with_header(h, 144)),
        Err(NpyError::Unsupported(_))
    ));
    // Keys twice, text after the dict, and unterminated strings are malformed.
    for h in [
        "{'descr': '<f4', 'descr': '<f4', 'fortran_order': False, 'shape': (2, 3, 3), }",
        "{'descr': '<f4', 'fortran_order': False, 'shape': (2, 3, 3), } x",
        "{'descr': '<f4, 'fortran_order': False, 'shape': (2, 3, 3), }",
        "{'descr': '<f4', 'fortran_order': 'False', 'shape': (2, 3, 3), }",
    ] {
        assert!(
            matches!(parse_rgb_f32(&with_header(h, 72)), Err(NpyError::Format(_))),
            "{h}"
        );
    }
    // Other spacing and a one-element tuple are fine.
    let h = "{ \"descr\":'<f4','fortran_order':False,'shape':(6,) }";
    assert_eq!(parse_f32(&with_header(h, 24)).unwrap().shape, vec![6]);
}

#[test]
fn declared_sizes_are_capped_before_reading() {
    let h = "{'descr': '<f4', 'fortran_order': False, 'shape': (100000, 100000, 3), }";
    let e = parse_rgb_f32(&with_header(h, 0)).unwrap_err().to_string();
    assert!(e.contains("more than"), "{e}");
}

fn npz(entries: &[(&str, &[u8])], method: zip::CompressionMethod) -> Vec<u8> {
    use std::io::Write;
    let mut w = zip::ZipWriter::new(std::io::Cursor::new(Vec::new()));
    let opts = zip::write::SimpleFileOptions::default().compression_method(method);
    for (name, data) in entries {
        w.start_file(*name, opts).unwrap();
        w.write_all(data).unwrap();
    }
    w.finish().unwrap().into_inner()
}

#[test]
fn npz_stored_and_deflated() {
    let img = encode_rgb_f32(&sample());
    for m in [
        zip::CompressionMethod::Stored,
        zip::CompressionMethod::Deflated,
    ] {
        let z = npz(&[("other.npy", b"junk"), ("verts.npy", &img)], m);
        let a = parse_npz_f32(&z, "verts").unwrap();
        assert_eq!(a.shape, vec![2, 3, 3]);
        assert_eq!(a.data[3], 1.0);
        assert!(matches!(
            parse_npz_f32(&z, "nope"),
            Err(NpyError::MissingKey(_))
        ));
        assert!(parse_npz_f32(&z, "other").is_err());
    }
    assert!(parse_npz_f32(b"not a zip", "verts").is_err());
}

/// A raw deflate stream of `n` MiB of zeros, about 1 KiB a MiB: one
/// sync-flushed block repeated (each copy inflates to the same MiB).
pub(crate) fn zeros_deflated(mib: usize) -> Vec<u8> {
    use flate2::{Compress, Compression, FlushCompress};
    let mut c = Compress::new(Compression::best(), false);
    let mut block = Vec::with_capacity(1 << 16);
    c.compress_vec(&vec![0u8; 1 << 20], &mut block, FlushCompress::Sync)
        .unwrap();
    let mut out = block.repeat(mib);
    // A final empty block.
    let mut end = Vec::with_capacity(64);
    let mut c = Compress::new(Compression::best(), false);
    c.compress_vec(&[], &mut end, FlushCompress::Finish)
        .unwrap();
    out.extend(end);
    out
}

/// A zip archive of one deflated entry `name`, `mib` MiB of zeros
/// declared with their true size and CRC.
fn zip_bomb(name: &str, mib: usize) -> Vec<u8> {
    let data = zeros_deflated(mib);
    let mut crc = crc32fast::Hasher::new();
    crc.update(&vec![0u8; 1 << 20]);
    let one = crc.clone();
    for _ in 1..mib {
        crc.combine(&one);
    }
    let crc = crc.finalize();
    let size = u32::try_from(mib << 20).unwrap();
    let le32 = |v: u32| v.to_le_bytes();
    let mut fields = Vec::new();
    fields.extend([20u8, 0, 0, 0, 8, 0, 0, 0, 0, 0]); // version, flags, deflate, time, date
    fields.extend(le32(crc));
    fields.extend(le32(data.len() as u32));
    fields.extend(le32(size));
    fields.extend((name.len() as u16).to_le_bytes());
    fields.extend([0, 0]); // no extra field
    let mut z = le32(0x0403_4b50).to_vec();
    z.extend(&fields);
    z.extend(name.as_bytes());
    z.extend(&data);
    let cd_at = z.len() as u32;
    z.extend(le32(0x0201_4b50));
    z.extend([20, 0]); // made by
    z.extend(&fields);
    z.extend([0u8; 10]); // comment, disk, attributes
    z.extend(le32(0)); // the local header's offset
    z.extend(name.as_bytes());
    let cd_len = z.len() as u32 - cd_at;
    z.extend(le32(0x0605_4b50));
    z.extend([0, 0, 0, 0, 1, 0, 1, 0]);
    z.extend(le32(cd_len));
    z.extend(le32(cd_at));
    z.extend([0, 0]);
    z
}

#[test]
fn npz_bombs_are_refused_from_their_declared_size() {
    // 3 GiB of zeros in 3 MB: refused before any is inflated.
    let z = zip_bomb("verts.npy", 3 << 10);
    assert!(z.len() < 4 << 20, "{}", z.len());
    let e = parse_npz_f32(&z, "verts").unwrap_err().to_string();
    assert!(e.contains("declares 3221225472 bytes"), "{e}");
    // The archive is sound: a small one inflates (and is then not a
    // .npy file).
    let e = parse_npz_f32(&zip_bomb("verts.npy", 2), "verts")
        .unwrap_err()
        .to_string();
    assert!(e.contains("magic"), "{e}");
    // A declared size that understates the data: no more than it is
    // inflated.
    let mut lying = zip_bomb("verts.npy", 64);
    let at = lying.len() - 22 - 46 - "verts.npy".len() + 24;
    lying[at..at + 4].copy_from_slice(&1000u32.to_le_bytes());
    let e = parse_npz_f32(&lying, "verts").unwrap_err().to_string();
    assert!(e.contains("declares 1000"), "{e}");
}

#[test]
fn npz_arrays_read_by_name_as_f64() {
    let f64s = encode_f64(&[2, 2], &[1.5, -2.0, 1e300, 0.25]);
    let f32s = encode_rgb_f32(&sample());
    let ints = with_header(
        "{'descr': '<i4', 'fortran_order': False, 'shape': (2,), }",
        8,
    );
    let z = npz(
        &[
            ("world_mat_0.npy", &f64s),
            ("img.npy", &f32s),
            ("ints.npy", &ints),
            ("notes.txt", b"x"),
        ],
        zip::CompressionMethod::Deflated,
    );
    let mut a = Npz::parse(z).unwrap();
    assert_eq!(a.keys(), vec!["world_mat_0", "img", "ints"]);
    assert_eq!(
        a.read_f64("world_mat_0", 4).unwrap(),
        (vec![2, 2], vec![1.5, -2.0, 1e300, 0.25])
    );
    let (shape, v) = a.read_f64("img", 100).unwrap();
    assert_eq!((shape, v[3], v[5]), (vec![2, 3, 3], 1.0, -1.25));
    // Too many numbers for the caller: refused from the header.
    let e = a.read_f64("world_mat_0", 3).unwrap_err().to_string();
    assert!(e.contains("more than 3"), "{e}");
    let e = a.read_f64("ints", 100).unwrap_err().to_string();
    assert!(e.contains("<i4") && e.contains("'<f8'"), "{e}");
    assert!(matches!(
        a.read_f64("scale_mat_0", 16),
        Err(NpyError::MissingKey(_))
    ));
    assert!(Npz::parse(b"not a zip".to_vec()).is_err());
    // A 3 GiB bomb is refused from its declared size.
    let mut bomb = Npz::parse(zip_bomb("world_mat_0.npy", 3 << 10)).unwrap();
    let e = bomb.read_f64("world_mat_0", 16).unwrap_err().to_string();
    assert!(e.contains("declares 3221225472 bytes"), "{e}");
    // And a file larger than the caller's cap is not read.
    let dir = std::env::temp_dir().join(format!("sdfl-npz-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("big.npz");
    std::fs::write(&path, vec![0u8; 2000]).unwrap();
    let e = Npz::read(&path, 1000).err().unwrap().to_string();
    assert!(e.contains("larger than 1000 bytes"), "{e}");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn reads_the_assignment_bunny_when_present() {
    // Reads ../shared/data/assignment3 (from the repository root) only
    // where it exists.
    let p = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../shared/data/assignment3/bunny_pointcloud.npz");
    if !p.is_file() {
        eprintln!("note: {} not found; skipping", p.display());
        return;
    }
    let a = read_npz_f32(&p, "verts").unwrap();
    assert_eq!(a.shape, vec![10000, 3]);
    assert!(a.data.iter().all(|v| v.is_finite()));
}
