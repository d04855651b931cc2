-- LMS integrations (issue 17): per-integration credentials of the learning record store under
-- /xapi/. An admin creates one for each LMS integration and revokes it; the LRS authenticates
-- each request with HTTP Basic (key as user name, secret as password).
--
-- The secret is 32 random bytes shown once at creation; only its SHA-256 is stored (a high-entropy
-- secret needs no slow hash, and the LRS checks one on every request). A revoked credential is kept
-- (its statements name it as their authority) but no longer authenticates.
CREATE TABLE lrs_credentials (
    id            UUID PRIMARY KEY,
    name          TEXT NOT NULL CHECK (length(name) BETWEEN 1 AND 200),
    -- The Basic user name: public, unique.
    key           TEXT NOT NULL UNIQUE CHECK (key ~ '^[A-Za-z0-9_-]{8,64}$'),
    secret_sha256 BYTEA NOT NULL CHECK (length(secret_sha256) = 32),
    can_read      BOOLEAN NOT NULL,
    can_write     BOOLEAN NOT NULL,
    -- The xAPI Agent set as the authority of every statement stored through this credential.
    authority     JSONB NOT NULL,
    created_by    UUID NOT NULL REFERENCES users (id),
    created_at    TIMESTAMPTZ NOT NULL DEFAULT now(),
    revoked_at    TIMESTAMPTZ,
    CHECK (can_read OR can_write)
);
