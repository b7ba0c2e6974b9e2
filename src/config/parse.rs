//! The parser: words → [`SyntaxFile`], with every problem reported (not only the first).
//!
//! It matches tokens as whole words, reads each token's arguments by its [`ArgShape`], and
//! recovers after an error by skipping to the next word that is a token, so one mistake gives one
//! message, not a cascade.

use super::diag::{Diagnostic, Diagnostics, Severity, Span};
use super::lexer::{shorten, Lexer, Word};
use super::syntax::{Entry, Extension, Spanned, SyntaxFile, Value};
use super::tokens::{self, ArgShape, FileKind, TokenDef, TokenId};
use super::Limits;
use std::path::Path;

/// The first word of an extension line: a comment to Performer 3.0 (`#`), whatever follows.
pub(crate) const EXTENSION_MARK: &str = "#clipmap";

struct Parser<'a, 'p> {
    lx: Lexer<'a>,
    path: &'p Path,
    kind: FileKind,
    limits: &'p Limits,
    diags: Diagnostics,
    entries: Vec<Entry>,
    extensions: Vec<Extension>,
    stopped: bool,
}

/// Parses `src` as a file of `kind`. Returns the tree (possibly partial) and all findings.
pub fn parse(src: &[u8], path: &Path, kind: FileKind, limits: &Limits) -> (SyntaxFile, Diagnostics) {
    let mut p = Parser {
        lx: Lexer::new(src),
        path,
        kind,
        limits,
        diags: Diagnostics::default(),
        entries: Vec::new(),
        extensions: Vec::new(),
        stopped: false,
    };
    let binary = binary_kind(src);
    let too_large = src.len() > limits.max_file_bytes;
    // A known magic number says more than the length; the length more than binary bytes.
    if let Some(what) = binary.filter(|w| !too_large || *w != BINARY) {
        // One finding, not a cascade of words cut out of binary data (and no line of it shown).
        let d = Diagnostic::new(
            Severity::Error,
            "not-text",
            path,
            None,
            format!(
                "the file is {what}, not {} {} configuration file; none of it was read",
                if kind == FileKind::ImageCache { "an" } else { "a" },
                kind.noun()
            ),
        )
        .expected("a text file of tokens")
        .hint(binary_hint(what, path));
        p.push(d);
    } else if too_large {
        p.error(
            "file-too-large",
            Some(Span::START),
            format!(
                "the file is {} bytes, more than the limit of {} bytes for a configuration file",
                src.len(),
                limits.max_file_bytes
            ),
        );
    } else {
        p.run();
    }
    let file = SyntaxFile { path: path.to_path_buf(), kind, entries: p.entries, extensions: p.extensions };
    (file, p.diags)
}

/// Binary data that is told from a configuration by its first bytes, in words.
const MAGIC: [(&[u8], &str); 8] = [
    (b"II*\0", TIFF),
    (b"MM\0*", TIFF),
    (b"II+\0", TIFF),
    (b"MM\0+", TIFF),
    (b"\x89PNG\r\n\x1a\n", "a PNG image"),
    (b"\xff\xd8\xff", "a JPEG image"),
    (b"\x28\xb5\x2f\xfd", "zstd-compressed data"),
    (b"\x1f\x8b", "gzip-compressed data"),
];

/// What [`binary_kind`] calls data that is not text and has no known magic number.
const BINARY: &str = "binary data";

/// What [`binary_kind`] calls a TIFF or BigTIFF file.
const TIFF: &str = "a TIFF image (a GeoTIFF or COG)";

