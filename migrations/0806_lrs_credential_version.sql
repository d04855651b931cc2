-- The xAPI version an LMS integration speaks (1.0.3 or 2.0.0), set by the admin who creates its
-- credential. Every request still names its version in X-Experience-API-Version and is answered by
-- that version's rules; the credential's version is used only where a request names none (or one
-- this LRS does not accept): its 400 answer then carries the version the integration speaks, as
-- xAPI 1.0.3's and 2.0.0's Communication 3.3 each require of their own LRSs.
-- Existing credentials keep today's behaviour (2.0.0).
ALTER TABLE lrs_credentials
    ADD COLUMN xapi_version TEXT NOT NULL DEFAULT '2.0.0'
        CHECK (xapi_version IN ('1.0.3', '2.0.0'));
