-- The learning record store's statements (issue 17; xAPI 2.0 Statement resource).
--
-- One row per statement: the whole statement as stored (with id, stored, authority and version
-- filled by the LRS) in `statement`, plus the columns the resource needs to find it fast. `seq`
-- orders statements as stored and is the cursor of `more` paging (a later insert always gets a
-- larger seq, so pages already handed out never shift).
CREATE TABLE xapi_statements (
    seq         BIGSERIAL PRIMARY KEY,
    id          UUID NOT NULL UNIQUE,
    statement   JSONB NOT NULL,
    -- The LRS's `stored`, truncated to milliseconds (as it appears in `statement`).
    stored      TIMESTAMPTZ NOT NULL,
    -- For a voiding statement: the id of the statement it voids.
    voids       UUID,
    -- A voided statement is only returned through `voidedStatementId`.
    voided      BOOLEAN NOT NULL DEFAULT false,
    -- The statement without the properties the LRS may set (id, stored, authority, version,
    -- attachments' raw data): same id with different content is a conflict.
    content     JSONB NOT NULL
);
CREATE INDEX xapi_statements_stored ON xapi_statements (stored);
CREATE INDEX xapi_statements_voids ON xapi_statements (voids) WHERE voids IS NOT NULL;

-- The filter keys of each statement, one row each: `a:` + agent key (actor or object), `A:` +
-- agent key (any agent the statement names: related_agents), `v:` + verb id, `o:` + activity id
-- (object), `O:` + activity id (any activity: related_activities), `r:` + registration. A
-- statement that targets another (StatementRef object) also carries its target's keys, so the
-- spec's "filter conditions for StatementRefs" hold with one index lookup per condition.
CREATE TABLE xapi_statement_keys (
    key TEXT NOT NULL,
    seq BIGINT NOT NULL REFERENCES xapi_statements (seq),
    PRIMARY KEY (key, seq)
);
CREATE INDEX xapi_statement_keys_seq ON xapi_statement_keys (seq);

-- Attachments' raw data, stored once per content hash.
CREATE TABLE xapi_attachments (
    sha2         TEXT PRIMARY KEY,
    content_type TEXT NOT NULL,
    content      BYTEA NOT NULL
);

-- Activities' latest definitions from stored statements (read by the Activities resource).
CREATE TABLE xapi_activities (
    activity_id TEXT PRIMARY KEY,
    definition  JSONB NOT NULL,
    updated_at  TIMESTAMPTZ NOT NULL DEFAULT now()
);
