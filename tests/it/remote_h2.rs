//! HTTP/2 where the server offers it, end to end on loopback: nginx speaking HTTP/2 only, with
//! prior knowledge on plain HTTP (h2c, `RemoteOptions::h2c`, `CLIPMAP_REMOTE_H2C=1`) and by
//! ALPN over TLS (a server certificate of a test CA, trusted through
//! `RemoteOptions::ca_file`, `CLIPMAP_REMOTE_CA_FILE`). Every texel is checked against the hash
//! texture, and nginx's access log counts the connections the requests came on: over HTTP/2
//! they share a few, where HTTP/1.1 takes one a request in flight. The test CA is made with the
//! `openssl` command, which `.ci/run` installs.

use crate::common::exec_bounded;
use crate::common::remote::{point_config_at, Nginx};
use crate::remote::{every_tile, load, prepare, quick_opts, read_checked};
use clipmap::limits::Limits;
use clipmap::source::remote::{RemoteOptions, RemoteSource};
use std::collections::BTreeSet;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Duration;

const CLIPTEX: &str = env!("CARGO_BIN_EXE_cliptex");

/// Readers at once: many more than the connections HTTP/2 needs.
const READERS: usize = 16;

/// Reads every tile of `src` with [`READERS`] threads at once, every texel checked; returns
/// the tiles read.
fn read_all_at_once(src: &RemoteSource) -> usize {
    let tiles = every_tile(src);
    std::thread::scope(|s| {
        for j in 0..READERS {
            let tiles = &tiles;
            s.spawn(move || {
                for &id in tiles.iter().skip(j).step_by(READERS) {
                    read_checked(src, id).unwrap_or_else(|e| panic!("{id}: {e}"));
                }
            });
        }
    });
    tiles.len()
}

/// What nginx logged once it logged at least `expected` requests (it writes a request's line
/// after its answer went out, so the last may come a moment after the client has it; 10 s at
/// most): the connections the requests came on, their protocols, and the number of requests
/// (all answered 206).
fn logged(n: &Nginx, expected: usize) -> (BTreeSet<u64>, BTreeSet<String>, usize) {
    let t = std::time::Instant::now();
    let mut reqs = n.requests();
    while reqs.len() < expected && t.elapsed() < Duration::from_secs(10) {
        std::thread::sleep(Duration::from_millis(20));
        reqs = n.requests();
    }
    assert!(reqs.iter().all(|r| r.3 == 206), "every request answered with its range: {reqs:?}");
    let conns = reqs.iter().map(|r| r.0).collect();
    let protocols = reqs.iter().map(|r| r.2.clone()).collect();
    (conns, protocols, reqs.len())
}

fn source(ct: &Path, opts: RemoteOptions) -> RemoteSource {
    RemoteSource::new(load(ct), &Limits::default(), opts).unwrap()
}

/// A test CA and a server certificate it signed for `127.0.0.1`, made with `openssl` in
/// `dir`: (CA certificate, server certificate, server key), PEM files.
fn test_ca(dir: &Path) -> (PathBuf, PathBuf, PathBuf) {
    let (ca, ca_key) = (dir.join("ca.pem"), dir.join("ca.key"));
    let (cert, key, csr, ext) =
        (dir.join("server.pem"), dir.join("server.key"), dir.join("server.csr"), dir.join("ext"));
    std::fs::write(&ext, "subjectAltName=IP:127.0.0.1\nbasicConstraints=CA:FALSE\nextendedKeyUsage=serverAuth\n")
        .unwrap();
    let ec = ["-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:prime256v1", "-nodes"];
    let s = |p: &Path| p.to_str().unwrap().to_string();
    let steps: [Vec<String>; 3] = [
        ["req", "-x509"]
            .iter()
            .chain(&ec)
            .map(|a| a.to_string())
            .chain(
                ["-keyout", &s(&ca_key), "-out", &s(&ca), "-days", "2", "-subj", "/CN=clipmap test CA"]
                    .map(String::from),
            )
            .collect(),
        ["req"]
            .iter()
            .chain(&ec)
            .map(|a| a.to_string())
            .chain(["-keyout", &s(&key), "-out", &s(&csr), "-subj", "/CN=127.0.0.1"].map(String::from))
            .collect(),
        [
            "x509",
            "-req",
            "-in",
            &s(&csr),
            "-CA",
            &s(&ca),
            "-CAkey",
            &s(&ca_key),
            "-CAcreateserial",
            "-out",
            &s(&cert),
            "-days",
            "2",
            "-extfile",
            &s(&ext),
        ]
        .map(String::from)
        .to_vec(),
    ];
    for args in steps {
        let out = Command::new("openssl")
            .current_dir(dir)
            .args(&args)
            .output()
            .expect("the openssl command is needed for this test: apt-get install openssl (.ci/run does it)");
        assert!(out.status.success(), "openssl {}:\n{}", args.join(" "), String::from_utf8_lossy(&out.stderr));
    }
    (ca, cert, key)
}

