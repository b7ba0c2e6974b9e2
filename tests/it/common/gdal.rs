//! GDAL from the tests: the Python with GDAL's binding, and running a script that writes a file
//! with it (the COG tests have GDAL write the files they read).

use std::path::Path;
use std::process::{Command, Stdio};

/// The Python that has GDAL's binding (`python3-gdal`, which .ci/run installs): the system's
/// `/usr/bin/python3` when it has it, else `python3` on the path.
pub fn python() -> &'static str {
    let has_gdal =
        |p: &str| Command::new(p).args(["-c", "from osgeo import gdal"]).output().is_ok_and(|o| o.status.success());
    ["/usr/bin/python3", "python3"].into_iter().find(|p| has_gdal(p)).unwrap_or("python3")
}

/// Runs the Python `script` (given on standard input) with `args` in `dir`; its output is one
/// line `WIDTH HEIGHT` per IFD GDAL decoded, returned in order. `what` names the case in a failure.
pub fn write_with(script: &str, args: &[String], dir: &Path, what: &str) -> Vec<[u64; 2]> {
    let mut child = Command::new(python())
        .args(args)
        .current_dir(dir)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("python3 (with GDAL's binding, python3-gdal, which .ci/run installs)");
    use std::io::Write;
    child.stdin.take().unwrap().write_all(script.as_bytes()).unwrap();
    let out = child.wait_with_output().unwrap();
    assert!(out.status.success(), "{what}: GDAL failed: {}", String::from_utf8_lossy(&out.stderr));
    String::from_utf8(out.stdout)
        .unwrap()
        .lines()
        .map(|l| {
            let v: Vec<u64> = l.split(' ').map(|x| x.parse().unwrap()).collect();
            [v[0], v[1]]
        })
        .collect()
}

/// A `clipmapd` serving a file, killed when dropped.
pub struct Served {
    child: std::process::Child,
    /// Its standard error, for failure messages.
    pub err: std::path::PathBuf,
    /// A client attached to its mapping.
    pub client: clipmap::shm::Client,
}

impl Served {
    /// Starts `clipmapd FILE --clip CLIP` as `name` in `dir` (socket `NAME.sock` there) and
    /// attaches to its mapping, within 30 s.
    // The child is waited for on every path: by `Drop` once it is in a `Served`, here before the
    // panic when no mapping appears.
    pub fn start(file: &Path, clip: u64, name: &str, dir: &Path) -> Served {
        Served::start_with(file, clip, name, dir, &[])
    }

    /// [`Served::start`] with these environment variables set for the service.
    #[allow(clippy::zombie_processes)]
    pub fn start_with(file: &Path, clip: u64, name: &str, dir: &Path, envs: &[(&str, &str)]) -> Served {
        let err = dir.join(format!("{name}.err"));
        let child = Command::new(env!("CARGO_BIN_EXE_clipmapd"))
            .envs(envs.iter().copied())
            .arg(file)
            .args(["--clip", &clip.to_string(), "--tick-hz", "120", "--name", name, "--shm-dir"])
            .arg(dir)
            .arg("--socket")
            .arg(dir.join(format!("{name}.sock")))
            .stdout(Stdio::null())
            .stderr(std::fs::File::create(&err).unwrap())
            .spawn()
            .unwrap();
        let t = std::time::Instant::now();
        loop {
            if let Ok(client) = clipmap::shm::Client::attach(dir, name) {
                return Served { child, err, client };
            }
            if t.elapsed() > std::time::Duration::from_secs(30) {
                let mut child = child;
                let _ = child.kill();
                let _ = child.wait();
                panic!("no mapping\n{}", std::fs::read_to_string(&err).unwrap_or_default());
            }
            std::thread::sleep(std::time::Duration::from_millis(20));
        }
    }

    /// What it wrote on standard error so far.
    pub fn log(&self) -> String {
        std::fs::read_to_string(&self.err).unwrap_or_default()
    }
}

impl Drop for Served {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}
