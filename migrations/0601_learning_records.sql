-- Learning records (issue 6): accounts and roles, server-side sessions, courses, attempts,
-- append-only activity, technical results, faculty reviews and the audit trail.
--
-- Append-only tables (activity_events, technical_results, reviews, audit_events) reject UPDATE,
-- DELETE and TRUNCATE with a trigger, so not even a bug in the server can rewrite history.
-- Foreign keys into them use the default NO ACTION: deleting a user with history fails.

CREATE TABLE users (
    id             UUID PRIMARY KEY,
    email          TEXT NOT NULL UNIQUE CHECK (email = lower(email) AND email LIKE '_%@_%'),
    display_name   TEXT NOT NULL CHECK (length(display_name) BETWEEN 1 AND 200),
    role           TEXT NOT NULL CHECK (role IN ('learner', 'faculty', 'admin')),
    -- PHC string (argon2id, parameters included).
    password_hash  TEXT NOT NULL,
    -- TOTP (RFC 6238): a pending secret during enrolment, the active one after confirmation, and
    -- the last accepted time step (a code is never accepted twice).
    totp_pending   BYTEA,
    totp_secret    BYTEA,
    totp_last_step BIGINT,
    -- Demo accounts created by the embedded-default run; shown as such everywhere.
    is_demo        BOOLEAN NOT NULL DEFAULT FALSE,
    created_at     TIMESTAMPTZ NOT NULL DEFAULT now()
);

-- Server-side sessions. Only the SHA-256 of the cookie token is stored, so a database leak does
-- not hand out live sessions.
CREATE TABLE auth_sessions (
    token_sha256 BYTEA PRIMARY KEY CHECK (length(token_sha256) = 32),
    user_id      UUID NOT NULL REFERENCES users (id) ON DELETE CASCADE,
    csrf_token   TEXT NOT NULL,
    -- True when the login presented a valid TOTP code.
    mfa          BOOLEAN NOT NULL,
    created_at   TIMESTAMPTZ NOT NULL DEFAULT now(),
    last_seen_at TIMESTAMPTZ NOT NULL DEFAULT now(),
    expires_at   TIMESTAMPTZ NOT NULL
);
CREATE INDEX auth_sessions_user ON auth_sessions (user_id);

-- Failed logins per e-mail, for throttling (rows older than the window are pruned on login).
CREATE TABLE login_failures (
    id    BIGSERIAL PRIMARY KEY,
    email TEXT NOT NULL,
    at    TIMESTAMPTZ NOT NULL DEFAULT now()
);
CREATE INDEX login_failures_email_at ON login_failures (email, at);

CREATE TABLE courses (
    id         UUID PRIMARY KEY,
    code       TEXT NOT NULL UNIQUE CHECK (length(code) BETWEEN 1 AND 64),
    title      TEXT NOT NULL CHECK (length(title) BETWEEN 1 AND 200),
    created_at TIMESTAMPTZ NOT NULL DEFAULT now()
);

CREATE TABLE course_members (
    course_id UUID NOT NULL REFERENCES courses (id),
    user_id   UUID NOT NULL REFERENCES users (id),
    role      TEXT NOT NULL CHECK (role IN ('learner', 'faculty')),
    added_at  TIMESTAMPTZ NOT NULL DEFAULT now(),
    PRIMARY KEY (course_id, user_id)
);
CREATE INDEX course_members_user ON course_members (user_id);

-- Every station revision the server has loaded, with the SHA-256 of its file: a published
-- (id, revision, rubric revision) can never silently change content.
CREATE TABLE station_revisions (
    station_id      TEXT NOT NULL,
    revision        INTEGER NOT NULL CHECK (revision >= 1),
    rubric_revision INTEGER NOT NULL CHECK (rubric_revision >= 1),
    file_sha256     TEXT NOT NULL CHECK (file_sha256 ~ '^[0-9a-f]{64}$'),
    definition      JSONB NOT NULL,
    first_seen_at   TIMESTAMPTZ NOT NULL DEFAULT now(),
    PRIMARY KEY (station_id, revision, rubric_revision)
);

CREATE TABLE attempts (
    id              UUID PRIMARY KEY,
    learner_id      UUID NOT NULL REFERENCES users (id),
    course_id       UUID NOT NULL REFERENCES courses (id),
    station_id      TEXT NOT NULL,
    station_revision INTEGER NOT NULL,
    rubric_revision INTEGER NOT NULL,
    state           TEXT NOT NULL DEFAULT 'in_progress'
                    CHECK (state IN ('in_progress', 'submitted', 'returned', 'approved')),
    created_at      TIMESTAMPTZ NOT NULL DEFAULT now(),
    updated_at      TIMESTAMPTZ NOT NULL DEFAULT now(),
    FOREIGN KEY (station_id, station_revision, rubric_revision)
        REFERENCES station_revisions (station_id, revision, rubric_revision)
);
CREATE INDEX attempts_course_state ON attempts (course_id, state);
CREATE INDEX attempts_learner ON attempts (learner_id);

