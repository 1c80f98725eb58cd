-- A job's environment image (stored in `scenes`, the blobs by SHA-256, like its scene; NULL for no
-- environment or a uniform one), kept as a column so that deleting a job can tell when no job uses
-- a blob any more. And what the scene loader ignored when the job was submitted (a JSON array of
-- strings, control characters stripped, its size capped by the server).
ALTER TABLE jobs ADD COLUMN environment_hash TEXT REFERENCES scenes(hash);
ALTER TABLE jobs ADD COLUMN warnings TEXT NOT NULL DEFAULT '[]';
