//! How much CPU a benchmark actually got: this process's CPU time and the machine's steal
//! time, read from Linux `/proc`.
//!
//! On a shared virtual machine the hypervisor may run other guests on our virtual CPUs
//! ("steal" time). Wall-clock figures then overstate the cost of the code, and two threads
//! may get far less than two cores. [`Usage`] measures an interval three ways — wall
//! time, this process's user + system CPU time (which excludes stolen time), and the share
//! of the machine's CPU time that was stolen — so a benchmark can print all three.
//!
//! Off Linux (or without `/proc`) the CPU figures are `None`; wall time always works.

use std::time::Instant;

/// Clock ticks per second of the `/proc` counters (`USER_HZ`): 100 on every mainstream
/// Linux build (the kernel's ABI keeps it fixed whatever the internal tick rate).
pub const USER_HZ: f64 = 100.0;

/// User + system CPU seconds from the text of `/proc/<pid>/stat` (fields 14 and 15,
/// counted after the parenthesised command name, which may itself contain spaces or
/// parentheses).
pub fn parse_process_stat(text: &str) -> Option<f64> {
    let after = &text[text.rfind(')')? + 1..];
    let fields: Vec<&str> = after.split_whitespace().collect();
    // After the name: state (field 3) is index 0, so utime (14) is 11 and stime (15) is 12.
    let utime: u64 = fields.get(11)?.parse().ok()?;
    let stime: u64 = fields.get(12)?.parse().ok()?;
    Some((utime + stime) as f64 / USER_HZ)
}

/// User + system CPU seconds used by this process so far.
pub fn process_cpu_seconds() -> Option<f64> {
    parse_process_stat(&std::fs::read_to_string("/proc/self/stat").ok()?)
}

/// The machine's aggregate CPU time counters (first line of `/proc/stat`), in ticks.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct HostTicks {
    /// user + nice + system + irq + softirq.
    pub busy: u64,
    /// idle + iowait.
    pub idle: u64,
    /// Time the hypervisor gave our virtual CPUs to someone else.
    pub steal: u64,
}

impl HostTicks {
    /// Parses the `cpu ` line of `/proc/stat` (`user nice system idle iowait irq softirq
    /// steal …`; kernels before 2.6.11 have no steal column, read as 0).
    pub fn parse(text: &str) -> Option<HostTicks> {
        let line = text.lines().find(|l| l.starts_with("cpu "))?;
        let v: Vec<u64> = line
            .split_whitespace()
            .skip(1)
            .map(|f| f.parse().ok())
            .collect::<Option<_>>()?;
        let at = |i: usize| v.get(i).copied().unwrap_or(0);
        if v.len() < 4 {
            return None;
        }
        Some(HostTicks {
            busy: at(0) + at(1) + at(2) + at(5) + at(6),
            idle: at(3) + at(4),
            steal: at(7),
        })
    }

    /// The counters now.
    pub fn read() -> Option<HostTicks> {
        HostTicks::parse(&std::fs::read_to_string("/proc/stat").ok()?)
    }

    /// Share of the machine's CPU time between `earlier` and `self` that was stolen
    /// (0 when no time passed).
    pub fn steal_share_since(&self, earlier: &HostTicks) -> f64 {
        let d = |a: u64, b: u64| a.saturating_sub(b) as f64;
        let steal = d(self.steal, earlier.steal);
        let total = d(self.busy, earlier.busy) + d(self.idle, earlier.idle) + steal;
        if total > 0.0 {
            steal / total
        } else {
            0.0
        }
    }
}

/// A measurement in progress: wall clock, process CPU and host counters at its start.
#[derive(Clone, Copy, Debug)]
pub struct Usage {
    wall: Instant,
    cpu: Option<f64>,
    host: Option<HostTicks>,
}

/// What an interval cost, measured three ways.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct UsageReport {
    /// Wall-clock seconds.
    pub wall_s: f64,
    /// This process's user + system CPU seconds (stolen time excluded).
    pub cpu_s: Option<f64>,
    /// Share of the machine's CPU time stolen by the hypervisor.
    pub steal_share: Option<f64>,
}

impl Usage {
    /// Starts measuring.
    pub fn start() -> Usage {
        Usage {
            wall: Instant::now(),
            cpu: process_cpu_seconds(),
            host: HostTicks::read(),
        }
    }

