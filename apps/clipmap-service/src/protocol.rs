//! The control socket's line protocol, as pure functions: parse one request line, render replies.
//!
//! One request per line (`\n`-terminated, at most [`super::ControlLimits::max_line`] bytes,
//! UTF-8, words separated by spaces, command names case-insensitive). Every reply starts with
//! `OK` or `ERR`; see `docs/SHM.md` ("Control socket") for the whole table. Talking to the
//! socket and to the tick loop is [`super::control`]'s business; what the service answers, and
//! the text of each answer, is the `replies` room's.

mod replies;

pub use replies::{render, Answer, Refusal, Refused, Reply, Unanswered};

/// Whether a connection goes on after a reply.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Flow {
    /// It reads the next request.
    Continue,
    /// It closes after the reply.
    Close,
}

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
    /// `CENTRE LONLAT <lon> <lat>` (or `CENTER`): the level-0 clip centre at a WGS 84 longitude /
    /// latitude (degrees, finite), through the texture's georeferencing (docs/GEOREF.md).
    CentreLonLat([f64; 2]),
    /// `VIEW ...`: a command for one view (docs/VIEWS.md).
    View(ViewCommand),
    /// `VIEWS`: `OK {json}`, the views and their figures.
    Views,
    /// `QUIT`: closes this connection.
    Quit,
    /// `SHUTDOWN`: stops the service.
    Shutdown,
    /// `PATCH FILE <path>`: a growing texture takes the patch a sidecar file on the service's
    /// machine describes (docs/GROWING.md); `OK patch <id>` once it is durable.
    PatchFile(String),
    /// `PATCH DATA <bytes> <json>`: the same with the description on the line and the image's
    /// (or raw texels') bytes, exactly `<bytes>` of them, right after it.
    PatchData {
        /// Bytes that follow the line.
        bytes: u64,
        /// The description (JSON, one line).
        json: String,
    },
}

/// A command for one view, as `VIEW ...` asks (docs/VIEWS.md).
#[derive(Clone, Debug, PartialEq)]
pub enum ViewCommand {
    /// `VIEW ADD <name> [<weight>] [own]`: a further view, weight 1 by default; `own`: with grids
    /// of its own (docs/VIEWS.md, "Views far apart").
    Add {
        /// Its name.
        name: String,
        /// Its weight.
        weight: f64,
        /// With grids of its own.
        own: bool,
    },
    /// `VIEW REMOVE <name>`.
    Remove {
        /// The view.
        name: String,
    },
    /// `VIEW CENTRE <name> <s> <t>` (or `CENTER`): a view's level-0 centre (`main`: the primary).
    Centre {
        /// The view.
        name: String,
        /// Its centre.
        centre: [i64; 2],
    },
    /// `VIEW CENTRE <name> LONLAT <lon> <lat>` (or `CENTER`): a view's centre at a WGS 84
    /// longitude / latitude (degrees, finite).
    CentreLonLat {
        /// The view.
        name: String,
        /// Its centre's longitude and latitude.
        lonlat: [f64; 2],
    },
    /// `VIEW WEIGHT <name> <weight>`.
    Weight {
        /// The view.
        name: String,
        /// Its weight.
        weight: f64,
    },
    /// `VIEW LOD <name> <offset> [<effective>|all]`: the levels a view shows (docs/VIEWS.md,
    /// "Virtual views"); effective `all` (the default) or 1 and more.
    Lod {
        /// The view.
        name: String,
        /// Its LOD offset.
        offset: u32,
        /// Levels it addresses at once (`None`: all).
        effective: Option<u32>,
    },
    /// `VIEW HEIGHT <name> <height> <pixel angle> [<effective>]`: a LOD request as the request
    /// mapping's (docs/SHM.md, "Asking for a view's levels"), for those who cannot take its lock
    /// words (Python).
    Height {
        /// The view.
        name: String,
        /// Its height above the surface, level-0 texels.
        height: f64,
        /// A pixel's angle, radians.
        pixel_angle: f64,
        /// Levels it addresses at once (0: all).
        effective: u32,
    },
}

