//! Claims on keys that hold on shared filesystems (NFS, Lustre), where OS file locks are not
//! reliable: a claim is a file `locks/<key>.claim` created exclusively, by hard-linking a
//! fully written temporary file into place (atomic on every POSIX filesystem and on NFS,
//! unlike `O_EXCL` on old NFS clients). It names its holder (host, pid, the process's start
//! time, the Slurm job when there is one, and a random token) and carries a heartbeat: a
//! thread touches its modification time every [`ClaimPolicy::heartbeat`].
//!
//! A claim is **stale**, and is taken over, when
//! - its heartbeat is older than [`ClaimPolicy::stale_after`] (the holder died on another
//!   machine, or hangs), or
//! - its modification time lies further in the future than [`ClaimPolicy::stale_after`] (the
//!   holder's clock is ahead of ours, as between NFS hosts with skewed clocks, or the time was
//!   set by hand): the mtime says nothing then, and the claim is judged by its heartbeat's
//!   *content* instead — the holder also rewrites a beat file `locks/<key>.claim.beat` with a
//!   counter at each heartbeat, and a waiter that sees neither it nor the mtime change for
//!   `stale_after` on its own clock takes the claim over, or
//! - its holder ran on this host and that process no longer exists (pid gone, or reused by a
//!   process that started at another time): a killed local run is taken over at once, or
//! - a caller that knows the holder's Slurm job has ended breaks it ([`break_claim_of_job`]).
//!
//! Taking over renames the stale file to a unique name (only one taker's rename succeeds),
//! checks that the renamed file is the one judged stale (else links it back), and claims
//! afresh. Claims only prevent duplicate work: every store write is an atomic rename of
//! content-addressed data, so even two holders of one key (a holder judged stale while it
//! still ran) write identical entries.

use super::files::{hostname, now_unix, unique_suffix};
use crate::error::{io, EngineError};
use serde::{Deserialize, Serialize};
use std::fs;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, SystemTime};

/// Timing of the claim protocol.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ClaimPolicy {
    /// A claim whose heartbeat is older than this is stale.
    pub stale_after: Duration,
    /// How often a holder touches its claim.
    pub heartbeat: Duration,
}

impl Default for ClaimPolicy {
    /// 60 s stale bound and a 10 s heartbeat, or `AUGSPLAT_CLAIM_STALE_SECS` (the heartbeat is
    /// then a sixth of it).
    fn default() -> Self {
        let stale = std::env::var("AUGSPLAT_CLAIM_STALE_SECS")
            .ok()
            .and_then(|s| s.trim().parse::<f64>().ok())
            .filter(|s| s.is_finite() && *s > 0.0)
            .unwrap_or(60.0);
        ClaimPolicy {
            stale_after: Duration::from_secs_f64(stale),
            heartbeat: Duration::from_secs_f64(stale / 6.0),
        }
    }
}

/// Who holds a claim: the content of a claim file.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct ClaimHolder {
    /// Host name.
    pub host: String,
    /// Process id.
    pub pid: u32,
    /// The process's start time in clock ticks since boot (`/proc/PID/stat`), to tell a
    /// reused pid apart (0 when unknown).
    pub start_ticks: u64,
    /// The Slurm job (`JOBID` or `ARRAYJOB_TASK`) when the holder runs in one.
    pub slurm_job: Option<String>,
    /// Seconds since the Unix epoch when claimed.
    pub since_unix: u64,
    /// Unique per claim.
    pub token: String,
}

impl ClaimHolder {
    /// This process.
    pub fn this_process() -> ClaimHolder {
        let pid = std::process::id();
        ClaimHolder {
            host: hostname(),
            pid,
            start_ticks: start_ticks(pid).unwrap_or(0),
            slurm_job: slurm_job_id(),
            since_unix: now_unix(),
            token: format!("{pid}-{}", unique_suffix()),
        }
    }

    /// "pid 123 on host" or "Slurm job 45 (pid 123 on host)".
    pub fn describe(&self) -> String {
        match &self.slurm_job {
            Some(j) => format!("Slurm job {j} (pid {} on {})", self.pid, self.host),
            None => format!("pid {} on {}", self.pid, self.host),
        }
    }
}

