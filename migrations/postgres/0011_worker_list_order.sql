-- The workers list pages by (registered_ms DESC, id): an index in that order, so a page (by
-- cursor or number) reads its rows instead of sorting every registration.
CREATE INDEX workers_by_registration ON workers(registered_ms DESC, id);