/// What `src` is when it is binary data rather than text: a known magic number at its start, or
/// a start of which more than a quarter is control bytes (NUL and the like; tabs, line ends and
/// form feeds are text). A text file with a stray odd byte is not binary: it is parsed and the
/// word that holds the byte is reported where it is.
fn binary_kind(src: &[u8]) -> Option<&'static str> {
    if let Some((_, what)) = MAGIC.iter().find(|(m, _)| src.starts_with(m)) {
        return Some(what);
    }
    let head = &src[..src.len().min(512)];
    let control = head.iter().filter(|&&b| b < 0x20 && !matches!(b, b'\t' | b'\n' | b'\r' | 0x0c)).count();
    (head.len() >= 16 && control * 4 > head.len()).then_some(BINARY)
}

/// What to do instead of reading `path`, binary data of kind `what`, as a configuration.
fn binary_hint(what: &str, path: &Path) -> String {
    let p = path.display();
    match what {
        TIFF => format!(
            "a GeoTIFF or COG is served as it is, with no configuration: `cliptex info {p}` shows the texture it is served as, `cliptex check {p}` reads and checks every tile, `cliptex roam {p}` flies it, `clipmapd {p}` serves it; `clipprep --input {p} --config-only` writes a configuration that names it (docs/COG.md)"
        ),
        "a PNG image" | "a JPEG image" => {
            format!("prepare it into a clip texture first: `clipprep --input {p} --tile 256 --clip 512 --format rgb8 --out DIR`")
        }
        _ => "name the configuration file itself (a .ct or .ic file is text)".to_string(),
    }
}

