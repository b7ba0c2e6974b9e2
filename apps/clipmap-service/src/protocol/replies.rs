//! What the service answers, as types, and the one place they become the socket's text: the tick
//! loop answers a command with a [`Reply`] or a [`Refusal`], the control socket gathers every
//! answer of a request in an [`Answer`], and [`render`] writes its line (docs/SHM.md, "Control
//! socket").

use super::BadRequest;
use crate::patches::PatchRefusal;
use crate::stats::{ServiceStats, Status, ViewStats};
use crate::ticker::SendError;
use clipmap::clip::{ClipError, LodWindow, ViewError};
use clipmap::shm::ShmError;
use std::fmt;

/// What the tick loop did with a command it carried out (the text after `OK`).
#[derive(Clone, Debug, PartialEq)]
pub enum Reply {
    /// `BUDGET`: the copy budget per tick now (`None`: off).
    Budget(Option<f64>),
    /// `BORDER`: the invalid border applied (clamped by the engine).
    Border(u64),
    /// `CENTRE`: the centre the snapshot will publish (bounded).
    Centre([i64; 2]),
    /// `VIEW ADD`.
    ViewAdded {
        /// The view.
        name: String,
        /// Its weight.
        weight: f64,
        /// With grids of its own.
        own: bool,
    },
    /// `VIEW REMOVE`.
    ViewRemoved {
        /// The view.
        name: String,
    },
    /// `VIEW CENTRE`: the centre the view's snapshot will publish (bounded).
    ViewCentre {
        /// The view (`main`: the primary).
        name: String,
        /// Its centre.
        centre: [i64; 2],
    },
    /// `VIEW WEIGHT`.
    ViewWeight {
        /// The view.
        name: String,
        /// Its weight now.
        weight: f64,
    },
    /// `VIEW LOD` and `VIEW HEIGHT`: the levels the view shows from the next tick.
    ViewLod {
        /// The view.
        name: String,
        /// Its LOD window (`effective` `u32::MAX`: all).
        lod: LodWindow,
    },
}

impl fmt::Display for Reply {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Reply::Budget(Some(ms)) => write!(f, "budget {ms} ms"),
            Reply::Budget(None) => write!(f, "budget off"),
            Reply::Border(b) => write!(f, "border {b}"),
            Reply::Centre([s, t]) => write!(f, "centre {s} {t}"),
            Reply::ViewAdded { name, weight, own: false } => write!(f, "view {name} added, weight {weight}"),
            Reply::ViewAdded { name, weight, own: true } => {
                write!(f, "view {name} added, weight {weight}, grids of its own")
            }
            Reply::ViewRemoved { name } => write!(f, "view {name} removed"),
            Reply::ViewCentre { name, centre: [s, t] } => write!(f, "view {name} centre {s} {t}"),
            Reply::ViewWeight { name, weight } => write!(f, "view {name} weight {weight}"),
            Reply::ViewLod { name, lod } if lod.effective == u32::MAX => {
                write!(f, "view {name} lod offset {} effective all", lod.offset)
            }
            Reply::ViewLod { name, lod } => {
                write!(f, "view {name} lod offset {} effective {}", lod.offset, lod.effective)
            }
        }
    }
}

