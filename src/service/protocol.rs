//! The control socket's line protocol, as pure functions: parse one request line, format replies.
//!
//! One request per line (`\n`-terminated, at most [`super::ControlLimits::max_line`] bytes,
//! UTF-8, words separated by spaces, command names case-insensitive). Every reply starts with
//! `OK` or `ERR`; see `docs/SHM.md` ("Control socket") for the whole table. Talking to the
//! socket and to the tick loop is [`super::control`]'s business.

/// A parsed request.
#[derive(Clone, Debug, PartialEq)]
pub enum Request {
    /// `PING`: `OK pong`.
    Ping,
    /// `STATUS`: `OK {json}`.
    Status,
    /// `STATS`: `OK {json}`.
    Stats,
    /// `STATS PROM`: `OK prometheus <n>` followed by n lines of Prometheus text.
    StatsProm,
    /// `BUDGET <ms>` or `BUDGET off`: the copy budget per tick.
    Budget(Option<f64>),
    /// `BORDER <texels>`: the invalid border.
    Border(u64),
    /// `CENTRE <s> <t>` (or `CENTER`): the level-0 clip centre.
    Centre([i64; 2]),
    /// `QUIT`: closes this connection.
    Quit,
    /// `SHUTDOWN`: stops the service.
    Shutdown,
}

/// Largest copy budget accepted, in milliseconds.
pub const MAX_BUDGET_MS: f64 = 10_000.0;

/// The commands, for error messages.
pub const COMMANDS: &str =
    "PING, STATUS, STATS, STATS PROM, BUDGET <ms>|off, BORDER <texels>, CENTRE <s> <t>, QUIT, SHUTDOWN";

/// Parses one line (without its newline; a trailing `\r` is ignored). The error is the message
/// of the `ERR` reply.
pub fn parse(line: &[u8]) -> Result<Request, String> {
    let line = std::str::from_utf8(line).map_err(|_| "request is not UTF-8 text".to_string())?;
    let line = line.strip_suffix('\r').unwrap_or(line);
    let words: Vec<&str> = line.split_ascii_whitespace().collect();
    let Some((cmd, args)) = words.split_first() else {
        return Err(format!("empty request; expected one of {COMMANDS}"));
    };
    let cmd = cmd.to_ascii_uppercase();
    let arity = |n: usize, usage: &str| -> Result<(), String> {
        if args.len() == n {
            Ok(())
        } else {
            Err(format!("{cmd} takes {n} argument{}: {usage}", if n == 1 { "" } else { "s" }))
        }
    };
    match cmd.as_str() {
        "PING" => arity(0, "PING").map(|_| Request::Ping),
        "STATUS" => arity(0, "STATUS").map(|_| Request::Status),
        "STATS" => match args {
            [] => Ok(Request::Stats),
            [f] if f.eq_ignore_ascii_case("PROM") => Ok(Request::StatsProm),
            _ => Err("usage: STATS or STATS PROM".to_string()),
        },
        "BUDGET" => {
            arity(1, "BUDGET <milliseconds> or BUDGET off")?;
            if args[0].eq_ignore_ascii_case("off") {
                return Ok(Request::Budget(None));
            }
            match args[0].parse::<f64>() {
                Ok(ms) if (crate::limits::MIN_BUDGET_MS..=MAX_BUDGET_MS).contains(&ms) => Ok(Request::Budget(Some(ms))),
                _ => Err(format!(
                    "BUDGET: `{}` is not a number of milliseconds in [{}, {MAX_BUDGET_MS}] or `off`",
                    clip(args[0]),
                    crate::limits::MIN_BUDGET_MS
                )),
            }
        }
        "BORDER" => {
            arity(1, "BORDER <texels>")?;
            args[0]
                .parse::<u64>()
                .map(Request::Border)
                .map_err(|_| format!("BORDER: `{}` is not a whole number of texels", clip(args[0])))
        }
        "CENTRE" | "CENTER" => {
            arity(2, "CENTRE <s> <t>")?;
            let p = |w: &str| w.parse::<i64>().map_err(|_| format!("CENTRE: `{}` is not an integer", clip(w)));
            Ok(Request::Centre([p(args[0])?, p(args[1])?]))
        }
        "QUIT" => arity(0, "QUIT").map(|_| Request::Quit),
        "SHUTDOWN" => arity(0, "SHUTDOWN").map(|_| Request::Shutdown),
        _ => Err(format!("unknown command `{}`; expected one of {COMMANDS}", clip(&cmd))),
    }
}

/// At most 40 characters of a word, for error messages (replies stay short whatever was sent).
fn clip(w: &str) -> String {
    let mut s: String = w.chars().take(40).filter(|c| !c.is_control()).collect();
    if w.chars().count() > 40 {
        s.push('…');
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn requests_parse() {
        let cases: &[(&str, Request)] = &[
            ("PING", Request::Ping),
            ("status", Request::Status),
            ("STATS", Request::Stats),
            ("stats prom", Request::StatsProm),
            ("BUDGET 2.5", Request::Budget(Some(2.5))),
            ("BUDGET off", Request::Budget(None)),
            ("BORDER 16\r", Request::Border(16)),
            ("CENTRE -5 1000", Request::Centre([-5, 1000])),
            ("center 1 2", Request::Centre([1, 2])),
            ("  QUIT  ", Request::Quit),
            ("SHUTDOWN", Request::Shutdown),
        ];
        for (line, want) in cases {
            assert_eq!(parse(line.as_bytes()).as_ref(), Ok(want), "{line}");
        }
    }

    #[test]
    fn malformed_requests_say_what_was_expected() {
        let cases: &[(&[u8], &str)] = &[
            (b"", "empty request"),
            (b"FOO", "unknown command `FOO`"),
            (b"\xff\xfe", "not UTF-8"),
            (b"BUDGET", "takes 1 argument"),
            (b"BUDGET -1", "not a number of milliseconds"),
            (b"BUDGET NaN", "not a number of milliseconds"),
            (b"BUDGET 1e9", "not a number of milliseconds"),
            (b"BORDER x", "not a whole number"),
            (b"BORDER -3", "not a whole number"),
            (b"CENTRE 1", "takes 2 arguments"),
            (b"CENTRE 1 99999999999999999999", "not an integer"),
            (b"STATS JSON", "usage: STATS"),
            (b"PING now", "takes 0 arguments"),
        ];
        for (line, want) in cases {
            let err = parse(line).unwrap_err();
            assert!(err.contains(want), "{:?}: {err}", String::from_utf8_lossy(line));
        }
        let long = format!("X{}", "y".repeat(5000));
        assert!(parse(long.as_bytes()).unwrap_err().len() < 200, "error replies stay short");
    }
}
