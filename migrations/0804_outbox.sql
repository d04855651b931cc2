-- The durable outbox (issue 17): work for the outside world (xAPI statements for an external LRS,
-- LTI grade passback) is enqueued in the same transaction as the record that causes it, and
-- delivered later by server::outbox with retries, so nothing committed is ever lost and nothing is
-- sent for a record that was rolled back. The rows are the truth: a restart resumes from them.
--
-- Life of a row: pending (delivered_at and failed_at NULL) -> claimed by a worker for a lease
-- (next_attempt_at moved to the lease's end, attempts + 1) -> delivered (delivered_at) | retried
-- (next_attempt_at after the backoff, last_error) | failed for good (failed_at: a permanent error,
-- never retried). A worker that dies mid-delivery leaves its lease to expire; the row is then
-- delivered again (at-least-once: the receivers are idempotent by key).
CREATE TABLE outbox (
    id              BIGSERIAL PRIMARY KEY,
    kind            TEXT NOT NULL CHECK (kind ~ '^[a-z0-9-]{1,64}$'),
    -- Idempotency key of the producer: a second enqueue of (kind, key) does nothing.
    key             TEXT NOT NULL CHECK (length(key) BETWEEN 1 AND 500),
    payload         JSONB NOT NULL,
    created_at      TIMESTAMPTZ NOT NULL DEFAULT now(),
    attempts        INTEGER NOT NULL DEFAULT 0,
    next_attempt_at TIMESTAMPTZ NOT NULL DEFAULT now(),
    last_error      TEXT,
    last_error_at   TIMESTAMPTZ,
    delivered_at    TIMESTAMPTZ,
    failed_at       TIMESTAMPTZ,
    UNIQUE (kind, key)
);
-- The workers' claim query and the status's backlog read only the undelivered rows.
CREATE INDEX outbox_undelivered ON outbox (kind, next_attempt_at, id) WHERE delivered_at IS NULL;

-- Per-kind totals kept up to date by the workers (counting delivered rows would read the whole
-- history on every status request).
CREATE TABLE outbox_kind_stats (
    kind              TEXT PRIMARY KEY,
    delivered         BIGINT NOT NULL DEFAULT 0,
    last_delivered_at TIMESTAMPTZ,
    last_error        TEXT,
    last_error_at     TIMESTAMPTZ
);

-- A commit that enqueued something wakes the workers of every server process on this database
-- (notifications are sent at commit, never for a rolled-back transaction).
CREATE FUNCTION outbox_notify() RETURNS trigger LANGUAGE plpgsql AS $$
BEGIN
    PERFORM pg_notify('outbox', NEW.kind);
    RETURN NULL;
END;
$$;
CREATE TRIGGER outbox_notify AFTER INSERT ON outbox FOR EACH ROW EXECUTE FUNCTION outbox_notify();

-- The platform's own records become xAPI statements (server::xapi::platform). Each record is
-- queued here by a trigger in the transaction that inserts it, so no committed record is missed
-- and none of a rolled-back one is projected; the projector turns queued records into statements
-- in the local LRS and enqueues them for forwarding, in the transaction that deletes the queue
-- row. A record whose projection fails is kept with its error (failed_at) instead of blocking the
-- queue.
CREATE TABLE xapi_projection_queue (
    id         BIGSERIAL PRIMARY KEY,
    source     TEXT NOT NULL CHECK (source IN ('activity_event', 'technical_result', 'review',
                   'replay_check')),
    record_id  TEXT NOT NULL,
    queued_at  TIMESTAMPTZ NOT NULL DEFAULT now(),
    last_error TEXT,
    failed_at  TIMESTAMPTZ
);

CREATE FUNCTION xapi_projection_enqueue() RETURNS trigger LANGUAGE plpgsql AS $$
BEGIN
    INSERT INTO xapi_projection_queue (source, record_id) VALUES (TG_ARGV[0], NEW.id::text);
    PERFORM pg_notify('xapi_projection', '');
    RETURN NULL;
END;
$$;
CREATE TRIGGER activity_events_xapi AFTER INSERT ON activity_events
    FOR EACH ROW EXECUTE FUNCTION xapi_projection_enqueue('activity_event');
CREATE TRIGGER technical_results_xapi AFTER INSERT ON technical_results
    FOR EACH ROW EXECUTE FUNCTION xapi_projection_enqueue('technical_result');
CREATE TRIGGER reviews_xapi AFTER INSERT ON reviews
    FOR EACH ROW EXECUTE FUNCTION xapi_projection_enqueue('review');
-- A replay that does not reproduce a result corrects it: its statement is voided.
CREATE TRIGGER result_replay_checks_xapi AFTER INSERT ON result_replay_checks
    FOR EACH ROW WHEN (NEW.verdict = 'differs')
    EXECUTE FUNCTION xapi_projection_enqueue('replay_check');

-- Records stored before this migration are projected too, in the order they happened.
INSERT INTO xapi_projection_queue (source, record_id)
SELECT source, record_id FROM (
    SELECT 'activity_event' AS source, id::text AS record_id, recorded_at AS at, 0 AS rank
        FROM activity_events
    UNION ALL SELECT 'technical_result', id::text, created_at, 1 FROM technical_results
    UNION ALL SELECT 'review', id::text, created_at, 2 FROM reviews
    UNION ALL SELECT 'replay_check', id::text, checked_at, 3 FROM result_replay_checks
        WHERE verdict = 'differs'
) r ORDER BY at, rank, record_id;

-- The institution's external LRS that every statement the platform produces is forwarded to (at
-- most one; no row: forwarding is off and statements wait in the outbox until one is set). The
-- secret is sent as HTTP Basic on every request, so it is stored as given; the admin API never
-- returns it.
CREATE TABLE lrs_forwarding (
    singleton  BOOLEAN PRIMARY KEY DEFAULT TRUE CHECK (singleton),
    endpoint   TEXT NOT NULL CHECK (endpoint ~ '^https?://'),
    key        TEXT NOT NULL CHECK (length(key) BETWEEN 1 AND 200 AND position(':' IN key) = 0),
    secret     TEXT NOT NULL CHECK (length(secret) BETWEEN 1 AND 500),
    updated_by UUID NOT NULL REFERENCES users (id),
    updated_at TIMESTAMPTZ NOT NULL DEFAULT now()
);
