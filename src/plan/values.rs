//! Checks shared by the `.ct` and `.ic` builders: three-number sizes, non-negative integers.

use super::fields::{Field, Reader};
use super::portability;
use crate::config::{Severity, Span, Spanned};

/// How to check a three-number size.
#[derive(Clone, Copy, Debug)]
pub(crate) struct SizeRule {
    /// Each component must be a power of two.
    pub pow2: bool,
    /// Largest value of S and T.
    pub max: u64,
    /// Accept two numbers (R taken as 1) with a portability warning.
    pub allow_two: bool,
    /// R must be 1 (clipmaps are two-dimensional).
    pub r_is_one: bool,
}

/// The next power of two at or above `v` (for hints).
pub(crate) fn next_pow2(v: u64) -> u64 {
    v.checked_next_power_of_two().unwrap_or(u64::MAX)
}

/// Checks a mandatory three-number size: a missing one is an error with `hint` (what to add).
pub(crate) fn mandatory_size3(
    r: &mut Reader<'_>,
    field: &Field<Vec<Spanned<i64>>>,
    name: &str,
    hint: &str,
    rule: SizeRule,
) -> Option<[u64; 3]> {
    if field.is_absent() {
        missing(r, format!("`{name}` is missing; it is mandatory"), hint);
    }
    size3(r, field, name, rule)
}

/// Reports a mandatory field that is absent (`missing-mandatory`): `message` says which and why,
/// `hint` what to add.
pub(crate) fn missing(r: &mut Reader<'_>, message: impl Into<String>, hint: impl Into<String>) {
    let d = r.diag(Severity::Error, "missing-mandatory", Some(Span::START), message).hint(hint);
    r.push(d);
}

/// Checks a three-number size. Returns `None` (having reported why) when it is unusable.
pub(crate) fn size3(
    r: &mut Reader<'_>,
    field: &Field<Vec<Spanned<i64>>>,
    name: &str,
    rule: SizeRule,
) -> Option<[u64; 3]> {
    let (vals, span) = match field {
        Field::Given(v, s) => (v, *s),
        _ => return None,
    };
    let mut out = [1u64; 3];
    match vals.len() {
        3 => {}
        2 if rule.allow_two => {
            let d = r
                .diag(
                    Severity::Warning,
                    "size-missing-r",
                    Some(span),
                    format!("`{name}` has two numbers; R is taken as 1"),
                )
                .expected("three numbers: S T R")
                .hint(format!(
                    "write `{name} {} {} 1`: Performer 3.0 leaves R unset and fails with \"image size wasn't set\"",
                    vals[0].value, vals[1].value
                ));
            r.push(portability(d));
        }
        n => {
            let d = r
                .diag(
                    Severity::Error,
                    "size-needs-three",
                    Some(span),
                    format!("`{name}` has {n} number{}", if n == 1 { "" } else { "s" }),
                )
                .expected("three numbers: S T R")
                .hint(format!("write `{name} S T 1` (R is 1 for two-dimensional textures)"));
            r.push(d);
            return None;
        }
    }
    let mut ok = true;
    for (i, v) in vals.iter().enumerate() {
        let axis = ["S", "T", "R"][i];
        if v.value <= 0 {
            let d = r
                .diag(
                    Severity::Error,
                    "size-not-positive",
                    Some(v.span),
                    format!("{axis} of `{name}` must be positive"),
                )
                .found(v.value.to_string())
                .expected("a positive integer");
            r.push(d);
            ok = false;
            continue;
        }
        let u = v.value as u64;
        if i < 2 && u > rule.max {
            let d = r
                .diag(
                    Severity::Error,
                    "size-too-large",
                    Some(v.span),
                    format!("{axis} of `{name}` is larger than this reader's limit of {}", rule.max),
                )
                .found(v.value.to_string());
            r.push(d);
            ok = false;
            continue;
        }
        if rule.pow2 && !u.is_power_of_two() {
            let lower = next_pow2(u) / 2;
            let d = r
                .diag(
                    Severity::Error,
                    "size-not-power-of-two",
                    Some(v.span),
                    format!("{axis} of `{name}` must be a power of two"),
                )
                .found(v.value.to_string())
                .expected("a power of two")
                .hint(format!("the nearest powers of two are {lower} and {}", next_pow2(u)));
            r.push(d);
            ok = false;
            continue;
        }
        out[i] = u;
    }
    if ok && rule.r_is_one && out[2] != 1 {
        let d = r
            .diag(
                Severity::Error,
                "three-dimensional",
                Some(vals[2].span),
                format!("R of `{name}` is {}; only two-dimensional textures (R = 1) are supported", out[2]),
            )
            .found(out[2].to_string())
            .expected("1");
        r.push(d);
        ok = false;
    }
    ok.then_some(out)
}

/// A non-negative integer with a default. Negative values are errors.
pub(crate) fn non_negative(
    r: &mut Reader<'_>,
    field: &Field<Spanned<i64>>,
    name: &str,
    default: u64,
    defaulted: &mut Vec<&'static str>,
    key: &'static str,
) -> Option<u64> {
    match field {
        Field::Given(v, _) if v.value < 0 => {
            let d = r
                .diag(Severity::Error, "negative-value", Some(v.span), format!("`{name}` cannot be negative"))
                .found(v.value.to_string())
                .expected("0 or a positive integer");
            r.push(d);
            None
        }
        Field::Given(v, _) => Some(v.value as u64),
        Field::Absent => {
            defaulted.push(key);
            Some(default)
        }
        Field::Broken => None,
    }
}

/// The span of a field's token, if given.
pub(crate) fn span_of<T>(field: &Field<T>) -> Option<Span> {
    match field {
        Field::Given(_, s) => Some(*s),
        _ => None,
    }
}