impl<'a> Parser<'a, '_> {
    fn push(&mut self, d: Diagnostic) {
        if self.stopped {
            return;
        }
        if self.diags.items.len() + 1 >= self.limits.max_diagnostics {
            self.diags.push(Diagnostic::new(
                Severity::Error,
                "too-many-diagnostics",
                self.path,
                d.span,
                format!("too many problems ({}); stopping here", self.limits.max_diagnostics),
            ));
            self.stopped = true;
            return;
        }
        self.diags.push(d);
    }

    fn error(&mut self, code: &'static str, span: Option<Span>, msg: impl Into<String>) {
        let d = Diagnostic::new(Severity::Error, code, self.path, span, msg);
        self.push(d);
    }

    fn diag(&self, sev: Severity, code: &'static str, span: Span, msg: impl Into<String>) -> Diagnostic {
        Diagnostic::new(sev, code, self.path, Some(span), msg)
    }

    /// Decodes a word as UTF-8, reporting it otherwise.
    fn text(&mut self, w: &Word<'a>) -> Option<String> {
        if w.bytes.len() > self.limits.max_word_bytes {
            let d = self
                .diag(
                    Severity::Error,
                    "word-too-long",
                    w.span,
                    format!(
                        "a word of {} bytes is longer than the limit of {} bytes",
                        w.bytes.len(),
                        self.limits.max_word_bytes
                    ),
                )
                .found(w.shown())
                .hint(
                    "configuration values cannot contain whitespace and are short; is this a binary or a mangled file?",
                );
            self.push(d);
            return None;
        }
        match w.text() {
            Some(t) => Some(t.to_string()),
            None => {
                let d = self
                    .diag(Severity::Error, "not-utf8", w.span, "this word is not valid UTF-8")
                    .found(w.shown())
                    .expected("text in UTF-8")
                    .hint("save the file as UTF-8 (or ASCII); file names with other encodings must be renamed");
                self.push(d);
                None
            }
        }
    }

    fn is_token_word(w: &Word<'_>) -> bool {
        match w.text() {
            Some(t) => tokens::lookup(t).is_some() || tokens::is_comment_in_value_position(t),
            None => false,
        }
    }

    fn run(&mut self) {
        while let Some(w) = self.lx.next_word() {
            if self.stopped {
                return;
            }
            let Some(text) = self.text(&w) else { continue };
            if text == EXTENSION_MARK {
                self.extension(w.span);
                continue;
            }
            if tokens::is_comment_start(&text) {
                self.lx.skip_line(w.span.line);
                continue;
            }
            match tokens::lookup(&text) {
                Some(def) => self.entry(def, w.span),
                None => self.unknown(&text, w.span),
            }
            if self.entries.len() > self.limits.max_entries {
                self.error(
                    "too-many-entries",
                    Some(w.span),
                    format!("more than {} tokens in one file; stopping here", self.limits.max_entries),
                );
                self.stopped = true;
            }
        }
    }

    /// Reads the words after `#clipmap` on its line (at most a few: the rest is skipped).
    fn extension(&mut self, span: Span) {
        let mut words = Vec::new();
        while self.lx.peek().is_some_and(|w| w.span.line == span.line) {
            let w = self.lx.next_word().expect("peeked");
            if words.len() < 4 {
                if let Some(t) = self.text(&w) {
                    words.push(Spanned { value: t, span: w.span });
                }
            }
        }
        self.extensions.push(Extension { span, words });
    }

    fn unknown(&mut self, text: &str, span: Span) {
        let mut d = self
            .diag(
                Severity::Error,
                "unknown-token",
                span,
                format!("`{}` is not a {} token", shorten(text), self.kind.noun()),
            )
            .found(shorten(text))
            .expected("a token name");
        if let Some((def, rest)) = tokens::glued(text) {
            d = d.hint(format!("put a space between the token and its value: `{} {}`", def.name, shorten(rest)));
        } else if let Some(s) = tokens::suggest(text, self.kind) {
            d = d.hint(format!("did you mean `{s}`?"));
        } else if text.parse::<i64>().is_ok() {
            d = d.hint("a number here means the previous token got more values than it takes, or a token before it is misspelled");
        }
        self.push(d);
    }

    fn entry(&mut self, def: &'static TokenDef, span: Span) {
        let allowed = match self.kind {
            FileKind::ClipTexture => def.in_ct,
            FileKind::ImageCache => def.in_ic,
        };
        if !allowed {
            let (other, tool) = match self.kind {
                FileKind::ClipTexture => ("an image cache (.ic)", "icache"),
                FileKind::ImageCache => ("a clip texture (.ct)", "cliptex"),
            };
            let code = if matches!(def.id, TokenId::CtVersion | TokenId::IcVersion) {
                "wrong-file-kind"
            } else {
                "token-not-allowed"
            };
            let mut d = self.diag(
                Severity::Error,
                code,
                span,
                format!("`{}` belongs in {other} file, not in a {} file", def.name, self.kind.noun()),
            );
            d = if code == "wrong-file-kind" {
                d.hint(format!("this looks like {other} file: check it with `{tool} validate`"))
            } else {
                d.hint(format!("move `{}` to the file where it belongs, or remove it", def.name))
            };
            self.push(d);
        }
        let value = self.args(def, span);
        if def.obsolete {
            let d = self.diag(
                Severity::Note,
                "obsolete-token",
                span,
                format!("`{}` is obsolete; Performer ignores it and so do we", def.name),
            );
            self.push(d);
        }
        if allowed {
            self.entries.push(Entry { def, span, value });
        }
    }

    fn args(&mut self, def: &'static TokenDef, span: Span) -> Value {
        match def.args {
            ArgShape::None => Value::None,
            ArgShape::Int => match self.int(def, span, true) {
                Some(v) => Value::Int(v),
                None => Value::Missing,
            },
            ArgShape::Int3 => self.int3(def, span),
            ArgShape::Format | ArgShape::Word => match self.word(def, span) {
                Some(v) => Value::Word(v),
                None => Value::Missing,
            },
            ArgShape::Base => self.base(),
            ArgShape::List => self.list(def, span),
            ArgShape::ReadFunc => self.read_func(def, span),
            ArgShape::SkipWords => {
                while let Some(w) = self.lx.peek() {
                    if Self::is_token_word(w) {
                        break;
                    }
                    self.lx.next_word();
                }
                Value::Ignored
            }
            ArgShape::NumStreams => {
                // The manual gives three integers ("the modulo number for the s, t and r
                // directions"); older files give one or none. All are read and ignored.
                let line = span.line;
                for _ in 0..3 {
                    if !self
                        .lx
                        .peek()
                        .is_some_and(|w| w.span.line == line && w.text().is_some_and(|t| t.parse::<i64>().is_ok()))
                    {
                        break;
                    }
                    self.lx.next_word();
                }
                let next = self.lx.peek().map(|w| (w.span, w.shown(), w.text().is_some_and(tokens::is_comment_start)));
                if let Some((wspan, shown, is_comment)) = next {
                    if wspan.line == line && !is_comment {
                        let mut d = self
                            .diag(Severity::Warning, "num-streams-swallows-line", wspan, "Performer 3.0 treats `num_streams` as a comment and drops the rest of its line, including this")
                            .found(shown)
                            .hint("put `num_streams` on a line of its own, or remove it: the number of stream servers is the length of the stream lists");
                        d.portability = true;
                        self.push(d);
                    }
                }
                Value::Ignored
            }
        }
    }

    /// Skips comments between values (our extension; Performer stops reading the token there).
    fn skip_value_comments(&mut self, def: &'static TokenDef) {
        loop {
            let Some(w) = self.lx.peek() else { return };
            let Some(t) = w.text() else { return };
            if !tokens::is_comment_in_value_position(t) {
                return;
            }
            let span = w.span;
            // A comment only counts as "inside" the arguments if more arguments follow it.
            self.lx.skip_line(span.line);
            let more = self.lx.peek().is_some_and(|n| !Self::is_token_word(n));
            if more {
                let mut d = self
                    .diag(
                        Severity::Warning,
                        "comment-inside-arguments",
                        span,
                        format!(
                            "a comment inside the arguments of `{}`: Performer 3.0 stops reading the token here",
                            def.name
                        ),
                    )
                    .hint("move the comment after the last argument");
                d.portability = true;
                self.push(d);
            }
        }
    }

    fn parse_int(&mut self, w: &Word<'a>, def: &'static TokenDef) -> Option<Spanned<i64>> {
        let text = self.text(w)?;
        match parse_c_int(&text) {
            Ok(v) => Some(Spanned { value: v, span: w.span }),
            Err(IntError::Overflow) => {
                let d = self
                    .diag(
                        Severity::Error,
                        "number-out-of-range",
                        w.span,
                        format!("the value of `{}` is out of range", def.name),
                    )
                    .found(shorten(&text))
                    .expected("an integer between -2^63 and 2^63-1");
                self.push(d);
                None
            }
            Err(IntError::NotANumber) => {
                let mut d = self
                    .diag(Severity::Error, "expected-integer", w.span, format!("`{}` takes an integer", def.name))
                    .found(shorten(&text))
                    .expected("an integer");
                let digits: String =
                    text.chars().take_while(|c| c.is_ascii_digit() || *c == '-' || *c == '+').collect();
                if !digits.is_empty() && digits.len() < text.len() {
                    d = d.hint(format!(
                        "Performer 3.0 would read `{digits}` and then fail on `{}`; write the number alone",
                        shorten(&text[digits.len()..])
                    ));
                }
                self.push(d);
                None
            }
        }
    }

    fn int(&mut self, def: &'static TokenDef, span: Span, required: bool) -> Option<Spanned<i64>> {
        self.skip_value_comments(def);
        match self.lx.peek() {
            Some(w) if !Self::is_token_word(w) => {
                let w = self.lx.next_word().expect("peeked");
                self.parse_int(&w, def)
            }
            other => {
                if required {
                    let found = other.map(|w| w.shown());
                    let mut d = self
                        .diag(Severity::Error, "missing-value", span, format!("`{}` needs an integer value", def.name))
                        .expected("an integer after the token");
                    if let Some(f) = found {
                        d = d.found(f);
                    } else {
                        d = d.found("end of file");
                    }
                    self.push(d);
                }
                None
            }
        }
    }

    fn int3(&mut self, def: &'static TokenDef, span: Span) -> Value {
        let mut vals = Vec::with_capacity(3);
        for i in 0..3 {
            self.skip_value_comments(def);
            let next_is_int =
                self.lx.peek().is_some_and(|w| !Self::is_token_word(w) && w.text().is_some_and(looks_numeric));
            if !next_is_int {
                if i == 0 {
                    // No number at all: report what is there (or the end of file).
                    if let Some(w) = self.lx.peek() {
                        if !Self::is_token_word(w) {
                            let w = self.lx.next_word().expect("peeked");
                            self.parse_int(&w, def);
                            return Value::Missing;
                        }
                    }
                    let d = self
                        .diag(
                            Severity::Error,
                            "missing-value",
                            span,
                            format!("`{}` needs three integers (S T R)", def.name),
                        )
                        .expected("three integers after the token");
                    self.push(d);
                    return Value::Missing;
                }
                break;
            }
            let w = self.lx.next_word().expect("peeked");
            match self.parse_int(&w, def) {
                Some(v) => vals.push(v),
                None => return Value::Missing,
            }
        }
        Value::Int3(vals)
    }

    fn word(&mut self, def: &'static TokenDef, span: Span) -> Option<Spanned<String>> {
        self.skip_value_comments(def);
        match self.lx.peek() {
            Some(w) if !Self::is_token_word(w) => {
                let w = self.lx.next_word().expect("peeked");
                let text = self.text(&w)?;
                Some(Spanned { value: text, span: w.span })
            }
            other => {
                let found = other.map(|w| w.shown()).unwrap_or_else(|| "end of file".into());
                let what = if def.args == ArgShape::Format { "a format name or number" } else { "a value" };
                let d = self
                    .diag(Severity::Error, "missing-value", span, format!("`{}` needs {what}", def.name))
                    .found(found)
                    .expected(format!("{what} after the token"));
                self.push(d);
                None
            }
        }
    }

    fn base(&mut self) -> Value {
        match self.lx.peek() {
            Some(w) if !Self::is_token_word(w) => {
                let w = self.lx.next_word().expect("peeked");
                match self.text(&w) {
                    Some(t) => Value::Base(Some(Spanned { value: t, span: w.span })),
                    None => Value::Missing,
                }
            }
            _ => Value::Base(None),
        }
    }

    fn list(&mut self, def: &'static TokenDef, span: Span) -> Value {
        let mut items = Vec::new();
        while let Some(w) = self.lx.peek() {
            let Some(t) = w.text() else {
                let w = self.lx.next_word().expect("peeked");
                self.text(&w);
                continue;
            };
            if tokens::is_comment_in_value_position(t) {
                let line = w.span.line;
                let cspan = w.span;
                let same_line_as_item = items.last().is_some_and(|i: &Spanned<String>| i.span.line == line)
                    || (items.is_empty() && span.line == line);
                self.lx.skip_line(line);
                let more = self.lx.peek().is_some_and(|n| !Self::is_token_word(n));
                if more && !same_line_as_item {
                    let mut d = self
                        .diag(Severity::Warning, "comment-inside-list", cspan, format!("a comment line inside the list of `{}`: Performer 3.0 ends the list here and fails on the items after it", def.name))
                        .hint("move the comment before the token or after the list");
                    d.portability = true;
                    self.push(d);
                }
                continue;
            }
            if tokens::lookup(t).is_some() {
                break;
            }
            let w = self.lx.next_word().expect("peeked");
            if items.len() >= self.limits.max_list_items {
                if items.len() == self.limits.max_list_items {
                    let d = self.diag(
                        Severity::Error,
                        "list-too-long",
                        w.span,
                        format!("the list of `{}` has more than {} items", def.name, self.limits.max_list_items),
                    );
                    self.push(d);
                }
                items.push(Spanned { value: String::new(), span: w.span });
                continue;
            }
            if let Some(text) = self.text(&w) {
                if let Some(similar) = looks_like_token(&text) {
                    let d = self
                        .diag(Severity::Warning, "list-item-looks-like-token", w.span, format!("list item `{}` of `{}` looks like a misspelled token", shorten(&text), def.name))
                        .hint(format!("did you mean `{similar}`? A list runs until the next token, so a misspelled token and its values become list items"));
                    self.push(d);
                }
                if tokens::is_comment_start(&text) {
                    let mut d = self
                        .diag(
                            Severity::Warning,
                            "value-starts-with-comment-marker",
                            w.span,
                            format!("`{}` starts with `//`, which Performer 3.0 reads as a comment", shorten(&text)),
                        )
                        .hint("write the path differently (for example with a single leading slash)");
                    d.portability = true;
                    self.push(d);
                }
                items.push(Spanned { value: text, span: w.span });
            }
        }
        if items.len() > self.limits.max_list_items {
            items.truncate(self.limits.max_list_items);
        }
        Value::List(items)
    }

    fn read_func(&mut self, def: &'static TokenDef, span: Span) -> Value {
        let mut items = Vec::new();
        while items.len() < 2 {
            match self.lx.peek() {
                Some(w) if w.span.line == span.line && !Self::is_token_word(w) => {
                    let w = self.lx.next_word().expect("peeked");
                    if let Some(t) = self.text(&w) {
                        items.push(Spanned { value: t, span: w.span });
                    }
                }
                _ => break,
            }
        }
        if items.is_empty() {
            let d = self
                .diag(
                    Severity::Error,
                    "missing-value",
                    span,
                    format!("`{}` needs a function name (`read_func NAME` or `read_func LIBRARY NAME`)", def.name),
                )
                .expected("one or two words on the same line");
            self.push(d);
            return Value::Missing;
        }
        Value::List(items)
    }
}

