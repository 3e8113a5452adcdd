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
//! - its holder ran on this host and that process no longer exists (pid gone, or reused by a
//!   process that started at another time): a killed local run is taken over at once, or
//! - a caller that knows the holder's Slurm job has ended breaks it ([`break_claim_of_job`]).
//!
//! Taking over renames the stale file to a unique name (only one taker's rename succeeds),
//! checks that the renamed file is the one judged stale (else links it back), and claims
//! afresh. Claims only prevent duplicate work: every store write is an atomic rename of
//! content-addressed data, so even two holders of one key (a holder judged stale while it
//! still ran) write identical entries.

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
            host: crate::store::hostname(),
            pid,
            start_ticks: start_ticks(pid).unwrap_or(0),
            slurm_job: slurm_job_id(),
            since_unix: crate::store::now_unix(),
            token: format!("{pid}-{}", crate::store::unique_suffix()),
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
    if h.host != crate::store::hostname() || !Path::new("/proc/self/stat").exists() {
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
                ClaimHolder {
                    host: "?".into(),
                    pid: 0,
                    start_ticks: 0,
                    slurm_job: None,
                    since_unix: 0,
                    token: String::new(),
                },
                format!("unreadable, last touched {:.0} s ago", age.as_secs_f64()),
            )
        }),
        Some(h)
            if own_job.is_some()
                && h.slurm_job.as_deref() == own_job
                && (h.pid != std::process::id() || h.host != crate::store::hostname()) =>
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
    let aside = dir.join(format!(".stale-{}", crate::store::unique_suffix()));
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
    let holder = ClaimHolder::this_process();
    let mut waited = false;
    let mut took_over = None;
    let mut pause = Duration::from_millis(50);
    loop {
        if try_create(path, &holder)? {
            break;
        }
        if let Some((stale, _why)) = stale_reason(path, policy) {
            if take_over(path, &stale) {
                took_over = Some(stale);
                continue;
            }
        }
        waited = true;
        std::thread::sleep(pause);
        pause = (pause * 2).min(Duration::from_secs(1));
    }
    let stop = Arc::new(AtomicBool::new(false));
    let heartbeat = {
        let (path, token, stop, every) = (
            path.to_path_buf(),
            holder.token.clone(),
            stop.clone(),
            policy.heartbeat,
        );
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
