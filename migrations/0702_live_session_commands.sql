-- Live sessions (issue 7): every acknowledged command of a live session as its own row, written
-- by the server's relay before the acknowledgement is passed on to the browser. Until now the
-- log was a JSONB array in live_sessions.log, rewritten only when a connection ended or at
-- submit, so a server process that died mid-session lost what had been acknowledged since.
-- Append-only like the rest of the history: a logged command is never changed or removed.
CREATE TABLE live_session_commands (
    session_id   UUID NOT NULL REFERENCES live_sessions (id),
    seq          BIGINT NOT NULL CHECK (seq >= 0),
    t_ms         BIGINT NOT NULL CHECK (t_ms >= 0),
    command      JSONB NOT NULL,
    recorded_at  TIMESTAMPTZ NOT NULL DEFAULT now(),
    PRIMARY KEY (session_id, seq)
);

-- Move the logs recorded so far (their order is their sequence order).
INSERT INTO live_session_commands (session_id, seq, t_ms, command)
SELECT s.id, (e.entry ->> 'seq')::bigint, (e.entry ->> 't_ms')::bigint, e.entry -> 'command'
FROM live_sessions s, jsonb_array_elements(s.log) AS e(entry);

ALTER TABLE live_sessions DROP COLUMN log;

CREATE TRIGGER live_session_commands_append_only_rows BEFORE UPDATE OR DELETE
    ON live_session_commands FOR EACH ROW EXECUTE FUNCTION reject_append_only_change();
CREATE TRIGGER live_session_commands_append_only_truncate BEFORE TRUNCATE
    ON live_session_commands FOR EACH STATEMENT EXECUTE FUNCTION reject_append_only_change();
