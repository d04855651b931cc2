-- Several server replicas share one deployment: PostgreSQL is the only state they share.
--
-- render_workers: one row per render worker, written by its heartbeats (any replica takes
-- them). A worker whose heartbeats stop is marked dead by whichever replica notices first:
-- the UPDATE that marks it names the replica, and only one UPDATE can move a row out of
-- 'alive', so there is one winner.
CREATE TABLE render_workers (
    url             TEXT PRIMARY KEY,
    capacity        INTEGER NOT NULL CHECK (capacity BETWEEN 1 AND 10000),
    -- Sessions the worker itself reported in its last heartbeat.
    sessions        INTEGER NOT NULL DEFAULT 0 CHECK (sessions >= 0),
    renderer        JSONB NOT NULL,
    adapter         JSONB,
    state           TEXT NOT NULL DEFAULT 'alive' CHECK (state IN ('alive', 'draining', 'dead')),
    registered_at   TIMESTAMPTZ NOT NULL DEFAULT now(),
    last_seen       TIMESTAMPTZ NOT NULL DEFAULT now(),
    dead_since      TIMESTAMPTZ,
    marked_dead_by  TEXT
);

-- session_placements: one row per live session, where it runs and which replica relays it, at
-- which epoch. Deleted when the session ends on that replica (only by the replica that holds
-- the row's epoch), or by any replica once the holder stopped refreshing it (a replica that
-- died). An autoscaler counts these rows.
CREATE TABLE session_placements (
    session_id      UUID PRIMARY KEY REFERENCES live_sessions (id),
    epoch           BIGINT NOT NULL CHECK (epoch >= 0),
    replica         TEXT NOT NULL,
    -- NULL: the relaying replica's own in-process worker.
    worker_url      TEXT,
    worker_session  TEXT NOT NULL,
    placed_at       TIMESTAMPTZ NOT NULL DEFAULT now(),
    seen_at         TIMESTAMPTZ NOT NULL DEFAULT now()
);
CREATE INDEX session_placements_worker ON session_placements (worker_url);
CREATE INDEX session_placements_replica ON session_placements (replica);

-- The epoch of a session: bumped by every connection that takes the session over (on any
-- replica). Every appended command carries the epoch its writer holds, and the trigger below
-- refuses one whose epoch is not the session's current one, so a replica that lost the session
-- can never append again (no split brain). The row lock (FOR SHARE) orders appends and
-- takeovers: a takeover's UPDATE waits for appends in flight, and an append after it sees the
-- new epoch.
ALTER TABLE live_sessions ADD COLUMN epoch BIGINT NOT NULL DEFAULT 0 CHECK (epoch >= 0);
ALTER TABLE live_session_commands ADD COLUMN epoch BIGINT NOT NULL DEFAULT 0;

CREATE FUNCTION fence_live_session_command() RETURNS trigger LANGUAGE plpgsql AS $$
DECLARE
    current BIGINT;
BEGIN
    SELECT epoch INTO current FROM live_sessions WHERE id = NEW.session_id FOR SHARE;
    IF current IS DISTINCT FROM NEW.epoch THEN
        -- SQLSTATE PF409 (this schema's own): the writer was fenced off by a takeover.
        RAISE EXCEPTION 'session % is held at epoch %, not %', NEW.session_id, current, NEW.epoch
            USING ERRCODE = 'PF409';
    END IF;
    RETURN NEW;
END
$$;

CREATE TRIGGER live_session_commands_fenced BEFORE INSERT ON live_session_commands
    FOR EACH ROW EXECUTE FUNCTION fence_live_session_command();
