//! printf-style file-name formats (`tile_format`, `icache_format`): parsing, checking against the
//! parameter list, and rendering.
//!
//! Performer passes the format to C `sprintf` unchecked, so a wrong parameter count or type gives
//! garbage names or crashes (docs/PERFORMER-REFERENCE.md §1.6). We parse every conversion (flags, width,
//! precision, length modifiers, `%%`), check count and type against the parameter list before any
//! file is named, and render with the same semantics as C for the conversions file names use.
//! Written here rather than taken from a crate because the checks need the position of each
//! conversion and its expected argument type, which runtime-printf crates do not expose.

use nom::branch::alt;
use nom::bytes::complete::{tag, take_while, take_while1};
use nom::character::complete::{digit1, one_of};
use nom::combinator::{map, opt};
use nom::sequence::preceded;
use nom::IResult;

/// The type of argument a conversion consumes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum ArgType {
    /// `d i u x X o c`.
    Int,
    /// `s`.
    Str,
}

/// One `%…` conversion.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Conversion {
    /// Byte offset of the `%` in the format.
    pub offset: usize,
    /// The conversion as written (`%03d`).
    pub text: String,
    /// Flags (`-`, `0`, `+`, space, `#`).
    pub flags: String,
    /// Minimum width.
    pub width: Option<usize>,
    /// Precision.
    pub precision: Option<usize>,
    /// Conversion character.
    pub conv: char,
}

impl Conversion {
    /// The argument type this conversion needs.
    pub(crate) fn arg_type(&self) -> ArgType {
        if self.conv == 's' {
            ArgType::Str
        } else {
            ArgType::Int
        }
    }
}

/// A piece of a parsed format.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Piece {
    /// Literal text (`%%` already turned into `%`).
    Lit(String),
    /// A conversion.
    Conv(Conversion),
}

/// A parsed format.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Format {
    /// The format as written.
    pub text: String,
    /// Its pieces.
    pub pieces: Vec<Piece>,
}

/// A format that could not be parsed.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct FormatError {
    /// Byte offset of the bad conversion.
    pub offset: usize,
    /// What is wrong.
    pub message: String,
}

/// An argument value.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Arg {
    /// An integer parameter.
    Int(i64),
    /// A string parameter.
    Str(String),
}

/// A conversion's parts as written: flags, width, precision and the conversion character.
type ConvParts<'a> = (&'a str, Option<&'a str>, Option<&'a str>, char);

fn conversion(input: &str) -> IResult<&str, ConvParts<'_>> {
    let (input, _) = tag("%")(input)?;
    let (input, flags) = take_while(|c| "-0+ #".contains(c))(input)?;
    let (input, width) = opt(digit1)(input)?;
    let (input, precision) = opt(preceded(tag("."), map(opt(digit1), |d: Option<&str>| d.unwrap_or("0"))))(input)?;
    let (input, _) = opt(alt((tag("hh"), tag("ll"), tag("h"), tag("l"), tag("z"), tag("j"), tag("t"))))(input)?;
    let (input, conv) = one_of("diuxXocs")(input)?;
    Ok((input, (flags, width, precision, conv)))
}

fn literal(input: &str) -> IResult<&str, &str> {
    take_while1(|c| c != '%')(input)
}

impl Format {
    /// Parses a format string.
    pub fn parse(text: &str) -> Result<Format, FormatError> {
        let mut pieces = Vec::new();
        let mut rest = text;
        let mut lit = String::new();
        while !rest.is_empty() {
            let offset = text.len() - rest.len();
            if let Ok((r, l)) = literal(rest) {
                lit.push_str(l);
                rest = r;
                continue;
            }
            if let Some(r) = rest.strip_prefix("%%") {
                lit.push('%');
                rest = r;
                continue;
            }
            match conversion(rest) {
                Ok((r, (flags, width, precision, conv))) => {
                    if !lit.is_empty() {
                        pieces.push(Piece::Lit(std::mem::take(&mut lit)));
                    }
                    let parse_num = |s: Option<&str>| -> Result<Option<usize>, FormatError> {
                        match s {
                            None => Ok(None),
                            Some(s) => s.parse::<usize>().ok().filter(|&n| n <= 255).map(Some).ok_or(FormatError {
                                offset,
                                message: format!("width or precision `{s}` is too large (at most 255)"),
                            }),
                        }
                    };
                    pieces.push(Piece::Conv(Conversion {
                        offset,
                        text: rest[..rest.len() - r.len()].to_string(),
                        flags: flags.to_string(),
                        width: parse_num(width)?,
                        precision: parse_num(precision)?,
                        conv,
                    }));
                    rest = r;
                }
                Err(_) => {
                    let shown: String = rest.chars().take(6).collect();
                    let message = if rest.starts_with("%*")
                        || rest[1..].starts_with(|c: char| c.is_ascii_digit()) && rest.contains('*')
                    {
                        format!("`{shown}`: a width or precision taken from an argument (`*`) is not supported")
                    } else if rest.len() == 1 {
                        "a lone `%` at the end of the format (write `%%` for a percent sign)".to_string()
                    } else {
                        format!("`{shown}` is not a conversion this reader supports (d, i, u, x, X, o, c, s, or %% for a percent sign)")
                    };
                    return Err(FormatError { offset, message });
                }
            }
        }
        if !lit.is_empty() {
            pieces.push(Piece::Lit(lit));
        }
        Ok(Format { text: text.to_string(), pieces })
    }