#[test]
fn h2c_multiplexes_an_endpoints_reads_on_a_few_connections_where_http1_takes_many() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let pyr = prepare(&d.join("pyr"), 1024, 64, 128, &[]);
    // Hedges off: the requests nginx sees are the reads, one each.
    let opts = RemoteOptions { hedge_percent: 0, ..quick_opts() };

    // HTTP/1.1: a connection a request in flight.
    let h1 = Nginx::serve_logged(&pyr);
    let src = source(&point_config_at(&pyr, &d.join("cfg1"), &h1.url(), &[]), opts.clone());
    let tiles = read_all_at_once(&src);
    let st = src.stats();
    assert_eq!((st.http_version.as_str(), st.http2_answers, st.failures), ("HTTP/1.1", 0, 0), "{st:?}");
    let (conns, protocols, requests) = logged(&h1, tiles);
    assert_eq!(protocols, BTreeSet::from(["HTTP/1.1".to_string()]));
    assert_eq!(requests, tiles, "one request a tile");
    assert!(conns.len() > 4, "{READERS} readers at once over HTTP/1.1 take more than 4 connections: {conns:?}");

    // HTTP/2 with prior knowledge, to a server that speaks only HTTP/2 on plain HTTP.
    let h2 = Nginx::serve_h2(&pyr, None);
    let src = source(&point_config_at(&pyr, &d.join("cfg2"), &h2.url(), &[]), RemoteOptions { h2c: true, ..opts });
    assert_eq!(read_all_at_once(&src), tiles);
    let st = src.stats();
    assert_eq!((st.http_version.as_str(), st.failures), ("HTTP/2", 0), "{st:?}");
    assert_eq!(st.http2_answers, st.requests, "every answer over HTTP/2: {st:?}");
    let (conns, protocols, requests) = logged(&h2, tiles);
    assert_eq!(protocols, BTreeSet::from(["HTTP/2.0".to_string()]));
    assert_eq!(requests, tiles, "one request a tile");
    assert!(conns.len() <= 2, "{requests} requests multiplexed on at most 2 connections: {conns:?}");
}

#[test]
fn https_gets_http2_by_alpn_from_a_server_whose_ca_is_trusted_through_its_variable() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let pyr = prepare(&d.join("pyr"), 1024, 64, 128, &[]);
    let (ca, cert, key) = test_ca(d);
    let nginx = Nginx::serve_h2(&pyr, Some((&cert, &key)));
    let url = format!("https://127.0.0.1:{}", nginx.port);
    let ct = point_config_at(&pyr, &d.join("cfg"), &url, &[]);
    let opts = RemoteOptions { hedge_percent: 0, ..quick_opts() };

    // Without the CA the server's certificate is refused, and nothing is read.
    let src = source(&ct, RemoteOptions { retries: 0, ..opts.clone() });
    let id = every_tile(&src)[0];
    let e = read_checked(&src, id).expect_err("a certificate of an unknown CA is refused").to_string();
    assert!(e.to_ascii_lowercase().contains("certificate"), "{e}");
    assert!(logged(&nginx, 0).2 == 0, "no request reached the server");

    // With it: every tile, over HTTP/2 (the client offers h2 and http/1.1, nginx picks h2),
    // the requests multiplexed on a few connections.
    let src = source(&ct, RemoteOptions { ca_file: Some(ca.clone()), ..opts });
    let tiles = read_all_at_once(&src);
    let st = src.stats();
    assert_eq!((st.http_version.as_str(), st.http2_answers, st.failures), ("HTTP/2", st.requests, 0), "{st:?}");
    let (conns, protocols, requests) = logged(&nginx, tiles);
    assert_eq!(protocols, BTreeSet::from(["HTTP/2.0".to_string()]));
    assert_eq!(requests, tiles, "one request a tile");
    assert!(conns.len() <= 2, "{requests} requests multiplexed on at most 2 connections: {conns:?}");

    // The tools take the CA from CLIPMAP_REMOTE_CA_FILE: `cliptex check` reads every tile over
    // HTTPS with it, and without it cannot.
    let check = |envs: &[(&str, &str)]| {
        let args = ["check", ct.to_str().unwrap(), "--json"];
        let envs: Vec<(&str, &str)> = [("CLIPMAP_REMOTE_RETRIES", "0")].iter().chain(envs).copied().collect();
        exec_bounded(d, CLIPTEX, &args, &envs, Duration::from_secs(60))
    };
    let (out, desc) = check(&[("CLIPMAP_REMOTE_CA_FILE", ca.to_str().unwrap())]);
    assert_eq!(out.status.code(), Some(0), "every tile served:\n{desc}");
    let (out, desc) = check(&[]);
    assert_ne!(out.status.code(), Some(0), "an unknown CA's certificate is refused:\n{desc}");
    // A CA file without a certificate is refused when the source is opened, naming the
    // variable and the file, before any read.
    let bad = d.join("not-a-ca.pem");
    std::fs::write(&bad, "no certificate here\n").unwrap();
    let e = RemoteSource::new(load(&ct), &Limits::default(), RemoteOptions { ca_file: Some(bad), ..quick_opts() })
        .err()
        .expect("a CA file without a certificate is refused")
        .to_string();
    assert!(
        e.contains("CLIPMAP_REMOTE_CA_FILE") && e.contains("not-a-ca.pem") && e.contains("no PEM certificate"),
        "{e}"
    );
}