/// Why a word is not a C `%d` integer.
#[derive(Debug, PartialEq, Eq)]
pub(crate) enum IntError {
    /// Not an optional sign followed by decimal digits.
    NotANumber,
    /// Does not fit in 64 bits.
    Overflow,
}

/// Parses a whole word as a C-style decimal integer (optional sign, digits).
pub(crate) fn parse_c_int(text: &str) -> Result<i64, IntError> {
    use nom::character::complete::{digit1, one_of};
    use nom::combinator::{all_consuming, opt, recognize};
    use nom::sequence::pair;
    let parsed: nom::IResult<&str, &str> = all_consuming(recognize(pair(opt(one_of("+-")), digit1)))(text);
    match parsed {
        Ok((_, s)) => s.parse::<i64>().map_err(|_| IntError::Overflow),
        Err(_) => Err(IntError::NotANumber),
    }
}

fn looks_numeric(t: &str) -> bool {
    let t = t.strip_prefix(['+', '-']).unwrap_or(t);
    t.starts_with(|c: char| c.is_ascii_digit())
}

/// A list item within a small edit distance of a token name, that is not a plausible file name.
fn looks_like_token(item: &str) -> Option<&'static str> {
    if item.contains(['.', '/', '$', '%']) || item.starts_with("PF") {
        return None;
    }
    tokens::TOKENS.iter().filter(|d| d.name.len() > 4 && strsim::levenshtein(item, d.name) <= 2).map(|d| d.name).next()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn c_integers() {
        assert_eq!(parse_c_int("512"), Ok(512));
        assert_eq!(parse_c_int("-3"), Ok(-3));
        assert_eq!(parse_c_int("+7"), Ok(7));
        assert_eq!(parse_c_int("512abc"), Err(IntError::NotANumber));
        assert_eq!(parse_c_int("0x10"), Err(IntError::NotANumber));
        assert_eq!(parse_c_int("99999999999999999999"), Err(IntError::Overflow));
        assert_eq!(parse_c_int(""), Err(IntError::NotANumber));
    }
}