/// The Slurm job this process runs in (`SLURM_ARRAY_JOB_ID_SLURM_ARRAY_TASK_ID` for an array
/// task, else `SLURM_JOB_ID`), if any.
pub fn slurm_job_id() -> Option<String> {
    let arr = std::env::var("SLURM_ARRAY_JOB_ID").ok();
    let task = std::env::var("SLURM_ARRAY_TASK_ID").ok();
    match (arr, task) {
        (Some(a), Some(t)) if !a.is_empty() && !t.is_empty() => Some(format!("{a}_{t}")),
        _ => std::env::var("SLURM_JOB_ID").ok().filter(|s| !s.is_empty()),
    }
}

/// Field 22 of `/proc/PID/stat`: the process's start time in clock ticks since boot.
fn start_ticks(pid: u32) -> Option<u64> {
    let s = fs::read_to_string(format!("/proc/{pid}/stat")).ok()?;
    // The command name (field 2) is in parentheses and may hold spaces: split after it.
    let rest = &s[s.rfind(')')? + 1..];
    rest.split_whitespace().nth(19)?.parse().ok()
}

/// Whether the holder is a process of this host that no longer exists.
fn holder_dead_here(h: &ClaimHolder) -> bool {
    if h.host != hostname() || !Path::new("/proc/self/stat").exists() {
        return false;
    }
    match start_ticks(h.pid) {
        None => true,
        Some(t) => h.start_ticks != 0 && t != h.start_ticks,
    }
}

/// A held claim; dropping it stops the heartbeat and removes the claim file (if it is still
/// this claim's).
pub struct Claim {
    path: PathBuf,
    token: String,
    stop: Arc<AtomicBool>,
    heartbeat: Option<std::thread::JoinHandle<()>>,
    /// Whether another process held it first (we waited).
    pub waited: bool,
    /// The stale claim taken over, if any.
    pub took_over: Option<ClaimHolder>,
}

impl Drop for Claim {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(h) = self.heartbeat.take() {
            h.thread().unpark();
            let _ = h.join();
        }
        if read_holder(&self.path).is_some_and(|h| h.token == self.token) {
            let _ = fs::remove_file(&self.path);
            let _ = fs::remove_file(beat_path(&self.path));
        }
    }
}

/// The claim file of a key (hex) in the folder `locks`.
pub fn claim_path(locks: &Path, key_hex: &str) -> PathBuf {
    locks.join(format!("{key_hex}.claim"))
}

/// The holder named by a claim file, if it exists and is readable.
pub fn read_holder(path: &Path) -> Option<ClaimHolder> {
    let bytes = fs::read(path).ok()?;
    serde_json::from_slice(&bytes).ok()
}

/// Why the claim at `path` is stale (`None`: it is live, or gone).
pub fn stale_reason(path: &Path, policy: &ClaimPolicy) -> Option<(ClaimHolder, String)> {
    stale_reason_in_job(path, policy, slurm_job_id().as_deref())
}

/// [`stale_reason`] for a claimant running in Slurm job `own_job`: a claim held by an earlier
/// attempt of the same job (a requeued or preempted job keeps its id, and may restart on
/// another node) is stale at once.
pub fn stale_reason_in_job(
    path: &Path,
    policy: &ClaimPolicy,
    own_job: Option<&str>,
) -> Option<(ClaimHolder, String)> {
    let meta = fs::metadata(path).ok()?;
    let holder = read_holder(path);
    let age = meta
        .modified()
        .ok()
        .and_then(|m| SystemTime::now().duration_since(m).ok())
        .unwrap_or(Duration::ZERO);
    match holder {
        // A claim file that cannot be read: a writer died before linking it can't leave one
        // (it is written in full before it is linked), so it is foreign or damaged; judge it
        // by its age only.
        None => (age > policy.stale_after).then(|| {
            (
                unknown_holder(),
                format!("unreadable, last touched {:.0} s ago", age.as_secs_f64()),
            )
        }),
        Some(h)
            if own_job.is_some()
                && h.slurm_job.as_deref() == own_job
                && (h.pid != std::process::id() || h.host != hostname()) =>
        {
            let why = format!(
                "its holder, {}, was an earlier attempt of this Slurm job",
                h.describe()
            );
            Some((h, why))
        }
        Some(h) if holder_dead_here(&h) => {
            let why = format!("its holder, {}, is no longer running", h.describe());
            Some((h, why))
        }
        // A time in the future: only the waiter's watch of its heartbeat can tell (see
        // `acquire`).
        Some(_) if mtime_in_future(path, policy) => None,
        Some(h) if age > policy.stale_after => {
            let why = format!(
                "its holder, {}, has not renewed it for {:.0} s",
                h.describe(),
                age.as_secs_f64()
            );
            Some((h, why))
        }
        Some(_) => None,
    }
}

