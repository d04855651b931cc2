-- Failed logins are throttled per client and account together (OWASP Authentication Cheat Sheet,
-- "Login Throttling"), so failures from one client cannot lock the account for everyone.
ALTER TABLE login_failures ADD COLUMN client TEXT NOT NULL DEFAULT '';
CREATE INDEX login_failures_email_client_at ON login_failures (email, client, at);
