//! File names: environment expansion of fields, printf formats checked against their parameter
//! lists, and anchoring relative names to the configuration file's directory.
//!
//! The rule (docs/PERFORMER-REFERENCE.md §1.8, the documented intent): expand each field, build the final name
//! (base + list entry, or the printf output), then anchor it to the directory of the file that
//! named it if it does not start with `/`.

use super::env::{self, Env, Outcome};
use super::fields::Reader;
use super::params::{Param, ParamRef};
use super::printf::{Arg, ArgType, Format};
use crate::config::{Severity, Span, Spanned};
use crate::place::{Place, RemoteName};
use serde::Serialize;
use std::path::{Path, PathBuf};

/// Notes that `value` (the field at `span`, after expansion) is a remote location: an extension
/// Performer would not follow, so a portability finding (an error under `--strict`).
pub(crate) fn note_remote(r: &mut Reader<'_>, span: Span, value: &str, what: &str) {
    // A field read twice (no-.ic mode names tiles and pyramid files with one format) is
    // reported once.
    if RemoteName::parse(value).is_none() || r.reported("remote-location", Some(span)) {
        return;
    }
    let d = r
        .diag(
            Severity::Note,
            "remote-location",
            Some(span),
            format!("{what} is a remote location, an extension of this reader; Performer 3.0 would take it for a relative file name"),
        )
        .found(value.to_string())
        .hint("for files Performer must read, copy the tiles to a local disk and name them by path");
    r.push(super::portability(d));
}

/// Where a rendered or listed name lives: the one place the plan decides local or remote
/// ([`Place::anchored`]: a relative local name is joined to `dir`; absolute names and remote
/// locations, docs/CONFIG.md §15, are kept as written).
pub(crate) fn anchor(dir: &Path, name: &str) -> Place {
    Place::anchored(dir, name)
}

/// Expands `$VAR` at the start of a field, reporting what deserves a message.
pub(crate) fn expand_field(r: &mut Reader<'_>, field: &Spanned<String>, env: &Env) -> String {
    let x = env::expand(&field.value, env);
    note_remote(r, field.span, &x.value, "the name");
    let var = x.variable.clone().unwrap_or_default();
    match x.outcome {
        Outcome::Plain | Outcome::DefaultUsed => {}
        Outcome::UnsetEmpty => {
            let d = r
                .diag(
                    Severity::Warning,
                    "unset-variable",
                    Some(field.span),
                    format!("environment variable `{var}` is not set; it expands to nothing"),
                )
                .found(field.value.clone())
                .hint(format!("set `{var}`, or give a default: `${{{var}:-DIR}}`"));
            r.push(d);
        }
        Outcome::AbandonedColon => {
            let d = r
                .diag(Severity::Warning, "variable-value-has-colon", Some(field.span), format!("the value of `{var}` contains `:`, so (as in Performer) the field is used literally, `$` included"))
                .found(field.value.clone())
                .hint(format!("give `{var}` a single directory, without `:`"));
            r.push(d);
        }
        Outcome::EmptyName => {
            let d = r
                .diag(
                    Severity::Warning,
                    "empty-variable-name",
                    Some(field.span),
                    "`$` is followed by no variable name; the field is used literally",
                )
                .found(field.value.clone());
            r.push(d);
        }
    }
    x.value
}

/// Where a parameter list is used, which decides the parameters it may name.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Scope {
    /// `.ct` `icache_params`: names of level `.ic` files.
    CtIcache,
    /// `.ct` `tile_params` for pyramid files (in no-`.ic` mode also image cache tiles).
    CtTile {
        /// The same list also names image cache tiles (no-`.ic` mode).
        no_ic: bool,
    },
    /// `.ic` `tile_params`.
    Ic,
}

impl Scope {
    fn max_params(self) -> usize {
        match self {
            Scope::Ic => 16,
            _ => 6,
        }
    }

    fn token(self) -> &'static str {
        match self {
            Scope::CtIcache => "icache_params",
            _ => "tile_params",
        }
    }
}

