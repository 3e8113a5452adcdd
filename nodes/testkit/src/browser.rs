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
        // WebGL2 (the report's 3-D viewer) on the software rasteriser, without the
        // deprecation warning Chromium otherwise logs as a console message.
        "--enable-unsafe-swiftshader",
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

/// The bytes of the `data:…;base64,` URL that is the whole text of the element with id `id`
/// in a DOM dump (`--dump-dom`), or `None` when there is no such element. The last match
/// counts (a script's source may mention the id before the element that carries it).
///
/// Panics on a malformed URL (a test failure).
pub fn data_url_in_dom(dom: &str, id: &str) -> Option<Vec<u8>> {
    let at = dom.rfind(&format!("id=\"{id}\""))?;
    let start = at + dom[at..].find('>')? + 1;
    let end = start + dom[start..].find('<')?;
    let text = dom[start..end].trim();
    let b64 = &text[text.find(";base64,").expect("a base64 data URL") + 8..];
    Some(decode_base64(b64))
}

/// The text of the element with id `id` in a DOM dump (HTML entities `&amp;`, `&lt;`, `&gt;`
/// and `&quot;` decoded), or `None`. The last match counts, as in [`data_url_in_dom`].
pub fn text_in_dom(dom: &str, id: &str) -> Option<String> {
    let at = dom.rfind(&format!("id=\"{id}\""))?;
    let start = at + dom[at..].find('>')? + 1;
    let end = start + dom[start..].find('<')?;
    Some(
        dom[start..end]
            .replace("&lt;", "<")
            .replace("&gt;", ">")
            .replace("&quot;", "\"")
            .replace("&amp;", "&"),
    )
}

/// Decodes standard base64 (padding optional); panics on other characters.
pub fn decode_base64(s: &str) -> Vec<u8> {
    let value = |c: u8| -> u32 {
        match c {
            b'A'..=b'Z' => u32::from(c - b'A'),
            b'a'..=b'z' => u32::from(c - b'a') + 26,
            b'0'..=b'9' => u32::from(c - b'0') + 52,
            b'+' => 62,
            b'/' => 63,
            _ => panic!("not base64: {:?}", c as char),
        }
    };
    let digits: Vec<u8> = s
        .bytes()
        .filter(|&c| c != b'=' && !c.is_ascii_whitespace())
        .collect();
    let mut out = Vec::with_capacity(digits.len() * 3 / 4);
    for chunk in digits.chunks(4) {
        let mut acc = 0u32;
        for (i, &c) in chunk.iter().enumerate() {
            acc |= value(c) << (18 - 6 * i);
        }
        let bytes = acc.to_be_bytes();
        out.extend_from_slice(&bytes[1..chunk.len()]);
    }
    out
}

#[cfg(test)]
mod tests {
    #[test]
    fn base64_round_trip() {
        for (text, b64) in [
            ("", ""),
            ("f", "Zg=="),
            ("fo", "Zm8="),
            ("foo", "Zm9v"),
            ("foob", "Zm9vYg=="),
            ("fooba", "Zm9vYmE="),
            ("foobar", "Zm9vYmFy"),
        ] {
            assert_eq!(super::decode_base64(b64), text.as_bytes());
        }
        assert_eq!(super::decode_base64("+/8A"), vec![0xfb, 0xff, 0x00]);
    }
}
