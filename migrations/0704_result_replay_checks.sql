-- Technical results come only from the simulation; each is re-checked by replaying the logged
-- session that produced it. A check is a fact about a result at a time, so the checks are
-- append-only like the results themselves: the newest check of a result is its current verdict.
--   identical    the replay reproduced the stored measurements, score, outcome, final state and
--                final image exactly;
--   differs      it did not (`detail` says what differed);
--   unavailable  there is no log to replay (results reported by clients before this migration,
--                or a session whose record never linked its result).
CREATE TABLE result_replay_checks (
    id         BIGSERIAL PRIMARY KEY,
    result_id  UUID NOT NULL REFERENCES technical_results (id),
    verdict    TEXT NOT NULL CHECK (verdict IN ('identical', 'differs', 'unavailable')),
    detail     JSONB NOT NULL DEFAULT '{}'::jsonb,
    checked_at TIMESTAMPTZ NOT NULL DEFAULT now()
);
CREATE INDEX result_replay_checks_result ON result_replay_checks (result_id, id);

CREATE TRIGGER result_replay_checks_append_only_rows BEFORE UPDATE OR DELETE ON result_replay_checks
    FOR EACH ROW EXECUTE FUNCTION reject_append_only_change();
CREATE TRIGGER result_replay_checks_append_only_truncate BEFORE TRUNCATE ON result_replay_checks
    FOR EACH STATEMENT EXECUTE FUNCTION reject_append_only_change();

-- Results a client reported have no log: say so once, so every view shows it.
INSERT INTO result_replay_checks (result_id, verdict, detail)
SELECT id, 'unavailable', '{"reason": "reported by a client before results came only from the simulation"}'::jsonb
FROM technical_results WHERE source = 'client';