    /// The conversions, in order.
    pub fn conversions(&self) -> impl Iterator<Item = &Conversion> {
        self.pieces.iter().filter_map(|p| match p {
            Piece::Conv(c) => Some(c),
            Piece::Lit(_) => None,
        })
    }

    /// Renders the format with `args` (which must match the conversions in count and type: the
    /// plan checks this before rendering; a mismatch renders as an empty field).
    pub fn render(&self, args: &[Arg]) -> String {
        let mut out = String::new();
        let mut i = 0;
        for p in &self.pieces {
            match p {
                Piece::Lit(l) => out.push_str(l),
                Piece::Conv(c) => {
                    if let Some(a) = args.get(i) {
                        out.push_str(&render_one(c, a));
                    }
                    i += 1;
                }
            }
        }
        out
    }
}

fn pad(body: String, sign: &str, c: &Conversion, zero_ok: bool) -> String {
    let width = c.width.unwrap_or(0);
    let len = body.chars().count() + sign.len();
    if len >= width {
        return format!("{sign}{body}");
    }
    let fill = width - len;
    if c.flags.contains('-') {
        format!("{sign}{body}{}", " ".repeat(fill))
    } else if c.flags.contains('0') && zero_ok {
        format!("{sign}{}{body}", "0".repeat(fill))
    } else {
        format!("{}{sign}{body}", " ".repeat(fill))
    }
}

fn render_one(c: &Conversion, arg: &Arg) -> String {
    match (c.conv, arg) {
        ('s', Arg::Str(s)) => {
            let body: String = match c.precision {
                Some(p) => s.chars().take(p).collect(),
                None => s.clone(),
            };
            pad(body, "", c, false)
        }
        ('c', Arg::Int(v)) => pad(char::from(*v as u8).to_string(), "", c, false),
        (conv, Arg::Int(v)) => {
            let v = *v;
            let (neg, mag) = (v < 0, v.unsigned_abs());
            let mut digits = match conv {
                'x' => format!("{:x}", if neg { v as u32 as u64 } else { mag }),
                'X' => format!("{:X}", if neg { v as u32 as u64 } else { mag }),
                'o' => format!("{:o}", if neg { v as u32 as u64 } else { mag }),
                'u' if neg => format!("{}", v as u32),
                _ => mag.to_string(),
            };
            let signed = matches!(conv, 'd' | 'i');
            if let Some(p) = c.precision {
                if p == 0 && v == 0 {
                    digits.clear();
                } else if digits.len() < p {
                    digits = format!("{}{digits}", "0".repeat(p - digits.len()));
                }
            }
            if c.flags.contains('#') && v != 0 {
                match conv {
                    'x' => digits = format!("0x{digits}"),
                    'X' => digits = format!("0X{digits}"),
                    'o' if !digits.starts_with('0') => digits = format!("0{digits}"),
                    _ => {}
                }
            }
            let sign = if signed && neg {
                "-"
            } else if signed && c.flags.contains('+') {
                "+"
            } else if signed && c.flags.contains(' ') {
                " "
            } else {
                ""
            };
            pad(digits, sign, c, c.precision.is_none())
        }
        _ => String::new(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn r(fmt: &str, args: &[Arg]) -> String {
        Format::parse(fmt).unwrap().render(args)
    }

    #[test]
    fn renders_like_c() {
        use Arg::*;
        assert_eq!(
            r("%s%s.%d.r%03d.c%03d.raw888", &[Str("/".into()), Str("usr/t".into()), Int(16384), Int(4), Int(16)]),
            "/usr/t.16384.r004.c016.raw888"
        );
        assert_eq!(r("%5d|%-5d|%05d", &[Int(42), Int(42), Int(-42)]), "   42|42   |-0042");
        assert_eq!(
            r("%+d % d %.3d %x %X %#x %o", &[Int(7), Int(7), Int(7), Int(255), Int(255), Int(255), Int(8)]),
            "+7  7 007 ff FF 0xff 10"
        );
        assert_eq!(r("100%% %s", &[Str("done".into())]), "100% done");
        assert_eq!(r("%.2s|%4s|%-4s|", &[Str("abc".into()), Str("ab".into()), Str("ab".into())]), "ab|  ab|ab  |");
        assert_eq!(r("%ld %lld %hd", &[Int(1), Int(2), Int(3)]), "1 2 3");
        assert_eq!(r("%08.3d", &[Int(5)]), "     005");
    }

    #[test]
    fn conversions_are_counted_and_typed() {
        let f = Format::parse("a%%b%s%03dx").unwrap();
        let convs: Vec<_> = f.conversions().map(|c| (c.offset, c.arg_type())).collect();
        assert_eq!(convs, vec![(4, ArgType::Str), (6, ArgType::Int)]);
    }

    #[test]
    fn bad_conversions_are_reported_with_offsets() {
        assert_eq!(Format::parse("ab%q").unwrap_err().offset, 2);
        assert!(Format::parse("x%*d").unwrap_err().message.contains('*'));
        assert!(Format::parse("x%").unwrap_err().message.contains("lone"));
        assert!(Format::parse("%999d").unwrap_err().message.contains("too large"));
    }
}
