//! Reading typed values out of a [`SyntaxFile`] with the repetition rules of docs/PERFORMER-REFERENCE.md §1.5:
//! a repeated scalar is last-wins (with a warning here), a repeated base, format (in a `.ct`) or
//! file list is an error.

use crate::config::{Diagnostic, Diagnostics, Severity, Span, Spanned, SyntaxFile, TokenId, Value};

/// A field as found in the file.
#[derive(Clone, Debug)]
pub(crate) enum Field<T> {
    /// Given, with the span of its token.
    Given(T, Span),
    /// Not in the file.
    Absent,
    /// In the file but unreadable (already reported).
    Broken,
}

impl<T> Field<T> {
    /// The value, if given.
    pub fn value(&self) -> Option<&T> {
        match self {
            Field::Given(v, _) => Some(v),
            _ => None,
        }
    }

    /// True when absent (not when broken).
    pub(crate) fn is_absent(&self) -> bool {
        matches!(self, Field::Absent)
    }
}

/// Typed access to one file, collecting findings.
pub struct Reader<'a> {
    /// The file.
    pub file: &'a SyntaxFile,
    /// Findings.
    pub diags: &'a mut Diagnostics,
}

impl<'a> Reader<'a> {
    /// A reader over `file`.
    pub fn new(file: &'a SyntaxFile, diags: &'a mut Diagnostics) -> Self {
        Reader { file, diags }
    }

    /// Reports a finding.
    pub fn push(&mut self, d: Diagnostic) {
        self.diags.push(d);
    }

    /// Whether a finding with `code` at `span` has been reported about this file already.
    pub fn reported(&self, code: &str, span: Option<Span>) -> bool {
        self.diags.items.iter().any(|d| d.code == code && d.span == span && d.path == self.file.path)
    }

    /// A new finding about this file.
    pub(crate) fn diag(
        &self,
        sev: Severity,
        code: &'static str,
        span: Option<Span>,
        msg: impl Into<String>,
    ) -> Diagnostic {
        Diagnostic::new(sev, code, &self.file.path, span, msg)
    }

    /// Warns when a scalar token is repeated (the last value wins).
    fn repeated_scalar(&mut self, id: TokenId) {
        let all: Vec<_> = self.file.all(id).collect();
        if all.len() > 1 {
            let last = all[all.len() - 1];
            let first = all[0];
            let d = self
                .diag(
                    Severity::Warning,
                    "repeated-token",
                    Some(last.span),
                    format!("`{}` is given {} times; the last one (here) wins", last.def.name, all.len()),
                )
                .hint(format!("remove the earlier one at line {}", first.span.line));
            self.push(d);
        }
    }

    /// Reports a token that may appear only once.
    pub(crate) fn unique(&mut self, id: TokenId, what: &str) {
        let all: Vec<_> = self.file.all(id).collect();
        if all.len() > 1 {
            let second = all[1];
            let d = self
                .diag(
                    Severity::Error,
                    "duplicate-token",
                    Some(second.span),
                    format!("`{}` is given twice; {what} may be given only once", second.def.name),
                )
                .hint(format!("the first one is at line {}; keep one", all[0].span.line));
            self.push(d);
        }
    }

    /// An integer scalar (last wins).
    pub fn int(&mut self, id: TokenId) -> Field<Spanned<i64>> {
        self.repeated_scalar(id);
        match self.file.last(id) {
            None => Field::Absent,
            Some(e) => match &e.value {
                Value::Int(v) => Field::Given(v.clone(), e.span),
                _ => Field::Broken,
            },
        }
    }

    /// Up to three integers (last wins).
    pub(crate) fn int3(&mut self, id: TokenId) -> Field<Vec<Spanned<i64>>> {
        self.repeated_scalar(id);
        match self.file.last(id) {
            None => Field::Absent,
            Some(e) => match &e.value {
                Value::Int3(v) => Field::Given(v.clone(), e.span),
                _ => Field::Broken,
            },
        }
    }

    /// One word (last wins unless `unique`).
    pub fn word(&mut self, id: TokenId, unique: Option<&str>) -> Field<Spanned<String>> {
        match unique {
            Some(what) => self.unique(id, what),
            None => self.repeated_scalar(id),
        }
        let e = if unique.is_some() { self.file.first(id) } else { self.file.last(id) };
        match e {
            None => Field::Absent,
            Some(e) => match &e.value {
                Value::Word(v) => Field::Given(v.clone(), e.span),
                _ => Field::Broken,
            },
        }
    }

    /// A base (at most once): the word, or "" when the token has no value.
    pub fn base(&mut self, id: TokenId) -> Field<Spanned<String>> {
        self.unique(id, "a base");
        match self.file.first(id) {
            None => Field::Absent,
            Some(e) => match &e.value {
                Value::Base(Some(v)) => Field::Given(v.clone(), e.span),
                Value::Base(None) => Field::Given(Spanned { value: String::new(), span: e.span }, e.span),
                _ => Field::Broken,
            },
        }
    }

    /// A list; `unique` makes a repetition an error, otherwise the lists are concatenated.
    pub fn list(&mut self, id: TokenId, unique: Option<&str>) -> Field<Vec<Spanned<String>>> {
        if let Some(what) = unique {
            self.unique(id, what);
            return match self.file.first(id) {
                None => Field::Absent,
                Some(e) => match &e.value {
                    Value::List(v) => Field::Given(v.clone(), e.span),
                    _ => Field::Broken,
                },
            };
        }
        let mut items = Vec::new();
        let mut span = None;
        for e in self.file.all(id) {
            span.get_or_insert(e.span);
            if let Value::List(v) = &e.value {
                items.extend(v.iter().cloned());
            }
        }
        match span {
            Some(s) => Field::Given(items, s),
            None => Field::Absent,
        }
    }

    /// Span of the first entry of a token, if any.
    pub(crate) fn span_of(&self, id: TokenId) -> Option<Span> {
        self.file.first(id).map(|e| e.span)
    }
}
