-- Live simulation sessions (issue 7): the server's own copy of each session's initial state and
-- ordered command log. It is what a session is restored from when its render worker dies, and
-- what faculty replay an attempt from. The log grows only by acknowledged commands, in order.
CREATE TABLE live_sessions (
    id                  UUID PRIMARY KEY,
    attempt_id          UUID NOT NULL REFERENCES attempts (id),
    learner_id          UUID NOT NULL REFERENCES users (id),
    station_id          TEXT NOT NULL,
    initial_snapshot    JSONB NOT NULL,
    log                 JSONB NOT NULL DEFAULT '[]'::jsonb,
    -- Set at submit: the technical result, and hashes that a replay must reproduce exactly.
    result_id           UUID REFERENCES technical_results (id),
    final_state_sha256  TEXT,
    final_frame_sha256  TEXT,
    created_at          TIMESTAMPTZ NOT NULL DEFAULT now(),
    updated_at          TIMESTAMPTZ NOT NULL DEFAULT now()
);
CREATE INDEX live_sessions_attempt ON live_sessions (attempt_id, created_at);
