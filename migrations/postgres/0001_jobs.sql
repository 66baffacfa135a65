-- Jobs, their events and idempotency keys. Times are Unix milliseconds (UTC).
CREATE TABLE jobs (
    id            TEXT PRIMARY KEY,
    owner         TEXT NOT NULL,
    status        TEXT NOT NULL,
    stage         TEXT,
    progress      DOUBLE PRECISION NOT NULL DEFAULT 0,
    options       TEXT NOT NULL,
    input_format  TEXT NOT NULL,
    input_bytes   BIGINT NOT NULL,
    filename      TEXT,
    created_at    BIGINT NOT NULL,
    started_at    BIGINT,
    finished_at   BIGINT,
    expires_at    BIGINT,
    error_code    TEXT,
    error_message TEXT,
    attempts      BIGINT NOT NULL DEFAULT 0,
    result        TEXT,
    lease_owner   TEXT,
    lease_until   BIGINT,
    seq           BIGINT NOT NULL DEFAULT 0
);
-- The queue: oldest queued first.
CREATE INDEX jobs_queue ON jobs (status, created_at, id);
CREATE INDEX jobs_expiry ON jobs (expires_at) WHERE expires_at IS NOT NULL;

CREATE TABLE job_events (
    job_id TEXT NOT NULL REFERENCES jobs (id) ON DELETE CASCADE,
    seq    BIGINT NOT NULL,
    data   TEXT NOT NULL,
    PRIMARY KEY (job_id, seq)
);

CREATE TABLE idempotency_keys (
    owner        TEXT NOT NULL,
    key          TEXT NOT NULL,
    payload_hash TEXT NOT NULL,
    job_id       TEXT NOT NULL,
    created_at   BIGINT NOT NULL,
    PRIMARY KEY (owner, key)
);
