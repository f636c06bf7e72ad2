//! `import "other.sdfl"`: the imported file's `let`s and `fn`s are spliced
//! into the importing file where the `import` stands, so the checker and
//! evaluator see one file.
//!
//! Each imported file's tree is moved to offsets past every file before it
//! (see [`sdfl_lang::ast::Shift`]), so a span still names one place in one
//! file; [`Sources::locate`] attaches the files to the diagnostics, and
//! rendering shows each in the file its span is in. Paths are relative to the importing file and must stay inside the
//! main file's directory, name `.sdfl` files, and not import in a cycle. A
//! file imported twice (by two others) is read once.

use std::path::{Component, Path, PathBuf};

use sdfl_lang::ast::{File, Import, Item, Shift};
use sdfl_lang::diag::{codes, Diag, Diagnostics};
use sdfl_lang::{SourceFile, Span};

/// Most bytes of all files one load reads (the CLI's limit for one file).
pub const MAX_IMPORTED_BYTES: u64 = 64 << 20;
/// Longest chain of files importing each other (each level recurses).
pub const MAX_IMPORT_DEPTH: usize = 32;

/// The imported files, each with the offset its spans were moved by.
#[derive(Default)]
pub struct Sources {
    files: Vec<(usize, SourceFile)>,
}

impl Sources {
    /// `diags` with the imported files attached, so that their spans are
    /// shown in the files they point into.
    pub fn locate(&self, mut diags: Diagnostics) -> Diagnostics {
        diags.files = self.files.clone();
        diags
    }
}

/// Parses `source` and splices in what it imports.
pub fn resolve(source: &SourceFile) -> (Result<File, Diagnostics>, Sources) {
    let mut sources = Sources::default();
    let file = match sdfl_lang::parse::parse(&source.text) {
        Ok(f) => f,
        Err(d) => return (Err(d), sources),
    };
    if !file.items.iter().any(|i| matches!(i, Item::Import(_))) {
        return (Ok(file), sources);
    }
    let main = source.disk_path();
    let root = main.parent().map_or_else(PathBuf::new, Path::to_path_buf);
    let mut r = Resolver {
        root_canonical: std::fs::canonicalize(if root.as_os_str().is_empty() {
            Path::new(".")
        } else {
            &root
        })
        .ok(),
        root_display: Path::new(&source.name)
            .parent()
            .map_or_else(PathBuf::new, Path::to_path_buf),
        next_base: source.text.len() + 1,
        bytes: source.text.len() as u64,
        seen: Vec::new(),
        chain: vec![(
            std::fs::canonicalize(&main).unwrap_or(main.clone()),
            source.name.clone(),
        )],
        diags: Diagnostics::default(),
        sources: &mut sources,
    };
    let items = r.splice(file.items, &[], false);
    let diags = std::mem::take(&mut r.diags);
    if diags.is_empty() {
        (Ok(File { items }), sources)
    } else {
        (Err(diags), sources)
    }
}

struct Resolver<'s> {
    /// The main file's directory: every import must be inside it.
    root_canonical: Option<PathBuf>,
    root_display: PathBuf,
    next_base: usize,
    bytes: u64,
    /// Canonical paths of files already spliced in.
    seen: Vec<PathBuf>,
    /// The files importing the one being read, from the main file: their
    /// canonical paths and names.
    chain: Vec<(PathBuf, String)>,
    diags: Diagnostics,
    sources: &'s mut Sources,
}

