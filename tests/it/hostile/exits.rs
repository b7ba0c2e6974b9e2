//! One exit-code rule for every tool: 0 ok, 1 the input is bad (usage errors included), 2 the
//! tool could not run. And `validate`, `check` and the service agree on what is acceptable.

use super::service::{run, Service, CLIPBENCH, CLIPMAPD, CLIPPREP, CLIPTEX, ICACHE, ROOT};
use std::path::Path;

fn code(dir: &Path, prog: &str, args: &[&str]) -> (i32, String) {
    let (o, d) = run(dir, prog, args);
    (o.status.code().unwrap_or(-1), d)
}

#[test]
fn usage_errors_exit_1_and_help_and_version_exit_0_in_every_tool() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    for prog in [CLIPTEX, ICACHE, CLIPPREP, CLIPBENCH, CLIPMAPD] {
        let (c, desc) = code(d, prog, &["--no-such-option"]);
        assert_eq!(c, 1, "a usage error is bad input:\n{desc}");
        assert!(desc.contains("--no-such-option"), "{desc}");
        assert_eq!(code(d, prog, &["--help"]).0, 0, "{prog} --help");
        assert_eq!(code(d, prog, &["--version"]).0, 0, "{prog} --version");
    }
    let (c, desc) = code(d, CLIPTEX, &["roam", "--frames", "many"]);
    assert_eq!(c, 1, "{desc}");
}

#[test]
fn an_invalid_configuration_is_1_and_an_unreadable_one_2_in_every_subcommand() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    std::fs::write(d.join("bad.ct"), "ct_version2.0\nvirt_size 64 64 1\n").unwrap();
    std::fs::write(d.join("bad.ic"), "ic_version2.0\ntile_size 0 0 1\n").unwrap();
    let shm = d.to_str().unwrap();
    type Args = fn(&'static str) -> Vec<&'static str>;
    let cases: [(&str, Args); 7] = [
        (CLIPTEX, |f| vec!["validate", f]),
        (CLIPTEX, |f| vec!["info", f]),
        (CLIPTEX, |f| vec!["check", f]),
        (CLIPTEX, |f| vec!["dump", f, "--out", "x.png"]),
        (CLIPTEX, |f| vec!["roam", f, "--flight", "hover", "--frames", "1"]),
        (CLIPTEX, |f| vec!["tile", f, "--level", "0", "--s", "0", "--t", "0"]),
        (CLIPMAPD, |f| vec![f]),
    ];
    for (prog, args) in cases {
        let mut a = args("bad.ct");
        if prog == CLIPMAPD {
            a.extend(["--shm-dir", shm]);
        }
        let (c, desc) = code(d, prog, &a);
        assert_eq!(c, 1, "invalid:\n{desc}");
        a[if prog == CLIPMAPD { 0 } else { 1 }] = "missing.ct";
        let (c, desc) = code(d, prog, &a);
        assert_eq!(c, 2, "unreadable:\n{desc}");
    }
    for args in [vec!["validate", "bad.ic"], vec!["info", "bad.ic"], vec!["dump", "bad.ic", "--out", "x.png"]] {
        let (c, desc) = code(d, ICACHE, &args);
        assert_eq!(c, 1, "{desc}");
    }
    let (c, desc) = code(d, ICACHE, &["info", "missing.ic"]);
    assert_eq!(c, 2, "{desc}");
}

fn copy_prepared(dir: &Path) -> std::path::PathBuf {
    let dst = dir.join("prepared");
    let status = std::process::Command::new("cp")
        .arg("-r")
        .arg(Path::new(ROOT).join("config_examples/prepared"))
        .arg(&dst)
        .status()
        .unwrap();
    assert!(status.success());
    dst
}

