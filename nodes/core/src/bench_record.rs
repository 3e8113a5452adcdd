//! One benchmark figure as a small JSON record: what was measured, the command that reproduces
//! it, the figure in words and its headline value, the commit, the date and the machine.
//!
//! The benchmark examples of every node family write one with `--json PATH`
//! ([`take_json_arg`], [`BenchRecord::now`], [`BenchRecord::write`]); `docs/figures/` holds one
//! per row of `docs/current.md`, which `docs/scripts/current_table.py` renders from them. It
//! lives in this crate because every family's examples depend on it and on nothing lower.

use crate::error::CoreError;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// One measured figure (the fields of a `docs/figures/*.json` file).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BenchRecord {
    /// What was measured (`hash-grid field, forward+backward, 2 threads`).
    pub what: String,
    /// The command that reproduces it (`cargo run --release -p augsplat-field --example bench --
    /// 2 step 30`).
    pub command: String,
    /// The figure in words, with its conditions (`1.56 M samples/s with 1,024-ray steps`).
    pub figure: String,
    /// The headline number of the figure, in [`BenchRecord::unit`]; finite.
    pub value: f64,
    /// The unit of [`BenchRecord::value`] (`samples/s`, `ms`, `s`).
    pub unit: String,
    /// The commit measured (`git rev-parse --short HEAD`), `None` where unknown.
    pub commit: Option<String>,
    /// The UTC date of the measurement (`YYYY-MM-DD`).
    pub date: String,
    /// The machine: CPU model and logical cores (`AMD EPYC (Zen 4), 2 cores`).
    pub machine: String,
}

impl BenchRecord {
    /// A record of a measurement made now: today's UTC date, this machine ([`machine`]) and
    /// the commit of the source tree this program was built from ([`git_commit`]).
    pub fn now(
        what: impl Into<String>,
        command: impl Into<String>,
        figure: impl Into<String>,
        value: f64,
        unit: impl Into<String>,
    ) -> BenchRecord {
        BenchRecord {
            what: what.into(),
            command: command.into(),
            figure: figure.into(),
            value,
            unit: unit.into(),
            commit: git_commit(),
            date: today(),
            machine: machine(),
        }
    }

    /// The record as pretty JSON with a final newline.
    pub fn to_json(&self) -> String {
        let mut text = serde_json::to_string_pretty(self).expect("a record serializes");
        text.push('\n');
        text
    }

    /// Writes [`BenchRecord::to_json`] to `path` (creating its folder). A value that is not
    /// finite is an error: JSON has no number for it.
    pub fn write(&self, path: &Path) -> Result<(), CoreError> {
        if !self.value.is_finite() {
            return Err(CoreError::format(
                path,
                format!("the value of `{}` is {}", self.what, self.value),
            ));
        }
        if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
            std::fs::create_dir_all(dir).map_err(|e| CoreError::io(dir, e))?;
        }
        std::fs::write(path, self.to_json()).map_err(|e| CoreError::io(path, e))
    }

    /// Writes the record to `path` when there is one, printing where; a failure ends the
    /// program with status 1 (for the examples, whose `main` has nothing else to do with it).
    pub fn write_or_exit(&self, path: Option<&Path>) {
        let Some(path) = path else { return };
        match self.write(path) {
            Ok(()) => println!("record written: {}", path.display()),
            Err(e) => {
                eprintln!("{e}");
                std::process::exit(1);
            }
        }
    }
}

/// Removes `--json PATH` from `args` and returns the path (`None` without the option). A
/// `--json` without a path is an error naming the option.
pub fn take_json_arg(args: &mut Vec<String>) -> Result<Option<PathBuf>, String> {
    let Some(i) = args.iter().position(|a| a == "--json") else {
        return Ok(None);
    };
    if i + 1 >= args.len() {
        return Err("--json PATH: the path of the record is missing".into());
    }
    let path = PathBuf::from(args.remove(i + 1));
    args.remove(i);
    Ok(Some(path))
}

/// [`take_json_arg`] over this program's arguments (without the program name): the remaining
/// arguments and the path. A missing path ends the program with status 2.
pub fn args_and_json() -> (Vec<String>, Option<PathBuf>) {
    let mut args: Vec<String> = std::env::args().skip(1).collect();
    match take_json_arg(&mut args) {
        Ok(path) => (args, path),
        Err(e) => {
            eprintln!("{e}");
            std::process::exit(2);
        }
    }
}

