//! Diagnostics: every user-facing error is a [`Diag`] with a stable code, a
//! primary span and label, and help. All diagnostics of a file are gathered in
//! a [`Diagnostics`] and rendered together through miette.

use std::fmt;
use std::sync::Arc;

use miette::{GraphicalReportHandler, GraphicalTheme, LabeledSpan, NamedSource, SourceCode};

use crate::span::Span;

/// Stable diagnostic codes. Tests and users may match on these strings, so
/// they never change meaning; new codes are added, old ones are not reused.
pub mod codes {
    /// Text that is not sdfl: the parser's expected tokens are named.
    pub const SYNTAX: &str = "sdfl::syntax";
    /// Brackets, `if`s or `for`s nested too deep to parse safely.
    pub const NESTING: &str = "sdfl::syntax::nesting";
    /// A number literal that is not finite (`1e999`).
    pub const NUMBER: &str = "sdfl::syntax::number";
    /// A string escape sdfl does not have (`\q`).
    pub const ESCAPE: &str = "sdfl::syntax::escape";
    /// A unit written apart from its number (`30 deg`), or one sdfl does
    /// not have (`50mm`, `0.5rad`).
    pub const UNIT: &str = "sdfl::syntax::unit";
    /// A name that no `let`, parameter, loop or constant defines.
    pub const UNKNOWN_NAME: &str = "sdfl::name::unknown";
    /// A call of a function that is neither built in nor a `fn`.
    pub const UNKNOWN_FUNCTION: &str = "sdfl::name::unknown-function";
    /// A statement keyword that is not one of sdfl's (`render`, `train`…).
    pub const UNKNOWN_BLOCK: &str = "sdfl::name::unknown-block";
    /// A name defined twice in one scope.
    pub const DUPLICATE_NAME: &str = "sdfl::name::duplicate";
    /// A call of something that is a value, not a function.
    pub const NOT_CALLABLE: &str = "sdfl::name::not-callable";
    /// A `fn` named like a built-in function.
    pub const SHADOWS_BUILTIN: &str = "sdfl::name::shadows-builtin";
    /// A call of a `fn` defined below the call (or of itself): functions
    /// call only functions defined above them, so there is no recursion.
    pub const FN_ORDER: &str = "sdfl::fn::order";
    /// A list index that is not a whole number within the list.
    pub const INDEX: &str = "sdfl::value::index";
    /// An `import` path that is absolute, leaves the main file's directory
    /// or names something other than a `.sdfl` file.
    pub const IMPORT_PATH: &str = "sdfl::import::path";
    /// An `import`ed file that cannot be read.
    pub const IMPORT_MISSING: &str = "sdfl::import::missing";
    /// Files that import each other in a cycle.
    pub const IMPORT_CYCLE: &str = "sdfl::import::cycle";
    /// A statement (`render`, `train`) in an imported file, which may hold
    /// only `let`s, `fn`s and `import`s.
    pub const IMPORT_STATEMENT: &str = "sdfl::import::statement";
    /// A named argument the function does not take.
    pub const UNKNOWN_ARG: &str = "sdfl::arg::unknown";
    /// A required argument left out.
    pub const MISSING_ARG: &str = "sdfl::arg::missing";
    /// An argument given twice.
    pub const DUPLICATE_ARG: &str = "sdfl::arg::duplicate";
    /// More positional arguments than the function has parameters.
    pub const TOO_MANY_ARGS: &str = "sdfl::arg::too-many";
    /// A positional argument after a named one.
    pub const POSITIONAL_AFTER_NAMED: &str = "sdfl::arg::positional-after-named";
    /// A statement field the statement does not take.
    pub const UNKNOWN_FIELD: &str = "sdfl::field::unknown";
    /// A required statement field left out.
    pub const MISSING_FIELD: &str = "sdfl::field::missing";
    /// A statement field given twice.
    pub const DUPLICATE_FIELD: &str = "sdfl::field::duplicate";
    /// A value of the wrong type (a number where a shape is wanted).
    pub const TYPE: &str = "sdfl::type::mismatch";
    /// A value of the right type outside its range (a negative radius, `near` ≥ `far`).
    pub const VALUE: &str = "sdfl::value::range";
    /// Arithmetic without a result: division by zero, a non-finite result.
    pub const ARITHMETIC: &str = "sdfl::value::arithmetic";
    /// Input beyond sdfl's limits on size: a statement, a list, a scene, a `fn`'s parameters.
    pub const TOO_LARGE: &str = "sdfl::limit::too-large";
    /// An output or input path that escapes `--out` or that the file system refuses.
    pub const PATH: &str = "sdfl::path::escape";
    /// A file that could not be read or written.
    pub const IO: &str = "sdfl::io";
    /// A scene file (or an imported one) that is not UTF-8 text: refused at
    /// its first bad byte, never read with the bytes replaced.
    pub const SOURCE_ENCODING: &str = "sdfl::source::encoding";
    /// Two outputs (or an output and a checkpoint) write the same file.
    pub const OUTPUT_COLLISION: &str = "sdfl::path::collision";
    /// A number that the f32 runtime would flush to zero or overflow.
    pub const PRECISION: &str = "sdfl::value::precision";
    /// A run whose estimated work or memory is beyond what sdfl accepts.
    pub const WORK: &str = "sdfl::limit::work";
    /// A `fn` used as a shape (`sdf(f)`) does what a shape's function
    /// cannot: gives no number, calls what is no operation on numbers
    /// (`random`, a shape), loops.
    pub const SHAPE_FN: &str = "sdfl::fn::shape";
    /// A shape's function that interval arithmetic over its bound box finds
    /// can be infinite (a division by a range holding 0).
    pub const SHAPE_UNBOUNDED: &str = "sdfl::fn::unbounded";
    /// A warning: the camera cannot reach the scene within `far`.
    pub const MISSES_SCENE: &str = "sdfl::warn::misses-scene";
    /// A warning: a `param(...)` where nothing trains it (a render, or the
    /// data of a `train`): it keeps its starting value.
    pub const UNTRAINED_PARAM: &str = "sdfl::warn::untrained-param";
    /// A warning: a whole angle of 7 radians or more, likely meant in
    /// degrees (`rotate(s, 45)`).
    pub const DEGREES: &str = "sdfl::warn::degrees";
    /// A warning: a focal length far beyond NDC's (a lens's millimetres,
    /// `focal: 50`).
    pub const FOCAL: &str = "sdfl::warn::focal";
    /// A warning: a NeRF's `background` disagrees with its training data's
    /// (a NeRF-synthetic set composited over white, a black model).
    pub const BACKGROUND_MISMATCH: &str = "sdfl::warn::background-mismatch";
    /// A warning: a forward-facing (LLFF) capture trained by a NeRF with
    /// ordinary rays, not its NDC.
    pub const FORWARD_FACING: &str = "sdfl::warn::forward-facing";
    /// A warning: a `dataset` whose views are not one centred pinhole
    /// camera, which the Blender form (`camera_angle_x`) cannot state.
    pub const BLENDER_LENS: &str = "sdfl::warn::blender-lens";
}

