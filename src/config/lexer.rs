//! Splits configuration bytes into whitespace-separated words, each with its span.
//!
//! Words are what Performer's `%s` reads: runs of bytes that are not ASCII whitespace. The lexer
//! is lazy (a hostile file never becomes a huge vector of words) and caps the length of a word at
//! [`Limits::max_word_bytes`](super::Limits), reporting the full length so the parser can say so.

use super::diag::Span;

/// One word of the file.
#[derive(Clone, Debug)]
pub struct Word<'a> {
    /// The bytes of the word (possibly not UTF-8).
    pub bytes: &'a [u8],
    /// Where it is.
    pub span: Span,
}

impl Word<'_> {
    /// The word as text, when it is UTF-8.
    pub fn text(&self) -> Option<&str> {
        std::str::from_utf8(self.bytes).ok()
    }

    /// The word for messages: lossy UTF-8, shortened when long.
    pub fn shown(&self) -> String {
        shorten(&String::from_utf8_lossy(self.bytes))
    }
}

/// Shortens a string for a message (at most 60 characters).
pub(crate) fn shorten(s: &str) -> String {
    if s.chars().count() <= 60 {
        s.to_string()
    } else {
        let head: String = s.chars().take(57).collect();
        format!("{head}...")
    }
}

/// A lazy word iterator with one word of look-ahead.
pub(crate) struct Lexer<'a> {
    src: &'a [u8],
    pos: usize,
    line: u32,
    line_start: usize,
    peeked: Option<Word<'a>>,
}

impl<'a> Lexer<'a> {
    /// A lexer over `src`.
    pub fn new(src: &'a [u8]) -> Self {
        Lexer { src, pos: 0, line: 1, line_start: 0, peeked: None }
    }

    fn scan(&mut self) -> Option<Word<'a>> {
        let src = self.src;
        while self.pos < src.len() && src[self.pos].is_ascii_whitespace() {
            if src[self.pos] == b'\n' {
                self.line += 1;
                self.line_start = self.pos + 1;
            }
            self.pos += 1;
        }
        if self.pos >= src.len() {
            return None;
        }
        let start = self.pos;
        while self.pos < src.len() && !src[self.pos].is_ascii_whitespace() {
            self.pos += 1;
        }
        let span = Span {
            line: self.line,
            col: (start - self.line_start + 1).min(u32::MAX as usize) as u32,
            offset: start,
            len: self.pos - start,
        };
        Some(Word { bytes: &src[start..self.pos], span })
    }

    /// The next word.
    pub(crate) fn next_word(&mut self) -> Option<Word<'a>> {
        self.peeked.take().or_else(|| self.scan())
    }

    /// The next word, without consuming it.
    pub(crate) fn peek(&mut self) -> Option<&Word<'a>> {
        if self.peeked.is_none() {
            self.peeked = self.scan();
        }
        self.peeked.as_ref()
    }

    /// Skips the rest of the line `line` (a comment). A comment ended by the end of the file is
    /// fine.
    pub(crate) fn skip_line(&mut self, line: u32) {
        if let Some(p) = &self.peeked {
            if p.span.line != line {
                return;
            }
            self.peeked = None;
        }
        if self.line != line {
            return;
        }
        while self.pos < self.src.len() && self.src[self.pos] != b'\n' {
            self.pos += 1;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn words_carry_lines_and_columns() {
        let mut lx = Lexer::new(b"ct_version2.0\n  clip_size\t512\n");
        let a = lx.next_word().unwrap();
        assert_eq!((a.text(), a.span.line, a.span.col), (Some("ct_version2.0"), 1, 1));
        let b = lx.next_word().unwrap();
        assert_eq!((b.text(), b.span.line, b.span.col), (Some("clip_size"), 2, 3));
        let c = lx.next_word().unwrap();
        assert_eq!((c.text(), c.span.line, c.span.col), (Some("512"), 2, 13));
        assert!(lx.next_word().is_none());
    }

    #[test]
    fn skip_line_stops_at_newline_and_at_end_of_file() {
        let mut lx = Lexer::new(b"# a b c\nx # tail");
        let w = lx.next_word().unwrap();
        lx.skip_line(w.span.line);
        let x = lx.next_word().unwrap();
        assert_eq!(x.text(), Some("x"));
        let h = lx.next_word().unwrap();
        lx.skip_line(h.span.line);
        assert!(lx.next_word().is_none());
    }
}