/// Whether `clipmapd` starts on `ct` (and is then shut down), with its exit code when it does not.
fn service_accepts(dir: &Path, name: &str, ct: &str) -> Result<(), i32> {
    let s = Service::spawn(dir, name, &[ct], &[], "");
    let t = std::time::Instant::now();
    let mut s = s;
    loop {
        if let Some(st) = s.child.try_wait().unwrap() {
            return Err(st.code().unwrap_or(-1));
        }
        if s.alive() {
            return Ok(());
        }
        assert!(t.elapsed() < super::service::LIMIT, "clipmapd neither started nor stopped");
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
}

#[test]
fn validate_check_and_the_service_agree_on_a_table_of_configurations() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let p = copy_prepared(d);
    let ct = p.join("hash256.ct");
    let l0 = p.join("L00.ic");
    let ic = std::fs::read_to_string(&l0).unwrap();
    let huge = d.join("huge.ct");
    std::fs::write(
        &huge,
        "ct_version2.0\next_format PFTEX_PACK_8\nint_format PFTEX_RGB_8\nimg_format PFTEX_RGB\nvirt_size 1048576 1048576 1\nclip_size 1024\ntile_format t.%d.r%d.c%d.raw\ntile_params PFIMAGECACHE_TILE_FILENAMEARG_VSIZE_S PFIMAGECACHE_TILE_FILENAMEARG_TILENUM_T PFIMAGECACHE_TILE_FILENAMEARG_TILENUM_S\ntile_size 65536 65536 1\n",
    )
    .unwrap();
    let wide = d.join("wide.ct");
    std::fs::write(
        &wide,
        "ct_version2.0\next_format PFTEX_PACK_8\nint_format PFTEX_RGB_8\nimg_format PFTEX_RGB\nvirt_size 67108864 67108864 1\nclip_size 65536\ntile_format t.%d.r%d.c%d.raw\ntile_params PFIMAGECACHE_TILE_FILENAMEARG_VSIZE_S PFIMAGECACHE_TILE_FILENAMEARG_TILENUM_T PFIMAGECACHE_TILE_FILENAMEARG_TILENUM_S\ntile_size 2048 2048 1\n",
    )
    .unwrap();
    type Setup = Box<dyn Fn()>;
    let (l0a, ica) = (l0.clone(), ic.clone());
    let (l0b, icb) = (l0.clone(), ic.clone());
    let (l0c, icc) = (l0.clone(), ic.clone());
    let rows: Vec<(&str, &Path, Setup)> = vec![
        ("as prepared", &ct, Box::new(|| {})),
        ("tile_size 65536 squared", &huge, Box::new(|| {})),
        ("clip windows over the limit", &wide, Box::new(|| {})),
        (
            "default tile /dev/zero",
            &ct,
            Box::new(move || std::fs::write(&l0a, format!("{ica}default_tile /dev/zero\n")).unwrap()),
        ),
        ("default tile too short", &ct, {
            let short = d.join("short.raw");
            std::fs::write(&short, [0u8; 10]).unwrap();
            Box::new(move || std::fs::write(&l0b, format!("{icb}default_tile {}\n", short.display())).unwrap())
        }),
        ("default tile of one tile", &ct, {
            let good = d.join("good.raw");
            std::fs::write(&good, vec![0u8; 64 * 64 * 3]).unwrap();
            Box::new(move || std::fs::write(&l0c, format!("{icc}default_tile {}\n", good.display())).unwrap())
        }),
    ];
    for (i, (what, file, setup)) in rows.into_iter().enumerate() {
        std::fs::write(&l0, &ic).unwrap();
        setup();
        let f = file.to_str().unwrap();
        let (v, vd) = code(d, CLIPTEX, &["validate", f]);
        let (c, cd) = code(d, CLIPTEX, &["check", f]);
        let svc = service_accepts(d, &format!("agree{i}"), f);
        assert_eq!(v == 0, svc.is_ok(), "{what}: validate and the service disagree ({svc:?}):\n{vd}");
        if c == 0 {
            assert_eq!(v, 0, "{what}: check accepts what validate refuses:\n{cd}\n{vd}");
        }
        if let Err(code) = svc {
            assert_eq!(code, 1, "{what}: the service refuses it as bad input");
            assert_ne!(c, 0, "{what}: check accepts what the service refuses:\n{cd}");
        }
    }
}
