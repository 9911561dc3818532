//! CPU time and peak memory of this process, read from `/proc/self` (Linux): the one helper
//! behind `dynapix bench`, `dynapix synth --bench` and the benchmark examples. On a shared
//! machine wall time over-states the cost; CPU time does not.

use serde::Serialize;

/// Clock ticks per second of the `/proc` interface (`USER_HZ`, fixed at 100 on Linux).
const USER_HZ: f64 = 100.0;

/// CPU time (user + system) and peak resident memory of this process so far.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct ProcessUsage {
    /// User + system CPU seconds of every thread of the process (10 ms resolution).
    pub cpu_seconds: f64,
    /// Peak resident set size (MiB) since the process started.
    pub peak_rss_mib: f64,
}

/// User + system CPU seconds of every thread of this process, from `/proc/self/stat`;
/// `None` where the file does not exist or cannot be parsed.
pub fn cpu_seconds() -> Option<f64> {
    parse_cpu_seconds(&std::fs::read_to_string("/proc/self/stat").ok()?)
}

/// The process's CPU time and peak memory (`None` where `/proc/self` does not say).
pub fn process_usage() -> Option<ProcessUsage> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    Some(ProcessUsage {
        cpu_seconds: cpu_seconds()?,
        peak_rss_mib: parse_peak_rss_kib(&status)? / 1024.0,
    })
}

/// utime + stime (fields 14 and 15) of a `/proc/PID/stat` line, in seconds. The command name
/// (field 2) is in parentheses and may hold spaces, so fields are counted after its `)`.
fn parse_cpu_seconds(stat: &str) -> Option<f64> {
    let fields: Vec<&str> = stat.rsplit_once(')')?.1.split_whitespace().collect();
    let utime: f64 = fields.get(11)?.parse().ok()?;
    let stime: f64 = fields.get(12)?.parse().ok()?;
    Some((utime + stime) / USER_HZ)
}

/// The `VmHWM` (peak resident set) line of `/proc/PID/status`, in KiB.
fn parse_peak_rss_kib(status: &str) -> Option<f64> {
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    line.split_whitespace().nth(1)?.parse().ok()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stat_and_status_lines_parse() {
        let stat = "1234 (a (b) c) R 1 2 3 4 5 6 7 8 9 10 250 75 0 0 20 0 4 0";
        assert_eq!(parse_cpu_seconds(stat), Some(3.25));
        assert_eq!(parse_cpu_seconds("garbage"), None);
        let status = "Name:\tx\nVmPeak:\t  9000 kB\nVmHWM:\t    2048 kB\nVmRSS:\t 1000 kB\n";
        assert_eq!(parse_peak_rss_kib(status), Some(2048.0));
        assert_eq!(parse_peak_rss_kib("Name: x\n"), None);
    }

    #[test]
    fn cpu_time_grows_with_work() {
        let (Some(before), Some(_)) = (cpu_seconds(), process_usage()) else {
            eprintln!("skipping: no /proc/self on this system");
            return;
        };
        // Busy work until the CPU clock has advanced 50 ms (on a loaded machine that takes
        // longer than 50 ms of wall time); a clock that never advances fails after 20 s.
        let start = std::time::Instant::now();
        let mut x = 0u64;
        while cpu_seconds().is_some_and(|c| c < before + 0.05) && start.elapsed().as_secs() < 20 {
            for _ in 0..100_000 {
                x = std::hint::black_box(x.wrapping_mul(6364136223846793005).wrapping_add(1));
            }
        }
        let after = process_usage().unwrap();
        assert!(after.cpu_seconds >= before + 0.05, "{before} {after:?}");
        assert!(after.peak_rss_mib > 1.0, "{after:?}");
    }
}