/// A number in a message: plain when short, otherwise in short scientific
/// form (`1e308`, not 309 digits; `1e-46`, not 47 zeros).
pub fn fmt_num(x: f64) -> String {
    if x == 0.0 || !x.is_finite() || (1e-4..1e9).contains(&x.abs()) {
        format!("{x}")
    } else {
        format!("{x:e}")
    }
}

/// How bad a diagnostic is: errors fail the command, warnings are printed
/// and the command goes on.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Severity {
    /// The command fails (after reporting every diagnostic).
    Error,
    /// Printed; the command goes on.
    Warning,
}

/// One diagnostic: what went wrong, where, and what to do about it.
///
/// Boxed, so that `Result<T, Diag>` stays one pointer wide on the error
/// side: results of every check and evaluation step carry a `Diag`, and an
/// unboxed one (128 bytes) would be moved through each of them. Its fields
/// are read and written through [`DiagData`] (`d.code`, `d.help = ...`).
#[derive(Clone, PartialEq)]
pub struct Diag(Box<DiagData>);

/// The contents of a [`Diag`].
#[derive(Debug, Clone, PartialEq)]
pub struct DiagData {
    /// The stable code, one of [`codes`].
    pub code: &'static str,
    /// The sentence shown as the title of the report.
    pub message: String,
    /// Where in the source the problem is.
    pub span: Span,
    /// Shown under the primary span; empty for none.
    pub label: String,
    /// What the user can do about it.
    pub help: Option<String>,
    /// Secondary spans, e.g. the earlier definition of a duplicate name.
    pub notes: Vec<(Span, String)>,
}

