-- The lease in one round trip: `pathfarm_lease` reads the candidate jobs itself.
--
-- 0012's function took the candidates' ids from the server, which read them in a round trip of
-- their own just before. The scheduler's order stays in one place: the server passes its
-- candidate query (`candidate_jobs!` in `crates/server/src/store/lease.rs`, the same text
-- SQLite's lease runs), and the function runs it. Otherwise as 0012's (its comments hold).
DROP FUNCTION pathfarm_lease(TEXT, BIGINT, BIGINT, TEXT, BIGINT, BIGINT, TEXT, TEXT, TEXT, TEXT, TEXT);

CREATE FUNCTION pathfarm_lease(
    p_worker TEXT,
    p_lock_key BIGINT,
    p_max_leases BIGINT,
    p_candidates TEXT,      -- the candidate query: rows with the job's `id`, in scheduling order
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
    v_candidate RECORD;
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
    FOR v_candidate IN EXECUTE p_candidates LOOP
        v_job_id := v_candidate.id;
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
