// JSON API calls with the session cookie and the CSRF header on writes.

let csrfToken = null;

/** Sets the CSRF token of the current login (sent as X-CSRF-Token on writes). */
export function setCsrf(token) {
  csrfToken = token;
}

/** An API error: HTTP status, stable code and the server's message. */
export class ApiError extends Error {
  constructor(status, code, message, detail = {}) {
    super(message);
    this.status = status;
    this.code = code;
    /** The whole `error` object (e.g. `retry_after_s` and `readiness` of `anatomy_preparing`). */
    this.detail = detail;
  }
}

/** Calls the API; resolves to the JSON body (or null for 204), rejects with ApiError. */
export async function api(method, path, body) {
  const headers = { Accept: 'application/json' };
  if (body !== undefined) headers['Content-Type'] = 'application/json';
  if (method !== 'GET' && csrfToken) headers['X-CSRF-Token'] = csrfToken;
  const r = await fetch(path, {
    method,
    headers,
    body: body === undefined ? undefined : JSON.stringify(body),
    credentials: 'same-origin',
  });
  if (r.status === 204) return null;
  const text = await r.text();
  let json = null;
  try { json = text ? JSON.parse(text) : null; } catch { /* not JSON */ }
  if (!r.ok) {
    const e = json && json.error ? json.error : { code: 'http_' + r.status, message: text || r.statusText };
    throw new ApiError(r.status, e.code, e.message, e);
  }
  return json;
}
