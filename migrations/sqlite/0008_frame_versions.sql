-- Each tile counts the slices merged into it (keep in step with the other dialect), so that a
-- frame's image has a version of its own (the sum over its tiles): a merge into one frame leaves
-- every other frame's kept image and its ETag current. Tiles merged before count one.
ALTER TABLE tiles ADD COLUMN merges INTEGER NOT NULL DEFAULT 0;
UPDATE tiles SET merges = 1 WHERE samples > 0;
