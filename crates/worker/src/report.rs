//! What a worker did: [`WorkerReport`].

/// What a worker did before it stopped.
#[derive(Clone, Debug, Default)]
pub struct WorkerReport {
    pub tasks: u64,
    pub slices: u64,
    pub samples: u64,
    /// Samples rendered invalid (NaN, infinite, negative or huge) and dropped.
    pub invalid_samples: u64,
    /// Seconds the render threads were given work (the rest of the worker's time they waited
    /// on the network, the server or the worker's own bookkeeping).
    pub render_seconds: f64,
    /// The jobs whose invalid samples were reported: one warning per job, not one per sample.
    invalid_jobs_reported: std::collections::HashSet<String>,
}

impl WorkerReport {
    /// Adds another's counts to these (a worker's lanes, a farm's workers). `render_seconds` is
    /// then a sum over lanes that may have rendered at the same time on the same threads.
    pub fn add(&mut self, other: &WorkerReport) {
        self.tasks += other.tasks;
        self.slices += other.slices;
        self.samples += other.samples;
        self.invalid_samples += other.invalid_samples;
        self.render_seconds += other.render_seconds;
        self.invalid_jobs_reported
            .extend(other.invalid_jobs_reported.iter().cloned());
    }

    /// Counts a slice's invalid samples. The first slice of a job that has any logs one warning
    /// with the count and the first example; later ones only add to the count (given when the
    /// worker stops) and log at debug level, so a broken scene cannot flood the log.
    pub(crate) fn note_invalid(&mut self, job: &str, acc: &pathfarm_tracer::Accumulation) {
        if acc.invalid_count == 0 {
            return;
        }
        self.invalid_samples += acc.invalid_count;
        let first = acc
            .invalid
            .first()
            .map(|s| format!("pixel ({}, {}) sample {}", s.x, s.y, s.index));
        if self.invalid_jobs_reported.insert(job.to_string()) {
            tracing::warn!(
                job,
                count = acc.invalid_count,
                first = first.as_deref().unwrap_or("-"),
                "invalid samples dropped (NaN, infinite, negative or huge); later ones of this job \
                 are only counted (re-render one with `pathfarm render --debug-sample X,Y,INDEX`)"
            );
        } else {
            tracing::debug!(
                job,
                count = acc.invalid_count,
                first = first.as_deref().unwrap_or("-"),
                "invalid samples dropped"
            );
        }
    }
}
