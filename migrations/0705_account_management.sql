-- Account management: an admin can disable an account (its sessions are revoked and it cannot log
-- in until enabled again) and start a password reset; users change their own password.
ALTER TABLE users ADD COLUMN disabled_at TIMESTAMPTZ;

-- One-time password-reset tokens an admin starts and hands to the user out of band. Only the
-- SHA-256 of a token is stored, as for session tokens; a token is used once, before it expires.
CREATE TABLE password_resets (
    token_sha256 BYTEA PRIMARY KEY CHECK (length(token_sha256) = 32),
    user_id      UUID NOT NULL REFERENCES users (id) ON DELETE CASCADE,
    created_by   UUID NOT NULL REFERENCES users (id),
    created_at   TIMESTAMPTZ NOT NULL DEFAULT now(),
    expires_at   TIMESTAMPTZ NOT NULL,
    used_at      TIMESTAMPTZ
);
CREATE INDEX password_resets_user ON password_resets (user_id);
