//! Images read within limits (sizes declared, ancillary chunks, special
//! files), alpha as coverage, checkpoints read from real files only.

use sdfl_runtime::data::image::*;
use std::io;
use std::path::Path;

#[test]
fn large_images_are_decoded_one_at_a_time() {
    // Small images fill the pool's width; a 12000² one (576 MB) goes
    // alone, and so does whatever follows it past the budget.
    assert_eq!(batch_len(&[(800, 800); 2]), 2);
    assert_eq!(batch_len(&[(12_000, 12_000), (12_000, 12_000)]), 1);
    assert_eq!(batch_len(&[(800, 800), (12_000, 12_000)]), 1);
    assert_eq!(batch_len(&[(8000, 8000), (800, 800)]), 2);
    assert_eq!(batch_len(&[]), 0);
}

fn dir(name: &str) -> std::path::PathBuf {
    let d = std::env::temp_dir().join(format!("sdfl-data-image-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// A valid PNG header declaring `w`×`h` (followed by no image data).
fn png_header(w: u32, h: u32) -> Vec<u8> {
    let mut b = b"\x89PNG\r\n\x1a\n".to_vec();
    let mut ihdr = b"IHDR".to_vec();
    ihdr.extend_from_slice(&w.to_be_bytes());
    ihdr.extend_from_slice(&h.to_be_bytes());
    ihdr.extend_from_slice(&[8, 2, 0, 0, 0]);
    b.extend_from_slice(&13u32.to_be_bytes());
    b.extend_from_slice(&ihdr);
    b.extend_from_slice(&crc32(&ihdr).to_be_bytes());
    // An empty IDAT chunk: decoders read the header up to the first one.
    b.extend_from_slice(&0u32.to_be_bytes());
    b.extend_from_slice(b"IDAT");
    b.extend_from_slice(&crc32(b"IDAT").to_be_bytes());
    b
}

fn crc32(data: &[u8]) -> u32 {
    let mut c = 0xffff_ffffu32;
    for &byte in data {
        c ^= byte as u32;
        for _ in 0..8 {
            c = if c & 1 != 0 {
                0xedb8_8320 ^ (c >> 1)
            } else {
                c >> 1
            };
        }
    }
    !c
}

#[test]
fn declared_sizes_are_checked_before_decoding() {
    let d = dir("sizes");
    let huge = d.join("huge.png");
    std::fs::write(&huge, png_header(20_000, 10)).unwrap();
    let e = image_dimensions(&huge).unwrap_err().to_string();
    assert!(e.contains("huge.png") && e.contains("20000x10"), "{e}");
    assert!(read_rgb_image(&huge).is_err());
    // Each fits, together they do not.
    let big = d.join("big.png");
    // 8-bit: 1.02 GB each as training holds it.
    std::fs::write(&big, png_header(16_000, 16_000)).unwrap();
    assert_eq!(image_dimensions(&big).unwrap(), (16_000, 16_000));
    check_dataset([&big]).unwrap();
    let e = check_dataset([&big, &big]).unwrap_err().to_string();
    assert!(e.contains("at most"), "{e}");
}

/// A 16×16 PNG (opaque grey) with `chunk` (type and data) inserted
/// after its header.
fn png_with_chunk(kind: &[u8; 4], data: &[u8]) -> Vec<u8> {
    let mut png = Vec::new();
    image::RgbImage::from_pixel(16, 16, image::Rgb([128, 128, 128]))
        .write_to(&mut io::Cursor::new(&mut png), image::ImageFormat::Png)
        .unwrap();
    let mut chunk = (data.len() as u32).to_be_bytes().to_vec();
    chunk.extend(kind);
    chunk.extend(data);
    chunk.extend(crc32(&chunk[4..]).to_be_bytes());
    // The signature (8 bytes) and IHDR (25).
    png.splice(33..33, chunk);
    png
}

#[test]
fn ancillary_chunks_inflate_within_limits() {
    let d = dir("bombs");
    // An ICC profile of 2 GiB zeros in 2 MB: inflated only up to the
    // metadata limit, then dropped (as the png crate drops a bad
    // profile); the pixels load.
    let mut iccp = b"bomb\0\0\x78\x9c".to_vec();
    iccp.extend(crate::data::npy::zeros_deflated(2048));
    let n = 1u64 << 31;
    iccp.extend((((n % 65521) << 16) as u32 | 1).to_be_bytes());
    let path = d.join("iccp.png");
    std::fs::write(&path, png_with_chunk(b"iCCP", &iccp)).unwrap();
    let img = read_rgba_image(&path).unwrap();
    assert_eq!((img.width, img.height), (16, 16));
    let px = &img.pixels;
    assert!((px[0][0] - 128.0 / 255.0).abs() < 1e-6, "{:?}", px[0]);
    // Metadata beyond the limit that cannot be dropped is refused.
    let text = [b"k\0".as_slice(), &vec![b'x'; 17 << 20]].concat();
    let path = d.join("text.png");
    std::fs::write(&path, png_with_chunk(b"tEXt", &text)).unwrap();
    let e = read_rgb_image(&path).unwrap_err().to_string();
    assert!(e.contains("text.png") && e.contains("limit"), "{e}");
}

/// Whether a file has alpha is what it declares, not what its alpha
/// holds: RGB PNG and JPEG have none, grey+alpha and RGBA have it (an
/// opaque one too); coverage is alpha in 255ths, 16-bit to the nearest.
#[test]
fn alpha_is_known_and_read_as_coverage() {
    let d = dir("alpha");
    let grey = |x: u8| image::Rgb([x, x, x]);
    let rgb = image::RgbImage::from_fn(4, 2, |i, _| grey(60 * i as u8));
    rgb.save(d.join("rgb.png")).unwrap();
    rgb.save(d.join("rgb.jpg")).unwrap();
    let rgba = image::RgbaImage::from_fn(4, 2, |i, j| {
        image::Rgba([
            9,
            9,
            9,
            [0, 1, 128, 255][i as usize] * (1 - j as u8) + 255 * j as u8,
        ])
    });
    rgba.save(d.join("rgba.png")).unwrap();
    image::RgbaImage::from_pixel(4, 2, image::Rgba([9, 9, 9, 255]))
        .save(d.join("opaque.png"))
        .unwrap();
    let wide = image::ImageBuffer::<image::LumaA<u16>, Vec<u16>>::from_fn(2, 1, |i, _| {
        image::LumaA([1000, [32768, 65535][i as usize]])
    });
    wide.save(d.join("la16.png")).unwrap();
    for (name, alpha) in [
        ("rgb.png", false),
        ("rgb.jpg", false),
        ("rgba.png", true),
        ("opaque.png", true),
        ("la16.png", true),
    ] {
        let img = read_rgba_image(&d.join(name)).unwrap();
        assert_eq!(img.has_alpha, alpha, "{name}");
        // Without alpha, opaque.
        if !alpha {
            assert!(img.pixels.iter().all(|p| p[3] == 1.0), "{name}");
        }
    }
    let c = sdfl_runtime::data::coverage_from_alpha(
        &read_rgba_image(&d.join("rgba.png")).unwrap().pixels,
    );
    assert_eq!(&c[..], &[0, 1, 128, 255, 255, 255, 255, 255]);
    // 32768/65535 lies 0.5/65535 above 127.5/255: the nearest 255th is 128.
    let c = sdfl_runtime::data::coverage_from_alpha(
        &read_rgba_image(&d.join("la16.png")).unwrap().pixels,
    );
    assert_eq!(&c[..], &[128, 255]);
    // Alpha beyond 0..1 (a float source) is clamped, not wrapped.
    let c = sdfl_runtime::data::coverage_from_alpha(&[[0.0, 0.0, 0.0, -0.5], [0.0, 0.0, 0.0, 1.5]]);
    assert_eq!(&c[..], &[0, 255]);
}

#[test]
fn checkpoints_are_read_from_real_files_only() {
    let d = dir("checkpoint");
    std::fs::write(d.join("good.ckpt"), "bytes").unwrap();
    assert_eq!(
        read_checkpoint_bytes(&d.join("good.ckpt")).unwrap(),
        b"bytes"
    );
    let e = read_checkpoint_bytes(&d.join("missing.ckpt"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("missing.ckpt"), "{e}");
    #[cfg(unix)]
    {
        std::os::unix::fs::symlink(d.join("good.ckpt"), d.join("link.ckpt")).unwrap();
        let e = read_checkpoint_bytes(&d.join("link.ckpt"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("symbolic link"), "{e}");
    }
}

#[test]
fn special_files_are_refused() {
    let e = read_rgb_image(Path::new("/dev/zero"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("not a regular file"), "{e}");
    let d = dir("special");
    #[cfg(unix)]
    {
        let link = d.join("zero.npy");
        std::os::unix::fs::symlink("/dev/zero", &link).unwrap();
        let e = read_rgb_image(&link).unwrap_err().to_string();
        assert!(e.contains("not a regular file"), "{e}");
    }
    let e = read_rgb_image(&d).unwrap_err().to_string();
    assert!(e.contains("not a regular file"), "{e}");
}