/// Why the tick loop refused a view command (or a view of the command line, or a renderer's LOD
/// request): the text after `ERR`.
#[derive(Debug, thiserror::Error)]
pub enum Refusal {
    /// No view has the name.
    #[error("no view `{name}`: the views are {}", views.join(", "))]
    NoView {
        /// The name asked for.
        name: String,
        /// The views there are, the primary first.
        views: Vec<String>,
    },
    /// The engine refused (a taken name, a bad weight or LOD window, too many views, ...).
    #[error(transparent)]
    View(#[from] ViewError),
    /// A view with grids of its own: its mapping could not be made.
    #[error("view {name}: its own mapping {mapping}: {source}")]
    OwnMapping {
        /// The view.
        name: String,
        /// The mapping's name.
        mapping: String,
        /// Why.
        #[source]
        source: ShmError,
    },
    /// A view with grids of its own: its clipmap could not be made.
    #[error("view {name}: its own grids: {source}")]
    OwnGrids {
        /// The view.
        name: String,
        /// Why.
        #[source]
        source: ClipError,
    },
    /// `CENTRE LONLAT` (or `VIEW CENTRE ... LONLAT`) on a texture without georeferencing.
    #[error("CENTRE LONLAT: the texture has no georeferencing (only GeoTIFFs / COGs with georeferencing tags and tile pyramids, xyz: / .pmtiles / .mbtiles, have it; docs/GEOREF.md): give the centre in level-0 texels, CENTRE <s> <t>")]
    NoGeoref,
    /// `CENTRE LONLAT` at a point outside the texture or its projection's domain.
    #[error("CENTRE LONLAT {lon} {lat}: {why}")]
    LonLat {
        /// The longitude asked for.
        lon: f64,
        /// The latitude asked for.
        lat: f64,
        /// Where the point is, and the domain.
        why: String,
    },
    /// A LOD request (`VIEW HEIGHT`, a request mapping's LOD record) whose numbers are unusable.
    #[error("view {name}: LOD request refused: {why}")]
    LodRequest {
        /// The view.
        name: String,
        /// Which number, and what is expected.
        why: String,
    },
}

/// Why a command sent to the tick loop got no answer.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum Unanswered {
    /// It never reached the loop (busy or gone).
    #[error(transparent)]
    Unsent(#[from] SendError),
    /// The loop stopped before answering.
    #[error("the tick loop has stopped")]
    Stopped,
    /// The loop did not answer within the reply timeout.
    #[error("the tick loop did not answer in time")]
    Late,
}

/// Why a request (or a connection) was refused: the text after `ERR`.
#[derive(Debug, thiserror::Error)]
pub enum Refused {
    /// The line is not a request.
    #[error(transparent)]
    BadRequest(#[from] BadRequest),
    /// A `PATCH DATA` line that cannot say how many bytes follow (the connection closes).
    #[error("{0}; closing (nothing was taken)")]
    BadDataLine(BadRequest),
    /// The tick loop refused.
    #[error(transparent)]
    Tick(#[from] Refusal),
    /// The tick loop did not answer.
    #[error(transparent)]
    Unanswered(#[from] Unanswered),
    /// A patch was not taken.
    #[error(transparent)]
    Patch(#[from] PatchRefusal),
    /// No complete line within the idle time.
    #[error("idle for {ms} ms; closing")]
    Idle {
        /// The idle time.
        ms: u128,
    },
    /// A line longer than the limit.
    #[error("request longer than {max} bytes; closing")]
    TooLong {
        /// The limit.
        max: usize,
    },
    /// End of input in the middle of a line.
    #[error("incomplete request (no newline before end of input)")]
    Incomplete,
    /// More connections than the limit.
    #[error("too many connections (limit {limit}); closing")]
    TooMany {
        /// The limit.
        limit: usize,
    },
}

/// Everything a request may be answered with.
#[derive(Debug)]
pub enum Answer {
    /// `PING`.
    Pong,
    /// `STATUS`.
    Status(Box<Status>),
    /// `STATS`.
    Stats(Box<ServiceStats>),
    /// `STATS PROM`: the Prometheus text.
    StatsProm(String),
    /// `VIEWS`.
    Views(Vec<ViewStats>),
    /// A command the tick loop carried out.
    Done(Reply),
    /// A patch taken, by its id.
    Patched(u64),
    /// `QUIT`.
    Bye,
    /// `SHUTDOWN`.
    ShuttingDown,
    /// Refused.
    Refused(Refused),
}

impl Answer {
    /// Whether it is an `OK` reply.
    pub fn is_ok(&self) -> bool {
        !matches!(self, Answer::Refused(_))
    }
}

impl<E: Into<Refused>> From<E> for Answer {
    fn from(e: E) -> Answer {
        Answer::Refused(e.into())
    }
}

/// The reply's text, without its final newline: `OK ...` or `ERR ...` (`STATS PROM`: its first
/// line, `OK prometheus <n>`, and the n lines after it).
pub fn render(answer: &Answer) -> String {
    match answer {
        Answer::Pong => "OK pong".into(),
        // STATUS has always given its fields (and the growth block's) in name order: a JSON
        // value's object keeps its keys sorted.
        Answer::Status(s) => format!("OK {}", serde_json::to_value(s).map(|v| v.to_string()).unwrap_or_default()),
        Answer::Stats(s) => format!("OK {}", json(s.as_ref())),
        Answer::StatsProm(text) => {
            let text = text.trim_end();
            format!("OK prometheus {}\n{text}", text.lines().count())
        }
        Answer::Views(v) => format!("OK {}", json(v)),
        Answer::Done(reply) => format!("OK {reply}"),
        Answer::Patched(id) => format!("OK patch {id}"),
        Answer::Bye => "OK bye".into(),
        Answer::ShuttingDown => "OK shutting down".into(),
        Answer::Refused(why) => format!("ERR {why}"),
    }
}

/// Compact JSON, the fields in their declared order.
fn json(v: &impl serde::Serialize) -> String {
    serde_json::to_string(v).unwrap_or_default()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::stats::TickStats;
    use crate::Started;

    /// docs/SHM.md, "Control socket": each command's `OK` line.
    #[test]
    fn each_reply_renders_as_the_protocol_table_says() {
        let name = || "far".to_string();
        let lod = |offset, effective| LodWindow { offset, effective };
        let cases = [
            (Reply::Budget(Some(2.5)), "OK budget 2.5 ms"),
            (Reply::Budget(Some(4.0)), "OK budget 4 ms"),
            (Reply::Budget(None), "OK budget off"),
            (Reply::Border(16), "OK border 16"),
            (Reply::Centre([-5, 1000]), "OK centre -5 1000"),
            (Reply::ViewAdded { name: name(), weight: 1.0, own: false }, "OK view far added, weight 1"),
            (
                Reply::ViewAdded { name: name(), weight: 2.5, own: true },
                "OK view far added, weight 2.5, grids of its own",
            ),
            (Reply::ViewRemoved { name: name() }, "OK view far removed"),
            (Reply::ViewCentre { name: "main".into(), centre: [1, -2] }, "OK view main centre 1 -2"),
            (Reply::ViewWeight { name: name(), weight: 0.5 }, "OK view far weight 0.5"),
            (Reply::ViewLod { name: name(), lod: lod(3, u32::MAX) }, "OK view far lod offset 3 effective all"),
            (Reply::ViewLod { name: name(), lod: lod(0, 12) }, "OK view far lod offset 0 effective 12"),
        ];
        for (reply, want) in cases {
            assert_eq!(render(&Answer::Done(reply)), want);
        }
        assert_eq!(render(&Answer::Pong), "OK pong");
        assert_eq!(render(&Answer::Patched(7)), "OK patch 7");
        assert_eq!(render(&Answer::Bye), "OK bye");
        assert_eq!(render(&Answer::ShuttingDown), "OK shutting down");
        assert_eq!(render(&Answer::StatsProm("a 1\nb 2\n\n".into())), "OK prometheus 2\na 1\nb 2");
    }

    #[test]
    fn each_refusal_renders_as_err_and_says_why() {
        let no_view = Refusal::NoView { name: "x".into(), views: vec!["main".into(), "left".into()] };
        let cases: [(Answer, &str); 9] = [
            (no_view.into(), "ERR no view `x`: the views are main, left"),
            (Refusal::from(ViewError::Full).into(), "ERR 16 views already: remove one first"),
            (
                Refusal::LodRequest { name: "far".into(), why: "height nan".into() }.into(),
                "ERR view far: LOD request refused: height nan",
            ),
            (Unanswered::Unsent(SendError::Busy).into(), "ERR the tick loop is busy; try again"),
            (Unanswered::Stopped.into(), "ERR the tick loop has stopped"),
            (Unanswered::Late.into(), "ERR the tick loop did not answer in time"),
            (Refused::Idle { ms: 250 }.into(), "ERR idle for 250 ms; closing"),
            (Refused::TooMany { limit: 2 }.into(), "ERR too many connections (limit 2); closing"),
            (Refused::BadDataLine(BadRequest::Empty).into(), "ERR empty request; expected one of"),
        ];
        for (answer, want) in cases {
            assert!(!answer.is_ok());
            let text = render(&answer);
            assert!(text.starts_with(want), "{text}");
        }
        assert!(render(&PatchRefusal::NotGrowing.into()).starts_with("ERR PATCH: this service's texture does not grow"));
        assert!(Answer::Pong.is_ok());
    }

    /// `STATUS` gives its fields, and the growth block's, in name order, as it always has.
    #[test]
    fn status_renders_its_fields_in_name_order() {
        let started = Started {
            mapping: "/dev/shm/clipmap-a.map".into(),
            size: [4096, 4096],
            clip_size: 256,
            levels: 5,
            format: "rgba8".into(),
            mapping_bytes: 1 << 20,
        };
        let tick = TickStats {
            uptime_s: 1.5,
            tick_hz: 60.0,
            centre: [2048, -7],
            min_lod: 0.25,
            budget_ms: Some(2.0),
            valid: vec![[0, 0, 256, 256]],
            growth: Some(clipmap::shm::layout::Growth { patches: 3, texels_per_unit: 0.5, ..Default::default() }),
            ..TickStats::default()
        };
        let status = Status::of("a", "/tmp/a.sock".as_ref(), &started, &tick);
        let text = render(&Answer::Status(Box::new(status)));
        let json = text.strip_prefix("OK ").unwrap();
        let keys: Vec<String> =
            serde_json::from_str::<serde_json::Value>(json).unwrap().as_object().unwrap().keys().cloned().collect();
        let mut sorted = keys.clone();
        sorted.sort();
        assert_eq!(keys, sorted);
        let want = format!(
            concat!(
                r#"{{"budget_ms":2.0,"centre":[2048,-7],"clip_size":256,"format":"rgba8","#,
                r#""growth":{{"data_levels":0,"extent":[0,0,0,0],"outside_frame":0,"patches":3,"texels_per_unit":0.5,"tiles_pending":0,"tiles_rebuilt":0,"tiles_replaced":0,"world_origin":[0.0,0.0]}},"#,
                r#""invalid_border":0,"levels":5,"levels_disabled":0,"mapping":"/dev/shm/clipmap-a.map","mapping_bytes":1048576,"#,
                r#""min_lod":0.25,"name":"a","pid":{},"size":[4096,4096],"socket":"/tmp/a.sock","tick_hz":60.0,"ticks":0,"#,
                r#""uptime_s":1.5,"valid":[[0,0,256,256]]}}"#
            ),
            std::process::id()
        );
        assert_eq!(json, want);
    }
}
