//! A data set's files: paths that its files name, kept inside its
//! directory whatever links lead there, and the image folders that
//! formats without a list of images read.

use std::io;
use std::path::{Component, Path, PathBuf};

use sdfl_stdlib::builtins::MAX_VIEWS;

use super::error::invalid;

/// A relative path inside the data set as components (no `..`, no root,
/// not empty), `.png` added when it has no extension (as Blender's files
/// omit it).
pub fn relative(file_path: &str, add_png: bool) -> Option<PathBuf> {
    if file_path.contains('\0') {
        return None;
    }
    // Only named components: `./r_0` is `r_0`, and `.` or `./` name the
    // directory itself (whose `.png` would lie beside it).
    let mut rel = PathBuf::new();
    for c in Path::new(file_path).components() {
        match c {
            Component::Normal(n) => rel.push(n),
            Component::CurDir => {}
            _ => return None,
        }
    }
    if rel.as_os_str().is_empty() {
        return None;
    }
    if add_png && rel.extension().is_none() {
        rel.set_extension("png");
    }
    Some(rel)
}

/// `dir/rel`, which must exist and, links followed, lie strictly inside
/// `dir`. `file_path` is the text as written, for messages.
pub fn inside(dir: &Path, rel: &Path, file_path: &str) -> Result<PathBuf, String> {
    let image = dir.join(rel);
    let real = image
        .canonicalize()
        .map_err(|e| format!("{}: {e}", image.display()))?;
    let real_dir = dir
        .canonicalize()
        .map_err(|e| format!("{}: {e}", dir.display()))?;
    if !real.starts_with(&real_dir) || real == real_dir {
        return Err(format!(
            "frame image `{file_path}` leads outside the data set (to {})",
            real.display()
        ));
    }
    Ok(image)
}

/// The folder of a capture's images read at `1/downscale` of their size:
/// `images`, or `images_<downscale>` (nerfstudio's and LLFF's layout).
pub fn images_folder(downscale: u32) -> String {
    if downscale > 1 {
        format!("images_{downscale}")
    } else {
        "images".to_string()
    }
}

/// The PNG and JPEG files of `folder`, sorted by name; at most
/// `MAX_VIEWS`.
pub fn image_files(folder: &Path) -> io::Result<Vec<PathBuf>> {
    let mut files = Vec::new();
    for e in std::fs::read_dir(folder).map_err(|e| invalid(folder, e))? {
        let p = e.map_err(|e| invalid(folder, e))?.path();
        let ext = p
            .extension()
            .and_then(|x| x.to_str())
            .map(str::to_ascii_lowercase);
        if matches!(ext.as_deref(), Some("png" | "jpg" | "jpeg")) {
            files.push(p);
        }
        if files.len() > MAX_VIEWS {
            return Err(invalid(folder, format!("more than {MAX_VIEWS} images")));
        }
    }
    files.sort();
    Ok(files)
}