    /// The cost since [`Usage::start`].
    pub fn stop(&self) -> UsageReport {
        let wall_s = self.wall.elapsed().as_secs_f64();
        let cpu_s = match (self.cpu, process_cpu_seconds()) {
            (Some(a), Some(b)) => Some(b - a),
            _ => None,
        };
        let steal_share = match (self.host, HostTicks::read()) {
            (Some(a), Some(b)) => Some(b.steal_share_since(&a)),
            _ => None,
        };
        UsageReport {
            wall_s,
            cpu_s,
            steal_share,
        }
    }
}

impl UsageReport {
    /// Average number of this process's threads that were running (CPU / wall).
    pub fn busy_threads(&self) -> Option<f64> {
        self.cpu_s
            .filter(|_| self.wall_s > 0.0)
            .map(|c| c / self.wall_s)
    }

    /// One line for a benchmark: CPU time, busy threads and the stolen share.
    pub fn describe(&self) -> String {
        let cpu = match (self.cpu_s, self.busy_threads()) {
            (Some(c), Some(b)) => format!("CPU {c:.2} s ({b:.2} threads busy on average)"),
            _ => "CPU time unavailable".to_string(),
        };
        let steal = match self.steal_share {
            Some(s) => format!("host steal {:.0} %", 100.0 * s),
            None => "host steal unavailable".to_string(),
        };
        format!("wall {:.2} s, {cpu}, {steal}", self.wall_s)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn process_stat_fields_are_counted_after_the_command_name() {
        // A command name with spaces and a parenthesis must not shift the fields.
        let line = "4242 (my (odd) bench) R 1 4242 4242 0 -1 4194304 500 0 0 0 \
                    1234 56 0 0 20 0 3 0 100 1000 200";
        assert_eq!(parse_process_stat(line), Some((1234 + 56) as f64 / USER_HZ));
        assert_eq!(parse_process_stat("4242 (x) R 1 2"), None);
        assert_eq!(parse_process_stat("no parenthesis"), None);
    }

    #[test]
    fn host_ticks_split_busy_idle_and_steal() {
        let text = "cpu  100 5 20 300 7 1 2 50 0 0\ncpu0 50 2 10 150 3 0 1 25 0 0\n";
        let t = HostTicks::parse(text).unwrap();
        assert_eq!(
            t,
            HostTicks {
                busy: 100 + 5 + 20 + 1 + 2,
                idle: 300 + 7,
                steal: 50
            }
        );
        let later = HostTicks {
            busy: t.busy + 60,
            idle: t.idle + 10,
            steal: t.steal + 30,
        };
        assert!((later.steal_share_since(&t) - 30.0 / 100.0).abs() < 1e-12);
        assert_eq!(t.steal_share_since(&t), 0.0);
        // An old kernel without a steal column.
        let old = HostTicks::parse("cpu 1 2 3 4\n").unwrap();
        assert_eq!(old.steal, 0);
        assert_eq!(HostTicks::parse("intr 1 2 3\n"), None);
        assert_eq!(HostTicks::parse("cpu 1 x 3 4\n"), None);
    }

    #[test]
    fn a_busy_interval_uses_cpu_on_linux() {
        if !cfg!(target_os = "linux") {
            return;
        }
        let u = Usage::start();
        let start_cpu = process_cpu_seconds().expect("/proc/self/stat");
        // Spin until the kernel has charged us a few ticks (the wall time this takes depends
        // on how much the host lets us run), with a generous bound.
        let mut x = 0u64;
        let t = Instant::now();
        while process_cpu_seconds().unwrap_or(f64::MAX) - start_cpu < 0.05
            && t.elapsed().as_secs() < 20
        {
            for _ in 0..100_000 {
                x = x.wrapping_mul(6364136223846793005).wrapping_add(1);
            }
        }
        std::hint::black_box(x);
        let r = u.stop();
        let cpu = r.cpu_s.expect("/proc/self/stat");
        // The process's CPU time counts every thread — the test harness runs other tests
        // beside this one — so it is bounded by the wall time times the cores (plus two ticks
        // of sampling), not by the wall time alone.
        let cores = std::thread::available_parallelism().map_or(1, |n| n.get()) as f64;
        assert!(
            cpu >= 0.05 && cpu <= r.wall_s * cores + 2.0 / USER_HZ,
            "{r:?}"
        );
        let s = r.steal_share.expect("/proc/stat");
        assert!((0.0..=1.0).contains(&s));
        assert!(r.describe().contains("threads busy"));
    }
}
