//! Flights through a running `clipmapd`'s control socket: the centre moved at a set speed with
//! `CENTRE` (its position follows the clock, so the speed is the same on a slow machine), and
//! `STATS` sampled on the way; for the tests of adaptive paging's load control.
#![allow(dead_code)]

use std::io::{BufRead, BufReader, Write};
use std::os::unix::net::UnixStream;
use std::path::Path;
use std::time::{Duration, Instant};

/// One control connection kept open: a `CENTRE` costs a round trip, not a connect.
pub struct Control {
    r: BufReader<UnixStream>,
    w: UnixStream,
}

impl Control {
    /// Connects to `socket` (every reply bounded by 10 s).
    pub fn open(socket: &Path) -> Control {
        let w = UnixStream::connect(socket).unwrap_or_else(|e| panic!("connect {}: {e}", socket.display()));
        w.set_read_timeout(Some(Duration::from_secs(10))).unwrap();
        w.set_write_timeout(Some(Duration::from_secs(10))).unwrap();
        Control { r: BufReader::new(w.try_clone().unwrap()), w }
    }

    /// Sends one line; returns the reply line.
    pub fn ask(&mut self, line: &str) -> String {
        writeln!(self.w, "{line}").unwrap();
        let mut reply = String::new();
        self.r.read_line(&mut reply).unwrap();
        reply.trim_end().to_string()
    }

    /// `STATS`, parsed.
    pub fn stats(&mut self) -> serde_json::Value {
        let r = self.ask("STATS");
        let body = r.strip_prefix("OK ").unwrap_or_else(|| panic!("STATS: {r}"));
        serde_json::from_str(body).unwrap_or_else(|e| panic!("{e}: {r}"))
    }
}

/// Level `k`'s paging reason in a `STATS` reply.
pub fn reason(stats: &serde_json::Value, k: usize) -> String {
    stats["engine"]["paging"][k]["reason"].as_str().unwrap_or_else(|| panic!("no paging for level {k}: {stats}")).into()
}

/// Every level's paging reason in a `STATS` reply.
pub fn reasons(stats: &serde_json::Value) -> Vec<String> {
    stats["engine"]["paging"].as_array().unwrap().iter().map(|p| p["reason"].as_str().unwrap().to_string()).collect()
}

/// Whether every level is at rest: `hover`, or `fixed` for a level its grid holds whole (the
/// pyramid levels).
pub fn all_at_rest(stats: &serde_json::Value) -> bool {
    reasons(stats).iter().all(|r| r == "hover" || r == "fixed") && reasons(stats).iter().any(|r| r == "hover")
}

/// Flies the centre along s at `t`, from `lo` towards `hi` and back (bouncing), at `speed`
/// level-0 texels a second for `secs` seconds; each `CENTRE` goes out as soon as the last is
/// answered. Every `every`-th centre, `sample` gets the `STATS` reply and the seconds flown.
pub fn fly(
    c: &mut Control,
    t: i64,
    (lo, hi): (i64, i64),
    speed: f64,
    secs: f64,
    every: u64,
    mut sample: impl FnMut(&serde_json::Value, f64),
) {
    let span = (hi - lo) as f64;
    let start = Instant::now();
    let mut n = 0u64;
    loop {
        let flown = start.elapsed().as_secs_f64();
        if flown >= secs {
            break;
        }
        let phase = (speed * flown) % (2.0 * span);
        let s = lo + if phase < span { phase } else { 2.0 * span - phase } as i64;
        let r = c.ask(&format!("CENTRE {s} {t}"));
        assert!(r.starts_with("OK"), "CENTRE {s} {t}: {r}");
        n += 1;
        if n.is_multiple_of(every) {
            let st = c.stats();
            sample(&st, flown);
        }
    }
}

/// Polls `STATS` until `done` holds, at most `within`; returns the last reply and whether it held.
pub fn wait_stats(
    c: &mut Control,
    within: Duration,
    done: impl Fn(&serde_json::Value) -> bool,
) -> (serde_json::Value, bool) {
    let t = Instant::now();
    loop {
        let st = c.stats();
        if done(&st) {
            return (st, true);
        }
        if t.elapsed() > within {
            return (st, false);
        }
        std::thread::sleep(Duration::from_millis(20));
    }
}