impl Resolver<'_> {
    /// `items` with each `import` replaced by the imported items. `dir` is
    /// the importing file's directory relative to the main file's, as
    /// components; `imported` tells whether `items` come from an import
    /// (which may hold no statements).
    fn splice(&mut self, items: Vec<Item>, dir: &[String], imported: bool) -> Vec<Item> {
        let mut out = Vec::new();
        for item in items {
            match item {
                Item::Import(i) => {
                    if let Some(items) = self.import(&i, dir) {
                        out.extend(items);
                    }
                }
                Item::Block(b) if imported => self.diags.push(
                    Diag::new(
                        codes::IMPORT_STATEMENT,
                        b.kind.span,
                        format!("an imported file cannot hold a `{}` statement", b.kind.name),
                    )
                    .label("a statement in an imported file")
                    .help("imported files hold only `let`s, `fn`s and `import`s: move this statement into the file that imports it"),
                ),
                other => out.push(other),
            }
        }
        out
    }

    fn error(&mut self, code: &'static str, span: Span, message: String, label: &str, help: &str) {
        self.diags.push(
            Diag::new(code, span, message)
                .label(label.to_string())
                .help(help.to_string()),
        );
    }

    fn import(&mut self, i: &Import, dir: &[String]) -> Option<Vec<Item>> {
        let span = i.path_span;
        let path = Path::new(&i.path);
        if path.extension().is_none_or(|e| e != "sdfl") {
            self.error(
                codes::IMPORT_PATH,
                span,
                format!("`{}` is not a .sdfl file", i.path),
                "not a .sdfl file",
                "only scene files ending in `.sdfl` can be imported",
            );
            return None;
        }
        // Relative to the main file's directory, `..` resolved lexically.
        let mut rel: Vec<String> = dir.to_vec();
        for c in path.components() {
            match c {
                Component::Normal(n) => rel.push(n.to_string_lossy().into_owned()),
                Component::CurDir => {}
                Component::ParentDir if !rel.is_empty() => {
                    rel.pop();
                }
                Component::ParentDir => {
                    self.error(
                        codes::IMPORT_PATH,
                        span,
                        format!("`{}` is outside the main file's directory", i.path),
                        "leaves the directory",
                        "imports are confined to the main file's directory and the directories inside it",
                    );
                    return None;
                }
                Component::RootDir | Component::Prefix(_) => {
                    self.error(
                        codes::IMPORT_PATH,
                        span,
                        format!("`{}` is an absolute path", i.path),
                        "absolute",
                        "write the path relative to the importing file",
                    );
                    return None;
                }
            }
        }
        let rel_path: PathBuf = rel.iter().collect();
        let name = self.root_display.join(&rel_path).display().to_string();
        let on_disk = self
            .root_canonical
            .as_ref()
            .map(|r| r.join(&rel_path))
            .and_then(|p| std::fs::canonicalize(p).ok());
        let Some(canonical) = on_disk else {
            self.error(
                codes::IMPORT_MISSING,
                span,
                format!("cannot find `{name}`"),
                "no such file",
                "the path is relative to the importing file",
            );
            return None;
        };
        // A link may point anywhere: what it points to must be inside too.
        if !self
            .root_canonical
            .as_ref()
            .is_some_and(|r| canonical.starts_with(r))
        {
            self.error(
                codes::IMPORT_PATH,
                span,
                format!("`{}` leads outside the main file's directory", i.path),
                "a link out of the directory",
                "imports are confined to the main file's directory and the directories inside it",
            );
            return None;
        }
        if let Some(at) = self.chain.iter().position(|(p, _)| *p == canonical) {
            let mut names: Vec<&str> = self.chain[at..].iter().map(|(_, n)| n.as_str()).collect();
            names.push(&name);
            let cycle = names.join(" → ");
            self.error(
                codes::IMPORT_CYCLE,
                span,
                format!("import cycle: {cycle}"),
                "imports a file that imports this one",
                "files cannot import each other in a cycle: move what both need into a third file",
            );
            return None;
        }
        if self.seen.contains(&canonical) {
            return Some(Vec::new());
        }
        if self.chain.len() > MAX_IMPORT_DEPTH {
            self.error(
                codes::TOO_LARGE,
                span,
                format!("imports nested more than {MAX_IMPORT_DEPTH} files deep"),
                "too deep",
                "import the files from one place instead of each from the one before",
            );
            return None;
        }
        let text = match self.read(&canonical) {
            Ok(t) => t,
            Err(Unread::Io(why)) => {
                self.error(
                    codes::IMPORT_MISSING,
                    span,
                    format!("cannot read `{name}`: {why}"),
                    "cannot be read",
                    "import a readable scene file",
                );
                return None;
            }
            Err(Unread::Encoding(bad)) => {
                self.error(
                    codes::SOURCE_ENCODING,
                    span,
                    format!("`{name}` is not UTF-8 text: {} is not UTF-8", bad.place()),
                    "imports a file that is not UTF-8",
                    &format!("save `{name}` as UTF-8: sdfl reads no other encoding"),
                );
                return None;
            }
        };
        self.seen.push(canonical.clone());
        let base = self.next_base;
        self.next_base += text.len() + 1;
        let source = SourceFile::new(name.clone(), text);
        self.sources.files.push((base, source.clone()));
        let file = match sdfl_lang::parse::parse(&source.text) {
            Ok(f) => f,
            Err(d) => {
                for mut d in d.diags {
                    d.span.shift(base);
                    for n in &mut d.notes {
                        n.0.shift(base);
                    }
                    self.diags.push(d);
                }
                return None;
            }
        };
        let mut items = file.items;
        for item in &mut items {
            item.shift(base);
        }
        let mut sub_dir = rel;
        sub_dir.pop();
        self.chain.push((canonical, name));
        let items = self.splice(items, &sub_dir, true);
        self.chain.pop();
        Some(items)
    }

    /// A regular file's text, within the byte budget of the load.
    fn read(&mut self, path: &Path) -> Result<String, Unread> {
        let left = MAX_IMPORTED_BYTES.saturating_sub(self.bytes);
        let bytes = crate::files::open_regular(path)
            .and_then(|f| crate::files::read_to_cap(f, path, left))
            .map_err(|e| match e.kind() {
                std::io::ErrorKind::FileTooLarge => Unread::Io(format!(
                    "the files imported add up to more than {MAX_IMPORTED_BYTES} bytes"
                )),
                // The error names the canonical path; the message names the import.
                _ => Unread::Io(
                    e.to_string()
                        .strip_prefix(&format!("{}: ", path.display()))
                        .map_or_else(|| e.to_string(), str::to_string),
                ),
            })?;
        self.bytes = self.bytes.saturating_add(bytes.len() as u64);
        crate::files::utf8(bytes).map_err(Unread::Encoding)
    }
}

/// Why an imported file was not read.
enum Unread {
    Io(String),
    Encoding(crate::files::NotUtf8),
}
