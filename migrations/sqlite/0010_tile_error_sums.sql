-- Error estimates from the tiles (keep in step with the other dialect; crates/server/src/store/
-- estimates.rs reads them). Each merge stores its tile's share of the image-level relative error:
-- Σ Var[pixel mean luminance] over its pixels with two samples or more, Σ mean luminance, and the
-- pixels with fewer than two (no variance estimate). A job's or a frame's error is then a sum over
-- its tiles, with no image assembled. NULL: not known (a tile merged before this migration, or
-- none yet); the server computes what is missing for the jobs still running when it starts.
ALTER TABLE tiles ADD COLUMN err_var DOUBLE PRECISION;
ALTER TABLE tiles ADD COLUMN err_lum DOUBLE PRECISION;
ALTER TABLE tiles ADD COLUMN err_unestimated INTEGER;
-- Each frame's convergence history, as job_progress is the job's.
CREATE TABLE frame_progress (
    job_id        TEXT NOT NULL REFERENCES jobs(id) ON DELETE CASCADE,
    frame         INTEGER NOT NULL,
    elapsed_ms    INTEGER NOT NULL,    -- since the job's first lease
    samples_done  INTEGER NOT NULL,    -- merged into the frame
    rel_error     DOUBLE PRECISION,
    PRIMARY KEY (job_id, frame, elapsed_ms)
);