pub use clipmap::limits::MAX_BUDGET_MS;

/// The commands, for error messages.
pub(crate) const COMMANDS: &str =
    "PING, STATUS, STATS, STATS PROM, BUDGET <ms>|off, BORDER <texels>, CENTRE <s> <t>, VIEW ..., VIEWS, PATCH FILE <path>, PATCH DATA <bytes> <json>, QUIT, SHUTDOWN";

/// Why a request line was refused; its text is the message of the `ERR` reply (words quoted
/// from the request are cut to 40 characters).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum BadRequest {
    /// The line is not UTF-8.
    #[error("request is not UTF-8 text")]
    NotUtf8,
    /// Nothing but blanks.
    #[error("empty request; expected one of {COMMANDS}")]
    Empty,
    /// A command with the wrong number of arguments.
    #[error("{command} takes {count} argument{}: {usage}", if *count == 1 { "" } else { "s" })]
    Arity {
        /// The command, upper case.
        command: String,
        /// Arguments it takes.
        count: usize,
        /// Its usage.
        usage: &'static str,
    },
    /// `STATS` with something other than `PROM`.
    #[error("usage: STATS or STATS PROM")]
    Stats,
    /// A budget that is not a number of milliseconds in range, nor `off`.
    #[error("BUDGET: `{0}` is not a number of milliseconds in [{min}, {MAX_BUDGET_MS}] or `off`", min = clipmap::limits::MIN_BUDGET_MS)]
    Budget(String),
    /// A border that is not a whole number.
    #[error("BORDER: `{0}` is not a whole number of texels")]
    Border(String),
    /// A centre coordinate that is not an integer.
    #[error("CENTRE: `{0}` is not an integer")]
    Centre(String),
    /// A `CENTRE LONLAT` longitude or latitude that is not a finite number.
    #[error(
        "CENTRE LONLAT: `{0}` is not a finite number of degrees (usage: CENTRE LONLAT <longitude> <latitude>, WGS 84)"
    )]
    CentreLonLat(String),
    /// No such command.
    #[error("unknown command `{0}`; expected one of {COMMANDS}")]
    Unknown(String),
    /// A `VIEW` request of the wrong shape, or a bad name or weight.
    #[error("{0}; usage: VIEW ADD <name> [<weight>] [own], VIEW REMOVE <name>, VIEW CENTRE <name> <s> <t>, VIEW CENTRE <name> LONLAT <lon> <lat>, VIEW WEIGHT <name> <weight>, VIEW LOD <name> <offset> [<effective>|all], VIEW HEIGHT <name> <height> <pixel angle> [<effective>]")]
    View(String),
    /// A `PATCH` request of the wrong shape.
    #[error("usage: PATCH FILE <path of a sidecar .json> or PATCH DATA <bytes> <json description> followed by the bytes ({0})")]
    Patch(String),
}