/// The command that runs example `example` of package `package` with `args`:
/// `cargo run --release -p PACKAGE --example EXAMPLE -- ARGS` (no `--` without arguments; an
/// argument with characters a shell reads is single-quoted).
pub fn example_command(package: &str, example: &str, args: &[String]) -> String {
    let mut cmd = format!("cargo run --release -p {package} --example {example}");
    if !args.is_empty() {
        cmd.push_str(" --");
        for a in args {
            cmd.push(' ');
            cmd.push_str(&shell_word(a));
        }
    }
    cmd
}

/// `a` as one shell word: as is when it holds only characters no shell reads specially, else
/// single-quoted.
fn shell_word(a: &str) -> String {
    let plain = !a.is_empty()
        && a.chars()
            .all(|c| c.is_ascii_alphanumeric() || "-_./=,:+@%".contains(c));
    if plain {
        a.to_string()
    } else {
        format!("'{}'", a.replace('\'', r"'\''"))
    }
}

/// The CPU model (`model name` of `/proc/cpuinfo`; the architecture where there is none).
pub fn cpu_model() -> String {
    std::fs::read_to_string("/proc/cpuinfo")
        .ok()
        .and_then(|info| cpu_model_in(&info))
        .unwrap_or_else(|| std::env::consts::ARCH.to_string())
}

/// The `model name` of a `/proc/cpuinfo` text, followed by the core generation where the
/// model name leaves it out (virtual AMD hosts report only "AMD EPYC"): `AMD EPYC (Zen 4)`.
pub fn cpu_model_in(cpuinfo: &str) -> Option<String> {
    let field = |key: &str| {
        cpuinfo
            .lines()
            .find(|l| l.split(':').next().map(str::trim) == Some(key))
            .and_then(|l| l.split_once(':'))
            .map(|(_, v)| v.trim().to_string())
    };
    let model = field("model name")?;
    let generation = match (
        field("vendor_id").as_deref(),
        field("cpu family").as_deref(),
    ) {
        (Some("AuthenticAMD"), Some("23")) => Some("Zen 2 or older"),
        (Some("AuthenticAMD"), Some("25")) => {
            let avx512 = field("flags").is_some_and(|f| f.split(' ').any(|x| x == "avx512f"));
            Some(if avx512 { "Zen 4" } else { "Zen 3" })
        }
        (Some("AuthenticAMD"), Some("26")) => Some("Zen 5"),
        _ => None,
    };
    Some(match generation {
        Some(g) if !model.contains("Zen") => format!("{model} ({g})"),
        _ => model,
    })
}

/// Logical cores this process may use.
pub fn cores() -> usize {
    std::thread::available_parallelism()
        .map(|n| n.get())
        .unwrap_or(1)
}

/// This machine in words: `CPU MODEL, N cores` (`AMD EPYC (Zen 4), 2 cores`).
pub fn machine() -> String {
    format!("{}, {} cores", cpu_model(), cores())
}

/// Today's UTC date, `YYYY-MM-DD`.
pub fn today() -> String {
    let days = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_secs() / 86_400)
        .unwrap_or(0) as i64;
    civil_date(days)
}

/// `YYYY-MM-DD` of a day number since 1970-01-01 (proleptic Gregorian).
pub fn civil_date(days: i64) -> String {
    // Howard Hinnant's days-to-civil algorithm.
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = doy - (153 * mp + 2) / 5 + 1;
    let m = if mp < 10 { mp + 3 } else { mp - 9 };
    let y = yoe + era * 400 + i64::from(m <= 2);
    format!("{y:04}-{m:02}-{d:02}")
}