impl std::ops::Deref for Diag {
    type Target = DiagData;
    fn deref(&self) -> &DiagData {
        &self.0
    }
}

impl std::ops::DerefMut for Diag {
    fn deref_mut(&mut self) -> &mut DiagData {
        &mut self.0
    }
}

impl fmt::Debug for Diag {
    // As the unboxed struct printed, so test failures read the same.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let d = &*self.0;
        f.debug_struct("Diag")
            .field("code", &d.code)
            .field("message", &d.message)
            .field("span", &d.span)
            .field("label", &d.label)
            .field("help", &d.help)
            .field("notes", &d.notes)
            .finish()
    }
}

impl From<DiagData> for Diag {
    fn from(d: DiagData) -> Self {
        Diag(Box::new(d))
    }
}

impl Diag {
    /// An error (or warning, by its code) with no label, help or notes yet:
    /// the builder methods below add them.
    pub fn new(code: &'static str, span: Span, message: impl Into<String>) -> Self {
        DiagData {
            code,
            message: message.into(),
            span,
            label: String::new(),
            help: None,
            notes: Vec::new(),
        }
        .into()
    }
    /// The contents, owned (to move fields out).
    pub fn into_data(self) -> DiagData {
        *self.0
    }
    /// Warnings are the codes under `sdfl::warn::` (kept in the code, so a
    /// diagnostic's severity is as stable as its code).
    pub fn severity(&self) -> Severity {
        if self.code.starts_with("sdfl::warn::") {
            Severity::Warning
        } else {
            Severity::Error
        }
    }
    /// The text under the primary span.
    pub fn label(mut self, label: impl Into<String>) -> Self {
        self.label = label.into();
        self
    }
    /// What the user can do about it.
    pub fn help(mut self, help: impl Into<String>) -> Self {
        self.help = Some(help.into());
        self
    }
    /// A secondary span with its text (an earlier definition, the other
    /// end of a collision).
    pub fn note(mut self, span: Span, text: impl Into<String>) -> Self {
        self.notes.push((span, text.into()));
        self
    }
}

/// Diagnostics collected while processing one source file.
#[derive(Debug, Clone, Default)]
pub struct Diagnostics {
    /// In the order found; [`Diagnostics::sorted`] orders them by position.
    pub diags: Vec<Diag>,
    /// The files the loaded one imports, each with the offset its spans
    /// were moved to (past the loaded file's and each other's): a span at
    /// or past an offset points into that file. (Kept here rather than on
    /// each [`Diag`], which stays small.)
    pub files: Vec<(usize, SourceFile)>,
}

impl Diagnostics {
    /// The imported file `span` points into (`None`: the loaded file) and
    /// the span within that file.
    pub fn locate(&self, span: Span) -> (Option<&SourceFile>, Span) {
        match self
            .files
            .iter()
            .rev()
            .find(|(base, _)| *base <= span.start)
        {
            Some((base, f)) => (Some(f), Span::new(span.start - base, span.end - base)),
            None => (None, span),
        }
    }

    /// `d` with its spans in the file of its primary span, and that file:
    /// a note in another file becomes a sentence of the help. `main` is the
    /// loaded file.
    fn localised(&self, d: &Diag, main: &SourceFile) -> (Option<&SourceFile>, Diag) {
        let (file, span) = self.locate(d.span);
        let mut local: Diag = DiagData {
            span,
            notes: Vec::new(),
            ..(**d).clone()
        }
        .into();
        for (s, text) in &d.notes {
            let (note_file, s) = self.locate(*s);
            if note_file.map(|f| &f.name) == file.map(|f| &f.name) {
                local.notes.push((s, text.clone()));
                continue;
            }
            let f = note_file.unwrap_or(main);
            let (name, (line, col)) = (f.name.as_str(), f.line_col(s.start));
            let help = local.help.take().unwrap_or_default();
            local.help = Some(format!("{help} ({text}: {name}:{line}:{col})"));
        }
        (file, local)
    }