/// Parses one line (without its newline; a trailing `\r` is ignored).
pub fn parse(line: &[u8]) -> Result<Request, BadRequest> {
    let line = std::str::from_utf8(line).map_err(|_| BadRequest::NotUtf8)?;
    let line = line.strip_suffix('\r').unwrap_or(line);
    let words: Vec<&str> = line.split_ascii_whitespace().collect();
    let Some((cmd, args)) = words.split_first() else {
        return Err(BadRequest::Empty);
    };
    let cmd = cmd.to_ascii_uppercase();
    let arity = |count: usize, usage: &'static str| -> Result<(), BadRequest> {
        if args.len() == count {
            Ok(())
        } else {
            Err(BadRequest::Arity { command: clip(&cmd), count, usage })
        }
    };
    match cmd.as_str() {
        "PING" => arity(0, "PING").map(|_| Request::Ping),
        "STATUS" => arity(0, "STATUS").map(|_| Request::Status),
        "STATS" => match args {
            [] => Ok(Request::Stats),
            [f] if f.eq_ignore_ascii_case("PROM") => Ok(Request::StatsProm),
            _ => Err(BadRequest::Stats),
        },
        "BUDGET" => {
            arity(1, "BUDGET <milliseconds> or BUDGET off")?;
            if args[0].eq_ignore_ascii_case("off") {
                return Ok(Request::Budget(None));
            }
            match args[0].parse::<f64>() {
                Ok(ms) if (clipmap::limits::MIN_BUDGET_MS..=MAX_BUDGET_MS).contains(&ms) => {
                    Ok(Request::Budget(Some(ms)))
                }
                _ => Err(BadRequest::Budget(clip(args[0]))),
            }
        }
        "BORDER" => {
            arity(1, "BORDER <texels>")?;
            args[0].parse::<u64>().map(Request::Border).map_err(|_| BadRequest::Border(clip(args[0])))
        }
        "CENTRE" | "CENTER" if args.first().is_some_and(|w| w.eq_ignore_ascii_case("LONLAT")) => {
            if args.len() != 3 {
                return Err(BadRequest::Arity {
                    command: format!("{} LONLAT", clip(&cmd)),
                    count: 2,
                    usage: "CENTRE LONLAT <longitude> <latitude>",
                });
            }
            let d = |w: &str| degrees(w).ok_or_else(|| BadRequest::CentreLonLat(clip(w)));
            Ok(Request::CentreLonLat([d(args[1])?, d(args[2])?]))
        }
        "CENTRE" | "CENTER" => {
            arity(2, "CENTRE <s> <t> or CENTRE LONLAT <longitude> <latitude>")?;
            let p = |w: &str| w.parse::<i64>().map_err(|_| BadRequest::Centre(clip(w)));
            Ok(Request::Centre([p(args[0])?, p(args[1])?]))
        }
        "PATCH" => {
            let mode = args.first().map(|w| w.to_ascii_uppercase());
            match (mode.as_deref(), args.len()) {
                (Some("FILE"), n) if n >= 2 => {
                    // The path is the rest of the line after `FILE` (it may hold spaces).
                    let rest = line.trim_start();
                    let rest = rest[rest.find(char::is_whitespace).unwrap_or(rest.len())..].trim_start();
                    let path = rest[4..].trim();
                    Ok(Request::PatchFile(path.to_string()))
                }
                (Some("DATA"), n) if n >= 3 => {
                    let bytes = args[1]
                        .parse::<u64>()
                        .map_err(|_| BadRequest::Patch(format!("`{}` is not a byte count", clip(args[1]))))?;
                    let at = line.find('{').ok_or_else(|| BadRequest::Patch("no JSON description".into()))?;
                    Ok(Request::PatchData { bytes, json: line[at..].trim_end().to_string() })
                }
                _ => Err(BadRequest::Patch(format!("got {} argument(s)", args.len()))),
            }
        }
        "VIEW" => view(args).map(Request::View),
        "VIEWS" => arity(0, "VIEWS").map(|_| Request::Views),
        "QUIT" => arity(0, "QUIT").map(|_| Request::Quit),
        "SHUTDOWN" => arity(0, "SHUTDOWN").map(|_| Request::Shutdown),
        _ => Err(BadRequest::Unknown(clip(&cmd))),
    }
}

