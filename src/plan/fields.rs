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

    /// The `#clipmap KEY VALUE` lines whose KEY is one of `keys`, as (key, value), in the file's
    /// order. Lines without a value are left out: the paging reader reports every `#clipmap`
    /// line's shape.
    pub(crate) fn extension_settings(&self, keys: &[&str]) -> Vec<(Spanned<String>, Spanned<String>)> {
        let line = |l: &crate::config::syntax::Extension| Some((l.words.first()?.clone(), l.words.get(1)?.clone()));
        self.file.extensions.iter().filter_map(line).filter(|(k, _)| keys.contains(&k.value.as_str())).collect()
    }

    /// The value of the file's one `#clipmap KEY VALUE` line, and where its key is written; each
    /// further such line is a `duplicate-extension` error that expects `one`. `None` when there
    /// is none.
    pub(crate) fn single_extension(&mut self, key: &str, one: &str) -> Option<(Spanned<String>, Span)> {
        let mut found: Option<(Spanned<String>, Span)> = None;
        for (k, value) in self.extension_settings(&[key]) {
            if let Some((_, first)) = &found {
                let d = self
                    .diag(
                        Severity::Error,
                        "duplicate-extension",
                        Some(k.span),
                        format!("`#clipmap {key}` is given twice"),
                    )
                    .found(value.value.clone())
                    .expected(one)
                    .hint(format!("keep one `#clipmap {key}` line; the first one is at line {}", first.line));
                self.push(d);
                continue;
            }
            found = Some((value, k.span));
        }
        found
    }

    /// A `bad-extension-value` error at `value`, the value of `#clipmap KEY` that is no value of
    /// it, saying what is `expected`.
    pub(crate) fn bad_extension_value(
        &mut self,
        key: &Spanned<String>,
        value: &Spanned<String>,
        expected: impl Into<String>,
    ) {
        let d = self
            .diag(
                Severity::Error,
                "bad-extension-value",
                Some(value.span),
                format!("`{}` is no value for `#clipmap {}`", value.value, key.value),
            )
            .found(value.value.clone())
            .expected(expected);
        self.push(d);
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
