//! The process collector's metrics, under the names every Prometheus client library gives them
//! (`process_cpu_seconds_total`, `process_resident_memory_bytes`, …), so that the dashboards
//! written for those work unchanged. Read from `/proc/self` at scrape time (the `procfs` crate);
//! on other systems, or when `/proc` cannot be read, they are left out rather than reported as 0.

use std::fmt::Write;

/// Appends the process metrics to `out`.
pub fn render(out: &mut String) {
    #[cfg(target_os = "linux")]
    if let Some(p) = linux::read() {
        write(out, &p);
    }
    #[cfg(not(target_os = "linux"))]
    let _ = out;
}

/// What the process collector reports.
#[cfg_attr(not(target_os = "linux"), allow(dead_code))]
struct Process {
    cpu_seconds: f64,
    resident_bytes: u64,
    virtual_bytes: u64,
    start_time_seconds: f64,
    threads: i64,
    open_fds: Option<usize>,
    max_fds: Option<u64>,
}

#[cfg_attr(not(target_os = "linux"), allow(dead_code))]
fn write(out: &mut String, p: &Process) {
    let mut metric = |name: &str, kind: &str, help: &str, value: String| {
        let _ = writeln!(
            out,
            "# HELP {name} {help}\n# TYPE {name} {kind}\n{name} {value}"
        );
    };
    metric(
        "process_cpu_seconds_total",
        "counter",
        "Total user and system CPU time spent in seconds.",
        p.cpu_seconds.to_string(),
    );
    metric(
        "process_resident_memory_bytes",
        "gauge",
        "Resident memory size in bytes.",
        p.resident_bytes.to_string(),
    );
    metric(
        "process_virtual_memory_bytes",
        "gauge",
        "Virtual memory size in bytes.",
        p.virtual_bytes.to_string(),
    );
    metric(
        "process_start_time_seconds",
        "gauge",
        "Start time of the process since unix epoch in seconds.",
        p.start_time_seconds.to_string(),
    );
    metric(
        "process_threads",
        "gauge",
        "Number of OS threads in the process.",
        p.threads.to_string(),
    );
    if let Some(n) = p.open_fds {
        metric(
            "process_open_fds",
            "gauge",
            "Number of open file descriptors.",
            n.to_string(),
        );
    }
    if let Some(n) = p.max_fds {
        metric(
            "process_max_fds",
            "gauge",
            "Maximum number of open file descriptors.",
            n.to_string(),
        );
    }
}

#[cfg(target_os = "linux")]
mod linux {
    use super::Process;
    use procfs::process::LimitValue;

    pub(super) fn read() -> Option<Process> {
        let me = procfs::process::Process::myself().ok()?;
        let stat = me.stat().ok()?;
        let ticks = procfs::ticks_per_second() as f64;
        let boot = procfs::boot_time_secs().ok()? as f64;
        let max_fds = me
            .limits()
            .ok()
            .and_then(|l| match l.max_open_files.soft_limit {
                LimitValue::Value(n) => Some(n),
                LimitValue::Unlimited => None,
            });
        Some(Process {
            cpu_seconds: (stat.utime + stat.stime) as f64 / ticks,
            resident_bytes: stat.rss * procfs::page_size(),
            virtual_bytes: stat.vsize,
            start_time_seconds: boot + stat.starttime as f64 / ticks,
            threads: stat.num_threads,
            open_fds: me.fd_count().ok(),
            max_fds,
        })
    }
}

#[cfg(all(test, target_os = "linux"))]
mod tests {
    /// This test process's own figures: plausible, and its memory what `/proc/self/status` says.
    #[test]
    fn reads_this_process() {
        let big = vec![1u8; 64 << 20];
        let p = super::linux::read().expect("/proc/self readable");
        assert!(p.resident_bytes >= 64 << 20, "{}", p.resident_bytes);
        assert!(p.virtual_bytes >= p.resident_bytes);
        assert!(p.threads >= 1);
        assert!(p.open_fds.is_some_and(|n| n >= 3));
        let now = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .unwrap()
            .as_secs_f64();
        assert!(p.start_time_seconds <= now + 1.0 && p.start_time_seconds > now - 3600.0);
        let mut out = String::new();
        super::write(&mut out, &p);
        assert!(out.contains("# TYPE process_cpu_seconds_total counter\n"));
        assert!(out.contains(&format!(
            "process_resident_memory_bytes {}\n",
            p.resident_bytes
        )));
        drop(big);
    }
}
