-- A slice whose every sample is invalid completes nothing (keep in step with the other dialect).
-- The task is queued again for another worker, and this column names the worker whose slice it
-- was: that worker is not given the task again, and a second worker's all-invalid slice fails the
-- job (the scene, not the worker, produces no valid value there).
ALTER TABLE tasks ADD COLUMN all_invalid_worker TEXT;