/// The beat file beside claim file `path`: its holder's token and a counter, rewritten at
/// every heartbeat (what a waiter watches when the claim's mtime cannot be trusted).
pub fn beat_path(path: &Path) -> PathBuf {
    let mut name = path.file_name().unwrap_or_default().to_os_string();
    name.push(".beat");
    path.with_file_name(name)
}

/// Whether the claim file's modification time lies more than `policy.stale_after` in the
/// future (clock skew between hosts, or a time set by hand): then only its heartbeat's content
/// tells whether its holder lives.
pub fn mtime_in_future(path: &Path, policy: &ClaimPolicy) -> bool {
    fs::metadata(path)
        .ok()
        .and_then(|m| m.modified().ok())
        .and_then(|m| m.duration_since(SystemTime::now()).ok())
        .is_some_and(|ahead| ahead > policy.stale_after)
}

/// What a waiter last saw of a claim whose mtime cannot be trusted, measured on its own clock.
struct BeatWatch {
    /// The claim's holder token, its beat file's content and its mtime when last seen.
    seen: (Option<String>, Option<Vec<u8>>, Option<SystemTime>),
    /// When that was first seen.
    since: std::time::Instant,
}

impl BeatWatch {
    fn look(path: &Path) -> (Option<String>, Option<Vec<u8>>, Option<SystemTime>) {
        (
            read_holder(path).map(|h| h.token),
            fs::read(beat_path(path)).ok(),
            fs::metadata(path).ok().and_then(|m| m.modified().ok()),
        )
    }
    /// How long nothing of the claim has changed (own clock).
    fn unchanged_for(watch: &mut Option<BeatWatch>, path: &Path) -> Duration {
        let now = BeatWatch::look(path);
        match watch {
            Some(w) if w.seen == now => w.since.elapsed(),
            _ => {
                *watch = Some(BeatWatch {
                    seen: now,
                    since: std::time::Instant::now(),
                });
                Duration::ZERO
            }
        }
    }
}

/// Tries once to create the claim file `path` for `holder`: `Ok(true)` when created.
fn try_create(path: &Path, holder: &ClaimHolder) -> Result<bool, EngineError> {
    let dir = path.parent().unwrap_or(Path::new("."));
    let tmp = dir.join(format!(".{}.tmp", holder.token));
    let bytes = serde_json::to_vec(holder).expect("a claim serialises");
    fs::write(&tmp, bytes).map_err(io("writing claim", &tmp))?;
    let linked = match fs::hard_link(&tmp, path) {
        Ok(()) => true,
        Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => false,
        // NFS may report a failure for a link that was made (a lost reply to a retried
        // request): the link count tells.
        Err(e) => {
            if link_count(&tmp) == Some(2) {
                true
            } else {
                let _ = fs::remove_file(&tmp);
                return Err(EngineError::Io {
                    what: "creating claim",
                    path: path.to_path_buf(),
                    source: e,
                });
            }
        }
    };
    let _ = fs::remove_file(&tmp);
    Ok(linked)
}

/// Rewrites the beat file of claim `path` (atomically: written beside it, then renamed).
fn write_beat(path: &Path, token: &str, beats: u64) {
    let beat = beat_path(path);
    let tmp = beat.with_extension(format!("beat.{}", unique_suffix()));
    if fs::write(&tmp, format!("{token} {beats}")).is_ok() && fs::rename(&tmp, &beat).is_err() {
        let _ = fs::remove_file(&tmp);
    }
}