/// Checks a format and its parameter list. Reports every problem; returns the parsed pair when
/// both are usable.
pub fn check_format(
    r: &mut Reader<'_>,
    format: &Spanned<String>,
    expanded: &str,
    params: &[Spanned<String>],
    params_span: Option<Span>,
    scope: Scope,
) -> Option<(Format, Vec<ParamRef>)> {
    let mut ok = true;
    let parsed = match Format::parse(expanded) {
        Ok(f) => Some(f),
        Err(e) => {
            let d = r
                .diag(
                    Severity::Error,
                    "bad-format",
                    Some(format.span),
                    format!("the file-name format has a bad conversion at character {}: {}", e.offset + 1, e.message),
                )
                .found(format.value.clone())
                .expected("printf conversions %d %i %u %x %X %o %c %s (with flags, width, precision) or %%");
            r.push(d);
            None
        }
    };
    let token = scope.token();
    if params.len() > scope.max_params() {
        let d = r.diag(
            Severity::Error,
            "too-many-params",
            params_span,
            format!(
                "`{token}` names {} parameters; at most {} are allowed in {}",
                params.len(),
                scope.max_params(),
                if scope == Scope::Ic { "an .ic file" } else { "a .ct file" }
            ),
        );
        r.push(d);
        ok = false;
    }
    let mut refs = Vec::new();
    for p in params {
        let Some(param) = Param::from_name(&p.value) else {
            let mut d = r
                .diag(
                    Severity::Error,
                    "unknown-param",
                    Some(p.span),
                    format!("`{}` is not a file-name parameter", p.value),
                )
                .found(p.value.clone())
                .expected("a PFIMAGECACHE_TILE_FILENAMEARG_* or PFCLIPTEX_FNAMEARG_* name");
            if let Some(s) = Param::suggest(&p.value) {
                d = d.hint(format!("did you mean `{s}`?"));
            }
            r.push(d);
            ok = false;
            continue;
        };
        let refusal = match (scope, param) {
            (Scope::Ic, _) if Param::is_cliptex_spelling(&p.value) => Some("clip-texture parameters (PFCLIPTEX_*) cannot be used in an .ic file".to_string()),
            (Scope::CtIcache | Scope::CtTile { .. }, Param::StreamServerName) => Some("stream servers are not supported in clip texture (.ct) file names".to_string()),
            (Scope::CtTile { .. }, Param::ImageCacheBase) => Some("PFCLIPTEX_FNAMEARG_IMAGE_CACHE_BASE has no meaning in `tile_params` (Performer 3.0 crashes on it); use PFCLIPTEX_FNAMEARG_TILE_BASE".to_string()),
            (Scope::CtIcache, Param::CacheName) => Some("the tile base has no meaning in `icache_params` (Performer 3.0 crashes on it); use PFCLIPTEX_FNAMEARG_IMAGE_CACHE_BASE".to_string()),
            (Scope::CtTile { no_ic: true }, Param::Level) => Some("PFCLIPTEX_FNAMEARG_LEVEL has no meaning for image cache tiles in no-.ic mode (the same `tile_params` names them); use PFIMAGECACHE_TILE_FILENAMEARG_VSIZE_S to tell levels apart".to_string()),
            _ => None,
        };
        if let Some(msg) = refusal {
            let d = r.diag(Severity::Error, "param-not-allowed", Some(p.span), msg).found(p.value.clone());
            r.push(d);
            ok = false;
            continue;
        }
        refs.push(ParamRef { param, name: p.value.clone(), span: p.span });
    }
    let parsed = parsed?;
    if !ok {
        return None;
    }
    let convs: Vec<_> = parsed.conversions().cloned().collect();
    if convs.len() != refs.len() {
        let d = r
            .diag(Severity::Error, "param-count-mismatch", Some(format.span), format!("the format has {} conversion{} but `{token}` names {} parameter{}", convs.len(), if convs.len() == 1 { "" } else { "s" }, refs.len(), if refs.len() == 1 { "" } else { "s" }))
            .found(format.value.clone())
            .hint("give one parameter per conversion, in order (`%%` is a literal percent sign and takes none); Performer 3.0 does not check this and makes garbage names");
        r.push(d);
        return None;
    }
    for (c, p) in convs.iter().zip(&refs) {
        if c.arg_type() != p.param.arg_type() {
            let (want, have) = match p.param.arg_type() {
                ArgType::Int => ("%d (or another integer conversion)", "an integer"),
                ArgType::Str => ("%s", "a string"),
            };
            let d = r
                .diag(
                    Severity::Error,
                    "param-type-mismatch",
                    Some(p.span),
                    format!("conversion `{}` does not fit parameter `{}`, which is {have}", c.text, p.name),
                )
                .expected(want)
                .hint("change the conversion or reorder the parameters");
            r.push(d);
            ok = false;
        }
    }
    ok.then_some((parsed, refs))
}

/// How an image cache names its tile files.
#[derive(Clone, Debug, Serialize)]
pub struct TileNaming {
    /// The format after expansion.
    pub format: String,
    /// True when the default `%s%s.%d.r%03d.c%03d.raw888` is used.
    pub default_format: bool,
    /// The parameters, in order.
    pub params: Vec<Param>,
    /// The cache name (`tile_base` after expansion; CACHENAME).
    pub cache_name: String,
    /// Directory relative names are anchored to.
    pub dir: PathBuf,
    #[serde(skip)]
    pub(super) parsed: Format,
}

impl TileNaming {
    /// The default format and parameters of an image cache.
    pub fn default_format(cache_name: String, dir: PathBuf) -> TileNaming {
        let text = "%s%s.%d.r%03d.c%03d.raw888";
        TileNaming {
            format: text.into(),
            default_format: true,
            params: vec![Param::StreamServerName, Param::CacheName, Param::VsizeS, Param::TilenumT, Param::TilenumS],
            cache_name,
            dir,
            parsed: Format::parse(text).expect("the default format parses"),
        }
    }

    /// A checked format.
    pub fn new(parsed: Format, params: Vec<Param>, cache_name: String, dir: PathBuf) -> TileNaming {
        TileNaming { format: parsed.text.clone(), default_format: false, params, cache_name, dir, parsed }
    }

    /// Renders a name with a value for each parameter, anchored (`anchor`).
    pub fn render(&self, value: impl Fn(Param) -> Arg) -> Place {
        let args: Vec<Arg> = self.params.iter().map(|&p| value(p)).collect();
        anchor(&self.dir, &self.parsed.render(&args))
    }
}