/// `VIEW ...` (the words after `VIEW`).
fn view(args: &[&str]) -> Result<ViewCommand, BadRequest> {
    let bad = |why: String| BadRequest::View(why);
    let name = |w: &str, main_ok: bool| -> Result<String, BadRequest> {
        if main_ok && w == clipmap::shm::layout::views::PRIMARY_NAME {
            return Ok(w.to_string());
        }
        clipmap::shm::layout::views::check_name(w).map_err(|why| bad(clip_owned(why)))?;
        Ok(w.to_string())
    };
    let weight = |w: &str| -> Result<f64, BadRequest> {
        match w.parse::<f64>() {
            Ok(x) if x.is_finite() && x > 0.0 => Ok(x),
            _ => Err(bad(format!("weight `{}`: expected a positive finite number such as 1 or 3", clip(w)))),
        }
    };
    let sub = args.first().map(|w| w.to_ascii_uppercase());
    match (sub.as_deref(), &args[1.min(args.len())..]) {
        (Some("ADD"), [n]) => Ok(ViewCommand::Add { name: name(n, false)?, weight: 1.0, own: false }),
        (Some("ADD"), [n, o]) if o.eq_ignore_ascii_case("own") => {
            Ok(ViewCommand::Add { name: name(n, false)?, weight: 1.0, own: true })
        }
        (Some("ADD"), [n, w]) => Ok(ViewCommand::Add { name: name(n, false)?, weight: weight(w)?, own: false }),
        (Some("ADD"), [n, w, o]) if o.eq_ignore_ascii_case("own") => {
            Ok(ViewCommand::Add { name: name(n, false)?, weight: weight(w)?, own: true })
        }
        (Some("REMOVE"), [n]) => Ok(ViewCommand::Remove { name: name(n, false)? }),
        (Some("CENTRE" | "CENTER"), [n, l, lon, lat]) if l.eq_ignore_ascii_case("LONLAT") => {
            let d = |w: &str| degrees(w).ok_or_else(|| bad(format!("`{}` is not a finite number of degrees", clip(w))));
            Ok(ViewCommand::CentreLonLat { name: name(n, true)?, lonlat: [d(lon)?, d(lat)?] })
        }
        (Some("CENTRE" | "CENTER"), [_, l, rest @ ..]) if l.eq_ignore_ascii_case("LONLAT") => Err(bad(format!(
            "VIEW CENTRE <name> LONLAT takes a longitude and a latitude, got {} number(s)",
            rest.len()
        ))),
        (Some("CENTRE" | "CENTER"), [n, s, t]) => {
            let p = |w: &str| w.parse::<i64>().map_err(|_| bad(format!("`{}` is not an integer", clip(w))));
            Ok(ViewCommand::Centre { name: name(n, true)?, centre: [p(s)?, p(t)?] })
        }
        (Some("WEIGHT"), [n, w]) => Ok(ViewCommand::Weight { name: name(n, true)?, weight: weight(w)? }),
        (Some("LOD"), [n, o, rest @ ..]) if rest.len() <= 1 => {
            let offset = o.parse::<u32>().map_err(|_| {
                bad(format!("LOD offset `{}`: expected a level number, 0 (the finest) or more", clip(o)))
            })?;
            let effective = match rest.first() {
                None => None,
                Some(e) if e.eq_ignore_ascii_case("all") => None,
                Some(e) => match e.parse::<u32>() {
                    Ok(x) if x >= 1 => Some(x),
                    _ => return Err(bad(format!("effective levels `{}`: expected 1 or more, or all", clip(e)))),
                },
            };
            Ok(ViewCommand::Lod { name: name(n, true)?, offset, effective })
        }
        (Some("HEIGHT"), [n, h, a, rest @ ..]) if rest.len() <= 1 => {
            let num = |w: &str, what: &str, max: f64| match w.parse::<f64>() {
                Ok(x) if x.is_finite() && x > 0.0 && x < max => Ok(x),
                _ => Err(bad(format!(
                    "{what} `{}`: expected a finite number above 0{}",
                    clip(w),
                    if max.is_finite() { " and below pi" } else { "" }
                ))),
            };
            let height = num(h, "height", f64::INFINITY)?;
            let angle = num(a, "pixel angle", std::f64::consts::PI)?;
            let effective = match rest.first() {
                None => 0,
                Some(e) => e
                    .parse::<u32>()
                    .map_err(|_| bad(format!("effective levels `{}`: expected 0 (all) or more", clip(e))))?,
            };
            Ok(ViewCommand::Height { name: name(n, true)?, height, pixel_angle: angle, effective })
        }
        (Some(other @ ("ADD" | "REMOVE" | "CENTRE" | "CENTER" | "WEIGHT" | "LOD" | "HEIGHT")), rest) => {
            Err(bad(format!("VIEW {other} with {} argument(s)", rest.len())))
        }
        (Some(other), _) => Err(bad(format!("unknown VIEW command `{}`", clip(other)))),
        (None, _) => Err(bad("VIEW alone".to_string())),
    }
}

