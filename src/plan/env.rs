//! Environment variable expansion, exactly as Performer 3.0 does it (docs/PERFORMER-REFERENCE.md §1.7).
//!
//! Only a `$` that begins a field is expanded, at most one variable per field; `$(NAME)`,
//! `${NAME}` and bare `$NAME` forms (the brackets are interchangeable); `NAME:-default` supplies a
//! default only when the variable is *unset* (a set-but-empty variable wins, unlike POSIX); a value
//! containing `:` abandons the expansion and keeps the field literally. This module also owns the
//! [`Env`] used for lookups, so tools can expand against `--env`/`--unset` without touching the
//! process environment.

use std::collections::BTreeMap;

/// Where variable values come from: overrides first, then (unless disabled) the process
/// environment.
#[derive(Clone, Debug, Default)]
pub struct Env {
    overrides: BTreeMap<String, Option<String>>,
    isolated: bool,
}

impl Env {
    /// The process environment.
    pub fn process() -> Self {
        Env::default()
    }

    /// An environment with no variables at all except those set explicitly (for tests).
    pub fn isolated() -> Self {
        Env { overrides: BTreeMap::new(), isolated: true }
    }

    /// Sets a variable (it shadows the process environment).
    pub fn set(&mut self, name: &str, value: &str) -> &mut Self {
        self.overrides.insert(name.to_string(), Some(value.to_string()));
        self
    }

    /// Unsets a variable (even if the process environment has it).
    pub fn unset(&mut self, name: &str) -> &mut Self {
        self.overrides.insert(name.to_string(), None);
        self
    }

    /// The value of a variable, `None` when unset.
    pub fn get(&self, name: &str) -> Option<String> {
        match self.overrides.get(name) {
            Some(v) => v.clone(),
            None if self.isolated => None,
            None => std::env::var_os(name).map(|v| v.to_string_lossy().into_owned()),
        }
    }
}

/// The outcome of expanding one field.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Expansion {
    /// The field after expansion (the field itself when nothing was expanded).
    pub value: String,
    /// The variable looked up, if any.
    pub variable: Option<String>,
    /// What happened, when it deserves a message.
    pub outcome: Outcome,
}

/// What the expansion did.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Outcome {
    /// No variable in the field, or the variable was set.
    Plain,
    /// The variable was unset and its `:-` default was used.
    DefaultUsed,
    /// The variable was unset and had no default: it expanded to "".
    UnsetEmpty,
    /// The value contained `:`; Performer keeps the field literally (`$` included).
    AbandonedColon,
    /// `$` followed by nothing usable (empty name): no expansion.
    EmptyName,
}

/// Expands a field per Performer 3.0's rules.
pub fn expand(field: &str, env: &Env) -> Expansion {
    let plain = |outcome| Expansion { value: field.to_string(), variable: None, outcome };
    let Some(rest) = field.strip_prefix('$') else {
        return plain(Outcome::Plain);
    };
    let bracketed = rest.starts_with('(') || rest.starts_with('{');
    let spec: &str = if bracketed {
        let inner = &rest[1..];
        match inner.find([')', '}']) {
            Some(end) => &inner[..end],
            None => inner,
        }
    } else {
        match rest.find(['.', '/']) {
            Some(end) => &rest[..end],
            None => rest,
        }
    };
    let (name, default) = match spec.find(":-") {
        Some(p) => (&spec[..p], Some(&spec[p + 2..])),
        None => (spec, None),
    };
    if name.is_empty() {
        return plain(Outcome::EmptyName);
    }
    let (value, outcome) = match env.get(name) {
        Some(v) => (v, Outcome::Plain),
        None => match default {
            Some(d) => (d.to_string(), Outcome::DefaultUsed),
            None => (String::new(), Outcome::UnsetEmpty),
        },
    };
    if value.contains(':') {
        return Expansion {
            value: field.to_string(),
            variable: Some(name.to_string()),
            outcome: Outcome::AbandonedColon,
        };
    }
    // Rule 6: what follows the variable.
    let tail = if let Some(p) = field.find([')', '}']) {
        &field[p + 1..]
    } else if let Some(p) = field.find(['.', '/']) {
        &field[p..]
    } else {
        ""
    };
    Expansion { value: format!("{value}{tail}"), variable: Some(name.to_string()), outcome }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn env() -> Env {
        let mut e = Env::isolated();
        e.set("CLIPTEST_PYR", "/mnt/pyr").set("EMPTY", "").set("COLON", "a:b");
        e
    }

    fn x(field: &str) -> String {
        expand(field, &env()).value
    }

    #[test]
    fn performer_verified_examples() {
        assert_eq!(x("$(CLIPTEST_PYR)/a"), "/mnt/pyr/a");
        assert_eq!(x("${CLIPTEST_PYR}/a"), "/mnt/pyr/a");
        assert_eq!(x("$(CLIPTEST_PYR}/a"), "/mnt/pyr/a");
        assert_eq!(x("$CLIPTEST_PYR.d/a"), "/mnt/pyr.d/a");
        assert_eq!(x("${UNSET:-/fb}/a"), "/fb/a");
        assert_eq!(x("$UNSET/a"), "/a");
        assert_eq!(x("${EMPTY:-/fb}/a"), "/a");
        assert_eq!(x("$HV:-dflt/sub/"), "dflt/sub/");
    }

    #[test]
    fn only_a_leading_variable_is_expanded() {
        assert_eq!(x("/data/$CLIPTEST_PYR"), "/data/$CLIPTEST_PYR");
        assert_eq!(x("$CLIPTEST_PYR/$CLIPTEST_PYR"), "/mnt/pyr/$CLIPTEST_PYR");
    }

    #[test]
    fn a_value_with_a_colon_keeps_the_field_literally() {
        let e = expand("$COLON/x", &env());
        assert_eq!(e.value, "$COLON/x");
        assert_eq!(e.outcome, Outcome::AbandonedColon);
    }

    #[test]
    fn empty_names_and_plain_fields_are_untouched() {
        assert_eq!(expand("$/x", &env()).outcome, Outcome::EmptyName);
        assert_eq!(x("$/x"), "$/x");
        assert_eq!(x("plain/x"), "plain/x");
        assert_eq!(expand("$UNSET/a", &env()).outcome, Outcome::UnsetEmpty);
        assert_eq!(expand("${UNSET:-/fb}/a", &env()).outcome, Outcome::DefaultUsed);
    }

    #[test]
    fn unset_override_hides_the_process_environment() {
        let mut e = Env::process();
        e.unset("PATH");
        assert_eq!(e.get("PATH"), None);
        e.set("PATH", "x");
        assert_eq!(e.get("PATH"), Some("x".into()));
    }
}
