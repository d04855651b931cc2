-- LMS integrations (issue 17): the document resources of the learning record store (xAPI 2.0,
-- IEEE 9274.1.1, Communication "Document Resources"): State (activity + agent [+ registration] +
-- stateId), Activity Profile (activity + profileId) and Agent Profile (agent + profileId).
--
-- One table for the three resources. Documents are arbitrary bytes stored exactly as sent, with
-- their Content-Type; `etag` is the SHA-256 of the content in hex (the ETag the LRS sends, quoted).
-- Ids and IRIs can be long (xAPI sets no limit), so the keys are SHA-256 digests of the
-- length-prefixed parts rather than the text itself (a B-tree entry holds at most about 2.7 kB):
-- `scope_sha256` names the resource and its activity and agent, `doc_sha256` adds the registration
-- and the document id. The text columns are kept for listing ids and for reading.
CREATE TABLE xapi_documents (
    doc_sha256    BYTEA PRIMARY KEY CHECK (length(doc_sha256) = 32),
    scope_sha256  BYTEA NOT NULL CHECK (length(scope_sha256) = 32),
    kind          TEXT NOT NULL CHECK (kind IN ('state', 'activity_profile', 'agent_profile')),
    -- The Activity's IRI ('' for agent profiles).
    activity_id   TEXT NOT NULL,
    -- The agent's identity key (`xapi::agent::ifi_key`; '' for activity profiles).
    agent_key     TEXT NOT NULL,
    -- State documents only: the registration they belong to, if any.
    registration  UUID,
    -- The stateId or profileId.
    document_id   TEXT NOT NULL,
    content_type  TEXT NOT NULL,
    content       BYTEA NOT NULL,
    etag          TEXT NOT NULL CHECK (etag ~ '^[0-9a-f]{64}$'),
    updated_at    TIMESTAMPTZ NOT NULL DEFAULT now(),
    CHECK (kind = 'state' OR registration IS NULL)
);

-- Multiple-document GET (ids, optionally since a time) and DELETE of a scope.
CREATE INDEX xapi_documents_scope ON xapi_documents (scope_sha256, updated_at);
