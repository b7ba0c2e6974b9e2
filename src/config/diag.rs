//! Diagnostics: what went wrong, where, what was found, what was expected, and how to fix it.
//!
//! Every finding of the reader (syntax or plan stage) is a [`Diagnostic`]. Location is a file
//! path plus an optional [`Span`]; the message never repeats the location. Rendering follows the
//! compilers' convention `path:line:col: severity: message`, followed by the offending line with a
//! caret and the hint.

use serde::Serialize;
use std::fmt;
use std::path::{Path, PathBuf};

/// A place in a configuration file. Lines and columns are 1-based; the column counts bytes.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
pub struct Span {
    /// Line number, from 1.
    pub line: u32,
    /// Column (byte) number, from 1.
    pub col: u32,
    /// Byte offset of the first byte.
    pub offset: usize,
    /// Length in bytes.
    pub len: usize,
}

impl Span {
    /// The span of the start of the file.
    pub(crate) const START: Span = Span { line: 1, col: 1, offset: 0, len: 0 };
}

/// How bad a finding is.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Severity {
    /// Informational: something Performer does that the user may want to know.
    Note,
    /// The file works, but probably not as the author meant, or we changed something.
    Warning,
    /// The file cannot be used.
    Error,
}

impl fmt::Display for Severity {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Severity::Note => "note",
            Severity::Warning => "warning",
            Severity::Error => "error",
        })
    }
}

/// One finding.
#[derive(Clone, Debug, PartialEq, Eq, Serialize)]
pub struct Diagnostic {
    /// Severity as reported (after `--strict` promotion).
    pub severity: Severity,
    /// Stable kebab-case identifier of the kind of finding (for scripts and tests).
    pub code: &'static str,
    /// File the finding is about.
    pub path: PathBuf,
    /// Where in that file, when the finding has a place.
    #[serde(flatten, serialize_with = "ser_span")]
    pub span: Option<Span>,
    /// What is wrong, in one sentence, without the location.
    pub message: String,
    /// The offending text, if any.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub found: Option<String>,
    /// What was expected there.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub expected: Option<String>,
    /// How to fix it.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub hint: Option<String>,
    /// True when the finding is only about portability to Performer 3.0 (reported as an error
    /// under `--strict`, as a note otherwise).
    pub portability: bool,
}

fn ser_span<S: serde::Serializer>(span: &Option<Span>, ser: S) -> Result<S::Ok, S::Error> {
    use serde::ser::SerializeMap;
    let mut m = ser.serialize_map(Some(2))?;
    match span {
        Some(s) => {
            m.serialize_entry("line", &s.line)?;
            m.serialize_entry("col", &s.col)?;
        }
        None => {
            m.serialize_entry("line", &None::<u32>)?;
            m.serialize_entry("col", &None::<u32>)?;
        }
    }
    m.end()
}

impl Diagnostic {
    /// A new diagnostic.
    pub fn new(
        severity: Severity,
        code: &'static str,
        path: &Path,
        span: Option<Span>,
        message: impl Into<String>,
    ) -> Self {
        Diagnostic {
            severity,
            code,
            path: path.to_path_buf(),
            span,
            message: message.into(),
            found: None,
            expected: None,
            hint: None,
            portability: false,
        }
    }

    /// Adds the offending text.
    pub fn found(mut self, found: impl Into<String>) -> Self {
        self.found = Some(found.into());
        self
    }

    /// Adds what was expected.
    pub fn expected(mut self, expected: impl Into<String>) -> Self {
        self.expected = Some(expected.into());
        self
    }

    /// Adds a hint.
    pub fn hint(mut self, hint: impl Into<String>) -> Self {
        self.hint = Some(hint.into());
        self
    }

    /// Renders the diagnostic with the source line and a caret when `source` is the file's text.
    pub fn render(&self, source: Option<&[u8]>) -> String {
        let mut out = String::new();
        let loc = match self.span {
            Some(s) => format!("{}:{}:{}", self.path.display(), s.line, s.col),
            None => format!("{}", self.path.display()),
        };
        out.push_str(&format!("{loc}: {}: {}", self.severity, self.message));
        match (&self.found, &self.expected) {
            (Some(f), Some(e)) => out.push_str(&format!(" (found `{f}`, expected {e})")),
            (Some(f), None) => out.push_str(&format!(" (found `{f}`)")),
            (None, Some(e)) => out.push_str(&format!(" (expected {e})")),
            (None, None) => {}
        }
        out.push('\n');
        if let (Some(src), Some(span)) = (source, self.span) {
            if let Some(line) = source_line(src, span) {
                let shown: String = String::from_utf8_lossy(line).chars().take(160).collect();
                out.push_str(&format!("  {:>4} | {}\n", span.line, shown.trim_end()));
                let pad = " ".repeat((span.col as usize).saturating_sub(1).min(160));
                let carets = "^".repeat(span.len.clamp(1, 80));
                out.push_str(&format!("       | {pad}{carets}\n"));
            }
        }
        if let Some(h) = &self.hint {
            out.push_str(&format!("  = hint: {h}\n"));
        }
        out
    }
}

fn source_line(src: &[u8], span: Span) -> Option<&[u8]> {
    let start = src[..span.offset.min(src.len())].iter().rposition(|&b| b == b'\n').map_or(0, |p| p + 1);
    let end = src[start..].iter().position(|&b| b == b'\n').map_or(src.len(), |p| start + p);
    if start > src.len() {
        return None;
    }
    Some(&src[start..end])
}

impl fmt::Display for Diagnostic {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.render(None).trim_end())
    }
}

/// The findings about one file, or a tree of files (a `.ct` and its `.ic` files).
#[derive(Clone, Debug, Default, Serialize)]
pub struct Diagnostics {
    /// All findings, in the order they were made.
    pub items: Vec<Diagnostic>,
}

impl Diagnostics {
    /// Adds a finding.
    pub fn push(&mut self, d: Diagnostic) {
        self.items.push(d);
    }

    /// Adds all findings of `other`.
    pub fn extend(&mut self, other: Diagnostics) {
        self.items.extend(other.items);
    }

    /// True when any finding is an error.
    pub fn has_errors(&self) -> bool {
        self.items.iter().any(|d| d.severity == Severity::Error)
    }

    /// Number of findings of a severity.
    pub fn count(&self, sev: Severity) -> usize {
        self.items.iter().filter(|d| d.severity == sev).count()
    }

    /// Applies the reporting mode: under `strict`, warnings and portability findings become
    /// errors; otherwise portability findings are notes.
    pub fn apply_mode(&mut self, strict: bool) {
        for d in &mut self.items {
            if strict && (d.portability || d.severity == Severity::Warning) {
                d.severity = Severity::Error;
            } else if !strict && d.portability && d.severity != Severity::Error {
                d.severity = Severity::Note;
            }
        }
    }
}
