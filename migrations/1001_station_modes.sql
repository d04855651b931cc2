-- How a station runs in a course, set by the course's faculty: 'practice' (the session may
-- give hints such as "needle in the scan plane") or 'assessment' (no hints, and the technical
-- result is not sent over the session's socket). A station without a row runs in practice.
CREATE TABLE course_station_modes (
    course_id   UUID NOT NULL REFERENCES courses (id) ON DELETE CASCADE,
    station_id  TEXT NOT NULL CHECK (station_id <> ''),
    mode        TEXT NOT NULL CHECK (mode IN ('practice', 'assessment')),
    set_by      UUID REFERENCES users (id),
    set_at      TIMESTAMPTZ NOT NULL DEFAULT now(),
    PRIMARY KEY (course_id, station_id)
);

-- The mode an attempt was opened in: fixed at opening, so a change of the course's setting
-- never changes an attempt under way (or the meaning of one already scored).
ALTER TABLE attempts ADD COLUMN mode TEXT NOT NULL DEFAULT 'practice'
    CHECK (mode IN ('practice', 'assessment'));