/// A finite number of degrees (`nan`, `inf` and what does not parse: `None`).
fn degrees(w: &str) -> Option<f64> {
    w.parse::<f64>().ok().filter(|x| x.is_finite())
}

fn clip_owned(s: String) -> String {
    if s.chars().count() > 200 {
        s.chars().take(200).collect()
    } else {
        s
    }
}

/// Whether `line` is a `PATCH DATA` request, well formed or not: bytes follow such a line, so a
/// refused one closes the connection rather than read those bytes as requests.
pub(crate) fn announces_data(line: &[u8]) -> bool {
    let mut words = line.split(|b| b.is_ascii_whitespace()).filter(|w| !w.is_empty());
    matches!(
        (words.next(), words.next()),
        (Some(a), Some(b)) if a.eq_ignore_ascii_case(b"PATCH") && b.eq_ignore_ascii_case(b"DATA")
    )
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
        let add = |name: &str, weight, own| Request::View(ViewCommand::Add { name: name.into(), weight, own });
        let lod =
            |name: &str, offset, effective| Request::View(ViewCommand::Lod { name: name.into(), offset, effective });
        let height = |name: &str, height, pixel_angle, effective| {
            Request::View(ViewCommand::Height { name: name.into(), height, pixel_angle, effective })
        };
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
            ("CENTRE LONLAT 13.4 52.5", Request::CentreLonLat([13.4, 52.5])),
            ("center lonlat -122.42 -37.77", Request::CentreLonLat([-122.42, -37.77])),
            (
                "VIEW CENTRE left LONLAT 180 -85",
                Request::View(ViewCommand::CentreLonLat { name: "left".into(), lonlat: [180.0, -85.0] }),
            ),
            (
                "view center main lonlat 1e-3 2",
                Request::View(ViewCommand::CentreLonLat { name: "main".into(), lonlat: [0.001, 2.0] }),
            ),
            ("  QUIT  ", Request::Quit),
            ("SHUTDOWN", Request::Shutdown),
            ("VIEW ADD left", add("left", 1.0, false)),
            ("view add sensor.1 3", add("sensor.1", 3.0, false)),
            ("VIEW ADD far own", add("far", 1.0, true)),
            ("VIEW ADD far 2 OWN", add("far", 2.0, true)),
            ("VIEW REMOVE left", Request::View(ViewCommand::Remove { name: "left".into() })),
            ("VIEW CENTRE left -5 7", Request::View(ViewCommand::Centre { name: "left".into(), centre: [-5, 7] })),
            ("VIEW center main 1 2", Request::View(ViewCommand::Centre { name: "main".into(), centre: [1, 2] })),
            ("VIEW WEIGHT right 0.5", Request::View(ViewCommand::Weight { name: "right".into(), weight: 0.5 })),
            ("VIEW LOD high 3", lod("high", 3, None)),
            ("view lod main 0 12", lod("main", 0, Some(12))),
            ("VIEW LOD high 2 all", lod("high", 2, None)),
            ("VIEW HEIGHT high 12000 0.001", height("high", 12000.0, 0.001, 0)),
            ("view height main 5e3 0.002 16", height("main", 5000.0, 0.002, 16)),
            ("VIEWS", Request::Views),
            ("PATCH FILE /tmp/a b.json", Request::PatchFile("/tmp/a b.json".into())),
            (
                "patch data 12 {\"bbox\": [0, 0, 1, 1]}",
                Request::PatchData { bytes: 12, json: "{\"bbox\": [0, 0, 1, 1]}".into() },
            ),
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
            (b"CENTRE LONLAT 1", "CENTRE LONLAT takes 2 arguments: CENTRE LONLAT <longitude> <latitude>"),
            (b"CENTRE LONLAT 1 2 3", "CENTRE LONLAT takes 2 arguments"),
            (b"CENTRE LONLAT NaN 2", "CENTRE LONLAT: `NaN` is not a finite number of degrees"),
            (b"center lonlat 1 inf", "`inf` is not a finite number of degrees"),
            (b"CENTRE LONLAT 1 north", "`north` is not a finite number of degrees"),
            (b"CENTRE LONLAT x", "takes 2 arguments"),
            (b"VIEW CENTRE a LONLAT 1 nan", "`nan` is not a finite number of degrees"),
            (b"VIEW CENTRE a LONLAT 1", "LONLAT takes a longitude and a latitude, got 1 number(s)"),
            (b"STATS JSON", "usage: STATS"),
            (b"PING now", "takes 0 arguments"),
            (b"PATCH", "usage: PATCH FILE"),
            (b"PATCH FILE", "usage: PATCH FILE"),
            (b"PATCH DATA x {}", "`x` is not a byte count"),
            (b"PATCH DATA 3 nojson", "no JSON description"),
            (b"VIEW", "VIEW alone"),
            (b"VIEW JUMP a", "unknown VIEW command `JUMP`"),
            (b"VIEW LOD high -1", "LOD offset `-1`: expected a level number"),
            (b"VIEW LOD high 1 0", "effective levels `0`: expected 1 or more, or all"),
            (b"VIEW LOD high", "VIEW LOD with 1 argument(s)"),
            (b"VIEW HEIGHT high nan 0.001", "height `nan`: expected a finite number above 0"),
            (b"VIEW HEIGHT high 100 4", "pixel angle `4`: expected a finite number above 0 and below pi"),
            (b"VIEW ADD", "VIEW ADD with 0 argument(s)"),
            (b"VIEW ADD main", "the primary view's own"),
            (b"VIEW ADD a/b", "expected 1 to 31 of"),
            (b"VIEW ADD abcdefghijklmnopqrstuvwxyz0123456", "expected 1 to 31 of"),
            (b"VIEW ADD a 0", "weight `0`"),
            (b"VIEW ADD a NaN", "weight `NaN`"),
            (b"VIEW ADD a -2", "weight `-2`"),
            (b"VIEW REMOVE main", "the primary view's own"),
            (b"VIEW CENTRE a 1", "VIEW CENTRE with 2 argument(s)"),
            (b"VIEW CENTRE a 1 x", "`x` is not an integer"),
            (b"VIEWS x", "takes 0 arguments"),
        ];
        for (line, want) in cases {
            let err = parse(line).unwrap_err().to_string();
            assert!(err.contains(want), "{:?}: {err}", String::from_utf8_lossy(line));
        }
        for line in [&b"PATCH DATA 9 nojson"[..], b"patch  data x {}", b" PATCH DATA", b"PATCH\tDATA 5"] {
            assert!(parse(line).is_err() && announces_data(line), "{:?}", String::from_utf8_lossy(line));
        }
        assert!(!announces_data(b"PATCH FILE x") && !announces_data(b"PATCHDATA 1 {}") && !announces_data(b""));
        let long = format!("X{}", "y".repeat(5000));
        assert!(parse(long.as_bytes()).unwrap_err().to_string().len() < 260, "error replies stay short");
        assert_eq!(parse(b"BUDGET 0").unwrap_err(), BadRequest::Budget("0".into()));
        assert_eq!(parse(b"").unwrap_err(), BadRequest::Empty);
    }
}