/// The holder of a claim file that cannot be read.
fn unknown_holder() -> ClaimHolder {
    ClaimHolder {
        host: "?".into(),
        pid: 0,
        start_ticks: 0,
        slurm_job: None,
        since_unix: 0,
        token: String::new(),
    }
}

#[cfg(unix)]
fn link_count(p: &Path) -> Option<u64> {
    use std::os::unix::fs::MetadataExt;
    fs::metadata(p).ok().map(|m| m.nlink())
}

#[cfg(not(unix))]
fn link_count(_p: &Path) -> Option<u64> {
    None
}

/// Moves the stale claim at `path` aside if it is still the one held by `stale` (by token);
/// `true` when it was removed.
fn take_over(path: &Path, stale: &ClaimHolder) -> bool {
    let dir = path.parent().unwrap_or(Path::new("."));
    let aside = dir.join(format!(".stale-{}", unique_suffix()));
    if fs::rename(path, &aside).is_err() {
        return false; // gone already (released, or another taker won)
    }
    let moved = read_holder(&aside);
    if moved.as_ref().is_some_and(|m| m.token != stale.token) {
        // A fresh claim was made between our check and the rename: put it back.
        let _ = fs::hard_link(&aside, path);
        let _ = fs::remove_file(&aside);
        return false;
    }
    let _ = fs::remove_file(&aside);
    true
}

/// Claims the key whose claim file is `path`: returns at once when nobody holds it, else
/// waits until the holder releases it or its claim is stale (and then takes it over).
pub fn acquire(path: &Path, policy: &ClaimPolicy) -> Result<Claim, EngineError> {
    acquire_reporting(path, policy, &|_| {})
}

/// [`acquire`], calling `on_wait` with `Some(holder)` each time the claim turns out to be
/// held by someone new (so a run can say whom it waits for), and with `None` once it holds the
/// claim after having waited.
pub fn acquire_reporting(
    path: &Path,
    policy: &ClaimPolicy,
    on_wait: &dyn Fn(Option<&ClaimHolder>),
) -> Result<Claim, EngineError> {
    let holder = ClaimHolder::this_process();
    let mut waited = false;
    let mut took_over = None;
    let mut pause = Duration::from_millis(50);
    let mut reported: Option<String> = None;
    let mut watch: Option<BeatWatch> = None;
    loop {
        if try_create(path, &holder)? {
            break;
        }
        let stale = stale_reason(path, policy).or_else(|| {
            // A claim dated in the future: stale when nothing of it changed for the bound.
            if !mtime_in_future(path, policy) {
                watch = None;
                return None;
            }
            let quiet = BeatWatch::unchanged_for(&mut watch, path);
            (quiet > policy.stale_after).then(|| {
                let h = read_holder(path).unwrap_or_else(unknown_holder);
                let why = format!(
                    "its holder, {}, dated it in the future and its heartbeat has not \
                     changed for {:.0} s",
                    h.describe(),
                    quiet.as_secs_f64()
                );
                (h, why)
            })
        });
        if let Some((stale, _why)) = stale {
            if take_over(path, &stale) {
                took_over = Some(stale);
                watch = None;
                continue;
            }
        }
        if let Some(h) = read_holder(path) {
            if reported.as_deref() != Some(h.token.as_str()) {
                on_wait(Some(&h));
                reported = Some(h.token.clone());
            }
        }
        waited = true;
        std::thread::sleep(pause);
        pause = (pause * 2).min(Duration::from_secs(1));
    }
    if reported.is_some() {
        on_wait(None);
    }
    let stop = Arc::new(AtomicBool::new(false));
    let heartbeat = {
        let (path, token, stop, every) = (
            path.to_path_buf(),
            holder.token.clone(),
            stop.clone(),
            policy.heartbeat,
        );
        let mut beats: u64 = 0;
        std::thread::Builder::new()
            .name("claim-heartbeat".into())
            .spawn(move || loop {
                std::thread::park_timeout(every);
                if stop.load(Ordering::Relaxed) {
                    return;
                }
                if read_holder(&path).is_none_or(|h| h.token != token) {
                    return; // taken over (we were judged stale): stop renewing someone else's
                }
                if let Ok(f) = fs::OpenOptions::new().append(true).open(&path) {
                    let _ = f.set_modified(SystemTime::now());
                }
                beats += 1;
                write_beat(&path, &token, beats);
            })
            .ok()
    };
    Ok(Claim {
        path: path.to_path_buf(),
        token: holder.token,
        stop,
        heartbeat,
        waited,
        took_over,
    })
}

