//! The report's verdict ([`SoakReport::failures`]) and its markdown.

use super::memory::mib;
use super::SoakReport;
use std::fmt::Write as _;

impl SoakReport {
    /// Everything that makes this run a failure; empty when it passed.
    pub fn failures(&self) -> Vec<String> {
        let mut f = Vec::new();
        if self.errors > 0 {
            f.push(format!(
                "{} requests failed; first: {}",
                self.errors,
                self.first_errors.join(" | ")
            ));
        }
        if self.server_merged_uploads != self.uploads_accepted {
            f.push(format!(
                "the server merged {} uploads, {} were acknowledged as new",
                self.server_merged_uploads, self.uploads_accepted
            ));
        }
        if self.server_merged_samples != self.samples_accepted
            || self.store_samples != self.samples_accepted
        {
            f.push(format!(
                "samples acknowledged {}, merged by the server {}, held by the store {}",
                self.samples_accepted, self.server_merged_samples, self.store_samples
            ));
        }
        if self.uploads_duplicate > 0 || self.server_duplicate_uploads > 0 {
            f.push(format!(
                "duplicate uploads: {} acknowledged as such, {} counted by the server",
                self.uploads_duplicate, self.server_duplicate_uploads
            ));
        }
        if self.server_rejected_uploads > 0 {
            f.push(format!(
                "the server rejected {} uploads",
                self.server_rejected_uploads
            ));
        }
        if self.server_lease_expiries > 0 {
            f.push(format!(
                "{} leases expired although every worker heartbeats",
                self.server_lease_expiries
            ));
        }
        if self.server_header_timeouts > 0 {
            f.push(format!(
                "the server closed {} connections for a late request header, though every client \
                 sends whole requests",
                self.server_header_timeouts
            ));
        }
        if self.jobs_completed == 0 {
            f.push("no job completed".into());
        }
        if self.jobs_verified != self.jobs_completed {
            f.push(format!(
                "{} of {} completed jobs had an exact image",
                self.jobs_verified, self.jobs_completed
            ));
        }
        if let Some(m) = &self.memory {
            if m.flat == Some(false) {
                f.push(format!(
                    "memory not flat: last quarter's peak {:.1} MiB > {:.1} MiB (second quarter's \
                     peak {:.1} MiB × 1.1 + 16 MiB)",
                    mib(m.last_quarter_max_kib),
                    mib(m.limit_kib),
                    mib(m.second_quarter_max_kib)
                ));
            }
        }
        f
    }

    /// The report as markdown: a summary, the requests table and the memory figures.
    pub fn markdown(&self) -> String {
        let mut s = String::new();
        let _ = writeln!(
            s,
            "### Soak on {}: {:.0} s, {} simulated workers (one upload per {} s each), {} dashboard pollers, {} live jobs of {}×{} px, {}-px tiles, {} spp\n",
            self.store,
            self.seconds,
            self.workers,
            self.pace_s,
            self.pollers,
            self.live_jobs,
            self.job.width,
            self.job.height,
            self.job.tile_size,
            self.job.spp
        );
        let _ = writeln!(s, "| figure | value |\n|---|---|");
        let mut row = |k: &str, v: String| {
            let _ = writeln!(s, "| {k} | {v} |");
        };
        row(
            "uploads accepted (per second in the window)",
            format!(
                "{} ({:.1}/s)",
                self.uploads_accepted, self.uploads_per_second
            ),
        );
        row(
            "merged by the server / samples acknowledged, merged, in store",
            format!(
                "{} / {}, {}, {}",
                self.server_merged_uploads,
                self.samples_accepted,
                self.server_merged_samples,
                self.store_samples
            ),
        );
        row(
            "duplicates / rejected / lease expiries",
            format!(
                "{} / {} / {}",
                self.uploads_duplicate + self.server_duplicate_uploads,
                self.server_rejected_uploads,
                self.server_lease_expiries
            ),
        );
        row(
            "connections closed: header timeout / keep-alive timeout",
            format!(
                "{} / {}",
                self.server_header_timeouts, self.server_keep_alive_timeouts
            ),
        );
        row(
            "leases granted / answered no work",
            format!("{} / {}", self.leases, self.leases_empty),
        );
        row(
            "jobs submitted / completed / exact / deleted",
            format!(
                "{} / {} / {} / {}",
                self.jobs_submitted, self.jobs_completed, self.jobs_verified, self.jobs_deleted
            ),
        );
        row(
            "job duration p50 / max",
            format!(
                "{:.1} s / {:.1} s",
                self.job_seconds_p50, self.job_seconds_max
            ),
        );
        row("errors", self.errors.to_string());
        if let Some(m) = &self.memory {
            row(
                "server RSS after warm-up / middle / end / max (VmHWM)",
                format!(
                    "{:.1} / {:.1} / {:.1} / {:.1} ({:.1}) MiB",
                    mib(m.start_kib),
                    mib(m.middle_kib),
                    mib(m.end_kib),
                    mib(m.max_kib),
                    mib(m.hwm_kib)
                ),
            );
            row(
                "RSS peak 2nd quarter / last quarter / limit",
                format!(
                    "{:.1} / {:.1} / {:.1} MiB: {}",
                    mib(m.second_quarter_max_kib),
                    mib(m.last_quarter_max_kib),
                    mib(m.limit_kib),
                    match m.flat {
                        Some(true) => "flat",
                        Some(false) => "GROWING",
                        None => "not judged (window under a minute)",
                    }
                ),
            );
        }
        let _ = writeln!(
            s,
            "\n| request | endpoint | count | p50 (ms) | p99 (ms) | max (ms) | statuses | errors |\n|---|---|---:|---:|---:|---:|---|---:|"
        );
        for r in &self.requests {
            let statuses = r
                .statuses
                .iter()
                .map(|(k, v)| format!("{k}: {v}"))
                .collect::<Vec<_>>()
                .join(", ");
            let _ = writeln!(
                s,
                "| {} | `{}` | {} | {:.1} | {:.1} | {:.1} | {} | {} |",
                r.kind, r.endpoint, r.count, r.p50_ms, r.p99_ms, r.max_ms, statuses, r.errors
            );
        }
        if !self.first_errors.is_empty() {
            let _ = writeln!(s, "\nFirst errors:\n");
            for e in &self.first_errors {
                let _ = writeln!(s, "- {e}");
            }
        }
        s
    }
}