    /// Adds one.
    pub fn push(&mut self, d: Diag) {
        self.diags.push(d);
    }
    /// Whether there are none, warnings included.
    pub fn is_empty(&self) -> bool {
        self.diags.is_empty()
    }
    /// Whether any diagnostic is an error (not only warnings).
    pub fn has_errors(&self) -> bool {
        self.diags.iter().any(|d| d.severity() == Severity::Error)
    }
    /// How many, warnings included.
    pub fn len(&self) -> usize {
        self.diags.len()
    }
    /// Adds another file's (or stage's) diagnostics and imported files.
    pub fn extend(&mut self, other: Diagnostics) {
        self.diags.extend(other.diags);
        for f in other.files {
            if !self.files.contains(&f) {
                self.files.push(f);
            }
        }
    }
    /// Sort by position so a report reads top to bottom.
    pub fn sorted(mut self) -> Self {
        self.diags.sort_by_key(|d| (d.span.start, d.span.end));
        self
    }
}

/// A source file: its name (as shown to the user) and its text.
#[derive(Debug, Clone, PartialEq)]
pub struct SourceFile {
    /// The name shown in reports.
    pub name: String,
    /// The whole text.
    pub text: Arc<str>,
    /// Where it is on disk, when that differs from `name`: its `import`s
    /// are resolved from here (else from `name`).
    pub path: Option<std::path::PathBuf>,
}

impl SourceFile {
    /// A file shown as `name`, found on disk under that name too.
    pub fn new(name: impl Into<String>, text: impl Into<Arc<str>>) -> Self {
        SourceFile {
            name: name.into(),
            text: text.into(),
            path: None,
        }
    }
    /// The same file, found on disk at `path` (its name stays as shown).
    pub fn at(mut self, path: impl Into<std::path::PathBuf>) -> Self {
        self.path = Some(path.into());
        self
    }
    /// Where the file is on disk: `path`, or its name.
    pub fn disk_path(&self) -> std::path::PathBuf {
        self.path
            .clone()
            .unwrap_or_else(|| std::path::PathBuf::from(&self.name))
    }
    /// 1-based line and column of a byte offset.
    pub fn line_col(&self, offset: usize) -> (usize, usize) {
        let offset = offset.min(self.text.len());
        let before = &self.text[..floor_char_boundary(&self.text, offset)];
        let line = before.matches('\n').count() + 1;
        let col = before.rsplit('\n').next().map_or(0, |l| l.chars().count()) + 1;
        (line, col)
    }
}

fn floor_char_boundary(s: &str, mut i: usize) -> usize {
    while i > 0 && !s.is_char_boundary(i) {
        i -= 1;
    }
    i
}

/// Lines longer than this are not quoted in reports (a megabyte line would
/// otherwise be printed whole); the location is given as line:column instead.
const MAX_QUOTED_LINE: usize = 400;

/// Most diagnostics rendered in full; the rest are counted. (Each report
/// scans the source for its lines: 100k errors in a large file took minutes,
/// and no one reads past the first screenfuls.)
pub const MAX_RENDERED: usize = 50;

/// A diagnostic joined with its source, as miette wants it.
struct Located<'a> {
    diag: &'a Diag,
    source: Option<NamedSource<Arc<str>>>,
    location: String,
}

impl fmt::Debug for Located<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        self.diag.fmt(f)
    }
}

impl fmt::Display for Located<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if self.source.is_some() {
            write!(f, "{}", self.diag.message)
        } else {
            write!(f, "{} (at {})", self.diag.message, self.location)
        }
    }
}

impl std::error::Error for Located<'_> {}

