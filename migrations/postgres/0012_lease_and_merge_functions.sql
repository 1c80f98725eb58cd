-- The lease and the merge in one statement each (PostgreSQL only; SQLite runs them in its group
-- commit).
--
-- Every lease writes its job's row (the counters), and so does every merge: on a busy farm they
-- queue on that row, and each holds it until its transaction commits. Run as one statement
-- outside an explicit transaction, a write commits inside the server's round trip: the job's row
-- is held for microseconds, not for the time the farm server takes to send COMMIT
-- (docs/benchmarks.md, "the lease and the merge in one statement").
--
-- A lease in one statement.
--
-- The server reads the candidate jobs first (in its own scheduling order, without locks) and
-- passes their ids; the state machines' moves come from the server too (`states.rs`), as JSON
-- objects {"from": "to", ...}. Lock order as everywhere: tasks, jobs, workers (the worker's
-- advisory lock, taken first and only by leases, adds no cycle).
--
-- Returns one row: `outcome` is 'leased' (the task's and job's columns set), 'none' (no work),
-- 'no_worker', 'untrusted' or 'too_many' (with `held`). A worker deleted while its lease was
-- being written raises SQLSTATE P0002 (no_data_found), rolling the lease back.
CREATE FUNCTION pathfarm_lease(
    p_worker TEXT,
    p_lock_key BIGINT,
    p_max_leases BIGINT,
    p_candidates TEXT,      -- JSON array of job ids, in scheduling order
    p_now BIGINT,
    p_expires BIGINT,
    p_token TEXT,
    p_task_to TEXT,         -- a queued task's state once leased
    p_job_moves TEXT,       -- JSON: job states a lease is allowed in -> the state after it
    p_leased_moves TEXT,    -- JSON: worker states -> after a lease
    p_no_work_moves TEXT    -- JSON: worker states -> after asking and finding no work
) RETURNS TABLE (
    outcome TEXT,
    held BIGINT,
    task_id BIGINT,
    job_id TEXT,
    done_end BIGINT,
    sample_end BIGINT,
    x0 BIGINT,
    y0 BIGINT,
    width BIGINT,
    height BIGINT,
    frame BIGINT,
    settings TEXT,
    scene_hash TEXT
) LANGUAGE plpgsql AS $$
DECLARE
    v_untrusted BIGINT;
    v_job_moves JSONB := p_job_moves::jsonb;
    v_job_id TEXT;
    v_task_id BIGINT;
BEGIN
    -- One worker's leases one at a time, across servers: the count below sees every earlier one.
    PERFORM pg_advisory_xact_lock(p_lock_key);
    SELECT w.untrusted INTO v_untrusted FROM workers w WHERE w.id = p_worker;
    IF NOT FOUND THEN
        outcome := 'no_worker';
        RETURN NEXT;
        RETURN;
    END IF;
    SELECT COUNT(*) INTO held FROM tasks t WHERE t.worker_id = p_worker AND t.state = 'leased';
    IF v_untrusted = 1 OR held >= p_max_leases THEN
        outcome := CASE WHEN v_untrusted = 1 THEN 'untrusted' ELSE 'too_many' END;
        RETURN NEXT;
        RETURN;
    END IF;
    FOR v_job_id IN SELECT c FROM jsonb_array_elements_text(p_candidates::jsonb) c LOOP
        -- The job's next task for this worker (not one refused to it: `all_invalid.rs`,
        -- `verification.rs`), never waiting for another server's claim.
        SELECT t.id INTO v_task_id FROM tasks t
            WHERE t.job_id = v_job_id AND t.state = 'queued'
              AND (t.all_invalid_worker IS NULL OR t.all_invalid_worker <> p_worker)
              AND (t.not_for IS NULL OR (' ' || t.not_for || ' ') NOT LIKE ('% ' || p_worker || ' %'))
            ORDER BY t.pass, t.id LIMIT 1 FOR UPDATE SKIP LOCKED;
        CONTINUE WHEN NOT FOUND;
        -- The job's state checked under its lock: paused or ended since the candidates were
        -- read, the next candidate is tried (the task, only locked, stays queued).
        UPDATE jobs j SET state = v_job_moves ->> j.state,
                started_ms = COALESCE(j.started_ms, p_now),
                queued_tasks = j.queued_tasks - 1, leased_tasks = j.leased_tasks + 1
            WHERE j.id = v_job_id AND v_job_moves ? j.state
            RETURNING j.settings, j.scene_hash INTO settings, scene_hash;
        CONTINUE WHEN NOT FOUND;
        UPDATE workers w SET state = COALESCE(p_leased_moves::jsonb ->> w.state, w.state),
                current_task = v_task_id, current_job = v_job_id, last_seen_ms = p_now
            WHERE w.id = p_worker;
        IF NOT FOUND THEN
            RAISE EXCEPTION USING ERRCODE = 'no_data_found',
                MESSAGE = 'worker ' || p_worker || ' deregistered during its lease';
        END IF;
        UPDATE tasks t SET state = p_task_to, lease_token = p_token, worker_id = p_worker,
                lease_expires_ms = p_expires, leases = t.leases + 1
            FROM tiles ti
            WHERE t.id = v_task_id AND ti.job_id = t.job_id AND ti.tile_index = t.tile_index
            RETURNING t.id, t.job_id, t.done_end, t.sample_end, ti.x0, ti.y0, ti.width,
                ti.height, ti.frame
            INTO task_id, job_id, done_end, sample_end, x0, y0, width, height, frame;
        outcome := 'leased';
        RETURN NEXT;
        RETURN;
    END LOOP;
    UPDATE workers w SET state = COALESCE(p_no_work_moves::jsonb ->> w.state, w.state),
            current_task = NULL, current_job = NULL, last_seen_ms = p_now
        WHERE w.id = p_worker;
    outcome := 'none';
    RETURN NEXT;
