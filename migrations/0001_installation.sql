-- One row per installation: created on the first start, kept across restarts. /healthz reports its
-- id, which makes "a restart keeps the data" observable from outside.
CREATE TABLE installation (
    singleton  BOOLEAN PRIMARY KEY DEFAULT TRUE CHECK (singleton),
    id         UUID        NOT NULL,
    created_at TIMESTAMPTZ NOT NULL DEFAULT now(),
    starts     BIGINT      NOT NULL DEFAULT 0 CHECK (starts >= 0)
);