-- Engagement, recorded by the server. recorded_at is the server's clock at insert time;
-- client_time is what the client said, kept for analysis, never trusted for ordering.
CREATE TABLE activity_events (
    id          BIGSERIAL PRIMARY KEY,
    attempt_id  UUID NOT NULL REFERENCES attempts (id),
    user_id     UUID NOT NULL REFERENCES users (id),
    kind        TEXT NOT NULL CHECK (kind IN ('session_launched', 'station_opened', 'page_viewed',
                    'view_changed', 'image_acquired', 'needle_adjusted', 'injection', 'submission')),
    recorded_at TIMESTAMPTZ NOT NULL DEFAULT clock_timestamp(),
    client_time TIMESTAMPTZ,
    detail      JSONB NOT NULL DEFAULT '{}'::jsonb
);
CREATE INDEX activity_events_attempt ON activity_events (attempt_id, id);

CREATE TABLE technical_results (
    id                        UUID PRIMARY KEY,
    attempt_id                UUID NOT NULL REFERENCES attempts (id),
    seq                       INTEGER NOT NULL CHECK (seq >= 1),
    submitted_by              UUID NOT NULL REFERENCES users (id),
    -- 'client': measurements reported by an authenticated client; 'server': computed by the
    -- server's own simulation session.
    source                    TEXT NOT NULL CHECK (source IN ('client', 'server')),
    outcome                   TEXT NOT NULL CHECK (outcome IN ('met', 'not_met', 'incomplete')),
    score                     DOUBLE PRECISION,
    measured_weight_fraction  DOUBLE PRECISION NOT NULL,
    station_id                TEXT NOT NULL,
    station_revision          INTEGER NOT NULL,
    rubric_revision           INTEGER NOT NULL,
    station_sha256            TEXT NOT NULL,
    measurements              JSONB NOT NULL,
    detail                    JSONB NOT NULL,
    -- Reproducibility record.
    code_revision             TEXT NOT NULL,
    server_version            TEXT NOT NULL,
    asset_hashes              JSONB NOT NULL,
    device_profile            JSONB NOT NULL,
    imaging_settings          JSONB NOT NULL,
    interaction_log_ref       TEXT,
    activity_upto_event_id    BIGINT,
    activity_event_count      BIGINT NOT NULL,
    created_at                TIMESTAMPTZ NOT NULL DEFAULT clock_timestamp(),
    UNIQUE (attempt_id, seq)
);

CREATE TABLE reviews (
    id          UUID PRIMARY KEY,
    attempt_id  UUID NOT NULL REFERENCES attempts (id),
    result_id   UUID NOT NULL REFERENCES technical_results (id),
    reviewer_id UUID NOT NULL REFERENCES users (id),
    decision    TEXT NOT NULL CHECK (decision IN ('approved', 'returned')),
    comment     TEXT NOT NULL,
    created_at  TIMESTAMPTZ NOT NULL DEFAULT clock_timestamp()
);
CREATE INDEX reviews_attempt ON reviews (attempt_id, created_at);

CREATE TABLE audit_events (
    id          BIGSERIAL PRIMARY KEY,
    at          TIMESTAMPTZ NOT NULL DEFAULT clock_timestamp(),
    actor_id    UUID REFERENCES users (id),
    action      TEXT NOT NULL,
    object_type TEXT NOT NULL,
    object_id   TEXT NOT NULL,
    detail      JSONB NOT NULL DEFAULT '{}'::jsonb
);
CREATE INDEX audit_events_object ON audit_events (object_type, object_id, id);

CREATE FUNCTION reject_append_only_change() RETURNS trigger LANGUAGE plpgsql AS $$
BEGIN
    RAISE EXCEPTION 'table % is append-only: % is not allowed', TG_TABLE_NAME, TG_OP
        USING ERRCODE = 'insufficient_privilege';
END;
$$;

DO $$
DECLARE t TEXT;
BEGIN
    FOREACH t IN ARRAY ARRAY['activity_events', 'technical_results', 'reviews', 'audit_events'] LOOP
        EXECUTE format('CREATE TRIGGER %I BEFORE UPDATE OR DELETE ON %I
                        FOR EACH ROW EXECUTE FUNCTION reject_append_only_change()',
                       t || '_append_only_rows', t);
        EXECUTE format('CREATE TRIGGER %I BEFORE TRUNCATE ON %I
                        FOR EACH STATEMENT EXECUTE FUNCTION reject_append_only_change()',
                       t || '_append_only_truncate', t);
    END LOOP;
END;
$$;
