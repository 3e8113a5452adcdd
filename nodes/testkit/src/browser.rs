//! Headless Chromium, as the report tests run it.

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

/// The first Chromium found on `PATH` (`chromium`, `chromium-browser`, `google-chrome`), or
/// `None` after reporting the skip for `test` (a failure under `CI=true`).
pub fn chromium(test: &str) -> Option<PathBuf> {
    let found = ["chromium", "chromium-browser", "google-chrome"]
        .into_iter()
        .find(|name| {
            Command::new(name)
                .arg("--version")
                .stdout(Stdio::null())
                .stderr(Stdio::null())
                .status()
                .is_ok_and(|s| s.success())
        });
    match found {
        Some(name) => Some(PathBuf::from(name)),
        None => {
            crate::skip(
                test,
                "`chromium` is not installed (apt-get install -y chromium)",
            );
            None
        }
    }
}

/// A headless Chromium command with a fresh profile in `profile` and no background network
/// traffic (the test machines have no network).
pub fn headless(exe: &Path, profile: &Path) -> Command {
    let mut c = Command::new(exe);
    c.args([
        "--headless",
        "--no-sandbox",
        "--disable-gpu",
        "--disable-dev-shm-usage",
        "--disable-background-networking",
        "--disable-component-update",
        "--disable-sync",
        "--no-first-run",
        "--enable-logging=stderr",
        "--v=0",
    ])
    .arg(format!("--user-data-dir={}", profile.display()));
    c
}

/// Runs `cmd`, killing it after `limit` (then panics); returns (stdout, stderr).
pub fn run_limited(mut cmd: Command, limit: Duration) -> (String, String) {
    let dir = std::env::temp_dir().join(format!(
        "augsplat-testkit-{}-{}",
        std::process::id(),
        Instant::now().elapsed().as_nanos() ^ (&cmd as *const Command as usize as u128)
    ));
    std::fs::create_dir_all(&dir).expect("create a temporary folder");
    let (o, e) = (dir.join("stdout"), dir.join("stderr"));
    let mut child = cmd
        .stdout(std::fs::File::create(&o).expect("create the stdout file"))
        .stderr(std::fs::File::create(&e).expect("create the stderr file"))
        .spawn()
        .expect("start the browser");
    let start = Instant::now();
    loop {
        if child.try_wait().expect("wait for the browser").is_some() {
            break;
        }
        if start.elapsed() > limit {
            let _ = child.kill();
            let _ = child.wait();
            panic!("the browser did not finish within {limit:?}");
        }
        std::thread::sleep(Duration::from_millis(100));
    }
    let out = (
        std::fs::read_to_string(&o).unwrap_or_default(),
        std::fs::read_to_string(&e).unwrap_or_default(),
    );
    let _ = std::fs::remove_dir_all(&dir);
    out
}