/// Removes the claim at `path` if its holder ran in Slurm job `job` (which the caller knows
/// has ended); `true` when removed.
pub fn break_claim_of_job(path: &Path, job: &str) -> bool {
    match read_holder(path) {
        Some(h) if h.slurm_job.as_deref() == Some(job) => take_over(path, &h),
        _ => false,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn policy(stale_ms: u64) -> ClaimPolicy {
        ClaimPolicy {
            stale_after: Duration::from_millis(stale_ms),
            heartbeat: Duration::from_millis(stale_ms / 6),
        }
    }

    #[test]
    fn a_claim_is_exclusive_and_released_on_drop() {
        let dir = tempfile::tempdir().unwrap();
        let p = claim_path(dir.path(), "ab");
        let c = acquire(&p, &policy(60_000)).unwrap();
        assert!(!c.waited);
        assert_eq!(read_holder(&p).unwrap().pid, std::process::id());
        assert!(!try_create(&p, &ClaimHolder::this_process()).unwrap());
        let p2 = p.clone();
        let t = std::thread::spawn(move || acquire(&p2, &policy(60_000)).unwrap().waited);
        std::thread::sleep(Duration::from_millis(300));
        drop(c);
        assert!(
            t.join().unwrap(),
            "the second claimant waited for the first"
        );
        assert!(!p.exists(), "released");
        // No temporary files are left behind.
        assert_eq!(fs::read_dir(dir.path()).unwrap().count(), 0);
    }

    #[test]
    fn a_live_claim_is_renewed_and_not_stale() {
        let dir = tempfile::tempdir().unwrap();
        let p = claim_path(dir.path(), "cd");
        let pol = policy(600);
        let _c = acquire(&p, &pol).unwrap();
        std::thread::sleep(Duration::from_millis(1500));
        assert!(
            stale_reason(&p, &pol).is_none(),
            "the heartbeat keeps it fresh"
        );
    }

    #[test]
    fn a_claim_of_a_dead_local_process_is_taken_over_at_once() {
        let dir = tempfile::tempdir().unwrap();
        let p = claim_path(dir.path(), "ef");
        let mut child = std::process::Command::new("true").spawn().unwrap();
        let pid = child.id();
        child.wait().unwrap();
        let mut dead = ClaimHolder::this_process();
        dead.pid = pid;
        dead.start_ticks = 1;
        assert!(try_create(&p, &dead).unwrap());
        let pol = policy(3_600_000);
        let why = stale_reason(&p, &pol).expect("stale").1;
        assert!(why.contains("no longer running"), "{why}");
        let c = acquire(&p, &pol).unwrap();
        assert_eq!(c.took_over.as_ref().map(|h| h.pid), Some(pid));
    }

    #[test]
    fn a_claim_without_heartbeat_is_taken_over_after_the_bound() {
        let dir = tempfile::tempdir().unwrap();
        let p = claim_path(dir.path(), "01");
        let mut remote = ClaimHolder::this_process();
        remote.host = "another-host".into();
        assert!(try_create(&p, &remote).unwrap());
        let pol = policy(800);
        assert!(stale_reason(&p, &pol).is_none(), "fresh");
        let t = std::time::Instant::now();
        let c = acquire(&p, &pol).unwrap();
        let waited = t.elapsed();
        assert!(c.waited && c.took_over.is_some());
        assert!(waited >= Duration::from_millis(700), "{waited:?}");
        assert!(waited < Duration::from_secs(5), "{waited:?}");
    }

    #[test]
    fn a_claim_dated_in_the_future_is_judged_by_its_heartbeat() {
        let dir = tempfile::tempdir().unwrap();
        let p = claim_path(dir.path(), "89");
        let mut remote = ClaimHolder::this_process();
        remote.host = "host-with-a-fast-clock".into();
        assert!(try_create(&p, &remote).unwrap());
        let future = SystemTime::now() + Duration::from_secs(3600);
        fs::File::options()
            .append(true)
            .open(&p)
            .unwrap()
            .set_modified(future)
            .unwrap();
        let pol = policy(600);
        assert!(mtime_in_future(&p, &pol));
        assert!(
            stale_reason(&p, &pol).is_none(),
            "the mtime alone decides nothing"
        );
        // Nobody renews it: taken over once nothing changed for the bound, on our clock.
        let seen = std::sync::Mutex::new(Vec::new());
        let t = std::time::Instant::now();
        let c = acquire_reporting(&p, &pol, &|h| {
            if let Some(h) = h {
                seen.lock().unwrap().push(h.host.clone())
            }
        })
        .unwrap();
        let waited = t.elapsed();
        assert!(c.took_over.is_some());
        assert!(waited >= Duration::from_millis(500), "{waited:?}");
        assert!(waited < Duration::from_secs(10), "{waited:?}");
        assert_eq!(
            *seen.lock().unwrap(),
            ["host-with-a-fast-clock"],
            "whom it waited for"
        );
    }

    #[test]
    fn a_live_claim_dated_in_the_future_is_not_taken_over() {
        let dir = tempfile::tempdir().unwrap();
        let p = claim_path(dir.path(), "8a");
        let pol = policy(600);
        let held = acquire(&p, &pol).unwrap();
        // The holder's clock is an hour ahead: each heartbeat dates the claim in the future.
        let stop = Arc::new(AtomicBool::new(false));
        let skew = {
            let (p, stop) = (p.clone(), stop.clone());
            std::thread::spawn(move || {
                while !stop.load(Ordering::Relaxed) {
                    if let Ok(f) = fs::File::options().append(true).open(&p) {
                        let _ = f.set_modified(SystemTime::now() + Duration::from_secs(3600));
                    }
                    std::thread::sleep(Duration::from_millis(20));
                }
            })
        };
        let p2 = p.clone();
        let waiter = std::thread::spawn(move || acquire(&p2, &pol).unwrap().took_over.is_some());
        std::thread::sleep(Duration::from_millis(2000));
        assert!(p.exists() && read_holder(&p).is_some());
        drop(held);
        stop.store(true, Ordering::Relaxed);
        skew.join().unwrap();
        assert!(
            !waiter.join().unwrap(),
            "a live holder's claim was never taken over"
        );
    }

    #[test]
    fn a_fresh_claim_is_not_taken_by_a_late_taker() {
        let dir = tempfile::tempdir().unwrap();
        let p = claim_path(dir.path(), "23");
        let old = ClaimHolder {
            token: "old".into(),
            ..ClaimHolder::this_process()
        };
        let fresh = ClaimHolder::this_process();
        assert!(try_create(&p, &fresh).unwrap());
        assert!(!take_over(&p, &old), "the file is not the stale one");
        assert_eq!(read_holder(&p).unwrap().token, fresh.token);
    }

    #[test]
    fn an_earlier_attempt_of_the_same_slurm_job_is_stale_at_once() {
        let dir = tempfile::tempdir().unwrap();
        let p = claim_path(dir.path(), "67");
        let h = ClaimHolder {
            host: "node-a".into(),
            slurm_job: Some("99".into()),
            ..ClaimHolder::this_process()
        };
        assert!(try_create(&p, &h).unwrap());
        let pol = policy(3_600_000);
        assert!(stale_reason_in_job(&p, &pol, None).is_none());
        assert!(stale_reason_in_job(&p, &pol, Some("98")).is_none());
        let why = stale_reason_in_job(&p, &pol, Some("99")).unwrap().1;
        assert!(why.contains("earlier attempt"), "{why}");
    }

    #[test]
    fn a_slurm_jobs_claim_is_broken_by_its_job_id_only() {
        let dir = tempfile::tempdir().unwrap();
        let p = claim_path(dir.path(), "45");
        let h = ClaimHolder {
            slurm_job: Some("77_3".into()),
            ..ClaimHolder::this_process()
        };
        assert!(try_create(&p, &h).unwrap());
        assert!(!break_claim_of_job(&p, "77_4"));
        assert!(p.exists());
        assert!(break_claim_of_job(&p, "77_3"));
        assert!(!p.exists());
    }
}
