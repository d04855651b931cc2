-- LTI 1.3 tool side and LTI Advantage (issue 17): registered platforms, the tool's own keys,
-- OIDC login states and used nonces, the accounts/courses/resource links that launches map to,
-- the AGS targets, and the queue that triggers fill when an LTI learner's attempt is scored or
-- approved (the learning records never import the LTI module: these triggers are the only link).

CREATE TABLE lti_platforms (
    id              UUID PRIMARY KEY,
    name            TEXT NOT NULL CHECK (length(name) BETWEEN 1 AND 200),
    issuer          TEXT NOT NULL CHECK (length(issuer) BETWEEN 1 AND 2000),
    client_id       TEXT NOT NULL CHECK (length(client_id) BETWEEN 1 AND 2000),
    deployment_ids  TEXT[] NOT NULL CHECK (cardinality(deployment_ids) >= 1),
    auth_url        TEXT NOT NULL,
    token_url       TEXT NOT NULL,
    jwks_url        TEXT NOT NULL,
    -- Optional defaults when a launch carries no AGS/NRPS claim.
    lineitems_url   TEXT,
    memberships_url TEXT,
    created_at      TIMESTAMPTZ NOT NULL DEFAULT now(),
    updated_at      TIMESTAMPTZ NOT NULL DEFAULT now(),
    UNIQUE (issuer, client_id)
);

-- The tool's RSA keys. Exactly one is active (signs); retired keys stay in the JWKS for a grace
-- period. The private key never leaves the database and the server.
CREATE TABLE lti_tool_keys (
    kid               TEXT PRIMARY KEY,
    private_pkcs8_pem TEXT NOT NULL,
    public_jwk        JSONB NOT NULL,
    created_at        TIMESTAMPTZ NOT NULL DEFAULT now(),
    retired_at        TIMESTAMPTZ
);
CREATE UNIQUE INDEX lti_tool_keys_one_active ON lti_tool_keys ((TRUE)) WHERE retired_at IS NULL;

-- OIDC login: state (its SHA-256) -> nonce, the browser binding (SHA-256 of a cookie value),
-- single use, short expiry.
CREATE TABLE lti_login_states (
    state_sha256    BYTEA PRIMARY KEY,
    nonce           TEXT NOT NULL,
    browser_sha256  BYTEA NOT NULL,
    platform_id     UUID NOT NULL REFERENCES lti_platforms (id) ON DELETE CASCADE,
    target_link_uri TEXT NOT NULL,
    expires_at      TIMESTAMPTZ NOT NULL
);

-- Nonces of accepted id_tokens (a replay is refused even with a fresh state).
CREATE TABLE lti_used_nonces (
    platform_id UUID NOT NULL REFERENCES lti_platforms (id) ON DELETE CASCADE,
    nonce       TEXT NOT NULL,
    expires_at  TIMESTAMPTZ NOT NULL,
    PRIMARY KEY (platform_id, nonce)
);

-- Platform users (issuer, sub) -> our accounts.
CREATE TABLE lti_users (
    issuer  TEXT NOT NULL,
    sub     TEXT NOT NULL,
    user_id UUID NOT NULL REFERENCES users (id),
    PRIMARY KEY (issuer, sub)
);
CREATE INDEX lti_users_user ON lti_users (user_id);

-- Platform contexts -> our courses, with the NRPS endpoint of the last launch.
CREATE TABLE lti_contexts (
    platform_id     UUID NOT NULL REFERENCES lti_platforms (id) ON DELETE CASCADE,
    context_id      TEXT NOT NULL,
    course_id       UUID NOT NULL REFERENCES courses (id),
    memberships_url TEXT,
    PRIMARY KEY (platform_id, context_id)
);
CREATE INDEX lti_contexts_course ON lti_contexts (course_id);

-- Deep-linking requests awaiting the instructor's choice (single use, short expiry).
CREATE TABLE lti_deep_links (
    token_sha256  BYTEA PRIMARY KEY,
    platform_id   UUID NOT NULL REFERENCES lti_platforms (id) ON DELETE CASCADE,
    deployment_id TEXT NOT NULL,
    return_url    TEXT NOT NULL,
    data          TEXT,
    expires_at    TIMESTAMPTZ NOT NULL
);

-- Where a learner's technical score for (course, station) is published (AGS line item).
CREATE TABLE lti_grade_targets (
    user_id      UUID NOT NULL REFERENCES users (id),
    course_id    UUID NOT NULL REFERENCES courses (id),
    station_id   TEXT NOT NULL,
    platform_id  UUID NOT NULL REFERENCES lti_platforms (id) ON DELETE CASCADE,
    sub          TEXT NOT NULL,
    lineitem_url TEXT NOT NULL,
    updated_at   TIMESTAMPTZ NOT NULL DEFAULT now(),
    PRIMARY KEY (user_id, course_id, station_id)
);

-- Scores to publish: filled by the triggers below, drained into the outbox by the LTI module.
CREATE TABLE lti_score_queue (
    id        BIGSERIAL PRIMARY KEY,
    result_id UUID NOT NULL REFERENCES technical_results (id),
    stage     TEXT NOT NULL CHECK (stage IN ('scored', 'approved')),
    at        TIMESTAMPTZ NOT NULL DEFAULT clock_timestamp()
);

CREATE FUNCTION lti_queue_score() RETURNS trigger LANGUAGE plpgsql AS $$
DECLARE
    rid UUID;
    st  TEXT;
BEGIN
    IF TG_TABLE_NAME = 'technical_results' THEN
        rid := NEW.id;
        st := 'scored';
    ELSE
        IF NEW.decision <> 'approved' THEN
            RETURN NULL;
        END IF;
        rid := NEW.result_id;
        st := 'approved';
    END IF;
    INSERT INTO lti_score_queue (result_id, stage)
    SELECT rid, st
    WHERE EXISTS (
        SELECT 1 FROM attempts a
        JOIN lti_grade_targets g
          ON g.user_id = a.learner_id AND g.course_id = a.course_id AND g.station_id = a.station_id
        WHERE a.id = NEW.attempt_id);
    RETURN NULL;
END;
$$;

CREATE TRIGGER technical_results_lti_score AFTER INSERT ON technical_results
    FOR EACH ROW EXECUTE FUNCTION lti_queue_score();
CREATE TRIGGER reviews_lti_score AFTER INSERT ON reviews
    FOR EACH ROW EXECUTE FUNCTION lti_queue_score();
