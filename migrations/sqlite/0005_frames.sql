-- Frame jobs (keep in step with migrations/postgres). A frame job plans each frame's tiles apart:
-- a tile's row names its frame (NULL for a still job's tiles, which are all a still job has), and
-- its accumulation is that frame's alone. Tasks keep naming tiles by index; their `pass` is the
-- lease order's rank (see crates/server/src/scheduler.rs).
ALTER TABLE tiles ADD COLUMN frame INTEGER;