/// The short commit of the source tree this crate was built from (`git rev-parse --short
/// HEAD` there), `None` where git or the repository is absent.
pub fn git_commit() -> Option<String> {
    let out = std::process::Command::new("git")
        .args(["rev-parse", "--short", "HEAD"])
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .stderr(std::process::Stdio::null())
        .output()
        .ok()?;
    let hash = String::from_utf8(out.stdout).ok()?.trim().to_string();
    (out.status.success() && !hash.is_empty()).then_some(hash)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn args(a: &[&str]) -> Vec<String> {
        a.iter().map(|s| s.to_string()).collect()
    }

    #[test]
    fn the_json_option_is_taken_out_of_the_arguments() {
        let mut a = args(&["2", "--json", "out/r.json", "step"]);
        assert_eq!(take_json_arg(&mut a), Ok(Some("out/r.json".into())));
        assert_eq!(a, args(&["2", "step"]));
        let mut a = args(&["2", "step"]);
        assert_eq!(take_json_arg(&mut a), Ok(None));
        assert_eq!(a, args(&["2", "step"]));
        let mut a = args(&["2", "--json"]);
        assert!(take_json_arg(&mut a).unwrap_err().contains("--json PATH"));
    }

    #[test]
    fn commands_quote_what_a_shell_would_read() {
        assert_eq!(
            example_command("augsplat-field", "bench", &args(&["2", "step", "30"])),
            "cargo run --release -p augsplat-field --example bench -- 2 step 30"
        );
        assert_eq!(
            example_command("augsplat-scene", "bench_triangulate", &[]),
            "cargo run --release -p augsplat-scene --example bench_triangulate"
        );
        assert_eq!(
            example_command("p", "e", &args(&["a b", "it's", ""])),
            r"cargo run --release -p p --example e -- 'a b' 'it'\''s' ''"
        );
    }

    #[test]
    fn machine_and_dates() {
        let info = "processor\t: 0\nmodel name\t: AMD EPYC 9R14 96-Core Processor\nflags\t: fpu\n";
        assert_eq!(
            cpu_model_in(info).as_deref(),
            Some("AMD EPYC 9R14 96-Core Processor")
        );
        assert_eq!(cpu_model_in("Features\t: neon\n"), None);
        let epyc = |flags: &str| {
            format!(
                "vendor_id\t: AuthenticAMD\ncpu family\t: 25\nmodel name\t: AMD EPYC\nflags\t\t: {flags}\n"
            )
        };
        assert_eq!(
            cpu_model_in(&epyc("fpu avx2 fma avx512f")).as_deref(),
            Some("AMD EPYC (Zen 4)")
        );
        assert_eq!(
            cpu_model_in(&epyc("fpu avx2 fma avx512")).as_deref(),
            Some("AMD EPYC (Zen 3)")
        );
        assert!(machine().ends_with(" cores"), "{}", machine());
        assert_eq!(civil_date(0), "1970-01-01");
        assert_eq!(civil_date(20_417), "2025-11-25");
        assert_eq!(civil_date(11_016), "2000-02-29");
        assert_eq!(today().len(), 10);
    }

    #[test]
    fn the_figures_of_the_docs_are_records() {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../docs/figures");
        let mut n = 0;
        for entry in std::fs::read_dir(&dir).unwrap() {
            let path = entry.unwrap().path();
            if path.extension().is_none_or(|e| e != "json") {
                continue;
            }
            let text = std::fs::read_to_string(&path).unwrap();
            let r: BenchRecord =
                serde_json::from_str(&text).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
            assert!(r.value.is_finite(), "{}", path.display());
            n += 1;
        }
        assert!(
            (1..=12).contains(&n),
            "{n} records: docs/current.md has 1 to 12 rows"
        );
    }

    #[test]
    fn a_record_round_trips_and_refuses_a_value_that_is_not_a_number() {
        let dir = tempfile::tempdir().unwrap();
        let mut r = BenchRecord {
            what: "w".into(),
            command: "c".into(),
            figure: "1.5 ms".into(),
            value: 1.5,
            unit: "ms".into(),
            commit: None,
            date: "2026-11-28".into(),
            machine: "cpu (2 cores)".into(),
        };
        let path = dir.path().join("figures/r.json");
        r.write(&path).unwrap();
        let text = std::fs::read_to_string(&path).unwrap();
        assert!(
            text.contains("\"commit\": null") && text.ends_with("}\n"),
            "{text}"
        );
        let back: BenchRecord = serde_json::from_str(&text).unwrap();
        assert_eq!(back, r);
        r.value = f64::NAN;
        let e = r.write(&path).unwrap_err().to_string();
        assert!(e.contains("r.json") && e.contains("NaN"), "{e}");
    }
}