impl miette::Diagnostic for Located<'_> {
    fn code<'b>(&'b self) -> Option<Box<dyn fmt::Display + 'b>> {
        Some(Box::new(self.diag.code))
    }
    fn severity(&self) -> Option<miette::Severity> {
        Some(match self.diag.severity() {
            Severity::Error => miette::Severity::Error,
            Severity::Warning => miette::Severity::Warning,
        })
    }
    fn help<'b>(&'b self) -> Option<Box<dyn fmt::Display + 'b>> {
        self.diag
            .help
            .as_ref()
            .map(|h| Box::new(h) as Box<dyn fmt::Display>)
    }
    fn source_code(&self) -> Option<&dyn SourceCode> {
        self.source.as_ref().map(|s| s as &dyn SourceCode)
    }
    fn labels(&self) -> Option<Box<dyn Iterator<Item = LabeledSpan> + '_>> {
        self.source.as_ref()?;
        let primary = LabeledSpan::new_primary_with_span(
            (!self.diag.label.is_empty()).then(|| self.diag.label.clone()),
            self.diag.span,
        );
        let notes = self
            .diag
            .notes
            .iter()
            .map(|(s, t)| LabeledSpan::new_with_span(Some(t.clone()), *s));
        Some(Box::new(std::iter::once(primary).chain(notes)))
    }
}

/// Render diagnostics as text. `color` selects ANSI colours (for terminals);
/// without colour the output is stable and is what the file tests compare.
pub fn render(source: &SourceFile, diags: &Diagnostics, color: bool) -> String {
    let theme = if color {
        GraphicalTheme::unicode()
    } else {
        GraphicalTheme::unicode_nocolor()
    };
    let handler = GraphicalReportHandler::new_themed(theme)
        .with_width(100)
        .with_links(false);
    let mut out = String::new();
    for diag in diags.diags.iter().take(MAX_RENDERED) {
        // A diagnostic inside an imported file is shown in that file.
        let (file, local) = diags.localised(diag, source);
        let (source, diag) = (file.unwrap_or(source), &local);
        let (line, col) = source.line_col(diag.span.start);
        let quotable = [diag.span.start, diag.span.end]
            .into_iter()
            .chain(diag.notes.iter().map(|n| n.0.start))
            .all(|off| line_len_at(&source.text, off) <= MAX_QUOTED_LINE);
        let located = Located {
            diag,
            source: quotable.then(|| NamedSource::new(source.name.clone(), source.text.clone())),
            location: format!("{}:{line}:{col}", source.name),
        };
        // Writing into a String cannot fail.
        let _ = handler.render_report(&mut out, &located);
    }
    let n = diags.len();
    if n > MAX_RENDERED {
        let rest = n - MAX_RENDERED;
        let codes: std::collections::BTreeSet<&str> =
            diags.diags[MAX_RENDERED..].iter().map(|d| d.code).collect();
        let codes: Vec<&str> = codes.into_iter().collect();
        out.push_str(&format!(
            "... and {rest} more diagnostic{} not shown ({})\n",
            if rest == 1 { "" } else { "s" },
            codes.join(", ")
        ));
    }
    let warnings = diags
        .diags
        .iter()
        .filter(|d| d.severity() == Severity::Warning)
        .count();
    let errors = n - warnings;
    if errors > 0 {
        out.push_str(&format!(
            "{errors} error{} in {}\n",
            if errors == 1 { "" } else { "s" },
            source.name
        ));
    } else if warnings > 0 {
        out.push_str(&format!(
            "{warnings} warning{} in {}\n",
            if warnings == 1 { "" } else { "s" },
            source.name
        ));
    }
    out
}

fn line_len_at(text: &str, offset: usize) -> usize {
    let offset = floor_char_boundary(text, offset.min(text.len()));
    let start = text[..offset].rfind('\n').map_or(0, |i| i + 1);
    let end = text[offset..].find('\n').map_or(text.len(), |i| offset + i);
    end - start
}

/// The nearest of `candidates` to `name`, if it is close enough to be a
/// plausible typo.
pub fn suggest<'a>(name: &str, candidates: impl IntoIterator<Item = &'a str>) -> Option<&'a str> {
    candidates
        .into_iter()
        .map(|c| (strsim::damerau_levenshtein(name, c), c))
        // Close enough, and not a rewrite of the whole name (`i` is no typo
        // of `a`).
        .filter(|(d, c)| *d <= (name.len().max(c.len()) / 3).max(1) && *d < name.len().min(c.len()))
        .min_by_key(|(d, c)| (*d, *c))
        .map(|(_, c)| c)
}