END;
$$;

-- A merge in one statement: the writes of a slice's merge, checked and committed inside one round
-- trip, so a merge too holds its job's row for microseconds. The server reads the task and its
-- tile without locks, checks the slice and merges it into the tile (`tasks.rs`), then calls this
-- with what it read: the task's lease token and `done_end`, the tile's `merges`. Under the rows'
-- locks (tasks, tiles, jobs, workers) the function checks they are unchanged and writes; when
-- either changed meanwhile it writes nothing and answers 'stale', and the server reads again.
-- Ordinary tasks only, with verification off (a verification's and an all-invalid slice's
-- merges stay multi-statement transactions).
--
-- Returns one row: `outcome` 'merged' or 'stale'; the job's state after the merge and whether
-- this merge completed it.
CREATE FUNCTION pathfarm_merge(
    p_task BIGINT,
    p_token TEXT,
    p_done_end BIGINT,          -- the task's done_end as read
    p_merges BIGINT,            -- the tile's merges as read
    p_end BIGINT,               -- the task's done_end after the merge
    p_task_to TEXT,             -- the task's state after the merge
    p_complete BIGINT,          -- 1 when the merge finishes the task
    p_tile_samples BIGINT,
    p_accum BYTEA,
    p_err_var DOUBLE PRECISION,
    p_err_lum DOUBLE PRECISION,
    p_err_unestimated BIGINT,
    p_samples BIGINT,           -- pixel samples merged
    p_now BIGINT,
    p_worker_moves TEXT,        -- JSON: worker states -> after the merge
    p_complete_moves TEXT       -- JSON: job states that may complete -> after completing
) RETURNS TABLE (
    outcome TEXT,
    job_state TEXT,
    completed BOOLEAN
) LANGUAGE plpgsql AS $$
DECLARE
    v_job TEXT;
    v_tile BIGINT;
    v_worker TEXT;
    v_done BIGINT;
    v_planned BIGINT;
    v_verifying BIGINT;
BEGIN
    completed := FALSE;
    SELECT t.job_id, t.tile_index, t.worker_id INTO v_job, v_tile, v_worker FROM tasks t
        WHERE t.id = p_task AND t.lease_token = p_token AND t.done_end = p_done_end
          AND t.state = 'leased' AND t.verifies IS NULL
        FOR UPDATE;
    IF NOT FOUND THEN
        outcome := 'stale';
        RETURN NEXT;
        RETURN;
    END IF;
    UPDATE tiles ti SET samples = p_tile_samples, accum = p_accum, merges = ti.merges + 1,
            err_var = p_err_var, err_lum = p_err_lum, err_unestimated = p_err_unestimated
        WHERE ti.job_id = v_job AND ti.tile_index = v_tile AND ti.merges = p_merges;
    IF NOT FOUND THEN
        outcome := 'stale';
        RETURN NEXT;
        RETURN;
    END IF;
    UPDATE tasks t SET done_end = p_end, state = p_task_to WHERE t.id = p_task;
    UPDATE jobs j SET samples_done = j.samples_done + p_samples,
            version = j.version + (CASE WHEN p_samples > 0 THEN 1 ELSE 0 END),
            leased_tasks = j.leased_tasks - p_complete
        WHERE j.id = v_job
        RETURNING j.state, j.samples_done, j.samples_planned, j.verifying
        INTO job_state, v_done, v_planned, v_verifying;
    IF NOT FOUND THEN
        RAISE EXCEPTION 'job % vanished during a merge', v_job;
    END IF;
    -- A pipelined worker finishes a task's last upload after it leased its next task: the merge
    -- that completes the task leaves that next task (and the worker busy with it) as it is.
    IF v_worker IS NOT NULL THEN
        UPDATE workers w SET samples_done = w.samples_done + p_samples, last_seen_ms = p_now,
                state = CASE WHEN p_complete = 1 AND w.current_task <> p_task THEN w.state
                        ELSE COALESCE(p_worker_moves::jsonb ->> w.state, w.state) END,
                current_task = CASE WHEN p_complete = 1 AND w.current_task = p_task THEN NULL
                               ELSE w.current_task END,
                current_job = CASE WHEN p_complete = 1 AND w.current_task = p_task THEN NULL
                              ELSE w.current_job END
            WHERE w.id = v_worker;
    END IF;
    -- The job's last samples (and no verification pending): it completes.
    IF v_done >= v_planned AND v_verifying <= 0 AND p_complete_moves::jsonb ? job_state THEN
        UPDATE jobs j SET state = p_complete_moves::jsonb ->> j.state, finished_ms = p_now
            WHERE j.id = v_job
            RETURNING j.state INTO job_state;
        completed := TRUE;
    END IF;
    outcome := 'merged';
    RETURN NEXT;
END;
$$;
